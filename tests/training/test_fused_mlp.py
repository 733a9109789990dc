"""The fused MLP (`training/fused_mlp.py`) against torch's, on the CPU through Triton's interpreter, which
runs its kernels on CPU tensors (`TRITON_INTERPRET=1`, which tests/conftest.py sets before triton is
imported; with AQUARIUM_TEST_DEVICE=cuda:N the interpreter stays off and the tests that need the kernels
on the CPU skip, the CUDA one runs).

Errors are relative to the largest magnitude of the float64 reference (torch's MLP in float64).
Measured on the CPU over SHAPES (Triton 3.9.0's interpreter, whose products are numpy's): forward
<= 4.5e-7 (torch's float32: 4.5e-7), gradients <= 4.1e-7 (torch's: 7.4e-7); its tanh alone within
8.6e-7 relative (9.3e-8 absolute) of float64's. A whole PPO update with the fused MLPs:
tests/training/test_fused_ppo.py.
"""

import copy
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest

pytest.importorskip("triton")  # the fused MLP's kernels (the `fused` extra)

import torch
import torch.nn as nn
from rsl_rl.models import MLPModel
from rsl_rl.modules import MLP
from tensordict import TensorDict

from aquarium_warp.training import fused_mlp, make_config
from aquarium_warp.training.config import FUSED_IL_MODEL, FUSED_MODEL, runner_config
from aquarium_warp.training.fused_mlp import FusedMLP, FusedMLPModel

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"

FORWARD_TOLERANCE = 2e-6  # relative to the reference's largest magnitude; measured <= 4.5e-7
GRADIENT_TOLERANCE = 2e-6  # measured <= 4.1e-7
TF32_TOLERANCE = 1e-2  # TF32 products on CUDA (10-bit mantissas): about 1e-3

ROWS = 64  # forward rows per tile of the nets below up to width 64 (fused_mlp.block_rows; backward: 32):
# the counts below leave a partial last tile for both

# (input, hidden, output, activation, rows): the default actor with a tail; an input of 100 columns
# (padded to 128) with elu; one relu layer of 16 with an output of 1 (padded to 16); 128 wide in whole
# tiles; three elu layers of 128 with an output of 128 and a tail.
SHAPES = [
    (29, [64, 64], 9, "tanh", 3 * ROWS + 8),
    (100, [32, 32], 3, "elu", 2 * ROWS + 2),
    (7, [16], 1, "relu", ROWS + 1),
    (29, [128], 5, "tanh", 2 * 32),
    (13, [128, 128, 128], 128, "elu", 3 * 32 + 5),
]


@pytest.fixture
def interpreter() -> None:
    """Skips unless the kernels take CPU tensors (Triton's interpreter)."""
    if not fused_mlp.INTERPRETED:
        pytest.skip("Triton's interpreter is off (AQUARIUM_TEST_DEVICE=cuda): see test_triton_on_cuda_*")


def relative_error(value: torch.Tensor, reference: torch.Tensor) -> float:
    return float((value.detach().double() - reference).abs().max() / reference.abs().max())


def _mlps(n_in, hidden, n_out, activation, seed=0):
    torch.manual_seed(seed)
    mlp = MLP(n_in, n_out, hidden, activation)
    return mlp, FusedMLP(copy.deepcopy(mlp))


def _ran_fused(y: torch.Tensor) -> bool:
    """Whether `y` came out of the kernels' autograd function (behind FusedMLP's reshape), not torch's modules."""
    return type(y.grad_fn.next_functions[0][0]).__name__ == "TritonMLPFunctionBackward"


