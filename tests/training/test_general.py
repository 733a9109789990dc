"""The randomised-world presets (`general-prey`, `general-predator`, `general`): the learned-prey
recipe over the declared ranges, one observation interface, trainable on the CPU; and
`naivchase-mixed`, their prey's opponent (NaivChase with and without target confusion by world)."""

from __future__ import annotations

import json
import os

import pytest
import torch

pytest.importorskip("rsl_rl")

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.drivers import make_driver
from aquarium_warp.heuristics import make_policy
from aquarium_warp.training.config import (
    GENERAL_PRESETS,
    GENERAL_RANGES,
    LEARNED_PREY_RECIPE,
    env_config,
    make_config,
    team_runner,
)
from aquarium_warp.training.export import load_policy, world_interface
from aquarium_warp.training.randomize import parse_spec
from aquarium_warp.training.trainer import Trainer


def test_the_general_presets_are_the_recipe_over_the_declared_ranges():
    configs = {name: make_config(name) for name in GENERAL_PRESETS}
    assert [c["train"]["team"] for c in configs.values()] == ["prey", "predator", "both"]
    assert [c["train"]["opponent"] for c in configs.values()] == ["naivchase-mixed", "turnaway", None]
    for name, config in configs.items():
        assert config["train"]["randomize"] == GENERAL_RANGES, name
        for key, value in LEARNED_PREY_RECIPE["env"].items():
            assert config["env"][key] == value, name
        assert team_runner(config, "prey")["algorithm"]["entropy_coef"] == 0.01
        world = env_config(config)
        # the batch holds the largest drawn prey count; a live count is a world's draw
        assert world.prey_capacity == parse_spec(f"prey_count={GENERAL_RANGES['prey_count']}")[1].high == 64
        assert world.confusion_radius == 100.0 and world.predator_count == 1
        assert config["train"]["iterations"] == 1000 and config["train"]["episodes"] is None
    # one observation interface for every world of the range, and for every preset
    for team in ("prey", "predator"):
        interfaces = {str(world_interface(c["env"], team)) for c in configs.values()}
        assert len(interfaces) == 1, team
    # the evaluation grid's views and fields of view are trained values, the predator speeds inside the range
    views = parse_spec(f"prey_view_distance={GENERAL_RANGES['prey_view_distance']}")[1].values
    fovs = parse_spec(f"prey_fov_angle={GENERAL_RANGES['prey_fov_angle']}")[1].values
    speeds = parse_spec(f"predator_max_speed={GENERAL_RANGES['predator_max_speed']}")[1]
    assert {100.0, 200.0, 10000.0} <= set(views) and {120.0, 240.0, 360.0} <= set(fovs)
    assert (speeds.low, speeds.high) == (4.5, 6.0)
    assert parse_spec(f"capture_confusion={GENERAL_RANGES['capture_confusion']}")[1].values == (0.0, 16.0)


@pytest.mark.parametrize("preset", GENERAL_PRESETS)
def test_each_general_preset_trains_on_the_cpu(preset, tmp_path, one_thread):
    small = {
        "train": {"num_worlds": 6, "iterations": 2, "device": "cpu", "quiet": True, "export": ["jit"]},
        "env": {"max_steps": 12},
        "runner": {"num_steps_per_env": 8},
    }
    trainer = Trainer(make_config(preset, small), str(tmp_path / "run"))
    trainer.train()
    for vec in trainer.vec_envs.values():
        if vec.randomizer is None:  # both teams: the first team's adapter draws for the worlds
            continue
        drawn = vec.randomizer.values
        assert set(drawn) == set(GENERAL_RANGES)
        assert drawn["prey_count"].min() >= 4 and drawn["prey_count"].max() <= 64
        assert set(drawn["capture_confusion"].tolist()) <= {0.0, 16.0}
        assert ((drawn["predator_max_speed"] >= 4.5) & (drawn["predator_max_speed"] <= 6.0)).all()
        config = vec.env.config  # the worlds' current values are the draws
        assert list(config.prey.view_distance) == drawn["prey_view_distance"].tolist()
    exported = trainer.export()
    files = exported if preset == "general" else {trainer.config["train"]["team"]: exported}
    trainer.close()
    # The fixed interface: each policy acts in a world of any prey count and view of the range.
    world = env_config(make_config(preset)).with_values(
        {"prey_count": (5, 64), "prey.view_distance": (100.0, 10000.0), "prey.fov_angle": (360.0, 120.0)}
    )
    env = BatchedAquarium(world, num_worlds=2, device="cpu")
    for team, paths in files.items():
        assert load_policy(paths["jit"]).team == team
        actions = make_driver(paths["jit"], env, team)()
        assert actions.shape == (2, 64 if team == "prey" else 1)


