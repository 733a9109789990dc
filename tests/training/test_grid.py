"""The evaluation grid (`training/grid.py`, `aquarium-warp eval --grid`): a cell's values from the one
batch of every cell equal the cell evaluated alone (bit for bit on the CPU where the slots agree), do
not depend on the other cells, and the targets name every failing cell."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

pytest.importorskip("rsl_rl")

from aquarium_warp import AquariumConfig
from aquarium_warp.cli import main
from aquarium_warp.training.evaluate import run_episodes
from aquarium_warp.training.grid import check_targets, run_pairing
from aquarium_warp.training.grid_cells import Cell, grid_cells

# A small, crowded torus so that short episodes have captures.
BASE = AquariumConfig(width=300.0, height=300.0, predator_count=1, max_steps=40, spawn_heading="paper")
CELLS = [Cell(3, 100.0, 120.0, 5.0), Cell(6, 200.0, 360.0, 4.5), Cell(6, 10000.0, 240.0, 6.0)]


def alone(cell: Cell, prey: str, predator: str, episodes: int, seed: int) -> float:
    """The cell's value evaluated on its own (`evaluate.run_episodes`: a batch of `episodes` worlds)."""
    world = BASE.with_values(
        {
            "prey_count": cell.prey_count,
            "prey.view_distance": cell.prey_view_distance,
            "prey.fov_angle": cell.prey_fov_angle,
            "predator.max_speed": cell.predator_max_speed,
        }
    )
    records = run_episodes(world, prey, predator, episodes, seed, device="cpu")
    return float(np.mean([r["captures_per_prey"] for r in records]))


@pytest.mark.parametrize("prey, predator", [("turnaway", "naivchase"), ("boids", "naivchase-noconfusion")])
def test_a_cell_of_the_batch_equals_the_cell_alone(prey, predator, one_thread):
    episodes, seeds = 3, (0, 5)
    grid = run_pairing(prey, predator, BASE, CELLS, episodes, seeds, device="cpu")
    assert grid.shape == (3, 2) and grid.max() > 0  # captures happened
    for c in (1, 2):  # the cells of the grid's largest prey count: their slots are those of a batch alone
        for s, seed in enumerate(seeds):
            assert grid[c, s] == alone(CELLS[c], prey, predator, episodes, seed), (c, seed)
    # Blocks do not interact: the same cells in another order and company give the same values.
    other = run_pairing(prey, predator, BASE, [CELLS[2], Cell(6, 100.0, 360.0, 5.0), CELLS[0]], episodes, seeds, "cpu")
    assert np.array_equal(other[[2, 0]], grid[[0, 2]])
    assert not np.array_equal(grid[0], grid[1])  # the cells are not all the same world


def test_the_grid_is_every_combination():
    cells = grid_cells()
    assert len(cells) == 108 and len(set(cells)) == 108
    assert cells[0] == Cell(6, 100.0, 120.0, 4.5) and cells[-1] == Cell(64, 10000.0, 360.0, 6.0)
    assert cells[0].label == "6 prey, 100 px, 120 deg, speed 4.5"
    assert cells[-1].label == "64 prey, unlimited, 360 deg, speed 6"


def _result(means: dict[tuple[str, str], list[float]], cells: list[Cell]) -> dict:
    """A grid record with the given per-cell means (one value per cell, no interval)."""
    return {
        "cells": [{**c.__dict__, "label": c.label} for c in cells],
        "pairings": [
            {"prey": a, "predator": b, "cells": list(range(len(v))), "stats": [{"mean": x, "ci95": None} for x in v]}
            for (a, b), v in means.items()
        ],
    }


