"""CPU speed of two source trees, alternating, in one run: the mean `BatchedAquarium.step()` time of 64
default worlds (random actions, after a warm-up) and the time of a short PPO training (the `tiny`
preset, 6 iterations), each in a child process whose `PYTHONPATH` holds one tree's staged package
(`aquarium_warp/` with `kernels/` and `training/` inside, as installed). Each tree compiles its kernels
in an untimed first child. Issue 29 used it for the refactor's before/after check:

    git worktree add --detach /tmp/before 9959373
    python benchmarks/refactor_speed_cpu.py --before /tmp/before --after . --reps 5 \
        --out benchmarks/results/refactor_speed/cpu.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

CHILD = r"""
import json, os, time
import torch
torch.set_num_threads(1)  # one thread: less sensitive to a busy machine, the same for both trees
from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.training.config import make_config
from aquarium_warp.training.trainer import Trainer
cfg = AquariumConfig()
env = BatchedAquarium(cfg, num_worlds=64, device="cpu", seed=0)
env.reset()
g = torch.Generator().manual_seed(0)
actions = {"prey": torch.randint(0, cfg.action_count, (64, env.prey_capacity), generator=g),
           "predator": torch.randint(0, cfg.action_count, (64, 1), generator=g)}
for _ in range(50):
    env.step(actions)
start = time.perf_counter()
for _ in range(1000):
    env.step(actions)
step_ms = (time.perf_counter() - start)  # 1000 steps: the total in s is the mean in ms
env.close()
import tempfile
trainer = Trainer(make_config("tiny", {"train": {"device": "cpu", "iterations": 6, "quiet": True, "export": []}}),
                  log_dir=tempfile.mkdtemp())
start = time.perf_counter()
trainer.train()
print(json.dumps({"step_ms": step_ms, "train_s": time.perf_counter() - start}))
"""


def stage(tree: str, where: str) -> str:
    """`tree`'s package as installed (`aquarium_warp` holding `kernels` and `training`) under `where`."""
    package = os.path.join(where, "aquarium_warp")
    skip = shutil.ignore_patterns("__pycache__")
    shutil.copytree(os.path.join(tree, "aquarium_warp"), package, ignore=skip)
    for sub in ("kernels", "training"):
        shutil.copytree(os.path.join(tree, sub), os.path.join(package, sub), ignore=skip)
    return where


def measure(path: str) -> dict:
    env = dict(os.environ, PYTHONPATH=path, GIT_PYTHON_REFRESH="quiet")
    run = subprocess.run(
        [sys.executable, "-c", CHILD], cwd=tempfile.gettempdir(), env=env, capture_output=True, text=True
    )
    lines = [line for line in run.stdout.splitlines() if line.startswith("{")]
    if run.returncode or not lines:
        raise RuntimeError(f"the child for {path} failed: {run.stderr[-2000:]}")
    return json.loads(lines[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="source tree measured first in each round")
    parser.add_argument("--after", required=True, help="source tree measured second in each round")
    parser.add_argument("--reps", type=int, default=5, help="rounds (each tree once per round)")
    parser.add_argument("--out", default=None, help="JSON to write")
    args = parser.parse_args(argv)
    if args.reps < 1:
        raise SystemExit(f"--reps={args.reps} must be >= 1")
    work = tempfile.mkdtemp()
    trees = {
        "before": stage(args.before, os.path.join(work, "before")),
        "after": stage(args.after, os.path.join(work, "after")),
    }
    # The staged tree, not the source: a source tree holds `kernels/` beside `aquarium_warp/`, not in it.
    sys.path.insert(0, trees["after"])
    from aquarium_warp.atomic import atomic_open
    from aquarium_warp.records import command_line, git_info, machine_info

    for path in trees.values():
        measure(path)  # compiles the tree's kernels (untimed)
    runs: dict[str, list[dict]] = {name: [] for name in trees}
    for _ in range(args.reps):
        for name, path in trees.items():
            runs[name].append(measure(path))
            print(name, runs[name][-1], flush=True)
    keys = ("step_ms", "train_s")
    medians = {name: {k: statistics.median(r[k] for r in rs) for k in keys} for name, rs in runs.items()}
    # The fastest round: on a shared machine, the least disturbed one (the median is given beside it).
    minima = {name: {k: min(r[k] for r in rs) for k in keys} for name, rs in runs.items()}
    result = {
        "runs": runs,
        "medians": medians,
        "minima": minima,
        "after_over_before": {k: medians["after"][k] / medians["before"][k] for k in keys},
        "after_over_before_minima": {k: minima["after"][k] / minima["before"][k] for k in keys},
        # Each tree's checkout, read from git (the staged copies that ran have none).
        "commits": {name: git_info(repository=path) for name, path in (("before", args.before), ("after", args.after))},
        "command": command_line(),
        "git": git_info(repository=args.after),
        "machine": machine_info("cpu"),
    }
    print(
        json.dumps({key: result[key] for key in ("medians", "minima", "after_over_before", "after_over_before_minima")})
    )
    if args.out:  # written whole or not at all
        with atomic_open(args.out) as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
