"""`eval --cross-play`: the matrix of every prey policy against every predator policy equals separate
evaluations with the same seeds (and the per-episode records they aggregate); checkpoint globs expand
in training order; the Elo fit recovers hand-made ratings."""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")

import torch

from aquarium_warp import BatchedAquarium
from aquarium_warp.drivers import make_driver
from aquarium_warp.training.config import env_config, make_config
from aquarium_warp.training.cross_play import CROSS_PLAY_METRICS, cross_play, elo_ratings, expand_specs
from aquarium_warp.training.evaluate import evaluate_policies, run_episodes
from aquarium_warp.training.trainer import Trainer


def test_elo_ratings_recover_hand_made_ratings():
    prey, predators = np.array([1700.0, 1500.0, 1350.0]), np.array([1450.0, 1800.0])
    # The Elo model's expected prey scores for these ratings: the fit must give them back (up to the
    # common shift, fixed by the mean of 1500).
    score = 1 / (1 + 10 ** ((predators[None, :] - prey[:, None]) / 400))
    got_prey, got_predators = elo_ratings(score, games=200)
    shift = 1500 - np.concatenate([prey, predators]).mean()
    np.testing.assert_allclose(got_prey, prey + shift, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got_predators, predators + shift, rtol=0, atol=1e-6)
    # By hand: even scores give equal ratings; a prey that always survives stays finite and on top.
    even_prey, even_pred = elo_ratings(np.full((2, 2), 0.5), games=10)
    np.testing.assert_allclose(np.concatenate([even_prey, even_pred]), 1500.0, atol=1e-9)
    top, _ = elo_ratings(np.array([[1.0, 1.0], [0.5, 0.5]]), games=10)
    assert np.all(np.isfinite(top)) and top[0] > top[1]
    # 0.5 / 10 games: 0.95 vs 0.5 means 400 * log10(19) Elo points between the two prey.
    assert top[0] - top[1] == pytest.approx(400 * np.log10(19), abs=1e-6)
    with pytest.raises(ValueError, match="score"):
        elo_ratings(np.array([[1.5]]), games=1)


@pytest.mark.slow
def test_cross_play_matrix_equals_single_evaluations(tmp_path):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        config = make_config(
            "tiny",
            {
                "train": {"num_worlds": 2, "iterations": 2, "quiet": True, "export": []},
                "env": {"max_steps": 25},
                "runner": {"num_steps_per_env": 4, "save_interval": 1},
            },
        )
        Trainer(config, str(tmp_path / "run")).train()
    finally:
        torch.set_num_threads(threads)
    run = str(tmp_path / "run")
    # Natural order: model_10 after model_1 (a link stands in for a later checkpoint).
    os.link(os.path.join(run, "model_1.pt"), os.path.join(run, "model_10.pt"))
    assert [s.split("=")[0] for s in expand_specs(["random", f"ckpt={run}/model_*.pt"])] == [
        "random",
        "ckpt/model_0",
        "ckpt/model_1",
        "ckpt/model_10",
    ]
    os.remove(os.path.join(run, "model_10.pt"))

    prey = ["random", f"{run}/model_*.pt"]
    predators = ["naivchase", "naivchase-noconfusion"]
    seeds, episodes = [0, 1], 2
    result = cross_play(prey, predators, episodes=episodes, seeds=seeds, device="cpu")
    cp = result["cross_play"]
    assert cp["prey"] == ["random", "model_0", "model_1"] and cp["predator"] == predators
    world = env_config(config)
    assert result["protocol"]["env"] == world.to_dict()  # the checkpoints' world
    env = BatchedAquarium(world, num_worlds=1, device="cpu")
    assert make_driver("naivchase-noconfusion", env, "predator").confusion is False
    assert make_driver("naivchase", env, "predator").confusion is True
    specs = {"random": "random", "model_0": f"{run}/model_0.pt", "model_1": f"{run}/model_1.pt"}
    for i, label in enumerate(cp["prey"]):
        for j, predator in enumerate(predators):
            single = evaluate_policies([specs[label]], [predator], world, episodes=episodes, seeds=seeds, device="cpu")[
                "summary"
            ][0]
            for metric in CROSS_PLAY_METRICS[:3]:
                assert cp["matrices"][metric]["mean"][i][j] == single[f"{metric}_mean"], (label, predator, metric)
                assert cp["matrices"][metric]["std"][i][j] == single[f"{metric}_std"], (label, predator, metric)
            # From the episodes themselves: per-seed means, then mean and std over the seeds.
            per_seed = [run_episodes(world, specs[label], predator, episodes, seed, device="cpu") for seed in seeds]
            captures = [np.mean([r["captures_per_prey"] for r in records]) for records in per_seed]
            survival = [
                np.mean([np.mean(np.array(r["prey_captures"][: world.prey_count]) == 0) for r in records])
                for records in per_seed
            ]
            assert cp["matrices"]["captures_per_prey"]["mean"][i][j] == pytest.approx(np.mean(captures), abs=1e-12)
            assert cp["matrices"]["captures_per_prey"]["std"][i][j] == pytest.approx(np.std(captures), abs=1e-12)
            assert cp["matrices"]["prey_survival"]["mean"][i][j] == pytest.approx(np.mean(survival), abs=1e-12)
    assert np.max(cp["matrices"]["captures_per_prey"]["mean"]) > 0  # the predators do catch prey here
    rating = result["rating"]
    assert set(rating["prey"]) == set(cp["prey"]) and set(rating["predator"]) == set(predators)
    assert np.mean(list(rating["prey"].values()) + list(rating["predator"].values())) == pytest.approx(1500)

    # The command line: the same matrix into CSV/JSON, and the heatmaps.
    from aquarium_warp.cli import main

    out = str(tmp_path / "xp")
    assert (
        main(
            [
                "eval",
                "--cross-play",
                "--prey",
                *prey,
                "--predator",
                *predators,
                "--episodes",
                str(episodes),
                "--seeds",
                *map(str, seeds),
                "--out",
                out,
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    with open(os.path.join(out, "cross_play.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["prey_policy"], r["predator_policy"]) for r in rows] == [(a, b) for a in cp["prey"] for b in predators]
    for r in rows:
        i, j = cp["prey"].index(r["prey_policy"]), predators.index(r["predator_policy"])
        for metric in CROSS_PLAY_METRICS:
            assert float(r[f"{metric}_mean"]) == cp["matrices"][metric]["mean"][i][j]
    saved = json.loads(open(os.path.join(out, "cross_play.json")).read())
    assert saved["matrices"] == cp["matrices"] and saved["rating"] == rating
    for metric in ("captures_per_prey", "prey_survival"):
        assert os.path.getsize(os.path.join(out, f"cross_play_{metric}.png")) > 0
