"""Is the fused path fit to be the CUDA default? The check declared in `benchmarks/fused_default.md`
(cells, measures, margins, decision), run in steps, each writing into `--out`:

- `train`: the four cells' runs (`runs/<cell>-s<seed>/`), each alone in its own worker process, `--per-gpu`
  at a time on each of `--gpus` cards (finished runs are kept: a rerun trains what is missing);
- `eval`: every policy in world B with the paper's spawn headings, 100 episodes x evaluation seeds 0, 1,
  2: `per_seed.csv` (the prey against NaivChase; the both-teams predators against TurnAway);
- `report`: per measure fused minus torch, Welch 95% interval against the margin, TOST, and the
  decision: `report.json`, printed.

    python benchmarks/fused_default.py --out runs/fused_default --gpus 4 --per-gpu 5
    python benchmarks/fused_default.py --out /tmp/fd --gpus 0 --seeds 0 1 --episodes 2 --eval-seeds 0 \\
        --set train.episodes=null --set train.iterations=2 --set train.num_worlds=4 --set env.max_steps=30 \\
        --max-steps 30    # a CPU smoke run
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.atomic import atomic_open
from aquarium_warp.records import command_line, provenance
from aquarium_warp.statistics import difference, equivalence, interval, interval_verdict

SEEDS = (0, 1, 2, 3, 4)
PATHS = {  # declared in fused_default.md
    "torch": ("train.fused_mlp=false", "train.tf32=false"),
    "fused": ("train.fused_mlp=true", "train.tf32=true"),
}
SETUPS = ("recipe", "both")
EPISODES, EVAL_SEEDS = 100, (0, 1, 2)
# measure -> (setup, what, margin, margin relative to the torch cell's mean)
MEASURES = {
    "E1": ("recipe", "prey_vs_naivchase", 0.20, False),
    "E2": ("both", "prey_vs_naivchase", 0.10, True),
    "E3": ("both", "predator_vs_turnaway", 0.10, True),
    "C1": ("recipe", "curve", 0.10, True),
    "C2": ("both", "curve", 0.10, True),
}
CURVE_FRACTION = 0.10  # the last 10% of iterations


def cell_config(setup: str, path: str, seed: int, sets: list[str]) -> dict:
    from aquarium_warp.training import make_config
    from aquarium_warp.training.config import deep_update, parse_assignment

    config = make_config("learned-prey-b")
    for assignment in PATHS[path] + tuple(sets):
        deep_update(config, parse_assignment(assignment))
    config["train"].update(seed=seed, quiet=True, export="jit")
    config["runner"]["save_interval"] = 500  # a checkpoint to continue from, not one per 50 iterations
    if setup == "both":
        config["train"].update(team="both", opponent=None)
    return config


def training_tasks(args) -> list[dict]:
    return [
        {
            "name": f"train-{setup}-{path}-s{seed}",
            "config": cell_config(setup, path, seed, args.set),
            "run_dir": str(Path(args.out) / "runs" / f"{setup}-{path}-s{seed}"),
        }
        for setup in SETUPS
        for path in PATHS
        for seed in args.seeds
    ]


def policy(run_dir: str, setup: str, team: str) -> str:
    return str(Path(run_dir) / "exported" / (team if setup == "both" else "") / "policy.pt")


def evaluate(args, trainings: list[dict], device: str) -> list[dict]:
    """Per run: its prey against NaivChase, and (both teams) its predator against TurnAway, in world B."""
    from aquarium_warp.training import make_config
    from aquarium_warp.training.config import env_config
    from aquarium_warp.training.evaluate import evaluate_policies

    env = env_config(make_config("learned-prey-b")).replace(spawn_heading="paper")
    if args.max_steps is not None:
        env = env.replace(max_steps=args.max_steps)
    rows = []
    for setup in SETUPS:
        for path in PATHS:
            runs = [t for t in trainings if f"-{setup}-{path}-" in t["name"]]
            for team, opponent, what in (("prey", "naivchase", "prey_vs_naivchase"),
                                         ("predator", "turnaway", "predator_vs_turnaway")):  # fmt: skip
                if team == "predator" and setup != "both":
                    continue
                specs = {f"s{s}={policy(t['run_dir'], setup, team)}": s for s, t in zip(args.seeds, runs, strict=True)}
                prey, predator = (list(specs), [opponent]) if team == "prey" else ([opponent], list(specs))
                result = evaluate_policies(prey, predator, env, args.episodes, args.eval_seeds, device)
                column = "prey_policy" if team == "prey" else "predator_policy"
                means = {r[column]: r["captures_per_prey_mean"] for r in result["summary"]}
                rows += [{"setup": setup, "path": path, "seed": s, "measure": what,
                          "value": means[spec.partition("=")[0]]} for spec, s in specs.items()]  # fmt: skip
    return rows


def curve_rows(args, trainings: list[dict]) -> list[dict]:
    """Per run: captures per prey in training, the mean over its last 10% of iterations (the prey team's curve
    where both learn)."""
    import numpy as np

    from aquarium_warp.training.plots import read_run_curve

    rows = []
    for t in trainings:
        setup, path, seed = t["name"].split("-")[1:]
        csv_path = str(Path(t["run_dir"]) / ("progress_prey.csv" if setup == "both" else "progress.csv"))
        curve = read_run_curve(csv_path)["captures_per_prey"]
        start = len(curve) - max(1, round(CURVE_FRACTION * len(curve)))
        value = float(np.nanmean(curve[start:])) if np.isfinite(curve[start:]).any() else math.nan
        rows.append({"setup": setup, "path": path, "seed": int(seed[1:]), "measure": "curve", "value": value})
    return rows


def report(args, rows: list[dict]) -> dict:
    def values(setup: str, path: str, what: str) -> list[float]:
        return [float(r["value"]) for r in rows if (r["setup"], r["path"], r["measure"]) == (setup, path, what)]

    out: dict = {"plan": "benchmarks/fused_default.md", "measures": {}}
    for name, (setup, what, margin, relative) in MEASURES.items():
        fused, torch_ = values(setup, "fused", what), values(setup, "torch", what)
        if relative:
            margin *= abs(interval(torch_)["mean"])
        d = difference(fused, torch_, confidence=0.95)
        verdict = interval_verdict(d, margin)
        out["measures"][name] = {"setup": setup, "measure": what, "margin": margin, "fused": interval(fused),
                                 "torch": interval(torch_), "difference_95": d,
                                 "tost": equivalence(fused, torch_, margin) if margin > 0 else None,
                                 "verdict": verdict}  # fmt: skip
    out["decision"] = (
        "fused path fit to be the CUDA default"
        if all(m["verdict"] == "equivalent" for m in out["measures"].values())
        else "the default stays torch's float32 path"
    )
    out["seeds"] = args.seeds
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--gpus", type=int, default=None, help="cards to train on (default: all; 0: the CPU)")
    p.add_argument("--per-gpu", type=int, default=5, help="trainings at a time on each card")
    p.add_argument("--steps", default="train,eval,report")
    p.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="training seeds of each cell")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config changes of every training")
    p.add_argument("--episodes", type=int, default=EPISODES, help="evaluation episodes per evaluation seed")
    p.add_argument("--eval-seeds", type=int, nargs="+", default=list(EVAL_SEEDS))
    p.add_argument("--max-steps", type=int, default=None, help="evaluation episode length (default: the world's)")
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    args = p.parse_args(argv)

    from aquarium_warp.jobs import run_jobs, task_devices
    from aquarium_warp.studies.common import run_training_task

    steps = args.steps.split(",")
    devices = task_devices(args.gpus)
    trainings = training_tasks(args)
    os.makedirs(args.out, exist_ok=True)
    start = time.perf_counter()
    if "train" in steps:
        jobs = args.per_gpu if devices[0] != "cpu" else 1
        run_jobs(run_training_task, trainings, args.out, jobs=jobs, devices=devices, label="train",
                 runs_per_process=1)  # fmt: skip
        print(f"trainings: {time.perf_counter() - start:.1f} s", flush=True)
    per_seed = Path(args.out) / "per_seed.csv"
    if "eval" in steps:
        begin = time.perf_counter()
        rows = evaluate(args, trainings, devices[0]) + curve_rows(args, trainings)
        with atomic_open(per_seed, newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["setup", "path", "seed", "measure", "value"])
            writer.writeheader()
            writer.writerows(rows)
        print(f"evaluation: {time.perf_counter() - begin:.1f} s", flush=True)
    if "report" in steps:
        with open(per_seed, newline="") as f:
            out = report(args, list(csv.DictReader(f)))
        out["wall_s"] = round(time.perf_counter() - start, 1)
        out.update(provenance(devices[0], command_line(sys.argv[1:], Path(sys.argv[0]).name), args.commit))
        with atomic_open(Path(args.out) / "report.json") as f:
            json.dump(out, f, indent=2)
        for name, m in out["measures"].items():
            d = m["difference_95"]
            p_value = m["tost"]["p"] if m["tost"] else math.nan
            print(f"{name} ({m['setup']}, {m['measure']}): fused {m['fused']['mean']:.3f}, torch "
                  f"{m['torch']['mean']:.3f}, fused - torch {d['difference']:+.3f} [{d['low']:+.3f}, "
                  f"{d['high']:+.3f}], margin {m['margin']:.3f}: {m['verdict']} (TOST p {p_value:.3g})")  # fmt: skip
        print(out["decision"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
