"""MODEL.md steps 1-10 of a world in one launch: the fused step of worlds whose cell lists are
whole-world lists (worlds of one cell: small worlds).

The staged step (`WorldShard.step_program`) launches a kernel per stage, about ten per step, each
over every world's slots of one type. For small worlds those launches cost more than their work: a
GPU is launch-bound below some thousands of worlds, and on the CPU each launch walks the whole batch
again, out of cache. Here one block of threads takes one world through the whole step: its lanes
stride over the world's slots in every stage (so any block size serves any world), and each stage
calls the very function that the stage's own kernel calls (`move_agent`, `mark_captures`, ...,
`observe_row`), with the same arguments, so the fused step computes what the staged one does.

Stages depend on each other's results across slots (prey count their sharers only once every predator
has marked its captures; a predator sums shares only once every prey has counted its sharers; the
respawn moves prey that the share pass reads ...), so a block barrier separates them. Warp 1.19 has
no public barrier, but every in-place update of a shared tile element ends with one (`WP_TILE_SYNC`:
`__syncthreads` on a GPU, a fiber switch on the CPU): each lane adds 0 to its own element of a
block-sized shared tile, which costs one uncontended shared-memory add per lane and the barrier,
which also makes the block's global writes before it visible to the block after it. Per-world
work of one thread (reproduction, the end of the step) runs on lane 0 between two barriers.

The kernel is generated per block size (no barrier at all with one lane), per the two observer
types' slot counts (their rows are `observation_rows`' fixed-size rows) and per `observe_flow`; on
the CPU a block is one lane (Warp runs CPU blocks of more lanes as fibers, opt-in, which only the
tests use, to check that the barriers are where they must be), which loops over its world in cache.
Only whole-world lists qualify: they are the state's own arrays in slot order, so there is no cell
list to rebuild between the stages, and the capture passes' sums run in slot order as in the staged
step (bit for bit on the CPU).
"""

import functools

import warp as wp

from .capture import count_sharers, mark_captures, respawn_or_remove, share_rewards
from .common import PREDATOR, PREY, AgentType, WorldParams
from .grid import CellLists
from .motion import move_agent
from .observation import observation_rows
from .population import close_episode, collect_reward, finish_step, reproduce
from .state import Actions, Agents, Scratch, StepOutputs, WorldCounters

wp.set_module_options({"enable_backward": False})


@functools.cache
def world_step_kernel(prey_slots: tuple[int, int], predator_slots: tuple[int, int], block_dim: int,
                      observe_flow: bool):
    """The fused step for prey observing `prey_slots` (predator slots, prey slots) and predators
    observing `predator_slots`, launched with `dim=(worlds, block_dim)` and `block_dim`; its
    `prey_rows` and `predator_rows` arguments are `observation_rows`' structs (`kernel.rows_types`)."""
    prey_row, PreyRows, PreyRow = observation_rows(prey_slots[0], prey_slots[1], True, observe_flow)
    predator_row, PredatorRows, PredatorRow = observation_rows(predator_slots[0], predator_slots[1], True, observe_flow)

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
        w, lane = wp.tid()
        prey = world.prey_capacity
        predators = world.predator_capacity
        if wp.static(block_dim > 1):
            barrier = wp.tile_zeros(shape=block_dim, dtype=int, storage="shared")
        # 1-4: motion, from the contact partners of the last observation pass.
        for i in range(lane, world.capacity, block_dim):
            move_agent(world, types, action_direction, actions, counters, agents, scratch, outputs, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        # 5-6: captures, sharers, shares and starvation, respawn or removal.
        for p in range(lane, predators, block_dim):
            mark_captures(world, types, grid, agents, scratch, w, p, 0, 1)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for i in range(lane, prey, block_dim):
            count_sharers(world, types, grid, agents, scratch, outputs, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for p in range(lane, predators, block_dim):
            share_rewards(world, types, grid, scratch, agents, outputs, counters, w, p)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for i in range(lane, prey, block_dim):
            respawn_or_remove(world, scratch, counters, agents, outputs, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        # 7: reproduction (the same for every lane of the block, so all of them reach the barrier).
        if reproduction != 0:
            if lane == 0:
                reproduce(world, scratch, agents, counters, w)
            if wp.static(block_dim > 1):
                barrier[lane] += 0
        # 8-9: rewards, episode end, auto-reset.
        for i in range(lane, world.capacity, block_dim):
            collect_reward(world, agents, outputs, counters, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        if lane == 0:
            finish_step(world, counters, outputs, w)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        for i in range(lane, world.capacity, block_dim):
            close_episode(world, counters, outputs, agents, w, i)
        if wp.static(block_dim > 1):
            barrier[lane] += 0
        # 10: observations of the final state, and the next step's contact partners.
        for i in range(lane, world.capacity, block_dim):
            if i < prey:
                r = w * prey + i
                prey_rows.obs[r] = prey_row(world, types, grid, agents, counters, PREY, w, i, r, prey_rows, scratch)
            else:
                r = w * predators + i - prey
                predator_rows.obs[r] = predator_row(world, types, grid, agents, counters, PREDATOR, w, i, r,
                                                    predator_rows, scratch)

    kernel = wp.kernel(enable_backward=False, module="unique")(world_step)
    kernel.block_dim = block_dim
    # Per observer type: the struct type of its outputs and its row type (see `observation_rows`).
    kernel.rows_types = {"prey": (PreyRows, PreyRow), "predator": (PredatorRows, PredatorRow)}
    return kernel
