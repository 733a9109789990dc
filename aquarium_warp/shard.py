"""Shards and launch programs: how a batch's kernels are recorded and run.

Worlds never interact, so a batch is split into shards, contiguous blocks of worlds that run in
parallel threads on the CPU (on a GPU one shard holds every world). A `WorldShard` holds views of the
batch's state groups for its worlds and its own cell lists; random streams are keyed by the global
world index, so results do not depend on the split.

A launch program is a fixed list of recorded launches per shard (no allocation, no host sync), made
once: every value that changes between runs (the seed, the episode and step counters) is device
data that the kernels read. `ShardSet` is the one owner of programs: it records the env's own
(`step`, `observe`, `reset`) and those that heuristics and metrics ask for (`ShardSet.record`), and
runs them (`Program.run`); on a GPU the step runs as one CUDA graph, captured on its first run.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import torch
import warp as wp

from .agent_types import TYPES
from .config import AquariumConfig
from .device import WARP_SETUP_LOCK
from .device import torch_stream as torch_stream_of
from .kernels import capture, motion, observation, population, spawn, world_step
from .kernels import grid as grid_kernels
from .kernels.common import PREDATOR, PREY, WorldParams
from .kernels.state import Agents
from .state import SimulationState

TYPE_CODES = {"prey": int(PREY), "predator": int(PREDATOR)}
# Largest world whose GPU cell lists are built by ranking each slot over its world instead of counting
# the agents of every cell (each thread reads its whole world, so the cost per agent grows with the world).
RANK_SORT_MAX_CAPACITY = 128
# Below this many worlds per thread, the thread hand-off costs more than the second core gives.
MIN_WORLDS_PER_THREAD = 32
OBSERVATION_BLOCK = 128  # threads per block of the GPU observation kernel
# Lanes of a block of the fused step on a GPU: worlds of at most this many slots are packed into it, a
# lane per slot (7 worlds of 17 slots use 119 of 128 lanes), read when an env is built (a probe may set
# another). Worlds of more slots (worlds of one cell hold at most SINGLE_CELL_CAPACITY unless a
# config's grid_cell_size makes larger ones) take a block of their own: whole warps, one lane per slot
# up to FUSED_MAX_BLOCK, whose lanes then loop over the slots.
FUSED_BLOCK = 128
FUSED_MAX_BLOCK = 256
STEP_KERNELS = ("auto", "fused", "stages")
# Largest batch (agent slots) that "auto" runs fused on a GPU. H200, default worlds of 17 slots, CUDA
# graph (benchmarks/probe_fused_gpu.py, benchmarks/results/fused_step_h200/): fused 0.040 vs staged
# 0.062 ms at 4,096 worlds (69,632 slots), 0.133 vs 0.113 ms at 16,384 worlds (278,528 slots): past a
# few thousand worlds the staged kernels keep more warps busy than the fused step's barriers allow.
AUTO_FUSED_GPU_MAX_SLOTS = 131_072


def world_params(cfg: AquariumConfig, auto_reset: bool, values: wp.array, flow_grid: wp.array) -> WorldParams:
    """The `WorldParams` of worlds of `cfg`, with their per-world `values` (a view of the batch's
    `WorldValues` for these worlds) and the batch's flow grids."""
    p = WorldParams()
    p.width = cfg.width
    p.height = cfg.height
    p.prey_capacity = cfg.prey_capacity
    p.capacity = cfg.capacity
    p.predator_capacity = cfg.predator_capacity
    p.action_count = cfg.action_count
    p.max_steps = cfg.max_steps
    p.fov_enabled = int(cfg.fov_enabled)
    p.respawn_captured_prey = int(cfg.respawn_captured_prey)
    p.max_prey = cfg.max_prey
    p.signed_observations = int(cfg.observation_range == "-1..1")
    p.ego_actions = int(cfg.action_frame == "ego")
    p.random_spawn_heading = int(cfg.spawn_heading == "random")
    p.auto_reset = int(auto_reset)
    p.values = values
    p.flow_grid = flow_grid
    return p


