"""docs/model.md step 10: field-of-view observations (and the contact partners of step 3).

Per live agent: the own 5-tuple (with `observe_flow` then the current there, two values), then its
nearest visible predators and nearest visible prey, each block sorted by (distance, slot), packed as
6-tuples; unused slots are zero and a boolean mask marks
the filled ones. Candidates come from a search of the cell lists that widens ring by ring and stops
as soon as no unseen agent can be visible (beyond the view distance) or closer than the K-th kept
one, so an unlimited view distance still costs about K neighbours' worth of cells, not the whole
world. It reads cells a row run at a time (the cells of a row within reach are one range of entries):
first the square of rings 0..2 at most, which at the default sizes is the whole search, then one
ring per step. Observers read their own fields, and their kept neighbours' velocities, from the
state by slot; the cell lists give the candidates' slots and positions.

The same neighbour pass also finds each agent's contact partner for the next step's motion (docs/model.md
step 3 reads start-of-step positions, which are exactly these), so motion needs no search of its own.

One row's work is a function, `observe_row`, generated per observer slot counts by `observation_rows`
(so the top-K lists and the observation row are fixed-size registers); the fused step
(`world_step.py`) calls it too. The kernel is generated per slot counts and per block size: one
thread per row of an observation array. One launch
serves both agent types when they observe the same slot counts (the first blocks take one type's
rows, the rest the other's; a type alone takes a launch of its own otherwise), so the few predators'
blocks run beside the prey's instead of in a small launch of their own, which would leave most of
the GPU idle while its threads walk their neighbours. A block assembles its rows in shared memory and stores them as one
contiguous run (on a GPU, one thread writing a 29-float row alone would scatter 29 stores 116 bytes
apart across the warp). On the CPU (block size 1) each thread stores its row itself: Warp's CPU tile
arena is not released between the blocks of one launch.
"""

import functools

import warp as wp

from .common import (
    PREDATOR,
    PREY,
    AgentType,
    WorldParams,
    angle_value,
    current,
    ego_components,
    in_view,
    ranks_before,
    slot_type,
    torus_displacement,
)
from .grid import CellLists, next_ring, next_run, rings_for_radius, run_entry, run_length, seen_radius, widening_walk
from .state import Agents, Scratch, WorldCounters

wp.set_module_options({"enable_backward": False})

NO_SLOT = wp.constant(2147483647)  # slot of an unfilled list entry: ranks after every agent
# Registers per GPU thread: the compiler's own choice (96) allows 31% occupancy and the pass waits on
# memory. On an H200 (graph step, row-run search): cap 72: 0.491 ms for one world of 1M agents and
# 0.294 ms for 65,536 x 17; cap 64: 0.516 / 0.306 ms; 56: 0.553 ms (1M); 80: 0.499 ms (1M).
MAX_REGISTERS = 72
# The search starts with the square of rings 0..2 at most (row runs: one range of entries per row),
# which holds the whole search at the default sizes; wider searches go on ring by ring.
FIRST_SQUARE_RINGS = 2


@wp.func
def scaled(x: float, signed: int) -> float:
    if signed != 0:
        return 2.0 * x - 1.0
    return x


@wp.func
def scaled_signed(x: float, signed: int) -> float:
    """A signed value in [-1, 1] (clamped: rounding may pass the ends), in the observation range."""
    c = wp.clamp(x, -1.0, 1.0)
    if signed != 0:
        return c
    return 0.5 * (c + 1.0)


Tuple6 = wp.types.vector(length=6, dtype=float)

# Own-block lengths of the observation frames (`AquariumConfig.observation_layout`), before the flow values.
OWN_SIZES = {"world": 5, "ego": 2, "ego+heading": 4}


@wp.func
def neighbour_tuple(
    world: WorldParams,
    observer: AgentType,
    neighbour: AgentType,
    neighbour_type: int,
    d2: float,
    offset: wp.vec2,
    position: wp.vec2,
    speed: float,
) -> Tuple6:
    """type, x / width, y / height, distance / v, bearing, speed / s of one observed neighbour."""
    signed = world.signed_observations
    return Tuple6(
        scaled(float(neighbour_type), signed),
        scaled(position[0] / world.width, signed),
        scaled(position[1] / world.height, signed),
        scaled(wp.min(wp.sqrt(d2) / observer.distance_norm, 1.0), signed),
        scaled(angle_value(offset), signed),
        # Clamped speeds are <= s up to one rounding step; keep the scaled value inside [0, 1].
        scaled(wp.min(speed / neighbour.max_speed, 1.0), signed),
    )


