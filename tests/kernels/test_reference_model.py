"""Self-tests of the float64 reference model (tests/reference_model.py) on hand-computed cases.

These tests do not need aquarium_warp: configurations are SimpleNamespace objects with docs/model.md's defaults.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import reference_model as ref

PREY_DEFAULTS = dict(
    max_speed=4.0,
    max_steering_force=0.6,
    max_acceleration=1.0,
    mass=3.0,
    radius=20.0,
    view_distance=100.0,
    fov_angle=120.0,
    bounce_strength=1.0,
    predator_slots=1,
    prey_slots=3,
)
PREDATOR_DEFAULTS = dict(
    max_speed=5.0,
    max_steering_force=0.6,
    max_acceleration=0.6,
    mass=10.0,
    radius=30.0,
    view_distance=200.0,
    fov_angle=150.0,
    bounce_strength=0.625,
    predator_slots=1,
    prey_slots=3,
)
WORLD_DEFAULTS = dict(
    width=800.0,
    height=800.0,
    prey_count=16,
    predator_count=1,
    action_count=16,
    max_steps=3000,
    fov_enabled=True,
    respawn_captured_prey=True,
    prey_reward=1.0,
    prey_capture_penalty=1000.0,
    predator_reward=10.0,
    catch_share_radius=100.0,
    predator_starvation_steps=3000,
    prey_reproduction=False,
    prey_replication_age=200,
    max_prey=20,
    observation_range="0..1",
)


def make_cfg(prey=None, predator=None, **world):
    w = dict(WORLD_DEFAULTS)
    w.update(world)
    cfg = SimpleNamespace(
        **w,
        prey=SimpleNamespace(**{**PREY_DEFAULTS, **(prey or {})}),
        predator=SimpleNamespace(**{**PREDATOR_DEFAULTS, **(predator or {})}),
    )
    cfg.prey_capacity = max(cfg.prey_count, cfg.max_prey) if cfg.prey_reproduction else cfg.prey_count
    cfg.capacity = cfg.prey_capacity + cfg.predator_count
    return cfg


def agent(pos, vel=(0.0, 0.0), acc=(0.0, 0.0), heading=None, age=0, rep=200, starve=0, alive=True):
    return dict(pos=pos, vel=vel, acc=acc, heading=heading, age=age, rep=rep, starve=starve, alive=alive)


def cruise_prey(pos, **kw):
    """Prey at full speed 'up' with acceleration 'up': action 0 moves it by exactly (0, -4)."""
    return agent(pos, vel=(0.0, -4.0), acc=(0.0, -1.0), heading=(0.0, -1.0), **kw)


def cruise_pred(pos, **kw):
    """Predator at full speed 'up': action 0 moves it by exactly (0, -5)."""
    return agent(pos, vel=(0.0, -5.0), acc=(0.0, -0.6), heading=(0.0, -1.0), **kw)


def make_world(cfg, prey=(), predators=()):
    """State with the given prey in slots 0.. and predators in slots prey_capacity..; others dead.
    A ``None`` entry leaves that slot dead."""
    st = ref.empty_state(cfg)
    slots = [(i, a) for i, a in enumerate(prey)] + [(cfg.prey_capacity + i, a) for i, a in enumerate(predators)]
    for slot, a in slots:
        if a is None:
            continue
        st["position"][slot] = a["pos"]
        st["velocity"][slot] = a["vel"]
        st["acceleration"][slot] = a["acc"]
        v = np.asarray(a["vel"], float)
        if a["heading"] is not None:
            st["heading"][slot] = a["heading"]
        elif np.linalg.norm(v) > 0:
            st["heading"][slot] = v / np.linalg.norm(v)
        else:
            st["heading"][slot] = (-1.0, 0.0)
        st["alive"][slot] = a["alive"]
        st["age"][slot] = a["age"]
        st["replication_age"][slot] = a["rep"]
        st["starvation"][slot] = a["starve"]
    return st


def zeros_actions(cfg):
    return np.zeros(cfg.capacity, np.int64)


# --------------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "a, b, expected",
    [
        ((10.0, 10.0), (20.0, 30.0), (10.0, 20.0)),
        ((790.0, 10.0), (10.0, 10.0), (20.0, 0.0)),  # across the x seam
        ((10.0, 10.0), (790.0, 790.0), (-20.0, -20.0)),  # across the corner
        ((100.0, 0.0), (500.0, 0.0), (400.0, 0.0)),  # exactly L/2 stays +L/2
        ((500.0, 0.0), (100.0, 0.0), (-400.0, 0.0)),  # exactly -L/2 stays -L/2
        ((100.0, 0.0), (500.5, 0.0), (-399.5, 0.0)),
    ],
)
def test_torus_delta(a, b, expected):
    cfg = make_cfg()
    assert tuple(ref.torus_delta(cfg, a, b)) == expected


@pytest.mark.parametrize(
    "x, length, expected",
    [(-0.5, 800.0, 799.5), (800.0, 800.0, 0.0), (803.25, 800.0, 3.25), (-1e-20, 800.0, 0.0), (0.0, 800.0, 0.0)],
)
def test_wrap_axis(x, length, expected):
    r = ref.wrap_axis(x, length)
    assert r == expected and 0.0 <= r < length


@pytest.mark.parametrize(
    "action, expected",
    [(0, (0.0, -4.0)), (4, (4.0, 0.0)), (8, (0.0, 4.0)), (12, (-4.0, 0.0)), (2, (4 / math.sqrt(2), -4 / math.sqrt(2)))],
)
def test_desired_velocity_clockwise_from_up(action, expected):
    np.testing.assert_allclose(ref.desired_velocity(action, 16, 4.0), expected, atol=1e-12)


@pytest.mark.parametrize(
    "action, n, expected",
    [
        (0, 16, (0.0, -4.0)),
        (4, 16, (4.0, 0.0)),
        (8, 16, (0.0, 4.0)),
        (12, 16, (-4.0, 0.0)),
        (3, 12, (4.0, 0.0)),
        (1, 4, (4.0, 0.0)),
    ],
)
def test_quarter_turns_are_exact(action, n, expected):
    assert tuple(ref.desired_velocity(action, n, 4.0)) == expected


@pytest.mark.parametrize("action, velocity, heading", [(4, (-1.0, 0.0), (-1.0, 0.0)), (8, (0.0, -1.0), (0.0, -1.0))])
def test_fresh_prey_cancelled_by_a_quarter_turn_stops_and_keeps_heading(action, velocity, heading):
    """V = -(unit action direction), A = 0: A' = k * unit(F) = (unit direction) for prey (k = 1), V' = 0 exactly."""
    cfg = make_cfg(prey_count=1, predator_count=1)
    st = make_world(cfg, prey=[agent((100.0, 100.0), vel=velocity, heading=heading)], predators=[agent((500.0, 500.0))])
    actions = zeros_actions(cfg)
    actions[0] = action
    new = ref.motion(cfg, st, actions)
    assert tuple(new["velocity"][0]) == (0.0, 0.0)
    assert tuple(new["heading"][0]) == heading
    assert tuple(new["position"][0]) == (100.0, 100.0)


# --------------------------------------------------------------------------------------------------
# Motion
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["prey", "predator"])
def test_acceleration_turn_rate_is_asin_of_force_over_k(kind):
    """|A| = k, and the largest turn in one step is asin((f/m)/k): prey ~11.5 deg, predator ~5.7 deg."""
    cfg = make_cfg(prey_count=1, predator_count=1)
    t = getattr(cfg, kind)
    slot = 0 if kind == "prey" else cfg.prey_capacity
    u = t.max_steering_force / t.mass
    phi = math.asin(u / t.max_acceleration)
    other = 1 if kind == "prey" else 0
    desired = ref.desired_velocity(0, 16, t.max_speed)

    def turn_for(direction_angle):
        f_dir = np.array([math.cos(direction_angle), math.sin(direction_angle)])
        st = make_world(cfg, prey=[agent((100.0, 100.0))], predators=[agent((500.0, 500.0))])
        st["acceleration"][slot] = (t.max_acceleration, 0.0)
        st["velocity"][slot] = desired - 2.0 * t.max_steering_force * f_dir  # |D - V| = 2f -> F = f * f_dir
        new = ref.motion(cfg, st, zeros_actions(cfg))
        a = new["acceleration"][slot]
        assert math.isclose(np.linalg.norm(a), t.max_acceleration, rel_tol=1e-12)
        assert np.all(new["acceleration"][other] == ref.steering_acceleration(cfg, st, other, 0))
        return math.atan2(a[1], a[0])

    # the maximising force direction is 90 deg + phi away from A
    assert turn_for(math.pi / 2 + phi) == pytest.approx(phi, abs=1e-12)
    turns = [abs(turn_for(x)) for x in np.linspace(-math.pi, math.pi, 721)]
    assert max(turns) <= phi + 1e-12
    assert max(turns) == pytest.approx(phi, abs=1e-4)
    assert math.degrees(phi) == pytest.approx(11.5369590328 if kind == "prey" else 5.7391704773, abs=1e-8)


def test_exact_reversal_stalls_and_speed_is_clamped():
    """Prey at full speed east commanded west: A + F/m = (0.8, 0) -> A' = (1, 0), V' = (5, 0) clamped to (4, 0)."""
    cfg = make_cfg(prey_count=1, predator_count=1)
    st = make_world(
        cfg, prey=[agent((100.0, 100.0), vel=(4.0, 0.0), acc=(1.0, 0.0))], predators=[agent((500.0, 500.0))]
    )
    actions = zeros_actions(cfg)
    actions[0] = 12
    new = ref.motion(cfg, st, actions)
    np.testing.assert_allclose(new["acceleration"][0], (1.0, 0.0), atol=1e-15)
    np.testing.assert_allclose(new["velocity"][0], (4.0, 0.0), atol=1e-15)
    np.testing.assert_allclose(new["position"][0], (104.0, 100.0), atol=1e-12)
    np.testing.assert_allclose(new["heading"][0], (1.0, 0.0), atol=1e-15)


def test_speed_clamp_keeps_direction():
    cfg = make_cfg(prey_count=1, predator_count=1)
    st = make_world(
        cfg, prey=[agent((100.0, 100.0), vel=(3.0, 3.0), acc=(0.0, 1.0))], predators=[agent((500.0, 500.0))]
    )
    actions = zeros_actions(cfg)
    actions[0] = 4  # east
    new = ref.motion(cfg, st, actions)
    # F = (4,0) - (3,3) = (1,-3), |F| = sqrt(10) -> clamped to 0.6; A + F/3 -> normalised to length 1
    f = np.array([1.0, -3.0]) / math.sqrt(10) * 0.6
    raw = np.array([0.0, 1.0]) + f / 3
    a = raw / np.linalg.norm(raw)
    v = np.array([3.0, 3.0]) + a
    v = v / np.linalg.norm(v) * 4.0
    np.testing.assert_allclose(new["acceleration"][0], a, atol=1e-14)
    np.testing.assert_allclose(new["velocity"][0], v, atol=1e-14)
    assert np.linalg.norm(new["velocity"][0]) == pytest.approx(4.0, abs=1e-14)
    np.testing.assert_allclose(new["heading"][0], v / 4.0, atol=1e-14)


def test_zero_acceleration_sum_stays_zero_and_zero_velocity_keeps_heading():
    cfg = make_cfg(prey_count=1, predator_count=1)
    # V = (0, 0.6), action 0 (up, D = (0, -4) exactly): F = (0, -4.6) clamped to length 0.6; A = -F/m,
    # so A + F/m is exactly zero. (With other actions sin/cos leave ~1e-16 components: the branch is fragile.)
    force = ref.clamp_length(np.array([0.0, -4.6]), 0.6)
    st = make_world(
        cfg,
        prey=[agent((100.0, 100.0), vel=(0.0, 0.6), acc=tuple(-force / 3.0), heading=(0.0, 1.0))],
        predators=[agent((500.0, 500.0))],
    )
    new = ref.motion(cfg, st, zeros_actions(cfg))
    assert tuple(new["acceleration"][0]) == (0.0, 0.0)
    assert tuple(new["velocity"][0]) == (0.0, 0.6)
    assert tuple(new["heading"][0]) == (0.0, 1.0)
    # a bounce at distance 0 with zero velocity: V' = V = 0 and the old heading is kept
    st = make_world(
        cfg := make_cfg(prey_count=2, predator_count=1),
        prey=[agent((100.0, 100.0), heading=(0.6, 0.8)), agent((100.0, 100.0), heading=(0.0, 1.0))],
        predators=[agent((500.0, 500.0))],
    )
    new = ref.motion(cfg, st, zeros_actions(cfg))
    assert tuple(new["velocity"][0]) == (0.0, 0.0) and tuple(new["heading"][0]) == (0.6, 0.8)
    assert tuple(new["position"][1]) == (100.0, 100.0) and tuple(new["heading"][1]) == (0.0, 1.0)
    # the acceleration is stored even though the bounce replaced V + A'
    np.testing.assert_allclose(new["acceleration"][0], (0.0, -1.0), atol=1e-15)


def test_wrap_across_the_seam():
    cfg = make_cfg(prey_count=1, predator_count=1)
    d = ref.desired_velocity(2, 16, 4.0)  # north-east at full speed
    st = make_world(
        cfg,
        prey=[agent((798.5, 0.5), vel=tuple(d), acc=tuple(d / 4.0))],
        predators=[agent((0.0, 799.5), vel=(-1.0, 1.0))],
    )
    actions = zeros_actions(cfg)
    actions[0] = 2
    actions[1] = 6  # predator: south-east
    new = ref.motion(cfg, st, actions)
    np.testing.assert_allclose(new["velocity"][0], d, atol=1e-14)
    np.testing.assert_allclose(new["position"][0], (798.5 + d[0] - 800.0, 0.5 + d[1] + 800.0), atol=1e-12)
    p = new["position"][1]
    v = new["velocity"][1]
    assert 0.0 <= p[0] < 800.0 and 0.0 <= p[1] < 800.0
    np.testing.assert_allclose(p, ((0.0 + v[0]) % 800.0, (799.5 + v[1]) % 800.0), atol=1e-12)
    assert v[0] < 0 and v[1] > 0.5  # it did cross both seams


@pytest.mark.parametrize(
    "kind, positions, expected_push",
    [
        # prey 20 apart across the x seam: pushed away, the torus-shortest way, with strength 1
        ("prey", [(5.0, 100.0), (785.0, 100.0)], [(1.0, 0.0), (-1.0, 0.0)]),
        # predators 50 apart across the y seam, strength 0.625
        ("predator", [(300.0, 780.0), (300.0, 30.0)], [(0.0, -0.625), (0.0, 0.625)]),
        # exactly at contact distance (40): no contact, V' = V + A'
        ("prey", [(100.0, 100.0), (124.0, 132.0)], [None, None]),
        # 3-4-5 triangle inside contact distance: unit push along the displacement
        ("prey", [(100.0, 100.0), (112.0, 116.0)], [(-0.6, -0.8), (0.6, 0.8)]),
    ],
)
def test_bounce(kind, positions, expected_push):
    n = len(positions)
    cfg = make_cfg(prey_count=n if kind == "prey" else 1, predator_count=n if kind == "predator" else 1)
    agents = [agent(p) for p in positions]
    if kind == "prey":
        st = make_world(cfg, prey=agents, predators=[agent((400.0, 400.0))])
        slots = list(range(n))
    else:
        st = make_world(cfg, prey=[agent((600.0, 400.0))], predators=agents)
        slots = [cfg.prey_capacity + i for i in range(n)]
    new = ref.motion(cfg, st, zeros_actions(cfg))
    for slot, push in zip(slots, expected_push):
        acc = ref.steering_acceleration(cfg, st, slot, 0)
        np.testing.assert_allclose(new["acceleration"][slot], acc, atol=1e-15)
        expected_v = acc if push is None else np.array(push)
        np.testing.assert_allclose(new["velocity"][slot], expected_v, atol=1e-14)
        np.testing.assert_allclose(new["position"][slot], ref.wrap(cfg, st["position"][slot] + expected_v), atol=1e-12)


@pytest.mark.parametrize(
    "others, partner",
    [
        ([(130.0, 100.0), (70.0, 100.0)], 1),  # tie at 30: the lower slot
        ([(70.0, 100.0), (130.0, 100.0)], 1),
        ([(135.0, 100.0), (70.0, 100.0)], 2),  # nearest wins
        ([(135.0, 100.0), (100.0, 100.0)], 2),  # distance 0 is the nearest (and gives no push)
        ([(140.0, 100.0), (100.0, 60.0)], None),  # both exactly at 40: no contact
    ],
)
def test_contact_partner_nearest_then_lowest_slot(others, partner):
    cfg = make_cfg(prey_count=3, predator_count=1)
    st = make_world(cfg, prey=[agent((100.0, 100.0))] + [agent(p) for p in others], predators=[agent((400.0, 400.0))])
    assert ref.contact_partner(cfg, st, 0) == partner


def test_dead_agents_are_ignored_by_contact_capture_and_vision():
    cfg = make_cfg(prey_count=2, predator_count=2)
    st = make_world(
        cfg,
        prey=[agent((100.0, 100.0)), agent((110.0, 100.0), alive=False)],
        predators=[agent((400.0, 400.0)), agent((100.0, 100.0), alive=False)],
    )
    assert ref.contact_partner(cfg, st, 0) is None
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0)
    assert not captured.any() and info["captures"] == 0
    assert tuple(new["position"][1]) == (110.0, 100.0)  # dead slots do not move
    assert rewards.tolist() == [1.0, 0.0, 0.0, 0.0]
    obs, mask = ref.observe(cfg, new)
    assert not mask["prey"][0].any()
    assert not obs["prey"][1].any() and not mask["prey"][1].any()
    assert not obs["predator"][1].any() and not mask["predator"][1].any()


# --------------------------------------------------------------------------------------------------
# Capture, starvation, reproduction, truncation
# --------------------------------------------------------------------------------------------------
# Capture confusion: prey 0 (cruising, (10, 400) -> (10, 396)) in contact with the predator at (10, 440);
# the other prey, cruising too (4 px up), at least 40 px from each other (no same-type contact) and out of
# the predator's contact. confusion_radius 50 in an 800 x 800 world.
CONFUSION_CASES = {
    # name: (capture_probability, capture_confusion, other prey's start positions, chance)
    "no confusion: p0": (0.7, 0.0, [(55.0, 400.0)], 0.7),
    "lone prey": (1.0, 4.0, [(400.0, 400.0)], 1.0),
    "k = 3, one across the seam": (1.0, 1.0, [(765.0, 400.0), (10.0, 355.0), (55.0, 400.0)], 0.25),
    "exactly at the radius: not counted": (1.0, 1.0, [(760.0, 400.0), (10.0, 350.0)], 1.0),
    "p0 = 0.6, c = 2, k = 1": (0.6, 2.0, [(55.0, 400.0), (400.0, 400.0)], 0.2),
    "p0 = 0": (0.0, 3.0, [(55.0, 400.0)], 0.0),
}


@pytest.mark.parametrize("case", list(CONFUSION_CASES))
def test_capture_chance(case):
    p0, c, others, chance = CONFUSION_CASES[case]
    cfg = make_cfg(
        prey_count=1 + len(others),
        capture_probability=p0,
        capture_confusion=c,
        confusion_radius=50.0,
    )
    st = make_world(
        cfg, prey=[cruise_prey((10.0, 400.0))] + [cruise_prey(p) for p in others], predators=[agent((10.0, 440.0))]
    )
    moved = ref.motion(cfg, ref.as_state(cfg, st), zeros_actions(cfg))
    assert ref.capture_chance(cfg, moved, 0) == pytest.approx(chance, rel=1e-12)
    draw = {0: chance - 1e-9, 1: 0.0, 2: 0.0, 3: 0.0}  # just below the chance: a capture where it is > 0
    kw = dict(respawn_position={0: (1.0, 1.0)}, respawn_replication_age={0: 200})
    *_, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0, capture_draw=draw, **kw)
    assert list(info["capturers"]) == ([0] if chance > 0 else []) and captured[0] == (chance > 0)
    if 0 < chance < 1:
        *_, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0, capture_draw={0: chance}, **kw)
        assert info["captures"] == 0 and not captured[0]  # captured iff u < p: not at u = p
        with pytest.raises(ValueError, match="a capture draw for slot 0"):
            ref.step(cfg, st, zeros_actions(cfg), 0, **kw)
    else:
        ref.step(cfg, st, zeros_actions(cfg), 0, **kw)  # chance 0 or 1: no draw needed


def test_failed_capture_attempt_is_no_capture():
    """A contact that does not capture: survival reward, ageing, no share and no feeding of the predator."""
    cfg = make_cfg(prey_count=1, predator_count=1, capture_probability=0.5, respawn_captured_prey=False)
    st = make_world(cfg, prey=[cruise_prey((400.0, 400.0), age=7)], predators=[agent((400.0, 420.0), starve=5)])
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0, capture_draw={0: 0.5})
    assert info["captures"] == 0 and not captured.any() and not term.any()
    assert rewards.tolist() == [1.0, 0.0]
    assert new["age"][0] == 8 and new["alive"][0] and new["starvation"][1] == 6


def test_capture_shared_by_two_predators():
    cfg = make_cfg(prey_count=1, predator_count=3, predator_starvation_steps=3000)
    st = make_world(
        cfg,
        prey=[cruise_prey((400.0, 400.0), age=7, rep=180)],  # -> (400, 396)
        predators=[
            cruise_pred((400.0, 445.0), starve=17),  # -> (400, 440): 44 < 50, capturer
            cruise_pred((480.0, 405.0), starve=30),  # -> (480, 400): 80.1 < 100, sharer only
            cruise_pred((400.0, 250.0), starve=40),  # -> (400, 245): 151 away, nothing
        ],
    )
    new, rewards, term, trunc, captured, info = ref.step(
        cfg, st, zeros_actions(cfg), 10, respawn_position={0: (12.5, 700.0)}, respawn_replication_age={0: 222}
    )
    assert info["capturers"] == {0: [1]} and info["sharers"] == {0: [1, 2]} and info["captures"] == 1
    assert rewards.tolist() == [-999.0, 5.0, 5.0, 0.0]
    assert captured.tolist() == [True, False, False, False]
    assert not term.any() and not trunc.any()
    # respawned as a fresh prey
    assert tuple(new["position"][0]) == (12.5, 700.0)
    assert tuple(new["velocity"][0]) == (-1.0, 0.0) and tuple(new["heading"][0]) == (-1.0, 0.0)
    assert tuple(new["acceleration"][0]) == (0.0, 0.0)
    assert new["age"][0] == 0 and new["replication_age"][0] == 222 and new["alive"][0]
    # capturer reset then +1; others +1
    assert new["starvation"][1:].tolist() == [1, 31, 41]
    np.testing.assert_allclose(new["position"][1:], [(400, 440), (480, 400), (400, 245)], atol=1e-12)
    assert info["world_step"] == 11


def test_two_capturers_and_two_captures_add_up():
    cfg = make_cfg(prey_count=2, predator_count=2, respawn_captured_prey=False)
    st = make_world(
        cfg,
        prey=[cruise_prey((100.0, 400.0)), cruise_prey((500.0, 400.0))],  # -> (100, 396), (500, 396)
        predators=[
            cruise_pred((470.0, 411.0), starve=9),  # -> (470, 406): 31.6 from prey 1
            cruise_pred((530.0, 411.0), starve=9),  # -> (530, 406): 31.6 from prey 1
        ],
    )
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0)
    assert info["capturers"] == {1: [2, 3]}
    assert rewards.tolist() == [1.0, -1000.0, 5.0, 5.0]
    assert term.tolist() == [False, True, False, False] and not trunc.any()
    assert new["alive"].tolist() == [True, False, True, True]
    assert new["starvation"][2:].tolist() == [1, 1]

    # predator 2 captures prey 0 alone (prey 1 is 200 away from it: no share) and shares prey 1
    st = make_world(
        cfg,
        prey=[cruise_prey((300.0, 400.0)), cruise_prey((500.0, 400.0))],
        predators=[cruise_pred((330.0, 411.0)), cruise_pred((530.0, 411.0))],
    )
    cfg2 = make_cfg(prey_count=2, predator_count=2, catch_share_radius=250.0, respawn_captured_prey=False)
    new, rewards, *_ = ref.step(cfg2, st, zeros_actions(cfg2), 0)
    # prey 0: capturer 2; sharers {2, 3} (pred 3 is 200.0 from prey 0) -> 5 each
    # prey 1: capturer 3; sharers {2, 3} -> 5 each
    assert rewards.tolist() == [-1000.0, -1000.0, 10.0, 10.0]
    new, rewards, *_ = ref.step(cfg, st, zeros_actions(cfg), 0)  # share radius 100: each alone
    assert rewards.tolist() == [-1000.0, -1000.0, 10.0, 10.0]
    st["position"][3] = (370.0, 411.0)  # both predators near prey 0, predator 3 captures nothing itself
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0)
    assert info["capturers"] == {0: [2]} and info["sharers"] == {0: [2, 3]}
    assert rewards.tolist() == [-1000.0, 1.0, 5.0, 5.0]


def test_last_prey_removed_ends_the_episode():
    cfg = make_cfg(prey_count=1, predator_count=2, respawn_captured_prey=False)
    st = make_world(
        cfg, prey=[cruise_prey((100.0, 400.0))], predators=[cruise_pred((100.0, 430.0)), cruise_pred((600.0, 100.0))]
    )
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 5)
    assert info["episode_over"]
    assert term.tolist() == [True, False, False] and trunc.tolist() == [False, True, True]
    assert rewards.tolist() == [-1000.0, 10.0, 0.0]


@pytest.mark.parametrize(
    "counters, captures, alive_after, starvation_after",
    [
        ([4, 4], False, [True, True], [5, 5]),  # 5 is not above the limit 5
        ([4, 5], False, [True, False], [5, 6]),  # 6 is
        ([5, 0], False, [False, True], [6, 1]),
        ([5, 5], True, [True, False], [1, 6]),  # the capturer survives
    ],
)
def test_starvation_exactly_at_the_limit(counters, captures, alive_after, starvation_after):
    # limit 5: a predator dies when its counter (after +1) exceeds 5
    cfg = make_cfg(prey_count=1, predator_count=2, predator_starvation_steps=5)
    prey_pos = (100.0, 400.0) if captures else (700.0, 700.0)
    st = make_world(
        cfg,
        prey=[cruise_prey(prey_pos)],
        predators=[cruise_pred((100.0, 430.0), starve=counters[0]), cruise_pred((400.0, 100.0), starve=counters[1])],
    )
    new, rewards, term, trunc, captured, info = ref.step(
        cfg, st, zeros_actions(cfg), 0, respawn_position={0: (700.0, 700.0)}, respawn_replication_age={0: 200}
    )
    assert new["alive"][1:].tolist() == alive_after
    assert term[1:].tolist() == [not a for a in alive_after]
    # the counter of the starved one is kept as it was computed (counter + 1)
    assert new["starvation"][1:].tolist() == starvation_after
    assert not trunc.any()


def test_starvation_of_the_last_predator_truncates_the_others():
    cfg = make_cfg(prey_count=2, predator_count=1, predator_starvation_steps=3)
    st = make_world(
        cfg,
        prey=[cruise_prey((100.0, 100.0)), cruise_prey((300.0, 100.0))],
        predators=[cruise_pred((500.0, 500.0), starve=3)],
    )
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0)
    assert term.tolist() == [False, False, True]
    assert trunc.tolist() == [True, True, False]
    assert rewards.tolist() == [1.0, 1.0, 0.0]


@pytest.mark.parametrize("world_step, over", [(98, False), (99, True)])
def test_truncation_at_max_steps(world_step, over):
    cfg = make_cfg(prey_count=2, predator_count=1, max_steps=100)
    st = make_world(cfg, prey=[cruise_prey((100.0, 100.0)), None], predators=[cruise_pred((500.0, 500.0))])
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), world_step)
    assert info["world_step"] == world_step + 1 and info["episode_over"] == over
    assert trunc.tolist() == ([True, False, True] if over else [False, False, False])
    assert not term.any()


def _repro_cfg(prey_count, max_prey, **kw):
    return make_cfg(
        prey_count=prey_count,
        predator_count=1,
        prey_reproduction=True,
        max_prey=max_prey,
        prey_replication_age=10,
        **kw,
    )


@pytest.mark.parametrize(
    "prey, max_prey, births, ages_after",
    [
        # three parents due, cap 5 with 3 alive: two children in slots 3, 4; the third parent keeps its age
        ([(9, 10), (9, 10), (9, 10), None, None], 5, [(0, 3), (1, 4)], [0, 0, 10, 0, 0]),
        # slot 1 free at the start: children take the lowest free slots in order (1, then 4)
        ([(9, 10), None, (20, 10), (9, 10), None], 5, [(0, 1), (2, 4)], [0, 0, 0, 10, 0]),
        # age reaches replication age - 1 only: not eligible
        ([(8, 10), (3, 10), None], 3, [], [9, 4, 0]),
        # cap reached at the start: nobody reproduces
        ([(9, 10), (9, 10), (9, 10)], 3, [], [10, 10, 10]),
    ],
)
def test_reproduction_up_to_the_cap(prey, max_prey, births, ages_after):
    cfg = _repro_cfg(prey_count=3, max_prey=max_prey)
    assert cfg.prey_capacity == max(3, max_prey)
    xs = [100.0 + 60.0 * i for i in range(len(prey))]
    agents = [None if p is None else cruise_prey((x, 300.0), age=p[0], rep=p[1]) for x, p in zip(xs, prey)]
    st = make_world(cfg, prey=agents, predators=[cruise_pred((700.0, 700.0))])
    newborn = {s: 150 + s for s in range(cfg.prey_capacity)}
    new, rewards, term, trunc, captured, info = ref.step(
        cfg, st, zeros_actions(cfg), 0, newborn_replication_age=newborn
    )
    assert info["births"] == births
    assert new["age"][: cfg.prey_capacity].tolist() == ages_after
    for parent, child in births:
        assert tuple(new["position"][child]) == tuple(new["position"][parent])
        np.testing.assert_allclose(new["position"][parent], (xs[parent], 296.0), atol=1e-12)
        assert tuple(new["velocity"][child]) == (0.0, 0.0) and tuple(new["acceleration"][child]) == (0.0, 0.0)
        assert tuple(new["heading"][child]) == (-1.0, 0.0)
        assert new["replication_age"][child] == 150 + child and new["alive"][child]
    live = new["alive"][: cfg.prey_capacity]
    assert rewards[: cfg.prey_capacity].tolist() == [1.0 if a else 0.0 for a in live]
    assert live.sum() <= max_prey


def test_reproduction_does_not_reuse_a_slot_freed_this_step():
    cfg = _repro_cfg(prey_count=3, max_prey=3, respawn_captured_prey=False)
    st = make_world(
        cfg,
        prey=[cruise_prey((100.0, 400.0)), cruise_prey((300.0, 400.0), age=9, rep=10), cruise_prey((500.0, 400.0))],
        predators=[cruise_pred((100.0, 430.0))],
    )
    new, rewards, term, trunc, captured, info = ref.step(cfg, st, zeros_actions(cfg), 0, newborn_replication_age={})
    assert captured[0] and not new["alive"][0]
    assert info["births"] == [] and new["age"][1] == 10


def test_respawned_prey_and_newborns_get_the_survival_reward():
    cfg = _repro_cfg(prey_count=2, max_prey=3)
    st = make_world(
        cfg,
        prey=[cruise_prey((100.0, 400.0), age=50, rep=10), cruise_prey((300.0, 400.0), age=9, rep=10), None],
        predators=[cruise_pred((100.0, 430.0))],
    )
    new, rewards, term, trunc, captured, info = ref.step(
        cfg,
        st,
        zeros_actions(cfg),
        0,
        respawn_position={0: (600.0, 600.0)},
        respawn_replication_age={0: 9},
        newborn_replication_age={2: 11},
    )
    # prey 0 captured (no ageing, no reproduction: its age is 0 < 9), prey 1 reproduces into slot 2
    assert info["respawned"] == [0] and info["births"] == [(1, 2)]
    assert rewards.tolist() == [-999.0, 1.0, 1.0, 10.0]
    assert new["age"][:3].tolist() == [0, 0, 0]


# --------------------------------------------------------------------------------------------------
# Observations
# --------------------------------------------------------------------------------------------------
def _polar(center, distance, angle_deg, cfg):
    """Point at ``distance`` from ``center`` in direction ``angle_deg`` (math convention, y down => screen
    angle is measured clockwise), wrapped."""
    a = math.radians(angle_deg)
    return tuple(ref.wrap(cfg, (center[0] + distance * math.cos(a), center[1] + distance * math.sin(a))))


@pytest.mark.parametrize(
    "center, heading, distance, angle, fov_enabled, visible",
    [
        # observer heading east at the right edge; the target lies across the x seam
        ((790.0, 400.0), (1.0, 0.0), 50.0, 59.9, True, True),
        ((790.0, 400.0), (1.0, 0.0), 50.0, -59.9, True, True),
        ((790.0, 400.0), (1.0, 0.0), 50.0, 60.1, True, False),
        ((790.0, 400.0), (1.0, 0.0), 50.0, -60.1, True, False),
        ((790.0, 400.0), (1.0, 0.0), 50.0, 60.1, False, True),
        ((790.0, 400.0), (1.0, 0.0), 50.0, 180.0, False, True),
        # heading north-west at the top-left corner; the target across both seams
        ((5.0, 5.0), (-math.sqrt(0.5), -math.sqrt(0.5)), 40.0, -135.0 + 59.9, True, True),
        ((5.0, 5.0), (-math.sqrt(0.5), -math.sqrt(0.5)), 40.0, -135.0 - 60.1, True, False),
        # view distance 100, inclusive
        ((790.0, 400.0), (1.0, 0.0), 99.999, 10.0, True, True),
        ((790.0, 400.0), (1.0, 0.0), 100.001, 10.0, True, False),
        ((790.0, 400.0), (1.0, 0.0), 100.001, 10.0, False, False),
    ],
)
def test_view_cone_across_the_seam(center, heading, distance, angle, fov_enabled, visible):
    cfg = make_cfg(prey_count=2, predator_count=1, fov_enabled=fov_enabled)
    target = _polar(center, distance, angle, cfg)
    st = make_world(cfg, prey=[agent(center, heading=heading), agent(target)], predators=[agent((400.0, 100.0))])
    assert ref.is_visible(cfg, st, 0, 1) == visible
    obs, mask = ref.observe(cfg, st)
    assert mask["prey"][0].tolist() == [False, visible, False, False]


def test_view_distance_boundary_is_inclusive_and_distance_zero_is_visible():
    cfg = make_cfg(prey_count=3, predator_count=1)
    st = make_world(
        cfg,
        prey=[agent((100.0, 100.0), heading=(0.6, 0.8)), agent((160.0, 180.0)), agent((100.0, 100.0))],
        predators=[agent((400.0, 400.0))],
    )
    assert ref.torus_distance(cfg, st["position"][0], st["position"][1]) == 100.0
    assert ref.is_visible(cfg, st, 0, 1)
    st["heading"][0] = (-0.6, -0.8)  # facing away: the distance-0 agent is still visible
    assert not ref.is_visible(cfg, st, 0, 1) and ref.is_visible(cfg, st, 0, 2)
    obs, mask = ref.observe(cfg, st)
    # the distance-0 neighbour: distance 0, bearing 0.5
    assert obs["prey"][0][11:17].tolist() == [1.0, 100 / 800, 100 / 800, 0.0, 0.5, 0.0]


def test_observation_values_slot_order_and_ties():
    """Predator observer with FOV off and infinite view: nearest first, ties by slot index."""
    cfg = make_cfg(
        prey_count=5,
        predator_count=3,
        fov_enabled=False,
        predator=dict(view_distance=math.inf, predator_slots=2, prey_slots=3),
    )
    c = (400.0, 400.0)
    prey = [
        agent((400.0, 430.0), vel=(0.0, 2.0)),  # slot 0: d 30 (south)
        agent((400.0, 390.0), vel=(3.0, 0.0)),  # slot 1: d 10 (north)
        agent((430.0, 400.0)),  # slot 2: d 30 (east), ties with slot 0
        agent((390.0, 400.0), vel=(0.0, -4.0)),  # slot 3: d 10 (west), ties with slot 1
        agent((405.0, 400.0), alive=False),  # slot 4: dead
    ]
    preds = [
        agent(c, vel=(0.0, -2.5)),  # slot 5: observer, heading north
        agent((0.0, 400.0), vel=(5.0, 0.0)),  # slot 6: d 400 across the seam? 400 = L/2 exactly
        agent((700.0, 700.0)),  # slot 7: d = sqrt(2)*300 = 424.26 (torus: 300, 300)
    ]
    st = make_world(cfg, prey=prey, predators=preds)
    obs, mask, slots = ref.observe(cfg, st, with_slots=True)
    o = obs["predator"][0]
    assert slots["predator"][0].tolist() == [6, 7, 1, 3, 0]
    assert mask["predator"][0].tolist() == [True] * 5
    half_diag = math.sqrt(400.0**2 + 400.0**2)
    expected = [
        0.0,
        0.5,
        0.5,
        0.75,
        0.5,  # own: predator, heading north (-atan2(-1, 0) = 90 deg -> 0.75), speed 2.5/5
        # predator slot 6: dx = 0 - 400 = -400 = -L/2 stays -400: west, bearing (-180 + 180) / 360 = 0
        0.0,
        0.0,
        0.5,
        400.0 / half_diag,
        0.0,
        1.0,
        # predator slot 7: displacement (300, 300): -atan2(300, 300) = -45 deg -> 135 / 360
        0.0,
        700 / 800,
        700 / 800,
        math.sqrt(2) * 300 / half_diag,
        135.0 / 360.0,
        0.0,
        # prey slot 1 (north): 90 deg -> 0.75, speed 3/4
        1.0,
        0.5,
        390 / 800,
        10 / half_diag,
        0.75,
        0.75,
        # prey slot 3 (west): -atan2(0, -10) = -180 deg -> 0
        1.0,
        390 / 800,
        0.5,
        10 / half_diag,
        0.0,
        1.0,
        # prey slot 0 (south): -atan2(30, 0) = -90 -> 0.25, speed 2/4
        1.0,
        0.5,
        430 / 800,
        30 / half_diag,
        0.25,
        0.5,
    ]
    np.testing.assert_allclose(o, expected, atol=1e-15)

    # the same in "-1..1": used values mapped by 2x - 1
    cfg_signed = make_cfg(
        prey_count=5,
        predator_count=3,
        fov_enabled=False,
        observation_range="-1..1",
        predator=dict(view_distance=math.inf, predator_slots=2, prey_slots=3),
    )
    obs_s, mask_s = ref.observe(cfg_signed, st)
    np.testing.assert_allclose(obs_s["predator"][0], 2 * np.array(expected) - 1, atol=1e-15)

    # with the FOV off, prey slot 1 (view 100) sees predator 5 (d 10) and prey 3 (14.1), 2 (31.6), 0 (40)
    assert slots["prey"][1].tolist() == [5, 3, 2, 0]
    # a prey observer (defaults: 1 predator slot, 3 prey slots, view 100, FOV 120), FOV on
    cfg_fov = make_cfg(
        prey_count=5, predator_count=3, predator=dict(view_distance=math.inf, predator_slots=2, prey_slots=3)
    )
    obs, mask = ref.observe(cfg_fov, st)
    o1, m1 = obs["prey"][1], mask["prey"][1]
    # own: prey, heading east (velocity (3, 0)): -atan2(0, 1) = 0 -> 0.5; speed 3/4
    np.testing.assert_allclose(o1[:5], [1.0, 0.5, 390 / 800, 0.5, 0.75], atol=1e-15)
    # heading east: sees slot 2 (430,400): displacement (30, 10), 18.4 deg off; slot 0 (400,430) is at
    # (0, 40): 90 deg off -> invisible; slot 3 (390,400) at (-10, 10): 135 deg off; observer predator (400,400)
    # at (0, 10): 90 deg off -> invisible. Dead slot 4 never.
    assert m1.tolist() == [False, True, False, False]
    assert not o1[5:11].any() and not o1[17:].any()
    d = math.sqrt(30.0**2 + 10.0**2)
    np.testing.assert_allclose(
        o1[11:17], [1.0, 430 / 800, 0.5, d / 100.0, (-math.degrees(math.atan2(10, 30)) + 180) / 360, 0.0], atol=1e-15
    )
    # in "-1..1" unused slots stay 0
    cfg_fov_signed = make_cfg(
        prey_count=5,
        predator_count=3,
        observation_range="-1..1",
        predator=dict(view_distance=math.inf, predator_slots=2, prey_slots=3),
    )
    o1s = ref.observe(cfg_fov_signed, st)[0]["prey"][1]
    np.testing.assert_allclose(o1s[:5], 2 * o1[:5] - 1, atol=1e-15)
    assert not o1s[5:11].any() and not o1s[17:].any()
    np.testing.assert_allclose(o1s[11:17], 2 * o1[11:17] - 1, atol=1e-15)


def test_more_visible_than_slots_keeps_the_nearest():
    cfg = make_cfg(prey_count=6, predator_count=1, fov_enabled=False)
    # distances 50, 20, 20, 45, 5 from slot 0 -> nearest three: 5 (slot 5), 20 (slot 2), 20 (slot 3)
    offsets = [(0.0, 50.0), (0.0, 20.0), (20.0, 0.0), (27.0, 36.0), (3.0, 4.0)]
    prey = [agent((780.0, 790.0))] + [
        agent(tuple(ref.wrap(make_cfg(), (780.0 + dx, 790.0 + dy)))) for dx, dy in offsets
    ]
    st = make_world(cfg, prey=prey, predators=[agent((780.0, 100.0))])
    obs, mask, slots = ref.observe(cfg, st, with_slots=True)
    assert slots["prey"][0].tolist() == [-1, 5, 2, 3]
    assert mask["prey"][0].tolist() == [False, True, True, True]


def test_infinite_view_distance_uses_the_half_diagonal():
    cfg = make_cfg(
        width=300.0, height=400.0, prey_count=1, predator_count=1, fov_enabled=False, prey=dict(view_distance=math.inf)
    )
    st = make_world(cfg, prey=[agent((0.0, 0.0))], predators=[agent((150.0, 200.0))])
    obs, mask = ref.observe(cfg, st)
    assert mask["prey"][0].tolist() == [True, False, False, False]
    assert obs["prey"][0][8] == 1.0  # the farthest possible point: 250 / 250
    # the predator (view 200) cannot see the prey 250 away
    assert not mask["predator"][0].any()


def test_step_observations_use_the_end_of_step_state():
    cfg = make_cfg(prey_count=1, predator_count=1)
    st = make_world(cfg, prey=[cruise_prey((100.0, 400.0))], predators=[cruise_pred((100.0, 430.0))])
    new, rewards, term, trunc, captured, info = ref.step(
        cfg, st, zeros_actions(cfg), 0, respawn_position={0: (103.0, 300.0)}, respawn_replication_age={0: 190}
    )
    obs, mask = ref.observe(cfg, new)
    for key in ("prey", "predator"):
        np.testing.assert_array_equal(info["observations"][key], obs[key])
        np.testing.assert_array_equal(info["observation_mask"][key], mask[key])
    # the respawned prey heads west, the predator (at (100, 425)) north: the prey at (103, 300) is 125 away,
    # within the predator's view 200 and 1.4 deg off its heading
    assert mask["predator"][0].tolist() == [False, True, False, False]
    assert obs["prey"][0][3] == 0.0  # heading (-1, 0): -atan2(0, -1) = -180 -> 0


# --------------------------------------------------------------------------------------------------
# Predator confusion (docs/model.md step 5, capture_rule "confusion")
# --------------------------------------------------------------------------------------------------
def confusion_cfg(**world):
    base = dict(
        prey_count=3, capture_rule="confusion", capture_probability=1.0, capture_confusion=1.0, confusion_angle=15.0
    )
    return make_cfg(**{**base, "handling_steps": 4, **world})


def confusion_world(cfg, others, predator_starve=0, handling=0):
    """Prey 0 at (400, 400), the predator 2 px south of it, all cruising north: after the move the
    predator is 1 px south of prey 0, heading north. ``others``: positions of prey 1.. (None: dead)."""
    prey = [cruise_prey((400.0, 400.0))] + [None if p is None else cruise_prey(p) for p in others]
    st = make_world(cfg, prey, [cruise_pred((400.0, 402.0), starve=predator_starve)])
    st["handling"][cfg.prey_capacity] = handling
    return st


@pytest.mark.parametrize(
    "others, fov, expected_k",
    [
        ([(400.0, 350.0), (400.0, 300.0)], 150.0, 2),  # both ahead, seen, in the window
        ([(400.0, 350.0), (400.0, 461.0)], 150.0, 1),  # one 60 px behind: outside the FOV
        ([(400.0, 350.0), (400.0, 461.0)], 360.0, 1),  # seen now, but 180 degrees off the target's bearing
        ([(400.0, 350.0), (400.0, 196.0)], 150.0, 1),  # one 205 px ahead: beyond the view distance
        # 100 px from the predator at 14 and 16 degrees from north: in and out of the 15-degree window
        ([(400.0 + 100 * math.sin(math.radians(14)), 401.0 - 100 * math.cos(math.radians(14))), None], 150.0, 1),
        ([(400.0 + 100 * math.sin(math.radians(16)), 401.0 - 100 * math.cos(math.radians(16))), None], 150.0, 0),
        ([(400.0, 350.0), None], 150.0, 1),  # a dead prey does not count
    ],
)
def test_confusion_counts_only_the_prey_the_predator_sees_near_its_target(others, fov, expected_k):
    cfg = confusion_cfg(predator=dict(fov_angle=fov))
    moved = ref.motion(cfg, confusion_world(cfg, others), zeros_actions(cfg))
    p = cfg.prey_capacity
    assert ref.attack_target(cfg, moved, p) == 0
    assert len(ref.prey_seen_near_target(cfg, moved, p, 0)) == expected_k
    assert ref.attack_chance(cfg, moved, p, 0) == pytest.approx(1.0 / (1.0 + expected_k))


def test_confusion_window_across_the_seam():
    """The target's bearing and a neighbour's across the top seam: 51 px north of the predator."""
    cfg = confusion_cfg()
    prey = [cruise_prey((400.0, 10.0)), cruise_prey((400.0, 760.0))]
    st = make_world(cfg, prey + [None], [cruise_pred((400.0, 12.0))])
    moved = ref.motion(cfg, st, zeros_actions(cfg))
    assert ref.prey_seen_near_target(cfg, moved, cfg.prey_capacity, 0) == [1]


def test_one_draw_per_attack_then_the_handling_time():
    """A failed attack (u = 0.9 >= 1 / 2) starts H = 4 steps without attacks though the prey stays in
    contact (draws then would capture: u = 0); the counter falls 4, 3, 2, 1, 0, then the attack captures.
    Under density dilution the same draws of the prey would have captured at once."""
    cfg = confusion_cfg()
    st = confusion_world(cfg, [(400.0, 350.0), None])
    p = cfg.prey_capacity
    counters, captures = [], []
    for t in range(6):
        draw = {p: 0.9 if t == 0 else 0.0}
        st, _, _, _, captured, info = ref.step(
            cfg,
            st,
            zeros_actions(cfg),
            t,
            respawn_position={0: (100.0, 100.0)},
            respawn_replication_age={0: 200},
            attack_draw=draw,
        )
        counters.append(int(st["handling"][p]))
        captures.append(info["captures"])
    assert counters == [4, 3, 2, 1, 0, 0] and captures == [0, 0, 0, 0, 0, 1]
    assert info["capturers"] == {0: [p]}


def test_no_handling_time_and_no_confusion():
    """H = 0: a failed attack attacks again in the next step. c = 0, p0 = 1: the first attack captures
    with no draw given, whatever the predator sees."""
    cfg = confusion_cfg(handling_steps=0)
    st = confusion_world(cfg, [(400.0, 350.0), None])
    p = cfg.prey_capacity
    st, *_, info = ref.step(cfg, st, zeros_actions(cfg), 0, attack_draw={p: 0.5})
    assert info["attacks"] == {p: (0, False)} and st["handling"][p] == 0
    st, *_, info = ref.step(
        cfg,
        st,
        zeros_actions(cfg),
        1,
        respawn_position={0: (100.0, 100.0)},
        respawn_replication_age={0: 200},
        attack_draw={p: 0.25},
    )
    assert info["attacks"] == {p: (0, True)}
    cfg = confusion_cfg(capture_confusion=0.0)
    st = confusion_world(cfg, [(400.0, 350.0), (400.0, 300.0)], predator_starve=9)
    new, rewards, *_, info = ref.step(
        cfg, st, zeros_actions(cfg), 0, respawn_position={0: (100.0, 100.0)}, respawn_replication_age={0: 200}
    )
    assert info["capturers"] == {0: [p]} and new["starvation"][p] == 1 and rewards[p] == 10.0


def test_a_handling_predator_is_no_capturer():
    """Two predators overlap prey 0; the handling one does not attack: the other captures alone, and
    with catch_share_radius 0 the reward is its alone (under density dilution both would share it)."""
    cfg = confusion_cfg(predator_count=2, capture_confusion=0.0, catch_share_radius=0.0)
    prey = [cruise_prey((400.0, 400.0)), None, None]
    st = make_world(cfg, prey, [cruise_pred((400.0, 402.0), starve=7), cruise_pred((430.0, 402.0), starve=7)])
    a, b = cfg.prey_capacity, cfg.prey_capacity + 1
    st["handling"][b] = 2
    new, rewards, *_, info = ref.step(
        cfg, st, zeros_actions(cfg), 0, respawn_position={0: (100.0, 100.0)}, respawn_replication_age={0: 200}
    )
    assert info["capturers"] == {0: [a]} and info["sharers"] == {0: [a]}
    assert rewards[a] == 10.0 and rewards[b] == 0.0
    assert new["starvation"][[a, b]].tolist() == [1, 8] and new["handling"][[a, b]].tolist() == [0, 1]
    dilution = make_cfg(prey_count=3, predator_count=2, catch_share_radius=0.0)
    _, rewards, *_, info = ref.step(
        dilution,
        st,
        zeros_actions(dilution),
        0,
        respawn_position={0: (100.0, 100.0)},
        respawn_replication_age={0: 200},
    )
    assert info["capturers"] == {0: [a, b]} and rewards[a] == rewards[b] == 5.0
