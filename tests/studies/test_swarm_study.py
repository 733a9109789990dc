"""The swarm study (`aquarium-warp study swarm`, issue #30) on the CPU: its screen part end to end on a
tiny grid (a row per heuristic prey x predator, the aggregation index from the uniform prey's
nearest-neighbour distance, a rerun that runs no task), with a capture-confusion axis, its learned
part end to end (the capture-confusion conditions too), the training runs' configs against
`aquarium-warp train`'s, and its option checks."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math

import pytest

from aquarium_warp.cli import build_parser, main
from aquarium_warp.jobs import FINISHED_DIR, task_devices
from aquarium_warp.statistics import interval
from aquarium_warp.studies import STUDIES, swarm

SCREEN = [
    "study",
    "swarm",
    "--part",
    "screen",
    "--prey-counts",
    "4",
    "--view-distances",
    "200",
    "--predator-speeds",
    "5",
    "--episodes",
    "2",
    "--eval-seeds",
    "2",
    "--max-steps",
    "60",
    "--gpus",
    "0",
    "--no-figures",
]


def test_the_screen_end_to_end_and_a_rerun_runs_nothing(tmp_path, capsys, one_thread):
    assert STUDIES["swarm"] is swarm
    out = tmp_path / "swarm"
    assert main(SCREEN + ["--out", str(out)]) == 0
    assert "(1 to run)" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"].startswith("aquarium-warp study swarm --part screen")
    rows = summary["screen"]
    assert sorted((r["prey_policy"], r["predator_policy"]) for r in rows) == sorted(
        (p, q) for p in swarm.HEURISTIC_PREY for q in swarm.PREDATORS
    )
    for row in rows:
        assert (row["prey_count"], row["view_distance"], row["predator_speed"]) == (4, 200.0, 5.0)
        uniform = row["uniform"]["nn_mean"]
        assert uniform > 0 and {"local_alignment", "milling"} <= set(row["uniform"])
        nn, index = row["swarm_nn_mean"], row[swarm.PRIMARY]
        assert nn["n"] == index["n"] == 2  # one value per evaluation seed
        assert index["values"] == pytest.approx([v / uniform for v in nn["values"]], rel=1e-12)
        assert index["mean"] == pytest.approx(nn["mean"] / uniform, rel=1e-12)
        captures = row["captures_per_prey"]
        assert captures["mean"] == pytest.approx(sum(captures["values"]) / 2) and captures["ci95"] is not None
    lines = (out / "screen.csv").read_text().splitlines()
    assert len(lines) == 1 + len(rows)
    task = out / FINISHED_DIR / "screen-n4-v200-p5.json"
    before, mtime = task.read_bytes(), task.stat().st_mtime_ns
    # The same command again: the screen world's task is kept, nothing runs.
    assert main(SCREEN + ["--out", str(out)]) == 0
    assert "(0 to run)" in capsys.readouterr().out
    assert task.read_bytes() == before and task.stat().st_mtime_ns == mtime
    assert json.loads((out / "summary.json").read_text())["screen"] == rows


def test_the_screen_with_capture_confusion_keeps_the_worlds_without_it(tmp_path, capsys, one_thread):
    """`--capture-confusion 0,4`: the c = 0 world is the screen's task as before (its name, its kept
    result); the c = 4 world is a task of its own, its env has the confusion, and its rows say so."""
    out = tmp_path / "swarm"
    assert main(SCREEN + ["--out", str(out)]) == 0
    plain = out / FINISHED_DIR / "screen-n4-v200-p5.json"
    before = plain.read_bytes()
    capsys.readouterr()
    assert main(SCREEN + ["--capture-confusion", "0,4", "--out", str(out)]) == 0
    assert "(1 to run)" in capsys.readouterr().out
    assert plain.read_bytes() == before
    confused = json.loads((out / FINISHED_DIR / "screen-n4-v200-p5-c4.json").read_text())["result"]
    assert confused["env"]["capture_confusion"] == 4.0 and confused["env"]["confusion_radius"] == 100.0
    assert json.loads(before)["result"]["env"]["capture_confusion"] == 0.0
    rows = json.loads((out / "summary.json").read_text())["screen"]
    pairs = len(swarm.HEURISTIC_PREY) * len(swarm.PREDATORS)
    assert [r["capture_confusion"] for r in rows] == [0.0] * pairs + [4.0] * pairs
    header = (out / "screen.csv").read_text().splitlines()[0].split(",")
    assert header[:4] == ["prey_count", "view_distance", "predator_speed", "capture_confusion"]


def options(**changes) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    swarm.add_arguments(parser)
    args = parser.parse_args([])
    for name, value in changes.items():
        setattr(args, name, value)
    return args


@pytest.mark.parametrize(
    "changes, option",
    [
        ({"seeds": 1}, "--seeds"),
        ({"episodes": 0}, "--episodes"),
        ({"eval_seeds": 0}, "--eval-seeds"),
        ({"max_steps": 0}, "--max-steps"),
        ({"per_gpu": 0}, "--per-gpu"),
        ({"train_worlds": 0}, "--train-worlds"),
        ({"gpus": -1}, "--gpus"),
        ({"conditions": "swarm,flocking"}, "--conditions"),
        ({"conditions": "swarm,swarm"}, "--conditions"),
        ({"prey_counts": "1,8"}, "--prey-counts"),
        ({"prey_counts": "8,8"}, "--prey-counts"),
        ({"view_distances": "0.5"}, "--view-distances"),
        ({"predator_speeds": "5,0"}, "--predator-speeds"),
        ({"predator_speeds": "five"}, "--predator-speeds"),
        ({"capture_confusion": "-1"}, "--capture-confusion"),
        ({"capture_confusion": "0,1e16"}, "--capture-confusion"),
        ({"capture_confusion": "4,4"}, "--capture-confusion"),
    ],
)
def test_check_refuses_bad_options_naming_them(changes, option):
    with pytest.raises(ValueError) as error:
        swarm.check(options(**changes))
    message = str(error.value)
    assert message.startswith(f"{option}=") and len(message.splitlines()) == 1, message


def test_check_accepts_the_defaults_and_parses_the_lists():
    study = swarm.check(options())
    assert study.prey_counts == [8, 16, 32, 64] and study.view_distances == [100.0, 200.0, 400.0]
    assert study.predator_speeds == [5.0, 4.5, 4.0, 3.5] and study.conditions == list(swarm.CONDITIONS)
    assert study.capture_confusion == [0.0]


def test_a_bad_option_is_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "swarm"
    assert main(SCREEN + ["--seeds", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "aquarium-warp study: --seeds=1 must be an integer >= 2", err
    assert not out.exists()


def test_an_out_that_is_a_file_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "results.json"
    out.write_text("a user's file")
    assert main(SCREEN + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aquarium-warp study: --out ") and "is a file, not a folder" in err, err
    assert out.read_text() == "a user's file"


def test_comparisons_keep_their_keys_and_the_pairing():
    a, b = [1.0, 2.0, 3.0, 4.0], [0.5, 1.0, 2.5, 3.0]  # matched differences 0.5, 1, 0.5, 1
    paired = swarm.comparison(a, b, True, 1.2)
    assert set(paired) == {"difference", "ci95", "paired", "margin", "equivalent"} and paired["paired"] is True
    # t(0.975, 3) = 3.182446, se = sqrt(1/12 / 4); t(0.95, 3) = 2.353363: 90% interval inside ±1.2
    assert paired["difference"] == pytest.approx(0.75)
    assert paired["ci95"] == pytest.approx(3.182446 * math.sqrt(1 / 48), abs=1e-6) and paired["equivalent"] is True
    welch = swarm.comparison(a, b, False, None)
    assert set(welch) == {"difference", "ci95", "paired"} and welch["ci95"] > paired["ci95"]
    assert swarm.comparison(a, b, False, 0.0)["equivalent"] is False  # no captures: no margin to be inside
    assert interval([1.0, None, 3.0]) == {
        "mean": 2.0,
        "ci95": pytest.approx(12.706205 * 1.0, abs=1e-5),
        "n": 2,
        "values": [1.0, 3.0],
    }


def old_train_argv(args, condition: str, seed: int, device: str) -> list[str]:
    """The `aquarium-warp train` command line that trained the committed results (`train_command` of
    swarm.py before its trainings ran in-process, commit 39265e4), without its --log-dir."""
    spec = swarm.CONDITIONS[condition]
    worlds = args.train_worlds or max(1, swarm.TRAIN_AGENT_STEPS // (spec["prey"] * 32 * args.iterations))
    iterations = args.iterations * spec.get("budget", 1)
    argv = [
        "train",
        "--preset",
        args.train_preset,
        "--seed",
        str(seed),
        "--device",
        device,
        "--quiet",
        "--export",
        "jit",
        "--overwrite",
        "--save-interval",
        str(iterations),
        "--prey",
        str(spec["prey"]),
        "--num-worlds",
        str(worlds),
        "--iterations",
        str(iterations),
        "--entropy",
        "0.01",
        "--predator-policy",
        spec["opponent"],
    ]
    recipe = ("env.observation_frame=ego", "env.spawn_heading=random")  # the recipe's part of those commands
    # (the commands ran when torch's float32 path was the default; today it takes the two --set)
    torch_path = ("train.fused_mlp=false", "train.tf32=false")
    for s in torch_path + swarm.SCENARIO + recipe + tuple(spec["sets"]) + tuple(args.train_set):
        argv += ["--set", s]
    return argv


@pytest.mark.parametrize(
    "changes",
    [{}, {"train_preset": "tiny", "iterations": 2, "train_worlds": 4, "train_set": ["runner.num_steps_per_env=8"]}],
)
def test_each_condition_trains_with_the_config_of_its_train_command(changes):
    from aquarium_warp.training.cli import train_config

    args = options(**changes)
    study = swarm.check(args)
    for condition in swarm.CONDITIONS:
        for seed, device in ((0, "cpu"), (3, "cuda:0")):
            config = swarm.run_config(study, condition, seed)
            assert config["train"]["device"] is None  # the task is given its device
            config["train"]["device"] = device
            assert config == train_config(build_parser().parse_args(old_train_argv(args, condition, seed, device)))


def test_more_gpus_than_the_machine_has_are_refused():
    import torch

    count = torch.cuda.device_count()
    with pytest.raises(ValueError, match=rf"^--gpus={count + 1} must be at most the {count} CUDA devices"):
        task_devices(count + 1)
    assert task_devices(0) == ["cpu"]


LEARNED = [
    "study",
    "swarm",
    "--part",
    "learned",
    "--conditions",
    "no-neighbours",
    "--seeds",
    "2",
    "--iterations",
    "1",
    "--train-worlds",
    "2",
    "--train-preset",
    "tiny",
    "--episodes",
    "1",
    "--eval-seeds",
    "2",
    "--max-steps",
    "40",
    "--gpus",
    "0",
    "--no-figures",
]


def test_the_confusion_conditions_train_in_their_worlds():
    """The capture-confusion conditions: the swarm scenario (N = 32, 360 degrees, 200 px) with c = 16
    and a 100 px radius, trained against NaivChase without target confusion (as `no-confusion`, their
    c = 0 control), each control with its one change, compared on that predator's evaluation."""
    from aquarium_warp.training.config import env_config

    study = swarm.check(options())
    configs = {c: swarm.run_config(study, c, 0) for c in swarm.CONDITIONS if c.startswith("confusion")}
    worlds = {c: env_config(config) for c, config in configs.items()}
    assert set(worlds) == {
        "confusion",
        "confusion-no-neighbours",
        "confusion-no-predation",
        "confusion-mild",
        "confusion-strong",
        "confusion-strong-no-neighbours",
    }
    control = env_config(swarm.run_config(study, "no-confusion", 0))
    base = worlds["confusion"]
    assert base == control.replace(capture_confusion=16.0, confusion_radius=100.0)
    assert (base.prey_count, base.prey.fov_angle, base.prey.view_distance) == (32, 360.0, 200.0)
    assert base.capture_probability == 1.0 and base.predator.max_speed == 5.0 and base.prey.prey_slots == 3
    assert worlds["confusion-no-neighbours"] == base.replace(prey=dataclasses.replace(base.prey, prey_slots=0))
    assert worlds["confusion-no-predation"] == base.replace(capture_probability=0.0)
    assert worlds["confusion-mild"] == base.replace(capture_confusion=4.0)
    strong = worlds["confusion-strong"]
    assert strong == base.replace(capture_confusion=64.0)
    assert worlds["confusion-strong-no-neighbours"] == strong.replace(prey=dataclasses.replace(base.prey, prey_slots=0))
    for c, config in configs.items():
        assert config["train"]["opponent"] == "naivchase-noconfusion", c
        assert swarm.CONDITIONS[c]["evaluated"] == "noconfusion"
    # The dose figure's c of each condition is the c its world trains with.
    swarm_world = env_config(swarm.run_config(study, "swarm", 0))
    for c, world in {**worlds, "no-confusion": control, "swarm": swarm_world}.items():
        assert swarm.capture_confusion_of(c) == world.capture_confusion, c
    for control_condition in ("no-confusion", "confusion-no-neighbours", "confusion-no-predation", "confusion-mild"):
        assert ("confusion", control_condition) in swarm.CONTRASTS
    assert {("confusion-strong", "confusion"), ("confusion-strong", "confusion-strong-no-neighbours")} <= set(
        swarm.CONTRASTS
    )


