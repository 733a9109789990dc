"""docs/model.md steps 1-10 of a world in one launch: the fused step of worlds whose cell lists are
whole-world lists (worlds of one cell: small worlds).

The staged step (`WorldShard.step_program`) launches a kernel per stage, about ten per step, each
over every world's slots of one type. For small worlds those launches cost more than their work: a
GPU is launch-bound below some thousands of worlds, and on the CPU each launch walks the whole batch
again, out of cache. Here each world goes through the whole step in one launch, and each stage calls
the very function that the stage's own kernel calls (`move_agent`, `contacts_or_attack`, ...,
`observe_row`), with the same arguments, so the fused step computes what the staged one does.

Lanes: where a world's slots fit a block of several lanes, `block_dim // capacity` consecutive worlds
are packed into a block, a lane per slot (lane t takes slot `t % capacity` of the block's world
`t // capacity`), so a GPU warp's lanes are nearly all busy (one world of 17 slots per block of 32
left 15 lanes idle); lanes past the last packed world, or past the batch, take no slot and only meet
the others at the barriers. A world of more slots takes a block of its own whose lanes stride over its
slots in every stage (so any block size serves any world); so does every world on the CPU, in a
block of one lane.

Observations: where prey and predators observe the same slot counts (the default), the two types'
row functions are one function (`observation_rows` is cached), called at one site with the observer
type and its outputs as values; a warp holds both types' lanes, and two call sites would run the
long neighbour search once per type, one after the other, each with the other type's lanes idle. Only
the stores differ by type. Packed blocks assemble each type's rows in shared memory and store them as
one run (the block's worlds are consecutive, so are their rows of each type), as
`observation_kernel` does: a lane storing its row alone scatters a row's floats across the warp.

Stages depend on each other's results across slots (prey resolve their captures only once every predator
has marked its contacts; a predator sums shares only once every prey has counted its sharers; the
respawn moves prey that the share pass reads ...), so a block barrier separates them. Warp 1.19 has
no public barrier, but every in-place update of a shared tile element ends with one (`WP_TILE_SYNC`:
`__syncthreads` on a GPU, a fiber switch on the CPU): each lane adds 0 to its own element of a
block-sized shared tile, which costs one uncontended shared-memory add per lane and the barrier,
which also makes the block's global writes before it visible to the block after it. Per-world
work of one thread (reproduction, the end of the step) runs on the world's first lane between two
barriers.

The kernel is generated per block size (no barrier at all with one lane), per packed capacities, per
the two observer types' slot counts (their rows are `observation_rows`' fixed-size rows), per
`observe_flow` and per register cap (MAX_REGISTERS); on the CPU a block is one lane (Warp runs CPU
blocks of more lanes as fibers, opt-in, which only the tests use, to check the barriers and the
packing), which loops over its world in cache.
Only whole-world lists qualify: they are the state's own arrays in slot order, so there is no cell
list to rebuild between the stages, and the capture passes' sums run in slot order as in the staged
step (bit for bit on the CPU).
"""

import functools

import warp as wp

from .capture import contacts_or_attack, resolve_capture, respawn_or_remove, share_rewards
from .common import PREDATOR, PREY, AgentType, WorldParams
from .grid import CellLists
from .motion import motion_stage
from .observation import observation_rows
from .population import close_episode, finish_step, reproduce
from .state import Actions, Agents, Scratch, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})

# Registers per GPU thread of the fused step (`cuda_max_registers`): read when a kernel is made (and
# part of its cache key), so a probe can set another cap before building an env. The staged
# observation kernel, which holds most of the step's registers, runs best at 72 (`observation.py`).
MAX_REGISTERS: int | None = 72  # None: the compiler's choice


