"""Timers: repeated timed runs of a step, and single calls timed on the device (CUDA events) or by
a synchronised wall clock."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import torch
import warp as wp


def timed_runs(
    step: Callable[[int], object],
    sync: Callable[[], object],
    seconds: float,
    repeats: int,
    step_s: float,
    min_steps: int = 3,
) -> list[float]:
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


def repeats_within(asked: int, step_time: float) -> int:
    """Steps to time one by one (stages, heuristics): `asked`, fewer when a step is slow (about 2 s
    of steps), at least 3."""
    return max(3, min(asked, int(math.ceil(2.0 / max(step_time, 1e-9)))))


def wall_clock(fn: Callable[[], object]) -> float:
    """Seconds `fn()` took on the host's clock (on the CPU, the computation itself)."""
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


class DeviceTimer:
    """Times a callable on the env's device: CUDA events on Warp's stream (device time), a
    synchronised wall clock on the CPU."""

    def __init__(self, device: str):
        self.device = device
        self.cuda = wp.get_device(device).is_cuda

    def __call__(self, fn: Callable[[], object]) -> float:
        if not self.cuda:
            return wall_clock(fn)
        stream = wp.get_stream(self.device)
        start = wp.Event(self.device, enable_timing=True)
        end = wp.Event(self.device, enable_timing=True)
        stream.record_event(start)
        fn()
        stream.record_event(end)
        return wp.get_event_elapsed_time(start, end) / 1e3


def torch_timer(device: str) -> Callable[[Callable[[], object]], float]:
    """A timer of torch work on `device`: CUDA events on torch's stream, the wall clock on the CPU."""
    if torch.device(device).type != "cuda":
        return wall_clock

    def run(fn: Callable[[], object]) -> float:
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        fn()
        end.record()
        end.synchronize()
        return start.elapsed_time(end) / 1e3

    return run
