"""The three ways of building the cell lists give every cell the same agents in the same order.

`sort_into_cells_per_world` (CPU), `rank_into_cells_per_world` (GPU, small worlds) and the count
build (GPU, large worlds: cell counts, their prefix sum, agents dropped into their cells in arrival
order, then each cell ordered by slot) must agree, since neighbour order (and so every tie) follows
the cell lists. Each build is checked against a numpy stable sort by (world, cell, slot) on
random worlds with dead slots, agents on cell borders and on the seam, for one cell per world and
for several.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from aquarium_warp import AquariumConfig
from aquarium_warp.kernels import grid as grid_kernels
from aquarium_warp.kernels.state import Agents
from aquarium_warp.params import BatchParams
from aquarium_warp.shard import cell_lists, world_params


def build(method: str, cfg, dims, position, alive, device):
    W, C = alive.shape
    g = cell_lists(cfg, W, dims, device, build=method)
    params = BatchParams(cfg, W, device)
    world = world_params(cfg, True, params.values, params.flow_grid)
    agents = Agents()  # only the fields the builds read
    agents.position = wp.array(position, dtype=wp.vec2, device=device)
    agents.alive = wp.array(alive, dtype=wp.bool, device=device)
    if method == "counting":
        wp.launch(grid_kernels.sort_into_cells_per_world, W, inputs=[world, agents], outputs=[g], device=device)
    elif method == "rank":
        wp.launch(grid_kernels.rank_into_cells_per_world, (W, C), inputs=[world, agents], outputs=[g], device=device)
    else:
        wp.launch(grid_kernels.compute_cell_keys, (W, C), inputs=[world, agents], outputs=[g], device=device)
        # On a GPU the arrival order in a cell varies from run to run; the CPU's is slot order. Reverse
        # it in every cell, so that ordering the cells by slot has work to do here too.
        key = g.key.numpy()
        n = W * C
        live = key[:n] >= 0
        key[n:][live] = g.cell_count.numpy()[key[:n][live]] - 1 - key[n:][live]
        g.key.assign(key)
        wp.utils.array_scan(g.cell_count, g.cell_end, inclusive=True)
        wp.launch(grid_kernels.drop_into_cells, W * C, outputs=[g], device=device)
        wp.launch(grid_kernels.order_cells, W * C, inputs=[world, agents], outputs=[g], device=device)
    return {name: getattr(g, name).numpy() for name in ("cell_start", "cell_end", "agent", "position")}


def expected_cells(cfg, dims, position, alive):
    """Agents (flat slot index) of every (world, cell), in slot order: a numpy stable sort."""
    W, C = alive.shape
    dx, dy = dims
    cx = np.minimum((position[..., 0] * (dx / cfg.width)).astype(np.int64), dx - 1)
    cy = np.minimum((position[..., 1] * (dy / cfg.height)).astype(np.int64), dy - 1)
    cells = {}
    for w in range(W):
        for i in range(C):
            if alive[w, i]:
                cells.setdefault(w * dx * dy + cy[w, i] * dx + cx[w, i], []).append(w * C + i)
    return cells


@pytest.mark.parametrize("dims", [(1, 1), (3, 2), (5, 5)])
def test_cell_list_builds_agree(device, dims):
    cfg = AquariumConfig(width=300.0, height=200.0, prey_count=11, predator_count=3)
    W, C = 64, cfg.capacity
    rng = np.random.default_rng(sum(dims))
    # Positions on a 1/4 px lattice, some exactly on cell borders and on the seam (0).
    position = np.stack([rng.integers(0, 4 * 300, (W, C)) / 4.0, rng.integers(0, 4 * 200, (W, C)) / 4.0], -1)
    border = rng.random((W, C)) < 0.2
    position[border, 0] = rng.integers(0, dims[0], border.sum()) * (300.0 / dims[0])
    position = position.astype(np.float32)
    alive = rng.random((W, C)) < 0.8
    alive[3] = False  # a world with no live agent
    alive[5] = True
    want = expected_cells(cfg, dims, position, alive)
    flat_position = position.reshape(-1, 2)
    for method in ("counting", "rank", "count"):
        got = build(method, cfg, dims, position, alive, device)
        occupied = {c: list(got["agent"][got["cell_start"][c] : got["cell_end"][c]]) for c in want}
        assert occupied == want, f"{method}: cells differ"
        empty = np.ones(W * dims[0] * dims[1], bool)
        empty[list(want)] = False
        assert (got["cell_start"][empty] == got["cell_end"][empty]).all(), f"{method}: an empty cell has agents"
        # Searches read a run of cells along a row as one range: in a world, every cell (empty ones
        # too) ends where the next one starts.
        per_world = dims[0] * dims[1]
        starts = got["cell_start"].reshape(W, per_world)
        ends = got["cell_end"].reshape(W, per_world)
        assert (ends[:, :-1] == starts[:, 1:]).all(), f"{method}: cell ranges do not follow each other"
        assert (starts <= ends).all(), f"{method}: a cell range is reversed"
        listed = np.concatenate([np.arange(got["cell_start"][c], got["cell_end"][c]) for c in want])
        assert (got["position"][listed] == flat_position[got["agent"][listed]]).all(), (
            f"{method}: gathered positions differ"
        )


@wp.kernel
def runs_of_rows(grid: grid_kernels.CellLists, cases: wp.array(dtype=wp.vec4i), runs: wp.array(dtype=wp.vec4i)):
    q = wp.tid()
    case = cases[q]  # center x, center y, oy, (x_first + 50) * 100 + x_last + 50
    runs[q] = grid_kernels.row_run_entries(
        grid, 1, wp.vec2i(case[0], case[1]), case[2], case[3] // 100 - 50, case[3] % 100 - 50
    )


@pytest.mark.parametrize("dims", [(5, 3), (4, 4), (1, 2)])
def test_row_runs_cover_the_run_cells_once(device, dims):
    """`row_run_entries` gives exactly the entries of the cells of a run, also where the run crosses
    the seam partly (two ranges) or wholly (one range at the row's far end), and nothing for an empty
    run: compared with the cells' own ranges, for every center and every run within [-lo, hi]."""
    cfg = AquariumConfig(width=300.0, height=200.0, prey_count=30, predator_count=2)
    W, C = 2, cfg.capacity
    rng = np.random.default_rng(7)
    position = np.stack([rng.random((W, C)) * 300.0, rng.random((W, C)) * 200.0], -1).astype(np.float32)
    alive = rng.random((W, C)) < 0.9
    got = build("counting", cfg, dims, position, alive, device)
    g = cell_lists(cfg, W, dims, device, build="counting")
    g.cell_start = wp.array(got["cell_start"], dtype=int, device=device)
    g.cell_end = wp.array(got["cell_end"], dtype=int, device=device)
    dx, dy = dims
    lo_x, hi_x, lo_y, hi_y = (dx - 1) // 2, dx // 2, (dy - 1) // 2, dy // 2
    cases, want = [], []
    for cx in range(dx):
        for cy in range(dy):
            for oy in range(-lo_y, hi_y + 1):
                for a in range(-lo_x, hi_x + 1):
                    for b in range(a - 1, hi_x + 1):  # b = a - 1: an empty run
                        cases.append((cx, cy, oy, (a + 50) * 100 + b + 50))
                        row = (cy + oy) % dy
                        cells = [dx * dy + row * dx + (cx + x) % dx for x in range(a, b + 1)]
                        want.append(sorted(e for c in cells for e in range(got["cell_start"][c], got["cell_end"][c])))
    cases_wp = wp.array(np.array(cases, np.int32), dtype=wp.vec4i, device=device)
    runs = wp.zeros(len(cases), dtype=wp.vec4i, device=device)
    wp.launch(runs_of_rows, len(cases), inputs=[g, cases_wp], outputs=[runs], device=device)
    for case, r, w in zip(cases, runs.numpy(), want):
        entries = list(range(r[0], r[1])) + list(range(r[2], r[3]))
        assert sorted(entries) == w, f"case {case}: entries {entries}, want {w}"
        assert len(set(entries)) == len(entries)