CONFUSION_LEARNED = [
    "confusion,confusion-no-neighbours,confusion-no-predation,no-confusion" if a == "no-neighbours" else a
    for a in LEARNED
]


@pytest.mark.slow
def test_the_confusion_conditions_end_to_end(tmp_path, capsys, one_thread):
    """The capture-confusion conditions and their c = 0 control train, and each policy is evaluated in
    its own world (with the confusion it was trained with): the never-capturing predator catches nothing
    there; the declared contrasts are made, on the nearest-target predator's evaluation."""
    out = tmp_path / "swarm"
    assert main(CONFUSION_LEARNED + ["--out", str(out)]) == 0
    assert "training 4 conditions x 2 seeds (8 to run)" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    conditions = summary["learned"]["conditions"]
    assert list(conditions) == ["confusion", "confusion-no-neighbours", "confusion-no-predation", "no-confusion"]
    for c, entry in conditions.items():
        assert entry["seeds"] == [0, 1] and entry["noconfusion"][swarm.PRIMARY]["n"] == 2
        assert ("blind" in entry) == (c != "confusion-no-neighbours")
        evaluated = json.loads((out / FINISHED_DIR / f"eval-{c}-s0.json").read_text())["result"]["env"]
        assert evaluated["capture_confusion"] == (0.0 if c == "no-confusion" else 16.0)
        assert evaluated["capture_probability"] == (0.0 if c == "confusion-no-predation" else 1.0)
    no_predation = conditions["confusion-no-predation"]
    for label in ("naivchase", "blind", "noconfusion", "boids|naivchase-noconfusion", "turnaway|naivchase"):
        assert no_predation[label]["captures_per_prey"]["mean"] == 0.0
    comparisons = summary["learned"]["comparisons"]
    made = {c["comparison"] for c in comparisons}
    for control in ("no-confusion", "confusion-no-neighbours", "confusion-no-predation"):
        assert f"confusion minus {control}" in made
    assert "confusion minus boids prey" in made
    # The contrast is made on the `noconfusion` evaluations of both conditions.
    primary = next(
        c for c in comparisons if c["comparison"] == "confusion minus no-confusion" and c["measure"] == swarm.PRIMARY
    )
    a = conditions["confusion"]["noconfusion"][swarm.PRIMARY]["mean"]
    b = conditions["no-confusion"]["noconfusion"][swarm.PRIMARY]["mean"]
    assert primary["difference"] == pytest.approx(a - b)
    swarm.plot(str(out), summary)
    assert (out / "learned.png").stat().st_size > 0 and (out / "confusion_dose.png").stat().st_size > 0


