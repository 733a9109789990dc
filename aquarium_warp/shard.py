"""`WorldShard`: a contiguous block of worlds with its own cell lists and pre-recorded launch programs.

Worlds never interact, so a batch can be split into shards that run in parallel threads on the CPU
(on GPU one shard holds every world). Each shard sees views of the batch's arrays; random streams are
keyed by the global world index, so results do not depend on how the batch is split.
"""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import warp as wp

from .config import AquariumConfig
from .kernels import capture, motion, population, spawn
from .kernels import grid as grid_kernels
from .kernels.common import WorldParams


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


def cell_lists(cfg: AquariumConfig, num_worlds: int, dims: tuple[int, int], device) -> grid_kernels.CellLists:
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
    g.cell_start = wp.zeros(num_worlds * g.cells_per_world, dtype=int, device=device)
    g.cell_end = wp.zeros(num_worlds * g.cells_per_world, dtype=int, device=device)
    g.key = wp.zeros(2 * n, dtype=int, device=device)
    g.agent = wp.zeros(2 * n, dtype=int, device=device)
    g.position = wp.zeros(n, dtype=wp.vec2, device=device)
    g.speed = wp.zeros(n, dtype=float, device=device)
    g.heading = wp.zeros(n, dtype=wp.vec2, device=device)
    g.entry = wp.zeros(n, dtype=int, device=device)
    return g


class WorldShard:
    """Worlds `[w0, w1)` of a batch: MODEL.md's step as a fixed list of recorded launches."""

    def __init__(self, cfg: AquariumConfig, state, w0: int, w1: int, dims, types, action_direction,
                 observe_kernel, seed_key: int, device, auto_reset: bool = True):
        self.cfg, self.device = cfg, device
        self.w0, self.w1 = w0, w1
        self.num_worlds = W = w1 - w0
        self.auto_reset = auto_reset
        self.world = world_params(cfg, seed_key, w0, auto_reset)
        self.grid = cell_lists(cfg, W, dims, device)
        self.types = types
        self.action_direction = action_direction
        self.observe_kernel = observe_kernel
        self.s = SimpleNamespace(**{name: value[w0:w1] for name, value in vars(state).items()
                                    if isinstance(value, wp.array)})
        self.programs = {"step": self._step_program(), "observe": self._observe_program(),
                         "reset": self._reset_program()}

    def run(self, program: str) -> None:
        for command in self.programs[program]:
            command()

    def _launch(self, kernel, dim, inputs, outputs):
        return wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device,
                         record_cmd=True).launch

    # Programs ------------------------------------------------------------------------------------
    def _build_grid_program(self) -> list:
        """Cell lists of the current positions (no allocation, no host sync)."""
        s, g, W, C = self.s, self.grid, self.num_worlds, self.cfg.capacity
        count = W * C
        if not wp.get_device(self.device).is_cuda:
            return [self._launch(grid_kernels.sort_into_cells_per_world, W,
                                 [self.world, g, s.position, s.velocity, s.heading, s.alive],
                                 [g.key, g.cell_start, g.cell_end, g.agent, g.position, g.speed, g.heading])]
        return [
            self._launch(grid_kernels.compute_cell_keys, (W, C), [self.world, g, s.position, s.alive, W],
                         [g.key, g.agent]),
            functools.partial(wp.utils.radix_sort_pairs, g.key, g.agent, count),
            g.cell_start.zero_,
            g.cell_end.zero_,
            self._launch(grid_kernels.find_cell_ranges, count,
                         [self.world, g, s.position, s.velocity, s.heading, count, W * g.cells_per_world],
                         [g.cell_start, g.cell_end, g.position, g.speed, g.heading]),
        ]

    def _observe_program(self) -> list:
        """MODEL.md step 10 (and the contact partners of the next step's step 3)."""
        s, W, C = self.s, self.num_worlds, self.cfg.capacity
        return self._build_grid_program() + [
            self._launch(self.observe_kernel, W * C,
                         [self.world, self.types, self.grid, s.alive, W],
                         [s.obs_prey, s.obs_predator, s.mask_prey, s.mask_predator, s.slot_prey,
                          s.slot_predator, s.contact_partner, s.contact_offset]),
        ]

    def _spawn(self, only_ended: bool):
        s = self.s
        return self._launch(spawn.spawn_episode, (self.num_worlds, self.cfg.capacity),
                            [self.world, s.episode, int(only_ended), s.episode_ended],
                            [s.alive, s.position, s.velocity, s.acceleration, s.heading, s.age,
                             s.replication_age, s.starvation])

    def _reset_program(self) -> list:
        s, cfg = self.s, self.cfg
        return [s.world_step.zero_, s.episode.zero_, s.episode_captures.zero_, s.episode_return.zero_,
                s.episode_ended.zero_, functools.partial(s.prey_alive_count.fill_, cfg.prey_count),
                functools.partial(s.predator_alive_count.fill_, cfg.predator_count),
                self._spawn(only_ended=False)] + self._observe_program()

    def _step_program(self) -> list:
        """MODEL.md steps 1-10 for every world of the shard."""
        s, g, world, types, cfg = self.s, self.grid, self.world, self.types, self.cfg
        W, C, Pc, P = self.num_worlds, cfg.capacity, cfg.prey_capacity, cfg.predator_count
        program = [a.zero_ for a in (s.reward, s.terminated, s.truncated, s.captured, s.captures)]
        # 1-4: motion; contact partners were found by the last observation pass.
        program.append(self._launch(motion.integrate_motion, (W, C),
                                    [world, types, self.action_direction, s.prey_action, s.predator_action,
                                     s.alive, s.contact_partner, s.contact_offset],
                                    [s.position, s.velocity, s.acceleration, s.heading]))
        # 5: captures on the moved positions.
        program += self._build_grid_program()
        program.append(self._launch(capture.detect_captures, (W, P), [world, types, g, s.alive, s.position],
                                    [s.captured]))
        program.append(self._launch(capture.resolve_captures, (W, Pc),
                                    [world, types, g, s.world_step, s.episode, s.captured],
                                    [s.alive, s.position, s.velocity, s.acceleration, s.heading, s.age,
                                     s.replication_age, s.starvation, s.share_count, s.reward, s.terminated,
                                     s.captures, s.prey_alive_count]))
        program.append(self._launch(capture.share_capture_rewards, (W, P),
                                    [world, types, g, s.alive, s.position, s.captured, s.share_count],
                                    [s.reward, s.starvation]))
        # 6-7: starvation and reproduction.
        program.append(self._launch(population.starve_predators, (W, P), [world],
                                    [s.alive, s.starvation, s.terminated, s.predator_alive_count]))
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
        program.append(self._launch(population.truncate_ended_episodes, (W, C), [s.episode_ended, s.alive],
                                    [s.truncated, s.episode_return]))
        if self.auto_reset:
            program.append(self._spawn(only_ended=True))
        # 10: observations of the final state, and the contact partners of the next step's motion.
        return program + self._observe_program()
