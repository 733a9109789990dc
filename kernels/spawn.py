"""Fresh agents: the initial state of an episode, a respawned prey and a newborn (MODEL.md
"Randomness" and "Details"). Every draw comes from a counter-based stream, so it is reproducible."""

import warp as wp

from .common import PREY, PURPOSE_SPAWN, WorldParams, random_stream, slot_type

wp.set_module_options({"enable_backward": False})


@wp.func
def draw_replication_age(world: WorldParams, rng: wp.uint32) -> int:
    """Integer uniform in [ceil(0.75 R), floor(1.25 R)] for R = prey_replication_age."""
    return wp.randi(rng, world.replication_age_min, world.replication_age_max + 1)


@wp.func
def make_fresh_prey(
    world: WorldParams,
    w: int,
    i: int,
    pos: wp.vec2,
    rng: wp.uint32,
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
):
    """A prey at `pos` moving west at speed 1, as at the start of an episode; keeps only its slot."""
    alive[w, i] = True
    position[w, i] = pos
    velocity[w, i] = wp.vec2(-1.0, 0.0)
    acceleration[w, i] = wp.vec2(0.0, 0.0)
    heading[w, i] = wp.vec2(-1.0, 0.0)
    age[w, i] = 0
    replication_age[w, i] = draw_replication_age(world, rng)
    starvation[w, i] = 0


@wp.func
def uniform_position(world: WorldParams, rng: wp.uint32, margin: float) -> wp.vec2:
    """Uniform in [margin, width - margin) x [margin, height - margin)."""
    x = wp.randf(rng, margin, world.width - margin)
    y = wp.randf(rng, margin, world.height - margin)
    # randf's float rounding can reach the upper bound; with margin 0 that bound is the point 0.
    if x >= world.width:
        x = 0.0
    if y >= world.height:
        y = 0.0
    return wp.vec2(x, y)


@wp.func
def spawn_slot(
    world: WorldParams,
    w: int,
    i: int,
    episode: int,
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
):
    """Slot i of world w at the start of an episode: prey uniform 20 px inside the edges moving west,
    predators uniform anywhere moving north, zero acceleration; prey slots past `prey_count` empty."""
    rng = random_stream(world.seed, world.world_offset + w, episode, 0, i, PURPOSE_SPAWN)
    if slot_type(world, i) == PREY:
        if i < world.prey_count:
            pos = uniform_position(world, rng, 20.0)
            make_fresh_prey(world, w, i, pos, rng, alive, position, velocity, acceleration, heading, age,
                            replication_age, starvation)
        else:
            alive[w, i] = False
            position[w, i] = wp.vec2(0.0, 0.0)
            velocity[w, i] = wp.vec2(0.0, 0.0)
            acceleration[w, i] = wp.vec2(0.0, 0.0)
            heading[w, i] = wp.vec2(-1.0, 0.0)
            age[w, i] = 0
            replication_age[w, i] = 0
            starvation[w, i] = 0
    else:
        alive[w, i] = True
        position[w, i] = uniform_position(world, rng, 0.0)
        velocity[w, i] = wp.vec2(0.0, -1.0)
        acceleration[w, i] = wp.vec2(0.0, 0.0)
        heading[w, i] = wp.vec2(0.0, -1.0)
        age[w, i] = 0
        replication_age[w, i] = 0
        starvation[w, i] = 0


@wp.kernel
def spawn_episode(
    world: WorldParams,
    episode: wp.array(dtype=wp.int32),
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
):
    """Initial state of every world's episode (`spawn_slot`); auto-reset inside a step goes through
    `population.close_ended_episodes`."""
    w, i = wp.tid()
    spawn_slot(world, w, i, episode[w], alive, position, velocity, acceleration, heading, age, replication_age,
               starvation)
