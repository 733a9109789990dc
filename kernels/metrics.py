"""Swarm metrics of every world on the device: polarization, local alignment, milling, cohesion,
nearest-neighbour distances, groups (connected components), distance to the nearest predator,
populations.

All metrics are about the live prey of a world; distances are torus-shortest, in px. Neighbour
queries read the cell lists that the observation pass built on the current state, so no metric does
all-pairs work:
- nearest prey: a ring-by-ring search that stops once no unseen prey can be nearer;
- nearest predator: the same search, or, when predators are few, a loop over the predator slots
  (cost per prey `predator_count`; a ring search would walk every prey entry between a prey and a
  far-away lone predator);
- groups: a parallel union-find over the pairs of live prey closer than the linking distance, found
  by a fixed-radius search. Roots are hooked under the smaller slot index with an atomic
  compare-and-swap, so every parent index is below its child's and the final root of a component
  is its smallest prey slot, whatever order the threads ran in: the labels are deterministic.

Sums over the prey of a world run in two deterministic stages (no float atomics): per chunk of
`CHUNK` slots in slot order, then over the chunks in order. Integer counters (histogram bins,
group sizes) use integer atomics, whose result does not depend on the order.

Launch order per shard (see `aquarium_warp.metrics.SwarmMetrics`): zero the integer counters,
`prey_distances`, `link_groups`, `local_alignment`, `resolve_groups`, `prey_partial_sums`,
`finish_prey_sums`, `centroid_partial_sums`, `finish_cohesion`.
"""

import warp as wp

from .common import PREY, WorldParams, slot_type, torus_displacement, wrap_coordinate
from .grid import (
    CellLists,
    listed_slot,
    next_cell,
    next_ring,
    next_run,
    ring_walk,
    run_entry,
    run_length,
    seen_radius,
    square_walk,
)
from .state import Agents, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})

# Prey slots summed per partial sum (first stage of the two-stage reductions).
CHUNK = wp.constant(256)

# Columns of the per-world result matrix `values` [W, NUM_VALUES] (float32).
POLARIZATION = wp.constant(0)  # |mean unit heading| of live prey, in [0, 1]
COHESION = wp.constant(1)  # mean torus distance of live prey to their centroid, px
CENTROID_X = wp.constant(2)  # circular-mean centroid of live prey, px in [0, width)
CENTROID_Y = wp.constant(3)  # px in [0, height)
NN_MEAN = wp.constant(4)  # mean over live prey of the distance to the nearest other live prey, px
GROUPS = wp.constant(5)  # connected components of live prey (links: distance < linking distance)
LARGEST_GROUP = wp.constant(6)  # live prey in the largest group / live prey, in (0, 1]
PREDATOR_DISTANCE = wp.constant(7)  # mean over live prey of the distance to the nearest live predator, px
PREY_ALIVE = wp.constant(8)  # live prey
PREDATOR_ALIVE = wp.constant(9)  # live predators
CAPTURES = wp.constant(10)  # captures in the last step
# Mean over live prey with a linked neighbour (distance < linking distance) of |own heading + the
# neighbours' headings| / (1 + neighbours), in [0, 1]: alignment among neighbours, whatever the global order.
LOCAL_ALIGNMENT = wp.constant(11)
# |mean over live prey of (r / |r|) x heading|, r the prey's torus offset from the centroid, in [0, 1]:
# 1 for prey circling the centroid all one way (a mill), about 1 / sqrt(n) for random headings.
MILLING = wp.constant(12)
NUM_VALUES = wp.constant(13)
VALUE_NAMES = (
    "polarization",
    "cohesion",
    "centroid_x",
    "centroid_y",
    "nn_mean",
    "groups",
    "largest_group",
    "predator_distance",
    "prey_alive",
    "predator_alive",
    "captures",
    "local_alignment",
    "milling",
)

