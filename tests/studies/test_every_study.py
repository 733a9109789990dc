"""Every registered study (`aquarium_warp.studies.STUDIES`) runs end to end at a tiny size on the CPU
through `aquarium-warp study <name>` and writes its record, naming the command it ran."""

from __future__ import annotations

import json

import pytest

from aquarium_warp.cli import main
from aquarium_warp.studies import STUDIES

pytest.importorskip("rsl_rl")

CPU = ["--device", "cpu"]
EPISODES = ["--seeds", "1", "--episode-steps", "10", "--metrics-every", "5", "--no-progress", "--no-figures"]
# name -> (options of a tiny run without the output folder, the output folder's option, the record it writes)
TINY: dict[str, tuple[list[str], str, str]] = {
    "swarm-size": (["--prey", "4", *EPISODES, *CPU], "--out", "swarm_size.json"),
    "fov-view": (["--fov", "360", "--view", "100", "--prey", "4", *EPISODES, *CPU], "--out", "fov_view.json"),
    "group-hunting": (
        ["--predators", "1", "--prey", "3", "--prey-conditions", "turnaway", "--share-radius", "0", "--seeds", "2"]
        + ["--worlds", "2", "--iterations", "1", "--train-steps", "20", "--eval-worlds", "2", "--eval-steps", "20"]
        + ["--no-figures", *CPU],
        "--out",
        "group_hunting.json",
    ),
    "many-eyes": (
        ["--group-sizes", "1", "--fov", "360", "--seeds", "2", "--rows", "8", "--iterations", "1"]
        + ["--train-steps", "20", "--eval-rows", "8", "--eval-steps", "20", "--no-figures", *CPU],
        "--out",
        "many_eyes.json",
    ),
    "flow": (
        ["--strengths", "0", "--seeds", "2", "--episodes-per-seed", "1", "--episode-steps", "20", "--prey", "8"]
        + ["--no-figures", *CPU],
        "--out",
        "flow.json",
    ),
    "swarm": (
        ["--part", "screen", "--prey-counts", "4", "--view-distances", "200", "--predator-speeds", "5"]
        + ["--episodes", "1", "--eval-seeds", "2", "--max-steps", "20", "--gpus", "0", "--no-figures"],
        "--out",
        "summary.json",
    ),
    "phase": (
        # the co-evolving cell: both teams and the opponent pool (a fixed-predator cell: test_phase_study.py)
        ["--cells", "coevolving-c0", "--seeds", "2", "--control-seeds", "2", "--iterations", "1", "--train-worlds", "2"]
        + ["--episodes", "1", "--eval-seeds", "2", "--max-steps", "20", "--gpus", "0", "--no-figures"]
        + ["--train-set", "runner.num_steps_per_env=8"],
        "--out",
        "summary.json",
    ),
    "learned-prey": (
        ["--plan", "tiny", "--gpus", "0", "--episodes", "1", "--eval-seeds", "0"],
        "--out",
        "learned_prey_tiny.json",
    ),
    "coevolution": (
        [
            "--tiny",
            "--worlds",
            "4",
            "--max-steps",
            "40",
            "--steps",
            "8",
            "--agent-steps",
            "1000",
            "--speed-iterations",
            "1",
        ]
        + ["--eval-episodes", "1", "--eval-seeds", "0", "--no-figures"],
        "--out-dir",
        "summary.json",
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(STUDIES))
def test_every_registered_study_runs_tiny_on_the_cpu(name, tmp_path, capsys, one_thread):
    assert name in TINY, f"give study {name!r} a tiny run in TINY"
    options, out_option, record = TINY[name]
    argv = ["study", name, *options, out_option, str(tmp_path / "out")]
    assert main(argv) == 0, capsys.readouterr().err
    with open(tmp_path / "out" / record, encoding="utf-8") as f:
        written = json.load(f)
    command = written.get("command") or written.get("run", {}).get("command")
    assert command.startswith(f"aquarium-warp study {name} "), command
