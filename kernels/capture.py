"""MODEL.md steps 5 and 6: captures after the move, reward sharing, starvation, respawn or removal.

Four passes keep every sum deterministic (no float atomics): predators mark the prey they overlap;
each captured prey counts its sharers and takes the penalty; each predator sums its shares over the
captured prey near it (in the grid's fixed order), resets its starvation counter if it captured,
then starves by one step; captured prey respawn or are removed last, so the passes before all see
the positions of the capture.

The passes search the cell lists of the start-of-step positions (built by the last observation
pass), not cell lists of the moved ones: every agent moved by at most its max speed since, so a
search radius widened by the max speeds (`start_of_step_radius`) finds every pair that is within
the capture or share radius now, and the exact test uses the moved positions. This saves a second
cell-list build per step. (Whole-world lists hold every slot of the world, so there the widening
changes nothing.)
"""

import warp as wp

from .common import PREDATOR, PREY, PURPOSE_RESPAWN, AgentType, WorldParams, random_stream, slot_type, torus_displacement
from .grid import (CellLists, cell_coords, listed_slot, rings_for_radius, row_run_entries, run_entry, run_length,
                   square_extent)
from .spawn import make_fresh_prey, uniform_position

wp.set_module_options({"enable_backward": False})


@wp.func
def start_of_step_radius(world: WorldParams, radius: float, moved: float) -> float:
    """Radius around a moved position that holds, at their start-of-step positions, every agent now
    within `radius` of it, when they moved by at most `moved` px (plus float rounding of the
    clamped speeds and of the wrap)."""
    return radius + moved * (1.0 + 1.0e-5) + 1.0e-6 * (world.width + world.height)


# Threads per predator in `detect_captures` on cell lists, each taking every CAPTURE_ROW_THREADS-th
# row of the predator's search square (3 rows at the default sizes): predators are few, so one thread
# each would leave most of a GPU idle while they wait on their candidates' positions. (H200, one world
# of 1M agents: 0.032 -> 0.024 ms.) Whole-world lists are one row: one thread per predator.
CAPTURE_ROW_THREADS = 3


@wp.kernel
def detect_captures(
    world: WorldParams,
    types: wp.array(dtype=AgentType),
    grid: CellLists,
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    row_threads: int,
    captured: wp.array2d(dtype=wp.bool),
):
    """Predators mark the prey they overlap, launched with `(worlds, predators, row_threads)` threads,
    each taking every `row_threads`-th row of the search (concurrent writes of True to one flag agree,
    so the rows need no combining)."""
    w, p, row_thread = wp.tid()  # predator slots only
    i = world.prey_capacity + p
    if not alive[w, i]:
        return
    pos = position[w, i]
    contact = types[PREY].radius + types[PREDATOR].radius
    center = cell_coords(grid, pos)
    base = w * world.capacity
    box = square_extent(grid, rings_for_radius(grid, start_of_step_radius(world, contact, types[PREY].max_speed)))
    for oy in range(box[2] + row_thread, box[3] + 1, row_threads):
        runs = row_run_entries(grid, w, center, oy, box[0], box[1])
        for n in range(run_length(runs)):
            k2 = run_entry(runs, n)
            j = listed_slot(grid, k2, base)
            if j >= 0 and slot_type(world, j) == PREY:
                d = torus_displacement(world, pos, position[w, j])
                if wp.dot(d, d) < contact * contact:
                    captured[w, j] = True


