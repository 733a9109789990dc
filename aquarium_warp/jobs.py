"""The job runner: every task of a study (a setting of the swarm-size study, a training run of an open
question) through `run_jobs`, which keeps finished tasks, runs the others here (one after another, on
threads or in worker processes, after a `warm_up`) or as Ray tasks, and returns the results in task
order. Training sweeps (`aquarium_warp.training.sweep`) run on Ray through `run_ray_tasks` too. It sits
below training and the studies, which both use it; a study's own tasks (`studies.jobs.run_tasks`) and
the training task (`studies.common.run_training_task`, a `GroupedJob`) are theirs.

Finished tasks: each result is written to `<out>/finished/<name>.json` with its `task_key` (the task
and the study's settings) as it comes, so a rerun of the same study (after it was stopped at a time
limit, say, or with more `--seeds`) runs only the tasks it has no result for. A task that raises is not
finished: a training stopped by SIGINT or SIGTERM raises `arguments.Interrupted` with its state kept
(`studies.common.train_and_export`), which ends the run with the signal's exit code; the rerun continues it.

Several devices of one machine (`devices`): worker processes, each bound to one device, run `jobs`
tasks at a time on each; a task takes the next free device, which its function is given and its key
does not hold, so a rerun on another number of GPUs keeps the finished tasks.

Ray: each task is a Ray task holding the GPUs (or the GPU fraction) and CPUs it needs (`RayOptions`);
Ray schedules the tasks over the cluster's machines and reruns a task whose worker died
(`max_retries`) while the finished ones stay done. Ray is optional (`pip install
'aquarium-warp[distributed]'`) and imported only when a study or sweep runs on it. The tasks import
aquarium_warp on the workers: every machine of the cluster needs the same install.

```python
from aquarium_warp.jobs import RayOptions
from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_swarm_size_study
run_swarm_size_study(SwarmSizeStudy(prey=[4, 8, 16], out="out"), ray=RayOptions(address="auto", gpus_per_task=0.5))
```
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import dataclasses
import json
import math
import os
import platform
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing import get_context
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .arguments import check_int, non_negative_float, non_negative_int, positive_float
from .atomic import atomic_open
from .config import AquariumConfig

INSTALL = "pip install 'aquarium-warp[distributed]'"
# Finished tasks, one JSON file each under the study's `out`.
FINISHED_DIR = "finished"


# ---------------------------------------------------------------------------------------------- Ray
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
        check_int("max_retries", self.max_retries, 0)

    def record(self, device: str) -> dict:
        """The JSON's record of a run on Ray: the cluster's address, what each task held and the device."""
        return {
            "address": self.address,
            "gpus_per_task": self.gpus_per_task,
            "cpus_per_task": self.cpus_per_task,
            "max_retries": self.max_retries,
            "device": device,
        }


def add_ray_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """`--ray [ADDRESS]` and what each Ray task holds (`ray_options` reads them)."""
    g = parser.add_argument_group("Ray", f"run each {what} as a Ray task, on one machine or a cluster ({INSTALL})")
    g.add_argument(
        "--ray",
        nargs="?",
        const="",
        default=None,
        metavar="ADDRESS",
        help=f"run each {what} as a Ray task: on the cluster at ADDRESS ('auto': the one `ray start` "
        "started on this machine; 'ray://HOST:10001': Ray Client), without ADDRESS on "
        "$RAY_ADDRESS's cluster or else a new one on this machine",
    )
    g.add_argument(
        "--gpus-per-task",
        type=non_negative_float,
        default=None,
        metavar="G",
        help="GPUs each task holds: a fraction in [0, 1] (0.25: four tasks share a GPU) or a whole "
        "number (default 1 where the cluster has GPUs and --device is not 'cpu', else 0)",
    )
    g.add_argument(
        "--cpus-per-task", type=positive_float, default=None, metavar="C", help="CPU cores each task holds (default 1)"
    )
    g.add_argument(
        "--max-retries",
        type=non_negative_int,
        default=None,
        metavar="R",
        help="reruns of a task whose worker died (default 3)",
    )


def ray_options(args: argparse.Namespace) -> RayOptions | None:
    """The `RayOptions` of `add_ray_arguments`' options, or None without --ray."""
    given = {
        name: value
        for name, value in (
            ("gpus_per_task", args.gpus_per_task),
            ("cpus_per_task", args.cpus_per_task),
            ("max_retries", args.max_retries),
        )
        if value is not None
    }
    if args.ray is None:
        if given:
            names = ", ".join("--" + name.replace("_", "-") for name in given)
            raise ValueError(f"{names} set the Ray tasks: give --ray too")
        return None
    options = RayOptions(address=args.ray or None, **given)
    options.validate()
    return options


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
        raise ValueError(
            f"device={device!r}: on Ray a task runs on the GPU that Ray assigns it ('cuda') or on "
            "the CPU ('cpu'); --gpus-per-task sets how much of a GPU it holds"
        )
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


