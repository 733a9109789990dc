"""MODEL.md step 10: field-of-view observations (and the contact partners of step 3).

Per live agent: the own 5-tuple, then its nearest visible predators and nearest visible prey, each
block sorted by (distance, slot), packed as 6-tuples; unused slots are zero and a boolean mask marks
the filled ones. Candidates come from a ring-by-ring search of the cell lists that stops as soon as
no unseen agent can be visible (beyond the view distance) or closer than the K-th kept one, so an
unlimited view distance still costs about K neighbours' worth of cells, not the whole world.

The same neighbour pass also finds each agent's contact partner for the next step's motion (MODEL.md
step 3 reads start-of-step positions, which are exactly these), so motion needs no search of its own.

The kernel is generated per `max_slots` (the largest slot count of any block), so the top-K lists
are fixed-size registers.
"""

import functools

import warp as wp

from .common import PREDATOR, PREY, AgentType, WorldParams, angle_value, slot_type, torus_displacement
from .grid import (CellLists, cell_coords, cell_gap, last_ring, offset_cell, ring_offset, ring_side_length,
                   ring_sides, rings_for_radius, searched_radius)

wp.set_module_options({"enable_backward": False})


@wp.func
def put_value(
    obs_prey: wp.array3d(dtype=float),
    obs_predator: wp.array3d(dtype=float),
    is_prey: bool,
    w: int,
    row: int,
    col: int,
    value: float,
):
    if is_prey:
        obs_prey[w, row, col] = value
    else:
        obs_predator[w, row, col] = value


@wp.func
def put_neighbour(
    mask_prey: wp.array3d(dtype=wp.bool),
    mask_predator: wp.array3d(dtype=wp.bool),
    slot_prey: wp.array3d(dtype=wp.int32),
    slot_predator: wp.array3d(dtype=wp.int32),
    is_prey: bool,
    w: int,
    row: int,
    col: int,
    slot: int,
):
    """Record which agent slot fills observation slot `col` (-1: empty)."""
    if is_prey:
        mask_prey[w, row, col] = slot >= 0
        slot_prey[w, row, col] = slot
    else:
        mask_predator[w, row, col] = slot >= 0
        slot_predator[w, row, col] = slot


@wp.func
def scaled(x: float, signed: int) -> float:
    if signed != 0:
        return 2.0 * x - 1.0
    return x


@wp.func
def ranks_before(d2: float, slot: int, other_d2: float, other_slot: int) -> bool:
    """Neighbour order: nearer first, ties to the lower slot."""
    return d2 < other_d2 or (d2 == other_d2 and slot < other_slot)


