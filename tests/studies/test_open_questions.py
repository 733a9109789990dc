"""The open-question studies (`aquarium_warp/studies/`): their measures on hand-made cases, and each
subcommand's plumbing at tiny sizes through the CLI (a couple of PPO iterations, few worlds, short
episodes, 2 seeds), checking the files and their columns."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
import torch

from aquarium_warp.arguments import number_list
from aquarium_warp.cli import main
from aquarium_warp.studies.flow import ANGLE_BINS, EscapeMeasures
from aquarium_warp.studies.group_hunting import encirclement, pair_distances
from aquarium_warp.studies.many_eyes import FlightOnsets, dilution_expectation


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def read_json(path):
    with open(path, encoding="utf-8") as f:
        return json.load(f)


# ---------------------------------------------------------------------------------------------- measures
def test_encirclement_on_predators_placed_by_hand():
    centre = torch.tensor([[400.0, 400.0]]).repeat(5, 1)
    predators = torch.tensor(
        [
            [[450.0, 400.0], [350.0, 400.0], [0.0, 0.0]],  # opposite sides: balanced, gap 180
            [[450.0, 400.0], [460.0, 400.0], [0.0, 0.0]],  # one side, same bearing: spread 0, gap 360
            [[500.0, 400.0], [400.0 - 50.0, 400.0 + 86.6025], [400.0 - 50.0, 400.0 - 86.6025]],  # 3 at 120 degrees
            [[450.0, 400.0], [400.0, 650.0], [0.0, 0.0]],  # the second is beyond the radius: one predator
            [[400.0, 450.0], [400.0, 350.0], [300.0, 400.0]],  # the third is dead
        ]
    )
    alive = torch.tensor(
        [[True, True, False], [True, True, False], [True, True, True], [True, True, False], [True, True, False]]
    )
    count, spread, gap = encirclement(centre, predators, alive, 200.0, 800.0, 800.0)
    assert count.tolist() == [2, 2, 3, 1, 2]
    assert spread[0] == pytest.approx(1.0) and gap[0] == pytest.approx(180.0)
    assert spread[1] == pytest.approx(0.0, abs=1e-9) and gap[1] == pytest.approx(360.0)
    assert spread[2] == pytest.approx(1.0, abs=1e-5) and gap[2] == pytest.approx(120.0, abs=1e-3)
    assert math.isnan(spread[3]) and math.isnan(gap[3])
    assert spread[4] == pytest.approx(1.0) and gap[4] == pytest.approx(180.0)
    # Across the torus edge: a prey at x = 5 and predators at x = 795 and x = 55 are 10 and 50 px away.
    count, spread, gap = encirclement(
        torch.tensor([[5.0, 400.0]]),
        torch.tensor([[[795.0, 400.0], [55.0, 400.0]]]),
        torch.tensor([[True, True]]),
        100.0,
        800.0,
        800.0,
    )
    assert count.item() == 2 and spread.item() == pytest.approx(1.0) and gap.item() == pytest.approx(180.0)


def test_pair_distances_use_the_torus_and_skip_dead_predators():
    predators = torch.tensor([[[10.0, 0.0], [790.0, 0.0], [400.0, 400.0]]])
    d = pair_distances(predators, torch.tensor([[True, True, False]]), 800.0, 800.0)
    assert d.tolist() == pytest.approx([20.0])
    assert pair_distances(predators, torch.tensor([[True, True, True]]), 800.0, 800.0).numel() == 3


def _flights(respawn_at=None, pushed_at=None):
    """Three prey against a predator at (500, 400): prey 0 at 150 px (unseen: beyond its 100 px view) and
    prey 2 at 70 px (seen, ahead) swim towards it and turn round over two steps; prey 1 at 50 px swims
    away all along (fleeing, but it never turns)."""
    detector = FlightOnsets(
        lag=2,
        flee_angle=45.0,
        flee_distance=200.0,
        turn_angle=30.0,
        max_speed=4.0,
        view_distance=100.0,
        fov_angle=120.0,
        width=800.0,
        height=800.0,
    )
    position = torch.tensor([[[350.0, 400.0], [450.0, 400.0], [430.0, 400.0]]])
    predator, predator_alive = torch.tensor([[[500.0, 400.0]]]), torch.tensor([[True]])
    alive = torch.ones(1, 3, dtype=torch.bool)
    turn = [(4.0, 0.0), (0.0, 4.0), (-4.0, 0.0), (-4.0, 0.0)]
    onsets = []
    for t, v in enumerate(turn):
        velocity = torch.tensor([[v, (-4.0, 0.0), v]])
        heading = velocity / 4.0
        respawned = torch.zeros(1, 3, dtype=torch.bool)
        if respawn_at == t:
            respawned[0, 0] = True
        pushed = torch.zeros(1, 3, dtype=torch.bool)
        if pushed_at == t:
            pushed[0, 0] = True
        onsets.append(detector.update(position, velocity, heading, alive, predator, predator_alive, respawned, pushed))
    return detector, torch.stack(onsets)


def test_flight_onsets_on_a_hand_made_trajectory():
    detector, onsets = _flights()
    # One onset each for prey 0 and 2, at the first step of straight flight (t = 2); none for prey 1.
    assert onsets[:, 0].nonzero().tolist() == [[2, 0], [2, 2]]
    result = detector.result()
    assert result["onsets"] == 2
    assert result["fid"] == pytest.approx((150.0 + 70.0) / 2)  # distances when the turns began (t - lag)
    assert result["blind_fraction"] == pytest.approx(0.5)  # prey 0 never saw the predator, prey 2 did
    # A prey respawned within the lag has no onset: its history belongs to its previous life.
    detector, onsets = _flights(respawn_at=1)
    assert onsets[:, 0].nonzero().tolist() == [[2, 2]]
    # Nor one whose turn had a bounce off a neighbour in it (pushed in the move after t = 1).
    detector, onsets = _flights(pushed_at=1)
    assert onsets[:, 0].nonzero().tolist() == [[2, 2]]
    # A push after the onset's step does not matter.
    detector, onsets = _flights(pushed_at=2)
    assert onsets[:, 0].nonzero().tolist() == [[2, 0], [2, 2]]


def test_dilution_expectation_formula():
    assert dilution_expectation([1, 4, 16], [2.0, 9.0, 9.0]).tolist() == pytest.approx([2.0, 0.5, 0.125])
    # The smallest group size need not come first, nor be 1: c(N0) * N0 / N.
    assert dilution_expectation([8, 2, 4], [9.0, 1.0, 9.0]).tolist() == pytest.approx([0.25, 1.0, 0.5])


def test_escape_cosine_against_the_measured_current():
    escape = EscapeMeasures(
        1, torch.device("cpu"), flee_angle=45.0, flee_distance=200.0, max_speed=4.0, width=800.0, height=800.0
    )
    current = torch.tensor([1.0, 0.0])
    before = torch.tensor([[[100.0, 100.0], [700.0, 700.0], [799.5, 300.0]]])
    velocity = torch.tensor([[[-2.0, 0.0], [0.0, 3.0], [2.0, 0.0]]])
    position = (before + velocity + current) % 800.0  # the third prey wraps round the edge
    predator = torch.tensor([[[150.0, 100.0], [700.0, 300.0]]])
    escape.update(
        before, position, velocity, torch.ones(1, 3, dtype=torch.bool), predator, torch.ones(1, 2, dtype=torch.bool)
    )
    # Prey 0 flees predator 0 (51 px behind it, against the current); prey 2 flees predator 1 (102 px
    # behind it, with the current); prey 1 is 400 px from both, not fleeing, and crosses the current.
    values = escape.per_world()
    assert values["escape_cosine"][0] == pytest.approx(0.0)  # (-1 + 1) / 2
    assert values["downstream_fraction"][0] == pytest.approx(0.5)
    assert values["cruise_cosine"][0] == pytest.approx(0.0, abs=1e-6)
    histogram = escape.histogram[0].tolist()
    assert histogram[0] == 1 and histogram[ANGLE_BINS - 1] == 1 and sum(histogram) == 2


def test_number_list_names_the_option_and_range():
    assert number_list("1,2,...,8", int, "--predators", 1, 64) == [1, 2, 4, 8]
    with pytest.raises(ValueError, match=r"--fov=.*400.*\(0, 360\]"):
        number_list("60,400", float, "--fov", 0.0, 360.0, low_open=True)
    with pytest.raises(ValueError, match=r"--strengths.*\[0, 100\]"):
        number_list("-1", float, "--strengths", 0.0, 100.0)


# ---------------------------------------------------------------------------------------------- the CLI
def _check_record(path, study):
    record = read_json(path)
    assert record["study"] == study and record["command"].startswith(f"aquarium-warp study {study} ")
    assert record["device"] == "cpu" and record["wall_time_s"] > 0 and 0 <= record["training_fraction"] <= 1
    assert record["spread"].startswith("mean ± 1 s.e.m.")
    return record


def test_group_hunting_random_baseline(tmp_path, capsys, one_thread):
    """`--random-baseline`: random predator teams against TurnAway prey at every team size and seed, and
    `random_differences`, each learned team's seed mean minus theirs (checked against the CSV)."""
    out = tmp_path / "gh"
    args = ["study", "group-hunting", "--predators", "1,2", "--prey", "3", "--prey-conditions", "turnaway"]
    args += ["--share-radius", "0", "--seeds", "2", "--worlds", "4", "--iterations", "1", "--train-steps", "40"]
    args += ["--eval-worlds", "2", "--eval-steps", "60", "--no-baseline", "--random-baseline", "--device", "cpu"]
    assert main(args + ["--out", str(out)]) == 0, capsys.readouterr().err
    rows = read_csv(out / "group_hunting.csv")
    assert sorted((r["condition"], r["predators"], r["seed"]) for r in rows if r["condition"] == "random") == [
        ("random", n, seed) for n in ("1", "2") for seed in ("0", "1")
    ]
    record = json.loads((out / "group_hunting.json").read_text())
    assert {r["label"] for r in record["results"]} == {
        "random predators vs TurnAway (heuristic)",
        "learned vs TurnAway prey, reward capturer only",
    }
    differences = record["random_differences"]
    assert [(d["condition"], d["predators"]) for d in differences] == [("turnaway", 1), ("turnaway", 2)]
    for d in differences:
        n = str(d["predators"])
        turnaway, random = (
            [float(r["captures_per_predator"]) for r in rows if (r["condition"], r["predators"]) == (c, n)]
            for c in ("turnaway", "random")
        )
        got = d["differences"]["captures_per_predator"]["difference"]
        assert got == pytest.approx(sum(turnaway) / len(turnaway) - sum(random) / len(random))


