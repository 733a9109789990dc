"""Co-evolution on one GPU: both teams learn (`aquarium-warp train --team both`), with an opponent pool,
for at least 1e9 agent-steps; then a cross-play matrix over the run's checkpoints, the swarm metrics
along training, one video, and the end-to-end speed of the two-learner path against the one-team path.

    python benchmarks/coevolution.py --device cuda:0 --out-dir benchmarks/results/coevolution_h100
    python benchmarks/coevolution.py --tiny --out-dir /tmp/coevolution_tiny          # CPU, about a minute

The run (defaults): 4096 worlds of 32 prey and 4 predators in docs/model.md's 800 x 800 px world, 500-step
episodes, both teams Parameter Sharing with the trainer's default PPO (two tanh layers of 64, 32 steps
x 4096 worlds per iteration, 5 epochs x 4 mini-batches), simultaneous updates, an opponent pool
(a snapshot of each team every 20 iterations, 4 kept, uniform; each team plays the other's snapshots
in 20% of the worlds). Agent-steps count every simulated agent (both teams learn): worlds x 36 x
steps; the iterations are the fewest that reach `--agent-steps`.

Steps:
1. speed: `--speed-iterations` timed iterations (after 2 untimed ones: warm-up and graph capture) of
   the same world with (a) one team learning (prey against NaivChase predators, the paper's setting),
   (b) both teams learning, (c) both teams with the pool, each in a process of its own; agent-steps/s
   of all agents and of the learning rows;
2. the co-evolution run, checkpoints every `iterations / --generations` iterations (`run/`);
3. cross-play (`aquarium_warp.training.cross_play.cross_play`): every prey generation (and Random,
   TurnAway) against every predator generation (and Random, NaivChase), `--eval-episodes` x
   `--eval-seeds`; each generation against the previous one;
4. one video (`episode.gif`, and its last frame `episode.png`) of the final policies;
5. training curves of both teams and the swarm metrics along training (`training_curves.png`).

Writes `summary.json`, `speed.csv`, `cross_play.csv/json`, `generations.csv`, `training_curves.csv`,
the figures and the GIF into `--out-dir`, and prints a compact summary. The checkpoints are deleted at
the end unless `--keep-checkpoints` (about 10 MB each at the default size).
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.records import command_line, git_info, machine_info
from aquarium_warp.training import Trainer, make_config
from aquarium_warp.training.config import env_config
from aquarium_warp.training.cross_play import cross_play, write_cross_play
from aquarium_warp.training.episode_video import EpisodeVideo, gif_bytes
from aquarium_warp.training.plots import plot_cross_play

SWARM = ("polarization", "groups", "cohesion", "nn_mean")


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def settings(args) -> dict:
    """The run config's changes for the co-evolution run (without the team)."""
    return {
        "env": {
            "prey_count": args.prey,
            "predator_count": args.predators,
            "max_steps": args.max_steps,
            **({"width": 400.0, "height": 400.0} if args.tiny else {}),
        },
        "train": {
            "num_worlds": args.worlds,
            "device": args.device,
            "seed": args.seed,
            "quiet": True,
            "export": ["jit"],
            "metrics_every": 10,
        },
        "runner": {"num_steps_per_env": args.steps},
    }


def pool_settings(args) -> dict:
    return {"train": {"pool_every": args.pool_every, "pool_size": args.pool_size, "pool_fraction": args.pool_fraction}}


def speed_paths(args) -> dict[str, tuple[str, list[dict]]]:
    """The paths whose speed is compared: `{key: (name, config changes)}`, same world for all."""
    both = {"train": {"team": "both"}}
    return {
        "one": ("one team (prey vs NaivChase)", [{"train": {"team": "prey", "opponent": "naivchase"}}]),
        "both": ("both teams", [both]),
        "pool": ("both teams + pool", [both, pool_settings(args)]),
    }


