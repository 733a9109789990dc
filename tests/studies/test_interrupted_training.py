"""Issue 49: a study's training stopped by SIGINT is not finished: the study exits with the signal's
code, keeps no result of the task in `finished/` and writes no outputs, and a rerun continues the
training from its kept state (the result then equals an uninterrupted study's)."""

from __future__ import annotations

import csv
import json
import os
import signal

import pytest

pytest.importorskip("rsl_rl")

from aquarium_warp.cli import main
from aquarium_warp.training.trainer import Trainer

GROUP_HUNTING = [
    "study",
    "group-hunting",
    "--predators",
    "1",
    "--prey",
    "3",
    "--prey-conditions",
    "turnaway",
    "--share-radius",
    "0",
    "--seeds",
    "1",
    "--worlds",
    "4",
    "--iterations",
    "3",
    "--train-steps",
    "40",
    "--eval-worlds",
    "2",
    "--eval-steps",
    "60",
    "--no-baseline",
    "--device",
    "cpu",
    "--no-figures",
]
MANY_EYES = [
    "study",
    "many-eyes",
    "--group-sizes",
    "2",
    "--fov",
    "120",
    "--seeds",
    "1",
    "--rows",
    "4",
    "--iterations",
    "3",
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
]
SWARM = [
    "study",
    "swarm",
    "--part",
    "learned",
    "--conditions",
    "no-neighbours",
    "--seeds",
    "2",
    "--iterations",
    "3",
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
# (arguments, the study's output file, where the interrupted training's state is kept under --out)
STUDIES = {
    "group-hunting": (GROUP_HUNTING, "group_hunting.csv", "policies/turnaway_share0_pred1_seed0/interrupted.pt"),
    "many-eyes": (MANY_EYES, "many_eyes.csv", "policies/learned_N2_fov120_seed0/interrupted.pt"),
    "swarm": (SWARM, "summary.json", "runs/no-neighbours-s0/model_1.pt"),
}


def result(path) -> list[dict] | dict:
    """A study's result without its times: the CSV's rows, or the swarm study's learned part."""
    if path.suffix == ".json":
        return json.loads(path.read_text())["learned"]
    with open(path, newline="", encoding="utf-8") as f:
        return [{k: v for k, v in r.items() if not k.endswith("_s")} for r in csv.DictReader(f)]


def finished(out) -> list[str]:
    folder = out / "finished"
    return sorted(os.listdir(folder)) if folder.is_dir() else []


@pytest.mark.slow
@pytest.mark.parametrize("study", list(STUDIES))
def test_sigint_during_a_studys_training_keeps_it_unfinished_and_the_rerun_continues_it(
    study, tmp_path, capsys, monkeypatch, one_thread
):
    argv, output, kept = STUDIES[study]
    out = tmp_path / "out"
    after = Trainer.after_iteration

    def interrupted(self, iteration):  # Ctrl-C during iteration 1 (the second of 3)
        after(self, iteration)
        if iteration == 1:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(Trainer, "after_iteration", interrupted)
    handler = signal.getsignal(signal.SIGINT)
    assert main(argv + ["--out", str(out)]) == 128 + signal.SIGINT
    assert signal.getsignal(signal.SIGINT) is handler
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"aquarium-warp study: stopped by SIGINT after iteration 2 of 3 of a training run, kept in "
        f"{out / os.path.dirname(kept) if study == 'swarm' else out / kept}: rerun the same command to continue it"
    )
    assert (out / kept).is_file() and not (out / output).exists()
    assert not [name for name in finished(out) if not name.startswith("screen")]  # the training task is not kept
    monkeypatch.undo()

    assert main(argv + ["--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"continuing {out / kept} at iteration 2 of 3" in printed
    assert (out / output).is_file() and finished(out)
    kept_state = out / kept
    assert kept_state.exists() == (study == "swarm")  # a run directory keeps its checkpoints; a policy folder not
    # the continued training gives the uninterrupted study's result
    assert main(argv + ["--out", str(tmp_path / "reference")]) == 0
    assert result(out / output) == result(tmp_path / "reference" / output)
