"""rsl-rl `VecEnv` adapter over `BatchedAquarium`: one learning team, the other team driven inside `step()`.

Rows. Every slot of the learning team in every world is one row, world-major: row `w * S + s` is slot
`s` of world `w` (S = `env.prey_capacity` for prey, `env.predator_capacity` for predators), so
`num_envs = W * S`, `num_actions = 1` (one discrete action, a float category index as rsl-rl stores it).

Outputs of `step(actions [N, 1])`:
- observations: a `TensorDict({"policy": [N, L] float32})`. Two buffers alternate: PPO keeps a
  reference to the TensorDict it acted on and copies it into its storage only after the next
  `step()`, so each step writes into the buffer it did not return last time. A centralised critic
  (`critic="team"` or `"world"`, the MAPPO setting) adds one group for rsl-rl's "critic" observation
  set: `"team"` `[N, S * L]`, the team's joint observation (every slot of the row's world, slot
  order), or `"world"` `[N, 7 * capacity + 1]`, the world state (`world_state.WorldState`); it is
  zero for inactive rows, like their own observation.
- rewards `[N]` float32: the env's reward times `reward_scale` (rows inactive at the start of the
  step get 0).
- dones `[N]` int64 and `extras["time_outs"]` `[N]` bool (truncations only, which PPO bootstraps).
  A row's episode is the life of the agent in its slot:
  * a captured prey is a termination (done, no time-out), whether it respawns (a fresh agent in the
    same slot starts the row's next episode) or is removed; a starved predator likewise;
  * the end of its world's episode (`max_steps`) is a time-out for every live agent;
  * inactive rows (a dead slot: respawn off, starvation, or an empty reproduction slot) get reward 0
    and done 0 while they stay empty, and done 1 (no time-out) at the step their slot is filled again
    (birth, or the world's reset). Their observation is the env's all-zero one, so the critic learns
    a value of 0 for it and their advantages vanish; the stretch forms one zero-reward "episode" in
    rsl-rl's own episode statistics (which therefore count them where slots can be empty).
- `extras["log"]`: only on steps where at least one world's episode ended, per ended world (that
  started its episode at step 0; see `episode_length_buf`): `Episode/captures` (captures in the
  world's episode), `Episode/captures_per_prey` (that / prey_count), `Episode/reward_per_agent` (the
  learning team's undiscounted, unscaled episode reward summed over its slots / the team's initial
  agent count; where counts differ per world or are randomised, the largest: per slot),
  `Episode/opponent_reward_per_agent`, `Episode/length`. rsl-rl's logger concatenates every such
  entry of an iteration and averages: the mean over the episodes that ended.

The other team acts inside `step()` through `opponent()`, a callable returning its int actions
`[W, slots]` on the env's device, decided from the state before the step (a heuristic from
`aquarium_warp.heuristics.make_policy`, `drivers.TrainedOpponent` around a loaded policy, or, when both
teams learn, `drivers.LearnerActions`: the other learner's action buffer, written by the training loop
before the first adapter steps the worlds).

Worlds the learner does not drive. With an opponent pool (`pool.OpponentPool`) a team may be played
by one of its own past snapshots in some worlds (`set_driven(mask [W])`); there its rows are inactive
for its learner (zero observation and reward, as empty slots), their episodes ending where the world's
episode ends.

Host synchronisation. `step()` makes none when the world episodes can only end by truncation
(respawn on and a starvation limit of at least `max_steps - 1`: the paper's setting): a host copy of
every world's step counter says when episodes end. Otherwise it reads one flag per step
(`episode_ended.any()`). Domain randomisation (`randomize`) adds one per step: finding the worlds
whose episode ended, to draw their new values on the host. rsl-rl's own logger syncs each step anyway
when a log directory is set.
"""

from __future__ import annotations

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from ..agent_types import OTHER, TYPES
from ..device import TorchStreamLaunches
from ..env import BatchedAquarium
from ..kernels import rows as row_kernels
from ..metrics import EPISODE_METRICS, EpisodeMetrics
from ..per_world import largest
from ..world_state import WorldState
from . import _rsl  # noqa: F401
from .randomize import ParamRandomizer

