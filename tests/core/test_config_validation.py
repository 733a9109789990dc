"""Validation of `AquariumConfig`, `AgentTypeConfig` (through the world config) and `BatchedAquarium`'s own
arguments: every bad value is refused with a `ValueError` that names the field (per-type fields as
"prey.radius" / "predator.radius") and states the allowed range; valid edge values are accepted."""

from __future__ import annotations

import dataclasses
import math
import re
import resource
import time

import numpy as np
import pytest
import torch

from aquarium_warp import AgentTypeConfig, AquariumConfig, BatchedAquarium
from aquarium_warp.config import MAX_OBSERVED_SLOTS, default_predator, default_prey

NAN = math.nan
INF = math.inf


def build(field: str, value, **others) -> AquariumConfig:
    """An AquariumConfig with `field` set to `value`; "prey.x" / "predator.x" set a per-type field."""
    if "." in field:
        kind, name = field.split(".")
        base = default_prey() if kind == "prey" else default_predator()
        # dataclasses.replace does not validate an AgentTypeConfig: the world config does.
        others[kind] = dataclasses.replace(base, **{name: value})
        return AquariumConfig(**others)
    return AquariumConfig(**{field: value}, **others)


def assert_names_field(message: str, field: str) -> None:
    # The message must start with the offending field, so that e.g. "prey.max_speed" is not blamed on
    # "predator.max_speed" or on a world field.
    assert message.startswith((field + "=", field + " ")), (field, message)


# --------------------------------------------------------------------------------------------------
# World fields: (field, bad value, text of the allowed range that the message must show)
# --------------------------------------------------------------------------------------------------
WORLD_CASES = []
for _f in ("width", "height"):
    for _v in (-800.0, 0.0, 40, 40.0, 1e7 + 1, NAN, INF, -INF, True, "800", None):
        WORLD_CASES.append((_f, _v, "(40, 1e7]"))
for _f in ("prey_count", "predator_count"):
    for _v in (0, -1, 1.5, 2.0, True, False, "3", None, np.nan):
        WORLD_CASES.append((_f, _v, "an integer >= 1"))
for _v in (0, -3, 65537, 16.0, True, "16", None):
    WORLD_CASES.append(("action_count", _v, "[1, 65536]"))
for _v in (0, -1, 10.5, True, NAN, None):
    WORLD_CASES.append(("max_steps", _v, "an integer >= 1"))
for _f in ("fov_enabled", "respawn_captured_prey", "prey_reproduction"):
    for _v in (1, 0, "True", None, np.float64(1.0)):
        WORLD_CASES.append((_f, _v, "True or False"))
for _f in ("prey_reward", "prey_capture_penalty", "predator_reward"):
    for _v in (NAN, INF, -INF, True, "1", None):
        WORLD_CASES.append((_f, _v, "a finite number"))
for _v in (-1.0, -1e-9, NAN, INF, True, "100", None):
    WORLD_CASES.append(("catch_share_radius", _v, ">= 0"))
for _v in (-0.1, 1.01, 2, NAN, INF, True, "1", None):
    WORLD_CASES.append(("capture_probability", _v, "in [0, 1]"))
for _v in (-1.0, -1e-9, NAN, INF, True, "4", None):
    WORLD_CASES.append(("capture_confusion", _v, ">= 0"))
for _v in (0.0, -1.0, NAN, INF, True, "100", None):
    WORLD_CASES.append(("confusion_radius", _v, "> 0"))
for _v in ("Confusion", "olson", "", 1, None, True):
    WORLD_CASES.append(("capture_rule", _v, "one of ('dilution', 'confusion')"))
for _v in (0.0, -15.0, 180.5, 360.0, NAN, INF, True, "15", None):
    WORLD_CASES.append(("confusion_angle", _v, "in (0, 180] degrees"))
for _v in (-1, 10**6 + 1, 10.0, 2.5, True, NAN, "10", None):
    WORLD_CASES.append(("handling_steps", _v, "an integer in [0, 1000000]"))
