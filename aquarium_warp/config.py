"""Frozen configuration of an Aquarium world: MODEL.md's parameters with their defaults.

`AquariumConfig` holds the world parameters and one `AgentTypeConfig` per agent type (`prey`,
`predator`). Every field is validated on construction; a bad value raises `ValueError` naming the
field and its allowed range.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

OBSERVATION_RANGES = ("0..1", "-1..1")

# Slots per observation block are unrolled in registers by the observation kernel; 16 per block is
# far beyond any setting in the paper and keeps the kernel small.
MAX_OBSERVED_SLOTS = 16


def _check(name: str, value, ok: bool, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isnan(value)


@dataclass(frozen=True)
class AgentTypeConfig:
    """Parameters of one agent type (MODEL.md, per-type table). Lengths in px, angles in degrees,
    speeds in px/step."""

    max_speed: float
    max_steering_force: float
    max_acceleration: float
    mass: float
    radius: float
    view_distance: float
    fov_angle: float
    bounce_strength: float
    predator_slots: int = 1
    prey_slots: int = 3

    def validate(self, prefix: str) -> None:
        positive = ("max_speed", "max_steering_force", "max_acceleration", "mass", "radius")
        for name in positive:
            value = getattr(self, name)
            _check(f"{prefix}.{name}", value, _is_real(value) and math.isfinite(value) and value > 0,
                   "a finite number > 0")
        v = self.view_distance
        _check(f"{prefix}.view_distance", v, _is_real(v) and v > 0, "a number > 0 (math.inf for unlimited)")
        a = self.fov_angle
        _check(f"{prefix}.fov_angle", a, _is_real(a) and 0 < a <= 360, "in (0, 360] degrees")
        b = self.bounce_strength
        _check(f"{prefix}.bounce_strength", b, _is_real(b) and math.isfinite(b) and b >= 0,
               "a finite number >= 0")
        for name in ("predator_slots", "prey_slots"):
            value = getattr(self, name)
            _check(f"{prefix}.{name}", value, _is_int(value) and 0 <= value <= MAX_OBSERVED_SLOTS,
                   f"an integer in [0, {MAX_OBSERVED_SLOTS}]")

    @property
    def observation_size(self) -> int:
        """Length of this type's observation vector: 5 + 6 * (predator_slots + prey_slots)."""
        return 5 + 6 * (self.predator_slots + self.prey_slots)


def default_prey() -> AgentTypeConfig:
    return AgentTypeConfig(max_speed=4.0, max_steering_force=0.6, max_acceleration=1.0, mass=3.0,
                           radius=20.0, view_distance=100.0, fov_angle=120.0, bounce_strength=1.0)


def default_predator() -> AgentTypeConfig:
    return AgentTypeConfig(max_speed=5.0, max_steering_force=0.6, max_acceleration=0.6, mass=10.0,
                           radius=30.0, view_distance=200.0, fov_angle=150.0, bounce_strength=0.625)


@dataclass(frozen=True)
class AquariumConfig:
    """World parameters (MODEL.md "World parameters"); defaults are marl-aquarium 0.1.10's.

    `respawn_captured_prey` is the reference's `keep_prey_count_constant`. `grid_cell_size` is a
    performance setting only (None picks one from the interaction radii); results do not depend on it.
    """

    width: float = 800.0
    height: float = 800.0
    prey_count: int = 16
    predator_count: int = 1
    action_count: int = 16
    max_steps: int = 3000
    fov_enabled: bool = True
    respawn_captured_prey: bool = True
    prey_reward: float = 1.0
    prey_capture_penalty: float = 1000.0
    predator_reward: float = 10.0
    catch_share_radius: float = 100.0
    predator_starvation_steps: int = 3000
    prey_reproduction: bool = False
    prey_replication_age: int = 200
    max_prey: int = 20
    observation_range: str = "0..1"
    prey: AgentTypeConfig = field(default_factory=default_prey)
    predator: AgentTypeConfig = field(default_factory=default_predator)
    grid_cell_size: float | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            _check(name, value, _is_real(value) and math.isfinite(value) and 40 < value <= 1e7,
                   "a finite number in (40, 1e7] px (prey spawn 20 px from the edges)")
        _check("prey_count", self.prey_count, _is_int(self.prey_count) and self.prey_count >= 1,
               "an integer >= 1")
        _check("predator_count", self.predator_count,
               _is_int(self.predator_count) and self.predator_count >= 1, "an integer >= 1")
        _check("action_count", self.action_count,
               _is_int(self.action_count) and 1 <= self.action_count <= 65536, "an integer in [1, 65536]")
        _check("max_steps", self.max_steps, _is_int(self.max_steps) and self.max_steps >= 1,
               "an integer >= 1")
        for name in ("fov_enabled", "respawn_captured_prey", "prey_reproduction"):
            value = getattr(self, name)
            _check(name, value, isinstance(value, bool), "True or False")
        for name in ("prey_reward", "prey_capture_penalty", "predator_reward"):
            value = getattr(self, name)
            _check(name, value, _is_real(value) and math.isfinite(value), "a finite number")
        _check("catch_share_radius", self.catch_share_radius,
               _is_real(self.catch_share_radius) and math.isfinite(self.catch_share_radius)
               and self.catch_share_radius >= 0, "a finite number >= 0")
        _check("predator_starvation_steps", self.predator_starvation_steps,
               _is_int(self.predator_starvation_steps) and self.predator_starvation_steps >= 0,
               "an integer >= 0")
        _check("prey_replication_age", self.prey_replication_age,
               _is_int(self.prey_replication_age) and self.prey_replication_age >= 1, "an integer >= 1")
        _check("max_prey", self.max_prey, _is_int(self.max_prey) and self.max_prey >= 1, "an integer >= 1")
        _check("observation_range", self.observation_range, self.observation_range in OBSERVATION_RANGES,
               f"one of {OBSERVATION_RANGES}")
        for name in ("prey", "predator"):
            value = getattr(self, name)
            if not isinstance(value, AgentTypeConfig):
                raise ValueError(f"{name} must be an AgentTypeConfig, got {type(value).__name__}")
            value.validate(name)
        for name in ("prey", "predator"):
            speed = getattr(self, name).max_speed
            _check(f"{name}.max_speed", speed, speed < 0.5 * min(self.width, self.height),
                   "smaller than half the world's width and height")
        if self.grid_cell_size is not None:
            g = self.grid_cell_size
            _check("grid_cell_size", g, _is_real(g) and math.isfinite(g) and g > 0,
                   "None or a finite number > 0")
        _check("capacity", self.capacity, self.capacity <= 2**30, "at most 2**30 agent slots per world")

    # Derived sizes -------------------------------------------------------------------------------
    @property
    def prey_capacity(self) -> int:
        """Prey slots per world: room for reproduction up to `max_prey` when it is on."""
        return max(self.prey_count, self.max_prey) if self.prey_reproduction else self.prey_count

    @property
    def capacity(self) -> int:
        """Agent slots per world: prey slots first, then predator slots."""
        return self.prey_capacity + self.predator_count

    @property
    def max_torus_distance(self) -> float:
        return math.hypot(self.width / 2.0, self.height / 2.0)

    def replace(self, **changes) -> "AquariumConfig":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "AquariumConfig":
        data = dict(data)
        for name in ("prey", "predator"):
            if isinstance(data.get(name), dict):
                data[name] = AgentTypeConfig(**data[name])
        return cls(**data)
