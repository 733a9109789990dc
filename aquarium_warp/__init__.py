"""aquarium-warp: the Aquarium predator-prey environment as batched NVIDIA Warp kernels."""

from .config import AgentTypeConfig, AquariumConfig
from .env import BatchedAquarium
from .interop.pettingzoo_registry import register as _register_pettingzoo
from .interop.pettingzoo_registry import register_gymnasium as _register_gymnasium

_register_pettingzoo()  # pettingzoo.make("parallel" | "aec", "aquarium/Aquarium-v1"): see interop.pettingzoo_registry
_register_gymnasium()  # gym.make_vec("aquarium/Aquarium-v1", num_envs=...): the same module

__all__ = ["AgentTypeConfig", "AquariumConfig", "BatchedAquarium", "aquarium_v1"]
__version__ = "0.1.0"


def __getattr__(name):
    # `from aquarium_warp import aquarium_v1` imports the PettingZoo module on first use only.
    if name == "aquarium_v1":
        import importlib

        module = importlib.import_module(".aquarium_v1", __name__)
        globals()[name] = module
        return module
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
