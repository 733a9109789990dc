"""The fused Warp MLP (`training/fused_mlp.py`) against torch's, on the CPU (the same kernels run on CUDA).

Errors are relative to the largest magnitude of the float64 reference (torch's MLP in float64).
Measured on the CPU over SHAPES (warp 1.19): forward <= 4.7e-7 (torch's float32: 3.8e-7), parameter
and input gradients <= 4.8e-7 (torch's: 6.7e-7); after one full PPO update from the same state,
every parameter within 5.7e-6 of the torch update's (Adam divides each gradient by its running RMS,
so a rounding difference in a tiny gradient becomes a difference in a step).
"""

import copy
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest
import torch
from rsl_rl.models import MLPModel
from rsl_rl.modules import MLP
from tensordict import TensorDict

from aquarium_warp.training import make_config
from aquarium_warp.training.config import FUSED_MODEL, runner_config
from aquarium_warp.training.fused_mlp import FusedMLP, FusedMLPModel, MLPSpec

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"

FORWARD_TOLERANCE = 2e-6  # relative to the reference's largest magnitude; measured <= 4.7e-7
GRADIENT_TOLERANCE = 2e-6  # measured <= 4.8e-7
UPDATE_TOLERANCE = 5e-5  # one PPO update, per parameter tensor; measured <= 5.7e-6

ROWS = 64  # rows per tile of the nets below but the last (MLPSpec.rows), which takes 16

# (input, hidden, output, activation, rows): the default actor; a two-chunk input (100 > 64 columns,
# the second chunk zero-padded) with elu; one relu layer; 128 wide, in whole tiles; two layers of
# 128 (tiles of 16 rows), with a tail.
SHAPES = [
    (29, [64, 64], 9, "tanh", 3 * ROWS + 8),
    (100, [32, 48], 3, "elu", 2 * ROWS + 2),
    (7, [16], 1, "relu", ROWS + 1),
    (29, [128], 5, "tanh", 2 * ROWS),
    (29, [128, 128], 5, "tanh", 3 * 16 + 5),
]


def relative_error(value: torch.Tensor, reference: torch.Tensor) -> float:
    return float((value.detach().double() - reference).abs().max() / reference.abs().max())


def _mlps(n_in, hidden, n_out, activation, seed=0):
    torch.manual_seed(seed)
    mlp = MLP(n_in, n_out, hidden, activation)
    return mlp, FusedMLP(copy.deepcopy(mlp))


@pytest.mark.parametrize("n_in,hidden,n_out,activation,rows", SHAPES)
def test_forward_and_gradients_match_torch_within_float32_rounding(n_in, hidden, n_out, activation, rows):
    mlp, fused = _mlps(n_in, hidden, n_out, activation)
    reference = copy.deepcopy(mlp).double()
    gen = torch.Generator().manual_seed(1)
    x = torch.randn(rows, n_in, generator=gen)
    grad = torch.randn(rows, n_out, generator=gen)
    x_fused, x_torch, x_ref = x.clone().requires_grad_(), x.clone().requires_grad_(), x.double().requires_grad_()

    y_ref = reference(x_ref)
    y_ref.backward(grad.double())
    y_torch = mlp(x_torch)
    y_torch.backward(grad)
    y = fused(x_fused)
    y.backward(grad)

    assert y.shape == (rows, n_out) and y.dtype == torch.float32
    torch_error = relative_error(y_torch, y_ref.detach())
    assert relative_error(y.detach(), y_ref.detach()) <= max(FORWARD_TOLERANCE, 4 * torch_error)
    for (name, p), p_torch, p_ref in zip(fused.named_parameters(), mlp.parameters(), reference.parameters()):
        assert relative_error(p.grad, p_ref.grad) <= max(
            GRADIENT_TOLERANCE, 4 * relative_error(p_torch.grad, p_ref.grad)
        ), name
    assert relative_error(x_fused.grad, x_ref.grad) <= GRADIENT_TOLERANCE


