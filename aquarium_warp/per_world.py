"""Per-world parameters: which fields may differ between the worlds of a batch, their two spellings, and
the samplers that draw them.

A config names a type's field with a dot (`prey.max_speed`, as `AquariumConfig.per_world_fields` lists
them); keywords and command-line options name it flat (`prey_max_speed`, as `env.set_params` and
`--randomize` take it): `dotted_name` turns the one into the other. A per-world value is a scalar (every
world), a tuple (one value per world) or a sampler (`Uniform`, `LogUniform`, `Choice`: drawn per world).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from .agent_types import TYPES
from .checks import is_real, require

# Per-type fields that may differ between the worlds of a batch (observation slots change array sizes).
PER_WORLD_TYPE_FIELDS = (
    "max_speed",
    "max_steering_force",
    "max_acceleration",
    "mass",
    "radius",
    "view_distance",
    "fov_angle",
    "bounce_strength",
)
# World fields that may differ between worlds: none changes an array's size (live counts are at most
# the batch's capacity, the largest count).
PER_WORLD_FIELDS = (
    "prey_count",
    "predator_count",
    "prey_reward",
    "prey_capture_penalty",
    "prey_contact_penalty",
    "predator_reward",
    "catch_share_radius",
    "capture_probability",
    "capture_confusion",
    "confusion_radius",
    "capture_rule",
    "confusion_angle",
    "handling_steps",
    "predator_starvation_steps",
    "prey_replication_age",
    "flow",
)
INTEGER_FIELDS = ("prey_count", "predator_count", "handling_steps", "predator_starvation_steps", "prey_replication_age")
# Every per-world field by its flat name: the world fields, then `prey_<field>` and `predator_<field>`.
FLAT_NAMES = PER_WORLD_FIELDS + tuple(f"{t}_{n}" for t in TYPES for n in PER_WORLD_TYPE_FIELDS)


def dotted_name(flat: str) -> str:
    """The config's name of a per-world field named flat: `prey_max_speed` -> `prey.max_speed`; a world
    field keeps its name."""
    if flat not in FLAT_NAMES:
        raise ValueError(f"unknown per-world parameter {flat!r}; settable: {list(FLAT_NAMES)}")
    for t in TYPES:
        if flat.startswith(t + "_") and flat[len(t) + 1 :] in PER_WORLD_TYPE_FIELDS:
            return f"{t}.{flat[len(t) + 1 :]}"
    return flat


@dataclass(frozen=True)
class Uniform:
    """Per-world values drawn uniformly from [low, high] (integers for integer fields)."""

    low: float
    high: float

    def draw(self, rng: np.random.Generator, n: int, integer: bool) -> list:
        if integer:
            return [int(x) for x in rng.integers(int(self.low), int(self.high) + 1, size=n)]
        return [float(x) for x in rng.uniform(self.low, self.high, size=n)]

    def check(self, name: str) -> None:
        require(
            name,
            (self.low, self.high),
            is_real(self.low) and is_real(self.high) and self.low <= self.high,
            "a range of two numbers with low <= high",
        )


@dataclass(frozen=True)
class LogUniform(Uniform):
    """Per-world values whose logarithm is uniform in [log low, log high] (0 < low <= high)."""

    def draw(self, rng: np.random.Generator, n: int, integer: bool) -> list:
        values = np.exp(rng.uniform(math.log(self.low), math.log(self.high), size=n))
        return [int(round(x)) for x in values] if integer else [float(x) for x in values]

    def check(self, name: str) -> None:
        require(
            name,
            (self.low, self.high),
            is_real(self.low) and is_real(self.high) and 0 < self.low <= self.high,
            "a range of two numbers with 0 < low <= high",
        )


@dataclass(frozen=True)
class Choice:
    """Per-world values drawn uniformly from `values`."""

    values: tuple

    def draw(self, rng: np.random.Generator, n: int, integer: bool) -> list:
        return [self.values[k] for k in rng.integers(0, len(self.values), size=n)]

    def check(self, name: str) -> None:
        require(name, self.values, isinstance(self.values, tuple) and len(self.values) > 0, "a non-empty tuple")


SAMPLERS = (Uniform, LogUniform, Choice)


def per_world(value, num_worlds: int) -> list:
    """A field's values, one per world (a tuple's values, or a scalar repeated)."""
    return list(value) if isinstance(value, tuple) else [value] * num_worlds


def largest(value) -> float:
    """The largest per-world value of a field (the value itself when it is a scalar)."""
    if isinstance(value, tuple):
        return max(value)
    if isinstance(value, Choice):
        return max(value.values)
    if isinstance(value, Uniform):
        return value.high
    return value


# ---------------------------------------------------------------------------------------------- set_params
def selected_worlds(world, num_worlds: int) -> list[int]:
    """The worlds `BatchedAquarium.set_params(world=...)` names: None (every world), an index or a
    sequence of distinct indices in [0, `num_worlds`)."""
    if world is None:
        return list(range(num_worlds))
    single = isinstance(world, (int, np.integer, bool))
    indices = [world] if single else list(world) if isinstance(world, (list, tuple, range, np.ndarray)) else []
    # Repeated worlds would leave it to the order which of their values holds: refused.
    if (
        not indices
        or any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < num_worlds for k in indices)
        or len(set(map(int, indices))) < len(indices)
    ):
        raise ValueError(f"world={world!r} must be None, an integer or distinct integers in [0, {num_worlds - 1}]")
    return [int(k) for k in indices]


def merged_values(
    current: Callable[[str], object],
    num_worlds: int,
    worlds: list[int],
    fields: Mapping[str, object],
    rng: np.random.Generator,
) -> dict[str, object]:
    """`set_params`' `fields` (flat or dotted names; a scalar, one value per world of `worlds` or a
    sampler drawn from `rng`) merged into each field's `current(dotted name)` values of the other worlds:
    `{dotted name: value}`, a scalar where every world shares the value (as a config gives it), else a
    tuple of one value per world."""
    values: dict[str, object] = {}
    for key, value in fields.items():
        name = dotted_name(key)
        if isinstance(value, SAMPLERS):
            value.check(key)
            value = value.draw(rng, len(worlds), name in INTEGER_FIELDS)
        elif hasattr(value, "tolist"):
            value = value.tolist()
        given = list(value) if isinstance(value, (list, tuple)) else [value] * len(worlds)
        if len(given) != len(worlds):
            raise ValueError(f"{key} gives {len(given)} values for {len(worlds)} worlds")
        column = per_world(current(name), num_worlds)
        for k, v in zip(worlds, given):
            column[k] = v
        values[name] = column[0] if all(v == column[0] for v in column) else tuple(column)
    return values


def check_live_counts(current: Callable[[str], object], num_worlds: int, capacity: Mapping[str, int]) -> None:
    """A one-line ValueError unless every world's `<type>_count` (`current(name)`) fits its type's
    `capacity`, the batch's slots."""
    for t, limit in capacity.items():
        name = f"{t}_count"
        counts = per_world(current(name), num_worlds)
        over = [k for k, n in enumerate(counts) if n > limit]
        if over:
            raise ValueError(
                f"world {over[0]}: {name}={counts[over[0]]} is out of range: must be an integer in "
                f"[1, {limit}] (the batch's slots)"
            )
