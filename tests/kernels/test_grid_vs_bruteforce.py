"""The cell-list neighbour search against an all-pairs brute force, on thousands of random worlds.

Every world of a batch gets its own random configuration (positions on a 0.5 px grid, so squared
distances are exact in float32 and ties are ties in both implementations). The kernels' observed
slots (which agents fill each observation slot, in order) and contact partners must equal the brute
force exactly, dense and sparse, with the field of view on and off, and with unlimited view distance.
"""

from __future__ import annotations

import dataclasses
import math
import zlib

import numpy as np
import pytest

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.env import SINGLE_CELL_CAPACITY

NUM_WORLDS = 1500


def torus_d2(pos, width, height):
    """[W, C, C] squared torus distances (float64, exact for 0.5-grid inputs) and displacements i->j."""
    d = pos[:, None, :, :] - pos[:, :, None, :]
    for axis, length in ((0, width), (1, height)):
        c = d[..., axis]
        c[c > length / 2] -= length
        c[c < -length / 2] += length
    return (d**2).sum(-1), d


def brute_force(cfg: AquariumConfig, pos, heading, alive):
    """Observed slots [W, C, K] (-1 empty) and contact partners [W, C] from all pairs."""
    W, C = alive.shape
    Pc = cfg.prey_capacity
    is_prey = np.arange(C) < Pc
    d2, d = torus_d2(pos, cfg.width, cfg.height)
    types = [cfg.prey if p else cfg.predator for p in is_prey]
    k_max = max(t.predator_slots + t.prey_slots for t in types)
    slots = np.full((W, C, k_max), -1, np.int64)
    partner = np.full((W, C), -1, np.int64)
    idx = np.arange(C)
    for i in range(C):
        t = types[i]
        other = alive & alive[:, i : i + 1] & (idx != i)[None, :]
        visible = other & (d2[:, i] <= t.view_distance**2)
        if cfg.fov_enabled:
            dist = np.sqrt(d2[:, i])
            cos = (d[:, i] * heading[:, i, None, :]).sum(-1) / np.where(dist > 0, dist, 1.0)
            visible &= (dist == 0) | (cos >= math.cos(math.radians(t.fov_angle / 2)))
        same = other & (is_prey == is_prey[i])[None, :] & (d2[:, i] < (2 * t.radius) ** 2)
        for w in range(W):
            col = 0
            for block_is_prey, k in ((False, t.predator_slots), (True, t.prey_slots)):
                cand = np.nonzero(visible[w] & (is_prey == block_is_prey))[0]
                cand = cand[np.lexsort((cand, d2[w, i, cand]))][:k]  # (distance, slot) order
                slots[w, i, col : col + len(cand)] = cand
                col += k
            cand = np.nonzero(same[w])[0]
            if len(cand):
                partner[w, i] = cand[np.lexsort((cand, d2[w, i, cand]))][0]
    return slots, partner


def random_state(rng, cfg: AquariumConfig, W: int, axis_headings: bool):
    C = cfg.capacity
    pos = np.stack(
        [rng.integers(0, int(2 * cfg.width), (W, C)) / 2.0, rng.integers(0, int(2 * cfg.height), (W, C)) / 2.0], axis=-1
    )
    # Clusters: copy some agents onto others (exact overlaps) or half a world away (ties at L/2).
    dup = rng.random((W, C)) < 0.1
    src = rng.integers(0, C, (W, C))
    pos[dup] = pos[np.nonzero(dup)[0], src[dup]]
    if axis_headings:  # cone edges at irrational slopes: no exact-boundary cases between float widths
        angles = rng.integers(0, 4, (W, C)) * (math.pi / 2)
    else:
        angles = rng.random((W, C)) * 2 * math.pi
    heading = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    alive = rng.random((W, C)) < 0.9
    return pos, heading, alive


def with_types(cfg: AquariumConfig, **per_type) -> AquariumConfig:
    return dataclasses.replace(
        cfg, prey=dataclasses.replace(cfg.prey, **per_type), predator=dataclasses.replace(cfg.predator, **per_type)
    )


CASES = {
    "dense": AquariumConfig(width=300.0, height=240.0, prey_count=14, predator_count=3),
    "sparse": AquariumConfig(width=1600.0, height=1000.0, prey_count=12, predator_count=2),
    "fov-off": AquariumConfig(width=500.0, height=500.0, prey_count=14, predator_count=3, fov_enabled=False),
    "unlimited": with_types(
        AquariumConfig(width=2000.0, height=900.0, prey_count=10, predator_count=3, fov_enabled=False),
        view_distance=math.inf,
    ),
    "unlimited-fov": with_types(
        AquariumConfig(width=700.0, height=700.0, prey_count=10, predator_count=2), view_distance=math.inf
    ),
    "more-slots": with_types(
        AquariumConfig(width=400.0, height=400.0, prey_count=14, predator_count=4), predator_slots=3, prey_slots=5
    ),
    "tiny-cells": AquariumConfig(width=800.0, height=800.0, prey_count=14, predator_count=3, grid_cell_size=45.0),
    # Worlds this small are one cell by default; the same worlds cut into cells exercise the ring search.
    "dense-cells": AquariumConfig(width=300.0, height=240.0, prey_count=14, predator_count=3, grid_cell_size=70.0),
    "unlimited-fov-cells": with_types(
        AquariumConfig(width=700.0, height=700.0, prey_count=10, predator_count=2, grid_cell_size=90.0),
        view_distance=math.inf,
    ),
    # More slots than SINGLE_CELL_CAPACITY: cells chosen automatically (fewer worlds: the brute force is slow).
    "crowd": AquariumConfig(width=1200.0, height=900.0, prey_count=72, predator_count=6),
}
WORLDS = {"crowd": 100}


