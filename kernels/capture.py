"""MODEL.md step 5: captures after the move, reward sharing, respawn or removal of captured prey.

Two passes keep every sum deterministic (no float atomics): the prey pass decides captures and counts
each capture's sharers; the predator pass sums its shares over the captured prey it is near, in the
grid's fixed order. Both read positions from cell lists built after the move, so the prey pass can
respawn a captured prey in place without the predator pass seeing the new position.
"""

import warp as wp

from .common import PREDATOR, PREY, PURPOSE_RESPAWN, AgentType, WorldParams, random_stream, slot_type, torus_displacement
from .grid import CellLists, cell_coords, ring_cell, ring_size, rings_for_radius
from .spawn import make_fresh_prey, uniform_position

wp.set_module_options({"enable_backward": False})


@wp.kernel
def detect_captures(
    world: WorldParams,
    types: wp.array(dtype=AgentType),
    grid: CellLists,
    world_step: wp.array(dtype=wp.int32),
    episode: wp.array(dtype=wp.int32),
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
    captured: wp.array2d(dtype=wp.bool),
    share_count: wp.array2d(dtype=wp.int32),
    reward: wp.array2d(dtype=float),
    terminated: wp.array2d(dtype=wp.bool),
    captures: wp.array(dtype=wp.int32),
    prey_alive_count: wp.array(dtype=wp.int32),
):
    w, i = wp.tid()  # prey slots only
    if not alive[w, i]:
        return
    pos = position[w, i]
    contact = types[PREY].radius + types[PREDATOR].radius
    share = wp.max(world.catch_share_radius, contact)
    is_captured = bool(False)
    sharers = int(0)
    center = cell_coords(grid, pos)
    base = w * world.capacity
    for r in range(rings_for_radius(grid, share) + 1):
        for q in range(ring_size(r)):
            c = ring_cell(grid, w, center, r, q)
            if c >= 0:
                for k2 in range(grid.cell_start[c], grid.cell_end[c]):
                    j = grid.agent[k2] - base
                    if slot_type(world, j) == PREDATOR:
                        d = torus_displacement(world, pos, grid.position[k2])
                        d2 = wp.dot(d, d)
                        if d2 < contact * contact:
                            is_captured = True
                            sharers += 1
                        elif d2 < world.catch_share_radius * world.catch_share_radius:
                            sharers += 1
    if not is_captured:
        age[w, i] = age[w, i] + 1
        return
    captured[w, i] = True
    share_count[w, i] = sharers
    reward[w, i] = -world.prey_capture_penalty
    wp.atomic_add(captures, w, 1)
    if world.respawn_captured_prey != 0:
        rng = random_stream(world.seed, w, episode[w], world_step[w] + 1, i, PURPOSE_RESPAWN)
        make_fresh_prey(world, w, i, uniform_position(world, rng, 0.0), rng, alive, position, velocity,
                        acceleration, heading, age, replication_age, starvation)
    else:
        alive[w, i] = False
        terminated[w, i] = True
        wp.atomic_add(prey_alive_count, w, -1)


@wp.kernel
def share_capture_rewards(
    world: WorldParams,
    types: wp.array(dtype=AgentType),
    grid: CellLists,
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    captured: wp.array2d(dtype=wp.bool),
    share_count: wp.array2d(dtype=wp.int32),
    reward: wp.array2d(dtype=float),
    starvation: wp.array2d(dtype=wp.int32),
):
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
    for r in range(rings_for_radius(grid, share) + 1):
        for q in range(ring_size(r)):
            c = ring_cell(grid, w, center, r, q)
            if c >= 0:
                for k2 in range(grid.cell_start[c], grid.cell_end[c]):
                    j = grid.agent[k2] - base
                    if slot_type(world, j) == PREY:
                        if captured[w, j]:
                            d = torus_displacement(world, pos, grid.position[k2])
                            d2 = wp.dot(d, d)
                            inside_share = d2 < world.catch_share_radius * world.catch_share_radius
                            if d2 < contact * contact:
                                is_capturer = True
                            if inside_share or d2 < contact * contact:
                                total += world.predator_reward / float(share_count[w, j])
    reward[w, i] = total
    if is_capturer:
        starvation[w, i] = 0