@wp.func
def ego_neighbour_tuple(
    observer: AgentType,
    neighbour: AgentType,
    heading: wp.vec2,
    d2: float,
    offset: wp.vec2,
    relative_velocity: wp.vec2,
    signed: int,
) -> Tuple6:
    """present, distance / v, bearing (forward, right), relative velocity (forward, right) / (s_i + s_j)
    of one observed neighbour in the observer's ego frame (docs/model.md "Egocentric observations")."""
    distance = wp.sqrt(d2)
    bearing = wp.vec2(0.0, 0.0)  # no direction to an agent at the observer's own position
    if distance > 0.0:
        bearing = ego_components(heading, offset) / distance
    relative = ego_components(heading, relative_velocity) / (observer.max_speed + neighbour.max_speed)
    return Tuple6(
        1.0,
        scaled(wp.min(distance / observer.distance_norm, 1.0), signed),
        scaled_signed(bearing[0], signed),
        scaled_signed(bearing[1], signed),
        scaled_signed(relative[0], signed),
        scaled_signed(relative[1], signed),
    )


@functools.cache
def observation_rows(predator_slots: int, prey_slots: int, whole_world: bool, observe_flow: bool, frame: str = "world"):
    """The observation of one agent, for observers with `predator_slots` and `prey_slots` slots, on
    whole-world cell lists or not, with the two flow values after the own block or not, in the
    observation `frame` ("world": docs/model.md's layout; "ego", or "ego+heading" with the observer's world
    heading in its own block, for ego actions and world actions: `AquariumConfig.observation_layout`):
    returns `(observe_row, ObservedRows, Row)`, the function, the struct of one observer type's outputs
    and the row type. Made once per combination, and shared by `observation_kernel` and the fused step
    (`world_step.py`), so both run the same code."""
    slots = predator_slots + prey_slots
    ego = frame != "world"
    own_heading = frame == "ego+heading"
    base = OWN_SIZES[frame]
    own = base + 2 * int(observe_flow)  # the own block, then the observed current if asked for
    # The nearest visible agents found so far, one list: predators in [0, predator_slots), prey after
    # them; each block sorted by (distance, slot), unfilled entries (inf, NO_SLOT). Every index into
    # the lists is a compile-time constant (unrolled loops), so they stay in registers.
    KeptFloat = wp.types.vector(length=max(slots, 1), dtype=float)
    KeptInt = wp.types.vector(length=max(slots, 1), dtype=int)
    last_predator = max(predator_slots - 1, 0)  # last entry of each block (unused if the block is empty)
    last_prey = max(slots - 1, 0)
    Row = wp.types.vector(length=own + 6 * slots, dtype=float)

    # One observer type's outputs: the `Observations` arrays of the type, its rows as `Row` values (the
    # row type depends on the slot counts, so this struct is made with the function, in a module of its own).
    class ObservedRows:
        obs: wp.array(dtype=Row)  # [rows] rows of the [W, per_world, L] observations (same memory)
        mask: wp.array2d(dtype=wp.bool)  # [rows, K]
        observed_slot: wp.array2d(dtype=wp.int32)  # [rows, K]

    ObservedRows = wp.struct(ObservedRows, module="unique")

    def observe_row(
        world: WorldParams,
        types: wp.array2d(dtype=AgentType),
        grid: CellLists,
        agents: Agents,
        counters: WorldCounters,
        t: int,
        w: int,
        i: int,
        r: int,
        out: ObservedRows,
        scratch: Scratch,
    ):
        # Slot i of world w, of type t, observes: its mask and observed slots go to row r of `out`, its
        # contact partner to `scratch`; the row itself is returned (zero for a dead slot), for the
        # caller to store.
        row = Row()
        if not agents.alive[w, i]:
            for s in range(wp.static(slots)):
                out.mask[r, s] = False
                out.observed_slot[r, s] = -1
            scratch.contact_partner[w, i] = -1
        else:
            p = types[w, t]
            pos = agents.position[w, i]
            h = agents.heading[w, i]

            # Ring-by-ring search for the nearest visible agents of each type, and for the nearest
            # overlapping agent of the own type (the contact partner of the next step's motion).
            kept_d2 = KeptFloat()
            kept_entry = KeptInt()
            kept_slot = KeptInt()
            for e in range(wp.static(slots)):
                kept_d2[e] = wp.inf
                kept_slot[e] = NO_SLOT
            v = p.view_distance
            v2 = v * v
            contact = 2.0 * p.radius
            contact2 = contact * contact
            contact_rings = rings_for_radius(grid, contact)
            partner_d2 = contact2
            partner_slot = int(-1)
            partner_disp = wp.vec2(0.0, 0.0)
            # The first step visits the square of rings 0..first_ring (usually the whole search),
            # later steps one ring each; cells farther than any wanted agent are skipped.
            first_ring = wp.min(rings_for_radius(grid, wp.max(v, contact)), wp.max(contact_rings, FIRST_SQUARE_RINGS))
            walk = widening_walk(grid, w, world.capacity, pos, first_ring, wp.max(v2, contact2))
            searching = bool(True)
            while searching:
                while next_run(grid, walk):
                    runs = walk.runs
                    if wp.static(whole_world):
                        # The world's slots, as a range the compiler knows (a run read from the lists
                        # cost this pass 10% on the CPU).
                        runs = wp.vec4i(walk.base, walk.base + world.capacity, 0, 0)
                    for n in range(run_length(runs)):
                        k2 = run_entry(runs, n)
                        # listed_slot, resolved at compile time
                        if wp.static(whole_world):
                            j = wp.where(grid.alive[k2], k2 - walk.base, -1)
                        else:
                            j = grid.agent[k2] - walk.base
                        if j >= 0 and j != i:
                            jt = slot_type(world, j)
                            d = torus_displacement(world, pos, grid.position[k2])
                            d2 = wp.dot(d, d)
                            if jt == t and d2 < contact2:
                                if partner_slot < 0 or ranks_before(d2, j, partner_d2, partner_slot):
                                    partner_d2 = d2
                                    partner_slot = j
                                    partner_disp = d
                            visible = in_view(world, h, d, d2, v2, p.cos_half_fov)
                            # Insert into the type's block if it ranks before the block's last
                            # entry: the candidate sinks past every entry it ranks before,
                            # carrying the displaced one along.
                            last_d2 = wp.where(jt == PREDATOR, kept_d2[last_predator], kept_d2[last_prey])
                            last_slot = wp.where(jt == PREDATOR, kept_slot[last_predator], kept_slot[last_prey])
                            if visible and ranks_before(d2, j, last_d2, last_slot):
                                carry_d2 = d2
                                carry_slot = j
                                carry_entry = k2
                                for e in range(wp.static(slots)):
                                    in_block = (e < predator_slots) == (jt == PREDATOR)
                                    if in_block and ranks_before(carry_d2, carry_slot, kept_d2[e], kept_slot[e]):
                                        swap_d2 = kept_d2[e]
                                        swap_slot = kept_slot[e]
                                        swap_entry = kept_entry[e]
                                        kept_d2[e] = carry_d2
                                        kept_slot[e] = carry_slot
                                        kept_entry[e] = carry_entry
                                        carry_d2 = swap_d2
                                        carry_slot = swap_slot
                                        carry_entry = swap_entry
                # Every agent closer than `reach` has been seen; whole-world lists end after one step
                # (known at compile time: 9% fewer spill bytes on sm_90 than a test of the ring).
                reach = seen_radius(grid, walk.ring)
                if wp.static(whole_world) or reach == wp.inf:
                    searching = False
                elif walk.ring >= contact_rings:
                    if reach > v:
                        searching = False
                    else:
                        reach2 = reach * reach
                        done = True
                        farthest = float(0.0)  # squared distance of the farthest agent still wanted
                        for tt in range(2):
                            kth = wp.where(tt == PREDATOR, kept_d2[last_predator], kept_d2[last_prey])
                            if (tt == PREDATOR and predator_slots > 0) or (tt == PREY and prey_slots > 0):
                                if kth == wp.inf:  # block not full yet
                                    done = False
                                    farthest = v2
                                else:
                                    farthest = wp.max(farthest, kth)
                                    if kth >= reach2:
                                        done = False
                        searching = not done
                        walk.bound2 = wp.max(wp.min(farthest, v2), contact2)
                next_ring(walk)
            scratch.contact_partner[w, i] = partner_slot
            scratch.contact_offset[w, i] = -partner_disp  # from the partner to this agent

            # The own 5-tuple, then the kept neighbours: predator block first, then prey block (slot
            # loops unrolled, so the row stays in registers).
            signed = world.signed_observations
            own_velocity = agents.velocity[w, i]
            if wp.static(ego):
                # No torus coordinates and no world angles: the type, the own speed and (for world
                # actions) the heading as a unit vector.
                row[0] = scaled(float(t), signed)
                row[1] = scaled(wp.min(wp.length(own_velocity) / p.max_speed, 1.0), signed)
                if wp.static(own_heading):
                    row[2] = scaled_signed(h[0], signed)
                    row[3] = scaled_signed(h[1], signed)
            else:
                row[0] = scaled(float(t), signed)
                row[1] = scaled(pos[0] / world.width, signed)
                row[2] = scaled(pos[1] / world.height, signed)
                row[3] = scaled(angle_value(h), signed)
                row[4] = scaled(wp.min(wp.length(own_velocity) / p.max_speed, 1.0), signed)
            if wp.static(observe_flow):
                # The current the next move adds here (same position and step counter), in the
                # observer's max speeds, clipped to [-1, 1], then (c + 1) / 2 like a 0..1 value (in
                # the ego frame: its forward and right components).
                c = current(world, world.values[w], pos, counters.world_step[w]) / p.max_speed
                if wp.static(ego):
                    c = ego_components(h, c)
                    for q in range(2):
                        row[base + q] = scaled_signed(c[q], signed)
                else:
                    for q in range(2):
                        row[base + q] = scaled(0.5 * (wp.clamp(c[q], -1.0, 1.0) + 1.0), signed)
            for e in range(wp.static(slots)):
                if kept_slot[e] != NO_SLOT:
                    jt = wp.where(e < predator_slots, PREDATOR, PREY)
                    k2 = kept_entry[e]
                    offset = torus_displacement(world, pos, grid.position[k2])
                    neighbour = Tuple6()
                    if wp.static(ego):
                        neighbour = ego_neighbour_tuple(
                            p,
                            types[w, jt],
                            h,
                            kept_d2[e],
                            offset,
                            agents.velocity[w, kept_slot[e]] - own_velocity,
                            signed,
                        )
                    else:
                        neighbour = neighbour_tuple(
                            world,
                            p,
                            types[w, jt],
                            jt,
                            kept_d2[e],
                            offset,
                            grid.position[k2],
                            wp.length(agents.velocity[w, kept_slot[e]]),
                        )
                    for q in range(6):
                        row[own + 6 * e + q] = neighbour[q]
                    out.mask[r, e] = True
                    out.observed_slot[r, e] = kept_slot[e]
                else:
                    out.mask[r, e] = False
                    out.observed_slot[r, e] = -1
        return row

    return wp.func(observe_row, module="unique"), ObservedRows, Row


