"""Recurrent (rsl-rl `RNNModel`) policies end to end on the CPU: bit-exact resume with the actor's and
critic's hidden states in the checkpoint, export (TorchScript, ONNX) with per-row hidden states kept by
`load_policy`, evaluation, and the refusal of Individual Learning with recurrent models."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")

import torch  # noqa: E402

from aquarium_warp.training.config import make_config  # noqa: E402
from aquarium_warp.training.export import load_policy  # noqa: E402
from aquarium_warp.training.trainer import Trainer  # noqa: E402


@pytest.fixture
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def rnn_config(rnn_type="lstm", **train):
    model = {"class_name": "RNNModel", "rnn_type": rnn_type, "rnn_hidden_dim": 8, "hidden_dims": [16]}
    return make_config("tiny", {"train": {"num_worlds": 4, "iterations": 4, "quiet": True, "export": [], **train},
                                "env": {"max_steps": 30},
                                "runner": {"num_steps_per_env": 10, "save_interval": 2,
                                           "actor": dict(model), "critic": dict(model)}})


def _hidden(model):
    h = model.get_hidden_state()
    return h if isinstance(h, tuple) else (h,)


@pytest.mark.parametrize("rnn_type", ["lstm", "gru"])
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
