"""`aquarium-warp study learned-prey` (`benchmarks/learned_prey.py`) on the CPU: every training's config against the
`aquarium-warp train` command line that trained it before its trainings ran in-process, and the tiny plan end to end
(trainings, evaluations with the baselines, the record with per-seed values and provenance; a rerun runs nothing
again, and a report keeps result files it finds)."""

from __future__ import annotations

import glob
import json
import os
import shlex

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")
from aquarium_warp.studies import learned_prey

RESULTS = os.path.join(os.path.dirname(__file__), "..", "..", "benchmarks", "results", "learned_prey_ego")
# The conditions that no committed plan trained, as `CONDITIONS` gave them before the trainings ran
# in-process (commit ec1364b): (preset, --set assignments, other `train` arguments).
UNRECORDED = {
    "ego-rand-il": (
        "paper",
        ["env.observation_frame=ego", "env.action_frame=ego", "env.spawn_heading=random"],
        ["--sharing", "individual"],
    ),
    "tiny-ego": (
        "tiny",
        ["env.observation_frame=ego", "env.action_frame=ego", "env.spawn_heading=random"],
        ["--iterations", "2"],
    ),
    "tiny-world": ("tiny", [], ["--iterations", "2"]),
}


def recorded_train_argv() -> dict[tuple[str, str, int], list[str]]:
    """The `aquarium-warp train` command lines that trained the committed results (their records'
    "trainings"), by (condition, world, seed), without the interpreter and --log-dir."""
    argv = {}
    for path in glob.glob(os.path.join(RESULTS, "learned_prey_*.json")):
        with open(path, encoding="utf-8") as f:
            trainings = json.load(f)["trainings"]
        for training in trainings:
            words = shlex.split(training["command"])
            log = words.index("--log-dir")
            name, seed = os.path.basename(words[log + 1]).rsplit("-s", 1)
            condition, world = name.rsplit("-", 1)
            argv[(condition, world, int(seed))] = words[words.index("train") : log] + words[log + 2 :]
    return argv


def old_train_argv(condition: str, world: str, seed: int, device: str) -> list[str]:
    """An `UNRECORDED` condition's command line (`train_command` at commit ec1364b, without --log-dir)."""
    preset, sets, extra = UNRECORDED[condition]
    argv = ["train", "--preset", preset, "--seed", str(seed), "--device", device, "--quiet", "--export", "jit"]
    for s in learned_prey.WORLDS[world] + sets:
        argv += ["--set", s]
    return argv + extra


def test_each_condition_trains_with_the_config_of_its_train_command():
    from aquarium_warp.cli import build_parser
    from aquarium_warp.training.cli import train_config

    recorded = recorded_train_argv()
    planned = {(c, w, s) for plan in learned_prey.PLANS.values() for c, w, seeds in plan for s in seeds}
    assert {key for key in planned if key[0] not in UNRECORDED} <= set(recorded)
    cases = dict(recorded)
    for condition in UNRECORDED:
        for world in learned_prey.WORLDS:
            for seed, device in ((0, "cpu"), (3, "cuda:0")):
                cases[(condition, world, seed)] = old_train_argv(condition, world, seed, device)
    assert {condition for condition, _, _ in cases} == set(learned_prey.CONDITIONS)
    for (condition, world, seed), argv in cases.items():
        config = learned_prey.run_config(condition, world, seed)
        assert config["train"]["device"] is None  # the task is given its device
        config["train"]["device"] = argv[argv.index("--device") + 1]
        # (the commands ran when torch's float32 path was the default; today it takes the two --set)
        argv = argv + ["--set", "train.fused_mlp=false", "--set", "train.tf32=false"]
        assert config == train_config(build_parser().parse_args(argv)), (condition, world, seed)


@pytest.mark.slow
def test_the_tiny_plan_end_to_end(tmp_path, staged_copy):
    out = str(tmp_path / "lp")
    argv = [
        "--plan",
        "tiny",
        "--gpus",
        "0",
        "--out",
        out,
        "--episodes",
        "2",
        "--eval-seeds",
        "0",
        "--commit",
        "abc1234",
    ]
    assert learned_prey.main(argv) == 0
    with open(os.path.join(out, "learned_prey_tiny.json"), encoding="utf-8") as f:
        record = json.load(f)
    assert record["git"]["commit"] == "abc1234" and "device_name" in record["machine"]
    assert "learned_prey.py" in record["command"]
    rows = {(r["condition"], r["world"]): r for r in record["rows"]}
    assert set(rows) == {("tiny-ego", "A"), ("tiny-world", "B")}
    assert rows[("tiny-ego", "A")]["learned"]["n"] == 2 and len(rows[("tiny-ego", "A")]["learned"]["values"]) == 2
    for row in rows.values():
        assert {"random", "constant", "turnaway"} <= set(row)
    with open(os.path.join(out, "eval", "tiny-ego-A.json"), encoding="utf-8") as f:
        assert json.load(f)["git"]["commit"] == "abc1234"
    # A rerun keeps every task (finished/) and runs nothing.
    assert learned_prey.main(argv) == 0
    with open(os.path.join(out, "learned_prey_tiny.json"), encoding="utf-8") as f:
        assert json.load(f)["trainings"] == []
    # A report into a folder that already holds a result keeps it.
    results = tmp_path / "results"
    results.mkdir()
    (results / "learned_prey_tiny.json").write_text('{"kept": true}')
    learned_prey.report(out, str(results))
    assert json.loads((results / "learned_prey_tiny.json").read_text()) == {"kept": True}
    assert (results / "curves.csv").exists() and (results / "eval" / "tiny-world-B.json").exists()
