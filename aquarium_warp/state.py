"""The simulation state of a batch of worlds: the typed groups of `kernels/state.py`, allocated once.

`SimulationState` holds one instance of each group (`state.agents.position` is a Warp array
`[W, C]`); kernels take the groups whole. `state.torch` exposes every array as a torch tensor under
its field name (`state.torch.position`), sharing memory (zero copy). `state.rows(w0, w1)` views
the groups of worlds `[w0, w1)`, which is what a `WorldShard` runs on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import torch
import warp as wp

from .kernels.state import Actions, Agents, Observations, Scratch, StepOutputs, WorldCounters

if TYPE_CHECKING:
    from warp._src.codegen import Struct


def struct_type(cls) -> Struct:
    """A `@wp.struct` class as what Warp made of it, a `Struct` (its fields `vars`, `numpy_dtype()`):
    mypy ignores class decorators and would type it as the plain class."""
    return cls


# Attribute name -> group type, in the order kernels take them (inputs before outputs).
GROUPS = {
    "actions": Actions,
    "agents": Agents,
    "worlds": WorldCounters,
    "scratch": Scratch,
    "outputs": StepOutputs,
    "observations": Observations,
}
# The agent fields a user may read and set (`BatchedAquarium.set_state`), and the tensors of
# `state_dict()`: the whole simulation state (the seed travels as an integer, or a tuple of them, from
# which every world's stream key and index follow).
AGENT_FIELDS = tuple(struct_type(Agents).vars)
STATE_DICT_FIELDS = AGENT_FIELDS + tuple(
    n for n in struct_type(WorldCounters).vars if n not in ("seed", "stream_world")
)


def group_rows(group_type, group, w0: int, w1: int):
    """A new `group_type` instance whose arrays view worlds `[w0, w1)` of `group`'s."""
    view = group_type()
    for name in struct_type(group_type).vars:
        setattr(view, name, getattr(group, name)[w0:w1])
    return view


class SimulationState:
    """The groups of a batch of worlds: `actions` (`Actions`), `agents` (`Agents`), `worlds`
    (`WorldCounters`), `scratch` (`Scratch`), `outputs` (`StepOutputs`) and `observations`
    (`Observations`); `torch` (a namespace of torch views of every field, by field name) on the
    state that owns the memory."""

    def __init__(self, actions, agents, worlds, scratch, outputs, observations):
        self.actions = actions
        self.agents = agents
        self.worlds = worlds
        self.scratch = scratch
        self.outputs = outputs
        self.observations = observations
        self._torch: TorchViews | None = None

    @property
    def torch(self) -> TorchViews:
        """Torch views of every field, by name (`state.torch.position`); on the state that owns the
        memory, not on a shard's `rows()`."""
        if self._torch is None:
            raise AttributeError("torch views belong to the state that owns the memory, not to a shard's rows")
        return self._torch

    @classmethod
    def allocate(
        cls,
        num_worlds: int,
        capacity: int,
        prey_capacity: int,
        predator_capacity: int,
        prey_obs_size: int,
        predator_obs_size: int,
        prey_mask_size: int,
        predator_mask_size: int,
        device,
    ) -> SimulationState:
        """Zeroed arrays for `num_worlds` worlds of `capacity` slots (the sizes of the field docs)."""
        W, C = num_worlds, capacity
        shapes = {  # field -> shape; every other field is [W, C] or [W] as its dtype's ndim says
            "ended_return": (W, 2),
            "prey_action": (W, prey_capacity),
            "predator_action": (W, predator_capacity),
            "obs_prey": (W, prey_capacity, prey_obs_size),
            "obs_predator": (W, predator_capacity, predator_obs_size),
            "mask_prey": (W, prey_capacity, prey_mask_size),
            "mask_predator": (W, predator_capacity, predator_mask_size),
            "slot_prey": (W, prey_capacity, prey_mask_size),
            "slot_predator": (W, predator_capacity, predator_mask_size),
        }
        groups = {}
        for group_name, group_type in GROUPS.items():
            group = group_type()
            for name, var in struct_type(group_type).vars.items():
                field = cast(wp.array, var.type)  # every field of a group is declared as a `wp.array[...]`
                shape = shapes.get(name, (W, C) if field.ndim == 2 else W)
                setattr(group, name, wp.zeros(shape, dtype=field.dtype, device=device))
            groups[group_name] = group
        state = cls(**groups)
        state._torch = TorchViews(state)
        return state

    def arrays(self) -> dict[str, wp.array]:
        """Field name -> Warp array, over every group."""
        return {
            name: getattr(getattr(self, group), name)
            for group, group_type in GROUPS.items()
            for name in struct_type(group_type).vars
        }

    def rows(self, w0: int, w1: int) -> SimulationState:
        """The groups of worlds `[w0, w1)`: views of this state's arrays."""
        return SimulationState(
            **{name: group_rows(group_type, getattr(self, name), w0, w1) for name, group_type in GROUPS.items()}
        )


class TorchViews:
    """Zero-copy torch views of every array of a `SimulationState`, by field name; made once (each
    conversion costs host time)."""

    def __init__(self, state: SimulationState):
        for name, array in state.arrays().items():
            setattr(self, name, wp.to_torch(array))

    def __getattr__(self, name: str) -> torch.Tensor:
        # Only reached for a name that is not a field; declared so type checkers see every field as a Tensor.
        raise AttributeError(f"no state field {name!r}")


def estimate_bytes(cfg, num_worlds: int, cells_per_world: int) -> int:
    """Device bytes of a batch of `num_worlds` worlds of `cfg` (state, outputs, cell lists), about."""
    obs = max(cfg.observation_size("prey"), cfg.observation_size("predator"))
    slots = max(p.predator_slots + p.prey_slots for p in (cfg.prey, cfg.predator))
    return num_worlds * (cfg.capacity * bytes_per_slot(obs, slots) + cells_per_world * 12 + 64)


def bytes_per_slot(prey_obs_size: int, mask_size: int) -> int:
    """Device bytes per agent slot: state, outputs, cell lists and observations (an estimate)."""
    state = 4 * 8 + 1 + 4 * 4  # vec2 fields, alive, int fields
    outputs = 4 + 1 + 1 + 1 + 4 + 4 + 4 + 4  # reward, flags, share count, caught prey, episode return, action
    grid = 2 * 4 + 2 * 4 + 8  # keys (with arrival orders), agents (with scratch), sorted position
    return state + outputs + grid + 4 * prey_obs_size + mask_size
