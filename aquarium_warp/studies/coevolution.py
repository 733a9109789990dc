"""`aquarium-warp study coevolution`: co-evolution on one GPU, over several training seeds: both teams learn
(`aquarium-warp train --team both`), with an opponent pool, for at least 1e9 agent-steps per seed; per seed a
cross-play matrix over evenly spaced generations, the swarm metrics along training and one video; over the seeds
each cross-play cell's mean with its 95% interval and the declared comparisons with theirs; and the end-to-end speed
of the two-learner path against the one-team path.

    aquarium-warp study coevolution --device cuda:0 --seeds 0 1 2 --out-dir benchmarks/results/coevolution_h100
    aquarium-warp study coevolution --tiny --seeds 0 1 --out-dir /tmp/coevolution_tiny     # CPU, a few minutes

`python benchmarks/coevolution.py` (the command the committed results name) takes the same options (`main`).

The run (defaults): 4096 worlds of 32 prey and 4 predators in docs/model.md's 800 x 800 px world, 500-step
episodes, both teams Parameter Sharing with the trainer's default PPO (two tanh layers of 64, 32 steps
x 4096 worlds per iteration, 5 epochs x 4 mini-batches), simultaneous updates, an opponent pool
(a snapshot of each team every 20 iterations, 4 kept, uniform; each team plays the other's snapshots
in 20% of the worlds). Agent-steps count every simulated agent (both teams learn): worlds x 36 x
steps; the iterations I are the fewest that reach `--agent-steps`.

Generations (`--generations` G): generation k = 1..G is the pair of policies after round(k I / G)
iterations (halves rounded up, `generation_iterations`): evenly spaced, the last one the final
policies. The run trains up to each generation in turn (`Trainer.train` continues the same run, bit
for bit as one call), and the checkpoint the runner writes at the end of each stretch holds it.

Steps:
1. speed: `--speed-iterations` timed iterations (after 2 untimed ones: warm-up and graph capture) of
   the same world (the first seed's) with (a) one team learning (prey against NaivChase predators, the
   paper's setting), (b) both teams learning, (c) both teams with the pool, each in a process of its
   own; agent-steps/s of all agents and of the learning rows;
2. per training seed s of `--seeds` (into `seed<s>/`): the co-evolution run (`seed<s>/run/`), one video
   (`episode.gif`, and its last frame `episode.png`) of the final policies, cross-play
   (`aquarium_warp.training.cross_play.cross_play`): every prey generation (and Random, TurnAway)
   against every predator generation (and Random, NaivChase), `--eval-episodes` x the evaluation
   seeds, which are `--eval-seeds` + `seeding.evaluation_seed(s)` (so that the heuristic cells, too,
   are a fresh sample per training seed), and the training curves;
3. over the training seeds: each cell's per-seed value (captures per prey per episode, the mean over
   the evaluation episodes and seeds; prey survival, rewards likewise), their mean and 95% Student-t
   interval; the declared comparisons (`declared_comparisons`) with paired 95% t intervals over the
   seeds; the training curves' means with 95% bands.

Primary measure: captures per prey per episode. The comparisons, declared with the design (each a
difference of two cells of one seed's matrix, oriented so that > 0 is a gain of the team named):
- `predator-vs-baseline`: each predator generation against Random and against NaivChase predators,
  all facing TurnAway prey;
- `prey-vs-baseline`: each prey generation against TurnAway and against Random prey, all facing
  NaivChase predators;
- `latest-vs-earlier` (the arms race): the final predators against predator generation k, both facing
  the final prey; the final prey against prey generation k, both facing the final predators;
- `consecutive`: the new predators against the previous ones, facing the previous prey; the new prey
  against the previous ones, facing the previous predators (a cycle shows as gains that come and go).
The 8G - 4 intervals are each at 95%, not adjusted for their number.

The speed points and each seed are tasks of the studies' job runner (`aquarium_warp.jobs`):
each result is kept in `--out-dir/finished/`, and a rerun (after a time limit, or with more `--seeds`,
or `--speed-only` first and the rest in a later call) runs only what is missing.

Writes `summary.json` (settings, provenance, every seed's values and times, the matrices' means and
intervals, the comparisons), `cross_play.csv` (a row per cell and metric: mean, 95% half-width, the
per-seed values), `comparisons.csv`, `speed.csv`, `training_curves.csv`, the figures
`cross_play_generations.png` and `training_curves.png` (95% bands over the seeds), and per seed its
cross-play files, `training_curves.csv` and the GIF into `--out-dir`, and prints a compact summary.
The checkpoints are deleted once a seed is done unless `--keep-checkpoints` (about 10 MB each at the
default size).
"""

