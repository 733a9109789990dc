"""Native vector envs over `BatchedAquarium`: a Gymnasium `VectorEnv` (here) and a Stable-Baselines3
`VecEnv` (`sb3.py`), with no SuperSuit or PettingZoo layer in between.

```python
from aquarium_warp import AquariumConfig
from aquarium_warp.interop.gymnasium import AquariumVectorEnv

envs = AquariumVectorEnv(AquariumConfig(prey_count=16), num_worlds=64)   # every agent of 64 worlds
obs, infos = envs.reset(seed=0)                                          # [64 * 20, L] float32
obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())

prey = AquariumVectorEnv(num_worlds=64, team="prey", opponent="naivchase")   # prey learn, heuristic predators
```

Rows. `team="all"` (default): every agent slot of every world is one row, world-major, and within a
world in `aquarium_v1`'s `possible_agents` order: the predators, then the prey slots (including those
that reproduction can fill), so `num_envs = W * (predator_capacity + prey_capacity)` and row `w * S + k`
is the agent that SuperSuit's route gives row `w * S + k` (one parameter-shared policy; both types
must then have the same observation size). `team="prey"` or `"predator"`: only that team's slots
(`W * slots` rows, `w * slots + s` is slot `s` of world `w`, as `training/vec_env.py` lays out rsl-rl's
rows); the other team acts inside `step()` through `opponent`: a policy spec (`drivers.make_driver`:
a heuristic name, a policy file or a shipped policy's name; files need the training extra) or a
callable returning its int actions `[W, slots]` on the env's device, decided from the state before
the step (e.g. `drivers.make_driver("runs/x/exported/policy.pt", aquarium, "predator")`, with
`aquarium=` the `BatchedAquarium` given to this env).

A row's episode is the life of the agent in its slot (the convention of `training/vec_env.py`, which
rsl-rl training uses), and each step returns:
- `terminations`: the agent died in this step: a caught prey (whether it respawns, when a fresh agent
  in the same slot starts the row's next episode, or is removed), a starved predator; and the step at
  which an empty slot is filled again (a birth, or the world's reset), ending the row's zero-reward
  stretch while it was empty;
- `truncations`: the agent was alive (and not caught) when its world's episode ended (`max_steps`, or
  the other type died out);
- rewards: the env's; 0 for rows whose slot was empty at the start of the step.
Dead slots. A slot without a live agent (respawn off, starvation, a reproduction slot not yet filled)
stays a row: its observation is all zeros, its reward 0, and it is neither terminated nor truncated
until the slot is filled; its action is ignored. `infos["active"]` (bool `[N]`) marks the rows that
hold a live agent after the step, for losses that mask the empty ones.

Autoreset: `metadata["autoreset_mode"]` is `SAME_STEP`: the simulation starts an ended world's next
episode (and respawns caught prey) inside its own step, so the observation returned with a termination
or truncation is already the next episode's first. The ended episode's last observation is never
computed, so `infos` has no `"final_obs"` (nor SB3's `"terminal_observation"`): an algorithm that
bootstraps truncations from it must use another estimate (rsl-rl's, used in `training/`, takes the
value of the observation the row acted on) or treat truncations as terminations (SB3's PPO does, when
`"terminal_observation"` is missing).

Seeding: `reset(seed=s)` runs what `BatchedAquarium(seed=s)` runs (world `w` of the same seed: the same
episode), and seeds `action_space` / `single_action_space` from `s`; later `reset()` calls without a
seed continue a sequence of seeds fixed by `s` (or by the constructor's `seed=`; without either, by
Python's `random`), as `aquarium_v1.parallel_env` does. The worlds draw from one seed, so `seed` is an
int, not a list per row.

Buffers and devices. Observations are written into one of two buffers `[N, L]` on the simulation's
device, alternating between steps (an algorithm may hold the previous step's observations while the
next step runs, as SB3's PPO does): a returned observation array stays valid until the step after the
next. `array_type="torch"` returns these torch tensors themselves (no host copy: zero copy on a GPU);
`"numpy"` (default) returns numpy arrays: on the CPU views of the same memory (zero copy), on a GPU one
copy to the host per step. Rewards and flags are new arrays each step.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from ..config import AquariumConfig
from ..drivers import make_driver
from ..env import TYPES, BatchedAquarium
from ..seeding import next_reset_seed, reset_seeds

TEAMS = ("all", "prey", "predator")
ARRAY_TYPES = ("numpy", "torch")
OTHER = {"prey": "predator", "predator": "prey"}


def _check_seed(seed, name: str = "seed") -> int | None:
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(
            f"{name}={seed!r} must be None or an integer in [0, 2**63 - 1] (the worlds draw from "
            "one seed: no list per row)"
        )
    return int(seed)


class AquariumRows:
    """The rows of a `BatchedAquarium` as one batch of single-agent envs (the engine behind
    `AquariumVectorEnv` and `sb3.AquariumSB3VecEnv`; see this module's doc for the rows'
    semantics). Tensors only, on the simulation's device.

    Args: `config`, `num_worlds`, `device` ("cpu" by default), `seed` (None: drawn from Python's
    `random`), `cpu_threads`, or `aquarium=` an existing `BatchedAquarium` (with `auto_reset=True`;
    then those four are not allowed); `team` ("all", "prey" or "predator"); `opponent` (team mode only:
    a heuristic name or a callable returning the other team's actions `[W, slots]`);
    `validate_actions` (False skips the range check of the actions and its host sync on a GPU)."""

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device: Any = "cpu",
        seed: int | None = None,
        cpu_threads: int | None = None,
        team: str = "all",
        opponent: Any = None,
        aquarium: BatchedAquarium | None = None,
        validate_actions: bool = True,
    ):
        if team not in TEAMS:
            raise ValueError(f"team={team!r} must be one of {TEAMS}")
        if not isinstance(validate_actions, bool):
            raise ValueError(f"validate_actions={validate_actions!r} must be True or False")
        seed = _check_seed(seed)
        self._seed_rng = reset_seeds(seed)
        if aquarium is None:
            aquarium = BatchedAquarium(
                config,
                num_worlds=num_worlds,
                device=device,
                seed=seed if seed is not None else next_reset_seed(self._seed_rng),
                cpu_threads=cpu_threads,
                auto_reset=True,
            )
        elif not isinstance(aquarium, BatchedAquarium) or not aquarium.auto_reset:
            raise ValueError("aquarium must be a BatchedAquarium with auto_reset=True")
        elif config is not None or num_worlds != 1 or seed is not None or cpu_threads is not None:
            raise ValueError(
                "aquarium= takes the config, num_worlds, seed and cpu_threads of that BatchedAquarium; "
                "do not pass them too"
            )
        self.aquarium = env = aquarium
        self.team = team
        self.validate_actions = validate_actions
        self.config = cfg = env.config
        W = self.num_worlds = env.num_worlds
        if team == "all":
            self.types: tuple[str, ...] = ("predator", "prey")  # aquarium_v1's possible_agents order
            sizes = {env.observation_size[t] for t in TYPES}
            if len(sizes) != 1:
                raise ValueError(
                    f"team='all' needs one observation size for both types (one shared policy), got "
                    f"{env.observation_size}; use team='prey' or 'predator'"
                )
            if opponent is not None:
                raise ValueError("opponent is for team='prey' or 'predator' (with team='all' every agent is a row)")
            self.opponent = None
        else:
            self.types = (team,)
            if isinstance(opponent, str):
                opponent = make_driver(opponent, env, OTHER[team])
            if opponent is None or not callable(opponent):
                raise ValueError(
                    f"opponent must be a policy spec or a callable returning the {OTHER[team]} "
                    f"actions [W, slots] (team={team!r})"
                )
            self.opponent = opponent
        slots = {"prey": env.prey_capacity, "predator": env.predator_capacity}
        self.slices: dict[str, slice] = {}
        start = 0
        for t in self.types:
            self.slices[t] = slice(start, start + slots[t])
            start += slots[t]
        self.slots = S = start
        self.num_rows = W * S
        self.observation_size = L = env.observation_size[self.types[0]]
        self.action_count = cfg.action_count
        self.device = dev = env.torch_device
        low = -1.0 if cfg.observation_range == "-1..1" else 0.0
        self.single_observation_space = spaces.Box(low, 1.0, (L,), np.float32)
        self.single_action_space = spaces.Discrete(cfg.action_count)

        self._obs = [torch.zeros(W, S, L, dtype=torch.float32, device=dev) for _ in range(2)]
        self._current = 0
        self._actions = torch.zeros(W, S, dtype=torch.int32, device=dev)
        self._rewards = torch.zeros(W, S, dtype=torch.float32, device=dev)
        self._terminated = torch.zeros(W, S, dtype=torch.bool, device=dev)
        self._truncated = torch.zeros(W, S, dtype=torch.bool, device=dev)
        self._active = torch.zeros(W, S, dtype=torch.bool, device=dev)
        out, captured = env.outputs, env.state.torch.captured[:, : env.prey_capacity]
        self._in = {
            typ: (
                out.rewards[typ],
                out.terminated[typ],
                out.truncated[typ],
                env.alive[typ],
                captured if typ == "prey" else None,
            )
            for typ in self.types
        }
        self._step_actions = {typ: self._actions[:, self.slices[typ]] for typ in self.types}
        self._load()

    # ------------------------------------------------------------------ internals
    def _alive_rows(self, out: torch.Tensor) -> torch.Tensor:
        for typ, sl in self.slices.items():
            out[:, sl] = self._in[typ][3]
        return out

    def _load(self) -> None:
        """Rows' activity and observations from the env's current state (after a reset)."""
        self._alive_rows(self._active)
        self._copy_observations()

    def _copy_observations(self) -> None:
        obs = self._obs[self._current]
        for typ, sl in self.slices.items():
            obs[:, sl] = self.aquarium.observations[typ]

    @property
    def observations(self) -> torch.Tensor:
        """`[N, L]` float32: the current observation buffer (overwritten by the step after the next)."""
        return self._obs[self._current].view(self.num_rows, -1)

    @property
    def active(self) -> torch.Tensor:
        """`[N]` bool: rows holding a live agent (a view, updated by every step and reset)."""
        return self._active.view(-1)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        """Every world's new episode: with `seed`, the one of `BatchedAquarium(seed=seed)`; without, with the
        next seed of the sequence (see the module doc). Returns `observations`."""
        seed = _check_seed(seed)
        if seed is not None:
            self._seed_rng = reset_seeds(seed)
        else:
            seed = next_reset_seed(self._seed_rng)
        self.aquarium.reset(seed=seed)
        self._load()
        return self.observations

    def _check_actions(self, actions) -> torch.Tensor:
        if isinstance(actions, torch.Tensor):
            if actions.device != self.device:  # as BatchedAquarium.step: no silent copy between devices
                raise ValueError(f"actions are on {actions.device}, but the env runs on {self.aquarium.device}")
            a = actions
        else:
            try:
                arr = np.asarray(actions)
            except (ValueError, TypeError):
                raise ValueError(f"actions must be integers in [0, {self.action_count - 1}], one per row") from None
            if arr.dtype.kind not in "biuf":
                raise ValueError(f"actions must be integers in [0, {self.action_count - 1}], one per row")
            a = torch.from_numpy(np.ascontiguousarray(arr))
        if a.numel() != self.num_rows or (a.dim() > 1 and a.shape[0] != self.num_rows):
            raise ValueError(f"actions must have shape ({self.num_rows},) (one per row), got {tuple(a.shape)}")
        if self.validate_actions:
            if a.dtype.is_floating_point:
                if not bool(torch.equal(a, a.round())):
                    raise ValueError(f"actions must be integers in [0, {self.action_count - 1}], got fractions")
            elif a.dtype == torch.bool or a.dtype.is_complex:
                raise ValueError(f"actions must be integers in [0, {self.action_count - 1}], got {a.dtype}")
            if a.numel() and (int(a.min()) < 0 or int(a.max()) >= self.action_count):
                raise ValueError(
                    f"actions must be integers in [0, {self.action_count - 1}], got values in "
                    f"[{int(a.min())}, {int(a.max())}]"
                )
        return a.reshape(self.num_worlds, self.slots)

    def step(self, actions) -> None:
        """Step every world with one action per row (`[N]` ints: numpy, torch or a sequence); the
        results are in `observations`, `rewards`, `terminated`, `truncated`, `active`."""
        self._actions.copy_(self._check_actions(actions))
        step_actions = dict(self._step_actions)
        if self.opponent is not None:
            step_actions[OTHER[self.team]] = self.opponent()
        self.aquarium.step(step_actions, validate=False)
        self._outcomes()
        self._current ^= 1
        self._copy_observations()

    def _outcomes(self) -> None:
        """Rows' rewards and flags of the last simulation step (`training.vec_env.AquariumVecEnv.row_outcomes`'
        convention, split into terminations and truncations)."""
        for typ, sl in self.slices.items():
            reward, terminated, truncated, alive, captured = self._in[typ]
            active = self._active[:, sl]
            died = terminated if captured is None else terminated | captured
            # Active rows end with their life; inactive rows end (a termination) when their slot is filled.
            time_out = truncated & ~died & active
            self._truncated[:, sl] = time_out
            self._terminated[:, sl] = torch.where(active, died, alive)
            torch.mul(reward, active, out=self._rewards[:, sl])
            active.copy_(alive)

    @property
    def rewards(self) -> torch.Tensor:
        return self._rewards.view(-1)

    @property
    def terminated(self) -> torch.Tensor:
        return self._terminated.view(-1)

    @property
    def truncated(self) -> torch.Tensor:
        return self._truncated.view(-1)

    def close(self) -> None:
        self.aquarium.close()


class AquariumVectorEnv(VectorEnv):
    """Gymnasium `VectorEnv` over a `BatchedAquarium`: one row per agent slot of every world, or per slot of
    one team (see the module doc). Keyword arguments: those of `AquariumRows`, plus `array_type`
    ("numpy" or "torch": the type of the returned observations, rewards and flags)."""

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device: Any = "cpu",
        seed: int | None = None,
        team: str = "all",
        opponent: Any = None,
        array_type: str = "numpy",
        **kwargs: Any,
    ):
        if array_type not in ARRAY_TYPES:
            raise ValueError(f"array_type={array_type!r} must be one of {ARRAY_TYPES}")
        self.rows = rows = AquariumRows(
            config, num_worlds=num_worlds, device=device, seed=seed, team=team, opponent=opponent, **kwargs
        )
        self.array_type = array_type
        self.num_envs = rows.num_rows
        self.single_observation_space = rows.single_observation_space
        self.single_action_space = rows.single_action_space
        self.observation_space = spaces.Box(
            rows.single_observation_space.low[0], 1.0, (self.num_envs, rows.observation_size), np.float32
        )
        self.action_space = spaces.MultiDiscrete(np.full(self.num_envs, rows.action_count, dtype=np.int64))
        self.render_mode = None
        # numpy views of the observation buffers (zero copy on the CPU)
        self._host = rows.device.type == "cpu"
        self._obs_np = [o.view(self.num_envs, -1).numpy() for o in rows._obs] if self._host else None

    @property
    def aquarium(self) -> BatchedAquarium:
        return self.rows.aquarium

    def _out(self, x: torch.Tensor, copy: bool = True):
        if self.array_type == "torch":
            return x.clone() if copy else x
        return x.numpy().copy() if self._host else x.cpu().numpy()

    def _observations(self):
        rows = self.rows
        if self.array_type == "torch":
            return rows.observations
        if self._obs_np is not None:
            return self._obs_np[rows._current]
        return rows.observations.cpu().numpy()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """`(observations [N, L], infos)`: every world's new episode (see the module doc's seeding).
        `options` is accepted and unused."""
        self.rows.reset(seed)
        if seed is not None:
            self.action_space.seed(seed)
            self.single_action_space.seed(seed)
        return self._observations(), {"active": self._out(self.rows.active)}

    def step(self, actions):
        """`(observations [N, L], rewards [N], terminations [N], truncations [N], infos)` with
        `infos = {"active": [N] bool}`; see the module doc."""
        rows = self.rows
        rows.step(actions)
        return (
            self._observations(),
            self._out(rows.rewards),
            self._out(rows.terminated),
            self._out(rows.truncated),
            {"active": self._out(rows.active)},
        )

    def close_extras(self, **kwargs: Any) -> None:
        self.rows.close()