@wp.kernel
def count_capture_sharers(
    world: WorldParams,
    types: wp.array(dtype=AgentType),
    grid: CellLists,
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    captured: wp.array2d(dtype=wp.bool),
    age: wp.array2d(dtype=wp.int32),
    share_count: wp.array2d(dtype=wp.int32),
    reward: wp.array2d(dtype=float),
    captures: wp.array(dtype=wp.int32),
):
    """Each captured prey counts its sharers and takes the penalty; the other live prey age by one."""
    w, i = wp.tid()  # prey slots only
    if not alive[w, i]:
        return
    if not captured[w, i]:
        age[w, i] = age[w, i] + 1
        return
    pos = position[w, i]
    contact = types[PREY].radius + types[PREDATOR].radius
    share = wp.max(world.catch_share_radius, contact)
    sharers = int(0)
    center = cell_coords(grid, pos)
    base = w * world.capacity
    box = square_extent(grid, rings_for_radius(grid, start_of_step_radius(world, share, types[PREDATOR].max_speed)))
    for oy in range(box[2], box[3] + 1):
        runs = row_run_entries(grid, w, center, oy, box[0], box[1])
        for n in range(run_length(runs)):
            k2 = run_entry(runs, n)
            j = listed_slot(grid, k2, base)
            if j >= 0 and slot_type(world, j) == PREDATOR:
                d = torus_displacement(world, pos, position[w, j])
                d2 = wp.dot(d, d)
                if d2 < contact * contact or d2 < world.catch_share_radius * world.catch_share_radius:
                    sharers += 1
    share_count[w, i] = sharers
    reward[w, i] = -world.prey_capture_penalty
    wp.atomic_add(captures, w, 1)


@wp.kernel
def share_capture_rewards(
    world: WorldParams,
    types: wp.array(dtype=AgentType),
    grid: CellLists,
    position: wp.array2d(dtype=wp.vec2),
    captured: wp.array2d(dtype=wp.bool),
    share_count: wp.array2d(dtype=wp.int32),
    alive: wp.array2d(dtype=wp.bool),
    reward: wp.array2d(dtype=float),
    starvation: wp.array2d(dtype=wp.int32),
    terminated: wp.array2d(dtype=wp.bool),
    predator_alive_count: wp.array(dtype=wp.int32),
):
    """Each predator sums its shares of this step's captures; then MODEL.md step 6: a capture resets
    its steps-since-last-capture counter, which then grows by one; past the limit it dies."""
    w, p = wp.tid()  # predator slots only
    i = world.prey_capacity + p
    if not alive[w, i]:
        return
    pos = position[w, i]
    contact = types[PREY].radius + types[PREDATOR].radius
    share = wp.max(world.catch_share_radius, contact)
    total = float(0.0)
    is_capturer = bool(False)
    center = cell_coords(grid, pos)
    base = w * world.capacity
    box = square_extent(grid, rings_for_radius(grid, start_of_step_radius(world, share, types[PREY].max_speed)))
    for oy in range(box[2], box[3] + 1):
        runs = row_run_entries(grid, w, center, oy, box[0], box[1])
        for n in range(run_length(runs)):
            k2 = run_entry(runs, n)
            j = listed_slot(grid, k2, base)
            if j >= 0 and slot_type(world, j) == PREY:
                if captured[w, j]:
                    d = torus_displacement(world, pos, position[w, j])
                    d2 = wp.dot(d, d)
                    inside_share = d2 < world.catch_share_radius * world.catch_share_radius
                    if d2 < contact * contact:
                        is_capturer = True
                    if inside_share or d2 < contact * contact:
                        total += world.predator_reward / float(share_count[w, j])
    reward[w, i] = total
    hunger = starvation[w, i] + 1
    if is_capturer:
        hunger = 1
    starvation[w, i] = hunger
    if hunger > world.predator_starvation_steps:
        alive[w, i] = False
        terminated[w, i] = True
        wp.atomic_add(predator_alive_count, w, -1)


@wp.kernel
def respawn_captured_prey(
    world: WorldParams,
    world_step: wp.array(dtype=wp.int32),
    episode: wp.array(dtype=wp.int32),
    captured: wp.array2d(dtype=wp.bool),
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
    terminated: wp.array2d(dtype=wp.bool),
    prey_alive_count: wp.array(dtype=wp.int32),
):
    """A captured prey reappears as a fresh prey at a uniform position, or is removed and terminated."""
    w, i = wp.tid()  # prey slots only
    if not captured[w, i]:
        return
    if world.respawn_captured_prey != 0:
        rng = random_stream(world.seed, world.world_offset + w, episode[w], world_step[w] + 1, i, PURPOSE_RESPAWN)
        make_fresh_prey(world, w, i, uniform_position(world, rng, 0.0), rng, alive, position, velocity,
                        acceleration, heading, age, replication_age, starvation)
    else:
        alive[w, i] = False
        terminated[w, i] = True
        wp.atomic_add(prey_alive_count, w, -1)
