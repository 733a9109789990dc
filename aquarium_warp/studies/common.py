"""What the studies share besides the job runner (`aquarium_warp.jobs`) and statistics (`statistics`), in sections:

- **rows**: `group_rows` (a study's rows grouped by setting; a group's rows are the seeds);
- **training**: run configs (`training_config`), training runs through the `Trainer` API
  (`train_and_export`, `run_training_task`, `run_training_population`, `pretrain_populations`) and the
  policies they export (`policy_path`);
- **rollouts**: evaluation episodes that see every step's state (`rollout`);
- **geometry**: the torus and fleeing (`torus_delta`, `nearest_predator`, `cosine`, `fleeing`);
- **outputs**: the files (`write_outputs`, `write_csv`), the record of a run (`run_record`), the closing
  line (`written`) and the error-band figures (`pyplot`, `band`, `save_figure`);
- **command line**: the options every open-question study takes (`add_common_arguments`) and a
  study's own options in `aquarium-warp study <name>` (`study_options`).

Figures give the mean over seeds and its standard error (`sem`, std over seeds / sqrt(n)), drawn as a
band of mean ± 1 s.e.m.; the JSON files give the 95% interval of the mean too (`statistics.seed_stats`).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import csv
import dataclasses
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..arguments import DEVICE_HELP, int_at_least, non_negative_float, option, positive_float, positive_int
from ..atomic import atomic_open, write_figure
from ..records import json_safe, provenance

if TYPE_CHECKING:
    import torch

    from ..config import AquariumConfig
    from ..rollout import Observer, StepView

# torch and the simulator are imported where a study runs: the studies' options (`study --help`) stay light.

BAND = "mean ± 1 s.e.m. over seeds"
# Options that mean the same in several studies: their settings fields' `field(metadata=...)`.
ITERATIONS = option("PPO iterations per run, 32 steps each", type=positive_int)
TRAIN_STEPS = option("episode length in training", type=int_at_least(2))
EVAL_STEPS = option("evaluation episode length", type=int_at_least(2))
FLEE_ANGLE = option(
    "degrees: fleeing = velocity within this of straight away from the predator", type=non_negative_float
)
FLEE_DISTANCE = option("px: fleeing needs the nearest predator this close", type=positive_float)
# ... and in the studies whose tasks run on GPUs with their results kept (swarm, phase), checked by the
# study's own rules (its error names the option).
TASK_GPUS = option("GPUs to spread tasks over (default: all; 0: CPU)", type=int)
TRAIN_WORLDS = option("worlds per training run (default: TRAIN_AGENT_STEPS / (prey x 32 x iterations))", type=int)
EVAL_EPISODES = option("evaluation episodes per evaluation seed", type=int)
EVAL_SEEDS = option("evaluation seeds, a count N: seeds 0 to N-1 (eval --seeds takes a list of seeds)", type=int)
MAX_STEPS = option("episode length (docs/model.md's)", type=int)
COMMIT = option("the commit to record, of a copy without git history (a checkout's own is read from git)")

FIGURE_BAND = "bands: the 95% Student-t interval of the mean over seeds"


def check_task_options(settings, *more: tuple[str, object, int]) -> None:
    """A one-line `ValueError` naming the option unless the run options the swarm and phase studies share
    (`--seeds` >= 2, `--iterations`, `--episodes`, `--eval-seeds`, `--max-steps`, `--per-gpu` >= 1,
    `--train-worlds` >= 1 where given, `--gpus` >= 0 where given) and `more` (name, value, lowest) are in
    range."""
    from ..arguments import check_int

    for name, value, low in (
        ("--seeds", settings.seeds, 2),
        *more,
        ("--iterations", settings.iterations, 1),
        ("--episodes", settings.episodes, 1),
        ("--eval-seeds", settings.eval_seeds, 1),
        ("--max-steps", settings.max_steps, 1),
        ("--per-gpu", settings.per_gpu, 1),
    ):
        check_int(name, value, low)
    if settings.train_worlds is not None:
        check_int("--train-worlds", settings.train_worlds, 1)
    if settings.gpus is not None:
        check_int("--gpus", settings.gpus, 0)


# ---------------------------------------------------------------------------------------------- rows
def group_rows(rows: list[dict], keys: Sequence[str]) -> dict[tuple, list[dict]]:
    """`rows` grouped by their values of `keys` (one group per setting; its rows are the seeds), in
    order of first appearance."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    return groups