@pytest.mark.slow
def test_the_learned_part_end_to_end_and_a_rerun_runs_nothing(tmp_path, capsys, one_thread):
    out = tmp_path / "swarm"
    assert main(LEARNED + ["--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "training 1 condition x 2 seeds (2 to run)" in printed and "evaluating 2 policies (2 to run)" in printed
    summary = json.loads((out / "summary.json").read_text())
    entry = summary["learned"]["conditions"]["no-neighbours"]
    assert entry["seeds"] == [0, 1] and "blind" not in entry  # no prey slots to empty
    assert entry["naivchase"][swarm.PRIMARY]["n"] == 2 and "boids|naivchase" in entry
    assert [(t["condition"], t["seed"]) for t in summary["trainings"]] == [("no-neighbours", 0), ("no-neighbours", 1)]
    policy = out / "runs" / "no-neighbours-s1" / "exported" / "policy.pt"
    mtime = policy.stat().st_mtime_ns
    assert main(LEARNED + ["--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "(2 to run)" not in printed and "(1 to run)" not in printed and printed.count("(0 to run)") == 3
    assert policy.stat().st_mtime_ns == mtime
    again = json.loads((out / "summary.json").read_text())
    assert again["learned"] == summary["learned"] and again["trainings"] == summary["trainings"]


def test_the_swarm_preset_is_the_confusion_strong_condition():
    """`aquarium-warp train --preset swarm` trains the world, predator, recipe and budget of the study's
    `confusion-strong` condition (the scenario where learned prey aggregate)."""
    from aquarium_warp.training.config import env_config, make_config

    study = swarm.run_config(swarm.check(options()), "confusion-strong", 0)
    preset = make_config("swarm")
    assert env_config(preset) == env_config(study)
    assert env_config(preset).capture_confusion == 64.0 and env_config(preset).prey_count == 32
    for key in ("team", "opponent", "num_worlds", "iterations", "episodes", "actor_lr", "critic_lr"):
        assert preset["train"][key] == study["train"][key], key
    assert preset["runner"]["algorithm"] == study["runner"]["algorithm"]
