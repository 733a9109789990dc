"""Opponent pool (fictitious self-play) for `train.team = "both"`: each team may play, in some worlds,
against past snapshots of the other team instead of its live learner.

Every `train.pool_every` iterations the trainer calls `snapshot()`: each team's actor (observation
normaliser and MLP) is copied into a ring of `train.pool_size` slots of stacked parameters (the oldest
snapshot is replaced). Worlds draw their match when their episode ends (and once at the start), on the
device, from torch's global random stream (two uniforms per world and step, kept only where a world's
episode ended; the stream's state is in every checkpoint): with probability `f_prey` the predators are
a snapshot (the prey learn against the past), with probability `f_predator` the prey are, otherwise
both teams are live (`f_team` is that team's `pool_fraction`; a world plays at most one team's
snapshots, so that every world feeds at least one learner). Which snapshot: `"uniform"` over the
filled slots, or `"latest"`, weights 1, 2, ..., n from the oldest to the newest. Before the first
snapshot every world is live.

Acting (`act()`, inside the rollout step's CUDA graph): the snapshots of a team whose snapshots are
played are evaluated at once on all of its observations (`torch.func.functional_call` under `vmap`
over the stacked parameters: one batched product per layer, no loop over snapshots or worlds), each
row keeps the logits of its world's snapshot, and actions are sampled from them as the learner
sampled when it was that snapshot; they replace the learner's actions in those worlds. The learner's
rows there are inactive (`AquariumVecEnv.set_driven`). Feed-forward actors only (a snapshot keeps no
hidden state).
"""

from __future__ import annotations

import copy

import numpy as np
import torch
import torch.nn as nn
from torch.func import functional_call

from ..agent_types import OTHER, TYPES
from .config import POOL_SAMPLING
from .vec_env import AquariumVecEnv

# The actor's parts that a snapshot keeps: its observation normaliser, then its MLP (logits).
ACTOR_PARTS = ("obs_normalizer", "mlp")


