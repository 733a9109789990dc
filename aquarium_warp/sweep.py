"""Training sweeps: one `aquarium-warp train` run per seed and setting, one after another on this machine or
as Ray tasks (`aquarium_warp.ray_tasks`).

    aquarium-warp sweep train --seeds 0,1,2 --vary train.sharing=parameter,individual --out runs/grid \\
        [--ray [ADDRESS]] [any option of aquarium-warp train]

trains every combination of a seed and the varied settings (each an `aquarium-warp train --set KEY=VALUE`)
through `training.cli.run_train`, the function behind `aquarium-warp train`, in a directory of its own:
`<out>/seed<s>`, or `<out>/<KEY=VALUE_...>/seed<s>` with `--vary`. Each run directory holds
`sweep_run.json`, the run's options and status. A rerun of the sweep keeps the finished runs and resumes
a started one from its newest checkpoint (`Trainer.resume`), so a Ray task rerun after its worker died
continues from the last checkpoint rather than from the start. `<out>/sweep.json` lists the runs.
On Ray the workers write the run directories: give an `--out` that every machine of the cluster sees.
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

from .atomic import atomic_open
from .number_lists import parse_list
from .ray_tasks import RayOptions, placement, run_tasks

RUN_RECORD = "sweep_run.json"
# Train options that do not change what a run computes: a kept run is one whatever their values.
NOT_THE_RUN = ("device", "quiet", "log_dir", "resume", "overwrite")


def parse_vary(text: str) -> tuple[str, tuple[str, ...]]:
    """`"train.sharing=parameter,individual"` -> ("train.sharing", ("parameter", "individual")). Values
    are JSON or words (as in `--set`); commas inside [...] or {...} belong to the value."""
    key, sep, values = text.partition("=")
    parts = tuple(v.strip() for v in re.split(r",(?![^\[{]*[\]}])", values))
    if not sep or not key.strip() or not all(parts):
        raise ValueError(f"--vary {text!r}: expected KEY.PATH=VALUE,VALUE,... "
                         "(e.g. train.sharing=parameter,individual)")
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
        from .training.config import parse_assignment

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


def train_run(train_args: argparse.Namespace, run: TrainingRun) -> dict:
    """Train `run` in its directory with `aquarium-warp train`'s options `train_args`: kept if
    `sweep_run.json` says it finished, resumed from its newest checkpoint if it started, else from
    scratch. Returns the run's record (also in `sweep_run.json`). One sweep task, on Ray or here."""
    from .training.checkpoints import latest_checkpoint
    from .training.cli import add_train_arguments, run_train

    args = argparse.Namespace(**vars(train_args))
    args.seed, args.log_dir, args.set = run.seed, run.run_dir, list(train_args.set) + list(run.sets)
    options = json.loads(json.dumps({k: v for k, v in vars(args).items() if k not in NOT_THE_RUN}))
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
    if resume_from is not None:  # `train --resume`: the checkpoint holds the run's config
        parser = argparse.ArgumentParser()
        add_train_arguments(parser)
        args = parser.parse_args(["--resume", run.run_dir] + (["--quiet"] if args.quiet else []))
    else:
        args.overwrite = True  # the directory holds only this sweep's record of the run
    os.makedirs(run.run_dir, exist_ok=True)
    record = {"seed": run.seed, "set": list(run.sets), "run_dir": run.run_dir, "options": options,
              "status": "running", "node": platform.node(), "resumed_from": resume_from}
    _write_json(path, record)
    start = time.perf_counter()
    run_train(args)
    record.update(status="done", wall_s=round(time.perf_counter() - start, 2))
    _write_json(path, record)
    return dict(record, kept=False)


def run_training_sweep(sweep: TrainingSweep, train_args: argparse.Namespace, ray: RayOptions | None = None) -> dict:
    """Every run of `sweep` with `aquarium-warp train`'s options `train_args` (`train_run`), one after
    another here or each a Ray task. Writes and returns `<out>/sweep.json`."""
    sweep.validate()
    if train_args.resume is not None:
        raise ValueError("--resume: a sweep resumes its started runs itself; rerun it with the same --out")
    if train_args.seed is not None:
        raise ValueError("--seed: a sweep takes its seeds as --seeds")
    if train_args.log_dir is not None:
        raise ValueError("--log-dir: a sweep's runs go to --out/<setting>/seed<s>")
    if getattr(train_args, "overwrite", False):
        raise ValueError("--overwrite: a sweep keeps its finished runs and resumes the started ones; give it "
                         "another --out to start over")
    runs = sweep.runs()
    start = time.perf_counter()
    if ray is None:
        records = []
        for run in runs:
            records.append(train_run(train_args, run))
            _report(records[-1])
    else:
        ray, device = placement(ray, train_args.device)
        on_ray = argparse.Namespace(**dict(vars(train_args), device=device))
        records = run_tasks(train_run, [(on_ray, run) for run in runs], ray, on_result=lambda _, r: _report(r))
    summary = {"seeds": list(sweep.seeds), "vary": {key: list(values) for key, values in sweep.vary},
               "ray": None if ray is None else {"address": ray.address, "gpus_per_task": ray.gpus_per_task,
                                                 "cpus_per_task": ray.cpus_per_task, "max_retries": ray.max_retries},
               "wall_time_s": round(time.perf_counter() - start, 2), "runs": records}
    os.makedirs(sweep.out, exist_ok=True)
    _write_json(os.path.join(sweep.out, "sweep.json"), summary)
    return summary


def _report(record: dict) -> None:
    how = "kept (finished before)" if record["kept"] else f"done in {record['wall_s']:.1f} s on {record['node']}"
    print(f"aquarium-warp sweep: {record['run_dir']} {how}", flush=True)


def _write_json(path: str, value: dict) -> None:
    with atomic_open(path) as f:
        json.dump(value, f, indent=1)
