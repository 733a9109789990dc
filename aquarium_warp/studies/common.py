"""What the open-question studies share: option checks, training runs through the `Trainer` API,
several runs at once in worker processes or as Ray tasks, evaluation rollouts that see every step's state, the
geometry of fleeing, statistics over seeds, the output files and the error-band plots.

Statistics: every measure is first reduced to one value per seed (training seed or block of worlds);
figures and tables give the mean over seeds and its standard error (`sem`, std over seeds / sqrt(n)),
drawn as a band of mean ± 1 s.e.m.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import platform
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context

import numpy as np
import torch

from ..atomic import atomic_open, write_figure
from ..bench.machine import git_info, machine_info
from ..config import AquariumConfig
from ..device import resolve_device
from ..env import BatchedAquarium
from ..json_records import json_safe
from ..number_lists import parse_list
from ..ray_tasks import RayOptions, placement
from ..ray_tasks import run_tasks as run_ray_tasks
from ..rollout import Observer, StepView, StepViews
from ..rollout import rollout as run_rollout
from ..study import write_csv

BAND = "mean ± 1 s.e.m. over seeds"


# ---------------------------------------------------------------------------------------------- options
def number_list(text, kind: type, name: str, low: float, high: float | None = None, *,
                low_open: bool = False) -> list:
    """`parse_list` of an option, each value checked against [low, high] (or (low, high] with
    `low_open`); the error names the option and the allowed range."""
    values = parse_list(text, kind, name)
    for v in values:
        if (v <= low if low_open else v < low) or (high is not None and v > high):
            allowed = f"{'(' if low_open else '['}{low:g}, {'inf)' if high is None else f'{high:g}]'}"
            raise ValueError(f"{name}={text!r}: {v!r} is out of range: every value must be in {allowed}")
    return values


def check_int(name: str, value, low: int = 1) -> None:
    """A `ValueError` naming `name` unless `value` is an integer >= `low`."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{name}={value!r} must be an integer >= {low}")