# Columns of the first-stage partial sums [W, chunks, NUM_PARTIALS].
_P_COUNT = wp.constant(0)  # live prey
_P_HEAD_X = wp.constant(1)  # sum of unit headings
_P_HEAD_Y = wp.constant(2)
_P_COS_X = wp.constant(3)  # sum of cos / sin of 2 pi x / width (circular mean of x)
_P_SIN_X = wp.constant(4)
_P_COS_Y = wp.constant(5)
_P_SIN_Y = wp.constant(6)
_P_NN_SUM = wp.constant(7)  # nearest-prey distances, px, and how many prey have one
_P_NN_COUNT = wp.constant(8)
_P_PRED_SUM = wp.constant(9)  # nearest-predator distances, px, and how many prey have one
_P_PRED_COUNT = wp.constant(10)
_P_LARGEST = wp.constant(11)  # largest group size among the roots of the chunk
_P_ROOTS = wp.constant(12)  # groups (roots) in the chunk
_P_ALIGN_SUM = wp.constant(13)  # local alignments, and how many prey have a linked neighbour
_P_ALIGN_COUNT = wp.constant(14)
NUM_PARTIALS = wp.constant(15)

TWO_PI = wp.constant(6.283185307179586)


@wp.struct
class SwarmArrays:
    """The metrics' device buffers (allocated by `aquarium_warp.metrics.SwarmMetrics`)."""

    nearest_prey: wp.array2d(dtype=float)
    """[W, Pc] float32, px, torus distance of each live prey to the nearest other live prey; -1: none."""
    nearest_predator: wp.array2d(dtype=float)
    """[W, Pc] float32, px, to the nearest live predator; -1: none."""
    nn_histogram: wp.array2d(dtype=wp.int32)
    """[W, bins] int32, nearest-prey distances per bin (the last bin also counts those beyond)."""
    parent: wp.array(dtype=wp.int32)
    """[W * Pc] int32, union-find forest of the groups: world w's prey slot i at w * Pc + i."""
    group_label: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, smallest prey slot of each live prey's group; -1 for dead slots."""
    group_size: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, members of the group whose root is the slot."""
    local_alignment: wp.array2d(dtype=float)
    """[W, Pc] float32, |own + linked neighbours' headings| / (1 + neighbours); -1: dead or no neighbour."""
    partial: wp.array3d(dtype=float)
    """[W, chunks, NUM_PARTIALS] float32, first-stage sums (columns `_P_*`)."""
    values: wp.array2d(dtype=float)
    """[W, NUM_VALUES] float32, the per-world results (columns named by `VALUE_NAMES`)."""


@wp.func
def find_root(parent: wp.array(dtype=wp.int32), base: int, x: int) -> int:
    """Root of prey slot `x` in the union-find forest `parent[base + slot]`, halving the path on the
    way (each write replaces a parent by a grandparent: benign when threads race)."""
    r = x
    p = int(parent[base + r])
    while p != r:
        g = int(parent[base + p])
        if g != p:
            parent[base + r] = wp.int32(g)
        r = p
        p = g
    return r


@wp.func
def unite(parent: wp.array(dtype=wp.int32), base: int, a: int, b: int):
    """Merge the trees of slots `a` and `b`: the larger root is hooked under the smaller one by an
    atomic compare-and-swap; if it stopped being a root meanwhile, retry from where it now points."""
    ra = find_root(parent, base, a)
    rb = find_root(parent, base, b)
    while ra != rb:
        hi = wp.max(ra, rb)
        lo = wp.min(ra, rb)
        old = int(wp.atomic_cas(parent, base + hi, wp.int32(hi), wp.int32(lo)))
        if old == hi:
            ra = lo
            rb = lo
        else:
            ra = find_root(parent, base, old)
            rb = find_root(parent, base, lo)