# ---------------------------------------------------------------------------------------------- training
def training_config(
    env: dict,
    team: str,
    opponent: str | None,
    worlds: int,
    iterations: int,
    seed: int,
    device: str,
    recipe: bool = False,
) -> dict:
    """A run config: the `paper` preset's PPO settings (parameter sharing; with `recipe` the learned-prey
    recipe's), the world `env` (AquariumConfig fields), `iterations` PPO iterations of `worlds` worlds, no
    logging, checkpoints or swarm metrics."""
    from ..training.config import LEARNED_PREY_RECIPE, deep_update, make_config
    from ..training.fast_path import TORCH_FLOAT32

    config = make_config(
        "paper",
        {
            "env": env,
            "train": {
                "team": team,
                "opponent": opponent,
                "num_worlds": worlds,
                "iterations": iterations,
                "episodes": None,
                "seed": seed,
                "device": device,
                "quiet": True,
                "metrics_every": 0,
                "export": ["jit"],
                **TORCH_FLOAT32,
            },
        },
    )
    if recipe:
        deep_update(config, {"runner": LEARNED_PREY_RECIPE["runner"]})
    return config


# The checkpoint that an interrupted training without a log directory leaves in its policy folder.
INTERRUPTED = "interrupted.pt"
# A training that a population trained before its task ran (`pretrain_populations`): its config, policies
# and time, in the task's policy folder, which `train_and_export` then returns instead of training.
TRAINED = "trained.json"


def train_and_export(config: dict, out_dir: str, log_dir: str | None = None) -> tuple[dict[str, str], float]:
    """Train one run in this process (`Trainer`; with `log_dir`, its config, logs and checkpoints there,
    the directory claimed meanwhile) and export its policies (TorchScript) into `out_dir` (both teams:
    `out_dir/<team>/`). Returns `{team: policy file}` and the training's wall time in seconds in this
    call (construction and export not included).

    A training stopped by SIGINT or SIGTERM (`Trainer.stop`) is not finished: nothing is exported, its
    state is kept (the last checkpoint in `log_dir`, else `<out_dir>/interrupted.pt`) and
    `arguments.Interrupted` raised; the next call with the same config continues it from there. A kept state
    of another config is replaced by a new run."""
    from ..arguments import Interrupted
    from ..training import Trainer
    from ..training.run_dir import claim_run_directory

    trained = _trained_before(config, out_dir) if log_dir is None else None
    if trained is not None:
        return trained
    saved = _saved_training(config, out_dir, log_dir)
    claimed = (
        None if log_dir is None else claim_run_directory(log_dir, resume=saved is not None, overwrite=saved is None)
    )
    try:
        if saved is None:
            trainer = Trainer(copy.deepcopy(config), log_dir=log_dir)
        elif log_dir is not None:
            trainer = Trainer.resume(saved[0], log_dir=log_dir)
        else:
            trainer = Trainer(copy.deepcopy(config), run_id=saved[1])
            trainer.load(saved[0])
        if saved is not None:
            print(f"  continuing {saved[0]} at iteration {trainer.iteration} of {trainer.total_iterations}", flush=True)
        try:
            start = time.perf_counter()
            trainer.train()
            seconds = time.perf_counter() - start
            if trainer.stop.signum is not None:
                kept = log_dir  # the runner checkpointed the last iteration there
                if kept is None:
                    os.makedirs(out_dir, exist_ok=True)
                    kept = os.path.join(out_dir, INTERRUPTED)
                    trainer.save(kept)
                raise Interrupted(
                    f"stopped by {trainer.stop.name} after iteration {trainer.iteration} of "
                    f"{trainer.total_iterations} of a training run, kept in {kept}: rerun the same command to "
                    "continue it",
                    trainer.stop.signum,
                )
            exported = trainer.export(out_dir, formats=["jit"])
        finally:
            trainer.close()
    finally:
        if claimed is not None:
            claimed.release()
    if log_dir is None and saved is not None:
        os.remove(saved[0])  # finished: nothing left to continue
    if len(trainer.teams) == 1:
        return {trainer.teams[0]: exported["jit"]}, seconds
    return {team: paths["jit"] for team, paths in exported.items()}, seconds


