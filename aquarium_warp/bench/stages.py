"""The stages of a step: which kernel belongs to which stage, and the time of each stage measured
command by command over eagerly launched steps."""

from __future__ import annotations

import functools
import statistics
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch
import warp as wp

from ..agent_types import TYPES
from .settings import BenchSettings
from .timing import DeviceTimer, repeats_within, torch_timer

if TYPE_CHECKING:
    from ..env import BatchedAquarium
    from ..shard import WorldShard

# A fused step (`step_kernel`, kernels/world_step.py) is one command: its time is the "fused" stage and
# the kernel stages read 0; a staged step leaves "fused" at 0.
STAGES = ("actions", "motion", "grid", "captures", "population", "observations", "fused")
STAGE_LABELS = {
    "actions": "action copy-in",
    "motion": "motion (steering, acceleration, contact, integration)",
    "grid": "grid build (cell lists, once per step)",
    "captures": "captures (detect, resolve, share, starve)",
    "population": "population, rewards, episode end",
    "observations": "observations",
    "heuristics": "heuristic policies (not in the step)",
    "fused": "the whole step in one launch (worlds of one cell: kernels/world_step.py)",
}
# Kernel name -> stage (commands of `WorldShard.programs["step"]`).
KERNEL_STAGES = {
    "integrate_motion": "motion",
    "compute_cell_keys": "grid",
    "array_scan": "grid",
    "drop_into_cells": "grid",
    "order_cells": "grid",
    "sort_into_cells_per_world": "grid",
    "rank_into_cells_per_world": "grid",
    "detect_contacts": "captures",
    "resolve_captures": "captures",
    "share_capture_rewards": "captures",
    "respawn_captured_prey": "captures",
    "reproduce_prey": "population",
    "finish_world_step": "population",
    "close_ended_episodes": "population",
}


def command_name(command: Callable[[], object]) -> str:
    """Kernel name of a recorded launch, or the function name of another command."""
    launch = getattr(command, "__self__", None)
    if launch is not None and hasattr(launch, "kernel"):
        return launch.kernel.key
    return getattr(getattr(command, "func", command), "__name__", "command")


def command_stage(command: Callable[[], object]) -> str:
    """The stage of one command of a shard's step program (`shard.programs["step"]`)."""
    name = command_name(command)
    if name in KERNEL_STAGES:
        return KERNEL_STAGES[name]
    if "observ" in name:
        return "observations"
    if "world_step" in name:
        return "fused"
    return "other"


def copy_actions_in(actions: dict[str, torch.Tensor], chosen: dict[str, torch.Tensor]) -> None:
    """The step's first stage: both teams' actions copied into the env's action arrays."""
    for t in TYPES:
        actions[t].copy_(chosen[t])


def stage_times(
    env: BatchedAquarium, pool: list[dict[str, torch.Tensor]], device: str, settings: BenchSettings, step_time: float
) -> dict:
    """Median time of every command of the step program over a few eagerly launched steps, summed by
    stage. CUDA: events recorded between consecutive commands of a step, read after the step, so the
    intervals partition the step's device timeline (launch gaps included where the GPU outruns the
    host). CPU: a wall clock around each command, the commands of all shards run in the env's
    threads one command at a time."""
    timer = DeviceTimer(device)
    copy_timer = torch_timer(device)
    shard = env.shards[0]
    program = shard.programs["step"]
    names = [command_name(c) for c in program]
    stages = [command_stage(c) for c in program]
    reps = repeats_within(settings.stage_repeats, step_time)
    samples: list[list[float]] = [[] for _ in program]
    copies = []
    actions = env.actions
    events = [wp.Event(device, enable_timing=True) for _ in range(len(program) + 1)] if timer.cuda else []

    def run_recorded(s: WorldShard) -> None:  # CUDA: one shard, on Warp's stream (after torch's, by run_on_shards)
        stream = wp.get_stream(device)
        stream.record_event(events[0])
        for i, command in enumerate(s.programs["step"]):
            command()
            stream.record_event(events[i + 1])

    def run_command(i: int) -> None:  # CPU: command i of every shard's program, in the env's threads
        env.run_on_shards(lambda s: s.programs["step"][i]())

    for k in range(reps):
        copies.append(copy_timer(functools.partial(copy_actions_in, actions, pool[k % 8])))
        if timer.cuda:
            env.run_on_shards(run_recorded)
            wp.synchronize_event(events[-1])
            for i in range(len(program)):
                samples[i].append(wp.get_event_elapsed_time(events[i], events[i + 1], synchronize=False) / 1e3)
        else:
            for i in range(len(program)):
                samples[i].append(timer(functools.partial(run_command, i)))
    per_command = [statistics.median(s) for s in samples]
    totals = dict.fromkeys(STAGES, 0.0)
    totals["actions"] = statistics.median(copies)
    for stage, t in zip(stages, per_command):
        totals[stage] = totals.get(stage, 0.0) + t
    stage_ms = {s: t * 1e3 for s, t in totals.items()}
    return {
        "stages_ms": stage_ms,
        "stage_sum_ms": sum(stage_ms.values()),
        "commands_ms": [{"name": n, "stage": s, "ms": t * 1e3} for n, s, t in zip(names, stages, per_command)],
        "stage_repeats": reps,
        "stage_timing": (
            "CUDA events between consecutive commands of eagerly launched steps (device timeline), median over steps"
            if timer.cuda
            else "wall clock around each command (all shards), median over steps"
        ),
    }
