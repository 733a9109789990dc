"""Host-side checks: the number ranges the kernels stay finite in, and the checks of what a user hands
a `BatchedAquarium` (actions, state values, state dicts) before anything reaches the device.

Every check raises a one-line `ValueError` that names the parameter and what it may be, and a check
that fails changes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    import torch

    from .state import SimulationState

# torch and the state's Warp groups are imported where a check needs them: the config's checks run in
# light processes too (`aquarium-warp --help`, config validation).

# The counters `set_state` may set besides the agent fields.
SETTABLE_COUNTERS = ("world_step", "episode")

# Ranges that keep the kernels' float32 arithmetic finite and exact to float32 for any reachable
# state. The kernels square lengths (distances, vector lengths) and add per-step rates to velocities,
# so every length, speed, force, acceleration and mass lies in [SMALLEST, LARGEST]: a square, and a
# sum of a few squares, of such values stays inside float32's normal range [1.2e-38, 3.4e38] with a
# wide margin (no overflow to inf, no underflow to a subnormal or to 0). Worlds are at most 1e7 px.
SMALLEST = 1e-15
LARGEST = 1e15
# Episode returns add every reward of a world's slots over an episode in float32: the largest
# per-step reward magnitude x max_steps x prey slots must stay below this (float32's max is 3.4e38).
RETURN_LIMIT = 1e38
# Counters (steps, ages, starvation) are int32 on the device.
INT32_MAX = 2**31 - 1
# The largest handling time (`AquariumConfig.handling_steps`): far beyond any episode of the studies.
MAX_HANDLING_STEPS = 10**6


def require(name: str, value, ok: bool, allowed: str) -> None:
    """Raise `ValueError` naming `name`, its `value` and what is `allowed`, unless `ok`."""
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def is_int(value) -> bool:
    """Python or numpy integers (not bools)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def is_real(value) -> bool:
    """Python or numpy integers or reals, not NaN (and not bools)."""
    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, (bool, np.bool_))
        and not math.isnan(value)
    )


# ---------------------------------------------------------------------------------------------- the env
# What the checks read of a `BatchedAquarium` and its config, as protocols: the env and the config import
# this module, so it imports neither.
class WorldConfig(Protocol):
    @property
    def width(self) -> float: ...
    @property
    def height(self) -> float: ...
    @property
    def max_steps(self) -> int: ...
    @property
    def action_count(self) -> int: ...


class Env(Protocol):
    @property
    def config(self) -> WorldConfig: ...
    @property
    def device(self) -> str: ...
    @property
    def torch_device(self) -> torch.device: ...
    @property
    def num_worlds(self) -> int: ...
    @property
    def prey_capacity(self) -> int: ...
    @property
    def predator_capacity(self) -> int: ...
    @property
    def state(self) -> SimulationState: ...
    @property
    def actions(self) -> Mapping[str, torch.Tensor]: ...
    @property
    def alive(self) -> Mapping[str, torch.Tensor]: ...


# ---------------------------------------------------------------------------------------------- actions
def action_tensor(actions) -> torch.Tensor:
    """Actions as a tensor; numpy arrays of the other byte order are converted first (torch reads only
    native ones)."""
    import torch

    if isinstance(actions, np.ndarray) and not actions.dtype.isnative:
        actions = actions.astype(actions.dtype.newbyteorder("="))
    return actions if isinstance(actions, torch.Tensor) else torch.as_tensor(actions)


def check_actions(env: Env, actions) -> None:
    """`actions` fits `env`'s action buffers (keys, integer dtype, shape, device), and every live
    agent's action is in [0, action_count - 1]."""
    import torch

    types = tuple(env.actions)
    if not isinstance(actions, Mapping):
        raise ValueError(f"actions must be a dict with keys {types}, got {type(actions).__name__}")
    missing = [t for t in types if t not in actions]
    extra = [k for k in actions if k not in types]
    if missing or extra:
        raise ValueError(f"actions must have exactly the keys {types}; missing {missing}, unknown {extra}")
    n = env.config.action_count
    out_of_range = {}
    for t in types:
        a = actions[t]
        expected = tuple(env.actions[t].shape)
        if isinstance(a, np.ndarray):
            if env.torch_device.type != "cpu":
                raise ValueError(f"actions[{t!r}] is a numpy array; pass a torch tensor on {env.device}")
            if a.dtype.kind not in "biufc":
                raise ValueError(f"actions[{t!r}] must have an integer dtype, got numpy {a.dtype}")
            a = action_tensor(a)
        if not isinstance(a, torch.Tensor):
            raise ValueError(f"actions[{t!r}] must be a torch tensor, got {type(a).__name__}")
        if a.dtype.is_floating_point or a.dtype.is_complex or a.dtype == torch.bool:
            raise ValueError(f"actions[{t!r}] must have an integer dtype, got {a.dtype}")
        if tuple(a.shape) != expected:
            raise ValueError(
                f"actions[{t!r}] must have shape {list(expected)} (num_worlds, {t} slots), got {list(a.shape)}"
            )
        if a.device != env.torch_device:
            raise ValueError(f"actions[{t!r}] is on {a.device}, but the env runs on {env.device}")
        out_of_range[t] = (a, ((a < 0) | (a >= n)) & env.alive[t])
    # One device sync for both types, then the first bad action named.
    flags = torch.stack([bad.any() for _, bad in out_of_range.values()]).tolist()
    for (t, (a, bad)), flagged in zip(out_of_range.items(), flags):
        if flagged:
            w, i = (int(x) for x in torch.nonzero(bad)[0])
            raise ValueError(
                f"actions[{t!r}][{w}, {i}]={int(a[w, i])} is out of range: live agents' "
                f"actions must be in [0, {n - 1}] (action_count={n})"
            )