def run_ray_tasks(
    function: Callable, calls: Sequence[tuple], options: RayOptions, on_result: Callable[[int, Any], None] | None = None
) -> list:
    """`function(*call)` for every call as Ray tasks, results in the order of `calls`. `on_result(i,
    result)` runs on this process as each task finishes. A task whose worker dies reruns up to
    `options.max_retries` times; an error in the task cancels the others and is raised here."""
    ray = connect(options)
    # Options given to ray.remote itself (not .options()): Ray then starts a fresh worker for every GPU
    # task, so each one sees the GPU it was assigned.
    remote = ray.remote(
        num_gpus=options.gpus_per_task or 0, num_cpus=options.cpus_per_task, max_retries=options.max_retries
    )(function)
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


def _on_worker(function: Callable[[dict], Any], task: dict) -> tuple[Any, str]:
    """A Ray task: `function(task)` and the name of the machine that ran it."""
    return function(task), platform.node()


# ---------------------------------------------------------------------------------------------- here
def resolve_jobs(jobs: int | None, device: str, threads: bool = False) -> int:
    """Tasks at once on this machine: `jobs`, else in worker processes 4 on a GPU and 1 on the CPU, on
    threads the CPU's cores. On one GPU the processes' kernels take turns (time slicing), so a run's
    GPU-bound PPO iterations gain little from company (the paper preset's runs took as long four at a
    time as one after another); what overlaps is the rest, which waits on the host: process start, the
    trainer's construction and CUDA graph capture, the evaluation loops (a host sync per step). Threads
    on a GPU run one at a time: a batch already fills the device, and a CUDA graph being captured in
    one thread must not see another thread's launches."""
    on_gpu = str(device).startswith("cuda")
    if threads and on_gpu:
        return 1
    if jobs is not None:
        check_int("jobs", jobs)
        return jobs
    if threads:
        return os.cpu_count() or 1
    return 4 if on_gpu else 1


def warm_up(
    device: str,
    config: AquariumConfig | None = None,
    prey: str = "turnaway",
    predator: str = "naivchase",
    confusion: bool = True,
    linking_distance: float | None = None,
) -> None:
    """Build (or load from Warp's cache) the kernels of a step of `config` (a two-prey copy; default the
    model's world) with the `prey` and `predator` drivers and the swarm metrics, once, before tasks run
    at once: worker processes must not all compile them, nor threads load them together."""
    from .drivers import make_drivers
    from .env import BatchedAquarium
    from .metrics import SwarmMetrics

    cfg = (config or AquariumConfig()).replace(prey_count=2, max_steps=2)
    if cfg.prey_reproduction:
        cfg = cfg.replace(max_prey=4)
    env = BatchedAquarium(cfg, num_worlds=1, device=device, seed=0)
    drivers = make_drivers({"prey": prey, "predator": predator}, env, confusion=confusion)
    env.reset()
    SwarmMetrics(env, linking_distance=linking_distance).compute()
    env.step({team: drive() for team, drive in drivers.items()}, validate=False)
    env.close()


def task_devices(gpus: int | None) -> list[str]:
    """The `devices` of `run_jobs` for a `--gpus` option: CUDA devices 0 to `gpus` - 1 (None: every
    one), or the CPU (`gpus` 0, or a machine without CUDA)."""
    import torch

    available = torch.cuda.device_count()
    if gpus is not None and gpus > available:
        raise ValueError(f"--gpus={gpus} must be at most the {available} CUDA devices of this machine")
    return [f"cuda:{k}" for k in range(available if gpus is None else gpus)] or ["cpu"]


# ---------------------------------------------------------------------------------------------- the runner
# Entries of a task that name its folders under the study's `out` (where it writes or reads its files):
# not part of its key, so a study keeps its tasks wherever `out` is given from.
TASK_FOLDERS = ("policy_dir", "run_dir", "run_dirs")


# Study settings that never change a task's computation: the seed count (adding seeds keeps the
# finished ones), where it writes, its workers, figures and device option.
STUDY_RUN_OPTIONS = ("seeds", "out", "jobs", "figures", "device")


