"""`aquarium-warp study many-eyes`: do learned prey in larger groups detect and escape a predator
earlier than alone, beyond dilution? (The paper's open question on the many-eyes hypothesis.)

For every group size N and prey field-of-view angle, each seed trains prey (parameter sharing) against
one NaivChase predator and evaluates them against NaivChase with confusion (a random visible prey each
step) and without (the nearest), in docs/model.md's 800 x 800 world. The training budget per run is the
same number of prey-steps at every N: `rows` learning rows per iteration, so `rows // N` worlds of N
prey (more worlds for small groups), `iterations` PPO iterations of 32 steps. TurnAway prey (which react
only to a predator they see themselves) are evaluated the same way as a heuristic reference.

Measures, per seed (`eval_rows // N` evaluation worlds of one `eval_steps`-step episode each):
- `captures_per_prey` per episode. Next to it, the pure-dilution expectation
  `dilution(N) = c(N0) * N0 / N` (N0 the smallest group size, normally 1): what each prey would
  suffer if the predator's total capture rate stayed that of the smallest group and were shared among
  N prey. Vigilance (or confusion) shows as captures below it; a predator that finds prey faster
  in bigger groups pushes captures above it, so dilution alone is an upper bound on the benefit.
- Flight onsets (`FlightOnsets`): a prey *flees* at a step when its nearest predator is within
  `flee_distance` px, it moves at >= half its max speed, and its velocity points away from the
  predator within `flee_angle` degrees (`common.fleeing`). A *flight onset* is a step t where it
  flees, did not flee at t - 1 nor at t - `lag`, and its velocity turned by at least `turn_angle`
  degrees since t - `lag` (the prey's own turn started the flight, not the predator passing by), with
  no same-type contact push in those moves (a bounce off a neighbour is no decision); the prey must
  have lived `lag` steps (no respawn in between).
- `fid`: the flight initiation distance, the distance to the nearest predator at t - `lag`, when the
  turn began (px): earlier detection = larger.
- `blind_fraction`: the fraction of onsets where the predator was not visible to the prey itself
  (beyond its view distance or outside its view cone) at every step from t - `lag` to t - 1. A
  memoryless prey that turns away from a predator it cannot see has the information from its
  neighbours, or turned by chance: the N = 1 value and TurnAway's at the same N (TurnAway reacts only
  to what it sees) are the chance levels. Many eyes: this fraction and the FID grow with N beyond them.
- `onsets_per_prey`: flight onsets per prey per 1000 steps.

The redesign (issue #30; `--area-per-prey`, `--recipe`, `--neighbour-control`): in the fixed 800 x 800
arena N confounds group size with density, the prey see neighbours' positions but not their motion, and
nothing tells detection through neighbours from chance. `--area-per-prey A` keeps the density fixed (a
square arena of side sqrt(N A)); `--recipe` trains with the learned-prey recipe, whose ego observations
give every neighbour's relative velocity; `--neighbour-control` trains the same prey without prey slots
at every N > 1, the control for detection through neighbours: many eyes needs the FID and the blind
fraction above it (`learned_minus_no_neighbours`, with TOST equivalence within `MARGINS` for a null).

Outputs (`--out`, default `many_eyes/` in the current directory): `many_eyes.csv` (one row per policy, N,
FOV, predator and seed), `many_eyes.json` (settings, command, machine, timings, means and s.e.m.,
dilution expectations, definitions), `many_eyes.png`, the trained policies in `policies/` and each
task's result in `finished/` (a rerun of the same command keeps them and runs only the others).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..arguments import (
    add_options,
    check_distinct,
    check_int,
    check_number,
    from_options,
    non_negative_float,
    number_list,
    option,
    plural,
    positive_float,
    positive_int,
)
from ..atomic import check_output_dir
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


PREDATORS = ("naivchase", "naivchase-noconfusion")
MEASURES = ("captures_per_prey", "fid", "blind_fraction", "onsets_per_prey")
# Equivalence margins of the neighbour control, declared with the redesign: a "no effect" of seeing
# neighbours needs the 90% interval of learned minus no-neighbours inside these.
MARGINS = {"captures_per_prey": 0.1, "fid": 10.0, "blind_fraction": 0.05, "onsets_per_prey": 0.5}


@dataclass
class ManyEyesStudy:
    """Settings of the many-eyes study (the CLI's options; defaults sized for one H200 in ~7 min)."""

    # Settings that only list which tasks exist (jobs.task_key): a run over fewer keeps the rest.
    TASK_AXES = ("group_sizes", "fov_angles", "turnaway", "neighbour_control")

    group_sizes: list[int] = field(
        default_factory=lambda: [1, 4, 16, 64],
        metadata=option("prey per world (list)", parse=lambda text, flag: number_list(text, int, flag, 1, 4096)),
    )
    fov_angles: list[float] = field(
        default_factory=lambda: [60.0, 120.0, 240.0, 360.0],
        metadata=option(
            "prey field-of-view angles, degrees in (0, 360] (list)",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, 360.0, low_open=True),
            flag="--fov",
        ),
    )
    seeds: int = 5
    rows: int = field(
        default=4096,
        metadata=option("learning prey per iteration: --rows // N worlds of N prey", type=positive_int),
    )
    iterations: int = field(default=120, metadata=common.ITERATIONS)
    train_steps: int = field(default=500, metadata=common.TRAIN_STEPS)
    eval_rows: int = field(
        default=512,
        metadata=option("evaluation prey per seed: --eval-rows // N worlds, at least 2", type=positive_int),
    )
    eval_steps: int = field(default=1000, metadata=common.EVAL_STEPS)
    view_distance: float = field(
        default=100.0, metadata=option("prey view distance, px (docs/model.md's)", type=positive_float)
    )
    flee_angle: float = field(default=45.0, metadata=common.FLEE_ANGLE)
    flee_distance: float = field(default=200.0, metadata=common.FLEE_DISTANCE)
    turn_angle: float = field(
        default=30.0,
        metadata=option("degrees the prey must turn over --lag steps for a flight onset", type=non_negative_float),
    )
    lag: int = field(default=5, metadata=option("steps of a flight onset's turn", type=positive_int))
    turnaway: bool = field(default=True, metadata=option("no TurnAway reference", negated=True))
    # The redesign (issue #30): `area_per_prey` px^2 fixes the density (a square arena of side
    # sqrt(N * area_per_prey); None: docs/model.md's 800 x 800 at every N); `recipe`: the learned-prey
    # recipe (ego observations, which carry each neighbour's relative velocity, random spawn headings,
    # entropy 0.01); `neighbour_control`: also train prey without prey slots at every N > 1.
    area_per_prey: float | None = field(
        default=None,
        metadata=option(
            "px^2 per prey: a square arena of side sqrt(N x this), the same density at every N "
            "(default: 800 x 800 at every N; 40000 is 16 prey in 800 x 800)",
            type=positive_float,
        ),
    )
    recipe: bool = field(
        default=False,
        metadata=option(
            "train with the learned-prey recipe: ego observations (neighbours' relative velocity), "
            "random spawn headings, entropy 0.01"
        ),
    )
    neighbour_control: bool = field(
        default=False,
        metadata=option("also train prey without prey slots at every N > 1 (the neighbour ablation)"),
    )
    device: str | None = None
    jobs: int | None = None
    out: str = "many_eyes"
    figures: bool = True

    def validate(self) -> None:
        if not self.group_sizes or not self.fov_angles:
            raise ValueError("group sizes and FOV angles must each list at least one value")
        check_distinct("--group-sizes", self.group_sizes)
        check_distinct("--fov", self.fov_angles)
        for n in self.group_sizes:
            check_int("group size", n)
        for fov in self.fov_angles:
            check_number("FOV angle (degrees)", fov, 1e-3, 360.0)
        for name in ("seeds", "rows", "iterations", "train_steps", "eval_rows", "eval_steps", "lag"):
            check_int(name.replace("_", "-"), getattr(self, name))
        if self.eval_steps <= self.lag + 1:
            raise ValueError(f"eval-steps={self.eval_steps} must exceed lag + 1 = {self.lag + 1}")
        check_number("view-distance", self.view_distance, 1e-3, 1e6)
        check_number("flee-angle", self.flee_angle, 0.0, 180.0)
        check_number("turn-angle", self.turn_angle, 0.0, 180.0)
        check_number("flee-distance", self.flee_distance, 1e-3, 1e6)
        if self.area_per_prey is not None:
            check_number("area-per-prey", self.area_per_prey, 1.0, 1e8)

    def env(self, n: int, fov: float, steps: int, prey_slots: int | None = None) -> dict:
        """The world's config fields (a predator never starves within an episode: one full episode per world)."""
        env: dict = {
            "prey_count": n,
            "predator_count": 1,
            "max_steps": steps,
            "predator_starvation_steps": steps,
            "prey": {"fov_angle": float(fov), "view_distance": float(self.view_distance)},
        }
        if self.area_per_prey is not None:
            env["width"] = env["height"] = math.sqrt(n * self.area_per_prey)
        if self.recipe:
            env.update(LEARNED_PREY_RECIPE["env"])
        if prey_slots is not None:
            env["prey"]["prey_slots"] = prey_slots
        return env

    def policies(self, n: int) -> tuple[str, ...]:
        """The prey policies evaluated at group size `n`."""
        learned = ("learned", "no-neighbours") if self.neighbour_control and n > 1 else ("learned",)
        return learned + (("turnaway",) if self.turnaway else ())

    def tasks(self, device: str) -> list[dict]:
        """One task per (policy, N, FOV, seed): the training runs first, then the TurnAway references."""
        tasks = []
        for policy in ("learned", "no-neighbours", "turnaway"):
            for n in sorted(self.group_sizes):
                if policy not in self.policies(n):
                    continue
                for fov in self.fov_angles:
                    for seed in range(self.seeds):
                        name = f"{policy}_N{n}_fov{fov:g}_seed{seed}"
                        tasks.append(
                            {
                                "name": name,
                                "policy": policy,
                                "group_size": n,
                                "fov_angle": fov,
                                "seed": seed,
                                "device": device,
                                "study": self,
                                "policy_dir": os.path.join(self.out, "policies", name),
                            }
                        )
        return tasks


