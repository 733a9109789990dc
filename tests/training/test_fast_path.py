"""`train.fused_mlp` and `train.tf32` resolved (`training/fast_path.py`): "auto" takes the fused MLP, loss and
TF32 products on CUDA where Triton imports and the kernels serve the config, torch's float32 path
everywhere else; config.json records both, and `train` prints the path first. On the CPU the default is
today's torch path, bit for bit."""

from __future__ import annotations

import json
import sys

import pytest
import torch

from aquarium_warp.training import Trainer, fast_path, make_config
from aquarium_warp.training.fast_path import fused_config_problem, resolve_fast_path

# "auto" asked for explicitly (the default since benchmarks/fused_default_followup.md's check), so these
# tests keep meaning what they say if the default changes again.
TINY = {"train": {"num_worlds": 2, "iterations": 1, "quiet": True, "export": [], "fused_mlp": "auto", "tf32": "auto"}}


def config(*changes: dict) -> dict:
    return make_config("tiny", TINY, *changes)


def test_the_default_is_auto_fused_on_cuda_and_torch_float32_on_the_cpu(monkeypatch):
    train = make_config("default")["train"]
    assert train["fused_mlp"] == "auto" and train["tf32"] == "auto"
    monkeypatch.setattr(fast_path, "triton_imports", lambda: True)
    assert (
        resolve_fast_path(make_config("tiny"), "cuda").line() == "path: fused MLP + loss, TF32 (auto: cuda with triton)"
    )
    assert resolve_fast_path(make_config("tiny"), "cpu").line() == "path: torch float32 (auto: cpu)"
    pinned = make_config("tiny", {"train": fast_path.TORCH_FLOAT32})  # one flag away: torch's path on CUDA
    assert resolve_fast_path(pinned, "cuda").line() == "path: torch float32 (train.fused_mlp=false; train.tf32=false)"


def test_auto_on_cuda_with_triton_takes_the_fused_path(monkeypatch):
    monkeypatch.setattr(fast_path, "triton_imports", lambda: True)
    path = resolve_fast_path(config(), "cuda")
    assert (path.fused_mlp, path.tf32, path.reason) == (True, True, "auto: cuda with triton")
    assert path.line() == "path: fused MLP + loss, TF32 (auto: cuda with triton)"
    assert path.record() == {
        "requested": {"fused_mlp": "auto", "tf32": "auto"},
        "fused_mlp": True,
        "tf32": True,
        "reason": "auto: cuda with triton",
    }


def test_auto_on_cuda_without_triton_and_on_the_cpu_takes_torch_float32(monkeypatch):
    monkeypatch.setattr(fast_path, "triton_imports", lambda: False)
    path = resolve_fast_path(config(), "cuda")
    assert (path.fused_mlp, path.tf32) == (False, False)
    assert path.line() == "path: torch float32 (auto: cuda without triton)"
    monkeypatch.setattr(fast_path, "triton_imports", lambda: pytest.fail("the CPU asks nothing of Triton"))
    path = resolve_fast_path(config(), "cpu")
    assert path.line() == "path: torch float32 (auto: cpu)"


def test_triton_imports_says_whether_the_import_succeeds(monkeypatch):
    pytest.importorskip("triton")
    assert fast_path.triton_imports() is True
    monkeypatch.setitem(sys.modules, "triton", None)  # what an absent package raises: ImportError
    assert fast_path.triton_imports() is False


# Configs the fused kernels do not serve, and what the reason names.
UNSERVED = [
    ({"train": {"critic": "team"}}, "critic reads a second observation group"),
    ({"runner": {"algorithm": {"schedule": "adaptive", "desired_kl": 0.01}}}, "adaptive learning-rate schedule"),
    ({"runner": {"actor": {"obs_normalization": True}}}, "prey actor's observation normalisation"),
    ({"runner": {"critic": {"hidden_dims": [48, 48]}}}, r"prey critic's hidden layers [48, 48] must be"),
    ({"runner": {"actor": {"hidden_dims": [64, 32]}}}, r"prey actor's hidden layers [64, 32] must be"),
    ({"runner": {"actor": {"activation": "selu"}}}, "activation 'selu' is not tanh, relu or elu"),
    ({"runner": {"critic": {"class_name": "RNNModel"}}}, "prey critic is 'RNNModel', not rsl-rl's MLPModel"),
    ({"env": {"action_count": 200}}, "layer widths [64, 64, 200] must be in [1, 128]"),
    ({"teams": {"predator": {"critic": "world"}}, "train": {"team": "both"}}, "predator critic reads"),
]


@pytest.mark.parametrize("changes,reason", UNSERVED)
def test_auto_takes_torch_float32_where_the_kernels_do_not_serve(changes, reason, monkeypatch):
    monkeypatch.setattr(fast_path, "triton_imports", lambda: True)
    path = resolve_fast_path(config(changes), "cuda")
    assert (path.fused_mlp, path.tf32) == (False, False)
    assert path.reason.startswith("auto: ") and reason in path.reason
    assert path.describe() == "torch float32"