def _trained_before(config: dict, out_dir: str) -> tuple[dict[str, str], float] | None:
    """`train_and_export`'s result for `config` where a population trained it into `out_dir` already
    (`TRAINED`, of the same config, its policies present); else None."""
    from ..training.config import config_difference
    from ..training.trainer import run_config

    try:
        with open(os.path.join(out_dir, TRAINED), encoding="utf-8") as f:
            record = json.load(f)
    except (OSError, ValueError):
        return None
    same = config_difference(record.get("config"), run_config(config)) is None
    if not same or not all(os.path.isfile(p) for p in record.get("policies", {}).values()):
        return None
    return dict(record["policies"]), float(record["seconds"])


def pretrain_populations(
    trainings: list[tuple[dict, str]], device: str, runs_per_process: int | None = None, report=print
) -> None:
    """Train the `(config, out_dir)` trainings of a study's pending tasks that may share a process as
    populations (`training/population.py`), before the tasks run: each run's policy exported into its
    `out_dir` with `TRAINED`, so that the task's `train_and_export` returns it. Populations hold
    `runs_per_process` runs (None: `population.population_size`, one on the CPU: nothing is trained here);
    trainings that would be alone, or that have a kept state to continue, are left to their tasks. A
    signal stops every run of a population; each keeps its state as `<out_dir>/interrupted.pt`, which the
    rerun's task continues, and `arguments.Interrupted` is raised."""
    from ..arguments import Interrupted
    from ..training.checkpoints import write_checkpoint
    from ..training.population import Population, population_groups
    from ..training.run_dir import claim_run_directory
    from ..training.trainer import run_config

    kept = [
        _trained_before(config, out_dir) is not None or _saved_training(config, out_dir, None) is not None
        for config, out_dir in trainings
    ]
    configs_all = [config for config, _ in trainings]
    for indices, why in population_groups(configs_all, kept, device, runs_per_process, report):
        if len(indices) < 2:
            continue  # trained by its own task
        group = [trainings[i] for i in indices]
        if report is not None:
            report(f"  training {len(group)} runs as one population on {device} ({why})")
        configs = [dict(c, train={**c["train"], "device": device}) for c, _ in group]
        run_dirs = [os.path.join(d, "population-run") for _, d in group]
        with contextlib.ExitStack() as held:
            # Each run's log folder replaced, as a training alone replaces its own: no earlier rows mixed in.
            for run_dir in run_dirs:
                held.callback(claim_run_directory(run_dir, overwrite=True).release)
            population = Population(configs, run_dirs=run_dirs)
            held.callback(population.close)
            start_time = time.perf_counter()
            population.train()
            seconds = time.perf_counter() - start_time
            if population.stop.signum is not None:
                for k, (_, out_dir) in enumerate(group):
                    write_checkpoint(population.run_state(k), os.path.join(out_dir, INTERRUPTED))
                raise Interrupted(
                    f"stopped by {population.stop.name} after iteration {population.iteration} of a population "
                    f"of {len(group)} training runs, each kept in its folder: rerun the same command to continue",
                    population.stop.signum,
                )
            for k, (config, out_dir) in enumerate(group):
                if k not in population.stopped:
                    path = population.export(k, formats=["jit"], out_dir=out_dir)["jit"]
                    with atomic_open(os.path.join(out_dir, TRAINED)) as f:
                        json.dump({"config": run_config(config), "seconds": seconds,
                                   "policies": {population.team: path}}, f)  # fmt: skip
            if population.stopped:  # reported after the other runs' policies are kept
                failed = ", ".join(f"{group[k][1]} ({why})" for k, why in population.stopped.items())
                raise RuntimeError(f"trainings stopped early: {failed}")


