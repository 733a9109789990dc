"""Shipped policies by short name (`aquarium_warp.pretrained`): a name resolves to its file wherever a
policy file is taken (eval, video, study, `load_policy`, the PettingZoo env through `world`), an
existing path wins over a name, and an unknown name is refused with the shipped names. The shipped
index itself: every entry loads, in the world its metadata names."""

from __future__ import annotations

import dataclasses
import json
import os

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")

import torch

from aquarium_warp import aquarium_v1, pretrained
from aquarium_warp.cli import main
from aquarium_warp.training.config import env_config, make_config
from aquarium_warp.training.export import load_policy, policy_world
from aquarium_warp.training.trainer import Trainer

EGO = {"observation_frame": "ego", "action_frame": "ego", "spawn_heading": "random"}


@pytest.fixture
def shipped(tmp_path, monkeypatch, one_thread):
    """A policy directory holding one tiny trained ego policy under the name "prey-tiny"."""
    config = make_config(
        "tiny",
        {
            "train": {"num_worlds": 2, "iterations": 1, "quiet": True, "export": ["jit"]},
            "env": {**EGO, "prey_count": 3, "max_steps": 20},
            "runner": {"num_steps_per_env": 4},
        },
    )
    trainer = Trainer(config, str(tmp_path / "run"))
    trainer.train()
    path = trainer.export()["jit"]
    folder = tmp_path / "policies"
    folder.mkdir()
    os.replace(path, folder / "prey_tiny.pt")
    world = env_config(config).to_dict()
    (folder / "index.json").write_text(json.dumps({"policies": {"prey-tiny": {"file": "prey_tiny.pt", "env": world}}}))
    monkeypatch.setattr(pretrained, "DIRECTORY", str(folder))
    pretrained.index.cache_clear()
    yield str(folder / "prey_tiny.pt"), world
    pretrained.index.cache_clear()


def test_a_name_resolves_to_its_file_and_a_path_wins(shipped, tmp_path, monkeypatch):
    path, world = shipped
    assert pretrained.names() == ["prey-tiny"]
    assert pretrained.resolve("prey-tiny") == pretrained.resolve("PREY-TINY") == path
    assert pretrained.resolve("turnaway") == "turnaway" and pretrained.is_policy_file("prey-tiny")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "prey-tiny").write_text("a local file of that name")
    assert pretrained.resolve("prey-tiny") == "prey-tiny"  # an existing path is never shadowed
    assert pretrained.world("prey-tiny").to_dict() == world
    with pytest.raises(ValueError, match=r"'prey-nope' is unknown: shipped are \['prey-tiny'\]"):
        pretrained.world("prey-nope")


def test_load_policy_and_the_pettingzoo_env_take_a_name(shipped):
    path, world = shipped
    assert policy_world("prey-tiny") == policy_world(path)
    policy = load_policy("prey-tiny")
    env = aquarium_v1.parallel_env(config=pretrained.world("prey-tiny"))
    observations, _ = env.reset(seed=3)
    prey = {a: o for a, o in observations.items() if a.startswith("prey")}
    actions = policy.act(prey)
    assert set(actions) == set(prey) and all(0 <= a < env.config.action_count for a in actions.values())
    assert len(next(iter(prey.values()))) == policy.observation_size == 2 + 6 * 4  # the ego layout


