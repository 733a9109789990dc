"""`aquarium-warp bench`: the scaling benchmark suite (library and command line).

Up to three sweeps, random actions and observations on:

* **agents**: one world of N agents at the default density (16 prey per predator, 17 agents per
  800 x 800 px; `density_config`), N from `--agents` (default 16, 64, ..., 1,000,000);
* **worlds**: W default worlds of 17 agents, W from `--worlds` (default 1, 16, ..., 65,536);
* **load** (with `--load-agents L`, off by default): N agents per world (default density) for N from
  `--agents` up to L, in W = max(1, round(L / N)) worlds, so that about L agents are in flight at
  every point. One small world leaves a GPU idle (its step is bound by kernel launches), so per-agent
  time along the agents series mixes launch overhead with the cost of larger worlds; the load series
  keeps the device equally busy and shows how per-agent time changes with the size of a world alone.
  The summary's `<series>_per_agent_time_ratio` (max / min ns per agent-step from ~1,000 agents per
  world to the largest world) says how flat it is.

For every point: agent-steps per second of `env.step()` (median of `--repeats` timed runs of at least
`--seconds` after warm-up, synchronised timers; on CUDA the step replays a CUDA graph); the same for
the eager step (the recorded launches without the graph, CUDA only: "n/a" on the CPU); the time of
each stage of the step (the step program's commands grouped into motion, grid build, captures,
population and rewards, observations, plus the copy-in of the actions) and of the heuristic
policies (`heuristic_actions`, not part of the step); device memory (the env's arrays, and on CUDA
the drop in the device's free memory); and a bandwidth check: the bytes one step must move per
agent (`step_byte_model`, written out per kernel below) times agent-steps/s, as a fraction of the
device-to-device copy bandwidth measured in the same run.

Peers measured in the same run when asked: with `--original`, the original marl-aquarium 0.1.10 (CPU,
default config, through `benchmarks/original_aquarium.py`, which installs it from the package index
into a throwaway virtual environment) and, with `--vmas`, VMAS's predator-prey scenario `simple_tag`
at the agent counts of the agents and worlds series on the same device (`benchmarks/vmas_peer.py`).
Ratios are reported.

Output (`--out-dir`, default: the current directory): a printed table, `<out-dir>/scaling_<device>.json` and log-log figures
`<out-dir>/scaling_<device>_throughput.png` (agent-steps/s vs agents in flight; the load series vs
agents per world), `..._per_agent.png` (ns per agent-step, the same axes) and `..._stages.png` (share
of each stage).

    aquarium-warp bench --device cuda:0 --agents 16,64,...,1000000 --worlds 1,16,...,65536 --vmas --original
    aquarium-warp bench --device cuda:0 --agents 1000,4000,...,1000000 --worlds 1 --load-agents 4000000
    python benchmarks/bench_scaling.py --device cpu --agents 16,64,...,100000 --worlds 1,16,...,4096
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import gc
import importlib
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
BENCHMARKS = REPO / "benchmarks"
STAGES = ("actions", "motion", "grid", "captures", "population", "observations")
STAGE_LABELS = {"actions": "action copy-in", "motion": "motion (steering, acceleration, contact, integration)",
                "grid": "grid build (cell lists, once per step)", "captures": "captures (detect, resolve, share, starve)",
                "population": "population, rewards, episode end", "observations": "observations",
                "heuristics": "heuristic policies (not in the step)"}
# Kernel name -> stage (commands of `WorldShard._step_program`).
KERNEL_STAGES = {
    "integrate_motion": "motion",
    "compute_cell_keys": "grid", "array_scan": "grid", "drop_into_cells": "grid", "order_cells": "grid",
    "sort_into_cells_per_world": "grid",
    "rank_into_cells_per_world": "grid",
    "detect_captures": "captures", "count_capture_sharers": "captures", "share_capture_rewards": "captures",
    "respawn_captured_prey": "captures",
    "reproduce_prey": "population", "collect_rewards": "population", "finish_world_step": "population",
    "close_ended_episodes": "population",
}


# --------------------------------------------------------------------------------------- settings
def parse_counts(text, name: str = "counts") -> list[int]:
    """`"16,64,...,1000000"` -> [16, 64, 256, ..., 262144, 1000000]: an ellipsis continues the
    progression of the terms before it (geometric when they have a constant ratio above 1, else
    arithmetic: `"100,200,300,...,600"`) while it stays below the last term, which always ends the list."""
    if isinstance(text, (list, tuple)):
        return [int(x) for x in text]
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    if not parts:
        raise ValueError(f"{name}={text!r} is empty")
    try:
        if "..." not in parts:
            values = [int(p) for p in parts]
        else:
            at = parts.index("...")
            if parts.count("...") != 1 or at < 2 or at != len(parts) - 2:
                raise ValueError(f"{name}={text!r}: write at least two terms, '...', then the last term")
            head, last = [int(p) for p in parts[:at]], int(parts[-1])
            ratio = head[1] / head[0] if head[0] > 0 else 0.0
            step = head[1] - head[0]
            rules = []  # geometric when the ratio is constant (write 3 terms for steps: 100,200,300,...)
            if ratio > 1 and all(b == a * ratio for a, b in zip(head[:-1], head[1:])):
                rules.append(lambda v: int(round(v * ratio)))
            if step > 0 and all(b - a == step for a, b in zip(head[:-1], head[1:])):
                rules.append(lambda v: v + step)
            if not rules:
                raise ValueError(f"{name}={text!r}: the terms before '...' must grow by a constant ratio or step")
            advance = rules[0]
            values = list(head)
            while advance(values[-1]) < last:
                values.append(advance(values[-1]))
            values = [v for v in values if v < last] + [last]
    except ValueError as error:
        if "..." in str(error) or "constant" in str(error):
            raise
        raise ValueError(f"{name}={text!r} must be a comma-separated list of integers") from None
    if any(v < 1 for v in values):
        raise ValueError(f"{name}={text!r}: every count must be >= 1")
    return values


@dataclasses.dataclass
class BenchSettings:
    """What `run_bench` measures. Counts are lists of ints (or strings for `parse_counts`)."""

    device: str | None = None  # None: cuda:0 when present, else cpu
    agents: list = dataclasses.field(default_factory=lambda: parse_counts("16,64,...,1000000"))
    worlds: list = dataclasses.field(default_factory=lambda: parse_counts("1,16,...,65536"))
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
    git_commit: str | None = None  # default: `git rev-parse HEAD` of the repository
    copy_bytes: int | None = None  # buffer size of the copy-bandwidth test (default 1 GiB CUDA, 256 MiB CPU)
    cpu_threads: int | None = None
    quiet: bool = False

    def __post_init__(self):
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


# --------------------------------------------------------------------------------------- configs
def split_agents(agents: int) -> tuple[int, int]:
    """(prey, predators) for `agents` agents: about one predator per 16 prey, at least one of each
    (also how `benchmarks/vmas_peer.py` splits VMAS's agents)."""
    if agents < 2:
        raise ValueError(f"agents={agents} must be >= 2 (at least one prey and one predator)")
    predators = max(1, round(agents / 17))
    return agents - predators, predators


def density_config(agents: int, **changes):
    """About `agents` agents (16 prey per predator) at the default density of 17 per 800 x 800 px."""
    from .config import AquariumConfig

    prey, predators = split_agents(agents)
    side = 800.0 * math.sqrt((prey + predators) / 17.0)
    return AquariumConfig(prey_count=prey, predator_count=predators, width=side, height=side, **changes)


def load_worlds(agents_per_world: int, load_agents: int) -> int:
    """Worlds of the load series' point: about `load_agents` agents in flight, at least one world."""
    return max(1, round(load_agents / agents_per_world))


def random_actions(cfg, worlds: int, generator, device) -> dict:
    """One random action per slot of both types, as int32 (the env's own action dtype: a timed step
    copies them in without a conversion)."""
    import torch

    return {t: torch.randint(0, cfg.action_count, (worlds, n), generator=generator, device=device, dtype=torch.int32)
            for t, n in (("prey", cfg.prey_capacity), ("predator", cfg.predator_count))}


def sweep_points(settings: BenchSettings) -> list[tuple[str, object, int]]:
    """(series, config, worlds) of every point: the agents sweep (one world), the worlds sweep, then
    the load sweep (with `settings.load_agents`: each N of `settings.agents` up to it, in
    `load_worlds(N, load_agents)` worlds)."""
    from .config import AquariumConfig

    points = [("agents", density_config(n), 1) for n in settings.agents]
    points += [("worlds", AquariumConfig(), w) for w in settings.worlds]
    if settings.load_agents is not None:
        points += [("load", density_config(n), load_worlds(n, settings.load_agents))
                   for n in settings.agents if n <= settings.load_agents]
    return points


# --------------------------------------------------------------------------------------- byte model
F32 = I32 = 4  # float32 and int32 (Warp's `int`), bytes
VEC2 = 8  # wp.vec2 (two float32)
BOOL = 1


def step_byte_model(cfg, dims: tuple[int, int] | None = None, cuda: bool = True) -> dict:
    """Bytes one `step()` must move per agent slot, stage by stage (reads and writes of DRAM).

    Counted: every array element that a kernel thread reads or writes for its own agent (or cell, or
    world, divided among the world's slots), once per launch. The grid stage follows the step's path
    (`grid_path`): whole-world lists (one-cell worlds, no build), rank per slot (small worlds on
    CUDA), cell counts and their prefix sum (larger worlds on CUDA) or counting sort (the CPU). Not counted: gathers of other
    agents' data during neighbour searches (cell ranges, neighbours' positions, speeds, slots), which
    small worlds keep in cache (one world of 1M agents does not: Nsight Compute measures 1.5x the
    model's total there, `benchmarks/profile_step.py`), rare events (captures, respawns, episode ends), and the
    per-type parameter structs. A lower bound for this algorithm, not for any algorithm.
    Returns `{"stages": {stage: {"read": B, "write": B}}, "read", "write", "total"}` per agent slot,
    with `cells_per_world` and `grid_path` (the build's description).
    """
    from .env import _grid_dims
    from .shard import grid_build

    C, P, Pc = cfg.capacity, cfg.predator_count, cfg.prey_capacity
    dims_x, dims_y = dims if dims is not None else _grid_dims(cfg)
    cells = dims_x * dims_y / C  # grid cells per agent slot
    pred = P / C  # share of slots that are predators
    prey = Pc / C
    per_world = 1.0 / C
    stages = {}

    # Action copy-in (env.step): int32 action of every slot copied from the caller's tensor.
    stages["actions"] = {"read": I32, "write": I32}

    # motion.integrate_motion, (W, C) threads. Reads: alive, action, contact partner and offset
    # (found by the last observation pass), position, velocity, acceleration. Writes: position,
    # velocity, acceleration, heading, and clears the step's reward, terminated, truncated and
    # captured flags (and the world's capture count).
    stages["motion"] = {"read": BOOL + I32 + I32 + VEC2 + 3 * VEC2,
                        "write": 4 * VEC2 + F32 + 3 * BOOL + per_world * I32}

    # Grid build (cell lists of the final positions), once per step: captures search the cell lists
    # of the start-of-step positions, which are the last step's.
    path = grid_build(cfg, (dims_x, dims_y), cuda)
    whole_world = path == "whole-world"
    if whole_world:
        # One cell per world: the lists are fixed and the searches read the state itself.
        build = []
    elif path == "rank":
        # rank_into_cells_per_world: per slot read alive and position (the rest of its world is read
        # through the cache); write the sorted agent index and position; and the range of every cell,
        # empty ones included.
        build = [{"read": BOOL + VEC2, "write": I32 + VEC2 + 2 * I32 * cells}]
    elif path == "count":
        # cell_count.zero_: one int32 per cell.
        clear = {"read": 0.0, "write": I32 * cells}
        # compute_cell_keys: read position, alive; write the key and the arrival order (an atomic
        # read-modify-write of the cell's count).
        keys = {"read": VEC2 + BOOL + I32, "write": I32 + I32 + I32}
        # array_scan of the counts into the cell ends: read and write one int32 per cell.
        scan = {"read": I32 * cells, "write": I32 * cells}
        # drop_into_cells: read key, arrival order and the cell's start; write the scratch entry.
        drop = {"read": 3 * I32, "write": I32}
        # order_cells: read the scratch entry, its key, its cell's range and the cell's other scratch
        # entries (cached) and the position; write the entry and the position.
        order = {"read": 3 * I32 + VEC2, "write": I32 + VEC2}
        build = [clear, keys, scan, drop, order]
    else:
        # sort_into_cells_per_world (the CPU's counting sort): clear the counts (a pass writing cells);
        # per agent read alive and position, write its key and count it (read-modify-write of the
        # cell's count); a prefix sum over the cells (read count, write start and end); per agent
        # read the key, position and the cell's cursor, write the sorted agent index, position and
        # the cursor.
        build = [{"read": 0.0, "write": I32 * cells},
                 {"read": BOOL + VEC2 + I32, "write": I32 + I32},
                 {"read": 4 * cells, "write": 8 * cells},
                 {"read": I32 + VEC2 + I32, "write": I32 + VEC2 + I32}]
    stages["grid"] = {"read": sum(b["read"] for b in build), "write": sum(b["write"] for b in build)}

    # Captures and starvation. detect_captures, a few threads per predator (rows of its search
    # square): read alive and position (the neighbour walk is a gather). count_capture_sharers, one thread per prey slot: read alive
    # and captured, read-modify-write age. share_capture_rewards, one thread per predator: read alive
    # and position, read-modify-write starvation, write reward. respawn_captured_prey, one thread per
    # prey slot: read captured.
    stages["captures"] = {
        "read": pred * (BOOL + VEC2) + prey * (BOOL + BOOL + I32) + pred * (BOOL + VEC2 + I32) + prey * BOOL,
        "write": prey * I32 + pred * (F32 + I32),
    }
    # Population, rewards, episode end. collect_rewards reads reward, alive and episode return and
    # writes reward and episode return; finish_world_step reads the world's step, captures, episode
    # captures and both alive counts and writes episode_ended, step and episode captures;
    # close_ended_episodes reads episode_ended once per world (it truncates and respawns ended worlds).
    stages["population"] = {
        "read": (F32 + BOOL + F32) + per_world * (5 * I32 + 2 * BOOL),
        "write": (F32 + F32) + per_world * (BOOL + 2 * I32),
    }
    if cfg.prey_reproduction:
        # reproduce_prey, one thread per world: reads alive, age and replication age of each prey slot.
        stages["population"]["read"] += prey * (BOOL + 2 * I32)

    # Observations: the observation kernel, one thread per slot: read alive, its position, heading
    # and velocity (from the state, by slot); write its observation row
    # (float32), the mask and slot of each neighbour slot, and the contact partner and offset.
    obs_floats = prey * cfg.observation_size("prey") + pred * cfg.observation_size("predator")
    slots = (prey * (cfg.prey.predator_slots + cfg.prey.prey_slots)
             + pred * (cfg.predator.predator_slots + cfg.predator.prey_slots))
    stages["observations"] = {"read": BOOL + 3 * VEC2,
                              "write": F32 * obs_floats + slots * (BOOL + I32) + I32 + VEC2}
    read = sum(s["read"] for s in stages.values())
    write = sum(s["write"] for s in stages.values())
    return {"stages": stages, "read": read, "write": write, "total": read + write,
            "cells_per_world": dims_x * dims_y,
            "grid_path": GRID_PATHS[path]}


# The byte model's name for each way of making the step's cell lists (`shard.grid_build`).
GRID_PATHS = {"whole-world": "whole-world lists (no build)", "rank": "rank per slot (CUDA)",
              "count": "cell counts + prefix sum (CUDA)", "counting": "counting sort (CPU)"}


# --------------------------------------------------------------------------------------- machine
def git_info(commit: str | None = None) -> dict:
    """The repository's commit and whether tracked files differ from it (`commit` overrides)."""
    if commit:
        return {"commit": commit, "dirty": None, "source": "given"}
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=REPO, timeout=30)
        if head.returncode != 0:
            return {"commit": "unknown", "dirty": None, "source": "git failed"}
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                                text=True, cwd=REPO, timeout=30)
        return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip()), "source": "git"}
    except (OSError, subprocess.SubprocessError):
        return {"commit": "unknown", "dirty": None, "source": "no git"}