# ---------------------------------------------------------------------------------------------- state values
def cpu_tensor(name: str, value) -> torch.Tensor:
    """`value` (a tensor, array, number or nested list) as a CPU tensor; a clear error naming `name`
    for what torch cannot hold (strings, objects, mixed types)."""
    import torch

    try:
        if not isinstance(value, torch.Tensor):
            value = np.asarray(value)
            if value.dtype.kind not in "biuf":
                raise TypeError(f"dtype {value.dtype}")
            value = torch.as_tensor(value.astype(value.dtype.newbyteorder("=")))
        if value.dtype in (torch.uint16, torch.uint32, torch.uint64):
            value = value.to(torch.float64)  # torch's wide unsigned types support little arithmetic
        return value.detach().cpu()
    except (TypeError, ValueError, RuntimeError, NotImplementedError) as error:
        raise ValueError(
            f"{name} must hold numbers (a tensor or array of booleans, integers or reals): {error}"
        ) from None


def integer_ranges(env: Env) -> dict[str, tuple[int, int, str]]:
    """`{field: (lowest, highest, why)}` of `env`'s integer state fields."""
    steps = env.config.max_steps
    return {
        # A prey's age grows by one per step for up to max_steps steps of an episode.
        "age": (
            0,
            INT32_MAX - steps,
            f"2**31 - 1 - max_steps: ages grow by one per step for up to max_steps={steps} steps (int32)",
        ),
        "replication_age": (0, INT32_MAX, "int32"),
        "starvation": (0, INT32_MAX - 1, "int32, grows by one per step"),
        "handling": (0, MAX_HANDLING_STEPS, f"steps left of a handling time, at most {MAX_HANDLING_STEPS}"),
        "world_step": (0, steps - 1, f"below max_steps={steps}"),
        "episode": (0, INT32_MAX - 1, "int32, grows by one per episode"),
        "episode_captures": (0, INT32_MAX, "int32"),
        "prey_alive_count": (0, env.prey_capacity, "live prey slots"),
        "predator_alive_count": (0, env.predator_capacity, "live predator slots"),
    }


def state_value_ranges(env: Env) -> dict[str, str]:
    """The values `env`'s state fields may take, per field, in words (`BatchedAquarium.state_value_ranges`)."""
    config = env.config
    return {name: text for name, (_, _, text) in integer_ranges(env).items()} | {
        "position": f"finite, in [0, {config.width}) x [0, {config.height}) (as float32)",
        "velocity": f"finite, each component in [-{LARGEST:g}, {LARGEST:g}] px/step",
        "acceleration": f"finite, each component in [-{LARGEST:g}, {LARGEST:g}] px/step^2",
        "heading": "finite unit vectors (|heading| = 1 within 1e-4)",
        "alive": "booleans (or 0/1)",
        "episode_return": "finite float32",
    }