for _v in (-1, 1.5, 3000.0, True, NAN, None):
    WORLD_CASES.append(("predator_starvation_steps", _v, "an integer >= 0"))
for _v in (0, -1, 200.0, True, NAN, None):
    WORLD_CASES.append(("prey_replication_age", _v, "an integer >= 1"))
for _v in (0, -5, 20.0, True, None):
    WORLD_CASES.append(("max_prey", _v, "an integer >= 1"))
for _v in ("0..2", "0..1 ", "[-1, 1]", "", 1, None, ("0..1",)):
    WORLD_CASES.append(("observation_range", _v, "('0..1', '-1..1')"))
for _v in (0.0, -10.0, NAN, INF, True, "50"):
    WORLD_CASES.append(("grid_cell_size", _v, "None or a finite number > 0"))


@pytest.mark.parametrize("field,value,allowed", WORLD_CASES, ids=[f"{f}={v!r}" for f, v, _ in WORLD_CASES])
def test_world_field_rejected(field, value, allowed):
    with pytest.raises(ValueError) as err:
        build(field, value)
    message = str(err.value)
    assert_names_field(message, field)
    assert allowed in message, message


# --------------------------------------------------------------------------------------------------
# Per-type fields, for both types
# --------------------------------------------------------------------------------------------------
TYPE_CASES = []
for _kind in ("prey", "predator"):
    for _f in ("max_speed", "max_steering_force", "max_acceleration", "mass", "radius"):
        for _v in (0.0, -1.0, NAN, INF, True, "4", None):
            TYPE_CASES.append((f"{_kind}.{_f}", _v, "a finite number > 0"))
    for _v in (0.0, -1.0, -INF, NAN, True, "100", None):
        TYPE_CASES.append((f"{_kind}.view_distance", _v, "a number > 0 (math.inf for unlimited)"))
    for _v in (0, 0.0, -10.0, 360.0001, 400, NAN, INF, True, "120"):
        TYPE_CASES.append((f"{_kind}.fov_angle", _v, "in (0, 360] degrees"))
    for _v in (-1.0, -1e-9, NAN, INF, True, "1"):
        TYPE_CASES.append((f"{_kind}.bounce_strength", _v, "a finite number >= 0"))
    for _f in ("predator_slots", "prey_slots"):
        for _v in (-1, MAX_OBSERVED_SLOTS + 1, 100, 1.0, True, None, "3"):
            TYPE_CASES.append((f"{_kind}.{_f}", _v, f"an integer in [0, {MAX_OBSERVED_SLOTS}]"))
    # Speeds of half the world or more would let one move skip the wrap's single correction.
    for _v in (400.0, 1000.0):
        TYPE_CASES.append((f"{_kind}.max_speed", _v, "smaller than half the world's width and height"))


@pytest.mark.parametrize("field,value,allowed", TYPE_CASES, ids=[f"{f}={v!r}" for f, v, _ in TYPE_CASES])
def test_type_field_rejected(field, value, allowed):
    with pytest.raises(ValueError) as err:
        build(field, value)
    message = str(err.value)
    assert_names_field(message, field)
    assert allowed in message, message


@pytest.mark.parametrize("kind", ["prey", "predator"])
def test_max_speed_against_the_smaller_side(kind):
    # Half the height (not the width) is the binding limit here.
    with pytest.raises(ValueError) as err:
        build(f"{kind}.max_speed", 50.0, width=800.0, height=100.0)
    assert_names_field(str(err.value), f"{kind}.max_speed")
    assert "half the world" in str(err.value)
    build(f"{kind}.max_speed", 49.999, width=800.0, height=100.0)  # just below: fine


@pytest.mark.parametrize("kind", ["prey", "predator"])
@pytest.mark.parametrize("value", [{}, None, "default", 3, default_prey().__dict__])
def test_type_config_must_be_an_agent_type_config(kind, value):
    with pytest.raises(ValueError) as err:
        AquariumConfig(**{kind: value})
    assert_names_field(str(err.value), kind)
    assert "AgentTypeConfig" in str(err.value)