@pytest.mark.parametrize("name", list(CASES))
def test_observed_slots_and_contacts_match_brute_force(device, name):
    cfg = CASES[name]
    W = WORLDS.get(name, NUM_WORLDS)
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    env = BatchedAquarium(cfg, num_worlds=W, device=device, seed=1)
    assert (env.grid_dims == (1, 1)) == (cfg.capacity <= SINGLE_CELL_CAPACITY and cfg.grid_cell_size is None)
    pos, heading, alive = random_state(rng, cfg, W, axis_headings=name != "unlimited")
    env.set_state(position=pos.astype(np.float32), heading=heading.astype(np.float32), alive=alive)
    expected_slots, expected_partner = brute_force(
        cfg, pos, env.state.torch.heading.cpu().numpy().astype(np.float64), alive
    )
    Pc = cfg.prey_capacity
    got = {"prey": env.observed_slot["prey"].cpu().numpy(), "predator": env.observed_slot["predator"].cpu().numpy()}
    for type_name, rows in (("prey", slice(0, Pc)), ("predator", slice(Pc, None))):
        want = expected_slots[:, rows, : got[type_name].shape[2]]
        mismatch = np.argwhere((got[type_name] != want).any(-1))
        assert len(mismatch) == 0, (
            f"{name}: {len(mismatch)} {type_name} observers differ, first world/row "
            f"{mismatch[0]}: kernel {got[type_name][tuple(mismatch[0])]} "
            f"brute force {want[tuple(mismatch[0])]}"
        )
    partner = env.state.torch.contact_partner.cpu().numpy()
    partner = np.where(alive, partner, -1)
    bad = np.argwhere(partner != expected_partner)
    assert len(bad) == 0, f"{name}: contact partners differ at {bad[:5].tolist()}"
    # Sanity of the test itself: the cases exercise both empty and full slot blocks and contacts.
    assert (expected_slots >= 0).any() and (expected_slots < 0).any()
    assert (expected_partner >= 0).any() or name in ("sparse", "unlimited")


def test_capture_pairs_match_brute_force(device):
    """Captures (prey within r_prey + r_pred of a predator after the move) on many random worlds."""
    cfg = AquariumConfig(width=300.0, height=300.0, prey_count=10, predator_count=3, respawn_captured_prey=False)
    W = NUM_WORLDS
    rng = np.random.default_rng(7)
    env = BatchedAquarium(cfg, num_worlds=W, device=device, seed=3)
    pos, heading, alive = random_state(rng, cfg, W, axis_headings=True)
    zero = np.zeros_like(pos, dtype=np.float32)
    env.set_state(
        position=pos.astype(np.float32),
        heading=heading.astype(np.float32),
        alive=alive,
        velocity=zero,
        acceleration=zero,
    )
    import torch

    actions = {
        "prey": torch.zeros(W, cfg.prey_capacity, dtype=torch.int64, device=env.torch_device),
        "predator": torch.zeros(W, cfg.predator_count, dtype=torch.int64, device=env.torch_device),
    }
    before_alive = env.state.torch.alive.clone().cpu().numpy()
    # Positions after the move are what captures use: read them back from a copy of the env's motion.
    _, _, terminated, _, info = env.step(actions)
    # Rebuild the moved positions by hand: from rest, action UP moves prey by k=1 and predators by 0.6
    # unless a same-type contact bounced them (then V' = V + b*unit = unit push, clamped).
    moved = pos.copy()
    d2, d = torus_d2(pos, cfg.width, cfg.height)
    Pc = cfg.prey_capacity
    for i in range(cfg.capacity):
        t = cfg.prey if i < Pc else cfg.predator
        same = np.arange(cfg.capacity) < Pc if i < Pc else np.arange(cfg.capacity) >= Pc
        contact = (
            alive
            & alive[:, i : i + 1]
            & same[None, :]
            & (np.arange(cfg.capacity) != i)[None, :]
            & (d2[:, i] < (2 * t.radius) ** 2)
        )
        key = np.where(contact, d2[:, i], np.inf)  # argmin takes the first (lowest slot) of equal minima
        j = key.argmin(1)
        has = np.isfinite(key.min(1))
        push = -d[np.arange(W), i, j]
        norm = np.linalg.norm(push, axis=1, keepdims=True)
        push = np.where(norm > 0, push / np.where(norm > 0, norm, 1) * t.bounce_strength, 0.0)
        step = np.where(has[:, None], push, np.array([0.0, -t.max_acceleration]))
        moved[:, i] = np.mod(pos[:, i] + step, [cfg.width, cfg.height])
    d2m, _ = torus_d2(moved, cfg.width, cfg.height)
    contact = (cfg.prey.radius + cfg.predator.radius) ** 2
    pred_alive = before_alive[:, Pc:]
    expected = ((d2m[:, :Pc, Pc:] < contact) & pred_alive[:, None, :]).any(-1) & before_alive[:, :Pc]
    # Skip worlds where a distance is within float rounding of the capture threshold.
    near = (np.abs(d2m[:, :Pc, Pc:] - contact) < 1e-2).any((1, 2))
    got = terminated["prey"].cpu().numpy()
    assert expected[~near].any(), "no captures generated: the test would not catch a miss"
    np.testing.assert_array_equal(got[~near], expected[~near])
    np.testing.assert_array_equal(info["captures"].cpu().numpy()[~near], expected[~near].sum(1))