@wp.kernel
def prey_distances(
    world: WorldParams,
    grid: CellLists,
    agents: Agents,
    predators_by_grid: int,
    bin_width: float,
    swarm: SwarmArrays,
):
    """Per prey slot `(w, i)`, i < prey_capacity: torus distance (px) to the nearest other live prey
    and to the nearest live predator (-1 where there is none, or the slot is dead); the nearest-prey
    distance is counted in `nn_histogram[w, bin]` (bin = floor(d / bin_width), the last bin also
    holds everything beyond). Also starts the union-find: `parent[w * prey_capacity + i] = i`.
    `predators_by_grid` 1: ring search for the nearest predator, 0: loop over the predator slots.
    `grid` must hold the cell lists of `agents.position`; `nn_histogram` must be zero."""
    w, i = wp.tid()
    swarm.parent[w * world.prey_capacity + i] = wp.int32(i)
    if not agents.alive[w, i]:
        swarm.nearest_prey[w, i] = -1.0
        swarm.nearest_predator[w, i] = -1.0
        return
    pos = agents.position[w, i]
    prey_d2 = float(0.0)
    prey_found = bool(False)
    pred_d2 = float(0.0)
    pred_found = bool(False)

    if predators_by_grid == 0:
        for j in range(world.prey_capacity, world.capacity):
            if agents.alive[w, j]:
                d = torus_displacement(world, pos, agents.position[w, j])
                d2 = wp.dot(d, d)
                if not pred_found or d2 < pred_d2:
                    pred_d2 = d2
                    pred_found = True

    # Ring by ring from the prey's own cell (a minimum does not depend on the visiting order).
    walk = ring_walk(grid, w, world.capacity, pos)
    want_pred = predators_by_grid != 0
    searching = bool(True)
    while searching:
        while next_cell(grid, walk):
            for k2 in range(grid.cell_start[walk.cell], grid.cell_end[walk.cell]):
                j = listed_slot(grid, k2, walk.base)
                if j >= 0 and j != i:
                    d = torus_displacement(world, pos, grid.position[k2])
                    d2 = wp.dot(d, d)
                    if slot_type(world, j) == PREY:
                        if not prey_found or d2 < prey_d2:
                            prey_d2 = d2
                            prey_found = True
                    elif want_pred:
                        if not pred_found or d2 < pred_d2:
                            pred_d2 = d2
                            pred_found = True
        reach = seen_radius(grid, walk.ring)  # every agent closer than this has been seen
        reach2 = reach * reach
        prey_done = prey_found and prey_d2 < reach2
        pred_done = (not want_pred) or (pred_found and pred_d2 < reach2)
        searching = reach != wp.inf and not (prey_done and pred_done)
        next_ring(walk)

    swarm.nearest_prey[w, i] = -1.0
    if prey_found:
        dist = wp.sqrt(prey_d2)
        swarm.nearest_prey[w, i] = dist
        bins = swarm.nn_histogram.shape[1]
        b = bins - 1
        if dist < float(bins) * bin_width:
            b = wp.min(int(dist / bin_width), bins - 1)
        wp.atomic_add(swarm.nn_histogram, w, b, wp.int32(1))
    swarm.nearest_predator[w, i] = -1.0
    if pred_found:
        swarm.nearest_predator[w, i] = wp.sqrt(pred_d2)


@wp.kernel
def link_groups(
    world: WorldParams, grid: CellLists, agents: Agents, linking_distances: wp.array(dtype=float), swarm: SwarmArrays
):
    """Per prey slot `(w, i)`: unite `i` with every live prey `j > i` at torus distance
    `< linking_distances[w]` (px; per world, as the prey radii may be), found by a fixed-radius search
    of the cell lists. `parent[w * prey_capacity + i]` must start as `i` (set by `prey_distances`)."""
    w, i = wp.tid()
    if not agents.alive[w, i]:
        return
    pos = agents.position[w, i]
    forest = w * world.prey_capacity
    linking_distance = linking_distances[w]
    link2 = linking_distance * linking_distance
    walk = square_walk(grid, w, world.capacity, pos, linking_distance, 0, 1)
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            k2 = run_entry(walk.runs, n)
            j = listed_slot(grid, k2, walk.base)
            if j > i and slot_type(world, j) == PREY:  # j > i >= 0: a live slot
                d = torus_displacement(world, pos, grid.position[k2])
                if wp.dot(d, d) < link2:
                    unite(swarm.parent, forest, i, j)


