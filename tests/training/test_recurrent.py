"""Recurrent (rsl-rl `RNNModel`) policies end to end on the CPU: bit-exact resume with the actor's and
critic's hidden states in the checkpoint, export (TorchScript, ONNX) with per-row hidden states kept by
`load_policy`, evaluation, and the refusal of Individual Learning with recurrent models."""

from __future__ import annotations

import json
import os

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")

import torch

from aquarium_warp.training.config import make_config
from aquarium_warp.training.export import load_policy
from aquarium_warp.training.trainer import Trainer


def rnn_config(rnn_type="lstm", **train):
    model = {"class_name": "RNNModel", "rnn_type": rnn_type, "rnn_hidden_dim": 8, "hidden_dims": [16]}
    return make_config(
        "tiny",
        {
            "train": {"num_worlds": 4, "iterations": 4, "quiet": True, "export": [], **train},
            "env": {"max_steps": 30},
            "runner": {"num_steps_per_env": 10, "save_interval": 2, "actor": dict(model), "critic": dict(model)},
        },
    )


def _hidden(model):
    h = model.get_hidden_state()
    return h if isinstance(h, tuple) else (h,)


@pytest.mark.parametrize("rnn_type", ["lstm", "gru"])
@pytest.mark.slow
def test_recurrent_resume_is_bit_exact(tmp_path, one_thread, rnn_type):
    config = rnn_config(rnn_type)
    full = Trainer(config, str(tmp_path / "full"))
    full.train()
    part = Trainer(config, str(tmp_path / "part"))
    part.train(2)
    saved = torch.load(tmp_path / "part" / "model_1.pt", weights_only=False)["infos"]["aquarium"]["hidden_states"]
    for name in ("actor", "critic"):  # the checkpoint holds the live hidden state after iteration 1
        live = _hidden(getattr(part.runner.alg, name))
        stored = saved[name] if isinstance(saved[name], tuple) else (saved[name],)
        assert len(live) == len(stored) == (2 if rnn_type == "lstm" else 1)
        assert all(torch.equal(a, b) and a.abs().sum() > 0 for a, b in zip(live, stored))
    resumed = Trainer.resume(str(tmp_path / "part"))
    assert resumed.iteration == 2
    resumed.train()
    for model in ("actor", "critic"):
        a, b = getattr(full.runner.alg, model), getattr(resumed.runner.alg, model)
        sa, sb = a.state_dict(), b.state_dict()
        assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa), model
        ha, hb = _hidden(a), _hidden(b)
        assert all(torch.equal(x, y) for x, y in zip(ha, hb)), f"{model} hidden state differs after resume"
    ta, tb = full.env.state_dict()["tensors"], resumed.env.state_dict()["tensors"]
    assert all(torch.equal(ta[n], tb[n]) for n in ta)
    # Without the hidden states in the checkpoint the resumed run would differ (the test can fail).
    ckpt = torch.load(tmp_path / "part" / "model_1.pt", weights_only=False)
    del ckpt["infos"]["aquarium"]["hidden_states"]
    torch.save(ckpt, tmp_path / "no_hidden.pt")
    other = Trainer.resume(str(tmp_path / "no_hidden.pt"), log_dir=str(tmp_path / "other"))
    other.train()
    sa, so = full.runner.alg.actor.state_dict(), other.runner.alg.actor.state_dict()
    assert not all(torch.equal(sa[k], so[k]) for k in sa)


def test_individual_learning_with_recurrent_model_is_refused():
    with pytest.raises(ValueError, match=r"train.sharing='individual'.*runner.actor.class_name='RNNModel'"):
        rnn_config(sharing="individual")


