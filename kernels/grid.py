"""Spatial hash grid over (world, cell), rebuilt every step; and the walks of neighbour searches.

Each world is tiled by `dims_x x dims_y` cells whose size divides the world exactly, so cell indices
wrap modulo the dims and the grid is a torus like the world. Live agents are listed by the key
`world * cells_per_world + cell`, and within a cell by slot, so the order (and every result derived
from it) is deterministic on CPU and GPU. Every cell, empty ones included, has a range of entries,
and in a world the cells follow each other: a cell's range ends where the next cell's begins. So a
run of cells along a row is one range of entries (`row_run_entries`; two where the run crosses the
seam), which searches read as such. Positions are gathered into that order for coalesced neighbour
reads (a search reads every candidate's position; other fields only of the few it keeps, which it
reads from the state by slot).

Four builds give the same lists. A world that is one cell needs none: its lists are "whole-world"
lists (`whole_world`), fixed at construction, in which cell w holds every slot of world w in slot
order, dead ones included (`listed_slot` skips those), and the positions are the state's own. On the
CPU, a counting sort per world (`sort_into_cells_per_world`, one thread per world). On a GPU, small
worlds rank each slot over its world (`rank_into_cells_per_world`, one thread per slot), and large
ones count the agents of each cell (`compute_cell_keys`), take a prefix sum of the counts as the
cell ranges, drop each agent into its cell in any order (`drop_into_cells`, which also zeroes the
counts for the next build, so no memset precedes the counting) and then order each cell by slot
(`order_cells`, each entry counting the lower slots of its cell): no sort of all keys. Dead
slots lie outside every cell: the count build lists none, the per-world builds list them after their
world's live agents.

Searches walk the cells around a point by rings: ring 0 is the cell itself, ring r the 8r cells at
Chebyshev cell distance r. Offsets are clipped to [-lo, hi] per axis, so on a small torus no cell is
visited twice, and after rings 0..r every agent closer than `r * reach` (reach = the smaller cell
side, less a rounding margin) has been seen (`seen_radius`), which bounds fixed-radius searches and
lets nearest-agent searches stop early. One iterator, `CellWalk`, serves the two walk styles:
- row runs: a row of the square, or a row or column of a ring, is read as a run of cells
  (`walk_segment`, `row_run_entries`), cells wholly beyond a distance bound skipped (`clip_run`).
  `square_walk` visits the square that holds a fixed radius (captures, group links);
  `widening_walk` a first square, then one ring per `next_ring`, under a bound the search lowers as
  it goes (observations). A search loops `while next_run(grid, walk)` and, inside, over the run's
  entries (`run_length`, `run_entry`, `listed_slot`).
- cells: `ring_walk` visits one cell at a time, ring by ring (`next_cell`, `next_ring`),
  for searches of the nearest agent anywhere in the world (heuristic policies, nearest-neighbour
  metrics), which mostly end within rings 0 and 1: there the row-run walk cost them 20% on the CPU.
"""

import warp as wp

from .common import WorldParams
from .state import Agents

wp.set_module_options({"enable_backward": False})


@wp.struct
class CellLists:
    """Cell lists of all worlds. N = num_worlds * capacity; arrays indexed by sorted entry k.

    With `whole_world` = 1 each world is one cell listing all its slots (entry k = flat slot index,
    dead slots included): `key` and `agent` are empty, and `position` and `alive` are flat views of
    the state's arrays."""

    dims_x: int
    dims_y: int
    cells_per_world: int
    whole_world: int  # 1: each world is one cell of all its slots, nothing is built (see above)
    cell_width: float  # px
    cell_height: float
    inv_cell_width: float  # 1/px
    inv_cell_height: float
    reach: float  # px of guaranteed search radius gained per ring
    # On a torus of `dims` cells, offsets in [-lo, hi] name every column (row) exactly once.
    lo_x: int  # (dims_x - 1) // 2
    hi_x: int  # dims_x // 2
    lo_y: int
    hi_y: int
    cell_start: wp.array(dtype=int)  # [num_worlds * cells_per_world], first entry k of each cell
    cell_end: wp.array(dtype=int)  # [num_worlds * cells_per_world], one past the last entry
    cell_count: wp.array(dtype=int)  # [num_worlds * cells_per_world] live agents per cell (count builds; else empty)
    key: wp.array(dtype=int)  # [2N] key of each flat slot (-1: dead), then its arrival order in its cell
    agent: wp.array(dtype=int)  # [2N] flat slot index world * capacity + slot, in list order; then scratch
    position: wp.array(dtype=wp.vec2)  # [N] px, gathered in sorted order
    alive: wp.array(dtype=wp.bool)  # [N] whole-world lists only: the state's alive flags (else empty)


