"""`aquarium-warp study phase`: the pre-registered design, the regimes its thresholds name and the
verdicts of its contrasts, checked on hand-made seed values; and a tiny end-to-end run on the CPU."""

import argparse

import pytest

from aquarium_warp.studies import STUDIES, phase


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    phase.add_arguments(parser)
    args = parser.parse_args(list(argv))
    args.argv = ["study", "phase", *argv]
    return args


def test_the_study_is_registered_with_its_declared_cells():
    assert STUDIES["phase"] is phase
    assert len(phase.CELLS) == 20
    slices = {c.slice for c in phase.CELLS.values()}
    assert slices == {"rule", "density-view", "fov", "predator-speed", "coevolving"}
    # The density x view slice is a full 3 x 3 grid with the swarm preset's world at its centre.
    grid = {(c.prey, c.view) for c in phase.CELLS.values() if c.slice == "density-view"}
    assert grid | {(32, 200.0)} == {(n, v) for n in (8, 32, 128) for v in (100.0, 200.0, 400.0)}
    centre = phase.CELLS["dilution-c64"]
    assert (centre.prey, centre.view, centre.fov, centre.strength) == (32, 200.0, 360.0, 64.0)
    # c = 0 is one cell; its mediation partner is dilution at c = 64, the others' is c = 0.
    assert phase.CELLS["c0"].other_strength() == ("dilution", 64.0)
    assert phase.CELLS["confusion-c1"].other_strength() == ("confusion", 0.0)
    assert phase.controls_of(phase.CELLS["coevolving-c0"]) == ("learned", "no-slots")
    # The first tier runs by default: the rule slice, the density-view cross and Li et al.'s condition.
    assert parse().cells.split(",") == list(phase.FIRST_TIER)
    assert phase.FIRST_TIER[-1] == "coevolving-c0" and "dilution-c64" in phase.FIRST_TIER
    assert {phase.CELLS[c].slice for c in phase.FIRST_TIER} == {"rule", "density-view", "coevolving"}


def test_the_committed_first_tier_finds_every_kept_task(tmp_path):
    """The tasks the default command builds are the ones whose results the first tier kept
    (benchmarks/results/phase_h200_9e8c35c/finished.tgz): a rerun with the same options runs nothing
    again, so any change to a task's key (a training config, an evaluation's settings) fails here."""
    import os
    import pathlib
    import tarfile

    from aquarium_warp.jobs import read_finished

    results = pathlib.Path(__file__).parents[2] / "benchmarks" / "results" / "phase_h200_9e8c35c"
    (tmp_path / "finished").mkdir()
    with tarfile.open(results / "finished.tgz") as archive:
        for member in archive.getmembers():
            if member.isfile():  # each finished/<task>.json
                (tmp_path / "finished" / os.path.basename(member.name)).write_bytes(archive.extractfile(member).read())
    study = phase.check(parse("--out", str(tmp_path)))
    trainings = phase.training_tasks(study)
    tasks = trainings + phase.eval_tasks(study, trainings) + phase.baseline_tasks(study, trainings)
    assert len(tasks) == 441 == len(list((tmp_path / "finished").iterdir()))
    assert [t["name"] for t in tasks if not read_finished(str(tmp_path), t)[0]] == []


