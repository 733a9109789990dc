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

Peers measured in the same run when asked, by the source tree's `python benchmarks/bench_scaling.py`
(the same options; their measuring code lives in `benchmarks/`, not in the package): with
`--original`, the original marl-aquarium 0.1.10 (CPU, default config, through
`benchmarks/original_aquarium.py`, which installs it from the package index into a throwaway virtual
environment) and, with `--vmas`, VMAS's predator-prey scenario `simple_tag` at the agent counts of
the agents and worlds series on the same device (`benchmarks/vmas_peer.py`). `aquarium-warp bench`
can read a stored measurement of the original (`--original-json`). Ratios are reported.

Output (`--out-dir`, default: the current directory): a printed table, `<out-dir>/scaling_<device>.json`
and log-log figures `<out-dir>/scaling_<device>_throughput.png` (agent-steps/s vs agents in flight;
the load series vs agents per world), `..._per_agent.png` (ns per agent-step, the same axes) and
`..._stages.png` (share of each stage).

    aquarium-warp bench --device cuda:0 --agents 1000,4000,...,1000000 --worlds 1 --load-agents 4000000
    python benchmarks/bench_scaling.py --device cuda:0 --agents 16,64,...,1000000 --worlds 1,16,...,65536 \
        --vmas --original

One module a job: `settings` (what a run measures), `sweeps` (configurations and their points),
`point` (one point measured), `timing` (timers), `stages` (the step's stages, timed command by
command), `byte_model`, `bandwidth` (the copy bandwidth), `machine` (commit, device, versions),
`peers` (the peers' results and ratios), `summary`, `table`, `plots`, `suite` (`run_bench`) and
`cli` (the options and `main`); `floors` (the hardware floors of PPO training).

This package is the one home of timing code: the scripts in `benchmarks/` (each a measurement whose
results and provenance are committed under `benchmarks/results/`) import their timers and floors from
here (and `aquarium_warp.device.synchronize`).
"""

import importlib
from typing import TYPE_CHECKING

# Light modules, imported at once: `summary` is also its module's name, which a lazy import of the
# function would leave bound to the module.
from .settings import BenchSettings, parse_counts
from .summary import RATIO_FROM_AGENTS_PER_WORLD, SERIES, per_agent_time_ratio, summary

if TYPE_CHECKING:
    from .bandwidth import copy_bandwidth
    from .byte_model import GRID_PATHS, step_byte_model
    from .cli import add_arguments, main, run_from_args, settings_from_args
    from .machine import available_bytes
    from .peers import OriginalHarness, Peers, VmasHarness, add_ratios, measure_original_peer, measure_vmas_peer
    from .plots import plot_results
    from .point import array_bytes, estimate_bytes, measure_point
    from .stages import KERNEL_STAGES, STAGE_LABELS, STAGES, command_name, command_stage, copy_actions_in, stage_times
    from .suite import replot, run_bench
    from .sweeps import density_config, load_worlds, split_agents, sweep_points
    from .table import format_row, format_table
    from .timing import DeviceTimer, repeats_within, timed_runs, torch_timer, wall_clock

__all__ = [
    "GRID_PATHS",
    "KERNEL_STAGES",
    "RATIO_FROM_AGENTS_PER_WORLD",
    "SERIES",
    "STAGES",
    "STAGE_LABELS",
    "BenchSettings",
    "DeviceTimer",
    "OriginalHarness",
    "Peers",
    "VmasHarness",
    "add_arguments",
    "add_ratios",
    "array_bytes",
    "available_bytes",
    "command_name",
    "command_stage",
    "copy_actions_in",
    "copy_bandwidth",
    "density_config",
    "estimate_bytes",
    "format_row",
    "format_table",
    "load_worlds",
    "main",
    "measure_original_peer",
    "measure_point",
    "measure_vmas_peer",
    "parse_counts",
    "per_agent_time_ratio",
    "plot_results",
    "repeats_within",
    "replot",
    "run_bench",
    "run_from_args",
    "settings_from_args",
    "split_agents",
    "stage_times",
    "step_byte_model",
    "summary",
    "sweep_points",
    "timed_runs",
    "torch_timer",
    "wall_clock",
]

# Imported on first use, so that `aquarium-warp bench --help` loads neither torch nor Warp (the suite's
# modules do).
_LAZY = {
    "copy_bandwidth": ".bandwidth",
    "GRID_PATHS": ".byte_model",
    "step_byte_model": ".byte_model",
    "add_arguments": ".cli",
    "main": ".cli",
    "run_from_args": ".cli",
    "settings_from_args": ".cli",
    "available_bytes": ".machine",
    "OriginalHarness": ".peers",
    "Peers": ".peers",
    "VmasHarness": ".peers",
    "add_ratios": ".peers",
    "measure_original_peer": ".peers",
    "measure_vmas_peer": ".peers",
    "plot_results": ".plots",
    "array_bytes": ".point",
    "estimate_bytes": ".point",
    "measure_point": ".point",
    "KERNEL_STAGES": ".stages",
    "STAGE_LABELS": ".stages",
    "STAGES": ".stages",
    "command_name": ".stages",
    "command_stage": ".stages",
    "copy_actions_in": ".stages",
    "stage_times": ".stages",
    "replot": ".suite",
    "run_bench": ".suite",
    "density_config": ".sweeps",
    "load_worlds": ".sweeps",
    "split_agents": ".sweeps",
    "sweep_points": ".sweeps",
    "format_row": ".table",
    "format_table": ".table",
    "DeviceTimer": ".timing",
    "repeats_within": ".timing",
    "timed_runs": ".timing",
    "torch_timer": ".timing",
    "wall_clock": ".timing",
}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value
