"""Bad input to `BatchedAquarium.step` and `set_state`: every bad call raises a `ValueError` that names the
offending key or parameter and its allowed range, and leaves the simulation exactly as it was.

Each test drives two envs built alike: `env` gets the bad calls, `twin` does not; both then take the same
valid steps, and must stay bit-identical (so a failed call changed nothing and the env still steps)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium

W = 3
CFG = AquariumConfig(max_steps=1000)
A = CFG.action_count


def state_of(env) -> dict:
    sd = env.state_dict()
    sd["observations"] = {t: env.observations[t].clone() for t in ("prey", "predator")}
    sd["mask"] = {t: env.observation_mask[t].clone() for t in ("prey", "predator")}
    sd["slot"] = {t: env.observed_slot[t].clone() for t in ("prey", "predator")}
    return sd


def assert_same_state(a: dict, b: dict) -> None:
    assert a["config"] == b["config"] and a["num_worlds"] == b["num_worlds"] and a["seed"] == b["seed"]
    assert a["tensors"].keys() == b["tensors"].keys()
    for name in a["tensors"]:
        assert torch.equal(a["tensors"][name], b["tensors"][name]), name
    for key in ("observations", "mask", "slot"):
        for t in ("prey", "predator"):
            assert torch.equal(a[key][t], b[key][t]), (key, t)


def random_actions(env, gen) -> dict:
    return {
        "prey": torch.randint(0, env.config.action_count, (env.num_worlds, env.prey_capacity), generator=gen),
        "predator": torch.randint(0, env.config.action_count, (env.num_worlds, env.predator_capacity), generator=gen),
    }


def step_both(env, twin, gen, steps: int = 3, actions=None, twin_actions=None) -> None:
    for _ in range(steps):
        a = actions if actions is not None else random_actions(env, gen)
        env.step(a)
        twin.step(twin_actions if twin_actions is not None else a)
        assert_same_state(state_of(env), state_of(twin))


@pytest.fixture(scope="module")
def pair():
    env = BatchedAquarium(CFG, num_worlds=W, device="cpu", seed=11)
    twin = BatchedAquarium(CFG, num_worlds=W, device="cpu", seed=11)
    gen = torch.Generator().manual_seed(0)
    step_both(env, twin, gen, steps=5)
    yield env, twin, gen
    env.close()
    twin.close()


def good(t: str, dtype=torch.int64) -> torch.Tensor:
    n = CFG.prey_count if t == "prey" else CFG.predator_count
    return torch.zeros(W, n, dtype=dtype)


def with_(t: str, value) -> dict:
    actions = {"prey": good("prey"), "predator": good("predator")}
    actions[t] = value
    return actions


def out_of_range(t: str, value: int, dtype=torch.int64) -> dict:
    a = good(t, dtype)
    a[1, 0] = value  # slot 0 of world 1: a live agent (no deaths in this config)
    return with_(t, a)


# (id, actions, substrings the message must contain)
BAD_ACTIONS = [
    ("missing_predator", lambda: {"prey": good("prey")}, ["'predator'", "missing ['predator']", "exactly the keys"]),
    ("missing_prey", lambda: {"predator": good("predator")}, ["missing ['prey']", "exactly the keys"]),
    ("empty_dict", dict, ["missing ['prey', 'predator']"]),
    (
        "extra_key",
        lambda: {"prey": good("prey"), "predator": good("predator"), "shark": good("predator")},
        ["unknown ['shark']", "exactly the keys"],
    ),
    ("not_a_mapping", lambda: [good("prey"), good("predator")], ["actions must be a dict", "'prey'", "'predator'"]),
]
for _t, _n in (("prey", CFG.prey_count), ("predator", CFG.predator_count)):
    _key = f"actions[{_t!r}]"
    BAD_ACTIONS += [
        (
            f"{_t}_shape_extra_slot",
            lambda t=_t, n=_n: with_(t, torch.zeros(W, n + 1, dtype=torch.int64)),
            [_key, f"must have shape [{W}, {_n}]"],
        ),
        (
            f"{_t}_shape_flat",
            lambda t=_t, n=_n: with_(t, torch.zeros(W * n, dtype=torch.int64)),
            [_key, f"must have shape [{W}, {_n}]"],
        ),
        (
            f"{_t}_shape_3d",
            lambda t=_t, n=_n: with_(t, torch.zeros(W, n, 1, dtype=torch.int64)),
            [_key, f"must have shape [{W}, {_n}]"],
        ),
        (
            f"{_t}_shape_worlds",
            lambda t=_t, n=_n: with_(t, torch.zeros(W + 1, n, dtype=torch.int64)),
            [_key, f"must have shape [{W}, {_n}]"],
        ),
        (f"{_t}_float32", lambda t=_t: with_(t, good(t, torch.float32)), [_key, "integer dtype"]),
        (f"{_t}_float64", lambda t=_t: with_(t, good(t, torch.float64)), [_key, "integer dtype"]),
        (f"{_t}_float16", lambda t=_t: with_(t, good(t, torch.float16)), [_key, "integer dtype"]),
        (f"{_t}_bool", lambda t=_t: with_(t, good(t, torch.bool)), [_key, "integer dtype"]),
        (f"{_t}_complex", lambda t=_t: with_(t, good(t, torch.complex64)), [_key, "integer dtype"]),
        (f"{_t}_minus_one", lambda t=_t: out_of_range(t, -1), [_key, "[1, 0]=-1", f"[0, {A - 1}]"]),
        (f"{_t}_action_count", lambda t=_t: out_of_range(t, A), [_key, f"[1, 0]={A}", f"[0, {A - 1}]"]),
        (f"{_t}_huge", lambda t=_t: out_of_range(t, 2**40), [_key, f"[0, {A - 1}]"]),
        (f"{_t}_int8_minus_one", lambda t=_t: out_of_range(t, -1, torch.int8), [_key, f"[0, {A - 1}]"]),
        (f"{_t}_int32_action_count", lambda t=_t: out_of_range(t, A, torch.int32), [_key, f"[0, {A - 1}]"]),
        (f"{_t}_numpy_float", lambda t=_t, n=_n: with_(t, np.zeros((W, n), dtype=np.float32)), [_key, "integer dtype"]),
        (f"{_t}_numpy_bool", lambda t=_t, n=_n: with_(t, np.zeros((W, n), dtype=bool)), [_key, "integer dtype"]),
        (
            f"{_t}_numpy_out_of_range",
            lambda t=_t, n=_n: with_(t, np.full((W, n), A, dtype=np.int32)),
            [_key, f"[0, {A - 1}]"],
        ),
        (
            f"{_t}_numpy_wrong_shape",
            lambda t=_t, n=_n: with_(t, np.zeros((n, W), dtype=np.int64)),
            [_key, f"must have shape [{W}, {_n}]"],
        ),
        (f"{_t}_python_list", lambda t=_t, n=_n: with_(t, [[0] * n for _ in range(W)]), [_key, "torch tensor"]),
        (f"{_t}_python_int", lambda t=_t: with_(t, 3), [_key, "torch tensor"]),
        (f"{_t}_none", lambda t=_t: with_(t, None), [_key, "torch tensor"]),
        (f"{_t}_meta_device", lambda t=_t: with_(t, good(t).to("meta")), [_key, "env runs on cpu"]),
    ]


@pytest.mark.parametrize("make,expected", [(m, e) for _, m, e in BAD_ACTIONS], ids=[i for i, _, _ in BAD_ACTIONS])
def test_bad_actions_rejected_and_state_unchanged(pair, make, expected):
    env, twin, gen = pair
    before = state_of(env)
    with pytest.raises(ValueError) as err:
        env.step(make())
    for text in expected:
        assert text in str(err.value), (text, str(err.value))
    assert_same_state(state_of(env), before)
    step_both(env, twin, gen)  # still steps, exactly like the env that never saw the bad call


def test_valid_action_forms_accepted(pair):
    env, twin, gen = pair
    a = random_actions(env, gen)
    for t in ("prey", "predator"):
        a[t][0, 0] = 0
        a[t][-1, -1] = A - 1  # both ends of the range
    variants = [
        {t: a[t].to(torch.int32) for t in a},
        {t: a[t].to(torch.int16) for t in a},
        {t: a[t].to(torch.uint8) for t in a},
        {t: a[t].numpy() for t in a},
        {t: a[t].numpy().astype(np.int32) for t in a},
        {"predator": a["predator"], "prey": a["prey"].t().contiguous().t()},  # non-contiguous, key order swapped
    ]
    for v in variants:
        env.step(v)
        twin.step(a)
        assert_same_state(state_of(env), state_of(twin))


# --------------------------------------------------------------------------------------------------
# Out-of-range actions of dead slots are accepted and ignored
# --------------------------------------------------------------------------------------------------
def test_dead_slots_beyond_prey_count_ignored():
    # Reproduction on: prey slots [prey_count, max_prey) start empty; no birth within the test.
    cfg = AquariumConfig(prey_count=4, max_prey=8, prey_reproduction=True, prey_replication_age=1000)
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=3)
    twin = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=3)
    gen = torch.Generator().manual_seed(1)
    try:
        assert not env.alive["prey"][:, 4:].any()
        for junk in (-1, cfg.action_count, 10**6, -(2**40), 2**40):
            a = random_actions(env, gen)
            bad = {t: v.clone() for t, v in a.items()}
            bad["prey"][:, 4:] = junk
            env.step(bad)
            twin.step(a)
            assert_same_state(state_of(env), state_of(twin))
        # the live slots are still checked
        bad = random_actions(env, gen)
        bad["prey"][0, 3] = -1
        with pytest.raises(ValueError, match=r"actions\['prey'\]\[0, 3\]=-1"):
            env.step(bad)
    finally:
        env.close()
        twin.close()


def test_dead_slots_after_capture_and_starvation_ignored():
    cfg = AquariumConfig(prey_count=4, predator_count=2, respawn_captured_prey=False, predator_starvation_steps=500)
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=5)
    twin = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=5)
    gen = torch.Generator().manual_seed(2)
    Pc = env.prey_capacity
    try:
        # World 0: prey 0 on top of predator 0 (it is captured in the next step, permanently).
        position = env.state.torch.position[0].clone()
        position[0] = position[Pc]
        # World 1: predator 1 is one step from starving.
        starvation = env.state.torch.starvation[1].clone()
        starvation[Pc + 1] = cfg.predator_starvation_steps
        for e in (env, twin):
            e.set_state(world=0, position=position)
            e.set_state(world=1, starvation=starvation)
        a = random_actions(env, gen)
        _, _, terminated, _, info = env.step(a)
        twin.step(a)
        assert bool(terminated["prey"][0, 0]) and not bool(env.alive["prey"][0, 0])
        assert bool(terminated["predator"][1, 1]) and not bool(env.alive["predator"][1, 1])
        assert not info["episode_ended"].any()
        assert_same_state(state_of(env), state_of(twin))
        for junk in (-1, cfg.action_count, 12345):
            a = random_actions(env, gen)
            bad = {t: v.clone() for t, v in a.items()}
            bad["prey"][0, 0] = junk
            bad["predator"][1, 1] = junk
            env.step(bad)
            twin.step(a)
            assert_same_state(state_of(env), state_of(twin))
    finally:
        env.close()
        twin.close()


# --------------------------------------------------------------------------------------------------
# set_state with bad values
# --------------------------------------------------------------------------------------------------
C = CFG.capacity


def _field(env, name, world=0):
    return getattr(env.state.torch, name)[world].clone()


def _pos(env, x, y, slot=2):
    p = _field(env, "position")
    p[slot] = torch.tensor([x, y])
    return dict(world=0, position=p)


def _vec(env, name, value, slot=1):
    v = _field(env, name)
    v[slot] = torch.tensor(value)
    return {"world": 0, name: v}


def _int(env, name, value, slot=0):
    v = _field(env, name)
    v[slot] = value
    return {"world": 0, name: v}


BAD_STATES = [
    ("position_x_eq_width", lambda e: _pos(e, CFG.width, 5.0), ["position", f"[0, {CFG.width})"]),
    ("position_y_eq_height", lambda e: _pos(e, 5.0, CFG.height), ["position", f"[0, {CFG.height})"]),
    ("position_negative", lambda e: _pos(e, -0.5, 5.0), ["position", f"[0, {CFG.width})"]),
    ("position_far", lambda e: _pos(e, 1e6, 5.0), ["position"]),
    ("position_nan", lambda e: _pos(e, float("nan"), 5.0), ["position", "finite"]),
    ("position_inf", lambda e: _pos(e, 5.0, float("inf")), ["position", "finite"]),
    (
        "position_all_worlds",
        lambda e: dict(
            position=torch.where(
                torch.arange(W)[:, None, None] == W - 1, torch.full((W, C, 2), CFG.width), e.state.torch.position
            )
        ),
        ["position"],
    ),
    ("velocity_nan", lambda e: _vec(e, "velocity", [float("nan"), 0.0]), ["velocity", "finite"]),
    ("velocity_inf", lambda e: _vec(e, "velocity", [0.0, float("-inf")]), ["velocity", "finite"]),
    ("acceleration_nan", lambda e: _vec(e, "acceleration", [float("nan"), 0.0]), ["acceleration", "finite"]),
    ("heading_not_unit", lambda e: _vec(e, "heading", [0.5, 0.0]), ["heading", "unit"]),
    ("heading_zero", lambda e: _vec(e, "heading", [0.0, 0.0]), ["heading", "unit"]),
    ("heading_nan", lambda e: _vec(e, "heading", [float("nan"), 1.0]), ["heading", "finite"]),
    ("age_negative", lambda e: _int(e, "age", -1), ["age", ">= 0"]),
    ("replication_age_negative", lambda e: _int(e, "replication_age", -5), ["replication_age", ">= 0"]),
    ("starvation_negative", lambda e: _int(e, "starvation", -1, slot=C - 1), ["starvation", ">= 0"]),
    ("world_step_negative", lambda e: dict(world=1, world_step=-1), ["world_step", ">= 0"]),
    (
        "world_step_max_steps",
        lambda e: dict(world=1, world_step=CFG.max_steps),
        ["world_step", f"[0, {CFG.max_steps - 1}]"],
    ),
    (
        "world_step_all_worlds",
        lambda e: dict(world_step=torch.tensor([0, CFG.max_steps + 5, 0])),
        ["world_step", f"[0, {CFG.max_steps - 1}]"],
    ),
    ("episode_negative", lambda e: dict(world=2, episode=-1), ["episode", ">= 0"]),
    ("unknown_field", lambda e: dict(world=0, mass=torch.ones(C)), ["mass", "settable", "position"]),
    ("unknown_output_field", lambda e: dict(world=0, reward=torch.zeros(C)), ["reward", "settable"]),
    (
        "shape_one_world_missing_slot",
        lambda e: dict(world=0, position=torch.ones(C - 1, 2)),
        ["position", f"shape [{C}, 2]"],
    ),
    (
        "shape_one_world_3d_vectors",
        lambda e: dict(world=0, velocity=torch.zeros(C, 3)),
        ["velocity", f"shape [{C}, 2]"],
    ),
    (
        "shape_all_worlds_for_one",
        lambda e: dict(world=0, alive=torch.ones(W, C, dtype=torch.bool)),
        ["alive", f"shape [{C}]"],
    ),
    ("shape_one_world_for_all", lambda e: dict(age=torch.zeros(C, dtype=torch.int32)), ["age", f"shape [{W}, {C}]"]),
    (
        "shape_world_step_vector",
        lambda e: dict(world=0, world_step=torch.zeros(W, dtype=torch.int32)),
        ["world_step", "shape []"],
    ),
    ("world_out_of_range", lambda e: dict(world=W, age=torch.zeros(C, dtype=torch.int32)), ["world=", f"[0, {W - 1}]"]),
    ("world_negative", lambda e: dict(world=-1, age=torch.zeros(C, dtype=torch.int32)), ["world=", f"[0, {W - 1}]"]),
    ("world_float", lambda e: dict(world=1.0, age=torch.zeros(C, dtype=torch.int32)), ["world=", f"[0, {W - 1}]"]),
    ("world_string", lambda e: dict(world="0", age=torch.zeros(C, dtype=torch.int32)), ["world=", f"[0, {W - 1}]"]),
    # A valid field together with a bad one: nothing at all may be written.
    (
        "valid_position_bad_velocity",
        lambda e: {**_pos(e, 1.0, 2.0), "velocity": _vec(e, "velocity", [float("nan"), 0])["velocity"]},
        ["velocity"],
    ),
    (
        "valid_alive_bad_age",
        lambda e: dict(world=0, alive=torch.zeros(C, dtype=torch.bool), age=torch.full((C,), -3, dtype=torch.int32)),
        ["age"],
    ),
]


@pytest.mark.parametrize("make,expected", [(m, e) for _, m, e in BAD_STATES], ids=[i for i, _, _ in BAD_STATES])
def test_bad_set_state_rejected_and_state_unchanged(pair, make, expected):
    env, twin, gen = pair
    kwargs = make(env)
    before = state_of(env)
    with pytest.raises(ValueError) as err:
        env.set_state(**kwargs)
    for text in expected:
        assert text in str(err.value), (text, str(err.value))
    assert_same_state(state_of(env), before)
    step_both(env, twin, gen)


def test_valid_set_state_applies_to_both(pair):
    """Positive control: the same valid set_state on both envs keeps them identical and takes effect."""
    env, twin, gen = pair
    p = _field(env, "position", world=1)
    p[0] = torch.tensor([0.0, CFG.height - 1e-3])  # both edges of the allowed range
    h = _field(env, "heading", world=1)
    h[0] = torch.tensor([0.6, -0.8])
    for e in (env, twin):
        e.set_state(world=1, position=p, heading=h, age=torch.zeros(C, dtype=torch.int32), world_step=CFG.max_steps - 1)
    assert torch.equal(env.state.torch.position[1], p)
    assert int(env.state.torch.world_step[1]) == CFG.max_steps - 1
    a = random_actions(env, gen)
    _, _, _, truncated, info = env.step(a)
    twin.step(a)
    assert bool(info["episode_ended"][1]) and int(info["episode_length"][1]) == CFG.max_steps
    assert truncated["prey"][1].all() and truncated["predator"][1].all()
    assert_same_state(state_of(env), state_of(twin))
    step_both(env, twin, gen)


def test_fractional_negative_age_rejected(pair):
    env, twin, gen = pair
    before = state_of(env)
    age = _field(env, "age").double()
    age[0] = -0.5
    try:
        with pytest.raises(ValueError, match="age"):
            env.set_state(world=0, age=age)
    finally:
        # keep the pair in step for the tests after this one, whatever happened
        if not torch.equal(env.state.torch.age, before["tensors"]["age"]):
            env.load_state_dict(before)
    assert_same_state(state_of(env), before)