@wp.func
def listed_slot(grid: CellLists, k: int, base: int) -> int:
    """Slot (within its world, whose first flat slot index is `base`) of sorted entry k, or -1 for a
    dead slot, which only whole-world lists hold."""
    if grid.whole_world != 0:
        if grid.alive[k]:
            return k - base
        return -1
    return grid.agent[k] - base


@wp.func
def cell_coords(grid: CellLists, p: wp.vec2) -> wp.vec2i:
    cx = wp.min(int(p[0] * grid.inv_cell_width), grid.dims_x - 1)
    cy = wp.min(int(p[1] * grid.inv_cell_height), grid.dims_y - 1)
    return wp.vec2i(cx, cy)


@wp.func
def cell_in_world(grid: CellLists, p: wp.vec2) -> int:
    """Index of the cell holding `p` within its world."""
    c = cell_coords(grid, p)
    return c[1] * grid.dims_x + c[0]


@wp.func
def wrap_cell(c: int, dims: int) -> int:
    """Cell index modulo `dims`, for c in [-dims, 2 dims)."""
    if c < 0:
        return c + dims
    if c >= dims:
        return c - dims
    return c


@wp.func
def row_base(grid: CellLists, world: int, center: wp.vec2i, oy: int) -> int:
    """Global index of cell (0, center_y + oy) of `world`."""
    return world * grid.cells_per_world + wrap_cell(center[1] + oy, grid.dims_y) * grid.dims_x


@wp.func
def row_run_entries(grid: CellLists, world: int, center: wp.vec2i, oy: int, x_first: int, x_last: int) -> wp.vec4i:
    """Entries of the cells at offsets (x_first..x_last, oy) from `center`, offsets within the torus's
    [-lo, hi]: the range [first0, end0), then [first1, end1) where the run crosses the seam (else empty);
    all empty if x_first > x_last."""
    if x_first > x_last:
        return wp.vec4i(0, 0, 0, 0)
    base = row_base(grid, world, center, oy)
    a = center[0] + x_first
    b = center[0] + x_last
    dims = grid.dims_x
    if b < 0 or a >= dims:  # the whole run lies across the seam
        shift = wp.where(b < 0, dims, -dims)
        return wp.vec4i(grid.cell_start[base + a + shift], grid.cell_end[base + b + shift], 0, 0)
    if a < 0:  # the run's left part lies at the row's far end
        return wp.vec4i(
            grid.cell_start[base + a + dims],
            grid.cell_end[base + dims - 1],
            grid.cell_start[base],
            grid.cell_end[base + b],
        )
    if b >= dims:  # its right part lies at the row's start
        return wp.vec4i(
            grid.cell_start[base + a],
            grid.cell_end[base + dims - 1],
            grid.cell_start[base],
            grid.cell_end[base + b - dims],
        )
    return wp.vec4i(grid.cell_start[base + a], grid.cell_end[base + b], 0, 0)


@wp.func
def run_length(runs: wp.vec4i) -> int:
    return runs[1] - runs[0] + runs[3] - runs[2]


@wp.func
def run_entry(runs: wp.vec4i, n: int) -> int:
    """The n-th entry of the ranges of `row_run_entries`."""
    first_part = runs[1] - runs[0]
    if n < first_part:
        return runs[0] + n
    return runs[2] + n - first_part


@wp.func
def ring_sides(r: int) -> int:
    """Ring r is walked as `ring_sides(r)` sides of `ring_side_length(r)` cells (ring 0: one cell)."""
    if r == 0:
        return 1
    return 4


