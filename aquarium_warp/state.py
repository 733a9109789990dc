"""Structure-of-arrays simulation state, allocated once per environment.

Warp arrays are the storage; `TorchViews` exposes the same memory as torch tensors (zero copy).
Agent arrays are `[num_worlds, capacity]`: prey slots `[0, prey_capacity)`, then predator slots.
"""

from __future__ import annotations

import warp as wp

# name: (dtype, doc) -- the agent fields a user may read and set
AGENT_FIELDS = {
    "position": (wp.vec2, "[W, C, 2] float32, px, in [0, width) x [0, height)"),
    "velocity": (wp.vec2, "[W, C, 2] float32, px/step"),
    "acceleration": (wp.vec2, "[W, C, 2] float32, px/step^2, carried between steps (memory)"),
    "heading": (wp.vec2, "[W, C, 2] float32, unit vector of the last non-zero velocity"),
    "alive": (wp.bool, "[W, C] bool, the slot holds a live agent"),
    "age": (wp.int32, "[W, C] int32, prey: steps since birth or last reproduction"),
    "replication_age": (wp.int32, "[W, C] int32, prey: age at which it reproduces"),
    "starvation": (wp.int32, "[W, C] int32, predators: steps since the last capture"),
}

# name: (dtype, doc) -- per-world counters
WORLD_FIELDS = {
    "world_step": (wp.int32, "[W] int32, steps taken in the current episode"),
    "episode": (wp.int32, "[W] int32, index of the current episode (keys the random streams)"),
    "episode_captures": (wp.int32, "[W] int32, captures so far in the current episode"),
    "prey_alive_count": (wp.int32, "[W] int32, live prey"),
    "predator_alive_count": (wp.int32, "[W] int32, live predators"),
}


class SimulationState:
    """All arrays of a batch of worlds. Attributes are Warp arrays; `.torch` holds torch views."""

    def __init__(self, num_worlds: int, capacity: int, prey_capacity: int, predator_count: int,
                 prey_obs_size: int, predator_obs_size: int, prey_mask_size: int, predator_mask_size: int,
                 device):
        W, C = num_worlds, capacity
        zeros = lambda shape, dtype: wp.zeros(shape, dtype=dtype, device=device)  # noqa: E731
        for name, (dtype, _) in AGENT_FIELDS.items():
            setattr(self, name, zeros((W, C), dtype))
        for name, (dtype, _) in WORLD_FIELDS.items():
            setattr(self, name, zeros(W, dtype))
        # Per-step outputs and scratch.
        self.reward = zeros((W, C), float)  # this step's reward per slot
        self.terminated = zeros((W, C), wp.bool)
        self.truncated = zeros((W, C), wp.bool)
        self.captured = zeros((W, C), wp.bool)  # prey captured this step
        self.contact_partner = zeros((W, C), wp.int32)  # slot of the overlapping same-type agent, or -1
        self.contact_offset = zeros((W, C), wp.vec2)  # torus displacement from that partner, px
        self.share_count = zeros((W, C), wp.int32)  # predators sharing each capture
        self.episode_return = zeros((W, C), float)  # reward summed over the episode, per slot
        self.captures = zeros(W, wp.int32)  # captures this step
        self.episode_ended = zeros(W, wp.bool)
        self.ended_length = zeros(W, wp.int32)
        self.ended_captures = zeros(W, wp.int32)
        self.ended_return = zeros((W, 2), float)  # [:, 0] predators, [:, 1] prey, summed over agents
        self.prey_action = zeros((W, prey_capacity), wp.int32)
        self.predator_action = zeros((W, predator_count), wp.int32)
        self.obs_prey = zeros((W, prey_capacity, prey_obs_size), float)
        self.obs_predator = zeros((W, predator_count, predator_obs_size), float)
        self.mask_prey = zeros((W, prey_capacity, prey_mask_size), wp.bool)
        self.mask_predator = zeros((W, predator_count, predator_mask_size), wp.bool)
        self.slot_prey = zeros((W, prey_capacity, prey_mask_size), wp.int32)  # observed agents' slots, -1 empty
        self.slot_predator = zeros((W, predator_count, predator_mask_size), wp.int32)
        self.torch = TorchViews(self)


class TorchViews:
    """Zero-copy torch views of a `SimulationState`, made once (each conversion costs host time)."""

    def __init__(self, state: SimulationState):
        for name, value in vars(state).items():
            if isinstance(value, wp.array):
                setattr(self, name, wp.to_torch(value))


def estimate_bytes(cfg, num_worlds: int, cells_per_world: int) -> int:
    """Device bytes of a batch of `num_worlds` worlds of `cfg` (state, outputs, cell lists), about."""
    obs = max(cfg.prey.observation_size, cfg.predator.observation_size)
    slots = max(p.predator_slots + p.prey_slots for p in (cfg.prey, cfg.predator))
    return num_worlds * (cfg.capacity * bytes_per_slot(obs, slots) + cells_per_world * 12 + 64)


def bytes_per_slot(prey_obs_size: int, mask_size: int) -> int:
    """Device bytes per agent slot: state, outputs, cell lists and observations (an estimate)."""
    state = 4 * 8 + 1 + 3 * 4  # vec2 fields, alive, int fields
    outputs = 4 + 1 + 1 + 1 + 4 + 4 + 4  # reward, flags, share count, episode return, action
    grid = 2 * 4 + 2 * 4 + 8  # keys (with arrival orders), agents (with scratch), sorted position
    return state + outputs + grid + 4 * prey_obs_size + mask_size