def world_step_kernel(
    prey_slots: tuple[int, int],
    predator_slots: tuple[int, int],
    block_dim: int,
    observe_flow: bool,
    capacities: tuple[int, int],
    frame: str = "world",
    ego_actions: bool = False,
):
    """The fused step for prey observing `prey_slots` (predator slots, prey slots) and predators
    observing `predator_slots`, in blocks of `block_dim` lanes, for worlds of `capacities` (prey,
    predator) slots, with at most MAX_REGISTERS registers per GPU thread. Launched with
    `dim=(blocks, block_dim)` and `block_dim`, where `blocks` is the worlds over
    `kernel.worlds_per_block`, rounded up; its `prey_rows` and `predator_rows` arguments are
    `observation_rows`' structs (`kernel.rows_types`), in the observation `frame`, with the motion of
    `motion_stage(ego_actions)`."""
    # Worlds that fit a block of several lanes are packed, a lane per slot; the others (and every world
    # in a block of one lane) take a block of their own, whose lanes stride over the slots.
    packed = capacities if 1 < sum(capacities) <= block_dim else None
    return _world_step_kernel(
        prey_slots, predator_slots, block_dim, observe_flow, packed, MAX_REGISTERS, frame, ego_actions
    )


@functools.cache
def _world_step_kernel(
    prey_slots: tuple[int, int],
    predator_slots: tuple[int, int],
    block_dim: int,
    observe_flow: bool,
    packed: tuple[int, int] | None,
    max_registers: int,
    frame: str,
    ego_actions: bool,
):
    move_agent = motion_stage(ego_actions)[0]
    prey_row, PreyRows, PreyRow = observation_rows(prey_slots[0], prey_slots[1], True, observe_flow, frame)
    predator_row, PredatorRows, PredatorRow = observation_rows(
        predator_slots[0], predator_slots[1], True, observe_flow, frame
    )
    # Lanes per world (the stride of the stage loops) and worlds per block.
    lanes = sum(packed) if packed else block_dim
    worlds_per_block = block_dim // lanes
    # One call site of the row function where both types observe the same slot counts (the same
    # function, rows struct and row type: `observation_rows` is cached).
    one_call = prey_slots == predator_slots
    # Packed blocks' rows of each type, staged in shared memory.
    staged_prey, staged_predators = (worlds_per_block * packed[0], worlds_per_block * packed[1]) if packed else (0, 0)

    def observe_slot(
        world: WorldParams,
        types: wp.array2d(dtype=AgentType),
        grid: CellLists,
        agents: Agents,
        counters: WorldCounters,
        w: int,
        i: int,
        prey_rows: PreyRows,
        predator_rows: PredatorRows,
        scratch: Scratch,
    ):
        # Slot i of world w observes (its mask, observed slots and contact partner are written): returns
        # its row as a prey row and as a predator row, of which the caller keeps the one of i's type.
        prey = world.prey_capacity
        if wp.static(one_call):
            # Prey and predator lanes run the same instructions; only the outputs they write differ.
            t = PREY
            r = w * prey + i
            out = prey_rows
            if i >= prey:
                t = PREDATOR
                r = w * world.predator_capacity + i - prey
                out = predator_rows
            row = prey_row(world, types, grid, agents, counters, t, w, i, r, out, scratch)
            return row, row
        else:
            prey_value = PreyRow()
            predator_value = PredatorRow()
            if i < prey:
                prey_value = prey_row(
                    world, types, grid, agents, counters, PREY, w, i, w * prey + i, prey_rows, scratch
                )
            else:
                predator_value = predator_row(
                    world,
                    types,
                    grid,
                    agents,
                    counters,
                    PREDATOR,
                    w,
                    i,
                    w * world.predator_capacity + i - prey,
                    predator_rows,
                    scratch,
                )
            return prey_value, predator_value

    observe_slot = wp.func(observe_slot, module="unique")

    def world_step(
        world: WorldParams,
        types: wp.array2d(dtype=AgentType),
        action_direction: wp.array(dtype=wp.vec2),
        actions: Actions,
        grid: CellLists,
        reproduction: int,
        counters: WorldCounters,
        agents: Agents,
        scratch: Scratch,
        outputs: StepOutputs,
        prey_rows: PreyRows,
        predator_rows: PredatorRows,
    ):
        block, lane = wp.tid()
        group = lane // wp.static(lanes)
        w = block * wp.static(worlds_per_block) + group
        first = lane - group * wp.static(lanes)  # the lane's first slot; it strides by `lanes`
        if group >= wp.static(worlds_per_block) or w >= counters.world_step.shape[0]:
            first = world.capacity  # a lane past the block's worlds takes no slot, only the barriers
        prey = world.prey_capacity
        predators = world.predator_capacity
        if wp.static(block_dim > 1):
            barrier = wp.tile_zeros(shape=block_dim, dtype=int, storage="shared")
        # 1-4: motion, from the contact partners of the last observation pass.
        for i in range(first, world.capacity, wp.static(lanes)):
            move_agent(world, types, action_direction, actions, counters, agents, scratch, outputs, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        # 5-6: captures, sharers, shares and starvation, respawn or removal (and 8: the rewards of every
        # predator and prey slot, in the share and respawn passes).
        for p in range(first, predators, wp.static(lanes)):
            contacts_or_attack(world, types, grid, agents, scratch, counters, w, p, 0, 1)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for i in range(first, prey, wp.static(lanes)):
            resolve_capture(world, types, grid, agents, scratch, outputs, counters, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for p in range(first, predators, wp.static(lanes)):
            share_rewards(world, types, grid, scratch, agents, outputs, counters, w, p)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for i in range(first, prey, wp.static(lanes)):
            respawn_or_remove(world, scratch, counters, agents, outputs, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        # 7: reproduction; 9: episode end (8, the rewards, was finished by the share and respawn passes
        # and `reproduce`), both by the world's first lane.
        if first == 0:
            if reproduction != 0:
                reproduce(world, scratch, agents, outputs, counters, w)
            finish_step(world, counters, outputs, w)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for i in range(first, world.capacity, wp.static(lanes)):
            close_episode(world, counters, outputs, agents, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        # 10: observations of the final state, and the next step's contact partners.
        if wp.static(packed is None):
            for i in range(first, world.capacity, wp.static(lanes)):
                prey_value, predator_value = observe_slot(
                    world, types, grid, agents, counters, w, i, prey_rows, predator_rows, scratch
                )
                if i < prey:
                    prey_rows.obs[w * prey + i] = prey_value
                else:
                    predator_rows.obs[w * predators + i - prey] = predator_value
        else:
            # A lane per slot: the block's rows of each type are one run of the type's rows (its worlds
            # are consecutive), assembled in shared memory and stored together.
            prey_value = PreyRow()
            predator_value = PredatorRow()
            if first < world.capacity:
                prey_value, predator_value = observe_slot(
                    world, types, grid, agents, counters, w, first, prey_rows, predator_rows, scratch
                )
            prey_staged = wp.tile_empty(shape=wp.static(staged_prey), dtype=PreyRow, storage="shared")
            predator_staged = wp.tile_empty(shape=wp.static(staged_predators), dtype=PredatorRow, storage="shared")
            wp.tile_scatter_masked(prey_staged, group * prey + first, prey_value, first < prey)
            wp.tile_scatter_masked(
                predator_staged,
                group * predators + first - prey,
                predator_value,
                first >= prey and first < world.capacity,
            )
            prey_obs = prey_rows.obs  # local arrays: tile_store does not take a struct's field (Warp 1.19)
            predator_obs = predator_rows.obs
            wp.tile_store(prey_obs, prey_staged, offset=block * wp.static(staged_prey))
            wp.tile_store(predator_obs, predator_staged, offset=block * wp.static(staged_predators))

    kernel = wp.kernel(enable_backward=False, module="unique", cuda_max_registers=max_registers)(world_step)
    kernel.block_dim = block_dim
    kernel.worlds_per_block = worlds_per_block
    # Per observer type: the struct type of its outputs and its row type (see `observation_rows`).
    kernel.rows_types = {"prey": (PreyRows, PreyRow), "predator": (PredatorRows, PredatorRow)}
    return kernel
