"""`WorldShard`: a contiguous block of worlds with its own cell lists and pre-recorded launch programs.

Worlds never interact, so a batch can be split into shards that run in parallel threads on the CPU
(on GPU one shard holds every world). Each shard sees views of the batch's arrays; random streams are
keyed by the global world index, so results do not depend on how the batch is split.
"""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import warp as wp

from .config import AquariumConfig
from .kernels import capture, motion, population, spawn
from .kernels import grid as grid_kernels
from .kernels.common import PREDATOR, PREY, WorldParams

TYPE_CODES = {"prey": int(PREY), "predator": int(PREDATOR)}
# Largest world whose GPU cell lists are built by ranking each slot over its world instead of counting
# the agents of every cell (each thread reads its whole world, so the cost per agent grows with the world).
RANK_SORT_MAX_CAPACITY = 128


def world_params(cfg: AquariumConfig, seed_key: int, world_offset: int, auto_reset: bool) -> WorldParams:
    p = WorldParams()
    p.width = cfg.width
    p.height = cfg.height
    p.prey_capacity = cfg.prey_capacity
    p.capacity = cfg.capacity
    p.prey_count = cfg.prey_count
    p.predator_count = cfg.predator_count
    p.action_count = cfg.action_count
    p.max_steps = cfg.max_steps
    p.fov_enabled = int(cfg.fov_enabled)
    p.respawn_captured_prey = int(cfg.respawn_captured_prey)
    p.prey_reward = cfg.prey_reward
    p.prey_capture_penalty = cfg.prey_capture_penalty
    p.predator_reward = cfg.predator_reward
    p.catch_share_radius = cfg.catch_share_radius
    p.predator_starvation_steps = cfg.predator_starvation_steps
    p.max_prey = cfg.max_prey
    p.replication_age_min = math.ceil(0.75 * cfg.prey_replication_age)
    p.replication_age_max = math.floor(1.25 * cfg.prey_replication_age)
    p.signed_observations = int(cfg.observation_range == "-1..1")
    p.seed = seed_key
    p.world_offset = world_offset
    p.auto_reset = int(auto_reset)
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


