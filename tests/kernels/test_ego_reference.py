"""Hand-computed cases of the reference's ego-spec options (/work/notes/ego-spec.md): egocentric observations
(observation_frame "ego"), egocentric actions (action_frame "ego"), random spawn headings (spawn_heading
"random") and the heuristics' action choice in the ego frame.

Every expected value is worked out in the test (screen coordinates: x right, y down; the right axis of a
heading h is r = (-hy, hx), so the right of "east" is "south"). Tables give the natural values (before the
observation range's mapping); the mapping is applied here, in both ranges. These tests need no Warp kernel.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import reference_model as ref
from test_reference_model import agent, make_cfg, make_world

EAST, NORTH, SOUTH = (1.0, 0.0), (0.0, -1.0), (0.0, 1.0)
H = (0.6, 0.8)  # a heading that is not axis-aligned (south-east-ish); its right axis is (-0.8, 0.6)
UNSIGNED = (True, True, False, False, False, False)  # per slot value: present, distance | f, r, vf, vr


def ego_cfg(**kw):
    kw.setdefault("observation_frame", "ego")
    kw.setdefault("action_frame", "ego")
    return make_cfg(**kw)


def mapped(values, unsigned_flags, observation_range):
    """The spec's range mapping, written out: "0..1" maps signed values by (x + 1) / 2, "-1..1" maps unsigned
    values by 2x - 1."""
    out = []
    for x, unsigned in zip(values, unsigned_flags):
        if observation_range == "0..1":
            out.append(x if unsigned else (x + 1.0) / 2.0)
        else:
            out.append(2.0 * x - 1.0 if unsigned else x)
    return out


# --------------------------------------------------------------------------------------------------
# Neighbour slots
# --------------------------------------------------------------------------------------------------
# (observer position, heading, velocity; neighbour position, velocity; natural values
#  [present, distance / 100, bearing_f, bearing_r, relvel_f, relvel_r]). Prey observing prey: view 100
# (d_max 100), s_i + s_j = 8; the FOV is off so that targets beside and behind are seen.
SLOT_CASES = {
    # 30 px straight ahead of an observer heading east; u = (0, 0) - (2, 0): forward -2/8
    "ahead": ((400.0, 400.0), EAST, (2.0, 0.0), (430.0, 400.0), (0.0, 0.0), [1.0, 0.3, 1.0, 0.0, -0.25, 0.0]),
    # 40 px to the right of east is +y (south); u = (0, 4) - (2, 0) = (-2, 4): forward -2/8, right 4/8
    "right_of_east": ((400.0, 400.0), EAST, (2.0, 0.0), (400.0, 440.0), (0.0, 4.0), [1.0, 0.4, 0.0, 1.0, -0.25, 0.5]),
    # to the left of east (north, -y), moving west: u = (-4, 0) - (2, 0): forward -6/8
    "left_of_east": ((400.0, 400.0), EAST, (2.0, 0.0), (400.0, 350.0), (-4.0, 0.0), [1.0, 0.5, 0.0, -1.0, -0.75, 0.0]),
    # behind a north-heading observer (+y is behind), moving east = the observer's right
    "behind_north": ((400.0, 400.0), NORTH, (0.0, 0.0), (400.0, 460.0), (4.0, 0.0), [1.0, 0.6, -1.0, 0.0, 0.0, 0.5]),
    # across the x seam: from x=790 to x=10 on the 800 px world is +20 (east); heading north, east is the
    # right; the neighbour moves north (the observer's forward) at 4
    "seam_right_of_north": (
        (790.0, 400.0),
        NORTH,
        (0.0, 0.0),
        (10.0, 400.0),
        (0.0, -4.0),
        [1.0, 0.2, 0.0, 1.0, 0.5, 0.0],
    ),
    # across the y seam: from y=795 to y=15 is +20 (south): ahead of a south-heading observer
    "seam_ahead_south": ((100.0, 795.0), SOUTH, (0.0, 4.0), (100.0, 15.0), (0.0, 4.0), [1.0, 0.2, 1.0, 0.0, 0.0, 0.0]),
    # heading H = (0.6, 0.8): displacement (-40, 30) has d.f = -24 + 24 = 0, d.r = 32 + 18 = 50 (right);
    # u = (4, 0): u.f = 2.4, u.r = -0.8 * 4 = -3.2
    "right_of_H": ((200.0, 200.0), H, (0.0, 0.0), (160.0, 230.0), (4.0, 0.0), [1.0, 0.5, 0.0, 1.0, 0.3, -0.4]),
    # displacement (30, 40) = 50 H: straight ahead; u = (0, 0) - (1.2, 1.6) = -2 H: forward -2/8
    "ahead_of_H": ((200.0, 200.0), H, (1.2, 1.6), (230.0, 240.0), (0.0, 0.0), [1.0, 0.5, 1.0, 0.0, -0.25, 0.0]),
    # distance 0: bearing (0, 0); u = -(1.2, 1.6) - (1.2, 1.6) = -4 H: forward -4/8
    "distance_zero": ((200.0, 200.0), H, (1.2, 1.6), (200.0, 200.0), (-1.2, -1.6), [1.0, 0.0, 0.0, 0.0, -0.5, 0.0]),
    # relative velocity clipped: a neighbour set faster than its max speed, u = (20, 0) along H's axes:
    # u.f = 12 / 8 -> 1, u.r = -16 / 8 -> -1
    "relvel_clipped": ((200.0, 200.0), H, (0.0, 0.0), (230.0, 240.0), (20.0, 0.0), [1.0, 0.5, 1.0, 0.0, 1.0, -1.0]),
}


@pytest.mark.parametrize("observation_range", ["0..1", "-1..1"])
@pytest.mark.parametrize("case", list(SLOT_CASES))
def test_ego_prey_slot(case, observation_range):
    p_i, h, v_i, p_j, v_j, natural = SLOT_CASES[case]
    cfg = ego_cfg(prey_count=2, predator_count=1, fov_enabled=False, observation_range=observation_range)
    st = make_world(
        cfg, prey=[agent(p_i, vel=v_i, heading=h), agent(p_j, vel=v_j, heading=EAST)], predators=[agent((600.0, 600.0))]
    )  # out of view
    obs, mask, slots = ref.observe(cfg, st, with_slots=True)
    o = obs["prey"][0]
    assert o.shape == (2 + 6 * 4,)
    # slots: 1 predator slot (empty), then the prey block: the neighbour is prey slot 0 (columns 8..13)
    assert mask["prey"][0].tolist() == [False, True, False, False] and slots["prey"][0].tolist() == [-1, 1, -1, -1]
    np.testing.assert_allclose(o[8:14], mapped(natural, UNSIGNED, observation_range), rtol=0, atol=1e-12)
    assert not o[2:8].any() and not o[14:].any()  # unused slots: all six values 0 in either range


@pytest.mark.parametrize("observation_range", ["0..1", "-1..1"])
def test_ego_predator_slot_uses_both_max_speeds(observation_range):
    """A prey (s 4) observing a predator (s 5) 30 px to its left: s_i + s_j = 9. Heading east, the left is -y;
    u = (0, -4.5) - (0, 0): u.r = 1 * -4.5 -> -0.5."""
    cfg = ego_cfg(prey_count=1, predator_count=1, fov_enabled=False, observation_range=observation_range)
    st = make_world(cfg, prey=[agent((400.0, 400.0), heading=EAST)], predators=[agent((400.0, 370.0), vel=(0.0, -4.5))])
    obs, mask = ref.observe(cfg, st)
    assert mask["prey"][0].tolist() == [True, False, False, False]
    np.testing.assert_allclose(
        obs["prey"][0][2:8], mapped([1.0, 0.3, 0.0, -1.0, 0.0, -0.5], UNSIGNED, observation_range), atol=1e-12
    )


def test_ego_slots_keep_the_world_layouts_selection_and_order():
    """Same selection (visible, nearest first, ties to the lower slot) as the world layout: FOV on (prey 120
    degrees, heading east), the one behind is not seen; two at distance 30 tie and keep slot order."""
    cfg = ego_cfg(prey_count=5, predator_count=1)
    st = make_world(
        cfg,
        prey=[
            agent((400.0, 400.0), heading=EAST),
            agent((430.0, 400.0)),  # 30 ahead
            agent((370.0, 400.0)),  # 30 behind: outside the cone
            agent((424.0, 418.0)),  # 30 away, 36.9 degrees right: ties with slot 1
            agent((410.0, 400.0)),
        ],  # 10 ahead: nearest
        predators=[agent((700.0, 700.0))],
    )
    obs, mask, slots = ref.observe(cfg, st, with_slots=True)
    assert slots["prey"][0].tolist() == [-1, 4, 1, 3]
    o = obs["prey"][0]
    # slot 3: displacement (24, 18): bearing (24 / 30, 18 / 30) = (0.8, 0.6) -> (0.9, 0.8) in "0..1"
    np.testing.assert_allclose(o[20:26], [1.0, 0.3, 0.9, 0.8, 0.5, 0.5], atol=1e-12)
    # the world layout selects the same agents
    world = make_cfg(prey_count=5, predator_count=1)
    assert ref.observe(world, st, with_slots=True)[2]["prey"][0].tolist() == [-1, 4, 1, 3]


# --------------------------------------------------------------------------------------------------
# Own block and length
# --------------------------------------------------------------------------------------------------
UNIFORM_2 = SimpleNamespace(kind="uniform", velocity=(2.0, 0.0), amplitude=0.0)  # c = (0.5, 0) for prey
UNIFORM_10 = SimpleNamespace(kind="uniform", velocity=(10.0, 0.0), amplitude=0.0)  # c = (2.5, 0)

# (action_frame, flow, observe_flow, prey velocity, natural own values, unsigned flags). The prey heads H.
OWN_CASES = {
    # [type 1, speed 2 / 4]
    "ego_actions": ("ego", None, False, (1.2, 1.6), [1.0, 0.5], (True, True)),
    # world actions add the world heading [0.6, 0.8]
    "world_actions": ("world", None, False, (1.2, 1.6), [1.0, 0.5, 0.6, 0.8], (True, True, False, False)),
    # speed 5 > 4 (a state set beyond the clamp): min(5 / 4, 1) = 1
    "speed_clipped": ("ego", None, False, (3.0, 4.0), [1.0, 1.0], (True, True)),
    # c = (0.5, 0): c.f = 0.6 * 0.5 = 0.3, c.r = -0.8 * 0.5 = -0.4
    "flow_ego": ("ego", UNIFORM_2, True, (0.0, 0.0), [1.0, 0.0, 0.3, -0.4], (True, True, False, False)),
    "flow_world_actions": (
        "world",
        UNIFORM_2,
        True,
        (0.0, 0.0),
        [1.0, 0.0, 0.6, 0.8, 0.3, -0.4],
        (True, True, False, False, False, False),
    ),
    # c = (2.5, 0): rotated first (c.f = 1.5, c.r = -2.0), then each clipped: (1, -1). Clipping the world
    # components first would give (0.6, -0.8).
    "flow_clipped_after_rotation": (
        "ego",
        UNIFORM_10,
        True,
        (0.0, 0.0),
        [1.0, 0.0, 1.0, -1.0],
        (True, True, False, False),
    ),
    # a flow that is not observed changes nothing in the row
    "flow_not_observed": ("ego", UNIFORM_2, False, (1.2, 1.6), [1.0, 0.5], (True, True)),
}


@pytest.mark.parametrize("observation_range", ["0..1", "-1..1"])
@pytest.mark.parametrize("case", list(OWN_CASES))
def test_ego_own_block(case, observation_range):
    frame, flow, observe_flow, vel, natural, flags = OWN_CASES[case]
    cfg = ego_cfg(
        action_frame=frame,
        prey_count=1,
        predator_count=1,
        observation_range=observation_range,
        flow=flow,
        observe_flow=observe_flow,
    )
    st = make_world(cfg, prey=[agent((100.0, 100.0), vel=vel, heading=H)], predators=[agent((500.0, 500.0))])
    o = ref.observe(cfg, st)[0]["prey"][0]
    assert ref.own_size(cfg) == len(natural) and o.shape == (len(natural) + 24,)
    np.testing.assert_allclose(o[: len(natural)], mapped(natural, flags, observation_range), atol=1e-12)
    assert not o[len(natural) :].any()  # nothing in view


def test_ego_own_block_of_a_predator():
    """Type 0, speed 5 / 5; in "-1..1" both unsigned values map by 2x - 1: (-1, 1)."""
    for rng, expected in (("0..1", [0.0, 1.0]), ("-1..1", [-1.0, 1.0])):
        cfg = ego_cfg(prey_count=1, predator_count=1, observation_range=rng)
        st = make_world(cfg, prey=[agent((100.0, 100.0))], predators=[agent((500.0, 500.0), vel=(0.0, -5.0))])
        assert ref.observe(cfg, st)[0]["predator"][0][:2].tolist() == expected


@pytest.mark.parametrize(
    "frame, observe_flow, slots, length",
    [
        ("ego", False, (1, 3), 26),  # the spec's default: 2 + 24
        ("world", False, (1, 3), 28),
        ("ego", True, (1, 3), 28),
        ("world", True, (1, 3), 30),
        ("ego", False, (2, 3), 32),
        ("world", True, (0, 1), 12),
    ],
)
def test_ego_observation_length(frame, observe_flow, slots, length):
    cfg = ego_cfg(
        action_frame=frame, observe_flow=observe_flow, prey=dict(predator_slots=slots[0], prey_slots=slots[1])
    )
    assert ref.observation_length(cfg, cfg.prey) == length
    st = make_world(cfg, prey=[agent((100.0, 100.0))], predators=[agent((500.0, 500.0))])
    assert ref.observe(cfg, st)[0]["prey"].shape[1] == length


def test_configs_without_the_new_fields_keep_the_world_layout_and_paper_spawn():
    cfg = make_cfg(prey_count=1, predator_count=1)  # names none of the three options
    assert not hasattr(cfg, "observation_frame") and ref.observation_length(cfg, cfg.prey) == 29
    assert ref.observation_frame(cfg) == "world" and ref.action_frame(cfg) == "world"
    assert ref.spawn_heading(cfg) == "paper"
    st = make_world(cfg, prey=[agent((100.0, 100.0), heading=H)], predators=[agent((500.0, 500.0))])
    named = make_cfg(
        prey_count=1, predator_count=1, observation_frame="world", action_frame="world", spawn_heading="paper"
    )
    np.testing.assert_array_equal(ref.observe(cfg, st)[0]["prey"], ref.observe(named, st)[0]["prey"])


# --------------------------------------------------------------------------------------------------
# Ego actions
# --------------------------------------------------------------------------------------------------
R = (-0.8, 0.6)  # the right axis of H


@pytest.mark.parametrize(
    "action, direction",
    [
        (0, H),  # forward
        (4, R),  # n/4: a right turn
        (8, (-0.6, -0.8)),  # n/2: reverse
        (12, (0.8, -0.6)),  # 3n/4: left
        (2, ((0.6 - 0.8) / math.sqrt(2), (0.8 + 0.6) / math.sqrt(2))),  # 45 degrees right: (H + R) / sqrt 2
    ],
)
def test_ego_desired_velocity_turns_from_the_heading(action, direction):
    np.testing.assert_allclose(ref.ego_desired_velocity(action, 16, 4.0, H), 4.0 * np.array(direction), atol=1e-12)


def test_ego_forward_action_is_exactly_the_heading():
    assert ref.ego_desired_velocity(0, 16, 5.0, H).tolist() == [5.0 * 0.6, 5.0 * 0.8]
    assert ref.ego_desired_velocity(4, 16, 5.0, EAST).tolist() == [0.0, 5.0]  # right of east is south


@pytest.mark.parametrize("action, new_heading", [(0, H), (4, R), (8, (-0.6, -0.8)), (12, (0.8, -0.6))])
def test_ego_action_in_a_step(action, new_heading):
    """A resting prey (V = 0, A = 0) heading H: F = 0.6 dir(D), A' = dir(D) * k (k = 1), V' = A' = dir(D), so
    the new heading and velocity are the desired direction, turned from the start-of-step heading."""
    for frame, expected in (("ego", new_heading), ("world", None)):
        cfg = make_cfg(prey_count=1, predator_count=1, action_frame=frame)
        st = make_world(cfg, prey=[agent((300.0, 300.0), heading=H)], predators=[agent((600.0, 600.0))])
        new = ref.motion(cfg, st, np.array([action, 0]))
        if expected is None:  # world frame: action a points 2 pi a / 16 clockwise from up, whatever the heading
            expected = [(0.0, -1.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0)][action // 4]
        np.testing.assert_allclose(new["heading"][0], expected, atol=1e-12)
        np.testing.assert_allclose(new["velocity"][0], expected, atol=1e-12)
        np.testing.assert_allclose(new["position"][0], np.array([300.0, 300.0]) + expected, atol=1e-12)


def test_ego_action_uses_the_start_of_step_heading_not_the_velocity():
    """Heading north while drifting east at 4 (V = (4, 0), A = 0): action 0 wants D = 4 * north = (0, -4);
    F = (-4, -4) clamped to 0.6 along (-1, -1) / sqrt 2; A' = that direction * k = (-1, -1) / sqrt 2."""
    cfg = make_cfg(prey_count=1, predator_count=1, action_frame="ego")
    st = make_world(cfg, prey=[agent((300.0, 300.0), vel=(4.0, 0.0), heading=NORTH)], predators=[agent((600.0, 600.0))])
    new = ref.motion(cfg, st, np.array([0, 0]))
    s = 1.0 / math.sqrt(2.0)
    np.testing.assert_allclose(new["acceleration"][0], [-s, -s], atol=1e-12)
    np.testing.assert_allclose(new["velocity"][0], [4.0 - s, -s], atol=1e-12)


