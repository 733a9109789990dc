"""Swarm metrics of every world on the device: polarization, local alignment, milling, cohesion,
nearest-neighbour distances, groups (connected components), distance to the nearest predator,
populations; and the groups' measures: sizes, per-group order, identities across calls, the
nearest-neighbour ratios to their nulls and the share of prey with a capture-confusion neighbour.

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
group sizes) use integer atomics, whose result does not depend on the order. The groups' passes
(`track_groups`, `finish_groups`) take one thread per world and walk its slots in order (integer
bookkeeping, O(prey capacity)); `group_order` takes one thread per group and sums its members in
slot order.

Launch order per shard (see `aquarium_warp.metrics.SwarmMetrics`): zero the integer counters,
`prey_distances`, `link_groups`, `local_alignment`, `resolve_groups`, `prey_partial_sums`,
`finish_prey_sums`, `centroid_partial_sums`, `finish_cohesion`, `track_groups`, `group_order`,
`finish_groups`.
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
# The groups' measures (`finish_groups` and `track_groups`; "measured groups": at least `min_group_size` prey).
MEAN_GROUP_SIZE = wp.constant(13)  # live prey / groups
GROUPED_SHARE = wp.constant(14)  # share of live prey in groups of >= 2 (with a linked neighbour)
MEASURED_SHARE = wp.constant(15)  # share of live prey in measured groups
GROUP_POLARIZATION = wp.constant(16)  # member-weighted mean over measured groups of |mean unit heading|
GROUP_ROTATION = wp.constant(17)  # the same of |mean (r / |r|) x heading|, r from the group's centroid
GROUP_SPEED = wp.constant(18)  # the same of |mean velocity|, px/step
GROUP_AGE = wp.constant(19)  # member-weighted mean age (steps) of the measured groups
GROUPS_ENDED = wp.constant(20)  # tracked groups that ended since the previous state
ENDED_LIFETIME_TOTAL = wp.constant(21)  # their lifetimes summed, steps
NN_RATIO_POINT = wp.constant(22)  # NN_MEAN / the expected one of uniform points
NN_RATIO_HARD_DISK = wp.constant(23)  # NN_MEAN / the expected one of non-overlapping disks
CONFUSION_NEIGHBOUR_SHARE = wp.constant(24)  # share of live prey with another within confusion_radius
NUM_VALUES = wp.constant(25)
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
    "mean_group_size",
    "grouped_share",
    "measured_share",
    "group_polarization",
    "group_rotation",
    "group_speed",
    "group_age",
    "groups_ended",
    "ended_lifetime_total",
    "nn_ratio_point",
    "nn_ratio_hard_disk",
    "confusion_neighbour_share",
)
# The first columns, the swarm's measures; the rest, the groups' (`aquarium_warp.metrics.GROUP_METRICS`).
NUM_SWARM_VALUES = 13

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
    confusion_neighbour: wp.array2d(dtype=wp.bool)
    """[W, Pc] bool, another live prey is strictly within `confusion_radius` (k >= 1 of the capture rule)."""
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
    and to the nearest live predator (-1 where there is none, or the slot is dead), and whether that
    prey is strictly within the world's `confusion_radius` (`confusion_neighbour`); the nearest-prey
    distance is counted in `nn_histogram[w, bin]` (bin = floor(d / bin_width), the last bin also
    holds everything beyond). Also starts the union-find: `parent[w * prey_capacity + i] = i`.
    `predators_by_grid` 1: ring search for the nearest predator, 0: loop over the predator slots.
    `grid` must hold the cell lists of `agents.position`; `nn_histogram` must be zero."""
    w, i = wp.tid()
    swarm.parent[w * world.prey_capacity + i] = wp.int32(i)
    swarm.confusion_neighbour[w, i] = False
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
        confusion_radius = world.values[w].confusion_radius
        swarm.confusion_neighbour[w, i] = prey_d2 < confusion_radius * confusion_radius  # as capture.confusing_prey
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


