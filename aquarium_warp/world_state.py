"""The global state of every world of a `BatchedAquarium` as one vector per world: the PettingZoo env's
`state()` and the centralised critic's "world" input in training (`training/vec_env.py`)."""

from __future__ import annotations

import torch

from .kernels.common import PREDATOR, PREY

# Values per agent slot in `state()`.
STATE_FIELDS = ("alive", "x", "y", "vx", "vy", "heading_x", "heading_y")


class WorldState:
    """The global state of every world of a `BatchedAquarium`: calling it gives `[W, 7 * capacity + 1]`
    float32 on the env's device (the PettingZoo env's `state()`, and the centralised critic's "world"
    input in training, where it runs inside CUDA graphs: its constants are made once, here).

    Per agent slot, predators first, then prey slots (`possible_agents`' order):
    `[alive, x / width, y / height, vx / max_speed, vy / max_speed, heading_x, heading_y]` (`alive` 0 or
    1, positions in [0, 1], velocities and the heading unit vector in [-1, 1]; all zeros for an empty
    slot), then the episode's progress `world_step / max_steps` in [0, 1]. Computed in float64 and
    rounded once."""

    def __init__(self, aquarium):
        cfg, Pc = aquarium.config, aquarium.prey_capacity
        self.aquarium, self.max_steps = aquarium, cfg.max_steps
        dev = aquarium.torch_device
        self.order = torch.cat([torch.arange(Pc, cfg.capacity, device=dev), torch.arange(Pc, device=dev)])
        # Type code of each slot in the state's order, to read each world's max speeds at every call
        # (`set_params` changes them in place, also under a captured graph).
        self.slot_type = torch.cat(
            [torch.full((cfg.capacity - Pc,), int(PREDATOR), device=dev), torch.full((Pc,), int(PREY), device=dev)]
        )
        self.size = torch.tensor([cfg.width, cfg.height], dtype=torch.float64, device=dev)
        self.length = len(STATE_FIELDS) * cfg.capacity + 1

    def __call__(self) -> torch.Tensor:
        t, order = self.aquarium.state.torch, self.order
        alive = t.alive[:, order]
        fields = torch.cat(
            [
                alive.unsqueeze(-1).double(),
                (t.position[:, order].double() / self.size).clamp(0.0, 1.0),
                (t.velocity[:, order].double() / self.aquarium.max_speeds[:, self.slot_type, None]).clamp(-1.0, 1.0),
                t.heading[:, order].clamp(-1.0, 1.0).double(),
            ],
            dim=-1,
        )
        fields = torch.where(alive.unsqueeze(-1), fields, 0.0)
        progress = (t.world_step.double() / self.max_steps).clamp(max=1.0)
        return torch.cat([fields.flatten(1), progress.unsqueeze(1)], dim=1).float()
