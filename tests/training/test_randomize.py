"""Domain randomisation (`training/randomize.py`, `train --randomize`): per-world values drawn at every
world's reset, inside the range, reproducible for a seed; bad specs refused in one line naming the field."""

from __future__ import annotations

import json

import pytest
import torch

pytest.importorskip("rsl_rl")

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.training.randomize import ParamRandomizer, parse_spec

CFG = AquariumConfig(width=300.0, height=260.0, prey_count=8, predator_count=2, max_steps=4)
SPECS = {"prey_max_speed": "2:6", "prey_count": "3,5,8", "predator_reward": "5:20"}


def run(seed: int, steps: int = 13) -> list:
    """Every world's (prey max speed, prey count, predator reward) after construction and each step,
    and the device rows the kernels read at the end."""
    env = BatchedAquarium(CFG, 4, device="cpu", seed=0)
    randomizer = ParamRandomizer(env, SPECS, seed=seed)
    zeros = {"prey": torch.zeros(4, 8, dtype=torch.int32), "predator": torch.zeros(4, 2, dtype=torch.int32)}
    history = []
    for _ in range(steps + 1):
        c = env.config
        history.append((c.prey.max_speed, c.prey_count, c.predator_reward))
        out = env.step(zeros)
        randomizer.update(out.info["episode_ended"])
    rows = env.agent_types.numpy()["max_speed"][:, 1].tolist(), env.world_values.numpy()["prey_count"].tolist()
    return history, rows, env.config


def test_values_drawn_at_every_reset_in_range_and_reproducible():
    history, rows, cfg = run(seed=1)
    # Episodes of 4 steps: the values hold within an episode and change at its end (steps 4, 8, 12).
    speeds = [h[0] for h in history]
    for k in range(1, len(history)):
        changed = speeds[k] != speeds[k - 1]
        assert changed == (k % 4 == 0), k
    for speed, count, reward in history:
        assert all(2.0 <= s <= 6.0 for s in speed) and all(5.0 <= r <= 20.0 for r in reward)
        assert set(count) <= {3, 5, 8}
    assert len({h[0][0] for h in history}) == 4  # four episodes, four draws
    # The kernels read the drawn values.
    assert rows[0] == pytest.approx(list(cfg.prey.max_speed), rel=1e-7) and rows[1] == list(cfg.prey_count)
    assert run(seed=1)[0] == history
    assert run(seed=2)[0] != history


@pytest.mark.parametrize(
    "spec, message",
    [
        ("prey_max_speed=-1:3", "--randomize prey_max_speed: -1.0 is not allowed"),
        ("prey_count=2,9", "--randomize prey_count: 9 is not allowed"),
        ("prey_count=2.5:4", "--randomize prey_count: '2.5' is not an integer"),
        ("prey_speed=1:2", "--randomize prey_speed: unknown field"),
        ("prey_radius=5:x", "--randomize prey_radius: 'x' is not a number"),
        ("prey_count=inf:inf", "--randomize prey_count: 'inf' is not a finite number"),
        ("prey_radius=nan:2", "--randomize prey_radius: 'nan' is not a finite number"),
        ("prey_radius=9:5", "--randomize prey_radius=9:5: needs low <= high"),
        ("prey_radius", "expected FIELD=LOW:HIGH"),
    ],
)
def test_bad_spec_is_one_line_naming_the_field(spec, message):
    env = BatchedAquarium(CFG, 2, device="cpu", seed=0)
    with pytest.raises(ValueError) as error:
        field, _, text = spec.partition("=")
        parse_spec(spec)
        ParamRandomizer(env, {field: text})
    assert message in str(error.value) and "\n" not in str(error.value)


def test_cli_train_randomize(tmp_path, capsys):
    from aquarium_warp.cli import main

    common = [
        "--preset",
        "tiny",
        "--num-worlds",
        "2",
        "--max-steps",
        "10",
        "--num-steps-per-env",
        "8",
        "--log-dir",
        str(tmp_path / "run"),
        "--quiet",
        "--export",
        "none",
        "--iterations",
        "1",
    ]
    assert main(["train", "--randomize", "prey_max_speed=1:0", *common]) == 2
    err = capsys.readouterr().err.strip()
    assert "prey_max_speed" in err and "\n" not in err
    assert main(["train", "--randomize", "prey_max_speed=3:5", "--randomize", "predator_count=1", *common]) == 0
    with open(tmp_path / "run" / "config.json", encoding="utf-8") as f:
        train = json.load(f)["config"]["train"]
    assert train["randomize"] == {"prey_max_speed": "3:5", "predator_count": "1"}