@wp.kernel
def local_alignment(
    world: WorldParams, grid: CellLists, agents: Agents, linking_distances: wp.array(dtype=float), swarm: SwarmArrays
):
    """Per prey slot `(w, i)`: `swarm.local_alignment[w, i]` from the live prey closer than
    `linking_distances[w]` (the groups' links; a fixed-radius search, summed in the cells' order)."""
    w, i = wp.tid()
    swarm.local_alignment[w, i] = -1.0
    if not agents.alive[w, i]:
        return
    pos = agents.position[w, i]
    linking_distance = linking_distances[w]
    link2 = linking_distance * linking_distance
    total = agents.heading[w, i]
    count = int(0)
    walk = square_walk(grid, w, world.capacity, pos, linking_distance, 0, 1)
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            k2 = run_entry(walk.runs, n)
            j = listed_slot(grid, k2, walk.base)
            if j >= 0 and j != i and slot_type(world, j) == PREY:
                d = torus_displacement(world, pos, grid.position[k2])
                if wp.dot(d, d) < link2:
                    total = total + agents.heading[w, j]
                    count += 1
    if count > 0:
        swarm.local_alignment[w, i] = wp.length(total) / float(count + 1)


@wp.kernel
def resolve_groups(world: WorldParams, agents: Agents, swarm: SwarmArrays):
    """Per prey slot `(w, i)`: `swarm.group_label[w, i]` = the smallest prey slot of its group (-1 if dead),
    and `swarm.group_size[w, root]` counts the group's members. `group_size` must be zero."""
    w, i = wp.tid()
    if not agents.alive[w, i]:
        swarm.group_label[w, i] = -1
        return
    root = find_root(swarm.parent, w * world.prey_capacity, i)
    swarm.group_label[w, i] = wp.int32(root)
    wp.atomic_add(swarm.group_size, w, root, wp.int32(1))


@wp.kernel
def prey_partial_sums(world: WorldParams, agents: Agents, swarm: SwarmArrays):
    """First stage of the per-world sums: chunk `c` of world `w` sums prey slots
    `[c * CHUNK, (c + 1) * CHUNK)` in slot order into `swarm.partial[w, c, :]` (columns `_P_*`)."""
    w, c = wp.tid()
    count = float(0.0)
    head = wp.vec2(0.0, 0.0)
    cos_x = float(0.0)
    sin_x = float(0.0)
    cos_y = float(0.0)
    sin_y = float(0.0)
    nn_sum = float(0.0)
    nn_count = float(0.0)
    pred_sum = float(0.0)
    pred_count = float(0.0)
    largest = int(0)
    roots = int(0)
    align_sum = float(0.0)
    align_count = float(0.0)
    first = c * CHUNK
    end = wp.min(first + CHUNK, world.prey_capacity)
    for i in range(first, end):
        if agents.alive[w, i]:
            count += 1.0
            head = head + agents.heading[w, i]
            p = agents.position[w, i]
            ax = TWO_PI * p[0] / world.width
            ay = TWO_PI * p[1] / world.height
            cos_x += wp.cos(ax)
            sin_x += wp.sin(ax)
            cos_y += wp.cos(ay)
            sin_y += wp.sin(ay)
            nn = swarm.nearest_prey[w, i]
            if nn >= 0.0:
                nn_sum += nn
                nn_count += 1.0
            pd = swarm.nearest_predator[w, i]
            if pd >= 0.0:
                pred_sum += pd
                pred_count += 1.0
            if swarm.group_label[w, i] == i:
                roots += 1
                largest = wp.max(largest, int(swarm.group_size[w, i]))
            alignment = swarm.local_alignment[w, i]
            if alignment >= 0.0:
                align_sum += alignment
                align_count += 1.0
    swarm.partial[w, c, _P_COUNT] = count
    swarm.partial[w, c, _P_HEAD_X] = head[0]
    swarm.partial[w, c, _P_HEAD_Y] = head[1]
    swarm.partial[w, c, _P_COS_X] = cos_x
    swarm.partial[w, c, _P_SIN_X] = sin_x
    swarm.partial[w, c, _P_COS_Y] = cos_y
    swarm.partial[w, c, _P_SIN_Y] = sin_y
    swarm.partial[w, c, _P_NN_SUM] = nn_sum
    swarm.partial[w, c, _P_NN_COUNT] = nn_count
    swarm.partial[w, c, _P_PRED_SUM] = pred_sum
    swarm.partial[w, c, _P_PRED_COUNT] = pred_count
    swarm.partial[w, c, _P_LARGEST] = float(largest)
    swarm.partial[w, c, _P_ROOTS] = float(roots)
    swarm.partial[w, c, _P_ALIGN_SUM] = align_sum
    swarm.partial[w, c, _P_ALIGN_COUNT] = align_count