def machine_info(device: str) -> dict:
    import numpy as np
    import torch
    import warp as wp

    try:
        vmas = _benchmarks_module("vmas_peer").vmas_version()
    except ImportError:
        vmas = None
    dev = wp.get_device(device)
    info = {"device": device, "device_name": dev.name, "platform": platform.platform(),
            "python": platform.python_version(), "warp": wp.__version__, "torch": torch.__version__,
            "numpy": np.__version__, "vmas": vmas, "cpu_count": os.cpu_count(),
            "cpu_threads_available": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    if dev.is_cuda:
        info["device_memory_bytes"] = int(dev.total_memory)
        info["cuda_capability"] = list(torch.cuda.get_device_capability(torch.device(device)))
        info["torch_cuda"] = torch.version.cuda
        try:
            info["driver"] = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                            capture_output=True, text=True, timeout=30).stdout.strip() or None
        except (OSError, subprocess.SubprocessError):
            info["driver"] = None
    return info


def _available_bytes(device: str) -> int:
    import warp as wp

    dev = wp.get_device(device)
    if dev.is_cuda:
        return int(dev.free_memory)
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError):
        return 1 << 40


def copy_bandwidth(device: str, nbytes: int | None = None, repeats: int = 10) -> dict:
    """Device-to-device copy bandwidth: a `torch` copy of `nbytes` between two buffers on `device`,
    median of `repeats` timed copies (CUDA events on CUDA). Counts the bytes read plus written, like
    the byte model: `2 * nbytes / time`."""
    import torch

    tdev = torch.device(device)
    cuda = tdev.type == "cuda"
    if nbytes is None:
        nbytes = (1 << 30) if cuda else (256 << 20)
    nbytes = int(min(nbytes, _available_bytes(device) // 4))
    src = torch.empty(nbytes, dtype=torch.uint8, device=tdev)
    src.fill_(1)
    dst = torch.empty_like(src)
    times = []
    for i in range(repeats + 2):
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            dst.copy_(src)
            end.record()
            end.synchronize()
            t = start.elapsed_time(end) / 1e3
        else:
            t0 = time.perf_counter()
            dst.copy_(src)
            t = time.perf_counter() - t0
        if i >= 2:  # two warm-up copies
            times.append(t)
    del src, dst
    if cuda:
        torch.cuda.empty_cache()
    t = statistics.median(times)
    return {"bytes": nbytes, "seconds": t, "bytes_per_s": 2 * nbytes / t,
            "method": f"torch copy_ of {nbytes / 2**20:.0f} MiB on {device}, bytes read + written per second, "
                      f"median of {repeats}" + ("" if cuda else f" ({torch.get_num_threads()} torch threads)")}


# --------------------------------------------------------------------------------------- one point
def command_name(command) -> str:
    """Kernel name of a recorded launch, or the function name of another command."""
    launch = getattr(command, "__self__", None)
    if launch is not None and hasattr(launch, "kernel"):
        return launch.kernel.key
    return getattr(getattr(command, "func", command), "__name__", "command")


def command_stage(command, shard) -> str:
    """The stage of one command of `shard.programs["step"]`."""
    name = command_name(command)
    owner = getattr(command, "__self__", None)
    if name in ("zero_", "fill_"):
        grid = shard.grid
        return "grid" if owner is grid.cell_count else "population"
    if name in KERNEL_STAGES:
        return KERNEL_STAGES[name]
    if "observ" in name:
        return "observations"
    return "other"


def estimate_bytes(cfg, worlds: int) -> int:
    """Memory a point needs, about: the env's own estimate plus the sort's scratch and the action pool."""
    from .env import _grid_dims
    from .state import estimate_bytes as env_bytes

    dims = _grid_dims(cfg)
    n = worlds * cfg.capacity
    env = env_bytes(cfg, worlds, dims[0] * dims[1])
    return int(1.25 * env + 8 * 4 * n + 16 * n)  # margin, 8 action sets (int32), sort scratch


def array_bytes(env) -> int:
    """Bytes of the env's Warp arrays: the simulation state and every shard's cell lists."""
    import warp as wp

    def size(a):
        return int(getattr(a, "capacity", 0) or a.size * wp.types.type_size_in_bytes(a.dtype))

    total = sum(size(a) for a in vars(env.state).values() if isinstance(a, wp.array))
    for shard in env.shards:
        g = shard.grid
        owned = ("cell_start", "cell_end", "cell_count", "key", "agent")
        if g.cell_end.ptr == g.cell_start.ptr + 4:  # count builds: both are views of one bounds array
            owned = tuple(f for f in owned if f != "cell_end")
        if not g.whole_world:  # whole-world lists view the state's own positions
            owned += ("position",)
        total += sum(size(getattr(g, f)) for f in owned)
    return total


def timed_runs(step, sync, seconds: float, repeats: int, step_s: float, min_steps: int = 3) -> list[float]:
    """Seconds per step of `repeats` runs of at least `seconds` and `min_steps` steps each: `step(i)`
    advances one step, `sync()` waits for the device (every step when a step takes more than 1/20 of
    `seconds`, else every 8), `step_s` is a first estimate of a step's time."""
    sync_every = 1 if step_s > seconds / 20 else 8
    per_step = []
    for _ in range(repeats):
        sync()
        steps, start = 0, time.perf_counter()
        while True:
            step(steps)
            steps += 1
            if steps % sync_every == 0:
                sync()
                if steps >= min_steps and time.perf_counter() - start >= seconds:
                    break
        per_step.append((time.perf_counter() - start) / steps)
    return per_step


class _Timer:
    """Times a callable on the env's device: CUDA events on Warp's stream (device time), a
    synchronised wall clock on the CPU."""

    def __init__(self, device: str):
        import warp as wp

        self.wp = wp
        self.device = device
        self.cuda = wp.get_device(device).is_cuda

    def __call__(self, fn) -> float:
        wp = self.wp
        if self.cuda:
            stream = wp.get_stream(self.device)
            start = wp.Event(self.device, enable_timing=True)
            end = wp.Event(self.device, enable_timing=True)
            stream.record_event(start)
            fn()
            stream.record_event(end)
            return wp.get_event_elapsed_time(start, end) / 1e3
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t


def _torch_timer(device: str):
    import torch

    tdev = torch.device(device)
    if tdev.type != "cuda":
        def run(fn):
            t = time.perf_counter()
            fn()
            return time.perf_counter() - t
        return run

    def run(fn):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        fn()
        end.record()
        end.synchronize()
        return start.elapsed_time(end) / 1e3
    return run


def measure_point(series: str, cfg, worlds: int, device: str, settings: BenchSettings) -> dict:
    """Measure one configuration; returns the point's record (status "ok", "skipped" or "failed")."""
    import torch
    import warp as wp

    from .env import BatchedAquarium, _grid_dims
    from .heuristics import heuristic_actions

    agents = worlds * cfg.capacity
    dims = _grid_dims(cfg)
    cuda = wp.get_device(device).is_cuda
    row = {"series": series, "worlds": worlds, "agents_per_world": cfg.capacity, "agents": agents,
           "prey_per_world": cfg.prey_capacity, "predators_per_world": cfg.predator_count,
           "world_size_px": [cfg.width, cfg.height], "cells_per_world": dims[0] * dims[1], "status": "ok", "note": None}
    if agents > settings.max_agents_in_flight:
        return {**row, "status": "skipped",
                "note": f"{agents} agents > --max-agents-in-flight {settings.max_agents_in_flight}"}
    need = estimate_bytes(cfg, worlds)
    gc.collect()
    if cuda:
        wp.synchronize_device(device)
        torch.cuda.empty_cache()
    free = _available_bytes(device)
    row["memory_estimate_bytes"] = need
    if need > settings.memory_fraction * free:
        return {**row, "status": "skipped", "note": f"needs about {need / 2**30:.2f} GiB, "
                f"{free / 2**30:.2f} GiB free on {device}"}
    env = None
    try:
        tdev = torch.device(device)
        gen = torch.Generator(device=tdev).manual_seed(0)
        pool = [random_actions(cfg, worlds, gen, tdev) for _ in range(8)]
        if cuda:
            torch.cuda.synchronize(tdev)
        free_before = _available_bytes(device)
        build_start = time.perf_counter()
        env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=0, cpu_threads=settings.cpu_threads)
        sync = (lambda: torch.cuda.synchronize(tdev)) if cuda else (lambda: None)
        step_s = 0.0
        for i in range(settings.warmup_steps):  # the first step on CUDA captures the graph
            t = time.perf_counter()
            env.step(pool[i % 8], validate=False)
            sync()
            step_s = time.perf_counter() - t
        row["build_s"] = time.perf_counter() - build_start
        row["memory"] = {"arrays_bytes": array_bytes(env),
                         "device_bytes": (free_before - _available_bytes(device)) if cuda else None,
                         "note": "arrays: the env's Warp arrays (state, outputs, cell lists)"
                                 + ("; device: drop of the device's free memory across construction, warm-up "
                                    "and graph capture" if cuda else "")}
        row["memory"]["bytes_per_agent"] = row["memory"]["arrays_bytes"] / agents

        runs = timed_runs(lambda k: env.step(pool[k % 8], validate=False), sync, settings.seconds,
                           settings.repeats, step_s)
        step_time = statistics.median(runs)
        row.update({"step_ms": step_time * 1e3, "agent_steps_per_s": agents / step_time,
                    "ns_per_agent_step": step_time / agents * 1e9, "runs_step_ms": [t * 1e3 for t in runs],
                    "timing": "CUDA graph replay (env.step), synchronised wall clock" if cuda
                    else "env.step (recorded launches, shards in threads), wall clock"})

        # Eager vs graph (CUDA): the same step without the graph.
        if cuda and settings.eager:
            actions = env._actions

            def eager(k):
                for t in ("prey", "predator"):
                    actions[t].copy_(pool[k % 8][t])
                env.run_on_shards(lambda shard: shard.run("step"))

            eager(0)
            sync()
            eruns = timed_runs(eager, sync, settings.seconds, settings.repeats, step_s)
            e = statistics.median(eruns)
            row["eager"] = {"step_ms": e * 1e3, "agent_steps_per_s": agents / e, "runs_step_ms": [t * 1e3 for t in eruns]}
            row["graph_speedup"] = e / step_time
        else:
            row["eager"] = None
            row["graph_speedup"] = None
            row["graph_note"] = ("n/a: no CUDA graph on the CPU (env.step runs the recorded launches)" if not cuda
                                 else "eager not measured")

        if settings.stages:
            row.update(_stage_times(env, pool, device, settings, step_time))
        if settings.heuristics:
            heuristic_actions(env)  # records the policies' launches
            sync()
            timer = _Timer(device)
            reps = _reps(settings.stage_repeats, step_time)
            samples = [timer(lambda: heuristic_actions(env)) for _ in range(reps)]
            row["heuristics_ms"] = statistics.median(samples) * 1e3
            row["heuristics_ns_per_agent"] = row["heuristics_ms"] * 1e6 / agents

        model = step_byte_model(cfg, dims, cuda=cuda)
        row["bytes_per_agent_step"] = model["total"]
        row["bytes_model"] = {s: v["read"] + v["write"] for s, v in model["stages"].items()}
        row["achieved_bytes_per_s"] = model["total"] * row["agent_steps_per_s"]
    except Exception as error:  # noqa: BLE001  (an OOM or driver error skips the point, never the suite)
        row = {**row, "status": "failed", "note": f"{type(error).__name__}: {error}"[:500]}
    finally:
        if env is not None:
            env.close()
        env = None
        pool = None
        gc.collect()
        if cuda:
            try:
                wp.synchronize_device(device)
                torch.cuda.empty_cache()
            except Exception:  # noqa: BLE001
                pass
    return row


def _reps(asked: int, step_time: float) -> int:
    """Steps timed command by command: fewer when a step is slow (at least 3)."""
    return max(3, min(asked, int(math.ceil(2.0 / max(step_time, 1e-9)))))


def _stage_times(env, pool, device: str, settings: BenchSettings, step_time: float) -> dict:
    """Median time of every command of the step program over a few eagerly launched steps, summed by
    stage. CUDA: events recorded between consecutive commands of a step, read after the step, so the
    intervals partition the step's device timeline (launch gaps included where the GPU outruns the
    host). CPU: a wall clock around each command, the commands of all shards run in the env's
    threads one command at a time."""
    import warp as wp

    timer = _Timer(device)
    copy_timer = _torch_timer(device)
    shard = env.shards[0]
    program = shard.programs["step"]
    names = [command_name(c) for c in program]
    stages = [command_stage(c, shard) for c in program]
    reps = _reps(settings.stage_repeats, step_time)
    samples = [[] for _ in program]
    copies = []
    actions = env._actions
    events = [wp.Event(device, enable_timing=True) for _ in range(len(program) + 1)] if timer.cuda else None

    def run_recorded(s):  # CUDA: one shard, on Warp's stream (run_on_shards orders it after torch's)
        stream = wp.get_stream(device)
        stream.record_event(events[0])
        for i, command in enumerate(s.programs["step"]):
            command()
            stream.record_event(events[i + 1])

    for k in range(reps):
        def copy_in():
            for t in ("prey", "predator"):
                actions[t].copy_(pool[k % 8][t])

        copies.append(copy_timer(copy_in))
        if timer.cuda:
            env.run_on_shards(run_recorded)
            wp.synchronize_event(events[-1])
            for i in range(len(program)):
                samples[i].append(wp.get_event_elapsed_time(events[i], events[i + 1], synchronize=False) / 1e3)
        else:
            for i in range(len(program)):
                samples[i].append(timer(lambda: env.run_on_shards(lambda s: s.programs["step"][i]())))
    per_command = [statistics.median(s) for s in samples]
    totals = {s: 0.0 for s in STAGES}
    totals["actions"] = statistics.median(copies)
    for stage, t in zip(stages, per_command):
        totals[stage] = totals.get(stage, 0.0) + t
    stage_ms = {s: t * 1e3 for s, t in totals.items()}
    return {"stages_ms": stage_ms, "stage_sum_ms": sum(stage_ms.values()),
            "commands_ms": [{"name": n, "stage": s, "ms": t * 1e3} for n, s, t in zip(names, stages, per_command)],
            "stage_repeats": reps,
            "stage_timing": ("CUDA events between consecutive commands of eagerly launched steps (device timeline), "
                             "median over steps" if timer.cuda
                             else "wall clock around each command (all shards), median over steps")}


# --------------------------------------------------------------------------------------- peers
def _benchmarks_module(name: str):
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    return importlib.import_module(name)


def measure_original_peer(settings: BenchSettings) -> dict:
    """The original marl-aquarium 0.1.10 (raw env, default config, CPU), or why it was not measured."""
    if settings.original_json:
        try:
            stored = json.loads(Path(settings.original_json).read_text())
            raw = stored.get("results", {}).get("raw", stored)
            return {"status": "stored", "agent_steps_per_s": raw["agent_steps_per_s"],
                    "env_steps_per_s": raw["env_steps_per_s"], "source": str(settings.original_json),
                    "machine": stored.get("machine"),
                    "note": "measured earlier, possibly on another machine (see machine)"}
        except (OSError, KeyError, ValueError) as error:
            return {"status": "skipped", "note": f"could not read {settings.original_json}: {error}"}
    if not settings.original:
        return {"status": "skipped", "note": "not asked for (--original)"}
    try:
        module = _benchmarks_module("original_aquarium")
    except ImportError as error:
        return {"status": "skipped", "note": f"benchmarks/original_aquarium.py not importable: {error}"}
    try:
        result = module.measure_original(seconds=settings.original_seconds, repeats=3, which="raw", warmup=1.0)
    except Exception as error:  # noqa: BLE001  (no network for the venv, a failing child, ...)
        return {"status": "skipped", "note": f"{type(error).__name__}: {str(error)[:400]}"}
    return {"status": "ok", "agent_steps_per_s": result["agent_steps_per_s"], "env_steps_per_s": result["env_steps_per_s"],
            "runs": [r["agent_steps_per_s"] for r in result["runs"]], "seconds": result["seconds"],
            "repeats": result["repeats"], "versions": result.get("versions"), "entry_point": result["entry_point"],
            "agents": 17, "config": "default (16 prey, 1 predator, 800 x 800 px)"}


def measure_vmas_peer(settings: BenchSettings, device: str, log, started: float | None = None) -> dict:
    """VMAS simple_tag at the agent counts of both sweeps (within the caps), or why not."""
    if not settings.vmas:
        return {"status": "skipped", "note": "not asked for (--vmas)", "points": []}
    try:
        module = _benchmarks_module("vmas_peer")
    except ImportError as error:
        return {"status": "skipped", "note": f"benchmarks/vmas_peer.py not importable: {error}", "points": []}
    if module.vmas_version() is None:
        return {"status": "skipped", "note": "vmas is not importable (pip install vmas)", "points": []}
    plan = [("agents", n, 1) for n in settings.agents]
    plan += [("worlds", 17, w) for w in settings.worlds]
    points = []
    for series, n, envs in plan:
        base = {"series": series, "agents_per_env": n, "envs": envs, "agents": n * envs}
        if (settings.budget_s is not None and started is not None
                and time.perf_counter() - started > settings.budget_s):
            points.append({**base, "status": "skipped", "note": "suite time budget spent"})
            continue
        if n > settings.vmas_max_agents_per_env:
            points.append({**base, "status": "skipped",
                           "note": f"{n} agents per env > --vmas-max-agents-per-env {settings.vmas_max_agents_per_env}"})
            continue
        if envs > settings.vmas_max_envs or n * envs > settings.max_agents_in_flight:
            points.append({**base, "status": "skipped", "note": "over --vmas-max-envs or --max-agents-in-flight"})
            continue
        try:
            r = module.measure_vmas(n, envs, device, seconds=settings.seconds, repeats=min(settings.repeats, 3),
                                    budget_s=settings.vmas_budget_s)
            points.append({**base, "status": "ok", **r})
            log(f"  VMAS {module.SCENARIO:10s} {series:6s} {envs:6d} x {n:7d}  {r['step_ms']:10.3f} ms  "
                f"{r['agent_steps_per_s']:11.3e} agent-steps/s")
        except Exception as error:  # noqa: BLE001
            points.append({**base, "status": "failed", "note": f"{type(error).__name__}: {str(error)[:300]}"})
            log(f"  VMAS {series} {envs} x {n}: failed ({type(error).__name__})")
        gc.collect()
    return {"status": "ok", "scenario": module.SCENARIO, "vmas": module.vmas_version(), "points": points,
            "split": "predators = max(1, round(N / 17)), prey = N - predators (as ours)",
            "note": "scenario defaults otherwise (2 landmarks, 10 substeps), discrete actions, observations "
                    "computed in every step"}


# --------------------------------------------------------------------------------------- the suite
def run_bench(settings: BenchSettings) -> dict:
    """Run the whole suite, write the JSON and figures, print the table; returns the JSON's content."""
    import warp as wp

    from .env import resolve_device

    log = (lambda *a: None) if settings.quiet else (lambda *a: print(*a, flush=True))
    device = resolve_device(settings.device)
    cuda = wp.get_device(device).is_cuda
    if cuda:
        try:  # freed memory goes back to the device at once, so free-memory deltas are per point
            wp.set_mempool_release_threshold(device, 0)
        except Exception:  # noqa: BLE001
            pass
    started = time.perf_counter()
    machine = machine_info(device)
    log(f"aquarium-warp bench on {device} ({machine['device_name']}), warp {machine['warp']}, torch {machine['torch']}")
    bandwidth = copy_bandwidth(device, settings.copy_bytes)
    log(f"copy bandwidth: {bandwidth['bytes_per_s'] / 1e9:.1f} GB/s (read + write)")

    points = []
    for series, cfg, worlds in sweep_points(settings):
        if settings.budget_s is not None and time.perf_counter() - started > settings.budget_s:
            points.append({"series": series, "worlds": worlds, "agents_per_world": cfg.capacity,
                           "agents": worlds * cfg.capacity, "status": "skipped", "note": "suite time budget spent"})
            continue
        row = measure_point(series, cfg, worlds, device, settings)
        if row["status"] == "ok":
            row["fraction_of_copy_bandwidth"] = row["achieved_bytes_per_s"] / bandwidth["bytes_per_s"]
        points.append(row)
        log(format_row(row))

    original = measure_original_peer(settings)
    if original.get("agent_steps_per_s"):
        log(f"  original marl-aquarium 0.1.10 (CPU, default, {original['status']}): "
            f"{original['agent_steps_per_s']:.3e} agent-steps/s")
    else:
        log(f"  original marl-aquarium: {original['note']}")
    vmas = measure_vmas_peer(settings, device, log, started)
    if vmas["status"] != "ok":
        log(f"  VMAS: {vmas['note']}")
    add_ratios(points, original, vmas)

    out_dir = Path(settings.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = device.replace(":", "")
    result = {
        "benchmark": "aquarium-warp scaling: agent-steps/s of BatchedAquarium.step (random actions, observations on)",
        "created_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": " ".join(sys.argv),
        "machine": machine, "git": git_info(settings.git_commit),
        "settings": {k: v for k, v in dataclasses.asdict(settings).items() if k not in ("quiet",)},
        "method": {
            "throughput": f"median of {settings.repeats} runs of >= {settings.seconds} s after {settings.warmup_steps} "
                          "warm-up steps; actions from a pool of 8 random sets drawn beforehand; agents counted as "
                          "slots (worlds x capacity)",
            "stages": STAGE_LABELS,
            "bandwidth": "achieved = bytes_per_agent_step (step_byte_model) x agent-steps/s; fraction of the "
                         "measured copy bandwidth (both count bytes read + written)",
            "byte_model": step_byte_model.__doc__.strip(),
        },
        "copy_bandwidth": bandwidth,
        "points": points,
        "peers": {"original": original, "vmas": vmas},
        "summary": summary(points, original, vmas),
        "wall_s": None,
    }
    figures = []
    if settings.plots:
        try:
            figures = plot_results(result, out_dir / f"scaling_{tag}")
        except Exception as error:  # noqa: BLE001
            log(f"figures failed: {type(error).__name__}: {error}")
    result["figures"] = [Path(f).name for f in figures]  # next to the JSON
    result["wall_s"] = time.perf_counter() - started
    path = out_dir / f"scaling_{tag}.json"
    path.write_text(json.dumps(_clean(result), indent=2) + "\n")
    result["json"] = str(path)
    log("")
    log(format_table(result))
    log(f"wrote {path}" + (f" and {len(figures)} figures" if figures else "") + f" in {result['wall_s']:.0f} s")
    return result


def add_ratios(points: list, original: dict, vmas: dict) -> None:
    """Ours over the peers, per point: vs the original (one 17-agent world on the CPU) and vs VMAS at
    the same series, worlds and agents per world."""
    by = {(p["series"], p["envs"], p["agents_per_env"]): p for p in vmas.get("points", []) if p.get("status") == "ok"}
    base = original.get("agent_steps_per_s")
    for row in points:
        if row.get("status") != "ok":
            continue
        ratios = {}
        if base:
            ratios["vs_original"] = row["agent_steps_per_s"] / base
        peer = by.get((row["series"], row["worlds"], row["agents_per_world"]))
        if peer:
            ratios["vs_vmas"] = row["agent_steps_per_s"] / peer["agent_steps_per_s"]
            row["vmas_agent_steps_per_s"] = peer["agent_steps_per_s"]
        row["ratios"] = ratios


SERIES = ("agents", "worlds", "load")
RATIO_FROM_AGENTS_PER_WORLD = 1000  # per-agent time ratios run from this world size (or the next above)


def per_agent_time_ratio(points: list, series: str,
                         from_agents_per_world: int = RATIO_FROM_AGENTS_PER_WORLD) -> dict | None:
    """How flat per-agent time is along one series, from the smallest world of at least
    `from_agents_per_world` agents to the largest world: the two points' agents per world and ns per
    agent-step, and ratio = max / min ns per agent-step over the series' measured points between them
    (inclusive). None when the series has no measured world of that size below its largest."""
    pts = [p for p in points if p.get("status") == "ok" and p["series"] == series]
    start = [p["agents_per_world"] for p in pts if p["agents_per_world"] >= from_agents_per_world]
    if not start:
        return None
    lo, hi = min(start), max(p["agents_per_world"] for p in pts)
    if lo >= hi:
        return None
    span = [p for p in pts if lo <= p["agents_per_world"] <= hi]
    ns = [p["ns_per_agent_step"] for p in span]

    def at(n):  # the point of that world size (the first, should a size repeat)
        return next(p for p in span if p["agents_per_world"] == n)

    return {"agents_per_world": [lo, hi], "worlds": [at(lo)["worlds"], at(hi)["worlds"]],
            "ns_per_agent_step": [at(lo)["ns_per_agent_step"], at(hi)["ns_per_agent_step"]],
            "ratio": max(ns) / min(ns), "points": len(span)}


def summary(points: list, original: dict, vmas: dict,
            from_agents_per_world: int = RATIO_FROM_AGENTS_PER_WORLD) -> dict:
    """Headline numbers. `<series>_per_agent_time_ratio` (`per_agent_time_ratio`) for every series
    with measured worlds from `from_agents_per_world` agents up to a larger one."""
    ok = [p for p in points if p.get("status") == "ok"]
    out = {}
    if ok:
        best = max(ok, key=lambda p: p["agent_steps_per_s"])
        out["best"] = {k: best[k] for k in ("series", "worlds", "agents_per_world", "agent_steps_per_s")}
        fractions = [p["fraction_of_copy_bandwidth"] for p in ok if "fraction_of_copy_bandwidth" in p]
        if fractions:
            out["max_fraction_of_copy_bandwidth"] = max(fractions)
        for series in SERIES:
            s = [p for p in ok if p["series"] == series]
            if len(s) >= 2:
                out[f"{series}_ns_per_agent_first_last"] = [s[0]["ns_per_agent_step"], s[-1]["ns_per_agent_step"]]
        for series in SERIES:
            flat = per_agent_time_ratio(ok, series, from_agents_per_world)
            if flat is not None:
                out[f"{series}_per_agent_time_ratio"] = flat
        ratios = [p["ratios"]["vs_vmas"] for p in ok if "vs_vmas" in p.get("ratios", {})]
        if ratios:
            out["vs_vmas_min_max"] = [min(ratios), max(ratios)]
        if original.get("agent_steps_per_s"):
            out["best_vs_original"] = best["agent_steps_per_s"] / original["agent_steps_per_s"]
        speedups = [p["graph_speedup"] for p in ok if p.get("graph_speedup")]
        if speedups:
            out["graph_speedup_min_max"] = [min(speedups), max(speedups)]
    return out


def _clean(value):
    """JSON without NaN or infinity (None instead)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


# --------------------------------------------------------------------------------------- printing
def _si(x) -> str:
    return "-" if x is None else f"{x:.3g}"


def format_row(row: dict) -> str:
    head = f"{row['series']:6s} {row['worlds']:6d} x {row['agents_per_world']:7d}"
    if row.get("status") != "ok":
        return f"{head}  {row['status']}: {row.get('note')}"
    eager = f"{row['graph_speedup']:.2f}x" if row.get("graph_speedup") else "n/a"
    return (f"{head}  {row['step_ms']:9.3f} ms  {row['agent_steps_per_s']:10.3e} agent-steps/s  "
            f"{row['ns_per_agent_step']:9.2f} ns/agent  eager/graph {eager}")


def format_table(result: dict) -> str:
    lines = []
    cols = ("series", "worlds x agents", "step ms", "agent-steps/s", "ns/agent", "graph", "act", "mot", "grid",
            "capt", "pop", "obs", "heur", "MiB", "B/agent", "BW frac", "xVMAS", "xorig")
    lines.append("{:6s} {:>16s} {:>9s} {:>13s} {:>9s} {:>6s} | {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} | {:>6s} | "
                 "{:>8s} {:>7s} {:>7s} {:>8s} {:>8s}".format(*cols))
    lines.append("       (stage columns and heur: ns per agent-step)")
    for p in result["points"]:
        head = f"{p['series']:6s} {p['worlds']:>7d} x {p['agents_per_world']:<7d}"
        if p.get("status") != "ok":
            lines.append(f"{head} {p['status']}: {p.get('note')}")
            continue
        st = p.get("stages_ms", {})
        ns = lambda ms: "-" if ms is None else f"{ms * 1e6 / p['agents']:.3g}"  # noqa: E731
        r = p.get("ratios", {})
        lines.append("{} {:9.3f} {:13.3e} {:9.2f} {:>6s} | {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} | {:>6s} | "
                     "{:>8s} {:7.0f} {:7.3f} {:>8s} {:>8s}".format(
                         head, p["step_ms"], p["agent_steps_per_s"], p["ns_per_agent_step"],
                         f"{p['graph_speedup']:.2f}x" if p.get("graph_speedup") else "n/a",
                         *(ns(st.get(s)) for s in STAGES), ns(p.get("heuristics_ms")),
                         _si(p["memory"]["arrays_bytes"] / 2**20), p["bytes_per_agent_step"],
                         p.get("fraction_of_copy_bandwidth", float("nan")), _si(r.get("vs_vmas")), _si(r.get("vs_original"))))
    bw = result["copy_bandwidth"]
    lines.append(f"copy bandwidth {bw['bytes_per_s'] / 1e9:.1f} GB/s (read + write); graph = eager/graph step time; "
                 "B/agent: byte model; BW frac: achieved / copy bandwidth")
    original = result["peers"]["original"]
    if original.get("agent_steps_per_s"):
        lines.append(f"original marl-aquarium 0.1.10 (CPU, default config): {original['agent_steps_per_s']:.3e} "
                     f"agent-steps/s ({original['status']})")
    vmas = result["peers"]["vmas"]
    for v in vmas.get("points", []):
        if v.get("status") == "ok":
            lines.append(f"VMAS {v['scenario']} {v['series']:6s} {v['envs']:6d} envs x {v['agents_per_env']:5d}: "
                         f"{v['step_ms']:10.3f} ms  {v['agent_steps_per_s']:.3e} agent-steps/s")
    load = (result.get("settings") or {}).get("load_agents")
    if load and any(p["series"] == "load" for p in result["points"]):
        lines.append(f"load series: worlds = max(1, round({load:,} / agents per world)), ~{load:,} agents in flight")
    summ = result.get("summary") or {}
    for series in SERIES:
        flat = summ.get(f"{series}_per_agent_time_ratio")
        if flat:
            (lo, hi), (ns_lo, ns_hi) = flat["agents_per_world"], flat["ns_per_agent_step"]
            lines.append(f"per-agent time flatness, {series} series: {lo:,} -> {hi:,} agents per world: "
                         f"{ns_lo:.3g} -> {ns_hi:.3g} ns/agent-step, max/min {flat['ratio']:.2f} "
                         f"over {flat['points']} points")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------- figures
def plot_results(result: dict, stem) -> list[Path]:
    """Log-log figures next to the JSON: agent-steps/s and ns per agent-step vs agents in flight (one
    line per series; the load series, whose agents in flight hardly change, vs agents per world), and
    the share of each stage of the step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stem = Path(stem)
    machine = result["machine"]
    where = f"{machine['device_name']} ({machine['device']})"
    commit = (result.get("git") or {}).get("commit") or "unknown"
    stamp = (f"random actions, observations on; warp {machine['warp']}, torch {machine['torch']}"
             + (f", vmas {machine['vmas']}" if machine.get("vmas") else "") + f"; commit {commit[:10]}")
    ok = [p for p in result["points"] if p.get("status") == "ok"]
    series = {"agents": ("aquarium-warp: 1 world of N agents", "tab:blue", "o"),
              "worlds": ("aquarium-warp: W worlds x 17 agents", "tab:orange", "s")}
    load_pts = [p for p in ok if p["series"] == "load"]
    if load_pts:
        load = (result.get("settings") or {}).get("load_agents") or round(statistics.median(p["agents"] for p in load_pts))
        series["load"] = (f"aquarium-warp: ~{load:,} agents in flight as worlds of N (x = N)", "tab:purple", "D")
    x_key = {"load": "agents_per_world"}  # the other series: agents in flight
    vmas = [v for v in result["peers"]["vmas"].get("points", []) if v.get("status") == "ok"]
    original = result["peers"]["original"]
    bw = result["copy_bandwidth"]["bytes_per_s"]
    paths = []
    for kind in ("throughput", "per_agent"):
        fig, ax = plt.subplots(figsize=(8.5, 7))
        value = (lambda r: r) if kind == "throughput" else (lambda r: 1e9 / r)
        for key, (label, color, marker) in series.items():
            pts = [p for p in ok if p["series"] == key]
            if not pts:
                continue
            x = x_key.get(key, "agents")
            xs = [p[x] for p in pts]
            ax.plot(xs, [value(p["agent_steps_per_s"]) for p in pts], marker=marker, color=color, label=label)
            eager = [(p[x], p["eager"]["agent_steps_per_s"]) for p in pts if p.get("eager")]
            if eager:
                ax.plot(*zip(*[(x, value(y)) for x, y in eager]), marker=marker, color=color, linestyle="--",
                        alpha=0.6, label=label + " (eager, no graph)")
            bound = [value(bw / p["bytes_per_agent_step"]) for p in pts]
            ax.plot(xs, bound, color=color, linestyle=":", alpha=0.7,
                    label=f"bound: copy bandwidth / bytes per agent-step ({key})")
        for key, label, color, marker in (("agents", "VMAS simple_tag: 1 env of N agents", "tab:green", "^"),
                                          ("worlds", "VMAS simple_tag: W envs x 17 agents", "tab:red", "v")):
            pts = [v for v in vmas if v["series"] == key]
            if pts:
                ax.plot([v["agents"] for v in pts], [value(v["agent_steps_per_s"]) for v in pts], marker=marker,
                        color=color, label=label)
        if original.get("agent_steps_per_s"):
            ax.plot([17], [value(original["agent_steps_per_s"])], marker="*", markersize=14, color="black",
                    linestyle="none", label="original marl-aquarium (CPU, 17 agents)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("agents stepped at once (worlds x agents per world)"
                      + ("; load series: agents per world" if load_pts else ""))
        ax.set_ylabel("agent-steps per second" if kind == "throughput" else "ns per agent-step")
        ax.set_title(("Throughput" if kind == "throughput" else "Time per agent-step") + f" on {where}\n{stamp}",
                     fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, frameon=False)
        fig.tight_layout()
        path = stem.parent / f"{stem.name}_{kind}.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths.append(path)

    staged = [p for p in ok if p.get("stages_ms")]
    if staged:
        panels = ("agents", "worlds") + (("load",) if any(p["series"] == "load" for p in staged) else ())
        fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.5), sharey=True)
        names = list(STAGES) + ["heuristics"]
        colors = plt.get_cmap("tab10").colors
        for ax, key in zip(axes, panels):
            pts = [p for p in staged if p["series"] == key]
            if not pts:
                ax.set_visible(False)
                continue
            xs = list(range(len(pts)))
            bottom = [0.0] * len(pts)
            for j, name in enumerate(names):
                vals = [(p["stages_ms"].get(name, 0.0) if name != "heuristics" else p.get("heuristics_ms", 0.0)) or 0.0
                        for p in pts]
                totals = [p["stage_sum_ms"] + (p.get("heuristics_ms") or 0.0) for p in pts]
                share = [100 * v / t if t else 0.0 for v, t in zip(vals, totals)]
                ax.bar(xs, share, bottom=bottom, color=colors[j % 10], label=STAGE_LABELS[name],
                       hatch="//" if name == "heuristics" else None)
                bottom = [b + s for b, s in zip(bottom, share)]
            ax.set_xticks(xs)
            ax.set_xticklabels([f"{p['agents']:,}" if key == "agents" else f"{p['worlds']:,}x{p['agents_per_world']:,}"
                                for p in pts], rotation=45, ha="right", fontsize=8)
            ax.set_title(series[key][0].split(" (")[0], fontsize=10)
            ax.set_xlabel("agents" if key == "agents" else "worlds x agents")
        axes[0].set_ylabel("share of step + heuristics time, %")
        handles, labels = next(a for a in axes if a.get_visible()).get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7.5)
        fig.suptitle(f"Where the step's time goes on {where}\n{stamp}", fontsize=10)
        fig.tight_layout(rect=(0, 0.12, 1, 0.93))
        path = stem.parent / f"{stem.name}_stages.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths.append(path)
    return paths


