"""Frozen configuration of an Aquarium world: docs/model.md's parameters with their defaults.

`AquariumConfig` holds the world parameters and one `AgentTypeConfig` per agent type (`prey`,
`predator`). Every field is validated on construction; a bad value raises `ValueError` naming the
field and its allowed range.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .agent_types import TYPES
from .checks import INT32_MAX, LARGEST, MAX_HANDLING_STEPS, RETURN_LIMIT, SMALLEST, is_int, is_real, require
from .per_world import INTEGER_FIELDS, PER_WORLD_FIELDS, PER_WORLD_TYPE_FIELDS, SAMPLERS, Choice, Uniform, largest
from .seeding import config_stream

OBSERVATION_RANGES = ("0..1", "-1..1")
FRAMES = ("world", "ego")
SPAWN_HEADINGS = ("paper", "random")
CAPTURE_RULES = ("dilution", "confusion")

# Slots per observation block are unrolled in registers by the observation kernel; 16 per block is
# far beyond any setting in the paper and keeps the kernel small.
MAX_OBSERVED_SLOTS = 16


def _in_range(value, lo: float, hi: float) -> bool:
    return is_real(value) and lo <= value <= hi


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


def _per_world_value(name: str, value):
    """A per-world value (sequence, array, tensor) as a tuple of Python scalars, a sampler as is, a
    scalar as is."""
    if isinstance(value, SAMPLERS):
        value.check(name)
        return value
    if isinstance(value, FlowConfig) or isinstance(value, (str, bytes, dict)):
        return value
    if hasattr(value, "tolist") and not isinstance(value, (np.integer, np.floating, np.bool_)):
        value = value.tolist()  # numpy arrays and torch tensors
    if isinstance(value, (list, tuple)):
        require(name, value, len(value) >= 1, "a scalar or a non-empty sequence of one value per world")
        # A world's flow given as a dict becomes its FlowConfig here, so the stored tuple holds configs.
        return tuple(
            v
            if isinstance(v, FlowConfig)
            else _flow_from_dict(v, f"{name}[{k}].")
            if isinstance(v, dict) and name == "flow"
            else (v.item() if hasattr(v, "item") else v)
            for k, v in enumerate(value)
        )
    return value


def _world_value(value, world: int):
    return value[world] if isinstance(value, tuple) else value


@dataclass(frozen=True)
class FlowConfig:
    """A current that carries the agents (docs/model.md "Flow fields"), in px per step.

    `kind`: "none" (default: no current), "uniform" (`velocity` = (c_x, c_y)), "vortex" (a Rankine
    vortex at `centre` with `strength` w px/step at the core's edge, `core_radius` r_c px; positive
    w turns clockwise on screen) or "grid" (`grid`: nested sequences `[rows][cols][2]` of currents at
    cell centres, bilinear, torus-wrapped). Any kind varies in time as (1 + `amplitude` sin(2 pi t /
    `period`)), `amplitude` >= 0 (0: steady), `period` > 0 steps.
    """

    kind: str = "none"
    velocity: tuple = (0.0, 0.0)
    centre: tuple = (400.0, 400.0)
    strength: float = 0.0
    core_radius: float = 100.0
    grid: tuple | None = None
    amplitude: float = 0.0
    period: float = 1000.0

    def __post_init__(self) -> None:
        require("flow.kind", self.kind, self.kind in FLOW_KINDS, f"one of {FLOW_KINDS}")
        for name in ("velocity", "centre"):
            value = getattr(self, name)
            if hasattr(value, "tolist"):
                value = value.tolist()
            ok = (
                isinstance(value, (list, tuple))
                and len(value) == 2
                and all(is_real(v) and abs(v) <= LARGEST for v in value)
            )
            require(f"flow.{name}", value, ok, f"two finite numbers (x, y) with |x|, |y| <= {LARGEST:g}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        require(
            "flow.strength",
            self.strength,
            _in_range(self.strength, -LARGEST, LARGEST),
            f"a finite number in [-{LARGEST:g}, {LARGEST:g}] px/step",
        )
        require(
            "flow.core_radius",
            self.core_radius,
            _in_range(self.core_radius, SMALLEST, LARGEST),
            f"a finite number > 0, in [{SMALLEST:g}, {LARGEST:g}] px",
        )
        require(
            "flow.amplitude",
            self.amplitude,
            _in_range(self.amplitude, 0.0, LARGEST),
            f"a finite number >= 0 (at most {LARGEST:g})",
        )
        require(
            "flow.period",
            self.period,
            _in_range(self.period, SMALLEST, LARGEST),
            f"a finite number > 0 steps, in [{SMALLEST:g}, {LARGEST:g}]",
        )
        if self.kind == "grid" or self.grid is not None:
            try:
                grid = np.asarray(self.grid if self.grid is not None else [], dtype=np.float64)
            except (TypeError, ValueError):  # ragged rows or cells, or entries that are no numbers
                require(
                    "flow.grid",
                    self.grid,
                    False,
                    "an array [rows, cols, 2] (rows, cols >= 1) of currents at "
                    "cell centres: every row as long, every cell two numbers",
                )
            require(
                "flow.grid",
                "an array of shape " + str(list(grid.shape)),
                grid.ndim == 3 and grid.shape[0] >= 1 and grid.shape[1] >= 1 and grid.shape[2] == 2,
                "an array [rows, cols, 2] (rows, cols >= 1) of currents at cell centres",
            )
            bad = ~(np.isfinite(grid) & (np.abs(grid) <= LARGEST))
            if bad.any():
                i, j, k = (int(x) for x in np.argwhere(bad)[0])
                require(
                    f"flow.grid[{i}, {j}, {k}]",
                    float(grid[i, j, k]),
                    False,
                    f"a finite number with |value| <= {LARGEST:g} px/step",
                )
            object.__setattr__(
                self, "grid", tuple(tuple(tuple(float(c) for c in cell) for cell in row) for row in grid)
            )
        _normalise(self, (), ("strength", "core_radius", "amplitude", "period"))
        for name in ("strength", "core_radius", "amplitude", "period"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def reach(self) -> float:
        """The largest length of the current anywhere, at any time (px/step): bounds an agent's drift."""
        if self.kind == "uniform":
            base = math.hypot(*self.velocity)
        elif self.kind == "vortex":
            base = abs(self.strength)
        elif self.kind == "grid":
            base = float(np.max(np.hypot(*np.moveaxis(np.asarray(self.grid), -1, 0))))
        else:
            return 0.0
        return base * (1.0 + self.amplitude)