def _saved_training(config: dict, out_dir: str, log_dir: str | None) -> tuple[str, str | None] | None:
    """The checkpoint that an interrupted training of `config` left (`log_dir`'s newest, else
    `<out_dir>/interrupted.pt`) and its run id; None where there is none or it is of another config."""
    from ..training.checkpoints import newest_readable_checkpoint, read_checkpoint
    from ..training.config import config_difference
    from ..training.trainer import run_config

    try:
        if log_dir is not None:
            path, checkpoint = newest_readable_checkpoint(log_dir)
        else:
            path = os.path.join(out_dir, INTERRUPTED)
            checkpoint = read_checkpoint(path)
    except ValueError:  # none, or none readable
        return None
    state = checkpoint["infos"]["aquarium"]
    if config_difference(state["config"], run_config(config)) is not None:
        return None
    return path, state.get("run_id")


def policy_path(run: str) -> str:
    """The policy that the training run in the folder `run` exported (`run_training_task`)."""
    return os.path.join(run, "exported", "policy.pt")


def run_training_population(tasks: list[dict], device: str) -> list[dict]:
    """Jobs of `run_training_task` trained together, as one population (`training.population`) on
    `device`: each run into its task's `run_dir` (config, progress CSV, TensorBoard log, checkpoints, the
    exported policy), as `run_training_task` trains it alone. A training stopped by SIGINT or SIGTERM
    keeps every run's checkpoint in its folder and raises `arguments.Interrupted`; a rerun continues each run
    there (alone: its checkpoints are `Trainer`'s)."""
    from ..arguments import Interrupted
    from ..training.population import Population
    from ..training.run_dir import claim_run_directory

    configs = [copy.deepcopy(task["config"]) for task in tasks]
    for config in configs:
        config["train"]["device"] = device
    claimed = []
    try:
        for task in tasks:
            claimed.append(claim_run_directory(task["run_dir"], overwrite=True))
        population = Population(configs, run_dirs=[task["run_dir"] for task in tasks])
        try:
            start = time.perf_counter()
            population.train()
            seconds = time.perf_counter() - start
            if population.stop.signum is not None:
                raise Interrupted(
                    f"stopped by {population.stop.name} after iteration {population.iteration} of a population of "
                    f"{len(tasks)} training runs, each kept in its folder: rerun the same command to continue them",
                    population.stop.signum,
                )
            for k in range(population.K):
                if k in population.stopped:
                    raise RuntimeError(f"training run {tasks[k]['name']} stopped: {population.stopped[k]}")
                population.export(k, formats=["jit"])
        finally:
            population.close()
    finally:
        for run_dir in claimed:
            run_dir.release()
    return [{"seconds": round(seconds, 1), "population": len(tasks)} for _ in tasks]


class TrainingTask:
    """The job of a study's training run (`jobs.run_jobs` with `devices`, a `jobs.GroupedJob`): train
    the run config `task["config"]` on `device` in this process into the folder `task["run_dir"]`
    (config, progress CSV, TensorBoard log, the last checkpoint, the exported policy: `policy_path`),
    continuing an interrupted training of the same config there, else replacing an earlier run's
    outputs. Pending tasks that may share a process train together as populations."""

    def __call__(self, task: dict, device: str) -> dict:
        config = copy.deepcopy(task["config"])
        config["train"]["device"] = device
        _, seconds = train_and_export(config, os.path.dirname(policy_path(task["run_dir"])), log_dir=task["run_dir"])
        return {"seconds": round(seconds, 1)}

    def groups(
        self, tasks: Sequence[dict], device: str, runs_per_process: int | None, report: Callable[[str], None] | None
    ) -> list[list[int]]:
        """`tasks` in the groups that train in one process: those of one `population.group_key` in
        populations of `runs_per_process` (None: `population.population_size`); a task whose folder
        holds a checkpoint (an interrupted training), or whose config trains alone, is a group of its own."""
        from ..training.checkpoints import newest_readable_checkpoint
        from ..training.population import population_groups

        resumes = []
        for task in tasks:
            try:
                newest_readable_checkpoint(task["run_dir"])
                resumes.append(True)
            except (ValueError, FileNotFoundError):
                resumes.append(False)
        groups = population_groups([task["config"] for task in tasks], resumes, device, runs_per_process, report)
        return [group for group, _ in groups]

    def run_group(self, tasks: list[dict], device: str) -> list:
        """One group of `groups`: a task alone, or a population (`run_training_population`)."""
        if len(tasks) == 1:
            return [self(tasks[0], device)]
        return run_training_population(tasks, device)