def check_number(name: str, value, low: float, high: float = math.inf) -> None:
    """A `ValueError` naming `name` unless `value` is a finite number in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (low <= value <= high) \
            or not math.isfinite(value):
        raise ValueError(f"{name}={value!r} must be a finite number in [{low:g}, {high:g}]")


def resolve_jobs(jobs: int | None, device: str) -> int:
    """Training runs at once: `jobs`, else 4 on a GPU and 1 on the CPU. On one GPU the processes'
    kernels take turns (time slicing), so a run's GPU-bound PPO iterations gain little from company
    (the paper preset's runs took as long four at a time as one after another); what overlaps is the
    rest, which waits on the host: process start, the trainer's construction and CUDA graph capture,
    the evaluation loops (a host sync per step)."""
    if jobs is not None:
        check_int("jobs", jobs)
        return jobs
    return 4 if str(device).startswith("cuda") else 1


# ---------------------------------------------------------------------------------------------- jobs
def warm_up(device: str) -> None:
    """Build (or load from Warp's cache) the simulator's kernels once, before worker processes start, so
    that they do not all compile them at once."""
    from ..heuristics import make_policy
    from ..metrics import SwarmMetrics

    env = BatchedAquarium(AquariumConfig(prey_count=2, max_steps=2), num_worlds=1, device=device)
    env.reset()
    SwarmMetrics(env).compute()
    env.step({"prey": make_policy("turnaway", env, "prey")(), "predator": make_policy("naivchase", env, "predator")()})
    env.close()


# Finished tasks, one JSON file each under the study's `out`: a rerun of the same study (after the
# command was stopped at a time limit, say) keeps them and runs only the others.
FINISHED_DIR = "finished"


def task_key(task: dict) -> dict:
    """What a kept result must have been computed with: the task (not where it writes) and the study's
    settings (not its output directory, workers, figures or device option: the task has the device it
    ran on), as read back from JSON."""
    import json

    settings = {k: v for k, v in dataclasses.asdict(task["study"]).items()
                if k not in ("out", "jobs", "figures", "device")}
    own = {k: v for k, v in task.items() if k not in ("study", "policy_dir")}
    return json.loads(json.dumps({"task": own, "study": settings}))


@dataclasses.dataclass
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
        record = run_record(study_name, study, self.device, self.wall_s, sum(r["train_s"] for r in rows),
                            sum(r["job_s"] for r in rows), self.jobs, command, self.kept)
        if self.ray is not None:
            record["ray"] = self.ray
        return record


def run_tasks(study, function: Callable[[dict], dict], label: str, ray: RayOptions | None = None) -> TaskRun:
    """Check `study`'s settings, resolve its device and jobs, and run its tasks (`study.tasks(device)`)
    with `run_jobs`, timed: here, or with `ray` each task a Ray task on the device Ray assigns it."""
    study.validate()
    if ray is not None and study.jobs is not None:
        raise ValueError(f"--jobs {study.jobs} sets the worker processes on this machine; with --ray each "
                         "training run is a task (--cpus-per-task, --gpus-per-task)")
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
    results, kept, nodes = run_jobs(function, tasks, jobs or 1, device, study.out, label, ray)
    record = None
    if ray is not None:
        record = {"address": ray.address, "gpus_per_task": ray.gpus_per_task, "cpus_per_task": ray.cpus_per_task,
                  "max_retries": ray.max_retries, "device": device, "nodes": nodes}
    return TaskRun(results, kept, device, jobs, time.perf_counter() - start, record)


def _on_worker(function: Callable[[dict], dict], task: dict) -> tuple[dict, str]:
    """A Ray task: `function(task)` and the name of the machine that ran it."""
    return function(task), platform.node()


def group_rows(rows: list[dict], keys: Sequence[str]) -> dict[tuple, list[dict]]:
    """`rows` grouped by their values of `keys` (one group per setting; its rows are the seeds), in
    order of first appearance."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    return groups


def run_jobs(function: Callable[[dict], dict], tasks: Sequence[dict], jobs: int, device: str, out: str,
             label: str = "run", ray: RayOptions | None = None) -> tuple[list[dict], int, list[str]]:
    """`function(task)` for every task, in order of the tasks: in this process with `jobs=1`, else in a
    pool of `jobs` worker processes (spawn context, so each has its own CUDA context) after `warm_up`,
    or with `ray` (placed: `ray_tasks.placement`) as Ray tasks, a task whose worker dies rerun by Ray.
    `function` must be a module-level function and the tasks picklable (each with a unique "name").
    Each result is written to `out/finished/<name>.json` as it comes; a task whose file holds the same
    `task_key` is not run again. Prints one line per finished task. Returns the results, the number
    of kept ones and the machines that ran Ray tasks (sorted; empty without Ray)."""
    import json

    results: list[dict | None] = [None] * len(tasks)
    keys = [task_key(task) for task in tasks]
    paths = [os.path.join(out, FINISHED_DIR, f"{task['name']}.json") for task in tasks]
    for i, path in enumerate(paths):
        if os.path.isfile(path):
            with open(path, encoding="utf-8") as f:
                kept = json.load(f)
            if kept.get("key") == keys[i]:
                results[i] = kept["result"]
    kept_count = sum(r is not None for r in results)
    if kept_count:
        print(f"  {label}: {kept_count} of {len(tasks)} tasks kept from {os.path.join(out, FINISHED_DIR)}")
    todo = [i for i, r in enumerate(results) if r is None]
    os.makedirs(os.path.join(out, FINISHED_DIR), exist_ok=True)
    start = time.perf_counter()

    def done(i: int, result: dict) -> None:
        with atomic_open(paths[i]) as f:  # JSON reads back the same floats (NaN included)
            json.dump({"key": keys[i], "result": result}, f)
        results[i] = result
        finished = sum(r is not None for r in results)
        elapsed = time.perf_counter() - start
        left = elapsed / (finished - kept_count) * (len(tasks) - finished)  # longest tasks first: an overestimate
        print(f"  {label} {finished}/{len(tasks)} ({tasks[i]['name']}) after {elapsed:.0f} s, ~{left:.0f} s "
              "left", flush=True)

    nodes: set[str] = set()
    if ray is not None:
        def finished(k: int, result: tuple[dict, str]) -> None:
            nodes.add(result[1])
            done(todo[k], result[0])

        run_ray_tasks(_on_worker, [(function, tasks[i]) for i in todo], ray, on_result=finished)
    elif jobs <= 1 or len(todo) <= 1:
        for i in todo:
            done(i, function(tasks[i]))
    else:
        warm_up(device)
        with ProcessPoolExecutor(max_workers=min(jobs, len(todo)), mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(function, tasks[i]): i for i in todo}
            for future in as_completed(futures):
                done(futures[future], future.result())
    return [r for r in results if r is not None], kept_count, sorted(nodes)


# ---------------------------------------------------------------------------------------------- training
def training_config(env: dict, team: str, opponent: str | None, worlds: int, iterations: int, seed: int,
                    device: str) -> dict:
    """A run config: the `paper` preset's PPO settings (parameter sharing), the world `env` (AquariumConfig
    fields), `iterations` PPO iterations of `worlds` worlds, no logging, checkpoints or swarm metrics."""
    from ..training.config import make_config

    return make_config("paper", {"env": env, "train": {
        "team": team, "opponent": opponent, "num_worlds": worlds, "iterations": iterations, "episodes": None,
        "seed": seed, "device": device, "quiet": True, "metrics_every": 0, "export": ["jit"]}})


def train_and_export(config: dict, out_dir: str) -> tuple[dict[str, str], float]:
    """Train one run in this process (`Trainer`, no log directory) and export its policies (TorchScript)
    into `out_dir` (both teams: `out_dir/<team>/`). Returns `{team: policy file}` and the training's
    wall time in seconds (construction and export not included)."""
    from ..training import Trainer

    trainer = Trainer(copy.deepcopy(config))
    try:
        start = time.perf_counter()
        trainer.train()
        seconds = time.perf_counter() - start
        exported = trainer.export(out_dir, formats=["jit"])
    finally:
        trainer.close()
    if len(trainer.teams) == 1:
        return {trainer.teams[0]: exported["jit"]}, seconds
    return {team: paths["jit"] for team, paths in exported.items()}, seconds


# ---------------------------------------------------------------------------------------------- rollouts
def rollout(cfg: AquariumConfig, prey: str, predator: str, worlds: int, seed: int, device: str,
            on_step: Callable[[StepView], None], metrics_every: int = 0) -> dict:
    """Play one episode of `cfg.max_steps` steps in each of `worlds` worlds with the prey and predator
    specs (`aquarium_warp.drivers`: heuristic names, policy files or shipped names; trained policies
    act deterministically), calling
    `on_step` after every step but the last (whose state is already the next episode's first: the worlds
    reset themselves). Returns per-world numpy arrays: `captures` (the episode's),
    `length` and, with `metrics_every`, the episode means of the swarm metrics (`EPISODE_METRICS`)."""
    from ..drivers import make_drivers
    from ..metrics import EpisodeMetrics

    env = BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=seed)
    drivers = make_drivers({"prey": prey, "predator": predator}, env, seed=seed)
    episodes = EpisodeMetrics(env, every=metrics_every) if metrics_every else None

    def measure(view: StepView) -> None:
        if view.step < cfg.max_steps - 1:  # the last step's state is already the next episode's first
            on_step(view)

    observers: list[Observer] = [StepViews(measure)] if episodes is None else [episodes, StepViews(measure)]
    run_rollout(env, drivers, cfg.max_steps, observers)
    info = env.outputs.info
    ended = info["episode_ended"]
    if not bool(ended.all()):
        raise RuntimeError("rollout: a world's episode ended early (a team died out): not one episode per world")
    out = {"captures": info["episode_captures"].cpu().numpy().astype(np.float64),
           "length": info["episode_length"].cpu().numpy().astype(np.float64)}
    if episodes is not None:
        out.update({k: v.detach().cpu().double().numpy() for k, v in episodes.result().items()})
    env.close()
    return out


# ---------------------------------------------------------------------------------------------- geometry
def torus_delta(delta: torch.Tensor, width: float, height: float) -> torch.Tensor:
    """The torus-shortest form of displacements `delta` `[..., 2]` in a `width` x `height` world."""
    size = torch.tensor([width, height], dtype=delta.dtype, device=delta.device)
    return delta - size * torch.round(delta / size)


def nearest_predator(prey_position: torch.Tensor, predator_position: torch.Tensor, predator_alive: torch.Tensor,
                     width: float, height: float) -> tuple[torch.Tensor, torch.Tensor]:
    """For prey `[W, N, 2]` and predators `[W, P, 2]` (`predator_alive` `[W, P]`): the displacement from
    each prey's nearest live predator to the prey (`[W, N, 2]`, the direction of escape) and its
    length (`[W, N]`, inf without a live predator)."""
    away = torus_delta(prey_position[:, :, None, :] - predator_position[:, None, :, :], width, height)
    distance = torch.linalg.vector_norm(away, dim=-1).masked_fill(~predator_alive[:, None, :], math.inf)
    nearest = distance.argmin(dim=-1, keepdim=True)
    return (torch.gather(away, 2, nearest[..., None].expand(-1, -1, 1, 2)).squeeze(2),
            torch.gather(distance, 2, nearest).squeeze(2))


def cosine(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cosine of the angle between vectors `[..., 2]` (0 where either is zero)."""
    norm = torch.linalg.vector_norm(a, dim=-1) * torch.linalg.vector_norm(b, dim=-1)
    return torch.where(norm > 0, (a * b).sum(-1) / norm.clamp_min(1e-12), torch.zeros_like(norm))


def fleeing(velocity: torch.Tensor, away: torch.Tensor, distance: torch.Tensor, max_speed: float,
            flee_angle: float, flee_distance: float) -> torch.Tensor:
    """Whether each prey flees its nearest predator: the predator is within `flee_distance` px, the
    prey moves at least half its `max_speed`, and its velocity points away from the predator within
    `flee_angle` degrees (`away`: displacement from the predator to the prey)."""
    speed = torch.linalg.vector_norm(velocity, dim=-1)
    return (distance <= flee_distance) & (speed >= 0.5 * max_speed) & \
        (cosine(velocity, away) >= math.cos(math.radians(flee_angle)))


# ---------------------------------------------------------------------------------------------- outputs
def write_outputs(out: str, name: str, rows: list[dict], summary: dict,
                  plot: Callable[[dict, str], str | list[str]] | None = None) -> dict:
    """`<name>.csv` (rows) and `<name>.json` (summary) in `out`, then, with `plot`, the figures that
    `plot(summary, out)` draws; returns `summary` with `files` (`{"csv", "json"}`) and `figures`
    (paths) added."""
    import json

    os.makedirs(out, exist_ok=True)
    paths = {"csv": os.path.join(out, f"{name}.csv"), "json": os.path.join(out, f"{name}.json")}
    write_csv(paths["csv"], rows)
    with atomic_open(paths["json"]) as f:
        json.dump(json_safe(summary), f, indent=1)
    figures = plot(summary, out) if plot is not None else []
    summary["files"] = paths
    summary["figures"] = [figures] if isinstance(figures, str) else list(figures)
    return summary


def written(summary: dict) -> str:
    """The CLI's closing line: the files written, the wall time and the device."""
    names = list(summary["files"].values()) + summary["figures"]
    return f"wrote {', '.join(names)} in {summary['wall_time_s']:.1f} s on {summary['machine']['device_name']}"


def command_line(argv: Sequence[str] | None = None) -> str:
    """The command as typed: `aquarium-warp` and `argv` (default: this process's arguments), shell-quoted."""
    return " ".join(["aquarium-warp"] + [shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv)])


def run_record(study: str, settings, device: str, wall_s: float, train_s: float, job_s: float,
               jobs: int | None, command: str | None, kept: int = 0) -> dict:
    """The JSON's record of a run: the study, the exact command (default `command_line()`), the commit
    (`git_info`), its settings, the machine, the wall time, the summed training time of its runs and the
    fraction of the workers' time spent training (`kept`: tasks kept from an earlier run, whose times count too)."""
    return {"study": study, "command": command if command is not None else command_line(), "git": git_info(),
            "settings": dataclasses.asdict(settings), "device": device, "machine": machine_info(device),
            "jobs": jobs, "tasks_kept": kept, "wall_time_s": round(wall_s, 2), "training_time_s": round(train_s, 2),
            "training_fraction": train_s / job_s if job_s > 0 else 0.0,
            "training_fraction_definition": "summed training time of the runs (PPO iterations only) / summed "
                                            "time of the jobs (training, export and evaluation) in the workers",
            "training_time_per_wall_time": train_s / wall_s if wall_s > 0 else 0.0,
            "training_time_per_wall_time_definition": "summed training time of the runs / this call's wall time "
                                                      "(above 1 where runs trained at once; kept runs count)",
            "spread": BAND}


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def band(ax, x, stats: list[dict], label: str | None = None, style: str = "o-", **kwargs):
    """A line of the means and a band of mean ± 1 s.e.m. (`seed_stats` dicts, one per x)."""
    mean = np.array([np.nan if s["mean"] is None else s["mean"] for s in stats], dtype=float)
    sem = np.nan_to_num(np.array([np.nan if s["sem"] is None else s["sem"] for s in stats], dtype=float))
    line, = ax.plot(x, mean, style, label=label, ms=4, lw=1.4, **kwargs)
    ax.fill_between(x, mean - sem, mean + sem, color=line.get_color(), alpha=0.2, lw=0)
    return line


def save_figure(fig, out: str, name: str, title: str) -> str:
    fig.suptitle(f"{title}\n({BAND})", fontsize=9)
    fig.tight_layout()
    path = os.path.join(out, name)
    write_figure(fig, path, dpi=110)
    pyplot().close(fig)
    return path