# The device-side sums' columns (`accumulate_episode_stats`); captures per prey is derived on the host.
EPISODE_KEYS = ["Episode/captures", "Episode/reward_per_agent", "Episode/opponent_reward_per_agent", "Episode/length"]


class RunConfig(dict):
    """The run's config as the VecEnv's `cfg`: a dict with the `to_dict()` that rsl-rl's W&B writer
    calls on it (`WandbLogWriter.store_config`; its fallback, `dataclasses.asdict`, fails on a dict)."""

    def to_dict(self) -> dict:
        return dict(self)


class AquariumVecEnv(VecEnv):
    """rsl-rl VecEnv over a `BatchedAquarium` (created with `auto_reset=True`); see the module doc.

    Args:
        env: the batched simulator.
        team: the learning team, "prey" or "predator".
        opponent: callable returning the other team's actions `[W, slots]` (int, on the env's device).
        reward_scale: factor on the rewards returned to PPO (episode statistics stay unscaled).
        cfg: the run configuration (rsl-rl's logger stores it); defaults to the env config's dict.
        metrics_every: swarm metrics sampled every N steps (0: none; one adapter of a world is enough).
        critic: "local", or the extra observation group of a centralised critic, "team" or "world".
    """

    def __init__(
        self,
        env: BatchedAquarium,
        team: str = "prey",
        opponent=None,
        reward_scale: float | list[float] = 1.0,
        cfg: dict | None = None,
        metrics_every: int = 10,
        critic: str = "local",
        randomize=None,
        randomize_seed: int = 0,
        runs: int = 1,
    ):
        if not isinstance(env, BatchedAquarium):
            raise ValueError(f"env must be a BatchedAquarium, got {type(env).__name__}")
        if team not in TYPES:
            raise ValueError(f"team={team!r} must be one of {TYPES}")
        if not env.auto_reset:
            raise ValueError("AquariumVecEnv needs a BatchedAquarium with auto_reset=True")
        if opponent is None or not callable(opponent):
            raise ValueError("opponent must be a callable returning the other team's actions [W, slots]")
        if critic not in ("local", "team", "world"):
            raise ValueError(f"critic={critic!r} must be 'local', 'team' or 'world'")
        self.env, self.team, self.other = env, team, OTHER[team]
        # Domain randomisation (`randomize.py`): new per-world values at every world's reset.
        self.randomizer = ParamRandomizer(env, randomize, randomize_seed) if randomize else None
        self.opponent = opponent
        # A population (`population.py`): `runs` equal blocks of worlds, each with its own reward scale
        # and episode statistics.
        if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1 or env.num_worlds % runs:
            raise ValueError(f"runs={runs!r} must be an integer >= 1 that divides the {env.num_worlds} worlds")
        self.runs = runs
        scales = [float(x) for x in reward_scale] if isinstance(reward_scale, (list, tuple)) else [float(reward_scale)]
        if len(scales) not in (1, runs):
            raise ValueError(f"reward_scale gives {len(scales)} values for {runs} runs")
        # One scale is applied by the outcome kernel; the runs' own scales after it (`row_outcomes`).
        self.reward_scale = scales[0] if len(set(scales)) == 1 else 1.0
        self._run_scales = None if len(set(scales)) == 1 else torch.tensor(scales, device=env.torch_device)
        ecfg = env.config
        self.cfg = RunConfig(cfg if cfg is not None else {"env": ecfg.to_dict()})
        self.num_worlds = W = env.num_worlds
        self.slots = S = env.prey_capacity if team == "prey" else env.predator_capacity
        # Per-agent logs divide by the team's count; where counts differ per world (or are randomised),
        # by the largest (the slots per world): the worlds' own counts change at resets the log does not see.
        prey_count, predator_count = largest(ecfg.prey_count), largest(ecfg.predator_count)
        self.team_count = prey_count if team == "prey" else predator_count
        self.other_count = predator_count if team == "prey" else prey_count
        self.num_envs = W * S
        self.num_actions = 1
        self.action_count = ecfg.action_count
        self.observation_size = L = env.observation_size[team]
        self.max_episode_length = ecfg.max_steps
        self.device = env.torch_device
        dev = self.device

        t = env.state.torch
        Pc = env.prey_capacity
        self._rewards_in = env.outputs.rewards[team]
        self._terminated_in = env.outputs.terminated[team]
        self._truncated_in = env.outputs.truncated[team]
        self._alive = env.alive[team]
        self._captured_in = t.captured[:, :Pc] if team == "prey" else None
        self._info = info = env.outputs.info
        self._episode_ended = info["episode_ended"]
        self._ended_length = info["episode_length"]
        self._ended_captures = info["episode_captures"]
        self._ended_return = info["episode_return"][team]
        self._ended_return_other = info["episode_return"][self.other]

        self._obs = [torch.zeros(W * S, L, dtype=torch.float32, device=dev) for _ in range(2)]
        # The centralised critic's group (None: the critic sees the actor's observation only).
        self.critic_group = None if critic == "local" else critic
        self._world_state = WorldState(env) if critic == "world" else None  # None: the team's joint observation
        self._critic_obs: list[torch.Tensor] | None = None  # the critic group's two buffers
        if self.critic_group is not None:
            size = self._world_state.length if self._world_state is not None else S * L
            self._critic_obs = [torch.zeros(W * S, size, dtype=torch.float32, device=dev) for _ in range(2)]
        self._obs_td = [
            TensorDict(
                {"policy": o, **({critic: self._critic_obs[k]} if self._critic_obs else {})},
                batch_size=[W * S],
                device=dev,
            )
            for k, o in enumerate(self._obs)
        ]
        self._current = 0
        self._rewards = torch.zeros(W * S, dtype=torch.float32, device=dev)
        self._dones = torch.zeros(W * S, dtype=torch.long, device=dev)
        self._time_outs = torch.zeros(W * S, dtype=torch.bool, device=dev)
        self._actions = torch.zeros(W, S, dtype=torch.int32, device=dev)
        self._active = torch.zeros(W, S, dtype=torch.bool, device=dev)
        # Worlds whose team this learner drives (`set_driven`; None: all) and the rows live in them.
        self.driven: torch.Tensor | None = None
        self._live = torch.zeros(W, S, dtype=torch.bool, device=dev)
        self.extras: dict = {"time_outs": self._time_outs}

        starvation_ok = ecfg.predator_starvation_steps >= ecfg.max_steps - 1
        self.predictable_ends = bool(ecfg.respawn_captured_prey and starvation_ok)
        # Swarm metrics (aquarium_warp.metrics) sampled every `metrics_every` steps and logged per
        # ended episode as "Swarm/<name>"; 0 turns them off.
        self.swarm = EpisodeMetrics(env, every=metrics_every) if metrics_every else None
        # Device-side episode statistics (`accumulate_episode_stats`, used by the training loop of
        # `loop.py`): per world "its episode started at step 0", sums and counts of the logged values.
        self.device_stats = False
        self._full = torch.zeros(W, dtype=torch.bool, device=dev)
        self._stat_names = EPISODE_KEYS + ([f"Swarm/{n}" for n in EPISODE_METRICS] if self.swarm else [])
        # The running sums `episode_stats_snapshot()` takes: per logged value its sum (C), then its count
        # (C), then, over the row episodes (agent lives) that ended, their reward total and count.
        C = len(self._stat_names)
        self._stats = torch.zeros(runs * (2 * C + 2), dtype=torch.float64, device=dev)  # run by run
        self._stat_terms = torch.zeros(W, 2 * C + 2, dtype=torch.float64, device=dev)  # each world's terms
        # Rows' running reward sums.
        self._row_return = torch.zeros(W * S, dtype=torch.float32, device=dev)
        self._no_swarm = torch.zeros(W, 0, dtype=torch.float64, device=dev)  # the statistics' swarm columns
        self._launches = TorchStreamLaunches(env.device)  # those of kernels/rows.py
        self.sync_from_env()

    # ------------------------------------------------------------------ internal state
    def sync_from_env(self) -> None:
        """Take rows' activity, the host step counters and the current observations from the env
        (after construction, `load_state_dict` or a change of the step counters)."""
        self._active.copy_(self._live_rows())
        # Host copy of the worlds' step counters (kept up to date only where episodes end predictably).
        self._host_step = self.env.state.torch.world_step.cpu().numpy().astype(np.int64)
        # A world's episode statistics are logged only if the episode started at step 0.
        self._host_full = self._host_step == 0
        self._full.copy_(torch.from_numpy(self._host_full))
        self.copy_observations()
        if self.swarm is not None:
            self.swarm.begin()

    def _live_rows(self) -> torch.Tensor:
        """`[W, S]`: rows whose slot holds a live agent that this learner drives."""
        if self.driven is None:
            return self._alive
        return torch.logical_and(self._alive, self.driven.unsqueeze(1), out=self._live)

    def set_driven(self, driven: torch.Tensor | None) -> None:
        """`driven [W]` bool (a buffer its owner updates in place): the worlds in which this learner
        drives its team; elsewhere its rows are inactive (see the module doc). None: every world."""
        self.driven = driven
        self.sync_from_env()

    @property
    def episode_stats_size(self) -> int:
        """Length of `episode_stats_snapshot()` (each run's statistics, one after another)."""
        return self.runs * (2 * len(self._stat_names) + 2)

    # ------------------------------------------------------------------ VecEnv API
    def get_observations(self) -> TensorDict:
        return self._obs_td[self._current]

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """Per row: its world's step counter in the current world episode (`[N]` int32, a copy)."""
        return self.env.state.torch.world_step.repeat_interleave(self.slots)

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        """Set every world's step counter (rsl-rl's `init_at_random_ep_len` spreads the worlds'
        truncations this way); the first slot's row of each world is used, clamped to
        `[0, max_steps - 1]`. Worlds set to a non-zero step are left out of the episode statistics
        until their next episode."""
        value = torch.as_tensor(value).reshape(self.num_worlds, self.slots)[:, 0]
        steps = value.to(torch.int64).clamp(0, self.max_episode_length - 1).to(torch.int32).cpu()
        self.env.set_state(world_step=steps)
        self.sync_from_env()

    def step(self, actions: torch.Tensor):
        self.step_simulation(actions)
        if self.swarm is not None:
            self.swarm.update(self._info)
        self.row_outcomes()
        self._current ^= 1
        self.copy_observations()
        self.extras = {"time_outs": self._time_outs}
        log = self._episode_log()
        if log is not None:
            self.extras["log"] = log
        return self._obs_td[self._current], self._rewards, self._dones, self.extras

    # The parts of `step()`, which the training loop of `loop.py` calls separately: the tensor-only
    # parts (`row_outcomes`, `copy_observations`, `accumulate_episode_stats`) can be captured in a CUDA
    # graph; `step_simulation` too where `step_capturable` says so.
    def step_simulation(self, actions: torch.Tensor | None = None) -> None:
        """The other team acts and every world steps; `actions [N, 1]` (float category indices) are
        the learning team's, or None when they were already written into `actions_buffer`."""
        if actions is not None:
            self._actions.copy_(actions.reshape(self.num_worlds, self.slots))  # float -> int32 (exact)
        other_actions = self.opponent()
        self.env.step({self.team: self._actions, self.other: other_actions}, validate=False)
        if self.randomizer is not None:
            self.randomizer.update(self._episode_ended)

    @property
    def step_capturable(self) -> bool:
        """Whether `step_simulation(None)` is device work only, so a CUDA graph may hold it: an opponent
        marked `capturable` (a heuristic, the other learner's buffer; a loaded policy's own random
        stream and a recurrent one's host state are not), no domain randomisation (it reads the
        ended worlds on the host), swarm metrics without a trace (its samples are host lists) and
        worlds whose step can be recorded (`env.step_capturable`)."""
        return (
            self.randomizer is None
            and bool(getattr(self.opponent, "capturable", False))
            and (self.swarm is None or not self.swarm.trace_names)
            and self.env.step_capturable
        )

    @property
    def actions_buffer(self) -> torch.Tensor:
        """`[W, S]` int32: the learning team's actions that `step_simulation(None)` applies."""
        return self._actions

    @property
    def outputs(self) -> tuple[torch.Tensor, torch.Tensor, dict]:
        """`(rewards [N], dones [N], {"time_outs": [N]})`: the buffers `row_outcomes()` writes."""
        return self._rewards, self._dones, {"time_outs": self._time_outs}

    @property
    def info(self) -> dict:
        """The env's per-world step outputs (views; see `BatchedAquarium.step`)."""
        return self._info

    def row_outcomes(self) -> None:
        """Rows' rewards, dones and time-outs of the last simulation step (see the module doc): one
        launch of `kernels.rows.learner_row_outcomes` on torch's current stream."""
        W, S = self.num_worlds, self.slots
        live = self._live_rows()  # (recorded once per liveness buffer: `set_driven` changes it)
        captured = self._captured_in if self._captured_in is not None else self._terminated_in
        self._launches.run(
            ("row_outcomes", live.data_ptr()),
            row_kernels.learner_row_outcomes,
            (W, S),
            lambda: [
                self._terminated_in,
                captured,
                self._truncated_in,
                live,
                self._rewards_in,
                float(self.reward_scale),
                self._active,
                self._dones.view(W, S),
                self._time_outs.view(W, S),
                self._rewards.view(W, S),
            ],
        )
        if self._run_scales is not None:
            self._rewards.view(self.runs, -1).mul_(self._run_scales.unsqueeze(1))

    def copy_observations(self) -> None:
        """The learning team's observations after the last step into the current buffer (and the
        centralised critic's group); zero for rows inactive in worlds this learner does not drive."""
        W, S = self.num_worlds, self.slots
        obs = self._obs[self._current].view(W, S, -1)
        obs.copy_(self.env.observations[self.team])
        if self.driven is not None:
            obs.mul_(self._active.unsqueeze(-1))
        if self._critic_obs is not None:
            critic = self._critic_obs[self._current].view(W, S, -1)
            joint = obs.reshape(W, 1, -1) if self._world_state is None else self._world_state().unsqueeze(1)
            torch.mul(joint, self._active.unsqueeze(-1), out=critic)

    def accumulate_episode_stats(self) -> None:
        """Device-side counterpart of the `extras["log"]` statistics (no host sync): adds the world
        episodes that ended in the last step (those that started at step 0) and the rows' ended lives
        to running sums, which `episode_stats_snapshot()` takes and clears. Every step's graph runs it,
        though episodes end rarely: one launch of `kernels.rows.episode_statistics` (each world's
        terms), then their sum over the worlds. Sums are of the raw per-world values; the divisions by
        team sizes happen in `decode_episode_stats`."""
        W, S = self.num_worlds, self.slots
        self._launches.run(
            "episode_statistics",
            row_kernels.episode_statistics,
            W,
            lambda: [
                self._episode_ended,
                self._full,
                self._ended_captures,
                self._ended_return,
                self._ended_return_other,
                self._ended_length,
                self.swarm.ended_values if self.swarm is not None else self._no_swarm,
                self._rewards.view(W, S),
                self._dones.view(W, S),
                self._row_return.view(W, S),
                self._stat_terms,
            ],
        )
        if self.runs == 1:
            self._stats += self._stat_terms.sum(dim=0)
        else:  # each run's worlds summed apart
            self._stats += self._stat_terms.view(self.runs, W // self.runs, -1).sum(dim=1).view(-1)

    def episode_stats_snapshot(self) -> torch.Tensor:
        """The running sums of `accumulate_episode_stats` as one new device tensor (for
        `decode_episode_stats`), then cleared: device work only, no host sync."""
        snapshot = self._stats.clone()
        self._stats.zero_()
        return snapshot

    def decode_episode_stats(self, snapshot) -> tuple[dict[str, float], int, float]:
        """From a snapshot's values: `({name: mean over the ended world episodes}, how many ended, the
        mean reward of the rows' ended lives (NaN if none))`."""
        values = [float(v) for v in snapshot]
        k = len(self._stat_names)
        sums, counts, (row_total, row_count) = values[:k], values[k : 2 * k], values[2 * k :]
        means = {name: s / c for name, s, c in zip(self._stat_names, sums, counts) if c > 0}
        prey_count = self.team_count if self.team == "prey" else self.other_count
        if "Episode/captures" in means:  # per-world sums -> the logged per-agent values
            means["Episode/captures_per_prey"] = means["Episode/captures"] / prey_count
            means["Episode/reward_per_agent"] /= self.team_count
            means["Episode/opponent_reward_per_agent"] /= self.other_count
        return means, int(counts[0]), (row_total / row_count if row_count else float("nan"))

    def _episode_log(self) -> dict | None:
        """Statistics of the world episodes that ended this step (None when none did)."""
        if self.predictable_ends:
            self._host_step += 1
            ended = self._host_step >= self.max_episode_length
            if not ended.any():
                return None
            self._host_step[ended] = 0
        else:
            if not bool(self._episode_ended.any()):  # the one host sync of this mode
                return None
            ended = self._episode_ended.cpu().numpy()
        report = ended & self._host_full
        self._host_full |= ended
        if not report.any():
            return None
        if report.all():
            index = None
        else:
            index = torch.from_numpy(np.flatnonzero(report)).to(self.device)

        def pick(x: torch.Tensor) -> torch.Tensor:
            return (x if index is None else x.index_select(0, index)).to(torch.float32, copy=True)

        captures = pick(self._ended_captures)
        prey_count = self.team_count if self.team == "prey" else self.other_count
        swarm = {}
        if self.swarm is not None:
            values = pick(self.swarm.ended_values)
            swarm = {f"Swarm/{name}": values[:, m] for m, name in enumerate(EPISODE_METRICS)}
        return {
            **swarm,
            "Episode/captures": captures,
            "Episode/captures_per_prey": captures / prey_count,
            "Episode/reward_per_agent": pick(self._ended_return) / self.team_count,
            "Episode/opponent_reward_per_agent": pick(self._ended_return_other) / self.other_count,
            "Episode/length": pick(self._ended_length),
        }

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self, with_env: bool = True) -> dict:
        """Everything needed to continue bit-exactly: the simulation (unless `with_env=False`: another
        adapter of the same worlds saves it), row activity, host counters and the opponent's own state
        (a heuristic's random streams are keyed by the simulation state)."""
        opponent_state = self.opponent.state_dict() if hasattr(self.opponent, "state_dict") else {}
        return {
            **({"env": self.env.state_dict()} if with_env else {}),
            "active": self._active.cpu().clone(),
            "host_full": self._full.cpu().numpy() if self.device_stats else self._host_full.copy(),
            "row_return": self._row_return.cpu().clone(),
            "opponent": opponent_state,
            "swarm": self.swarm.state_dict() if self.swarm is not None else None,
            "randomizer": self.randomizer.state_dict() if self.randomizer is not None else None,
        }

    def load_state_dict(self, state: dict) -> None:
        if self.randomizer is not None and state.get("randomizer") is not None:
            self.randomizer.load_state_dict(state["randomizer"])  # first: the env's state names its values
        if "env" in state:
            self.env.load_state_dict(state["env"])
        self.sync_from_env()
        self._active.copy_(state["active"].to(self.device))
        self._host_full = np.asarray(state["host_full"], dtype=bool).copy()
        self._full.copy_(torch.from_numpy(self._host_full))
        if "row_return" in state:
            self._row_return.copy_(state["row_return"].to(self.device))
        if state.get("opponent") and hasattr(self.opponent, "load_state_dict"):
            self.opponent.load_state_dict(state["opponent"])
        if self.swarm is not None and state.get("swarm") is not None:
            self.swarm.load_state_dict(state["swarm"])

    def close(self) -> None:
        self.env.close()