def measure_speed_in_subprocess(key: str, argv: list[str]) -> dict:
    """`measure_speed` of one path in a process of its own: several graph-capturing trainers built one
    after another in one process once failed a capture (training/README.md), and each process frees
    its graphs' memory when it ends."""
    done = subprocess.run([sys.executable, __file__, *argv, "--speed-path", key], capture_output=True, text=True)
    lines = [line for line in done.stdout.splitlines() if line.startswith("SPEED ")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"speed of {key!r} failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
    return json.loads(lines[-1][len("SPEED ") :])


def _number(text: str):
    """A CSV cell as the number it was written from (the text where it is not one)."""
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def measure_speed(args, name: str, *changes: dict) -> dict:
    """Agent-steps per second of `--speed-iterations` iterations after 2 untimed ones."""
    config = make_config("default", settings(args), *changes)
    trainer = Trainer(config)
    device = trainer.device
    trainer.train(2)
    sync(device)
    start = time.perf_counter()
    trainer.train(args.speed_iterations)
    sync(device)
    seconds = time.perf_counter() - start
    steps = args.steps * args.speed_iterations
    agents = trainer.env.num_worlds * (args.prey + args.predators)
    rows = sum(v.num_envs for v in trainer.vec_envs.values())
    point = {
        "path": name,
        "teams": "+".join(trainer.teams),
        "graphs": bool(trainer.runner.loop.graphs),
        "iterations": args.speed_iterations,
        "seconds": seconds,
        "agent_steps_per_s": agents * steps / seconds,
        "learning_rows_per_s": rows * steps / seconds,
    }
    trainer.close()
    return point


def read_scalars(run_dir: str) -> dict[str, list[tuple[int, float]]]:
    """Every TensorBoard scalar of a run: `{tag: [(iteration, value), ...]}`."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(run_dir, size_guidance={"scalars": 0}).Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def plot_curves(scalars: dict, steps_per_iteration: int, path: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [
        ("captures per prey per episode", ["prey/Episode/captures_per_prey"]),
        ("reward per agent per episode", ["prey/Episode/reward_per_agent", "predator/Episode/reward_per_agent"]),
        ("polarization", ["Swarm/polarization"]),
        ("groups", ["Swarm/groups"]),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4))
    for ax, (title, tags) in zip(axes, panels):
        for tag in tags:
            if tag in scalars:
                x, y = zip(*scalars[tag])
                ax.plot((np.array(x) + 1) * steps_per_iteration, y, label=tag.split("/")[0] if len(tags) > 1 else None)
        ax.set_title(title)
        ax.set_xlabel("agent-steps")
        if len(tags) > 1:
            ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def generations_table(result: dict) -> list[dict]:
    """Each generation against the previous one, from the captures matrix: did the new prey get caught
    less by the previous predators, and do the new predators catch more of the previous prey?"""
    cp = result["cross_play"]
    captures = np.array(cp["matrices"]["captures_per_prey"]["mean"])
    prey = [p for p in cp["prey"] if p.startswith("gen")]
    predator = [p for p in cp["predator"] if p.startswith("gen")]
    rows = []
    for g in range(1, len(prey)):
        i, j = cp["prey"].index(prey[g]), cp["predator"].index(predator[g])
        i0, j0 = cp["prey"].index(prey[g - 1]), cp["predator"].index(predator[g - 1])
        rows.append(
            {
                "generation": prey[g],
                "previous": prey[g - 1],
                "previous_vs_previous": captures[i0, j0],
                "new_prey_vs_previous_predators": captures[i, j0],
                "previous_prey_vs_new_predators": captures[i0, j],
                "new_vs_new": captures[i, j],
                "prey_improved": bool(captures[i, j0] < captures[i0, j0]),
                "predators_improved": bool(captures[i0, j] > captures[i0, j0]),
            }
        )
    return rows


def write_csv(rows: list[dict], path: str) -> str:
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--device", default=None, help="'cuda:0' (default when present) or 'cpu'")
    p.add_argument("--out-dir", default="coevolution_results", help="output folder")
    p.add_argument("--tiny", action="store_true", help="a CPU-sized run of every step (400 x 400 px, 16 worlds)")
    p.add_argument("--worlds", type=int, default=None, help="worlds (default 4096; tiny 16)")
    p.add_argument("--prey", type=int, default=None, help="prey per world (default 32; tiny 8)")
    p.add_argument("--predators", type=int, default=None, help="predators per world (default 4; tiny 2)")
    p.add_argument("--max-steps", type=int, default=None, help="episode length (default 500; tiny 100)")
    p.add_argument("--steps", type=int, default=32, help="rollout steps per iteration")
    p.add_argument("--agent-steps", type=float, default=None, help="agent-steps of the run (default 1e9; tiny 2e5)")
    p.add_argument("--generations", type=int, default=None, help="checkpoints compared (default 6; tiny 3)")
    p.add_argument("--pool-every", type=int, default=None, help="pool snapshot interval (default 20; tiny 2)")
    p.add_argument("--pool-size", type=int, default=4, help="snapshots kept per team")
    p.add_argument("--pool-fraction", type=float, default=0.2, help="worlds per team against the other's snapshots")
    p.add_argument(
        "--speed-iterations", type=int, default=None, help="timed iterations per speed point (default 10; tiny 2)"
    )
    p.add_argument("--eval-episodes", type=int, default=None, help="cross-play episodes per seed (default 64; tiny 4)")
    p.add_argument("--eval-seeds", type=int, nargs="+", default=[0, 1], help="cross-play seeds")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--keep-checkpoints", action="store_true", help="keep run/model_*.pt")
    p.add_argument("--speed-only", action="store_true", help="measure step 1 only and write speed.csv")
    p.add_argument(
        "--speed-from",
        default=None,
        help="a speed.csv written earlier (same settings): step 1 reads it instead of measuring, so the "
        "speed points and the run can go in separate calls of a time-limited machine",
    )
    p.add_argument(
        "--speed-path",
        choices=("one", "both", "pool"),
        default=None,
        help="(internal) measure the speed of one path and print it as JSON",
    )
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    defaults = dict(
        worlds=(16, 4096),
        prey=(8, 32),
        predators=(2, 4),
        max_steps=(100, 500),
        agent_steps=(2e5, 1e9),
        generations=(3, 6),
        pool_every=(2, 20),
        speed_iterations=(2, 10),
        eval_episodes=(4, 64),
    )
    for name, (tiny, full) in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, tiny if args.tiny else full)
    if args.tiny and args.device is None:
        args.device = "cpu"
    if args.device == "cpu":
        torch.set_num_threads(1)  # the small networks run fastest on one thread (as in the tests)
    if args.speed_path is not None:
        name, changes = speed_paths(args)[args.speed_path]
        print("SPEED " + json.dumps(measure_speed(args, name, *changes)))
        return 0
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run_dir = str(out / "run")
    agents = args.prey + args.predators
    iterations = math.ceil(args.agent_steps / (args.worlds * agents * args.steps))
    save_every = max(1, iterations // args.generations)
    started = time.perf_counter()
    print(
        f"coevolution: {args.worlds} worlds x ({args.prey} prey + {args.predators} predators), "
        f"{iterations} iterations of {args.steps} steps = {iterations * args.worlds * agents * args.steps:.3g} "
        f"agent-steps, device {args.device or 'default'}",
        flush=True,
    )

    # 1. speed of the one-team path against the two-learner path, same world
    if args.speed_from:
        with open(args.speed_from, newline="", encoding="utf-8") as f:
            speed = [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(f)]
    else:
        speed = [
            measure_speed_in_subprocess(key, [a for a in argv if a != "--speed-only"])
            for key in ("one", "both", "pool")
        ]
    for point in speed:
        print(
            f"  speed {point['path']:>30}: {point['agent_steps_per_s']:.3g} agent-steps/s "
            f"({point['learning_rows_per_s']:.3g} learning rows/s)",
            flush=True,
        )

    if args.speed_only:
        write_csv(speed, str(out / "speed.csv"))
        return 0

    # 2. the co-evolution run
    config = make_config(
        "default",
        settings(args),
        pool_settings(args),
        {"train": {"team": "both", "iterations": iterations}, "runner": {"save_interval": save_every}},
    )
    trainer = Trainer(config, run_dir)
    device = trainer.device
    start = time.perf_counter()
    trainer.train()
    sync(device)
    train_seconds = time.perf_counter() - start
    trainer.export()
    print(
        f"  trained {iterations} iterations in {train_seconds:.1f} s "
        f"({iterations * args.worlds * agents * args.steps / train_seconds:.3g} agent-steps/s)",
        flush=True,
    )

    # 4. one video of the final policies (rendered before the trainer goes)
    video = EpisodeVideo(env_config(config), device, args.seed, steps=min(300, args.max_steps))
    frames = video.record(trainer.video_drivers)
    video.close()
    (out / "episode.gif").write_bytes(gif_bytes(frames, video.fps))
    from aquarium_warp.render import save_png

    save_png(frames[-1], str(out / "episode.png"))
    trainer.close()
    del trainer

    # 3. cross-play over the generations (checkpoints), with the heuristics as anchors
    checkpoints = sorted(
        glob.glob(os.path.join(run_dir, "model_*.pt")), key=lambda path: int(Path(path).stem.split("_")[1])
    )
    picks = np.unique(np.linspace(0, len(checkpoints) - 1, args.generations).round().astype(int))
    chosen = [checkpoints[i] for i in picks]  # evenly spaced, the first and the last included
    gens = [f"gen{Path(c).stem.split('_')[1]}={c}" for c in chosen]
    start = time.perf_counter()
    result = cross_play(
        ["random", "turnaway"] + gens,
        gens + ["random", "naivchase"],
        env_config(config),
        episodes=args.eval_episodes,
        seeds=args.eval_seeds,
        device=args.device,
        max_worlds=args.eval_episodes,
    )
    cross_seconds = time.perf_counter() - start
    write_cross_play(result, str(out))
    for metric in ("captures_per_prey", "prey_survival"):
        plot_cross_play(result, str(out / f"cross_play_{metric}.png"), metric)
    generations = generations_table(result)
    if generations:
        write_csv(generations, str(out / "generations.csv"))

    # 5. curves: both teams' episode statistics and the swarm metrics along training
    scalars = read_scalars(run_dir)
    steps_per_iteration = args.worlds * agents * args.steps
    plot_curves(scalars, steps_per_iteration, str(out / "training_curves.png"))
    curve_tags = [t for t in scalars if t.startswith(("prey/Episode", "predator/Episode", "Swarm/"))]
    rows = {}
    for tag in curve_tags:
        for it, value in scalars[tag]:
            rows.setdefault(it, {"iteration": it, "agent_steps": (it + 1) * steps_per_iteration})[tag] = value
    if rows:
        with open(out / "training_curves.csv", "w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=["iteration", "agent_steps"] + curve_tags)
            writer.writeheader()
            writer.writerows([rows[k] for k in sorted(rows)])
    write_csv(speed, str(out / "speed.csv"))
    if not args.keep_checkpoints:
        for path in checkpoints:
            os.remove(path)

    def first_last(tag):
        values = scalars.get(tag, [])
        return (values[0][1], values[-1][1]) if values else (float("nan"), float("nan"))

    one, two = speed[0]["agent_steps_per_s"], speed[2]["agent_steps_per_s"]
    summary = {
        "settings": {**vars(args), "iterations": iterations, "save_every": save_every, "command": command_line()},
        "git": git_info(),
        "device": str(device),
        "machine": machine_info(str(device)),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor(),
        "agent_steps": iterations * steps_per_iteration,
        "train_seconds": train_seconds,
        "train_agent_steps_per_s": iterations * steps_per_iteration / train_seconds,
        "speed": speed,
        "two_learner_over_one_team": two / one,
        "cross_play_seconds": cross_seconds,
        "cross_play": result["cross_play"],
        "rating": result.get("rating"),
        "generations": generations,
        "swarm_first_last": {name: first_last(f"Swarm/{name}") for name in SWARM},
        "total_seconds": time.perf_counter() - started,
    }
    with open(out / "summary.json", "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=1, default=float)

    # the compact summary
    print(f"\n{'agent-steps':>12} {'train s':>8} {'agent-steps/s':>14} {'two/one speed':>14}")
    print(
        f"{summary['agent_steps']:12.3g} {train_seconds:8.1f} {summary['train_agent_steps_per_s']:14.3g} "
        f"{two / one:14.2f}"
    )
    cp = result["cross_play"]
    captures = cp["matrices"]["captures_per_prey"]["mean"]
    width = max(len(a) for a in cp["prey"]) + 1
    print("\ncaptures per prey per episode (rows: prey, columns: predators)")
    print(" " * width + "".join(f"{b:>10}" for b in cp["predator"]))
    for a, row in zip(cp["prey"], captures):
        print(f"{a:>{width}}" + "".join(f"{v:10.3f}" for v in row))
    if generations:
        print(
            f"\n{'generation':>12} {'prev/prev':>10} {'new prey':>10} {'new pred':>10} {'prey better':>12} "
            f"{'pred better':>12}"
        )
        for g in generations:
            print(
                f"{g['generation']:>12} {g['previous_vs_previous']:10.3f} "
                f"{g['new_prey_vs_previous_predators']:10.3f} "
                f"{g['previous_prey_vs_new_predators']:10.3f} {str(g['prey_improved']):>12} "
                f"{str(g['predators_improved']):>12}"
            )
    print(
        "\nswarm metrics, first -> last logged value: "
        + ", ".join(f"{name} {a:.3g} -> {b:.3g}" for name, (a, b) in summary["swarm_first_last"].items())
    )
    print(f"\n{summary['total_seconds']:.0f} s in all; files in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
