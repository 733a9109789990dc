"""docs/model.md steps 5 and 6: captures after the move, reward sharing, starvation, respawn or removal;
and step 8's rewards, which these passes finish (no pass of their own).

Four passes keep every sum deterministic (no float atomics): predators mark the prey they overlap
(contacts); each prey in contact decides whether it is captured (under capture confusion, one draw
against p0 / (1 + c k), k its prey neighbours; a failed attempt clears the mark) and, if captured,
counts its sharers and takes the penalty; each predator sums its shares over the captured prey near
it (in the grid's fixed order), resets its starvation counter if it captured, then starves by one
step; captured prey respawn or are removed last, so the passes before all see the positions of the
capture.

Rewards: a predator's is final at the end of the share pass, which adds it to the slot's episode sum
(every predator slot, dead ones included, whose reward is this step's 0); a prey's is final once it
is respawned or removed: the respawn pass, over every prey slot, adds the survival reward to each prey
alive after it and the prey's reward to its episode sum. (Newborns, made later by
`population.reproduce`, get theirs there.)

The passes search the cell lists of the start-of-step positions (built by the last observation
pass), not cell lists of the moved ones: every agent moved by at most its max speed since, so a
search radius widened by the max speeds (`start_of_step_radius`) finds every pair that is within
the capture, share or confusion radius now, and the exact test uses the moved positions. This saves
a second cell-list build per step. (Whole-world lists hold every slot of the world, so there the
widening changes nothing.)
"""

import warp as wp

from .common import (
    PREDATOR,
    PREY,
    PURPOSE_CAPTURE,
    PURPOSE_RESPAWN,
    AgentType,
    WorldParams,
    slot_type,
    torus_displacement,
)
from .grid import CellLists, listed_slot, next_run, run_entry, run_length, square_walk
from .spawn import finishing_step_stream, make_fresh_prey, uniform_position
from .state import Agents, Scratch, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})


@wp.func
def start_of_step_radius(world: WorldParams, w: int, radius: float, speed: float) -> float:
    """Radius around a moved position that holds, at their start-of-step positions, every agent now
    within `radius` of it, when they moved at most `speed` px plus world w's largest current (plus
    float rounding of the clamped speeds, the current and the wrap)."""
    moved = speed + world.values[w].flow_reach
    return radius + moved * (1.0 + 1.0e-5) + 1.0e-6 * (world.width + world.height)


# Threads per predator in `detect_contacts` on cell lists, each taking every CAPTURE_ROW_THREADS-th
# row of the predator's search square (3 rows at the default sizes): predators are few, so one thread
# each would leave most of a GPU idle while they wait on their candidates' positions. (H200, one world
# of 1M agents: 0.032 -> 0.024 ms.) Whole-world lists are one row: one thread per predator.
CAPTURE_ROW_THREADS = 3


@wp.func
def mark_contacts(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    agents: Agents,
    scratch: Scratch,
    w: int,
    p: int,
    row_thread: int,
    row_threads: int,
):
    """Predator p of world w (if live) marks the prey it overlaps in `scratch.captured` (a contact,
    which `resolve_capture` then turns into a capture or not), searching every `row_threads`-th row of
    its search square from `row_thread` on (concurrent writes of True to one flag agree, so the rows
    need no combining)."""
    i = world.prey_capacity + p
    if not agents.alive[w, i]:
        return
    pos = agents.position[w, i]
    contact = types[w, PREY].radius + types[w, PREDATOR].radius
    walk = square_walk(
        grid,
        w,
        world.capacity,
        pos,
        start_of_step_radius(world, w, contact, types[w, PREY].max_speed),
        row_thread,
        row_threads,
    )
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and slot_type(world, j) == PREY:
                d = torus_displacement(world, pos, agents.position[w, j])
                if wp.dot(d, d) < contact * contact:
                    scratch.captured[w, j] = True


@wp.func
def confusing_prey(
    world: WorldParams, types: wp.array2d(dtype=AgentType), grid: CellLists, agents: Agents, w: int, i: int
) -> int:
    """The number k of other live prey of world w strictly within `confusion_radius` of prey i, all at
    their moved positions."""
    pos = agents.position[w, i]
    radius = world.values[w].confusion_radius
    k = int(0)
    walk = square_walk(
        grid, w, world.capacity, pos, start_of_step_radius(world, w, radius, types[w, PREY].max_speed), 0, 1
    )
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and j != i and slot_type(world, j) == PREY:
                d = torus_displacement(world, pos, agents.position[w, j])
                if wp.dot(d, d) < radius * radius:
                    k += 1
    return k


@wp.func
def capture_draw(world: WorldParams, counters: WorldCounters, w: int, i: int) -> float:
    """Prey slot i's draw u in [0, 1) that decides its contact in the step being finished."""
    return wp.randf(finishing_step_stream(world, counters, w, i, PURPOSE_CAPTURE))