@pytest.mark.parametrize("rnn_type", ["lstm", "gru"])
@pytest.mark.slow
def test_recurrent_export_reload_and_evaluate(tmp_path, one_thread, rnn_type):
    """TorchScript, ONNX and the checkpoint of a GRU or LSTM policy act like rsl-rl's own `RNNModel` over a
    rollout, hidden state per row and reset where rows are done; `RecurrentOpponent` finds the same
    dones as the training adapter; the evaluation protocol runs it."""
    trainer = Trainer(rnn_config(rnn_type, iterations=1, export=["jit", "onnx"]), str(tmp_path / "run"))
    trainer.train()
    paths = trainer.export()
    kinds = {"jit": paths["jit"], "checkpoint": str(tmp_path / "run" / "model_0.pt")}
    try:
        import onnxruntime  # noqa: F401

        kinds["onnx"] = paths["onnx"]
    except ImportError:
        pass
    policies = {kind: load_policy(path) for kind, path in kinds.items()}
    assert all(p.recurrent == {"rnn_type": rnn_type, "num_layers": 1, "hidden_size": 8} for p in policies.values())
    driven = load_policy(paths["jit"])  # inside RecurrentOpponent, which finds the dones itself
    from aquarium_warp.training.drivers import RecurrentOpponent

    vec, actor = trainer.vec_env, trainer.actor
    opponent = RecurrentOpponent(driven, vec.env, "prey")
    actor.eval()
    actor.reset()
    done_steps = 0
    for _ in range(45):  # max_steps 30: every row's episode ends at least once
        obs = vec.get_observations()
        with torch.no_grad():  # not inference_mode: rsl-rl resets its hidden state in place
            expected = actor(obs).squeeze(-1).long()  # rsl-rl's deterministic output, its own RNN state
        for kind, policy in policies.items():
            assert torch.equal(policy(obs["policy"]), expected), kind
            reference = actor.get_hidden_state()
            for mine, ref in zip(policy.hidden_state, reference if rnn_type == "lstm" else (reference,)):
                if kind == "onnx":  # ONNX Runtime's own kernels round differently
                    torch.testing.assert_close(mine, ref, rtol=1e-5, atol=1e-6)
                else:  # the same torch operations as rsl-rl's
                    assert torch.equal(mine, ref), kind
        acted = opponent()
        assert torch.equal(acted.reshape(-1).long(), expected)
        reference = actor.get_hidden_state()
        assert torch.equal(driven.hidden_state[0], reference[0] if rnn_type == "lstm" else reference)
        _, _, dones, _ = vec.step(expected.unsqueeze(-1).float())
        done_steps += int(dones.any())
        actor.reset(dones)
        for policy in policies.values():
            policy.reset(dones)
    assert done_steps >= 2  # captures and the world's end reset rows
    # A RecurrentOpponent restored from another's state_dict continues exactly like it.
    restored = RecurrentOpponent(load_policy(paths["jit"]), vec.env, "prey")
    restored.load_state_dict(opponent.state_dict())
    assert torch.equal(restored(), opponent()) and torch.equal(restored.policy.hidden_state[0], driven.hidden_state[0])
    with pytest.raises(ValueError, match="call reset"):
        policies["jit"](obs["policy"][:3])
    policies["jit"].reset()
    assert policies["jit"](obs["policy"][:3]).shape == (3,)

    if rnn_type == "gru":
        return  # the evaluation below does not depend on the RNN type
    from aquarium_warp.drivers import common_world
    from aquarium_warp.training.evaluate import evaluate_policies

    env = common_world([paths["jit"]], None)
    runs = {
        kind: evaluate_policies(
            prey=[f"{kind}={path}"], predator=["naivchase"], env=env, episodes=2, seeds=[0], device="cpu"
        )["episodes"]
        for kind, path in kinds.items()
    }
    assert len(runs["jit"]) == 2 and all(r["length"] == 30 for r in runs["jit"])
    strip = [{k: v for k, v in r.items() if k not in ("prey_policy", "prey_spec")} for r in runs["jit"]]
    for kind, records in runs.items():  # the same actions in every format: the same episodes
        same = [{k: v for k, v in r.items() if k not in ("prey_policy", "prey_spec")} for r in records]
        # as JSON text, so that an undefined measure (NaN, e.g. group order without a measured group) matches
        assert json.dumps(same, sort_keys=True) == json.dumps(strip, sort_keys=True), kind
    # ... and `aquarium-warp video` films it (past the episode's end at step 30), rows reset by
    # RecurrentOpponent.
    from aquarium_warp.cli import main
    from aquarium_warp.drivers import make_driver

    assert isinstance(make_driver(paths["jit"], vec.env, "prey", seed=0), RecurrentOpponent)
    out = str(tmp_path / "recurrent.mp4")
    assert (
        main(
            [
                "video",
                "--prey-policy",
                paths["onnx" if "onnx" in kinds else "jit"],
                "--steps",
                "35",
                "--out",
                out,
                "--no-progress",
            ]
        )
        == 0
    )
    assert os.path.getsize(out) > 0
