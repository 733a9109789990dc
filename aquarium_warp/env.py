"""`BatchedAquarium`: many independent Aquarium worlds stepped at once by Warp kernels.

The step is a fixed sequence of kernel launches (MODEL.md steps 1-10) with no allocation and no host
synchronisation, replayed as a CUDA graph on GPU. Inputs and outputs are torch tensors that share
memory with the simulation (zero copy): returned tensors are overwritten by the next `step()`, so
clone what you keep.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from typing import Mapping

import numpy as np
import torch
import warp as wp

from .config import AquariumConfig
from .state import AGENT_FIELDS, WORLD_FIELDS, SimulationState, estimate_bytes
from .kernels import observation
from .kernels.common import AgentType
from .shard import WorldShard

TYPES = ("prey", "predator")
# Below this many worlds per thread, the thread hand-off costs more than the second core gives.
MIN_WORLDS_PER_THREAD = 32
OBSERVATION_BLOCK = 128  # threads per block of the GPU observation kernel
# Worlds of at most this many slots are one cell, whose fixed whole-world lists need no build per step
# (H200, ~1M agents in flight: worlds of 64 stepped 14% faster with cells than as one cell).
SINGLE_CELL_CAPACITY = 32
_warp_ready = False
# What Warp's native library prints during init on a machine without the NVIDIA driver.
_NO_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"
_init_messages = ""  # what init printed while silenced


def _wants_cuda(device) -> bool:
    return (device.type == "cuda") if isinstance(device, torch.device) else (
        isinstance(device, str) and device.startswith("cuda"))


def _init_warp(device=None) -> None:
    """Initialise Warp once. Its native library warns on stderr when no CUDA driver is found, also
    for users who never asked for CUDA; unless `device` names CUDA, that warning is held back (kept
    for the error that `resolve_device` raises if CUDA is asked for later) and anything else printed
    during init is passed on."""
    global _warp_ready, _init_messages
    if _warp_ready:
        return
    wp.config.log_level = wp.LOG_WARNING  # no banner
    if _wants_cuda(device):
        wp.init()
    else:
        sys.stderr.flush()
        saved = os.dup(2)
        with tempfile.TemporaryFile(mode="w+b") as captured:
            os.dup2(captured.fileno(), 2)
            try:
                wp.init()
            finally:
                os.dup2(saved, 2)
                os.close(saved)
            captured.seek(0)
            _init_messages = captured.read().decode(errors="replace")
        others = [line for line in _init_messages.splitlines(keepends=True) if _NO_DRIVER_WARNING not in line]
        if others:
            sys.stderr.write("".join(others))
    _warp_ready = True


def resolve_device(device) -> str:
    """Warp device name for `device`: None picks "cuda:0" when CUDA is present, else "cpu"."""
    _init_warp(device)
    if device is None:
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if isinstance(device, torch.device):
        device = str(device) if device.type == "cpu" or device.index is not None else f"{device.type}:0"
    if not isinstance(device, str):
        raise ValueError(f"device={device!r} must be None, a string like 'cpu' or 'cuda:0', or a torch.device")
    if device == "cuda":
        device = "cuda:0"
    names = [d.alias for d in wp.get_devices()]
    if device not in names:
        driver = f" ({_init_messages.strip()})" if _NO_DRIVER_WARNING in _init_messages and _wants_cuda(device) else ""
        raise ValueError(f"device={device!r} is not available; available devices: {names}{driver}")
    return device


def seed_key(seed) -> int:
    """The 32-bit key of the random streams for a non-negative integer `seed`."""
    if isinstance(seed, (bool, float)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r} must be a non-negative integer")
    seed = int(seed)
    key = 0
    while True:  # fold every 32-bit word of the seed into the key
        key = (key * 0x9E3779B1 + (seed & 0xFFFFFFFF)) & 0xFFFFFFFF
        seed >>= 32
        if seed == 0:
            return key


def _cpu_threads(cpu_threads) -> int:
    if cpu_threads is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if isinstance(cpu_threads, bool) or not isinstance(cpu_threads, int) or cpu_threads < 1:
        raise ValueError(f"cpu_threads={cpu_threads!r} must be None or an integer >= 1")
    return cpu_threads


def _grid_dims(cfg: AquariumConfig) -> tuple[int, int]:
    """Cells per axis. A world of at most SINGLE_CELL_CAPACITY slots is one cell: checking every
    agent of the world costs less than building cell lists and visiting the cells around each agent. Otherwise cells at least
    slightly wider than the typical query radius let most queries finish within one ring, and at
    most about one cell per agent slot keeps the cell table small (at the default density that is
    about 190 px: on an H200, one world of 1M agents stepped 9% faster than with 101 px cells)."""
    contact = max(2 * cfg.prey.radius, 2 * cfg.predator.radius, cfg.prey.radius + cfg.predator.radius)
    if cfg.grid_cell_size is not None:
        target = cfg.grid_cell_size
    elif cfg.capacity <= SINGLE_CELL_CAPACITY:
        return 1, 1
    else:
        finite_views = [v for v in (cfg.prey.view_distance, cfg.predator.view_distance) if math.isfinite(v)]
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


def _type_params(cfg: AquariumConfig, t) -> AgentType:
    p = AgentType()
    p.max_speed = t.max_speed
    p.max_steering_force = t.max_steering_force
    p.max_acceleration = t.max_acceleration
    p.mass = t.mass
    p.radius = t.radius
    p.view_distance = t.view_distance
    p.distance_norm = min(t.view_distance, cfg.max_torus_distance)
    cos_half_fov = math.cos(math.radians(t.fov_angle / 2.0))
    # cos(90 deg) is 6e-17 in floats: it would exclude the inclusive boundary of a 180-degree cone.
    p.cos_half_fov = -2.0 if t.fov_angle >= 360 else (0.0 if abs(cos_half_fov) < 1e-12 else cos_half_fov)
    p.bounce_strength = t.bounce_strength
    p.predator_slots = t.predator_slots
    p.prey_slots = t.prey_slots
    return p


class BatchedAquarium:
    """`num_worlds` independent Aquarium worlds on one device.

    Observations: `{"prey": [W, prey_capacity, L_prey], "predator": [W, predator_count, L_pred]}`
    float32; `observation_mask` says which neighbour slots are filled. Actions: integer tensors
    `{"prey": [W, prey_capacity], "predator": [W, predator_count]}` on the env's device; actions of
    dead slots are ignored. A world whose episode ends resets itself inside `step()`; with
    `auto_reset=False` it stays as it ended until `reset()` (single-world wrappers use this).
    """

    def __init__(self, config: AquariumConfig | None = None, num_worlds: int = 1, device=None, seed: int = 0,
                 cpu_threads: int | None = None, auto_reset: bool = True):
        if config is None:
            config = AquariumConfig()
        if not isinstance(config, AquariumConfig):
            raise ValueError(f"config must be an AquariumConfig, got {type(config).__name__}")
        if isinstance(num_worlds, bool) or not isinstance(num_worlds, (int, np.integer)) or num_worlds < 1:
            raise ValueError(f"num_worlds={num_worlds!r} must be an integer >= 1")
        if not isinstance(auto_reset, bool):
            raise ValueError(f"auto_reset={auto_reset!r} must be True or False")
        self.auto_reset = auto_reset
        self.config = cfg = config
        self.num_worlds = W = int(num_worlds)
        self.device = resolve_device(device)
        self.torch_device = torch.device(self.device)
        seed_key(seed)
        self.seed = int(seed)
        self.prey_capacity = cfg.prey_capacity
        self.predator_count = cfg.predator_count
        self.capacity = C = cfg.capacity
        self.observation_size = {"prey": cfg.prey.observation_size, "predator": cfg.predator.observation_size}
        self.observed_slots = {t: getattr(cfg, t).predator_slots + getattr(cfg, t).prey_slots for t in TYPES}

        dims_x, dims_y = _grid_dims(cfg)
        cells = dims_x * dims_y
        if W * C * 2 >= 2**31 or W * cells + 1 >= 2**31:
            raise ValueError(f"num_worlds={W} x capacity={C} (cells per world {cells}) exceeds the 32-bit "
                             "index range of the cell lists; use fewer worlds or agents")
        self._check_memory(cells)

        self._dims = (dims_x, dims_y)
        types = [_type_params(cfg, cfg.predator), _type_params(cfg, cfg.prey)]  # index = type code
        self._types = wp.array(types, dtype=AgentType, device=self.device)
        self._action_direction = wp.array(action_directions(cfg.action_count), dtype=wp.vec2, device=self.device)
        self.state = SimulationState(W, C, cfg.prey_capacity, cfg.predator_count,
                                     self.observation_size["prey"], self.observation_size["predator"],
                                     self.observed_slots["prey"], self.observed_slots["predator"], self.device)
        # One observation kernel per observer type's slot counts; rows are staged by blocks of
        # OBSERVATION_BLOCK threads on a GPU (tile kernels run one thread per block on the CPU).
        block = OBSERVATION_BLOCK if wp.get_device(self.device).is_cuda else 1
        whole_world = self._dims == (1, 1)  # the shards' cell lists are whole-world lists
        self._observe_kernels = {t: observation.observation_kernel(getattr(cfg, t).predator_slots,
                                                                   getattr(cfg, t).prey_slots, block, whole_world)
                                 for t in TYPES}
        threads = _cpu_threads(cpu_threads) if not wp.get_device(self.device).is_cuda else 1
        shards = max(1, min(threads, W // MIN_WORLDS_PER_THREAD))
        bounds = [W * k // shards for k in range(shards + 1)]
        self._shard_ranges = list(zip(bounds[:-1], bounds[1:]))
        self._pool = ThreadPoolExecutor(max_workers=shards) if shards > 1 else None
        self._make_shards(seed_key(seed))
        self._build_views()
        self.reset()

    # ------------------------------------------------------------------ construction helpers
    def _check_memory(self, cells_per_world: int) -> None:
        need = estimate_bytes(self.config, self.num_worlds, cells_per_world)
        dev = wp.get_device(self.device)
        if dev.is_cuda:
            available = dev.free_memory
        else:
            available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
        if need > 0.9 * available:
            raise ValueError(f"num_worlds={self.num_worlds} with capacity {self.capacity} needs about "
                             f"{need / 2**30:.2f} GiB on {self.device}, but only {available / 2**30:.2f} GiB "
                             "is free; use fewer worlds or agents")

    def _build_views(self) -> None:
        t, Pc = self.state.torch, self.prey_capacity
        self.observations = {"prey": t.obs_prey, "predator": t.obs_predator}
        self.observation_mask = {"prey": t.mask_prey, "predator": t.mask_predator}
        self.observed_slot = {"prey": t.slot_prey, "predator": t.slot_predator}
        self._rewards = {"prey": t.reward[:, :Pc], "predator": t.reward[:, Pc:]}
        self._terminated = {"prey": t.terminated[:, :Pc], "predator": t.terminated[:, Pc:]}
        self._truncated = {"prey": t.truncated[:, :Pc], "predator": t.truncated[:, Pc:]}
        self.alive = {"prey": t.alive[:, :Pc], "predator": t.alive[:, Pc:]}
        self._actions = {"prey": t.prey_action, "predator": t.predator_action}
        self._info = {
            "captures": t.captures,
            "episode_ended": t.episode_ended,
            "episode_length": t.ended_length,
            "episode_captures": t.ended_captures,
            "episode_return": {"prey": t.ended_return[:, 1], "predator": t.ended_return[:, 0]},
            "alive": self.alive,
            "observation_mask": self.observation_mask,
        }

    # ------------------------------------------------------------------ running the shards
    def _make_shards(self, seed_key: int) -> None:
        self._shards = [
            WorldShard(self.config, self.state, w0, w1, self._dims, self._types, self._action_direction,
                       self._observe_kernels, seed_key, self.device, self.auto_reset)
            for w0, w1 in self._shard_ranges
        ]
        self._graph = None

    def run_on_shards(self, work) -> None:
        """Call `work(shard)` for every `WorldShard` the way the env runs its own programs: shards
        in parallel threads on CPU (Warp's CPU kernels release the GIL); on GPU on Warp's stream,
        ordered after the torch work that produced the inputs and before the torch work that reads
        the outputs (torch's legacy default stream cannot be captured into a graph)."""
        if not wp.get_device(self.device).is_cuda:
            if self._pool is not None:
                list(self._pool.map(work, self._shards))
            else:
                for shard in self._shards:
                    work(shard)
            return
        torch_stream = wp.stream_from_torch(torch.cuda.current_stream(self.torch_device))
        stream = wp.get_stream(self.device)
        stream.wait_stream(torch_stream)
        with wp.ScopedStream(stream):
            for shard in self._shards:
                work(shard)
        torch_stream.wait_stream(stream)

    @property
    def shards(self) -> tuple:
        """The `WorldShard`s (blocks of worlds with their cell lists and parameter structs); their
        cell lists hold the positions of the last returned observations."""
        return tuple(self._shards)

    @property
    def agent_types(self) -> wp.array:
        """Per-type parameters (`kernels.common.AgentType`), indexed by type code (predator 0, prey 1)."""
        return self._types

    @property
    def action_directions(self) -> wp.array:
        """[action_count] vec2: unit desired direction of each action."""
        return self._action_direction

    def _run(self, program: str) -> None:
        """Run a shard program ("step", "observe" or "reset"); the step is one CUDA graph on GPU."""
        if program != "step" or not wp.get_device(self.device).is_cuda:
            self.run_on_shards(lambda shard: shard.run(program))
            return

        def step_graph(shard):
            if self._graph is None:
                shard.run(program)  # loads every module before capture
                with wp.ScopedCapture(device=self.device, stream=wp.get_stream(self.device)) as capture_scope:
                    shard.run(program)
                self._graph = capture_scope.graph
            else:
                wp.capture_launch(self._graph, stream=wp.get_stream(self.device))

        self.run_on_shards(step_graph)

    # ------------------------------------------------------------------ public API
    def reset(self, seed: int | None = None) -> dict[str, torch.Tensor]:
        """Start a new episode in every world; with `seed`, reseed first. Returns the observations."""
        if seed is not None:
            key = seed_key(seed)
            self.seed = int(seed)
            self._make_shards(key)  # the seed is baked into recorded launches and graphs
        self._run("reset")
        return self.observations

    def step(self, actions: Mapping[str, torch.Tensor], validate: bool = True):
        """Advance every world by one step.

        Returns `(obs, rewards, terminated, truncated, info)`: dicts of torch tensors keyed by agent
        type ("prey" [W, prey_capacity], "predator" [W, predator_count]); `info` holds per-world
        "captures" this step, "episode_ended" and, valid where it is set, "episode_length",
        "episode_captures" and "episode_return" (summed over the type's agents), plus "alive" and
        "observation_mask" of the returned observations. Worlds whose episode ended were reset, so
        their observations are the new episode's first ones.
        """
        if validate:
            self._validate_actions(actions)
        for t in TYPES:
            self._actions[t].copy_(actions[t] if isinstance(actions[t], torch.Tensor) else torch.as_tensor(actions[t]))
        self._run("step")
        return self.observations, self._rewards, self._terminated, self._truncated, self._info

    def _validate_actions(self, actions) -> None:
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict with keys {TYPES}, got {type(actions).__name__}")
        missing = [t for t in TYPES if t not in actions]
        extra = [k for k in actions if k not in TYPES]
        if missing or extra:
            raise ValueError(f"actions must have exactly the keys {TYPES}; missing {missing}, unknown {extra}")
        n = self.config.action_count
        for t in TYPES:
            a = actions[t]
            expected = tuple(self._actions[t].shape)
            if isinstance(a, np.ndarray):
                if self.torch_device.type != "cpu":
                    raise ValueError(f"actions[{t!r}] is a numpy array; pass a torch tensor on {self.device}")
                a = torch.from_numpy(a)
            if not isinstance(a, torch.Tensor):
                raise ValueError(f"actions[{t!r}] must be a torch tensor, got {type(a).__name__}")
            if a.dtype.is_floating_point or a.dtype.is_complex or a.dtype == torch.bool:
                raise ValueError(f"actions[{t!r}] must have an integer dtype, got {a.dtype}")
            if tuple(a.shape) != expected:
                raise ValueError(f"actions[{t!r}] must have shape {list(expected)} "
                                 f"(num_worlds, {t} slots), got {list(a.shape)}")
            if a.device != self.torch_device:
                raise ValueError(f"actions[{t!r}] is on {a.device}, but the env runs on {self.device}")
            bad = ((a < 0) | (a >= n)) & self.alive[t]
            if bool(bad.any()):
                w, i = (int(x) for x in torch.nonzero(bad)[0])
                raise ValueError(f"actions[{t!r}][{w}, {i}]={int(a[w, i])} is out of range: live agents' "
                                 f"actions must be in [0, {n - 1}] (action_count={n})")

    # ------------------------------------------------------------------ state access
    def set_state(self, world: int | None = None, **fields) -> dict[str, torch.Tensor]:
        """Overwrite part of the state and recompute everything derived from it (counts, cell lists,
        observations). Fields: the agent fields of `AGENT_FIELDS` shaped `[C, ...]` (one world) or
        `[W, C, ...]` (all worlds, `world=None`), and `world_step` / `episode` (a scalar for one world,
        `[W]` for all). Headings must be unit vectors. Returns the observations of the new state."""
        t = self.state.torch
        unknown = [k for k in fields if k not in AGENT_FIELDS and k not in ("world_step", "episode")]
        if unknown:
            raise ValueError(f"unknown state fields {unknown}; settable: {list(AGENT_FIELDS)} + ['world_step', 'episode']")
        if world is not None and (isinstance(world, bool) or not isinstance(world, (int, np.integer))
                                  or not 0 <= world < self.num_worlds):
            raise ValueError(f"world={world!r} must be None or an integer in [0, {self.num_worlds - 1}]")
        sel = slice(None) if world is None else int(world)
        staged = {}
        for name, value in fields.items():
            target = getattr(t, name)[sel]
            value = torch.as_tensor(np.asarray(value) if not isinstance(value, torch.Tensor) else value).cpu()
            if target.dtype == torch.bool and not value.dtype == torch.bool and not ((value == 0) | (value == 1)).all():
                raise ValueError(f"{name} must hold booleans (or 0/1)")
            if target.dtype == torch.int32 and (value.dtype.is_floating_point or value.dtype == torch.bool):
                if value.dtype == torch.bool or not (torch.isfinite(value) & (value == value.round())).all():
                    raise ValueError(f"{name} must hold integers")
            value = value.to(target.dtype)
            if name in ("world_step", "episode") and world is None and value.dim() == 0:
                value = value.expand(target.shape)
            if tuple(value.shape) != tuple(target.shape):
                raise ValueError(f"{name} must have shape {list(target.shape)}, got {list(value.shape)}")
            staged[name] = value
        self._check_state_values(staged, sel)
        for name, value in staged.items():
            getattr(t, name)[sel].copy_(value.to(self.torch_device))
        alive = t.alive
        t.prey_alive_count.copy_(alive[:, : self.prey_capacity].sum(dim=1).to(torch.int32))
        t.predator_alive_count.copy_(alive[:, self.prey_capacity:].sum(dim=1).to(torch.int32))
        self._run("observe")
        return self.observations

    def _check_state_values(self, staged: dict, sel) -> None:
        cfg = self.config
        if "position" in staged:
            p = staged["position"]
            if not torch.isfinite(p).all():
                raise ValueError("position must be finite")
            if (p[..., 0] < 0).any() or (p[..., 0] >= cfg.width).any() or (p[..., 1] < 0).any() or (p[..., 1] >= cfg.height).any():
                raise ValueError(f"position must lie in [0, {cfg.width}) x [0, {cfg.height})")
        for name in ("velocity", "acceleration", "heading"):
            if name in staged and not torch.isfinite(staged[name]).all():
                raise ValueError(f"{name} must be finite")
        if "heading" in staged:
            norm = torch.linalg.vector_norm(staged["heading"].double(), dim=-1)
            if ((norm - 1.0).abs() > 1e-4).any():
                raise ValueError("heading must hold unit vectors (|heading| = 1 within 1e-4)")
        for name in ("age", "replication_age", "starvation", "world_step", "episode"):
            if name in staged and (staged[name] < 0).any():
                raise ValueError(f"{name} must be >= 0")
        if "world_step" in staged and (staged["world_step"] >= cfg.max_steps).any():
            raise ValueError(f"world_step must be in [0, {cfg.max_steps - 1}] (max_steps={cfg.max_steps})")

    def state_dict(self) -> dict:
        """A copy of the whole simulation state (CPU tensors) plus the config and seed."""
        t = self.state.torch
        names = list(AGENT_FIELDS) + list(WORLD_FIELDS) + ["episode_return"]
        return {
            "config": self.config.to_dict(),
            "num_worlds": self.num_worlds,
            "seed": self.seed,
            "tensors": {n: getattr(t, n).detach().cpu().clone() for n in names},
        }

    def load_state_dict(self, state: dict) -> dict[str, torch.Tensor]:
        """Restore a `state_dict()` taken from an env with the same config and number of worlds."""
        if state.get("config") != self.config.to_dict() or state.get("num_worlds") != self.num_worlds:
            raise ValueError("state_dict was taken from an env with another config or num_worlds")
        if state.get("seed") != self.seed:
            self.seed = int(state["seed"])
            self._make_shards(seed_key(self.seed))
        t = self.state.torch
        for name, value in state["tensors"].items():
            target = getattr(t, name)
            if tuple(value.shape) != tuple(target.shape):
                raise ValueError(f"state_dict tensor {name} has shape {list(value.shape)}, expected {list(target.shape)}")
            target.copy_(value.to(self.torch_device))
        self._run("observe")
        return self.observations

    # ------------------------------------------------------------------ pickling and copying
    # Outputs of the last step that `load_state_dict` does not recompute: carried so that a copy's
    # buffers hold what the original's last `step()` returned, not only the state.
    _CARRIED_OUTPUTS = ("reward", "terminated", "truncated", "captures", "episode_ended", "ended_length",
                        "ended_captures", "ended_return", "prey_action", "predator_action")

    def __getstate__(self) -> dict:
        """Pickle and `copy.deepcopy` carry the constructor's arguments, `state_dict()` and the last
        step's outputs; Warp arrays, kernels, threads and CUDA graphs cannot travel and are rebuilt
        by `__setstate__`, so the copy continues the same trajectory."""
        t = self.state.torch
        return {
            "config": self.config,
            "num_worlds": self.num_worlds,
            "device": self.device,
            "cpu_threads": len(self._shard_ranges),  # the same split of worlds over threads
            "auto_reset": self.auto_reset,
            "state": self.state_dict(),
            "outputs": {n: getattr(t, n).detach().cpu().clone() for n in self._CARRIED_OUTPUTS},
        }

    def __setstate__(self, saved: dict) -> None:
        state = saved["state"]
        self.__init__(saved["config"], num_worlds=saved["num_worlds"], device=saved["device"], seed=state["seed"],
                      cpu_threads=saved["cpu_threads"], auto_reset=saved["auto_reset"])
        self.load_state_dict(state)
        t = self.state.torch
        for name, value in saved["outputs"].items():
            getattr(t, name).copy_(value.to(self.torch_device))

    def close(self) -> None:
        """Release the CUDA graph and the worker threads; the arrays go with the object."""
        self._graph = None
        pool, self._pool = getattr(self, "_pool", None), None
        if pool is not None:
            pool.shutdown(wait=False)

    def __del__(self) -> None:
        self.close()