def _compare_to_torch(mlp, fused, x, grad):
    """The fused MLP's output and gradients (x's included) against torch's float32 and float64 MLPs."""
    reference = copy.deepcopy(mlp).double()
    x_fused, x_torch, x_ref = x.clone().requires_grad_(), x.clone().requires_grad_(), x.double().requires_grad_()

    y_ref = reference(x_ref)
    y_ref.backward(grad.double())
    y_torch = mlp(x_torch)
    y_torch.backward(grad)
    y = fused(x_fused)
    y.backward(grad)

    assert _ran_fused(y)
    assert y.shape == (x.shape[0], grad.shape[1]) and y.dtype == torch.float32
    torch_error = relative_error(y_torch, y_ref.detach())
    assert relative_error(y.detach(), y_ref.detach()) <= max(FORWARD_TOLERANCE, 4 * torch_error)
    for (name, p), p_torch, p_ref in zip(fused.named_parameters(), mlp.parameters(), reference.parameters()):
        assert relative_error(p.grad, p_ref.grad) <= max(
            GRADIENT_TOLERANCE, 4 * relative_error(p_torch.grad, p_ref.grad)
        ), name
    assert relative_error(x_fused.grad, x_ref.grad) <= GRADIENT_TOLERANCE


@pytest.mark.parametrize("n_in,hidden,n_out,activation,rows", SHAPES)
def test_forward_and_gradients_match_torch_within_float32_rounding(n_in, hidden, n_out, activation, rows, interpreter):
    mlp, fused = _mlps(n_in, hidden, n_out, activation)
    gen = torch.Generator().manual_seed(1)
    x = 2 * torch.randn(rows, n_in, generator=gen)  # (tanh's range: its series below 1/16 and exp above)
    _compare_to_torch(mlp, fused, x, torch.randn(rows, n_out, generator=gen))


def test_triton_kernels_really_run_under_the_interpreter(interpreter):
    """A weight changed in the call alone (not in the module) changes the output as torch's MLP
    with that weight does: the kernels compute it, not torch's modules."""
    mlp, fused = _mlps(29, [64, 64], 9, "tanh")
    x = torch.randn(70, 29)
    params = [p.detach().clone() for layer in list(mlp)[0::2] for p in (layer.weight, layer.bias)]
    params[2][3, 5] += 1.0  # the second layer's weight
    with torch.no_grad():
        out = fused_mlp.TritonMLPFunction.apply(fused.spec, x, *params)
        mlp[2].weight[3, 5] += 1.0
        expected = mlp(x)
        assert relative_error(out, expected.double()) <= FORWARD_TOLERANCE
        assert relative_error(fused(x), expected.double()) > 1e-3  # the module's weight is unchanged


def test_parameter_gradients_without_input_gradient_and_the_tail_rows_add_nothing(interpreter):
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


def test_bit_exact_on_the_cpu(interpreter):
    """Same inputs twice -> identical outputs and gradients. On the CPU programs run one after another;
    on a GPU each program adds into its own row of partial gradients in a fixed order, so this holds
    there by construction too (test_triton_on_cuda_* replays a graph against an eager call)."""
    _, fused = _mlps(100, [32, 32], 3, "elu")
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


def test_empty_batch_and_leading_dimensions(interpreter):
    mlp, fused = _mlps(7, [16], 2, "relu")
    assert fused(torch.zeros(0, 7)).shape == (0, 2)
    x = torch.randn(3, 5, 7)
    assert relative_error(fused(x).detach(), mlp(x).detach().double()) <= FORWARD_TOLERANCE


@pytest.mark.parametrize("features", [6, 8])
def test_input_of_the_wrong_width_is_refused_as_by_torch(features, interpreter):
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
        ([32, 64], "tanh", r"hidden layers \[32, 64\] must be 1 to 3 layers of one width"),
        ([48], "tanh", r"hidden layers \[48\] must be 1 to 3 layers of one width in \[16, 32, 64, 128\]"),
        ([16] * 4, "tanh", "must be 1 to 3 layers"),
    ],
)
def test_unsupported_mlp_is_one_line_error(hidden, activation, message):
    with pytest.raises(ValueError, match=message) as info:
        FusedMLP(MLP(8, 4, hidden, activation))
    assert "\n" not in str(info.value)


