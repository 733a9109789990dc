"""Fresh agents: the initial state of an episode, a respawned prey and a newborn (docs/model.md
"Randomness" and "Details"). Every draw comes from a counter-based stream, so it is reproducible."""

import warp as wp

from .common import PREY, PURPOSE_HEADING, PURPOSE_SPAWN, WorldParams, mix32, random_stream, slot_type
from .state import Agents, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})


@wp.func
def finishing_step_stream(world: WorldParams, counters: WorldCounters, w: int, slot: int, purpose: int) -> wp.uint32:
    """Random stream of `slot` in world w for a draw made while finishing the step being taken (a
    capture, a respawn, a newborn): keyed by the step's new counter, t + 1 (docs/model.md, Randomness)."""
    return random_stream(
        counters.seed[w], counters.stream_world[w], counters.episode[w], counters.world_step[w] + 1, slot, purpose
    )


@wp.func
def draw_replication_age(world: WorldParams, w: int, rng: wp.uint32) -> int:
    """Integer uniform in [ceil(0.75 R), floor(1.25 R)] for R = world w's prey_replication_age."""
    values = world.values[w]
    return wp.randi(rng, values.replication_age_min, values.replication_age_max + 1)


@wp.func
def fresh_heading(world: WorldParams, rng: wp.uint32, paper: wp.vec2) -> wp.vec2:
    """A fresh agent's heading: `paper` (prey west, predators north), or with `spawn_heading="random"`
    a uniform direction (cos phi, sin phi), phi drawn from a stream derived from the agent's own
    (`rng`), so that the paper layout's draws stay as they are."""
    if world.random_spawn_heading == 0:
        return paper
    heading_rng = mix32(rng ^ wp.uint32(PURPOSE_HEADING))
    phi = wp.randf(heading_rng, 0.0, 2.0 * wp.pi)
    return wp.vec2(wp.cos(phi), wp.sin(phi))


@wp.func
def make_fresh_prey(
    world: WorldParams,
    w: int,
    i: int,
    pos: wp.vec2,
    rng: wp.uint32,
    agents: Agents,
):
    """A prey at `pos` moving at speed min(1, max_speed) along its fresh heading (west in the paper), as
    at the start of an episode; keeps only its slot."""
    h = fresh_heading(world, rng, wp.vec2(-1.0, 0.0))
    set_slot(agents, w, i, True, pos, h * world.values[w].prey_spawn_speed, h, draw_replication_age(world, w, rng))


@wp.func
def set_slot(
    agents: Agents,
    w: int,
    i: int,
    alive: bool,
    position: wp.vec2,
    velocity: wp.vec2,
    heading: wp.vec2,
    replication_age: int,
):
    """Slot i of world w as a fresh agent (or an empty slot): zero acceleration, age, starvation and
    handling time."""
    agents.alive[w, i] = alive
    agents.position[w, i] = position
    agents.velocity[w, i] = velocity
    agents.acceleration[w, i] = wp.vec2(0.0, 0.0)
    agents.heading[w, i] = heading
    agents.age[w, i] = 0
    agents.replication_age[w, i] = replication_age
    agents.starvation[w, i] = 0
    agents.handling[w, i] = 0


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
def spawn_slot(world: WorldParams, counters: WorldCounters, w: int, i: int, episode: int, agents: Agents):
    """Slot i of world w at the start of its episode `episode`: prey uniform 20 px inside the edges
    moving west, predators uniform anywhere moving north (or both along a random heading:
    `fresh_heading`), at speed min(1, max_speed), zero acceleration; prey slots past
    the world's `prey_count` and predator slots past its `predator_count` empty."""
    rng = random_stream(counters.seed[w], counters.stream_world[w], episode, 0, i, PURPOSE_SPAWN)
    values = world.values[w]
    if slot_type(world, i) == PREY:
        if i < values.prey_count:
            make_fresh_prey(world, w, i, uniform_position(world, rng, 20.0), rng, agents)
        else:
            set_slot(agents, w, i, False, wp.vec2(0.0, 0.0), wp.vec2(0.0, 0.0), wp.vec2(-1.0, 0.0), 0)
    elif i - world.prey_capacity < values.predator_count:
        h = fresh_heading(world, rng, wp.vec2(0.0, -1.0))
        set_slot(agents, w, i, True, uniform_position(world, rng, 0.0), h * values.predator_spawn_speed, h, 0)
    else:
        set_slot(agents, w, i, False, wp.vec2(0.0, 0.0), wp.vec2(0.0, 0.0), wp.vec2(0.0, -1.0), 0)


@wp.kernel
def spawn_episode(world: WorldParams, counters: WorldCounters, outputs: StepOutputs, agents: Agents):
    """Every world's first episode (a reset): its counters at zero and its agents as `spawn_slot` makes
    them (the seed in `counters.seed` is kept); auto-reset inside a step goes through
    `population.close_ended_episodes`."""
    w, i = wp.tid()
    counters.episode_return[w, i] = 0.0
    if i == 0:
        counters.world_step[w] = 0
        counters.episode[w] = 0
        counters.episode_captures[w] = 0
        counters.prey_alive_count[w] = world.values[w].prey_count
        counters.predator_alive_count[w] = world.values[w].predator_count
        outputs.episode_ended[w] = False
    spawn_slot(world, counters, w, i, 0, agents)
