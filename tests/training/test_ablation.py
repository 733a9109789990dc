"""The neighbour-ablation control: a trained policy acting with the slots of one type empty. The
columns come from the layout (hand-counted here for each frame), the env's own observations stay as
they are, heuristics are refused (they read the state), and `eval --blind` parses strictly."""

from __future__ import annotations

import json
import os

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")

import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.cli import main
from aquarium_warp.drivers import make_driver
from aquarium_warp.training.drivers import TrainedOpponent


@pytest.mark.parametrize(
    "kw, own",
    [
        ({}, 5),  # type, x, y, heading, speed
        ({"observation_frame": "ego", "action_frame": "ego"}, 2),  # type, speed
        ({"observation_frame": "ego"}, 4),  # type, speed, heading x, y
        ({"observation_frame": "ego", "observe_flow": True}, 6),  # ... and the current's two values
    ],
)
def test_neighbour_columns_follow_the_layout(kw, own):
    cfg = AquariumConfig(**kw)
    assert cfg.neighbour_columns("prey", "predator") == slice(own, own + 6)  # one predator slot
    assert cfg.neighbour_columns("prey", "prey") == slice(own + 6, own + 24)  # three prey slots
    assert cfg.neighbour_columns("prey", "prey").stop == cfg.observation_size("prey")


class Recorder:
    """A policy that records what it was shown and always answers action 3."""

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        self.seen = obs.clone()
        return torch.full((obs.shape[0],), 3, dtype=torch.int64)


@pytest.mark.parametrize("kw", [{}, {"observation_frame": "ego"}])
def test_a_blind_policy_sees_empty_slots_of_the_type_only(kw):
    env = BatchedAquarium(
        AquariumConfig(prey_count=12, width=300.0, height=300.0, **kw), num_worlds=4, device="cpu", seed=1
    )
    env.reset()
    for _ in range(20):  # prey in each other's view
        env.step({"prey": torch.zeros(4, 12, dtype=torch.int32), "predator": torch.zeros(4, 1, dtype=torch.int32)})
    before = env.observations["prey"].clone()
    cols = env.config.neighbour_columns("prey", "prey")
    assert before[..., cols].abs().sum() > 0  # there is something to hide
    policy = Recorder()
    actions = TrainedOpponent(policy, env, "prey", blind_to="prey")()
    seen = policy.seen.reshape(before.shape)
    assert (actions == 3).all() and torch.equal(env.observations["prey"], before)  # the env is untouched
    assert (seen[..., cols] == 0).all()
    keep = torch.ones(before.shape[-1], dtype=torch.bool)
    keep[cols] = False
    assert torch.equal(seen[..., keep], before[..., keep])
    TrainedOpponent(policy, env, "prey")()
    assert torch.equal(policy.seen.reshape(before.shape), before)  # not blind: everything


def test_blindness_is_for_trained_policies_and_checked():
    env = BatchedAquarium(AquariumConfig(prey_count=2), num_worlds=1, device="cpu")
    with pytest.raises(ValueError, match="applies to trained policies, not to the heuristic 'turnaway'"):
        make_driver("turnaway", env, "prey", blind_to="prey")
    with pytest.raises(ValueError, match="blind_to='fish' must be None or one of"):
        make_driver("turnaway", env, "prey", blind_to="fish")


@pytest.mark.parametrize("value, message", [("prey", "expected TEAM=TYPE"), ("prey=shark", "expected TEAM=TYPE")])
def test_eval_blind_option_is_parsed_strictly(tmp_path, capsys, value, message):
    assert (
        main(
            [
                "eval",
                "--prey",
                "turnaway",
                "--predator",
                "naivchase",
                "--episodes",
                "1",
                "--seeds",
                "0",
                "--max-steps",
                "5",
                "--no-figures",
                "--out",
                str(tmp_path),
                "--blind",
                value,
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_cross_play_applies_blind(tmp_path):
    """Issue 49: `eval --cross-play --blind` ablates the trained policies as `eval --blind` does (it was
    ignored in silence)."""

    def cross_play(*blind: str):
        out = tmp_path / ("blind" if blind else "seeing")
        argv = ["eval", "--cross-play", "--prey", "prey-a", "--predator", "naivchase", "--episodes", "2"]
        argv += ["--seeds", "0", "--max-steps", "300", "--device", "cpu", "--no-figures", "--out", str(out)]
        assert main([*argv, *blind]) == 0
        saved = json.loads((out / "cross_play.json").read_text())
        return saved["protocol"]["blind_to"], saved["matrices"]["captures_per_prey"]["mean"]

    seeing, blind = cross_play(), cross_play("--blind", "prey=prey")
    assert seeing[0] == {} and blind[0] == {"prey": "prey"}
    assert blind[1] != seeing[1]  # prey-a that see no other prey are caught at another rate