@wp.func
def circular_mean(cos_sum: float, sin_sum: float, length: float) -> float:
    """Circular mean (px in [0, length)) of coordinates given by the sums of cos and sin of their angles
    2 pi x / length; 0 where the sums vanish (no preferred position)."""
    return wrap_coordinate(wp.atan2(sin_sum, cos_sum) * length / TWO_PI, length)


@wp.kernel
def finish_prey_sums(world: WorldParams, counters: WorldCounters, outputs: StepOutputs, swarm: SwarmArrays):
    """Second stage per world `w`: sums the chunks in order and writes every column of `swarm.values[w]`
    except COHESION. Undefined means (no live prey; fewer than two for NN_MEAN; no predator for
    PREDATOR_DISTANCE) are NaN."""
    w = wp.tid()
    n = float(0.0)
    head_x = float(0.0)
    head_y = float(0.0)
    cos_x = float(0.0)
    sin_x = float(0.0)
    cos_y = float(0.0)
    sin_y = float(0.0)
    nn_sum = float(0.0)
    nn_count = float(0.0)
    pred_sum = float(0.0)
    pred_count = float(0.0)
    largest = float(0.0)
    groups = float(0.0)
    align_sum = float(0.0)
    align_count = float(0.0)
    for c in range(swarm.partial.shape[1]):
        n += swarm.partial[w, c, _P_COUNT]
        head_x += swarm.partial[w, c, _P_HEAD_X]
        head_y += swarm.partial[w, c, _P_HEAD_Y]
        cos_x += swarm.partial[w, c, _P_COS_X]
        sin_x += swarm.partial[w, c, _P_SIN_X]
        cos_y += swarm.partial[w, c, _P_COS_Y]
        sin_y += swarm.partial[w, c, _P_SIN_Y]
        nn_sum += swarm.partial[w, c, _P_NN_SUM]
        nn_count += swarm.partial[w, c, _P_NN_COUNT]
        pred_sum += swarm.partial[w, c, _P_PRED_SUM]
        pred_count += swarm.partial[w, c, _P_PRED_COUNT]
        largest = wp.max(largest, swarm.partial[w, c, _P_LARGEST])
        groups += swarm.partial[w, c, _P_ROOTS]
        align_sum += swarm.partial[w, c, _P_ALIGN_SUM]
        align_count += swarm.partial[w, c, _P_ALIGN_COUNT]
    nan = wp.nan
    swarm.values[w, GROUPS] = groups
    swarm.values[w, PREY_ALIVE] = n
    swarm.values[w, PREDATOR_ALIVE] = float(counters.predator_alive_count[w])
    swarm.values[w, CAPTURES] = float(outputs.captures[w])
    if n > 0.0:
        swarm.values[w, POLARIZATION] = wp.length(wp.vec2(head_x, head_y)) / n
        swarm.values[w, CENTROID_X] = circular_mean(cos_x, sin_x, world.width)
        swarm.values[w, CENTROID_Y] = circular_mean(cos_y, sin_y, world.height)
        swarm.values[w, LARGEST_GROUP] = largest / n
    else:
        swarm.values[w, POLARIZATION] = nan
        swarm.values[w, CENTROID_X] = nan
        swarm.values[w, CENTROID_Y] = nan
        swarm.values[w, LARGEST_GROUP] = nan
    swarm.values[w, NN_MEAN] = nan
    if nn_count > 0.0:
        swarm.values[w, NN_MEAN] = nn_sum / nn_count
    swarm.values[w, PREDATOR_DISTANCE] = nan
    if pred_count > 0.0:
        swarm.values[w, PREDATOR_DISTANCE] = pred_sum / pred_count
    swarm.values[w, LOCAL_ALIGNMENT] = nan
    if align_count > 0.0:
        swarm.values[w, LOCAL_ALIGNMENT] = align_sum / align_count