def test_the_targets_name_each_failing_cell():
    cells = [Cell(6, 100.0, 120.0, 5.0), Cell(6, 200.0, 360.0, 5.0), Cell(16, 200.0, 360.0, 6.0)]
    result = _result(
        {
            ("turnaway", "naivchase"): [2.0, 1.0, 1.0],
            ("prey-any", "naivchase"): [1.9, 0.6, 0.5],  # below TurnAway everywhere, 0.6x at 360 degrees
            ("prey-b", "naivchase"): [3.0, 0.5, 0.4],  # its own world is cell 1: 0.6 > 1.1 x 0.5
            ("turnaway", "predator-any"): [2.6, 1.2, 1.4],  # 1.3x: 2.6 >= 2.6 yes, 1.2 < 1.3 fails, 1.4 >= 1.3
            ("prey-any", "predator-any"): [2.0, 0.6, 0.6],  # above NaivChase's 1.9, 0.6 (fails: equal), 0.5
        },
        cells,
    )
    targets = {t["target"]: t for t in check_targets(result, specialists={"prey-b": cells[1], "prey-c": cells[2]})}
    below = targets["prey-any below TurnAway vs naivchase"]
    assert below["met"] and below["cells"] == 3
    full = targets["prey-any at most 0.6x TurnAway at 360 deg vs naivchase"]
    assert full["met"] and full["cells"] == 2  # 0.6 <= 0.6 x 1.0 holds; 0.5 <= 0.6 too
    specialist = targets["prey-any within 10% of prey-b in its own world vs naivchase"]
    assert not specialist["met"] and specialist["failing"] == ["6 prey, 200 px, 360 deg, speed 5: 0.600 vs 0.500"]
    assert "prey-any within 10% of prey-c in its own world vs naivchase" not in targets  # not evaluated
    ratio = targets["predator-any at least 1.3x naivchase against TurnAway"]
    assert ratio["failing"] == ["6 prey, 200 px, 360 deg, speed 5: 1.200 vs 1.000"]
    above = targets["predator-any above naivchase against prey-any"]
    assert above["failing"] == ["6 prey, 200 px, 360 deg, speed 5: 0.600 vs 0.600"]
    assert not any("noconfusion" in t for t in targets)  # no pairing against it: no target


def test_eval_grid_writes_the_tables_and_per_seed_values(tmp_path, capsys, one_thread):
    out = str(tmp_path / "grid")
    args = ["eval", "--grid", "--prey", "turnaway", "constant", "--predator", "naivchase", "--episodes", "2"]
    args += ["--seeds", "0", "1", "--grid-prey-counts", "3,5", "--grid-views", "100,10000", "--grid-fovs", "360"]
    args += ["--grid-speeds", "5", "--max-steps", "30", "--set", "env.width=300", "--set", "env.height=300"]
    assert main(args + ["--device", "cpu", "--out", out]) == 0
    printed = capsys.readouterr().out
    assert (
        "captures per prey per episode against naivchase" in printed
        and "5 prey, unlimited, 360 deg, speed 5" in printed
    )
    with open(os.path.join(out, "grid.json"), encoding="utf-8") as f:
        record = json.load(f)
    assert [c["label"] for c in record["cells"]] == [
        f"{n} prey, {v}, 360 deg, speed 5" for n in (3, 5) for v in ("100 px", "unlimited")
    ]
    turnaway = next(p for p in record["pairings"] if p["prey"] == "turnaway")
    values = np.array(turnaway["runs"][0]["values"])
    assert values.shape == (4, 2)
    stats = turnaway["stats"][3]
    assert stats["mean"] == pytest.approx(values[3].mean()) and stats["over"] == "evaluation seeds"
    with open(os.path.join(out, "grid.csv"), encoding="utf-8") as f:
        assert len(f.read().strip().splitlines()) == 1 + 2 * 4 * 2
    assert record["protocol"]["base"]["width"] == 300.0 and record["protocol"]["episodes"] == 2
    capsys.readouterr()
    assert main(["eval", "--grid", "--grid-fovs", "400", "--out", out]) == 2
    assert "--grid-fovs" in capsys.readouterr().err