from __future__ import annotations

import argparse
import csv
import functools
import glob
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import numpy as np

from ..arguments import check_distinct, check_int
from ..records import command_line, json_safe, machine_info, provenance
from ..seeding import EVALUATION_STRIDE, evaluation_seed
from ..statistics import difference, mean_interval
from ..training.config import env_config, make_config
from ..training.fast_path import TORCH_FLOAT32
from .common import study_options

if TYPE_CHECKING:
    from ..training import Trainer

# torch, the simulator and the trainer are imported where a task runs: `aquarium-warp study --help` stays light.

SWARM = ("polarization", "groups", "cohesion", "nn_mean")
CURVE_PREFIXES = ("prey/Episode", "predator/Episode", "Swarm/")
PREY_BASELINES = ("random", "turnaway")
PREDATOR_BASELINES = ("random", "naivchase")
PRIMARY = "captures_per_prey"


def settings(args, seed: int) -> dict:
    """The run config's changes for a co-evolution run of training seed `seed` (without the team and
    the device)."""
    return {
        "env": {
            "prey_count": args.prey,
            "predator_count": args.predators,
            "max_steps": args.max_steps,
            **({"width": 400.0, "height": 400.0} if args.tiny else {}),
        },
        "train": {
            "num_worlds": args.worlds,
            "seed": seed,
            "quiet": True,
            "export": ["jit"],
            "metrics_every": 10,
            **TORCH_FLOAT32,
        },
        "runner": {"num_steps_per_env": args.steps},
    }


def pool_settings(args) -> dict:
    return {"train": {"pool_every": args.pool_every, "pool_size": args.pool_size, "pool_fraction": args.pool_fraction}}


def run_iterations(args) -> int:
    """The fewest iterations that reach `--agent-steps`."""
    return math.ceil(args.agent_steps / (args.worlds * (args.prey + args.predators) * args.steps))


