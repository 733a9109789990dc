"""Native vector envs over `BatchedAquarium`: a Gymnasium `VectorEnv` (here) and a Stable-Baselines3
`VecEnv` (`sb3.py`), with no SuperSuit or PettingZoo layer in between.

```python
import gymnasium as gym
import aquarium_warp  # registers "aquarium/Aquarium-v1" for gym.make_vec
from aquarium_warp import AquariumConfig
from aquarium_warp.interop.gymnasium import AquariumVectorEnv

envs = AquariumVectorEnv(AquariumConfig(prey_count=16), num_worlds=64)   # every agent of 64 worlds
obs, infos = envs.reset(seed=0)                                          # [64 * 20, L] float32
obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())

prey = AquariumVectorEnv(num_worlds=64, team="prey", opponent="naivchase")   # prey learn, heuristic predators
same = AquariumVectorEnv(num_worlds=64, autoreset_mode="same_step")          # final_obs in infos
envs = gym.make_vec("aquarium/Aquarium-v1", num_envs=4 * 17)                 # 4 default worlds
```

Rows. `team="all"` (default): every agent slot of every world is one row (a Gymnasium sub-env),
world-major, and within a world in `aquarium_v1`'s `possible_agents` order: the predators, then the
prey slots (including those that reproduction can fill), so `num_envs = W * (predator_capacity +
prey_capacity)` and row `w * S + k` is the agent that SuperSuit's route gives row `w * S + k` (one
parameter-shared policy; both types must then have the same observation size). `team="prey"` or
`"predator"`: only that team's slots (`W * slots` rows, `w * slots + s` is slot `s` of world `w`, as
`training/vec_env.py` lays out rsl-rl's rows); the other team acts inside `step()` through `opponent`:
a policy spec (`drivers.make_driver`: a heuristic name, a policy file or a shipped policy's name; files
need the training extra) or a callable returning its int actions `[W, slots]` on the env's device,
decided from the state before the step (e.g. `drivers.make_driver("runs/x/exported/policy.pt",
aquarium, "predator")`, with `aquarium=` the `BatchedAquarium(..., auto_reset=False)` given to this env).

Episodes. A row's episode is the life of one agent in its slot: it ends with a termination when the
agent dies (a caught prey, whether a fresh prey respawns in its slot or it is removed; a starved
predator) and with a truncation when the agent is alive as its world's episode ends (`max_steps`, or
the other type died out). A row's reward is its slot's reward in the steps its agent acted. A slot
without a live agent (respawn off, starvation, a reproduction slot not yet filled) is an empty row:
its observation is all zeros, its reward 0, it is neither terminated nor truncated (no episode: the
empty stretch is not one) and its action is ignored; its next episode starts when the slot is filled
(a birth, or its world's next episode), with that agent's first observation. `infos["active"]` (bool
`[N]`) marks the rows whose next action moves a live agent (mask losses with it: a transition counts
where the row was active before the step). An episode's length, as Gymnasium's and SB3's statistics
count it, includes the empty steps before its agent appeared.

Autoreset (`autoreset_mode=`, declared in `metadata["autoreset_mode"]`). The simulation starts a
fresh agent inside its step: a respawned prey takes its caught predecessor's slot, and a newborn an
empty one. The env runs its `BatchedAquarium` without auto-reset: an ended world keeps its last state
(its agents' last observations) until the env starts its next episode (`kernels/population.py`'s
`restart_worlds`, which draws what the simulation's own auto-reset would: the same episodes follow).
- `AutoresetMode.NEXT_STEP` ("next_step", the default, as Gymnasium's own vector envs): a row that
  ends returns its episode's last observation with the flag, then, at the next step (its reset step:
  reward 0, no flags, its action ignored), the first observation of its next episode. A world that
  ended starts its next episode at that step: it is not moved (its reset step is exact; the
  simulation steps it once more in its ended state and discards that step, then spawns it). A prey
  respawned inside a running world cannot wait: its row's reset step is its first step, moved by the
  action given for that row (chosen without seeing it), and its reward of that step is not counted; a
  respawned prey caught again in that very step is not an episode. Every Gymnasium vector wrapper works
  on this mode (the observation wrappers take no other).
- `AutoresetMode.SAME_STEP` ("same_step"): a row that ends returns the first observation of its next
  episode with the flag (the respawned prey's, or its world's next episode's) and, as Gymnasium's
  same-step vector envs, `infos["final_obs"]` (numpy object array `[N]`: the ended episodes' last
  observations where `infos["_final_obs"]`, else None) and `infos["final_info"]` (the rows' infos of
  that step, masked by `infos["_final_info"]`). Every step counts: this mode is exact for per-slot
  respawns too (SB3's env uses it). Gymnasium's observation wrappers refuse it (their check).
- Last observations: a truncated agent's is its real observation of its world's last state; a dead
  agent observes nothing, so a terminated row's last observation is all zeros, as an empty slot's (its
  value is never bootstrapped from).
- Cost: the spawn of an ended world and one more observation pass over the batch (for the worlds'
  new first observations) in each step after which (next-step) or in which (same-step) some world
  ended (a world that lasts its `max_steps`, 3,000 by default, ends once in that many steps; worlds
  stepped together end together). Same-step also copies every row's observation once more per step
  (the last observations) and builds `final_obs` (one Python object per ended row) in steps where some
  row ended. The rows' outcomes, observations and activity take a few launches
  (`kernels/rows.py`); each step reads two numbers from the device (rows ended, worlds ended).

Infos follow Gymnasium's vector convention: every key `k` comes with a boolean mask `_k` (which rows
have it; all of them for `"active"`).

Seeding: `reset(seed=s)` (a Python or NumPy integer) runs what `BatchedAquarium(seed=s)` runs (world `w`
of the same seed: the same episode), and seeds `action_space` / `single_action_space` from `s`; later
`reset()` calls without a seed continue a sequence of seeds fixed by `s` (or by the constructor's
`seed=`; without either, by Python's `random`), as `aquarium_v1.parallel_env` does. The worlds draw
from one seed, so `seed` is an integer, not a list per row.

Buffers and devices. Observations are written into one of two buffers `[N, L]` on the simulation's
device, alternating between steps (an algorithm may hold the previous step's observations while the
next step runs, as SB3's PPO does): a returned observation array stays valid until the step after the
next. `array_type="torch"` returns these torch tensors themselves (no host copy: zero copy on a GPU);
`"numpy"` (default) returns numpy arrays: on the CPU views of the same memory (zero copy), on a GPU one
copy to the host per step. Rewards, flags and infos are new arrays each step.

Rendering: `render_mode="rgb_array"` makes `render()` return, as Gymnasium's vector envs do, one frame
per row: the frame of the row's world (`render.render_world`), drawn when first read and shared by the
world's rows; `RecordVideo(envs, ..., record_first_only=True)` records world 0.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import warp as wp
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..agent_types import OTHER, TYPES
from ..config import AquariumConfig
from ..drivers import make_driver
from ..env import BatchedAquarium
from ..kernels import population
from ..kernels import rows as row_kernels
from ..seeding import next_reset_seed, reset_seeds

TEAMS = ("all", "prey", "predator")
ARRAY_TYPES = ("numpy", "torch")
AUTORESET_MODES = {"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP}
RENDER_MODES = ("rgb_array",)
RENDER_FPS = 30  # a frame per step


def _check_seed(seed, name: str = "seed") -> int | None:
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(
            f"{name}={seed!r} must be None or an integer in [0, 2**63 - 1] (the worlds draw from "
            "one seed: no list per row)"
        )
    return int(seed)


def autoreset_mode_of(mode) -> AutoresetMode:
    """`AutoresetMode.NEXT_STEP` or `SAME_STEP`, given as the member or its name ("next_step", "same_step")."""
    if isinstance(mode, AutoresetMode) and mode in AUTORESET_MODES.values():
        return mode
    if isinstance(mode, str) and mode.lower() in AUTORESET_MODES:
        return AUTORESET_MODES[mode.lower()]
    raise ValueError(
        f"autoreset_mode={mode!r} must be AutoresetMode.NEXT_STEP or AutoresetMode.SAME_STEP "
        "(or 'next_step', 'same_step')"
    )


class AquariumRows:
    """The rows of a `BatchedAquarium` as one batch of single-agent envs (the engine behind
    `AquariumVectorEnv` and `sb3.AquariumSB3VecEnv`; see this module's doc for the rows'
    semantics). Tensors only, on the simulation's device.

    Args: `config`, `num_worlds`, `device` ("cpu" by default), `seed` (None: drawn from Python's
    `random`), `cpu_threads`, or `aquarium=` an existing `BatchedAquarium` (with `auto_reset=False`: the
    rows start ended worlds' next episodes themselves; then those four are not allowed); `team` ("all",
    "prey" or "predator"); `opponent` (team mode only: a heuristic name or a callable returning the other
    team's actions `[W, slots]`); `autoreset_mode` (`AutoresetMode.NEXT_STEP`, the default, or
    `SAME_STEP`); `validate_actions` (False skips the range check of the actions and its host sync on
    a GPU)."""

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
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
    ):
        if team not in TEAMS:
            raise ValueError(f"team={team!r} must be one of {TEAMS}")
        if not isinstance(validate_actions, bool):
            raise ValueError(f"validate_actions={validate_actions!r} must be True or False")
        self.autoreset_mode = autoreset_mode_of(autoreset_mode)
        seed = _check_seed(seed)
        self._seed_rng = reset_seeds(seed)
        if aquarium is None:
            aquarium = BatchedAquarium(
                config,
                num_worlds=num_worlds,
                device=device,
                seed=seed if seed is not None else next_reset_seed(self._seed_rng),
                cpu_threads=cpu_threads,
                auto_reset=False,
            )
        elif not isinstance(aquarium, BatchedAquarium) or aquarium.auto_reset:
            raise ValueError(
                "aquarium must be a BatchedAquarium with auto_reset=False (the rows start ended worlds' "
                "next episodes themselves, after observing their last state)"
            )
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

        # The rows' buffers: Warp arrays (the row kernels' arguments, sliced per shard) and their torch views.
        def buffer(shape, dtype):
            array = wp.zeros(shape, dtype=dtype, device=env.device)
            return array, wp.to_torch(array)

        obs = [buffer((W, S, L), wp.float32) for _ in range(2)]  # alternating between steps
        final_obs = buffer((W, S, L), wp.float32)
        rewards, terminated, truncated, ended, active, no_row = (
            buffer((W, S), dtype) for dtype in (wp.float32, wp.bool, wp.bool, wp.bool, wp.bool, wp.bool)
        )
        # Worlds that ended in a step (`ended_worlds[i]`, alternating: next-step restarts them at the next
        # step, reading one while the step notes the next in the other), and no world.
        ended_worlds = [buffer(W, wp.bool) for _ in range(2)]
        no_world = buffer(W, wp.bool)
        self._obs = [o[1] for o in obs]
        self._current = 0
        self._final_obs = final_obs[1]
        self._actions = torch.zeros(W, S, dtype=torch.int32, device=dev)
        self._rewards, self._terminated, self._truncated, self._ended, self._active = (
            x[1] for x in (rewards, terminated, truncated, ended, active)
        )
        self._ended_worlds = [x[1] for x in ended_worlds]
        self.ended_rows = 0  # rows whose episode ended in the last step (read from the device)
        self._restart_due = False  # next-step: worlds ended in the last step, to restart at this one
        next_step = int(self.autoreset_mode is AutoresetMode.NEXT_STEP)
        first_slot = {"prey": 0, "predator": env.prey_capacity}  # the state's slot order: prey, then predators
        row_slot: wp.array = wp.array(
            np.concatenate([first_slot[t] + np.arange(slots[t]) for t in self.types]), dtype=wp.int32, device=env.device
        )

        def rows(shard, array):
            return array[0][shard.w0 : shard.w1]

        def outcomes(shard, restarting, noted):
            s = shard.state
            return shard.record(
                row_kernels.vector_row_outcomes,
                (shard.num_worlds, S),
                [
                    row_slot,
                    s.outputs.terminated,
                    s.scratch.captured,
                    s.outputs.truncated,
                    s.outputs.reward,
                    s.outputs.episode_ended,
                    rows(shard, restarting),
                    rows(shard, active),
                ],
                [rows(shard, x) for x in (rewards, terminated, truncated, ended, noted)],
            )

        def observations(shard, zero, out):
            o = shard.state.observations
            return shard.record(
                row_kernels.row_observations,
                (shard.num_worlds, S),
                [env.prey_capacity, row_slot, o.obs_prey, o.obs_predator, rows(shard, zero)],
                [rows(shard, out)],
            )

        def activity(shard, noted):
            return shard.record(
                row_kernels.row_activity,
                (shard.num_worlds, S),
                [next_step, row_slot, shard.state.agents.alive, rows(shard, ended), rows(shard, noted)],
                [rows(shard, active)],
            )

        def restart(shard, worlds):
            return [
                shard.record(
                    population.restart_worlds,
                    shard.num_worlds,
                    [shard.world, rows(shard, worlds)],
                    [shard.state.worlds, shard.state.agents],
                )
            ] + shard.observe_program()

        record = env.record_program
        if next_step:
            # Step i (of buffer i) restarts the worlds noted by the step before (in ended_worlds[1 - i])
            # first, then takes the rows' outcomes and notes the worlds that ended (in ended_worlds[i]).
            self._restart_programs = [record(lambda shard, i=i: restart(shard, ended_worlds[1 - i])) for i in range(2)]
            self._row_programs = [
                record(
                    lambda shard, i=i: [
                        outcomes(shard, ended_worlds[1 - i], ended_worlds[i]),
                        observations(shard, terminated, obs[i]),
                        activity(shard, ended_worlds[i]),
                    ]
                )
                for i in range(2)
            ]
        else:
            # Outcomes and last observations; then, where some world ended, its restart; then the
            # observations and rows' activity of the state after it.
            self._outcome_program = record(
                lambda shard: [
                    outcomes(shard, no_world, ended_worlds[0]),
                    observations(shard, terminated, final_obs),
                ]
            )
            self._restart_programs = [record(lambda shard: restart(shard, ended_worlds[0]))]
            self._row_programs = [
                record(lambda shard, i=i: [observations(shard, no_row, obs[i]), activity(shard, no_world)])
                for i in range(2)
            ]
        self._step_actions = {typ: self._actions[:, self.slices[typ]] for typ in self.types}
        self._start()

    # ------------------------------------------------------------------ internals
    def _start(self) -> None:
        """Rows after a reset: every live agent starts its row's episode."""
        env = self.aquarium
        for typ, sl in self.slices.items():
            self._active[:, sl] = env.alive[typ]
            self._obs[self._current][:, sl] = env.observations[typ]
        for worlds in self._ended_worlds:
            worlds.zero_()
        self._restart_due = False
        self.ended_rows = 0

    @property
    def observations(self) -> torch.Tensor:
        """`[N, L]` float32: the current observation buffer (overwritten by the step after the next)."""
        return self._obs[self._current].view(self.num_rows, -1)

    @property
    def final_observations(self) -> torch.Tensor:
        """`[N, L]` float32, same-step mode: the observations of the state the last step ended in (before
        any world's restart), zeros for terminated rows: in the rows of `ended`, their episodes' last
        observations (overwritten by the next step)."""
        return self._final_obs.view(self.num_rows, -1)

    @property
    def active(self) -> torch.Tensor:
        """`[N]` bool: rows whose next action moves a live agent (a view, updated by every step and reset)."""
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
        self._start()
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
        results are in `observations`, `rewards`, `terminated`, `truncated`, `active` (and, same-step,
        `final_observations`)."""
        self._actions.copy_(self._check_actions(actions))
        step_actions = dict(self._step_actions)
        if self.opponent is not None:
            step_actions[OTHER[self.team]] = self.opponent()
        self.aquarium.step(step_actions, validate=False)
        self._current ^= 1
        i = self._current
        if self.autoreset_mode is AutoresetMode.NEXT_STEP:
            if self._restart_due:  # the worlds that ended in the last step start their next episode
                self._restart_programs[i].run()
            self._row_programs[i].run()
            self._restart_due = bool(self._ended_worlds[i].any())  # the step's reads from the device
            self.ended_rows = int(self._ended.sum())
            return
        self._outcome_program.run()
        self.ended_rows = int(self._ended.sum())
        if bool(self._ended_worlds[0].any()):
            self._restart_programs[0].run()
        self._row_programs[i].run()

    @property
    def rewards(self) -> torch.Tensor:
        return self._rewards.view(-1)

    @property
    def terminated(self) -> torch.Tensor:
        return self._terminated.view(-1)

    @property
    def truncated(self) -> torch.Tensor:
        return self._truncated.view(-1)

    @property
    def ended(self) -> torch.Tensor:
        """`[N]` bool: terminated or truncated in the last step."""
        return self._ended.view(-1)

    def row_world(self, row: int) -> int:
        """The world of row `row`."""
        return row // self.slots

    def close(self) -> None:
        self.aquarium.close()


def check_render_mode(render_mode) -> str | None:
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode={render_mode!r} must be None or one of {RENDER_MODES}")
    return render_mode


class RowFrames(Sequence):
    """One frame per row, as Gymnasium's vector `render()` returns: the frame of the row's world, drawn
    when first read (`render.render_world`) and shared by the world's rows."""

    def __init__(self, rows: AquariumRows):
        self._rows = rows
        self._frames: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return self._rows.num_rows

    def __getitem__(self, row):
        if isinstance(row, slice):
            return [self[i] for i in range(*row.indices(len(self)))]
        if not -len(self) <= row < len(self):
            raise IndexError(f"row {row} out of range [0, {len(self) - 1}]")
        world = self._rows.row_world(row % len(self))
        if world not in self._frames:
            from ..render import render_world  # lazy: only rendering needs it

            self._frames[world] = render_world(self._rows.aquarium, world)
        return self._frames[world]


