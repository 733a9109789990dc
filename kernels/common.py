"""Shared parameter structs and device functions, in four sections:

- **codes**: the type codes (`PREDATOR`, `PREY`), the purposes of random draws (`PURPOSE_*`), the capture
  rules (`CAPTURE_*`) and the flow kinds (`FLOW_*`);
- **parameters**: `AgentType` (per type and world), `WorldValues` (per world), `WorldParams` (batch-wide),
  and `slot_type`;
- **geometry**: the torus (`torus_delta`, `torus_displacement`, `wrap_coordinate`), the field of view
  (`in_view`, `ranks_before`), the flow (`current`) and the ego frame (`ego_components`, `ego_to_world`,
  `world_to_ego`, `angle_value`);
- **random streams**: `mix32`, `random_stream` and the draws from a stream.

Conventions used by every kernel:
- A world has `capacity` agent slots: prey in `[0, prey_capacity)`, predators after them.
- Type codes follow the observation's type value: `PREDATOR = 0`, `PREY = 1`; per-type parameters live
  in a `[worlds, 2]` `wp.array2d(dtype=AgentType)` indexed by world and that code (`types[w, t]`), so
  one kernel serves both types and every world has its own values; the other per-world values are
  `world.values[w]` (`WorldValues`).
- Positions are px in `[0, width) x [0, height)`, velocities px/step, headings unit vectors.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

# --------------------------------------------------------------------------------------------------------- codes
PREDATOR = wp.constant(0)
PREY = wp.constant(1)

# Purposes of random draws: each draw is keyed by (seed, world, episode, step, slot, purpose).
PURPOSE_SPAWN = wp.constant(1)
PURPOSE_RESPAWN = wp.constant(2)
PURPOSE_NEWBORN = wp.constant(3)
PURPOSE_POLICY = wp.constant(4)
PURPOSE_HEADING = wp.constant(5)  # a fresh agent's random heading, derived from its spawn stream
PURPOSE_CAPTURE = wp.constant(6)  # whether a contact captures, under density dilution
PURPOSE_ATTACK = wp.constant(7)  # whether a predator's attack captures, under predator confusion

# Capture rules (`WorldValues.capture_rule`, docs/model.md step 5).
CAPTURE_DILUTION = wp.constant(0)  # every contact may capture: p0 / (1 + c k), k prey near the prey
CAPTURE_CONFUSION = wp.constant(1)  # one attack per predator: p0 / (1 + c k), k prey it sees near its target

# Flow kinds (`WorldValues.flow_kind`).
FLOW_NONE = wp.constant(0)
FLOW_UNIFORM = wp.constant(1)
FLOW_VORTEX = wp.constant(2)
FLOW_GRID = wp.constant(3)


# ---------------------------------------------------------------------------------------------------- parameters
@wp.struct
class AgentType:
    """Per-type parameters (docs/model.md's per-type table), with derived values precomputed on the host."""

    max_speed: float  # s, px/step
    max_steering_force: float  # f
    max_acceleration: float  # k, px/step^2
    mass: float  # m
    radius: float  # r, px (hit box)
    view_distance: float  # v, px; +inf means unlimited
    distance_norm: float  # min(v, largest torus distance): scales observed distances into [0, 1]
    cos_half_fov: float  # cos(alpha / 2)
    bounce_strength: float  # b, px/step
    predator_slots: int  # observed predator slots
    prey_slots: int  # observed prey slots


@wp.struct
class WorldValues:
    """The world parameters that may differ between the worlds of a batch (one per world), with
    derived values precomputed on the host."""

    prey_count: int  # live prey at the start of an episode (at most prey_capacity)
    predator_count: int  # live predators at the start of an episode (at most predator_capacity)
    prey_reward: float
    prey_capture_penalty: float
    prey_contact_penalty: float  # a live prey's cost of a step in contact with a predator that does not capture it
    predator_reward: float
    catch_share_radius: float  # px
    capture_rule: int  # CAPTURE_DILUTION or CAPTURE_CONFUSION
    capture_probability: float  # p0: the chance that a contact (an attack) captures a lone prey
    capture_confusion: float  # c, the rule's strength: p0 / (1 + c k)
    confusion_radius: float  # px: dilution's k counts the other prey this close to the prey
    confusion_cos: float  # cos(confusion_angle), -2 at 180 degrees: confusion's k counts the seen prey
    # whose bearing is within confusion_angle of the target's
    handling_steps: int  # H: steps a predator cannot attack after a failed attack (confusion rule)
    predator_starvation_steps: int
    replication_age_min: int  # ceil(0.75 * prey_replication_age)
    replication_age_max: int  # floor(1.25 * prey_replication_age)
    prey_spawn_speed: float  # min(1, prey max_speed), px/step: a fresh prey's speed (docs/model.md "Randomness")
    predator_spawn_speed: float  # min(1, predator max_speed), px/step: a fresh predator's speed
    flow_kind: int  # FLOW_NONE, FLOW_UNIFORM, FLOW_VORTEX or FLOW_GRID
    flow_vector: wp.vec2  # uniform: the current (px/step); vortex: the centre (px)
    flow_strength: float  # vortex: px/step at the core's edge
    flow_core_radius: float  # vortex: px
    flow_amplitude: float  # time variation (1 + a sin(2 pi t / T)); 0: steady
    flow_period: float  # T, steps
    flow_grid: int  # grid: index into WorldParams.flow_grid
    flow_reach: float  # largest length of the current (px/step): widens the capture searches


@wp.struct
class WorldParams:
    """Parameters of a batch's worlds: sizes shared by all, and `values`, one `WorldValues` per world."""

    width: float
    height: float
    prey_capacity: int
    capacity: int
    predator_capacity: int
    action_count: int
    max_steps: int
    fov_enabled: int
    respawn_captured_prey: int
    max_prey: int
    signed_observations: int  # 1: observation range "-1..1"
    ego_actions: int  # 1: action_frame "ego" (read by the heuristics; motion is compiled per frame)
    random_spawn_heading: int  # 1: spawn_heading "random" (fresh agents face a uniform direction)
    auto_reset: int  # 1: a world whose episode ended starts the next one inside the same step
    values: wp.array(dtype=WorldValues)  # [shard's worlds]
    flow_grid: wp.array3d(dtype=wp.vec2)  # [grids, rows, cols] currents at cell centres, px/step


@wp.func
def slot_type(world: WorldParams, slot: int) -> int:
    if slot < world.prey_capacity:
        return PREY
    return PREDATOR


# ------------------------------------------------------------------------------------------------------ geometry
@wp.func
def torus_delta(d: float, length: float) -> float:
    """Shortest signed difference on a circle of `length`, for `d` in (-length, length). Selects, not
    branches: neighbour searches call this for every candidate, and a warp's threads disagree."""
    half = 0.5 * length
    return wp.where(d > half, d - length, wp.where(d < -half, d + length, d))


@wp.func
def torus_displacement(world: WorldParams, a: wp.vec2, b: wp.vec2) -> wp.vec2:
    """Torus-shortest displacement from `a` to `b`."""
    return wp.vec2(torus_delta(b[0] - a[0], world.width), torus_delta(b[1] - a[1], world.height))


@wp.func
def in_view(world: WorldParams, heading: wp.vec2, d: wp.vec2, d2: float, v2: float, cos_half_fov: float) -> bool:
    """Visibility of an agent at displacement `d` (squared length `d2`): within the view distance
    (squared: `v2`) and, with the field of view on, inside the cone of half-angle cos^-1(cos_half_fov)
    around the unit `heading`; an agent at the observer's own position is visible."""
    visible = d2 <= v2
    if visible and world.fov_enabled != 0 and d2 > 0.0:
        visible = wp.dot(heading, d) >= wp.sqrt(d2) * cos_half_fov
    return visible


@wp.func
def ranks_before(d2: float, slot: int, other_d2: float, other_slot: int) -> bool:
    """Neighbour order: nearer first, ties to the lower slot."""
    return d2 < other_d2 or (d2 == other_d2 and slot < other_slot)


@wp.func
def wrap_coordinate(x: float, length: float) -> float:
    """Modulo into [0, length) for x in (-length, 2 length) (one move is shorter than the world).
    A tiny negative x rounds up to `length` on the first add; that point is 0 on the circle."""
    y = x
    if y < 0.0:
        y = y + length
    if y >= length:
        y = y - length
    return y


@wp.func
def current(world: WorldParams, v: WorldValues, pos: wp.vec2, t: int) -> wp.vec2:
    """The flow's current C(P, t) at `pos` at step `t` (docs/model.md "Flow fields"), px/step."""
    c = wp.vec2(0.0, 0.0)
    if v.flow_kind == FLOW_UNIFORM:
        c = v.flow_vector
    elif v.flow_kind == FLOW_VORTEX:
        d = torus_displacement(world, v.flow_vector, pos)
        rho = wp.length(d)
        if rho > 0.0:
            profile = wp.where(rho < v.flow_core_radius, rho / v.flow_core_radius, v.flow_core_radius / rho)
            c = wp.vec2(-d[1], d[0]) * (v.flow_strength * profile / rho)
    elif v.flow_kind == FLOW_GRID:
        rows = world.flow_grid.shape[1]
        cols = world.flow_grid.shape[2]
        # Cell centres sit at half cells: the four around `pos` and the weights, wrapped round the torus.
        u = pos[0] * float(cols) / world.width - 0.5
        r = pos[1] * float(rows) / world.height - 0.5
        j0f = wp.floor(u)
        i0f = wp.floor(r)
        fx = u - j0f
        fy = r - i0f
        j0 = (int(j0f) + cols) % cols
        i0 = (int(i0f) + rows) % rows
        j1 = (j0 + 1) % cols
        i1 = (i0 + 1) % rows
        k = v.flow_grid
        cells = world.flow_grid
        c = (
            ((1.0 - fx) * (1.0 - fy)) * cells[k, i0, j0]
            + (fx * (1.0 - fy)) * cells[k, i0, j1]
            + ((1.0 - fx) * fy) * cells[k, i1, j0]
            + (fx * fy) * cells[k, i1, j1]
        )
    if v.flow_amplitude != 0.0:
        c = c * (1.0 + v.flow_amplitude * wp.sin(2.0 * wp.pi * float(t) / v.flow_period))
    return c


@wp.func
def ego_components(h: wp.vec2, u: wp.vec2) -> wp.vec2:
    """`u` in the ego frame of an agent heading `h` (a unit vector): (u . f, u . r) on its forward
    axis f = h and its right axis r = (-h_y, h_x) (h turned 90 degrees clockwise on screen, y down)."""
    return wp.vec2(h[0] * u[0] + h[1] * u[1], h[0] * u[1] - h[1] * u[0])


@wp.func
def ego_to_world(h: wp.vec2, a: wp.vec2) -> wp.vec2:
    """The world direction of `a`, a direction in the action table's screen convention ((sin t, -cos t):
    t clockwise from up), read as t clockwise from the forward axis of an agent heading `h`:
    cos(t) f + sin(t) r."""
    return wp.vec2(-a[1] * h[0] - a[0] * h[1], a[0] * h[0] - a[1] * h[1])


@wp.func
def world_to_ego(h: wp.vec2, d: wp.vec2) -> wp.vec2:
    """The inverse of `ego_to_world`: world direction `d` in the action table's screen convention
    relative to heading `h`, (d . r, -(d . f)), so that forward reads as "up" (action 0)."""
    e = ego_components(h, d)
    return wp.vec2(e[1], -e[0])


@wp.func
def angle_value(v: wp.vec2) -> float:
    """The reference's angle -atan2(y, x) in degrees, mapped from [-180, 180] to [0, 1]."""
    return 0.5 - wp.atan2(v[1], v[0]) / (2.0 * wp.pi)


_MIX_1 = wp.constant(wp.uint32(0x85EBCA6B))
_MIX_2 = wp.constant(wp.uint32(0xC2B2AE35))
# ------------------------------------------------------------------------------------------------ random streams
_GOLDEN = wp.constant(wp.uint32(0x9E3779B9))


@wp.func
def mix32(h: wp.uint32) -> wp.uint32:
    """Murmur3 finaliser: a bijective avalanche of 32 bits."""
    h = h ^ (h >> wp.uint32(16))
    h = h * _MIX_1
    h = h ^ (h >> wp.uint32(13))
    h = h * _MIX_2
    h = h ^ (h >> wp.uint32(16))
    return h


@wp.func
def random_stream(seed: wp.uint32, world: int, episode: int, step: int, slot: int, purpose: int) -> wp.uint32:
    """State of a counter-based random stream keyed by (seed, world, episode, step, slot, purpose):
    integer arithmetic only, so CPU and GPU draw the same numbers."""
    h = mix32(seed ^ _GOLDEN)
    h = mix32(h ^ wp.uint32(world))
    h = mix32(h ^ wp.uint32(episode))
    h = mix32(h ^ wp.uint32(step))
    h = mix32(h ^ wp.uint32(slot))
    h = mix32(h ^ wp.uint32(purpose))
    return h