def generation_iterations(iterations: int, generations: int) -> list[int]:
    """The iterations completed at generations 1..`generations` of a run of `iterations`: round(k x
    iterations / generations), halves rounded up (in integers, no float rounding), so the last is the
    run's end and neighbours are `iterations / generations` apart, give or take one."""
    check_int("--generations", generations, 2)
    if generations > iterations:
        raise ValueError(f"--generations={generations} must be in [2, {iterations}] (the run's iterations)")
    return [(2 * k * iterations + generations) // (2 * generations) for k in range(1, generations + 1)]


def checkpoint_after(run_dir: str, iterations: int) -> str:
    """The checkpoint holding the policies after `iterations` completed iterations: the runner names it
    by its last iteration's 0-based index."""
    return os.path.join(run_dir, f"model_{iterations - 1}.pt")


def train_generations(trainer: Trainer, iterations: list[int]) -> None:
    """Train up to each of `iterations` in turn; each stretch ends with a checkpoint (`checkpoint_after`).
    A SIGINT/SIGTERM ends a stretch early (`Trainer.stop`): the seed then stops here, unfinished (a
    rerun trains it again), instead of taking short stretches for generations."""
    for k, n in enumerate(iterations, 1):
        trainer.train(n - trainer.iteration)
        if trainer.stop.signum is not None:
            raise RuntimeError(
                f"training stopped by signal {trainer.stop.signum} at iteration {trainer.iteration}, before "
                f"generation {k} ({n} iterations): this seed is not finished"
            )


def evaluation_seeds(seed: int, eval_seeds: list[int]) -> list[int]:
    """The cross-play seeds of training seed `seed`: `seeding.evaluation_seed(seed)` + each of `eval_seeds`."""
    return [evaluation_seed(seed) + e for e in eval_seeds]


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
    command = [sys.executable, "-m", "aquarium_warp", "study", "coevolution", *argv, "--speed-path", key]
    done = subprocess.run(command, capture_output=True, text=True)
    lines = [line for line in done.stdout.splitlines() if line.startswith("SPEED ")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"speed of {key!r} failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
    return json.loads(lines[-1][len("SPEED ") :])


def measure_speed(args, name: str, *changes: dict) -> dict:
    """Agent-steps per second of `--speed-iterations` iterations after 2 untimed ones."""
    from ..device import synchronize
    from ..training import Trainer

    config = make_config("default", settings(args, args.seeds[0]), {"train": {"device": args.device}}, *changes)
    trainer = Trainer(config)
    device = trainer.device
    trainer.train(2)
    synchronize(device)
    start = time.perf_counter()
    trainer.train(args.speed_iterations)
    synchronize(device)
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


# ---- the tasks (`jobs.run_jobs`: kept in <out-dir>/finished/) ---------------------------------------


def speed_task(args) -> dict:
    return {
        "name": "speed",
        "world": settings(args, args.seeds[0]),
        "pool": pool_settings(args),
        "speed_iterations": args.speed_iterations,
    }


def measure_speeds(task: dict, device: str, argv: list[str]) -> dict:
    """The speed task: each of `speed_paths` measured in a process of its own (`argv`: the study's options)."""
    return {
        "points": [measure_speed_in_subprocess(key, argv) for key in ("one", "both", "pool")],
        "machine": machine_info(device),
    }


def seed_task(args, seed: int, out: Path) -> dict:
    iterations = run_iterations(args)
    return {
        "name": f"seed{seed}",
        "seed": seed,
        # Only the stretches' ends save (and iteration 0, which every run saves): `train_generations`.
        "config": [
            settings(args, seed),
            pool_settings(args),
            {"train": {"team": "both", "iterations": iterations}, "runner": {"save_interval": iterations + 1}},
        ],
        "generation_iterations": generation_iterations(iterations, args.generations),
        "eval_episodes": args.eval_episodes,
        "eval_seeds": evaluation_seeds(seed, args.eval_seeds),
        "run_dir": str(out / f"seed{seed}" / "run"),
    }


def read_scalars(run_dir: str) -> dict[str, list[tuple[int, float]]]:
    """Every TensorBoard scalar of a run (all its event files): `{tag: [(iteration, value), ...]}`."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(run_dir, size_guidance={"scalars": 0}).Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def run_seed(task: dict, device: str, keep_checkpoints: bool = False) -> dict:
    """One training seed: train to each generation, a video of the final policies, cross-play of the
    generations and the heuristics; writes its files beside its run and returns its per-seed values."""
    from ..device import synchronize
    from ..training import Trainer
    from ..training.cross_play import CROSS_PLAY_METRICS, cross_play, write_cross_play
    from ..training.episode_video import EpisodeVideo, gif_bytes
    from ..training.plots import plot_cross_play

    run_dir = task["run_dir"]
    folder = os.path.dirname(run_dir)
    if os.path.isdir(run_dir):  # a run stopped before it finished: a finished seed is kept, not rerun
        shutil.rmtree(run_dir)
    config = make_config("default", *task["config"], {"train": {"device": device}})
    trainer = Trainer(config, run_dir)
    torch_device = trainer.device
    start = time.perf_counter()
    train_generations(trainer, task["generation_iterations"])
    synchronize(torch_device)
    train_seconds = time.perf_counter() - start
    trainer.export()
    train = config["train"]
    agent_steps = (
        train["iterations"]
        * train["num_worlds"]
        * config["runner"]["num_steps_per_env"]
        * (config["env"]["prey_count"] + config["env"]["predator_count"])
    )
    print(
        f"  seed {task['seed']}: trained {train['iterations']} iterations in {train_seconds:.1f} s "
        f"({agent_steps / train_seconds:.3g} agent-steps/s)",
        flush=True,
    )

    # one video of the final policies (rendered before the trainer goes)
    max_steps = config["env"]["max_steps"]
    video = EpisodeVideo(env_config(config), device, task["seed"], steps=min(300, max_steps))
    frames = video.record(trainer.video_drivers)
    video.close()
    Path(folder, "episode.gif").write_bytes(gif_bytes(frames, video.fps))
    from ..render import save_png

    save_png(frames[-1], os.path.join(folder, "episode.png"))
    trainer.close()
    del trainer

    # cross-play over the generations, with the heuristics as anchors
    gens = [f"gen{k}={checkpoint_after(run_dir, n)}" for k, n in enumerate(task["generation_iterations"], 1)]
    start = time.perf_counter()
    result = cross_play(
        list(PREY_BASELINES) + gens,
        gens + list(PREDATOR_BASELINES),
        env_config(config),
        episodes=task["eval_episodes"],
        seeds=task["eval_seeds"],
        device=device,
        max_worlds=task["eval_episodes"],
    )
    cross_seconds = time.perf_counter() - start
    write_cross_play(result, folder)
    plot_cross_play(result, os.path.join(folder, f"cross_play_{PRIMARY}.png"), PRIMARY)

    scalars = read_scalars(run_dir)
    curves = {tag: values for tag, values in scalars.items() if tag.startswith(CURVE_PREFIXES)}
    write_curves_csv(
        {tag: dict(values) for tag, values in curves.items()},
        agent_steps // train["iterations"],
        os.path.join(folder, "training_curves.csv"),
    )
    kept = {checkpoint_after(run_dir, n) for n in task["generation_iterations"]} if keep_checkpoints else set()
    for path in glob.glob(os.path.join(run_dir, "model_*.pt")):
        if path not in kept:
            os.remove(path)

    def first_last(tag):
        values = scalars.get(tag, [])
        return (values[0][1], values[-1][1]) if values else (math.nan, math.nan)

    cp = result["cross_play"]
    return json_safe(
        {
            "seed": task["seed"],
            "device": device,
            "machine": result["machine"],
            "generation_iterations": task["generation_iterations"],
            "eval_seeds": task["eval_seeds"],
            "agent_steps": agent_steps,
            "train_seconds": train_seconds,
            "train_agent_steps_per_s": agent_steps / train_seconds,
            "cross_play_seconds": cross_seconds,
            "prey": cp["prey"],
            "predator": cp["predator"],
            "matrices": {m: cp["matrices"][m]["mean"] for m in CROSS_PLAY_METRICS},
            "curves": curves,
            "swarm_first_last": {name: first_last(f"Swarm/{name}") for name in SWARM},
        }
    )


# ---- over the training seeds --------------------------------------------------------------------------


def aggregate(seed_results: list[dict]) -> dict:
    """Per cross-play cell and metric: the per-seed values (`seeds`: one matrix per training seed), their
    mean and the half-width of its 95% Student-t interval over the seeds (`ci95`, None for one seed)."""
    first = seed_results[0]
    out: dict = {
        "prey": first["prey"],
        "predator": first["predator"],
        "seeds": [r["seed"] for r in seed_results],
        "matrices": {},
    }
    for metric in first["matrices"]:
        values = np.array([r["matrices"][metric] for r in seed_results], dtype=np.float64)  # seed x prey x predator
        cells = [[mean_interval(values[:, i, j]) for j in range(values.shape[2])] for i in range(values.shape[1])]
        out["matrices"][metric] = {
            "mean": [[m for m, _ in row] for row in cells],
            "ci95": [[h for _, h in row] for row in cells],
            "seeds": values.tolist(),
        }
    return out


def declared_comparisons(generations: int) -> list[dict]:
    """The comparisons declared with the design: `{family, team, a, b}` with `a` and `b` (prey, predator)
    cells, the difference a - b of captures per prey oriented so that > 0 is a gain of `team` (its
    learned or newer policy catching more, or being caught less)."""
    gens = [f"gen{k}" for k in range(1, generations + 1)]
    last = gens[-1]
    out = []

    def add(family: str, team: str, a: tuple[str, str], b: tuple[str, str]) -> None:
        out.append({"family": family, "team": team, "a": list(a), "b": list(b)})

    for g in gens:
        for base in PREDATOR_BASELINES:
            add("predator-vs-baseline", "predator", ("turnaway", g), ("turnaway", base))
    for g in gens:
        for base in ("turnaway", "random"):
            add("prey-vs-baseline", "prey", (base, "naivchase"), (g, "naivchase"))
    for g in gens[:-1]:
        add("latest-vs-earlier", "predator", (last, last), (last, g))
        add("latest-vs-earlier", "prey", (g, last), (last, last))
    for previous, new in zip(gens, gens[1:]):
        add("consecutive", "predator", (previous, new), (previous, previous))
        add("consecutive", "prey", (previous, previous), (new, previous))
    return out


def compare_cells(aggregated: dict, declared: list[dict], metric: str = PRIMARY) -> list[dict]:
    """Each declared comparison over the training seeds: the per-seed values of its two cells and their
    differences, and the paired 95% t interval of the mean difference (`statistics.difference`)."""
    rows, cols = aggregated["prey"], aggregated["predator"]
    values = np.array(aggregated["matrices"][metric]["seeds"], dtype=np.float64)

    def cell(pair):
        return values[:, rows.index(pair[0]), cols.index(pair[1])]

    out = []
    for c in declared:
        a, b = cell(c["a"]), cell(c["b"])
        out.append(
            {
                **c,
                "metric": metric,
                "a_seeds": a.tolist(),
                "b_seeds": b.tolist(),
                "differences": (a - b).tolist(),
                **difference(a, b, paired=True),
            }
        )
    return out


def aggregate_curves(seed_results: list[dict]) -> dict[str, dict[int, tuple[float, float | None, int]]]:
    """Per training-curve tag and iteration: the mean over the seeds, the 95% half-width and the seeds
    that logged a value there."""
    out: dict[str, dict[int, tuple[float, float | None, int]]] = {}
    tags = dict.fromkeys(tag for r in seed_results for tag in r["curves"])
    for tag in tags:
        by_iteration: dict[int, list[float]] = {}
        for r in seed_results:
            for it, value in r["curves"].get(tag, []):
                by_iteration.setdefault(int(it), []).append(math.nan if value is None else value)
        out[tag] = {}
        for it in sorted(by_iteration):
            mean, half = mean_interval(by_iteration[it])
            out[tag][it] = (mean, half, int(np.isfinite(by_iteration[it]).sum()))
    return out


# ---- files and figures -------------------------------------------------------------------------------


def write_csv(rows: list[dict], path: str) -> str:
    """`rows` as CSV, a column for every key of any row (in first-seen order; a measure without a value in
    a row, e.g. group measures in an iteration without groups, is left empty)."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for row in rows for k in row)), restval="")
        writer.writeheader()
        writer.writerows(rows)
    return path


def write_curves_csv(curves: Mapping[str, Mapping[int, object]], steps_per_iteration: int, path: str) -> None:
    """A row per iteration, a column per tag (a value, or over seeds `mean`, `ci95` and `n` columns)."""
    iterations = sorted({it for values in curves.values() for it in values})
    rows = []
    for it in iterations:
        row: dict = {"iteration": it, "agent_steps": (it + 1) * steps_per_iteration}
        for tag, values in curves.items():
            value = values.get(it)
            if isinstance(value, tuple):
                row.update({f"{tag} mean": value[0], f"{tag} ci95": value[1], f"{tag} n": value[2]})
            else:
                row[tag] = value
        rows.append(row)
    if rows:
        write_csv(rows, path)


def write_cross_play_csv(aggregated: dict, path: str) -> None:
    rows = []
    for metric, m in aggregated["matrices"].items():
        for i, prey in enumerate(aggregated["prey"]):
            for j, predator in enumerate(aggregated["predator"]):
                rows.append(
                    {
                        "prey_policy": prey,
                        "predator_policy": predator,
                        "metric": metric,
                        "mean": m["mean"][i][j],
                        "ci95": m["ci95"][i][j],
                        **{f"seed{s}": m["seeds"][k][i][j] for k, s in enumerate(aggregated["seeds"])},
                    }
                )
    write_csv(rows, path)


def write_comparisons_csv(comparisons: list[dict], seeds: list[int], path: str) -> None:
    write_csv(
        [
            {
                "family": c["family"],
                "team": c["team"],
                "a_prey": c["a"][0],
                "a_predator": c["a"][1],
                "b_prey": c["b"][0],
                "b_predator": c["b"][1],
                "difference": c["difference"],
                "low": c["low"],
                "high": c["high"],
                "n": c["n_a"],
                **{f"seed{s}": d for s, d in zip(seeds, c["differences"])},
            }
            for c in comparisons
        ],
        path,
    )


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _band(ax, x, stats: list[tuple[float, float | None]], label: str | None, **kwargs) -> None:
    """A line of the means and a band of their 95% intervals (`(mean, half-width)` per x)."""
    mean = np.array([m for m, _ in stats], dtype=np.float64)
    half = np.array([np.nan if h is None else h for _, h in stats], dtype=np.float64)
    (line,) = ax.plot(x, mean, label=label, **kwargs)
    ax.fill_between(x, mean - half, mean + half, color=line.get_color(), alpha=0.2, lw=0)


def plot_generations(aggregated: dict, agent_steps: list[float], path: str) -> str:
    """Captures per prey over the generations, means and 95% bands over the training seeds: the
    predators against TurnAway prey, the prey against NaivChase predators (each beside its baselines),
    and the arms race (the final generations against every earlier one)."""
    plt = _pyplot()
    rows, cols = aggregated["prey"], aggregated["predator"]
    m = aggregated["matrices"][PRIMARY]
    gens = [g for g in rows if g.startswith("gen")]
    x = np.asarray(agent_steps, dtype=np.float64)

    def cell(prey, predator):
        i, j = rows.index(prey), cols.index(predator)
        return m["mean"][i][j], m["ci95"][i][j]

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), sharey=True)
    panels = (
        (
            axes[0],
            "predator generations vs TurnAway prey",
            [cell("turnaway", g) for g in gens],
            [(f"{b} predators", cell("turnaway", b)) for b in PREDATOR_BASELINES],
        ),
        (
            axes[1],
            "prey generations vs NaivChase predators",
            [cell(g, "naivchase") for g in gens],
            [(f"{b} prey", cell(b, "naivchase")) for b in PREY_BASELINES],
        ),
    )
    for ax, title, stats, baselines in panels:
        _band(ax, x, stats, "learned", marker="o", color="C0")
        for (label, (mean, half)), color in zip(baselines, ("C1", "C2")):
            ax.axhline(mean, ls="--", lw=1, label=label, color=color)
            if half is not None:
                ax.axhspan(mean - half, mean + half, color=color, alpha=0.15, lw=0)
        ax.set_title(title)
    last = gens[-1]
    ax = axes[2]
    _band(ax, x, [cell(g, g) for g in gens], "prey k vs predators k", marker="o")
    _band(ax, x, [cell(last, g) for g in gens], "final prey vs predators k", marker="s")
    _band(ax, x, [cell(g, last) for g in gens], "prey k vs final predators", marker="^")
    ax.set_title("arms race")
    axes[0].set_ylabel("captures per prey per episode")
    for ax in axes:
        ax.set_xlabel("generation k (agent-steps)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(f"means and 95% t intervals over {len(aggregated['seeds'])} training seeds", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_curves(curves: dict, steps_per_iteration: int, seeds: int, path: str) -> str:
    """Training curves of both teams and the swarm metrics: means and 95% bands over the seeds."""
    plt = _pyplot()
    panels = [
        ("captures per prey per episode", ["prey/Episode/captures_per_prey"]),
        ("reward per agent per episode", ["prey/Episode/reward_per_agent", "predator/Episode/reward_per_agent"]),
        ("polarization", ["Swarm/polarization"]),
        ("groups", ["Swarm/groups"]),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4))
    for ax, (title, tags) in zip(axes, panels):
        for tag in tags:
            if curves.get(tag):
                its = sorted(curves[tag])
                _band(
                    ax,
                    (np.array(its) + 1) * steps_per_iteration,
                    [curves[tag][it][:2] for it in its],
                    tag.split("/")[0] if len(tags) > 1 else None,
                )
        ax.set_title(title)
        ax.set_xlabel("agent-steps")
        if len(tags) > 1 and ax.get_legend_handles_labels()[0]:
            ax.legend()
    fig.suptitle(f"means and 95% t intervals over {seeds} training seeds", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def check(args) -> None:
    """A one-line ValueError naming the option unless the seeds and generations are in range."""
    if len(args.seeds) < 2:
        raise ValueError(f"--seeds={args.seeds!r} must name at least 2 training seeds (intervals over seeds)")
    check_distinct("--seeds", args.seeds)
    check_int("--jobs", args.jobs, 1)
    for seed in args.seeds:
        check_int("--seeds", seed, 0)
    check_distinct("--eval-seeds", args.eval_seeds)
    for seed in args.eval_seeds:  # below the stride, so that no two training seeds share one
        if not 0 <= seed < EVALUATION_STRIDE:
            raise ValueError(f"--eval-seeds={seed} must be in [0, {EVALUATION_STRIDE - 1}]")
    generation_iterations(run_iterations(args), args.generations)


HELP = "co-evolution: both teams learn with an opponent pool; cross-play of their generations over seeds"
DESCRIPTION = " ".join(__doc__.split("\n\n")[0].split(": ", 1)[1].split())


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None, help="'cuda:0' (default when present) or 'cpu'")
    p.add_argument("--out-dir", default="coevolution_results", help="output folder")
    p.add_argument("--tiny", action="store_true", help="a CPU-sized run of every step (400 x 400 px, 16 worlds)")
    p.add_argument(
        "--seeds", type=int, nargs="+", default=None, help="training seeds, at least 2 (default 0 1 2; tiny 0 1)"
    )
    p.add_argument("--worlds", type=int, default=None, help="worlds (default 4096; tiny 16)")
    p.add_argument("--prey", type=int, default=None, help="prey per world (default 32; tiny 8)")
    p.add_argument("--predators", type=int, default=None, help="predators per world (default 4; tiny 2)")
    p.add_argument("--max-steps", type=int, default=None, help="episode length (default 500; tiny 100)")
    p.add_argument("--steps", type=int, default=32, help="rollout steps per iteration")
    p.add_argument(
        "--agent-steps", type=float, default=None, help="agent-steps of each seed's run (default 1e9; tiny 2e5)"
    )
    p.add_argument(
        "--generations",
        type=int,
        default=None,
        help="evenly spaced generations compared, the last the final policies (default 6; tiny 3)",
    )
    p.add_argument("--pool-every", type=int, default=None, help="pool snapshot interval (default 20; tiny 2)")
    p.add_argument("--pool-size", type=int, default=4, help="snapshots kept per team")
    p.add_argument("--pool-fraction", type=float, default=0.2, help="worlds per team against the other's snapshots")
    p.add_argument(
        "--speed-iterations", type=int, default=None, help="timed iterations per speed point (default 10; tiny 2)"
    )
    p.add_argument("--eval-episodes", type=int, default=None, help="cross-play episodes per seed (default 64; tiny 4)")
    p.add_argument(
        "--eval-seeds",
        type=int,
        nargs="+",
        default=[0, 1],
        help=f"cross-play seeds, each in [0, {EVALUATION_STRIDE - 1}] (training seed s plays them "
        f"+ {EVALUATION_STRIDE} (s + 1), aquarium_warp.seeding.evaluation_seed)",
    )
    p.add_argument("--no-figures", action="store_true", help="no matplotlib figures (the files are written)")
    p.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="training seeds at once on the device, each in a worker process of its own (default 1)",
    )
    p.add_argument("--keep-checkpoints", action="store_true", help="keep the generations' seed<s>/run/model_*.pt")
    p.add_argument(
        "--speed-only",
        action="store_true",
        help="measure step 1 only and write speed.csv (kept: a later call runs the rest)",
    )
    p.add_argument(
        "--speed-path",
        choices=("one", "both", "pool"),
        default=None,
        help="(internal) measure the speed of one path and print it as JSON",
    )


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study coevolution`: the study's own options (after the study's name in `args.argv`)
    parsed again by `main`, so that the settings it records and its speed processes see them alone."""
    return main(study_options(args.argv, "coevolution"), command=command_line(args.argv))


def main(argv: list[str] | None = None, command: str | None = None) -> int:
    """Run the study with the options `argv` (default: this process's), recording `command` (default:
    `benchmarks/coevolution.py` and `argv`, the script the committed results name)."""
    import torch

    from ..device import resolve_device
    from ..jobs import run_jobs

    p = argparse.ArgumentParser(description=DESCRIPTION)
    add_arguments(p)
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
        seeds=([0, 1], [0, 1, 2]),
    )
    for name, (tiny, full) in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, tiny if args.tiny else full)
    if args.tiny and args.device is None:
        args.device = "cpu"
    if args.device == "cpu":
        torch.set_num_threads(1)  # the small networks run fastest on one thread (as in the tests)
    check(args)
    if args.speed_path is not None:
        name, changes = speed_paths(args)[args.speed_path]
        print("SPEED " + json.dumps(measure_speed(args, name, *changes)))
        return 0
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(args.device)
    agents = args.prey + args.predators
    iterations = run_iterations(args)
    steps_per_iteration = args.worlds * agents * args.steps
    gen_iterations = generation_iterations(iterations, args.generations)
    started = time.perf_counter()
    print(
        f"coevolution: {len(args.seeds)} seeds x {args.worlds} worlds x ({args.prey} prey + {args.predators} "
        f"predators), {iterations} iterations of {args.steps} steps = {iterations * steps_per_iteration:.3g} "
        f"agent-steps each, generations after {gen_iterations} iterations, device {device}",
        flush=True,
    )

    def report(line: str) -> None:
        print(line, flush=True)

    # 1. speed of the one-team path against the two-learner path, same world
    speed_run = run_jobs(
        functools.partial(measure_speeds, argv=[a for a in argv if a != "--speed-only"]),
        [speed_task(args)],
        str(out),
        devices=[device],
        label="speed",
        report=report,
    )
    speed = speed_run.results[0]["points"]
    for point in speed:
        print(
            f"  speed {point['path']:>30}: {point['agent_steps_per_s']:.3g} agent-steps/s "
            f"({point['learning_rows_per_s']:.3g} learning rows/s)",
            flush=True,
        )
    write_csv(speed, str(out / "speed.csv"))
    if args.speed_only:
        return 0

    # 2. each training seed: the run, a video, cross-play, curves
    seeds_run = run_jobs(
        functools.partial(run_seed, keep_checkpoints=args.keep_checkpoints),
        [seed_task(args, seed, out) for seed in args.seeds],
        str(out),
        jobs=args.jobs,
        devices=[device],
        label="seeds",
        report=report,
    )
    results = seeds_run.results

    # 3. over the seeds
    aggregated = aggregate(results)
    comparisons = compare_cells(aggregated, declared_comparisons(args.generations))
    write_cross_play_csv(aggregated, str(out / "cross_play.csv"))
    write_comparisons_csv(comparisons, args.seeds, str(out / "comparisons.csv"))
    curves = aggregate_curves(results)
    write_curves_csv(curves, steps_per_iteration, str(out / "training_curves.csv"))
    if not args.no_figures:
        plot_generations(
            aggregated, [n * steps_per_iteration for n in gen_iterations], str(out / "cross_play_generations.png")
        )
        plot_curves(curves, steps_per_iteration, len(results), str(out / "training_curves.png"))

    one, two = speed[0]["agent_steps_per_s"], speed[2]["agent_steps_per_s"]
    per_seed_keys = (
        "seed",
        "device",
        "eval_seeds",
        "agent_steps",
        "train_seconds",
        "train_agent_steps_per_s",
        "cross_play_seconds",
        "swarm_first_last",
        "machine",
    )
    summary = {
        **provenance(device, command or command_line(argv, "benchmarks/coevolution.py")),
        "settings": {**vars(args), "iterations": iterations, "generation_iterations": gen_iterations},
        "primary": PRIMARY,
        "tasks": {"kept": speed_run.kept + seeds_run.kept, "run": 1 + len(results) - speed_run.kept - seeds_run.kept},
        "speed": speed,
        "speed_machine": speed_run.results[0]["machine"],
        "two_learner_over_one_team": two / one,
        "per_seed": [{k: r[k] for k in per_seed_keys} for r in results],
        "cross_play": aggregated,
        "comparisons": comparisons,
        "swarm_last": {
            name: dict(
                zip(
                    ("mean", "ci95"),
                    mean_interval(
                        [
                            math.nan if r["swarm_first_last"][name][1] is None else r["swarm_first_last"][name][1]
                            for r in results
                        ]
                    ),
                )
            )
            for name in SWARM
        },
        "total_seconds": time.perf_counter() - started,
    }
    with open(out / "summary.json", "w", encoding="utf-8") as f:
        json.dump(json_safe(summary), f, indent=1)

    # the compact summary
    print(f"\n{'seed':>6} {'agent-steps':>12} {'train s':>8} {'agent-steps/s':>14}")
    for r in results:
        print(f"{r['seed']:6d} {r['agent_steps']:12.3g} {r['train_seconds']:8.1f} {r['train_agent_steps_per_s']:14.3g}")
    print(f"two-learner (+ pool) over one-team speed: {two / one:.2f}")
    rows, cols, m = aggregated["prey"], aggregated["predator"], aggregated["matrices"][PRIMARY]
    width = max(len(a) for a in rows) + 1
    print(f"\ncaptures per prey per episode, mean ± 95% over {len(results)} seeds (rows: prey, columns: predators)")
    print(" " * width + "".join(f"{b:>15}" for b in cols))
    for i, a in enumerate(rows):
        print(f"{a:>{width}}" + "".join(f"{m['mean'][i][j]:8.3f} ±{m['ci95'][i][j]:6.3f}" for j in range(len(cols))))
    print(
        f"\n{'family':>21} {'team':>9} {'a (prey|predator)':>21} {'b (prey|predator)':>21} {'a - b':>8} "
        f"{'95% interval':>20}"
    )
    for c in comparisons:
        print(
            f"{c['family']:>21} {c['team']:>9} {'|'.join(c['a']):>21} {'|'.join(c['b']):>21} "
            f"{c['difference']:8.3f} [{c['low']:8.3f}, {c['high']:8.3f}]"
        )
    print(
        "\nswarm metrics, last logged value over the seeds: "
        + ", ".join(
            f"{name} {s['mean']:.3g} ± {s['ci95'] if s['ci95'] is not None else math.nan:.2g}"
            for name, s in summary["swarm_last"].items()
        )
    )
    print(
        f"\n{summary['total_seconds']:.0f} s in all ({summary['tasks']['run']} tasks run, "
        f"{summary['tasks']['kept']} kept); files in {out}"
    )
    return 0
