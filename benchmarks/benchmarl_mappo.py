"""A BenchMARL MAPPO run on the `aquarium/predator_prey` task: both teams learn (a group each, with
its own actor and critic), and the per-iteration mean episode reward of each group is written as a
curve. Needs the `[torchrl]` extra in its environment of its own (see the README).

    python benchmarks/benchmarl_mappo.py --device cuda:0 --worlds 256 --max-steps 500 --iterations 40

Writes `benchmarl_mappo_<device>.json` (the curve, settings, versions, wall time) into `--out-dir`
and, where matplotlib is installed, `benchmarl_mappo_<device>.png`.
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def reward_curves(save_folder: str) -> dict[str, list[tuple[int, float]]]:
    """`{group: [(iteration, mean episode reward), ...]}` from BenchMARL's CSV logger files."""
    curves = {}
    for path in glob.glob(
        os.path.join(save_folder, "**", "collection_*_reward_episode_reward_mean.csv"), recursive=True
    ):
        group = Path(path).name[len("collection_") : -len("_reward_episode_reward_mean.csv")]
        with open(path, newline="", encoding="utf-8") as f:
            curves[group] = [(int(float(row[0])), float(row[1])) for row in csv.reader(f) if row]
    return curves


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu", help="sampling and training device, e.g. cuda:0")
    p.add_argument("--worlds", type=int, default=64, help="worlds of one BatchedAquarium (BenchMARL's envs)")
    p.add_argument("--max-steps", type=int, default=200, help="episode length; one iteration collects worlds x steps")
    p.add_argument("--iterations", type=int, default=10, help="BenchMARL iterations")
    p.add_argument("--prey", type=int, default=16, help="prey per world")
    p.add_argument("--predators", type=int, default=2, help="predators per world")
    p.add_argument(
        "--epochs",
        type=int,
        default=5,
        help="passes over each iteration's frames (BenchMARL's on_policy_n_minibatch_iters; its default "
        "45 with 400-frame mini-batches makes 28,800 optimizer steps per 128,000 frames)",
    )
    p.add_argument("--minibatch-size", type=int, default=4096, help="frames per mini-batch")
    p.add_argument("--seed", type=int, default=0, help="experiment seed")
    p.add_argument("--out-dir", default=".", help="where the JSON (and plot) go")
    args = p.parse_args(argv)
    for name in ("worlds", "max_steps", "iterations", "prey", "predators", "epochs", "minibatch_size"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")

    warnings.simplefilter("ignore")
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    from aquarium_warp.interop.benchmarl import AquariumTask

    task = AquariumTask.PREDATOR_PREY.get_task(
        config={"max_steps": args.max_steps, "prey_count": args.prey, "predator_count": args.predators}
    )
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = args.device
    config.on_policy_n_envs_per_worker = args.worlds
    config.on_policy_collected_frames_per_batch = args.worlds * args.max_steps
    config.on_policy_n_minibatch_iters = args.epochs
    config.on_policy_minibatch_size = min(args.minibatch_size, args.worlds * args.max_steps)
    config.max_n_iters = args.iterations
    config.max_n_frames = args.iterations * config.on_policy_collected_frames_per_batch  # default 3e6 stops early
    config.evaluation = False
    config.loggers = ["csv"]
    config.checkpoint_at_end = False
    config.save_folder = tempfile.mkdtemp(prefix="benchmarl_")
    start = time.perf_counter()
    experiment = Experiment(
        task=task,
        algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=args.seed,
        config=config,
    )
    experiment.run()
    wall = time.perf_counter() - start
    curves = reward_curves(config.save_folder)

    import torch

    from aquarium_warp.records import command_line, git_info

    dev = torch.device(args.device)
    result = {
        "benchmark": "benchmarl_mappo",
        "task": "aquarium/predator_prey",
        "algorithm": "MAPPO (BenchMARL defaults)",
        "settings": vars(args),
        "frames": experiment.total_frames,
        "iterations": experiment.n_iters_performed,
        "wall_seconds": wall,
        "frames_per_second": experiment.total_frames / wall,
        "device_name": (
            torch.cuda.get_device_name(dev) if dev.type == "cuda" else platform.processor() or platform.machine()
        ),
        "versions": {name: _version(name) for name in ("torch", "torchrl", "tensordict", "benchmarl", "warp-lang")},
        "command": command_line(argv, Path(__file__).name),
        "git": git_info(),
        "curves": curves,
    }
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"benchmarl_mappo_{args.device.replace(':', '')}"
    (out / f"{stem}.json").write_text(json.dumps(result, indent=2))
    print(
        f"{experiment.n_iters_performed} iterations, {experiment.total_frames} frames in {wall:.1f} s; "
        f"wrote {out / (stem + '.json')}"
    )
    for group, points in curves.items():
        print(f"  {group}: mean episode reward {points[0][1]:.1f} -> {points[-1][1]:.1f}")
    try:
        plot(result, out / f"{stem}.png")
    except ImportError:
        pass
    return 0


def _version(distribution: str) -> str:
    """The installed version; the module's `__version__` where the package was copied in without metadata
    (warp on the lent GPU machines)."""
    from importlib import import_module
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return getattr(import_module(distribution.split("-")[0]), "__version__", "unknown")


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for group, points in sorted(result["curves"].items()):
        ax.plot([i for i, _ in points], [r for _, r in points], label=group)
    s = result["settings"]
    ax.set_xlabel("BenchMARL iteration")
    ax.set_ylabel("mean episode reward per agent")
    ax.set_title(
        f"BenchMARL MAPPO on aquarium/predator_prey\n{s['worlds']} worlds, {s['prey']} prey, "
        f"{s['predators']} predators, {result['device_name']}",
        fontsize=10,
    )
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
