"""The paper's baseline policies (docs/model.md "Heuristic policies") as one kernel over every world.

Random, Constant (always the world direction "up", ignoring everything: the baseline of an agent
that does not react), TurnAway (flee the nearest visible agent of the other type), Boids (Reynolds
separation, alignment and cohesion over the visible agents of the own type, plus fleeing the nearest
visible one of the other type) and NaivChase
(chase a visible agent of the other type, with "confusion" a uniformly random one, else the nearest;
with none in sight the nearest one in the world). Each picks a world direction; with
`action_frame="ego"` the action is the one nearest to that direction seen from the agent's heading.
Visibility is the observation's rule (distance <= v, and with `fov_enabled` within alpha/2 of the
heading; distance 0 is visible). Targets come from a ring-by-ring
search of the cell lists built on the state the decision is made from, which stops as soon as no
unseen agent can change the answer, so no search is all-pairs.

Random draws use the stream (seed, world, episode, step, slot, PURPOSE_POLICY) of the deciding agent,
so actions are reproducible and equal on CPU and GPU, and do not depend on how worlds are sharded.
"""

import warp as wp

from .common import (
    PURPOSE_POLICY,
    AgentType,
    WorldParams,
    in_view,
    mix32,
    random_stream,
    slot_type,
    torus_displacement,
    world_to_ego,
)
from .grid import CellLists, listed_slot, next_cell, next_ring, ring_walk, seen_radius
from .state import Agents, WorldCounters

wp.set_module_options({"enable_backward": False})

# Policy codes (host and device).
POLICY_RANDOM = wp.constant(0)
POLICY_TURN_AWAY = wp.constant(1)  # flee the nearest visible agent of the other type
POLICY_CHASE_CONFUSED = wp.constant(2)  # chase a uniformly random visible one (else the nearest in the world)
POLICY_CHASE_NEAREST = wp.constant(3)  # chase the nearest visible one (else the nearest in the world)
POLICY_CONSTANT = wp.constant(4)  # always the world direction "up" (0, -1): no reaction at all
POLICY_BOIDS = wp.constant(5)  # Reynolds flocking over the visible same-type agents, fleeing a visible predator

# Boids (docs/model.md "Heuristic policies"): weights of the unit flee, separation, alignment and cohesion
# vectors; separation acts on neighbours closer than BOIDS_SEPARATION_RADII own hit-box radii.
BOIDS_FLEE = wp.constant(2.0)
BOIDS_SEPARATION = wp.constant(1.5)
BOIDS_ALIGNMENT = wp.constant(1.0)
BOIDS_COHESION = wp.constant(1.0)
BOIDS_SEPARATION_RADII = wp.constant(2.0)


@wp.func
def nearest_action(
    action_direction: wp.array(dtype=wp.vec2), action_count: int, direction: wp.vec2, heading: wp.vec2
) -> int:
    """The action whose desired direction makes the smallest angle with `direction` (ties: lower action);
    a zero direction falls back to `heading`. The angle's rounding picks a guess, and the exact test
    (largest dot product with the unit action directions) decides between it and its two neighbours,
    so the cost does not grow with `action_count`."""
    d = direction
    if d[0] == 0.0 and d[1] == 0.0:
        d = heading
    # Action a points at theta = 2 pi a / n clockwise from "up": (sin theta, -cos theta).
    theta = wp.atan2(d[0], -d[1])
    guess = int(wp.floor(theta * float(action_count) / (2.0 * wp.pi) + 0.5))
    best = int(-1)
    best_dot = float(0.0)
    for offset in range(-1, 2):
        a = guess + offset
        while a < 0:
            a += action_count
        while a >= action_count:
            a -= action_count
        dot = wp.dot(d, action_direction[a])
        if best < 0 or dot > best_dot or (dot == best_dot and a < best):
            best = a
            best_dot = dot
    return best


@wp.func
def action_towards(
    world: WorldParams, action_direction: wp.array(dtype=wp.vec2), direction: wp.vec2, heading: wp.vec2
) -> int:
    """The action of an agent heading `heading` that steers nearest to the world `direction` (zero: keep
    the heading), in the world's action frame."""
    if world.ego_actions != 0:  # seen from the heading, "keep the heading" is "up" (action 0)
        return nearest_action(
            action_direction, world.action_count, world_to_ego(heading, direction), wp.vec2(0.0, -1.0)
        )
    return nearest_action(action_direction, world.action_count, direction, heading)


@wp.func
def unit_or_zero(v: wp.vec2) -> wp.vec2:
    n = wp.length(v)
    if n > 0.0:
        return v / n
    return wp.vec2(0.0, 0.0)


@wp.func
def precedes(d2: float, slot: int, other_d2: float, other_slot: int) -> bool:
    """Nearer first, ties to the lower slot (a missing candidate has slot -1)."""
    return other_slot < 0 or d2 < other_d2 or (d2 == other_d2 and slot < other_slot)