def cell_lists(cfg: AquariumConfig, num_worlds: int, dims: tuple[int, int], device, state=None,
               build: str | None = None) -> grid_kernels.CellLists:
    """Cell lists of `num_worlds` worlds of `dims` cells, for the `build` that `grid_build` names (or the
    one given). Worlds of one cell get whole-world lists over the `state` arrays (views of
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
    g.whole_world = int(state is not None and dims == (1, 1))
    cells = num_worlds * g.cells_per_world
    if g.whole_world:
        first = np.arange(num_worlds, dtype=np.int32) * cfg.capacity
        g.cell_start = wp.array(first, dtype=int, device=device)
        g.cell_end = wp.array(first + cfg.capacity, dtype=int, device=device)
        g.key = g.agent = g.cell_count = wp.empty(0, dtype=int, device=device)
        g.position, g.alive = state.position.flatten(), state.alive.flatten()
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
    """Worlds `[w0, w1)` of a batch: MODEL.md's step as a fixed list of recorded launches."""

    def __init__(self, cfg: AquariumConfig, state, w0: int, w1: int, dims, types, action_direction,
                 observe_kernels, seed_key: int, device, auto_reset: bool = True):
        self.cfg, self.device = cfg, device
        self.w0, self.w1 = w0, w1
        self.num_worlds = W = w1 - w0
        self.world = world_params(cfg, seed_key, w0, auto_reset)
        self.types = types
        self.action_direction = action_direction
        self.observe_kernels = observe_kernels  # {"prey": kernel, "predator": kernel}
        self._views = []  # arrays viewing state memory with another dtype (kept alive with the shard)
        self.s = SimpleNamespace(**{name: value[w0:w1] for name, value in vars(state).items()
                                    if isinstance(value, wp.array)})
        self.grid = cell_lists(cfg, W, dims, device, self.s)
        self.programs = {"step": self._step_program(), "observe": self._observe_program(),
                         "reset": self._reset_program()}

    def run(self, program: str) -> None:
        for command in self.programs[program]:
            command()

    def _launch(self, kernel, dim, inputs, outputs):
        return wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device,
                         record_cmd=True).launch

    def _launch_blocks(self, kernel, blocks: int, block_dim: int, inputs, outputs):
        """A tile kernel: `blocks` blocks of `block_dim` threads, `block, lane = wp.tid()`."""
        return wp.launch(kernel, dim=(blocks, block_dim), block_dim=block_dim, inputs=inputs, outputs=outputs,
                         device=self.device, record_cmd=True).launch

    # Programs ------------------------------------------------------------------------------------
    def _build_grid_program(self) -> list:
        """Cell lists of the current positions (no allocation, no host sync)."""
        s, g, W, C = self.s, self.grid, self.num_worlds, self.cfg.capacity
        count = W * C
        build = grid_build(self.cfg, (g.dims_x, g.dims_y), wp.get_device(self.device).is_cuda)
        if g.whole_world:
            return []  # the lists are fixed and read the state itself
        if build == "counting":
            return [self._launch(grid_kernels.sort_into_cells_per_world, W, [self.world, g, s.position, s.alive],
                                 [g.key, g.cell_start, g.cell_end, g.agent, g.position])]
        if build == "rank":
            return [self._launch(grid_kernels.rank_into_cells_per_world, (W, C), [self.world, g, s.position, s.alive],
                                 [g.cell_start, g.cell_end, g.agent, g.position])]
        return [
            g.cell_count.zero_,
            self._launch(grid_kernels.compute_cell_keys, (W, C), [self.world, g, s.position, s.alive],
                         [g.key, g.cell_count]),
            # Every cell's end is the running count of live agents (its start the previous cell's end).
            functools.partial(wp.utils.array_scan, g.cell_count, g.cell_end, True),
            self._launch(grid_kernels.drop_into_cells, count, [g], [g.agent]),
            self._launch(grid_kernels.order_cells, count, [self.world, g, s.position], [g.agent, g.position]),
        ]

    def _observation_outputs(self, type_name: str, kernel) -> list:
        """One observer type's observation rows, masks and observed slots, as the kernel takes them."""
        s = self.s
        obs = getattr(s, f"obs_{type_name}")
        rows = obs.shape[0] * obs.shape[1]
        slots = obs.shape[2] // 6  # 5 + 6 * slots values per row
        # The [W, per_world, L] observations as [W * per_world] rows of L floats (same memory).
        obs_rows = wp.array(ptr=obs.ptr, dtype=kernel.row_type, shape=(rows,), device=obs.device)
        self._views.append(obs_rows)
        return [obs_rows, getattr(s, f"mask_{type_name}").reshape((rows, slots)),
                getattr(s, f"slot_{type_name}").reshape((rows, slots))]

    def _observe_launches(self) -> list:
        """MODEL.md step 10 (and the contact partners of the next step's step 3): one launch for both
        observer types when one kernel serves both, else one per type."""
        s, W, cfg = self.s, self.num_worlds, self.cfg
        rows = {"prey": W * cfg.prey_capacity, "predator": W * cfg.predator_count}
        kernels = self.observe_kernels
        groups = [("prey", "predator")] if kernels["prey"] is kernels["predator"] else [("prey",), ("predator",)]
        launches = []
        for group in groups:
            kernel, block = kernels[group[0]], kernels[group[0]].block_dim
            assert kernel.whole_world == bool(self.grid.whole_world), "observation kernel built for other lists"
            first, second = group[0], group[1] if len(group) == 2 else None
            first_blocks = (rows[first] + block - 1) // block
            second_rows = rows[second] if second else 0
            first_outputs = self._observation_outputs(first, kernel)
            # A type alone passes its own outputs again for the (empty) second range.
            second_outputs = self._observation_outputs(second, kernel) if second else first_outputs
            launches.append(self._launch_blocks(
                kernel, first_blocks + (second_rows + block - 1) // block, block,
                [self.world, self.types, self.grid, s.alive, s.position, s.velocity, s.heading, TYPE_CODES[first],
                 rows[first], first_blocks, second_rows],
                first_outputs + second_outputs + [s.contact_partner, s.contact_offset]))
        return launches

    def _observe_program(self) -> list:
        """Cell lists of the current state, then the observations of every agent."""
        return self._build_grid_program() + self._observe_launches()

    def _spawn(self):
        s = self.s
        return self._launch(spawn.spawn_episode, (self.num_worlds, self.cfg.capacity), [self.world, s.episode],
                            [s.alive, s.position, s.velocity, s.acceleration, s.heading, s.age,
                             s.replication_age, s.starvation])

    def _reset_program(self) -> list:
        s, cfg = self.s, self.cfg
        return [s.world_step.zero_, s.episode.zero_, s.episode_captures.zero_, s.episode_return.zero_,
                s.episode_ended.zero_, functools.partial(s.prey_alive_count.fill_, cfg.prey_count),
                functools.partial(s.predator_alive_count.fill_, cfg.predator_count),
                self._spawn()] + self._observe_program()

    def _step_program(self) -> list:
        """MODEL.md steps 1-10 for every world of the shard."""
        s, g, world, types, cfg = self.s, self.grid, self.world, self.types, self.cfg
        W, C, Pc, P = self.num_worlds, cfg.capacity, cfg.prey_capacity, cfg.predator_count
        # 1-4: motion (which also clears this step's rewards and flags); contact partners were found
        # by the last observation pass.
        program = [self._launch(motion.integrate_motion, (W, C),
                                [world, types, self.action_direction, s.prey_action, s.predator_action,
                                 s.alive, s.contact_partner, s.contact_offset],
                                [s.position, s.velocity, s.acceleration, s.heading, s.reward, s.terminated,
                                 s.truncated, s.captured, s.captures])]
        # 5-6: captures on the moved positions, searched in the start-of-step cell lists; starvation.
        row_threads = 1 if g.whole_world else capture.CAPTURE_ROW_THREADS
        program.append(self._launch(capture.detect_captures, (W, P, row_threads),
                                    [world, types, g, s.alive, s.position, row_threads], [s.captured]))
        program.append(self._launch(capture.count_capture_sharers, (W, Pc),
                                    [world, types, g, s.alive, s.position, s.captured],
                                    [s.age, s.share_count, s.reward, s.captures]))
        program.append(self._launch(capture.share_capture_rewards, (W, P),
                                    [world, types, g, s.position, s.captured, s.share_count],
                                    [s.alive, s.reward, s.starvation, s.terminated, s.predator_alive_count]))
        program.append(self._launch(capture.respawn_captured_prey, (W, Pc),
                                    [world, s.world_step, s.episode, s.captured],
                                    [s.alive, s.position, s.velocity, s.acceleration, s.heading, s.age,
                                     s.replication_age, s.starvation, s.terminated, s.prey_alive_count]))
        # 7: reproduction.
        if cfg.prey_reproduction:
            program.append(self._launch(population.reproduce_prey, W, [world, s.world_step, s.episode, s.captured],
                                        [s.alive, s.position, s.velocity, s.acceleration, s.heading, s.age,
                                         s.replication_age, s.starvation, s.prey_alive_count]))
        # 8-9: rewards, episode end, auto-reset of ended worlds.
        program.append(self._launch(population.collect_rewards, (W, C), [world, s.alive],
                                    [s.reward, s.episode_return]))
        program.append(self._launch(population.finish_world_step, W, [world, s.captures, s.episode_return],
                                    [s.world_step, s.episode, s.episode_captures, s.prey_alive_count,
                                     s.predator_alive_count, s.episode_ended, s.ended_length, s.ended_captures,
                                     s.ended_return]))
        program.append(self._launch(population.close_ended_episodes, (W, C), [world, s.episode, s.episode_ended],
                                    [s.alive, s.position, s.velocity, s.acceleration, s.heading, s.age,
                                     s.replication_age, s.starvation, s.truncated, s.episode_return]))
        # 10: observations of the final state, and the contact partners of the next step's motion.
        return program + self._observe_program()