def grid_build(cfg: AquariumConfig, dims: tuple[int, int], cuda: bool) -> str:
    """How the cell lists of worlds of `cfg` with `dims` cells are built: "whole-world" (one cell, no
    build), "counting" (CPU counting sort per world), "rank" (GPU, rank per slot) or "count" (GPU,
    cell counts and their prefix sum)."""
    if tuple(dims) == (1, 1):
        return "whole-world"
    if not cuda:
        return "counting"
    return "rank" if cfg.capacity <= RANK_SORT_MAX_CAPACITY else "count"


def fused_step(step_kernel: str, dims: tuple[int, int], cuda: bool = False, slots: int = 0) -> bool:
    """Whether worlds with `dims` cells take the fused step (`kernels/world_step.py`, one launch) for
    the env option `step_kernel`: "auto" where it applies (worlds of one cell, whose cell lists are
    whole-world lists) and, on a GPU, for batches of at most AUTO_FUSED_GPU_MAX_SLOTS agent `slots`;
    "fused" (a ValueError where it does not apply) or "stages" (a launch per stage)."""
    if not isinstance(step_kernel, str) or step_kernel not in STEP_KERNELS:
        raise ValueError(f"step_kernel={step_kernel!r} must be one of {', '.join(map(repr, STEP_KERNELS))}")
    whole_world = tuple(dims) == (1, 1)
    if step_kernel == "fused" and not whole_world:
        raise ValueError(
            f"step_kernel='fused' needs worlds of one cell (whole-world cell lists), but this config's "
            f"worlds have {dims[0]} x {dims[1]} cells (more slots than one cell takes, or grid_cell_size "
            "set): use step_kernel='auto' or 'stages'"
        )
    if step_kernel == "auto" and cuda and slots > AUTO_FUSED_GPU_MAX_SLOTS:
        return False
    return step_kernel != "stages" and whole_world


