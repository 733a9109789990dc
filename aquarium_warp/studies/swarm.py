"""The swarm study: can collective behaviour pay in Aquarium, and does it emerge in learned prey?
(`aquarium-warp study swarm`)

Part 1, the scenario screen (heuristics, no training). In 360-degree worlds, captures per prey per
episode and the swarm measures of random, constant-heading, TurnAway and Boids prey (Boids: Reynolds
flocking over the seen prey, fleeing a seen predator; the positive control of the measures), against
NaivChase with confusion (a uniformly random visible target) and without it (the nearest), over
density (prey per 800 x 800 torus), prey view distance and predator speed. A world's collective
payoff is Boids' captures over TurnAway's: below 1, flocking lowers captures there. The scenario of
part 2 is chosen from it.

Part 2, learned prey (the learned-prey recipe: ego observations, random spawn headings, entropy 0.01)
in the scenario world, `--seeds` training seeds per condition:

| condition | what differs from `swarm` | rules out |
|---|---|---|
| `swarm` | - (`SCENARIO`, N = 32) | |
| `no-neighbours` | prey observe no prey (0 prey slots) | structure without interaction |
| `no-attack` | trained against a random predator (one that never hunts) | structure not induced by predation |
| `no-penalty` | no capture penalty (a capture still ends the prey's life in training) | the penalty's role |
| `no-confusion` | trained against NaivChase without confusion | a confusion-driven benefit |
| `sparse` | N = 8 (a quarter of the density) | the density dose |
| `swarm-2x` | twice the iterations | a budget that has not plateaued |
| `slow-predator` | N = 16, predator max speed 3.5 (the prey's is 4) | the screen's world where flocking pays |
| `slow-predator-no-neighbours` | the same, 0 prey slots | its neighbour control |

(`no-attack` and `swarm-2x` were added after the first run, at eb9c892: its `no-predation` control, a
zero penalty, turned out not to remove predation, since training ends a captured prey's life. The two
`slow-predator` conditions were added after the screen's results, at 1d9a73b.)

Every trained policy is evaluated in its own world against NaivChase, with its prey slots emptied
(the neighbour ablation, `blind`), and against NaivChase without confusion, beside the four
heuristics; the swarm measures are read against uniformly random prey in the same arena.

Primary measure, declared before any training run: the aggregation index R = mean nearest-neighbour
distance / the uniformly random prey's, per training seed (R < 1: aggregation, R > 1: spacing).
Secondary: local alignment, milling, largest-group fraction, captures per prey. Statistics: mean and
95% t interval over training seeds, differences between conditions with 95% Welch intervals (paired
over seeds for the ablation), and an equivalence margin for a "no effect" reading (`MARGINS`).

Tasks (a screen world, a training run, a policy's evaluation) keep their results in `--out`; a rerun,
or one with more `--seeds`, runs only what is missing.
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import json
import math
import multiprocessing
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence

from ..arguments import check_distinct, check_int, number_list
from ..records import command_line, provenance
from .statistics import difference, equivalence, finite, mean_interval

# The scenario: prey see all around, 200 px (reacting pays only with rear vision and range, see
# docs/learned-prey.md); everything else is the paper's world.
SCENARIO = ("env.prey.fov_angle=360", "env.prey.view_distance=200")
RECIPE = ("env.observation_frame=ego", "env.spawn_heading=random")
CONDITIONS: dict[str, dict] = {
    "swarm": {"prey": 32, "sets": (), "opponent": "naivchase"},
    "no-neighbours": {"prey": 32, "sets": ("env.prey.prey_slots=0",), "opponent": "naivchase"},
    "no-attack": {"prey": 32, "sets": (), "opponent": "random"},
    "no-penalty": {"prey": 32, "sets": ("env.prey_capture_penalty=0",), "opponent": "naivchase"},
    "no-confusion": {"prey": 32, "sets": (), "opponent": "naivchase-noconfusion"},
    "sparse": {"prey": 8, "sets": (), "opponent": "naivchase"},
    "swarm-2x": {"prey": 32, "sets": (), "opponent": "naivchase", "budget": 2},
    # Where the screen finds that flocking pays (a predator slower than the prey, N <= 16, 200 px).
    "slow-predator": {"prey": 16, "sets": ("env.predator.max_speed=3.5",), "opponent": "naivchase"},
    "slow-predator-no-neighbours": {"prey": 16, "sets": ("env.predator.max_speed=3.5", "env.prey.prey_slots=0"),
                                    "opponent": "naivchase"},
}
# "a minus b" comparisons between conditions (each against NaivChase): a treatment and its control.
CONTRASTS = (("swarm", "no-neighbours"), ("swarm", "no-attack"), ("swarm", "no-penalty"), ("swarm", "no-confusion"),
             ("swarm", "sparse"), ("swarm", "swarm-2x"), ("slow-predator", "slow-predator-no-neighbours"))
# Evaluations of each trained policy: label -> (predator, prey slots emptied)
EVALUATIONS = {"naivchase": ("naivchase", False), "blind": ("naivchase", True),
               "noconfusion": ("naivchase-noconfusion", False)}
HEURISTIC_PREY = ("random", "constant", "turnaway", "boids")
PREDATORS = ("naivchase", "naivchase-noconfusion")
MEASURES = ("captures_per_prey", "swarm_nn_mean", "swarm_local_alignment", "swarm_milling", "swarm_polarization",
            "swarm_largest_group", "swarm_groups")
PRIMARY = "aggregation_index"
# Equivalence margins, declared with the design: |difference| inside the margin reads "no effect".
MARGINS = {"aggregation_index": 0.05, "swarm_local_alignment": 0.05, "captures_per_prey_relative": 0.10}
# Per-prey training budget: about 1.3e8 prey-steps and 500 PPO iterations at either density.
TRAIN_AGENT_STEPS = 32 * 256 * 32 * 500


HELP = "can collective behaviour pay, and does it emerge in learned prey? (heuristic screen, learned prey, controls)"
DESCRIPTION = ("Part screen: heuristic prey (random, constant, TurnAway, Boids) against NaivChase with and without "
               "confusion over density, prey view distance and predator speed, with the aggregation index against "
               "uniformly random prey. Part learned: train --seeds prey runs per condition (the swarm scenario and its "
               "controls), evaluate each with and without its prey slots and against NaivChase without confusion, "
               "and compare the conditions with 95% intervals and declared equivalence margins. Tasks keep their "
               "results in --out (tasks/); a rerun runs only what is missing. Writes summary.json, screen.csv, "
               "learned.csv and figures.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--part", choices=("screen", "learned", "all"), default="all",
                        help="the heuristic scenario screen, the learned prey with their controls, or both")
    parser.add_argument("--prey-counts", default="8,16,32,64", help="screen: prey per world (density)")
    parser.add_argument("--view-distances", default="100,200,400", help="screen: prey view distances, px (360 deg)")
    parser.add_argument("--predator-speeds", default="5,4.5,4,3.5",
                        help="screen: predator max speeds (the prey's is 4)")
    parser.add_argument("--conditions", default=",".join(CONDITIONS), help="learned: conditions to train")
    parser.add_argument("--seeds", type=int, default=5, help="learned: training seeds per condition (>= 2)")
    parser.add_argument("--iterations", type=int, default=500, help="learned: PPO iterations per run")
    parser.add_argument("--train-worlds", type=int, default=None,
                        help="learned: worlds per training run (default: TRAIN_AGENT_STEPS / (prey x 32 x iterations))")
    parser.add_argument("--episodes", type=int, default=64, help="evaluation episodes per evaluation seed")
    parser.add_argument("--eval-seeds", type=int, default=2, help="evaluation seeds")
    parser.add_argument("--max-steps", type=int, default=3000, help="episode length (docs/model.md: 3000)")
    parser.add_argument("--gpus", type=int, default=None, help="GPUs to spread tasks over (default: all; 0: CPU)")
    parser.add_argument("--per-gpu", type=int, default=4, help="tasks at a time per GPU")
    parser.add_argument("--train-preset", default="paper", help="learned: the preset trained from")
    parser.add_argument("--train-set", action="append", default=[], metavar="KEY=VALUE",
                        help="learned: extra `train --set` assignments (tiny smoke runs)")
    parser.add_argument("--commit", default=None, help="the commit to record (a copy without git history)")
    parser.add_argument("--no-figures", action="store_true", help="no matplotlib figures")
    parser.add_argument("--out", default="swarm_study", help="output directory")


def check(args) -> None:
    """A one-line `ValueError` naming the option unless every option is in range; sets the parsed lists
    (`prey_count_list`, `view_list`, `speed_list`, `condition_list`)."""
    conditions = [c for c in args.conditions.split(",") if c]
    unknown = [c for c in conditions if c not in CONDITIONS]
    if unknown or not conditions:
        raise ValueError(f"--conditions={args.conditions!r}: choose from {', '.join(CONDITIONS)}")
    check_distinct("--conditions", conditions)
    for name, value, low in (("--seeds", args.seeds, 2), ("--iterations", args.iterations, 1),
                             ("--episodes", args.episodes, 1), ("--eval-seeds", args.eval_seeds, 1),
                             ("--max-steps", args.max_steps, 1), ("--per-gpu", args.per_gpu, 1)):
        check_int(name, value, low)
    if args.train_worlds is not None:
        check_int("--train-worlds", args.train_worlds, 1)
    if args.gpus is not None:
        check_int("--gpus", args.gpus, 0)
    args.prey_count_list = number_list(args.prey_counts, int, "--prey-counts", 2)
    args.view_list = number_list(args.view_distances, float, "--view-distances", 1)
    args.speed_list = number_list(args.predator_speeds, float, "--predator-speeds", 0, low_open=True)
    for name, values in (("--prey-counts", args.prey_count_list), ("--view-distances", args.view_list),
                         ("--predator-speeds", args.speed_list)):
        check_distinct(name, values)  # a repeated value would name one task twice
    args.condition_list = conditions


# ---- tasks and their kept results -------------------------------------------------------------------

def task_path(out: str, kind: str, name: str) -> str:
    return os.path.join(out, "tasks", kind, f"{name}.json")


def read_task(path: str) -> dict | None:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        return None


def write_task(path: str, record: dict) -> None:
    from ..atomic import atomic_open
    from ..records import json_safe

    os.makedirs(os.path.dirname(path), exist_ok=True)
    with atomic_open(path) as f:
        json.dump(json_safe(record), f, indent=1)


def screen_config(n: int, view: float, predator_speed: float, max_steps: int):
    import dataclasses

    from ..config import AquariumConfig

    cfg = AquariumConfig(prey_count=n, max_prey=max(n, 20), max_steps=max_steps, spawn_heading="random")
    return cfg.replace(prey=dataclasses.replace(cfg.prey, fov_angle=360.0, view_distance=view),
                       predator=dataclasses.replace(cfg.predator, max_speed=predator_speed))


def per_seed_values(result: dict, prey_label: str, predator_label: str) -> dict[str, list[float]]:
    """`{measure: [mean over the episodes of each evaluation seed]}` of one (prey, predator) pair."""
    seeds = sorted({r["seed"] for r in result["episodes"]})
    out: dict[str, list[float]] = {}
    for m in MEASURES:
        out[m] = []
        for s in seeds:
            values = [r[m] for r in result["episodes"] if r["prey_policy"] == prey_label
                      and r["predator_policy"] == predator_label and r["seed"] == s and not math.isnan(r[m])]
            out[m].append(sum(values) / len(values) if values else float("nan"))
    return out


def uniform_measures(cfg, device: str, seed: int = 0) -> dict[str, float]:
    """Swarm measures of uniformly random prey (random headings) in `cfg`'s arena at its prey count."""
    from .swarm_size import uniform_baseline

    snapshots = max(8, min(256, 65536 // cfg.prey_count))
    return uniform_baseline(cfg, snapshots, None, device, seed=seed)


def run_heuristics(cfg, task: dict) -> dict:
    """Every heuristic prey against every predator of `PREDATORS` in `cfg`, with the uniform baseline."""
    from ..training.evaluate import evaluate_policies

    result = evaluate_policies(list(HEURISTIC_PREY), list(PREDATORS), cfg, episodes=task["episodes"],
                               seeds=range(task["eval_seeds"]), device=task["device"])
    values = {f"{p}|{q}": per_seed_values(result, p, q) for p in HEURISTIC_PREY for q in PREDATORS}
    return {"task": {k: v for k, v in task.items() if k != "device"}, "values": values,
            "uniform": uniform_measures(cfg, task["device"]), "machine": result["machine"], "env": cfg.to_dict()}


def run_screen_task(task: dict) -> dict:
    return run_heuristics(screen_config(task["prey"], task["view"], task["predator_speed"], task["max_steps"]), task)


def run_eval_task(task: dict) -> dict:
    """One trained policy in its own world: each of `EVALUATIONS`."""
    from ..config import AquariumConfig
    from ..training.evaluate import common_policy_env, evaluate_policies

    cfg = common_policy_env([task["policy"]], AquariumConfig()).replace(max_steps=task["max_steps"])
    values, machine = {}, None
    for label, (predator, blind) in EVALUATIONS.items():
        if blind and cfg.prey.prey_slots == 0:
            continue  # no prey slots to empty
        result = evaluate_policies([f"learned={task['policy']}"], [predator], cfg, episodes=task["episodes"],
                                   seeds=range(task["eval_seeds"]), device=task["device"],
                                   blind_to={"prey": "prey"} if blind else None)
        values[label] = per_seed_values(result, "learned", predator)
        machine = result["machine"]
    return {"task": {k: v for k, v in task.items() if k != "device"}, "values": values,
            "uniform": uniform_measures(cfg, task["device"]), "machine": machine, "env": cfg.to_dict()}


def run_baseline_task(task: dict) -> dict:
    """The heuristic prey in a condition's world (its first seed's policy's): the same evaluation seeds."""
    from ..config import AquariumConfig
    from ..training.evaluate import common_policy_env

    cfg = common_policy_env([task["policy"]], AquariumConfig()).replace(max_steps=task["max_steps"])
    return run_heuristics(cfg, task)


def _in_worker(function: Callable[[dict], dict], task: dict, path: str) -> str:
    write_task(path, function(task))
    return path


def gpu_count(requested: int | None) -> int:
    if requested is not None:
        return requested
    import torch

    return torch.cuda.device_count()


def run_in_processes(function: Callable[[dict], dict], tasks: Sequence[tuple[dict, str]], gpus: int,
                     per_gpu: int, label: str) -> None:
    """Run `(task, result path)` pairs in spawned worker processes, `per_gpu` per GPU."""
    if not gpus:  # the CPU: one task at a time, here (Warp's CPU kernels take one thread each)
        for done, (task, path) in enumerate(tasks, 1):
            _in_worker(function, dict(task, device="cpu"), path)
            print(f"  {label} {done}/{len(tasks)}: {os.path.basename(path)}", flush=True)
        return
    slots = gpus * per_gpu
    context = multiprocessing.get_context("spawn")
    with futures.ProcessPoolExecutor(min(slots, len(tasks)), mp_context=context) as pool:
        jobs = []
        for k, (task, path) in enumerate(tasks):
            device = f"cuda:{k % gpus}"
            jobs.append(pool.submit(_in_worker, function, dict(task, device=device), path))
        for done, job in enumerate(futures.as_completed(jobs), 1):
            print(f"  {label} {done}/{len(jobs)}: {os.path.basename(job.result())}", flush=True)


# ---- training ---------------------------------------------------------------------------------------

def run_dir(out: str, condition: str, seed: int) -> str:
    return os.path.join(out, "runs", f"{condition}-s{seed}")


def policy_path(out: str, condition: str, seed: int) -> str:
    return os.path.join(run_dir(out, condition, seed), "exported", "policy.pt")


def train_command(args, condition: str, seed: int, device: str) -> list[str]:
    spec = CONDITIONS[condition]
    worlds = args.train_worlds or max(1, TRAIN_AGENT_STEPS // (spec["prey"] * 32 * args.iterations))
    iterations = args.iterations * spec.get("budget", 1)
    cmd = [sys.executable, "-m", "aquarium_warp", "train", "--preset", args.train_preset, "--seed", str(seed),
           "--device", device, "--quiet", "--export", "jit", "--log-dir", run_dir(args.out, condition, seed),
           "--overwrite", "--save-interval", str(iterations), "--prey", str(spec["prey"]), "--num-worlds",
           str(worlds), "--iterations", str(iterations), "--entropy", "0.01",
           "--predator-policy", spec["opponent"]]
    for s in SCENARIO + RECIPE + tuple(spec["sets"]) + tuple(args.train_set):
        cmd += ["--set", s]
    return cmd


def run_trainings(args, gpus: int) -> list[dict]:
    """Train every (condition, seed) without an exported policy; `per_gpu` at a time on each GPU."""
    jobs = [(c, s) for c in args.condition_list for s in range(args.seeds)
            if not os.path.exists(policy_path(args.out, c, s))]
    slots = gpus * args.per_gpu if gpus else 1

    def one(k: int, condition: str, seed: int) -> dict:
        gpu = k % gpus if gpus else None
        device = "cuda:0" if gpu is not None else "cpu"
        cmd = train_command(args, condition, seed, device)
        env = dict(os.environ, NCCL_NVLS_ENABLE="0", GIT_PYTHON_REFRESH="quiet")
        if gpu is not None:
            env["CUDA_VISIBLE_DEVICES"] = str(gpu)
        log = os.path.join(args.out, "logs", f"train-{condition}-s{seed}.log")
        os.makedirs(os.path.dirname(log), exist_ok=True)
        start = time.perf_counter()
        with open(log, "w", encoding="utf-8") as f:
            rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=env).returncode
        seconds = round(time.perf_counter() - start, 1)
        print(f"  train {condition} s{seed}: rc={rc} {seconds} s", flush=True)
        if rc != 0:
            raise RuntimeError(f"training {condition} seed {seed} failed (rc={rc}); see {log}")
        return {"condition": condition, "seed": seed, "command": shlex.join(cmd), "seconds": seconds}

    with futures.ThreadPoolExecutor(max(1, min(slots, len(jobs) or 1))) as pool:
        return list(pool.map(lambda a: one(*a), [(k, c, s) for k, (c, s) in enumerate(jobs)]))


# ---- statistics (statistics.py: Student-t intervals, Welch or paired differences, TOST) ---------------

def interval(values: Sequence[float]) -> dict:
    """The finite `values` (result files write a NaN, a measure with no sample, as null): their `mean`,
    the half-width of its 95% Student-t interval (`ci95`, None below two values), `n` and the `values`."""
    v = finite(values).tolist()
    mean, ci95 = mean_interval(v)
    return {"mean": mean, "ci95": ci95, "n": len(v), "values": v}


def comparison(a: Sequence[float], b: Sequence[float], paired: bool, margin: float | None) -> dict:
    """mean(a) - mean(b) with the half-width of its 95% interval (`paired`: of the matched differences,
    else Welch) and, with a `margin`, whether the TOST at 5% finds them equivalent within it (a margin
    that is not a positive number, from a condition without captures, finds nothing equivalent)."""
    d = difference(a, b, paired=paired)
    out = {"difference": d["difference"], "ci95": d["high"] - d["difference"], "paired": paired}
    if margin is not None:
        out["margin"] = margin
        out["equivalent"] = bool(margin > 0) and equivalence(a, b, margin, paired=paired)["equivalent"]
    return out


# ---- the summary ------------------------------------------------------------------------------------

def _values(record: dict, key: str, measure: str) -> list[float]:
    """One value per evaluation seed of `measure` (the aggregation index from the mean NN distance)."""
    if measure == PRIMARY:
        return (finite(record["values"][key]["swarm_nn_mean"]) / record["uniform"]["nn_mean"]).tolist()
    return record["values"][key][measure]


def seed_value(record: dict, key: str, measure: str) -> float:
    """The mean over evaluation seeds (NaN without a finite value)."""
    return mean_interval(_values(record, key, measure))[0]


def summarize_screen(out: str, tasks: list[dict]) -> list[dict]:
    rows = []
    for task in tasks:
        record = read_task(task_path(out, "screen", task["name"]))
        if record is None:
            continue
        for p in HEURISTIC_PREY:
            for q in PREDATORS:
                key = f"{p}|{q}"
                row = {"prey_count": task["prey"], "view_distance": task["view"],
                       "predator_speed": task["predator_speed"], "prey_policy": p, "predator_policy": q}
                for m in MEASURES + (PRIMARY,):
                    row[m] = interval(_values(record, key, m))
                row["uniform"] = record["uniform"]
                rows.append(row)
    return rows


def summarize_learned(out: str, conditions: Sequence[str], seeds: int) -> dict:
    """Per condition and evaluation: per-seed values and their mean with 95% interval; the baselines;
    and the pre-declared comparisons."""
    per: dict[str, dict] = {}
    for c in conditions:
        found = [read_task(task_path(out, "eval", f"{c}-s{s}")) for s in range(seeds)]
        records = [r for r in found if r is not None]
        if not records:
            continue
        entry: dict = {"seeds": [r["task"]["seed"] for r in records], "uniform": records[0]["uniform"]}
        for label in EVALUATIONS:
            if label in records[0]["values"]:
                entry[label] = {m: interval([seed_value(r, label, m) for r in records])
                                for m in MEASURES + (PRIMARY,)}
        baseline = read_task(task_path(out, "baseline", c))
        if baseline is not None:  # over evaluation seeds
            for label in baseline["values"]:
                entry[label] = {m: interval(_values(baseline, label, m)) for m in MEASURES + (PRIMARY,)}
        per[c] = entry
    comparisons = []

    def compare(what: str, a: dict, b: dict, measure: str, paired: bool) -> None:
        margin = MARGINS.get(measure)
        if measure == "captures_per_prey":
            margin = MARGINS["captures_per_prey_relative"] * b[measure]["mean"]
        d = comparison(a[measure]["values"], b[measure]["values"], paired, margin)
        comparisons.append({"comparison": what, "measure": measure, **d})

    for m in (PRIMARY, "swarm_local_alignment", "swarm_milling", "captures_per_prey"):
        for c, entry in per.items():
            for label, what in (("blind", "neighbour-ablated"), ("noconfusion", "vs no-confusion")):
                if label in entry:
                    compare(f"{c}: vs NaivChase minus {what} (paired)", entry["naivchase"], entry[label], m, True)
        for a, b in CONTRASTS:
            if a in per and b in per:
                compare(f"{a} minus {b}", per[a]["naivchase"], per[b]["naivchase"], m, False)
        for c in ("swarm", "slow-predator"):
            for prey in HEURISTIC_PREY:
                if c in per and f"{prey}|naivchase" in per[c]:
                    compare(f"{c} minus {prey} prey", per[c]["naivchase"], per[c][f"{prey}|naivchase"], m, False)
    return {"conditions": per, "comparisons": comparisons}


def screen_tasks(args) -> list[dict]:
    return [{"name": f"n{n}-v{int(v)}-p{s:g}", "prey": n, "view": v, "predator_speed": s, "episodes": args.episodes,
             "eval_seeds": args.eval_seeds, "max_steps": args.max_steps}
            for n in args.prey_count_list for v in args.view_list for s in args.speed_list]


def eval_tasks(args) -> list[dict]:
    return [{"name": f"{c}-s{s}", "condition": c, "seed": s, "policy": policy_path(args.out, c, s),
             "episodes": args.episodes, "eval_seeds": args.eval_seeds, "max_steps": args.max_steps}
            for c in args.condition_list for s in range(args.seeds)]


def baseline_tasks(args) -> list[dict]:
    return [{"name": c, "condition": c, "policy": policy_path(args.out, c, 0), "episodes": args.episodes,
             "eval_seeds": args.eval_seeds, "max_steps": args.max_steps} for c in args.condition_list]


def run(args) -> int:
    check(args)
    gpus = gpu_count(args.gpus)
    os.makedirs(args.out, exist_ok=True)
    start = time.perf_counter()
    summary: dict = {"design": {"scenario": SCENARIO, "recipe": RECIPE, "conditions": CONDITIONS,
                                "evaluations": EVALUATIONS, "primary": PRIMARY, "margins": MARGINS,
                                "train_agent_steps": TRAIN_AGENT_STEPS, "iterations": args.iterations,
                                "episodes": args.episodes, "eval_seeds": args.eval_seeds,
                                "max_steps": args.max_steps, "seeds": args.seeds}}
    if args.part in ("screen", "all"):
        tasks = screen_tasks(args)
        todo = [(t, task_path(args.out, "screen", t["name"])) for t in tasks
                if read_task(task_path(args.out, "screen", t["name"])) is None]
        print(f"study swarm: screen, {len(tasks)} worlds ({len(todo)} to run)", flush=True)
        run_in_processes(run_screen_task, todo, gpus, args.per_gpu, "screen")
        summary["screen"] = summarize_screen(args.out, tasks)
    if args.part in ("learned", "all"):
        print(f"study swarm: training {len(args.condition_list)} conditions x {args.seeds} seeds", flush=True)
        summary["trainings"] = run_trainings(args, gpus)
        tasks = eval_tasks(args)
        todo = [(t, task_path(args.out, "eval", t["name"])) for t in tasks
                if read_task(task_path(args.out, "eval", t["name"])) is None]
        print(f"study swarm: evaluating {len(tasks)} policies ({len(todo)} to run)", flush=True)
        run_in_processes(run_eval_task, todo, gpus, args.per_gpu, "eval")
        tasks = baseline_tasks(args)
        todo = [(t, task_path(args.out, "baseline", t["name"])) for t in tasks
                if read_task(task_path(args.out, "baseline", t["name"])) is None]
        run_in_processes(run_baseline_task, todo, gpus, args.per_gpu, "baselines")
        summary["learned"] = summarize_learned(args.out, args.condition_list, args.seeds)
    summary.update(provenance("cuda:0" if gpus else "cpu", command_line(args.argv), commit=args.commit),
                   wall_s=round(time.perf_counter() - start, 1))
    write_task(os.path.join(args.out, "summary.json"), summary)
    write_tables(args.out, summary)
    if not args.no_figures:
        plot(args.out, summary)
    print(f"study swarm: wrote {os.path.join(args.out, 'summary.json')} ({summary['wall_s']} s)")
    return 0


# ---- tables and figures -----------------------------------------------------------------------------

def write_tables(out: str, summary: dict) -> None:
    """`screen.csv` (one row per world, prey and predator: means and interval half-widths) and
    `learned.csv` (one row per condition, evaluation and training seed: the per-seed values)."""
    import csv

    from ..atomic import atomic_open

    if summary.get("screen"):
        columns = ["prey_count", "view_distance", "predator_speed", "prey_policy", "predator_policy"]
        with atomic_open(os.path.join(out, "screen.csv"), newline="") as f:
            w = csv.writer(f)
            w.writerow(columns + [f"{m}{s}" for m in MEASURES + (PRIMARY,) for s in ("", "_ci95")])
            for row in summary["screen"]:
                w.writerow([row[c] for c in columns] + [v for m in MEASURES + (PRIMARY,)
                                                        for v in (row[m]["mean"], row[m]["ci95"])])
    learned = summary.get("learned", {}).get("conditions", {})
    if learned:
        with atomic_open(os.path.join(out, "learned.csv"), newline="") as f:
            w = csv.writer(f)
            w.writerow(["condition", "evaluation", "seed"] + list(MEASURES + (PRIMARY,)))
            for c, entry in learned.items():
                for label in EVALUATIONS:
                    if label in entry:
                        for k, seed in enumerate(entry["seeds"]):
                            w.writerow([c, label, seed] + [entry[label][m]["values"][k]
                                                           if k < len(entry[label][m]["values"]) else ""
                                                           for m in MEASURES + (PRIMARY,)])


def plot(out: str, summary: dict) -> None:
    """`screen.png`: Boids' captures over TurnAway's against density, per view distance, predator speed
    and confusion; `learned.png`: the primary measure and captures per condition with 95% intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summary.get("screen") or []
    if rows:
        speeds = sorted({r["predator_speed"] for r in rows})
        fig, axes = plt.subplots(len(PREDATORS), len(speeds), figsize=(3.6 * len(speeds), 3.2 * len(PREDATORS)),
                                 sharey=True, squeeze=False)
        for i, (speed, predator) in enumerate((s, q) for s in speeds for q in PREDATORS):
            ax = axes[i % len(PREDATORS), i // len(PREDATORS)]
            for view in sorted({r["view_distance"] for r in rows}):
                pick = {(r["prey_count"], r["prey_policy"]): r for r in rows if r["predator_speed"] == speed
                        and r["view_distance"] == view and r["predator_policy"] == predator}
                counts = sorted({n for n, _ in pick})
                ratio = [pick[(n, "boids")]["captures_per_prey"]["mean"]
                         / max(pick[(n, "turnaway")]["captures_per_prey"]["mean"], 1e-9) for n in counts]
                ax.plot(counts, ratio, "o-", label=f"view {view:g} px")
            ax.axhline(1.0, color="grey", lw=0.8)
            ax.set_xscale("log", base=2)
            ax.set_yscale("log")
            ax.set_title(f"predator speed {speed:g}, {predator}", fontsize=9)
            ax.set_xlabel("prey per world")
        axes[0, 0].set_ylabel("captures: Boids / TurnAway")
        axes[0, 0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(out, "screen.png"), dpi=120)
        plt.close(fig)
    learned = summary.get("learned", {}).get("conditions", {})
    if learned:
        fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
        for ax, measure in zip(axes, (PRIMARY, "captures_per_prey"), strict=True):
            labels, means, errs = [], [], []
            for c, entry in learned.items():
                for label in list(EVALUATIONS) + [f"{p}|naivchase" for p in HEURISTIC_PREY]:
                    if label in entry and (c == "swarm" or label in EVALUATIONS):
                        labels.append(f"{c}\n{label.replace('|naivchase', '')}")
                        means.append(entry[label][measure]["mean"])
                        errs.append(entry[label][measure]["ci95"] or 0.0)
            ax.bar(range(len(labels)), means, yerr=errs, capsize=3)
            ax.set_xticks(range(len(labels)), labels, rotation=90, fontsize=7)
            ax.set_ylabel(measure)
            if measure == PRIMARY:
                ax.axhline(1.0, color="grey", lw=0.8)
        fig.tight_layout()
        fig.savefig(os.path.join(out, "learned.png"), dpi=120)
        plt.close(fig)
