"""Stable-Baselines3 `VecEnv` over `BatchedAquarium` (needs the `[interop]` extra), no SuperSuit in between.

```python
from stable_baselines3 import PPO
from aquarium_warp import AquariumConfig
from aquarium_warp.interop.sb3 import AquariumSB3VecEnv

vec = AquariumSB3VecEnv(AquariumConfig(prey_count=6, max_steps=200), num_worlds=16)   # every agent a row
model = PPO("MlpPolicy", vec, n_steps=64, batch_size=448, seed=0).learn(total_timesteps=100_000)

prey = AquariumSB3VecEnv(num_worlds=16, team="prey", opponent="naivchase")    # one team learns
```

Rows, dead slots, respawns, autoreset, seeding and buffers: as `gymnasium.AquariumVectorEnv` (its
module doc), with SB3's conventions:
- `dones = terminations | truncations`; `infos` is a list of one dict per row: `{}`, or for a done row
  `{"TimeLimit.truncated": bool}` (True for a truncation). There is no `"terminal_observation"`: the
  simulation never computes the ended episode's last observation (it resets inside its step), so
  SB3's PPO does not bootstrap truncated rows (it treats them as terminations).
- Dead slots are rows with an all-zero observation, reward 0 and `dones` 0 until their slot is filled
  (a done then); `vec.active` (numpy bool `[N]`) says which rows hold a
  live agent.
- Seeding: `PPO(seed=s)` calls `vec.seed(s)`, and the `reset()` that `learn()` makes then runs the
  episode of `BatchedAquarium(seed=s)` (only the first of SB3's per-row seeds is used: the worlds
  draw from one seed); `reset()` without a pending seed continues the env's sequence of seeds.
- Observations are numpy arrays: on the CPU views of two alternating buffers (PPO keeps the previous
  step's array while the next step runs: valid until the step after the next), on a GPU one copy to the
  host per step. Rewards and flags are new arrays.
`get_attr`, `set_attr` and `env_method` act on this object (one simulation for every row) and return
one entry per requested row.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from ..config import AquariumConfig
from .gymnasium import AquariumRows


class AquariumSB3VecEnv(VecEnv):
    """Stable-Baselines3 `VecEnv` over a `BatchedAquarium`; keyword arguments as `AquariumRows`."""

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device: Any = "cpu",
        seed: int | None = None,
        team: str = "all",
        opponent: Any = None,
        **kwargs: Any,
    ):
        self.rows = rows = AquariumRows(
            config, num_worlds=num_worlds, device=device, seed=seed, team=team, opponent=opponent, **kwargs
        )
        self.render_mode = None
        self._host = rows.device.type == "cpu"
        self._obs_np = [o.view(rows.num_rows, -1).numpy() for o in rows._obs] if self._host else None
        self._actions: Any = None
        super().__init__(rows.num_rows, rows.single_observation_space, rows.single_action_space)

    @property
    def aquarium(self):
        return self.rows.aquarium

    @property
    def active(self) -> np.ndarray:
        """`[N]` bool (a copy): rows holding a live agent."""
        return self.rows.active.cpu().numpy().copy()

    def _observations(self) -> np.ndarray:
        if self._obs_np is not None:
            return self._obs_np[self.rows._current]
        return self.rows.observations.cpu().numpy()

    def reset(self) -> np.ndarray:
        seed = self._seeds[0] if self._seeds else None
        self.rows.reset(seed)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._observations()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        rows = self.rows
        rows.step(self._actions)
        terminated = rows.terminated.cpu().numpy()
        truncated = rows.truncated.cpu().numpy()
        dones = terminated | truncated  # a new array
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(dones).tolist():
            infos[i]["TimeLimit.truncated"] = bool(truncated[i])
        return self._observations(), rows.rewards.cpu().numpy().copy(), dones, infos

    def close(self) -> None:
        self.rows.close()

    def _count(self, indices: VecEnvIndices) -> int:
        return len(list(self._get_indices(indices)))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self, attr_name)
        return [value] * self._count(indices)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        result = getattr(self, method_name)(*method_args, **method_kwargs)
        return [result] * self._count(indices)

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * self._count(indices)
