"""Stable-Baselines3 `VecEnv` over `BatchedAquarium` (needs the `[interop]` extra), no SuperSuit in between.

```python
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor, VecVideoRecorder
from aquarium_warp import AquariumConfig
from aquarium_warp.interop.sb3 import AquariumSB3VecEnv

vec = VecMonitor(AquariumSB3VecEnv(AquariumConfig(prey_count=6, max_steps=200), num_worlds=16))   # every agent a row
model = PPO("MlpPolicy", vec, n_steps=64, batch_size=448, seed=0).learn(total_timesteps=100_000)

prey = AquariumSB3VecEnv(num_worlds=16, team="prey", opponent="naivchase")    # one team learns
video = VecVideoRecorder(AquariumSB3VecEnv(num_worlds=2, render_mode="rgb_array"), "videos",
                         record_video_trigger=lambda step: step == 0, video_length=100)   # world 0
```

Rows, episodes, empty slots, seeding and buffers: as `gymnasium.AquariumVectorEnv` (its module doc) in
its same-step autoreset mode (SB3's own convention: a done row's observation is its next episode's
first), with SB3's conventions:
- `dones = terminations | truncations`; `infos` is a list of one dict per row: `{}`, or for a done row
  `{"TimeLimit.truncated": bool, "terminal_observation": [L] float32}` (True for a truncation; the
  ended episode's last observation: a truncated agent's real one, all zeros for a dead agent), from
  which SB3's algorithms bootstrap truncated episodes.
- Empty slots are rows with an all-zero observation, reward 0 and never done (no episode, so
  `VecMonitor` counts real lives only: its returns are the agents' returns; its lengths include the
  empty steps before an agent appeared); `vec.active` (numpy bool `[N]`) says which rows hold a live
  agent.
- Seeding: `PPO(seed=s)` calls `vec.seed(s)`, and the `reset()` that `learn()` makes then runs the
  episode of `BatchedAquarium(seed=s)` (only the first of SB3's per-row seeds is used: the worlds
  draw from one seed); `reset()` without a pending seed continues the env's sequence of seeds.
- Observations are numpy arrays: on the CPU views of two alternating buffers (PPO keeps the previous
  step's array while the next step runs: valid until the step after the next), on a GPU one copy to the
  host per step. Rewards and flags are new arrays.
- `render_mode="rgb_array"`: `render()` returns the frame of world `render_world` (0 by default; the
  project's renderer, `render.render_world`), so `VecVideoRecorder` records it (it needs `moviepy`);
  `get_images()` returns one frame per row, its world's.
- Threads: on the CPU the simulation's worker threads (one per core) and torch's (as many) take turns
  and get in each other's way: on 2 cores PPO ran several times slower than with one torch thread. So
  `torch_threads="auto"` (default) sets `torch.set_num_threads(1)` (process-wide) when the simulation
  runs on a CPU of at most `SMALL_CPU_CORES` cores; an integer sets that many, None leaves torch alone.
`get_attr`, `set_attr` and `env_method` act on this object (one simulation for every row) and return
one entry per requested row.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from ..config import AquariumConfig
from ..device import resolve_cpu_threads
from .gymnasium import RENDER_FPS, AquariumRows, RowFrames, check_render_mode

SMALL_CPU_CORES = 4  # "auto" gives torch one thread on CPUs of at most this many cores


def set_torch_threads(torch_threads, simulation_on_cpu: bool) -> None:
    """Apply `torch_threads` ("auto", None or an integer >= 1; see the module doc)."""
    if torch_threads == "auto":
        if simulation_on_cpu and resolve_cpu_threads(None) <= SMALL_CPU_CORES:
            torch.set_num_threads(1)
        return
    if torch_threads is None:
        return
    if isinstance(torch_threads, bool) or not isinstance(torch_threads, (int, np.integer)) or torch_threads < 1:
        raise ValueError(f"torch_threads={torch_threads!r} must be 'auto', None or an integer >= 1")
    torch.set_num_threads(int(torch_threads))


class AquariumSB3VecEnv(VecEnv):
    """Stable-Baselines3 `VecEnv` over a `BatchedAquarium`; keyword arguments as `AquariumRows` (always
    same-step), plus `render_mode` (None or "rgb_array"), `render_world` (the world `render()` draws)
    and `torch_threads` ("auto", None or an integer; see the module doc)."""

    def __init__(
        self,
        config: AquariumConfig | None = None,
        num_worlds: int = 1,
        device: Any = "cpu",
        seed: int | None = None,
        team: str = "all",
        opponent: Any = None,
        render_mode: str | None = None,
        render_world: int = 0,
        torch_threads: int | str | None = "auto",
        **kwargs: Any,
    ):
        if "autoreset_mode" in kwargs:
            raise ValueError(
                "autoreset_mode: SB3's VecEnv is same-step (a done row returns its next episode's first observation)"
            )
        self.render_mode = check_render_mode(render_mode)
        self.rows = rows = AquariumRows(
            config,
            num_worlds=num_worlds,
            device=device,
            seed=seed,
            team=team,
            opponent=opponent,
            autoreset_mode=AutoresetMode.SAME_STEP,
            **kwargs,
        )
        if (
            isinstance(render_world, bool)
            or not isinstance(render_world, (int, np.integer))
            or not 0 <= render_world < rows.num_worlds
        ):
            raise ValueError(f"render_world={render_world!r} must be an integer in [0, {rows.num_worlds - 1}]")
        self.render_world = int(render_world)
        set_torch_threads(torch_threads, rows.device.type == "cpu")
        self._host = rows.device.type == "cpu"
        self._obs_np = [o.view(rows.num_rows, -1).numpy() for o in rows._obs] if self._host else None
        self._actions: Any = None
        super().__init__(rows.num_rows, rows.single_observation_space, rows.single_action_space)
        self.metadata["render_fps"] = RENDER_FPS  # type: ignore[assignment]  # SB3 types metadata as lists only

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
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        dones = rows.ended.cpu().numpy().copy()
        if rows.ended_rows:
            index = torch.nonzero(rows.ended).view(-1)
            final = rows.final_observations[index].cpu().numpy()  # a new array: the rows' own copies
            truncated = rows.truncated[index].cpu().numpy()
            for k, i in enumerate(index.tolist()):
                infos[i] = {"TimeLimit.truncated": bool(truncated[k]), "terminal_observation": final[k]}
        return self._observations(), rows.rewards.cpu().numpy().copy(), dones, infos

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """`render_mode="rgb_array"`: the frame of world `render_world`, numpy uint8 `[H, W, 3]`."""
        if mode is not None and mode != self.render_mode:
            raise ValueError(f"render(mode={mode!r}): this env renders {self.render_mode!r} (its render_mode)")
        if self.render_mode is None:
            return None
        from ..render import render_world  # lazy: only rendering needs it

        return render_world(self.rows.aquarium, self.render_world)

    def get_images(self) -> list[np.ndarray | None]:
        """One frame per row: its world's (each world drawn once)."""
        if self.render_mode is None:
            return [None] * self.num_envs
        return list(RowFrames(self.rows))

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
