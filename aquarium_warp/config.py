"""Frozen configuration of an Aquarium world: MODEL.md's parameters with their defaults.

`AquariumConfig` holds the world parameters and one `AgentTypeConfig` per agent type (`prey`,
`predator`). Every field is validated on construction; a bad value raises `ValueError` naming the
field and its allowed range.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

OBSERVATION_RANGES = ("0..1", "-1..1")

# Slots per observation block are unrolled in registers by the observation kernel; 16 per block is
# far beyond any setting in the paper and keeps the kernel small.
MAX_OBSERVED_SLOTS = 16

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


def _check(name: str, value, ok: bool, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def _is_int(value) -> bool:
    """Python or numpy integers (not bools)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
            and not math.isnan(value))


def _in_range(value, lo: float, hi: float) -> bool:
    return _is_real(value) and lo <= value <= hi


def _normalise(obj, ints: tuple, reals: tuple, bools: tuple = ()) -> None:
    """Store numpy scalars of a frozen dataclass as Python ones (after validation), so configs compare,
    hash and serialise alike."""
    for name in ints:
        object.__setattr__(obj, name, int(getattr(obj, name)))
    for name in reals:
        value = getattr(obj, name)
        if isinstance(value, (np.integer, np.floating)):
            object.__setattr__(obj, name, float(value) if isinstance(value, np.floating) else int(value))
    for name in bools:
        object.__setattr__(obj, name, bool(getattr(obj, name)))


