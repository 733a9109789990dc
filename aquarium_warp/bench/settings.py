"""What a run of the suite measures: `BenchSettings`, and the count lists of its sweeps."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from ..arguments import parse_list


def parse_counts(text: str | Sequence[int], name: str = "counts") -> list[int]:
    """`"16,64,...,1000000"` -> [16, 64, 256, ..., 262144, 1000000]: positive integers; an ellipsis
    continues the progression of the terms before it (geometric when they have a constant ratio
    above 1, else arithmetic: `"100,200,300,...,600"`) while it stays below the last term, which
    always ends the list (`arguments.parse_list` with `last="cap"`)."""
    return parse_list(text, int, name, last="cap", minimum=1)


@dataclasses.dataclass
class BenchSettings:
    """What `run_bench` measures. Counts are lists of ints (or strings for `parse_counts`)."""

    device: str | None = None  # None: cuda:0 when present, else cpu
    agents: list[int] = dataclasses.field(default_factory=lambda: parse_counts("16,64,...,1000000"))
    worlds: list[int] = dataclasses.field(default_factory=lambda: parse_counts("1,16,...,65536"))
    # The load series: each N of `agents` up to this many, in max(1, round(load_agents / N)) worlds
    # (about load_agents agents in flight at every point); None: no load series.
    load_agents: int | None = None
    seconds: float = 1.0  # each timed run lasts at least this long
    repeats: int = 5  # timed runs per point (the median is reported)
    warmup_steps: int = 5
    stage_repeats: int = 10  # steps timed command by command for the stage breakdown
    max_agents_in_flight: int = 4_194_304  # points with more agents (worlds x agents per world) are skipped
    memory_fraction: float = 0.8  # skip a point whose estimated memory exceeds this share of what is free
    eager: bool = True  # also time the eager step on CUDA
    stages: bool = True
    heuristics: bool = True
    # The peers (`peers.Peers`: benchmarks/bench_scaling.py passes the harnesses of benchmarks/).
    original: bool = False  # measure the original marl-aquarium (CPU; installs it into a throwaway venv)
    original_json: str | None = None  # or reuse a stored measurement (benchmarks/results/original_cpu.json)
    original_seconds: float = 3.0
    vmas: bool = False
    vmas_max_agents_per_env: int = 256  # VMAS's per-agent Python loops make bigger worlds take minutes a step
    vmas_max_envs: int = 65536
    vmas_budget_s: float = 20.0  # timed seconds per VMAS point at most
    budget_s: float | None = None  # skip the remaining points (with a note) once the suite ran this long
    out_dir: str = "."
    plots: bool = True
    git_commit: str | None = None  # names a copy without git history; a checkout's commit is read from git
    copy_bytes: int | None = None  # buffer size of the copy-bandwidth test (default 1 GiB CUDA, 256 MiB CPU)
    cpu_threads: int | None = None
    quiet: bool = False

    def __post_init__(self) -> None:
        self.agents = parse_counts(self.agents, "agents")
        self.worlds = parse_counts(self.worlds, "worlds")
        if self.load_agents is not None:
            self.load_agents = int(self.load_agents)
            if self.load_agents < 1:
                raise ValueError(f"load_agents={self.load_agents} must be >= 1 (or None: no load series)")
        if self.seconds <= 0 or self.repeats < 1 or self.stage_repeats < 1 or self.warmup_steps < 1:
            raise ValueError("seconds must be > 0, repeats, stage_repeats and warmup_steps >= 1")
        # Checked up front, naming the flag: later, a bad value would fail every point (or the copy test).
        if min(self.agents) < 2:  # density_config needs one prey and one predator
            raise ValueError(f"--agents: every count must be >= 2, got {min(self.agents)}")
        if self.cpu_threads is not None and self.cpu_threads < 1:
            raise ValueError(f"--cpu-threads={self.cpu_threads} must be >= 1")
        if self.copy_bytes is not None and self.copy_bytes <= 0:
            raise ValueError(f"--copy-mib must be >= 1 (copy_bytes={self.copy_bytes} must be > 0)")
