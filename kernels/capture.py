"""docs/model.md steps 5 and 6: captures after the move, reward sharing, starvation, respawn or removal;
and step 8's rewards, which these passes finish (no pass of their own).

Four passes keep every sum deterministic (no float atomics). First the predators: under density
dilution each marks the prey it overlaps (contacts); under predator confusion each that is not
handling makes one attack on the nearest prey it overlaps (`attack`: one draw against p0 / (1 + c k),
k the other prey it sees near its target) and marks its target if the attack captures, or starts its
handling time if not. Then each prey: under dilution a prey in contact decides whether it is captured
(one draw against p0 / (1 + c k), k its prey neighbours; a failed attempt clears the mark); a
captured prey counts its sharers and takes the penalty. Each predator then sums its shares over the
captured prey near it (in the grid's fixed order), resets its starvation counter if it captured, then
starves by one step; captured prey respawn or are removed last, so the passes before all see the
positions of the capture.

Rewards: a predator's is final at the end of the share pass, which adds it to the slot's episode sum
(every predator slot, dead ones included, whose reward is this step's 0); a prey's is final once it
is respawned or removed: the respawn pass, over every prey slot, adds the survival reward to each prey
alive after it and the prey's reward to its episode sum. (Newborns, made later by
`population.reproduce`, get theirs there.)

The passes search the cell lists of the start-of-step positions (built by the last observation
pass), not cell lists of the moved ones: every agent moved by at most its max speed since, so a
search radius widened by the max speeds (`start_of_step_radius`) finds every pair that is within
the capture, share, confusion or view radius now, and the exact test uses the moved positions. This
saves a second cell-list build per step. (Whole-world lists hold every slot of the world, so there
the widening changes nothing; an unlimited view searches every cell.)
"""

import warp as wp