@dataclass(frozen=True)
class AgentTypeConfig:
    """Parameters of one agent type (MODEL.md, per-type table). Lengths in px, angles in degrees,
    speeds in px/step. Numpy scalars are accepted (and stored as Python numbers).

    Allowed ranges (float32-safe, see `SMALLEST` / `LARGEST`): `max_speed` in [1e-15, half the
    world's smaller side); `max_steering_force`, `max_acceleration`, `mass` and `radius` in
    [1e-15, 1e15], with `min(max_steering_force, 2 max_speed) / mass` (the largest steering
    acceleration) at most 1e15; `view_distance` in [1e-15, 1e15] or `math.inf` (unlimited);
    `fov_angle` in (0, 360]; `bounce_strength` 0 or in [1e-15, 1e15]; slots in [0, 16].
    """

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
        bounded = f"a finite number > 0, in [{SMALLEST:g}, {LARGEST:g}] (float32-safe)"
        for name in ("max_speed", "max_steering_force", "max_acceleration", "mass", "radius"):
            value = getattr(self, name)
            _check(f"{prefix}.{name}", value, _in_range(value, SMALLEST, LARGEST), bounded)
        steering = min(self.max_steering_force, 2.0 * self.max_speed) / self.mass
        _check(f"{prefix}.mass", self.mass, steering <= LARGEST,
               f"at least min(max_steering_force, 2 max_speed) / {LARGEST:g} = "
               f"{min(self.max_steering_force, 2.0 * self.max_speed) / LARGEST:g} (a finite number > 0: the "
               "largest steering acceleration, force / mass, must stay float32-safe)")
        v = self.view_distance
        _check(f"{prefix}.view_distance", v, _in_range(v, SMALLEST, LARGEST) or v == math.inf,
               f"a number > 0 (math.inf for unlimited): math.inf or in [{SMALLEST:g}, {LARGEST:g}]")
        a = self.fov_angle
        _check(f"{prefix}.fov_angle", a, _is_real(a) and 0 < a <= 360, "in (0, 360] degrees")
        b = self.bounce_strength
        _check(f"{prefix}.bounce_strength", b, _is_real(b) and (b == 0 or SMALLEST <= b <= LARGEST),
               f"a finite number >= 0: 0 or in [{SMALLEST:g}, {LARGEST:g}] (float32-safe)")
        for name in ("predator_slots", "prey_slots"):
            value = getattr(self, name)
            _check(f"{prefix}.{name}", value, _is_int(value) and 0 <= value <= MAX_OBSERVED_SLOTS,
                   f"an integer in [0, {MAX_OBSERVED_SLOTS}]")
        _normalise(self, ("predator_slots", "prey_slots"),
                   ("max_speed", "max_steering_force", "max_acceleration", "mass", "radius", "view_distance",
                    "fov_angle", "bounce_strength"))

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
    Numpy scalars are accepted (and stored as Python numbers).

    Allowed ranges: `width`, `height` in (40, 1e7] px; counts (and `max_prey`) integers >= 1 with at
    most 2**30 agent slots per world; `action_count` in [1, 65536]; `max_steps` in [1, 2**31 - 1] and
    `predator_starvation_steps` in [0, 2**31 - 2] (int32 counters on the device);
    `prey_replication_age` in [1, 1717986917] (its 1.25x drawn ages must fit in int32);
    `catch_share_radius` 0 or in [1e-15, 1e15]; the three rewards finite with
    |reward| x max_steps x prey slots at most 1e38, so that episode returns (float32 sums over an
    episode) stay finite; `grid_cell_size` None or a finite number > 0. Per-type ranges: see
    `AgentTypeConfig`.
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
        _check("max_steps", self.max_steps, _is_int(self.max_steps) and 1 <= self.max_steps <= INT32_MAX,
               "an integer >= 1 and <= 2**31 - 1 (an int32 step counter)")
        for name in ("fov_enabled", "respawn_captured_prey", "prey_reproduction"):
            value = getattr(self, name)
            _check(name, value, isinstance(value, (bool, np.bool_)), "True or False")
        _check("catch_share_radius", self.catch_share_radius,
               _is_real(self.catch_share_radius) and (self.catch_share_radius == 0
                                                     or SMALLEST <= self.catch_share_radius <= LARGEST),
               f"a finite number >= 0: 0 or in [{SMALLEST:g}, {LARGEST:g}] px (float32-safe)")
        # A starving predator's counter reaches predator_starvation_steps + 1 (int32).
        _check("predator_starvation_steps", self.predator_starvation_steps,
               _is_int(self.predator_starvation_steps) and 0 <= self.predator_starvation_steps <= INT32_MAX - 1,
               "an integer >= 0 and <= 2**31 - 2 (an int32 counter)")
        # Replication ages are drawn up to floor(1.25 R), and the draw's exclusive bound, one more, is
        # int32: the largest R with floor(5 R / 4) + 1 <= 2**31 - 1.
        max_replication_age = (4 * INT32_MAX - 1) // 5
        _check("prey_replication_age", self.prey_replication_age,
               _is_int(self.prey_replication_age) and 1 <= self.prey_replication_age <= max_replication_age,
               f"an integer >= 1 and <= {max_replication_age} (its 1.25x drawn ages are int32)")
        # Unused without reproduction, but still an int32 kernel parameter.
        _check("max_prey", self.max_prey, _is_int(self.max_prey) and 1 <= self.max_prey <= 2**30,
               "an integer >= 1 and <= 2**30 (the agent slots' limit)")
        _check("observation_range", self.observation_range,
               isinstance(self.observation_range, str) and self.observation_range in OBSERVATION_RANGES,
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
        _check("capacity", self.capacity, self.capacity <= 2**30,
               "at most 2**30 agent slots per world: prey_count (with reproduction max(prey_count, max_prey)) "
               "+ predator_count")
        reward_limit = RETURN_LIMIT / (self.max_steps * self.prey_capacity)
        for name in ("prey_reward", "prey_capture_penalty", "predator_reward"):
            value = getattr(self, name)
            _check(name, value, _is_real(value) and math.isfinite(value) and abs(value) <= reward_limit,
                   f"a finite number with |{name}| <= 1e38 / (max_steps x prey slots) = {reward_limit:.3g} "
                   "(episode returns are float32 sums)")
        _normalise(self, ("prey_count", "predator_count", "action_count", "max_steps", "predator_starvation_steps",
                          "prey_replication_age", "max_prey"),
                   ("width", "height", "prey_reward", "prey_capture_penalty", "predator_reward", "catch_share_radius",
                    "grid_cell_size"),
                   ("fov_enabled", "respawn_captured_prey", "prey_reproduction"))

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
        """The config of `to_dict()`'s form; unknown keys are refused by name (ValueError)."""
        if not isinstance(data, dict):
            raise ValueError(f"an AquariumConfig dict must be a dict, got {type(data).__name__}")
        data = dict(data)
        _check_keys(data, cls, "")
        for name in ("prey", "predator"):
            if isinstance(data.get(name), dict):
                _check_keys(data[name], AgentTypeConfig, f"{name}.")
                data[name] = AgentTypeConfig(**data[name])
        return cls(**data)


def _check_keys(data: dict, cls, prefix: str) -> None:
    known = [f.name for f in dataclasses.fields(cls)]
    unknown = [f"{prefix}{k}" for k in data if k not in known]
    if unknown:
        raise ValueError(f"unknown config fields {unknown}; known {prefix[:-1] or 'world'} fields: {known}")
