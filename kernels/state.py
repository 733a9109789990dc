"""The simulation state as typed groups: Warp structs of arrays that kernels take whole.

A kernel signature names the groups it works on (`agents: Agents`, `outputs: StepOutputs`), not the
dozen arrays inside them; a struct of arrays is passed by value, which copies the array descriptors
(pointer, shape, strides), never the data. `aquarium_warp.state.SimulationState` allocates one instance of each
group per batch of worlds and views the same arrays as torch tensors.

Shapes use W worlds, C = capacity agent slots per world (prey slots `[0, Pc)` with Pc = prey_capacity,
then the P predator slots), L the observation length of a type and K = predator_slots + prey_slots
of a type's observations. Each field's docstring gives its shape, dtype and unit.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.struct
class Agents:
    """Per-slot state of every agent (docs/model.md "World and agents"). A dead slot's values are stale."""

    position: wp.array2d(dtype=wp.vec2)
    """[W, C] vec2 float32, px, in [0, width) x [0, height)."""
    velocity: wp.array2d(dtype=wp.vec2)
    """[W, C] vec2 float32, px/step."""
    acceleration: wp.array2d(dtype=wp.vec2)
    """[W, C] vec2 float32, px/step^2, carried between steps (the acceleration's memory)."""
    heading: wp.array2d(dtype=wp.vec2)
    """[W, C] vec2 float32, unit vector of the last non-zero velocity."""
    alive: wp.array2d(dtype=wp.bool)
    """[W, C] bool, the slot holds a live agent."""
    age: wp.array2d(dtype=wp.int32)
    """[W, C] int32, steps; prey: since birth or the last reproduction."""
    replication_age: wp.array2d(dtype=wp.int32)
    """[W, C] int32, steps; prey: the age at which it reproduces."""
    starvation: wp.array2d(dtype=wp.int32)
    """[W, C] int32, steps; predators: since the last capture."""
    handling: wp.array2d(dtype=wp.int32)
    """[W, C] int32, steps; predators under the confusion capture rule: left of the handling time after a
    failed attack, during which the predator cannot attack (0: it may attack); 0 under density dilution."""


@wp.struct
class WorldCounters:
    """Per-world episode counters, and the random streams' key: all device data, so a reset or a
    reseed is a write into these arrays, never a new recording of the launches."""

    world_step: wp.array(dtype=wp.int32)
    """[W] int32, steps taken in the current episode."""
    episode: wp.array(dtype=wp.int32)
    """[W] int32, index of the current episode (keys the random streams)."""
    episode_captures: wp.array(dtype=wp.int32)
    """[W] int32, captures so far in the current episode."""
    prey_alive_count: wp.array(dtype=wp.int32)
    """[W] int32, live prey."""
    predator_alive_count: wp.array(dtype=wp.int32)
    """[W] int32, live predators."""
    episode_return: wp.array2d(dtype=float)
    """[W, C] float32, reward summed over the current episode, per slot."""
    seed: wp.array(dtype=wp.uint32)
    """[W] uint32, key of the world's random streams (`seeding.seed_key` of the seed of its group of worlds)."""
    stream_world: wp.array(dtype=wp.int32)
    """[W] int32, the world's index in its random streams: its index within its seed's group of worlds
    (the batch, or one of the equal groups of a batch given several seeds: `seeding.seed_groups`)."""


@wp.struct
class Actions:
    """The step's inputs: one action index per slot, in [0, action_count) (dead slots' are ignored)."""

    prey_action: wp.array2d(dtype=wp.int32)
    """[W, Pc] int32, action of each prey slot."""
    predator_action: wp.array2d(dtype=wp.int32)
    """[W, P] int32, action of each predator."""


@wp.struct
class StepOutputs:
    """What one step reports (besides the observations); cleared at the start of every step."""

    reward: wp.array2d(dtype=float)
    """[W, C] float32, this step's reward per slot."""
    terminated: wp.array2d(dtype=wp.bool)
    """[W, C] bool, the agent died in this step (captured without respawn, or starved)."""
    truncated: wp.array2d(dtype=wp.bool)
    """[W, C] bool, the agent was alive when its world's episode ended in this step."""
    captures: wp.array(dtype=wp.int32)
    """[W] int32, captures in this step."""
    episode_ended: wp.array(dtype=wp.bool)
    """[W] bool, the world's episode ended in this step."""
    ended_length: wp.array(dtype=wp.int32)
    """[W] int32, steps of the episode that ended (valid where `episode_ended`)."""
    ended_captures: wp.array(dtype=wp.int32)
    """[W] int32, captures of the episode that ended (valid where `episode_ended`)."""
    ended_return: wp.array2d(dtype=float)
    """[W, 2] float32, its reward summed over agents: [:, 0] predators, [:, 1] prey (where `episode_ended`)."""


@wp.struct
class Observations:
    """Observations of the state after a step (docs/model.md step 10), per observer type."""

    obs_prey: wp.array3d(dtype=float)
    """[W, Pc, L_prey] float32, in [0, 1] (or [-1, 1]); rows of dead slots are zero."""
    obs_predator: wp.array3d(dtype=float)
    """[W, P, L_predator] float32."""
    mask_prey: wp.array3d(dtype=wp.bool)
    """[W, Pc, K_prey] bool, the observed-neighbour slot is filled."""
    mask_predator: wp.array3d(dtype=wp.bool)
    """[W, P, K_predator] bool."""
    slot_prey: wp.array3d(dtype=wp.int32)
    """[W, Pc, K_prey] int32, slot of each observed neighbour, -1 where empty."""
    slot_predator: wp.array3d(dtype=wp.int32)
    """[W, P, K_predator] int32."""


@wp.struct
class Scratch:
    """Values that pass from one kernel of the step to a later one."""

    captured: wp.array2d(dtype=wp.bool)
    """[W, C] bool, prey captured in this step."""
    share_count: wp.array2d(dtype=wp.int32)
    """[W, C] int32, predators sharing the capture of each captured prey."""
    caught_prey: wp.array2d(dtype=wp.int32)
    """[W, C] int32, predator slots under the confusion capture rule: the prey slot its attack captured in
    this step, or -1 (written by every live predator of such a world; unused under density dilution)."""
    contact_partner: wp.array2d(dtype=wp.int32)
    """[W, C] int32, slot of the overlapping same-type agent (docs/model.md step 3), or -1; found by the
    observation pass for the next step's motion."""
    contact_offset: wp.array2d(dtype=wp.vec2)
    """[W, C] vec2 float32, px, torus displacement from that partner to the agent."""