def test_capacity_limit():
    with pytest.raises(ValueError) as err:
        AquariumConfig(prey_count=2**30)
    assert_names_field(str(err.value), "capacity")
    assert "2**30" in str(err.value)


def test_replace_revalidates():
    cfg = AquariumConfig()
    with pytest.raises(ValueError, match=r"^prey_count="):
        cfg.replace(prey_count=0)
    with pytest.raises(ValueError, match=r"^prey\.radius="):
        cfg.replace(prey=dataclasses.replace(cfg.prey, radius=-1.0))


def test_from_dict_validates():
    data = AquariumConfig().to_dict()
    data["predator"]["fov_angle"] = 400.0
    with pytest.raises(ValueError, match=r"^predator\.fov_angle="):
        AquariumConfig.from_dict(data)
    data["predator"]["fov_angle"] = 150.0
    assert AquariumConfig.from_dict(data) == AquariumConfig()


# --------------------------------------------------------------------------------------------------
# Valid edge values
# --------------------------------------------------------------------------------------------------
VALID_CASES = [
    ("width", 41.0),
    ("width", 41),
    ("width", 1e7),
    ("height", 40.5),
    ("height", 1e7),
    ("width", np.float64(500.0)),
    ("prey_count", 1),
    ("predator_count", 1),
    ("prey_count", 500),
    ("action_count", 1),
    ("action_count", 65536),
    ("max_steps", 1),
    ("fov_enabled", False),
    ("respawn_captured_prey", False),
    ("prey_reproduction", True),
    ("prey_reward", 0.0),
    ("prey_reward", -3),
    ("prey_capture_penalty", 0),
    ("prey_capture_penalty", -5.0),
    ("predator_reward", 0.0),
    ("predator_reward", 1e30),
    ("catch_share_radius", 0.0),
    ("catch_share_radius", 0),
    ("catch_share_radius", 1e9),
    ("capture_probability", 0.0),
    ("capture_probability", 1),
    ("capture_probability", 0.25),
    ("capture_confusion", 0),
    ("capture_confusion", 4.0),
    ("confusion_radius", 1e9),
    ("capture_rule", "dilution"),
    ("capture_rule", "confusion"),
    ("confusion_angle", 180.0),
    ("confusion_angle", 1e-9),
    ("handling_steps", 0),
    ("handling_steps", 10**6),
    ("predator_starvation_steps", 0),
    ("prey_replication_age", 1),
    ("max_prey", 1),
    ("observation_range", "0..1"),
    ("observation_range", "-1..1"),
    ("grid_cell_size", None),
    ("grid_cell_size", 1e-3),
    ("grid_cell_size", 1e6),
]
for _kind in ("prey", "predator"):
    VALID_CASES += [
        (f"{_kind}.max_speed", 1e-6),
        (f"{_kind}.max_speed", 399.999),
        (f"{_kind}.max_speed", 4),
        (f"{_kind}.max_steering_force", 1e-9),
        (f"{_kind}.max_steering_force", 1e9),
        (f"{_kind}.max_acceleration", 1e-9),
        (f"{_kind}.mass", 1e-9),
        (f"{_kind}.mass", 1e9),
        (f"{_kind}.radius", 1e-9),
        (f"{_kind}.radius", 1e6),
        (f"{_kind}.view_distance", INF),
        (f"{_kind}.view_distance", 1e-9),
        (f"{_kind}.view_distance", 1e12),
        (f"{_kind}.fov_angle", 360.0),
        (f"{_kind}.fov_angle", 360),
        (f"{_kind}.fov_angle", 1e-6),
        (f"{_kind}.bounce_strength", 0.0),
        (f"{_kind}.bounce_strength", 0),
        (f"{_kind}.predator_slots", 0),
        (f"{_kind}.predator_slots", MAX_OBSERVED_SLOTS),
        (f"{_kind}.prey_slots", 0),
        (f"{_kind}.prey_slots", MAX_OBSERVED_SLOTS),
    ]


