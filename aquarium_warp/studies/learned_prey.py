"""`aquarium-warp study learned-prey`: learned prey against the heuristics: train prey under named conditions in worlds
A, B and C, then evaluate every trained policy beside the random, constant-heading and TurnAway baselines against
NaivChase, and write per-seed values, means with 95% intervals and training curves.

Worlds (prey perception; everything else is the paper preset: 6 prey, 1 NaivChase predator):
A: the paper's (120 degrees, 100 px); B: 360 degrees, 200 px; C: 360 degrees, unlimited (10,000 px).

Every condition is the `paper` preset (or another preset) plus config assignments (`train --set`'s
form; `CONDITIONS`); a plan (`PLANS`) names the (condition, world, seeds) to run. Trainings and
evaluations are tasks of the studies' job runner (`aquarium_warp.jobs.run_jobs`): `--per-gpu`
at a time on each of `--gpus` GPUs (0: one at a time on the CPU), each training into
`runs/<condition>-<world>-s<seed>/`; on GPUs the trainings that may share a process train together as
populations (`training/population.py`), one at a time per GPU, each run as if alone. Finished tasks
are kept in `--out` (`finished/`), so a rerun runs only what is missing.

Evaluation: per (condition, world), one task evaluates the condition's policies (one label per
training seed) and the three baselines in the condition's own world (so its action frame), with the
paper's spawn headings (`spawn_heading="paper"`, the world of the committed TurnAway numbers), against
NaivChase, `--episodes` episodes x `--eval-seeds` seeds. The primary measure, declared before any run:
captures per prey per episode, lower is better. Learned: the mean over training seeds of each seed's
mean, with a 95% t interval over training seeds; baselines: over evaluation seeds.

    aquarium-warp study learned-prey --plan screen --gpus 4 --per-gpu 3 --out runs/learned_prey
    aquarium-warp study learned-prey --plan tiny --gpus 0 --out /tmp/lp   # a CPU smoke run

`python benchmarks/learned_prey.py` (the command the committed results name) takes the same options (`main`).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time

from ..atomic import atomic_open
from ..jobs import read_finished, run_jobs, task_devices
from ..records import command_line, git_info, machine_info
from ..statistics import interval
from .common import policy_path, run_training_task, study_options

WORLDS = {
    "A": [],
    "B": ["env.prey.fov_angle=360", "env.prey.view_distance=200"],
    "C": ["env.prey.fov_angle=360", "env.prey.view_distance=10000"],
}
EGO_OBS = ["env.observation_frame=ego"]
EGO = EGO_OBS + ["env.action_frame=ego"]
RANDOM_SPAWN = ["env.spawn_heading=random"]
ENTROPY_01 = ["runner.algorithm.entropy_coef=0.01"]


def episodes(n: int) -> list[str]:
    """A budget of `n` training episodes (the paper's: 4000)."""
    return [f"train.episodes={n}"]


# name -> (preset, config assignments)
CONDITIONS: dict[str, tuple[str, list[str]]] = {
    "world-frame": ("paper", []),
    "ego-obs": ("paper", EGO_OBS),
    "ego": ("paper", EGO),
    "ego-rand": ("paper", EGO + RANDOM_SPAWN),
    "ego-rand-worldcritic": ("paper", EGO + RANDOM_SPAWN + ["train.critic=world"]),
    "ego-rand-ent01": ("paper", EGO + RANDOM_SPAWN + ENTROPY_01),
    "ego-rand-4x": ("paper", EGO + RANDOM_SPAWN + episodes(16000)),
    "ego-rand-il": ("paper", EGO + RANDOM_SPAWN + ["train.sharing=individual"]),
    # Round 2 (after "screen"): ego observations with world actions, random spawn, more entropy; 2x budget.
    "r2-egoobs-ent01": ("paper", EGO_OBS + RANDOM_SPAWN + ENTROPY_01 + episodes(8000)),
    "r2-egoobs-ent03": ("paper", EGO_OBS + RANDOM_SPAWN + ["runner.algorithm.entropy_coef=0.03"] + episodes(8000)),
    "r2-egoobs-ent01-wide": (
        "paper",
        EGO_OBS
        + RANDOM_SPAWN
        + ["runner.actor.hidden_dims=[256,256]", "runner.critic.hidden_dims=[256,256]"]
        + ENTROPY_01
        + episodes(8000),
    ),
    "r2-egoobs-ent01-slots5": (
        "paper",
        EGO_OBS + RANDOM_SPAWN + ["env.prey.prey_slots=5"] + ENTROPY_01 + episodes(8000),
    ),
    "r2-egoobs-ent01-clip2": (
        "paper",
        EGO_OBS + RANDOM_SPAWN + ENTROPY_01 + ["runner.algorithm.clip_param=0.2"] + episodes(8000),
    ),
    "r2-egoobs-ent01-gamma": (
        "paper",
        EGO_OBS
        + RANDOM_SPAWN
        + ENTROPY_01
        + ["runner.algorithm.gamma=0.995", "runner.algorithm.lam=0.98"]
        + episodes(8000),
    ),
    "r2-ego-ent01": ("paper", EGO + RANDOM_SPAWN + ENTROPY_01 + episodes(8000)),
    "r2-egoobs-ent01-paperspawn": ("paper", EGO_OBS + ENTROPY_01 + episodes(8000)),
    # The paper's PS vs IL comparison (its budget) on ego observations, random spawn and entropy 0.01.
    "recipe-ps-1x": ("paper", EGO_OBS + RANDOM_SPAWN + ENTROPY_01),
    "recipe-il-1x": ("paper", EGO_OBS + RANDOM_SPAWN + ENTROPY_01 + ["train.sharing=individual"]),
    # The recipe declared before round 2's results: round 2's first condition at 4x the paper's budget.
    "recipe": ("paper", EGO_OBS + RANDOM_SPAWN + ENTROPY_01 + episodes(16000)),
    # The neighbour control: the recipe with no prey slots (the prey see the predator only).
    "recipe-noprey": ("paper", EGO_OBS + RANDOM_SPAWN + ["env.prey.prey_slots=0"] + ENTROPY_01 + episodes(16000)),
    "tiny-ego": ("tiny", EGO + RANDOM_SPAWN + ["train.iterations=2"]),
    "tiny-world": ("tiny", ["train.iterations=2"]),
}
PLANS: dict[str, list[tuple[str, str, list[int]]]] = {
    "screen": [
        (c, "B", [0, 1])
        for c in ("world-frame", "ego-obs", "ego", "ego-rand", "ego-rand-worldcritic", "ego-rand-ent01", "ego-rand-4x")
    ]
    + [(c, w, [0, 1]) for c in ("ego-rand", "ego-rand-4x") for w in ("A", "C")],
    "round2": [
        (c, "B", [0, 1, 2])
        for c in (
            "r2-egoobs-ent01",
            "r2-egoobs-ent03",
            "r2-egoobs-ent01-wide",
            "r2-egoobs-ent01-slots5",
            "r2-egoobs-ent01-clip2",
            "r2-egoobs-ent01-gamma",
            "r2-ego-ent01",
            "r2-egoobs-ent01-paperspawn",
        )
    ]
    + [(c, "A", [0, 1, 2, 3, 4]) for c in ("recipe-ps-1x", "recipe-il-1x")],
    "recipe": [("recipe", w, [0, 1, 2, 3, 4]) for w in ("A", "B", "C")],
    "noprey": [("recipe-noprey", w, [0, 1, 2, 3, 4]) for w in ("B", "C")],
    "tiny": [("tiny-ego", "A", [0, 1]), ("tiny-world", "B", [0])],
}
BASELINES = ("random", "constant", "turnaway")


def run_dir(out: str, condition: str, world: str, seed: int) -> str:
    return os.path.join(out, "runs", f"{condition}-{world}-s{seed}")


def run_config(condition: str, world: str, seed: int) -> dict:
    """The Trainer config of `condition`'s training run in `world` with `seed`, without a device (its
    task is given one): what `aquarium-warp train --preset <preset> --seed <seed> --quiet --export jit`
    with `--set` of torch's float32 path (`TORCH_FLOAT32`, the committed results'), the world's and the
    condition's assignments builds."""
    from ..training.config import deep_update, make_config, parse_assignment
    from ..training.fast_path import TORCH_FLOAT32

    preset, assignments = CONDITIONS[condition]
    changes = {"train": {"device": None, "seed": seed, "quiet": True, "export": "jit", **TORCH_FLOAT32}}
    for assignment in WORLDS[world] + assignments:
        deep_update(changes, parse_assignment(assignment))
    return make_config(preset, changes)


def training_tasks(out: str, plan: list[tuple[str, str, list[int]]]) -> list[dict]:
    """A training task per (condition, world, seed) of `plan`, the longest first (so that they do not
    start last)."""
    from ..training.config import total_iterations

    tasks = [
        {
            "name": f"train-{c}-{w}-s{s}",
            "condition": c,
            "world": w,
            "seed": s,
            "config": run_config(c, w, s),
            "run_dir": run_dir(out, c, w, s),
        }
        for c, w, seeds in plan
        for s in seeds
    ]
    return sorted(tasks, key=lambda task: -total_iterations(task["config"]))


def eval_tasks(
    out: str,
    plan: list[tuple[str, str, list[int]]],
    trainings: list[dict],
    episodes: int,
    eval_seeds: list[int],
    commit: str | None,
) -> list[dict]:
    """An evaluation task per (condition, world) of `plan`; its runs' configs are part of it, so that
    runs trained again with other settings are evaluated again, and so is the `commit` it records."""
    config = {(t["condition"], t["world"], t["seed"]): t["config"] for t in trainings}
    return [
        {
            "name": f"eval-{c}-{w}",
            "condition": c,
            "world": w,
            "seeds": seeds,
            "trainings": [config[(c, w, s)] for s in seeds],
            "run_dirs": [run_dir(out, c, w, s) for s in seeds],
            "episodes": episodes,
            "eval_seeds": eval_seeds,
            "commit": commit,
        }
        for c, w, seeds in plan
    ]


def run_eval_task(task: dict, device: str) -> dict:
    """The record of `eval/<condition>-<world>.json`: each policy's and baseline's captures and reward
    per prey, per evaluation seed too, with the protocol and provenance."""
    from ..config import AquariumConfig
    from ..drivers import common_world
    from ..records import json_safe
    from ..training.evaluate import evaluate_policies

    learned = [f"s{s}={policy_path(run)}" for s, run in zip(task["seeds"], task["run_dirs"], strict=True)]
    env = common_world(learned, AquariumConfig()).replace(spawn_heading="paper")
    episodes, eval_seeds = task["episodes"], task["eval_seeds"]
    result = evaluate_policies(
        learned + list(BASELINES), ["naivchase"], env, episodes=episodes, seeds=eval_seeds, device=device
    )
    per_seed = {}
    for row in result["summary"]:
        values = [r["captures_per_prey"] for r in result["episodes"] if r["prey_policy"] == row["prey_policy"]]
        per_seed[row["prey_policy"]] = {
            "captures_per_prey": row["captures_per_prey_mean"],
            "reward_per_prey": row["reward_per_prey_mean"],
            "per_eval_seed": [
                float(
                    sum(
                        r["captures_per_prey"]
                        for r in result["episodes"]
                        if r["prey_policy"] == row["prey_policy"] and r["seed"] == s
                    )
                    / episodes
                )
                for s in eval_seeds
            ],
            "episodes": len(values),
        }
    return json_safe(
        {
            "condition": task["condition"],
            "world": task["world"],
            "policies": per_seed,
            "protocol": result["protocol"],
            "command": result["command"],
            # Read from git; the plan's --commit only names a lent machine's copy without git history.
            "git": git_info(task["commit"]),
            "machine": result["machine"],
        }
    )


def summarize(out: str, plan: list[tuple[str, str, list[int]]]) -> list[dict]:
    rows = []
    for condition, world, seeds in plan:
        path = os.path.join(out, "eval", f"{condition}-{world}.json")
        with open(path, encoding="utf-8") as f:
            ev = json.load(f)
        policies = ev["policies"]
        row: dict = {
            "condition": condition,
            "world": world,
            "seeds": seeds,
            "learned": interval([policies[f"s{s}"]["captures_per_prey"] for s in seeds]),
        }
        for b in BASELINES:
            row[b] = interval(policies[b]["per_eval_seed"])
        t = row["turnaway"]["mean"]
        c = row["constant"]["mean"]
        row["learned_over_turnaway"] = row["learned"]["mean"] / t if t else None
        row["learned_over_constant"] = row["learned"]["mean"] / c if c else None
        rows.append(row)
    return rows


def fmt(s: dict) -> str:
    return f"{s['mean']:.2f}" + (f" ± {s['ci95']:.2f}" if s["ci95"] is not None else "")


HELP = "learned prey against the heuristics: named training conditions in worlds A, B and C"
DESCRIPTION = " ".join(__doc__.split("\n\n")[0].split(": ", 1)[1].split())


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--plan", choices=sorted(PLANS), default="screen", help="the (condition, world, seeds) to run (default screen)"
    )
    p.add_argument(
        "--out",
        default="runs/learned_prey",
        help="output folder: runs, evaluations, summaries (default runs/learned_prey)",
    )
    p.add_argument("--gpus", type=int, default=1, help="GPUs to spread the tasks over (0: the CPU)")
    p.add_argument(
        "--per-gpu",
        type=int,
        default=2,
        help="evaluations at once per GPU (trainings that may share a process run as one population per GPU)",
    )
    p.add_argument("--episodes", type=int, default=50, help="evaluation episodes per evaluation seed")
    p.add_argument("--eval-seeds", type=int, nargs="+", default=[0, 1], help="evaluation seeds (default 0 1)")
    p.add_argument(
        "--commit", default=None, help="the commit of a copy without git history (a checkout's own is read from git)"
    )
    p.add_argument(
        "--report",
        metavar="RESULTS",
        default=None,
        help="only copy a finished --out into the folder RESULTS, with curves.csv and curves.png",
    )


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study learned-prey`: the study's own options (after its name in `args.argv`) parsed
    again by `main`."""
    return main(study_options(args.argv, "learned-prey"), command=command_line(args.argv))


def main(argv: list[str] | None = None, command: str | None = None) -> int:
    """Run the study with the options `argv` (default: this process's), recording `command` (default:
    `python benchmarks/learned_prey.py` and `argv`, the script the committed results name)."""
    p = argparse.ArgumentParser(description=DESCRIPTION)
    add_arguments(p)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    if args.report:
        report(args.out, args.report)
        return 0
    devices = task_devices(args.gpus)
    jobs = args.per_gpu if devices[0] != "cpu" else 1  # Warp's CPU kernels take one thread each
    plan = PLANS[args.plan]
    start = time.perf_counter()
    trainings = training_tasks(args.out, plan)
    ran = [False] * len(trainings)

    def trained(i: int, result: dict, kept: bool) -> None:
        ran[i] = not kept

    print(f"learned_prey: {sum(not read_finished(args.out, t)[0] for t in trainings)} trainings", flush=True)
    results = run_jobs(
        run_training_task,
        trainings,
        args.out,
        jobs=jobs,
        devices=devices,
        label="train",
        on_result=trained,
        report=lambda line: print(line, flush=True),
    ).results
    train_s = time.perf_counter() - start
    evaluations = eval_tasks(args.out, plan, trainings, args.episodes, args.eval_seeds, args.commit)

    def write_evaluation(i: int, record: dict, kept: bool) -> None:
        path = os.path.join(args.out, "eval", f"{evaluations[i]['condition']}-{evaluations[i]['world']}.json")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with atomic_open(path) as f:
            json.dump(record, f, indent=1)

    run_jobs(
        run_eval_task,
        evaluations,
        args.out,
        jobs=jobs,
        devices=devices,
        label="eval",
        on_result=write_evaluation,
        report=lambda line: print(line, flush=True),
    )
    rows = summarize(args.out, plan)
    record = {
        "command": command or command_line(["benchmarks/learned_prey.py", *argv], os.path.basename(sys.executable)),
        "git": git_info(args.commit),
        "machine": machine_info(devices[0]),
        "gpus": args.gpus,
        "per_gpu": args.per_gpu,
        "measure": "captures per prey per episode against NaivChase (lower is better); learned: mean over "
        "training seeds of each seed's mean, 95% t interval over training seeds; baselines: "
        "over evaluation seeds; evaluated with spawn_heading='paper' in the condition's world",
        "episodes_per_eval_seed": args.episodes,
        "eval_seeds": args.eval_seeds,
        "conditions": {c: CONDITIONS[c] for c, _, _ in plan},
        "worlds": WORLDS,
        "train_wall_s": round(train_s, 1),
        "wall_s": round(time.perf_counter() - start, 1),
        # The trainings this call ran (not those kept from an earlier one).
        "trainings": [
            {"condition": t["condition"], "world": t["world"], "seed": t["seed"], "run_dir": t["run_dir"], **r}
            for t, r, now in zip(trainings, results, ran)
            if now
        ],
        "rows": rows,
    }
    with atomic_open(os.path.join(args.out, f"learned_prey_{args.plan}.json")) as f:
        json.dump(record, f, indent=1)
    with atomic_open(os.path.join(args.out, f"learned_prey_{args.plan}.csv"), newline="") as f:
        w = csv.writer(f)
        w.writerow(["condition", "world", "policy", "seed", "captures_per_prey"])
        for r in rows:
            for s, v in zip(r["seeds"], r["learned"]["values"]):
                w.writerow([r["condition"], r["world"], "learned", s, v])
            for b in BASELINES:
                for s, v in zip(args.eval_seeds, r[b]["values"]):
                    w.writerow([r["condition"], r["world"], b, f"eval{s}", v])
    print(
        f"{'condition':>22} {'world':>5} {'learned':>14} {'random':>12} {'constant':>12} {'turnaway':>12} "
        f"{'L/TA':>6} {'L/const':>7}"
    )
    for r in rows:
        print(
            f"{r['condition']:>22} {r['world']:>5} {fmt(r['learned']):>14} {fmt(r['random']):>12} "
            f"{fmt(r['constant']):>12} {fmt(r['turnaway']):>12} {r['learned_over_turnaway']:6.2f} "
            f"{r['learned_over_constant']:7.2f}"
        )
    return 0


def report(out: str, results: str, every: int = 5) -> None:
    """Copy a finished `out`'s summaries and evaluations into `results` (a committed folder) with the
    runs' training curves (`curves.csv`: every `every`-th iteration of each run's progress.csv) and
    their figure (`curves.png`: training captures per prey, mean and range over seeds). Summaries and
    evaluations already in `results` are kept as they are (they may carry added provenance)."""
    import glob
    import shutil

    os.makedirs(os.path.join(results, "eval"), exist_ok=True)
    for pattern, folder in (
        (os.path.join(out, "learned_prey_*.*"), results),
        (os.path.join(out, "eval", "*.json"), os.path.join(results, "eval")),
    ):
        for path in glob.glob(pattern):
            if not os.path.exists(os.path.join(folder, os.path.basename(path))):
                shutil.copy(path, folder)
    columns = ("iteration", "agent_steps", "captures_per_prey", "entropy", "value_loss")
    curves: dict[str, dict[str, list]] = {}
    with open(os.path.join(results, "curves.csv"), "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(("run",) + columns)
        for run in sorted(glob.glob(os.path.join(out, "runs", "*", "progress.csv"))):
            name = os.path.basename(os.path.dirname(run))
            with open(run, encoding="utf-8") as g:
                rows = [r for r in csv.DictReader(g) if r["captures_per_prey"] not in ("", None)]
            kept = rows[::every] + ([rows[-1]] if rows and (len(rows) - 1) % every else [])
            for r in kept:
                writer.writerow([name] + [r[c] for c in columns])
            condition = name.rsplit("-s", 1)[0]
            curves.setdefault(condition, {}).setdefault(
                name, [(float(r["agent_steps"]), float(r["captures_per_prey"])) for r in kept]
            )
    _plot_curves(curves, os.path.join(results, "curves.png"))


def _plot_curves(curves: dict[str, dict[str, list]], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    worlds = sorted({c.rsplit("-", 1)[1] for c in curves})
    fig, axes = plt.subplots(1, len(worlds), figsize=(5.2 * len(worlds), 4.2), squeeze=False)
    for ax, world in zip(axes[0], worlds):
        ax.set_prop_cycle(color=plt.get_cmap("tab20")(np.arange(20)))
        for condition in sorted(c for c in curves if c.endswith("-" + world)):
            runs = list(curves[condition].values())
            n = min(len(r) for r in runs)
            x = np.array([p[0] for p in runs[0][:n]]) / 1e6
            y = np.array([[p[1] for p in r[:n]] for r in runs])
            (line,) = ax.plot(x, y.mean(0), lw=1.3, label=f"{condition.rsplit('-', 1)[0]} ({len(runs)} seeds)")
            ax.fill_between(x, y.min(0), y.max(0), color=line.get_color(), alpha=0.15, lw=0)
        ax.set(title=f"world {world}", xlabel="prey-steps (millions)", ylabel="training captures per prey per episode")
        ax.legend(fontsize=6)
    fig.suptitle(
        "Training curves: mean over seeds, band = range over seeds (training worlds: their own spawn headings)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