# --------------------------------------------------------------------------------------------------
# Heuristics in the ego frame
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "direction, heading, n, expected",
    [
        # TurnAway fleeing a predator straight ahead (displacement 50 H): d = -50 H, u = (0, 50): reverse, n/2
        ((-30.0, -40.0), H, 16, 8),
        # fleeing a predator on the right (displacement 50 R): d = -50 R, u = (-50, 0): turn left, 3n/4
        ((40.0, -30.0), H, 16, 12),
        # chasing a prey on the right: u = (50, 0): n/4
        ((-40.0, 30.0), H, 16, 4),
        # straight ahead: 0 (whatever the world direction is)
        ((30.0, 40.0), H, 16, 0),
        # 45 degrees right of H: H + R = (-0.2, 1.4): action 2 of 16
        ((-0.2, 1.4), H, 16, 2),
        # zero direction: keep the heading, action 0
        ((0.0, 0.0), H, 16, 0),
        # heading east, a target south-east (forward 1, right 1): a tie of 0 and 1 of 4 goes to the lower
        ((1.0, 1.0), EAST, 4, 0),
        # heading east, north-east is forward 1, left 1: u = (-1, -1), a tie of 3 and 0 goes to 0
        ((1.0, -1.0), EAST, 4, 0),
        # heading east, south-west is back 1, right 1: u = (1, 1), a tie of 1 and 2 goes to 1
        ((-1.0, 1.0), EAST, 4, 1),
        # heading south, a target to the west is on its right: n/4
        ((-7.0, 0.0), SOUTH, 8, 2),
    ],
)
def test_ego_heuristic_action(direction, heading, n, expected):
    assert ref.ego_nearest_action(direction, heading, n) == expected