@functools.cache
def observation_kernel(max_slots: int):
    """The observation kernel for blocks of at most `max_slots` slots (compiled once per value)."""
    listed = 2 * max_slots  # predator list in [0, max_slots), prey list in [max_slots, 2 max_slots)
    FloatList = wp.types.vector(length=listed, dtype=float)
    IntList = wp.types.vector(length=listed, dtype=int)

    def observe(
        world: WorldParams,
        types: wp.array(dtype=AgentType),
        grid: CellLists,
        alive: wp.array2d(dtype=wp.bool),
        num_worlds: int,
        obs_prey: wp.array3d(dtype=float),
        obs_predator: wp.array3d(dtype=float),
        mask_prey: wp.array3d(dtype=wp.bool),
        mask_predator: wp.array3d(dtype=wp.bool),
        slot_prey: wp.array3d(dtype=wp.int32),
        slot_predator: wp.array3d(dtype=wp.int32),
        contact_partner: wp.array2d(dtype=wp.int32),
        contact_offset: wp.array2d(dtype=wp.vec2),
    ):
        # One thread per agent: every world's prey first, then every world's predators. Threads of
        # one type run side by side (on a GPU a warp does not wait for the longer searches of the
        # other type), and each type's output rows are written in order.
        thread = wp.tid()
        prey_threads = num_worlds * world.prey_capacity
        w = int(0)
        i = int(0)
        if thread < prey_threads:
            w = thread // world.prey_capacity
            i = thread - w * world.prey_capacity
        else:
            u = thread - prey_threads
            w = u // world.predator_count
            i = world.prey_capacity + u - w * world.predator_count
        idx = w * world.capacity + i
        k = grid.entry[idx]  # sorted entry
        t = slot_type(world, i)
        p = types[t]
        is_prey = t == PREY
        row = i
        if not is_prey:
            row = i - world.prey_capacity
        slots = p.predator_slots + p.prey_slots
        if not alive[w, i]:
            for col in range(5 + 6 * slots):
                put_value(obs_prey, obs_predator, is_prey, w, row, col, 0.0)
            for s in range(slots):
                put_neighbour(mask_prey, mask_predator, slot_prey, slot_predator, is_prey, w, row, s, -1)
            contact_partner[w, i] = -1
            return

        pos = grid.position[k]
        h = grid.heading[k]
        signed = world.signed_observations
        put_value(obs_prey, obs_predator, is_prey, w, row, 0, scaled(float(t), signed))
        put_value(obs_prey, obs_predator, is_prey, w, row, 1, scaled(pos[0] / world.width, signed))
        put_value(obs_prey, obs_predator, is_prey, w, row, 2, scaled(pos[1] / world.height, signed))
        put_value(obs_prey, obs_predator, is_prey, w, row, 3, scaled(angle_value(h), signed))
        # Clamped speeds are <= s up to one rounding step; keep the scaled value inside [0, 1].
        own_speed = wp.min(grid.speed[k] / p.max_speed, 1.0)
        put_value(obs_prey, obs_predator, is_prey, w, row, 4, scaled(own_speed, signed))

        # Ring-by-ring search for the nearest visible agents of each type, and for the nearest
        # overlapping agent of the own type (the contact partner of the next step's motion).
        kept_d2 = FloatList()
        kept_entry = IntList()
        kept_slot = IntList()
        wanted = wp.vec2i(p.predator_slots, p.prey_slots)  # indexed by type code
        kept = wp.vec2i(0, 0)
        v = p.view_distance
        v2 = v * v
        contact = 2.0 * p.radius
        contact2 = contact * contact
        contact_rings = rings_for_radius(grid, contact)
        partner_d2 = contact2
        partner_slot = int(-1)
        partner_disp = wp.vec2(0.0, 0.0)
        center = cell_coords(grid, pos)
        base = w * world.capacity
        last = last_ring(grid)
        r = int(0)
        searching = bool(True)
        # Where the observer lies inside its cell: cells farther than any wanted agent are skipped.
        inside_x = pos[0] - float(center[0]) * grid.cell_width
        inside_y = pos[1] - float(center[1]) * grid.cell_height
        bound2 = wp.max(v2, contact2)
        while searching:
            for side in range(ring_sides(r)):
                for u in range(ring_side_length(r)):
                    o = ring_offset(r, side, u)
                    c = offset_cell(grid, w, center, o)
                    gap_x = cell_gap(o[0], inside_x, grid.cell_width, grid.dims_x)
                    gap_y = cell_gap(o[1], inside_y, grid.cell_height, grid.dims_y)
                    if c >= 0 and gap_x * gap_x + gap_y * gap_y <= bound2:
                        for k2 in range(grid.cell_start[c], grid.cell_end[c]):
                            j = grid.agent[k2] - base
                            jt = slot_type(world, j)
                            if k2 != k:
                                d = torus_displacement(world, pos, grid.position[k2])
                                d2 = wp.dot(d, d)
                                if jt == t and d2 < contact2:
                                    if partner_slot < 0 or ranks_before(d2, j, partner_d2, partner_slot):
                                        partner_d2 = d2
                                        partner_slot = j
                                        partner_disp = d
                                n_wanted = wanted[jt]
                                visible = n_wanted > 0 and d2 <= v2
                                if visible and world.fov_enabled != 0 and d2 > 0.0:
                                    visible = wp.dot(h, d) >= wp.sqrt(d2) * p.cos_half_fov
                                offset = jt * max_slots
                                n = kept[jt]
                                last_kept = offset + wp.max(n_wanted, 1) - 1
                                if visible and (n < n_wanted or ranks_before(d2, j, kept_d2[last_kept], kept_slot[last_kept])):
                                    at = offset + wp.min(n, n_wanted - 1)
                                    while at > offset and ranks_before(d2, j, kept_d2[at - 1], kept_slot[at - 1]):
                                        kept_d2[at] = kept_d2[at - 1]
                                        kept_entry[at] = kept_entry[at - 1]
                                        kept_slot[at] = kept_slot[at - 1]
                                        at -= 1
                                    kept_d2[at] = d2
                                    kept_entry[at] = k2
                                    kept_slot[at] = j
                                    if n < n_wanted:
                                        kept[jt] = n + 1
            if r >= last:
                searching = False
            elif r >= contact_rings:
                reach = searched_radius(grid, r)
                if reach > v:
                    searching = False
                else:
                    reach2 = reach * reach
                    done = True
                    farthest = float(0.0)  # squared distance of the farthest agent still wanted
                    for tt in range(2):
                        if wanted[tt] > 0:
                            if kept[tt] < wanted[tt]:
                                done = False
                                farthest = v2
                            else:
                                kth = kept_d2[tt * max_slots + wanted[tt] - 1]
                                farthest = wp.max(farthest, kth)
                                if kth >= reach2:
                                    done = False
                    searching = not done
                    bound2 = wp.max(wp.min(farthest, v2), contact2)
            r += 1
        contact_partner[w, i] = partner_slot
        contact_offset[w, i] = -partner_disp  # from the partner to this agent

        # Pack the kept neighbours: predator block first, then prey block.
        for block in range(2):
            jt = PREDATOR
            first = 0
            if block == 1:
                jt = PREY
                first = p.predator_slots
            for s in range(wanted[jt]):
                col = 5 + 6 * (first + s)
                if s < kept[jt]:
                    at = jt * max_slots + s
                    k2 = kept_entry[at]
                    d = torus_displacement(world, pos, grid.position[k2])
                    dist = wp.sqrt(kept_d2[at])
                    neighbour_speed = wp.min(grid.speed[k2] / types[jt].max_speed, 1.0)
                    put_value(obs_prey, obs_predator, is_prey, w, row, col + 0, scaled(float(jt), signed))
                    put_value(obs_prey, obs_predator, is_prey, w, row, col + 1,
                              scaled(grid.position[k2][0] / world.width, signed))
                    put_value(obs_prey, obs_predator, is_prey, w, row, col + 2,
                              scaled(grid.position[k2][1] / world.height, signed))
                    put_value(obs_prey, obs_predator, is_prey, w, row, col + 3,
                              scaled(wp.min(dist / p.distance_norm, 1.0), signed))
                    put_value(obs_prey, obs_predator, is_prey, w, row, col + 4, scaled(angle_value(d), signed))
                    put_value(obs_prey, obs_predator, is_prey, w, row, col + 5, scaled(neighbour_speed, signed))
                    put_neighbour(mask_prey, mask_predator, slot_prey, slot_predator, is_prey, w, row, first + s,
                                  kept_slot[at])
                else:
                    for e in range(6):
                        put_value(obs_prey, obs_predator, is_prey, w, row, col + e, 0.0)
                    put_neighbour(mask_prey, mask_predator, slot_prey, slot_predator, is_prey, w, row, first + s, -1)

    return wp.kernel(enable_backward=False, module="unique")(observe)
