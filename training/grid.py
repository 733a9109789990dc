"""The evaluation grid (`aquarium-warp eval --grid`): every pairing of a prey and a predator policy over
a grid of worlds, each pairing ONE batch of worlds with per-world parameters.

A cell is a world: its prey count, the prey's view distance and field of view, and the predator's top
speed (`PREY_COUNTS`, `VIEWS`, `FOVS`, `SPEEDS`: 4 x 3 x 3 x 3 = 108 cells); everything else is the
base world (docs/model.md's, with the trained policies' observation interface and the paper's spawn
headings). A pairing's batch holds, for
every cell and every evaluation seed, a block of `episodes` worlds with the cell's values, seeded with
that evaluation seed (`seeding.seed_groups`): each block draws exactly what a batch of `episodes` worlds of
that seed draws. Every world plays one episode. The measure: captures per prey per episode, its mean
over a block's episodes (one value per cell and evaluation seed).

What holds bit for bit (on the CPU, `tests/training/test_grid.py`): a cell's values do not depend on the
other cells of its batch (blocks do not interact, and each counts its worlds from 0), and a cell whose
prey count is the grid's largest equals that cell evaluated alone (`evaluate.run_episodes`, a batch of
its own). A cell of fewer prey equals itself in any grid of the same largest count; alone it would
differ in the predators' spawn draws, which are keyed by slot, and predator slots follow the batch's
prey capacity (docs/per-world.md): the same statistics, not the same bits.

Statistics (`cell_stats`): a label of one policy (a heuristic) gets the mean over evaluation seeds and
its 95% t interval over them; a label of several policies (training seeds, `LABEL=SPEC` given once per
seed) the mean over training seeds of each seed's mean, with the interval over training seeds.
`check_targets` checks the general policies' targets cell by cell and names every failing cell.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import os
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from ..atomic import atomic_open
from ..config import AquariumConfig
from ..device import resolve_device
from ..drivers import is_heuristic, make_drivers, trained_world
from ..env import BatchedAquarium
from ..records import json_safe, provenance
from ..rollout import Observer, rollout
from ..statistics import interval
from .evaluate import parse_spec
from .grid_cells import NAIVCHASE, Cell

# The targets (docs/general-policies.md): prey-any at most 0.6x TurnAway's captures where prey see 360
# degrees and below TurnAway everywhere; predator-any at least 1.3x NaivChase's against TurnAway and
# above it against prey-any; a specialist's own world: prey-any at most 10% above the specialist.
FULL_VIEW_RATIO, PREDATOR_RATIO, SPECIALIST_MARGIN = 0.6, 1.3, 0.1


def grid_config(base: AquariumConfig, cells: Sequence[Cell], episodes: int, seeds: Sequence[int]):
    """`(config, seed groups)` of one pairing's batch: a block of `episodes` worlds per (cell, evaluation
    seed), cell-major, each with the cell's values; the seed groups (one seed per block) for
    `BatchedAquarium(seed=...)`."""
    blocks = [(cell, seed) for cell in cells for seed in seeds]

    def per_world(value_of: Callable[[Cell], float]) -> tuple:
        return tuple(value_of(cell) for cell, _ in blocks for _ in range(episodes))

    config = base.with_values(
        {
            "prey_count": per_world(lambda c: c.prey_count),
            "prey.view_distance": per_world(lambda c: c.prey_view_distance),
            "prey.fov_angle": per_world(lambda c: c.prey_fov_angle),
            "predator.max_speed": per_world(lambda c: c.predator_max_speed),
        }
    )
    return config, tuple(int(seed) for _, seed in blocks)


class FirstEpisodeCaptures(Observer):
    """Each world's captures in its first episode (one host sync per step: whether any ended)."""

    def __init__(self, env: BatchedAquarium):
        self.captures = np.full(env.num_worlds, -1, dtype=np.int64)

    @property
    def done(self) -> bool:
        return bool((self.captures >= 0).all())

    def on_step(self, env: BatchedAquarium, step: int, result) -> None:
        ended = result.info["episode_ended"]
        if bool(ended.any()):
            index = torch.nonzero(ended).flatten()
            caps = result.info["episode_captures"][index].cpu().numpy()
            worlds = index.cpu().numpy()
            first = self.captures[worlds] < 0
            self.captures[worlds[first]] = caps[first]


def run_pairing(
    prey: str,
    predator: str,
    base: AquariumConfig,
    cells: Sequence[Cell],
    episodes: int = 50,
    seeds: Sequence[int] = (0, 1, 2),
    device=None,
) -> np.ndarray:
    """`[cells, seeds]`: captures per prey per episode of `prey` against `predator` (specs), the mean over
    each block's `episodes` episodes, every cell in one batch. Trained policies act by argmax."""
    config, groups = grid_config(base, cells, episodes, seeds)
    env = BatchedAquarium(config, num_worlds=len(groups) * episodes, device=device, seed=groups)
    try:
        drivers = make_drivers({"prey": prey, "predator": predator}, env)
        captures = FirstEpisodeCaptures(env)
        rollout(env, drivers, 2 * base.max_steps, [captures], reset=False, until=lambda: captures.done)
    finally:
        env.close()
    if not captures.done:  # pragma: no cover - defensive: every world ends an episode within max_steps
        raise RuntimeError("the grid's worlds did not finish their episodes")
    per_prey = captures.captures.reshape(len(cells), len(seeds), episodes) / np.array(
        [cell.prey_count for cell in cells], dtype=np.float64
    ).reshape(-1, 1, 1)
    return per_prey.mean(axis=2)


