"""aquarium-warp: the Aquarium predator-prey environment as batched NVIDIA Warp kernels."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .interop.pettingzoo_registry import register as _register_pettingzoo
from .interop.pettingzoo_registry import register_gymnasium as _register_gymnasium

if TYPE_CHECKING:
    from . import aquarium_v1
    from .config import AgentTypeConfig, AquariumConfig
    from .env import BatchedAquarium

_register_pettingzoo()  # pettingzoo.make("parallel" | "aec", "aquarium/Aquarium-v1"): see interop.pettingzoo_registry
_register_gymnasium()  # gym.make_vec("aquarium/Aquarium-v1", num_envs=...): the same module

__all__ = ["AgentTypeConfig", "AquariumConfig", "BatchedAquarium", "aquarium_v1"]
__version__ = "0.1.0"

# The public names, each imported from its module on first use: importing the package (the command line's
# parsers, the registries above) loads neither torch nor Warp.
_LAZY = {"AgentTypeConfig": ".config", "AquariumConfig": ".config", "BatchedAquarium": ".env"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    elif name == "aquarium_v1":  # `from aquarium_warp import aquarium_v1`: the PettingZoo module
        value = importlib.import_module(".aquarium_v1", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value