class AquariumVectorEnv(VectorEnv):
    """Gymnasium `VectorEnv` over a `BatchedAquarium`: one row per agent slot of every world, or per slot of
    one team (see the module doc). Keyword arguments: those of `AquariumRows` (`autoreset_mode` included),
    plus `array_type` ("numpy" or "torch": the type of the returned observations, rewards, flags and
    infos) and `render_mode` (None or "rgb_array")."""

    metadata: dict[str, Any] = {
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": list(RENDER_MODES),
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device: Any = "cpu",
        seed: int | None = None,
        team: str = "all",
        opponent: Any = None,
        array_type: str = "numpy",
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        **kwargs: Any,
    ):
        if array_type not in ARRAY_TYPES:
            raise ValueError(f"array_type={array_type!r} must be one of {ARRAY_TYPES}")
        self.render_mode = check_render_mode(render_mode)
        self.rows = rows = AquariumRows(
            config,
            num_worlds=num_worlds,
            device=device,
            seed=seed,
            team=team,
            opponent=opponent,
            autoreset_mode=autoreset_mode,
            **kwargs,
        )
        self.metadata = {**type(self).metadata, "autoreset_mode": rows.autoreset_mode}
        self.array_type = array_type
        self.num_envs = rows.num_rows
        self.single_observation_space = rows.single_observation_space
        self.single_action_space = rows.single_action_space
        self.observation_space = batch_space(rows.single_observation_space, self.num_envs)
        self.action_space = batch_space(rows.single_action_space, self.num_envs)
        # numpy views of the observation buffers (zero copy on the CPU)
        self._host = rows.device.type == "cpu"
        self._obs_np = [o.view(self.num_envs, -1).numpy() for o in rows._obs] if self._host else None

    @property
    def aquarium(self) -> BatchedAquarium:
        return self.rows.aquarium

    def _out(self, x: torch.Tensor):
        if self.array_type == "torch":
            return x.clone()
        return x.numpy().copy() if self._host else x.cpu().numpy()

    def _observations(self):
        rows = self.rows
        if self.array_type == "torch":
            return rows.observations
        if self._obs_np is not None:
            return self._obs_np[rows._current]
        return rows.observations.cpu().numpy()

    def _everywhere(self):
        """The mask of a key every row has."""
        if self.array_type == "torch":
            return torch.ones(self.num_envs, dtype=torch.bool, device=self.rows.device)
        return np.ones(self.num_envs, dtype=bool)

    def _infos(self) -> dict[str, Any]:
        rows = self.rows
        infos: dict[str, Any] = {"active": self._out(rows.active), "_active": self._everywhere()}
        if rows.autoreset_mode is AutoresetMode.SAME_STEP and rows.ended_rows:
            ended = self._out(rows.ended)
            index = torch.nonzero(rows.ended).view(-1)
            final = self._out(rows.final_observations[index])  # only the ended rows' last observations
            final_obs = np.full(self.num_envs, None, dtype=object)
            for k, i in enumerate(index.tolist()):
                final_obs[i] = final[k]
            # The ended rows' infos of the step, before their next episode: a truncated agent was active.
            infos["final_obs"], infos["_final_obs"] = final_obs, ended
            infos["final_info"] = {"active": self._out(rows.truncated), "_active": ended}
            infos["_final_info"] = ended
        return infos

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """`(observations [N, L], infos)`: every world's new episode (see the module doc's seeding).
        `options` is accepted and unused, but for Gymnasium's `reset_mask`, refused: rows share worlds,
        so none is reset alone."""
        if options and "reset_mask" in options:
            raise ValueError("options['reset_mask'] is not supported: rows share worlds; reset() resets every world")
        seed = _check_seed(seed)
        self.rows.reset(seed)
        if seed is not None:
            self.action_space.seed(seed)
            self.single_action_space.seed(seed)
        return self._observations(), self._infos()

    def step(self, actions):
        """`(observations [N, L], rewards [N], terminations [N], truncations [N], infos)`; see the module
        doc for the rows, the autoreset modes and the infos."""
        rows = self.rows
        rows.step(actions)
        return (
            self._observations(),
            self._out(rows.rewards),
            self._out(rows.terminated),
            self._out(rows.truncated),
            self._infos(),
        )

    def render(self) -> RowFrames | None:  # type: ignore[override]  # a lazy sequence, not a tuple
        """`render_mode="rgb_array"`: one frame per row, the frame of its world (drawn when read)."""
        if self.render_mode is None:
            return None
        return RowFrames(self.rows)

    def close_extras(self, **kwargs: Any) -> None:
        self.rows.close()


