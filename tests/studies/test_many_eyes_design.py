"""The many-eyes redesign's options (issue #30): fixed density, the learned-prey recipe and the neighbour
control, checked on hand-computed cases."""

import math

import pytest

from aquarium_warp.studies.many_eyes import ManyEyesStudy


@pytest.mark.parametrize("n, side", [(1, 200.0), (4, 400.0), (16, 800.0), (64, 1600.0)])
def test_area_per_prey_scales_the_arena_with_n(n, side):
    env = ManyEyesStudy(area_per_prey=40_000.0).env(n, 240.0, 500)
    assert env["width"] == env["height"] == pytest.approx(side)
    assert env["prey_count"] / (env["width"] * env["height"]) == pytest.approx(1 / 40_000)


def test_default_arena_is_the_models():
    env = ManyEyesStudy().env(16, 240.0, 500)
    assert "width" not in env and "height" not in env
    assert "observation_frame" not in env and "spawn_heading" not in env


def test_recipe_and_prey_slots():
    env = ManyEyesStudy(recipe=True).env(4, 120.0, 100, prey_slots=0)
    assert env["observation_frame"] == "ego" and env["spawn_heading"] == "random"
    assert env["prey"] == {"fov_angle": 120.0, "view_distance": 100.0, "prey_slots": 0}


def test_neighbour_control_policies():
    study = ManyEyesStudy(group_sizes=[1, 4], fov_angles=[240.0], seeds=2, neighbour_control=True)
    assert study.policies(1) == ("learned", "turnaway")
    assert study.policies(4) == ("learned", "no-neighbours", "turnaway")
    names = [t["name"] for t in study.tasks("cpu")]
    assert sum(n.startswith("no-neighbours_N4") for n in names) == 2
    assert not any(n.startswith("no-neighbours_N1") for n in names)
    assert len(names) == 2 * (2 + 1 + 2)


@pytest.mark.parametrize("area", [0.5, -1.0, math.inf])
def test_bad_area_per_prey(area):
    with pytest.raises(ValueError, match="area-per-prey"):
        ManyEyesStudy(area_per_prey=area).validate()
