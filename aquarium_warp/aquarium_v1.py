"""PettingZoo entry points, drop-in for marl-aquarium's `aquarium_v0`.

```python
from aquarium_warp import aquarium_v1          # was: from marl_aquarium import aquarium_v0

env = aquarium_v1.env(render_mode="rgb_array")             # AEC, as marl-aquarium's README uses it
env.reset(seed=42)
for agent in env.agent_iter():
    observation, reward, termination, truncation, info = env.last()
    action = None if termination or truncation else env.action_space(agent).sample()
    env.step(action)
env.close()

par = aquarium_v1.parallel_env(keep_prey_count_constant=False, predator_count=3)   # ParallelEnv
```

- `parallel_env(**kwargs)`: the raw `ParallelEnv` (no AEC round trip, unlike `aquarium_v0`).
- `env(**kwargs)`: the AEC form: PettingZoo's `parallel_to_aec` plus `CheckedActions` (PettingZoo's
  `AssertOutOfBoundsWrapper` with a `ValueError` naming the agent, the value and the range) and
  `OrderEnforcingWrapper`.
- `raw_env`: the `ParallelEnv` class.

Keyword arguments: marl-aquarium's names and defaults, this package's `AquariumConfig` fields or
`config=AquariumConfig(...)`, `device=` ("cpu" by default), `seed=`, `max_cycles=` (alias of
`max_time_steps` / `max_steps`). See `aquarium_warp.interop.pettingzoo`.
"""

from __future__ import annotations

import numpy as np
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

from .interop.pettingzoo import AquariumParallelEnv

raw_env = AquariumParallelEnv

__all__ = ["env", "parallel_env", "raw_env"]


def parallel_env(**kwargs) -> AquariumParallelEnv:
    """The Aquarium as a PettingZoo `ParallelEnv` (one world, CPU by default)."""
    return AquariumParallelEnv(**kwargs)


class CheckedActions(wrappers.BaseWrapper):
    """PettingZoo's `AssertOutOfBoundsWrapper`, whose bare assertion names nothing, as a `ValueError`
    naming the agent, the value and the allowed range (a bool is refused: it is no action index)."""

    def step(self, action) -> None:
        agent = self.agent_selection
        done = self.terminations[agent] or self.truncations[agent]
        space = self.action_space(agent)
        if not (done and action is None) and (isinstance(action, (bool, np.bool_)) or not space.contains(action)):
            raise ValueError(
                f"action {action!r} of agent {agent!r} is not in Discrete({space.n}): must be an "
                f"integer in [0, {space.n - 1}]" + (" or None (the agent is done)" if done else "")
            )
        super().step(action)


def env(**kwargs):
    """The Aquarium as a PettingZoo AEC env: `parallel_to_aec(parallel_env(**kwargs))` wrapped in
    `CheckedActions` and `OrderEnforcingWrapper` (as marl-aquarium's `aquarium_v0.env`, whose
    `AssertOutOfBoundsWrapper` `CheckedActions` replaces)."""
    aec = parallel_to_aec(AquariumParallelEnv(**kwargs))
    return wrappers.OrderEnforcingWrapper(CheckedActions(aec))