@pytest.mark.parametrize("field,value", VALID_CASES, ids=[f"{f}={v!r}" for f, v in VALID_CASES])
def test_valid_edge_value_accepted(field, value):
    cfg = build(field, value)
    if "." in field:
        kind, name = field.split(".")
        assert getattr(getattr(cfg, kind), name) == value
    else:
        assert getattr(cfg, field) == value or (value is None and getattr(cfg, field) is None)


def test_valid_combined_edges():
    # Reproduction with prey_count above max_prey, one neighbour slot (the fewest: issue 28), both FOVs full.
    cfg = AquariumConfig(
        width=41.0,
        height=41.0,
        prey_count=30,
        predator_count=1,
        max_prey=1,
        prey_reproduction=True,
        max_steps=1,
        predator_starvation_steps=0,
        prey=AgentTypeConfig(20.0, 1e-9, 1e-9, 1e-9, 1e-9, INF, 360.0, 0.0, 0, 1),
        predator=AgentTypeConfig(20.4, 1.0, 1.0, 1.0, 1.0, 1e-9, 1e-6, 0.0, 16, 16),
    )
    assert cfg.prey_capacity == 30 and cfg.capacity == 31
    assert cfg.prey.observation_size == 5 + 6 and cfg.predator.observation_size == 5 + 6 * 32


# --------------------------------------------------------------------------------------------------
# BatchedAquarium's own arguments
# --------------------------------------------------------------------------------------------------
ENV_CASES = [
    ("num_worlds", dict(num_worlds=0), ">= 1"),
    ("num_worlds", dict(num_worlds=-1), ">= 1"),
    ("num_worlds", dict(num_worlds=1.5), ">= 1"),
    ("num_worlds", dict(num_worlds=2.0), ">= 1"),
    ("num_worlds", dict(num_worlds=True), ">= 1"),
    ("num_worlds", dict(num_worlds="4"), ">= 1"),
    ("num_worlds", dict(num_worlds=None), ">= 1"),
    ("seed", dict(seed=-1), "non-negative integer"),
    ("seed", dict(seed="x"), "non-negative integer"),
    ("seed", dict(seed=1.0), "non-negative integer"),
    ("seed", dict(seed=True), "non-negative integer"),
    ("seed", dict(seed=None), "non-negative integer"),
    ("seed", dict(seed=np.int64(-3)), "non-negative integer"),
    ("device", dict(device="cuda:7"), "available devices"),
    ("device", dict(device="tpu"), "available devices"),
    ("device", dict(device="cpu:1"), "available devices"),
    ("device", dict(device=torch.device("cuda", 7)), "available devices"),
    ("device", dict(device=7), "a string like 'cpu' or 'cuda:0'"),
    ("cpu_threads", dict(cpu_threads=0), "None or an integer >= 1"),
    ("cpu_threads", dict(cpu_threads=-2), "None or an integer >= 1"),
    ("cpu_threads", dict(cpu_threads=1.5), "None or an integer >= 1"),
    ("cpu_threads", dict(cpu_threads=True), "None or an integer >= 1"),
    ("cpu_threads", dict(cpu_threads="2"), "None or an integer >= 1"),
    ("config", dict(config={}), "AquariumConfig"),
    ("config", dict(config=AquariumConfig().to_dict()), "AquariumConfig"),
    ("config", dict(config=default_prey()), "AquariumConfig"),
    ("config", dict(config="default"), "AquariumConfig"),
]