def checked_state_value(env: Env, name: str, value: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """`value` (a CPU tensor of the field's shape) as `dtype`, after checking that it holds values the
    field may take in `env`; the range check runs on the given values, before a cast could wrap them."""
    import torch

    config = env.config
    if value.dtype.is_complex:
        raise ValueError(f"{name} has dtype {value.dtype}; expected real numbers ({dtype})")
    if dtype == torch.bool:
        if value.dtype != torch.bool and not ((value == 0) | (value == 1)).all():
            raise ValueError(f"{name} must hold booleans (or 0/1)")
        return value.to(torch.bool)
    if dtype == torch.int32:
        if (
            value.dtype == torch.bool
            or value.dtype.is_floating_point
            and not (torch.isfinite(value) & (value == value.round())).all()
        ):
            raise ValueError(f"{name} must hold integers")
        lo, hi, why = integer_ranges(env)[name]
        wide = value.double() if value.dtype.is_floating_point else value.to(torch.int64)
        if value.numel() and (wide.min() < lo or wide.max() > hi):
            bad = wide[(wide < lo) | (wide > hi)][0].item()
            raise ValueError(
                f"{name} holds {bad:.0f}, out of range: must be >= {lo} and <= {hi}, i.e. in [{lo}, {hi}] ({why})"
            )
        return value.to(torch.int32)
    if value.dtype == torch.bool:
        raise ValueError(f"{name} must hold real numbers, got booleans")
    value = value.to(torch.float32)  # a value beyond float32's range becomes inf here and is refused
    if not torch.isfinite(value).all():
        raise ValueError(f"{name} must be finite (as float32)")
    if name == "position":
        x, y = value[..., 0], value[..., 1]
        if (x < 0).any() or (x >= config.width).any() or (y < 0).any() or (y >= config.height).any():
            raise ValueError(f"position must lie in [0, {config.width}) x [0, {config.height}) (as float32)")
    elif name in ("velocity", "acceleration") and (value.abs() > LARGEST).any():
        raise ValueError(f"{name} components must be in [-{LARGEST:g}, {LARGEST:g}] (float32-safe)")
    elif name == "heading":
        norm = torch.linalg.vector_norm(value.double(), dim=-1)
        if ((norm - 1.0).abs() > 1e-4).any():
            raise ValueError("heading must hold unit vectors (|heading| = 1 within 1e-4)")
    return value


def checked_state_fields(env: Env, world, fields: Mapping) -> dict[str, torch.Tensor]:
    """`env.set_state`'s `fields` for `world` (None: every world), checked: names, the world index,
    shapes and values; returned as CPU tensors of the fields' dtypes."""
    from .state import AGENT_FIELDS

    views, num_worlds = env.state.torch, env.num_worlds
    unknown = [k for k in fields if k not in AGENT_FIELDS and k not in SETTABLE_COUNTERS]
    if unknown:
        raise ValueError(f"unknown state fields {unknown}; settable: {list(AGENT_FIELDS)} + {list(SETTABLE_COUNTERS)}")
    if world is not None and (
        isinstance(world, bool) or not isinstance(world, (int, np.integer)) or not 0 <= world < num_worlds
    ):
        raise ValueError(f"world={world!r} must be None or an integer in [0, {num_worlds - 1}]")
    sel = slice(None) if world is None else int(world)
    staged = {}
    for name, value in fields.items():
        target = getattr(views, name)[sel]
        value = cpu_tensor(name, value)
        if name in SETTABLE_COUNTERS and world is None and value.dim() == 0:
            value = value.expand(target.shape)
        if tuple(value.shape) != tuple(target.shape):
            raise ValueError(f"{name} must have shape {list(target.shape)}, got {list(value.shape)}")
        staged[name] = checked_state_value(env, name, value, target.dtype)
    return staged


# State fields added after states were first saved, with the value every agent starts with (zero):
# `handling`, the predator's handling time of the confusion capture rule.
LATER_STATE_FIELDS = ("handling",)


def checked_state_tensors(env: Env, tensors) -> dict[str, torch.Tensor]:
    """The `"tensors"` of a `state_dict()` for `env`, checked: exactly `STATE_DICT_FIELDS`, each a tensor
    of the field's shape, dtype and values, live counts matching the alive flags; returned as CPU
    tensors."""
    import torch

    from .state import STATE_DICT_FIELDS

    views = env.state.torch
    if not isinstance(tensors, Mapping):
        raise ValueError(f"state_dict tensors must be a dict of tensors, got {type(tensors).__name__}")
    # A state saved before a field existed holds no tensor of it: the field's initial value, zero.
    tensors = {n: torch.zeros_like(getattr(views, n)).cpu() for n in LATER_STATE_FIELDS if n not in tensors} | dict(
        tensors
    )
    missing = [n for n in STATE_DICT_FIELDS if n not in tensors]
    unknown = [n for n in tensors if n not in STATE_DICT_FIELDS]
    if missing or unknown:
        raise ValueError(
            f"state_dict tensors must be exactly {list(STATE_DICT_FIELDS)}; missing {missing}, unknown {unknown}"
        )
    staged = {}
    for name in STATE_DICT_FIELDS:
        value, target = tensors[name], getattr(views, name)
        if not isinstance(value, torch.Tensor):
            raise ValueError(f"state_dict tensor {name} must be a torch tensor, got {type(value).__name__}")
        if tuple(value.shape) != tuple(target.shape):
            raise ValueError(f"state_dict tensor {name} has shape {list(value.shape)}, expected {list(target.shape)}")
        if value.dtype != target.dtype:
            raise ValueError(f"state_dict tensor {name} has dtype {value.dtype}, expected {target.dtype}")
        try:
            staged[name] = checked_state_value(env, name, value.detach().cpu(), target.dtype)
        except ValueError as error:
            raise ValueError(f"state_dict tensor {error}") from None
    alive, prey_capacity = staged["alive"], env.prey_capacity
    for kind, slots in (("prey", slice(0, prey_capacity)), ("predator", slice(prey_capacity, None))):
        count = staged[f"{kind}_alive_count"]
        if not torch.equal(count, alive[:, slots].sum(dim=1).to(torch.int32)):
            w = int(torch.nonzero(count != alive[:, slots].sum(dim=1))[0])
            raise ValueError(
                f"state_dict tensor {kind}_alive_count[{w}]={int(count[w])} does not match the "
                f"{int(alive[w, slots].sum())} live {kind} slots of world {w}"
            )
    return staged
