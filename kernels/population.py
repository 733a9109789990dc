"""MODEL.md steps 7-9: reproduction, survival rewards, episode end and auto-reset (starvation, step 6,
is counted in `capture.py`'s share pass, which already visits every predator).

Per-world counts change through integer atomics (exact in any order); per-world float sums are
taken by one thread per world in slot order, so they are deterministic too.
"""

import warp as wp

from .common import PREY, PURPOSE_NEWBORN, WorldParams, random_stream, slot_type
from .spawn import make_fresh_prey, spawn_slot

wp.set_module_options({"enable_backward": False})


@wp.kernel
def reproduce_prey(
    world: WorldParams,
    world_step: wp.array(dtype=wp.int32),
    episode: wp.array(dtype=wp.int32),
    captured: wp.array2d(dtype=wp.bool),
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
    prey_alive_count: wp.array(dtype=wp.int32),
):
    """One thread per world: parents in slot order; each child takes the lowest slot that was free at
    the start of the step (a prey removed this step does not free its slot until the next step)."""
    w = wp.tid()
    live = prey_alive_count[w]
    free = int(0)
    for parent in range(world.prey_capacity):
        if live >= world.max_prey:
            break
        if alive[w, parent] and age[w, parent] >= replication_age[w, parent]:
            while free < world.prey_capacity and (alive[w, free] or captured[w, free]):
                free += 1
            if free < world.prey_capacity:
                child = free
                rng = random_stream(world.seed, world.world_offset + w, episode[w], world_step[w] + 1, child, PURPOSE_NEWBORN)
                make_fresh_prey(world, w, child, position[w, parent], rng, alive, position, velocity,
                                acceleration, heading, age, replication_age, starvation)
                velocity[w, child] = wp.vec2(0.0, 0.0)
                age[w, parent] = 0
                live += 1
    prey_alive_count[w] = live


@wp.kernel
def collect_rewards(
    world: WorldParams,
    alive: wp.array2d(dtype=wp.bool),
    reward: wp.array2d(dtype=float),
    episode_return: wp.array2d(dtype=float),
):
    """Survival reward for every live prey (newborns included), then the per-slot episode sums."""
    w, i = wp.tid()
    r = reward[w, i]
    if slot_type(world, i) == PREY and alive[w, i]:
        r = r + world.prey_reward
        reward[w, i] = r
    episode_return[w, i] = episode_return[w, i] + r


@wp.kernel
def finish_world_step(
    world: WorldParams,
    captures: wp.array(dtype=wp.int32),
    episode_return: wp.array2d(dtype=float),
    world_step: wp.array(dtype=wp.int32),
    episode: wp.array(dtype=wp.int32),
    episode_captures: wp.array(dtype=wp.int32),
    prey_alive_count: wp.array(dtype=wp.int32),
    predator_alive_count: wp.array(dtype=wp.int32),
    episode_ended: wp.array(dtype=wp.bool),
    ended_length: wp.array(dtype=wp.int32),
    ended_captures: wp.array(dtype=wp.int32),
    ended_return: wp.array2d(dtype=float),
):
    """Advance the world's step counter; end the episode at `max_steps` or when a type is extinct,
    report its statistics, and start the counters of the next episode."""
    w = wp.tid()
    step = world_step[w] + 1
    total_captures = episode_captures[w] + captures[w]
    ended = step >= world.max_steps or prey_alive_count[w] == 0 or predator_alive_count[w] == 0
    episode_ended[w] = ended
    if not ended:
        world_step[w] = step
        episode_captures[w] = total_captures
        return
    ended_length[w] = step
    ended_captures[w] = total_captures
    prey_sum = float(0.0)
    predator_sum = float(0.0)
    for i in range(world.capacity):
        if i < world.prey_capacity:
            prey_sum += episode_return[w, i]
        else:
            predator_sum += episode_return[w, i]
    ended_return[w, 0] = predator_sum
    ended_return[w, 1] = prey_sum
    if world.auto_reset == 0:
        # The world stays as it ended (an explicit reset starts the next episode).
        world_step[w] = step
        episode_captures[w] = total_captures
        return
    world_step[w] = 0
    episode[w] = episode[w] + 1
    episode_captures[w] = 0
    prey_alive_count[w] = world.prey_count
    predator_alive_count[w] = world.predator_count


@wp.kernel
def close_ended_episodes(
    world: WorldParams,
    episode: wp.array(dtype=wp.int32),
    episode_ended: wp.array(dtype=wp.bool),
    alive: wp.array2d(dtype=wp.bool),
    position: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    acceleration: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    age: wp.array2d(dtype=wp.int32),
    replication_age: wp.array2d(dtype=wp.int32),
    starvation: wp.array2d(dtype=wp.int32),
    truncated: wp.array2d(dtype=wp.bool),
    episode_return: wp.array2d(dtype=float),
):
    """Every agent still alive when its world's episode ends is truncated and the slot's sums
    restart; with auto-reset the world's next episode starts here."""
    w, i = wp.tid()
    if not episode_ended[w]:
        return
    if alive[w, i]:
        truncated[w, i] = True
    episode_return[w, i] = 0.0
    if world.auto_reset != 0:
        spawn_slot(world, w, i, episode[w], alive, position, velocity, acceleration, heading, age,
                   replication_age, starvation)