@wp.kernel
def heuristic_policy(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    action_direction: wp.array(dtype=wp.vec2),
    agents: Agents,
    counters: WorldCounters,
    seed: wp.array(dtype=wp.uint32),
    policy: int,
    first_slot: int,
    action: wp.array2d(dtype=wp.int32),
):
    """Actions of agent slots `[first_slot, first_slot + action.shape[1])` (all of one type) in every
    world of the batch: `action[w, a]` for slot `first_slot + a`; dead slots get 0. `seed[w]` keys
    world w's draws (the env's `counters.seed`, or a policy's own). `grid` must hold the cell lists
    of `agents.position` (the observation pass builds them)."""
    w, a = wp.tid()
    i = first_slot + a
    if not agents.alive[w, i]:
        action[w, a] = 0
        return
    action_count = world.action_count
    step = counters.world_step[w]
    rng = random_stream(seed[w], counters.stream_world[w], counters.episode[w], step, i, PURPOSE_POLICY)
    if policy == POLICY_RANDOM:
        action[w, a] = wp.randi(rng, 0, action_count)
        return
    if policy == POLICY_CONSTANT:
        action[w, a] = action_towards(world, action_direction, wp.vec2(0.0, -1.0), agents.heading[w, i])
        return

    t = slot_type(world, i)
    target_type = 1 - t  # the other type: predators for TurnAway prey, prey for NaivChase predators
    p = types[w, t]
    pos = agents.position[w, i]
    h = agents.heading[w, i]
    v = p.view_distance
    v2 = v * v
    boids = policy == POLICY_BOIDS
    # Every visible agent counts (confusion's candidates; the Boids' flock), so the search runs to v.
    all_visible = policy == POLICY_CHASE_CONFUSED or boids
    # With none visible, chasers fall back to the nearest target in the world.
    in_world = policy == POLICY_CHASE_CONFUSED or policy == POLICY_CHASE_NEAREST
    separation_radius = BOIDS_SEPARATION_RADII * p.radius
    flock_count = int(0)  # Boids: visible agents of the own type, their summed offsets and headings
    flock_offset = wp.vec2(0.0, 0.0)
    flock_heading = wp.vec2(0.0, 0.0)
    separation = wp.vec2(0.0, 0.0)  # sum of -d / |d|^2 over the visible ones closer than the radius

    visible_count = int(0)
    near_d2 = float(0.0)  # nearest visible target
    near_slot = int(-1)
    near_disp = wp.vec2(0.0, 0.0)
    pick_key = wp.uint32(0)  # visible target of the lowest random priority (confusion)
    pick_slot = int(-1)
    pick_disp = wp.vec2(0.0, 0.0)
    any_d2 = float(0.0)  # nearest target in the world, visible or not
    any_slot = int(-1)
    any_disp = wp.vec2(0.0, 0.0)

    # Ring by ring from the agent's own cell (every choice below is independent of the visiting order).
    walk = ring_walk(grid, w, world.capacity, pos)
    searching = bool(True)
    while searching:
        while next_cell(grid, walk):
            for k2 in range(grid.cell_start[walk.cell], grid.cell_end[walk.cell]):
                j = listed_slot(grid, k2, walk.base)
                if j >= 0 and slot_type(world, j) == target_type:
                    d = torus_displacement(world, pos, grid.position[k2])
                    d2 = wp.dot(d, d)
                    if precedes(d2, j, any_d2, any_slot):
                        any_d2 = d2
                        any_slot = j
                        any_disp = d
                    visible = in_view(world, h, d, d2, v2, p.cos_half_fov)  # the observation's rule
                    if visible:
                        visible_count += 1
                        if precedes(d2, j, near_d2, near_slot):
                            near_d2 = d2
                            near_slot = j
                            near_disp = d
                        # Each candidate's priority is a bijective hash of its slot under the agent's
                        # stream: distinct, and the lowest is a uniform pick that does not depend on the
                        # order in which cells are visited.
                        key = mix32(rng ^ wp.uint32(j))
                        if pick_slot < 0 or key < pick_key:
                            pick_key = key
                            pick_slot = j
                            pick_disp = d
                elif boids and j >= 0 and j != i:  # a flock mate (sums in the cells' visiting order)
                    d = torus_displacement(world, pos, grid.position[k2])
                    d2 = wp.dot(d, d)
                    if in_view(world, h, d, d2, v2, p.cos_half_fov):
                        flock_count += 1
                        flock_offset = flock_offset + d
                        flock_heading = flock_heading + agents.heading[w, j]
                        if d2 > 0.0 and d2 < separation_radius * separation_radius:
                            separation = separation - d / d2
        reach = seen_radius(grid, walk.ring)  # every agent closer than this has been seen
        if reach == wp.inf:
            searching = False
        else:
            reach2 = reach * reach
            visible_done = reach > v or (not all_visible and near_slot >= 0 and near_d2 < reach2)
            if visible_done:
                if near_slot >= 0 or not in_world:
                    searching = False
                elif any_slot >= 0 and any_d2 < reach2:
                    searching = False
        next_ring(walk)

    direction = wp.vec2(0.0, 0.0)  # zero: keep the heading
    if policy == POLICY_TURN_AWAY:
        if near_slot >= 0:
            direction = -near_disp
    elif boids:
        if near_slot >= 0:
            direction = BOIDS_FLEE * unit_or_zero(-near_disp)
        if flock_count > 0:
            direction = (
                direction
                + BOIDS_SEPARATION * unit_or_zero(separation)
                + BOIDS_ALIGNMENT * unit_or_zero(flock_heading)
                + BOIDS_COHESION * unit_or_zero(flock_offset)
            )
    elif visible_count > 0:
        if all_visible:
            direction = pick_disp
        else:
            direction = near_disp
    elif any_slot >= 0:
        direction = any_disp
    action[w, a] = action_towards(world, action_direction, direction, h)