def test_parameter_gradients_without_input_gradient_and_the_tail_rows_add_nothing():
    mlp, fused = _mlps(29, [64, 64], 9, "tanh")
    x = torch.randn(ROWS + 5, 29)
    fused(x).square().sum().backward()  # x needs no gradient: the kernel without the input gradient
    mlp(x).square().sum().backward()
    for p, p_torch in zip(fused.parameters(), mlp.parameters()):
        assert relative_error(p.grad, p_torch.grad.double()) <= GRADIENT_TOLERANCE
    fused.zero_grad()
    head = x[:ROWS]
    fused(head).square().sum().backward()  # whole tiles only: the tail's rows are what differs
    head_grad = [p.grad.clone() for p in fused.parameters()]
    mlp.zero_grad()
    mlp(head).square().sum().backward()
    for g, p_torch in zip(head_grad, mlp.parameters()):
        assert relative_error(g, p_torch.grad.double()) <= GRADIENT_TOLERANCE


def test_bit_exact_on_the_cpu():
    """Same inputs twice -> identical outputs and gradients. On the CPU blocks run one after another;
    on a GPU each block adds into its own row of partial gradients in a fixed order, so this holds
    there by construction too (not tested here)."""
    _, fused = _mlps(100, [32, 48], 3, "elu")
    x = torch.randn(3 * ROWS + 7, 100)
    runs = []
    for _ in range(2):
        fused.zero_grad()
        xr = x.clone().requires_grad_()
        y = fused(xr)
        y.sin().sum().backward()
        runs.append([y.detach(), xr.grad, *(p.grad.clone() for p in fused.parameters())])
    for a, b in zip(*runs):
        assert torch.equal(a, b)


def test_empty_batch_and_leading_dimensions():
    mlp, fused = _mlps(7, [16], 2, "relu")
    assert fused(torch.zeros(0, 7)).shape == (0, 2)
    x = torch.randn(3, 5, 7)
    assert relative_error(fused(x).detach(), mlp(x).detach().double()) <= FORWARD_TOLERANCE


@pytest.mark.parametrize("features", [6, 8])
def test_input_of_the_wrong_width_is_refused_as_by_torch(features):
    mlp, fused = _mlps(7, [16], 2, "tanh")
    x = torch.randn(4, features)
    with pytest.raises(RuntimeError):  # torch's Linear
        mlp(x)
    with pytest.raises(ValueError, match=f"input of {features} features, the first layer takes 7") as info:
        fused(x)
    assert "\n" not in str(info.value)


def test_torch_path_where_the_kernels_do_not_serve():
    mlp, fused = _mlps(7, [16], 2, "tanh")
    x = torch.randn(10, 7, dtype=torch.float64)
    assert torch.equal(copy.deepcopy(fused).double()(x), copy.deepcopy(mlp).double()(x))  # float64: torch's
    scripted = torch.jit.script(copy.deepcopy(fused))  # TorchScript (policy export): torch's modules
    assert torch.equal(scripted(x.float()), mlp(x.float()))


@pytest.mark.parametrize(
    "hidden,activation,message",
    [
        ([64], "selu", "activation"),
        ([256], "tanh", "widths"),
        ([64], "lrelu", "activation"),
        ([128, 128, 128], "tanh", "shared memory"),
    ],
)
def test_unsupported_mlp_is_one_line_error(hidden, activation, message):
    with pytest.raises(ValueError, match=message) as info:
        FusedMLP(MLP(8, 4, hidden, activation))
    assert "\n" not in str(info.value)


def test_spec_flat_layout_round_trip():
    spec = MLPSpec((100, 32, 48, 3), "elu")
    assert MLPSpec((29, 64, 64, 9), "tanh").rows == ROWS
    params = [torch.randn(32, 100), torch.randn(32), torch.randn(48, 32), torch.randn(48), torch.randn(3, 48)]
    params.append(torch.randn(3))
    flat = spec.flat(tuple(params))
    assert flat.numel() == spec.size == 2 * 32 * 64 + 32 + 48 * 32 + 48 + 3 * 48 + 3
    for a, b in zip(spec.unflat(flat), params):
        assert torch.equal(a, b)


def _models(obs_dim=29, actions=9, fused=True, seed=0):
    obs = TensorDict({"policy": torch.zeros(4, obs_dim)}, batch_size=[4])
    groups = {"actor": ["policy"], "critic": ["policy"]}
    torch.manual_seed(seed)
    model_class = FusedMLPModel if fused else MLPModel
    return model_class(obs, groups, "actor", actions, hidden_dims=[64, 64], activation="tanh"), obs


