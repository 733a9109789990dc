"""PettingZoo's registry: `pettingzoo.make("parallel" | "aec", "aquarium/Aquarium-v1", **kwargs)`, and
Gymnasium's: `gym.make_vec("aquarium/Aquarium-v1", num_envs=N, **kwargs)`.

```python
import aquarium_warp  # registers the env (importing it is enough)
import gymnasium as gym
import pettingzoo

par = pettingzoo.make("parallel", "aquarium/Aquarium-v1", prey_count=16, max_cycles=200)
aec = pettingzoo.make("aec", "aquarium/Aquarium-v1")   # the AEC form, as aquarium_v1.env()
vec = gym.make_vec("aquarium/Aquarium-v1", num_envs=4 * 17)   # AquariumVectorEnv: 4 worlds of 17 rows
```

Gymnasium: `ENV_ID` has a `vector_entry_point` only (`interop.gymnasium.make_vector_env`: `num_envs` is
the number of rows, a multiple of a world's rows; keywords as `AquariumVectorEnv`'s plus `AquariumConfig`
fields). It has no single-agent entry point (`gym.make`): the env is multi-agent, each agent a row.

PettingZoo 1.27 adds `pettingzoo.make` / `pettingzoo.register` and deprecates the per-env `env()` /
`parallel_env()` constructors in its own packages (PettingZoo#1392). `import aquarium_warp` registers
`ENV_ID` in both registries, with the entry points `aquarium_warp.aquarium_v1:parallel_env` and
`aquarium_warp.aquarium_v1:env` (imported on the first `make`), so the keyword arguments are those of
`aquarium_v1` (marl-aquarium's names, `AquariumConfig` fields, `device=`, `seed=`, `max_cycles=`; see
`interop.pettingzoo.resolve_kwargs`). `pettingzoo.make(..., max_cycles=N)` passes `max_cycles` on, the
episode length in steps. With an older PettingZoo (no `pettingzoo.register`), nothing is registered and
`aquarium_v1.parallel_env()` / `aquarium_v1.env()` remain the constructors.
"""

from __future__ import annotations

ENV_ID = "aquarium/Aquarium-v1"
ENTRY_POINTS = {"parallel": "aquarium_warp.aquarium_v1:parallel_env", "aec": "aquarium_warp.aquarium_v1:env"}
VECTOR_ENTRY_POINT = "aquarium_warp.interop.gymnasium:make_vector_env"


def register() -> bool:
    """Register `ENV_ID` in PettingZoo's "parallel" and "aec" registries (idempotent: an id already
    there is left alone, so a reload does not warn). Returns False when the installed PettingZoo has
    no registry (before 1.27)."""
    import pettingzoo

    if not hasattr(pettingzoo, "register"):
        return False
    registries = {"parallel": pettingzoo.parallel_registry, "aec": pettingzoo.aec_registry}
    for env_type, entry_point in ENTRY_POINTS.items():
        if ENV_ID not in registries[env_type]:
            pettingzoo.register(env_type, ENV_ID, entry_point=entry_point)
    return True


def register_gymnasium() -> None:
    """Register `ENV_ID` in Gymnasium's registry for `gym.make_vec` (idempotent, as `register`)."""
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(ENV_ID, vector_entry_point=VECTOR_ENTRY_POINT)
