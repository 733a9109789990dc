"""Predator confusion (docs/model.md step 5, `capture_rule="confusion"`): each predator that is not
handling attacks the nearest prey it overlaps, captured with probability p0 / (1 + c k), k the other
live prey it sees (view distance, field of view) whose bearing lies within `confusion_angle` of the
target's; one draw per attack; a failed attack starts a handling time of `handling_steps` steps.

Hand-made worlds, each set into many worlds of one batch (every world draws its own numbers), on the
three capture paths: the fused step, the staged step on whole-world lists and the staged step on cell
lists (40 px cells, far smaller than the predator's 200 px view). The kernels against the float64
reference on random states are in test_kernels_vs_reference.py (`predator_confusion_*`), the fused
step against the staged one bit for bit in test_world_step.py, the parameters' ranges in
tests/core/test_config_validation.py.

Geometry: every agent cruises north at its full speed (prey 4, predator 5 px/step), so the prey keep
their distances and the predator, 2 px south of prey 0 at X, ends each step 1 px nearer the prey's line:
after the first move it is 1 px south of prey 0, heading north, and stays in contact for dozens of
steps. A neighbour set at offset `o` from prey 0 lies at `o + (0, -1)` from the predator after the move.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from test_capture_confusion import PATHS, WORLDS, X, captured_prey, make_env, set_every_world, step_up

from aquarium_warp import BatchedAquarium
from aquarium_warp.config import AquariumConfig

PREDATOR_AT = (X[0], X[1] + 2.0)
FAR = (400.0, 100.0)  # a prey out of every predator's view and window


def bearing_offset(degrees: float, distance: float) -> tuple[float, float]:
    """The offset from prey 0 of a prey `distance` px from the predator (after the move), at `degrees`
    clockwise from the target's bearing (north)."""
    a = math.radians(degrees)
    return (distance * math.sin(a), -distance * math.cos(a) + 1.0)


def near_target(offset: tuple[float, float], x: tuple[float, float] = X) -> tuple[float, float]:
    """The position of a prey at `offset` from prey 0 at `x`, on the 800 x 800 torus."""
    return ((x[0] + offset[0]) % 800.0, (x[1] + offset[1]) % 800.0)


def confusion_env(path: str, device: str, num_worlds: int = WORLDS, **world) -> BatchedAquarium:
    world.setdefault("prey_count", 2)
    return make_env(path, device, num_worlds=num_worlds, capture_rule="confusion", **world)


# Prey 0 is the target; prey 1 lies at the given offset from it. c = 1e15: with k >= 1 the chance is
# 1 / (1 + 1e15), which no draw of [0, 1) in 2**-24 steps other than 0 falls below; with k = 0 it is 1.
# name -> (offset of prey 1, confusion_angle, predator fov_angle, predator view_distance, captured)
HAND_CASES = {
    "a prey ahead, seen, in the window: counted": (bearing_offset(0.0, 50.0), 15.0, 150.0, 200.0, False),
    "a prey behind the predator, outside its FOV: not counted": (
        bearing_offset(180.0, 60.0),
        180.0,
        150.0,
        200.0,
        True,
    ),
    "the same prey with a 360-degree FOV: counted": (bearing_offset(180.0, 60.0), 180.0, 360.0, 200.0, False),
    "a prey beyond the view distance: not counted": (bearing_offset(0.0, 205.0), 15.0, 150.0, 200.0, True),
    "a prey just inside the view distance: counted": (bearing_offset(0.0, 195.0), 15.0, 150.0, 200.0, False),
    "a prey with an unlimited view far away: counted": (bearing_offset(0.0, 390.0), 15.0, 150.0, math.inf, False),
    "a prey 16 degrees off, window 15: not counted": (bearing_offset(16.0, 100.0), 15.0, 150.0, 200.0, True),
    "a prey 14 degrees off, window 15: counted": (bearing_offset(14.0, 100.0), 15.0, 150.0, 200.0, False),
    "a prey 14 degrees to the other side: counted": (bearing_offset(-14.0, 100.0), 15.0, 150.0, 200.0, False),
    # Prey 0 at y = 10 - 4 after the move, prey 1 at y = 10 - 51 wraps to 755: 51 px north across the seam.
    "a prey ahead across the seam: counted": ((0.0, -50.0), 15.0, 150.0, 200.0, False),
}


@pytest.mark.parametrize("case", list(HAND_CASES))
@pytest.mark.parametrize("path", list(PATHS))
def test_only_prey_the_predator_sees_near_its_target_confuse_it(case, path, device):
    offset, angle, fov, view, want = HAND_CASES[case]
    predator = dataclasses.replace(AquariumConfig().predator, fov_angle=fov, view_distance=view)
    x = X if "seam" not in case else (400.0, 10.0)
    env = confusion_env(path, device, capture_confusion=1e15, confusion_angle=angle, predator=predator)
    set_every_world(env, [x, near_target(offset, x)], [(x[0], x[1] + 2.0)])
    step_up(env)
    captured = captured_prey(env)
    assert captured[:, 0].tolist() == [want] * WORLDS, case
    assert not captured[:, 1].any()