@wp.func
def ring_side_length(r: int) -> int:
    if r == 0:
        return 1
    return 2 * r


@wp.func
def ring_offset(r: int, side: int, u: int) -> wp.vec2i:
    """Cell offset of the u-th cell of a side of ring r (the 8r cells at Chebyshev distance r,
    walked clockwise from the top left corner)."""
    if r == 0:
        return wp.vec2i(0, 0)
    if side == 0:
        return wp.vec2i(-r + u, -r)
    if side == 1:
        return wp.vec2i(r, -r + u)
    if side == 2:
        return wp.vec2i(r - u, r)
    return wp.vec2i(-r, r - u)


@wp.func
def sq(x: float) -> float:
    return x * x


@wp.func
def walk_segments(ring: int, first_ring: int) -> int:
    """Row runs of one step of a widening search: the first step visits the square of rings
    0..first_ring (one run per row), each later step the ring `ring` alone (its top and bottom rows,
    and the left and right cell of each row between)."""
    if ring == first_ring:
        return 2 * ring + 1
    return 4 * ring


@wp.func
def walk_segment(ring: int, first_ring: int, s: int) -> wp.vec3i:
    """The s-th row run (oy, x_first, x_last) of the step at `ring` (see `walk_segments`)."""
    if ring == first_ring:
        return wp.vec3i(s - ring, -ring, ring)
    if s < 2:
        oy = wp.where(s == 0, -ring, ring)
        return wp.vec3i(oy, -ring, ring)
    q = s - 2
    x = wp.where(q % 2 == 0, -ring, ring)
    return wp.vec3i(-ring + 1 + q // 2, x, x)


@wp.func
def clip_run(grid: CellLists, run: wp.vec3i, inside_x: float, inside_y: float, bound2: float) -> wp.vec3i:
    """The row run (oy, x_first, x_last) cut to the torus's representative offsets and to the cells
    within sqrt(bound2) of a point `inside_x`, `inside_y` px into its cell: x_first > x_last if none."""
    oy = run[0]
    if oy < -grid.lo_y or oy > grid.hi_y:
        return wp.vec3i(oy, 1, 0)
    x_first = wp.max(run[1], -grid.lo_x)
    x_last = wp.min(run[2], grid.hi_x)
    if bound2 == wp.inf:  # no distance bound (fixed squares, unbounded searches): no gaps to compute
        return wp.vec3i(oy, x_first, x_last)
    gap_y = cell_gap(oy, inside_y, grid.cell_height, grid.dims_y)
    gap_y2 = gap_y * gap_y
    # Gaps grow away from offset 0, so the cells in reach form one interval.
    while x_first <= x_last and sq(cell_gap(x_first, inside_x, grid.cell_width, grid.dims_x)) + gap_y2 > bound2:
        x_first += 1
    while x_last >= x_first and sq(cell_gap(x_last, inside_x, grid.cell_width, grid.dims_x)) + gap_y2 > bound2:
        x_last -= 1
    return wp.vec3i(oy, x_first, x_last)


@wp.func
def offset_cell(grid: CellLists, world: int, center: wp.vec2i, o: wp.vec2i) -> int:
    """Global index of the cell at offset `o` from `center`, or -1 where `o` is not the offset this
    torus names that cell by (it is visited under its representative offset instead)."""
    if o[0] < -grid.lo_x or o[0] > grid.hi_x or o[1] < -grid.lo_y or o[1] > grid.hi_y:
        return -1
    return row_base(grid, world, center, o[1]) + wrap_cell(center[0] + o[0], grid.dims_x)


@wp.func
def cell_gap(offset: int, inside: float, size: float, dims: int) -> float:
    """Distance along one axis from a point `inside` px into its cell to the cell `offset` cells away,
    the shorter way round the torus."""
    if offset == 0:
        return 0.0
    ahead = offset
    behind = offset - dims
    if offset < 0:
        ahead = offset + dims
        behind = offset
    return wp.min(float(ahead) * size - inside, inside + float(-behind - 1) * size)


@wp.func
def last_ring(grid: CellLists) -> int:
    """Ring after which every cell of the world has been visited."""
    return wp.max(grid.hi_x, grid.hi_y)


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


@wp.struct
class CellWalk:
    """A walk over the cells around a point (see the module docstring): a row run of cells at a time
    (made by `square_walk` or `widening_walk`, advanced by `next_run`) or one cell at a time (made by
    `ring_walk`, advanced by `next_cell`); `next_ring` starts the next ring."""

    world: int  # the world's index in the lists
    base: int  # flat slot index of the world's slot 0: an entry's slot is listed_slot(grid, entry, base)
    center: wp.vec2i  # the point's cell
    inside: wp.vec2  # px: where the point lies inside its cell
    bound2: float  # px^2: cells wholly farther than sqrt(bound2) from the point are skipped
    first_ring: int  # the first step visits the square of rings 0..first_ring; each later step one ring
    ring: int  # the current step's ring
    segment: int  # the current step's next row run (`walk_segment`)
    segments: int  # row runs of the current step
    segment_stride: int  # row runs taken: segment, segment + segment_stride, ...
    runs: wp.vec4i  # entries of the current row run (`row_run_entries`)
    side: int  # a cell walk's next cell: the u-th of side `side` of the current ring (`ring_offset`)
    u: int
    cell: int  # global index of the cell `next_cell` went to


@wp.func(inline=True)
def cell_walk(
    grid: CellLists,
    w: int,
    capacity: int,
    p: wp.vec2,
    first_ring: int,
    bound2: float,
    first_segment: int,
    segment_stride: int,
) -> CellWalk:
    """A walk whose first step is the square of rings 0..first_ring, of which a run walk takes the row
    runs first_segment, first_segment + segment_stride, ..."""
    walk = CellWalk()
    walk.world = w
    walk.base = w * capacity
    walk.center = cell_coords(grid, p)
    walk.inside = wp.vec2(
        p[0] - float(walk.center[0]) * grid.cell_width, p[1] - float(walk.center[1]) * grid.cell_height
    )
    walk.bound2 = bound2
    walk.first_ring = first_ring
    walk.ring = first_ring
    walk.segment = first_segment
    walk.segments = walk_segments(first_ring, first_ring)
    walk.segment_stride = segment_stride
    walk.runs = wp.vec4i(0, 0, 0, 0)
    walk.side = 0
    walk.u = 0
    return walk


@wp.func(inline=True)
def square_walk(
    grid: CellLists, w: int, capacity: int, p: wp.vec2, radius: float, row: int, row_stride: int
) -> CellWalk:
    """Fixed-radius walk: the square of cells that holds every agent of world `w` within `radius` of
    `p` (a world of `capacity` slots), row by row; rows `row`, `row + row_stride`, ... of the square
    only (a search split over `row_stride` threads), all rows with (0, 1)."""
    return cell_walk(grid, w, capacity, p, rings_for_radius(grid, radius), wp.inf, row, row_stride)


@wp.func(inline=True)
def widening_walk(grid: CellLists, w: int, capacity: int, p: wp.vec2, first_ring: int, bound2: float) -> CellWalk:
    """Widening walk: first the square of rings 0..first_ring around `p`'s cell, then, after each
    `next_ring`, the next ring; cells wholly farther than sqrt(`walk.bound2`) are skipped (a search
    may lower the bound as it goes). After the step of ring r every agent within
    `seen_radius(grid, r)` has been visited."""
    return cell_walk(grid, w, capacity, p, first_ring, bound2, 0, 1)


@wp.func(inline=True)
def next_run(grid: CellLists, walk: wp.ref[CellWalk]) -> bool:
    """Move `walk` to the next row run of its current step, whose entries are `run_entry(walk.runs, n)`
    for n < `run_length(walk.runs)`; False once the step is done. (A search loops over a run's entries
    itself: an iterator over single entries cost the observation pass 40% on the CPU.)"""
    if walk.segment >= walk.segments:
        return False
    if grid.whole_world != 0:  # the world is one cell: one run, its slots (no cell arithmetic)
        walk.runs = wp.vec4i(grid.cell_start[walk.world], grid.cell_end[walk.world], 0, 0)
    else:
        run = clip_run(
            grid, walk_segment(walk.ring, walk.first_ring, walk.segment), walk.inside[0], walk.inside[1], walk.bound2
        )
        walk.runs = row_run_entries(grid, walk.world, walk.center, run[0], run[1], run[2])
    walk.segment += walk.segment_stride
    return True


@wp.func
def seen_radius(grid: CellLists, ring: int) -> float:
    """px within which a walk has visited every agent once it has visited rings 0..ring; +inf once it
    has visited the whole world."""
    if ring >= last_ring(grid):
        return wp.inf
    return searched_radius(grid, ring)


@wp.func(inline=True)
def next_ring(walk: wp.ref[CellWalk]):
    """Make the ring after the current step's the walk's next step."""
    walk.ring += 1
    walk.segment = 0
    walk.segments = walk_segments(walk.ring, walk.first_ring)
    walk.segment_stride = 1
    walk.side = 0
    walk.u = 0


@wp.func(inline=True)
def ring_walk(grid: CellLists, w: int, capacity: int, p: wp.vec2) -> CellWalk:
    """Cell walk: the cells around `p` in world `w` (of `capacity` slots) one at a time (`next_cell`),
    ring by ring (`next_ring`) from `p`'s cell."""
    return cell_walk(grid, w, capacity, p, 0, wp.inf, 0, 1)


@wp.func(inline=True)
def next_cell(grid: CellLists, walk: wp.ref[CellWalk]) -> bool:
    """Move `walk` to the next cell of its current ring (`walk.cell`), skipping offsets that name a cell
    this torus names otherwise; False once the ring is done."""
    while walk.side < ring_sides(walk.ring):
        c = offset_cell(grid, walk.world, walk.center, ring_offset(walk.ring, walk.side, walk.u))
        walk.u += 1
        if walk.u >= ring_side_length(walk.ring):
            walk.u = 0
            walk.side += 1
        if c >= 0:
            walk.cell = c
            return True
    return False


@wp.kernel
def compute_cell_keys(world: WorldParams, agents: Agents, grid: CellLists):
    """Count build, step 1: each live agent's key, and its arrival order among its cell's agents
    (`cell_count`, zero beforehand, counts them: zero at allocation, and zeroed again by the last
    build's `drop_into_cells`; the order varies from run to run, `order_cells` replaces it by slot
    order)."""
    w, i = wp.tid()
    n = grid.position.shape[0]
    k = w * world.capacity + i
    if agents.alive[w, i]:
        cell = w * grid.cells_per_world + cell_in_world(grid, agents.position[w, i])
        grid.key[k] = cell
        grid.key[n + k] = wp.atomic_add(grid.cell_count, cell, 1)
    else:
        grid.key[k] = -1


@wp.kernel
def drop_into_cells(grid: CellLists):
    """Count build, step 3 (after the prefix sum of the counts into the cell ends): each live agent
    takes the place of its arrival order in its cell's range of the scratch list. The counts have
    had their last read (the prefix sum), so the threads zero them for the next build (cells k,
    k + agents, ...: a world may have more cells than slots)."""
    k = wp.tid()
    n = grid.position.shape[0]
    for c in range(k, grid.cell_count.shape[0], n):
        grid.cell_count[c] = 0
    cell = grid.key[k]
    if cell >= 0:
        grid.agent[n + grid.cell_start[cell] + grid.key[n + k]] = k


@wp.kernel
def order_cells(world: WorldParams, agents: Agents, grid: CellLists):
    """Count build, step 4: the agent at scratch entry k moves to its cell's start plus the number of
    lower slots in its cell (O(agents of the cell) per thread, like the searches that read the cell),
    and its position is gathered there."""
    k = wp.tid()
    n = grid.position.shape[0]
    if k >= grid.cell_end[grid.cell_end.shape[0] - 1]:  # past the last live agent
        return
    idx = grid.agent[n + k]
    cell = grid.key[idx]
    first = grid.cell_start[cell]
    at = first
    for q in range(first, grid.cell_end[cell]):
        if grid.agent[n + q] < idx:
            at += 1
    w = idx // world.capacity
    i = idx - w * world.capacity
    grid.agent[at] = idx
    grid.position[at] = agents.position[w, i]


@wp.func
def set_empty_cells(cell_start: wp.array(dtype=int), cell_end: wp.array(dtype=int), first: int, last: int, entry: int):
    """Cells [first, last) hold no agent: their ranges are empty, at `entry`."""
    for c in range(first, last):
        cell_start[c] = entry
        cell_end[c] = entry


@wp.kernel
def rank_into_cells_per_world(world: WorldParams, agents: Agents, grid: CellLists):
    """The cell lists of small worlds on a GPU, one thread per slot: a slot's entry is its rank by
    (cell, slot) among its world's live agents, counted over the world's slots (O(capacity) per
    thread, no sort). Live agents get the count build's order; dead slots follow them, as in
    `sort_into_cells_per_world`. The first agent of each occupied cell writes its cell's range and
    those of the empty cells between it and the occupied cell below (and above, for the last one)."""
    w, i = wp.tid()
    capacity = world.capacity
    first = w * capacity
    first_cell = w * grid.cells_per_world
    k = first + i
    at = int(0)
    if agents.alive[w, i]:
        cell = cell_in_world(grid, agents.position[w, i])
        before = int(0)  # live agents in lower cells
        ahead = int(0)  # live agents in the same cell with a lower slot
        inside = int(0)
        below = int(-1)  # the highest occupied cell below this one
        above = bool(False)  # any occupied cell above this one
        for j in range(capacity):
            if agents.alive[w, j]:
                other = cell_in_world(grid, agents.position[w, j])
                if other < cell:
                    before += 1
                    below = wp.max(below, other)
                elif other == cell:
                    inside += 1
                    if j < i:
                        ahead += 1
                else:
                    above = True
        at = first + before + ahead
        if ahead == 0:
            set_empty_cells(grid.cell_start, grid.cell_end, first_cell + below + 1, first_cell + cell, first + before)
            grid.cell_start[first_cell + cell] = first + before
            grid.cell_end[first_cell + cell] = first + before + inside
            if not above:
                set_empty_cells(
                    grid.cell_start,
                    grid.cell_end,
                    first_cell + cell + 1,
                    first_cell + grid.cells_per_world,
                    first + before + inside,
                )
    else:
        live = int(0)
        dead_ahead = int(0)
        for j in range(capacity):
            if agents.alive[w, j]:
                live += 1
            elif j < i:
                dead_ahead += 1
        at = first + live + dead_ahead
        if live == 0 and i == 0:  # no live agent: every cell is empty
            set_empty_cells(grid.cell_start, grid.cell_end, first_cell, first_cell + grid.cells_per_world, first)
    grid.agent[at] = k
    grid.position[at] = agents.position[w, i]


@wp.kernel
def sort_into_cells_per_world(world: WorldParams, agents: Agents, grid: CellLists):
    """The cell lists of one world by a counting sort in one thread (the CPU path: Warp runs CPU
    kernels on one thread anyway). Stable, so live agents get the GPU builds' order; a world's dead
    slots follow its live ones in its own block of entries (no query reads them)."""
    w = wp.tid()
    capacity = world.capacity
    first_cell = w * grid.cells_per_world
    for c in range(grid.cells_per_world):
        grid.cell_end[first_cell + c] = 0
    for i in range(capacity):
        k = w * capacity + i
        grid.key[k] = -1
        if agents.alive[w, i]:
            grid.key[k] = first_cell + cell_in_world(grid, agents.position[w, i])
            grid.cell_end[grid.key[k]] = grid.cell_end[grid.key[k]] + 1
    total = w * capacity
    for c in range(grid.cells_per_world):
        count = grid.cell_end[first_cell + c]
        grid.cell_start[first_cell + c] = total
        grid.cell_end[first_cell + c] = total  # becomes the write cursor, and ends as the cell's end
        total += count
    dead = total
    for i in range(capacity):
        k = w * capacity + i
        at = dead
        if grid.key[k] >= 0:
            at = grid.cell_end[grid.key[k]]
            grid.cell_end[grid.key[k]] = at + 1
        else:
            dead += 1
        grid.agent[at] = k
        grid.position[at] = agents.position[w, i]
