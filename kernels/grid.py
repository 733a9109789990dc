"""Spatial hash grid over (world, cell), rebuilt every step; and ring-by-ring neighbour search.

Each world is tiled by `dims_x x dims_y` cells whose size divides the world exactly, so cell indices
wrap modulo the dims and the grid is a torus like the world. Live agents are sorted by the key
`world * cells_per_world + cell` with a stable radix sort, so the order (and every result derived
from it) is deterministic on CPU and GPU; dead slots get a key past the last cell and sort last.
Positions and speeds are gathered into that order for coalesced neighbour reads.

Queries visit rings of cells around the query cell: ring 0 is the cell itself, ring r the 8r cells
at Chebyshev cell distance r. After rings 0..r every agent closer than `r * reach` (reach = the
smaller cell side, less a rounding margin) has been seen, which bounds fixed-radius queries and lets
k-nearest queries stop early. On a small torus, offsets are limited to one representative per
column and row, so no cell is visited twice.
"""

import warp as wp

from .common import WorldParams

wp.set_module_options({"enable_backward": False})


@wp.struct
class CellLists:
    """Cell lists of all worlds. N = num_worlds * capacity; arrays indexed by sorted entry k."""

    dims_x: int
    dims_y: int
    cells_per_world: int
    inv_cell_width: float  # 1/px
    inv_cell_height: float
    reach: float  # px of guaranteed search radius gained per ring
    cell_start: wp.array(dtype=int)  # [num_worlds * cells_per_world], first entry k of each cell
    cell_end: wp.array(dtype=int)  # [num_worlds * cells_per_world], one past the last entry
    key: wp.array(dtype=int)  # [2N] sort keys (second half is radix-sort scratch)
    agent: wp.array(dtype=int)  # [2N] flat slot index world * capacity + slot, in sorted order
    position: wp.array(dtype=wp.vec2)  # [N] px, gathered in sorted order
    speed: wp.array(dtype=float)  # [N] px/step, gathered in sorted order


@wp.func
def cell_coords(grid: CellLists, p: wp.vec2) -> wp.vec2i:
    cx = wp.min(int(p[0] * grid.inv_cell_width), grid.dims_x - 1)
    cy = wp.min(int(p[1] * grid.inv_cell_height), grid.dims_y - 1)
    return wp.vec2i(cx, cy)


@wp.func
def ring_size(r: int) -> int:
    if r == 0:
        return 1
    return 8 * r


@wp.func
def ring_offset(r: int, t: int) -> wp.vec2i:
    """The t-th cell offset of ring r, walking its four sides clockwise."""
    if r == 0:
        return wp.vec2i(0, 0)
    side = 2 * r
    u = t % side
    seg = t // side
    if seg == 0:
        return wp.vec2i(-r + u, -r)
    if seg == 1:
        return wp.vec2i(r, -r + u)
    if seg == 2:
        return wp.vec2i(r - u, r)
    return wp.vec2i(-r, r - u)


@wp.func
def ring_cell(grid: CellLists, world: int, center: wp.vec2i, r: int, t: int) -> int:
    """Global cell index of the t-th cell of ring r around `center`, or -1 when that offset is not
    the representative of its column/row on this torus (it was or will be visited as another one)."""
    o = ring_offset(r, t)
    if o[0] < -((grid.dims_x - 1) // 2) or o[0] > grid.dims_x // 2:
        return -1
    if o[1] < -((grid.dims_y - 1) // 2) or o[1] > grid.dims_y // 2:
        return -1
    cx = (center[0] + o[0] + grid.dims_x) % grid.dims_x
    cy = (center[1] + o[1] + grid.dims_y) % grid.dims_y
    return world * grid.cells_per_world + cy * grid.dims_x + cx


@wp.func
def last_ring(grid: CellLists) -> int:
    """Ring after which every cell of the world has been visited."""
    return wp.max(grid.dims_x // 2, grid.dims_y // 2)


@wp.func
def searched_radius(grid: CellLists, r: int) -> float:
    """Radius within which rings 0..r have found every agent (a margin absorbs rounding of cells)."""
    return (float(r) - 1.0e-3) * grid.reach


@wp.func
def rings_for_radius(grid: CellLists, radius: float) -> int:
    """Number of the last ring needed to find every agent within `radius`."""
    last = last_ring(grid)
    if radius >= float(last) * grid.reach:
        return last
    return wp.min(int(radius / grid.reach + 1.0e-3) + 1, last)


@wp.kernel
def compute_cell_keys(
    world: WorldParams,
    grid: CellLists,
    position: wp.array2d(dtype=wp.vec2),
    alive: wp.array2d(dtype=wp.bool),
    num_worlds: int,
    key: wp.array(dtype=int),
    agent: wp.array(dtype=int),
):
    w, i = wp.tid()
    k = w * world.capacity + i
    if alive[w, i]:
        c = cell_coords(grid, position[w, i])
        key[k] = w * grid.cells_per_world + c[1] * grid.dims_x + c[0]
    else:
        key[k] = num_worlds * grid.cells_per_world
    agent[k] = k


@wp.kernel
def find_cell_ranges(
    world: WorldParams,
    grid: CellLists,
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    count: int,
    sentinel: int,
    cell_start: wp.array(dtype=int),
    cell_end: wp.array(dtype=int),
    sorted_position: wp.array(dtype=wp.vec2),
    sorted_speed: wp.array(dtype=float),
):
    k = wp.tid()
    idx = grid.agent[k]
    w = idx // world.capacity
    i = idx - w * world.capacity
    sorted_position[k] = position[w, i]
    sorted_speed[k] = wp.length(velocity[w, i])
    key = grid.key[k]
    if key == sentinel:
        return
    if k == 0 or grid.key[k - 1] != key:
        cell_start[key] = k
    if k == count - 1 or grid.key[k + 1] != key:
        cell_end[key] = k + 1


def build_cell_lists(world: WorldParams, grid: CellLists, position, velocity, alive, num_worlds: int,
                     device) -> None:
    """Rebuild `grid` from the current state (no allocation, no host sync: graph-capturable)."""
    capacity = world.capacity
    count = num_worlds * capacity
    wp.launch(compute_cell_keys, dim=(num_worlds, capacity),
              inputs=[world, grid, position, alive, num_worlds], outputs=[grid.key, grid.agent], device=device)
    wp.utils.radix_sort_pairs(grid.key, grid.agent, count)
    grid.cell_start.zero_()
    grid.cell_end.zero_()
    wp.launch(find_cell_ranges, dim=count,
              inputs=[world, grid, position, velocity, count, num_worlds * grid.cells_per_world],
              outputs=[grid.cell_start, grid.cell_end, grid.position, grid.speed], device=device)
