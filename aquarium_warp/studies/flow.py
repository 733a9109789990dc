"""`aquarium-warp study flow`: how prey and predators fare in a current (the paper's future work:
vector flow fields), and whether fleeing prey escape with or against it.

Every (flow kind, strength, seed) runs as worlds of one `BatchedAquarium` (per-world `flow`, one
episode each): kind `uniform` (a current of `strength` px/step at `uniform_angle` degrees from +x towards
+y; default 90, along +y, across the prey's spawn heading, -x, which TurnAway keeps until it sees a
predator: a current along it would only measure that heading) or `vortex` (a Rankine vortex at the
world's centre, `strength` px/step at the edge of a core whose radius is a sixth of the world, clockwise).
Strength 0 is the still-water reference. By default the agents are the paper's heuristics, TurnAway prey
against NaivChase predators, which ignore the current (docs/model.md); `--prey-policy` / `--predator-policy`
take trained policy files instead (trained without the current in their observations, as they are).
Seed s is the block of `episodes_per_seed` worlds of a setting (independent random streams).

Measures, per seed:
- `captures_per_prey` per episode; `polarization`, `groups`, `largest_group`, `nn_mean`: the swarm
  metrics of `aquarium_warp.metrics`, episode means of states sampled every `metrics_every` steps.
- `escape_cosine`: the mean cosine between a fleeing prey's velocity and the current it drifts in,
  over every step and fleeing prey of an episode, then averaged over the seed's episodes (fleeing as
  in the many-eyes study, `common.fleeing`: nearest predator within `flee_distance`, at least half
  speed, velocity within `flee_angle` of straight away).
  The current is measured, not recomputed: the step's displacement minus the stored velocity
  (docs/model.md: `P' = wrap(P + V' + C)`), for prey alive and not captured in the step, where it is
  longer than 0.01 px/step. +1: escaping downstream; -1: against the current.
- `cruise_cosine`: the same for the prey that are not fleeing (the reference: do prey align with the
  current anyway?); `downstream_fraction`: the fraction of fleeing steps with a positive cosine.
- `escape_angle_histogram` (JSON and figure): the angle between escape velocity and current in
  `ANGLE_BINS` bins of 180 / `ANGLE_BINS` degrees, over every seed.

Outputs (`--out`, default `flow_study/` in the current directory): `flow.csv` (one row per kind, strength and
seed), `flow.json`, `flow.png` and `flow_escape_angles.png`.
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
    POLICY_SPECS,
    add_options,
    check_distinct,
    check_int,
    check_number,
    from_options,
    int_at_least,
    non_negative_int,
    number_list,
    option,
    plural,
    policy_spec,
    positive_int,
    word_list,
)
from ..atomic import check_output_dir, write_figure
from ..config import AquariumConfig, FlowConfig
from ..records import command_line
from ..statistics import compare, seed_stats
from . import common

if TYPE_CHECKING:
    from ..rollout import StepView


KINDS = ("uniform", "vortex")
ANGLE_BINS = 18
SWARM = ("polarization", "groups", "largest_group", "nn_mean")
MEASURES = ("captures_per_prey",) + SWARM + ("escape_cosine", "cruise_cosine", "downstream_fraction")


@dataclass
class FlowStudy:
    """Settings of the flow study (the CLI's options)."""

    kinds: list[str] = field(
        default_factory=lambda: list(KINDS),
        metadata=option(
            "flow kinds: 'uniform' (along --uniform-angle), 'vortex' (centred, clockwise)", parse=word_list
        ),
    )
    strengths: list[float] = field(
        default_factory=lambda: [0.0, 0.5, 1.0, 2.0, 3.0],
        metadata=option(
            "px per step (the vortex's at its core's edge; list)",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, 100.0),
        ),
    )
    seeds: int = 5
    episodes_per_seed: int = field(default=10, metadata=option("episodes (worlds) per seed", type=positive_int))
    episode_steps: int = field(default=3000, metadata=option("steps per episode", type=int_at_least(2)))
    prey: int = field(default=16, metadata=option("prey per world", type=positive_int))
    predators: int = field(default=1, metadata=option("predators per world", type=positive_int))
    prey_policy: str = field(default="turnaway", metadata=option(POLICY_SPECS["prey"], type=policy_spec("prey")))
    predator_policy: str = field(
        default="naivchase", metadata=option(POLICY_SPECS["predator"], type=policy_spec("predator"))
    )
    world_size: float = 800.0
    uniform_angle: float = field(
        default=90.0,
        metadata=option(
            "direction of the uniform current, degrees from +x towards +y (90: +y, across the prey's spawn heading -x)",
            type=float,
        ),
    )
    flee_angle: float = field(default=45.0, metadata=common.FLEE_ANGLE)
    flee_distance: float = field(default=200.0, metadata=common.FLEE_DISTANCE)
    metrics_every: int = field(default=10, metadata=option("sample the swarm metrics every K steps", type=positive_int))
    seed: int = field(default=0, metadata=option("seed of the batched worlds", type=non_negative_int))
    device: str | None = None
    out: str = "flow_study"
    figures: bool = True

    def validate(self) -> None:
        from ..drivers import check_spec

        bad = [k for k in self.kinds if k not in KINDS]
        if bad or not self.kinds:
            raise ValueError(f"flow kinds {self.kinds!r} must be a non-empty list of {KINDS}")
        if not self.strengths:
            raise ValueError("strengths must list at least one current strength")
        check_distinct("--kinds", self.kinds)
        check_distinct("--strengths", self.strengths)
        for s in self.strengths:
            check_number("flow strength (px/step)", s, 0.0, 100.0)
        for name in ("seeds", "episodes_per_seed", "prey", "predators", "metrics_every"):
            check_int(name.replace("_", "-"), getattr(self, name))
        check_int("episode-steps", self.episode_steps, 2)
        check_number("world-size", self.world_size, 100.0, 1e6)
        check_number("uniform-angle", self.uniform_angle, -360.0, 360.0)
        check_number("flee-angle", self.flee_angle, 0.0, 180.0)
        check_number("flee-distance", self.flee_distance, 1e-3, 1e6)
        for team, spec in (("prey", self.prey_policy), ("predator", self.predator_policy)):
            check_spec(spec, team, f"--{team}-policy")

    def settings(self) -> list[tuple[str, float]]:
        return [(kind, float(s)) for kind in self.kinds for s in self.strengths]

    def flow(self, kind: str, strength: float) -> FlowConfig:
        if kind == "uniform":
            angle = math.radians(self.uniform_angle)
            return FlowConfig("uniform", velocity=(strength * math.cos(angle), strength * math.sin(angle)))
        half = self.world_size / 2
        return FlowConfig("vortex", centre=(half, half), strength=strength, core_radius=self.world_size / 6)

    def config(self) -> AquariumConfig:
        """One batch: setting i (of `settings()`) is worlds [i * S * E, (i + 1) * S * E), seed s of it the
        block of E worlds from i * S * E + s * E. Predators never starve within an episode (one full
        episode per world)."""
        repeat = self.seeds * self.episodes_per_seed
        flows = tuple(self.flow(kind, s) for kind, s in self.settings() for _ in range(repeat))
        return AquariumConfig(
            prey_count=self.prey,
            predator_count=self.predators,
            max_steps=self.episode_steps,
            predator_starvation_steps=self.episode_steps,
            width=self.world_size,
            height=self.world_size,
        ).replace(flow=flows)

    @property
    def worlds(self) -> int:
        return len(self.settings()) * self.seeds * self.episodes_per_seed


