"""Hand-computed cases on the Warp kernels: each expected value is worked out from docs/model.md by hand.

Every case sets one small world with `set_state`, then steps it (or only observes it) and compares
with numbers computed here in plain Python, on both step paths (the fused launch that worlds of one
cell take by default, and the launch per stage).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium

UP, EAST, SOUTH, WEST = 0, 4, 8, 12  # actions of the 16-action default


STEP_KERNEL = {"value": "fused"}  # the step path of this test (`step_path`)


@pytest.fixture(autouse=True, params=["fused", "stages"])
def step_path(request):
    STEP_KERNEL["value"] = request.param
    yield request.param
    STEP_KERNEL["value"] = "fused"


def make_env(device, prey_count=2, predator_count=1, **world) -> BatchedAquarium:
    cfg = AquariumConfig(prey_count=prey_count, predator_count=predator_count, **world)
    return BatchedAquarium(cfg, num_worlds=1, device=device, seed=0, step_kernel=STEP_KERNEL["value"])


def place(env: BatchedAquarium, positions, velocities=None, accelerations=None, alive=None, **extra):
    """Set world 0: slots in order (prey first, then predators); headings follow the velocities."""
    C = env.capacity
    pos = np.asarray(positions, dtype=np.float32)
    vel = np.zeros((C, 2), np.float32) if velocities is None else np.asarray(velocities, np.float32)
    acc = np.zeros((C, 2), np.float32) if accelerations is None else np.asarray(accelerations, np.float32)
    speed = np.linalg.norm(vel, axis=1, keepdims=True)
    heading = np.where(speed > 0, vel / np.maximum(speed, 1e-30), np.array([1.0, 0.0], np.float32))
    live = np.ones(C, bool) if alive is None else np.asarray(alive, bool)
    fields = dict(position=pos, velocity=vel, acceleration=acc, heading=heading.astype(np.float32), alive=live)
    fields.update(extra)
    return env.set_state(world=0, **fields)


def act(env: BatchedAquarium, prey, predator):
    actions = {
        "prey": torch.tensor([prey], dtype=torch.int64, device=env.torch_device),
        "predator": torch.tensor([predator], dtype=torch.int64, device=env.torch_device),
    }
    return env.step(actions)


def state(env, name, slot):
    return getattr(env.state.torch, name)[0, slot].cpu().numpy().astype(np.float64)


# --------------------------------------------------------------------------------------------------
# Motion (steps 1-4)
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("agent_type", ["prey", "predator"])
def test_turn_rate_is_asin_of_force_over_mass_over_k(device, agent_type):
    """A steering force at angle acos(-(f/m)/k) from the acceleration turns it by asin((f/m)/k)."""
    env = make_env(device, prey_count=1, predator_count=1)
    p = getattr(env.config, agent_type)
    f_over_m, k = p.max_steering_force / p.mass, p.max_acceleration
    phi = math.acos(-f_over_m / k)  # angle of F from A (A points east)
    slot = 0 if agent_type == "prey" else 1
    desired = np.array([0.0, -p.max_speed])  # action UP
    force_dir = np.array([math.cos(phi), math.sin(phi)])
    velocity = desired - 2.0 * force_dir  # F = D - V = 2 * force_dir, clamped to f
    vel = np.zeros((2, 2))
    vel[slot] = velocity
    acc = np.zeros((2, 2))
    acc[slot] = (k, 0.0)
    place(env, [[100.0, 100.0], [500.0, 500.0]], vel, acc)
    act(env, [UP], [UP])
    a_new = state(env, "acceleration", slot)
    turned = math.atan2(a_new[1], a_new[0])
    assert turned == pytest.approx(math.asin(f_over_m / k), abs=1e-5)
    assert np.linalg.norm(a_new) == pytest.approx(k, rel=1e-6)


def test_acceleration_memory_and_speed_clamp(device):
    """Prey at full speed east, accelerating east, commanded east: V + A = 5 is clamped to 4."""
    env = make_env(device, prey_count=1)
    place(env, [[100.0, 100.0], [500.0, 500.0]], [[4.0, 0.0], [0.0, -1.0]], [[1.0, 0.0], [0.0, 0.0]])
    act(env, [EAST], [UP])
    np.testing.assert_allclose(state(env, "acceleration", 0), [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(state(env, "velocity", 0), [4.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(state(env, "position", 0), [104.0, 100.0], atol=1e-4)
    np.testing.assert_allclose(state(env, "heading", 0), [1.0, 0.0], atol=1e-6)


def test_zero_acceleration_sum_stays_zero_and_heading_is_kept(device):
    """A + F/m exactly zero keeps A' = 0; V' = 0 keeps the previous heading."""
    env = make_env(device, prey_count=1)
    # Prey: V = 0, action UP -> F = (0, -4) clamped to (0, -0.6); A = (0, 0.2) cancels F/m = (0, -0.2).
    place(
        env,
        [[100.0, 100.0], [500.0, 500.0]],
        [[0.0, 0.0], [0.0, -1.0]],
        [[0.0, 0.2], [0.0, 0.0]],
        heading=np.array([[0.0, 1.0], [0.0, -1.0]], np.float32),
    )
    act(env, [UP], [UP])
    np.testing.assert_array_equal(state(env, "acceleration", 0), [0.0, 0.0])
    np.testing.assert_array_equal(state(env, "velocity", 0), [0.0, 0.0])
    np.testing.assert_array_equal(state(env, "heading", 0), [0.0, 1.0])


@pytest.mark.parametrize(
    "start, velocity, expected",
    [
        ((798.0, 400.0), (4.0, 0.0), (2.0, 400.0)),  # east across the seam
        ((1.0, 400.0), (-4.0, 0.0), (797.0, 400.0)),  # west across the seam
        ((400.0, 1.0), (0.0, -4.0), (400.0, 797.0)),  # up across the top
        ((400.0, 799.5), (0.0, 4.0), (400.0, 3.5)),  # down across the bottom
        ((796.0, 400.0), (4.0, 0.0), (0.0, 400.0)),  # exactly onto the seam: x = 800 is x = 0
    ],
)
def test_wrap_is_a_true_modulo(device, start, velocity, expected):
    env = make_env(device, prey_count=1)
    direction = np.asarray(velocity) / np.linalg.norm(velocity)
    action = {(1, 0): EAST, (-1, 0): WEST, (0, -1): UP, (0, 1): SOUTH}[tuple(int(x) for x in direction)]
    place(env, [start, [100.0, 100.0]], [velocity, [0.0, -1.0]], [direction, [0.0, 0.0]])
    act(env, [action], [UP])
    np.testing.assert_allclose(state(env, "position", 0), expected, atol=1e-4)


@pytest.mark.parametrize(
    "p0, p1, push",
    [
        ((100.0, 100.0), (130.0, 100.0), (-1.0, 0.0)),  # overlap 30 < 40: pushed west
        ((5.0, 400.0), (790.0, 400.0), (1.0, 0.0)),  # 15 apart across the seam: pushed east, not west
        ((400.0, 795.0), (400.0, 20.0), (0.0, -1.0)),  # 25 apart across the bottom seam: pushed up
    ],
)
def test_bounce_pushes_away_from_the_nearest_same_type_agent(device, p0, p1, push):
    """Prey-prey contact: V' = V + b * unit(P_i - P_j) (b = 1) instead of V + A'."""
    env = make_env(device, prey_count=2)
    v0 = np.array([0.5, 0.5])
    place(env, [p0, p1, [600.0, 200.0]], [v0, [0.0, 0.0], [0.0, -1.0]])
    act(env, [UP, UP], [UP])
    np.testing.assert_allclose(state(env, "velocity", 0), v0 + np.asarray(push), atol=1e-6)
    # The acceleration is still updated and stored: F = (0,-4) - (0.5,0.5), clamped to 0.6, over m = 3.
    f = np.array([-0.5, -4.5])
    f = f / np.linalg.norm(f) * 0.6 / 3.0
    np.testing.assert_allclose(state(env, "acceleration", 0), f / np.linalg.norm(f), atol=1e-6)


def test_bounce_partner_is_the_nearest_and_exact_overlap_gives_no_push(device):
    env = make_env(device, prey_count=3)
    # Prey 0 overlaps prey 1 (d = 30) and prey 2 (d = 10, nearer): pushed away from prey 2 only.
    place(
        env,
        [[200.0, 200.0], [230.0, 200.0], [200.0, 210.0], [600.0, 600.0]],
        [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, -1.0]],
    )
    act(env, [UP, UP, UP], [UP])
    np.testing.assert_allclose(state(env, "velocity", 0), [0.0, -1.0], atol=1e-6)
    # Two prey at exactly the same position: no push, V' = V.
    place(
        env,
        [[300.0, 300.0], [300.0, 300.0], [500.0, 300.0], [600.0, 600.0]],
        [[0.25, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, -1.0]],
    )
    act(env, [UP, UP, UP], [UP])
    np.testing.assert_allclose(state(env, "velocity", 0), [0.25, 0.0], atol=1e-7)


# --------------------------------------------------------------------------------------------------
# Capture, starvation, reproduction (steps 5-9)
# --------------------------------------------------------------------------------------------------
def test_capture_shared_by_two_predators(device):
    """Predator A overlaps the prey (capturer), B is within the share radius, C is outside it."""
    env = make_env(device, prey_count=2, predator_count=3)
    # Everyone moves 'up' from rest: prey by k=1 px, predators by 0.6 px; distances below are after that.
    positions = [[400.0, 400.0], [100.0, 700.0], [430.0, 400.0], [400.0, 480.0], [520.0, 400.0]]
    zero = [[0.0, 0.0]] * 5
    place(env, positions, zero, zero, starvation=np.array([0, 0, 7, 7, 7], np.int32))
    _, rewards, terminated, truncated, info = act(env, [UP, UP], [UP, UP, UP])
    # Prey at (400, 399); A at (430, 399.4): d = 30.0 < 50; B at (400, 479.4): d = 80.4 < 100;
    # C at (520, 399.4): d = 120 > 100.
    assert int(info["captures"][0]) == 1
    np.testing.assert_allclose(rewards["predator"][0].cpu().numpy(), [5.0, 5.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(rewards["prey"][0].cpu().numpy(), [1.0 - 1000.0, 1.0])
    np.testing.assert_array_equal(state(env, "starvation", 2 + 0), 1)  # A captured: 0, then +1
    np.testing.assert_array_equal(state(env, "starvation", 2 + 1), 8)  # B only shared
    np.testing.assert_array_equal(state(env, "starvation", 2 + 2), 8)
    assert not terminated["prey"].any() and not truncated["prey"].any()
    # Respawned as a fresh prey somewhere else.
    np.testing.assert_array_equal(state(env, "velocity", 0), [-1.0, 0.0])
    np.testing.assert_array_equal(state(env, "acceleration", 0), [0.0, 0.0])
    assert int(env.state.torch.age[0, 0]) == 0


def test_two_captures_add_up_and_permanent_capture_removes_the_prey(device):
    env = make_env(device, prey_count=3, predator_count=1, respawn_captured_prey=False)
    # Two prey both overlap the predator; each capture pays 10 to it alone: 20.
    positions = [[400.0, 400.0], [420.0, 400.0], [100.0, 100.0], [410.0, 420.0]]
    place(env, positions, [[0.0, 0.0]] * 4)
    _, rewards, terminated, _, info = act(env, [UP, UP, UP], [UP])
    assert int(info["captures"][0]) == 2
    np.testing.assert_allclose(rewards["predator"][0].cpu().numpy(), [20.0])
    np.testing.assert_allclose(rewards["prey"][0].cpu().numpy(), [-1000.0, -1000.0, 1.0])
    np.testing.assert_array_equal(terminated["prey"][0].cpu().numpy(), [True, True, False])
    np.testing.assert_array_equal(env.alive["prey"][0].cpu().numpy(), [False, False, True])
    assert int(env.state.torch.prey_alive_count[0]) == 1


def test_starvation_at_exactly_the_limit(device):
    env = make_env(device, prey_count=1, predator_count=2, predator_starvation_steps=5)
    place(
        env,
        [[100.0, 100.0], [400.0, 400.0], [700.0, 700.0]],
        [[0.0, 0.0]] * 3,
        starvation=np.array([0, 4, 3], np.int32),
    )
    _, _, terminated, _, _ = act(env, [UP], [UP, UP])
    np.testing.assert_array_equal(env.state.torch.starvation[0, 1:].cpu().numpy(), [5, 4])  # 5 is not > 5
    assert not terminated["predator"].any()
    _, _, terminated, truncated, info = act(env, [UP], [UP, UP])
    np.testing.assert_array_equal(terminated["predator"][0].cpu().numpy(), [True, False])
    np.testing.assert_array_equal(env.alive["predator"][0].cpu().numpy(), [False, True])
    assert not bool(info["episode_ended"][0]) and not truncated["predator"].any()


def test_last_predator_starving_ends_the_episode(device):
    env = make_env(device, prey_count=1, predator_count=1, predator_starvation_steps=5)
    place(env, [[100.0, 100.0], [400.0, 400.0]], [[0.0, 0.0]] * 2, starvation=np.array([0, 5], np.int32))
    _, rewards, terminated, truncated, info = act(env, [UP], [UP])
    assert bool(terminated["predator"][0, 0]) and not bool(truncated["predator"][0, 0])
    assert bool(truncated["prey"][0, 0]) and not bool(terminated["prey"][0, 0])
    assert bool(info["episode_ended"][0]) and int(info["episode_length"][0]) == 1
    assert float(info["episode_return"]["prey"][0]) == 1.0
    # Auto-reset: the world is in its next episode, with every agent alive again.
    assert int(env.state.torch.episode[0]) == 1 and int(env.state.torch.world_step[0]) == 0
    assert env.alive["predator"].all() and env.alive["prey"].all()


def test_reproduction_up_to_the_cap(device):
    env = make_env(device, prey_count=3, predator_count=1, prey_reproduction=True, max_prey=5)
    assert env.prey_capacity == 5
    alive = np.array([True, True, True, False, False, True])
    repl = np.array([200, 180, 160, 0, 0, 0], np.int32)
    age = repl - 1  # each reaches its replication age this step
    age[3:] = 0
    positions = [[100.0, 100.0], [300.0, 100.0], [500.0, 100.0], [0.0, 0.0], [0.0, 0.0], [700.0, 700.0]]
    place(env, positions, [[0.0, 0.0]] * 6, alive=alive, age=age, replication_age=repl)
    _, rewards, *_ = act(env, [UP] * 5, [UP])
    np.testing.assert_array_equal(env.alive["prey"][0].cpu().numpy(), [True] * 5)
    np.testing.assert_array_equal(env.state.torch.age[0, :5].cpu().numpy(), [0, 0, 160, 0, 0])
    # Children at their parents' moved positions (moved up by 1 px), zero velocity, fresh heading.
    np.testing.assert_allclose(state(env, "position", 3), [100.0, 99.0], atol=1e-5)
    np.testing.assert_allclose(state(env, "position", 4), [300.0, 99.0], atol=1e-5)
    np.testing.assert_array_equal(state(env, "velocity", 3), [0.0, 0.0])
    np.testing.assert_array_equal(state(env, "heading", 4), [-1.0, 0.0])
    repl_child = env.state.torch.replication_age[0, 3:5].cpu().numpy()
    assert ((repl_child >= 150) & (repl_child <= 250)).all()
    np.testing.assert_allclose(rewards["prey"][0].cpu().numpy(), [1.0] * 5)  # newborns earn their first step
    assert int(env.state.torch.prey_alive_count[0]) == 5


# --------------------------------------------------------------------------------------------------
# Observations (step 10)
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("angle_deg, visible", [(59.0, True), (61.0, False), (-59.0, True), (-61.0, False)])
def test_view_cone_across_the_seam(device, angle_deg, visible):
    """Prey at x = 790 heading east sees a prey 20 px east of it across the seam within +-60 degrees."""
    env = make_env(device, prey_count=2)
    dx = 20.0
    dy = dx * math.tan(math.radians(angle_deg))
    observer, target = np.array([790.0, 400.0]), np.array([(790.0 + dx) % 800.0, 400.0 + dy])
    obs = place(env, [observer, target, [100.0, 100.0]], [[2.0, 0.0], [4.0, 0.0], [0.0, -1.0]])
    mask = env.observation_mask["prey"][0, 0].cpu().numpy()
    assert mask[1] == visible  # first prey slot (after one predator slot)
    if visible:
        dist = math.hypot(dx, dy)
        bearing = (-math.degrees(math.atan2(dy, dx)) + 180.0) / 360.0
        expected = [1.0, target[0] / 800.0, target[1] / 800.0, dist / 100.0, bearing, 1.0]
        np.testing.assert_allclose(obs["prey"][0, 0, 11:17].cpu().numpy(), expected, atol=1e-6)
        np.testing.assert_allclose(obs["prey"][0, 0, :5].cpu().numpy(), [1.0, 790 / 800, 0.5, 0.5, 0.5], atol=1e-6)
    else:
        np.testing.assert_array_equal(obs["prey"][0, 0, 11:17].cpu().numpy(), np.zeros(6))


@pytest.mark.parametrize("distance, visible", [(99.5, True), (100.0, True), (100.5, False)])
def test_view_distance_boundary_across_the_seam(device, distance, visible):
    env = make_env(device, prey_count=2)
    observer = np.array([10.0, 400.0])  # heading west: the target is across the left seam
    target = np.array([(10.0 - distance) % 800.0, 400.0])
    place(env, [observer, target, [400.0, 100.0]], [[-1.0, 0.0], [0.0, 0.0], [0.0, -1.0]])
    assert bool(env.observation_mask["prey"][0, 0, 1]) == visible


def test_slots_hold_the_nearest_sorted_with_ties_to_the_lower_slot(device):
    cfg = AquariumConfig(prey_count=6, predator_count=2, fov_enabled=False)
    env = BatchedAquarium(cfg, num_worlds=1, device=device, step_kernel=STEP_KERNEL["value"])
    # Observer prey 0 at (400, 400). Prey 1..5 at distances 30, 20, 20, 50, 90; predators at 150 and 60
    # (prey view distance is 100: the predator at 150 is not visible).
    positions = [[400, 400], [430, 400], [400, 420], [380, 400], [400, 350], [490, 400], [250, 400], [400, 460]]
    place(env, positions, [[0.0, 0.0]] * 8)
    slots = env.observed_slot["prey"][0, 0].tolist()
    assert slots == [7, 2, 3, 1]  # predator slot, then prey 2 and 3 (tie at 20: lower slot first), prey 1
    mask = env.observation_mask["prey"][0, 0].tolist()
    assert mask == [True, True, True, True]


def test_zero_distance_neighbour_is_visible_with_bearing_one_half(device):
    env = make_env(device, prey_count=2)
    obs = place(env, [[400.0, 400.0], [400.0, 400.0], [100.0, 100.0]], [[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0]])
    np.testing.assert_allclose(obs["prey"][0, 0, 11:17].cpu().numpy(), [1.0, 0.5, 0.5, 0.0, 0.5, 0.25], atol=1e-7)


def test_signed_observation_range_maps_used_values_only(device):
    env = make_env(device, prey_count=2, observation_range="-1..1")
    obs = place(env, [[400.0, 400.0], [420.0, 400.0], [100.0, 100.0]], [[1.0, 0.0], [0.0, 0.0], [0.0, -1.0]])
    row = obs["prey"][0, 0].cpu().numpy()
    np.testing.assert_allclose(row[:5], [1.0, 0.0, 0.0, 0.0, -0.5], atol=1e-6)  # 2x - 1 of [1, .5, .5, .5, .25]
    np.testing.assert_array_equal(row[5:11], np.zeros(6))  # no predator visible: slot stays 0
    np.testing.assert_allclose(row[11:17], [1.0, 2 * 420 / 800 - 1, 0.0, 2 * 0.2 - 1, 0.0, -1.0], atol=1e-6)


def test_without_auto_reset_an_ended_world_stays_as_it_ended(device):
    cfg = AquariumConfig(prey_count=2, predator_count=1, max_steps=3)
    env = BatchedAquarium(cfg, num_worlds=2, device=device, seed=0, auto_reset=False, step_kernel=STEP_KERNEL["value"])
    actions = {
        "prey": torch.zeros(2, 2, dtype=torch.int64, device=env.torch_device),
        "predator": torch.zeros(2, 1, dtype=torch.int64, device=env.torch_device),
    }
    for _ in range(2):
        _, _, _, truncated, info = env.step(actions)
        assert not info["episode_ended"].any()
    position_before = env.state.torch.position.clone()
    obs, _, _, truncated, info = env.step(actions)
    assert info["episode_ended"].all() and truncated["prey"].all()
    assert (info["episode_length"] == 3).all()
    # The last observations belong to the ended episode: the positions moved on from the last step.
    moved = torch.linalg.vector_norm(env.state.torch.position - position_before, dim=-1)
    assert (moved > 0).all() and (moved < 5.01).all()
    np.testing.assert_array_equal(env.state.torch.episode.cpu().numpy(), [0, 0])
    env.reset()
    assert (env.state.torch.world_step == 0).all()