from .common import (
    CAPTURE_CONFUSION,
    CAPTURE_DILUTION,
    PREDATOR,
    PREY,
    PURPOSE_ATTACK,
    PURPOSE_CAPTURE,
    PURPOSE_RESPAWN,
    AgentType,
    WorldParams,
    in_view,
    ranks_before,
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
def attack_target(
    world: WorldParams, types: wp.array2d(dtype=AgentType), grid: CellLists, agents: Agents, w: int, i: int
) -> int:
    """The prey that predator slot i of world w attacks: the nearest live prey it overlaps (torus
    distance < r_prey + r_predator, moved positions), ties to the lower slot; -1 if none."""
    pos = agents.position[w, i]
    contact = types[w, PREY].radius + types[w, PREDATOR].radius
    contact2 = contact * contact
    target = int(-1)
    target_d2 = contact2
    walk = square_walk(
        grid, w, world.capacity, pos, start_of_step_radius(world, w, contact, types[w, PREY].max_speed), 0, 1
    )
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and slot_type(world, j) == PREY:
                d = torus_displacement(world, pos, agents.position[w, j])
                d2 = wp.dot(d, d)
                if d2 < contact2 and (target < 0 or ranks_before(d2, j, target_d2, target)):
                    target = j
                    target_d2 = d2
    return target


@wp.func
def confusing_seen_prey(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    agents: Agents,
    w: int,
    i: int,
    target: int,
) -> int:
    """The number k of other live prey that predator slot i of world w sees (the observations' test,
    `in_view`: its view distance and field of view around its heading after the move) whose bearing
    lies within `confusion_angle` of the bearing of its target, all at their moved positions. A prey at
    the predator's own position has no bearing and counts, as does every seen prey when the target is
    there."""
    pos = agents.position[w, i]
    heading = agents.heading[w, i]
    predator = types[w, PREDATOR]
    v2 = predator.view_distance * predator.view_distance
    cos_window = world.values[w].confusion_cos
    to_target = torus_displacement(world, pos, agents.position[w, target])
    target_distance = wp.sqrt(wp.dot(to_target, to_target))
    k = int(0)
    # An unlimited view makes the radius +inf: the walk then covers every cell of the world.
    radius = start_of_step_radius(world, w, predator.view_distance, types[w, PREY].max_speed)
    walk = square_walk(grid, w, world.capacity, pos, radius, 0, 1)
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and j != target and slot_type(world, j) == PREY:
                d = torus_displacement(world, pos, agents.position[w, j])
                d2 = wp.dot(d, d)
                if in_view(world, heading, d, d2, v2, predator.cos_half_fov):
                    if wp.dot(to_target, d) >= target_distance * wp.sqrt(d2) * cos_window:
                        k += 1
    return k


@wp.func
def attack_draw(world: WorldParams, counters: WorldCounters, w: int, i: int) -> float:
    """Predator slot i's draw u in [0, 1) that decides its attack in the step being finished."""
    return wp.randf(finishing_step_stream(world, counters, w, i, PURPOSE_ATTACK))


@wp.func
def attack(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    agents: Agents,
    scratch: Scratch,
    counters: WorldCounters,
    w: int,
    p: int,
):
    """Predator p of world w (if live) under predator confusion: while handling it counts its handling
    time down by one and does not attack; otherwise it attacks the prey it overlaps nearest
    (`attack_target`), if any, with one draw against p0 / (1 + c k) (`confusing_seen_prey`, counted
    only when c > 0). A capture marks the target in `scratch.captured` (predators that capture one prey
    write the same True) and in the predator's `scratch.caught_prey`; a failed attack starts the
    handling time of `handling_steps`."""
    i = world.prey_capacity + p
    if not agents.alive[w, i]:
        return
    scratch.caught_prey[w, i] = -1
    if agents.handling[w, i] > 0:
        agents.handling[w, i] = agents.handling[w, i] - 1
        return
    target = attack_target(world, types, grid, agents, w, i)
    if target < 0:
        return
    values = world.values[w]
    chance = values.capture_probability
    if values.capture_confusion > 0.0:
        k = confusing_seen_prey(world, types, grid, agents, w, i, target)
        chance = chance / (1.0 + values.capture_confusion * float(k))
    if attack_draw(world, counters, w, i) < chance:
        scratch.captured[w, target] = True
        scratch.caught_prey[w, i] = target
    else:
        agents.handling[w, i] = values.handling_steps


@wp.func
def contacts_or_attack(
    world: WorldParams,
    types: wp.array2d(dtype=AgentType),
    grid: CellLists,
    agents: Agents,
    scratch: Scratch,
    counters: WorldCounters,
    w: int,
    p: int,
    row_thread: int,
    row_threads: int,
):
    """Step 5's predator pass for predator p of world w under its world's capture rule: `mark_contacts`
    (density dilution, its search split over `row_threads` threads) or `attack` (predator confusion,
    on row thread 0 alone: the nearest target needs every row of the search)."""
    if world.values[w].capture_rule == CAPTURE_CONFUSION:
        if row_thread == 0:
            attack(world, types, grid, agents, scratch, counters, w, p)
    else:
        mark_contacts(world, types, grid, agents, scratch, w, p, row_thread, row_threads)


@wp.func
def touches_predator(
    world: WorldParams, types: wp.array2d(dtype=AgentType), grid: CellLists, agents: Agents, w: int, i: int
) -> bool:
    """Whether a live predator overlaps prey slot i of world w (torus distance < r_prey + r_predator at
    the moved positions), whatever the capture rule: the contact that `prey_contact_penalty` costs."""
    pos = agents.position[w, i]
    contact = types[w, PREY].radius + types[w, PREDATOR].radius
    walk = square_walk(
        grid, w, world.capacity, pos, start_of_step_radius(world, w, contact, types[w, PREDATOR].max_speed), 0, 1
    )
    touched = bool(False)
    while next_run(grid, walk):
        for n in range(run_length(walk.runs)):
            j = listed_slot(grid, run_entry(walk.runs, n), walk.base)
            if j >= 0 and slot_type(world, j) == PREDATOR and agents.alive[w, j]:
                d = torus_displacement(world, pos, agents.position[w, j])
                if wp.dot(d, d) < contact * contact:
                    touched = True
    return touched


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
    """Prey slot i of world w: under density dilution, if in contact with a predator, it is captured
    with probability p0 / (1 + c k) (`confusing_prey`; no draw at p0 = 1, c = 0, where every contact
    captures), and a failed attempt clears its flag, so the later passes see only captures (under
    predator confusion the attacks have decided already). A captured prey counts its sharers
    (`scratch.share_count`: its capturers, the predators in contact under dilution or those whose attack
    captured it under confusion, and the predators within `catch_share_radius`) and takes the penalty; a
    live prey not captured ages by one."""
    if not agents.alive[w, i]:
        return
    values = world.values[w]
    dilution = values.capture_rule == CAPTURE_DILUTION
    if dilution and scratch.captured[w, i] and (values.capture_probability < 1.0 or values.capture_confusion > 0.0):
        chance = values.capture_probability
        if values.capture_confusion > 0.0:
            chance = chance / (1.0 + values.capture_confusion * float(confusing_prey(world, types, grid, agents, w, i)))
        if capture_draw(world, counters, w, i) >= chance:
            scratch.captured[w, i] = False
    if not scratch.captured[w, i]:
        agents.age[w, i] = agents.age[w, i] + 1
        if values.prey_contact_penalty != 0.0 and touches_predator(world, types, grid, agents, w, i):
            outputs.reward[w, i] = -values.prey_contact_penalty
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
                capturer = d2 < contact * contact
                if not dilution:
                    capturer = scratch.caught_prey[w, j] == i
                if capturer or d2 < values.catch_share_radius * values.catch_share_radius:
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
    """Predator p of world w (if live) sums its shares of this step's captures (in the lists' order): of
    each captured prey it captured (in contact under density dilution, its attack's target under
    predator confusion) or lies within `catch_share_radius` of; then docs/model.md step 6: a capture
    resets its steps-since-last-capture counter, which then grows by one; past the limit it dies. Its
    reward (this step's 0 for a dead predator) then goes into its episode sum."""
    i = world.prey_capacity + p
    if not agents.alive[w, i]:
        counters.episode_return[w, i] = counters.episode_return[w, i] + outputs.reward[w, i]
        return
    pos = agents.position[w, i]
    contact = types[w, PREY].radius + types[w, PREDATOR].radius
    values = world.values[w]
    share = wp.max(values.catch_share_radius, contact)
    dilution = values.capture_rule == CAPTURE_DILUTION
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
                    capturer = d2 < contact * contact
                    if not dilution:
                        capturer = scratch.caught_prey[w, i] == j
                    if capturer:
                        is_capturer = True
                    if inside_share or capturer:
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
    counters: WorldCounters,
    row_threads: int,
    agents: Agents,
    scratch: Scratch,
):
    """`contacts_or_attack`, launched with `(worlds, predators, row_threads)` threads."""
    w, p, row_thread = wp.tid()
    contacts_or_attack(world, types, grid, agents, scratch, counters, w, p, row_thread, row_threads)


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
