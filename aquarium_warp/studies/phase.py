"""The phase diagram of learned prey (`aquarium-warp study phase`): which capture rule, density, view
and predator give which collective state (dispersal, aggregation, a polarized school or a mill)?

The design below (`CELLS`, `CONTROLS`, `EVALUATIONS`, `PRIMARY`, `THRESHOLDS`, `MARGINS`) is the
pre-registration of docs/studies/phase.md: it was committed on its own before the first run, and a
change to it after that is stated where the results are quoted.

A cell is a world and a predator. Each cell's learned prey are trained with `--seeds` seeds (10), and
each of its other controls (`CONTROLS`) with `--control-seeds` (5):
- `learned`: the learned-prey recipe in the cell's world;
- `no-slots`: the same with 0 prey slots (the prey cannot see each other: structure without interaction);
- `no-predation`: contacts never capture (`capture_probability` 0) and each contact step costs the prey
  `CONTACT_PENALTY` (`prey_contact_penalty`): predation removed, the learning signal kept.

Every trained prey policy is evaluated (`EVALUATIONS`) in its own world against the cell's predator;
the `learned` ones also with their prey slots emptied (`blind`, paired) and at the other capture
strength (`other-c`: c = 0 for a cell with c > 0, the dilution rule at c = 64 for a cell with c = 0;
the mediation test: does a benefit run through the rule?). Random, constant-heading, TurnAway and
Boids prey play each cell's world beside them. The co-evolving cells train both teams (fictitious
self-play with an opponent pool) and evaluate each prey policy against its own run's final predator
and against the fixed predator; they have no `no-predation` control (a predator's only reward is its
captures, so without captures its team would not learn: the fixed-predator cell of the same world is
that control).

Measures per episode (`aquarium_warp.metrics`, sampled every 10 steps over 3000-step episodes),
reduced to one value per training seed (the mean over `--eval-seeds` x `--episodes` episodes):
the primary `PRIMARY` (mean nearest-neighbour distance of the live prey over that of the same number of
non-overlapping prey bodies placed uniformly at random on the torus, the hard-disk null), and the
secondaries `SECONDARY`. Regimes (`regime`) are named from the `learned` prey's 10 seed values by
`THRESHOLDS`; each regime is attributed (`readings`) by the declared contrasts with their `MARGINS`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from collections.abc import Sequence

from ..arguments import add_options, choice_list, from_options, option
from ..jobs import read_finished, run_jobs, task_devices
from ..records import command_line, json_safe, provenance
from ..statistics import difference, equivalence, interval, mean_interval
from . import common
from .common import policy_path, run_training_task

HELP = "the phase diagram of learned prey: collective state over capture rule, density, view and predator"
DESCRIPTION = (
    "Train learned prey (10 seeds) in each pre-registered cell with its controls (no prey slots; predation "
    "removed, contact penalised), evaluate them in their world, with their prey slots emptied and at the other "
    "capture strength, beside random, constant, TurnAway and Boids prey, and name each cell's collective state "
    "by the declared thresholds (docs/studies/phase.md). Tasks keep their results in --out (finished/); a "
    "rerun runs only what is missing. Writes summary.json, cells.csv, per_seed.csv, readings.csv, "
    "training_series.csv and figures."
)

# ---- the pre-registered design (docs/studies/phase.md) ------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Cell:
    """One world of the diagram and its predator. `rule`/`strength`: the capture rule of docs/model.md
    step 5 ("dilution": p0 / (1 + c k), k the prey within `DILUTION_RADIUS` of the target; "confusion":
    Olson et al.'s per-attack form) and its c; `coevolving`: the predators learn too (with an opponent pool)."""

    slice: str
    prey: int = 32
    view: float = 200.0
    fov: float = 360.0
    rule: str = "dilution"
    strength: float = 0.0
    predator_speed: float = 5.0
    coevolving: bool = False

    def sets(self) -> tuple[str, ...]:
        """The cell's world as `train --set` assignments (beyond the learned-prey recipe)."""
        return (
            f"env.prey.fov_angle={self.fov:g}",
            f"env.prey.view_distance={self.view:g}",
            f"env.predator.max_speed={self.predator_speed:g}",
            f"env.capture_rule={self.rule}",
            f"env.capture_confusion={self.strength:g}",
            f"env.confusion_radius={DILUTION_RADIUS:g}",
        )

    def other_strength(self) -> tuple[str, float]:
        """The (rule, c) of the `other-c` evaluation: c = 0 where the cell's c > 0, else dilution at 64."""
        return (self.rule, 0.0) if self.strength > 0 else ("dilution", 64.0)


DILUTION_RADIUS = 100.0
# The fixed predator: NaivChase towards the nearest visible prey, so that the capture rule is the only
# confusion at work (the swarm study's `confusion` conditions).
FIXED_PREDATOR = "naivchase-noconfusion"
# A contact of the `no-predation` control costs what a capture costs, without ending the prey's life.
CONTACT_PENALTY = 1000.0
# The co-evolving cells' opponent pool: a snapshot every 50 of the 500 iterations, 8 kept, 20% of worlds.
POOL = {"pool_every": 50, "pool_size": 8, "pool_fraction": 0.2}


def declared_cells() -> dict[str, Cell]:
    """The cells, by slice: `rule` (both capture rules over c at N = 32, 360 deg / 200 px), `density-view`
    (N x view distance under dilution at c = 64, the swarm preset's world at its centre), `fov` and
    `predator-speed` (one step each from that centre) and `coevolving` (learning predators: c = 0 is
    Li et al. 2023's condition). In the order they run: the first tier (`FIRST_TIER`), then the rest."""
    cells = {"c0": Cell("rule")}
    for rule, c in (("dilution", 1.0), ("dilution", 64.0), ("confusion", 1.0), ("confusion", 8.0), ("confusion", 64.0)):
        cells[f"{rule}-c{c:g}"] = Cell("rule", rule=rule, strength=c)
    for n, view in ((8, 200.0), (128, 200.0), (32, 100.0), (32, 400.0)):
        cells[f"n{n}-v{view:g}"] = Cell("density-view", prey=n, view=view, strength=64.0)
    cells["coevolving-c0"] = Cell("coevolving", coevolving=True)
    # The second tier, run in this order as far as the device time allows.
    cells["fov240"] = Cell("fov", fov=240.0, strength=64.0)
    cells["predator4"] = Cell("predator-speed", predator_speed=4.0, strength=64.0)
    cells["coevolving-dilution-c64"] = Cell("coevolving", strength=64.0, coevolving=True)
    cells["dilution-c8"] = Cell("rule", rule="dilution", strength=8.0)
    cells["predator6"] = Cell("predator-speed", predator_speed=6.0, strength=64.0)
    for n, view in ((8, 100.0), (8, 400.0), (128, 100.0), (128, 400.0)):
        cells[f"n{n}-v{view:g}"] = Cell("density-view", prey=n, view=view, strength=64.0)
    return cells


CELLS = declared_cells()
FIRST_TIER = tuple(CELLS)[:11]
CONTROLS: dict[str, tuple[str, ...]] = {
    "learned": (),
    "no-slots": ("env.prey.prey_slots=0",),
    "no-predation": ("env.capture_probability=0", f"env.prey_contact_penalty={CONTACT_PENALTY:g}"),
}
# label -> what it evaluates: "own" world; "blind": prey slots emptied; "other-c": `Cell.other_strength`;
# "fixed": a co-evolving cell's prey against the fixed predator.
EVALUATIONS = ("own", "blind", "other-c", "fixed")
HEURISTIC_PREY = ("random", "constant", "turnaway", "boids")

PRIMARY = "nn_ratio_hard_disk"
SECONDARY = (
    "nn_ratio_point",
    "largest_group",
    "measured_share",  # the share of prey in groups of at least 3
    "group_polarization",
    "group_rotation",
    "group_speed",
    "group_lifetime",
    "confusion_neighbour_share",  # the share of prey with another within the dilution radius
    "captures_per_prey",
)
# Regimes from the `learned` prey's seed values in their own world (95% t intervals over 10 seeds):
# aggregated when the interval of the primary lies below `aggregated`, dispersed when above `dispersed`;
# an aggregate is a polarized school when its mean per-group polarization >= `ordered` and rotation <
# `disordered`, a mill when rotation >= `ordered` and polarization < `disordered` (Tunstrom et al. 2013's
# cut-offs), else a disordered aggregate (a swarm).
THRESHOLDS = {"aggregated": 0.90, "dispersed": 1.10, "ordered": 0.65, "disordered": 0.35}
# Equivalence margins of the contrasts: a difference whose 95% interval lies beyond the margin is an
# effect; one whose 90% interval lies inside it (TOST) is none; anything else is undecided.
MARGINS = {PRIMARY: 0.05, "group_polarization": 0.10, "group_rotation": 0.10, "captures_per_prey": 0.10}
RELATIVE_MARGINS = ("captures_per_prey",)  # a fraction of the control's mean
# Per-run training budget (the swarm study's): about 1.3e8 prey-steps and 500 PPO iterations.
TRAIN_AGENT_STEPS = 32 * 256 * 32 * 500
ITERATIONS = 500
# Fast-path settings every training of the study uses (the fused MLP and loss, TF32 products on CUDA;
# their curves are equivalent to torch's float32 within 10%: docs/training.md).
FAST = ("train.fused_mlp=true", "train.tf32=true")


# ---- command line -------------------------------------------------------------------------------------


@dataclasses.dataclass
class PhaseStudy:
    """Settings of a run of the phase study (the CLI's options; the design is the constants above)."""

    cells: list[str] = dataclasses.field(
        default_factory=lambda: list(FIRST_TIER),
        metadata=option("cells to run", parse=choice_list(tuple(CELLS)), shown="the first tier"),
    )
    seeds: int = dataclasses.field(
        default=10, metadata=option("training seeds of the learned prey per cell: 0 to N-1", type=int)
    )
    control_seeds: int = dataclasses.field(
        default=5, metadata=option("training seeds of each trained control per cell: 0 to N-1", type=int)
    )
    iterations: int = dataclasses.field(default=ITERATIONS, metadata=option("PPO iterations per run", type=int))
    train_worlds: int | None = dataclasses.field(default=None, metadata=common.TRAIN_WORLDS)
    episodes: int = dataclasses.field(default=64, metadata=common.EVAL_EPISODES)
    eval_seeds: int = dataclasses.field(default=2, metadata=common.EVAL_SEEDS)
    max_steps: int = dataclasses.field(default=3000, metadata=common.MAX_STEPS)
    gpus: int | None = dataclasses.field(default=None, metadata=common.TASK_GPUS)
    per_gpu: int = dataclasses.field(default=4, metadata=option("evaluations at a time per GPU", type=int))
    train_set: list[str] = dataclasses.field(
        default_factory=list,
        metadata=option(
            "extra `train --set` assignments (tiny smoke runs; recorded in the summary)",
            repeated=True,
            metavar="KEY=VALUE",
        ),
    )
    commit: str | None = dataclasses.field(default=None, metadata=common.COMMIT)
    figures: bool = dataclasses.field(default=True, metadata=option("no matplotlib figures", negated=True))
    out: str = dataclasses.field(default="phase_study", metadata=option("output directory"))

    def validate(self) -> None:
        """A one-line `ValueError` naming the option unless every setting is in range."""
        common.check_task_options(self, ("--control-seeds", self.control_seeds, 2))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_options(parser, PhaseStudy)


def check(args: argparse.Namespace) -> PhaseStudy:
    """The study of the parsed options; a one-line `ValueError` naming the option unless every option is
    in range."""
    study = from_options(PhaseStudy, args)
    study.validate()
    return study


# ---- training -----------------------------------------------------------------------------------------


def controls_of(cell: Cell) -> tuple[str, ...]:
    return tuple(c for c in CONTROLS if not (cell.coevolving and c == "no-predation"))


def run_config(study: PhaseStudy, name: str, control: str, seed: int) -> dict:
    """The Trainer config of `name`'s `control` run with `seed`: `train --preset paper --team prey
    --seed S --prey N --num-worlds W --iterations I --opponent naivchase-noconfusion` with the learned-prey
    recipe, `FAST`, the cell's and the control's `--set` assignments and `--train-set`'s (co-evolving
    cells: `--team both` with `POOL`). W: `--train-worlds`, else `TRAIN_AGENT_STEPS` / (N x 32 x I)."""
    from ..training.config import LEARNED_PREY_RECIPE, deep_update, make_config, parse_assignment

    cell = CELLS[name]
    worlds = study.train_worlds or max(1, TRAIN_AGENT_STEPS // (cell.prey * 32 * study.iterations))
    changes: dict = {
        "train": {
            "team": "both" if cell.coevolving else "prey",
            "device": None,
            "seed": seed,
            "quiet": True,
            "export": "jit",
            "num_worlds": worlds,
            "iterations": study.iterations,
            "episodes": None,
            **({"opponent": None, **POOL} if cell.coevolving else {"opponent": FIXED_PREDATOR}),
        },
        "env": {"prey_count": cell.prey},
        "runner": {"save_interval": study.iterations},
    }
    deep_update(changes, LEARNED_PREY_RECIPE)
    for assignment in FAST + cell.sets() + CONTROLS[control] + tuple(study.train_set):
        deep_update(changes, parse_assignment(assignment))
    return make_config("paper", changes)


def run_dir(out: str, name: str, control: str, seed: int) -> str:
    return os.path.join(out, "runs", f"{name}-{control}-s{seed}")


def prey_policy(task: dict) -> str:
    """The prey policy a training task exported (a co-evolving run exports one per team)."""
    if task["coevolving"]:
        return os.path.join(task["run_dir"], "exported", "prey", "policy.pt")
    return policy_path(task["run_dir"])


def predator_policy(task: dict) -> str:
    return os.path.join(task["run_dir"], "exported", "predator", "policy.pt")


def training_tasks(study: PhaseStudy) -> list[dict]:
    tasks = []
    for name in study.cells:
        for control in controls_of(CELLS[name]):
            for seed in range(study.seeds if control == "learned" else study.control_seeds):
                tasks.append(
                    {
                        "name": f"train-{name}-{control}-s{seed}",
                        "cell": name,
                        "control": control,
                        "seed": seed,
                        "coevolving": CELLS[name].coevolving,
                        "config": run_config(study, name, control, seed),
                        "run_dir": run_dir(study.out, name, control, seed),
                    }
                )
    return tasks


# ---- evaluation ---------------------------------------------------------------------------------------


def world_of(task: dict, rule: str | None = None, strength: float | None = None):
    """The world a trained prey policy plays: its training world with the task's episode length, and
    the capture rule and strength replaced where given."""
    from ..drivers import trained_world

    cfg = trained_world(prey_policy(task)).replace(max_steps=task["max_steps"])
    if rule is not None:
        cfg = cfg.replace(capture_rule=rule, capture_confusion=strength)
    return cfg


def evaluations_of(task: dict) -> dict[str, tuple[str, bool, tuple[str, float] | None]]:
    """label -> (predator spec, prey slots emptied, (rule, c) or None for the world's own) of a policy."""
    cell = CELLS[task["cell"]]
    own = f"learned={predator_policy(task)}" if cell.coevolving else FIXED_PREDATOR
    out: dict[str, tuple[str, bool, tuple[str, float] | None]] = {"own": (own, False, None)}
    if task["control"] == "learned":
        out["blind"] = (own, True, None)
        out["other-c"] = (own, False, cell.other_strength())
    if task["control"] in ("learned", "no-slots") and cell.coevolving:
        out["fixed"] = (FIXED_PREDATOR, False, None)
    if task["control"] == "no-slots" and not cell.coevolving:
        out["other-c"] = (own, False, cell.other_strength())
    return out


def episode_values(result: dict, prey_label: str, predator_label: str) -> dict[str, list[float]]:
    """`{measure: [mean over the episodes of each evaluation seed]}` of one pairing, the ratios included."""
    seeds = sorted({r["seed"] for r in result["episodes"]})
    out: dict[str, list[float]] = {}
    rows = [r for r in result["episodes"] if r["prey_policy"] == prey_label and r["predator_policy"] == predator_label]
    for m in (PRIMARY,) + SECONDARY:
        out[m] = []
        for s in seeds:
            episodes = [r for r in rows if r["seed"] == s]
            if m == "group_lifetime":  # completed groups' lifetimes over the seed's episodes (steps)
                ended = sum(r["swarm_groups_ended"] for r in episodes)
                total = sum(r["swarm_ended_lifetime_total"] for r in episodes)
                out[m].append(total / ended if ended > 0 else float("nan"))
                continue
            key = m if m == "captures_per_prey" else f"swarm_{m}"
            values = [r[key] for r in episodes if not math.isnan(r[key])]
            out[m].append(sum(values) / len(values) if values else float("nan"))
    return out


def run_eval_task(task: dict, device: str) -> dict:
    """One trained prey policy: each of its `evaluations_of`."""
    from ..training.evaluate import evaluate_policies

    values, machine = {}, None
    for label, (predator, blind, strength) in evaluations_of(task).items():
        cfg = world_of(task, *(strength or (None, None)))
        result = evaluate_policies(
            [f"learned={prey_policy(task)}"],
            [predator],
            cfg,
            episodes=task["episodes"],
            seeds=range(task["eval_seeds"]),
            device=device,
            blind_to={"prey": "prey"} if blind else None,
        )
        values[label] = episode_values(result, "learned", result["summary"][0]["predator_policy"])
        machine = result["machine"]
    return json_safe({"values": values, "machine": machine})


def run_baseline_task(task: dict, device: str) -> dict:
    """The heuristic prey in a cell's world (its first `learned` run's) against the fixed predator."""
    from ..training.evaluate import evaluate_policies

    result = evaluate_policies(
        list(HEURISTIC_PREY),
        [FIXED_PREDATOR],
        world_of(task),
        episodes=task["episodes"],
        seeds=range(task["eval_seeds"]),
        device=device,
    )
    return json_safe(
        {"values": {p: episode_values(result, p, FIXED_PREDATOR) for p in HEURISTIC_PREY}, "machine": result["machine"]}
    )


def evaluation_task(study: PhaseStudy, name: str, training: dict) -> dict:
    """A task that plays the policy of `training` (a training task): its training config is part of the
    task, so that a run trained again with other settings is evaluated again."""
    return {
        "name": name,
        **{k: training[k] for k in ("cell", "control", "seed", "coevolving", "run_dir")},
        "training": training["config"],
        "episodes": study.episodes,
        "eval_seeds": study.eval_seeds,
        "max_steps": study.max_steps,
    }


def eval_tasks(study: PhaseStudy, trainings: Sequence[dict]) -> list[dict]:
    """An evaluation per trained policy."""
    return [evaluation_task(study, f"eval-{t['cell']}-{t['control']}-s{t['seed']}", t) for t in trainings]


def baseline_tasks(study: PhaseStudy, trainings: Sequence[dict]) -> list[dict]:
    """The heuristics of each cell, in the world of its first learned run."""
    return [
        evaluation_task(study, f"baseline-{t['cell']}", t)
        for t in trainings
        if t["control"] == "learned" and t["seed"] == 0
    ]


# ---- the readings (pure functions of the per-seed values) ---------------------------------------------


def contrast(a: Sequence[float], b: Sequence[float], measure: str, paired: bool, direction: int = 0) -> dict:
    """mean(a) - mean(b), its 95% interval (Welch, or `paired`), the measure's margin (relative ones as a
    fraction of mean(b)) and the verdict: "effect" when the interval lies beyond the margin (in
    `direction`'s sign where given: -1 below -margin, +1 above +margin, 0 either), "none" when the TOST
    finds equivalence within it, else "undecided"."""
    margin = MARGINS[measure]
    if measure in RELATIVE_MARGINS:
        margin *= abs(mean_interval(b)[0])
    d = difference(a, b, paired=paired)
    below, above = d["high"] < -margin, d["low"] > margin
    effect = below if direction < 0 else above if direction > 0 else below or above
    if effect:
        verdict = "effect"
    elif margin > 0 and equivalence(a, b, margin, paired=paired)["equivalent"]:
        verdict = "none"
    else:
        verdict = "undecided"
    return {
        "difference": d["difference"],
        "low": d["low"],
        "high": d["high"],
        "margin": margin,
        "paired": paired,
        "verdict": verdict,
    }


def regime(primary: Sequence[float], polarization: Sequence[float], rotation: Sequence[float]) -> str:
    """The collective state that `THRESHOLDS` name from the `learned` prey's seed values: "dispersed",
    "no structure", or an aggregate: "polarized school", "mill" or "swarm" (disordered)."""
    stats = interval(list(primary))
    if stats["n"] < 2:
        return "no structure"
    low, high = stats["mean"] - stats["ci95"], stats["mean"] + stats["ci95"]
    if low > THRESHOLDS["dispersed"]:
        return "dispersed"
    if high >= THRESHOLDS["aggregated"]:
        return "no structure"
    p, r = mean_interval(list(polarization))[0], mean_interval(list(rotation))[0]
    if p >= THRESHOLDS["ordered"] and r < THRESHOLDS["disordered"]:
        return "polarized school"
    if r >= THRESHOLDS["ordered"] and p < THRESHOLDS["disordered"]:
        return "mill"
    return "swarm"


def readings(per: dict) -> dict:
    """A cell's regime and its declared contrasts, from `per[control][evaluation][measure]` = seed values."""
    learned = per["learned"]["own"]
    state = regime(learned[PRIMARY], learned["group_polarization"], learned["group_rotation"])
    direction = {"dispersed": 1}.get(state, -1)
    out: dict = {"regime": state, "contrasts": []}

    def add(what: str, a: Sequence[float], b: Sequence[float], measure: str, paired: bool, sign: int = 0) -> None:
        out["contrasts"].append({"contrast": what, "measure": measure, **contrast(a, b, measure, paired, sign)})

    for control, what in (("no-slots", "learned - no prey slots"), ("no-predation", "learned - no predation")):
        if control in per:
            add(what, learned[PRIMARY], per[control]["own"][PRIMARY], PRIMARY, False, direction)
            for m in ("group_polarization", "group_rotation"):
                add(what, learned[m], per[control]["own"][m], m, False, 1)
    if "blind" in per["learned"]:
        blind = per["learned"]["blind"]
        add("learned - its slots emptied (paired)", learned[PRIMARY], blind[PRIMARY], PRIMARY, True, direction)
        add("learned - its slots emptied (paired)", learned["captures_per_prey"], blind["captures_per_prey"],
            "captures_per_prey", True)  # fmt: skip
    if "no-slots" in per:
        add("learned - no prey slots", learned["captures_per_prey"], per["no-slots"]["own"]["captures_per_prey"],
            "captures_per_prey", False)  # fmt: skip
        if "other-c" in per["learned"] and "other-c" in per["no-slots"]:
            add("at the other c: learned - no prey slots", per["learned"]["other-c"]["captures_per_prey"],
                per["no-slots"]["other-c"]["captures_per_prey"], "captures_per_prey", False)  # fmt: skip
    return out


# ---- the summary --------------------------------------------------------------------------------------


def seed_means(record: dict, label: str) -> dict[str, float]:
    """A policy's value of each measure in evaluation `label`: the mean over its evaluation seeds."""
    return {m: mean_interval(record["values"][label][m])[0] for m in (PRIMARY,) + SECONDARY}


def summarize(evaluations: Sequence[tuple[dict, dict]], baselines: Sequence[tuple[dict, dict]]) -> dict:
    """Per cell: per control and evaluation the per-seed values of every measure with their mean and 95%
    interval; the heuristics (over evaluation seeds); the regime and the declared contrasts."""
    seeds: dict[str, dict[str, dict[str, dict[str, list[float]]]]] = {}
    for task, record in evaluations:
        per_control = seeds.setdefault(task["cell"], {}).setdefault(task["control"], {})
        for label in record["values"]:
            values = seed_means(record, label)
            for m, v in values.items():
                per_control.setdefault(label, {}).setdefault(m, []).append(v)
    heuristics = {task["cell"]: record for task, record in baselines}
    cells: dict[str, dict] = {}
    for name, per in seeds.items():
        entry: dict = {"cell": dataclasses.asdict(CELLS[name])}
        entry["controls"] = {
            control: {label: {m: interval(v) for m, v in by.items()} for label, by in labels.items()}
            for control, labels in per.items()
        }
        if name in heuristics:
            entry["heuristics"] = {
                prey: {m: interval(v) for m, v in values.items()} for prey, values in heuristics[name]["values"].items()
            }
        if "learned" in per:
            entry.update(readings(per))
        cells[name] = entry
    return cells


def training_series(trainings: Sequence[dict]) -> list[dict]:
    """Swarm measures over training: per cell, control and iteration (those where episodes ended), the mean over
    seeds of each `Swarm/<measure>` column of the runs' swarm.csv files (the primary measure, largest
    group, per-group polarization and rotation)."""
    import csv

    columns = (PRIMARY, "largest_group", "group_polarization", "group_rotation")
    sums: dict[tuple[str, str, int], dict[str, list[float]]] = {}
    for t in trainings:
        path = os.path.join(t["run_dir"], "swarm.csv")
        if not os.path.exists(path):
            continue
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                iteration = int(row["iteration"])
                key = (t["cell"], t["control"], iteration)
                for c in columns:
                    value = row.get(f"Swarm/{c}")
                    if value not in (None, ""):
                        sums.setdefault(key, {}).setdefault(c, []).append(float(value))
    return [
        {"cell": cell, "control": control, "iteration": it, **{c: mean_interval(v)[0] for c, v in values.items()}}
        for (cell, control, it), values in sorted(sums.items())
    ]


def write_tables(out: str, summary: dict, series: list[dict]) -> None:
    """`cells.csv` (a row per cell, control and evaluation: means and 95% half-widths, with the regime),
    `per_seed.csv` (a row per cell, control, evaluation and training seed), `readings.csv` (a row per
    cell and declared contrast: difference, 95% interval, margin, verdict) and `training_series.csv`."""
    from .common import write_csv

    rows, per_seed = [], []
    for name, entry in summary["cells"].items():
        for control, labels in entry["controls"].items():
            for label, by in labels.items():
                row = {"cell": name, "control": control, "evaluation": label, "regime": entry.get("regime", "")}
                for m, stats in by.items():
                    row[m], row[f"{m}_ci95"] = stats["mean"], stats["ci95"]
                rows.append(row)
                for k in range(len(by[PRIMARY]["values"])):
                    per_seed.append(
                        {"cell": name, "control": control, "evaluation": label, "seed_index": k}
                        | {m: by[m]["values"][k] for m in by}
                    )
        for prey, by in entry.get("heuristics", {}).items():
            row = {"cell": name, "control": prey, "evaluation": "heuristic", "regime": ""}
            for m, stats in by.items():
                row[m], row[f"{m}_ci95"] = stats["mean"], stats["ci95"]
            rows.append(row)
    write_csv(os.path.join(out, "cells.csv"), rows)
    write_csv(os.path.join(out, "per_seed.csv"), per_seed)
    write_csv(
        os.path.join(out, "readings.csv"),
        [
            {"cell": name, "regime": entry["regime"], **contrast}
            for name, entry in summary["cells"].items()
            for contrast in entry.get("contrasts", [])
        ],
    )
    if series:
        write_csv(os.path.join(out, "training_series.csv"), series)


def run(args) -> int:
    from ..arguments import plural
    from ..atomic import atomic_open, check_output_dir

    study = check(args)
    devices = task_devices(study.gpus)
    trainings = training_tasks(study)  # their configs checked before anything runs
    check_output_dir(study.out, "--out")
    os.makedirs(study.out, exist_ok=True)
    start = time.perf_counter()

    def part(heading: str, function, tasks: list[dict], label: str) -> list:
        todo = sum(not read_finished(study.out, task)[0] for task in tasks)
        print(f"study phase: {heading} ({todo} to run)", flush=True)
        jobs = study.per_gpu if devices[0] != "cpu" else 1
        report = lambda line: print(line, flush=True)  # noqa: E731
        return run_jobs(function, tasks, study.out, jobs=jobs, devices=devices, label=label, report=report).results

    trained = part(
        f"training {plural(len(study.cells), 'cell')} x controls x {plural(study.seeds, 'seed')}",
        run_training_task,
        trainings,
        "train",
    )
    evaluations = eval_tasks(study, trainings)
    evaluated = part(f"evaluating {len(evaluations)} policies", run_eval_task, evaluations, "eval")
    baselines = baseline_tasks(study, trainings)
    heuristics = part(f"heuristic prey in {len(baselines)} cells", run_baseline_task, baselines, "baselines")
    summary: dict = {
        "design": {
            "cells": {name: dataclasses.asdict(CELLS[name]) for name in study.cells},
            "controls": CONTROLS,
            "evaluations": EVALUATIONS,
            "primary": PRIMARY,
            "secondary": SECONDARY,
            "thresholds": THRESHOLDS,
            "margins": MARGINS,
            "fixed_predator": FIXED_PREDATOR,
            "contact_penalty": CONTACT_PENALTY,
            "pool": POOL,
            "fast": FAST,
            "train_agent_steps": TRAIN_AGENT_STEPS,
            "iterations": study.iterations,
            "seeds": study.seeds,
            "control_seeds": study.control_seeds,
            "episodes": study.episodes,
            "eval_seeds": study.eval_seeds,
            "max_steps": study.max_steps,
            "train_set": study.train_set,
        },
        "trainings": [
            {k: t[k] for k in ("cell", "control", "seed", "run_dir")} | r
            for t, r in zip(trainings, trained, strict=True)
        ],
        "cells": summarize(
            list(zip(evaluations, evaluated, strict=True)), list(zip(baselines, heuristics, strict=True))
        ),
    }
    series = training_series(trainings)  # written to training_series.csv only: it is most of the data
    summary.update(provenance(devices[0], command_line(args.argv), commit=study.commit))
    summary["wall_s"] = round(time.perf_counter() - start, 1)
    with atomic_open(os.path.join(study.out, "summary.json")) as f:
        json.dump(json_safe(summary), f, indent=1)
    write_tables(study.out, summary, series)
    if study.figures:
        plot(study.out, summary, series)
    print(f"study phase: wrote {os.path.join(study.out, 'summary.json')} ({summary['wall_s']} s)")
    for name, entry in summary["cells"].items():
        if "regime" in entry:
            stats = entry["controls"]["learned"]["own"][PRIMARY]
            print(f"  {name}: {entry['regime']} ({PRIMARY} {stats['mean']:.3f} +- {stats['ci95'] or 0:.3f})")
    return 0


# ---- figures ------------------------------------------------------------------------------------------


def plot(out: str, summary: dict, series: list[dict]) -> None:
    """`phase_density_view.png`: heatmaps over prey count x view distance of the primary measure and the
    largest group (learned prey and their no-slot control), each cell with its mean, 95% half-width and
    regime; `phase_rule.png`: the primary measure and captures against c for both rules with 95% bands
    (learned, no slots, no predation, Boids, TurnAway); `phase_series.png`: the primary over training
    per cell."""
    from .common import band, pyplot, save_figure

    plt = pyplot()
    cells = summary["cells"]

    def stats(name: str, control: str, measure: str, label: str = "own") -> dict | None:
        return cells.get(name, {}).get("controls", {}).get(control, {}).get(label, {}).get(measure)

    grid = {(c.prey, c.view): n for n, c in CELLS.items() if c.slice == "density-view"} | {(32, 200.0): "dilution-c64"}
    if any(n in cells for n in grid.values()):
        counts, views = sorted({k[0] for k in grid}), sorted({k[1] for k in grid})
        panels = [
            ("learned", PRIMARY),
            ("no-slots", PRIMARY),
            ("learned", "largest_group"),
            ("learned", "group_polarization"),
        ]
        fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.8))
        for ax, (control, measure) in zip(axes, panels, strict=True):
            image = [
                [(stats(grid[(n, v)], control, measure) or {}).get("mean", float("nan")) for v in views] for n in counts
            ]
            ax.imshow(image, origin="lower", cmap="viridis", aspect="auto")
            for i, n in enumerate(counts):
                for j, v in enumerate(views):
                    s = stats(grid[(n, v)], control, measure)
                    if s is not None:
                        regime_name = cells[grid[(n, v)]].get("regime", "") if control == "learned" else ""
                        text = f"{s['mean']:.2f}\n+-{s['ci95'] or 0:.2f}\n{regime_name}"
                        ax.text(j, i, text, ha="center", va="center", fontsize=7, color="white")
            ax.set_xticks(range(len(views)), [f"{v:g}" for v in views])
            ax.set_yticks(range(len(counts)), [str(n) for n in counts])
            ax.set_xlabel("prey view distance (px)")
            ax.set_ylabel("prey per world")
            ax.set_title(f"{control}: {measure}", fontsize=9)
        save_figure(fig, out, "phase_density_view.png", "Dilution c = 64, 360 degrees, NaivChase (nearest target)")
    rule_cells = {n: c for n, c in CELLS.items() if c.slice == "rule" and n in cells}
    if rule_cells:
        strengths = sorted({c.strength for c in rule_cells.values()})
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
        for ax, measure in zip(axes, (PRIMARY, "captures_per_prey"), strict=True):
            for rule in ("dilution", "confusion"):
                names = [n for n, c in rule_cells.items() if c.rule == rule or c.strength == 0]
                names.sort(key=lambda n: rule_cells[n].strength)
                x = [strengths.index(rule_cells[n].strength) for n in names]
                for control in ("learned", "no-slots", "no-predation"):
                    points = [p for n in names if (p := stats(n, control, measure)) is not None]
                    if names and len(points) == len(names):
                        band(ax, x, points, label=f"{rule}: {control}")
            ax.set_xticks(range(len(strengths)), [f"{c:g}" for c in strengths])
            ax.set_xlabel("capture strength c")
            ax.set_ylabel(measure)
        axes[0].legend(fontsize=7)
        save_figure(fig, out, "phase_rule.png", "N = 32, 360 degrees / 200 px, NaivChase (nearest target)")
    if series:
        fig, ax = plt.subplots(figsize=(7, 4))
        for name in sorted({r["cell"] for r in series}):
            rows = [r for r in series if r["cell"] == name and r["control"] == "learned" and PRIMARY in r]
            if rows:
                ax.plot([r["iteration"] for r in rows], [r[PRIMARY] for r in rows], label=name, lw=1)
        ax.set_xlabel("PPO iteration")
        ax.set_ylabel(PRIMARY)
        ax.legend(fontsize=6, ncol=2)
        save_figure(fig, out, "phase_series.png", "Learned prey over training (mean over seeds)")