@pytest.mark.parametrize("path", list(PATHS))
def test_a_failed_attack_starts_the_handling_time(path, device):
    """One draw per attack: an attack that fails (k = 1, c = 1e15) sets the handling counter to H = 5;
    then, though every attack would now capture (c = 0) and the prey stays in contact, the predator
    counts down for H steps without attacking, and captures on the step after."""
    env = confusion_env(path, device, capture_confusion=1e15, handling_steps=5)
    set_every_world(env, [X, near_target(bearing_offset(0.0, 60.0))], [PREDATOR_AT])
    handling = []
    captured = []
    for step in range(7):
        out = step_up(env)
        if step == 0:
            env.set_params(capture_confusion=0.0)
        handling.append(env.state.torch.handling[:, env.prey_capacity].tolist())
        captured.append(out.info["captures"].tolist())
    assert handling == [[h] * WORLDS for h in (5, 4, 3, 2, 1, 0, 0)]
    assert captured == [[0] * WORLDS] * 6 + [[1] * WORLDS]
    assert captured_prey(env)[:, 0].all()


@pytest.mark.parametrize("path", list(PATHS))
def test_no_handling_time_attacks_again_next_step(path, device):
    """H = 0: a failed attack leaves the counter at 0, so the predator attacks again at once: with the
    confusion gone (c = 0) its next attack captures."""
    env = confusion_env(path, device, capture_confusion=1e15, handling_steps=0)
    set_every_world(env, [X, near_target(bearing_offset(0.0, 60.0))], [PREDATOR_AT])
    first = step_up(env)
    assert first.info["captures"].tolist() == [0] * WORLDS
    assert env.state.torch.handling[:, env.prey_capacity].tolist() == [0] * WORLDS
    env.set_params(capture_confusion=0.0)
    second = step_up(env)
    assert second.info["captures"].tolist() == [1] * WORLDS and captured_prey(env)[:, 0].all()


@pytest.mark.parametrize("path", list(PATHS))
def test_no_confusion_captures_at_the_first_contact(path, device):
    """c = 0 and p0 = 1: the first attack captures, whatever the predator sees (three prey in its window),
    the handling counter stays 0 and the predator is fed (starvation 0, then +1)."""
    env = confusion_env(path, device, prey_count=4, capture_confusion=0.0, capture_probability=1.0)
    near = [near_target(bearing_offset(a, d)) for a, d in ((0.0, 60.0), (5.0, 110.0), (-5.0, 160.0))]
    set_every_world(env, [X, *near], [PREDATOR_AT])
    env.state.torch.starvation[:, env.prey_capacity] = 9
    out = step_up(env)
    assert captured_prey(env).tolist() == [[True, False, False, False]] * WORLDS
    assert out.rewards["predator"].tolist() == [[10.0]] * WORLDS
    t = env.state.torch
    assert t.handling[:, env.prey_capacity].tolist() == [0] * WORLDS
    assert t.starvation[:, env.prey_capacity].tolist() == [1] * WORLDS


@pytest.mark.parametrize("path", list(PATHS))
def test_the_target_is_the_nearest_overlapping_prey_ties_to_the_lower_slot(path, device):
    """Two prey overlap the predator: the nearer one is attacked (and captured, c = 0), the other not; at
    equal distances the lower slot."""
    env = confusion_env(path, device, capture_confusion=0.0)
    right, left = (X[0] + 50.0, X[1]), X  # 50 px apart: no contact between the prey
    predator = (X[0] + 25.0, X[1] + 2.0)  # after the move 25 px from each in x, 1 px in y
    set_every_world(env, [right, left], [predator])
    step_up(env)
    assert captured_prey(env).tolist() == [[True, False]] * WORLDS
    set_every_world(env, [right, left], [(X[0] + 24.0, X[1] + 2.0)])  # now nearer to prey 1
    step_up(env)
    assert captured_prey(env).tolist() == [[False, True]] * WORLDS


@pytest.mark.parametrize("path", list(PATHS))
def test_a_handling_predator_in_contact_is_no_capturer(path, device):
    """Predator A captures the prey (c = 0); predator B overlaps it too but is handling, so it neither
    attacks nor captures: with `catch_share_radius` 0 the reward is A's alone (under density dilution
    both would share it) and B is not fed."""
    env = confusion_env(
        path, device, predator_count=2, capture_confusion=0.0, catch_share_radius=0.0, handling_steps=10
    )
    set_every_world(env, [X, FAR], [PREDATOR_AT, (X[0] + 30.0, X[1] + 2.0)])
    Pc = env.prey_capacity
    t = env.state.torch
    t.handling[:, Pc + 1] = 4
    t.starvation[:, Pc : Pc + 2] = 7
    out = step_up(env)
    assert captured_prey(env)[:, 0].all()
    assert out.rewards["predator"].tolist() == [[10.0, 0.0]] * WORLDS
    assert t.starvation[:, Pc : Pc + 2].tolist() == [[1, 8]] * WORLDS
    assert t.handling[:, Pc : Pc + 2].tolist() == [[0, 3]] * WORLDS