FLOW_KINDS = ("none", "uniform", "vortex", "grid")


@dataclass(frozen=True)
class AgentTypeConfig:
    """Parameters of one agent type (docs/model.md, per-type table). Lengths in px, angles in degrees,
    speeds in px/step. Numpy scalars are accepted (and stored as Python numbers).

    Allowed ranges (float32-safe, see `checks.SMALLEST` / `checks.LARGEST`): `max_speed` in [1e-15, half the
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
        for name in PER_WORLD_TYPE_FIELDS:
            object.__setattr__(self, name, _per_world_value(f"{prefix}.{name}", getattr(self, name)))
        if self.per_world_fields:  # AquariumConfig checks them world by world
            self._validate_slots(prefix)
            return
        bounded = f"a finite number > 0, in [{SMALLEST:g}, {LARGEST:g}] (float32-safe)"
        for name in ("max_speed", "max_steering_force", "max_acceleration", "mass", "radius"):
            value = getattr(self, name)
            require(f"{prefix}.{name}", value, _in_range(value, SMALLEST, LARGEST), bounded)
        steering = min(self.max_steering_force, 2.0 * self.max_speed) / self.mass
        require(
            f"{prefix}.mass",
            self.mass,
            steering <= LARGEST,
            f"at least min(max_steering_force, 2 max_speed) / {LARGEST:g} = "
            f"{min(self.max_steering_force, 2.0 * self.max_speed) / LARGEST:g} (a finite number > 0: the "
            "largest steering acceleration, force / mass, must stay float32-safe)",
        )
        v = self.view_distance
        require(
            f"{prefix}.view_distance",
            v,
            _in_range(v, SMALLEST, LARGEST) or v == math.inf,
            f"a number > 0 (math.inf for unlimited): math.inf or in [{SMALLEST:g}, {LARGEST:g}]",
        )
        a = self.fov_angle
        require(f"{prefix}.fov_angle", a, is_real(a) and 0 < a <= 360, "in (0, 360] degrees")
        b = self.bounce_strength
        require(
            f"{prefix}.bounce_strength",
            b,
            is_real(b) and (b == 0 or SMALLEST <= b <= LARGEST),
            f"a finite number >= 0: 0 or in [{SMALLEST:g}, {LARGEST:g}] (float32-safe)",
        )
        self._validate_slots(prefix)
        _normalise(self, (), PER_WORLD_TYPE_FIELDS)

    def _validate_slots(self, prefix: str) -> None:
        for name in ("predator_slots", "prey_slots"):
            value = getattr(self, name)
            require(
                f"{prefix}.{name}",
                value,
                is_int(value) and 0 <= value <= MAX_OBSERVED_SLOTS,
                f"an integer in [0, {MAX_OBSERVED_SLOTS}]",
            )
        if self.predator_slots == 0 and self.prey_slots == 0:  # the observation kernels need a neighbour slot
            raise ValueError(
                f"{prefix}.predator_slots=0 and {prefix}.prey_slots=0: an observation needs at least "
                "one neighbour slot (set either to 1 or more)"
            )
        _normalise(self, ("predator_slots", "prey_slots"), ())

    @property
    def per_world_fields(self) -> tuple[str, ...]:
        """Names of the fields given per world (a tuple of values or a sampler)."""
        return tuple(n for n in PER_WORLD_TYPE_FIELDS if isinstance(getattr(self, n), (tuple,) + SAMPLERS))

    @property
    def observation_size(self) -> int:
        """Length of this type's observation vector in the world frame without flow values:
        5 + 6 * (predator_slots + prey_slots) (`AquariumConfig.observation_size` gives every layout's)."""
        return 5 + 6 * (self.predator_slots + self.prey_slots)


def default_prey() -> AgentTypeConfig:
    return AgentTypeConfig(
        max_speed=4.0,
        max_steering_force=0.6,
        max_acceleration=1.0,
        mass=3.0,
        radius=20.0,
        view_distance=100.0,
        fov_angle=120.0,
        bounce_strength=1.0,
    )


def default_predator() -> AgentTypeConfig:
    return AgentTypeConfig(
        max_speed=5.0,
        max_steering_force=0.6,
        max_acceleration=0.6,
        mass=10.0,
        radius=30.0,
        view_distance=200.0,
        fov_angle=150.0,
        bounce_strength=0.625,
    )


@dataclass(frozen=True)
class AquariumConfig:
    """World parameters (docs/model.md "World parameters"); defaults are marl-aquarium 0.1.10's.

    `respawn_captured_prey` is the reference's `keep_prey_count_constant`. `grid_cell_size` is a
    performance setting only (None picks one from the interaction radii); results do not depend on it.
    Numpy scalars are accepted (and stored as Python numbers).

    Allowed ranges: `width`, `height` in (40, 1e7] px; counts (and `max_prey`) integers >= 1 with at
    most 2**30 agent slots per world; `action_count` in [1, 65536]; `max_steps` in [1, 2**31 - 1] and
    `predator_starvation_steps` in [0, 2**31 - 2] (int32 counters on the device);
    `prey_replication_age` in [1, 1717986917] (its 1.25x drawn ages must fit in int32);
    `catch_share_radius` 0 or in [1e-15, 1e15]; the capture rule (docs/model.md step 5)
    `capture_rule` "dilution" (density dilution: a contact captures with probability
    `capture_probability / (1 + capture_confusion k)`, k the other prey within `confusion_radius` of
    the prey) or "confusion" (predator confusion: each predator attacks the nearest prey it overlaps,
    captured with that probability for k the other prey it sees within `confusion_angle` of its
    target's bearing, and after a failed attack cannot attack for `handling_steps` steps), with
    `capture_probability` in [0, 1], `capture_confusion` (the rule's strength c) in [0, 1e15],
    `confusion_radius` in [1e-15, 1e15] px, `confusion_angle` in (0, 180] degrees and `handling_steps`
    an integer in [0, 1e6]; the rewards (`prey_reward`, `prey_capture_penalty`, `prey_contact_penalty`:
    a live prey's cost of each step it is in contact with a predator without being captured, and
    `predator_reward`) finite with
    |reward| x max_steps x prey slots at most 1e38, so that episode returns (float32 sums over an
    episode) stay finite; `grid_cell_size` None or a finite number > 0. Per-type ranges: see
    `AgentTypeConfig`.

    Frames and spawn (docs/model.md "Egocentric observations and actions"; the defaults are the paper's):
    `observation_frame` "world" (own position, world heading and bearings, neighbours' absolute
    positions) or "ego" (no torus coordinates and no world angles: per slot a present flag, distance,
    bearing and relative velocity in the observer's forward/right frame, angles as unit vectors);
    `action_frame` "world" (action a steers to the world direction 360 a / n degrees clockwise from up)
    or "ego" (the same angle clockwise from the agent's own heading; heuristics pick actions in this
    frame too); `spawn_heading` "paper" (prey west, predators north) or "random" (a uniform heading per
    fresh agent: episode start, respawn and birth).
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
    prey_contact_penalty: float = 0.0
    predator_reward: float = 10.0
    catch_share_radius: float = 100.0
    capture_probability: float = 1.0
    capture_confusion: float = 0.0
    confusion_radius: float = 100.0
    capture_rule: str = "dilution"
    confusion_angle: float = 15.0
    handling_steps: int = 10
    predator_starvation_steps: int = 3000
    prey_reproduction: bool = False
    prey_replication_age: int = 200
    max_prey: int = 20
    observation_range: str = "0..1"
    prey: AgentTypeConfig = field(default_factory=default_prey)
    predator: AgentTypeConfig = field(default_factory=default_predator)
    grid_cell_size: float | None = None
    flow: FlowConfig = field(default_factory=FlowConfig)
    observe_flow: bool = False
    observation_frame: str = "world"
    action_frame: str = "world"
    spawn_heading: str = "paper"

    def __post_init__(self) -> None:
        for name in PER_WORLD_FIELDS:
            object.__setattr__(self, name, _per_world_value(name, getattr(self, name)))
        if isinstance(self.flow, dict):
            object.__setattr__(self, "flow", _flow_from_dict(self.flow, "flow."))
        for name in TYPES:
            value = getattr(self, name)
            if not isinstance(value, AgentTypeConfig):
                raise ValueError(f"{name} must be an AgentTypeConfig, got {type(value).__name__}")
            value.validate(name)
        if self.per_world_fields:
            self._validate_worlds()
            return
        self._validate_scalars()

    @property
    def per_world_fields(self) -> tuple[str, ...]:
        """Names of the fields given per world (`prey.max_speed` for a type's), as tuples or samplers."""
        own = tuple(n for n in PER_WORLD_FIELDS if isinstance(getattr(self, n), (tuple,) + SAMPLERS))
        return own + tuple(f"{t}.{n}" for t in TYPES for n in getattr(self, t).per_world_fields)

    def _field(self, name: str):
        owner, _, leaf = name.rpartition(".")
        return getattr(getattr(self, owner) if owner else self, leaf)

    @property
    def num_worlds(self) -> int | None:
        """The number of worlds the per-world tuples are given for (None: none is a tuple)."""
        lengths = {len(self._field(n)) for n in self.per_world_fields if isinstance(self._field(n), tuple)}
        return lengths.pop() if len(lengths) == 1 else None

    @property
    def has_samplers(self) -> bool:
        return any(isinstance(self._field(n), SAMPLERS) for n in self.per_world_fields)

    def with_values(self, values: dict, validate: bool = True) -> AquariumConfig:
        """A copy with fields (names as in `per_world_fields`) set to `values` (validated again, unless
        `validate=False`: for values known to be valid, such as draws from a range checked once, since
        the checks cost about 70 us per world)."""
        replace = dataclasses.replace if validate else _replace_unchecked
        world = {n: v for n, v in values.items() if "." not in n}
        for t in TYPES:
            own = {n.split(".", 1)[1]: v for n, v in values.items() if n.startswith(t + ".")}
            if own:
                world[t] = replace(getattr(self, t), **own)
        return replace(self, **world)

    @classmethod
    def stack(cls, configs: list[AquariumConfig], worlds: int) -> AquariumConfig:
        """The config of `len(configs)` equal groups of `worlds` worlds, group k with the values of
        `configs[k]` (samplers drawn first: `draw`). The configs may differ only in what may differ per
        world; a one-line ValueError names the first other difference."""
        names = PER_WORLD_FIELDS + tuple(f"{t}.{n}" for t in TYPES for n in PER_WORLD_TYPE_FIELDS)
        base = configs[0]
        if any(c.has_samplers for c in configs):
            raise ValueError("stack: draw the configs' samplers first (AquariumConfig.draw)")
        fixed = base.to_dict()
        for k, config in enumerate(configs):
            other = config.with_values({n: base._field(n) for n in names}, validate=False).to_dict()
            for key in fixed:
                if other[key] != fixed[key]:
                    raise ValueError(
                        f"env configs 0 and {k} differ in {key} ({fixed[key]!r} and {other[key]!r}), which "
                        "cannot differ between the worlds of one batch"
                    )
        values = {}
        for name in names:
            each = [config._field(name) for config in configs]
            if any(isinstance(v, tuple) for v in each) or len({repr(v) for v in each}) > 1:
                values[name] = tuple(x for v in each for x in (v if isinstance(v, tuple) else (v,) * worlds))
        return base.with_values(values) if values else base

    def world(self, index: int) -> AquariumConfig:
        """The config of world `index` alone: every per-world tuple replaced by its value there."""
        if self.has_samplers:
            raise ValueError("a config with samplers has no world values yet: draw them first (`draw`)")
        return self.with_values({n: _world_value(self._field(n), index) for n in self.per_world_fields})

    def draw(self, num_worlds: int, seed: int | tuple[int, ...] = 0) -> AquariumConfig:
        """A copy whose samplers are replaced by `num_worlds` drawn values (`seeding.config_stream(seed)`,
        fields in `per_world_fields` order). A tuple of K seeds draws each of K equal groups of worlds
        from its own seed, as a batch of `num_worlds / K` worlds with that seed draws (`seeding.seed_groups`)."""
        seeds = seed if isinstance(seed, tuple) else (seed,)
        group = num_worlds // len(seeds)
        values: dict[str, tuple] = {}
        for s in seeds:
            rng = config_stream(s)
            for name in self.per_world_fields:
                value = self._field(name)
                if isinstance(value, SAMPLERS):
                    values[name] = values.get(name, ()) + tuple(value.draw(rng, group, name in INTEGER_FIELDS))
        return self.with_values(values) if values else self

    def _validate_worlds(self) -> None:
        """Every world's values obey the scalar ranges (checked on the config of each distinct world;
        a sampler's on its ends, or each choice); an error names the field and the world."""
        names = self.per_world_fields
        lengths = {n: len(self._field(n)) for n in names if isinstance(self._field(n), tuple)}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"per-world fields must give one value per world, the same number for all: {lengths}")
        n = next(iter(lengths.values()), 1)
        seen = set()
        for k in range(n):
            row = {name: _world_value(self._field(name), k) for name in names}
            samplers = [name for name, v in row.items() if isinstance(v, SAMPLERS)]
            variants = [row]
            for name in samplers:  # a sampler's ends (or every choice), the other samplers at their first
                ends = row[name].values if isinstance(row[name], Choice) else (row[name].low, row[name].high)
                base = {
                    m: (row[m].values[0] if isinstance(row[m], Choice) else row[m].low) if m in samplers else row[m]
                    for m in names
                }
                variants += [base | {name: end} for end in ends]
            for variant in variants[1:] if samplers else variants:
                key = tuple(repr(variant[name]) for name in names)
                if key in seen:
                    continue
                seen.add(key)
                try:
                    self.with_values(variant)
                except ValueError as error:
                    where = f"world {k}" if lengths else "a sampler's range"
                    raise ValueError(f"{where}: {error}") from None
        # What the batch shares: the slot count and the episode returns' float32 range.
        require("capacity", self.capacity, self.capacity <= 2**30, "at most 2**30 agent slots per world")
        reward_limit = RETURN_LIMIT / (self.max_steps * self.prey_capacity)
        for name in ("prey_reward", "prey_capture_penalty", "prey_contact_penalty", "predator_reward"):
            value = self._field(name)
            extremes = (
                value
                if isinstance(value, tuple)
                else (
                    (value.low, value.high)
                    if isinstance(value, Uniform)
                    else value.values
                    if isinstance(value, Choice)
                    else (value,)
                )
            )
            worst = max(abs(v) for v in extremes)
            require(
                name,
                worst,
                worst <= reward_limit,
                f"|{name}| <= 1e38 / (max_steps x the batch's prey slots) = {reward_limit:.3g} in every world",
            )

    def _validate_scalars(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            require(
                name,
                value,
                is_real(value) and math.isfinite(value) and 40 < value <= 1e7,
                "a finite number in (40, 1e7] px (prey spawn 20 px from the edges)",
            )
        require("prey_count", self.prey_count, is_int(self.prey_count) and self.prey_count >= 1, "an integer >= 1")
        require(
            "predator_count",
            self.predator_count,
            is_int(self.predator_count) and self.predator_count >= 1,
            "an integer >= 1",
        )
        require(
            "action_count",
            self.action_count,
            is_int(self.action_count) and 1 <= self.action_count <= 65536,
            "an integer in [1, 65536]",
        )
        require(
            "max_steps",
            self.max_steps,
            is_int(self.max_steps) and 1 <= self.max_steps <= INT32_MAX,
            "an integer >= 1 and <= 2**31 - 1 (an int32 step counter)",
        )
        for name in ("fov_enabled", "respawn_captured_prey", "prey_reproduction"):
            value = getattr(self, name)
            require(name, value, isinstance(value, (bool, np.bool_)), "True or False")
        require(
            "catch_share_radius",
            self.catch_share_radius,
            is_real(self.catch_share_radius)
            and (self.catch_share_radius == 0 or SMALLEST <= self.catch_share_radius <= LARGEST),
            f"a finite number >= 0: 0 or in [{SMALLEST:g}, {LARGEST:g}] px (float32-safe)",
        )
        require(
            "capture_probability",
            self.capture_probability,
            _in_range(self.capture_probability, 0.0, 1.0),
            "a number in [0, 1] (the chance that a contact, or an attack, captures a lone prey)",
        )
        require(
            "capture_confusion",
            self.capture_confusion,
            _in_range(self.capture_confusion, 0.0, LARGEST),
            f"a finite number >= 0, in [0, {LARGEST:g}] (the capture rule's strength; 0: none)",
        )
        require(
            "confusion_radius",
            self.confusion_radius,
            _in_range(self.confusion_radius, SMALLEST, LARGEST),
            f"a finite number > 0, in [{SMALLEST:g}, {LARGEST:g}] px (float32-safe)",
        )
        require("capture_rule", self.capture_rule, self.capture_rule in CAPTURE_RULES, f"one of {CAPTURE_RULES}")
        require(
            "confusion_angle",
            self.confusion_angle,
            is_real(self.confusion_angle) and 0 < self.confusion_angle <= 180,
            "in (0, 180] degrees (the half-width of the window around the target's bearing)",
        )
        require(
            "handling_steps",
            self.handling_steps,
            is_int(self.handling_steps) and 0 <= self.handling_steps <= MAX_HANDLING_STEPS,
            f"an integer in [0, {MAX_HANDLING_STEPS}] (steps a predator cannot attack after a failed attack)",
        )
        # A starving predator's counter reaches predator_starvation_steps + 1 (int32).
        require(
            "predator_starvation_steps",
            self.predator_starvation_steps,
            is_int(self.predator_starvation_steps) and 0 <= self.predator_starvation_steps <= INT32_MAX - 1,
            "an integer >= 0 and <= 2**31 - 2 (an int32 counter)",
        )
        # Replication ages are drawn up to floor(1.25 R), and the draw's exclusive bound, one more, is
        # int32: the largest R with floor(5 R / 4) + 1 <= 2**31 - 1.
        max_replication_age = (4 * INT32_MAX - 1) // 5
        require(
            "prey_replication_age",
            self.prey_replication_age,
            is_int(self.prey_replication_age) and 1 <= self.prey_replication_age <= max_replication_age,
            f"an integer >= 1 and <= {max_replication_age} (its 1.25x drawn ages are int32)",
        )
        # Unused without reproduction, but still an int32 kernel parameter.
        require(
            "max_prey",
            self.max_prey,
            is_int(self.max_prey) and 1 <= self.max_prey <= 2**30,
            "an integer >= 1 and <= 2**30 (the agent slots' limit)",
        )
        require(
            "observation_range",
            self.observation_range,
            isinstance(self.observation_range, str) and self.observation_range in OBSERVATION_RANGES,
            f"one of {OBSERVATION_RANGES}",
        )
        if not isinstance(self.flow, FlowConfig):
            raise ValueError(f"flow must be a FlowConfig (or its dict), got {type(self.flow).__name__}")
        require("observe_flow", self.observe_flow, isinstance(self.observe_flow, (bool, np.bool_)), "True or False")
        for name, allowed in (
            ("observation_frame", FRAMES),
            ("action_frame", FRAMES),
            ("spawn_heading", SPAWN_HEADINGS),
        ):
            value = getattr(self, name)
            require(name, value, isinstance(value, str) and value in allowed, f"one of {allowed}")
        # One move (speed plus drift) stays shorter than half the world, so a wrap is one add or subtract.
        drift = self.flow.reach
        for name in TYPES:
            speed = getattr(self, name).max_speed
            require(
                f"{name}.max_speed",
                speed,
                speed + drift < 0.5 * min(self.width, self.height),
                "smaller than half the world's width and height"
                + (f" less the flow's largest current {drift:g}" if drift else ""),
            )
        if self.grid_cell_size is not None:
            g = self.grid_cell_size
            require("grid_cell_size", g, is_real(g) and math.isfinite(g) and g > 0, "None or a finite number > 0")
        require(
            "capacity",
            self.capacity,
            self.capacity <= 2**30,
            "at most 2**30 agent slots per world: prey_count (with reproduction max(prey_count, max_prey)) "
            "+ predator_count",
        )
        reward_limit = RETURN_LIMIT / (self.max_steps * self.prey_capacity)
        for name in ("prey_reward", "prey_capture_penalty", "prey_contact_penalty", "predator_reward"):
            value = getattr(self, name)
            require(
                name,
                value,
                is_real(value) and math.isfinite(value) and abs(value) <= reward_limit,
                f"a finite number with |{name}| <= 1e38 / (max_steps x prey slots) = {reward_limit:.3g} "
                "(episode returns are float32 sums)",
            )
        _normalise(
            self,
            (*INTEGER_FIELDS, "action_count", "max_steps", "max_prey"),
            # the per-world fields that are numbers and not integers (the flow is a record, the rule a word)
            (
                "width",
                "height",
                *(n for n in PER_WORLD_FIELDS if n not in (*INTEGER_FIELDS, "flow", "capture_rule")),
                "grid_cell_size",
            ),
            ("fov_enabled", "respawn_captured_prey", "prey_reproduction", "observe_flow"),
        )

    # Derived sizes -------------------------------------------------------------------------------
    @property
    def prey_capacity(self) -> int:
        """Prey slots per world: room for reproduction up to `max_prey` when it is on."""
        prey = int(largest(self.prey_count))
        return max(prey, self.max_prey) if self.prey_reproduction else prey

    @property
    def predator_capacity(self) -> int:
        """Predator slots per world: the largest per-world predator count."""
        return int(largest(self.predator_count))

    @property
    def capacity(self) -> int:
        """Agent slots per world: prey slots first, then predator slots."""
        return self.prey_capacity + self.predator_capacity

    @property
    def observation_layout(self) -> str:
        """The observation row's layout (docs/model.md "Observations"): "world" (the paper's), "ego" (egocentric
        observations for ego actions) or "ego+heading" (egocentric, plus the own world heading that
        world actions need)."""
        if self.observation_frame == "world":
            return "world"
        return "ego" if self.action_frame == "ego" else "ego+heading"

    def observation_size(self, agent_type: str) -> int:
        """Length of the observation vector of `agent_type` ("prey" or "predator"): the own block (5 values
        in the world frame; in the ego frame 2, or 4 with world actions), 2 flow values with
        `observe_flow`, then 6 per observed slot."""
        from .kernels.observation import OWN_SIZES  # the layout the kernel writes (imported where used)

        own = OWN_SIZES[self.observation_layout]
        t = getattr(self, agent_type)
        return own + 2 * int(self.observe_flow) + 6 * (t.predator_slots + t.prey_slots)

    def neighbour_columns(self, agent_type: str, of_type: str) -> slice:
        """The columns of `agent_type`'s observation row that hold its observed `of_type` agents (6 per
        slot; predator slots come first), in every layout."""
        t = getattr(self, agent_type)
        own = self.observation_size(agent_type) - 6 * (t.predator_slots + t.prey_slots)
        if of_type == "predator":
            return slice(own, own + 6 * t.predator_slots)
        start = own + 6 * t.predator_slots
        return slice(start, start + 6 * t.prey_slots)

    @property
    def max_torus_distance(self) -> float:
        return math.hypot(self.width / 2.0, self.height / 2.0)

    def replace(self, **changes) -> AquariumConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def with_interface_of(self, other: AquariumConfig) -> AquariumConfig:
        """A copy whose agents observe and act as in `other` (the world a trained policy was trained in):
        its observation and action frames, observation range, flow observation and per-type slot counts;
        the world itself (sizes, counts, perception, spawn) stays this one's."""
        slots = ("predator_slots", "prey_slots")
        return self.replace(
            observation_frame=other.observation_frame,
            action_frame=other.action_frame,
            observation_range=other.observation_range,
            observe_flow=other.observe_flow,
            prey=dataclasses.replace(self.prey, **{n: getattr(other.prey, n) for n in slots}),
            predator=dataclasses.replace(self.predator, **{n: getattr(other.predator, n) for n in slots}),
        )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> AquariumConfig:
        """The config of `to_dict()`'s form; unknown keys are refused by name (ValueError)."""
        if not isinstance(data, dict):
            raise ValueError(f"an AquariumConfig dict must be a dict, got {type(data).__name__}")
        data = dict(data)
        _check_keys(data, cls, "")
        for name in TYPES:
            if isinstance(data.get(name), dict):
                _check_keys(data[name], AgentTypeConfig, f"{name}.")
                data[name] = AgentTypeConfig(**data[name])
        return cls(**data)  # a flow dict, or per-world flow dicts, become FlowConfigs there


def _replace_unchecked(obj, **changes):
    """`dataclasses.replace` without `__post_init__` (no checks, no normalisation)."""
    new = copy.copy(obj)
    for name, value in changes.items():
        object.__setattr__(new, name, value)
    return new


def _flow_from_dict(data: dict, prefix: str) -> FlowConfig:
    """A `FlowConfig` from a dict of its fields (unknown keys refused with their names)."""
    _check_keys(data, FlowConfig, prefix)
    return FlowConfig(**data)


def _check_keys(data: dict, cls, prefix: str) -> None:
    known = [f.name for f in dataclasses.fields(cls)]
    unknown = [f"{prefix}{k}" for k in data if k not in known]
    if unknown:
        raise ValueError(f"unknown config fields {unknown}; known {prefix[:-1] or 'world'} fields: {known}")