def test_ego_heuristic_action_of_a_north_heading_is_the_world_action():
    """Heading north, f = (0, -1) and r = (1, 0): u = (d.r, -(d.f)) = (dx, dy), the world rule itself."""
    from aquarium_warp.heuristics import nearest_action

    rng = np.random.default_rng(0)
    for d in rng.normal(size=(50, 2)):
        assert ref.ego_nearest_action(d, NORTH, 16) == nearest_action(d, np.array(NORTH), 16)


@pytest.mark.parametrize("heading", [H, EAST, (-0.28, 0.96)])
def test_ego_heuristic_picks_the_action_whose_ego_desired_direction_is_the_direction(heading):
    """The two ego conventions agree: the action the heuristic picks for a direction is the action whose ego
    desired velocity points that way."""
    for a in range(16):
        assert ref.ego_nearest_action(ref.ego_desired_velocity(a, 16, 3.0, heading), heading, 16) == a


# --------------------------------------------------------------------------------------------------
# Random spawn headings
# --------------------------------------------------------------------------------------------------
def test_episode_start_velocity_and_heading():
    paper = make_cfg(prey_count=1, predator_count=1)
    assert [v.tolist() for v in ref.episode_start_velocity_and_heading(paper, 0)] == [[-1.0, 0.0], [-1.0, 0.0]]
    assert [v.tolist() for v in ref.episode_start_velocity_and_heading(paper, 1)] == [[0.0, -1.0], [0.0, -1.0]]
    rand = make_cfg(prey_count=1, predator_count=1, spawn_heading="random")
    for slot in (0, 1):  # both types: velocity = heading * 1
        assert [v.tolist() for v in ref.episode_start_velocity_and_heading(rand, slot, (0.6, -0.8))] == [
            [0.6, -0.8],
            [0.6, -0.8],
        ]
    with pytest.raises(ValueError):
        ref.episode_start_velocity_and_heading(rand, 0)


