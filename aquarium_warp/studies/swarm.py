"""The swarm study: can collective behaviour pay in Aquarium, and does it emerge in learned prey?
(`aquarium-warp study swarm`)

Part 1, the scenario screen (heuristics, no training). In 360-degree worlds, captures per prey per
episode and the swarm measures of random, constant-heading, TurnAway and Boids prey (Boids: Reynolds
flocking over the seen prey, fleeing a seen predator; the positive control of the measures), against
NaivChase with confusion (a uniformly random visible target) and without it (the nearest), over
density (prey per 800 x 800 torus), prey view distance, predator speed and, with
`--capture-confusion`, the capture confusion c of docs/model.md step 5 (a contact captures with
probability 1 / (1 + c k), k the other prey within 100 px; the default 0 is the screen as first run:
its tasks keep their names and kept results). A world's collective payoff is Boids' captures over
TurnAway's: below 1, flocking lowers captures there. The scenario of part 2 is chosen from it.

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
| `confusion` | capture confusion c = 16 within 100 px (`CONFUSION`), NaivChase without target confusion | |
| `confusion-no-neighbours` | the same, 0 prey slots | structure without interaction |
| `confusion-no-predation` | the same, capture_probability 0 (never captures) | an untrained policy's grouping |
| `confusion-mild` | the same with c = 4 | the dose of capture confusion |
| `confusion-strong` | the same with c = 64 | the dose above |
| `confusion-strong-no-neighbours` | c = 64, 0 prey slots | its neighbour control |
| (`no-confusion`) | the same without capture confusion (c = 0): the condition above | capture confusion's role |

(`no-attack` and `swarm-2x` were added after the first run, at eb9c892: its `no-predation` control, a
zero penalty, turned out not to remove predation, since training ends a captured prey's life. The two
`slow-predator` conditions were added after the screen's results, at 1d9a73b. The four `confusion`
conditions were added after all of these had run: capture confusion (docs/model.md step 5) makes a
prey with others within 100 px harder to catch, a density-dependent capture rule (density dilution in
the sense of Olson, Knoester & Adami 2016, not Olson et al. 2013's perceptual confusion), which the
first run found missing for aggregation to pay. Their contrasts: `confusion` minus each of its controls and
minus `no-confusion`, the same world and predator without capture confusion.)

The design of the `confusion` conditions is declared here before any GPU run of them, from a CPU
screen at a tiny size (N = 32, 200 px, 1,000 steps, 4 episodes x 2 seeds, `--capture-confusion
0,1,4,16`). Boids' captures over TurnAway's at c = 0, 1, 4 and 16: against NaivChase at speed 5,
3.7, 3.5, 2.5 and 1.5; at speed 4, 5.2, 4.4, 3.7 and 1.5; against NaivChase without target
confusion at speed 5, 2.9, 2.1, 1.6 and 0.9. Only c = 16 against the nearest-target NaivChase
brought flocking below TurnAway, so that is the `confusion` world: a prey with one neighbour within
100 px is caught by a contact with probability 1/17, a lone prey always. Its predator in training and
in the comparisons (`evaluated`: the `noconfusion` evaluation) is NaivChase without target
confusion, so that capture confusion is the only confusion at work. `confusion-mild` (c = 4) is the
dose below it. The two `confusion-strong` conditions (c = 64) were added after those had run at 71f5ea7
(learned prey spaced out less as c grew, R 1.24, 1.20 and 1.06 at c = 0, 4 and 16, without
aggregating): the dose above, declared with the same primary measure before their run. Its
no-predation control is `confusion-no-predation`: with capture_probability 0 the value of c changes
nothing (tests/kernels/test_capture_confusion.py checks the trajectories bit for bit); that contrast
was added after the run.

Every trained policy is evaluated in its own world (the `confusion` conditions' with the capture
confusion they trained with) against NaivChase, with its prey slots emptied
(the neighbour ablation, `blind`), and against NaivChase without confusion, beside the four
heuristics; the swarm measures are read against uniformly random prey in the same arena.

Primary measure, declared before any training run: the aggregation index R = mean nearest-neighbour
distance / the uniformly random prey's, per training seed (R < 1: aggregation, R > 1: spacing).
Secondary: local alignment, milling, largest-group fraction, captures per prey. Statistics: mean and
95% t interval over training seeds, differences between conditions with 95% Welch intervals (paired
over seeds for the ablation), and an equivalence margin for a "no effect" reading (`MARGINS`).

Tasks (a screen world, a training run, a policy's evaluation, a condition's heuristics) run through
the studies' job runner (`jobs.run_jobs`), `--per-gpu` at a time on each of `--gpus` GPUs (0: one at
a time on the CPU), trainings in-process (`Trainer`, each into `runs/<condition>-s<seed>/`). Their
results are kept in `--out` (`finished/`); a rerun, one with more `--seeds` or on another number of
GPUs, runs only what is missing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from ..arguments import add_options, check_distinct, choice_list, from_options, number_list, option, plural
from ..checks import LARGEST
from ..jobs import read_finished, run_jobs, task_devices
from ..records import command_line, json_safe, provenance
from ..statistics import difference, equivalence, finite, interval, mean_interval
from . import common
from .common import policy_path, run_training_task

# The scenario: prey see all around, 200 px (reacting pays only with rear vision and range, see
# docs/learned-prey.md); everything else is the paper's world.
SCENARIO = ("env.prey.fov_angle=360", "env.prey.view_distance=200")


def capture_confusion_sets(c: float) -> tuple[str, ...]:
    """The `sets` of a world with capture confusion c within 100 px (docs/model.md step 5)."""
    return (f"env.capture_confusion={c:g}", "env.confusion_radius=100")


# Capture confusion of the `confusion` conditions, declared before their first run; and the doses.
CONFUSION = capture_confusion_sets(16)
STRONG_CONFUSION = capture_confusion_sets(64)
# The `confusion` conditions' predator, in training and in their comparisons (`evaluated`: the label
# of `EVALUATIONS` a condition is compared on; "naivchase" where absent).
NEAREST = {"opponent": "naivchase-noconfusion", "evaluated": "noconfusion"}
CONDITIONS: dict[str, dict] = {
    "swarm": {"prey": 32, "sets": (), "opponent": "naivchase"},
    "no-neighbours": {"prey": 32, "sets": ("env.prey.prey_slots=0",), "opponent": "naivchase"},
    "no-attack": {"prey": 32, "sets": (), "opponent": "random"},
    "no-penalty": {"prey": 32, "sets": ("env.prey_capture_penalty=0",), "opponent": "naivchase"},
    "no-confusion": {"prey": 32, "sets": (), **NEAREST},
    "sparse": {"prey": 8, "sets": (), "opponent": "naivchase"},
    "swarm-2x": {"prey": 32, "sets": (), "opponent": "naivchase", "budget": 2},
    # Where the screen finds that flocking pays (a predator slower than the prey, N <= 16, 200 px).
    "slow-predator": {"prey": 16, "sets": ("env.predator.max_speed=3.5",), "opponent": "naivchase"},
    "slow-predator-no-neighbours": {
        "prey": 16,
        "sets": ("env.predator.max_speed=3.5", "env.prey.prey_slots=0"),
        "opponent": "naivchase",
    },
    # A prey among many is harder to catch: can aggregation pay there?
    "confusion": {"prey": 32, "sets": CONFUSION, **NEAREST},
    "confusion-no-neighbours": {"prey": 32, "sets": CONFUSION + ("env.prey.prey_slots=0",), **NEAREST},
    "confusion-no-predation": {"prey": 32, "sets": CONFUSION + ("env.capture_probability=0",), **NEAREST},
    "confusion-mild": {"prey": 32, "sets": capture_confusion_sets(4), **NEAREST},
    "confusion-strong": {"prey": 32, "sets": STRONG_CONFUSION, **NEAREST},
    "confusion-strong-no-neighbours": {"prey": 32, "sets": STRONG_CONFUSION + ("env.prey.prey_slots=0",), **NEAREST},
}
# "a minus b" comparisons between conditions, both on a's `evaluated` label: a treatment and its control.
CONTRASTS = (
    ("swarm", "no-neighbours"),
    ("swarm", "no-attack"),
    ("swarm", "no-penalty"),
    ("swarm", "no-confusion"),
    ("swarm", "sparse"),
    ("swarm", "swarm-2x"),
    ("slow-predator", "slow-predator-no-neighbours"),
    ("confusion", "no-confusion"),
    ("confusion", "confusion-no-neighbours"),
    ("confusion", "confusion-no-predation"),
    ("confusion", "confusion-mild"),
    ("confusion-strong", "confusion"),
    ("confusion-strong", "confusion-strong-no-neighbours"),
    # Its no-predation control: with capture_probability 0, c changes nothing (the same trajectories).
    ("confusion-strong", "confusion-no-predation"),
)
# Evaluations of each trained policy: label -> (predator, prey slots emptied)
EVALUATIONS = {
    "naivchase": ("naivchase", False),
    "blind": ("naivchase", True),
    "noconfusion": ("naivchase-noconfusion", False),
}
HEURISTIC_PREY = ("random", "constant", "turnaway", "boids")
PREDATORS = ("naivchase", "naivchase-noconfusion")
MEASURES = (
    "captures_per_prey",
    "swarm_nn_mean",
    "swarm_local_alignment",
    "swarm_milling",
    "swarm_polarization",
    "swarm_largest_group",
    "swarm_groups",
)
PRIMARY = "aggregation_index"
# Equivalence margins, declared with the design: |difference| inside the margin reads "no effect".
MARGINS = {"aggregation_index": 0.05, "swarm_local_alignment": 0.05, "captures_per_prey_relative": 0.10}
# Per-prey training budget: about 1.3e8 prey-steps and 500 PPO iterations at either density.
TRAIN_AGENT_STEPS = 32 * 256 * 32 * 500


HELP = "can collective behaviour pay, and does it emerge in learned prey? (heuristic screen, learned prey, controls)"
DESCRIPTION = (
    "Part screen: heuristic prey (random, constant, TurnAway, Boids) against NaivChase with and without "
    "confusion over density, prey view distance, predator speed and capture confusion, with the aggregation "
    "index against "
    "uniformly random prey. Part learned: train --seeds prey runs per condition (the swarm scenario and its "
    "controls), evaluate each with and without its prey slots and against NaivChase without confusion, "
    "and compare the conditions with 95% intervals and declared equivalence margins. Tasks keep their "
    "results in --out (finished/); a rerun runs only what is missing. Writes summary.json, screen.csv, "
    "learned.csv and figures."
)


# The parts of the study a run takes (`--part`).
PARTS = ("screen", "learned", "all")


@dataclass
class SwarmStudy:
    """Settings of the swarm study (the CLI's options)."""

    part: str = field(
        default="all",
        metadata=option("the heuristic scenario screen, the learned prey with their controls, or both", choices=PARTS),
    )
    prey_counts: list[int] = field(
        default_factory=lambda: [8, 16, 32, 64],
        metadata=option("screen: prey per world (density)", parse=lambda text, flag: number_list(text, int, flag, 2)),
    )
    view_distances: list[float] = field(
        default_factory=lambda: [100.0, 200.0, 400.0],
        metadata=option(
            "screen: prey view distances, px (360 deg)", parse=lambda text, flag: number_list(text, float, flag, 1)
        ),
    )
    predator_speeds: list[float] = field(
        default_factory=lambda: [5.0, 4.5, 4.0, 3.5],
        metadata=option(
            "screen: predator max speeds (the prey's is 4)",
            parse=lambda text, flag: number_list(text, float, flag, 0, low_open=True),
        ),
    )
    capture_confusion: list[float] = field(
        default_factory=lambda: [0.0],
        metadata=option(
            "screen: capture confusion strengths c (docs/model.md step 5; confusion_radius 100 px), e.g. 0,1,4",
            parse=lambda text, flag: number_list(text, float, flag, 0, LARGEST),
        ),
    )
    conditions: list[str] = field(
        default_factory=lambda: list(CONDITIONS),
        metadata=option("learned: conditions to train", parse=choice_list(tuple(CONDITIONS)), shown="every condition"),
    )
    seeds: int = field(
        default=5,
        metadata=option("learned: training runs per condition, a count N: seeds 0 to N-1 (>= 2)", type=int),
    )
    iterations: int = field(default=500, metadata=option("learned: PPO iterations per run", type=int))
    train_worlds: int | None = field(default=None, metadata=common.TRAIN_WORLDS)
    episodes: int = field(default=64, metadata=common.EVAL_EPISODES)
    eval_seeds: int = field(default=2, metadata=common.EVAL_SEEDS)
    max_steps: int = field(default=3000, metadata=common.MAX_STEPS)
    gpus: int | None = field(default=None, metadata=common.TASK_GPUS)
    per_gpu: int = field(
        default=4,
        metadata=option(
            "evaluations at a time per GPU (trainings that may share a process run as one population per GPU)",
            type=int,
        ),
    )
    train_preset: str = field(default="paper", metadata=option("learned: the preset trained from"))
    train_set: list[str] = field(
        default_factory=list,
        metadata=option(
            "learned: extra `train --set` assignments (tiny smoke runs)", repeated=True, metavar="KEY=VALUE"
        ),
    )
    commit: str | None = field(default=None, metadata=common.COMMIT)
    figures: bool = field(default=True, metadata=option("no matplotlib figures", negated=True))
    out: str = field(default="swarm_study", metadata=option("output directory"))

    def validate(self) -> None:
        """A one-line `ValueError` naming the option unless every setting is in range."""
        common.check_task_options(self)
        for name, values in (
            ("--prey-counts", self.prey_counts),
            ("--view-distances", self.view_distances),
            ("--predator-speeds", self.predator_speeds),
            ("--capture-confusion", self.capture_confusion),
        ):
            check_distinct(name, values)  # a repeated value would name one task twice


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_options(parser, SwarmStudy)


def check(args: argparse.Namespace) -> SwarmStudy:
    """The study of the parsed options; a one-line `ValueError` naming the option unless every option is
    in range."""
    study = from_options(SwarmStudy, args)
    study.validate()
    return study


# ---- the tasks (`jobs.run_jobs`: kept in <out>/finished/, spread over the GPUs) -----------------------


def run_part(
    heading: str,
    function: Callable[[dict, str], dict],
    tasks: list[dict],
    study: SwarmStudy,
    devices: Sequence[str],
    label: str,
) -> list[dict]:
    """The results of `tasks` (`function(task, device)`) in task order, the kept ones read back: on the
    GPUs `--per-gpu` at a time on each, on the CPU one at a time here (Warp's CPU kernels take one
    thread each)."""
    todo = sum(not read_finished(study.out, task)[0] for task in tasks)
    print(f"study swarm: {heading} ({todo} to run)", flush=True)
    jobs = study.per_gpu if devices[0] != "cpu" else 1
    return run_jobs(
        function, tasks, study.out, jobs=jobs, devices=devices, label=label, report=lambda line: print(line, flush=True)
    ).results


def screen_config(n: int, view: float, predator_speed: float, max_steps: int, capture_confusion: float = 0.0):
    import dataclasses

    from ..config import AquariumConfig

    cfg = AquariumConfig(
        prey_count=n,
        max_prey=max(n, 20),
        max_steps=max_steps,
        spawn_heading="random",
        capture_confusion=capture_confusion,
    )
    return cfg.replace(
        prey=dataclasses.replace(cfg.prey, fov_angle=360.0, view_distance=view),
        predator=dataclasses.replace(cfg.predator, max_speed=predator_speed),
    )


def per_seed_values(result: dict, prey_label: str, predator_label: str) -> dict[str, list[float]]:
    """`{measure: [mean over the episodes of each evaluation seed]}` of one (prey, predator) pair."""
    seeds = sorted({r["seed"] for r in result["episodes"]})
    out: dict[str, list[float]] = {}
    for m in MEASURES:
        out[m] = []
        for s in seeds:
            values = [
                r[m]
                for r in result["episodes"]
                if r["prey_policy"] == prey_label
                and r["predator_policy"] == predator_label
                and r["seed"] == s
                and not math.isnan(r[m])
            ]
            out[m].append(sum(values) / len(values) if values else float("nan"))
    return out


def uniform_measures(cfg, device: str, seed: int = 0) -> dict[str, float]:
    """Swarm measures of uniformly random prey (random headings) in `cfg`'s arena at its prey count."""
    from .swarm_size import uniform_baseline

    snapshots = max(8, min(256, 65536 // cfg.prey_count))
    return uniform_baseline(cfg, snapshots, None, device, seed=seed)


def run_heuristics(cfg, task: dict, device: str) -> dict:
    """Every heuristic prey against every predator of `PREDATORS` in `cfg`, with the uniform baseline
    (as JSON writes it: a NaN, a measure without a sample, as None)."""
    from ..training.evaluate import evaluate_policies

    result = evaluate_policies(
        list(HEURISTIC_PREY),
        list(PREDATORS),
        cfg,
        episodes=task["episodes"],
        seeds=range(task["eval_seeds"]),
        device=device,
    )
    values = {f"{p}|{q}": per_seed_values(result, p, q) for p in HEURISTIC_PREY for q in PREDATORS}
    return json_safe(
        {"values": values, "uniform": uniform_measures(cfg, device), "machine": result["machine"], "env": cfg.to_dict()}
    )


def run_screen_task(task: dict, device: str) -> dict:
    cfg = screen_config(
        task["prey"], task["view"], task["predator_speed"], task["max_steps"], task.get("capture_confusion", 0.0)
    )
    return run_heuristics(cfg, task, device)


def policy_world(task: dict):
    """The world of the policy that `task`'s training run exported, with the task's episode length."""
    from ..drivers import trained_world

    return trained_world(policy_path(task["run_dir"])).replace(max_steps=task["max_steps"])


def run_eval_task(task: dict, device: str) -> dict:
    """One trained policy in its own world: each of `EVALUATIONS`."""
    from ..training.evaluate import evaluate_policies

    cfg = policy_world(task)
    values, machine = {}, None
    for label, (predator, blind) in EVALUATIONS.items():
        if blind and cfg.prey.prey_slots == 0:
            continue  # no prey slots to empty
        result = evaluate_policies(
            [f"learned={policy_path(task['run_dir'])}"],
            [predator],
            cfg,
            episodes=task["episodes"],
            seeds=range(task["eval_seeds"]),
            device=device,
            blind_to={"prey": "prey"} if blind else None,
        )
        values[label] = per_seed_values(result, "learned", predator)
        machine = result["machine"]
    return json_safe(
        {"values": values, "uniform": uniform_measures(cfg, device), "machine": machine, "env": cfg.to_dict()}
    )


def run_baseline_task(task: dict, device: str) -> dict:
    """The heuristic prey in a condition's world (its first seed's policy's): the same evaluation seeds."""
    return run_heuristics(policy_world(task), task, device)


# ---- training ---------------------------------------------------------------------------------------


def run_dir(out: str, condition: str, seed: int) -> str:
    return os.path.join(out, "runs", f"{condition}-s{seed}")


def run_config(study: SwarmStudy, condition: str, seed: int) -> dict:
    """The Trainer config of `condition`'s training run with `seed`, without a device (its task is
    given one): what `aquarium-warp train --preset <--train-preset> --seed <seed> --quiet --export jit
    --save-interval I --prey N --num-worlds W --iterations I --entropy 0.01 --predator-policy <opponent>`
    with `--set` of torch's float32 path (`TORCH_FLOAT32`), `SCENARIO`, the recipe's (`LEARNED_PREY_RECIPE`),
    the condition's and `--train-set`'s
    assignments builds, the command that trained the committed results. W: `--train-worlds`, else
    `TRAIN_AGENT_STEPS` / (N x 32 steps x `--iterations`); I: `--iterations` x the condition's budget."""
    from ..training.config import LEARNED_PREY_RECIPE, deep_update, make_config, parse_assignment
    from ..training.fast_path import TORCH_FLOAT32

    spec = CONDITIONS[condition]
    worlds = study.train_worlds or max(1, TRAIN_AGENT_STEPS // (spec["prey"] * 32 * study.iterations))
    iterations = study.iterations * spec.get("budget", 1)
    changes = {
        "train": {
            "team": "prey",
            "device": None,
            "seed": seed,
            "quiet": True,
            "export": "jit",
            "num_worlds": worlds,
            "iterations": iterations,
            "episodes": None,
            **TORCH_FLOAT32,
        },
        "env": {"prey_count": spec["prey"]},
        "runner": {"save_interval": iterations},
    }
    deep_update(changes, LEARNED_PREY_RECIPE)
    for assignment in SCENARIO + tuple(spec["sets"]) + tuple(study.train_set):
        deep_update(changes, parse_assignment(assignment))
    return make_config(study.train_preset, deep_update(changes, {"train": {"opponent": spec["opponent"]}}))


# ---- statistics (statistics.py: Student-t intervals, Welch or paired differences, TOST) ---------------


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


def summarize_screen(tasks: Sequence[dict], records: Sequence[dict]) -> list[dict]:
    """A row per screen world (`tasks`, with their `records`), heuristic prey and predator."""
    rows = []
    for task, record in zip(tasks, records, strict=True):
        for p in HEURISTIC_PREY:
            for q in PREDATORS:
                key = f"{p}|{q}"
                row = {
                    "prey_count": task["prey"],
                    "view_distance": task["view"],
                    "predator_speed": task["predator_speed"],
                    "capture_confusion": task.get("capture_confusion", 0.0),
                    "prey_policy": p,
                    "predator_policy": q,
                }
                for m in MEASURES + (PRIMARY,):
                    row[m] = interval(_values(record, key, m))
                row["uniform"] = record["uniform"]
                rows.append(row)
    return rows


def summarize_learned(evaluations: Sequence[tuple[dict, dict]], baselines: Sequence[tuple[dict, dict]]) -> dict:
    """Per condition and evaluation: per-seed values and their mean with 95% interval; the baselines;
    and the pre-declared comparisons. `evaluations`: (task, record) of each policy's evaluation, in
    the order of the conditions and seeds; `baselines`: (task, record) of each condition's heuristics."""
    by_condition: dict[str, list[tuple[dict, dict]]] = {}
    for task, record in evaluations:
        by_condition.setdefault(task["condition"], []).append((task, record))
    baseline_of = {task["condition"]: record for task, record in baselines}
    per: dict[str, dict] = {}
    for c, evaluated in by_condition.items():
        records = [record for _, record in evaluated]
        entry: dict = {"seeds": [task["seed"] for task, _ in evaluated], "uniform": records[0]["uniform"]}
        for label in EVALUATIONS:
            if label in records[0]["values"]:
                entry[label] = {m: interval([seed_value(r, label, m) for r in records]) for m in MEASURES + (PRIMARY,)}
        baseline = baseline_of.get(c)
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
            label = CONDITIONS[a].get("evaluated", "naivchase")
            if a in per and b in per and label in per[b]:
                compare(f"{a} minus {b}", per[a][label], per[b][label], m, False)
        for c in ("swarm", "slow-predator", "confusion", "confusion-strong"):
            label = CONDITIONS[c].get("evaluated", "naivchase")
            heuristic = f"|{EVALUATIONS[label][0]}"
            for prey in HEURISTIC_PREY:
                if c in per and f"{prey}{heuristic}" in per[c]:
                    compare(f"{c} minus {prey} prey", per[c][label], per[c][f"{prey}{heuristic}"], m, False)
    return {"conditions": per, "comparisons": comparisons}


def screen_tasks(study: SwarmStudy) -> list[dict]:
    """A task per screen world. A world without capture confusion (c = 0) is the task of the screen as
    first run, with its name and without a `capture_confusion` key, so that its kept results stay valid."""
    tasks = []
    for n in study.prey_counts:
        for v in study.view_distances:
            for s in study.predator_speeds:
                for c in study.capture_confusion:
                    task = {
                        "name": f"screen-n{n}-v{int(v)}-p{s:g}" + (f"-c{c:g}" if c else ""),
                        "prey": n,
                        "view": v,
                        "predator_speed": s,
                        "episodes": study.episodes,
                        "eval_seeds": study.eval_seeds,
                        "max_steps": study.max_steps,
                    }
                    if c:
                        task["capture_confusion"] = c
                    tasks.append(task)
    return tasks


def training_tasks(study: SwarmStudy) -> list[dict]:
    return [
        {
            "name": f"train-{c}-s{s}",
            "condition": c,
            "seed": s,
            "config": run_config(study, c, s),
            "run_dir": run_dir(study.out, c, s),
        }
        for c in study.conditions
        for s in range(study.seeds)
    ]


def eval_tasks(study: SwarmStudy, trainings: Sequence[dict]) -> list[dict]:
    """An evaluation of each training run's policy; its config is part of the task, so that a run
    trained again with other settings is evaluated again."""
    return [
        {
            "name": f"eval-{t['condition']}-s{t['seed']}",
            "condition": t["condition"],
            "seed": t["seed"],
            "training": t["config"],
            "run_dir": t["run_dir"],
            "episodes": study.episodes,
            "eval_seeds": study.eval_seeds,
            "max_steps": study.max_steps,
        }
        for t in trainings
    ]


def baseline_tasks(study: SwarmStudy, trainings: Sequence[dict]) -> list[dict]:
    """The heuristics in each condition's world, that of its first seed's run."""
    return [
        {
            "name": f"baseline-{t['condition']}",
            "condition": t["condition"],
            "training": t["config"],
            "run_dir": t["run_dir"],
            "episodes": study.episodes,
            "eval_seeds": study.eval_seeds,
            "max_steps": study.max_steps,
        }
        for t in trainings
        if t["seed"] == 0
    ]


def run(args) -> int:
    from ..atomic import atomic_open, check_output_dir
    from ..training.config import LEARNED_PREY_RECIPE

    study = check(args)
    devices = task_devices(study.gpus)
    trainings = training_tasks(study) if study.part != "screen" else []  # their configs checked first
    check_output_dir(study.out, "--out")
    os.makedirs(study.out, exist_ok=True)
    start = time.perf_counter()
    summary: dict = {
        "design": {
            "scenario": SCENARIO,
            "confusion": CONFUSION,
            "recipe": LEARNED_PREY_RECIPE,
            "conditions": CONDITIONS,
            "evaluations": EVALUATIONS,
            "primary": PRIMARY,
            "margins": MARGINS,
            "train_agent_steps": TRAIN_AGENT_STEPS,
            "iterations": study.iterations,
            "episodes": study.episodes,
            "eval_seeds": study.eval_seeds,
            "max_steps": study.max_steps,
            "seeds": study.seeds,
        }
    }
    if study.part != "learned":
        tasks = screen_tasks(study)
        records = run_part(f"screen, {len(tasks)} worlds", run_screen_task, tasks, study, devices, "screen")
        summary["screen"] = summarize_screen(tasks, records)
    if trainings:
        trained = run_part(
            f"training {plural(len(study.conditions), 'condition')} x {plural(study.seeds, 'seed')}",
            run_training_task,
            trainings,
            study,
            devices,
            "train",
        )
        summary["trainings"] = [
            {"condition": t["condition"], "seed": t["seed"], "run_dir": t["run_dir"], **r}
            for t, r in zip(trainings, trained, strict=True)
        ]
        evaluations = eval_tasks(study, trainings)
        evaluated = run_part(
            f"evaluating {len(evaluations)} policies", run_eval_task, evaluations, study, devices, "eval"
        )
        baselines = baseline_tasks(study, trainings)
        heuristics = run_part(
            f"heuristic prey in {len(baselines)} conditions' worlds",
            run_baseline_task,
            baselines,
            study,
            devices,
            "baselines",
        )
        summary["learned"] = summarize_learned(
            list(zip(evaluations, evaluated, strict=True)), list(zip(baselines, heuristics, strict=True))
        )
    summary.update(
        provenance(devices[0], command_line(args.argv), commit=study.commit),
        wall_s=round(time.perf_counter() - start, 1),
    )
    with atomic_open(os.path.join(study.out, "summary.json")) as f:
        json.dump(json_safe(summary), f, indent=1)
    write_tables(study.out, summary)
    if study.figures:
        plot(study.out, summary)
    print(f"study swarm: wrote {os.path.join(study.out, 'summary.json')} ({summary['wall_s']} s)")
    return 0


# ---- tables and figures -----------------------------------------------------------------------------


def write_tables(out: str, summary: dict) -> None:
    """`screen.csv` (one row per world, prey and predator: means and interval half-widths) and
    `learned.csv` (one row per condition, evaluation and training seed: the per-seed values)."""
    import csv

    from ..atomic import atomic_open

    if summary.get("screen"):
        columns = [
            "prey_count",
            "view_distance",
            "predator_speed",
            "capture_confusion",
            "prey_policy",
            "predator_policy",
        ]
        with atomic_open(os.path.join(out, "screen.csv"), newline="") as f:
            w = csv.writer(f)
            w.writerow(columns + [f"{m}{s}" for m in MEASURES + (PRIMARY,) for s in ("", "_ci95")])
            for row in summary["screen"]:
                w.writerow(
                    [row[c] for c in columns]
                    + [v for m in MEASURES + (PRIMARY,) for v in (row[m]["mean"], row[m]["ci95"])]
                )
    learned = summary.get("learned", {}).get("conditions", {})
    if learned:
        with atomic_open(os.path.join(out, "learned.csv"), newline="") as f:
            w = csv.writer(f)
            w.writerow(["condition", "evaluation", "seed"] + list(MEASURES + (PRIMARY,)))
            for c, entry in learned.items():
                for label in EVALUATIONS:
                    if label in entry:
                        for k, seed in enumerate(entry["seeds"]):
                            w.writerow(
                                [c, label, seed]
                                + [
                                    entry[label][m]["values"][k] if k < len(entry[label][m]["values"]) else ""
                                    for m in MEASURES + (PRIMARY,)
                                ]
                            )


def plot(out: str, summary: dict) -> None:
    """`screen.png`: Boids' captures over TurnAway's against density, per view distance, predator speed,
    NaivChase's confusion and capture confusion; `learned.png`: the primary measure and captures per
    condition with 95% intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summary.get("screen") or []
    if rows:
        speeds = sorted({r["predator_speed"] for r in rows})
        fig, axes = plt.subplots(
            len(PREDATORS), len(speeds), figsize=(3.6 * len(speeds), 3.2 * len(PREDATORS)), sharey=True, squeeze=False
        )
        confusions = sorted({r["capture_confusion"] for r in rows})
        for i, (speed, predator) in enumerate((s, q) for s in speeds for q in PREDATORS):
            ax = axes[i % len(PREDATORS), i // len(PREDATORS)]
            for view, c in ((v, c) for v in sorted({r["view_distance"] for r in rows}) for c in confusions):
                pick = {
                    (r["prey_count"], r["prey_policy"]): r
                    for r in rows
                    if r["predator_speed"] == speed
                    and r["view_distance"] == view
                    and r["capture_confusion"] == c
                    and r["predator_policy"] == predator
                }
                counts = sorted({n for n, _ in pick})
                ratio = [
                    pick[(n, "boids")]["captures_per_prey"]["mean"]
                    / max(pick[(n, "turnaway")]["captures_per_prey"]["mean"], 1e-9)
                    for n in counts
                ]
                label = f"view {view:g} px" + (f", c {c:g}" if len(confusions) > 1 else "")
                ax.plot(counts, ratio, "o-", label=label)
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
                # Heuristic prey beside the two scenarios, against the predator each is compared with.
                predator = EVALUATIONS[CONDITIONS[c].get("evaluated", "naivchase")][0]
                heuristics = [f"{p}|{predator}" for p in HEURISTIC_PREY] if c in ("swarm", "confusion") else []
                for label in list(EVALUATIONS) + heuristics:
                    if label in entry:
                        labels.append(f"{c}\n{label.split('|')[0]}")
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
        plot_confusion_dose(out, learned)


def capture_confusion_of(condition: str) -> float:
    """The capture confusion c a condition trains with (0 where its `sets` give none)."""
    for assignment in CONDITIONS[condition]["sets"]:
        key, _, value = assignment.partition("=")
        if key == "env.capture_confusion":
            return float(value)
    return 0.0


def plot_confusion_dose(out: str, learned: dict) -> None:
    """`confusion_dose.png`, where conditions trained against the nearest-target NaivChase ran: the
    primary measure and captures per prey against capture confusion c, for learned prey with and
    without prey slots and the heuristic prey in the same worlds, each with its 95% band."""
    from .common import band, pyplot, save_figure

    dose = [c for c in learned if CONDITIONS[c].get("evaluated") == "noconfusion"]
    if len(dose) < 2:
        return
    strengths = sorted({capture_confusion_of(c) for c in dose})
    fig, axes = pyplot().subplots(1, 2, figsize=(10, 3.8))
    for ax, measure in zip(axes, (PRIMARY, "captures_per_prey"), strict=True):
        series: dict[str, list[tuple[int, dict]]] = {}
        for c in dose:
            sets, x = CONDITIONS[c]["sets"], strengths.index(capture_confusion_of(c))
            if "env.capture_probability=0" in sets:
                continue  # no captures, so no dose: it is read beside the others in learned.png
            blind = "env.prey.prey_slots=0" in sets
            series.setdefault("learned, 0 prey slots" if blind else "learned", []).append(
                (x, learned[c]["noconfusion"][measure])
            )
            for prey in () if blind else ("turnaway", "boids", "random"):
                label = f"{prey}|naivchase-noconfusion"
                if label in learned[c]:
                    series.setdefault(prey, []).append((x, learned[c][label][measure]))
        for name, points in series.items():
            points.sort(key=lambda p: p[0])
            band(ax, [x for x, _ in points], [v for _, v in points], label=name)
        ax.set_xticks(range(len(strengths)), [f"{c:g}" for c in strengths])
        ax.set_xlabel("capture confusion c (confusion_radius 100 px)")
        ax.set_ylabel(measure)
        if measure == PRIMARY:
            ax.axhline(1.0, color="grey", lw=0.8)
    axes[0].legend(fontsize=8)
    save_figure(fig, out, "confusion_dose.png", "Prey against NaivChase (nearest target), N = 32, 360 degrees, 200 px")
