"""docs/model.md steps 1-4: steering, acceleration with memory, same-type contact, speed clamp, wrap.

All agents read the start-of-step state; each thread writes only its own slot. The contact partner
(step 3) comes precomputed from the neighbour pass in `observation.py`, which runs on the same
start-of-step positions at the end of the previous step (or after a reset or `set_state`).
"""

import functools

import warp as wp

from .common import FLOW_NONE, PREY, AgentType, WorldParams, current, ego_to_world, slot_type, wrap_coordinate
from .state import Actions, Agents, Scratch, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})

# Vector lengths below this have squares (< 1e-36) near float32's subnormal range (< 1.2e-38), where
# squaring loses precision or gives 0.
SHORTEST_SQUARABLE = wp.constant(1.0e-18)


@wp.func
def rescaled(v: wp.vec2) -> wp.vec2:
    """`v` divided by its larger component's magnitude (exact zero stays zero): the same direction with
    a length in [1, sqrt(2)], which squares exactly, for vectors shorter than SHORTEST_SQUARABLE, whose
    length is inexact (or 0) in float32."""
    largest = wp.max(wp.abs(v[0]), wp.abs(v[1]))
    if largest > 0.0:
        return v / largest
    return v


@wp.func
def clamp_length(v: wp.vec2, limit: float) -> wp.vec2:
    n = wp.length(v)
    if n > limit:
        return v * (limit / n)
    return v


@functools.cache
def motion_stage(ego_actions: bool):
    """`(move_agent, integrate_motion)`: the motion of one slot and its kernel, for actions in the world
    frame or (`ego_actions`, `action_frame="ego"`) turned by the start-of-step heading, decided at compile
    time so that the world frame's step carries no trace of the option. The fused step
    (`world_step.py`) calls the same `move_agent`.

    `move_agent(world, types, action_direction, actions, counters, agents, scratch, outputs, w, i)`
    moves slot i of world w if it is live (reads its contact partner in `scratch`), and clears its
    outputs and capture flag for this step; `integrate_motion` runs it for every slot."""

    def move_agent(
        world: WorldParams,
        types: wp.array2d(dtype=AgentType),
        action_direction: wp.array(dtype=wp.vec2),
        actions: Actions,
        counters: WorldCounters,
        agents: Agents,
        scratch: Scratch,
        outputs: StepOutputs,
        w: int,
        i: int,
    ):
        """Moves slot i of world w if it is live (reads its contact partner in `scratch`), and clears its
        outputs and capture flag for this step."""
        # This step's outputs start cleared (here rather than in separate memsets).
        outputs.reward[w, i] = 0.0
        outputs.terminated[w, i] = False
        outputs.truncated[w, i] = False
        scratch.captured[w, i] = False
        if i == 0:
            outputs.captures[w] = 0
        if not agents.alive[w, i]:
            return
        t = slot_type(world, i)
        p = types[w, t]

        # 1. Steering towards the action's desired velocity (paper eqs. 1 and 6).
        action = int(0)
        if t == PREY:
            action = int(actions.prey_action[w, i])
        else:
            action = int(actions.predator_action[w, i - world.prey_capacity])
        # `step(validate=False)` skips the host's range check: a clamp (no branch) keeps any action index
        # inside the direction table, so a bad action steers to the nearest end of the range instead of
        # reading out of bounds.
        action = wp.clamp(action, 0, world.action_count - 1)
        aim = action_direction[action]
        if wp.static(ego_actions):  # the action's angle is taken from the start-of-step heading
            aim = ego_to_world(agents.heading[w, i], aim)
        desired = aim * p.max_speed
        v = agents.velocity[w, i]
        steering_force = clamp_length(desired - v, p.max_steering_force)

        # 2. Acceleration with memory: the running sum is renormalised to k (paper eq. 2).
        acc = agents.acceleration[w, i] + steering_force / p.mass
        n = wp.length(acc)
        if n < SHORTEST_SQUARABLE:  # rare: a fresh agent's tiny steering force, or a near-exact cancellation
            acc = rescaled(acc)
            n = wp.length(acc)
        if n > 0.0:
            acc = acc * (p.max_acceleration / n)

        # 3. Same-type contact: the nearest overlapping agent of the same type pushes this one away. The
        # partner was found by the observation pass on these same start-of-step positions.
        v_new = v + acc
        if scratch.contact_partner[w, i] >= 0:
            offset = scratch.contact_offset[w, i]
            v_new = v
            if offset[0] != 0.0 or offset[1] != 0.0:
                v_new = v + wp.normalize(offset) * p.bounce_strength

        # 4. Speed clamp (paper eq. 3) and wrap onto the torus (eq. 4); a flow's current adds to the
        # displacement only (docs/model.md "Flow fields"), at the start-of-step position and step counter.
        v_new = clamp_length(v_new, p.max_speed)
        pos = agents.position[w, i]
        moved = pos + v_new
        values = world.values[w]
        if values.flow_kind != FLOW_NONE:  # no add of a zero current: "none" keeps every bit as before
            moved = moved + current(world, values, pos, counters.world_step[w])
        agents.position[w, i] = wp.vec2(wrap_coordinate(moved[0], world.width), wrap_coordinate(moved[1], world.height))
        agents.velocity[w, i] = v_new
        agents.acceleration[w, i] = acc
        speed = wp.length(v_new)
        if speed >= SHORTEST_SQUARABLE:
            agents.heading[w, i] = v_new / speed
        else:  # rare: a tiny velocity kept by a contact with bounce strength 0 (or set so)
            direction = rescaled(v_new)
            n_direction = wp.length(direction)
            if n_direction > 0.0:
                agents.heading[w, i] = direction / n_direction

    def integrate_motion(
        world: WorldParams,
        types: wp.array2d(dtype=AgentType),
        action_direction: wp.array(dtype=wp.vec2),
        actions: Actions,
        counters: WorldCounters,
        agents: Agents,
        scratch: Scratch,
        outputs: StepOutputs,
    ):
        """Moves every live agent (`move_agent`), one thread per slot."""
        w, i = wp.tid()
        move_agent(world, types, action_direction, actions, counters, agents, scratch, outputs, w, i)

    move_agent = wp.func(move_agent, module="unique")
    integrate_motion = wp.kernel(enable_backward=False, module="unique", name="integrate_motion")(integrate_motion)
    return move_agent, integrate_motion