@functools.cache
def observation_kernel(
    predator_slots: int,
    prey_slots: int,
    block_dim: int,
    whole_world: bool,
    observe_flow: bool = False,
    frame: str = "world",
):
    """The observation kernel for observers with `predator_slots` and `prey_slots` slots, launched with
    `dim=(blocks, block_dim)` and `block_dim`, on whole-world cell lists or not (compiled once per
    combination: the kind of lists is fixed at compile time here, where `listed_slot` would test it for
    every candidate), with the two flow values after the own block or not (docs/model.md "Flow fields"), in
    the observation `frame` (`observation_rows`)."""
    observe_row, ObservedRows, Row = observation_rows(predator_slots, prey_slots, whole_world, observe_flow, frame)

    def observe(
        world: WorldParams,
        types: wp.array2d(dtype=AgentType),
        grid: CellLists,
        agents: Agents,
        counters: WorldCounters,
        first_type: int,
        first_rows: int,
        first_blocks: int,
        second_rows: int,
        first: ObservedRows,
        second: ObservedRows,
        scratch: Scratch,
    ):
        # Blocks [0, first_blocks) take the `first_rows` rows of `first_type`'s [worlds * agents of
        # the type] rows, the blocks after them the other type's `second_rows` rows. Every thread of
        # a block reaches the shared store at the end, also past the last row.
        block, lane = wp.tid()
        t = first_type
        rows = first_rows
        out = first
        if block >= first_blocks:
            block = block - first_blocks
            t = PREY + PREDATOR - first_type
            rows = second_rows
            out = second
        per_world = world.prey_capacity
        first_slot = int(0)
        if t == PREDATOR:
            per_world = world.predator_capacity
            first_slot = world.prey_capacity
        r = block * block_dim + lane
        w = r // per_world
        i = first_slot + r - w * per_world
        row = Row()
        if r < rows:
            row = observe_row(world, types, grid, agents, counters, t, w, i, r, out, scratch)
        if wp.static(block_dim > 1):
            staged = wp.tile_empty(shape=block_dim, dtype=Row, storage="shared")
            wp.tile_scatter_masked(staged, lane, row, True)
            obs_rows = out.obs  # a local array: tile_store does not take a struct's field (Warp 1.19)
            wp.tile_store(obs_rows, staged, offset=block * block_dim)
        elif r < rows:
            out.obs[r] = row

    kernel = wp.kernel(enable_backward=False, module="unique", cuda_max_registers=MAX_REGISTERS)(observe)
    kernel.rows_type = ObservedRows  # type of the `first` and `second` arguments
    kernel.row_type = Row  # dtype of their `obs`
    kernel.block_dim = block_dim
    kernel.whole_world = whole_world
    return kernel