def test_naivchase_mixed_chases_with_confusion_in_even_worlds_and_the_nearest_prey_in_odd_ones():
    cfg = AquariumConfig(width=300.0, height=300.0, prey_count=12, predator_count=2)
    env = BatchedAquarium(cfg, num_worlds=6, device="cpu", seed=3)
    mixed = make_driver("naivchase-mixed", env, "predator")
    confused = make_policy("naivchase", env, "predator", confusion=True)
    nearest = make_policy("naivchase", env, "predator", confusion=False)
    prey = make_policy("random", env, "prey")
    differ = 0
    for _ in range(40):
        a, b, c = mixed().clone(), confused().clone(), nearest().clone()
        assert torch.equal(a[0::2], b[0::2]) and torch.equal(a[1::2], c[1::2])
        differ += int(not torch.equal(b, c))
        env.step({"prey": prey(), "predator": a})
    assert differ > 0  # the two chasers did choose differently
    assert mixed.capturable
    with pytest.raises(ValueError, match="policy"):
        make_driver("naivchase-mixed", env, "prey")


def _benchmark_module():
    import sys

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "benchmarks"))
    try:
        import general_policies as gp
    finally:
        sys.path.pop(0)
    return gp


def test_an_interrupted_general_training_continues_from_its_checkpoint(tmp_path, one_thread):
    gp = _benchmark_module()
    out = str(tmp_path / "out")
    small = {
        "train": {"num_worlds": 2, "iterations": 3, "device": "cpu", "quiet": True, "export": ["jit", "onnx"]},
        "env": {"max_steps": 12},
        "runner": {"num_steps_per_env": 4, "save_interval": 1},
    }
    folder = gp.run_dir(out, gp.PREY, 0)
    trainer = Trainer(make_config(gp.PREY, small), folder)
    trainer.train()
    trainer.export()
    trainer.close()
    assert gp.finished(out, gp.PREY, 0)
    # a run stopped after its second iteration: checkpoints 0 and 1 and an export, not the last checkpoint
    os.remove(os.path.join(folder, "model_2.pt"))
    assert not gp.finished(out, gp.PREY, 0)
    command, how = gp.pending_command(out, gp.PREY, 0, "cpu", [])
    assert how == "resume" and command[3:] == ["train", "--resume", folder, "--quiet"]
    gp.train_all(out, [gp.PREY], [0], ["cpu"], [], jobs=1, commit="0000000")
    assert gp.finished(out, gp.PREY, 0)
    # the training records the commit it was given (here beside this checkout's own, which git reads)
    with open(os.path.join(folder, "config.json"), encoding="utf-8") as f:
        assert json.load(f)["git"]["supplied"] == "0000000"
    with open(os.path.join(out, "trainings.jsonl"), encoding="utf-8") as f:
        (record,) = [json.loads(line) for line in f]
    assert record["how"] == "resume" and record["rc"] == 0
    # one stopped before its first checkpoint starts again, over what it left; one never started is new
    other = gp.run_dir(out, gp.PREY, 1)
    os.makedirs(other)
    with open(os.path.join(other, "config.json"), "w", encoding="utf-8") as f:
        f.write("{}")
    command, how = gp.pending_command(out, gp.PREY, 1, "cpu", ["train.num_worlds=2"])
    assert how == "restart" and command[-3:] == ["--set", "train.num_worlds=2", "--overwrite"]
    assert gp.pending_command(out, gp.PREY, 2, "cpu", [])[1] == "new" and not gp.finished(out, gp.PREY, 2)


@pytest.fixture
def general_policies(tmp_path, monkeypatch, one_thread):
    """Tiny `prey-any` and `predator-any`, trained on the CPU by the general presets and installed by
    benchmarks/general_policies.py's `install` into a policy folder of their own."""
    from aquarium_warp import pretrained

    gp = _benchmark_module()
    out, folder = str(tmp_path / "out"), str(tmp_path / "policies")
    small = {
        "train": {"num_worlds": 4, "iterations": 1, "device": "cpu", "quiet": True, "export": ["jit", "onnx"]},
        "env": {"max_steps": 12},
        "runner": {"num_steps_per_env": 4},
    }
    for preset, name, team in ((gp.PREY, "prey-any", "prey"), (gp.PREDATOR, "predator-any", "predator")):
        trainer = Trainer(make_config(preset, small), gp.run_dir(out, preset, 0))
        trainer.train()
        trainer.export()
        trainer.close()
        gp.install(folder, name, out, preset, 0, team, {"description": f"a tiny {name}"})
    monkeypatch.setattr(pretrained, "DIRECTORY", folder)
    pretrained.index.cache_clear()
    yield folder
    pretrained.index.cache_clear()


