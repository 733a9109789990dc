"""Drivers of a team of a `BatchedAquarium` by trained policies: callables that return the team's int
actions `[W, slots]` on the env's device, decided from the state before the step (the opponent of a
training run, `eval`, `video`, the studies, through `aquarium_warp.drivers.make_driver`).

- `TrainedOpponent`: a policy mapping observations `[N, L]` -> actions `[N]` (`export.load_policy`).
- `RecurrentOpponent`: a recurrent `LoadedPolicy`, its rows' hidden states reset where their episodes end.
- `policy_driver`: the one of the two a loaded policy needs.
- `LearnerActions`: the other learner's action buffer when both teams learn (`train.team = "both"`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..agent_types import TYPES
from ..env import BatchedAquarium

if TYPE_CHECKING:
    from .export import LoadedPolicy
    from .vec_env import AquariumVecEnv


class TrainedOpponent:
    """Drives one team of `env` with a policy mapping observations `[N, L]` -> actions `[N]`
    (e.g. `load_policy(...)`); returns int32 actions `[W, slots]` on the env's device.

    `blind_to` ("prey" or "predator"): the policy acts on observations whose slots of that type are
    empty (all zeros, as an unfilled slot reads): the neighbour-ablation control of a study."""

    def __init__(self, policy, env: BatchedAquarium, agent_type: str, blind_to: str | None = None):
        if agent_type not in TYPES:
            raise ValueError(f"agent_type={agent_type!r} must be one of {TYPES}")
        if blind_to is not None and blind_to not in TYPES:
            raise ValueError(f"blind_to={blind_to!r} must be None or one of {TYPES}")
        self.policy, self.env, self.agent_type = policy, env, agent_type
        obs = env.observations[agent_type]
        self._slots, self._obs_size = obs.shape[1], obs.shape[2]
        check = getattr(policy, "check_compatible", None)
        if check is not None:
            check(agent_type, env.config, self._slots)
        self.actions = torch.zeros(obs.shape[:2], dtype=torch.int32, device=env.torch_device)
        self.blind_to = blind_to
        self._blind = env.config.neighbour_columns(agent_type, blind_to) if blind_to is not None else None
        self._seen = torch.empty_like(obs) if blind_to is not None else None  # the ablated copy

    def __call__(self) -> torch.Tensor:
        obs = self.env.observations[self.agent_type]
        if self._seen is not None:
            self._seen.copy_(obs)
            self._seen[..., self._blind] = 0.0
            obs = self._seen
        obs = obs.reshape(-1, self._obs_size)
        with torch.inference_mode():
            act = self.policy(obs)
        self.actions.copy_(act.reshape(self.actions.shape))
        return self.actions

    def state_dict(self) -> dict:
        state = getattr(self.policy, "rng_state", None)
        return {"policy_rng": state()} if state is not None else {}

    def load_state_dict(self, state: dict) -> None:
        if "policy_rng" in state:
            self.policy.set_rng_state(state["policy_rng"])


def policy_driver(policy, env: BatchedAquarium, agent_type: str, blind_to: str | None = None):
    """`TrainedOpponent` around a loaded policy (`export.load_policy`), or `RecurrentOpponent` for a
    recurrent one (its rows' hidden states reset where their episodes end); `blind_to` as there."""
    if getattr(policy, "recurrent", None) is not None:
        return RecurrentOpponent(policy, env, agent_type, blind_to=blind_to)
    return TrainedOpponent(policy, env, agent_type, blind_to=blind_to)


class LearnerActions:
    """The other team's actions when it learns too (`train.team = "both"`): the action buffer of its
    adapter (`vec_env`, set once both adapters exist), which the training loop fills before the
    first adapter steps the worlds."""

    capturable = True  # a call only returns the buffer: a CUDA graph may hold it

    def __init__(self, vec_env: AquariumVecEnv | None = None):
        self.vec_env = vec_env

    def __call__(self) -> torch.Tensor:
        if self.vec_env is None:
            raise RuntimeError("LearnerActions: the other learner's adapter is not set yet")
        return self.vec_env.actions_buffer


class RecurrentOpponent:
    """Drives one team of a `BatchedAquarium` with a recurrent `LoadedPolicy`, as `TrainedOpponent`
    does, and before acting resets the hidden state of the rows whose episode ended in the step since
    its last call: the agent's life ended (captured, removed, starved, or its world's episode ended) or
    its empty slot was filled again, the row dones of the training adapter (`vec_env.py`). Call it
    once per env step."""

    def __init__(self, policy: LoadedPolicy, env: BatchedAquarium, agent_type: str, blind_to: str | None = None):
        self.driver, self.policy = TrainedOpponent(policy, env, agent_type, blind_to=blind_to), policy
        self._terminated, self._truncated = env.outputs.terminated[agent_type], env.outputs.truncated[agent_type]
        self._captured = env.state.torch.captured[:, : env.prey_capacity] if agent_type == "prey" else None
        self._alive = env.alive[agent_type]
        self._active: torch.Tensor | None = None  # rows alive when the policy last acted
        policy.reset()  # every row starts from zero states, as rsl-rl's rollouts do

    def __call__(self) -> torch.Tensor:
        if self._active is not None:
            ended = self._terminated | self._truncated
            if self._captured is not None:
                ended = ended | self._captured
            self.policy.reset(torch.where(self._active, ended, self._alive).reshape(-1))
        self._active = self._alive.clone()
        return self.driver()

    def state_dict(self) -> dict:
        """The sampling stream, the rows' hidden states and which rows were alive (for bit-exact resumes)."""
        hidden = self.policy.hidden_state
        return {
            **self.driver.state_dict(),
            "hidden_state": None if hidden is None else tuple(x.cpu().clone() for x in hidden),
            "active": None if self._active is None else self._active.cpu().clone(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.driver.load_state_dict(state)
        self.policy.hidden_state = state.get("hidden_state")
        self._active = None if state.get("active") is None else state["active"].to(self._alive.device)
