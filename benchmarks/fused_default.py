"""Is the fused path fit to be the CUDA default? The checks declared in `benchmarks/fused_default.md`
(`--plan first`) and `benchmarks/fused_default_followup.md` (`--plan followup`: both teams, new seeds, a
third path with float32 products) (cells, measures, margins, decision), run in steps, each writing into
`--out`:

- `train`: the plan's cells' runs (`runs/<cell>-s<seed>/`), each alone in its own worker process, `--per-gpu`
  at a time on each of `--gpus` cards (finished runs are kept: a rerun trains what is missing);
- `eval`: every policy in world B with the paper's spawn headings, 100 episodes x evaluation seeds 0, 1,
  2: `per_seed.csv` (the prey against NaivChase; the both-teams predators against TurnAway);
- `report`: per measure each candidate path minus torch, Welch 95% interval against the margin, TOST
  (the follow-up also pooled with the first check's seeds, `--prior`), and the decision: `report.json`,
  printed.

    python benchmarks/fused_default.py --out runs/fused_default --gpus 4 --per-gpu 5
    python benchmarks/fused_default.py --plan followup --out runs/followup --gpus 4 --per-gpu 8 \\
        --prior benchmarks/results/fused_default_h200x4_36f30d5/per_seed.csv
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

PATHS = {  # declared in fused_default.md (the follow-up adds fused_fp32)
    "torch": ("train.fused_mlp=false", "train.tf32=false"),
    "fused": ("train.fused_mlp=true", "train.tf32=true"),
    "fused_fp32": ("train.fused_mlp=true", "train.tf32=false"),
}
# plan -> its declaration, setups, paths (torch first, then the candidates) and training seeds
PLANS = {
    "first": ("benchmarks/fused_default.md", ("recipe", "both"), ("torch", "fused"), (0, 1, 2, 3, 4)),
    "followup": (
        "benchmarks/fused_default_followup.md",
        ("both",),
        ("torch", "fused_fp32", "fused"),
        tuple(range(5, 15)),
    ),
}
EPISODES, EVAL_SEEDS = 100, (0, 1, 2)
# measure -> (setup, what, margin, margin relative to the torch cell's mean)
MEASURES = {
    "E1": ("recipe", "prey_vs_naivchase", 0.20, False),
    "E2": ("both", "prey_vs_naivchase", 0.10, True),
    "E3": ("both", "predator_vs_turnaway", 0.10, True),
    "C1": ("recipe", "curve", 0.10, True),
    "C2": ("both", "curve", 0.10, True),
}
FOLLOWUP_MEASURES = ("E2", "E3", "C2")
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
    _, setups, paths, _ = PLANS[args.plan]
    return [
        {
            "name": f"train-{setup}-{path}-s{seed}",
            "config": cell_config(setup, path, seed, args.set),
            "run_dir": str(Path(args.out) / "runs" / f"{setup}-{path}-s{seed}"),
        }
        for setup in setups
        for path in paths
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
    _, setups, paths, _ = PLANS[args.plan]
    rows = []
    for setup in setups:
        for path in paths:
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


def compare(rows: list[dict], measure: str, candidate: str) -> dict:
    """`candidate` minus torch on `measure` (`MEASURES`: its setup, margin, and whether the margin is a
    fraction of torch's mean): Welch's 95% interval against the margin, its verdict and TOST."""
    setup, what, margin, relative = MEASURES[measure]

    def values(path: str) -> list[float]:
        return [float(r["value"]) for r in rows if (r["setup"], r["path"], r["measure"]) == (setup, path, what)]

    cand, ref = values(candidate), values("torch")
    if relative:
        margin *= abs(interval(ref)["mean"])
    d = difference(cand, ref, confidence=0.95)
    tost = equivalence(cand, ref, margin) if margin > 0 else None
    return {"setup": setup, "measure": what, "margin": margin, candidate: interval(cand), "torch": interval(ref),
            "difference_95": d, "tost": tost, "verdict": interval_verdict(d, margin)}  # fmt: skip


def report(args, rows: list[dict]) -> dict:
    """The first check's comparisons (`fused_default.md`) and its all-or-nothing decision."""
    out: dict = {"plan": PLANS["first"][0], "measures": {name: compare(rows, name, "fused") for name in MEASURES}}
    out["decision"] = (
        "fused path fit to be the CUDA default"
        if all(m["verdict"] == "equivalent" for m in out["measures"].values())
        else "the default stays torch's float32 path"
    )
    out["seeds"] = args.seeds
    return out


def report_followup(args, rows: list[dict], prior: list[dict]) -> dict:
    """The follow-up's comparisons (`fused_default_followup.md`): each candidate against torch on the new
    seeds, `fused` also pooled with the first check's `prior` rows, and the declared decision."""
    out: dict = {"plan": PLANS["followup"][0], "candidates": {}, "pooled": {}}
    both = [r for r in prior if r["setup"] == "both"]
    for name in FOLLOWUP_MEASURES:
        for candidate in ("fused", "fused_fp32"):
            out["candidates"].setdefault(candidate, {})[name] = compare(rows, name, candidate)
        out["pooled"][name] = compare(rows + both, name, "fused")

    def all_equivalent(measures: dict) -> bool:
        return all(m["verdict"] == "equivalent" for m in measures.values())

    if all_equivalent(out["candidates"]["fused"]) and all_equivalent(out["pooled"]):
        out["decision"] = "the fused path with TF32 products becomes the CUDA default"
    elif all_equivalent(out["candidates"]["fused_fp32"]):
        out["decision"] = "the fused path with float32 products becomes the CUDA default"
    else:
        out["decision"] = "the default stays torch's float32 path"
    out["seeds"] = args.seeds
    out["prior_seeds"] = sorted({int(r["seed"]) for r in both})
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--plan", choices=tuple(PLANS), default="first", help="the declared check to run")
    p.add_argument("--prior", default=None, help="the first check's per_seed.csv (the follow-up's pooled test)")
    p.add_argument("--gpus", type=int, default=None, help="cards to train on (default: all; 0: the CPU)")
    p.add_argument("--per-gpu", type=int, default=5, help="trainings at a time on each card")
    p.add_argument("--steps", default="train,eval,report")
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="training seeds per cell (default: the plan's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config changes of every training")
    p.add_argument("--episodes", type=int, default=EPISODES, help="evaluation episodes per evaluation seed")
    p.add_argument("--eval-seeds", type=int, nargs="+", default=list(EVAL_SEEDS))
    p.add_argument("--max-steps", type=int, default=None, help="evaluation episode length (default: the world's)")
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    args = p.parse_args(argv)
    if args.seeds is None:
        args.seeds = list(PLANS[args.plan][3])
    if args.plan == "followup" and "report" in args.steps.split(",") and args.prior is None:
        p.error("--plan followup's report needs --prior (the first check's per_seed.csv)")
    if "report" in args.steps.split(",") and len(set(args.seeds)) < 2:
        p.error(f"--seeds {args.seeds}: the report compares at least 2 distinct training seeds per cell")
    if args.prior is not None and not os.path.isfile(args.prior):
        p.error(f"--prior {args.prior!r} is not a file (the first check's per_seed.csv)")
    # One plan per --out: the plans write the same per_seed.csv and report.json.
    marker = Path(args.out) / "plan.txt"
    if marker.is_file() and marker.read_text().strip() != args.plan:
        p.error(f"--out {args.out!r} holds the {marker.read_text().strip()!r} plan's runs: give another folder")

    from aquarium_warp.jobs import run_jobs, task_devices
    from aquarium_warp.studies.common import run_training_task

    steps = args.steps.split(",")
    devices = task_devices(args.gpus)
    trainings = training_tasks(args)
    os.makedirs(args.out, exist_ok=True)
    marker.write_text(args.plan + "\n")
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
            rows = list(csv.DictReader(f))
        if args.plan == "followup":
            with open(args.prior, newline="") as f:
                out = report_followup(args, rows, list(csv.DictReader(f)))
        else:
            out = report(args, rows)
        out["wall_s"] = round(time.perf_counter() - start, 1)
        out.update(provenance(devices[0], command_line(sys.argv[1:], Path(sys.argv[0]).name), args.commit))
        with atomic_open(Path(args.out) / "report.json") as f:
            json.dump(out, f, indent=2)
        tables = ({"fused": out["measures"]} if args.plan == "first"
                  else {**out["candidates"], "fused, pooled": out["pooled"]})  # fmt: skip
        for label, measures in tables.items():
            candidate = label.split(",")[0]
            for name, m in measures.items():
                d = m["difference_95"]
                p_value = m["tost"]["p"] if m["tost"] else math.nan
                print(f"{name} ({m['setup']}, {m['measure']}) {label}: {m[candidate]['mean']:.3f}, torch "
                      f"{m['torch']['mean']:.3f}, difference {d['difference']:+.3f} [{d['low']:+.3f}, "
                      f"{d['high']:+.3f}], margin {m['margin']:.3f}: {m['verdict']} "
                      f"(TOST p {p_value:.3g})")  # fmt: skip
        print(out["decision"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