@wp.kernel
def centroid_partial_sums(world: WorldParams, agents: Agents, swarm: SwarmArrays):
    """First stage of the cohesion and milling sums: chunk `c` of world `w` sums the torus distances (px)
    of its live prey to the centroid in `swarm.values[w]` into `swarm.partial[w, c, 0]`, and their
    (r / |r|) x heading into `swarm.partial[w, c, 1]`."""
    w, c = wp.tid()
    total = float(0.0)
    turn = float(0.0)
    if swarm.values[w, PREY_ALIVE] > 0.0:
        centroid = wp.vec2(swarm.values[w, CENTROID_X], swarm.values[w, CENTROID_Y])
        end = wp.min(c * CHUNK + CHUNK, world.prey_capacity)
        for i in range(c * CHUNK, end):
            if agents.alive[w, i]:
                r = torus_displacement(world, centroid, agents.position[w, i])
                distance = wp.length(r)
                total += distance
                if distance > 0.0:
                    h = agents.heading[w, i]
                    turn += (r[0] * h[1] - r[1] * h[0]) / distance
    swarm.partial[w, c, 0] = total
    swarm.partial[w, c, 1] = turn


@wp.kernel
def finish_cohesion(swarm: SwarmArrays):
    """Second stage per world: `swarm.values[w, COHESION]` = mean distance to the centroid and
    `swarm.values[w, MILLING]` (NaN without prey)."""
    w = wp.tid()
    n = swarm.values[w, PREY_ALIVE]
    if n > 0.0:
        total = float(0.0)
        turn = float(0.0)
        for c in range(swarm.partial.shape[1]):
            total += swarm.partial[w, c, 0]
            turn += swarm.partial[w, c, 1]
        swarm.values[w, COHESION] = total / n
        swarm.values[w, MILLING] = wp.abs(turn) / n
    else:
        swarm.values[w, COHESION] = wp.nan
        swarm.values[w, MILLING] = wp.nan


@wp.kernel
def close_episodes(
    ended: wp.array(dtype=wp.bool),
    ended_captures: wp.array(dtype=wp.int32),
    ended_length: wp.array(dtype=wp.int32),
    sums: wp.array2d(dtype=wp.float64),
    counts: wp.array2d(dtype=wp.float64),
    hist: wp.array2d(dtype=wp.float64),
    done_sum: wp.array2d(dtype=wp.float64),
    done_count: wp.array2d(dtype=wp.float64),
    done_hist: wp.array2d(dtype=wp.float64),
    done_captures: wp.array(dtype=wp.float64),
    done_length: wp.array(dtype=wp.float64),
    episodes: wp.array(dtype=wp.float64),
    ended_values: wp.array2d(dtype=wp.float64),
):
    """One world per thread (`aquarium_warp.metrics.EpisodeMetrics.close_episodes`): where its episode
    ended, the episode's value of each metric (the mean of its samples; NaN without any) into
    `ended_values` and, if it has samples, the completed totals; its nearest-neighbour histogram,
    normalised, into the completed histogram; its captures and length; then the current episode's
    sums cleared. Elsewhere `ended_values` is NaN and nothing else changes."""
    w = wp.tid()
    nan = wp.float64(wp.nan)
    if not ended[w]:
        for k in range(sums.shape[1]):
            ended_values[w, k] = nan
        return
    for k in range(sums.shape[1]):
        mean = sums[w, k] / counts[w, k]  # 0 / 0: NaN, no sample
        ended_values[w, k] = mean
        if counts[w, k] > wp.float64(0.0):
            done_sum[w, k] = done_sum[w, k] + mean
            done_count[w, k] = done_count[w, k] + wp.float64(1.0)
        sums[w, k] = wp.float64(0.0)
        counts[w, k] = wp.float64(0.0)
    total = wp.float64(0.0)
    for b in range(hist.shape[1]):
        total = total + hist[w, b]
    for b in range(hist.shape[1]):
        if total > wp.float64(0.0):
            done_hist[w, b] = done_hist[w, b] + hist[w, b] / total
        hist[w, b] = wp.float64(0.0)
    done_captures[w] = done_captures[w] + wp.float64(ended_captures[w])
    done_length[w] = done_length[w] + wp.float64(ended_length[w])
    episodes[w] = episodes[w] + wp.float64(1.0)