def grid_base(specs: Sequence[str], base: AquariumConfig | None = None) -> AquariumConfig:
    """The grid's base world: `base` (default docs/model.md's, with the paper's spawn headings), taking
    the observation interface of the first trained policy among `specs` (the others must share it)."""
    world = base if base is not None else AquariumConfig(spawn_heading="paper")
    for spec in specs:
        _, value = parse_spec(spec)
        if not is_heuristic(value):
            return world.with_interface_of(trained_world(value))
    return world


def evaluate_grid(
    prey: Sequence[str],
    predator: Sequence[str],
    base: AquariumConfig,
    cells: Sequence[Cell],
    episodes: int = 50,
    seeds: Sequence[int] = (0, 1, 2),
    device=None,
    progress: Callable[[str], None] | None = None,
    only: dict[str, Sequence[Cell]] | None = None,
    commit: str | None = None,
) -> dict:
    """Every (prey spec, predator spec) pairing on the grid. `only`: {prey label: cells} evaluates that
    label in those cells alone (a specialist in its own world); `commit` names a copy without git
    history. Returns the record `write_grid` writes: cells, per-pairing values per spec, evaluation seed
    and cell, statistics per cell, protocol."""
    cells = list(cells)
    pairings: dict[tuple[str, str], dict] = {}
    for prey_spec, predator_spec in itertools.product(prey, predator):
        prey_label, prey_value = parse_spec(prey_spec)
        predator_label, predator_value = parse_spec(predator_spec)
        own = [cells.index(c) for c in only[prey_label]] if only and prey_label in only else list(range(len(cells)))
        if not own:
            continue
        start = time.perf_counter()
        values = run_pairing(prey_value, predator_value, base, [cells[i] for i in own], episodes, seeds, device)
        entry = pairings.setdefault(
            (prey_label, predator_label), {"prey": prey_label, "predator": predator_label, "cells": own, "runs": []}
        )
        entry["runs"].append({"prey_spec": prey_value, "predator_spec": predator_value, "values": values.tolist()})
        if progress is not None:
            progress(
                f"prey {prey_label} ({prey_value}) vs predator {predator_label} ({predator_value}): "
                f"{len(own)} cells x {len(seeds)} seeds x {episodes} episodes in {time.perf_counter() - start:.1f} s"
            )
    for entry in pairings.values():
        entry["stats"] = cell_stats(entry)
    return {
        "cells": [dataclasses.asdict(c) | {"label": c.label} for c in cells],
        "pairings": list(pairings.values()),
        "protocol": {
            "measure": "captures per prey per episode (lower: better prey); one episode per world",
            "episodes": episodes,
            "seeds": [int(s) for s in seeds],
            "max_steps": base.max_steps,
            "deterministic": True,
            "base": base.to_dict(),
        },
        **provenance(resolve_device(device), commit=commit),
    }


def cell_stats(entry: dict) -> list[dict]:
    """Per cell of a pairing: mean and 95% interval over evaluation seeds (one policy) or over training
    seeds of each one's mean over evaluation seeds (several)."""
    values = np.array([run["values"] for run in entry["runs"]], dtype=np.float64)  # [runs, cells, seeds]
    out = []
    for c in range(values.shape[1]):
        per = values[0, c] if values.shape[0] == 1 else values[:, c].mean(axis=1)
        stats = interval(per.tolist())
        stats["over"] = "evaluation seeds" if values.shape[0] == 1 else "training seeds"
        out.append(stats)
    return out


def pairing_means(result: dict) -> dict[tuple[str, str], dict[int, float]]:
    """{(prey, predator): {cell index: mean}}."""
    return {
        (p["prey"], p["predator"]): {c: s["mean"] for c, s in zip(p["cells"], p["stats"])} for p in result["pairings"]
    }