def test_eval_video_and_study_take_a_name(shipped, tmp_path, capsys):
    out = str(tmp_path / "eval")
    assert (
        main(
            [
                "eval",
                "--prey",
                "prey-tiny",
                "constant",
                "--predator",
                "naivchase",
                "--episodes",
                "2",
                "--seeds",
                "0",
                "--max-steps",
                "10",
                "--no-figures",
                "--out",
                out,
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    with open(os.path.join(out, "summary.json"), encoding="utf-8") as f:
        rows = json.load(f)["summary"]
    assert [r["prey_policy"] for r in rows] == ["prey-tiny", "constant"]
    assert (
        main(["video", "--prey-policy", "prey-tiny", "--steps", "3", "--out", str(tmp_path / "v.mp4"), "--no-progress"])
        == 0
    )
    assert os.path.getsize(tmp_path / "v.mp4") > 0
    from aquarium_warp import BatchedAquarium
    from aquarium_warp.drivers import make_driver

    env = BatchedAquarium(pretrained.world("prey-tiny"), num_worlds=2, device="cpu")
    actions = make_driver("prey-tiny", env, "prey")()
    assert actions.shape == (2, 3) and actions.dtype == torch.int32
    capsys.readouterr()
    assert main(["eval", "--prey", "prey-nope", "--predator", "naivchase", "--episodes", "1", "--out", out]) == 2
    assert "prey-nope" in capsys.readouterr().err


def test_every_shipped_policy_loads_in_its_world():
    from aquarium_warp import BatchedAquarium
    from aquarium_warp.drivers import make_driver

    for name in pretrained.names():
        policy, team = load_policy(name), pretrained.index()[name]["team"]
        world = pretrained.world(name)
        assert env_config({"env": policy_world(name)}).to_dict() == world.to_dict(), name
        assert policy.team == team and policy.observation_size == world.observation_size(team), name
        assert os.path.getsize(pretrained.resolve(name)) < 2_000_000, name  # small files only
        # their metadata predates the action frame and the flow: taken as the defaults they were trained with
        assert "action_frame" not in policy.meta["env"] and "observe_flow" not in policy.meta["env"], name
        env = BatchedAquarium(world, num_worlds=2, device="cpu")
        slots = world.prey_capacity if team == "prey" else world.predator_capacity
        assert make_driver(name, env, team)().shape == (2, slots), name


# prey-b reads ego rows with its world heading (world actions), no flow, 1 predator and 3 prey slots, in
# "0..1": each world below gives its prey rows of that same length, 28, which mean something else there.
EQUAL_LENGTH_MISMATCHES = [
    (
        {"action_frame": "ego", "observe_flow": True},
        "env.action_frame 'world' vs 'ego', env.observe_flow False vs True",
    ),
    ({"prey": {"prey_slots": 2, "predator_slots": 2}}, "env.prey.predator_slots 1 vs 2, env.prey.prey_slots 3 vs 2"),
    ({"observation_range": "-1..1"}, "env.observation_range '0..1' vs '-1..1'"),
]
INTERFACE = "policy's world interface differs from the env's (policy's value vs env's): "


@pytest.mark.parametrize("changes, differing", EQUAL_LENGTH_MISMATCHES)
def test_a_policy_is_refused_in_a_world_of_another_interface_of_equal_length(changes, differing):
    from aquarium_warp.training.config import deep_update

    policy = load_policy("prey-b")
    world = env_config({"env": deep_update(policy_world("prey-b"), changes)})
    assert world.observation_size("prey") == policy.observation_size == 28
    with pytest.raises(ValueError) as error:
        policy.check_compatible("prey", world, world.prey_capacity)
    assert str(error.value) == INTERFACE + differing
    policy.check_compatible("prey", pretrained.world("prey-b"), 6)  # its own world: no complaint


def test_a_policy_of_another_length_is_told_which_fields_differ():
    policy = load_policy("prey-b")
    world = pretrained.world("prey-b").replace(observation_frame="world", action_count=8)
    with pytest.raises(ValueError) as error:
        policy.check_compatible("prey", world, 6)
    assert str(error.value) == (
        INTERFACE + "env.observation_frame 'ego' vs 'world', env.action_count 16 vs 8; observations of length 28 vs 29"
    )


@pytest.mark.slow
def test_eval_and_train_refuse_a_policy_in_a_world_of_another_interface(tmp_path, capsys):
    """The issue's cases: the policy's world with the action frame and flow, or the slot split, changed."""
    eval_args = ["eval", "--prey", "prey-b", "--predator", "naivchase", "--episodes", "6", "--seeds", "0"]
    eval_args += ["--max-steps", "1000", "--device", "cpu", "--out", str(tmp_path / "eval")]
    train_args = ["train", "--preset", "tiny", "--team", "predator", "--prey-policy", "prey-b", "--device", "cpu"]
    train_args += ["--log-dir", str(tmp_path / "run"), "--set", "env.observation_frame=ego"]
    for command in (eval_args, train_args):
        for changes, differing in EQUAL_LENGTH_MISMATCHES[:2]:
            sets = [f"env.{k}.{n}={v}" for k, d in changes.items() if isinstance(d, dict) for n, v in d.items()]
            sets += [f"env.{k}={str(v).lower()}" for k, v in changes.items() if not isinstance(v, dict)]
            assert main(command + [arg for s in sets for arg in ("--set", s)]) == 2, (command[0], sets)
            err = capsys.readouterr().err.strip().splitlines()
            assert err == [f"aquarium-warp {command[0]}: prey policy prey-b: {INTERFACE}{differing}"], err
    assert os.listdir(tmp_path / "eval") == []  # refused before any episode: nothing written


@pytest.mark.parametrize("world", ["A", "B", "C"])
def test_the_recipe_presets_are_the_benchmarked_recipe(world):
    """`train --preset learned-prey-<w>` trains what `study learned-prey` ran as "recipe": the paper
    preset with its world's and its assignments."""
    from aquarium_warp.studies import learned_prey
    from aquarium_warp.training.config import deep_update, make_config, parse_assignment

    preset, assignments = learned_prey.CONDITIONS["recipe"]
    changes: dict = {}
    for assignment in learned_prey.WORLDS[world] + assignments:
        deep_update(changes, parse_assignment(assignment))
    assert make_config(f"learned-prey-{world.lower()}") == make_config(preset, changes)
    assert make_config(f"learned-prey-{world.lower()}") != make_config(preset)


def test_a_study_world_takes_the_policys_interface(shipped):
    """A study with a trained team keeps its own world (prey counts, perception, spawn) but lets the
    policy's agents observe and act as they were trained to (frames, range, slot counts)."""
    from aquarium_warp import AquariumConfig
    from aquarium_warp.studies.swarm_size import SwarmSizeStudy

    study = SwarmSizeStudy(prey=[5, 7], prey_policy="prey-tiny", seeds=1)
    policy_world = pretrained.world("prey-tiny")
    for setting in study.settings():
        cfg = setting["config"]
        assert (cfg.observation_frame, cfg.action_frame) == (policy_world.observation_frame, policy_world.action_frame)
        assert cfg.prey_count == setting["prey"] and cfg.spawn_heading == "paper" and cfg.width == 800.0
        assert cfg.observation_size("prey") == policy_world.observation_size("prey")
    assert SwarmSizeStudy(prey=[5], seeds=1).settings()[0]["config"].observation_frame == "world"
    other = AquariumConfig(observation_frame="ego", observation_range="-1..1", observe_flow=True)
    other = other.replace(prey=dataclasses.replace(other.prey, prey_slots=5, view_distance=300.0))
    mixed = AquariumConfig(prey_count=9).with_interface_of(other)
    assert (
        mixed.prey_count,
        mixed.observation_frame,
        mixed.observation_range,
        mixed.observe_flow,
        mixed.prey.prey_slots,
        mixed.prey.view_distance,
    ) == (9, "ego", "-1..1", True, 5, 100.0)