def make_vector_env(num_envs: int = 1, config: AquariumConfig | None = None, **kwargs: Any) -> AquariumVectorEnv:
    """`gym.make_vec("aquarium/Aquarium-v1", num_envs=N, **kwargs)`: an `AquariumVectorEnv` of `N` rows,
    `N / S` worlds of `S` rows each (`S` = the agent slots of a world, or of the team). Keywords: those of
    `AquariumVectorEnv` (not `num_worlds`: `num_envs` sets it) and `AquariumConfig` fields, which change
    `config` (default `AquariumConfig()`)."""
    if config is not None and not isinstance(config, AquariumConfig):
        raise ValueError(f"config must be an AquariumConfig, got {type(config).__name__}")
    if "num_worlds" in kwargs:
        raise ValueError("gym.make_vec takes num_envs (the rows), not num_worlds")
    fields = {f.name for f in dataclasses.fields(AquariumConfig)}
    changes = {k: kwargs.pop(k) for k in list(kwargs) if k in fields}
    config = (config or AquariumConfig()).replace(**changes) if changes else config or AquariumConfig()
    team = kwargs.get("team", "all")
    slots = {"all": config.capacity, "prey": config.prey_capacity, "predator": config.predator_capacity}.get(team)
    if slots is None:
        raise ValueError(f"team={team!r} must be one of {TEAMS}")
    if (
        isinstance(num_envs, bool)
        or not isinstance(num_envs, (int, np.integer))
        or num_envs < slots
        or num_envs % slots
    ):
        raise ValueError(
            f"num_envs={num_envs!r} must be a positive multiple of {slots} (the rows of one world: its "
            f"{'agent slots' if team == 'all' else team + ' slots'})"
        )
    return AquariumVectorEnv(config, num_worlds=int(num_envs) // slots, **kwargs)
