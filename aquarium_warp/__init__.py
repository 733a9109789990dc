"""aquarium-warp: the Aquarium predator-prey environment as batched NVIDIA Warp kernels."""

from .config import AgentTypeConfig, AquariumConfig
from .env import BatchedAquarium

__all__ = ["AgentTypeConfig", "AquariumConfig", "BatchedAquarium"]
__version__ = "0.1.0"