@pytest.mark.slow
def test_group_hunting_cli_tiny(tmp_path, capsys, one_thread):
    out = tmp_path / "gh"
    rc = main(
        [
            "study",
            "group-hunting",
            "--predators",
            "1,2",
            "--prey",
            "3",
            "--share-radius",
            "0",
            "--seeds",
            "2",
            "--worlds",
            "4",
            "--iterations",
            "2",
            "--train-steps",
            "40",
            "--eval-worlds",
            "2",
            "--eval-steps",
            "60",
            "--device",
            "cpu",
            "--out",
            str(out),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    rows = read_csv(out / "group_hunting.csv")
    assert list(rows[0]) == [
        "condition",
        "share_radius",
        "predators",
        "seed",
        "captures_per_predator",
        "captures_per_prey",
        "joint_fraction",
        "spread_capture",
        "spread_random",
        "gap_capture",
        "gap_random",
        "pair_distance_capture",
        "pair_distance_random",
        "train_s",
        "job_s",
    ]
    # 2 learned conditions + NaivChase, 2 team sizes, 2 seeds.
    assert sorted({r["condition"] for r in rows}) == ["cotrained", "naivchase", "turnaway"] and len(rows) == 12
    assert all(r["joint_fraction"] in ("0", "nan") for r in rows if r["predators"] == "1")
    record = _check_record(out / "group_hunting.json", "group-hunting")
    assert record["training_fraction"] > 0 and len(record["results"]) == 6
    assert (out / "group_hunting.png").stat().st_size > 0
    policies = out / "policies" / "cotrained_share0_pred2_seed1"
    assert (policies / "prey" / "policy.pt").is_file()
    # The flow study takes trained policy files: the co-trained teams in a vortex.
    rc = main(
        [
            "study",
            "flow",
            "--kinds",
            "vortex",
            "--strengths",
            "1",
            "--seeds",
            "2",
            "--episodes-per-seed",
            "1",
            "--episode-steps",
            "30",
            "--prey",
            "3",
            "--predators",
            "2",
            "--prey-policy",
            str(policies / "prey" / "policy.pt"),
            "--predator-policy",
            str(policies / "predator" / "policy.pt"),
            "--device",
            "cpu",
            "--no-figures",
            "--out",
            str(tmp_path / "flow"),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    assert read_json(tmp_path / "flow" / "flow.json")["settings"]["prey_policy"].endswith("policy.pt")


@pytest.mark.slow
def test_many_eyes_cli_tiny(tmp_path, capsys, one_thread):
    out = tmp_path / "me"
    rc = main(
        [
            "study",
            "many-eyes",
            "--group-sizes",
            "1,2",
            "--fov",
            "360",
            "--seeds",
            "2",
            "--rows",
            "8",
            "--iterations",
            "2",
            "--train-steps",
            "40",
            "--eval-rows",
            "8",
            "--eval-steps",
            "80",
            "--device",
            "cpu",
            "--out",
            str(out),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    rows = read_csv(out / "many_eyes.csv")
    assert list(rows[0]) == [
        "policy",
        "group_size",
        "fov_angle",
        "predator",
        "seed",
        "captures_per_prey",
        "fid",
        "blind_fraction",
        "onsets_per_prey",
        "train_s",
        "job_s",
    ]
    assert len(rows) == 2 * 2 * 2 * 2  # learned / turnaway, N, predator with / without confusion, seeds
    record = _check_record(out / "many_eyes.json", "many-eyes")
    for entry in record["results"]:
        single = next(
            e
            for e in record["results"]
            if e["group_size"] == 1 and (e["policy"], e["predator"]) == (entry["policy"], entry["predator"])
        )
        expected = single["metrics"]["captures_per_prey"]["mean"] / entry["group_size"]
        assert entry["dilution_expectation"]["mean"] == pytest.approx(expected)
    assert (out / "many_eyes.png").stat().st_size > 0


def test_flow_cli_tiny(tmp_path, capsys, one_thread):
    out = tmp_path / "flow"
    rc = main(
        [
            "study",
            "flow",
            "--strengths",
            "0,2",
            "--seeds",
            "2",
            "--episodes-per-seed",
            "1",
            "--episode-steps",
            "60",
            "--prey",
            "8",
            "--uniform-angle",
            "0",
            "--device",
            "cpu",
            "--out",
            str(out),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    rows = read_csv(out / "flow.csv")
    assert list(rows[0]) == [
        "kind",
        "strength",
        "seed",
        "episodes",
        "captures_per_prey",
        "polarization",
        "groups",
        "largest_group",
        "nn_mean",
        "escape_cosine",
        "cruise_cosine",
        "downstream_fraction",
    ]
    assert [(r["kind"], r["strength"]) for r in rows[::2]] == [
        ("uniform", "0"),
        ("uniform", "2"),
        ("vortex", "0"),
        ("vortex", "2"),
    ]
    assert all(r["escape_cosine"] == "nan" and r["cruise_cosine"] == "nan" for r in rows if r["strength"] == "0")
    # Prey spawn swimming west, against a +x current, and TurnAway keeps that heading until it sees a predator.
    uniform = [float(r["cruise_cosine"]) for r in rows if r["kind"] == "uniform" and r["strength"] == "2"]
    assert np.mean(uniform) < -0.5
    record = _check_record(out / "flow.json", "flow")
    assert record["training_fraction"] == 0
    for name in ("flow.png", "flow_escape_angles.png"):
        assert (out / name).stat().st_size > 0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["group-hunting", "--prey-conditions", "turnaway,wolves"], "prey conditions"),
        (["group-hunting", "--share-radius", "-5"], "--share-radius"),
        (["many-eyes", "--fov", "0,120"], "--fov"),
        (["many-eyes", "--group-sizes", "0,4"], "--group-sizes"),
        (["flow", "--kinds", "grid"], "flow kinds"),
        (["flow", "--prey-policy", "no_such_file.pt"], "prey-policy"),
        (["flow", "--prey-policy", "naivchase"], "prey heuristic"),  # a predator's heuristic
        (["flow", "--strengths", "1,2,1"], "--strengths=[1.0, 2.0, 1.0] repeats 1.0"),
        (["many-eyes", "--fov", "60,60.0"], "--fov=[60.0, 60.0] repeats"),
        (["group-hunting", "--predators", "1,2,2"], "--predators=[1, 2, 2] repeats 2"),
        (["group-hunting", "--prey-conditions", "turnaway,turnaway"], "--prey-conditions"),
    ],
)
def test_bad_options_are_named(argv, message, tmp_path, capsys):
    assert main(["study", *argv, "--device", "cpu", "--out", str(tmp_path / "x"), "--no-figures"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_jobs_in_worker_processes_match_one_process(tmp_path):
    """`--jobs 2` trains and evaluates in two spawned worker processes; the rows come back in task order."""
    argv = [
        "study",
        "group-hunting",
        "--predators",
        "1,2",
        "--prey-conditions",
        "turnaway",
        "--share-radius",
        "100",
        "--seeds",
        "1",
        "--worlds",
        "4",
        "--iterations",
        "2",
        "--train-steps",
        "40",
        "--eval-worlds",
        "2",
        "--eval-steps",
        "40",
        "--no-baseline",
        "--device",
        "cpu",
        "--no-figures",
    ]
    assert main(argv + ["--jobs", "2", "--out", str(tmp_path / "two")]) == 0
    assert main(argv + ["--jobs", "1", "--out", str(tmp_path / "one")]) == 0
    two, one = (read_csv(tmp_path / name / "group_hunting.csv") for name in ("two", "one"))
    assert [(r["predators"], r["seed"]) for r in two] == [("1", "0"), ("2", "0")]
    for a, b in zip(one, two):
        assert {k: v for k, v in a.items() if not k.endswith("_s")} == {
            k: v for k, v in b.items() if not k.endswith("_s")
        }
    assert read_json(tmp_path / "two" / "group_hunting.json")["jobs"] == 2


@pytest.mark.slow
def test_a_rerun_keeps_finished_tasks(tmp_path, capsys, one_thread):
    """Finished tasks are kept in `out/finished/`: a rerun runs none of them again and writes the same
    rows; other settings run afresh."""
    argv = [
        "study",
        "many-eyes",
        "--group-sizes",
        "1",
        "--fov",
        "120",
        "--seeds",
        "2",
        "--rows",
        "4",
        "--iterations",
        "1",
        "--train-steps",
        "20",
        "--eval-rows",
        "4",
        "--eval-steps",
        "30",
        "--no-turnaway",
        "--device",
        "cpu",
        "--no-figures",
        "--out",
        str(tmp_path),
    ]
    assert main(argv) == 0
    first = read_csv(tmp_path / "many_eyes.csv")
    assert len(list((tmp_path / "finished").iterdir())) == 2
    capsys.readouterr()
    assert main(argv) == 0
    assert "2 of 2 tasks kept" in capsys.readouterr().out
    assert read_csv(tmp_path / "many_eyes.csv") == first
    assert read_json(tmp_path / "many_eyes.json")["tasks_kept"] == 2
    assert main(argv + ["--eval-steps", "40"]) == 0  # the last value of an option counts
    assert "kept" not in capsys.readouterr().out
    assert read_json(tmp_path / "many_eyes.json")["tasks_kept"] == 0


@pytest.mark.slow
def test_the_open_questions_trainings_train_as_populations_with_the_same_results(tmp_path, capsys, one_thread):
    """Group hunting's and many eyes' trainings that may share a process train first as populations
    (2 runs per process here; on a GPU as many as it holds), then each task takes its trained policy:
    the results equal those of the trainings alone (bit for bit on the CPU)."""
    import os
    from pathlib import Path

    from aquarium_warp.studies.group_hunting import GroupHuntingStudy, run_group_hunting
    from aquarium_warp.studies.many_eyes import ManyEyesStudy, run_many_eyes

    hunting = {"predators": [2], "prey": 3, "prey_conditions": ["turnaway"], "share_radii": [0.0], "seeds": 2,
               "worlds": 4, "iterations": 2, "train_steps": 40, "eval_worlds": 2, "eval_steps": 60, "baseline": False,
               "device": "cpu", "figures": False}  # fmt: skip
    eyes = {"group_sizes": [4], "fov_angles": [120.0, 360.0], "seeds": 1, "rows": 16, "iterations": 2,
            "train_steps": 40, "eval_rows": 8, "eval_steps": 60, "turnaway": False, "device": "cpu",
            "figures": False}  # fmt: skip
    for study_class, run, settings, file in (
        (GroupHuntingStudy, run_group_hunting, hunting, "group_hunting.csv"),
        (ManyEyesStudy, run_many_eyes, eyes, "many_eyes.csv"),
    ):
        together = study_class(**settings, out=str(tmp_path / f"{file}-together"))
        run(together, runs_per_process=2)
        assert "training 2 runs as one population on cpu (up to 2: given)" in capsys.readouterr().out
        trained = [p for p, _, names in os.walk(tmp_path / f"{file}-together") if "trained.json" in names]
        assert len(trained) == 2
        alone = study_class(**settings, out=str(tmp_path / f"{file}-alone"))
        run(alone)
        assert "as one population" not in capsys.readouterr().out

        def measures(path):  # (the times differ)
            return [{k: v for k, v in row.items() if k not in ("train_s", "job_s")} for row in read_csv(path)]

        assert measures(Path(together.out) / file) == measures(Path(alone.out) / file)