@pytest.mark.parametrize(
    "argv, message",
    [
        (("--cells", "c0,nowhere"), "--cells='c0,nowhere': choose from"),
        (("--cells", "c0,c0"), "--cells"),
        (("--seeds", "1"), "--seeds"),
        (("--control-seeds", "1"), "--control-seeds"),
        (("--episodes", "0"), "--episodes"),
        (("--gpus", "-1"), "--gpus"),
    ],
)
def test_bad_options_are_refused_by_name(argv, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        phase.check(parse(*argv))


def test_regimes_follow_the_declared_thresholds():
    tight = lambda m: [m - 0.01, m, m + 0.01, m - 0.005, m + 0.005]  # noqa: E731
    # The primary's interval must lie wholly beyond a threshold.
    assert phase.regime(tight(1.3), tight(0.1), tight(0.1)) == "dispersed"
    assert phase.regime(tight(1.0), tight(0.9), tight(0.1)) == "no structure"
    assert phase.regime([0.80, 0.95, 0.70, 0.99, 0.85], tight(0.9), tight(0.1)) == "no structure"  # reaches 0.9
    assert phase.regime(tight(0.6), tight(0.8), tight(0.2)) == "polarized school"
    assert phase.regime(tight(0.6), tight(0.2), tight(0.8)) == "mill"
    assert phase.regime(tight(0.6), tight(0.5), tight(0.5)) == "swarm"
    assert phase.regime(tight(0.6), tight(0.7), tight(0.4)) == "swarm"  # ordered but rotating too much
    assert phase.regime([0.6], [0.8], [0.1]) == "no structure"  # one seed: no interval


def test_contrast_verdicts_use_the_margins_and_the_direction():
    a = [0.60, 0.61, 0.59, 0.60, 0.60]
    far = [0.90, 0.91, 0.89, 0.90, 0.90]
    near = [0.605, 0.60, 0.595, 0.60, 0.60]
    effect = phase.contrast(a, far, phase.PRIMARY, paired=False, direction=-1)
    assert effect["verdict"] == "effect" and effect["difference"] == pytest.approx(-0.3)
    # The same difference in the other direction is not the regime's effect, nor equivalence.
    assert phase.contrast(a, far, phase.PRIMARY, paired=False, direction=1)["verdict"] == "undecided"
    assert phase.contrast(a, near, phase.PRIMARY, paired=False, direction=-1)["verdict"] == "none"
    # A difference inside the margin whose interval is too wide to show equivalence.
    wide = [0.50, 0.70, 0.45, 0.75, 0.62]
    assert phase.contrast(a, wide, phase.PRIMARY, paired=False)["verdict"] == "undecided"
    # Captures: a margin of 10% of the control's mean.
    captures = phase.contrast([1.0, 1.02, 0.98, 1.0], [2.0, 2.02, 1.98, 2.0], "captures_per_prey", paired=True)
    assert captures["margin"] == pytest.approx(0.2) and captures["verdict"] == "effect"


def test_readings_credit_an_aggregate_to_interaction_and_predation():
    def values(primary, polarization=0.3, rotation=0.2, captures=1.0):
        spread = (-0.01, 0.0, 0.01, -0.005, 0.005)
        return {
            phase.PRIMARY: [primary + s for s in spread],
            "group_polarization": [polarization + s for s in spread],
            "group_rotation": [rotation + s for s in spread],
            "captures_per_prey": [captures + s for s in spread],
        }

    per = {
        "learned": {"own": values(0.6, captures=0.5), "blind": values(0.9, captures=1.0)},
        "no-slots": {"own": values(0.9, captures=1.0)},
        "no-predation": {"own": values(0.61)},
    }
    out = phase.readings(per)
    assert out["regime"] == "swarm"
    verdicts = {(c["contrast"], c["measure"]): c["verdict"] for c in out["contrasts"]}
    assert verdicts[("learned - no prey slots", phase.PRIMARY)] == "effect"
    assert verdicts[("learned - no predation", phase.PRIMARY)] == "none"
    assert verdicts[("learned - its slots emptied (paired)", "captures_per_prey")] == "effect"
    assert verdicts[("learned - no prey slots", "group_polarization")] == "none"


@pytest.mark.slow
def test_a_tiny_study_end_to_end_on_the_cpu(tmp_path):
    """Every part of a fixed-predator cell at a tiny size: trainings (learned prey and both trained
    controls), evaluations (own, blind, other-c), heuristics, the summary, its tables and figures; a rerun
    keeps every task. (A co-evolving cell runs in tests/studies/test_every_study.py.)"""
    import csv
    import json

    from aquarium_warp.cli import main

    argv = ["study", "phase", "--gpus", "0", "--cells", "confusion-c1", "--seeds", "2", "--control-seeds", "2"]
    argv += ["--iterations", "2", "--train-worlds", "2", "--episodes", "1", "--eval-seeds", "2", "--max-steps", "20"]
    argv += ["--train-set", "env.max_steps=8", "--train-set", "runner.num_steps_per_env=8", "--out", str(tmp_path)]
    assert main(argv) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    confusion = summary["cells"]["confusion-c1"]
    assert set(confusion["controls"]) == {"learned", "no-slots", "no-predation"}
    assert set(confusion["controls"]["learned"]) == {"own", "blind", "other-c"}
    assert set(confusion["heuristics"]) == set(phase.HEURISTIC_PREY)
    assert confusion["regime"] in {"dispersed", "no structure", "swarm", "polarized school", "mill"}
    # The no-predation control never captures.
    assert confusion["controls"]["no-predation"]["own"]["captures_per_prey"]["mean"] == 0.0
    with open(tmp_path / "readings.csv", newline="") as f:
        readings = list(csv.DictReader(f))
    assert {r["cell"] for r in readings} == {"confusion-c1"} and len(readings) == 10
    assert {r["verdict"] for r in readings} <= {"effect", "none", "undecided"}
    with open(tmp_path / "per_seed.csv", newline="") as f:
        assert sum(1 for r in csv.DictReader(f) if r["control"] == "learned" and r["evaluation"] == "own") == 2
    assert (tmp_path / "training_series.csv").exists() and (tmp_path / "phase_rule.png").exists()
    assert (tmp_path / "runs" / "confusion-c1-learned-s0" / "swarm.csv").exists()
    # A rerun of the same command runs nothing again.
    before = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "finished").iterdir()}
    assert main(argv) == 0
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "finished").iterdir()} == before