@pytest.mark.parametrize("path", ["fused", "cells"])
def test_captured_fraction_matches_olsons_chance(path, device):
    """Olson's strength c = 1 with k = 3 prey seen in the window: in 4,000 independent worlds the target
    is captured in a fraction within 4 binomial standard deviations of 1 / (1 + 3)."""
    worlds, p = 4000, 0.25
    env = confusion_env(path, device, num_worlds=worlds, prey_count=5, capture_confusion=1.0, confusion_angle=30.0)
    seen = [near_target(bearing_offset(a, d)) for a, d in ((-20.0, 70.0), (0.0, 120.0), (25.0, 170.0))]
    set_every_world(env, [X, *seen, FAR], [PREDATOR_AT])
    step_up(env)
    captured = captured_prey(env)
    assert not captured[:, 1:].any()
    fraction = captured[:, 0].mean()
    assert abs(fraction - p) <= 4.0 * math.sqrt(p * (1.0 - p) / worlds), fraction
    # each failed attack started a handling time, each capture none
    handling = env.state.torch.handling[:, env.prey_capacity].cpu().numpy()
    np.testing.assert_array_equal(handling, np.where(captured[:, 0], 0, 10))


def test_same_seed_same_actions_same_trajectory(device):
    """Under predator confusion the same seed and actions give the same trajectory, every array bit for
    bit on the CPU (within float tolerance on a GPU); another seed draws other attacks."""

    def run(seed: int) -> list:
        cfg = AquariumConfig(
            width=260.0, height=240.0, prey_count=12, predator_count=3, capture_rule="confusion", capture_confusion=1.0
        )
        env = BatchedAquarium(cfg, num_worlds=6, device=device, seed=seed)
        gen = torch.Generator().manual_seed(3)
        states, failures = [], 0
        for _ in range(150):
            actions = {
                t: torch.randint(0, 16, (6, getattr(env, f"{t}_capacity")), generator=gen).to(env.torch_device)
                for t in ("prey", "predator")
            }
            env.step(actions)
            failures += int((env.state.torch.handling == cfg.handling_steps).sum())
            states.append({name: getattr(env.state.torch, name).cpu().clone() for name in env.state.arrays()})
        assert failures > 5
        return states

    a, b, other = run(5), run(5), run(6)
    for step, (x, y) in enumerate(zip(a, b)):
        for name in x:
            if device == "cpu" or not x[name].is_floating_point():
                assert torch.equal(x[name], y[name]), (name, step)
            else:
                torch.testing.assert_close(x[name], y[name])
    assert not torch.equal(a[-1]["position"], other[-1]["position"])


def test_the_handling_counter_is_state_like_the_others():
    """The handling counter travels in `state_dict` and comes back with `load_state_dict` (the next steps
    then equal the saved env's, bit for bit); `set_state` refuses a counter outside [0, 1e6] in one line;
    an episode's start clears it."""
    cfg = AquariumConfig(
        width=260.0, height=240.0, prey_count=12, predator_count=3, capture_rule="confusion", capture_confusion=2.0
    )
    env = BatchedAquarium(cfg, num_worlds=4, device="cpu", seed=2)
    gen = torch.Generator().manual_seed(4)

    def actions():
        return {
            t: torch.randint(0, 16, (4, getattr(env, f"{t}_capacity")), generator=gen) for t in ("prey", "predator")
        }

    while not env.state.torch.handling.any():
        env.step(actions())
    saved = env.state_dict()
    assert torch.equal(saved["tensors"]["handling"], env.state.torch.handling)
    plan = [actions() for _ in range(20)]
    for a in plan:
        env.step(a)
    after = {name: getattr(env.state.torch, name).clone() for name in ("position", "handling", "alive")}
    env.load_state_dict(saved)
    assert torch.equal(env.state.torch.handling, saved["tensors"]["handling"])
    for a in plan:
        env.step(a)
    for name, value in after.items():
        assert torch.equal(getattr(env.state.torch, name), value), name
    for bad in (-1, 10**6 + 1):
        handling = env.state.torch.handling.clone()
        handling[0, -1] = bad
        with pytest.raises(ValueError, match=r"^handling holds .* must be >= 0 and <= 1000000"):
            env.set_state(world=None, handling=handling)
    env.reset(seed=2)
    assert not env.state.torch.handling.any()