class OpponentPool:
    """Snapshots of every learning team's actor, played per world against the other team (see the
    module doc). `learners`: `{team: (actor, vec_env)}` for both teams; `fractions`: `{team: f}`,
    the fraction of worlds in which `team` plays against the other team's snapshots."""

    def __init__(self, learners: dict, size: int, sampling: str, fractions: dict[str, float]):
        if sampling not in POOL_SAMPLING:
            raise ValueError(f"sampling={sampling!r} must be one of {POOL_SAMPLING}")
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"size={size!r} must be an integer >= 1")
        if set(learners) != set(TYPES) or set(fractions) != set(learners):
            raise ValueError("an opponent pool needs both teams' learners and pool fractions")
        if any(not 0 <= f <= 1 for f in fractions.values()) or sum(fractions.values()) > 1:
            raise ValueError(f"pool fractions {fractions} must be in [0, 1] and add up to at most 1")
        self.size, self.sampling = size, sampling
        self.count = 0  # snapshots taken so far (the ring holds the last min(count, size))
        self.teams = TYPES
        self.actors = {t: learners[t][0] for t in self.teams}
        self.envs: dict[str, AquariumVecEnv] = {t: learners[t][1] for t in self.teams}
        env = self.envs["prey"]
        self.num_worlds, self.device = env.num_worlds, env.device
        W, dev = self.num_worlds, self.device
        # Team t is played by snapshots where the OTHER team plays against the past.
        self.snapshot_share = {t: float(fractions[OTHER[t]]) for t in self.teams}
        # A world's uniform `role` draw: [0, f_prey) predators are a snapshot, [f_prey, f_prey + f_predator)
        # the prey are, the rest is live.
        self._low = {"predator": 0.0, "prey": float(fractions["prey"])}
        self._threshold = {
            "predator": float(fractions["prey"]),
            "prey": float(fractions["prey"] + fractions["predator"]),
        }
        self._templates = {}
        self._stacked: dict[str, dict[str, torch.Tensor]] = {}
        for team in self.teams:
            actor = self.actors[team]
            if getattr(actor, "is_recurrent", False):
                raise ValueError("an opponent pool needs feed-forward actors (snapshots keep no hidden state)")
            template = nn.Sequential(*(copy.deepcopy(getattr(actor, part)) for part in ACTOR_PARTS)).eval()
            self._templates[team] = template
            self._stacked[team] = {
                name: torch.zeros((size,) + tuple(value.shape), dtype=value.dtype, device=dev)
                for name, value in template.state_dict().items()
            }
        # Per world: the snapshot slot playing each team there, -1 where its learner plays it.
        self.index = {t: torch.full((W,), -1, dtype=torch.long, device=dev) for t in self.teams}
        self.driven = {t: torch.ones(W, dtype=torch.bool, device=dev) for t in self.teams}
        # Cumulative probabilities over the ring's slots (2 past the filled ones: never drawn), and
        # whether any snapshot exists: device tensors, so the captured draws read their current values.
        self._cdf = torch.full((size,), 2.0, dtype=torch.float32, device=dev)
        self._any = torch.zeros((), dtype=torch.bool, device=dev)
        self._ended = env.info["episode_ended"]
        self._all = torch.ones(W, dtype=torch.bool, device=dev)
        self._draw(self._all)
        for team in self.teams:
            self.envs[team].set_driven(self.driven[team])

    # ------------------------------------------------------------------ snapshots
    def snapshot(self) -> None:
        """Copy every team's current actor into the ring (outside any CUDA graph; the graphs read the
        stacked buffers, which keep their addresses)."""
        slot = self.count % self.size
        with torch.no_grad():
            for team in self.teams:
                actor, stacked = self.actors[team], self._stacked[team]
                for i, part in enumerate(ACTOR_PARTS):
                    for name, value in getattr(actor, part).state_dict().items():
                        stacked[f"{i}.{name}"][slot].copy_(value)
        self.count += 1
        self._cdf.copy_(torch.from_numpy(self.cdf(self.count, self.size, self.sampling)))
        self._any.fill_(True)

    @staticmethod
    def cdf(count: int, size: int, sampling: str) -> np.ndarray:
        """Cumulative probabilities over the ring's slots after `count` snapshots (float32 `[size]`;
        2.0 from the last filled slot on, so a uniform draw in [0, 1) never passes it)."""
        filled = min(count, size)
        age = (count - 1 - np.arange(filled)) % size  # slot s holds the snapshot taken `age` snapshots ago
        weights = np.ones(filled) if sampling == "uniform" else (filled - age).astype(np.float64)
        cdf = np.full(size, 2.0)
        cdf[: filled - 1] = np.cumsum(weights)[:-1] / weights.sum()
        return cdf.astype(np.float32)

    def probabilities(self) -> np.ndarray:
        """The probability of each ring slot being drawn (zeros before the first snapshot)."""
        if self.count == 0:
            return np.zeros(self.size)
        cdf = np.minimum(self.cdf(self.count, self.size, self.sampling).astype(np.float64), 1.0)
        return np.diff(np.concatenate([[0.0], cdf]))

    # ------------------------------------------------------------------ per step (captured on CUDA)
    def _draw(self, where: torch.Tensor) -> None:
        """New matches for the worlds in `where` `[W]` bool (two uniforms per world)."""
        role, pick = torch.rand(2, self.num_worlds, device=self.device)
        slot = torch.searchsorted(self._cdf, pick.unsqueeze(1), right=True).squeeze(1).clamp_(max=self.size - 1)
        for team in self.teams:
            played = (role >= self._low[team]) & (role < self._threshold[team]) & self._any
            new = torch.where(played, slot, -1)
            self.index[team].copy_(torch.where(where, new, self.index[team]))
            torch.lt(self.index[team], 0, out=self.driven[team])

    def resample(self) -> None:
        """After a step: worlds whose episode ended draw their next match (before the adapters read
        their rows' outcomes, so a row ends its episode with the world's and is inactive after)."""
        self._draw(self._ended)

    def act(self) -> None:
        """Before a step, after the learners acted: snapshot actions replace the learners' in the worlds
        their team plays as a snapshot."""
        for team in self.teams:
            if self.snapshot_share[team] == 0.0:
                continue
            env = self.envs[team]
            W, S = env.num_worlds, env.slots
            obs = env.env.observations[team].reshape(W * S, -1)
            template = self._templates[team]
            logits = torch.vmap(lambda params, template=template, obs=obs: functional_call(template, params, (obs,)))(
                self._stacked[team]
            )
            rows = self.index[team].clamp(min=0).view(W, 1).expand(W, S).reshape(-1)
            chosen = logits.gather(0, rows.view(1, -1, 1).expand(1, -1, logits.shape[-1])).squeeze(0)
            actions = torch.multinomial(torch.softmax(chosen, dim=-1), 1).view(W, S)
            buffer = env.actions_buffer
            buffer.copy_(torch.where(self.driven[team].unsqueeze(1), buffer, actions.to(buffer.dtype)))

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        return {
            "count": self.count,
            "stacked": {t: {k: v.cpu().clone() for k, v in s.items()} for t, s in self._stacked.items()},
            "index": {t: v.cpu().clone() for t, v in self.index.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        self.count = int(state["count"])
        for team in self.teams:
            for name, value in state["stacked"][team].items():
                self._stacked[team][name].copy_(value)
            self.index[team].copy_(state["index"][team])
            torch.lt(self.index[team], 0, out=self.driven[team])
        if self.count:
            self._cdf.copy_(torch.from_numpy(self.cdf(self.count, self.size, self.sampling)))
        self._any.fill_(self.count > 0)
        for team in self.teams:
            self.envs[team].set_driven(self.driven[team])
