"""The derived random streams (`aquarium_warp.seeding`): each rule by hand, the numpy streams of one
seed distinct from each other and reproducible, training's randomiser apart from the config's draws,
and `aquarium-warp video` seeding its teams as eval and the studies do."""

from __future__ import annotations

import dataclasses
import random
import zlib

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp import drivers as drivers_module
from aquarium_warp.per_world import Uniform
from aquarium_warp.seeding import (
    baseline_seed,
    config_stream,
    evaluation_seed,
    next_reset_seed,
    randomiser_stream,
    rank_seed,
    reset_seeds,
    seed_process,
    set_params_stream,
    space_seed,
    team_seed,
)


def test_each_rule_by_hand():
    assert (team_seed(7, "prey"), team_seed(7, "predator")) == (7, 8)
    with pytest.raises(ValueError, match="team"):
        team_seed(7, "shark")
    assert (rank_seed(10, 0), rank_seed(10, 3)) == (10, 13)
    assert (evaluation_seed(0), evaluation_seed(2)) == (1_000_003, 3_000_009)
    assert (baseline_seed(0, 16), baseline_seed(2, 16)) == (16, 2_000_022)
    assert config_stream(5).random() == np.random.default_rng(5).random()
    assert set_params_stream(5).random() == np.random.default_rng((5, 1)).random()
    assert randomiser_stream(5).random() == np.random.default_rng((5, 2)).random()
    assert next_reset_seed(reset_seeds(4)) == random.Random(4).getrandbits(63)
    expected = int(np.random.SeedSequence([3, zlib.crc32(b"prey_0"), 1]).generate_state(1, np.uint64)[0] >> 1)
    assert space_seed(3, "prey_0", 1) == expected


def test_numpy_streams_of_one_seed_are_distinct_and_reproducible():
    for seed in (0, 1, 12345):
        draws = [make(seed).random(8) for make in (config_stream, set_params_stream, randomiser_stream)]
        again = [make(seed).random(8) for make in (config_stream, set_params_stream, randomiser_stream)]
        assert all(np.array_equal(a, b) for a, b in zip(draws, again))
        assert all(not np.array_equal(draws[i], draws[j]) for i in range(3) for j in range(i + 1, 3))
    first, again = reset_seeds(9), reset_seeds(9)
    assert [next_reset_seed(first) for _ in range(3)] == [next_reset_seed(again) for _ in range(3)]
    assert len({space_seed(3, agent, kind) for agent in ("prey_0", "prey_1") for kind in (0, 1)}) == 4


def test_seed_process_seeds_torch_numpy_and_python():
    saved = (torch.get_rng_state(), np.random.get_state(), random.getstate())
    try:
        seed = 2**32 + 5  # numpy's legacy seed takes 32 bits: 5
        seed_process(seed)
        drawn = (torch.rand(3), np.random.rand(3), random.random())
        torch.manual_seed(seed)
        np.random.seed(5)
        random.seed(seed)
        assert torch.equal(drawn[0], torch.rand(3)) and np.array_equal(drawn[1], np.random.rand(3))
        assert drawn[2] == random.random()
    finally:
        torch.set_rng_state(saved[0])
        np.random.set_state(saved[1])
        random.setstate(saved[2])


def test_the_randomiser_draws_apart_from_the_config_and_reproducibly():
    """The same seed and the same range [3, 6]: the config's per-world draws and training's randomiser
    were one stream (their values equal); now each repeats itself and they differ."""
    pytest.importorskip("rsl_rl")
    from aquarium_warp.training.randomize import ParamRandomizer

    base = AquariumConfig(prey_count=4)
    sampled = base.replace(prey=dataclasses.replace(base.prey, max_speed=Uniform(3.0, 6.0)))
    config_draws = np.array(sampled.draw(6, seed=11).prey.max_speed)
    assert np.array_equal(config_draws, np.array(sampled.draw(6, seed=11).prey.max_speed))

    def randomiser_draws() -> np.ndarray:
        env = BatchedAquarium(base, num_worlds=6, device="cpu", seed=11)
        return ParamRandomizer(env, {"prey_max_speed": "3:6"}, seed=11).values["prey_max_speed"].copy()

    first = randomiser_draws()
    assert np.array_equal(first, randomiser_draws())
    assert ((first >= 3.0) & (first <= 6.0)).all()
    assert not np.array_equal(first, config_draws)
    assert np.array_equal(first, Uniform(3.0, 6.0).draw(randomiser_stream(11), 6, False))


def test_video_seeds_each_team_by_the_team_rule(monkeypatch, tmp_path):
    """`aquarium-warp video --seed 5`: the prey's driver gets seed 5, the predators' 6 (`team_seed`), as
    `make_drivers` gives eval's and the studies' teams."""
    pytest.importorskip("imageio_ffmpeg")
    from aquarium_warp.cli import main

    seeds = {}
    make_driver = drivers_module.make_driver

    def noting(spec, env, team, **kwargs):
        seeds[team] = kwargs["seed"]
        return make_driver(spec, env, team, **kwargs)

    monkeypatch.setattr(drivers_module, "make_driver", noting)
    assert (
        main(
            [
                "video",
                "--steps",
                "1",
                "--out",
                str(tmp_path / "v.mp4"),
                "--device",
                "cpu",
                "--frame-width",
                "32",
                "--prey",
                "3",
                "--seed",
                "5",
                "--no-progress",
            ]
        )
        == 0
    )
    assert seeds == {"prey": team_seed(5, "prey"), "predator": team_seed(5, "predator")} == {"prey": 5, "predator": 6}