def task_key(task: dict) -> dict:
    """What a kept result must have been computed with, as read back from JSON: the task (not its
    folders, `TASK_FOLDERS`; it names its seed or seed count, and its device unless `run_jobs` gives
    it one of `devices`) and, where it has a "study", the study's settings, less `STUDY_RUN_OPTIONS`
    and less the study's `TASK_AXES`: the settings that only list which tasks exist (team sizes,
    conditions), each task carrying its own value, so that a run over fewer or more of them keeps the
    tasks they share."""
    if "study" in task:
        study = task["study"]
        left_out = STUDY_RUN_OPTIONS + tuple(getattr(study, "TASK_AXES", ()))
        settings = {k: v for k, v in dataclasses.asdict(study).items() if k not in left_out}
    else:
        settings = {}
    own = {k: v for k, v in task.items() if k != "study" and k not in TASK_FOLDERS}
    return json.loads(json.dumps({"task": own, "study": settings}))


def finished_path(out: str, task: dict) -> str:
    """The file of `task`'s result under `out`."""
    return os.path.join(out, FINISHED_DIR, f"{task['name']}.json")


def read_finished(out: str, task: dict) -> tuple[bool, Any]:
    """`(True, result)` where `task`'s file under `out` holds a result computed with its `task_key`,
    else `(False, None)`."""
    path = finished_path(out, task)
    if os.path.isfile(path):
        with open(path, encoding="utf-8") as f:
            kept = json.load(f)
        if kept.get("key") == task_key(task):
            return True, kept["result"]
    return False, None


