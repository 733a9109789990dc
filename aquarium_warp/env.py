"""`BatchedAquarium`: many independent Aquarium worlds stepped at once by Warp kernels.

The step is a fixed sequence of kernel launches (docs/model.md steps 1-10) with no allocation and no host
synchronisation, replayed as a CUDA graph on GPU. Inputs and outputs are torch tensors that share
memory with the simulation (zero copy): returned tensors are overwritten by the next `step()`, so
clone what you keep.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import torch
import warp as wp

from . import checks
from .agent_types import TYPES
from .config import AquariumConfig
from .device import WARP_SETUP_LOCK, free_bytes, resolve_cpu_threads, resolve_device
from .params import BatchParams
from .per_world import check_live_counts, largest, merged_values, per_world, selected_worlds
from .seeding import seed_groups, seed_keys, seeds_value, set_params_stream
from .shard import Program, ShardSet, fused_step
from .state import STATE_DICT_FIELDS, SimulationState, estimate_bytes

# Worlds of at most this many slots are one cell, whose fixed whole-world lists need no build per step
# (H200, ~1M agents in flight: worlds of 64 stepped 14% faster with cells than as one cell).
SINGLE_CELL_CAPACITY = 32


def grid_dims(cfg: AquariumConfig) -> tuple[int, int]:
    """Cells per axis. A world of at most SINGLE_CELL_CAPACITY slots is one cell: checking every
    agent of the world costs less than building cell lists and visiting the cells around each agent.
    Otherwise cells at least
    slightly wider than the typical query radius let most queries finish within one ring, and at
    most about one cell per agent slot keeps the cell table small (at the default density that is
    about 190 px: on an H200, one world of 1M agents stepped 9% faster than with 101 px cells)."""
    # Per-world values: the largest (results do not depend on the cells, only the time does).
    prey_radius, predator_radius = largest(cfg.prey.radius), largest(cfg.predator.radius)
    contact = max(2 * prey_radius, 2 * predator_radius, prey_radius + predator_radius)
    if cfg.grid_cell_size is not None:
        target = cfg.grid_cell_size
    elif cfg.capacity <= SINGLE_CELL_CAPACITY:
        return 1, 1
    else:
        finite_views = [v for t in (cfg.prey, cfg.predator) for v in per_world(t.view_distance, 1) if math.isfinite(v)]
        target = 1.01 * max([contact] + ([min(finite_views)] if finite_views else []))
        max_cells = max(64, cfg.capacity)
        target = max(target, math.sqrt(cfg.width * cfg.height / max_cells))
    return max(1, int(cfg.width // target)), max(1, int(cfg.height // target))


def action_directions(action_count: int) -> np.ndarray:
    """`[action_count, 2]` float32 unit desired-velocity directions (sin theta, -cos theta) of the actions."""
    angles = 2.0 * np.pi * np.arange(action_count) / action_count
    directions = np.stack([np.sin(angles), -np.cos(angles)], axis=1)
    # Quarter turns are exact axes (sin(pi) is 1.2e-16 in floats, which would steer a prey that
    # already moves exactly along its desired direction).
    directions[np.abs(directions) < 1e-12] = 0.0
    return directions.astype(np.float32)


class StepResult(NamedTuple):
    """What `BatchedAquarium.step()` returns, and `BatchedAquarium.outputs` holds: a frozen record of
    the env's output buffers (torch tensors sharing memory with the simulation, overwritten by the
    next `step()`, `reset()` or `set_state()`: clone what you keep). Unpacks as the tuple
    `(observations, rewards, terminated, truncated, info)`.

    - `observations`: `{"prey": [W, prey_capacity, L_prey], "predator": [W, predator_capacity, L_predator]}`
      float32, the observations of the state after the step (docs/model.md step 10).
    - `rewards`: `{"prey": [W, prey_capacity], "predator": [W, predator_capacity]}` float32, this step's.
    - `terminated`, `truncated`: the same shapes, bool: the agent died in this step (captured without
      respawn, or starved); the agent was alive when its world's episode ended in this step.
    - `info`: per world `"captures"` `[W]` int32 (this step's), `"episode_ended"` `[W]` bool and, valid
      where that is set, `"episode_length"`, `"episode_captures"` `[W]` int32 and `"episode_return"`
      (`{"prey": [W], "predator": [W]}` float32, summed over the type's agents); plus `"alive"` and
      `"observation_mask"` (per type, as `env.alive` and `env.observation_mask`) of the observations.
    """

    observations: dict[str, torch.Tensor]
    rewards: dict[str, torch.Tensor]
    terminated: dict[str, torch.Tensor]
    truncated: dict[str, torch.Tensor]
    info: dict


class BatchedAquarium:
    """`num_worlds` independent Aquarium worlds on one device.

    Observations: `{"prey": [W, prey_capacity, L_prey], "predator": [W, predator_capacity, L_pred]}`
    float32; `observation_mask` says which neighbour slots are filled. Actions: integer tensors
    `{"prey": [W, prey_capacity], "predator": [W, predator_capacity]}` on the env's device; actions of
    dead slots are ignored. A world whose episode ends resets itself inside `step()`; with
    `auto_reset=False` it stays as it ended until `reset()` (single-world wrappers use this).
    `step_kernel` picks how a step is launched: "fused" (each world's whole step in one launch, for
    worlds of one cell: `kernels/world_step.py`), "stages" (a launch per stage) or "auto" (fused where
    it applies and, on a GPU, is faster: batches of at most `shard.AUTO_FUSED_GPU_MAX_SLOTS` slots);
    the results are the same.
    """

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device=None,
        seed: int | Sequence[int] = 0,
        cpu_threads: int | None = None,
        auto_reset: bool = True,
        step_kernel: str = "auto",
    ):
        if config is None:
            config = AquariumConfig()
        if not isinstance(config, AquariumConfig):
            raise ValueError(f"config must be an AquariumConfig, got {type(config).__name__}")
        if isinstance(num_worlds, bool) or not isinstance(num_worlds, (int, np.integer)) or num_worlds < 1:
            raise ValueError(f"num_worlds={num_worlds!r} must be an integer >= 1")
        if not isinstance(auto_reset, bool):
            raise ValueError(f"auto_reset={auto_reset!r} must be True or False")
        self.auto_reset = auto_reset
        seeds = seed_groups(seed, int(num_worlds))  # the seed's checks, before anything is drawn from it
        if config.num_worlds is not None and config.num_worlds != num_worlds:
            raise ValueError(
                f"the config gives per-world values for {config.num_worlds} worlds "
                f"({list(config.per_world_fields)}), but num_worlds={num_worlds}"
            )
        # Samplers are drawn once, from the seed: the env's config holds every world's values.
        self.config = cfg = config.draw(int(num_worlds), seeds_value(seeds)) if config.has_samplers else config
        self.num_worlds = W = int(num_worlds)
        self.device = resolve_device(device)
        self.torch_device = torch.device(self.device)
        self.seed = seeds_value(seeds)
        self._param_rng = set_params_stream(self.seed)  # `set_params`' samplers draw from it by default
        self.prey_capacity = cfg.prey_capacity
        self.predator_capacity = cfg.predator_capacity  # predator slots per world
        self.capacity = C = cfg.capacity
        self.observation_size = {t: cfg.observation_size(t) for t in TYPES}
        self.observed_slots = {t: getattr(cfg, t).predator_slots + getattr(cfg, t).prey_slots for t in TYPES}

        dims_x, dims_y = grid_dims(cfg)
        fused_step(step_kernel, (dims_x, dims_y))  # the option's errors before any allocation
        self._step_kernel_option = step_kernel
        cells = dims_x * dims_y
        if cells >= 2**31:
            smallest = math.sqrt(cfg.width * cfg.height / 2**30)
            raise ValueError(
                f"grid_cell_size={cfg.grid_cell_size!r} gives more than 2**31 cells per world (32-bit "
                f"cell indices): must be None or at least about {smallest:.3g} px"
            )
        if W * C * 2 >= 2**31 or W * cells + 1 >= 2**31:
            raise ValueError(
                f"num_worlds={W} x capacity={C} (cells per world {cells}) exceeds the 32-bit "
                "index range of the cell lists; use fewer worlds or agents"
            )
        self._check_memory(cells)

        with WARP_SETUP_LOCK:  # arrays of structs, kernels and recorded launches (see the lock)
            self._grid_dims = (dims_x, dims_y)
            self._params = BatchParams(cfg, W, self.device)
            self._action_direction: wp.array = wp.array(
                action_directions(cfg.action_count), dtype=wp.vec2, device=self.device
            )
            self.state = SimulationState.allocate(
                W,
                C,
                cfg.prey_capacity,
                cfg.predator_capacity,
                self.observation_size["prey"],
                self.observation_size["predator"],
                self.observed_slots["prey"],
                self.observed_slots["predator"],
                self.device,
            )
            self._write_seed(seeds)
            self._shards = ShardSet(
                cfg,
                self.state,
                self._grid_dims,
                self._params,
                self._action_direction,
                self.device,
                auto_reset,
                resolve_cpu_threads(cpu_threads),
                step_kernel,
            )
            self._build_views()
            self.reset()

    # ------------------------------------------------------------------ construction helpers
    def _check_memory(self, cells_per_world: int) -> None:
        need = estimate_bytes(self.config, self.num_worlds, cells_per_world)
        available = free_bytes(self.device)
        if need > 0.9 * available:
            raise ValueError(
                f"num_worlds={self.num_worlds} with capacity {self.capacity} needs about "
                f"{need / 2**30:.2f} GiB on {self.device}, but only {available / 2**30:.2f} GiB "
                "is free; use fewer worlds or agents"
            )

    def _build_views(self) -> None:
        t, Pc = self.state.torch, self.prey_capacity
        self.observations = {"prey": t.obs_prey, "predator": t.obs_predator}
        self.observation_mask = {"prey": t.mask_prey, "predator": t.mask_predator}
        self.observed_slot = {"prey": t.slot_prey, "predator": t.slot_predator}
        self.alive = {"prey": t.alive[:, :Pc], "predator": t.alive[:, Pc:]}
        self._actions = {"prey": t.prey_action, "predator": t.predator_action}
        info = {
            "captures": t.captures,
            "episode_ended": t.episode_ended,
            "episode_length": t.ended_length,
            "episode_captures": t.ended_captures,
            "episode_return": {"prey": t.ended_return[:, 1], "predator": t.ended_return[:, 0]},
            "alive": self.alive,
            "observation_mask": self.observation_mask,
        }
        self._outputs = StepResult(
            self.observations,
            {"prey": t.reward[:, :Pc], "predator": t.reward[:, Pc:]},
            {"prey": t.terminated[:, :Pc], "predator": t.terminated[:, Pc:]},
            {"prey": t.truncated[:, :Pc], "predator": t.truncated[:, Pc:]},
            info,
        )

    # ------------------------------------------------------------------ shards and programs
    def run_on_shards(self, work) -> None:
        """Call `work(shard)` for every `WorldShard` the way the env runs its own programs (see
        `ShardSet.run`)."""
        self._shards.run(work)

    def record_program(self, build) -> Program:
        """A launch program recorded once and run by `program.run()` on every shard, as the env runs its
        own: `build(shard)` returns the shard's commands, made with `shard.record(kernel, dim, inputs,
        outputs)` from the shard's `state` groups, `grid`, `world` and `types`. The seed and the episode
        counters are device data, so a program never needs recording again (heuristics and metrics
        record theirs this way)."""
        return self._shards.record(build)

    @property
    def shards(self) -> tuple:
        """The `WorldShard`s (blocks of worlds with their cell lists and parameter structs); their
        cell lists hold the positions of the last returned observations."""
        return self._shards.shards

    @property
    def step_kernel(self) -> str:
        """How a step is launched: "fused" (one launch, `kernels/world_step.py`) or "stages"."""
        return self._shards.step_path

    @property
    def grid_dims(self) -> tuple[int, int]:
        """Cells per axis of each world's cell lists (`grid_dims(config)`)."""
        return self._grid_dims

    @property
    def agent_types(self) -> wp.array:
        """`[W, 2]` per-type parameters of every world (`kernels.common.AgentType`), indexed by world and
        type code (predator 0, prey 1)."""
        return self._params.types

    @property
    def max_speeds(self) -> torch.Tensor:
        """`[W, 2]` float64 max speed of each world's predators (column `PREDATOR` = 0) and prey
        (`PREY` = 1), px/step, on the env's device; `set_params` updates it in place."""
        return self._params.max_speed

    @property
    def world_values(self) -> wp.array:
        """`[W]` per-world parameters (`kernels.common.WorldValues`)."""
        return self._params.values

    @property
    def action_directions(self) -> wp.array:
        """[action_count] vec2: unit desired direction of each action."""
        return self._action_direction

    @property
    def step_capturable(self) -> bool:
        """Whether `step()` may run inside a torch CUDA graph capture, its launches recorded into it (a
        training loop's whole-rollout graph): on the CPU and for worlds whose cell lists are not built
        by counts and a prefix sum (more slots than `shard.RANK_SORT_MAX_CAPACITY` with several cells)."""
        return self._shards.capturable

    def _write_seed(self, seeds: tuple[int, ...]) -> None:
        """Every world's stream key and stream index from the seeds of its group (`seed_groups`)."""
        worlds = np.tile(np.arange(self.num_worlds // len(seeds), dtype=np.int32), len(seeds))
        counters = self.state.worlds
        wp.copy(counters.seed, wp.array(seed_keys(seeds, self.num_worlds), dtype=wp.uint32, device=self.device))
        wp.copy(counters.stream_world, wp.array(worlds, dtype=wp.int32, device=self.device))

    def _run(self, program: str) -> None:
        """Run one of the env's programs: "step", "observe" or "reset"."""
        self._shards.programs[program].run()

    # ------------------------------------------------------------------ public API
    def reset(self, seed: int | None = None) -> dict[str, torch.Tensor]:
        """Start a new episode in every world; with `seed`, reseed first (a write of the seed's key into
        the device counters: nothing is rebuilt or recorded again). Returns the observations."""
        if seed is not None:
            seeds = seed_groups(seed, self.num_worlds)
            self.seed = seeds_value(seeds)
            self._param_rng = set_params_stream(self.seed)
            self._write_seed(seeds)
        self._run("reset")
        return self.observations

    @property
    def actions(self) -> dict[str, torch.Tensor]:
        """The step's input buffers: `{"prey": [W, prey_capacity], "predator": [W, predator_capacity]}` int32
        tensors on the env's device. `step(actions)` copies into them; writing into them and calling
        `step()` with no actions skips that copy."""
        return self._actions

    @property
    def outputs(self) -> StepResult:
        """The outputs of the last `step()` (observations: of the last `step()`, `reset()` or
        `set_state()`), as the `StepResult` that `step()` returns: the same buffers, always current."""
        return self._outputs

    def set_actions(self, actions: Mapping[str, torch.Tensor], validate: bool = True) -> None:
        """Copy `actions` (see `step`) into the input buffers `actions`, checked first unless `validate`
        is False."""
        if validate:
            checks.check_actions(self, actions)
        for t in TYPES:
            self._actions[t].copy_(checks.action_tensor(actions[t]))

    def step(self, actions: Mapping[str, torch.Tensor] | None = None, validate: bool = True) -> StepResult:
        """Advance every world by one step with `actions` (integer tensors `{"prey": [W, prey_capacity],
        "predator": [W, predator_capacity]}` on the env's device), or, with None, with the actions already
        in the `actions` buffers.

        Returns a `StepResult`, which unpacks as `(obs, rewards, terminated, truncated, info)`: dicts of
        torch tensors keyed by agent type; `info` holds per-world "captures" this step,
        "episode_ended" and, valid where it is set, "episode_length", "episode_captures" and
        "episode_return" (summed over the type's agents), plus "alive" and "observation_mask" of the
        returned observations. Worlds whose episode ended were reset, so their observations are the
        new episode's first ones.

        `validate=False` skips the host-side checks of the actions (and their one device sync); an action
        outside [0, action_count - 1] is then clamped into that range by the motion kernel, so no value
        reads or writes out of bounds.
        """
        if actions is None:
            if validate:
                checks.check_actions(self, self._actions)
        else:
            self.set_actions(actions, validate)
        self._run("step")
        return self._outputs

    # ------------------------------------------------------------------ per-world parameters
    def set_params(
        self, world=None, validate: bool = True, rng: np.random.Generator | None = None, **fields
    ) -> AquariumConfig:
        """Give worlds new parameter values between steps: `world` None (every world), an index or a
        sequence of indices; `fields` by name, the world fields of `per_world.PER_WORLD_FIELDS`
        (`prey_reward=2.0`, `flow=FlowConfig(...)`, `prey_count=8`) and the per-type ones as
        `prey_<field>` / `predator_<field>` (`prey_max_speed=[3.0, 5.0]`); a value is a scalar (every
        selected world), one value per selected world, or a sampler (`Uniform`, `LogUniform`,
        `Choice`, drawn from `rng`, a numpy Generator; by default from the env's own generator, seeded
        by the env's seed when the env is made and at a seeded `reset`, so each call draws new values).

        Values are checked world by world before anything changes (a bad one raises `ValueError`
        naming the field, the world and the allowed range); then they are copied into the device
        arrays the kernels read, so the next step uses them (a live count at the world's next reset).
        Nothing is rebuilt or recorded again. Returns the new `config`. `validate=False` skips the
        per-world checks of the values (about 70 us per world; the live counts' limits stay checked):
        for values already known to be valid, such as draws from a range checked once."""
        worlds = selected_worlds(world, self.num_worlds)
        if rng is None:
            rng = self._param_rng
        elif not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng={rng!r} must be a numpy.random.Generator or None")
        values = merged_values(self.config._field, self.num_worlds, worlds, fields, rng)
        new = self.config.with_values(values, validate)  # checks every world (an error names the world)
        check_live_counts(new._field, self.num_worlds, {"prey": self.prey_capacity, "predator": self.predator_capacity})
        self._params.write(new)
        self.config = new
        return new

    # ------------------------------------------------------------------ state access
    def set_state(self, world: int | None = None, **fields) -> dict[str, torch.Tensor]:
        """Overwrite part of the state and recompute everything derived from it (counts, cell lists,
        observations). Fields: the agent fields of `state.AGENT_FIELDS` shaped `[C, ...]` (one world) or
        `[W, C, ...]` (all worlds, `world=None`), and `world_step` / `episode` (a scalar for one world,
        `[W]` for all). Every value is checked (see `state_value_ranges`) before anything is written:
        a bad call raises `ValueError` and changes nothing. Returns the observations of the new state."""
        t = self.state.torch
        staged = checks.checked_state_fields(self, world, fields)
        sel = slice(None) if world is None else int(world)
        for name, value in staged.items():
            getattr(t, name)[sel].copy_(value.to(self.torch_device))
        alive = t.alive
        t.prey_alive_count.copy_(alive[:, : self.prey_capacity].sum(dim=1).to(torch.int32))
        t.predator_alive_count.copy_(alive[:, self.prey_capacity :].sum(dim=1).to(torch.int32))
        self._run("observe")
        return self.observations

    def state_value_ranges(self) -> dict[str, str]:
        """The values `set_state` and `load_state_dict` accept, per field. Integer counters are int32 on
        the device and must not overflow within an episode; vectors must keep the kernels' float32
        arithmetic finite (`checks.LARGEST`)."""
        return checks.state_value_ranges(self)

    def state_dict(self) -> dict:
        """A copy of the whole simulation state (CPU tensors) plus the config and seed."""
        t = self.state.torch
        return {
            "config": self.config.to_dict(),
            "num_worlds": self.num_worlds,
            "seed": self.seed,
            "tensors": {n: getattr(t, n).detach().cpu().clone() for n in STATE_DICT_FIELDS},
        }

    def load_state_dict(self, state: Mapping) -> dict[str, torch.Tensor]:
        """Restore a `state_dict()` taken from an env with the same config and number of worlds. All or
        nothing: every tensor's presence, shape, dtype and values (ranges, finiteness, live counts
        matching the alive flags) and the seed are checked before anything changes."""
        if not isinstance(state, Mapping):
            raise ValueError(f"state_dict must be a dict, got {type(state).__name__}")
        missing = [k for k in ("config", "num_worlds", "seed", "tensors") if k not in state]
        if missing:
            raise ValueError(f"state_dict lacks {missing}; expected a BatchedAquarium.state_dict()")
        try:  # a config saved before a field existed holds that field's default
            saved = AquariumConfig.from_dict(state["config"]).to_dict()
        except (TypeError, ValueError):
            saved = None
        if saved != self.config.to_dict() or state["num_worlds"] != self.num_worlds:
            raise ValueError("state_dict was taken from an env with another config or num_worlds")
        try:
            seeds = seed_groups(state["seed"], self.num_worlds)
        except ValueError as error:
            raise ValueError(f"state_dict {error}") from None
        staged = checks.checked_state_tensors(self, state["tensors"])
        t = self.state.torch
        self.seed = seeds_value(seeds)
        self._write_seed(seeds)
        for name, value in staged.items():
            getattr(t, name).copy_(value.to(self.torch_device))
        self._run("observe")
        return self.observations

    # ------------------------------------------------------------------ pickling and copying
    # Outputs of the last step that `load_state_dict` does not recompute: carried so that a copy's
    # buffers hold what the original's last `step()` returned, not only the state.
    _CARRIED_OUTPUTS = (
        "reward",
        "terminated",
        "truncated",
        "captures",
        "episode_ended",
        "ended_length",
        "ended_captures",
        "ended_return",
        "prey_action",
        "predator_action",
    )

    def __getstate__(self) -> dict:
        """Pickle and `copy.deepcopy` carry the constructor's arguments, `state_dict()` and the last
        step's outputs; Warp arrays, kernels, threads and CUDA graphs cannot travel and are rebuilt
        by `__setstate__`, so the copy continues the same trajectory."""
        t = self.state.torch
        return {
            "config": self.config,
            "num_worlds": self.num_worlds,
            "device": self.device,
            "cpu_threads": len(self.shards),  # the same split of worlds over threads
            "auto_reset": self.auto_reset,
            "step_kernel": self._step_kernel_option,
            "state": self.state_dict(),
            "outputs": {n: getattr(t, n).detach().cpu().clone() for n in self._CARRIED_OUTPUTS},
        }

    def __setstate__(self, saved: dict) -> None:
        state = saved["state"]
        type(self).__init__(
            self,
            saved["config"],
            num_worlds=saved["num_worlds"],
            device=saved["device"],
            seed=state["seed"],
            cpu_threads=saved["cpu_threads"],
            auto_reset=saved["auto_reset"],
            step_kernel=saved.get("step_kernel", "auto"),
        )
        self.load_state_dict(state)
        t = self.state.torch
        for name, value in saved["outputs"].items():
            getattr(t, name).copy_(value.to(self.torch_device))

    def close(self) -> None:
        """Release the CUDA graph and the worker threads; the arrays go with the object."""
        shards = getattr(self, "_shards", None)  # absent if the constructor failed
        if shards is not None:
            shards.close()

    def __del__(self) -> None:
        self.close()