def test_installed_general_policies_are_taken_by_name_and_as_learned(general_policies, tmp_path, capsys):
    from aquarium_warp import pretrained
    from aquarium_warp.cli import main
    from aquarium_warp.drivers import check_spec
    from aquarium_warp.viewer.simulation import Simulation, ViewOptions

    assert pretrained.names("prey") == ["prey-any"] and pretrained.names("predator") == ["predator-any"]
    assert sorted(os.listdir(general_policies)) == [
        "index.json", "predator_any.onnx", "predator_any.pt", "prey_any.onnx", "prey_any.pt"
    ]  # fmt: skip
    for name, team in (("prey-any", "prey"), ("predator-any", "predator")):
        entry = pretrained.index()[name]
        assert entry["team"] == team and entry["training_range"] == GENERAL_RANGES
        assert pretrained.for_team("learned", team) == pretrained.for_team("LEARNED", team) == name
        jit, onnx = load_policy(name), load_policy(os.path.join(general_policies, entry["onnx"]))
        obs = torch.rand(7, jit.observation_size)
        assert jit.team == onnx.team == team and torch.equal(jit(obs), onnx(obs))
        check_spec("learned", team)
    # The worlds the policies act in: any of the range; the learned ones by name and as "learned".
    world = env_config(make_config("general-prey")).with_values({"prey_count": (5, 64)})
    env = BatchedAquarium(world, num_worlds=2, device="cpu")
    with pytest.raises(ValueError, match="trained for 'prey', not 'predator'"):
        make_driver("prey-any", env, "predator")
    assert make_driver("learned", env, "prey")().shape == (2, 64)
    assert make_driver("learned", env, "predator")().shape == (2, 1)
    out = str(tmp_path / "eval")
    args = ["eval", "--prey", "learned", "--predator", "learned", "naivchase", "--episodes", "1", "--seeds", "0"]
    assert main(args + ["--max-steps", "5", "--no-figures", "--device", "cpu", "--out", out]) == 0
    assert "prey-any" in capsys.readouterr().out
    simulation = Simulation(ViewOptions(prey_policy="learned", predator_policy="learned", device="cpu"))
    assert simulation.specs == {"prey": "prey-any", "predator": "predator-any"}
    choices = simulation.policy_choices()
    assert "predator-any" in choices["predator"] and "prey-any" not in choices["predator"]


def test_the_coevolved_pair_alone_is_evaluated_beside_the_shipped_policies(tmp_path, one_thread):
    """`--teams none --coevolved`: only `--preset general` trains; its prey and predator go on the grids
    beside the shipped `prey-any` and `predator-any`, and nothing is picked or installed."""
    gp = _benchmark_module()
    out, folder = str(tmp_path / "out"), str(tmp_path / "policies")
    sets = ["train.iterations=1", "train.num_worlds=2", "env.max_steps=8", "runner.num_steps_per_env=4"]
    argv = ["--device", "cpu", "--seeds", "0", "--out", out, "--teams", "none", "--coevolved", "--max-steps", "8"]
    argv += ["--episodes", "1", "--eval-seeds", "0", "--grid-prey-counts", "4", "--install", folder]
    assert gp.main(argv + [arg for s in sets for arg in ("--set", s)]) == 0
    assert sorted(os.listdir(os.path.join(out, "runs"))) == ["general-s0"] and not os.path.exists(folder)
    pairs = {}
    for grid in ("grid_prey", "grid_predator"):
        with open(os.path.join(out, grid, "grid.json"), encoding="utf-8") as f:
            pairs[grid] = {(p["prey"], p["predator"]): p for p in json.load(f)["pairings"]}
    prey_any = pairs["grid_prey"][("prey-any", "naivchase")]
    assert [run["prey_spec"] for run in prey_any["runs"]] == ["prey-any"]  # the shipped one, by name
    assert ("general-prey-coevolved", "naivchase") in pairs["grid_prey"]
    assert {("turnaway", "predator-any"), ("prey-any", "general-predator-coevolved")} <= set(pairs["grid_predator"])
    with open(os.path.join(out, "general_policies.json"), encoding="utf-8") as f:
        record = json.load(f)
    assert record["shipped"] == {"prey-any": None, "predator-any": None} and record["installed"] == {}
    with pytest.raises(SystemExit):
        gp.main(["--teams", "none", "--out", out])  # nothing to train