# --------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default=None, help="'cpu' or 'cuda:0' (default: CUDA when present)")
    parser.add_argument("--agents", default="16,64,...,1000000",
                        help="agents of the one-world sweep (and agents per world of the load series), default "
                             "density; '...' continues the progression "
                             "(default 16,64,...,1000000)")
    parser.add_argument("--worlds", default="1,16,...,65536", help="worlds of 17 agents (default 1,16,...,65536)")
    parser.add_argument("--load-agents", type=int, default=None, metavar="L",
                        help="add the load series: each N of --agents up to L in max(1, round(L / N)) worlds, "
                             "about L agents in flight at every point, so that per-agent time compares across "
                             "world sizes at equal load (default: off)")
    parser.add_argument("--seconds", type=float, default=1.0, help="length of each timed run (default 1)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per point; the median is reported")
    parser.add_argument("--warmup-steps", type=int, default=5, help="untimed steps before each point's timing")
    parser.add_argument("--stage-repeats", type=int, default=10, help="steps timed command by command")
    parser.add_argument("--max-agents-in-flight", type=int, default=4_194_304,
                        help="skip points with more agents than this (default 4,194,304)")
    parser.add_argument("--no-eager", action="store_true", help="do not time the eager step (CUDA)")
    parser.add_argument("--no-stages", action="store_true", help="no per-stage timing")
    parser.add_argument("--no-heuristics", action="store_true", help="do not time the heuristic policies")
    parser.add_argument("--original", action=argparse.BooleanOptionalAction, default=False,
                        help="measure the original marl-aquarium 0.1.10 on the CPU; it is installed from the package "
                             "index into a throwaway virtual environment (default: not measured)")
    parser.add_argument("--original-json", default=None,
                        help="use a stored measurement of the original (e.g. benchmarks/results/original_cpu.json) "
                             "instead of measuring it")
    parser.add_argument("--original-seconds", type=float, default=3.0, help="length of each timed run of the original")
    parser.add_argument("--vmas", action="store_true", help="measure VMAS simple_tag at the same agent counts")
    parser.add_argument("--vmas-max-agents-per-env", type=int, default=256,
                        help="skip VMAS points with more agents per env (its per-agent Python loops are slow)")
    parser.add_argument("--vmas-max-envs", type=int, default=65536, help="skip VMAS points with more envs")
    parser.add_argument("--vmas-budget", type=float, default=20.0, help="timed seconds per VMAS point at most")
    parser.add_argument("--budget", type=float, default=None,
                        help="seconds; once the suite ran this long, the remaining points are skipped (noted)")
    parser.add_argument("--out-dir", default=".", help="where the JSON and figures go (default: the current "
                                                       "directory; the committed results are in benchmarks/results)")
    parser.add_argument("--no-plots", action="store_true", help="write the JSON only, no figures")
    parser.add_argument("--git-commit", default=None, help="commit to record (default: git rev-parse HEAD)")
    parser.add_argument("--copy-mib", type=int, default=None, help="MiB of the copy-bandwidth test")
    parser.add_argument("--cpu-threads", type=int, default=None, help="CPU threads of the env (default: all cores)")
    parser.add_argument("--quiet", action="store_true", help="print nothing (the JSON and figures are still written)")
    parser.add_argument("--replot", default=None, metavar="JSON",
                        help="only redraw the figures of an existing scaling_<device>.json, next to it")


