"""`aquarium-warp study group-hunting`: does cooperative hunting emerge among learning predators, and
does the shared catch reward cause it? (The paper's open question after Ritz et al. 2021.)

For every team size (1-4 predators, parameter sharing), prey condition and catch-sharing radius, each
seed trains one run and evaluates it:
- prey conditions: `turnaway` (predators learn against TurnAway prey, `team predator`) and `cotrained`
  (both teams learn in the same worlds, `team both`; evaluated against the prey trained with them);
- catch sharing: `catch_share_radius` 100 px (docs/model.md's default: every predator within 100 px of the
  captured prey shares the reward) and 0 px (only the capturer(s) in contact are rewarded: docs/model.md's
  sharers are the predators strictly within the radius plus every capturer);
- baseline: NaivChase predators against TurnAway prey at each team size (no training); with
  `--random-baseline` also predators that act at random (the floor a learned team must beat),
  compared with the teams trained against TurnAway prey in `random_differences`.

Evaluation: `eval_worlds` episodes of `eval_steps` steps per seed, deterministic (argmax) policies.
Measures, per seed (`HuntMeasures`):
- `captures_per_predator`: captures per predator per episode (and `captures_per_prey`).
- `joint_fraction`: fraction of captures with at least one other predator within `hunt_radius` of the
  capture point (default 200 px, the predator's view distance: a predator that close could see the prey
  and take part). The capture point is the captured prey's position at the start of its capture step
  (the simulator respawns it in the step; it moved at most its max speed, 4 px).
- `spread_capture`: the circular variance `1 - |mean of unit bearings|` of the predators within
  `hunt_radius` of the capture point, bearings taken from that point (captures with >= 2 such
  predators). 0: all predators on one side of the prey (a chase in file); 1: balanced around it
  (encircling). `gap_capture`: the largest angular gap between those bearings, degrees (360 (1 - 1/k)
  at best for k predators; 360 when they coincide). The circular variance needs no choice of angle
  origin and averages over any number of predators, so it is the headline; the gap is reported too.
- `spread_random`, `gap_random`: the same measures around every live prey at states sampled every
  `sample_every` steps, where >= 2 predators are within `hunt_radius` (the baseline: predators near a
  prey without capturing it).
- `pair_distance_capture`, `pair_distance_random`: mean torus distance between live predators at
  capture steps (in the capture's world) and at the sampled states. Hunting as a pack: smaller at
  captures; converging from different sides: the spread rises at captures.

Cooperation shows as captures per predator that grow with team size where the baseline's fall
(interference), joint captures above the baseline's rate, and a spread at captures above the random
times'. Comparing the shared and individual rewards at each team size tests whether sharing causes it.

The redesign (issue #30; `--predator-speed`, `--predator-slots`, `--recipe`): in the design above a lone
predator outruns its prey (5 against 4 px/step), each predator sees at most one teammate, and the shared
reward touches a minority of captures, so cooperation cannot pay. `--predator-speed 4` makes predators
no faster than prey, `--predator-slots 3` shows each predator its teammates, `--recipe` trains both
teams with the learned-prey recipe; a "sharing makes no difference" reading needs the TOST of
`reward_differences[...]["equivalence"]` (within `SHARING_MARGIN` of the capturer-only mean).

Outputs (`--out`, default `group_hunting/` in the current directory): `group_hunting.csv` (one row per
condition, team size and seed), `group_hunting.json` (settings, command, machine, timings, means and
s.e.m. over seeds, definitions), `group_hunting.png`, the trained policies in `policies/` and each
task's result in `finished/` (a rerun of the same command keeps them and runs only the others).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..arguments import (
    add_options,
    check_distinct,
    check_int,
    check_number,
    from_options,
    int_at_least,
    number_list,
    option,
    plural,
    positive_float,
    positive_int,
    word_list,
)
from ..atomic import check_output_dir
from ..config import AquariumConfig
from ..jobs import RayOptions, add_ray_arguments, ray_options
from ..records import command_line
from ..seeding import evaluation_seed
from ..statistics import compare, equivalence, finite, seed_stats
from ..training.config import LEARNED_PREY_RECIPE, env_config
from . import common
from .jobs import run_tasks

if TYPE_CHECKING:
    import torch

    from ..rollout import StepView


PREY_CONDITIONS = ("turnaway", "cotrained")
# Heuristic predator teams of the baselines (their condition names) -> how the labels name them.
HEURISTIC_TEAMS = {"naivchase": "NaivChase", "random": "random predators"}
# "Sharing makes no difference" needs the 90% interval of shared minus capturer-only captures per
# predator inside +-SHARING_MARGIN of the capturer-only mean (declared with the redesign).
SHARING_MARGIN = 0.10
MEASURES = (
    "captures_per_predator",
    "captures_per_prey",
    "joint_fraction",
    "spread_capture",
    "spread_random",
    "gap_capture",
    "gap_random",
    "pair_distance_capture",
    "pair_distance_random",
)


@dataclass
class GroupHuntingStudy:
    """Settings of the group-hunting study (the CLI's options; defaults sized for one H200 in ~7 min)."""

    # Settings that only list which tasks exist (jobs.task_key): a run over fewer keeps the rest.
    TASK_AXES = ("predators", "prey_conditions", "share_radii", "baseline", "random_baseline")

    predators: list[int] = field(
        default_factory=lambda: [1, 2, 3, 4],
        metadata=option("predator team sizes (list)", parse=lambda text, flag: number_list(text, int, flag, 1, 64)),
    )
    prey: int = field(
        default=6, metadata=option("prey per world, the same at every team size (the paper's)", type=positive_int)
    )
    prey_conditions: list[str] = field(
        default_factory=lambda: list(PREY_CONDITIONS),
        metadata=option(
            "comma list of 'turnaway' (predators learn against TurnAway) and 'cotrained' (both teams learn; team both)",
            parse=word_list,
        ),
    )
    share_radii: list[float] = field(
        default_factory=lambda: [100.0, 0.0],
        metadata=option(
            "catch_share_radius values, px (list; 0: the capturer alone)",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, 1e6),
            flag="--share-radius",
        ),
    )
    seeds: int = 5
    worlds: int = field(default=1024, metadata=option("training worlds per run", type=positive_int))
    iterations: int = field(default=100, metadata=common.ITERATIONS)
    train_steps: int = field(default=500, metadata=common.TRAIN_STEPS)
    eval_worlds: int = field(default=32, metadata=option("evaluation episodes (worlds) per seed", type=positive_int))
    eval_steps: int = field(default=1000, metadata=common.EVAL_STEPS)
    hunt_radius: float = field(
        default=200.0,
        metadata=option(
            "px; predators this close to a capture take part in it (the predator's view)", type=positive_float
        ),
    )
    sample_every: int = field(
        default=10, metadata=option("steps between the random-time states of the baselines", type=positive_int)
    )
    baseline: bool = field(default=True, metadata=option("no NaivChase teams", negated=True))
    random_baseline: bool = field(
        default=False,
        metadata=option("also random predator teams against TurnAway prey (the floor a learned team must beat)"),
    )
    world_size: float = 800.0
    # The redesign (issue #30): predators that cannot win alone (`predator_speed`, None: docs/model.md's 5;
    # the prey's is 4), predators that see their teammates (`predator_slots` predator slots, None: 1),
    # and the learned-prey recipe for both teams (`recipe`: ego observations, random spawn headings,
    # entropy 0.01).
    predator_speed: float | None = field(
        default=None,
        metadata=option(
            "predator max speed (default docs/model.md's 5; the prey's is 4: 4 or less and a lone predator "
            "cannot simply outrun its prey)",
            type=positive_float,
        ),
    )
    predator_slots: int | None = field(
        default=None,
        metadata=option(
            "predator slots each agent observes (default 1: a predator sees at most one teammate)",
            type=int_at_least(0),
        ),
    )
    recipe: bool = field(
        default=False,
        metadata=option("train with the learned-prey recipe: ego observations, random spawn headings, entropy 0.01"),
    )
    device: str | None = None
    jobs: int | None = None
    out: str = "group_hunting"
    figures: bool = True

    def validate(self) -> None:
        if not self.predators:
            raise ValueError("predators must list at least one team size")
        for name, values in (
            ("--predators", self.predators),
            ("--prey-conditions", self.prey_conditions),
            ("--share-radius", self.share_radii),
        ):
            check_distinct(name, values)
        for n in self.predators:
            check_int("predators", n)
        for name in (
            "prey",
            "seeds",
            "worlds",
            "iterations",
            "train_steps",
            "eval_worlds",
            "eval_steps",
            "sample_every",
        ):
            check_int(name.replace("_", "-"), getattr(self, name))
        if self.eval_steps < 2 or self.train_steps < 2:
            raise ValueError("eval-steps and train-steps must be >= 2 (an episode's last state is the next one's)")
        bad = [c for c in self.prey_conditions if c not in PREY_CONDITIONS]
        if bad or not self.prey_conditions:
            raise ValueError(f"prey conditions {self.prey_conditions!r} must be a non-empty list of {PREY_CONDITIONS}")
        if not self.share_radii:
            raise ValueError("share radii must list at least one catch_share_radius")
        for r in self.share_radii:
            check_number("share radius", r, 0.0, 1e6)
        check_number("hunt-radius", self.hunt_radius, 1e-3, 1e6)
        check_number("world-size", self.world_size, 100.0, 1e6)
        if self.predator_speed is not None:
            check_number("predator-speed", self.predator_speed, 0.1, 1e3)
        if self.predator_slots is not None:
            check_int("predator-slots", self.predator_slots, low=0)

    def env(self, predators: int, share_radius: float, steps: int) -> dict:
        """The world's config fields (a predator never starves within an episode: one full episode per world)."""
        env: dict = {
            "prey_count": self.prey,
            "predator_count": predators,
            "catch_share_radius": float(share_radius),
            "max_steps": steps,
            "predator_starvation_steps": steps,
            "width": self.world_size,
            "height": self.world_size,
        }
        predator: dict = {}
        if self.predator_speed is not None:
            predator["max_speed"] = float(self.predator_speed)
        if self.predator_slots is not None:
            predator["predator_slots"] = int(self.predator_slots)
        if predator:
            env["predator"] = predator
        if self.recipe:
            env.update(LEARNED_PREY_RECIPE["env"])
        return env

    def tasks(self, device: str) -> list[dict]:
        """One task per (condition, team size, seed): training runs first, the longest (both teams learning)
        first, then the baselines."""
        tasks = []
        for condition in sorted(self.prey_conditions, key=lambda c: c != "cotrained"):
            for radius in self.share_radii:
                for n in self.predators:
                    for seed in range(self.seeds):
                        name = f"{condition}_share{radius:g}_pred{n}_seed{seed}"
                        tasks.append(
                            {
                                "name": name,
                                "condition": condition,
                                "share_radius": radius,
                                "predators": n,
                                "seed": seed,
                                "train": True,
                                "device": device,
                                "study": self,
                                "policy_dir": os.path.join(self.out, "policies", name),
                            }
                        )
        heuristics = ["naivchase"] * self.baseline + ["random"] * self.random_baseline
        for predator in heuristics:
            for n in self.predators:
                for seed in range(self.seeds):
                    tasks.append(
                        {
                            "name": f"{predator}_pred{n}_seed{seed}",
                            "condition": predator,
                            "share_radius": AquariumConfig().catch_share_radius,
                            "predators": n,
                            "seed": seed,
                            "train": False,
                            "device": device,
                            "study": self,
                        }
                    )
        return tasks


