"""A study's tasks: `run_tasks` checks a study's settings, resolves its device and jobs, trains the
trainings its tasks share as populations and runs the tasks through the job runner
(`aquarium_warp.jobs.run_jobs`), here or on Ray."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

from ..jobs import RayOptions, placement, read_finished, resolve_jobs, run_jobs


@dataclass
class TaskRun:
    """What `run_tasks` did: the tasks' results (in task order), how many were kept from an earlier
    run, the device, the jobs at once (None on Ray), the wall time in seconds, and on Ray the run's
    record (address, what each task held, the machines that ran tasks)."""

    results: list[dict]
    kept: int
    device: str
    jobs: int | None
    wall_s: float
    ray: dict | None = None

    def record(self, study_name: str, study, rows: list[dict], command: str | None) -> dict:
        """`run_record` of this run, with the training and job times summed over `rows`."""
        from .common import run_record

        record = run_record(
            study_name,
            study,
            self.device,
            self.wall_s,
            sum(r["train_s"] for r in rows),
            sum(r["job_s"] for r in rows),
            self.jobs,
            command,
            self.kept,
        )
        if self.ray is not None:
            record["ray"] = self.ray
        return record


def run_tasks(
    study,
    function: Callable[[dict], dict],
    label: str,
    ray: RayOptions | None = None,
    training: Callable[[dict], dict | None] | None = None,
    runs_per_process: int | None = None,
) -> TaskRun:
    """Check `study`'s settings, resolve its device and jobs, and run its tasks (`study.tasks(device)`)
    with `run_jobs` in worker processes, timed: here, or with `ray` each task a Ray task on the device
    Ray assigns it. `training(task)`: the run config a task trains (None: it trains nothing), whose
    pending trainings that may share a process train first as populations
    (`common.pretrain_populations`, `runs_per_process` runs each; None: as many as the device holds),
    each task then taking its trained policy."""
    from ..env import resolve_device

    study.validate()
    if ray is not None and study.jobs is not None:
        raise ValueError(
            f"--jobs {study.jobs} sets the worker processes on this machine; with --ray each "
            "training run is a task (--cpus-per-task, --gpus-per-task)"
        )
    if ray is None:
        device = resolve_device(study.device)
        jobs: int | None = resolve_jobs(study.jobs, device)
    else:
        ray, device = placement(ray, study.device)
        jobs = None
    tasks = study.tasks(device)
    if ray is not None:  # workers write the trained policies themselves, wherever Ray starts them
        tasks = [dict(t, policy_dir=os.path.abspath(t["policy_dir"])) if "policy_dir" in t else t for t in tasks]
    start = time.perf_counter()
    if training is not None and ray is None:
        from .common import pretrain_populations

        pending = [t for t in tasks if not read_finished(study.out, t)[0]]
        trainings = [(config, t["policy_dir"]) for t in pending if (config := training(t)) is not None]
        pretrain_populations(trainings, device, runs_per_process, report=lambda line: print(line, flush=True))
    run = run_jobs(
        function,
        tasks,
        study.out,
        jobs=jobs or 1,
        device=device,
        ray=ray,
        label=label,
        report=lambda line: print(line, flush=True),
    )
    record = None if ray is None else dict(ray.record(device), nodes=run.nodes)
    return TaskRun(run.results, run.kept, device, jobs, time.perf_counter() - start, record)
