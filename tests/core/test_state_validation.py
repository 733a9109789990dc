"""`set_state` and `load_state_dict` check every value before writing anything (issue 15, cases 6
and 7): int64 values that would wrap in the int32 counters, values beyond float32, out-of-range or
inconsistent state dicts are refused with an error naming the field, and the env is left exactly as
it was (checked against a twin env that never saw the bad call)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from test_bad_input import assert_same_state, random_actions, state_of, step_both

from aquarium_warp import AquariumConfig, BatchedAquarium

W = 2
CFG = AquariumConfig(prey_count=12, predator_count=2, max_steps=1000)
C = CFG.capacity


@pytest.fixture(scope="module")
def pair():
    env = BatchedAquarium(CFG, num_worlds=W, device="cpu", seed=5)
    twin = BatchedAquarium(CFG, num_worlds=W, device="cpu", seed=5)
    gen = torch.Generator().manual_seed(2)
    step_both(env, twin, gen, steps=3)
    yield env, twin, gen
    env.close()
    twin.close()


def _column(env, name, value, slot=0, dtype=None):
    v = getattr(env.state.torch, name)[0].clone()
    v = v.to(dtype) if dtype is not None else v
    v[slot] = value
    return {"world": 0, name: v}


BAD_SET_STATE = [
    # int64 values that a cast to int32 would wrap (age=2**32+5 was stored as 5)
    ("age_wraps", lambda e: _column(e, "age", 2**32 + 5, dtype=torch.int64), ["age", "4294967301", "[0, "]),
    ("age_float_1e10", lambda e: _column(e, "age", 1e10, dtype=torch.float64), ["age", "10000000000", "int32"]),
    (
        "age_past_the_episode",
        lambda e: _column(e, "age", 2**31 - 1000, dtype=torch.int64),
        ["age", f"<= {2**31 - 1 - CFG.max_steps}", "max_steps"],
    ),
    ("world_step_wraps", lambda e: {"world": 0, "world_step": 2**32 + 1}, ["world_step", "[0, 999]"]),
    (
        "starvation_int32_max",
        lambda e: _column(e, "starvation", 2**31 - 1, slot=C - 1, dtype=torch.int64),
        ["starvation", f"<= {2**31 - 2}"],
    ),
    (
        "replication_age_uint64",
        lambda e: {"world": 0, "replication_age": np.full(C, 2**63, dtype=np.uint64)},
        ["replication_age", "[0, 2147483647]"],
    ),
    ("episode_wraps", lambda e: {"world": 1, "episode": 2**31}, ["episode", f"<= {2**31 - 2}"]),
    # floats beyond float32, or too large for the kernels' squares
    (
        "velocity_beyond_float32",
        lambda e: _column(e, "velocity", torch.tensor([1e39, 0.0]), dtype=torch.float64),
        ["velocity", "finite"],
    ),
    ("velocity_huge", lambda e: _column(e, "velocity", torch.tensor([1e20, 0.0])), ["velocity", "1e+15"]),
    ("acceleration_huge", lambda e: _column(e, "acceleration", torch.tensor([0.0, -2e15])), ["acceleration", "1e+15"]),
    (
        "position_rounds_to_width",
        lambda e: _column(e, "position", torch.tensor([CFG.width - 1e-6, 1.0]), dtype=torch.float64),
        ["position", "as float32"],
    ),
    # values torch cannot hold
    ("age_strings", lambda e: {"world": 0, "age": ["1"] * C}, ["age", "must hold numbers"]),
    ("age_objects", lambda e: {"world": 0, "age": np.array([object()] * C)}, ["age", "must hold numbers"]),
    (
        "velocity_complex",
        lambda e: {"world": 0, "velocity": torch.zeros(C, 2, dtype=torch.complex64)},
        ["velocity", "real numbers"],
    ),
]


@pytest.mark.parametrize("make,expected", [(m, e) for _, m, e in BAD_SET_STATE], ids=[i for i, _, _ in BAD_SET_STATE])
def test_bad_set_state_refused(pair, make, expected):
    env, twin, gen = pair
    before = state_of(env)
    with pytest.raises(ValueError) as err:
        env.set_state(**make(env))
    for text in expected:
        assert text in str(err.value), (text, str(err.value))
    assert_same_state(state_of(env), before)
    step_both(env, twin, gen)


def test_set_state_edges_accepted(pair):
    """The largest allowed counters and vectors are stored exactly and step without overflow."""
    env, twin, gen = pair
    fields = dict(
        world=1,
        age=torch.full((C,), 2**31 - 1 - CFG.max_steps, dtype=torch.int64),
        starvation=torch.zeros(C, dtype=torch.int64),
        world_step=CFG.max_steps - 1,
        velocity=torch.full((C, 2), 1e15),
        acceleration=torch.full((C, 2), -1e15),
    )
    for e in (env, twin):
        e.set_state(**fields)
    assert int(env.state.torch.age[1].min()) == 2**31 - 1 - CFG.max_steps
    env.set_state(world=1, replication_age=np.zeros(C, dtype=">i4"))  # big-endian arrays are numbers too
    twin.set_state(world=1, replication_age=np.zeros(C, dtype="<i4"))
    step_both(env, twin, gen, steps=2)
    t = env.state.torch
    assert torch.isfinite(t.velocity).all() and torch.isfinite(t.acceleration).all()
    assert (t.age >= 0).all()


def _bad_dict(env, change):
    sd = copy.deepcopy(env.state_dict())
    change(sd)
    return sd


def _alive_count_off_by_one(sd):
    sd["tensors"]["prey_alive_count"][1] -= 1


def _dead_but_counted(sd):
    sd["tensors"]["alive"][0, 0] = False  # the count still says it lives


BAD_STATE_DICTS = [
    (
        "position_far",
        lambda sd: sd["tensors"]["position"][0, 3].copy_(torch.tensor([1e9, -1e9])),
        ["position", "[0, 800.0)"],
    ),
    (
        "position_nan",
        lambda sd: sd["tensors"]["position"][1, 0].copy_(torch.tensor([float("nan"), 1.0])),
        ["position", "finite"],
    ),
    (
        "heading_not_unit",
        lambda sd: sd["tensors"]["heading"][0, 0].copy_(torch.tensor([2.0, 0.0])),
        ["heading", "unit"],
    ),
    (
        "velocity_inf",
        lambda sd: sd["tensors"]["velocity"][0, 0].copy_(torch.tensor([float("inf"), 0.0])),
        ["velocity", "finite"],
    ),
    (
        "episode_return_nan",
        lambda sd: sd["tensors"]["episode_return"][0, 0].fill_(float("nan")),
        ["episode_return", "finite"],
    ),
    ("world_step_at_max", lambda sd: sd["tensors"]["world_step"].fill_(CFG.max_steps), ["world_step", "[0, 999]"]),
    ("age_negative", lambda sd: sd["tensors"]["age"][0, 0].fill_(-1), ["age", ">= 0"]),
    ("episode_captures_negative", lambda sd: sd["tensors"]["episode_captures"].fill_(-2), ["episode_captures"]),
    ("alive_count_off_by_one", _alive_count_off_by_one, ["prey_alive_count[1]", "does not match", "world 1"]),
    ("dead_but_counted", _dead_but_counted, ["prey_alive_count[0]", "does not match"]),
    (
        "alive_count_too_big",
        lambda sd: sd["tensors"]["predator_alive_count"].fill_(3),
        ["predator_alive_count", "[0, 2]"],
    ),
    (
        "alive_as_float",
        lambda sd: sd["tensors"].__setitem__("alive", sd["tensors"]["alive"].float()),
        ["alive", "dtype torch.float32", "torch.bool"],
    ),
    (
        "age_as_int64",
        lambda sd: sd["tensors"].__setitem__("age", sd["tensors"]["age"].long()),
        ["age", "dtype torch.int64", "torch.int32"],
    ),
    ("truncated", lambda sd: sd["tensors"].pop("starvation"), ["missing ['starvation']"]),
    ("empty_tensors", lambda sd: sd["tensors"].clear(), ["missing ['position', 'velocity'"]),
    ("unknown_tensor", lambda sd: sd["tensors"].__setitem__("mass", torch.ones(W)), ["unknown ['mass']"]),
    (
        "wrong_shape",
        lambda sd: sd["tensors"].__setitem__("velocity", torch.zeros(W, C + 1, 2)),
        ["velocity", f"shape [{W}, {C + 1}, 2]", f"expected [{W}, {C}, 2]"],
    ),
    (
        "tensor_is_a_list",
        lambda sd: sd["tensors"].__setitem__("age", sd["tensors"]["age"].tolist()),
        ["age", "torch tensor"],
    ),
    ("seed_float", lambda sd: sd.__setitem__("seed", 3.5), ["seed=3.5", "non-negative integer"]),
    ("seed_negative", lambda sd: sd.__setitem__("seed", -1), ["seed=-1"]),
    ("no_tensors", lambda sd: sd.pop("tensors"), ["lacks ['tensors']"]),
    ("other_config", lambda sd: sd.__setitem__("config", CFG.replace(max_steps=5).to_dict()), ["another config"]),
]


@pytest.mark.parametrize(
    "change,expected", [(c, e) for _, c, e in BAD_STATE_DICTS], ids=[i for i, _, _ in BAD_STATE_DICTS]
)
def test_bad_state_dict_refused_all_or_nothing(pair, change, expected):
    """Issue 15 case 7: nothing is written before every tensor passed (an unknown key or a wrong shape
    used to raise after earlier tensors had been overwritten); the bad dict also carries another seed,
    which must not be taken either."""
    env, twin, gen = pair
    before = state_of(env)
    sd = _bad_dict(env, change)
    # Valid changes alongside the bad one, which must not be applied either.
    if sd.get("seed") == env.seed:
        sd["seed"] = env.seed + 1
    captures = sd.get("tensors", {}).get("episode_captures") if isinstance(sd.get("tensors"), dict) else None
    if isinstance(captures, torch.Tensor) and captures.dtype == torch.int32 and (captures >= 0).all():
        captures += 1
    with pytest.raises(ValueError) as err:
        env.load_state_dict(sd)
    for text in expected:
        assert text in str(err.value), (text, str(err.value))
    assert_same_state(state_of(env), before)
    step_both(env, twin, gen)


def test_state_dict_round_trip_with_another_seed(pair):
    """Positive control: a valid state dict (with another seed) is taken whole, and both envs continue
    alike from it."""
    env, twin, gen = pair
    donor = BatchedAquarium(CFG, num_worlds=W, device="cpu", seed=77)
    donor.step(random_actions(donor, gen))
    sd = donor.state_dict()
    env.load_state_dict(sd)
    twin.load_state_dict(sd)
    assert env.seed == 77
    assert_same_state(state_of(env), {**state_of(donor), "seed": 77})
    step_both(env, twin, gen)
    donor.close()