def _json_ready(value):
    """`value` with numpy arrays as lists (JSON writes a float's shortest repr, which reads back as the
    same float, NaN included: a kept result equals a fresh one)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    return value


@runtime_checkable
class GroupedJob(Protocol):
    """A job of `run_jobs` with `devices` whose pending tasks may run several in one process (training
    runs as one population): `groups(tasks, device, runs_per_process, report)` splits `tasks` into
    lists of their indices, and `run_group(tasks, device)` runs one list in one process and returns
    its results, in order. A job and its methods must be picklable (a module-level class's instance)."""

    def __call__(self, task: dict, device: str) -> Any: ...

    def groups(
        self, tasks: Sequence[dict], device: str, runs_per_process: int | None, report: Callable[[str], None] | None
    ) -> list[list[int]]: ...

    def run_group(self, tasks: list[dict], device: str) -> list: ...


@dataclass
class JobsRun:
    """What `run_jobs` did: the results in task order, how many were kept from an earlier run, and the
    machines that ran Ray tasks (sorted; empty without Ray)."""

    results: list
    kept: int
    nodes: list[str]


def run_jobs(
    function: Callable[..., Any],
    tasks: Sequence[dict],
    out: str,
    *,
    jobs: int = 1,
    threads: bool = False,
    device: str = "cpu",
    devices: Sequence[str] | None = None,
    ray: RayOptions | None = None,
    label: str = "run",
    prepare: Callable[[], None] | None = None,
    on_result: Callable[[int, Any, bool], None] | None = None,
    report: Callable[[str], None] | None = print,
    runs_per_process: int | None = None,
) -> JobsRun:
    """`function(task)` for every task (each a dict with a unique "name", and its "study" where it has
    settings of one): those whose `<out>/finished/<name>.json` holds the same `task_key` are kept, the
    others run, in the order of `tasks` (longest first runs best): with `ray` (placed: `placement`) as
    Ray tasks, a task whose worker dies rerun by Ray; else with `jobs=1` (or one task to run) in this
    process, or `jobs` at once on threads (`threads`) or in worker processes (spawned, so each has its
    own CUDA context), after `prepare()` (default: `warm_up(device)`). With `devices`, `function(task,
    device)` runs `jobs` at a time on each of `devices`, in worker processes bound to one device each
    (one device and `jobs=1`, or one task to run: here, on the first device; `prepare` defaults to
    `warm_up` of the first device). With processes or Ray, `function` must be a module-level function
    and the tasks picklable. Each result is written to its file as it comes; `on_result(i, result,
    kept)` follows (kept ones first), and `report` gets a line per finished task (None: quiet).

    A `GroupedJob` with `devices` (the studies' training task) runs its pending tasks in the groups it
    forms (training runs that share a process as one population: `runs_per_process` runs each, None: as
    many as the device's memory holds), one group at a time on each device."""
    if devices is not None:
        if not devices:
            raise ValueError("devices=[] must name at least one device")
        if ray is not None or threads:
            raise ValueError("devices spread tasks over worker processes of this machine: not with ray or threads")
        check_int("jobs", jobs)  # tasks at a time on each device
        device = devices[0]
    results: list = [None] * len(tasks)
    done_here = [False] * len(tasks)
    for i, task in enumerate(tasks):
        done_here[i], results[i] = read_finished(out, task)
    kept_count = sum(done_here)
    if kept_count and report is not None:
        report(f"  {label}: {kept_count} of {len(tasks)} tasks kept from {os.path.join(out, FINISHED_DIR)}")
    if on_result is not None:
        for i in range(len(tasks)):
            if done_here[i]:
                on_result(i, results[i], True)
    todo = [i for i in range(len(tasks)) if not done_here[i]]
    os.makedirs(os.path.join(out, FINISHED_DIR), exist_ok=True)
    start = time.perf_counter()

    def done(i: int, result) -> None:
        with atomic_open(finished_path(out, tasks[i])) as f:
            json.dump({"key": task_key(tasks[i]), "result": _json_ready(result)}, f)
        results[i], done_here[i] = result, True
        if on_result is not None:
            on_result(i, result, False)
        if report is not None:
            finished = sum(done_here)
            elapsed = time.perf_counter() - start
            left = elapsed / (finished - kept_count) * (len(tasks) - finished)  # longest first: an overestimate
            report(f"  {label} {finished}/{len(tasks)} ({tasks[i]['name']}) after {elapsed:.0f} s, ~{left:.0f} s left")

    nodes: set[str] = set()
    if isinstance(function, GroupedJob) and devices is not None and todo:
        pending = [tasks[i] for i in todo]
        groups = [[todo[k] for k in group] for group in function.groups(pending, devices[0], runs_per_process, report)]
        jobs_each = 1 if any(len(group) > 1 for group in groups) else jobs  # a population fills its GPU
        if (len(devices or [device]) == 1 and jobs_each <= 1) or len(groups) <= 1:
            for group in groups:
                for i, result in zip(group, function.run_group([tasks[i] for i in group], device)):
                    done(i, result)
        else:
            (prepare or (lambda: warm_up(device)))()

            def done_group(g: int, group_results: list) -> None:
                for i, result in zip(groups[g], group_results):
                    done(i, result)

            _run_on_devices(function.run_group, [(g, [tasks[i] for i in group]) for g, group in enumerate(groups)],
                            devices or [device], jobs_each, done_group)  # fmt: skip
        return JobsRun(results, kept_count, [])
    if ray is not None:

        def finished_on_ray(k: int, result: tuple[Any, str]) -> None:
            nodes.add(result[1])
            done(todo[k], result[0])

        run_ray_tasks(_on_worker, [(function, tasks[i]) for i in todo], ray, on_result=finished_on_ray)
    elif (jobs <= 1 and (devices is None or len(devices) == 1)) or len(todo) <= 1:
        for i in todo:
            done(i, function(tasks[i]) if devices is None else function(tasks[i], device))
    else:
        (prepare or (lambda: warm_up(device)))()
        if devices is not None:
            _run_on_devices(function, [(i, tasks[i]) for i in todo], devices, jobs, done)
        else:
            pool: futures.Executor = (
                futures.ThreadPoolExecutor(max_workers=min(jobs, len(todo)))
                if threads
                else futures.ProcessPoolExecutor(max_workers=min(jobs, len(todo)), mp_context=get_context("spawn"))
            )
            with pool:
                submitted = {pool.submit(function, tasks[i]): i for i in todo}
                for future in futures.as_completed(submitted):
                    done(submitted[future], future.result())
    return JobsRun(results, kept_count, sorted(nodes))


def _bind_device(device: str) -> None:
    """A worker process's start: make `device` its current CUDA device, so that code using the current
    device (a CUDA graph's capture, a synchronize) works on it and opens no context on GPU 0."""
    if device.startswith("cuda"):
        import torch

        torch.cuda.set_device(torch.device(device))


def _run_on_devices(
    function: Callable[[Any, str], Any],
    tasks: Sequence[tuple[int, Any]],
    devices: Sequence[str],
    per_device: int,
    done: Callable[[int, Any], None],
) -> None:
    """`function(task, device)` for the `(index, task)` pairs, in task order as slots free up: a pool of
    `per_device` spawned worker processes per device, each task on the device with the most free
    slots (the first of them on a tie); `done(index, result)` as each finishes."""
    context = get_context("spawn")
    pools = [
        futures.ProcessPoolExecutor(max_workers=per_device, mp_context=context, initializer=_bind_device, initargs=(d,))
        for d in devices
    ]
    free = [per_device] * len(devices)
    waiting = list(reversed(tasks))
    running: dict[futures.Future, tuple[int, int]] = {}
    try:
        while waiting or running:
            while waiting and max(free) > 0:
                k = free.index(max(free))
                i, task = waiting.pop()
                running[pools[k].submit(function, task, devices[k])] = (i, k)
                free[k] -= 1
            finished, _ = futures.wait(running, return_when=futures.FIRST_COMPLETED)
            for future in finished:
                i, k = running.pop(future)
                free[k] += 1
                done(i, future.result())
    finally:
        for pool in pools:  # after an error: the waiting tasks never start, the running ones end
            pool.shutdown(cancel_futures=True)
