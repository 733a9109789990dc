"""The one answer to "which world was this policy trained in" (`drivers.trained_world`, `common_world`,
`teams_world`): each former caller (eval's and cross-play's world, the video command, the viewer, the
swarm, phase and swarm-size studies, the grid's base) gets the world the shipped index records for the
policy (`policies/index.json`, written when the policies were shipped, read here without the policy
file), with its own changes on top, as it did before."""

from __future__ import annotations

import argparse
import os
import shutil
import types

import pytest

pytest.importorskip("rsl_rl", reason="trained policies need the training extra")

from aquarium_warp import pretrained
from aquarium_warp.cli import _video_config
from aquarium_warp.config import AquariumConfig
from aquarium_warp.drivers import common_world, teams_world, trained_world
from aquarium_warp.studies import phase, swarm
from aquarium_warp.studies.swarm_size import SwarmSizeStudy
from aquarium_warp.training.grid import grid_base
from aquarium_warp.viewer.simulation import Simulation, ViewOptions


@pytest.fixture
def run_dirs(tmp_path):
    """Training runs' folders holding the shipped prey-b policy where a run exports it: alone, and as
    the prey of a co-evolving run."""
    alone, both = tmp_path / "alone", tmp_path / "both"
    for target in (alone / "exported" / "policy.pt", both / "exported" / "prey" / "policy.pt"):
        target.parent.mkdir(parents=True)
        shutil.copy(pretrained.resolve("prey-b"), target)
    return str(alone), str(both)


def test_a_policy_file_or_name_gives_its_training_world():
    for name in pretrained.names("prey"):
        recorded = pretrained.world(name)
        assert trained_world(name) == recorded, name
        assert trained_world(pretrained.resolve(name)) == recorded, name
    # prey-a and prey-b differ in their prey's view (120 degrees and 100 px, 360 and 200)
    assert (pretrained.world("prey-a").prey.fov_angle, pretrained.world("prey-b").prey.fov_angle) == (120, 360)


def test_common_world_skips_heuristics_and_names_two_worlds_that_differ():
    fallback = AquariumConfig(prey_count=5)
    assert common_world(["turnaway", "naivchase"], fallback) is fallback
    assert common_world([], None) is None
    assert common_world(["turnaway", "b=prey-b", "prey-b"], fallback) == pretrained.world("prey-b")
    with pytest.raises(ValueError, match=r"'a=prey-a' and 'prey-b' were trained in different worlds \(.*fov_angle 120"):
        common_world(["a=prey-a", "prey-b"], fallback)


def test_teams_world_takes_the_counts_and_sizes_given():
    data = pretrained.world("prey-b").to_dict()
    data.update(prey_count=7, width=500.0)
    assert teams_world({"prey": "prey-b", "predator": "naivchase"}, prey_count=7, width=500.0, height=None) == (
        AquariumConfig.from_dict(data)
    )
    assert teams_world({"prey": "turnaway", "predator": "random"}, predator_count=3) == AquariumConfig(predator_count=3)


def test_each_former_caller_gets_the_policys_world(run_dirs):
    alone, both = run_dirs
    world = pretrained.world("prey-b")
    data = world.to_dict()

    # aquarium-warp video: the policy's world, the command line's counts and sizes on top
    args = argparse.Namespace(
        prey_policy="prey-b", predator_policy="naivchase", prey=None, predators=2, width=None, height=640.0, flow=None
    )
    assert _video_config(args) == AquariumConfig.from_dict({**data, "predator_count": 2, "height": 640.0})
    # aquarium-warp view: the same, from its options
    options = ViewOptions(prey_policy="prey-b", prey=9)
    view = Simulation._config(types.SimpleNamespace(options=options), {"prey": "prey-b", "predator": "naivchase"})
    assert view == AquariumConfig.from_dict({**data, "prey_count": 9})
    # the swarm and phase studies: the exported policy's world with the task's episode length
    assert swarm.policy_world({"run_dir": alone, "max_steps": 30}) == world.replace(max_steps=30)
    assert phase.world_of({"run_dir": both, "coevolving": True, "max_steps": 30}) == world.replace(max_steps=30)
    assert phase.world_of({"run_dir": alone, "coevolving": False, "max_steps": 30}, "confusion", 1.5) == world.replace(
        max_steps=30, capture_rule="confusion", capture_confusion=1.5
    )
    # the swarm-size study and eval --grid: docs/model.md's world observing and acting as the policy's
    policy = os.path.join(alone, "exported", "policy.pt")
    cfg = SwarmSizeStudy(prey=[4], prey_policy=policy, out="unused").settings()[0]["config"]
    assert (cfg.observation_frame, AquariumConfig().observation_frame, world.observation_frame) == (
        "ego",
        "world",
        "ego",
    )
    assert cfg.with_interface_of(world) == cfg  # the view stays the study's: fov 120, not the policy's 360
    assert grid_base(["random", f"b={policy}"]) == AquariumConfig(spawn_heading="paper").with_interface_of(world)