class FlightOnsets:
    """Streaming detector of flight onsets (module doc) for prey `[W, N]` of a world `width` x `height`;
    `update` once per step, in order."""

    def __init__(
        self,
        lag: int,
        flee_angle: float,
        flee_distance: float,
        turn_angle: float,
        max_speed: float,
        view_distance: float,
        fov_angle: float,
        width: float,
        height: float,
    ):
        self.lag, self.flee_angle, self.flee_distance = lag, flee_angle, flee_distance
        self.cos_turn = math.cos(math.radians(turn_angle))
        self.cos_half_fov = -2.0 if fov_angle >= 360 else math.cos(math.radians(fov_angle / 2))
        self.max_speed, self.view_distance, self.width, self.height = max_speed, view_distance, width, height
        self.history: deque = deque(maxlen=lag + 1)  # (velocity, fleeing, visible, distance, pushed) of t-lag..t
        self.age: torch.Tensor | None = None
        self.sums: dict[str, torch.Tensor] = {}  # onsets, their summed FID and blind ones, on the device (no sync)

    def update(
        self, position, velocity, heading, alive, predator_position, predator_alive, respawned, pushed=None
    ) -> torch.Tensor:
        """One step's state (prey `position`, `velocity`, `heading` `[W, N, 2]`, `alive` `[W, N]`, the
        predators', the prey `respawned` in this step `[W, N]` and, optionally, the prey that a same-type
        neighbour pushes in the next step's move `[W, N]`); returns this step's onsets `[W, N]`."""
        import torch

        away, distance = common.nearest_predator(position, predator_position, predator_alive, self.width, self.height)
        flees = common.fleeing(velocity, away, distance, self.max_speed, self.flee_angle, self.flee_distance) & alive
        visible = (distance <= self.view_distance) & (common.cosine(heading, -away) >= self.cos_half_fov)
        fresh = respawned | ~alive
        self.age = (
            torch.zeros_like(alive, dtype=torch.int32)
            if self.age is None
            else torch.where(fresh, torch.zeros_like(self.age), self.age + 1)
        )
        pushed = torch.zeros_like(flees) if pushed is None else pushed.clone()
        self.history.append((velocity.clone(), flees, visible, distance, pushed))
        if len(self.history) < self.lag + 1:
            return torch.zeros_like(flees)
        v0, flees0, _, distance0, _ = self.history[0]
        turned = common.cosine(velocity, v0) <= self.cos_turn
        window = list(self.history)[:-1]  # steps t-lag .. t-1, whose next moves made the turn
        bounced = torch.stack([h[4] for h in window]).any(dim=0)
        onset = flees & ~self.history[-2][1] & ~flees0 & turned & ~bounced & (self.age >= self.lag)
        seen = torch.stack([h[2] for h in window]).any(dim=0)
        for name, value in (("onsets", onset), ("fid", torch.where(onset, distance0, 0.0)), ("blind", onset & ~seen)):
            total = value.double().sum()
            self.sums[name] = self.sums[name] + total if name in self.sums else total
        return onset

    def on_step(self, view: StepView) -> None:
        """`common.rollout`'s callback."""
        Pc = view.captured.shape[1]
        t = view.env.state.torch
        self.update(
            view.position[:, :Pc],
            view.velocity[:, :Pc],
            t.heading[:, :Pc],
            view.alive[:, :Pc],
            view.position[:, Pc:],
            view.alive[:, Pc:],
            view.captured,
            t.contact_partner[:, :Pc] >= 0,
        )

    def result(self) -> dict[str, float]:
        """Onsets, their mean FID (px) and their blind fraction (NaN without onsets)."""
        sums = {k: float(v) for k, v in self.sums.items()}
        onsets = sums.get("onsets", 0.0)
        return {
            "onsets": onsets,
            "fid": sums["fid"] / onsets if onsets else math.nan,
            "blind_fraction": sums["blind"] / onsets if onsets else math.nan,
        }