@wp.struct
class GroupArrays:
    """The groups' device buffers (allocated by `aquarium_warp.metrics.SwarmMetrics`). Groups are indexed
    by their label (root slot). "Last" is the state of the last call, "before" the one before it (the
    predecessor state, whose groups the current ones continue)."""

    members: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, the live prey slots by group label, then slot (a group's members are contiguous)."""
    group_start: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, index in `members` of the root's first member (valid at roots)."""
    size_counts: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, groups of s members at column s - 1."""
    order: wp.array3d(dtype=float)
    """[W, Pc, 3] float32, per measured group's root: polarization, rotation, speed (px/step)."""
    votes: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32 scratch: members of the current group from each predecessor group (zero between
    uses); also the filling cursor of `members`."""
    predecessor: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, per current root: the predecessor group that holds a majority of its members, or -1."""
    claim_votes: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, per predecessor root: the most members it gave a current group that it is the
    majority of; `claim_group`: that group (the lower label on ties), or -1."""
    claim_group: wp.array2d(dtype=wp.int32)
    last_time: wp.array2d(dtype=wp.int32)
    """[W, 3] int32: (1 if set, episode, world_step) of the last call's state; `before_time`: its
    predecessor's."""
    before_time: wp.array2d(dtype=wp.int32)
    last_label: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, the measured groups' labels at the last call's state (-1: dead or in a smaller
    group); `before_label`: at its predecessor."""
    before_label: wp.array2d(dtype=wp.int32)
    last_birth: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, per measured root: the world step at which the group was first seen; `before_birth`:
    at the predecessor."""
    before_birth: wp.array2d(dtype=wp.int32)
    point_null: wp.array2d(dtype=float)
    """[W, Pc + 1] float32, px: expected mean nearest-neighbour distance of n uniform points (`nulls.py`),
    NaN for n < 2; `hard_disk_null`: of n non-overlapping prey hit boxes."""
    hard_disk_null: wp.array2d(dtype=float)


@wp.kernel
def track_groups(
    world: WorldParams,
    agents: Agents,
    counters: WorldCounters,
    min_group_size: int,
    swarm: SwarmArrays,
    groups: GroupArrays,
):
    """One thread per world `w`, in slot order (integer work only, so deterministic): the member lists,
    the groups per size, and each measured group's identity across calls (`aquarium_warp.metrics`
    defines it).

    The predecessor state is the last call's, unless this is the same state again (the same episode
    and step), which is then measured against the same predecessor as before: calls are idempotent.
    It links to the current state only within the same episode and at an earlier or equal step. A
    prey continues its predecessor slot if it was live there and its age grew by the steps between
    (a respawned or newborn prey restarts at age 0). Writes GROUPED_SHARE, MEASURED_SHARE, GROUP_AGE,
    GROUPS_ENDED and ENDED_LIFETIME_TOTAL of `swarm.values[w]`; `resolve_groups` must have run."""
    w = wp.tid()
    capacity = world.prey_capacity
    episode = counters.episode[w]
    step = counters.world_step[w]
    last = groups.last_time
    if not (last[w, 0] != 0 and last[w, 1] == episode and last[w, 2] == step):
        for k in range(3):
            groups.before_time[w, k] = last[w, k]
        for i in range(capacity):
            groups.before_label[w, i] = groups.last_label[w, i]
            groups.before_birth[w, i] = groups.last_birth[w, i]
    before_step = groups.before_time[w, 2]
    linked = groups.before_time[w, 0] != 0 and groups.before_time[w, 1] == episode and before_step <= step
    elapsed = step - before_step

    # Member lists: roots' offsets in slot order, then each member in slot order.
    offset = int(0)
    for i in range(capacity):
        groups.claim_votes[w, i] = 0
        groups.claim_group[w, i] = -1
        groups.size_counts[w, i] = 0
        groups.votes[w, i] = 0
        if swarm.group_label[w, i] == i:
            groups.group_start[w, i] = offset
            offset += int(swarm.group_size[w, i])
    for i in range(capacity):
        root = int(swarm.group_label[w, i])
        if root >= 0:
            groups.members[w, groups.group_start[w, root] + groups.votes[w, root]] = wp.int32(i)
            groups.votes[w, root] = groups.votes[w, root] + 1
    for i in range(capacity):
        groups.votes[w, i] = 0

    # Each measured group's predecessor: the previous measured group holding a strict majority of its
    # members; a previous group is continued by the group that took most of its members (ties: the
    # lower label).
    for g in range(capacity):
        if swarm.group_label[w, g] == g and int(swarm.group_size[w, g]) >= min_group_size:
            size = int(swarm.group_size[w, g])
            start = int(groups.group_start[w, g])
            best = int(-1)
            best_votes = int(0)
            if linked:
                for k in range(start, start + size):
                    j = int(groups.members[w, k])
                    p = int(groups.before_label[w, j])
                    if p >= 0 and agents.age[w, j] >= elapsed:
                        v = groups.votes[w, p] + 1
                        groups.votes[w, p] = v
                        if v > best_votes:
                            best_votes = v
                            best = p
                for k in range(start, start + size):
                    p = int(groups.before_label[w, groups.members[w, k]])
                    if p >= 0:
                        groups.votes[w, p] = 0
            groups.predecessor[w, g] = -1
            if 2 * best_votes > size:
                groups.predecessor[w, g] = wp.int32(best)
                if best_votes > groups.claim_votes[w, best]:
                    groups.claim_votes[w, best] = wp.int32(best_votes)
                    groups.claim_group[w, best] = wp.int32(g)

    # Sizes, and births and ages of the measured groups (ages and shares summed in slot order).
    n = int(0)
    grouped = int(0)
    measured = int(0)
    age_sum = wp.float64(0.0)
    for g in range(capacity):
        if swarm.group_label[w, g] == g:
            size = int(swarm.group_size[w, g])
            groups.size_counts[w, size - 1] = groups.size_counts[w, size - 1] + 1
            n += size
            if size >= 2:
                grouped += size
            if size >= min_group_size:
                p = int(groups.predecessor[w, g])
                birth = step
                if p >= 0:
                    if groups.claim_group[w, p] == g:
                        birth = int(groups.before_birth[w, p])
                groups.last_birth[w, g] = wp.int32(birth)
                measured += size
                age_sum += wp.float64(size) * wp.float64(step - birth)
    # The predecessor's measured groups that nobody continues ended.
    ended = int(0)
    lifetimes = wp.float64(0.0)
    if linked:
        for p in range(capacity):
            if groups.before_label[w, p] == p and groups.claim_group[w, p] < 0:
                ended += 1
                lifetimes += wp.float64(before_step - groups.before_birth[w, p])
    for i in range(capacity):
        root = int(swarm.group_label[w, i])
        groups.last_label[w, i] = -1
        if root >= 0:
            if int(swarm.group_size[w, root]) >= min_group_size:
                groups.last_label[w, i] = wp.int32(root)
    last[w, 0] = 1
    last[w, 1] = episode
    last[w, 2] = step

    nan = wp.nan
    swarm.values[w, GROUPED_SHARE] = nan
    swarm.values[w, MEASURED_SHARE] = nan
    if n > 0:
        swarm.values[w, GROUPED_SHARE] = float(grouped) / float(n)
        swarm.values[w, MEASURED_SHARE] = float(measured) / float(n)
    swarm.values[w, GROUP_AGE] = nan
    if measured > 0:
        swarm.values[w, GROUP_AGE] = float(age_sum / wp.float64(measured))
    swarm.values[w, GROUPS_ENDED] = float(ended)
    swarm.values[w, ENDED_LIFETIME_TOTAL] = float(lifetimes)


@wp.kernel
def group_order(world: WorldParams, agents: Agents, min_group_size: int, swarm: SwarmArrays, groups: GroupArrays):
    """Per prey slot `(w, g)` that is the root of a group of at least `min_group_size` members: its
    polarization |mean unit heading|, rotation |mean (r / |r|) x heading| (r the member's torus offset
    from the group's centroid, a circular mean per axis as for the swarm's) and speed |mean velocity|
    (px/step) into `groups.order[w, g]`, summed over the members in slot order."""
    w, g = wp.tid()
    if swarm.group_label[w, g] != g:
        return
    size = int(swarm.group_size[w, g])
    if size < min_group_size:
        return
    start = int(groups.group_start[w, g])
    head = wp.vec2(0.0, 0.0)
    velocity = wp.vec2(0.0, 0.0)
    cos_x = float(0.0)
    sin_x = float(0.0)
    cos_y = float(0.0)
    sin_y = float(0.0)
    for k in range(start, start + size):
        j = int(groups.members[w, k])
        head = head + agents.heading[w, j]
        velocity = velocity + agents.velocity[w, j]
        p = agents.position[w, j]
        ax = TWO_PI * p[0] / world.width
        ay = TWO_PI * p[1] / world.height
        cos_x += wp.cos(ax)
        sin_x += wp.sin(ax)
        cos_y += wp.cos(ay)
        sin_y += wp.sin(ay)
    centroid = wp.vec2(circular_mean(cos_x, sin_x, world.width), circular_mean(cos_y, sin_y, world.height))
    turn = float(0.0)
    for k in range(start, start + size):
        j = int(groups.members[w, k])
        r = torus_displacement(world, centroid, agents.position[w, j])
        distance = wp.length(r)
        if distance > 0.0:
            h = agents.heading[w, j]
            turn += (r[0] * h[1] - r[1] * h[0]) / distance
    m = float(size)
    groups.order[w, g, 0] = wp.length(head) / m
    groups.order[w, g, 1] = wp.abs(turn) / m
    groups.order[w, g, 2] = wp.length(velocity) / m


@wp.kernel
def finish_groups(world: WorldParams, agents: Agents, min_group_size: int, swarm: SwarmArrays, groups: GroupArrays):
    """Per world `w`, in slot order: MEAN_GROUP_SIZE, the member-weighted means of `groups.order` over
    the measured groups (GROUP_POLARIZATION, GROUP_ROTATION, GROUP_SPEED; NaN without one),
    CONFUSION_NEIGHBOUR_SHARE and the nearest-neighbour ratios (NaN where undefined); after
    `finish_prey_sums` and `group_order`."""
    w = wp.tid()
    polarization = float(0.0)
    rotation = float(0.0)
    speed = float(0.0)
    weight = float(0.0)
    neighboured = float(0.0)
    for i in range(world.prey_capacity):
        if agents.alive[w, i]:
            if swarm.confusion_neighbour[w, i]:
                neighboured += 1.0
            if swarm.group_label[w, i] == i and int(swarm.group_size[w, i]) >= min_group_size:
                m = float(swarm.group_size[w, i])
                polarization += m * groups.order[w, i, 0]
                rotation += m * groups.order[w, i, 1]
                speed += m * groups.order[w, i, 2]
                weight += m
    nan = wp.nan
    n = swarm.values[w, PREY_ALIVE]
    swarm.values[w, MEAN_GROUP_SIZE] = nan
    swarm.values[w, CONFUSION_NEIGHBOUR_SHARE] = nan
    if n > 0.0:
        swarm.values[w, MEAN_GROUP_SIZE] = n / swarm.values[w, GROUPS]
        swarm.values[w, CONFUSION_NEIGHBOUR_SHARE] = neighboured / n
    swarm.values[w, GROUP_POLARIZATION] = nan
    swarm.values[w, GROUP_ROTATION] = nan
    swarm.values[w, GROUP_SPEED] = nan
    if weight > 0.0:
        swarm.values[w, GROUP_POLARIZATION] = polarization / weight
        swarm.values[w, GROUP_ROTATION] = rotation / weight
        swarm.values[w, GROUP_SPEED] = speed / weight
    count = int(n)  # NaN tables at n < 2 and past the hard-disk null's reach
    nn_mean = swarm.values[w, NN_MEAN]
    swarm.values[w, NN_RATIO_POINT] = nn_mean / groups.point_null[w, count]
    swarm.values[w, NN_RATIO_HARD_DISK] = nn_mean / groups.hard_disk_null[w, count]


@wp.func
def close_histogram(hist: wp.array2d(dtype=wp.float64), done_hist: wp.array2d(dtype=wp.float64), w: int):
    """World w's episode histogram, normalised, added to the completed one (if it counted anything); then
    cleared."""
    total = wp.float64(0.0)
    for b in range(hist.shape[1]):
        total = total + hist[w, b]
    for b in range(hist.shape[1]):
        if total > wp.float64(0.0):
            done_hist[w, b] = done_hist[w, b] + hist[w, b] / total
        hist[w, b] = wp.float64(0.0)


@wp.kernel
def close_episodes(
    ended: wp.array(dtype=wp.bool),
    ended_captures: wp.array(dtype=wp.int32),
    ended_length: wp.array(dtype=wp.int32),
    sums: wp.array2d(dtype=wp.float64),
    counts: wp.array2d(dtype=wp.float64),
    hist: wp.array2d(dtype=wp.float64),
    group_hist: wp.array2d(dtype=wp.float64),
    done_sum: wp.array2d(dtype=wp.float64),
    done_count: wp.array2d(dtype=wp.float64),
    done_hist: wp.array2d(dtype=wp.float64),
    done_group_hist: wp.array2d(dtype=wp.float64),
    done_captures: wp.array(dtype=wp.float64),
    done_length: wp.array(dtype=wp.float64),
    episodes: wp.array(dtype=wp.float64),
    ended_values: wp.array2d(dtype=wp.float64),
):
    """One world per thread (`aquarium_warp.metrics.EpisodeMetrics.close_episodes`): where its episode
    ended, the episode's value of each metric (the mean of its samples; NaN without any) into
    `ended_values` and, if it has samples, the completed totals; its nearest-neighbour and group-size
    histograms, normalised, into the completed ones; its captures and length; then the current
    episode's sums cleared. Elsewhere `ended_values` is NaN and nothing else changes."""
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
    close_histogram(hist, done_hist, w)
    close_histogram(group_hist, done_group_hist, w)
    done_captures[w] = done_captures[w] + wp.float64(ended_captures[w])
    done_length[w] = done_length[w] + wp.float64(ended_length[w])
    episodes[w] = episodes[w] + wp.float64(1.0)
