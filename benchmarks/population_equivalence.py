"""Do a population's runs learn what the same runs learn alone? The check declared in
`benchmarks/population_equivalence.md` (cells, measure, margin), run in steps, each writing into `--out`:

- `population`: the learned-prey recipe in worlds A, B and C, seeds 0-4, as ONE population of 15 runs
  (`population/run-<k>`, run `5 w + s` world w's seed s), timed from its process's launch to its exit;
- `alone`: world B's seeds 0-4 as separate `aquarium-warp train` processes, `--per-gpu` at a time
  (`alone/s<k>`);
- `eval`: every policy against NaivChase in its own world (paper spawn headings), 100 episodes x
  evaluation seeds 0, 1, 2: `per_seed.csv`;
- `report`: the primary test (world B, population minus alone: Welch 95% interval against the margin,
  and TOST) and worlds A, B, C beside the committed numbers: `report.json`, printed.

    python benchmarks/population_equivalence.py --device cuda:0 --out runs/population_equivalence \\
        --set train.fused_mlp=true --set train.tf32=true
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.atomic import atomic_open
from aquarium_warp.records import command_line, provenance
from aquarium_warp.statistics import difference, equivalence, interval, interval_verdict

WORLDS = ("a", "b", "c")
SEEDS = (0, 1, 2, 3, 4)
MARGIN = 0.20  # captures per prey: declared in population_equivalence.md before any run
EVAL_SEEDS = (0, 1, 2)
EPISODES = 100
# benchmarks/results/learned_prey_ego/ (commit 885a0ca): the recipe alone, torch's float32 products
COMMITTED = {"a": (4.68, 0.15), "b": (1.54, 0.11), "c": (1.46, 0.05)}


def train_population(args) -> None:
    from aquarium_warp.training import make_config
    from aquarium_warp.training.config import deep_update, parse_assignment
    from aquarium_warp.training.population import Population

    configs = []
    for world in args.worlds:
        for seed in args.seeds:
            config = make_config(f"learned-prey-{world}")
            for s in args.set:
                deep_update(config, parse_assignment(s))
            config["train"].update(seed=seed, device=args.device, quiet=True)
            configs.append(config)
    population = Population(configs, log_dir=str(Path(args.out) / "population"))
    population.train()
    for k in range(population.K):
        population.export(k)
    population.close()


def train_alone(args) -> None:
    sets = [x for s in args.set for x in ("--set", s)]
    pending, running = list(args.seeds), []
    while pending or running:
        while pending and len(running) < args.per_gpu:
            seed = pending.pop(0)
            log_dir = str(Path(args.out) / "alone" / f"s{seed}")
            command = [sys.executable, "-m", "aquarium_warp", "train", "--preset", "learned-prey-b", "--seed",
                       str(seed), "--device", args.device, "--quiet", "--log-dir", log_dir, *sets]  # fmt: skip
            running.append(subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
        proc = running.pop(0)
        _, err = proc.communicate()
        if proc.returncode != 0:
            raise RuntimeError(f"a training alone failed: {err.strip()[-1500:]}")


def policies(out: Path, worlds: list[str], seeds: list[int]) -> list[dict]:
    """Every trained policy: cell, world, training seed, path (population run `len(seeds) w + i` is world
    w's i-th seed)."""
    found = [{"cell": "population", "world": w, "seed": s,
              "path": out / "population" / f"run-{len(seeds) * worlds.index(w) + i}" / "exported" / "policy.pt"}
             for w in worlds for i, s in enumerate(seeds)]  # fmt: skip
    found += [{"cell": "alone", "world": "b", "seed": s, "path": out / "alone" / f"s{s}" / "exported" / "policy.pt"}
              for s in seeds]  # fmt: skip
    return found


def evaluate(args) -> None:
    from aquarium_warp.training import make_config
    from aquarium_warp.training.config import env_config
    from aquarium_warp.training.evaluate import evaluate_policies

    rows = []
    for world in args.worlds:
        env = env_config(make_config(f"learned-prey-{world}")).replace(spawn_heading="paper")
        mine = [p for p in policies(Path(args.out), args.worlds, args.seeds) if p["world"] == world]
        specs = [f"{p['cell']}-s{p['seed']}={p['path']}" for p in mine]
        result = evaluate_policies(specs, "naivchase", env=env, episodes=EPISODES, seeds=EVAL_SEEDS, device=args.device)
        means = {r["prey_policy"]: r["captures_per_prey_mean"] for r in result["summary"]}
        for p in mine:
            rows.append({**{k: p[k] for k in ("cell", "world", "seed")},
                         "captures_per_prey": means[f"{p['cell']}-s{p['seed']}"]})  # fmt: skip
    with atomic_open(Path(args.out) / "per_seed.csv", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["cell", "world", "seed", "captures_per_prey"])
        writer.writeheader()
        writer.writerows(rows)


def report(args) -> dict:
    with open(Path(args.out) / "per_seed.csv", newline="") as f:
        rows = list(csv.DictReader(f))

    def values(cell: str, world: str) -> list[float]:
        return [float(r["captures_per_prey"]) for r in rows if r["cell"] == cell and r["world"] == world]

    population_b, alone_b = values("population", "b"), values("alone", "b")
    diff = difference(population_b, alone_b, confidence=0.95)
    tost = equivalence(population_b, alone_b, MARGIN)
    verdict = interval_verdict(diff, MARGIN)
    out = {
        "plan": "benchmarks/population_equivalence.md",
        "margin": MARGIN,
        "primary": {
            "population_b": population_b,
            "alone_b": alone_b,
            "difference_95": diff,
            "tost": tost,
            "verdict": verdict,
        },  # fmt: skip
        "worlds": {
            w: {"population": interval(values("population", w)), "committed_alone": COMMITTED[w]} for w in args.worlds
        },
        "seeds": args.seeds,
    }
    timing = Path(args.out) / "population_seconds.json"
    if timing.exists():
        out["population_wall"] = json.loads(timing.read_text())
    out.update(provenance(args.device, command_line(sys.argv[1:], Path(sys.argv[0]).name), args.commit))
    with atomic_open(Path(args.out) / "report.json") as f:
        json.dump(out, f, indent=2)
    print(f"world B, population - alone: {diff['difference']:+.3f} [{diff['low']:+.3f}, {diff['high']:+.3f}] "
          f"(95%), margin {MARGIN}: {verdict}; TOST p {tost['p']:.3g}")  # fmt: skip
    for w in args.worlds:
        got, (mean, half) = out["worlds"][w]["population"], COMMITTED[w]
        print(f"world {w.upper()}: population {got['mean']:.2f} ± {got['ci95']:.2f}, committed alone "
              f"{mean:.2f} ± {half:.2f}")  # fmt: skip
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--out", required=True)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config changes of every training")
    p.add_argument("--steps", default="population,alone,eval,report")
    p.add_argument("--per-gpu", type=int, default=3, help="separate trainings at a time (alone)")
    p.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="training seeds of each cell")
    p.add_argument("--worlds", nargs="+", default=list(WORLDS), choices=WORLDS, help="the population's worlds")
    p.add_argument("--commit", default=None, help="commit to record where git is not available")
    args = p.parse_args(argv)
    steps = args.steps.split(",")
    os.makedirs(args.out, exist_ok=True)
    if steps == ["population-child"]:  # the population's own process, timed by its parent
        train_population(args)
        return 0
    if "population" in steps:
        start = time.perf_counter()
        child = [sys.executable, __file__, "--steps", "population-child", "--device", args.device, "--out", args.out,
                 "--seeds", *map(str, args.seeds), "--worlds", *args.worlds,
                 *[x for s in args.set for x in ("--set", s)]]  # fmt: skip
        done = subprocess.run(child, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if done.returncode != 0:
            raise RuntimeError(f"the population failed: {done.stderr.strip()[-2000:]}")
        runs = len(args.seeds) * len(args.worlds)
        (Path(args.out) / "population_seconds.json").write_text(json.dumps({"runs": runs, "seconds": seconds}))
        print(f"population of {runs} runs: {seconds:.1f} s from launch to exit", flush=True)
    if "alone" in steps:
        start = time.perf_counter()
        train_alone(args)
        print(
            f"{len(args.seeds)} runs alone, {args.per_gpu} at a time: {time.perf_counter() - start:.1f} s", flush=True
        )
    if "eval" in steps:
        start = time.perf_counter()
        evaluate(args)
        print(f"evaluation: {time.perf_counter() - start:.1f} s", flush=True)
    if "report" in steps:
        report(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