# ---------------------------------------------------------------------------------------------- measures
def encirclement(
    centre: torch.Tensor, predators: torch.Tensor, alive: torch.Tensor, radius: float, width: float, height: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """How the predators `[E, P, 2]` (`alive` `[E, P]`) surround the points `centre` `[E, 2]`: the number
    within `radius` px (torus), the circular variance of their bearings from the centre (1 - |mean unit
    bearing|) and the largest angular gap between the bearings (degrees); the last two NaN where fewer
    than two predators are within `radius`."""
    import torch

    delta = common.torus_delta(predators - centre[:, None, :], width, height).double()
    near = alive & (torch.linalg.vector_norm(delta, dim=-1) < radius)
    count = near.sum(dim=1)
    unit = delta / torch.linalg.vector_norm(delta, dim=-1, keepdim=True).clamp_min(1e-12)
    mean = (unit * near[..., None]).sum(dim=1) / count.clamp_min(1)[:, None]
    variance = 1 - torch.linalg.vector_norm(mean, dim=-1)
    angle = torch.atan2(delta[..., 1], delta[..., 0]) % (2 * math.pi)
    ordered = torch.sort(torch.where(near, angle, torch.full_like(angle, 10.0)), dim=1).values
    gaps = ordered[:, 1:] - ordered[:, :-1]
    index = torch.arange(gaps.shape[1], device=gaps.device)
    gaps = torch.where(index[None, :] < (count - 1)[:, None], gaps, torch.zeros_like(gaps))
    last = torch.gather(ordered, 1, (count - 1).clamp_min(0)[:, None]).squeeze(1)
    wrap = ordered[:, 0] + 2 * math.pi - last
    gap = torch.maximum(gaps.max(dim=1).values if gaps.shape[1] else wrap, wrap)
    few = count < 2
    nan = torch.full_like(variance, math.nan)
    return count, torch.where(few, nan, variance), torch.where(few, nan, torch.rad2deg(gap))


def pair_distances(predators: torch.Tensor, alive: torch.Tensor, width: float, height: float) -> torch.Tensor:
    """Torus distances between every pair of live predators of each world (`[W, P, 2]`): a flat tensor."""
    import torch

    P = predators.shape[1]
    i, j = torch.triu_indices(P, P, offset=1, device=predators.device)
    d = torch.linalg.vector_norm(common.torus_delta(predators[:, i] - predators[:, j], width, height), dim=-1)
    return d[alive[:, i] & alive[:, j]]


class HuntMeasures:
    """Accumulates the capture geometry of a rollout (`common.rollout`'s `on_step`); see the module doc."""

    def __init__(self, hunt_radius: float, sample_every: int, width: float, height: float):
        self.radius, self.every, self.width, self.height = hunt_radius, sample_every, width, height
        self.values: dict[str, list[torch.Tensor]] = {
            k: []
            for k in (
                "count",
                "spread_capture",
                "gap_capture",
                "spread_random",
                "gap_random",
                "pair_capture",
                "pair_random",
            )
        }

    def __call__(self, view: StepView) -> None:
        import torch

        Pc = view.captured.shape[1]
        predators, alive = view.position[:, Pc:], view.alive[:, Pc:]
        if view.step % self.every == 0:  # around every live prey (row w * Pc + i: world w's predators)
            prey_alive = view.alive[:, :Pc].reshape(-1)
            centres = view.position[:, :Pc].reshape(-1, 2)[prey_alive]
            around = predators.repeat_interleave(Pc, dim=0)[prey_alive]
            _, spread, gap = encirclement(
                centres, around, alive.repeat_interleave(Pc, dim=0)[prey_alive], self.radius, self.width, self.height
            )
            self.values["spread_random"].append(spread)
            self.values["gap_random"].append(gap)
            self.values["pair_random"].append(pair_distances(predators, alive, self.width, self.height))
        if not bool(view.captured.any()):
            return
        world, slot = torch.nonzero(view.captured, as_tuple=True)
        count, spread, gap = encirclement(
            view.before_position[world, slot], predators[world], alive[world], self.radius, self.width, self.height
        )
        self.values["count"].append(count)
        self.values["spread_capture"].append(spread)
        self.values["gap_capture"].append(gap)
        self.values["pair_capture"].append(pair_distances(predators[world], alive[world], self.width, self.height))

    def result(self) -> dict[str, float]:
        import torch

        def mean(name: str, where=None) -> float:
            parts = self.values[name]
            if not parts:
                return math.nan
            v = torch.cat([p.double().reshape(-1) for p in parts])
            if where is not None:
                v = where(v).double()
            v = v[~torch.isnan(v)]
            return float(v.mean()) if v.numel() else math.nan

        return {
            "joint_fraction": mean("count", lambda c: c >= 2),
            "spread_capture": mean("spread_capture"),
            "spread_random": mean("spread_random"),
            "gap_capture": mean("gap_capture"),
            "gap_random": mean("gap_random"),
            "pair_distance_capture": mean("pair_capture"),
            "pair_distance_random": mean("pair_random"),
        }


# ---------------------------------------------------------------------------------------------- one task
def task_training(task: dict) -> dict | None:
    """The run config a task trains (None: a baseline trains nothing)."""
    if not task["train"]:
        return None
    study: GroupHuntingStudy = task["study"]
    both = task["condition"] == "cotrained"
    return common.training_config(
        study.env(task["predators"], task["share_radius"], study.train_steps),
        "both" if both else "predator",
        None if both else "turnaway",
        study.worlds,
        study.iterations,
        task["seed"],
        task["device"],
        study.recipe,
    )


def run_task(task: dict) -> dict:
    """Train (unless a baseline) and evaluate one (condition, team size, seed); a worker's job."""
    start = time.perf_counter()
    study: GroupHuntingStudy = task["study"]
    n, seed, device = task["predators"], task["seed"], task["device"]
    train_s = 0.0
    prey, predator = "turnaway", task["condition"]  # a baseline's condition names its heuristic predator
    config = task_training(task)
    if config is not None:
        policies, train_s = common.train_and_export(config, task["policy_dir"])
        predator = policies["predator"]
        prey = policies.get("prey", "turnaway")
    cfg = env_config({"env": study.env(n, task["share_radius"], study.eval_steps)})
    measures = HuntMeasures(study.hunt_radius, study.sample_every, cfg.width, cfg.height)
    episodes = common.rollout(cfg, prey, predator, study.eval_worlds, evaluation_seed(seed), device, measures)
    result = {
        "captures_per_predator": float(episodes["captures"].mean()) / n,
        "captures_per_prey": float(episodes["captures"].mean()) / study.prey,
        **measures.result(),
    }
    return {
        **{k: task[k] for k in ("name", "condition", "share_radius", "predators", "seed")},
        **result,
        "train_s": train_s,
        "job_s": time.perf_counter() - start,
    }


# ---------------------------------------------------------------------------------------------- study
def condition_label(condition: str, share_radius: float) -> str:
    if condition in HEURISTIC_TEAMS:
        return f"{HEURISTIC_TEAMS[condition]} vs TurnAway (heuristic)"
    prey = "TurnAway prey" if condition == "turnaway" else "co-trained prey"
    reward = f"shared within {share_radius:g} px" if share_radius > 0 else "capturer only"
    return f"learned vs {prey}, reward {reward}"


def run_group_hunting(
    study: GroupHuntingStudy,
    command: str | None = None,
    ray: RayOptions | None = None,
    runs_per_process: int | None = None,
) -> dict:
    """Run every task (`study.jobs` at once), write the CSV, JSON and figure; return the JSON's content.
    `command`: the command line recorded in the JSON (default: this process's, `records.command_line`).
    `ray`: run each training run as a Ray task instead (`jobs`); the JSON then has a "ray" entry. Without
    it, trainings that may share a process train first as populations (`jobs.run_tasks`;
    `runs_per_process`, None: as many as the device holds)."""
    run = run_tasks(study, run_task, "group-hunting", ray, training=task_training, runs_per_process=runs_per_process)
    results = run.results
    rows = [{k: v for k, v in r.items() if k != "name"} for r in results]
    groups = common.group_rows(results, ("condition", "share_radius", "predators"))
    entries = [
        {
            "condition": c,
            "share_radius": radius,
            "predators": n,
            "label": condition_label(c, radius),
            "metrics": {m: seed_stats([r[m] for r in rs]) for m in MEASURES},
        }
        for (c, radius, n), rs in groups.items()
    ]
    summary = run.record("group-hunting", study, results, command)
    summary["reward_differences"] = [
        {
            "condition": c,
            "predators": n,
            "share_radius": radius,
            "minus_share_radius": 0.0,
            "differences": compare(groups[(c, radius, n)], groups[(c, 0.0, n)], MEASURES),
            "equivalence": sharing_equivalence(groups[(c, radius, n)], groups[(c, 0.0, n)]),
        }
        for c in study.prey_conditions
        for n in study.predators
        for radius in study.share_radii
        if radius != 0 and 0 in study.share_radii
    ]
    if study.random_baseline:
        default_radius = AquariumConfig().catch_share_radius
        summary["random_differences"] = [
            {
                "condition": c,
                "predators": n,
                "share_radius": radius,
                "differences": compare(groups[(c, radius, n)], groups[("random", default_radius, n)], MEASURES),
            }
            for c in study.prey_conditions
            if c == "turnaway"  # the random teams hunt TurnAway prey: co-trained teams face other prey
            for n in study.predators
            for radius in study.share_radii
        ]
    summary["definitions"] = {
        "captures_per_predator": f"captures per predator per episode of {study.eval_steps} steps "
        f"({study.eval_worlds} episodes per seed, deterministic policies)",
        "joint_fraction": f"fraction of captures with >= 2 predators within {study.hunt_radius:g} px of the "
        "capture point (the captured prey's position at the start of its capture step)",
        "spread": "circular variance of the bearings from the capture point (or a prey, random times) of the "
        "predators within hunt_radius, where >= 2: 0 all on one side, 1 balanced around",
        "gap": "largest angular gap between those bearings, degrees",
        "random": f"around every live prey at states sampled every {study.sample_every} steps",
        "pair_distance": "mean torus distance between live predators, px (capture steps / sampled states)",
        "cotrained": "prey and predators trained together (team both); evaluated against each other",
        "share_radius": "catch_share_radius in training and evaluation; 0: only the capturer(s) are rewarded",
        "reward_differences": "per prey condition and team size, the shared reward (share_radius) minus the "
        "capturer alone (0): difference of the seed means with its 95% Welch interval "
        "(null with fewer than 2 seeds); equivalence: TOST of captures per predator within "
        f"+-{SHARING_MARGIN:.0%} of the capturer-only mean",
        "random_differences": "with --random-baseline, per sharing radius and team size: the learned team "
        "trained against TurnAway prey minus random predator teams (against TurnAway prey), difference of the "
        "seed means with its 95% Welch interval",
        "design": (
            f"predator max speed {study.predator_speed if study.predator_speed is not None else 5.0:g} "
            f"(prey 4), {study.predator_slots if study.predator_slots is not None else 1} predator slot(s), "
            + (
                f"the learned-prey recipe {LEARNED_PREY_RECIPE}"
                if study.recipe
                else "the paper preset's observations and PPO settings"
            )
        ),
    }
    summary["results"] = entries
    return common.write_outputs(
        study.out, "group_hunting", rows, summary, plot_group_hunting if study.figures else None
    )


def sharing_equivalence(shared: list[dict], alone: list[dict]) -> dict | None:
    """TOST of captures per predator, shared minus capturer-only, within `SHARING_MARGIN` of the
    capturer-only mean (None below two seeds each, or without captures)."""
    x, y = (
        finite(np.asarray([r["captures_per_predator"] for r in rows], dtype=np.float64)) for rows in (shared, alone)
    )
    if len(x) < 2 or len(y) < 2 or not float(np.mean(y)) > 0:
        return None
    return equivalence(x.tolist(), y.tolist(), SHARING_MARGIN * float(np.mean(y)))


def plot_group_hunting(summary: dict, out: str) -> str:
    """Four panels against team size: captures per predator, joint captures, spread (captures solid,
    random times dotted), predator-predator distance (captures solid, random times dotted)."""
    plt = common.pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    panels = [
        ("captures_per_predator", None, "captures per predator per episode"),
        ("joint_fraction", None, "captures with another predator near"),
        ("spread_capture", "spread_random", "circular variance of predator bearings"),
        ("pair_distance_capture", "pair_distance_random", "predator-predator distance (px)"),
    ]
    labels = list(dict.fromkeys(e["label"] for e in summary["results"]))
    for k, label in enumerate(labels):
        entries = sorted((e for e in summary["results"] if e["label"] == label), key=lambda e: e["predators"])
        x = np.array([e["predators"] for e in entries], dtype=float)
        for ax, (metric, baseline, _) in zip(axes.flat, panels):
            common.band(ax, x, [e["metrics"][metric] for e in entries], label, color=colors[k % len(colors)])
            if baseline is not None:
                common.band(ax, x, [e["metrics"][baseline] for e in entries], None, "s:", color=colors[k % len(colors)])
    sizes = sorted({e["predators"] for e in summary["results"]})
    for ax, (_, baseline, ylabel) in zip(axes.flat, panels):
        ax.set_xticks(sizes)
        ax.set_xlabel("predators (team size)")
        ax.set_ylabel(ylabel + (" (solid: at captures, dotted: random times)" if baseline else ""), fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, frameon=False)
    settings = summary["settings"]
    return common.save_figure(
        fig,
        out,
        "group_hunting.png",
        f"Group hunting: {settings['prey']} prey, {settings['seeds']} seeds, "
        f"{settings['iterations']} PPO iterations x {settings['worlds']} worlds per run",
    )


__all__ = ["GroupHuntingStudy", "run_group_hunting", "encirclement", "pair_distances", "HuntMeasures"]


# ---------------------------------------------------------------------------------------------- command line
HELP = "learning predator teams of 1-4: does cooperative hunting emerge, and does the shared catch reward cause it?"
DESCRIPTION = (
    "For every predator team size, prey condition (TurnAway prey, or prey co-trained with the predators) "
    "and catch_share_radius (shared reward, or 0: the capturer alone), train --seeds runs and evaluate "
    "them: captures per predator, joint captures, the predators' angular spread around the capture point "
    "and their distances, at captures and at random times; NaivChase teams as the baseline. Writes "
    "group_hunting.csv/json/png into --out."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, GroupHuntingStudy)
    common.add_common_arguments(p, "group_hunting")
    add_ray_arguments(p, "training run (with its evaluations) or NaivChase baseline")


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study group-hunting`: learning predator teams, with and without shared catch rewards."""
    study = from_options(GroupHuntingStudy, args, **common.common_settings(args))
    print(
        f"aquarium-warp study group-hunting: predators {study.predators}, {study.prey} prey "
        f"({', '.join(study.prey_conditions)}), catch_share_radius {study.share_radii}, "
        f"{plural(study.seeds, 'seed')} -> {study.out}"
    )
    check_output_dir(study.out, "--out")
    summary = run_group_hunting(study, command_line(args.argv), ray_options(args))
    print(f"{common.written(summary)} ({summary['training_fraction']:.0%} of the workers' time training)")
    return 0