run_training_task = TrainingTask()


# ---------------------------------------------------------------------------------------------- rollouts
def rollout(
    cfg: AquariumConfig,
    prey: str,
    predator: str,
    worlds: int,
    seed: int,
    device: str,
    on_step: Callable[[StepView], None],
    metrics_every: int = 0,
) -> dict:
    """Play one episode of `cfg.max_steps` steps in each of `worlds` worlds with the prey and predator
    specs (`aquarium_warp.drivers`: heuristic names, policy files or shipped names; trained policies
    act deterministically), calling
    `on_step` after every step but the last (whose state is already the next episode's first: the worlds
    reset themselves). Returns per-world numpy arrays: `captures` (the episode's),
    `length` and, with `metrics_every`, the episode means of the swarm metrics (`EPISODE_METRICS`)."""
    from ..drivers import make_drivers
    from ..env import BatchedAquarium
    from ..metrics import EpisodeMetrics
    from ..rollout import StepViews
    from ..rollout import rollout as run_rollout

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
    out = {
        "captures": info["episode_captures"].cpu().numpy().astype(np.float64),
        "length": info["episode_length"].cpu().numpy().astype(np.float64),
    }
    if episodes is not None:
        out.update({k: v.detach().cpu().double().numpy() for k, v in episodes.result().items()})
    env.close()
    return out


# ---------------------------------------------------------------------------------------------- geometry
def torus_delta(delta: torch.Tensor, width: float, height: float) -> torch.Tensor:
    """The torus-shortest form of displacements `delta` `[..., 2]` in a `width` x `height` world."""
    import torch

    size = torch.tensor([width, height], dtype=delta.dtype, device=delta.device)
    return delta - size * torch.round(delta / size)


