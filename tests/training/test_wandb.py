"""The Weights & Biases logger of rsl-rl (`--set runner.logger=wandb`, the `[wandb]` extra), offline: a
run trains, and the videos of `train.video_every` reach W&B as MP4 media as well as TensorBoard."""

from __future__ import annotations

import glob
import os

import pytest

pytest.importorskip("rsl_rl")
pytest.importorskip("wandb")


@pytest.mark.slow
def test_wandb_logger_trains_and_receives_videos(tmp_path, monkeypatch, one_thread):
    from aquarium_warp.training import Trainer, make_config

    monkeypatch.setenv("WANDB_MODE", "offline")  # nothing leaves the machine
    monkeypatch.setenv("WANDB_DIR", str(tmp_path))
    monkeypatch.setenv("WANDB_SILENT", "true")
    config = make_config(
        "tiny",
        {
            "train": {
                "num_worlds": 4,
                "iterations": 2,
                "quiet": True,
                "export": [],
                "video_every": 1,
                "video_steps": 5,
            },
            "env": {"max_steps": 20},
            "runner": {
                "num_steps_per_env": 8,
                "save_interval": 1,
                "logger": "wandb",
                "wandb_project": "aquarium-warp-test",
            },
        },
    )
    trainer = Trainer(config, str(tmp_path / "run"))
    trainer.train()
    trainer.close()
    assert sorted(os.listdir(tmp_path / "run" / "videos")) == ["iteration_0.mp4", "iteration_1.mp4"]
    uploaded = glob.glob(str(tmp_path / "wandb" / "offline-run-*" / "files" / "media" / "videos" / "*.mp4"))
    assert len(uploaded) == 2
