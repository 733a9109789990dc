"""Training sweeps: one training run per seed and setting, one after another on this machine or as Ray
tasks (`aquarium_warp.jobs`).

    aquarium-warp sweep train --seeds 0,1,2 --vary train.sharing=parameter,individual --out runs/grid \\
        [--ray [ADDRESS]] [any option of aquarium-warp train]

trains every combination of a seed and the varied settings (each an `aquarium-warp train --set KEY=VALUE`)
through the `Trainer` API, with the config `aquarium-warp train` builds from the same options
(`training.cli.train_config`), in a directory of its own: `<out>/seed<s>`, or `<out>/<KEY=VALUE_...>/seed<s>`
with `--vary`. Each run directory holds `sweep_run.json`, the run's options and status. A rerun of the
sweep keeps the finished runs and resumes a started one from its newest checkpoint (`Trainer.resume`), so
a Ray task rerun after its worker died continues from the last checkpoint rather than from the start.
`<out>/sweep.json` lists the runs. On Ray the workers write the run directories: give an `--out` that
every machine of the cluster sees.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import re
import shutil
import time
from dataclasses import dataclass

from ..arguments import parse_list, plural
from ..atomic import atomic_open
from ..jobs import RayOptions, add_ray_arguments, placement, ray_options, run_ray_tasks

RUN_RECORD = "sweep_run.json"
# Train options that do not change what a run computes: a kept run is one whatever their values.
NOT_THE_RUN = ("device", "quiet", "log_dir", "resume", "overwrite")


def parse_vary(text: str) -> tuple[str, tuple[str, ...]]:
    """`"train.sharing=parameter,individual"` -> ("train.sharing", ("parameter", "individual")). Values
    are JSON or words (as in `--set`); commas inside [...] or {...} belong to the value."""
    key, sep, values = text.partition("=")
    parts = tuple(v.strip() for v in re.split(r",(?![^\[{]*[\]}])", values))
    if not sep or not key.strip() or not all(parts):
        raise ValueError(
            f"--vary {text!r}: expected KEY.PATH=VALUE,VALUE,... (e.g. train.sharing=parameter,individual)"
        )
    return key.strip(), parts


@dataclass(frozen=True)
class TrainingRun:
    """One run of a sweep: its seed, its `--set` assignments and its directory."""

    seed: int
    sets: tuple[str, ...]
    run_dir: str


@dataclass(frozen=True)
class TrainingSweep:
    """Seeds x settings of a training sweep (the CLI's `sweep train` options)."""

    seeds: tuple[int, ...] = (0,)
    vary: tuple[tuple[str, tuple[str, ...]], ...] = ()  # (KEY.PATH, values) of `--set KEY.PATH=VALUE`
    out: str = "sweep"  # the sweep's directory: sweep.json and a directory per run

    def validate(self) -> None:
        from .config import parse_assignment

        parse_list(list(self.seeds), int, "seeds", minimum=0)
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds={list(self.seeds)} must list at least one seed, each once")
        keys = [key for key, _ in self.vary]
        if len(set(keys)) != len(keys):
            raise ValueError(f"vary={keys}: each key once (list its values after one '=')")
        for key, values in self.vary:
            if not values or len(set(values)) != len(values):
                raise ValueError(f"vary {key}={','.join(values)}: list at least one value, each once")
            for value in values:
                parse_assignment(f"{key}={value}")  # the key's form, as train --set checks it

    def runs(self) -> list[TrainingRun]:
        """Every setting (the product of the varied values) for every seed, settings outermost."""
        keys = [key for key, _ in self.vary]
        out = []
        for values in itertools.product(*(v for _, v in self.vary)):
            sets = tuple(f"{k}={v}" for k, v in zip(keys, values))
            setting_dir = "_".join(re.sub(r"[^A-Za-z0-9._=-]+", "-", s) for s in sets)
            for seed in self.seeds:
                out.append(TrainingRun(seed, sets, os.path.join(self.out, setting_dir, f"seed{seed}")))
        return out


def run_options(train_args: argparse.Namespace, run: TrainingRun) -> dict:
    """What `sweep_run.json` records of `run`'s options (`aquarium-warp train`'s, with the run's seed and
    settings), as read back from JSON: a rerun into the same directory must give the same."""
    options = dict(vars(train_args), seed=run.seed, set=[*train_args.set, *run.sets])
    return json.loads(json.dumps({k: v for k, v in options.items() if k not in NOT_THE_RUN}))


def train_run(run: TrainingRun, config: dict, options: dict) -> dict:
    """Train `run` in its directory with `config` (a `Trainer` config): kept if `sweep_run.json` says it
    finished with the same `options` (`run_options`), resumed from its newest checkpoint if it started,
    else from scratch. Returns the run's record (also in `sweep_run.json`). One sweep task, on Ray or here."""
    from . import Trainer, latest_checkpoint
    from .cli import finish_training
    from .run_dir import claim_run_directory

    path = os.path.join(run.run_dir, RUN_RECORD)
    if os.path.isfile(path):
        with open(path, encoding="utf-8") as f:
            record = json.load(f)
        if record["options"] != options:
            raise ValueError(f"{run.run_dir} holds a run with other options: give the sweep another --out")
        if record["status"] == "done":
            return dict(record, kept=True)
    elif os.path.isdir(run.run_dir) and os.listdir(run.run_dir):
        raise ValueError(f"{run.run_dir} exists and is not a run of a sweep: give the sweep another --out")
    try:
        resume_from: str | None = latest_checkpoint(run.run_dir)
    except ValueError:  # no readable checkpoint: start over
        resume_from = None
        shutil.rmtree(run.run_dir, ignore_errors=True)  # a started run's logs, which the new start would append to
    os.makedirs(run.run_dir, exist_ok=True)
    record = {
        "seed": run.seed,
        "set": list(run.sets),
        "run_dir": run.run_dir,
        "options": options,
        "status": "running",
        "node": platform.node(),
        "resumed_from": resume_from,
    }
    _write_json(path, record)
    start = time.perf_counter()
    # A new run's directory holds only this sweep's record of it: overwrite what an earlier start left.
    directory = claim_run_directory(run.run_dir, resume=resume_from is not None, overwrite=resume_from is None)
    try:
        if resume_from is not None:  # the checkpoint holds the run's config
            trainer = Trainer.resume(
                run.run_dir, log_dir=run.run_dir, changes={"train": {"quiet": True} if config["train"]["quiet"] else {}}
            )
            print(
                f"aquarium-warp sweep: resumed {run.run_dir} at iteration {trainer.iteration} of "
                f"{trainer.total_iterations}"
            )
        else:
            trainer = Trainer(config, log_dir=run.run_dir)
        try:
            finish_training(trainer, print)
        finally:
            trainer.close()
    finally:
        directory.release()
    record.update(status="done", wall_s=round(time.perf_counter() - start, 2))
    _write_json(path, record)
    return dict(record, kept=False)


def run_training_sweep(sweep: TrainingSweep, train_args: argparse.Namespace, ray: RayOptions | None = None) -> dict:
    """Every run of `sweep` with `aquarium-warp train`'s options `train_args` (`train_run`, its config
    from `train_config` with the run's settings and seed), one after another here or each a Ray task.
    Writes and returns `<out>/sweep.json`."""
    from .cli import train_config

    sweep.validate()
    if train_args.resume is not None:
        raise ValueError("--resume: a sweep resumes its started runs itself; rerun it with the same --out")
    if train_args.seed is not None:
        raise ValueError("--seed: a sweep takes its seeds as --seeds")
    if train_args.log_dir is not None:
        raise ValueError("--log-dir: a sweep's runs go to --out/<setting>/seed<s>")
    if getattr(train_args, "overwrite", False):
        raise ValueError(
            "--overwrite: a sweep keeps its finished runs and resumes the started ones; give it "
            "another --out to start over"
        )
    if ray is not None:  # the tasks run on the GPU that Ray assigns them, or on the CPU
        ray, device = placement(ray, train_args.device)
    calls = []
    for run in sweep.runs():
        config = train_config(train_args, run.sets)
        config["train"]["seed"] = run.seed
        if ray is not None:
            config["train"]["device"] = device
        calls.append((run, config, run_options(train_args, run)))
    start = time.perf_counter()
    if ray is None:
        records = []
        for call in calls:
            records.append(train_run(*call))
            _report(records[-1])
    else:
        records = run_ray_tasks(train_run, calls, ray, on_result=lambda _, r: _report(r))
    summary = {
        "seeds": list(sweep.seeds),
        "vary": {key: list(values) for key, values in sweep.vary},
        "ray": None
        if ray is None
        else {
            "address": ray.address,
            "gpus_per_task": ray.gpus_per_task,
            "cpus_per_task": ray.cpus_per_task,
            "max_retries": ray.max_retries,
        },
        "wall_time_s": round(time.perf_counter() - start, 2),
        "runs": records,
    }
    os.makedirs(sweep.out, exist_ok=True)
    _write_json(os.path.join(sweep.out, "sweep.json"), summary)
    return summary


def _report(record: dict) -> None:
    how = "kept (finished before)" if record["kept"] else f"done in {record['wall_s']:.1f} s on {record['node']}"
    print(f"aquarium-warp sweep: {record['run_dir']} {how}", flush=True)


def _write_json(path: str, value: dict) -> None:
    with atomic_open(path) as f:
        json.dump(value, f, indent=1)


# ---------------------------------------------------------------------------------------------- command line
HELP = "one `aquarium-warp train` run per seed and setting"
DESCRIPTION = (
    "Train every combination of a seed (--seeds) and the varied settings (--vary) in a run directory of "
    "its own, --out/<setting>/seed<s>, one after another or as Ray tasks (--ray). A rerun with the same "
    "--out keeps the finished runs and resumes the started ones from their newest checkpoint. Every "
    "option of `aquarium-warp train` applies to each run (not --seed, --log-dir, --resume, --overwrite)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .cli import add_train_arguments

    p.add_argument("--seeds", default="0", help="seeds: a comma list, '...' continues it (default 0)")
    p.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="a setting to sweep, as `train --set KEY=VALUE` takes it, e.g. "
        "train.sharing=parameter,individual (repeatable: every combination)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="the sweep's directory: sweep.json and one directory per run "
        "(default runs/sweep_<time>; on Ray one that every machine sees)",
    )
    add_train_arguments(p)
    add_ray_arguments(p, "training run")


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp sweep train`: one training run per seed and setting."""
    from .cli import add_train_arguments

    train = argparse.ArgumentParser()
    add_train_arguments(train)
    train_args = argparse.Namespace(**{name: getattr(args, name) for name in vars(train.parse_args([]))})
    sweep = TrainingSweep(
        seeds=tuple(parse_list(args.seeds, int, "--seeds", minimum=0)),
        vary=tuple(parse_vary(text) for text in args.vary),
        out=args.out or os.path.join("runs", f"sweep_{time.strftime('%Y%m%d-%H%M%S')}"),
    )
    sweep.validate()
    ray = ray_options(args)
    print(
        f"aquarium-warp sweep train: {plural(len(sweep.runs()), 'run')} ({plural(len(sweep.seeds), 'seed')}"
        f"{''.join(f' x {len(v)} {k}' for k, v in sweep.vary)}) {'as Ray tasks' if ray else 'one after another'} "
        f"-> {sweep.out}"
    )
    summary = run_training_sweep(sweep, train_args, ray)
    kept = sum(r["kept"] for r in summary["runs"])
    print(
        f"aquarium-warp sweep train: {len(summary['runs'])} runs ({kept} kept from before) in "
        f"{summary['wall_time_s']:.1f} s; {os.path.join(sweep.out, 'sweep.json')} lists them"
    )
    return 0