@pytest.mark.parametrize("name,kwargs,allowed", ENV_CASES, ids=[f"{n}={kw[n]!r}" for n, kw, _ in ENV_CASES])
def test_env_argument_rejected(name, kwargs, allowed):
    kwargs = dict(kwargs)
    kwargs.setdefault("config", AquariumConfig(max_steps=10))
    kwargs.setdefault("device", "cpu")
    with pytest.raises(ValueError) as err:
        BatchedAquarium(**kwargs)
    message = str(err.value)
    assert_names_field(message, name)
    assert allowed in message, message


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(num_worlds=1),
        dict(num_worlds=np.int64(2)),
        dict(seed=0),
        dict(seed=2**64 + 5),
        dict(seed=np.uint32(7)),
        dict(cpu_threads=1),
        dict(cpu_threads=None),
        dict(device=torch.device("cpu")),
        dict(device=None),
    ],
    ids=lambda kw: ",".join(f"{k}={v!r}" for k, v in kw.items()),
)
def test_env_argument_edge_accepted(kwargs):
    kwargs = dict(kwargs)
    kwargs.setdefault("device", "cpu")
    env = BatchedAquarium(AquariumConfig(max_steps=10), **kwargs)
    try:
        assert env.device == "cpu"
        obs, *_ = env.step(
            {
                "prey": torch.zeros(env.num_worlds, env.prey_capacity, dtype=torch.int64),
                "predator": torch.zeros(env.num_worlds, env.predator_capacity, dtype=torch.int64),
            }
        )
        assert torch.isfinite(obs["prey"]).all()
    finally:
        env.close()


def _peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB


def test_too_large_refused_up_front_with_estimate():
    # 10**7 worlds x 100 slots with 16 + 16 observed slots per agent: about 850 GiB, far beyond any host.
    # The 32-bit index checks pass (10**9 slots, 49 cells per world), so the memory estimate decides.
    big = AgentTypeConfig(4.0, 0.6, 1.0, 3.0, 20.0, 100.0, 120.0, 1.0, 16, 16)
    cfg = AquariumConfig(prey_count=99, predator_count=1, prey=big)
    rss_before = _peak_rss_bytes()
    start = time.perf_counter()
    with pytest.raises(ValueError) as err:
        BatchedAquarium(cfg, num_worlds=10**7, device="cpu")
    elapsed = time.perf_counter() - start
    message = str(err.value)
    assert_names_field(message, "num_worlds")
    match = re.search(r"needs about (\d+\.\d+) GiB", message)
    assert match, message
    assert float(match.group(1)) > 500.0, message
    assert re.search(r"only \d+\.\d+ GiB", message), message
    # Refused before allocating: quick, and the process's peak memory barely moved.
    assert elapsed < 5.0
    assert _peak_rss_bytes() - rss_before < 512 * 2**20


def test_index_range_overflow_refused_up_front():
    rss_before = _peak_rss_bytes()
    with pytest.raises(ValueError) as err:
        BatchedAquarium(AquariumConfig(prey_count=1000), num_worlds=10**7, device="cpu")
    assert_names_field(str(err.value), "num_worlds")
    assert _peak_rss_bytes() - rss_before < 512 * 2**20