@wp.func
def resolve_capture(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    agents: Agents,
    scratch: Scratch,
    outputs: StepOutputs,
    counters: WorldCounters,
    w: int,
    i: int,
):
    """Prey slot i of world w, if in contact with a predator, is captured with probability
    p0 / (1 + c k) (`confusing_prey`; no draw at p0 = 1, c = 0, where every contact captures); a failed
    attempt clears its flag, so the later passes see only captures. A captured prey counts its sharers
    (`scratch.share_count`) and takes the penalty; a live prey not captured ages by one."""
    if not agents.alive[w, i]:
        return
    values = world.values[w]
    if scratch.captured[w, i] and (values.capture_probability < 1.0 or values.capture_confusion > 0.0):
        chance = values.capture_probability
        if values.capture_confusion > 0.0:
            chance = chance / (1.0 + values.capture_confusion * float(confusing_prey(world, types, grid, agents, w, i)))
        if capture_draw(world, counters, w, i) >= chance:
            scratch.captured[w, i] = False
    if not scratch.captured[w, i]:
        agents.age[w, i] = agents.age[w, i] + 1
        return
    pos = agents.position[w, i]
    contact = types[w, PREY].radius + types[w, PREDATOR].radius
    share = wp.max(values.catch_share_radius, contact)
    sharers = int(0)
    radius = start_of_step_radius(world, w, share, types[w, PREDATOR].max_speed)
    walk = square_walk(grid, w, world.capacity, pos, radius, 0, 1)
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and slot_type(world, j) == PREDATOR:
                d = torus_displacement(world, pos, agents.position[w, j])
                d2 = wp.dot(d, d)
                if d2 < contact * contact or d2 < values.catch_share_radius * values.catch_share_radius:
                    sharers += 1
    scratch.share_count[w, i] = sharers
    outputs.reward[w, i] = -values.prey_capture_penalty
    wp.atomic_add(outputs.captures, w, 1)


@wp.func
def share_rewards(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    scratch: Scratch,
    agents: Agents,
    outputs: StepOutputs,
    counters: WorldCounters,
    w: int,
    p: int,
):
    """Predator p of world w (if live) sums its shares of this step's captures (in the lists' order);
    then docs/model.md step 6: a capture resets its steps-since-last-capture counter, which then grows by
    one; past the limit it dies. Its reward (this step's 0 for a dead predator) then goes into its
    episode sum."""
    i = world.prey_capacity + p
    if not agents.alive[w, i]:
        counters.episode_return[w, i] = counters.episode_return[w, i] + outputs.reward[w, i]
        return
    pos = agents.position[w, i]
    contact = types[w, PREY].radius + types[w, PREDATOR].radius
    values = world.values[w]
    share = wp.max(values.catch_share_radius, contact)
    total = float(0.0)
    is_capturer = bool(False)
    walk = square_walk(
        grid, w, world.capacity, pos, start_of_step_radius(world, w, share, types[w, PREY].max_speed), 0, 1
    )
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and slot_type(world, j) == PREY:
                if scratch.captured[w, j]:
                    d = torus_displacement(world, pos, agents.position[w, j])
                    d2 = wp.dot(d, d)
                    inside_share = d2 < values.catch_share_radius * values.catch_share_radius
                    if d2 < contact * contact:
                        is_capturer = True
                    if inside_share or d2 < contact * contact:
                        total += values.predator_reward / float(scratch.share_count[w, j])
    outputs.reward[w, i] = total
    counters.episode_return[w, i] = counters.episode_return[w, i] + total
    hunger = agents.starvation[w, i] + 1
    if is_capturer:
        hunger = 1
    agents.starvation[w, i] = hunger
    if hunger > values.predator_starvation_steps:
        agents.alive[w, i] = False
        outputs.terminated[w, i] = True
        wp.atomic_add(counters.predator_alive_count, w, -1)


@wp.func
def respawn_or_remove(
    world: WorldParams, scratch: Scratch, counters: WorldCounters, agents: Agents, outputs: StepOutputs, w: int, i: int
):
    """Prey slot i of world w, if captured, reappears as a fresh prey at a uniform position, or is
    removed and terminated; then docs/model.md step 8 for the slot: a prey alive now gets its survival
    reward, and the slot's reward goes into its episode sum."""
    if scratch.captured[w, i]:
        if world.respawn_captured_prey != 0:
            rng = finishing_step_stream(world, counters, w, i, PURPOSE_RESPAWN)
            make_fresh_prey(world, w, i, uniform_position(world, rng, 0.0), rng, agents)
        else:
            agents.alive[w, i] = False
            outputs.terminated[w, i] = True
            wp.atomic_add(counters.prey_alive_count, w, -1)
    r = outputs.reward[w, i]
    if agents.alive[w, i]:
        r = r + world.values[w].prey_reward
        outputs.reward[w, i] = r
    counters.episode_return[w, i] = counters.episode_return[w, i] + r


# The passes as kernels, one thread per slot of the type each pass takes (the staged step).


@wp.kernel
def detect_contacts(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    agents: Agents,
    row_threads: int,
    scratch: Scratch,
):
    """`mark_contacts`, launched with `(worlds, predators, row_threads)` threads."""
    w, p, row_thread = wp.tid()
    mark_contacts(world, types, grid, agents, scratch, w, p, row_thread, row_threads)


@wp.kernel
def resolve_captures(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    counters: WorldCounters,
    agents: Agents,
    scratch: Scratch,
    outputs: StepOutputs,
):
    """`resolve_capture` for every prey slot."""
    w, i = wp.tid()
    resolve_capture(world, types, grid, agents, scratch, outputs, counters, w, i)


@wp.kernel
def share_capture_rewards(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    scratch: Scratch,
    agents: Agents,
    outputs: StepOutputs,
    counters: WorldCounters,
):
    """`share_rewards` for every predator slot."""
    w, p = wp.tid()
    share_rewards(world, types, grid, scratch, agents, outputs, counters, w, p)


@wp.kernel
def respawn_captured_prey(
    world: WorldParams, scratch: Scratch, counters: WorldCounters, agents: Agents, outputs: StepOutputs
):
    """`respawn_or_remove` for every prey slot."""
    w, i = wp.tid()
    respawn_or_remove(world, scratch, counters, agents, outputs, w, i)
