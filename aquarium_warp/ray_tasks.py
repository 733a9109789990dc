"""Sweeps as Ray tasks: every setting of a study (`aquarium-warp study swarm-size --ray`) or every run of
a training sweep (`aquarium-warp sweep train --ray`) is one Ray task holding the GPUs (or the GPU
fraction) and CPUs it needs; Ray schedules the tasks over the cluster's machines and reruns a task
whose worker died (`max_retries`) while the finished ones stay done.

Ray is optional (`pip install 'aquarium-warp[distributed]'`) and imported only when a sweep runs on it.
The tasks import aquarium_warp on the workers: every machine of the cluster needs the same install.

```python
from aquarium_warp.ray_tasks import RayOptions
from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_swarm_size_study
run_swarm_size_study(SwarmSizeStudy(prey=[4, 8, 16], out="out"), ray=RayOptions(address="auto", gpus_per_task=0.5))
```
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

INSTALL = "pip install 'aquarium-warp[distributed]'"


@dataclass(frozen=True)
class RayOptions:
    """Where the tasks run and what each one holds."""

    address: str | None = None  # None: $RAY_ADDRESS's cluster, else a new local one; "auto": this machine's
    gpus_per_task: float | None = None  # None: 1 where the cluster has GPUs and the device is not the CPU
    cpus_per_task: float = 1.0
    max_retries: int = 3  # reruns of a task whose worker died (a Python error in the task is not retried)

    def validate(self) -> None:
        gpus = self.gpus_per_task
        # Ray packs fractions of one GPU, or takes whole GPUs: 1.5 GPUs is neither.
        if gpus is not None and not (math.isfinite(gpus) and (0 <= gpus <= 1 or gpus == int(gpus))):
            raise ValueError(f"gpus_per_task={gpus!r} must be a fraction in [0, 1] or a whole number of GPUs")
        if not (math.isfinite(self.cpus_per_task) and self.cpus_per_task > 0):
            raise ValueError(f"cpus_per_task={self.cpus_per_task!r} must be a finite number > 0")
        if isinstance(self.max_retries, bool) or not isinstance(self.max_retries, int) or self.max_retries < 0:
            raise ValueError(f"max_retries={self.max_retries!r} must be an integer >= 0")


def import_ray() -> Any:
    """The `ray` module, or a ValueError naming the extra to install."""
    try:
        import ray
    except ImportError as error:
        raise ValueError(f"running on Ray (--ray) needs Ray: {INSTALL} ({error})") from error
    return ray


def connect(options: RayOptions) -> Any:
    """The `ray` module, connected to `options.address` unless this process already is (to any cluster)."""
    ray = import_ray()
    if not ray.is_initialized():
        with warnings.catch_warnings():
            # The tip is about tasks without GPUs seeing the GPUs in a later Ray: ours name their device.
            warnings.filterwarnings("ignore", message="Tip: In future versions of Ray", category=FutureWarning)
            ray.init(address=options.address)
    return ray


def placement(options: RayOptions, device: str | None) -> tuple[RayOptions, str]:
    """`options` with the GPUs per task settled, and the device the tasks run on: "cuda:0" (the GPU
    that Ray assigns, the first one the task sees) when they hold GPUs, else "cpu". `device` is the
    one asked for: None (a GPU where the cluster has one), "cuda" or "cpu". Connects to the cluster."""
    options.validate()
    if device not in (None, "cpu", "cuda", "cuda:0"):
        raise ValueError(f"device={device!r}: on Ray a task runs on the GPU that Ray assigns it ('cuda') or on "
                         "the CPU ('cpu'); --gpus-per-task sets how much of a GPU it holds")
    cluster_gpus = float(connect(options).cluster_resources().get("GPU", 0.0))
    gpus = options.gpus_per_task
    if gpus is None:
        gpus = 1.0 if cluster_gpus > 0 and device != "cpu" else 0.0
    if gpus > cluster_gpus:
        raise ValueError(f"gpus_per_task={gpus:g}: the Ray cluster has {cluster_gpus:g} GPUs")
    if device == "cpu" and gpus > 0:
        raise ValueError(f"device='cpu' with gpus_per_task={gpus:g}: the tasks would hold GPUs they do not use")
    if device is not None and device != "cpu" and gpus == 0:
        raise ValueError(f"device={device!r} needs gpus_per_task > 0 (the Ray cluster has {cluster_gpus:g} GPUs)")
    return dataclasses.replace(options, gpus_per_task=gpus), ("cuda:0" if gpus > 0 else "cpu")


def run_tasks(function: Callable, calls: Sequence[tuple], options: RayOptions,
              on_result: Callable[[int, Any], None] | None = None) -> list:
    """`function(*call)` for every call as Ray tasks, results in the order of `calls`. `on_result(i,
    result)` runs on this process as each task finishes. A task whose worker dies reruns up to
    `options.max_retries` times; an error in the task cancels the others and is raised here."""
    ray = connect(options)
    # Options given to ray.remote itself (not .options()): Ray then starts a fresh worker for every GPU
    # task, so each one sees the GPU it was assigned.
    remote = ray.remote(num_gpus=options.gpus_per_task or 0, num_cpus=options.cpus_per_task,
                        max_retries=options.max_retries)(function)
    refs = [remote.remote(*call) for call in calls]
    index = {ref: i for i, ref in enumerate(refs)}
    results: list = [None] * len(refs)
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            i = index[done[0]]
            results[i] = ray.get(done[0])
            if on_result is not None:
                on_result(i, results[i])
    finally:
        for ref in pending:  # after an error or an interrupt: nothing left running for nobody
            ray.cancel(ref)
    return results
