"""Capture confusion (docs/model.md step 5): a contact captures prey j with probability
p0 / (1 + c k_j), k_j the other live prey strictly within `confusion_radius` of j at the moved
positions, decided by one draw per contacted prey and step.

Hand-made worlds, each set into many worlds of one batch (every world draws its own numbers), on the
three capture paths: the fused step (whole-world lists), the staged step on whole-world lists and the
staged step on cell lists. The kernel against the float64 reference on random states, with the kernels'
draws, is in test_kernels_vs_reference.py (the `capture_confusion_*` configs); the fused step against
the staged one bit for bit in test_world_step.py; the parameters' ranges in
tests/core/test_config_validation.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium

UP = 0  # action 0 of the 16-action default: steer north
WORLDS = 64
# name -> (step_kernel, grid_cell_size)
PATHS = {"fused": ("fused", None), "stages": ("stages", None), "cells": ("stages", 40.0)}
# Agents cruising north at full speed with their acceleration along the velocity move exactly (0, -s):
# prey (default s = 4) keep their distances to each other exactly.
PREY_CRUISE = {"velocity": (0.0, -4.0), "acceleration": (0.0, -1.0)}
PREDATOR_CRUISE = {"velocity": (0.0, -5.0), "acceleration": (0.0, -0.6)}


def make_env(path: str, device: str, num_worlds: int = WORLDS, seed: int = 0, **world) -> BatchedAquarium:
    step_kernel, cell = PATHS[path]
    cfg = AquariumConfig(grid_cell_size=cell, **world)
    env = BatchedAquarium(cfg, num_worlds=num_worlds, device=device, seed=seed, step_kernel=step_kernel)
    assert (env.grid_dims == (1, 1)) == (cell is None)
    return env


def set_every_world(env: BatchedAquarium, prey: list, predators: list, **extra) -> None:
    """Every world to the same state: `prey` and `predators` are lists of positions (None: a dead
    slot), all cruising north; `extra` per-slot fields ([C] arrays) override."""
    C, W = env.capacity, env.num_worlds
    fields = {
        "position": np.zeros((C, 2)),
        "velocity": np.zeros((C, 2)),
        "acceleration": np.zeros((C, 2)),
        "heading": np.tile([0.0, -1.0], (C, 1)),
        "alive": np.zeros(C, bool),
    }
    for slot, pos, cruise in [(i, p, PREY_CRUISE) for i, p in enumerate(prey)] + [
        (env.prey_capacity + i, p, PREDATOR_CRUISE) for i, p in enumerate(predators)
    ]:
        if pos is not None:
            fields["position"][slot] = pos
            fields["velocity"][slot] = cruise["velocity"]
            fields["acceleration"][slot] = cruise["acceleration"]
            fields["alive"][slot] = True
    fields.update(extra)
    env.set_state(
        world=None,
        **{name: np.broadcast_to(np.asarray(v), (W, *np.shape(v))).copy() for name, v in fields.items()},
        world_step=np.zeros(W, np.int32),
    )


def step_up(env: BatchedAquarium):
    actions = {
        t: torch.full((env.num_worlds, getattr(env, f"{t}_capacity")), UP, dtype=torch.int64, device=env.torch_device)
        for t in ("prey", "predator")
    }
    return env.step(actions)


def captured_prey(env: BatchedAquarium) -> np.ndarray:
    """[W, prey slots]: the prey captured in the last step."""
    return env.state.torch.captured[:, : env.prey_capacity].cpu().numpy()


# Prey 0 at X is in contact with the predator (1 px apart after the move); prey 1, if any, lies at the
# given offset from prey 0 (dead with `neighbour_alive` False). confusion_radius 50, world 800 x 800.
X = (10.0, 400.0)
# name -> (capture_probability, capture_confusion, neighbour offset or None, neighbour alive, captured)
HAND_CASES = {
    "lone prey, p0 = 1, c > 0: always captured": (1.0, 4.0, None, True, True),
    "lone prey, p0 = 0: never captured": (0.0, 0.0, None, True, False),
    "p0 = 0 with a neighbour and confusion: never captured": (0.0, 4.0, (45.0, 0.0), True, False),
    "neighbour across the seam (49.5 px): confused": (1.0, 1e15, (-49.5, 0.0), True, False),
    "neighbour exactly at confusion_radius across the seam: not counted": (1.0, 1e15, (-50.0, 0.0), True, True),
    "neighbour within the radius but dead: not counted": (1.0, 1e15, (0.0, 45.0), False, True),
    "neighbour beyond the radius: not counted": (1.0, 1e15, (0.0, 60.0), True, True),
}


@pytest.mark.parametrize("case", list(HAND_CASES))
@pytest.mark.parametrize("path", list(PATHS))
def test_hand_cases(case, path, device):
    """Prey 0's contact captures in every world or in none (chances 1 and 0, or 1 / (1 + 1e15), which no
    draw of [0, 1) in 2**-24 steps other than 0 falls below)."""
    p0, c, offset, neighbour_alive, want = HAND_CASES[case]
    env = make_env(path, device, prey_count=2, capture_probability=p0, capture_confusion=c, confusion_radius=50.0)
    neighbour = None if offset is None else ((X[0] + offset[0]) % 800.0, X[1] + offset[1])
    far = (400.0, 100.0)  # a lone second prey where the case has no neighbour
    set_every_world(env, [X, neighbour or far], [(X[0], X[1] + 2.0)])
    if offset is not None and not neighbour_alive:
        alive = env.state.torch.alive.clone()
        alive[:, 1] = False
        env.set_state(world=None, alive=alive)
    step_up(env)
    captured = captured_prey(env)
    assert captured[:, 0].tolist() == [want] * WORLDS, case
    assert not captured[:, 1].any()


@pytest.mark.parametrize("path", list(PATHS))
def test_failed_attempt_is_no_capture(path, device):
    """A contact that does not capture (p0 = 0, the predator that never captures) is simply no capture:
    no penalty, no share, no capture counted, the prey ages and stays alive (respawn off too), the
    predator is not fed and starves by one step."""
    env = make_env(path, device, prey_count=2, capture_probability=0.0, respawn_captured_prey=False)
    set_every_world(env, [X, (400.0, 100.0)], [(X[0], X[1] + 2.0)], age=np.array([5, 5, 0]))
    env.state.torch.starvation[:, 2] = 7
    out = step_up(env)
    t = env.state.torch
    assert out.info["captures"].tolist() == [0] * WORLDS
    assert out.rewards["prey"].tolist() == [[1.0, 1.0]] * WORLDS
    assert out.rewards["predator"].tolist() == [[0.0]] * WORLDS
    assert not out.terminated["prey"].any() and t.alive.all()
    assert t.age[:, :2].tolist() == [[6, 6]] * WORLDS
    assert t.starvation[:, 2].tolist() == [8] * WORLDS


@pytest.mark.parametrize("rule", ["dilution", "confusion"])
@pytest.mark.parametrize("path", list(PATHS))
def test_a_contact_that_does_not_capture_costs_the_contact_penalty(rule, path, device):
    """With `prey_contact_penalty`, the prey in contact that is not captured (p0 = 0: predation removed)
    gets its survival reward minus the penalty, in every step of the contact (under confusion also while
    the predator handles); a prey out of contact (the other one, 40 px from the predator's hit box)
    gets the survival reward alone, and nothing else changes."""
    env = make_env(path, device, prey_count=2, capture_probability=0.0, capture_rule=rule, prey_contact_penalty=7.5)
    set_every_world(env, [X, (X[0] + 60.0, X[1] + 2.0)], [(X[0], X[1] + 2.0)])
    for _ in range(3):  # all cruise north together: the contact holds
        out = step_up(env)
        assert out.rewards["prey"].tolist() == [[1.0 - 7.5, 1.0]] * WORLDS
        assert out.info["captures"].tolist() == [0] * WORLDS and env.state.torch.alive.all()


# The captured fraction of prey 0 over many worlds: (p0, c, k neighbours within the radius) -> p.
STATISTICS = {
    "c = 1, k = 3": (1.0, 1.0, 3, 0.25),
    "p0 = 0.5, no confusion": (0.5, 0.0, 0, 0.5),
    "p0 = 0.6, c = 2, k = 1": (0.6, 2.0, 1, 0.2),
    "c = 4, k = 2": (1.0, 4.0, 2, 1.0 / 9.0),
}


@pytest.mark.parametrize("case", list(STATISTICS))
@pytest.mark.parametrize("path", ["fused", "cells"])
def test_captured_fraction_matches_the_chance(case, path, device):
    """In 4,000 independent worlds, prey 0 in contact with k neighbours 30 px away (out of contact, as
    are the 3 - k prey 300 px away) is captured in a fraction within 4 binomial standard deviations
    of p0 / (1 + c k)."""
    p0, c, k, p = STATISTICS[case]
    worlds = 4000
    small = {"radius": 5.0}  # contact at 10 px
    base = AquariumConfig()
    env = make_env(
        path,
        device,
        num_worlds=worlds,
        prey_count=4,
        capture_probability=p0,
        capture_confusion=c,
        confusion_radius=100.0,
        prey=dataclasses.replace(base.prey, **small),
        predator=dataclasses.replace(base.predator, **small),
    )
    near = [(430.0, 400.0), (370.0, 400.0), (400.0, 430.0)]
    far = [(100.0, 100.0), (700.0, 100.0), (100.0, 700.0)]
    set_every_world(env, [(400.0, 400.0)] + near[:k] + far[k:], [(400.0, 402.0)])
    step_up(env)
    captured = captured_prey(env)
    assert not captured[:, 1:].any()
    fraction = captured[:, 0].mean()
    bound = 4.0 * math.sqrt(p * (1.0 - p) / worlds)
    assert abs(fraction - p) <= bound, (case, fraction, p, bound)


def trajectory(device: str, seed: int, steps: int = 150, capture_probability: float = 0.8, **world) -> list:
    world.setdefault("capture_confusion", 2.0)
    cfg = AquariumConfig(
        width=260.0, height=240.0, prey_count=12, predator_count=3, capture_probability=capture_probability, **world
    )
    env = BatchedAquarium(cfg, num_worlds=6, device=device, seed=seed)
    gen = torch.Generator().manual_seed(3)
    states, captures = [], 0
    for _ in range(steps):
        actions = {
            t: torch.randint(0, 16, (6, getattr(env, f"{t}_capacity")), generator=gen).to(env.torch_device)
            for t in ("prey", "predator")
        }
        captures += int(env.step(actions).info["captures"].sum())
        states.append({name: getattr(env.state.torch, name).cpu().clone() for name in env.state.arrays()})
    assert (captures > 20) == (capture_probability > 0)  # the draws decide many contacts, if any can capture
    return states


def test_same_seed_same_actions_same_trajectory(device):
    """With confusion on, the same seed and actions give the same trajectory, every array bit for bit
    on the CPU (within float tolerance on a GPU); another seed draws other captures."""
    a, b, other = trajectory(device, 5), trajectory(device, 5), trajectory(device, 6)
    for step, (x, y) in enumerate(zip(a, b)):
        for name in x:
            if device == "cpu" or not x[name].is_floating_point():
                assert torch.equal(x[name], y[name]), (name, step)
            else:
                torch.testing.assert_close(x[name], y[name])
    assert not torch.equal(a[-1]["position"], other[-1]["position"])


def test_a_predator_that_never_captures_makes_confusion_irrelevant():
    """With capture_probability 0 no contact captures, whatever c: the worlds with c = 16 and c = 64 run
    the same trajectory bit for bit (the swarm study's no-predation control serves both strengths)."""
    a = trajectory("cpu", 5, capture_probability=0.0, capture_confusion=16.0)
    b = trajectory("cpu", 5, capture_probability=0.0, capture_confusion=64.0)
    for step, (x, y) in enumerate(zip(a, b, strict=True)):
        for name in x:
            assert torch.equal(x[name], y[name]), (name, step)


@pytest.mark.parametrize("path", list(PATHS))
def test_per_world_confusion_in_one_batch(path, device):
    """One batch, per-world values: world 0 never captures (p0 = 0), world 1 has confusion but a lone
    prey (always captured), world 2 none at all (always captured); `set_params` then changes world 0's
    chance between two steps."""
    env = make_env(
        path,
        device,
        num_worlds=3,
        prey_count=2,
        capture_probability=(0.0, 1.0, 1.0),
        capture_confusion=(0.0, 4.0, 0.0),
        confusion_radius=(100.0, 50.0, 100.0),
    )
    state = dict(prey=[X, (400.0, 100.0)], predators=[(X[0], X[1] + 2.0)])
    set_every_world(env, **state)
    step_up(env)
    assert captured_prey(env)[:, 0].tolist() == [False, True, True]
    env.set_params(world=0, capture_probability=1.0)
    set_every_world(env, **state)
    step_up(env)
    assert captured_prey(env)[:, 0].tolist() == [True, True, True]