class EscapeMeasures:
    """Per-world sums of the escape and cruise cosines and the escape-angle histogram of a rollout."""

    def __init__(
        self,
        worlds: int,
        device,
        flee_angle: float,
        flee_distance: float,
        max_speed: float,
        width: float,
        height: float,
    ):
        import torch

        self.flee_angle, self.flee_distance, self.max_speed = flee_angle, flee_distance, max_speed
        self.width, self.height = width, height
        zeros = {"dtype": torch.float64, "device": device}
        self.sums = {
            k: torch.zeros(worlds, **zeros) for k in ("escape", "escape_n", "cruise", "cruise_n", "downstream")
        }
        self.histogram = torch.zeros(worlds, ANGLE_BINS, **zeros)

    def update(self, before_position, position, velocity, alive, predator_position, predator_alive) -> None:
        """One step of the prey (`[W, N, ...]`; `alive`: alive before and after, not captured)."""
        import torch

        current = common.torus_delta(position - before_position, self.width, self.height) - velocity
        moving = alive & (torch.linalg.vector_norm(current, dim=-1) > 0.01)
        away, distance = common.nearest_predator(position, predator_position, predator_alive, self.width, self.height)
        flees = common.fleeing(velocity, away, distance, self.max_speed, self.flee_angle, self.flee_distance)
        c = common.cosine(velocity, current).double()
        escape, cruise = moving & flees, moving & ~flees
        self.sums["escape"] += (c * escape).sum(dim=1)
        self.sums["escape_n"] += escape.sum(dim=1)
        self.sums["cruise"] += (c * cruise).sum(dim=1)
        self.sums["cruise_n"] += cruise.sum(dim=1)
        self.sums["downstream"] += ((c > 0) & escape).sum(dim=1)
        angle = torch.rad2deg(torch.acos(c.clamp(-1, 1)))
        bins = (angle / (180 / ANGLE_BINS)).long().clamp(0, ANGLE_BINS - 1)
        self.histogram += (torch.nn.functional.one_hot(bins, ANGLE_BINS) * escape[..., None]).sum(dim=1)

    def on_step(self, view: StepView) -> None:
        Pc = view.captured.shape[1]
        alive = view.before_alive[:, :Pc] & view.alive[:, :Pc] & ~view.captured
        self.update(
            view.before_position[:, :Pc],
            view.position[:, :Pc],
            view.velocity[:, :Pc],
            alive,
            view.position[:, Pc:],
            view.alive[:, Pc:],
        )

    def per_world(self) -> dict[str, np.ndarray]:
        s = {k: v.cpu().numpy() for k, v in self.sums.items()}
        with np.errstate(invalid="ignore", divide="ignore"):
            return {
                "escape_cosine": s["escape"] / s["escape_n"],
                "cruise_cosine": s["cruise"] / s["cruise_n"],
                "downstream_fraction": s["downstream"] / s["escape_n"],
                "escape_steps": s["escape_n"],
            }