def fused_block_dim(capacity: int, cuda: bool) -> int:
    """Lanes per block of the fused step for worlds of `capacity` slots: on a GPU FUSED_BLOCK (which
    packs several worlds) or, for larger worlds, whole warps, one lane per slot up to FUSED_MAX_BLOCK;
    on the CPU one (the thread loops over its world's slots)."""
    if not cuda:
        return 1
    if capacity <= FUSED_BLOCK:
        return FUSED_BLOCK
    return min(FUSED_MAX_BLOCK, 32 * ((capacity + 31) // 32))


def cell_lists(
    cfg: AquariumConfig,
    num_worlds: int,
    dims: tuple[int, int],
    device,
    agents: Agents | None = None,
    build: str | None = None,
) -> grid_kernels.CellLists:
    """Cell lists of `num_worlds` worlds of `dims` cells, for the `build` that `grid_build` names (or the
    one given). Worlds of one cell get whole-world lists over the `agents` arrays (views of
    `[num_worlds, capacity]` arrays), which never need a build."""
    dims_x, dims_y = dims
    n = num_worlds * cfg.capacity
    g = grid_kernels.CellLists()
    g.dims_x, g.dims_y = dims_x, dims_y
    g.cells_per_world = dims_x * dims_y
    g.cell_width = cfg.width / dims_x
    g.cell_height = cfg.height / dims_y
    g.inv_cell_width = dims_x / cfg.width
    g.inv_cell_height = dims_y / cfg.height
    g.reach = min(cfg.width / dims_x, cfg.height / dims_y)
    g.lo_x, g.hi_x = (dims_x - 1) // 2, dims_x // 2
    g.lo_y, g.hi_y = (dims_y - 1) // 2, dims_y // 2
    g.whole_world = int(agents is not None and dims == (1, 1))
    cells = num_worlds * g.cells_per_world
    if g.whole_world:
        if agents is None:
            raise ValueError("whole-world cell lists view the agents' arrays: pass `agents`")
        first = np.arange(num_worlds, dtype=np.int32) * cfg.capacity
        g.cell_start = wp.array(first, dtype=int, device=device)
        g.cell_end = wp.array(first + cfg.capacity, dtype=int, device=device)
        g.key = g.agent = g.cell_count = wp.empty(0, dtype=int, device=device)
        g.position, g.alive = agents.position.flatten(), agents.alive.flatten()
        return g
    if (build or grid_build(cfg, dims, wp.get_device(device).is_cuda)) == "count":
        # Live agents are packed in key order over all worlds, so each cell ends where the next one
        # starts: one array of bounds (its first entry stays 0) serves as both.
        bounds = wp.zeros(cells + 1, dtype=int, device=device)
        g.cell_start, g.cell_end = bounds[:cells], bounds[1:]
        g.cell_count = wp.zeros(cells, dtype=int, device=device)
    else:
        g.cell_start = wp.zeros(cells, dtype=int, device=device)
        g.cell_end = wp.zeros(cells, dtype=int, device=device)
        g.cell_count = wp.empty(0, dtype=int, device=device)
    g.key = wp.zeros(2 * n, dtype=int, device=device)
    g.agent = wp.zeros(2 * n, dtype=int, device=device)
    g.position = wp.zeros(n, dtype=wp.vec2, device=device)
    g.alive = wp.empty(0, dtype=wp.bool, device=device)
    return g


class WorldShard:
    """Worlds `[w0, w1)` of a batch: `state` (the batch's groups viewed for these worlds), `grid` (their
    cell lists), `world` (their `WorldParams`), and `programs`, the env's launch programs as recorded
    for this shard (name -> list of commands; docs/model.md's step is `programs["step"]`)."""

    def __init__(
        self,
        cfg: AquariumConfig,
        state: SimulationState,
        index: int,
        w0: int,
        w1: int,
        dims,
        params,
        action_direction,
        observe_kernels,
        device,
        auto_reset: bool = True,
        fused_kernel=None,
    ):
        self.cfg, self.device = cfg, device
        self.index = index
        self.w0, self.w1 = w0, w1
        self.num_worlds = w1 - w0
        self.world = world_params(cfg, auto_reset, params.values[w0:w1], params.flow_grid)
        self.types = params.types[w0:w1]  # [worlds, 2] AgentType of these worlds
        self.action_direction = action_direction
        self.observe_kernels = observe_kernels  # {"prey": kernel, "predator": kernel}
        self.fused_kernel = fused_kernel  # the fused step (`world_step.world_step_kernel`), or None: staged
        self.state = state.rows(w0, w1)
        self.grid = cell_lists(cfg, self.num_worlds, dims, device, self.state.agents)
        self._views: list[wp.array] = []  # arrays viewing state memory with another dtype (kept alive with the shard)
        self.programs: dict[str, list] = {}

    def run(self, program: str) -> None:
        """Run one of the env's programs ("step", "observe" or "reset") on this shard."""
        for command in self.programs[program]:
            command()

    def record(self, kernel, dim, inputs, outputs=(), block_dim: int | None = None):
        """A recorded launch of `kernel` over `dim` threads (blocks of `block_dim` for a tile kernel),
        as a command: calling it replays the launch."""
        options: dict[str, Any] = {} if block_dim is None else {"block_dim": block_dim}
        return wp.launch(
            kernel, dim=dim, inputs=list(inputs), outputs=list(outputs), device=self.device, record_cmd=True, **options
        ).launch

    # The env's programs -------------------------------------------------------------------------
    def build_grid_commands(self) -> list:
        """Cell lists of the current positions (no allocation, no host sync)."""
        agents, g, W, C = self.state.agents, self.grid, self.num_worlds, self.cfg.capacity
        build = grid_build(self.cfg, (g.dims_x, g.dims_y), wp.get_device(self.device).is_cuda)
        if g.whole_world:
            return []  # the lists are fixed and read the state itself
        if build == "counting":
            return [self.record(grid_kernels.sort_into_cells_per_world, W, [self.world, agents, g])]
        if build == "rank":
            return [self.record(grid_kernels.rank_into_cells_per_world, (W, C), [self.world, agents, g])]
        # `cell_count` is zero here (at allocation, and after every build: `drop_into_cells` zeroes it).
        return [
            self.record(grid_kernels.compute_cell_keys, (W, C), [self.world, agents, g]),
            # Every cell's end is the running count of live agents (its start the previous cell's end).
            functools.partial(wp.utils.array_scan, g.cell_count, g.cell_end, True),
            self.record(grid_kernels.drop_into_cells, W * C, [g]),
            self.record(grid_kernels.order_cells, W * C, [self.world, agents, g]),
        ]

    def _observed_rows(self, type_name: str, rows_type, row_type):
        """One observer type's observation rows (as `row_type` values), masks and observed slots, as a
        `rows_type` struct (both made by `observation.observation_rows`)."""
        observations = self.state.observations
        obs = getattr(observations, f"obs_{type_name}")
        rows = obs.shape[0] * obs.shape[1]
        out = rows_type()
        # The [W, per_world, L] observations as [W * per_world] rows of L floats (same memory).
        out.obs = wp.array(ptr=obs.ptr, dtype=row_type, shape=(rows,), device=obs.device)
        self._views.append(out.obs)
        out.mask = getattr(observations, f"mask_{type_name}").reshape((rows, -1))
        out.observed_slot = getattr(observations, f"slot_{type_name}").reshape((rows, -1))
        return out

    def observe_commands(self) -> list:
        """docs/model.md step 10 (and the contact partners of the next step's step 3): one launch for both
        observer types when one kernel serves both, else one per type."""
        W, cfg = self.num_worlds, self.cfg
        rows = {"prey": W * cfg.prey_capacity, "predator": W * cfg.predator_capacity}
        kernels = self.observe_kernels
        groups = [TYPES] if kernels["prey"] is kernels["predator"] else [("prey",), ("predator",)]
        commands = []
        for group in groups:
            kernel, block = kernels[group[0]], kernels[group[0]].block_dim
            assert kernel.whole_world == bool(self.grid.whole_world), "observation kernel built for other lists"
            first, second = group[0], group[1] if len(group) == 2 else None
            first_blocks = (rows[first] + block - 1) // block
            second_rows = rows[second] if second else 0
            first_out = self._observed_rows(first, kernel.rows_type, kernel.row_type)
            # A type alone passes its own outputs again for the (empty) second range.
            second_out = self._observed_rows(second, kernel.rows_type, kernel.row_type) if second else first_out
            commands.append(
                self.record(
                    kernel,
                    (first_blocks + (second_rows + block - 1) // block, block),
                    [
                        self.world,
                        self.types,
                        self.grid,
                        self.state.agents,
                        self.state.worlds,
                        TYPE_CODES[first],
                        rows[first],
                        first_blocks,
                        second_rows,
                    ],
                    [first_out, second_out, self.state.scratch],
                    block_dim=block,
                )
            )
        return commands

    def observe_program(self) -> list:
        """Cell lists of the current state, then the observations of every agent."""
        return self.build_grid_commands() + self.observe_commands()

    def reset_program(self) -> list:
        """Every world's first episode: counters and agents (`spawn_episode`), then observations."""
        s = self.state
        return [
            self.record(
                spawn.spawn_episode, (self.num_worlds, self.cfg.capacity), [self.world], [s.worlds, s.outputs, s.agents]
            )
        ] + self.observe_program()

    def step_program(self) -> list:
        """docs/model.md steps 1-10 for every world of the shard: one launch of the fused step where it
        applies (`step_kernel`), else a launch per stage."""
        s, g, world, types, cfg = self.state, self.grid, self.world, self.types, self.cfg
        if self.fused_kernel is not None:
            kernel = self.fused_kernel
            blocks = (self.num_worlds + kernel.worlds_per_block - 1) // kernel.worlds_per_block
            return [
                self.record(
                    kernel,
                    (blocks, kernel.block_dim),
                    [world, types, self.action_direction, s.actions, g, int(cfg.prey_reproduction)],
                    [
                        s.worlds,
                        s.agents,
                        s.scratch,
                        s.outputs,
                        self._observed_rows("prey", *kernel.rows_types["prey"]),
                        self._observed_rows("predator", *kernel.rows_types["predator"]),
                    ],
                    block_dim=kernel.block_dim,
                )
            ]
        W, C, Pc, P = self.num_worlds, cfg.capacity, cfg.prey_capacity, cfg.predator_capacity
        # 1-4: motion (which also clears this step's rewards and flags); contact partners were found
        # by the last observation pass.
        program = [
            self.record(
                motion.motion_stage(cfg.action_frame == "ego")[1],
                (W, C),
                [world, types, self.action_direction, s.actions, s.worlds],
                [s.agents, s.scratch, s.outputs],
            )
        ]
        # 5-6: captures on the moved positions, searched in the start-of-step cell lists; starvation.
        row_threads = 1 if g.whole_world else capture.CAPTURE_ROW_THREADS
        program += [
            self.record(
                capture.detect_contacts,
                (W, P, row_threads),
                [world, types, g, s.worlds, row_threads],
                [s.agents, s.scratch],
            ),
            self.record(
                capture.resolve_captures, (W, Pc), [world, types, g, s.worlds], [s.agents, s.scratch, s.outputs]
            ),
            self.record(
                capture.share_capture_rewards, (W, P), [world, types, g, s.scratch], [s.agents, s.outputs, s.worlds]
            ),
            self.record(capture.respawn_captured_prey, (W, Pc), [world, s.scratch], [s.worlds, s.agents, s.outputs]),
        ]
        # 7: reproduction (8, the rewards, are finished by the share and respawn passes and by
        # `reproduce_prey`, for its newborns).
        if cfg.prey_reproduction:
            program.append(
                self.record(population.reproduce_prey, W, [world, s.scratch], [s.agents, s.outputs, s.worlds])
            )
        # 9: episode end, auto-reset of ended worlds.
        program += [
            self.record(population.finish_world_step, W, [world], [s.worlds, s.outputs]),
            self.record(population.close_ended_episodes, (W, C), [world], [s.worlds, s.outputs, s.agents]),
        ]
        # 10: observations of the final state, and the contact partners of the next step's motion.
        return program + self.observe_program()


class Program:
    """One launch program: a list of commands per shard, run on every shard by `run()`; with `graph`,
    a GPU runs it as a CUDA graph captured on the first run."""

    def __init__(self, shards: ShardSet, commands: list[list], graph: bool = False):
        self.shards = shards
        self.commands = commands  # commands[shard.index]
        self.graph = graph and shards.cuda
        self._graph = None

    def run(self) -> None:
        # Inside a capture of torch's (a training loop's whole rollout) the launches themselves join it:
        # no graph of Warp's is captured or launched inside another graph.
        if not self.graph or self.shards.torch_capturing():
            commands = self.commands
            self.shards.run(lambda shard: [command() for command in commands[shard.index]])
            return
        self.shards.run(self._run_graph)

    def _run_graph(self, shard: WorldShard) -> None:
        stream = wp.get_stream(self.shards.device)
        if self._graph is None:
            for command in self.commands[shard.index]:  # loads every module before the capture
                command()
            with wp.ScopedCapture(device=self.shards.device, stream=stream) as capture_scope:
                for command in self.commands[shard.index]:
                    command()
            self._graph = capture_scope.graph
        else:
            wp.capture_launch(self._graph, stream=stream)

    def close(self) -> None:
        self._graph = None


class ShardSet:
    """The shards of a batch of `state`'s worlds and the one owner of launch programs: it records the
    env's programs (`programs`: "step", "observe", "reset") and any other that `record` is asked for,
    and runs them on every shard (`run`)."""

    def __init__(
        self,
        cfg: AquariumConfig,
        state: SimulationState,
        dims,
        params,
        action_direction,
        device,
        auto_reset: bool,
        threads: int,
        step_kernel: str = "auto",
    ):
        self.device = device
        self.cuda = wp.get_device(device).is_cuda
        W = state.agents.alive.shape[0]
        shards = 1 if self.cuda else max(1, min(threads, W // MIN_WORLDS_PER_THREAD))
        bounds = [W * k // shards for k in range(shards + 1)]
        # One observation kernel per observer type's slot counts; rows are staged by blocks of
        # OBSERVATION_BLOCK threads on a GPU (tile kernels run one thread per block on the CPU).
        block = OBSERVATION_BLOCK if self.cuda else 1
        whole_world = tuple(dims) == (1, 1)  # the shards' cell lists are whole-world lists
        observe_kernels = {
            t: observation.observation_kernel(
                getattr(cfg, t).predator_slots,
                getattr(cfg, t).prey_slots,
                block,
                whole_world,
                bool(cfg.observe_flow),
                cfg.observation_layout,
            )
            for t in TYPES
        }
        # The step of worlds of one cell in one launch (`fused_step`), with their observers' slot counts.
        fused = None
        if fused_step(step_kernel, dims, self.cuda, W * cfg.capacity):
            fused = world_step.world_step_kernel(
                (cfg.prey.predator_slots, cfg.prey.prey_slots),
                (cfg.predator.predator_slots, cfg.predator.prey_slots),
                fused_block_dim(cfg.capacity, self.cuda),
                bool(cfg.observe_flow),
                (cfg.prey_capacity, cfg.predator_capacity),
                cfg.observation_layout,
                cfg.action_frame == "ego",
            )
        self.step_path = "fused" if fused is not None else "stages"
        # Whether the programs may be recorded into a capture of torch's (`run`): every command a kernel
        # launch. The cell lists built by counts run `wp.utils.array_scan`, whose scratch allocation
        # invalidated such a capture on an H100 (only Warp's own capture of the step serves there).
        self.capturable = not self.cuda or grid_build(cfg, dims, self.cuda) != "count"
        self.shards = tuple(
            WorldShard(
                cfg, state, k, w0, w1, dims, params, action_direction, observe_kernels, device, auto_reset, fused
            )
            for k, (w0, w1) in enumerate(zip(bounds[:-1], bounds[1:]))
        )
        self._pool = ThreadPoolExecutor(max_workers=shards) if shards > 1 else None
        self.programs = {
            "step": self.record(WorldShard.step_program, graph=True),
            "observe": self.record(WorldShard.observe_program),
            "reset": self.record(WorldShard.reset_program),
        }
        for name, program in self.programs.items():
            for shard in self.shards:
                shard.programs[name] = program.commands[shard.index]

    def record(self, build: Callable[[WorldShard], list], graph: bool = False) -> Program:
        """The program whose commands on each shard are `build(shard)` (made with `WorldShard.record`)."""
        with WARP_SETUP_LOCK:  # recording a launch loads its module
            return Program(self, [build(shard) for shard in self.shards], graph)

    def run(self, work: Callable[[WorldShard], object]) -> None:
        """Call `work(shard)` for every shard: in parallel threads on CPU (Warp's CPU kernels release
        the GIL); on GPU on Warp's stream, ordered after the torch work that produced the inputs and
        before the torch work that reads the outputs (torch's legacy default stream cannot be captured
        into a graph)."""
        if not self.cuda:
            if self._pool is not None:
                list(self._pool.map(work, self.shards))
            else:
                for shard in self.shards:
                    work(shard)
            return
        torch_stream = torch_stream_of(torch.device(self.device))
        assert torch_stream is not None  # (a CUDA device)
        if self.torch_capturing():  # recorded into torch's capture, on its stream (no fork to Warp's)
            if not self.capturable:
                raise RuntimeError(
                    "these worlds' cell lists are built by counts and a prefix sum, which cannot be recorded "
                    "into a torch CUDA graph capture (env.step_capturable is False): step them outside it"
                )
            with wp.ScopedStream(torch_stream, sync_enter=False):
                for shard in self.shards:
                    work(shard)
            return
        stream = wp.get_stream(self.device)
        stream.wait_stream(torch_stream)
        with wp.ScopedStream(stream):
            for shard in self.shards:
                work(shard)
        torch_stream.wait_stream(stream)

    def torch_capturing(self) -> bool:
        """Whether torch's current stream on this GPU is capturing a CUDA graph (then `run` records its
        launches into that capture, on torch's stream)."""
        return self.cuda and torch.cuda.is_current_stream_capturing()

    def close(self) -> None:
        """Release the CUDA graph and the worker threads."""
        self.programs["step"].close()
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False)