def test_respawned_prey_takes_the_drawn_heading_at_speed_one():
    """A prey cruising up into a predator is captured and respawns; "random" takes the kernel's drawn heading
    (here (0.6, -0.8)) with velocity = heading, "paper" goes west at speed 1."""
    from test_reference_model import cruise_pred, cruise_prey

    for mode, heading in (("random", [0.6, -0.8]), ("paper", [-1.0, 0.0])):
        cfg = make_cfg(prey_count=1, predator_count=1, spawn_heading=mode)
        st = make_world(cfg, prey=[cruise_prey((400.0, 400.0))], predators=[cruise_pred((400.0, 430.0))])
        new, *_, info = ref.step(
            cfg,
            st,
            np.zeros(2, np.int64),
            0,
            respawn_position={0: (100.0, 100.0)},
            respawn_replication_age={0: 190},
            respawn_heading={0: (0.6, -0.8)},
        )
        assert info["respawned"] == [0]
        assert new["heading"][0].tolist() == heading and new["velocity"][0].tolist() == heading
        assert new["acceleration"][0].tolist() == [0.0, 0.0] and new["position"][0].tolist() == [100.0, 100.0]
    cfg = make_cfg(prey_count=1, predator_count=1, spawn_heading="random")
    st = make_world(cfg, prey=[cruise_prey((400.0, 400.0))], predators=[cruise_pred((400.0, 430.0))])
    with pytest.raises(ValueError, match="respawn heading"):
        ref.step(cfg, st, np.zeros(2, np.int64), 0, respawn_position={0: (1.0, 1.0)}, respawn_replication_age={0: 190})


def test_newborn_takes_the_drawn_heading_with_zero_velocity():
    for mode, heading in (("random", [-0.28, 0.96]), ("paper", [-1.0, 0.0])):
        cfg = make_cfg(prey_count=2, predator_count=1, prey_reproduction=True, max_prey=2, spawn_heading=mode)
        st = make_world(
            cfg, prey=[agent((100.0, 100.0), vel=(2.0, 0.0), age=199, rep=200), None], predators=[agent((600.0, 600.0))]
        )
        new, *_, info = ref.step(
            cfg,
            st,
            np.zeros(cfg.capacity, np.int64),
            0,
            newborn_replication_age={1: 180},
            newborn_heading={1: (-0.28, 0.96)},
        )
        assert info["births"] == [(0, 1)]
        assert new["heading"][1].tolist() == heading and new["velocity"][1].tolist() == [0.0, 0.0]
        assert new["position"][1].tolist() == new["position"][0].tolist()