def run_flow(study: FlowStudy, command: str | None = None) -> dict:
    """Run every setting in one batch, write the CSV, JSON and figures; return the JSON's content.
    `command`: the command line recorded in the JSON (default: this process's, `records.command_line`)."""
    import torch

    from ..device import resolve_device

    study.validate()
    device = resolve_device(study.device)
    cfg = study.config()
    worlds = study.worlds
    start = time.perf_counter()
    escape = EscapeMeasures(
        worlds, torch.device(device), study.flee_angle, study.flee_distance, cfg.prey.max_speed, cfg.width, cfg.height
    )
    episodes = common.rollout(
        cfg,
        study.prey_policy,
        study.predator_policy,
        worlds,
        study.seed,
        device,
        escape.on_step,
        metrics_every=study.metrics_every,
    )
    wall = time.perf_counter() - start
    per_world = {
        "captures_per_prey": episodes["captures"] / study.prey,
        **{k: episodes[k] for k in SWARM},
        **escape.per_world(),
    }
    histogram = escape.histogram.cpu().numpy()
    S, E = study.seeds, study.episodes_per_seed
    rows, entries = [], []
    for i, (kind, strength) in enumerate(study.settings()):
        block = slice(i * S * E, (i + 1) * S * E)
        per_seed = {}
        for m in MEASURES:
            with np.errstate(invalid="ignore"):
                values = per_world[m][block].reshape(S, E)
                per_seed[m] = np.array([np.nanmean(v) if np.isfinite(v).any() else math.nan for v in values])
        for s in range(S):
            rows.append(
                {
                    "kind": kind,
                    "strength": strength,
                    "seed": s,
                    "episodes": E,
                    **{m: float(per_seed[m][s]) for m in MEASURES},
                }
            )
        counts = histogram[block].sum(axis=0)
        entries.append(
            {
                "kind": kind,
                "strength": strength,
                "metrics": {m: seed_stats(per_seed[m]) for m in MEASURES},
                "escape_steps": float(per_world["escape_steps"][block].sum()),
                "escape_angle_histogram": (counts / counts.sum()).tolist() if counts.sum() else None,
            }
        )
    summary = common.run_record("flow", study, device, wall, 0.0, wall, 1, command)
    settings = common.group_rows(rows, ("kind", "strength"))
    summary["current_effects"] = [
        {
            "kind": kind,
            "strength": strength,
            "differences": compare(settings[(kind, strength)], settings[(kind, 0.0)], MEASURES),
        }
        for kind, strength in study.settings()
        if strength != 0 and (kind, 0.0) in settings
    ]
    summary["definitions"] = {
        "worlds": f"{worlds} worlds in one batch: per setting {S} seeds x {E} episodes of {study.episode_steps} steps",
        "uniform": f"current of strength px/step at {study.uniform_angle:g} degrees from +x towards +y",
        "vortex": f"Rankine vortex at the centre, strength px/step at the edge of a {study.world_size / 6:g} px core, "
        "clockwise on screen",
        "agents": f"prey {study.prey_policy}, predators {study.predator_policy} (heuristics ignore the current)",
        "fleeing": f"nearest predator within {study.flee_distance:g} px, speed >= half the max, velocity within "
        f"{study.flee_angle:g} degrees of straight away from it",
        "current": "measured: the step's torus displacement minus the stored velocity (prey alive, not captured, "
        "current > 0.01 px/step)",
        "escape_cosine": "mean cos(fleeing prey velocity, current) over an episode's steps and prey, averaged over "
        "the seed's episodes; cruise_cosine: non-fleeing; downstream_fraction likewise",
        "escape_angle_histogram": f"angle between escape velocity and current, {ANGLE_BINS} bins over [0, 180] "
        "degrees, fractions summed over seeds",
        "current_effects": "each strength minus still water (strength 0) of the same kind: difference of the seed "
        "means with its 95% Welch interval (null with fewer than 2 seeds)",
    }
    summary["results"] = entries
    return common.write_outputs(study.out, "flow", rows, summary, plot_flow if study.figures else None)