def check_targets(
    result: dict,
    prey_any: str = "prey-any",
    predator_any: str = "predator-any",
    specialists: dict[str, Cell] | None = None,
) -> list[dict]:
    """The general policies' targets, one entry per target and pairing present: `{"target", "met",
    "failing": [cell labels with their values]}` (at the means over seeds)."""
    means = pairing_means(result)
    cells = [Cell(**{k: v for k, v in c.items() if k != "label"}) for c in result["cells"]]
    out = []

    def check(name: str, a: dict[int, float], b: dict[int, float], ok: Callable[[float, float, Cell], bool], what):
        shared = sorted(set(a) & set(b))
        if not shared:
            return
        failing = [f"{cells[c].label}: {a[c]:.3f} vs {b[c]:.3f}" for c in shared if not ok(a[c], b[c], cells[c])]
        out.append({"target": name, "what": what, "cells": len(shared), "met": not failing, "failing": failing})

    for predator in NAIVCHASE:
        any_prey, turnaway = means.get((prey_any, predator)), means.get(("turnaway", predator))
        if any_prey and turnaway:
            check(
                f"{prey_any} below TurnAway vs {predator}",
                any_prey,
                turnaway,
                lambda a, b, cell: a < b,
                f"{prey_any} < turnaway in every cell",
            )
            check(
                f"{prey_any} at most {FULL_VIEW_RATIO}x TurnAway at 360 deg vs {predator}",
                {c: v for c, v in any_prey.items() if cells[c].prey_fov_angle >= 360.0},
                turnaway,
                lambda a, b, cell: a <= FULL_VIEW_RATIO * b,
                f"{prey_any} <= {FULL_VIEW_RATIO} x turnaway in every 360-degree cell",
            )
        for specialist, own in (specialists or {}).items():
            spec_means, any_prey = means.get((specialist, predator)), means.get((prey_any, predator))
            if spec_means and any_prey and own in cells:
                c = cells.index(own)
                check(
                    f"{prey_any} within {SPECIALIST_MARGIN:.0%} of {specialist} in its own world vs {predator}",
                    {k: v for k, v in any_prey.items() if k == c},
                    spec_means,
                    lambda a, b, cell: a <= (1 + SPECIALIST_MARGIN) * b,
                    f"{prey_any} <= {1 + SPECIALIST_MARGIN:g} x {specialist}",
                )
        learned, heuristic = means.get(("turnaway", predator_any)), means.get(("turnaway", predator))
        if learned and heuristic:
            check(
                f"{predator_any} at least {PREDATOR_RATIO}x {predator} against TurnAway",
                learned,
                heuristic,
                lambda a, b, cell: a >= PREDATOR_RATIO * b,
                f"{predator_any} >= {PREDATOR_RATIO} x {predator} vs turnaway",
            )
        learned, heuristic = means.get((prey_any, predator_any)), means.get((prey_any, predator))
        if learned and heuristic:
            check(
                f"{predator_any} above {predator} against {prey_any}",
                learned,
                heuristic,
                lambda a, b, cell: a > b,
                f"{predator_any} > {predator} vs {prey_any}",
            )
    return out


def format_tables(result: dict) -> list[str]:
    """The printed tables: per predator, a row per cell and a column per prey (mean ± 95% interval);
    per prey, a column per predator, where a predator is a trained policy."""
    cells = [c["label"] for c in result["cells"]]
    pairings = result["pairings"]
    prey_labels = list(dict.fromkeys(p["prey"] for p in pairings))
    predator_labels = list(dict.fromkeys(p["predator"] for p in pairings))
    index = {(p["prey"], p["predator"]): dict(zip(p["cells"], p["stats"])) for p in pairings}

    def value(s: dict | None) -> str:
        if s is None:
            return "-"
        return f"{s['mean']:.2f}" + (f"±{s['ci95']:.2f}" if s["ci95"] is not None else "")

    def table(title: str, columns: list[str], fixed: str, columns_are_prey: bool) -> list[str]:
        width = max(len(c) for c in cells)
        widths = [max(12, len(c) + 1) for c in columns]
        lines = [title, " " * width + "".join(f"{c:>{w}}" for c, w in zip(columns, widths))]
        for i, cell in enumerate(cells):
            keys = [(c, fixed) if columns_are_prey else (fixed, c) for c in columns]
            row = [value(index.get(k, {}).get(i)) for k in keys]
            if any(v != "-" for v in row):
                lines.append(f"{cell:>{width}}" + "".join(f"{v:>{w}}" for v, w in zip(row, widths)))
        return lines

    lines: list[str] = []
    for predator in predator_labels:
        lines += table(f"captures per prey per episode against {predator}", prey_labels, predator, True)
    if any(not is_heuristic(p["runs"][0]["predator_spec"], "predator") for p in pairings):
        for prey in prey_labels:
            lines += table(f"captures per prey per episode of {prey} prey", predator_labels, prey, False)
    return lines


def write_grid(result: dict, out_dir: str, targets: list[dict] | None = None) -> dict[str, str]:
    """`grid.json` (the record, with the targets) and `grid.csv` (one row per pairing, spec, cell and
    evaluation seed) into `out_dir`."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {"json": os.path.join(out_dir, "grid.json"), "csv": os.path.join(out_dir, "grid.csv")}
    with atomic_open(paths["json"]) as f:
        json.dump(json_safe({**result, "targets": targets or []}), f, indent=1)
    seeds = result["protocol"]["seeds"]
    with atomic_open(paths["csv"], newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["prey", "predator", "prey_spec", "predator_spec", *Cell.__annotations__, "seed", "value"])
        for p in result["pairings"]:
            for run in p["runs"]:
                for c, row in zip(p["cells"], run["values"]):
                    cell = result["cells"][c]
                    for seed, v in zip(seeds, row):
                        writer.writerow(
                            [p["prey"], p["predator"], run["prey_spec"], run["predator_spec"]]
                            + [cell[k] for k in Cell.__annotations__]
                            + [seed, v]
                        )
    return paths