def settings_from_args(args) -> BenchSettings:
    return BenchSettings(
        device=args.device, agents=args.agents, worlds=args.worlds, load_agents=args.load_agents,
        seconds=args.seconds, repeats=args.repeats,
        warmup_steps=args.warmup_steps, stage_repeats=args.stage_repeats,
        max_agents_in_flight=args.max_agents_in_flight, eager=not args.no_eager, stages=not args.no_stages,
        heuristics=not args.no_heuristics, original=args.original, original_json=args.original_json,
        original_seconds=args.original_seconds, vmas=args.vmas, vmas_max_agents_per_env=args.vmas_max_agents_per_env,
        vmas_max_envs=args.vmas_max_envs, vmas_budget_s=args.vmas_budget, budget_s=args.budget, out_dir=args.out_dir,
        plots=not args.no_plots, git_commit=args.git_commit,
        copy_bytes=None if args.copy_mib is None else args.copy_mib << 20, cpu_threads=args.cpu_threads,
        quiet=args.quiet)


def replot(json_path) -> list[Path]:
    """Redraw the figures of a scaling JSON next to it (e.g. after fetching a GPU run's results)."""
    path = Path(json_path)
    result = json.loads(path.read_text())
    stem = path.with_suffix("")
    figures = plot_results(result, stem)
    result["figures"] = [f.name for f in figures]
    path.write_text(json.dumps(_clean(result), indent=2) + "\n")
    return figures


def run_from_args(args) -> int:
    if args.replot:
        figures = replot(args.replot)
        print(f"redrew {', '.join(str(f) for f in figures)}")
        return 0
    run_bench(settings_from_args(args))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="aquarium-warp bench", description=__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_from_args(args)
    except ValueError as error:
        print(f"aquarium-warp bench: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