def plot_flow(summary: dict, out: str) -> list[str]:
    """`flow.png` (captures, polarization, groups, escape cosine against strength, a line per kind) and
    `flow_escape_angles.png` (the escape-angle histograms, a panel per kind, a line per strength)."""
    plt = common.pyplot()
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    kinds = list(dict.fromkeys(e["kind"] for e in summary["results"]))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    panels = (
        ("captures_per_prey", "captures per prey per episode"),
        ("polarization", "polarization"),
        ("groups", "groups (prey links < 2.5 radii)"),
        ("escape_cosine", "cos(escape velocity, current)"),
    )
    for k, kind in enumerate(kinds):
        entries = [e for e in summary["results"] if e["kind"] == kind]
        x = np.array([e["strength"] for e in entries])
        for ax, (metric, _) in zip(axes.flat, panels):
            common.band(ax, x, [e["metrics"][metric] for e in entries], kind, color=colors[k % len(colors)])
        common.band(
            axes[1, 1],
            x,
            [e["metrics"]["cruise_cosine"] for e in entries],
            f"{kind}, not fleeing",
            "s:",
            color=colors[k % len(colors)],
        )
    for ax, (_, ylabel) in zip(axes.flat, panels):
        ax.set_xlabel("current strength (px/step)")
        ax.set_ylabel(ylabel, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, frameon=False)
    settings = summary["settings"]
    paths = [
        common.save_figure(
            fig,
            out,
            "flow.png",
            f"Currents: {settings['prey']} {settings['prey_policy']} prey vs "
            f"{settings['predators']} {settings['predator_policy']}, {settings['seeds']} seeds",
        )
    ]
    fig, axes = plt.subplots(1, len(kinds), figsize=(5 * len(kinds), 4), squeeze=False)
    centres = (np.arange(ANGLE_BINS) + 0.5) * 180 / ANGLE_BINS
    for ax, kind in zip(axes[0], kinds):
        entries = [e for e in summary["results"] if e["kind"] == kind and e["escape_angle_histogram"] is not None]
        cmap = plt.get_cmap("viridis")
        for j, e in enumerate(entries):
            ax.plot(
                centres,
                e["escape_angle_histogram"],
                "o-",
                ms=3,
                color=cmap(j / max(1, len(entries) - 1)),
                label=f"{e['strength']:g} px/step",
            )
        ax.axhline(1 / ANGLE_BINS, color="k", ls=":", lw=1)
        ax.set_xlabel("angle between escape velocity and current (degrees)")
        ax.set_ylabel("fraction of fleeing prey-steps")
        ax.set_title(kind, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, frameon=False)
    fig.suptitle(
        "Escape direction relative to the current (all seeds; dotted: directions independent of the "
        "current, whose angle is uniform in 2D)",
        fontsize=9,
    )
    fig.tight_layout()
    path = os.path.join(out, "flow_escape_angles.png")
    write_figure(fig, path, dpi=110)
    plt.close(fig)
    return paths + [path]


__all__ = ["FlowStudy", "run_flow", "EscapeMeasures"]


# ---------------------------------------------------------------------------------------------- command line
HELP = "uniform currents and a vortex of growing strength: captures, swarm metrics, escape direction"
DESCRIPTION = (
    "Run every flow kind and strength as worlds of one batch (per-world flow), TurnAway prey vs NaivChase "
    "by default (heuristics ignore the current) or trained policy files, and write captures, polarization, "
    "groups and the angle between fleeing prey's velocity and the current (flow.csv/json, flow.png, "
    "flow_escape_angles.png) into --out."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, FlowStudy)
    common.add_common_arguments(p, "flow_study", jobs=False)


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study flow`: captures, swarm metrics and escape directions in currents."""
    study = from_options(FlowStudy, args, **common.common_settings(args, jobs=False))
    print(
        f"aquarium-warp study flow: {study.kinds} x strengths {study.strengths} px/step, "
        f"{plural(study.seeds, 'seed')} x {plural(study.episodes_per_seed, 'episode')} of "
        f"{plural(study.episode_steps, 'step')} -> {study.out}"
    )
    check_output_dir(study.out, "--out")
    summary = run_flow(study, command_line(args.argv))
    print(common.written(summary))
    return 0
