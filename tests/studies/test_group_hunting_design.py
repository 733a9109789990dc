"""The group-hunting redesign's options (issue #30): predators no faster than prey, teammates in view,
the learned-prey recipe, and the declared equivalence test of reward sharing, on hand-made cases."""

import pytest

from aquarium_warp.studies.group_hunting import SHARING_MARGIN, GroupHuntingStudy, sharing_equivalence


def test_default_world_is_the_models():
    env = GroupHuntingStudy().env(2, 100.0, 500)
    assert "predator" not in env and "observation_frame" not in env
    assert env["predator_count"] == 2 and env["catch_share_radius"] == 100.0


def test_redesign_fields():
    env = GroupHuntingStudy(predator_speed=4.0, predator_slots=3, recipe=True).env(3, 0.0, 200)
    assert env["predator"] == {"max_speed": 4.0, "predator_slots": 3}
    assert env["observation_frame"] == "ego" and env["spawn_heading"] == "random"
    assert env["catch_share_radius"] == 0.0 and env["max_steps"] == env["predator_starvation_steps"] == 200


@pytest.mark.parametrize(
    "field, value, option",
    [
        ("predator_speed", 0.0, "predator-speed"),
        ("predator_slots", -1, "predator-slots"),
        ("predator_slots", 1.5, "predator-slots"),
    ],
)
def test_bad_redesign_values(field, value, option):
    with pytest.raises(ValueError, match=option):
        GroupHuntingStudy(**{field: value}).validate()


def rows(values):
    return [{"captures_per_predator": v} for v in values]


def test_sharing_equivalence_cases():
    # Seed means 10 +- 0.01 on both sides: the difference's 90% interval is far inside +-10% of 10 = +-1.
    same = sharing_equivalence(rows([9.99, 10.0, 10.01, 10.0, 10.0]), rows([10.0, 10.01, 9.99, 10.0, 10.0]))
    assert same["equivalent"] and same["margin"] == pytest.approx(SHARING_MARGIN * 10.0)
    # Shared catches 20% more, consistently: not equivalent.
    apart = sharing_equivalence(rows([12.0, 12.1, 11.9, 12.0, 12.0]), rows([10.0, 10.1, 9.9, 10.0, 10.0]))
    assert not apart["equivalent"] and apart["difference"] == pytest.approx(2.0)
    # Too few seeds, or no captures to scale the margin by: no test.
    assert sharing_equivalence(rows([10.0]), rows([10.0, 10.0])) is None
    assert sharing_equivalence(rows([0.0, 0.0]), rows([0.0, 0.0])) is None