# --------------------------------------------------------------------------------------------------
# float32-safe ranges (issue 15): values validation used to accept that crashed the first step, gave
# NaN state or infinite rewards, or overflowed the int32 counters. Edges: the bound itself is accepted,
# the next value out is refused.
# --------------------------------------------------------------------------------------------------
FLOAT32_CASES = [
    # (field, refused value, accepted edge, text of the allowed range)
    ("max_steps", 2**31, 2**31 - 1, "<= 2**31 - 1"),
    ("max_steps", 2**32 + 10, 2**31 - 1, "<= 2**31 - 1"),
    ("predator_starvation_steps", 2**31 - 1, 2**31 - 2, "<= 2**31 - 2"),
    ("predator_starvation_steps", 2**31, 2**31 - 2, "<= 2**31 - 2"),
    ("prey_replication_age", 2**31 - 1, 1717986917, "<= 1717986917"),
    ("prey_replication_age", 1717986918, 1717986917, "<= 1717986917"),
    ("catch_share_radius", 0.99e-15, 1e-15, "0 or in [1e-15, 1e+15]"),
    ("catch_share_radius", 1.01e15, 1e15, "0 or in [1e-15, 1e+15]"),
    ("capture_confusion", 1.01e15, 1e15, "in [0, 1e+15]"),
    ("confusion_radius", 0.99e-15, 1e-15, "in [1e-15, 1e+15]"),
    ("confusion_radius", 1.01e15, 1e15, "in [1e-15, 1e+15]"),
    # |reward| x max_steps (3000) x prey slots (16) <= 1e38
    ("prey_reward", 1e39, 1e38 / 48000, "1e38 / (max_steps x prey slots)"),
    ("prey_capture_penalty", -1e39, -1e38 / 48000, "1e38 / (max_steps x prey slots)"),
    ("predator_reward", 2.1e33, 2.08e33, "1e38 / (max_steps x prey slots)"),
]
for _kind in ("prey", "predator"):
    for _f in ("max_steering_force", "max_acceleration", "radius"):
        FLOAT32_CASES += [
            (f"{_kind}.{_f}", 0.99e-15, 1e-15, "in [1e-15, 1e+15]"),
            (f"{_kind}.{_f}", 1.01e15, 1e15, "in [1e-15, 1e+15]"),
        ]
    FLOAT32_CASES += [
        (f"{_kind}.max_speed", 0.99e-15, 1e-15, "in [1e-15, 1e+15]"),
        (f"{_kind}.mass", 1e-45, 1e-15, "in [1e-15, 1e+15]"),  # 0.6 / 1e-45 is inf in float32
        (f"{_kind}.mass", 0.99e-15, 1.0, "in [1e-15, 1e+15]"),
        (f"{_kind}.mass", 1e25, 1e15, "in [1e-15, 1e+15]"),
        (f"{_kind}.mass", 1e30, 1e15, "in [1e-15, 1e+15]"),
        (f"{_kind}.max_acceleration", 1e38, 1e15, "in [1e-15, 1e+15]"),
        (f"{_kind}.bounce_strength", 1e39, 1e15, "0 or in [1e-15, 1e+15]"),
        (f"{_kind}.bounce_strength", 1e-30, 1e-15, "0 or in [1e-15, 1e+15]"),
        (f"{_kind}.max_steering_force", 1e-30, 1e-15, "in [1e-15, 1e+15]"),
        (f"{_kind}.view_distance", 1.01e15, 1e15, "math.inf or in [1e-15, 1e+15]"),
        (f"{_kind}.view_distance", 1e-30, 1e-15, "math.inf or in [1e-15, 1e+15]"),
    ]


@pytest.mark.parametrize("field,bad,edge,allowed", FLOAT32_CASES, ids=[f"{f}={b!r}" for f, b, _, _ in FLOAT32_CASES])
def test_float32_and_int32_ranges(field, bad, edge, allowed):
    with pytest.raises(ValueError) as err:
        build(field, bad)
    assert_names_field(str(err.value), field)
    assert allowed in str(err.value), str(err.value)
    cfg = build(field, edge)
    kind, _, name = field.rpartition(".")
    assert getattr(getattr(cfg, kind) if kind else cfg, name) == edge


def test_mass_against_the_steering_force():
    # With mass 1e-15 the default steering force gives 0.6 / 1e-15 = 6e14 px/step^2, within 1e15; a
    # steering force of 1e6 (limited by 2 max_speed = 8) gives 8e15, too much.
    build("prey.mass", 1e-15)
    with pytest.raises(
        ValueError, match=r"^prey\.mass=.*at least min\(max_steering_force, 2 max_speed\) / 1e\+15 = 8e-15"
    ):
        AquariumConfig(prey=dataclasses.replace(default_prey(), mass=1e-15, max_steering_force=1e6))


@pytest.mark.parametrize(
    "field,value",
    [
        ("prey_count", np.int64(16)),
        ("predator_count", np.int32(2)),
        ("max_steps", np.uint16(100)),
        ("width", np.float32(500.0)),
        ("prey_reward", np.float64(2.0)),
        ("fov_enabled", np.bool_(False)),
        ("prey.prey_slots", np.int8(2)),
        ("prey.radius", np.float32(10.0)),
    ],
)
def test_numpy_scalars_accepted_as_python_numbers(field, value):
    # Issue 15: prey_count=np.int64(16) said "out of range"; numpy integers are integers.
    cfg = build(field, value)
    kind, _, name = field.rpartition(".")
    stored = getattr(getattr(cfg, kind) if kind else cfg, name)
    assert stored == value and type(stored) in (int, float, bool)
    assert AquariumConfig.from_dict(cfg.to_dict()) == cfg
