"""docs/model.md steps 7-9: reproduction, episode end and auto-reset (starvation, step 6, is counted in
`capture.py`'s share pass, which already visits every predator).

Step 8's rewards are finished by the passes that already visit each slot, not by a pass of their own:
`capture.py`'s share pass adds each predator's reward to its episode sum, its respawn pass gives
each prey slot still alive its survival reward and adds the prey's reward to its episode sum, and
`reproduce` does both for each newborn (whose slot the respawn pass saw dead, with this step's reward
0, which `move_agent` cleared).

Per-world counts change through integer atomics (exact in any order); per-world float sums are
taken by one thread per world in slot order, so they are deterministic too.
"""

import warp as wp

from .common import PURPOSE_NEWBORN, WorldParams
from .spawn import finishing_step_stream, make_fresh_prey, spawn_slot
from .state import Agents, Scratch, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})


@wp.func
def reproduce(
    world: WorldParams, scratch: Scratch, agents: Agents, outputs: StepOutputs, counters: WorldCounters, w: int
):
    """World w's births, by one thread: parents in slot order; each child takes the lowest slot that
    was free at the start of the step (a prey removed this step does not free its slot until the next
    step), and gets its survival reward, which goes into its slot's episode sum (the respawn pass
    already added the slot's reward before the birth, 0: the sum is the same as adding 0 + the
    survival reward once, bit for bit)."""
    live = counters.prey_alive_count[w]
    free = int(0)
    for parent in range(world.prey_capacity):
        if live >= world.max_prey:
            break
        if agents.alive[w, parent] and agents.age[w, parent] >= agents.replication_age[w, parent]:
            while free < world.prey_capacity and (agents.alive[w, free] or scratch.captured[w, free]):
                free += 1
            if free < world.prey_capacity:
                child = free
                rng = finishing_step_stream(world, counters, w, child, PURPOSE_NEWBORN)
                make_fresh_prey(world, w, child, agents.position[w, parent], rng, agents)
                agents.velocity[w, child] = wp.vec2(0.0, 0.0)
                agents.age[w, parent] = 0
                r = outputs.reward[w, child] + world.values[w].prey_reward
                outputs.reward[w, child] = r
                counters.episode_return[w, child] = counters.episode_return[w, child] + r
                live += 1
    counters.prey_alive_count[w] = live


@wp.func
def start_next_episode(world: WorldParams, counters: WorldCounters, w: int):
    """World w's counters at the start of its next episode (its slots are spawned by `spawn_slot` with
    the new episode number)."""
    counters.world_step[w] = 0
    counters.episode[w] = counters.episode[w] + 1
    counters.episode_captures[w] = 0
    counters.prey_alive_count[w] = world.values[w].prey_count
    counters.predator_alive_count[w] = world.values[w].predator_count


@wp.func
def finish_step(world: WorldParams, counters: WorldCounters, outputs: StepOutputs, w: int):
    """Advance world w's step counter; end the episode at `max_steps` or when a type is extinct,
    report its statistics, and start the counters of the next episode (one thread per world)."""
    step = counters.world_step[w] + 1
    total_captures = counters.episode_captures[w] + outputs.captures[w]
    ended = step >= world.max_steps or counters.prey_alive_count[w] == 0 or counters.predator_alive_count[w] == 0
    outputs.episode_ended[w] = ended
    if not ended:
        counters.world_step[w] = step
        counters.episode_captures[w] = total_captures
        return
    outputs.ended_length[w] = step
    outputs.ended_captures[w] = total_captures
    prey_sum = float(0.0)
    predator_sum = float(0.0)
    for i in range(world.capacity):
        if i < world.prey_capacity:
            prey_sum += counters.episode_return[w, i]
        else:
            predator_sum += counters.episode_return[w, i]
    outputs.ended_return[w, 0] = predator_sum
    outputs.ended_return[w, 1] = prey_sum
    if world.auto_reset == 0:
        # The world stays as it ended (an explicit reset, or `restart_worlds`, starts the next episode).
        counters.world_step[w] = step
        counters.episode_captures[w] = total_captures
        return
    start_next_episode(world, counters, w)


@wp.func
def close_episode(world: WorldParams, counters: WorldCounters, outputs: StepOutputs, agents: Agents, w: int, i: int):
    """If world w's episode ended, slot i's agent (if still alive) is truncated and the slot's sums
    restart; with auto-reset the world's next episode starts here."""
    if not outputs.episode_ended[w]:
        return
    if agents.alive[w, i]:
        outputs.truncated[w, i] = True
    counters.episode_return[w, i] = 0.0
    if world.auto_reset != 0:
        spawn_slot(world, counters, w, i, counters.episode[w], agents)


# The steps as kernels (the staged step).


@wp.kernel
def reproduce_prey(world: WorldParams, scratch: Scratch, agents: Agents, outputs: StepOutputs, counters: WorldCounters):
    """`reproduce`, one thread per world."""
    reproduce(world, scratch, agents, outputs, counters, wp.tid())


@wp.kernel
def finish_world_step(world: WorldParams, counters: WorldCounters, outputs: StepOutputs):
    """`finish_step`, one thread per world."""
    finish_step(world, counters, outputs, wp.tid())


@wp.kernel
def restart_worlds(world: WorldParams, restart: wp.array(dtype=wp.bool), counters: WorldCounters, agents: Agents):
    """The worlds flagged in `restart` (ended, without auto-reset) start their next episode as auto-reset
    starts it inside the step (`finish_step`, `close_episode`): the same counters and spawns, so the
    same trajectory follows; one thread per world (its slots in order, after the counters)."""
    w = wp.tid()
    if not restart[w]:
        return
    start_next_episode(world, counters, w)
    for i in range(world.capacity):
        spawn_slot(world, counters, w, i, counters.episode[w], agents)


@wp.kernel
def close_ended_episodes(world: WorldParams, counters: WorldCounters, outputs: StepOutputs, agents: Agents):
    """`close_episode` for every slot."""
    w, i = wp.tid()
    close_episode(world, counters, outputs, agents, w, i)
