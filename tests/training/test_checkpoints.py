"""Damaged checkpoints and misused CLI options (issue 15, cases 8 and 9): `train --resume` on a
missing, empty, truncated, corrupt, text or foreign file gives a one-line error; a run directory whose
newest checkpoint is broken resumes from the newest readable one; checkpoints are written atomically."""

from __future__ import annotations

import os

import pytest

pytest.importorskip("rsl_rl")

import torch

from aquarium_warp.cli import main
from aquarium_warp.training.checkpoints import latest_checkpoint
from aquarium_warp.training.config import make_config
from aquarium_warp.training.trainer import Trainer


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny run of 3 iterations, checkpointed after each (model_<i>.pt: i + 1 iterations done)."""
    torch.set_num_threads(1)
    path = str(tmp_path_factory.mktemp("run"))
    config = make_config(
        "tiny",
        {
            "train": {"num_worlds": 4, "iterations": 3, "quiet": True, "export": []},
            "env": {"max_steps": 20},
            "runner": {"num_steps_per_env": 8, "save_interval": 1},
        },
    )
    trainer = Trainer(config, path)
    trainer.train()
    trainer.close()
    return path


def _damage(path: str, kind: str, source: str) -> None:
    data = open(source, "rb").read()
    with open(path, "wb") as f:
        f.write(
            {
                "empty": b"",
                "truncated": data[: len(data) // 2],
                "text": b"hello, not a checkpoint\n",
                "corrupt": bytes(reversed(data)),
            }[kind]
        )


@pytest.mark.parametrize("kind", ["missing", "empty", "truncated", "text", "corrupt", "foreign"])
def test_resume_from_a_damaged_checkpoint_is_one_line(run_dir, tmp_path, capsys, kind):
    path = str(tmp_path / "model_5.pt")
    if kind == "foreign":
        torch.save({"weights": torch.zeros(3)}, path)
    elif kind != "missing":
        _damage(path, kind, os.path.join(run_dir, "model_2.pt"))
    assert main(["train", "--resume", path, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith("aquarium-warp train: ") and path in err, err
    expected = {"missing": "does not exist", "foreign": "not a checkpoint of aquarium_warp.training"}
    assert expected.get(kind, "not a readable checkpoint") in err, err


def test_run_directory_falls_back_to_the_newest_readable_checkpoint(run_dir, tmp_path):
    import shutil

    broken = str(tmp_path / "run")
    shutil.copytree(run_dir, broken)
    _damage(os.path.join(broken, "model_2.pt"), "truncated", os.path.join(run_dir, "model_2.pt"))
    with pytest.warns(UserWarning, match=r"skipping .*model_2\.pt: not a readable checkpoint"):
        assert latest_checkpoint(broken) == os.path.join(broken, "model_1.pt")
    with pytest.warns(UserWarning, match="model_2.pt"):
        resumed = Trainer.resume(broken)
    reference = Trainer.resume(os.path.join(run_dir, "model_1.pt"), log_dir=str(tmp_path / "reference"))
    assert resumed.iteration == reference.iteration == 2
    a, b = resumed.runner.alg.save()["actor_state_dict"], reference.runner.alg.save()["actor_state_dict"]
    assert all(torch.equal(a[n], b[n]) for n in a)
    for name in os.listdir(broken):  # all broken: a one-line error
        if name.startswith("model_"):
            _damage(os.path.join(broken, name), "empty", os.path.join(run_dir, name))
    with pytest.warns(UserWarning), pytest.raises(ValueError, match="no readable checkpoint"):
        Trainer.resume(broken)
    resumed.close()
    reference.close()


def test_an_interrupted_save_leaves_the_previous_checkpoint(run_dir, tmp_path, monkeypatch):
    """Checkpoints are written to a temporary file and renamed: a save that dies half-way leaves the
    old file whole and no partial file behind."""
    import shutil

    path = str(tmp_path / "model_2.pt")
    shutil.copy(os.path.join(run_dir, "model_2.pt"), path)
    before = open(path, "rb").read()
    trainer = Trainer.resume(os.path.join(run_dir, "model_1.pt"), log_dir=str(tmp_path / "log"))

    def dies_half_way(obj, f, *args, **kwargs):
        f.write(before[: len(before) // 3])
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        trainer.runner.save(path)
    monkeypatch.undo()
    assert open(path, "rb").read() == before
    assert sorted(os.listdir(tmp_path)) == ["log", "model_2.pt"]
    trainer.runner.save(path)  # a completed save replaces it
    assert torch.load(path, weights_only=False)["iter"] == 2
    trainer.close()