def dilution_expectation(group_sizes, captures_per_prey) -> np.ndarray:
    """Pure dilution: `c(N0) * N0 / N` for each N, from the captures per prey `c(N0)` of the smallest group
    size N0 (a constant total capture rate shared among N prey)."""
    n = np.asarray(group_sizes, dtype=np.float64)
    c = np.asarray(captures_per_prey, dtype=np.float64)
    first = int(np.argmin(n))
    return c[first] * n[first] / n


# ---------------------------------------------------------------------------------------------- one task
def task_training(task: dict) -> dict | None:
    """The run config a task trains (None: TurnAway's trains nothing)."""
    if task["policy"] == "turnaway":
        return None
    study: ManyEyesStudy = task["study"]
    n, slots = task["group_size"], 0 if task["policy"] == "no-neighbours" else None
    return common.training_config(
        study.env(n, task["fov_angle"], study.train_steps, slots),
        "prey",
        "naivchase",
        max(1, study.rows // n),
        study.iterations,
        task["seed"],
        task["device"],
        study.recipe,
    )


def run_task(task: dict) -> list[dict]:
    """Train (learned prey) and evaluate one (N, FOV, seed) against both predators; a worker's job."""
    start = time.perf_counter()
    study: ManyEyesStudy = task["study"]
    n, fov, seed, device = task["group_size"], task["fov_angle"], task["seed"], task["device"]
    train_s, prey = 0.0, "turnaway"
    slots = 0 if task["policy"] == "no-neighbours" else None
    config = task_training(task)
    if config is not None:
        policies, train_s = common.train_and_export(config, task["policy_dir"])
        prey = policies["prey"]
    cfg = env_config({"env": study.env(n, fov, study.eval_steps, slots)})
    rows = []
    for predator in PREDATORS:
        flights = FlightOnsets(
            study.lag,
            study.flee_angle,
            study.flee_distance,
            study.turn_angle,
            cfg.prey.max_speed,
            cfg.prey.view_distance,
            cfg.prey.fov_angle,
            cfg.width,
            cfg.height,
        )
        worlds = max(2, study.eval_rows // n)
        episodes = common.rollout(cfg, prey, predator, worlds, evaluation_seed(seed), device, flights.on_step)
        f = flights.result()
        rows.append(
            {
                "policy": task["policy"],
                "group_size": n,
                "fov_angle": fov,
                "predator": predator,
                "seed": seed,
                "captures_per_prey": float(episodes["captures"].mean()) / n,
                "fid": f["fid"],
                "blind_fraction": f["blind_fraction"],
                "onsets_per_prey": f["onsets"] / (worlds * n) * 1000 / (cfg.max_steps - 1),
            }
        )
    job_s = time.perf_counter() - start
    for row in rows:
        row.update(train_s=train_s / len(rows), job_s=job_s / len(rows))
    return rows


def run_many_eyes(
    study: ManyEyesStudy,
    command: str | None = None,
    ray: RayOptions | None = None,
    runs_per_process: int | None = None,
) -> dict:
    """Run every task (`study.jobs` at once), write the CSV, JSON and figure; return the JSON's content.
    `command`: the command line recorded in the JSON (default: this process's, `records.command_line`).
    `ray`: run each training run as a Ray task instead (`jobs`); the JSON then has a "ray" entry. Without
    it, trainings that may share a process train first as populations (`jobs.run_tasks`;
    `runs_per_process`, None: as many as the device holds)."""
    run = run_tasks(study, _task_rows, "many-eyes", ray, training=task_training, runs_per_process=runs_per_process)
    results = [row for rows in run.results for row in rows["rows"]]
    groups = common.group_rows(results, ("policy", "predator", "fov_angle", "group_size"))
    entries = [
        {
            "policy": p,
            "predator": pred,
            "fov_angle": fov,
            "group_size": n,
            "metrics": {m: seed_stats([r[m] for r in rs]) for m in MEASURES},
        }
        for (p, pred, fov, n), rs in sorted(groups.items())
    ]
    curves: dict[tuple, list[dict]] = {}
    for e in entries:
        curves.setdefault((e["policy"], e["predator"], e["fov_angle"]), []).append(e)
    for curve in curves.values():  # entries are sorted by group size
        sizes = [e["group_size"] for e in curve]
        for key in ("mean", "sem"):
            values = [e["metrics"]["captures_per_prey"][key] for e in curve]
            expected = dilution_expectation(sizes, [math.nan if v is None else v for v in values])
            for e, x in zip(curve, expected):
                e.setdefault("dilution_expectation", {})[key] = float(x)
    summary = run.record("many-eyes", study, results, command)
    summary["learned_minus_turnaway"] = [
        {
            "predator": pred,
            "fov_angle": fov,
            "group_size": n,
            "differences": compare(rs, groups[("turnaway", pred, fov, n)], MEASURES),
        }
        for (p, pred, fov, n), rs in sorted(groups.items())
        if p == "learned" and study.turnaway
    ]
    summary["learned_minus_no_neighbours"] = [
        {
            "predator": pred,
            "fov_angle": fov,
            "group_size": n,
            "differences": compare(rs, groups[("no-neighbours", pred, fov, n)], MEASURES),
            "equivalence": {m: _equivalence(rs, groups[("no-neighbours", pred, fov, n)], m) for m in MEASURES},
        }
        for (p, pred, fov, n), rs in sorted(groups.items())
        if p == "learned" and ("no-neighbours", pred, fov, n) in groups
    ]
    summary["definitions"] = {
        "captures_per_prey": f"captures per prey per episode of {study.eval_steps} steps",
        "dilution_expectation": "c(N0) * N0 / N, N0 the smallest group size: each prey's share of the smallest "
        "group's total capture rate (sem scaled alike)",
        "fleeing": f"nearest predator within {study.flee_distance:g} px, speed >= half the max, velocity within "
        f"{study.flee_angle:g} degrees of straight away from it",
        "onset": f"fleeing at t, not at t-1 nor t-{study.lag}, velocity turned >= {study.turn_angle:g} degrees "
        f"since t-{study.lag} with no same-type contact push in those moves, prey alive (no respawn) since "
        f"t-{study.lag}",
        "fid": f"distance to the nearest predator at t-{study.lag} of an onset, px",
        "blind_fraction": f"onsets where the predator was outside the prey's own view (distance "
        f"{study.view_distance:g} px and FOV) at every step t-{study.lag}..t-1",
        "onsets_per_prey": "flight onsets per prey per 1000 steps",
        "training budget": f"{study.iterations} PPO iterations x 32 steps x {study.rows} prey rows per run "
        f"({study.rows} // N worlds): the same prey-steps at every N",
        "policies": "learned: trained prey (parameter sharing) vs NaivChase; turnaway: the heuristic",
        "predator": "naivchase: a random visible prey each step (confusion); naivchase-noconfusion: the nearest",
        "learned_minus_turnaway": "learned prey minus TurnAway at each predator, FOV and N: difference of the "
        "seed means with its 95% Welch interval (null with fewer than 2 seeds)",
        "learned_minus_no_neighbours": "learned prey minus prey trained without prey slots (the neighbour control) "
        f"at each predator, FOV and N > 1; equivalence: TOST within {MARGINS}",
        "arena": (
            f"square, side sqrt(N x {study.area_per_prey:g} px^2): the same density at every N"
            if study.area_per_prey is not None
            else "800 x 800 at every N"
        ),
        "recipe": (
            "ego observations (neighbours' relative velocity included), random spawn headings, entropy "
            f"{LEARNED_PREY_RECIPE['runner']['algorithm']['entropy_coef']}"
            if study.recipe
            else "the paper preset's observations and PPO settings"
        ),
    }
    summary["results"] = entries
    return common.write_outputs(study.out, "many_eyes", results, summary, plot_many_eyes if study.figures else None)


def _equivalence(a: list[dict], b: list[dict], measure: str) -> dict | None:
    """TOST of `measure` between two conditions' per-seed rows within `MARGINS` (None below two values)."""
    x, y = (finite(np.asarray([r[measure] for r in rows], dtype=np.float64)) for rows in (a, b))
    return equivalence(x.tolist(), y.tolist(), MARGINS[measure]) if len(x) >= 2 and len(y) >= 2 else None


def _task_rows(task: dict) -> dict:
    """`run_task` for `jobs.run_tasks` (whose tasks return a dict each)."""
    return {"name": task["name"], "rows": run_task(task)}


def plot_many_eyes(summary: dict, out: str) -> str:
    """Rows: NaivChase with / without confusion; columns: captures per prey (dashed: pure dilution),
    FID, blind fraction, against group size; a colour per FOV, solid learned, dotted TurnAway."""
    plt = common.pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(14, 8), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fovs = sorted({e["fov_angle"] for e in summary["results"]})
    for row, predator in enumerate(PREDATORS):
        for policy, style in (("learned", "o-"), ("no-neighbours", "^--"), ("turnaway", "s:")):
            for k, fov in enumerate(fovs):
                curve = [
                    e
                    for e in summary["results"]
                    if (e["policy"], e["predator"], e["fov_angle"]) == (policy, predator, fov)
                ]
                if not curve:
                    continue
                x = np.array([e["group_size"] for e in curve], dtype=float)
                color = colors[k % len(colors)]
                label = f"{policy}, FOV {fov:g}°"
                for ax, metric in zip(axes[row], ("captures_per_prey", "fid", "blind_fraction")):
                    common.band(ax, x, [e["metrics"][metric] for e in curve], label, style, color=color)
                if policy == "learned":
                    axes[row, 0].plot(
                        x, [e["dilution_expectation"]["mean"] for e in curve], "--", color=color, lw=1, alpha=0.7
                    )
        for ax, ylabel in zip(
            axes[row],
            (
                "captures per prey per episode (dashed: pure dilution)",
                "flight initiation distance (px)",
                "onsets with the predator unseen",
            ),
        ):
            ax.set_xscale("log", base=2)
            ax.set_xlabel("group size N (prey)")
            ax.set_ylabel(ylabel, fontsize=8)
            ax.set_title(f"vs {predator}", fontsize=8)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=6, frameon=False)
    settings = summary["settings"]
    return common.save_figure(
        fig,
        out,
        "many_eyes.png",
        f"Many eyes: prey groups vs one predator; {settings['seeds']} seeds, "
        f"{settings['iterations']} PPO iterations x {settings['rows']} prey rows per run",
    )


__all__ = ["ManyEyesStudy", "run_many_eyes", "FlightOnsets", "dilution_expectation"]


# ---------------------------------------------------------------------------------------------- command line
HELP = "learned prey groups of 1-64 with FOVs 60-360: dilution vs earlier detection"
DESCRIPTION = (
    "For every prey group size and FOV angle, train --seeds prey runs (parameter sharing) against NaivChase "
    "with the same prey-steps per run (--rows // N worlds) and evaluate them against NaivChase with and "
    "without confusion: captures per prey next to the pure-dilution expectation, flight initiation "
    "distance and the fraction of flight onsets with the predator out of the prey's own view; TurnAway "
    "prey as the reference. Writes many_eyes.csv/json/png."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, ManyEyesStudy)
    common.add_common_arguments(p, "many_eyes")
    add_ray_arguments(p, "training run (with its evaluations)")


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study many-eyes`: learned prey groups, dilution vs detection."""
    study = from_options(ManyEyesStudy, args, **common.common_settings(args))
    print(
        f"aquarium-warp study many-eyes: group sizes {study.group_sizes} x FOV {study.fov_angles}, "
        f"{plural(study.seeds, 'seed')} -> {study.out}"
    )
    check_output_dir(study.out, "--out")
    summary = run_many_eyes(study, command_line(args.argv), ray_options(args))
    print(f"{common.written(summary)} ({summary['training_fraction']:.0%} of the workers' time training)")
    return 0