def nearest_predator(
    prey_position: torch.Tensor,
    predator_position: torch.Tensor,
    predator_alive: torch.Tensor,
    width: float,
    height: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """For prey `[W, N, 2]` and predators `[W, P, 2]` (`predator_alive` `[W, P]`): the displacement from
    each prey's nearest live predator to the prey (`[W, N, 2]`, the direction of escape) and its
    length (`[W, N]`, inf without a live predator)."""
    import torch

    away = torus_delta(prey_position[:, :, None, :] - predator_position[:, None, :, :], width, height)
    distance = torch.linalg.vector_norm(away, dim=-1).masked_fill(~predator_alive[:, None, :], math.inf)
    nearest = distance.argmin(dim=-1, keepdim=True)
    return (
        torch.gather(away, 2, nearest[..., None].expand(-1, -1, 1, 2)).squeeze(2),
        torch.gather(distance, 2, nearest).squeeze(2),
    )


def cosine(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cosine of the angle between vectors `[..., 2]` (0 where either is zero)."""
    import torch

    norm = torch.linalg.vector_norm(a, dim=-1) * torch.linalg.vector_norm(b, dim=-1)
    return torch.where(norm > 0, (a * b).sum(-1) / norm.clamp_min(1e-12), torch.zeros_like(norm))


def fleeing(
    velocity: torch.Tensor,
    away: torch.Tensor,
    distance: torch.Tensor,
    max_speed: float,
    flee_angle: float,
    flee_distance: float,
) -> torch.Tensor:
    """Whether each prey flees its nearest predator: the predator is within `flee_distance` px, the
    prey moves at least half its `max_speed`, and its velocity points away from the predator within
    `flee_angle` degrees (`away`: displacement from the predator to the prey)."""
    import torch

    speed = torch.linalg.vector_norm(velocity, dim=-1)
    return (
        (distance <= flee_distance)
        & (speed >= 0.5 * max_speed)
        & (cosine(velocity, away) >= math.cos(math.radians(flee_angle)))
    )


# ---------------------------------------------------------------------------------------------- outputs
def write_outputs(
    out: str, name: str, rows: list[dict], summary: dict, plot: Callable[[dict, str], str | list[str]] | None = None
) -> dict:
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


def write_csv(path: str, rows: list[dict]) -> None:
    """`rows` (dicts with the same keys) as a CSV file, floats to 6 significant digits."""
    with atomic_open(path, newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


def written(summary: dict) -> str:
    """The CLI's closing line: the files written, the wall time and the device."""
    names = list(summary["files"].values()) + summary["figures"]
    return f"wrote {', '.join(names)} in {summary['wall_time_s']:.1f} s on {summary['machine']['device_name']}"


def run_record(
    study: str,
    settings,
    device: str,
    wall_s: float,
    train_s: float,
    job_s: float,
    jobs: int | None,
    command: str | None,
    kept: int = 0,
) -> dict:
    """The JSON's record of a run: the study, the exact command (default `command_line()`), the commit
    (`git_info`), its settings, the machine, the wall time, the summed training time of its runs and the
    fraction of the workers' time spent training (`kept`: tasks kept from an earlier run, whose times count too)."""
    return {
        "study": study,
        **provenance(device, command),
        "settings": dataclasses.asdict(settings),
        "device": device,
        "jobs": jobs,
        "tasks_kept": kept,
        "wall_time_s": round(wall_s, 2),
        "training_time_s": round(train_s, 2),
        "training_fraction": train_s / job_s if job_s > 0 else 0.0,
        "training_fraction_definition": "summed training time of the runs (PPO iterations only) / summed "
        "time of the jobs (training, export and evaluation) in the workers",
        "training_time_per_wall_time": train_s / wall_s if wall_s > 0 else 0.0,
        "training_time_per_wall_time_definition": "summed training time of the runs / this call's wall time "
        "(above 1 where runs trained at once; kept runs count)",
        "spread": BAND,
    }


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def band(ax, x, stats: list[dict], label: str | None = None, style: str = "o-", **kwargs):
    """A line of the means and a band of their 95% t intervals (`seed_stats` dicts, one per x)."""
    mean = np.array([np.nan if s["mean"] is None else s["mean"] for s in stats], dtype=float)
    half = np.nan_to_num(np.array([np.nan if s["ci95"] is None else s["ci95"] for s in stats], dtype=float))
    (line,) = ax.plot(x, mean, style, label=label, ms=4, lw=1.4, **kwargs)
    ax.fill_between(x, mean - half, mean + half, color=line.get_color(), alpha=0.2, lw=0)
    return line


def save_figure(fig, out: str, name: str, title: str) -> str:
    fig.suptitle(f"{title}\n({FIGURE_BAND})", fontsize=9)
    fig.tight_layout()
    path = os.path.join(out, name)
    write_figure(fig, path, dpi=110)
    pyplot().close(fig)
    return path


# ---------------------------------------------------------------------------------------------- command line
def add_common_arguments(p: argparse.ArgumentParser, out: str, jobs: bool = True) -> None:
    """The options of every open-question study: seeds, device, workers (`jobs`), output."""
    p.add_argument("--seeds", type=positive_int, default=5, help="independent runs per setting (default 5)")
    p.add_argument("--device", default=None, help=DEVICE_HELP)
    if jobs:
        p.add_argument(
            "--jobs",
            type=positive_int,
            default=None,
            help="training runs at once, each in a worker process of its own (spawned; on a GPU each "
            "with its own CUDA context); default 4 on a GPU, 1 on the CPU",
        )
    p.add_argument("--out", default=out, help=f"output directory (default {out})")
    p.add_argument("--no-figures", action="store_true", help="write CSV/JSON only, no figures")


def study_options(argv: Sequence[str], name: str) -> list[str]:
    """The options of `aquarium-warp study <name> ...` (`args.argv`, the command as given): the words after
    the study's name, for a study whose own `main(argv)` parses them (the one parser of its script and
    of `aquarium-warp study`)."""
    words = list(argv)
    return words[words.index(name) + 1 :]


def common_settings(args: argparse.Namespace, jobs: bool = True) -> dict:
    """The settings of `add_common_arguments`' options (with `jobs` as it was given), by field name."""
    settings = {"seeds": args.seeds, "device": args.device, "out": args.out, "figures": not args.no_figures}
    return dict(settings, jobs=args.jobs) if jobs else settings
