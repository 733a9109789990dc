"""One point of a sweep: build the worlds, time `env.step()` (graph and eager), its stages and the
heuristics, and account for memory and bytes moved. A point that cannot run is skipped or failed,
never the suite."""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import torch
import warp as wp

from ..config import AquariumConfig
from ..heuristics import heuristic_actions
from ..rollout import random_actions
from .byte_model import step_byte_model
from .machine import available_bytes
from .settings import BenchSettings
from .stages import copy_actions_in, stage_times
from .timing import DeviceTimer, repeats_within, timed_runs

if TYPE_CHECKING:
    from ..env import BatchedAquarium

ActionSet = dict[str, torch.Tensor]


def estimate_bytes(cfg: AquariumConfig, worlds: int) -> int:
    """Memory a point needs, about: the env's own estimate plus the sort's scratch and the action pool."""
    from ..env import grid_dims
    from ..state import estimate_bytes as env_bytes

    dims = grid_dims(cfg)
    n = worlds * cfg.capacity
    env = env_bytes(cfg, worlds, dims[0] * dims[1])
    return int(1.25 * env + 8 * 4 * n + 16 * n)  # margin, 8 action sets (int32), sort scratch


def array_bytes(env: BatchedAquarium) -> int:
    """Bytes of the env's Warp arrays: the simulation state and every shard's cell lists."""

    def size(a: wp.array) -> int:
        return int(getattr(a, "capacity", 0) or a.size * wp.types.type_size_in_bytes(a.dtype))

    total = sum(size(a) for a in env.state.arrays().values())
    for shard in env.shards:
        g = shard.grid
        owned: tuple[str, ...] = ("cell_start", "cell_end", "cell_count", "key", "agent")
        if g.cell_end.ptr == g.cell_start.ptr + 4:  # count builds: both are views of one bounds array
            owned = tuple(f for f in owned if f != "cell_end")
        if not g.whole_world:  # whole-world lists view the state's own positions
            owned += ("position",)
        total += sum(size(getattr(g, f)) for f in owned)
    return total


def measure_point(series: str, cfg: AquariumConfig, worlds: int, device: str, settings: BenchSettings) -> dict:
    """Measure one configuration; returns the point's record (status "ok", "skipped" or "failed")."""
    from ..env import BatchedAquarium, grid_dims  # at call time: tests replace BatchedAquarium

    agents = worlds * cfg.capacity
    dims = grid_dims(cfg)
    cuda = wp.get_device(device).is_cuda
    row: dict[str, Any] = {
        "series": series,
        "worlds": worlds,
        "agents_per_world": cfg.capacity,
        "agents": agents,
        "prey_per_world": cfg.prey_capacity,
        "predators_per_world": cfg.predator_count,
        "world_size_px": [cfg.width, cfg.height],
        "cells_per_world": dims[0] * dims[1],
        "status": "ok",
        "note": None,
    }
    if agents > settings.max_agents_in_flight:
        return {
            **row,
            "status": "skipped",
            "note": f"{agents} agents > --max-agents-in-flight {settings.max_agents_in_flight}",
        }
    need = estimate_bytes(cfg, worlds)
    gc.collect()
    if cuda:
        wp.synchronize_device(device)
        torch.cuda.empty_cache()
    free = available_bytes(device)
    row["memory_estimate_bytes"] = need
    if need > settings.memory_fraction * free:
        return {
            **row,
            "status": "skipped",
            "note": f"needs about {need / 2**30:.2f} GiB, {free / 2**30:.2f} GiB free on {device}",
        }
    env = None
    try:
        tdev = torch.device(device)
        gen = torch.Generator(device=tdev).manual_seed(0)
        pool = [random_actions(cfg, worlds, gen, tdev) for _ in range(8)]
        if cuda:
            torch.cuda.synchronize(tdev)
        free_before = available_bytes(device)
        build_start = time.perf_counter()
        env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=0, cpu_threads=settings.cpu_threads)
        _time_env(env, pool, row, device, settings, free_before, build_start)
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
        pool = []  # the action pool is freed before the device's cache is emptied
        gc.collect()
        if cuda:
            try:
                wp.synchronize_device(device)
                torch.cuda.empty_cache()
            except Exception:  # noqa: BLE001
                pass
    return row


def _time_env(
    env: BatchedAquarium,
    pool: list[ActionSet],
    row: dict[str, Any],
    device: str,
    settings: BenchSettings,
    free_before: int,
    build_start: float,
) -> None:
    """Warm `env` up and add the point's timings and memory to `row`."""
    row["step_kernel"] = env.step_kernel  # "fused" or "stages": which stages the breakdown can show
    tdev = torch.device(device)
    cuda = wp.get_device(device).is_cuda
    agents = row["agents"]
    sync: Callable[[], None] = (lambda: torch.cuda.synchronize(tdev)) if cuda else (lambda: None)
    step_s = 0.0
    for i in range(settings.warmup_steps):  # the first step on CUDA captures the graph
        t = time.perf_counter()
        env.step(pool[i % 8], validate=False)
        sync()
        step_s = time.perf_counter() - t
    row["build_s"] = time.perf_counter() - build_start
    row["memory"] = {
        "arrays_bytes": array_bytes(env),
        "device_bytes": (free_before - available_bytes(device)) if cuda else None,
        "note": "arrays: the env's Warp arrays (state, outputs, cell lists)"
        + ("; device: drop of the device's free memory across construction, warm-up and graph capture" if cuda else ""),
    }
    row["memory"]["bytes_per_agent"] = row["memory"]["arrays_bytes"] / agents

    runs = timed_runs(lambda k: env.step(pool[k % 8], validate=False), sync, settings.seconds, settings.repeats, step_s)
    step_time = statistics.median(runs)
    row.update(
        {
            "step_ms": step_time * 1e3,
            "agent_steps_per_s": agents / step_time,
            "ns_per_agent_step": step_time / agents * 1e9,
            "runs_step_ms": [t * 1e3 for t in runs],
            "timing": "CUDA graph replay (env.step), synchronised wall clock"
            if cuda
            else "env.step (recorded launches, shards in threads), wall clock",
        }
    )

    # Eager vs graph (CUDA): the same step without the graph.
    if cuda and settings.eager:
        actions = env.actions

        def eager(k: int) -> None:
            copy_actions_in(actions, pool[k % 8])
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
        row["graph_note"] = (
            "n/a: no CUDA graph on the CPU (env.step runs the recorded launches)" if not cuda else "eager not measured"
        )

    if settings.stages:
        row.update(stage_times(env, pool, device, settings, step_time))
    if settings.heuristics:
        heuristic_actions(env)  # records the policies' launches
        sync()
        timer = DeviceTimer(device)
        reps = repeats_within(settings.stage_repeats, step_time)
        samples = [timer(lambda: heuristic_actions(env)) for _ in range(reps)]
        row["heuristics_ms"] = statistics.median(samples) * 1e3
        row["heuristics_ns_per_agent"] = row["heuristics_ms"] * 1e6 / agents