def test_checkpoints_interchangeable_and_same_initial_parameters():
    fused, obs = _models(fused=True)
    plain, _ = _models(fused=False)
    assert isinstance(fused.mlp, FusedMLP) and type(plain.mlp) is MLP
    fused_state, plain_state = fused.state_dict(), plain.state_dict()
    assert list(fused_state) == list(plain_state)
    for key in plain_state:  # the same seed gives the same parameters: FusedMLP draws nothing
        assert torch.equal(fused_state[key], plain_state[key]), key
    other_fused, _ = _models(fused=True, seed=5)
    other_plain, _ = _models(fused=False, seed=6)
    other_fused.load_state_dict(plain_state)  # torch checkpoint -> fused model
    other_plain.load_state_dict(fused_state)  # fused checkpoint -> torch model
    obs["policy"] = torch.randn(4, 29)
    reference = plain(obs).detach().double()
    assert relative_error(other_fused(obs).detach(), reference) <= FORWARD_TOLERANCE
    assert torch.equal(other_plain(obs), plain(obs))


def test_config_switch_and_its_errors():
    config = make_config("tiny", {"train": {"fused_mlp": True}})
    runner = runner_config(config, slots=4, action_count=9)
    assert runner["actor"]["class_name"] == runner["critic"]["class_name"] == FUSED_MODEL
    assert runner_config(make_config("tiny"), slots=4, action_count=9)["actor"]["class_name"] == "MLPModel"
    for changes, message in (
        ({"train": {"fused_mlp": "yes"}}, "train.fused_mlp='yes' must be true or false"),
        ({"train": {"fused_mlp": True, "sharing": "individual"}}, "train.fused_mlp=true serves parameter sharing"),
        (
            {"train": {"fused_mlp": True}, "runner": {"critic": {"class_name": "RNNModel"}}},
            "train.fused_mlp=true serves parameter sharing",
        ),
    ):
        with pytest.raises(ValueError, match=message) as info:
            make_config("tiny", changes)
        assert "\n" not in str(info.value)


def _bench():
    sys.path.insert(0, str(BENCHMARKS))
    import bench_fused_update

    return bench_fused_update


@pytest.mark.slow
def test_ppo_update_on_device_fused_equals_torch_within_tolerance():
    """A full `AquariumPPO.update_on_device` (tiny preset: 4 epochs x 4 mini-batches) from the same
    state and samples, with torch's MLPs and with the fused ones."""
    bench = _bench()
    alg = bench.build("tiny", 4, "cpu")
    bench.fill_storage(alg)
    differences = bench.update_difference(bench.MLPSwitch(alg))
    assert len(differences) == 12  # 3 weights and 3 biases per network
    assert max(differences.values()) <= UPDATE_TOLERANCE, differences


@pytest.mark.slow
def test_bench_fused_update_runs_on_the_cpu(tmp_path):
    bench = _bench()
    out = tmp_path / "fused.json"
    assert (
        bench.main(
            ["--device", "cpu", "--worlds", "2", "--preset", "tiny", "--repeats", "1"]
            + ["--out", str(out), "--commit", "abc123"]
        )
        == 0
    )
    data = json.loads(out.read_text())
    assert data["git"] == {"commit": "abc123", "dirty": None, "source": "given"}
    point = data["points"][0]
    assert set(point["seconds"]) == {"torch eager", "fused eager"}
    assert point["floor"]["update_flops"] > 0 and point["floor"]["seconds"] is None  # no peak rates for a CPU
    assert max(point["max_relative_difference"].values()) <= UPDATE_TOLERANCE


@pytest.mark.slow
def test_fused_actor_exports_to_torchscript_and_onnx(tmp_path):
    """Exports take torch's path through the same modules: the policies' logits equal the actor's."""
    from aquarium_warp.training.export import export_policy, load_policy, policy_meta

    actor, obs = _models(fused=True)
    meta = policy_meta(make_config("tiny"), 4, 29, 9)
    paths = export_policy(actor, meta, str(tmp_path))
    x = torch.randn(8, 29)
    obs = TensorDict({"policy": x}, batch_size=[8])
    logits = actor.mlp(actor.get_latent(obs)).detach().double()
    for path in paths.values():
        assert relative_error(load_policy(path).logits(x), logits) <= FORWARD_TOLERANCE
