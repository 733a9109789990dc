"""MODEL.md steps 1-4: steering, acceleration with memory, same-type contact, speed clamp, wrap.

All agents read the start-of-step state: neighbour positions come from the cell lists (built on the
start-of-step positions), and each thread writes only its own slot.
"""

import warp as wp

from .common import PREY, AgentType, WorldParams, action_direction, slot_type, torus_displacement, wrap_coordinate
from .grid import CellLists, cell_coords, ring_cell, ring_size, rings_for_radius

wp.set_module_options({"enable_backward": False})


@wp.func
def clamp_length(v: wp.vec2, limit: float) -> wp.vec2:
    n = wp.length(v)
    if n > limit:
        return v * (limit / n)
    return v


@wp.kernel
def integrate_motion(
    world: WorldParams,
    types: wp.array(dtype=AgentType),
    grid: CellLists,
    prey_action: wp.array2d(dtype=wp.int32),
    predator_action: wp.array2d(dtype=wp.int32),
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
):
    k = wp.tid()  # sorted entry: neighbours of consecutive threads share cells
    idx = grid.agent[k]
    w = idx // world.capacity
    i = idx - w * world.capacity
    if not alive[w, i]:
        return
    t = slot_type(world, i)
    p = types[t]

    # 1. Steering towards the action's desired velocity (paper eqs. 1 and 6).
    action = int(0)
    if t == PREY:
        action = int(prey_action[w, i])
    else:
        action = int(predator_action[w, i - world.prey_capacity])
    desired = action_direction(action, world.action_count) * p.max_speed
    v = velocity[w, i]
    steering_force = clamp_length(desired - v, p.max_steering_force)

    # 2. Acceleration with memory: the running sum is renormalised to k (paper eq. 2).
    acc = acceleration[w, i] + steering_force / p.mass
    if acc[0] != 0.0 or acc[1] != 0.0:
        acc = acc * (p.max_acceleration / wp.length(acc))

    # 3. Same-type contact: the nearest overlapping agent of the same type pushes this one away.
    pos = grid.position[k]
    contact = 2.0 * p.radius
    best_d2 = contact * contact
    best_slot = int(-1)
    best_disp = wp.vec2(0.0, 0.0)
    center = cell_coords(grid, pos)
    base = w * world.capacity
    for r in range(rings_for_radius(grid, contact) + 1):
        for q in range(ring_size(r)):
            c = ring_cell(grid, w, center, r, q)
            if c >= 0:
                for k2 in range(grid.cell_start[c], grid.cell_end[c]):
                    j = grid.agent[k2] - base
                    if k2 != k and slot_type(world, j) == t:
                        d = torus_displacement(world, grid.position[k2], pos)
                        d2 = wp.dot(d, d)
                        closer = d2 < best_d2 or (d2 == best_d2 and j < best_slot)
                        if d2 < contact * contact and (best_slot < 0 or closer):
                            best_d2 = d2
                            best_slot = j
                            best_disp = d
    v_new = v + acc
    if best_slot >= 0:
        v_new = v
        if best_d2 > 0.0:
            v_new = v + best_disp * (p.bounce_strength / wp.sqrt(best_d2))

    # 4. Speed clamp (paper eq. 3) and wrap onto the torus (eq. 4).
    v_new = clamp_length(v_new, p.max_speed)
    position[w, i] = wp.vec2(wrap_coordinate(pos[0] + v_new[0], world.width),
                             wrap_coordinate(pos[1] + v_new[1], world.height))
    velocity[w, i] = v_new
    acceleration[w, i] = acc
    speed = wp.length(v_new)
    if speed > 0.0:
        heading[w, i] = v_new / speed


def launch_integrate_motion(world, types, grid, prey_action, predator_action, state, count, device, record=False):
    return wp.launch(integrate_motion, dim=count,
                     inputs=[world, types, grid, prey_action, predator_action, state.alive],
                     outputs=[state.position, state.velocity, state.acceleration, state.heading],
                     device=device, record_cmd=record)
