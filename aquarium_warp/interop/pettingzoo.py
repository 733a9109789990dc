"""PettingZoo `ParallelEnv` of one Aquarium world (the implementation behind `aquarium_v1`).

```python
from aquarium_warp import aquarium_v1

env = aquarium_v1.parallel_env(prey_count=16, seed=0)      # marl-aquarium's keyword names work too
obs, infos = env.reset(seed=42)
while env.agents:
    actions = {a: env.action_space(a).sample() for a in env.agents}
    obs, rewards, terminations, truncations, infos = env.step(actions)
env.close()
```

One world of a `BatchedAquarium` (the same Warp kernels as the batched simulator), on the CPU by
default (`device=`), created with `auto_reset=False` so the last observation of an episode belongs to
that episode. Observations are float32 numpy arrays, copied out of the simulation's buffers (the next
step does not change them).

Agents (`possible_agents`): `predator_0 .. predator_{P-1}`, then one `prey_j` per prey slot
(`prey_0 .. prey_{prey_capacity-1}`: the initial prey, then the slots that reproduction can fill).
`agents` holds the live ones in that order: a prey born into a slot joins in the step of its birth,
an agent that is terminated (caught with respawn off, starved) or truncated leaves. PettingZoo forbids
reviving a finished agent, so a newborn that refills the slot of a removed prey (only possible with
`respawn_captured_prey=False` and `prey_reproduction=True`) gets a fresh name
`prey_{prey_capacity}`, `prey_{prey_capacity+1}`, ...; in that configuration `possible_agents` also
lists these names, up to a proven bound on births per episode
(`prey_capacity * max_steps // ceil(0.75 * prey_replication_age)`; above `MAX_EXTRA_NAMES` it grows
on demand instead).

The dicts returned by `step()` hold every agent that was live before the step plus the prey born in it
(newborns of the step that ends the episode are not reported: they never act). An agent removed in a
step gets an all-zero last observation. Infos are empty dicts. Actions must be given for every live
agent (a missing one raises `ValueError`, as do an action outside `Discrete(action_count)`, a bool and
an agent name the env never had); entries for agents that have left are ignored.

Episodes: `max_time_steps` (= `max_steps` = `max_cycles`) steps, after which every live agent is
truncated (marl-aquarium ran `max_time_steps + 2` steps); an episode also ends when no prey or no
predator is left. A step after the end returns empty dicts (with a warning) until `reset()`; a step
before the first `reset()` is refused (`RuntimeError`), as the AEC env refuses it.

Seeding: `reset(seed=s)` runs the episode that `BatchedAquarium(seed=s)` runs in its world 0, and seeds
every agent's action and observation space from `s`; later `reset()` calls without a seed continue a
sequence fixed by `s`. Without any seed (`seed=None` here and in the constructor), the seeds come from
Python's global `random` module, so `random.seed(n)` makes marl-aquarium-style code reproducible.

Rendering: nothing is drawn by `step()`; `render()` draws on demand (marl-aquarium's behaviour, whose
default `render_mode` is "human" too). "human" opens a window, so it needs a display: without one
`render()` raises a `RuntimeError` saying so (use "rgb_array" for frames).

`state()` is the global state, a flat float32 vector (see `AquariumParallelEnv.state`).

Keyword arguments: marl-aquarium 0.1.10's names and defaults (`ORIGINAL_KEYWORDS`), this package's
`AquariumConfig` fields (also flattened per type, e.g. `predator_bounce_strength`), `config=`, and the
environment options of `ENV_OPTIONS`. See `resolve_kwargs`.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from pettingzoo import ParallelEnv

from ..agent_types import TYPES
from ..config import AgentTypeConfig, AquariumConfig
from ..env import BatchedAquarium
from ..seeding import next_reset_seed, reset_seeds, space_seed
from ..world_state import STATE_FIELDS, WorldState

# Above this many extra (refill) names, possible_agents grows on demand instead of listing them all.
MAX_EXTRA_NAMES = 10_000
# Environment options (not part of the simulation's config) and their defaults.
ENV_OPTIONS = {
    "render_mode": "human",  # marl-aquarium's default; nothing is drawn until render() is called
    "caption": "Aquarium",
    "fps": 60,
    "draw_force_vectors": False,
    "draw_action_vectors": False,
    "draw_view_cones": False,
    "draw_hit_boxes": False,
    "draw_death_circles": False,
    "observable_walls": 2,  # accepted for compatibility; unused (as in marl-aquarium)
    "device": "cpu",
    "seed": None,
}

# marl-aquarium keyword -> config targets. A target is a top-level AquariumConfig field name or a
# (type, AgentTypeConfig field) pair. Defaults are the original's, which equal AquariumConfig's.
ORIGINAL_KEYWORDS: dict[str, tuple] = {
    "width": ("width",),
    "height": ("height",),
    "max_time_steps": ("max_steps",),
    "action_count": ("action_count",),
    "predator_count": ("predator_count",),
    "prey_count": ("prey_count",),
    "predator_observe_count": (("prey", "predator_slots"), ("predator", "predator_slots")),
    "prey_observe_count": (("prey", "prey_slots"), ("predator", "prey_slots")),
    "fov_enabled": ("fov_enabled",),
    "keep_prey_count_constant": ("respawn_captured_prey",),
    "prey_radius": (("prey", "radius"),),
    "prey_max_acceleration": (("prey", "max_acceleration"),),
    "prey_max_velocity": (("prey", "max_speed"),),
    "prey_view_distance": (("prey", "view_distance"),),
    "prey_replication_age": ("prey_replication_age",),
    "prey_max_steer_force": (("prey", "max_steering_force"),),
    "prey_fov": (("prey", "fov_angle"),),
    "prey_reward": ("prey_reward",),
    "prey_punishment": ("prey_capture_penalty",),
    "max_prey_count": ("max_prey",),
    "predator_max_acceleration": (("predator", "max_acceleration"),),
    "predator_radius": (("predator", "radius"),),
    "predator_max_velocity": (("predator", "max_speed"),),
    "predator_view_distance": (("predator", "view_distance"),),
    "predator_max_steer_force": (("predator", "max_steering_force"),),
    "predator_max_age": ("predator_starvation_steps",),
    "predator_fov": (("predator", "fov_angle"),),
    "predator_reward": ("predator_reward",),
    "catch_radius": ("catch_share_radius",),
    "procreate": ("prey_reproduction",),
    # PettingZoo's convention (max_cycles_test): the episode length in steps.
    "max_cycles": ("max_steps",),
}

_TYPE_FIELDS = tuple(f.name for f in dataclasses.fields(AgentTypeConfig))
_CONFIG_FIELDS = tuple(f.name for f in dataclasses.fields(AquariumConfig) if f.name not in TYPES)


def _own_keywords() -> dict[str, tuple]:
    own: dict[str, tuple] = {name: (name,) for name in _CONFIG_FIELDS}
    for t in TYPES:
        for f in _TYPE_FIELDS:
            own[f"{t}_{f}"] = ((t, f),)
    return own


OWN_KEYWORDS = _own_keywords()
CONFIG_KEYWORDS = {**OWN_KEYWORDS, **ORIGINAL_KEYWORDS}
VALID_KEYWORDS = tuple(sorted(set(CONFIG_KEYWORDS) | set(ENV_OPTIONS) | {"config", "prey", "predator"}))


def _target_name(target) -> str:
    return target if isinstance(target, str) else f"{target[0]}.{target[1]}"


def _same(a, b) -> bool:
    if a is b:
        return True
    try:
        return bool(a == b)
    except Exception:  # noqa: BLE001 - values that cannot be compared count as different
        return False


def resolve_kwargs(kwargs: dict) -> tuple[AquariumConfig, dict]:
    """Split constructor keywords into an `AquariumConfig` and the environment options.

    Accepted: `config=AquariumConfig(...)`, `prey=` / `predator=AgentTypeConfig(...)`, every
    AquariumConfig field, every AgentTypeConfig field as `prey_<field>` / `predator_<field>`,
    marl-aquarium's names (`ORIGINAL_KEYWORDS`, plus PettingZoo's `max_cycles`), and `ENV_OPTIONS`.
    Several names for one setting must agree, and must agree with `config=` when it is given
    (otherwise `ValueError`). Unknown names raise `TypeError` listing the valid ones. Without
    `config=`, the predators' bounce strength follows marl-aquarium (`predator_max_velocity / 8`)
    unless it is given.
    """
    kwargs = dict(kwargs)
    unknown = sorted(k for k in kwargs if k not in VALID_KEYWORDS)
    if unknown:
        raise TypeError(
            f"aquarium_v1: unknown keyword argument(s) {unknown}; valid keywords are: {', '.join(VALID_KEYWORDS)}"
        )
    config = kwargs.pop("config", None)
    if config is not None and not isinstance(config, AquariumConfig):
        raise ValueError(f"config must be an AquariumConfig, got {type(config).__name__}")
    options = dict(ENV_OPTIONS)
    for name in ENV_OPTIONS:
        if name in kwargs:
            options[name] = kwargs.pop(name)

    assigned: dict = {}  # target -> (value, keyword)

    def assign(target, value, source: str) -> None:
        if target in assigned:
            old, old_source = assigned[target]
            if not _same(old, value):
                raise ValueError(
                    f"contradicting settings for {_target_name(target)}: {old_source}={old!r} but {source}={value!r}"
                )
            return
        assigned[target] = (value, source)

    for t in TYPES:
        if t in kwargs:
            value = kwargs.pop(t)
            if not isinstance(value, AgentTypeConfig):
                raise ValueError(f"{t} must be an AgentTypeConfig, got {type(value).__name__}")
            for f in _TYPE_FIELDS:
                assign((t, f), getattr(value, f), t)
    for name, value in kwargs.items():
        for target in CONFIG_KEYWORDS[name]:
            assign(target, value, name)

    base = config if config is not None else AquariumConfig()
    if config is not None:
        for target, (value, source) in assigned.items():
            current = getattr(base, target) if isinstance(target, str) else getattr(getattr(base, target[0]), target[1])
            if not _same(current, value):
                raise ValueError(f"{source}={value!r} contradicts config.{_target_name(target)}={current!r}")
        return config, options

    if ("predator", "max_speed") in assigned and ("predator", "bounce_strength") not in assigned:
        speed = assigned[("predator", "max_speed")][0]
        if isinstance(speed, (int, float)) and not isinstance(speed, bool):
            assigned[("predator", "bounce_strength")] = (speed / 8.0, "predator_max_velocity / 8")
    top = {t: v for t, (v, _) in assigned.items() if isinstance(t, str)}
    per_type = {
        typ: {t[1]: v for t, (v, _) in assigned.items() if not isinstance(t, str) and t[0] == typ} for typ in TYPES
    }
    for typ in TYPES:
        if per_type[typ]:
            try:
                top[typ] = dataclasses.replace(getattr(base, typ), **per_type[typ])
            except TypeError as error:  # pragma: no cover - fields are checked above
                raise ValueError(str(error)) from error
    return AquariumConfig(**top), options


def _extra_name_count(cfg: AquariumConfig) -> int:
    """Upper bound on prey born into an already used slot in one episode (0 when impossible).

    A slot is freed only by a permanent capture, refilled only by reproduction. Each prey gives at
    most one birth per `ceil(0.75 R)` steps of its life and at most `prey_capacity` prey live in any
    step, so an episode has at most `prey_capacity * max_steps // ceil(0.75 R)` births."""
    if cfg.respawn_captured_prey or not cfg.prey_reproduction:
        return 0
    min_age = max(1, math.ceil(0.75 * cfg.prey_replication_age))
    return cfg.prey_capacity * cfg.max_steps // min_age


class AquariumParallelEnv(ParallelEnv):
    """The Aquarium as a PettingZoo `ParallelEnv` (`aquarium_v1.parallel_env`, `aquarium_v1.raw_env`).

    Keyword arguments: see `resolve_kwargs` and the module docstring. Attributes: `config` (the
    `AquariumConfig`), `aquarium` (the one-world `BatchedAquarium`), `possible_agents`, `agents`,
    `state_space`, `render_mode`, `max_cycles` (= `config.max_steps`, informational).
    """

    metadata: dict[str, Any] = {
        "name": "aquarium_v1",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 60,
        "is_parallelizable": True,
    }

    def __init__(self, **kwargs):
        config, options = resolve_kwargs(kwargs)
        render_mode = options["render_mode"]
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode={render_mode!r} must be None or one of {self.metadata['render_modes']}")
        fps = options["fps"]
        if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not fps > 0 or not math.isfinite(fps):
            raise ValueError(f"fps={fps!r} must be a finite number > 0")
        if options["observable_walls"] != ENV_OPTIONS["observable_walls"]:
            warnings.warn(
                "observable_walls is accepted for compatibility with marl-aquarium but unused "
                "(walls are not observed; the world is a torus)",
                stacklevel=3,
            )
        if options["draw_death_circles"]:
            warnings.warn("draw_death_circles is not supported by aquarium-warp's renderer; ignored", stacklevel=3)
        self.metadata = {**type(self).metadata, "render_fps": fps}
        self.render_mode = render_mode
        self.config = cfg = config
        self.max_cycles = cfg.max_steps
        self._options = options
        self._window = None

        # Names and spaces.
        P, Pc = cfg.predator_count, cfg.prey_capacity
        self._P, self._Pc = P, Pc
        self._predator_names = [f"predator_{i}" for i in range(P)]
        self._prey_slot_names = [f"prey_{j}" for j in range(Pc)]
        extra = _extra_name_count(cfg)
        self._extra_names_listed = min(extra, MAX_EXTRA_NAMES)
        self.possible_agents = (
            self._predator_names + self._prey_slot_names + [f"prey_{Pc + k}" for k in range(self._extra_names_listed)]
        )
        self._possible_set = set(self.possible_agents)
        low = -1.0 if cfg.observation_range == "-1..1" else 0.0
        self._obs_shape = {t: (cfg.observation_size(t),) for t in TYPES}
        self._obs_low = low
        self._observation_spaces: dict = {}
        self._action_spaces: dict = {}
        C = cfg.capacity
        state_low = np.tile(np.array([0, 0, 0, -1, -1, -1, -1], np.float32), C)
        state_high = np.ones(len(STATE_FIELDS) * C, np.float32)
        self.state_space = spaces.Box(
            np.append(state_low, np.float32(0)), np.append(state_high, np.float32(1)), dtype=np.float32
        )

        # Seeding: reset(seed=s) runs the simulation with seed s; later resets without a seed take
        # seeds from a generator seeded with s. Without any seed, Python's global `random` seeds it
        # (so `random.seed(s)` makes marl-aquarium-style code reproducible).
        seed = options["seed"]
        self._seed_rng = None
        self._space_seed = None  # the last explicit seed; spaces are seeded from it
        sim_seed = self._next_sim_seed(seed)
        self.aquarium = BatchedAquarium(cfg, num_worlds=1, device=options["device"], seed=sim_seed, auto_reset=False)
        self._bind_buffers()
        self._closed = False
        self._has_reset = False  # PettingZoo's order: reset() before the first step()
        self._start_episode()

    # ------------------------------------------------------------------ set-up helpers
    def _bind_buffers(self) -> None:
        aq = self.aquarium
        t = aq.state.torch
        self._on_cpu = aq.torch_device.type == "cpu"
        # Action buffers on the host (numpy views of CPU tensors); BatchedAquarium.step copies them in.
        self._act_tensors = {
            "prey": torch.zeros((1, self._Pc), dtype=torch.int32),
            "predator": torch.zeros((1, self._P), dtype=torch.int32),
        }
        self._act_prey = self._act_tensors["prey"].numpy()[0]
        self._act_pred = self._act_tensors["predator"].numpy()[0]
        self._src = (
            t.obs_prey[0],
            t.obs_predator[0],
            t.reward[0],
            t.terminated[0],
            t.truncated[0],
            t.alive[0],
            t.episode_ended,
        )
        if self._on_cpu:
            self._views = tuple(x.numpy() for x in self._src)  # zero copy: always the current values
        self._world_state = WorldState(aq)  # made once: it reads the state (and max speeds) at each call

    # Attributes rebuilt after unpickling: views of the simulation's buffers, and the render window.
    _UNPICKLED = ("_act_tensors", "_act_prey", "_act_pred", "_src", "_views", "_on_cpu", "_window", "_world_state")

    def __getstate__(self) -> dict:
        """Pickle and `copy.deepcopy` carry the options, names, seeding generators, spaces and the
        simulation (`BatchedAquarium` pickles its own state); buffer views and any pygame window are
        rebuilt or left closed on the other side."""
        state = {k: v for k, v in self.__dict__.items() if k not in self._UNPICKLED}
        state["_act_values"] = {t: a.clone() for t, a in self._act_tensors.items()}
        return state

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        actions = state.pop("_act_values")
        self.__dict__.update(state)
        self._window = None
        self._bind_buffers()
        for t, a in actions.items():
            self._act_tensors[t].copy_(a)

    def _host(self):
        """(obs_prey [Pc, L], obs_predator [P, L], reward [C], terminated [C], truncated [C], alive [C],
        episode_ended [1]) as numpy: views of the buffers on the CPU, copies on a GPU."""
        if self._on_cpu:
            return self._views
        return tuple(x.cpu().numpy() for x in self._src)

    def _next_sim_seed(self, seed) -> int:
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
                raise ValueError(f"seed={seed!r} must be None or a non-negative integer")
            self._seed_rng = reset_seeds(int(seed))
            self._space_seed = int(seed)
            for kind, table in enumerate((self._action_spaces, self._observation_spaces)):
                for agent, space in table.items():
                    self._seed_space(space, agent, kind)
            return int(seed)
        if self._seed_rng is None:
            self._seed_rng = reset_seeds(None)
        return next_reset_seed(self._seed_rng)

    def _start_episode(self) -> None:
        """Names and live-agent tables of a freshly reset world."""
        cfg = self.config
        self._prey_name = list(self._prey_slot_names)  # current name of each prey slot's occupant
        self._slot_used = np.zeros(self._Pc, dtype=bool)
        self._slot_used[: cfg.prey_count] = True
        self._next_extra = self._Pc
        alive = self._host()[5]
        self._alive_prev = alive.copy()
        self._alive_prev_bytes = alive.tobytes()
        self._set_live(alive)
        self._stepped_after_end = False

    def _set_live(self, alive: np.ndarray) -> None:
        Pc = self._Pc
        pred_rows = np.flatnonzero(alive[Pc:])
        prey_rows = np.flatnonzero(alive[:Pc])
        self._pred_rows, self._prey_rows = pred_rows, prey_rows
        self._full_slots = np.concatenate([pred_rows + Pc, prey_rows])
        self._pred_live_names = [self._predator_names[i] for i in pred_rows.tolist()]
        self._prey_live_names = [self._prey_name[j] for j in prey_rows.tolist()]
        self._names = self._pred_live_names + self._prey_live_names
        self._n_pred_live = len(pred_rows)
        self.agents = list(self._names)

    def _fresh_name(self) -> str:
        name = f"prey_{self._next_extra}"
        self._next_extra += 1
        if name not in self._possible_set:  # only beyond MAX_EXTRA_NAMES
            self.possible_agents.append(name)
            self._possible_set.add(name)
        return name

    # ------------------------------------------------------------------ spaces
    def _seed_space(self, space, agent: str, kind: int) -> None:
        """Seed an agent's space from the last explicit seed (reset(seed=...) or seed=), so that
        sampling after a seeded reset is reproducible, newborns' spaces included."""
        if self._space_seed is not None:
            space.seed(space_seed(self._space_seed, agent, kind))

    def _agent_type(self, agent) -> str:
        if agent not in self._possible_set:
            raise KeyError(f"unknown agent {agent!r}; agents are named predator_<i> and prey_<j> (see possible_agents)")
        return "predator" if agent.startswith("predator_") else "prey"

    def observation_space(self, agent):
        """`Box(0, 1, (5 + 6 * (predator_slots + prey_slots),), float32)` (2 more with `observe_flow`;
        `Box(-1, 1, ...)` with `observation_range="-1..1"`); the same object for each call with the same agent."""
        space = self._observation_spaces.get(agent)
        if space is None:
            t = self._agent_type(agent)
            space = spaces.Box(self._obs_low, 1.0, self._obs_shape[t], np.float32)
            self._seed_space(space, agent, 1)
            self._observation_spaces[agent] = space
        return space

    def action_space(self, agent):
        """`Discrete(action_count)`; the same object for each call with the same agent."""
        space = self._action_spaces.get(agent)
        if space is None:
            self._agent_type(agent)
            space = spaces.Discrete(self.config.action_count)
            self._seed_space(space, agent, 0)
            self._action_spaces[agent] = space
        return space

    # ------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start a new episode (`seed`: a non-negative integer; the same seed gives the same
        episode). `options` is accepted and unused. Returns `(observations, infos)`."""
        self.aquarium.reset(seed=self._next_sim_seed(seed))  # reseeding writes the seed's key: no rebuild
        self._has_reset = True
        self._start_episode()
        obs_prey, obs_pred = self._host()[:2]
        obs = dict(zip(self._pred_live_names, obs_pred[self._pred_rows]))
        obs.update(zip(self._prey_live_names, obs_prey[self._prey_rows]))
        return obs, {a: {} for a in self._names}

    def _actions_array(self, actions) -> np.ndarray:
        names = self._names
        try:
            values = [actions[a] for a in names]
        except KeyError:
            missing = [a for a in names if a not in actions]
            raise ValueError(
                f"actions are missing for live agents {missing}; every agent in env.agents needs an action"
            ) from None
        except TypeError:
            raise ValueError(f"actions must be a dict keyed by agent name, got {type(actions).__name__}") from None
        if len(actions) != len(names):  # names of agents that left are ignored; names never given are refused
            unknown = sorted(str(a) for a in actions if a not in self._possible_set)
            if unknown:
                raise ValueError(
                    f"actions for unknown agent(s) {unknown}: agents are named predator_<i> and "
                    "prey_<j> (see possible_agents; env.agents are the live ones)"
                )
        if any(isinstance(v, (bool, np.bool_)) for v in values):  # numpy would take True as action 1
            return self._checked_actions(values)
        try:
            arr = np.asarray(values)
        except (ValueError, TypeError):  # e.g. a mix of scalars and 1-element arrays
            return self._checked_actions(values)
        if arr.dtype.kind not in "iu" or arr.shape != (len(names),):
            return self._checked_actions(values)
        if arr.min() < 0 or arr.max() >= self.config.action_count:
            return self._checked_actions(values)
        return arr

    def _checked_actions(self, values) -> np.ndarray:
        """Slow path: check each action on its own (naming the offending agent) and convert."""
        count = self.config.action_count
        out = np.empty(len(values), np.int64)
        for i, (name, value) in enumerate(zip(self._names, values)):
            a = np.asarray(value)
            if a.size != 1 or a.dtype.kind not in "iu" or not 0 <= int(a.reshape(())) < count:
                raise ValueError(
                    f"action {value!r} of agent {name!r} is not in Discrete({count}): "
                    f"actions must be integers in [0, {count - 1}]"
                )
            out[i] = int(a.reshape(()))
        return out

    def step(self, actions):
        """Advance the world by one step with one action per live agent.

        Returns `(observations, rewards, terminations, truncations, infos)`, each keyed by the agents
        that were live before the step plus the prey born in it. Terminated or truncated agents
        leave `agents`."""
        if not self._has_reset:
            raise RuntimeError("step() before reset(): call reset() first, as for every PettingZoo env")
        if not self._names:
            if not self._stepped_after_end:
                gymnasium.logger.warn("step() called with no live agents (the episode is over); call reset()")
                self._stepped_after_end = True
            return {}, {}, {}, {}, {}
        arr = self._actions_array(actions)
        k = self._n_pred_live
        self._act_pred[self._pred_rows] = arr[:k]
        self._act_prey[self._prey_rows] = arr[k:]
        self.aquarium.step(self._act_tensors, validate=False)

        obs_prey, obs_pred, reward, terminated, truncated, alive, ended = self._host()
        ended = bool(ended[0])
        if ended or alive.tobytes() != self._alive_prev_bytes:
            return self._step_with_changes(obs_prey, obs_pred, reward, terminated, truncated, alive, ended)
        # Fast path: the same agents before and after the step.
        names, slots = self._names, self._full_slots
        obs = dict(zip(self._pred_live_names, obs_pred[self._pred_rows]))
        obs.update(zip(self._prey_live_names, obs_prey[self._prey_rows]))
        return (
            obs,
            dict(zip(names, reward[slots].tolist())),
            dict(zip(names, terminated[slots].tolist())),
            dict(zip(names, truncated[slots].tolist())),
            {a: {} for a in names},
        )

    def _step_with_changes(self, obs_prey, obs_pred, reward, terminated, truncated, alive, ended):
        alive = alive.copy()
        pred_rows, prey_rows = self._pred_rows, self._prey_rows
        pred_names, prey_names = self._pred_live_names, list(self._prey_live_names)
        if not ended:
            born = np.flatnonzero(alive[: self._Pc] & ~self._alive_prev[: self._Pc])
            if len(born):
                for j in born.tolist():
                    name = self._fresh_name() if self._slot_used[j] else self._prey_slot_names[j]
                    self._slot_used[j] = True
                    self._prey_name[j] = name
                    prey_names.append(name)
                prey_rows = np.concatenate([prey_rows, born])
        names = pred_names + prey_names
        slots = np.concatenate([pred_rows + self._Pc, prey_rows])
        obs = dict(zip(pred_names, obs_pred[pred_rows]))
        obs.update(zip(prey_names, obs_prey[prey_rows]))
        result: tuple = (
            obs,
            dict(zip(names, reward[slots].tolist())),
            dict(zip(names, terminated[slots].tolist())),
            dict(zip(names, truncated[slots].tolist())),
            {a: {} for a in names},
        )
        self._alive_prev = alive
        self._alive_prev_bytes = alive.tobytes()
        self._set_live(alive if not ended else np.zeros_like(alive))
        return result

    # ------------------------------------------------------------------ state
    def state(self) -> np.ndarray:
        """Global state: a flat float32 vector of `7 * capacity + 1` values in `state_space` (the
        layout of `WorldState`, which computes it for every world of a `BatchedAquarium`)."""
        return self._world_state()[0].cpu().numpy()

    # ------------------------------------------------------------------ rendering
    def render(self):
        """`render_mode="rgb_array"`: the frame, numpy uint8 `[height_px, width_px, 3]` (RGB, image
        rows first, unlike marl-aquarium's transposed frames). `"human"`: shows the frame in a pygame
        window rate-limited to `metadata["render_fps"]` and returns None. Nothing is drawn by `step()`."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        from ..render import render_world  # lazy: only rendering needs it

        o = self._options
        frame = render_world(
            self.aquarium,
            0,
            view_cones=bool(o["draw_view_cones"]),
            hit_boxes=bool(o["draw_hit_boxes"]),
            velocities=bool(o["draw_force_vectors"] or o["draw_action_vectors"]),
        )
        if self.render_mode == "rgb_array":
            return frame
        self._show(frame)
        return None

    def _show(self, frame: np.ndarray) -> None:
        from ..render import Window

        if self._window is None:
            try:
                self._window = Window(
                    frame.shape[1], frame.shape[0], str(self._options["caption"]), fps=self.metadata["render_fps"]
                )
            except ImportError as error:
                raise gymnasium.error.DependencyNotInstalled(
                    "render_mode='human' needs pygame: pip install 'aquarium-warp[video]'"
                ) from error
        if not self._window.show(frame):  # the user closed the window
            self._window = None

    def _close_window(self) -> None:
        if self._window is not None:
            self._window.close()
            self._window = None

    def close(self) -> None:
        """Close the window (if any) and release the simulation's threads and graphs. Never exits
        the process (marl-aquarium's `close()` called `sys.exit()`)."""
        self._close_window()
        if not self._closed:
            self.aquarium.close()
            self._closed = True


raw_env = AquariumParallelEnv