def _models(obs_dim=29, actions=9, fused=False, seed=0):
    """rsl-rl's actor model, with the fused MLP (`fused`) or torch's `MLPModel`."""
    obs = TensorDict({"policy": torch.zeros(4, obs_dim)}, batch_size=[4])
    groups = {"actor": ["policy"], "critic": ["policy"]}
    torch.manual_seed(seed)
    kwargs = {"hidden_dims": [64, 64], "activation": "tanh"}
    if not fused:
        return MLPModel(obs, groups, "actor", actions, **kwargs), obs
    return FusedMLPModel(obs, groups, "actor", actions, **kwargs), obs


def test_checkpoints_interchangeable_and_same_initial_parameters():
    fused, obs = _models(fused=True)
    plain, _ = _models()
    assert isinstance(fused.mlp, FusedMLP) and type(plain.mlp) is MLP
    fused_state, plain_state = fused.state_dict(), plain.state_dict()
    assert list(fused_state) == list(plain_state)
    for key in plain_state:  # the same seed gives the same parameters: FusedMLP draws nothing
        assert torch.equal(fused_state[key], plain_state[key]), key
    other_fused, _ = _models(fused=True, seed=5)
    other_plain, _ = _models(seed=6)
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
    individual = runner_config(make_config("tiny", {"train": {"fused_mlp": True, "sharing": "individual"}}), 4, 9)
    assert individual["actor"]["class_name"] == individual["critic"]["class_name"] == FUSED_IL_MODEL
    assert individual["actor"]["num_agents"] == 4 and individual["algorithm"]["minibatch_group_size"] == 4
    for changes, message in (
        ({"train": {"fused_mlp": "yes"}}, r"train.fused_mlp='yes' must be true, false or 'auto'"),
        ({"train": {"fused_mlp": "triton"}}, r"train.fused_mlp='triton' must be true, false or 'auto'"),
        (
            {"train": {"fused_mlp": True}, "runner": {"critic": {"class_name": "RNNModel"}}},
            "train.fused_mlp serves rsl-rl's MLPModel",
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
def test_bench_fused_update_runs_on_the_cpu(tmp_path, interpreter, staged_copy):
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
    assert data["git"] == {"commit": "abc123", "dirty": None, "modified": None, "source": "argument"}
    point = data["points"][0]
    assert set(point["seconds"]) == {"torch eager", "fused-mlp eager", "fused eager"}
    assert point["floor"]["update_flops"] > 0 and point["floor"]["seconds"] is None  # no peak rates for a CPU
    for path in ("fused-mlp", "fused"):  # (their bounds: tests/training/test_fused_ppo.py)
        assert len(point["max_relative_difference"][path]) == 12


def test_fused_mlp_precision_runs_on_the_cpu(tmp_path, interpreter, staged_copy):
    """benchmarks/fused_mlp_precision.py under the interpreter (whose products are float32 whatever is
    asked): every case's errors against float64 are within the float32 tolerances, and recorded."""
    sys.path.insert(0, str(BENCHMARKS))
    import fused_mlp_precision

    assert (
        fused_mlp_precision.main(["--device", "cpu", "--rows", "100", "--commit", "abc123", "--out-dir", str(tmp_path)])
        == 0
    )
    data = json.loads((tmp_path / "fused_mlp_precision_cpu.json").read_text())
    assert data["git"]["commit"] == "abc123" and data["interpreted"] is True
    assert [case["precision"] for case in data["cases"]] == ["ieee", "tf32x3", "tf32"]
    for case in data["cases"]:
        assert 0 < case["fused_forward"] <= FORWARD_TOLERANCE and 0 < case["fused_gradients"] <= GRADIENT_TOLERANCE
    assert fused_mlp.FLOAT32_PRECISION == "tf32x3" and not torch.backends.cuda.matmul.allow_tf32  # restored


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


@pytest.mark.parametrize("tf32,float32_precision", [(False, "tf32x3"), (False, "ieee"), (True, "tf32x3")])
def test_triton_on_cuda_matches_torch_and_is_captured_in_a_cuda_graph(
    cuda_device, tf32, float32_precision, monkeypatch
):
    """On CUDA: outputs and gradients against torch's float64 MLP (float32 products, as three TF32
    products or as float32 multiply-adds, or one TF32 product where torch's float32 products may use
    TF32), and a forward and backward captured in a CUDA graph after one eager call give, replayed on
    new inputs, what an eager call gives."""
    monkeypatch.setattr(fused_mlp, "FLOAT32_PRECISION", float32_precision)
    device = torch.device(cuda_device)
    mlp, fused = _mlps(29, [64, 64], 9, "tanh")
    mlp, fused = mlp.to(device), fused.to(device)
    allow_tf32 = torch.backends.cuda.matmul.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = tf32
    try:
        reference = copy.deepcopy(mlp).double()
        x = torch.randn(3 * ROWS + 8, 29, device=device).requires_grad_()
        grad = torch.randn(x.shape[0], 9, device=device)
        y = fused(x)
        y.backward(grad)
        assert _ran_fused(y)
        x_ref = x.detach().double().requires_grad_()
        y_ref = reference(x_ref)
        y_ref.backward(grad.double())
        tolerance = TF32_TOLERANCE if tf32 else FORWARD_TOLERANCE
        assert relative_error(y, y_ref.detach()) <= tolerance
        for p, p_ref in zip(fused.parameters(), reference.parameters()):
            assert relative_error(p.grad, p_ref.grad) <= (TF32_TOLERANCE if tf32 else GRADIENT_TOLERANCE)
        assert relative_error(x.grad, x_ref.grad) <= (TF32_TOLERANCE if tf32 else GRADIENT_TOLERANCE)
        # The eager call's autograd graph holds the parameters' gradient accumulators, made on this
        # stream; a capture on another stream must not meet them.
        del y, y_ref

        static_x = torch.zeros_like(x).requires_grad_()
        params = list(fused.parameters())
        side = torch.cuda.Stream(device)
        side.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(side):  # the eager call (compiles the kernels), on the capturing stream
            torch.autograd.grad(fused(static_x), [static_x, *params], grad)
        torch.cuda.current_stream(device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, stream=side):
            static_y = fused(static_x)
            static_grads = torch.autograd.grad(static_y, [static_x, *params], grad)
        new_x = torch.randn_like(x)
        static_x.detach().copy_(new_x)
        graph.replay()
        eager_x = new_x.clone().requires_grad_()
        eager_y = fused(eager_x)
        eager_grads = torch.autograd.grad(eager_y, [eager_x, *params], grad)
        assert torch.equal(static_y, eager_y)  # the same kernels on the same inputs: deterministic
        for a, b in zip(static_grads, eager_grads):
            assert torch.equal(a, b)
    finally:
        torch.backends.cuda.matmul.allow_tf32 = allow_tf32


def test_parameters_that_are_not_row_major_are_read_as_torch_reads_them(interpreter):
    """A weight stored transposed (a non-contiguous view): the kernels get a row-major copy, and its
    gradient still reaches the parameter."""
    mlp, fused = _mlps(13, [32], 5, "tanh")
    for model in (mlp, fused):
        weight = model[0].weight.detach()
        model[0].weight = nn.Parameter(weight.t().contiguous().t())  # the same values, column-major
        assert not model[0].weight.is_contiguous()
    x, grad = torch.randn(70, 13), torch.randn(70, 5)
    _compare_to_torch(mlp, fused, x, grad)


def test_input_on_another_device_than_the_parameters_is_torch_error(cuda_device):
    """Parameters on the CPU, input on CUDA: torch's own error, not the kernels reading CPU addresses."""
    _, fused = _mlps(29, [64, 64], 9, "tanh")
    with pytest.raises(RuntimeError, match="same device|Expected all tensors"):
        fused(torch.randn(8, 29, device=cuda_device))
