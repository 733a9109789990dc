"""`aquarium-warp video` films a trained policy in the world it was trained in (from its metadata):
an Individual-Learning policy of 4 prey gets a 4-prey world; prey and predator policy files from
different worlds are refused; explicit world options still override."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")

import torch

import aquarium_warp.video
from aquarium_warp import AquariumConfig
from aquarium_warp.cli import main
from aquarium_warp.training.config import env_config, make_config
from aquarium_warp.training.export import export_policy
from aquarium_warp.training.trainer import Trainer


@pytest.fixture
def filmed(monkeypatch):
    """Records the env and the frame count of every `record` call the video command makes."""
    calls = []
    real = aquarium_warp.video.record

    def spy(env, *args, **kwargs):
        frames = real(env, *args, **kwargs)
        calls.append((env.config, env.prey_capacity, {t: o.shape for t, o in env.observations.items()}, frames))
        return frames

    monkeypatch.setattr(aquarium_warp.video, "record", spy)
    return calls


@pytest.mark.slow
def test_video_uses_the_trained_policys_world(tmp_path, filmed, capsys):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        # Individual Learning (one network per slot): it can act only for exactly 4 prey.
        config = make_config(
            "tiny",
            {
                "train": {"num_worlds": 2, "iterations": 1, "quiet": True, "export": ["jit"], "sharing": "individual"},
                "env": {"prey_count": 4, "width": 300.0, "height": 350.0, "max_steps": 20},
                "runner": {"num_steps_per_env": 4},
            },
        )
        trainer = Trainer(config, str(tmp_path / "il"))
        trainer.train()
        policy = trainer.export()["jit"]
    finally:
        torch.set_num_threads(threads)
    trained_world = env_config(config)

    out = str(tmp_path / "il.mp4")
    assert main(["video", "--prey-policy", policy, "--steps", "25", "--out", out, "--no-progress"]) == 0
    cfg, prey_capacity, shapes, frames = filmed[-1]
    assert cfg.to_dict() == trained_world.to_dict()  # prey count, arena, episode length: the policy's
    assert prey_capacity == 4 and shapes["prey"][:2] == (1, 4) and (cfg.width, cfg.height) == (300.0, 350.0)
    assert frames == 26 and os.path.getsize(out) > 0
    assert "4 prey" in capsys.readouterr().out

    # Explicit options override the policy's world (here into one the IL policy cannot act in).
    assert main(["video", "--prey-policy", policy, "--prey", "6", "--steps", "1", "--out", out, "--no-progress"]) == 2
    assert "4 per-slot networks" in capsys.readouterr().err

    # Heuristics only: docs/model.md's world, as before.
    assert main(["video", "--steps", "0", "--out", out, "--no-progress"]) == 0
    assert filmed[-1][0].to_dict() == AquariumConfig().to_dict() and filmed[-1][1] == 16

    # A predator policy file from another world (6 prey) is refused before anything is built.
    meta = {**trainer.policy_meta(), "team": "predator", "env": {**config["env"], "prey_count": 6}}
    other = export_policy(trainer.actor, meta, str(tmp_path / "other"), formats=["jit"])["jit"]
    count = len(filmed)
    assert (
        main(
            [
                "video",
                "--prey-policy",
                policy,
                "--predator-policy",
                other,
                "--steps",
                "1",
                "--out",
                out,
                "--no-progress",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert f"policies {policy!r} and {other!r} were trained in different worlds (prey_count 4 vs 6)" in err
    assert len(err.strip().splitlines()) == 1 and len(filmed) == count