def test_explicit_settings_are_kept(monkeypatch):
    monkeypatch.setattr(fast_path, "triton_imports", lambda: True)

    def resolved(fused, tf32, device="cuda"):
        path = resolve_fast_path(config({"train": {"fused_mlp": fused, "tf32": tf32}}), device)
        return path.fused_mlp, path.tf32, path.reason

    assert resolved(False, "auto") == (False, False, "train.fused_mlp=false; train.tf32=auto: float32")
    assert resolved("auto", False) == (True, False, "auto: cuda with triton; train.tf32=false")
    assert resolved(True, "auto") == (
        True,
        True,
        "train.fused_mlp=true; train.tf32=auto: TF32 with the fused MLP on cuda",
    )
    assert resolved(True, "auto", "cpu") == (True, False, "train.fused_mlp=true; train.tf32=auto: float32")
    assert resolved(False, True) == (False, True, "train.fused_mlp=false; train.tf32=true")
    # an explicit choice wins over what "auto" would refuse
    changes = {"train": {"fused_mlp": True, "tf32": True, "critic": "team"}}
    assert resolve_fast_path(config(changes), "cuda").describe() == "fused MLP + loss, TF32"
    assert resolve_fast_path(config({"train": {"fused_mlp": False, "tf32": True}}), "cuda").describe() == "torch TF32"


@pytest.mark.parametrize("name", ["fused_mlp", "tf32"])
@pytest.mark.parametrize("value", ["yes", 1, None, "AUTO"])
def test_bad_values_are_refused_in_one_line(name, value):
    with pytest.raises(ValueError, match=rf"^train\.{name}=.* must be true, false or 'auto'") as info:
        config({"train": {name: value}})
    assert "\n" not in str(info.value)


def test_auto_with_another_model_class_is_no_error():
    """`train.fused_mlp=true` refuses models the kernels do not take; "auto" takes torch's path for them."""
    recurrent = {"runner": {"actor": {"class_name": "RNNModel"}, "critic": {"class_name": "RNNModel"}}}
    config(recurrent)
    with pytest.raises(ValueError, match="train.fused_mlp serves rsl-rl's MLPModel"):
        config(recurrent, {"train": {"fused_mlp": True}})


@pytest.mark.parametrize("changes", [{}] + [changes for changes, _ in UNSERVED[:3]])
def test_the_config_check_agrees_with_the_built_learners(changes, one_thread):
    """Where `fused_config_problem` finds nothing, the built learner (fused models, Triton's interpreter on
    the CPU) runs the fused loss and rollout step; where it finds a problem, they do not."""
    from aquarium_warp.training import fused_mlp

    if not fused_mlp.INTERPRETED:
        pytest.skip("Triton's interpreter is off (AQUARIUM_TEST_DEVICE=cuda)")
    cfg = config(changes, {"train": {"fused_mlp": True}})
    trainer = Trainer(cfg)
    alg = trainer.runner.alg
    trainer.close()
    assert (fused_config_problem(cfg) is None) == (alg.fused_loss is not None) == (alg.fused_act is not None)


def test_config_json_and_the_first_printed_line(tmp_path, capsys, one_thread):
    from aquarium_warp.cli import main

    run = tmp_path / "run"
    assert main(["train", "--preset", "tiny", "--num-worlds", "2", "--iterations", "1", "--export", "none",
                 "--quiet", "--device", "cpu", "--log-dir", str(run), "--set", "train.fused_mlp=auto",
                 "--set", "train.tf32=auto"]) == 0  # fmt: skip
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "aquarium-warp train: path: torch float32 (auto: cpu)"
    record = json.loads((run / "config.json").read_text())
    assert record["config"]["train"]["fused_mlp"] == record["config"]["train"]["tf32"] == "auto"
    assert record["path"] == {
        "requested": {"fused_mlp": "auto", "tf32": "auto"},
        "fused_mlp": False,
        "tf32": False,
        "reason": "auto: cpu",
    }
    assert "fused_loss" not in record  # torch's path: no fused learner to report on


@pytest.mark.parametrize("value,parsed", [("auto", "auto"), ("true", True), ("false", False)])
def test_cli_set_takes_auto_true_and_false(value, parsed):
    from aquarium_warp.cli import build_parser
    from aquarium_warp.training.cli import train_config

    args = build_parser().parse_args(["train", "--set", f"train.fused_mlp={value}", "--set", f"train.tf32={value}"])
    train = train_config(args)["train"]
    assert train["fused_mlp"] == train["tf32"] == parsed


def test_cli_refuses_a_bad_value_in_one_line(tmp_path, capsys):
    from aquarium_warp.cli import main

    assert main(["train", "--preset", "tiny", "--set", "train.tf32=maybe", "--log-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err
        == "aquarium-warp train: train.tf32='maybe' must be true, false or 'auto' (the fused path on CUDA with Triton)"
    )


def test_auto_on_the_cpu_is_torch_float32_bit_for_bit(one_thread):
    """ "auto" and explicit `fused_mlp=false, tf32=false` train the same parameters on the CPU."""

    def parameters(*changes):
        trainer = Trainer(config(*changes))
        trainer.train(1)
        state = {k: v.clone() for k, v in trainer.runner.alg.actor.state_dict().items()}
        trainer.close()
        return state

    auto = parameters()
    explicit = parameters({"train": {"fused_mlp": False, "tf32": False}})
    assert auto.keys() == explicit.keys() and all(torch.equal(auto[k], explicit[k]) for k in auto)


def test_fused_true_without_triton_is_refused_in_one_line(monkeypatch):
    """`train.fused_mlp=true` where Triton does not import: a one-line error naming the setting and the
    extra, not an import traceback when the models are built; "auto" and false need no Triton."""
    monkeypatch.setattr(fast_path, "triton_imports", lambda: False)
    with pytest.raises(ValueError, match=r"^train\.fused_mlp=true needs Triton") as info:
        config({"train": {"fused_mlp": True}})
    assert "\n" not in str(info.value) and ".[fused]" in str(info.value)
    config({"train": {"fused_mlp": False}})
    config()  # "auto"
