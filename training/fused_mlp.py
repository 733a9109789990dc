"""The fused MLP: rsl-rl's `MLP` (Linear, activation, ..., Linear) as Triton kernels, its whole forward
in one kernel and its backward, which recomputes the hidden activations from the input, in one more
(plus a small sum in torch).

`FusedMLPModel` is rsl-rl's `MLPModel` whose `mlp` is a `FusedMLP`: the same `nn.Linear` and activation
modules (so the same parameters, initialisation and state_dict keys: checkpoints load into either
model), whose forward runs `TritonMLPFunction` for float32 inputs on the devices the kernels take
(`DEVICES`). `train.fused_mlp` (config.py, true or false) switches it on for the actor and the critic
of parameter sharing; for Individual Learning it makes them `FusedIndividualMLPModel`, whose
`BatchedMLP` keeps torch's forward and whose rollout step and loss run in fused_ppo.py's kernels,
which read each network's slice of its stacked parameters (`MLPSpec.stacked`, `_group_layers`).

In training, the PPO update of two such models also fuses rsl-rl's loss into kernels built from the
pieces below (`fused_ppo.FusedPPOLoss`: per mini-batch one kernel for the actor, one for the critic);
this module's `TritonMLPFunction` then serves the rollout's forward, and the update where the fused
loss does not serve.

- forward: one program per `BLOCK_M`-row tile of the input. It loads the tile (its columns padded to
  a power of two of at least 16 and masked), runs every layer in registers (`tl.dot`, bias,
  activation) with the weights read from torch's own `[out, in]` parameters, and stores only the
  output rows.
- backward: a fixed number of persistent programs (`backward_programs`: a few per multiprocessor),
  each taking every `programs`-th row tile. For each tile it recomputes the hidden activations (the
  forward saved only the input: recomputing a few small products costs less than storing and
  reading back every layer's activations of millions of rows), walks the layers back and adds the
  tile's weight and bias gradients into accumulators held in registers across its tiles; at the end
  it writes them as ONE row of a `[programs, parameters]` buffer, which torch sums. One row per
  program keeps that buffer small and needs no atomics: the sum's order is fixed, so the gradients
  are deterministic. It writes the input gradient only where the input requires one (a kernel
  compiled without that store otherwise). Rows past the end of the input read as zero, so they add
  nothing to the gradients.

Architectures (`mlp_spec`): 1 to 3 hidden layers of one width in `HIDDEN_WIDTHS` (the matrix
products' tiles are powers of two of at least 16), an output of at most `MAX_WIDTH` (padded), any
input width; tanh, relu and elu (alpha 1), whose derivatives are taken from the activation's output.
tanh is made of `exp` (no libdevice function), in a form without overflow and, for small inputs, a
series: accurate in float32.

Precision: on CUDA, float32 products as `FLOAT32_PRECISION` says: "tf32x3" (three TF32 products on the
tensor cores whose sum carries float32's precision) or "ieee" (one float32 multiply-add per term: on
one H200 at 8d0272d the PPO update took 2,691 ms at 65,536 worlds against torch's 424 ms, which is why
the default is "tf32x3"). Where torch's own float32 products may use TF32
(`torch.backends.cuda.matmul.allow_tf32`, which `train.tf32` sets), the kernels use one TF32 product
too (`input_precision="tf32"`, about 1e-3 relative), and tanh as the multiprocessor's approximation
(`tanh.approx.f32`, 2^-11 relative: TF32's own rounding; `FAST_TANH_WITH_TF32`), which made the fused
update 1.21x as fast on one H100 (benchmarks/results/fused_tuning_h100_27fb357/). Triton's
interpreter (the CPU) computes "ieee".
Autocast, other dtypes, TorchScript and ONNX export take the plain torch path.

Measured on one H200 at commit 48ee313 (benchmarks/results/fused_triton_h200_48ee313/):

- training (`bench_training.py --worlds 65536 --sharing parameter --loops fast`): torch 474.8
  ms/iteration (2.65e7 agent-steps/s); fused with float32 (tf32x3) products 500.0 ms (2.52e7); fused
  with TF32 products 263.7 ms (4.77e7), its update 230 ms against 423 ms. At 1,024 worlds: torch
  26.6 ms (7.40e6), fused TF32 19.8 ms (9.92e6).
- errors against float64 on 1,000,003 rows (29-64-64-9 tanh): tf32x3 forward 4.1e-7, gradients 4.9e-7
  (torch's float32: 3.9e-7, 2.0e-6); "ieee" forward 4.1e-7, gradients 1.5e-6; TF32 1.8e-3 / 1.9e-3
  (torch with TF32: 3.9e-4 / 4.2e-4).
- one full PPO update (`bench_fused_update.py`, default preset, 65,536 worlds), fused tf32x3 against
  torch: largest relative difference per parameter 1.13e-4 (actor.mlp.4.weight); the update, replayed
  from a CUDA graph, 1,221 ms against torch's 1,098 ms.

(An earlier backend of Warp tile kernels took 3.2x torch's update time on one H100,
benchmarks/results/fused_update_h100_5b61039/, and 242 s to compile for sm_90: it was removed.)

CUDA graphs: the kernels allocate nothing, read nothing back and launch on torch's current stream;
the row count is not a specialisation of the compiled kernel, so after a first eager call (which
compiles them) a forward and backward are captured in a CUDA graph.

On the CPU there are no Triton kernels: `FusedMLP` keeps torch's modules there, except under Triton's
interpreter (`TRITON_INTERPRET=1` before this module is imported), which runs these kernels on CPU
tensors (the tests do that).
"""

# (No `from __future__ import annotations`: TorchScript must resolve FusedMLP's annotations as objects.)
import functools
from dataclasses import dataclass
from typing import cast

import torch
import torch.nn as nn
import triton
import triton.language as tl
from rsl_rl.models import MLPModel
from rsl_rl.modules import MLP
from triton.runtime.interpreter import InterpretedFunction

from . import _rsl  # noqa: F401
from .models import BatchedLinear, BatchedMLP, IndividualMLPModel, StackedMLP, StackedMLPModel

HIDDEN_WIDTHS = (16, 32, 64, 128)  # allowed hidden widths (tl.dot's tiles: powers of two >= 16)
MAX_HIDDEN_LAYERS = 3  # the kernels spell out each layer (Triton has no lists of tensors)
MAX_WIDTH = 128  # widest hidden or output layer (the output padded to a power of two >= 16)
PROGRAMS_PER_SM = 2  # persistent backward programs per multiprocessor
INTERPRETER_PROGRAMS = 4  # the interpreter runs programs one after another; a few exercise the partial sums
NUM_WARPS = 4
FLOAT32_PRECISION = "tf32x3"  # tl.dot's input_precision for float32 on CUDA (see the module doc)
FAST_TANH_WITH_TF32 = True  # with TF32 products, tanh as the multiprocessor's approximation (see the module doc)
ACTIVATIONS = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu"}


@dataclass(frozen=True)
class MLPSpec:
    """An MLP's architecture as the kernels see it: the layer widths `dims` (input, hidden...,
    output), the activation's name, and for Individual Learning's `models.BatchedMLP` (`stacked`) the
    number of networks `groups` whose parameters it stacks (weights `[groups, in, out]`, biases
    `[groups, out]`; row `k` of a batch is network `k % groups`'s)."""

    dims: tuple[int, ...]
    activation: str
    groups: int = 1
    stacked: bool = False
    blocked: bool = False  # a population's `models.StackedMLP`: `[groups, out, in]`, each network's rows contiguous

    @property
    def layers(self) -> int:
        return len(self.dims) - 1

    def kernel_constants(self) -> dict:
        """The compile-time arguments of the PPO kernels that take stacked networks (fused_ppo.py)."""
        return {"GROUPS": self.groups, "TRANSPOSED": self.stacked, "BLOCKED": self.blocked}


def mlp_spec(mlp: nn.Sequential) -> MLPSpec:
    """The `MLPSpec` of an rsl-rl `MLP` (Linear, activation, ..., Linear); a one-line ValueError
    names what the kernels do not cover."""
    modules = list(mlp)
    linears = [m for m in modules[0::2] if isinstance(m, nn.Linear)]
    if len(modules) < 3 or len(modules) % 2 == 0 or len(linears) != len(modules[0::2]):
        raise ValueError(
            f"fused MLP: expected Linear, activation, ..., Linear modules, got {[type(m).__name__ for m in modules]}"
        )
    dims = (linears[0].in_features,) + tuple(m.out_features for m in linears)
    return MLPSpec(dims, _activation_name(modules[1::2], dims))


def stacked_mlp_spec(mlp: BatchedMLP) -> MLPSpec:
    """The `MLPSpec` of Individual Learning's `models.BatchedMLP` (one activation module between its
    `BatchedLinear` layers); a one-line ValueError names what the kernels do not cover."""
    layers = cast(list[BatchedLinear], list(mlp.layers))
    dims = (layers[0].in_features,) + tuple(layer.out_features for layer in layers)
    if len(layers) < 2:
        raise ValueError(f"fused MLP: Individual Learning's networks need a hidden layer, got widths {list(dims)}")
    return MLPSpec(dims, _activation_name([mlp.activation] * (len(layers) - 1), dims), mlp.groups, True)


def population_mlp_spec(mlp: StackedMLP) -> MLPSpec:
    """The `MLPSpec` of a population's `models.StackedMLP` (torch's `[out, in]` weights per network,
    network k's rows the k-th of K equal consecutive blocks); a one-line ValueError names what the
    kernels do not cover."""
    dims = (mlp.weights[0].shape[2],) + tuple(w.shape[1] for w in mlp.weights)
    if len(mlp.weights) < 2:
        raise ValueError(f"fused MLP: a population's networks need a hidden layer, got widths {list(dims)}")
    activations = [mlp.activation] * (len(mlp.weights) - 1)
    return MLPSpec(dims, _activation_name(activations, dims), mlp.runs, stacked=False, blocked=True)


def _activation_name(activations: list, dims: tuple[int, ...]) -> str:
    """The kernels' name of the MLP's activation modules, its widths checked (see `mlp_spec`)."""
    kinds = {type(m) for m in activations}
    if len(kinds) != 1 or next(iter(kinds)) not in ACTIVATIONS:
        raise ValueError(
            f"fused MLP: activation {sorted(k.__name__ for k in kinds)} is not supported; use tanh, relu or elu"
        )
    if any(isinstance(m, nn.ELU) and m.alpha != 1.0 for m in activations):
        raise ValueError("fused MLP: elu must have alpha 1.0")
    problem = widths_problem(dims[1:])
    if problem is not None:
        raise ValueError(f"fused MLP: {problem}")
    return ACTIVATIONS[next(iter(kinds))]


def widths_problem(widths: tuple[int, ...] | list[int]) -> str | None:
    """Why the kernels do not cover an MLP of these layer widths (hidden layers, then the output; the
    input's is free); None when they do."""
    if any(not 1 <= d <= MAX_WIDTH for d in widths):
        return f"layer widths {list(widths)} must be in [1, {MAX_WIDTH}]"
    hidden = widths[:-1]
    if len(hidden) > MAX_HIDDEN_LAYERS or len(set(hidden)) != 1 or hidden[0] not in HIDDEN_WIDTHS:
        layers = f"1 to {MAX_HIDDEN_LAYERS} layers of one width in {list(HIDDEN_WIDTHS)}"
        return f"hidden layers {list(hidden)} must be {layers}"
    return None


@triton.jit
def _activate(z, ACTIVATION: tl.constexpr, FAST_TANH: tl.constexpr):
    if ACTIVATION == "tanh" and FAST_TANH:  # the multiprocessor's tanh: 2**-11 relative, TF32's rounding
        return tl.inline_asm_elementwise("tanh.approx.f32 $0, $1;", "=f,f", [z], dtype=tl.float32, is_pure=True, pack=1)
    elif ACTIVATION == "tanh":
        # 1 - 2 / (exp(2|z|) + 1) as (1 - e) / (1 + e), e = exp(-2|z|) <= 1: no overflow; below
        # |z| = 1/16, where 1 - e would lose digits, the series z - z^3/3 + 2z^5/15 (next term < 1e-8 z).
        a = tl.abs(z)
        e = tl.exp(-2.0 * a)
        t = (1.0 - e) / (1.0 + e)
        z2 = z * z
        series = a * (1.0 + z2 * (-1.0 / 3.0 + z2 * (2.0 / 15.0)))
        t = tl.where(a < 0.0625, series, t)
        return tl.where(z < 0.0, -t, t)
    elif ACTIVATION == "relu":
        return tl.maximum(z, 0.0)
    else:  # elu, alpha 1
        return tl.where(z > 0.0, z, tl.exp(tl.minimum(z, 0.0)) - 1.0)  # (no overflow where unused)


@triton.jit
def _slope(y, ACTIVATION: tl.constexpr):
    """The activation's derivative, from its output `y`."""
    if ACTIVATION == "tanh":
        return 1.0 - y * y
    elif ACTIVATION == "relu":
        return tl.where(y > 0.0, 1.0, 0.0)  # as torch's: the gradient passes where the output is > 0
    else:
        return tl.where(y > 0.0, 1.0, y + 1.0)  # exp(z) = y + 1 where z <= 0


@triton.jit
def _matrix_offsets(ROWS: tl.constexpr, ROWS_P: tl.constexpr, COLS: tl.constexpr, COLS_P: tl.constexpr,
                    TRANSPOSED: tl.constexpr):  # fmt: skip
    """Offsets and mask of a `[ROWS, COLS]` matrix's `[ROWS_P, COLS_P]` tile: row-major, or stored as
    its transpose (`[COLS, ROWS]` row-major: the weights of `models.BatchedLinear`) with TRANSPOSED."""
    r = tl.arange(0, ROWS_P)
    c = tl.arange(0, COLS_P)
    offsets = c[None, :] * ROWS + r[:, None] if TRANSPOSED else r[:, None] * COLS + c[None, :]
    return offsets, (r[:, None] < ROWS) & (c[None, :] < COLS)


@triton.jit
def _load_matrix(ptr, ROWS: tl.constexpr, ROWS_P: tl.constexpr, COLS: tl.constexpr, COLS_P: tl.constexpr,
                 TRANSPOSED: tl.constexpr = False):  # fmt: skip
    """A `[ROWS, COLS]` matrix (see `_matrix_offsets`) as a `[ROWS_P, COLS_P]` tile, zero-padded."""
    offsets, mask = _matrix_offsets(ROWS, ROWS_P, COLS, COLS_P, TRANSPOSED)
    return tl.load(ptr + offsets, mask=mask, other=0.0)


@triton.jit
def _load_vector(ptr, N: tl.constexpr, N_P: tl.constexpr):
    i = tl.arange(0, N_P)
    return tl.load(ptr + i, mask=i < N, other=0.0)


@triton.jit
def _store_matrix(ptr, m, ROWS: tl.constexpr, ROWS_P: tl.constexpr, COLS: tl.constexpr, COLS_P: tl.constexpr,
                  TRANSPOSED: tl.constexpr = False):  # fmt: skip
    offsets, mask = _matrix_offsets(ROWS, ROWS_P, COLS, COLS_P, TRANSPOSED)
    tl.store(ptr + offsets, m, mask=mask)


@triton.jit
def _store_vector(ptr, v, N: tl.constexpr, N_P: tl.constexpr):
    i = tl.arange(0, N_P)
    tl.store(ptr + i, v, mask=i < N)


@triton.jit
def _rows(ptr, rows, n_rows, COLS: tl.constexpr, COLS_P: tl.constexpr):
    """Rows `rows` of a row-major `[n_rows, COLS]` matrix, zero past its end and in the padding."""
    c = tl.arange(0, COLS_P)
    mask = (rows[:, None] < n_rows) & (c[None, :] < COLS)
    return tl.load(ptr + rows[:, None] * COLS + c[None, :], mask=mask, other=0.0)


@triton.jit
def _layer(
    a,
    w_ptr,
    b_ptr,
    N_IN: tl.constexpr,
    N_IN_P: tl.constexpr,
    N_OUT: tl.constexpr,
    N_OUT_P: tl.constexpr,
    PRECISION: tl.constexpr,
    TRANSPOSED: tl.constexpr = False,
):
    """`a @ W^T + b` for torch's `[N_OUT, N_IN]` weight `W` (zero-padded; stored as `W^T` with TRANSPOSED)."""
    w = _load_matrix(w_ptr, N_OUT, N_OUT_P, N_IN, N_IN_P, TRANSPOSED)
    b = _load_vector(b_ptr, N_OUT, N_OUT_P)
    return tl.dot(a, tl.trans(w), input_precision=PRECISION) + b[None, :]


@triton.jit
def _back(
    g,
    a,
    w_ptr,
    ROWS: tl.constexpr,
    ROWS_P: tl.constexpr,
    COLS: tl.constexpr,
    COLS_P: tl.constexpr,
    PRECISION: tl.constexpr,
    TRANSPOSED: tl.constexpr = False,
):
    """For a layer of weight `[ROWS, COLS]` at `w_ptr` (stored as its transpose with TRANSPOSED), input
    `a` and output gradient `g`: the weight's gradient `g^T a`, the bias's (the column sums of `g`)
    and the input's, `g W`."""
    w = _load_matrix(w_ptr, ROWS, ROWS_P, COLS, COLS_P, TRANSPOSED)
    dw = tl.dot(tl.trans(g), a, input_precision=PRECISION)
    return dw, tl.sum(g, axis=0), tl.dot(g, w, input_precision=PRECISION)


@triton.jit
def _hidden(
    x, w0, b0, w1, b1, w2, b2,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, HIDDEN: tl.constexpr,
    ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, FAST_TANH: tl.constexpr, TRANSPOSED: tl.constexpr = False,
):  # fmt: skip
    """The hidden activations `(a1, a2, a3)` of the input tile `x`; past the `HIDDEN`-th layer each
    repeats the last (so `a3` is always the last hidden layer's)."""
    a1 = _activate(_layer(x, w0, b0, IN, IN_P, H, H, PRECISION, TRANSPOSED), ACTIVATION, FAST_TANH)
    a2 = a1
    if HIDDEN >= 2:
        a2 = _activate(_layer(a1, w1, b1, H, H, H, H, PRECISION, TRANSPOSED), ACTIVATION, FAST_TANH)
    a3 = a2
    if HIDDEN >= 3:
        a3 = _activate(_layer(a2, w2, b2, H, H, H, H, PRECISION, TRANSPOSED), ACTIVATION, FAST_TANH)
    return a1, a2, a3


@triton.jit
def _output_layer(w1, b1, w2, b2, w3, b3, HIDDEN: tl.constexpr):
    """The output layer's weight and bias pointers: layer `HIDDEN`'s."""
    if HIDDEN == 1:
        return w1, b1
    elif HIDDEN == 2:
        return w2, b2
    else:
        return w3, b3


@triton.jit
def _group_layers(
    g, w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, HIDDEN: tl.constexpr,
):  # fmt: skip
    """Network `g`'s layer pointers in parameters stacked over networks (`models.BatchedMLP`: weights
    `[groups, in, out]`, biases `[groups, out]`); layer `HIDDEN` is the output layer."""
    g = g.to(tl.int64)
    w0 += g * (IN * H)
    b0 += g * H
    if HIDDEN == 1:
        w1 += g * (H * OUT)
        b1 += g * OUT
    else:
        w1 += g * (H * H)
        b1 += g * H
    if HIDDEN == 2:
        w2 += g * (H * OUT)
        b2 += g * OUT
    elif HIDDEN == 3:
        w2 += g * (H * H)
        b2 += g * H
        w3 += g * (H * OUT)
        b3 += g * OUT
    return w0, b0, w1, b1, w2, b2, w3, b3


@triton.jit
def _zero_gradients(IN_P: tl.constexpr, H: tl.constexpr, OUT_P: tl.constexpr):
    """Gradient accumulators `(d0, e0, d1, e1, d2, e2, d_out, e_out)`: d<l> for hidden layer l's weight
    ([out, in], padded), e<l> for its bias; the output layer's d_out, e_out. (Those of hidden layers
    the MLP lacks are never stored, and compiled away.)"""
    return (
        tl.zeros((H, IN_P), dtype=tl.float32),
        tl.zeros((H,), dtype=tl.float32),
        tl.zeros((H, H), dtype=tl.float32),
        tl.zeros((H,), dtype=tl.float32),
        tl.zeros((H, H), dtype=tl.float32),
        tl.zeros((H,), dtype=tl.float32),
        tl.zeros((OUT_P, H), dtype=tl.float32),
        tl.zeros((OUT_P,), dtype=tl.float32),
    )


@triton.jit
def _backward_tile(
    g, x, a1, a2, a3, w0, w1, w2, w_out, d0, e0, d1, e1, d2, e2, d_out, e_out,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, TRANSPOSED: tl.constexpr = False,
):  # fmt: skip
    """Back through the layers of one tile from `g`, the gradient of its output (zero in rows that
    must add nothing): the accumulators with the tile's weight and bias gradients added, and the
    input's gradient `gx`."""
    dw, db, g = _back(g, a3, w_out, OUT, OUT_P, H, H, PRECISION, TRANSPOSED)
    d_out += dw
    e_out += db
    g = g * _slope(a3, ACTIVATION)
    if HIDDEN >= 3:
        dw, db, g = _back(g, a2, w2, H, H, H, H, PRECISION, TRANSPOSED)
        d2 += dw
        e2 += db
        g = g * _slope(a2, ACTIVATION)
    if HIDDEN >= 2:
        dw, db, g = _back(g, a1, w1, H, H, H, H, PRECISION, TRANSPOSED)
        d1 += dw
        e1 += db
        g = g * _slope(a1, ACTIVATION)
    dw, db, gx = _back(g, x, w0, H, H, IN, IN_P, PRECISION, TRANSPOSED)
    d0 += dw
    e0 += db
    return d0, e0, d1, e1, d2, e2, d_out, e_out, gx


@triton.jit
def _partial_row(partial_ptr, program, SUMS: tl.constexpr, IN: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr,
                 HIDDEN: tl.constexpr):  # fmt: skip
    """Where `program`'s row of a `[programs, parameters + SUMS]` buffer of partial sums starts."""
    width = H * IN + H + (HIDDEN - 1) * (H * H + H) + OUT * H + OUT + SUMS
    return partial_ptr + program.to(tl.int64) * width


@triton.jit
def _store_gradients(
    row, d0, e0, d1, e1, d2, e2, d_out, e_out,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, TRANSPOSED: tl.constexpr = False,
):  # fmt: skip
    """The accumulators at `row` in the order of the parameters (weight0, bias0, weight1, ...), each
    weight's as it is stored (transposed with TRANSPOSED); returns the pointer past them."""
    _store_matrix(row, d0, H, H, IN, IN_P, TRANSPOSED)
    _store_vector(row + H * IN, e0, H, H)
    row += H * IN + H
    if HIDDEN >= 2:
        _store_matrix(row, d1, H, H, H, H, TRANSPOSED)
        _store_vector(row + H * H, e1, H, H)
        row += H * H + H
    if HIDDEN >= 3:
        _store_matrix(row, d2, H, H, H, H, TRANSPOSED)
        _store_vector(row + H * H, e2, H, H)
        row += H * H + H
    _store_matrix(row, d_out, OUT, OUT_P, H, H, TRANSPOSED)
    _store_vector(row + OUT * H, e_out, OUT, OUT_P)
    return row + OUT * H + OUT


@triton.jit(do_not_specialize=["n_rows"])
def _forward_kernel(
    x_ptr, out_ptr, n_rows,
    w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    FAST_TANH: tl.constexpr,
):  # fmt: skip
    # Layer l's weight and bias are w<l>, b<l>; the output layer is layer HIDDEN (later pointers unused).
    rows = (tl.program_id(0) * BLOCK_M + tl.arange(0, BLOCK_M)).to(tl.int64)  # (rows x width may pass 2**31)
    x = _rows(x_ptr, rows, n_rows, IN, IN_P)
    _, _, last = _hidden(x, w0, b0, w1, b1, w2, b2, IN, IN_P, H, HIDDEN, ACTIVATION, PRECISION, FAST_TANH)
    w_out, b_out = _output_layer(w1, b1, w2, b2, w3, b3, HIDDEN)
    y = _layer(last, w_out, b_out, H, H, OUT, OUT_P, PRECISION)
    c = tl.arange(0, OUT_P)
    tl.store(out_ptr + rows[:, None] * OUT + c[None, :], y, mask=(rows[:, None] < n_rows) & (c[None, :] < OUT))


@triton.jit(do_not_specialize=["n_rows"])
def _backward_kernel(
    x_ptr, grad_out_ptr, grad_x_ptr, partial_ptr, n_rows,
    w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    FAST_TANH: tl.constexpr,
    GRAD_X: tl.constexpr,
):  # fmt: skip
    # Gradient accumulators, in registers across this program's tiles.
    d0, e0, d1, e1, d2, e2, d_out, e_out = _zero_gradients(IN_P, H, OUT_P)
    w_out, _ = _output_layer(w1, b1, w2, b2, w3, b3, HIDDEN)
    program = tl.program_id(0)
    for tile in range(program, tl.cdiv(n_rows, BLOCK_M), tl.num_programs(0)):
        rows = (tile * BLOCK_M + tl.arange(0, BLOCK_M)).to(tl.int64)  # (int64: rows x width may pass 2**31)
        x = _rows(x_ptr, rows, n_rows, IN, IN_P)
        a1, a2, a3 = _hidden(x, w0, b0, w1, b1, w2, b2, IN, IN_P, H, HIDDEN, ACTIVATION, PRECISION, FAST_TANH)
        g = _rows(grad_out_ptr, rows, n_rows, OUT, OUT_P)  # zero in rows past the end
        d0, e0, d1, e1, d2, e2, d_out, e_out, gx = _backward_tile(
            g, x, a1, a2, a3, w0, w1, w2, w_out, d0, e0, d1, e1, d2, e2, d_out, e_out,
            IN, IN_P, H, OUT, OUT_P, HIDDEN, ACTIVATION, PRECISION,
        )  # fmt: skip
        if GRAD_X:
            c = tl.arange(0, IN_P)
            mask = (rows[:, None] < n_rows) & (c[None, :] < IN)
            tl.store(grad_x_ptr + rows[:, None] * IN + c[None, :], gx, mask=mask)
    # This program's row of partial sums, in the order of the parameters (weight0, bias0, weight1, ...).
    row = _partial_row(partial_ptr, program, 0, IN, H, OUT, HIDDEN)
    _store_gradients(row, d0, e0, d1, e1, d2, e2, d_out, e_out, IN, IN_P, H, OUT, OUT_P, HIDDEN)


INTERPRETED = isinstance(_forward_kernel, InterpretedFunction)  # TRITON_INTERPRET=1 at import
DEVICES = ("cpu", "cuda") if INTERPRETED else ("cuda",)  # the devices whose tensors the kernels take


def _padded(width: int) -> int:
    """A width as a tile's: the power of two >= 16 at or above it (tl.dot's smallest tile is 16)."""
    return max(16, triton.next_power_of_2(width))


def block_rows(spec: MLPSpec, backward: bool = False) -> int:
    """Rows per tile. The backward kernels (and the fused loss's) keep every hidden layer's activations
    and the gradient accumulators in registers: 32 rows; on one H100 at 27fb357 (paper preset, 65,536
    worlds, TF32) the fused update took 73.6 ms with 32 rows, 86.5 ms with 64 and 167 ms with 128 (4
    warps, 2 programs per multiprocessor; 8 warps were slower at every size:
    benchmarks/results/fused_tuning_h100_27fb357/). The forward: 64 rows, 32 for the widest layers."""
    if backward:
        return 32
    return 32 if spec.dims[1] > 64 else 64


@functools.cache
def _multiprocessors(device: torch.device) -> int:
    return torch.cuda.get_device_properties(device).multi_processor_count


def backward_programs(device: torch.device, tiles: int) -> int:
    """Persistent programs of a backward over `tiles` row tiles: a few per multiprocessor on CUDA."""
    if device.type == "cuda" and not INTERPRETED:
        return min(tiles, PROGRAMS_PER_SM * _multiprocessors(device))
    return min(tiles, INTERPRETER_PROGRAMS)


def _constants(spec: MLPSpec, precision: str, backward: bool = False) -> dict:
    """The kernels' compile-time arguments for `spec` (`backward`: of a backward or loss kernel)."""
    return {
        "IN": spec.dims[0],
        "IN_P": _padded(spec.dims[0]),
        "H": spec.dims[1],
        "OUT": spec.dims[-1],
        "OUT_P": _padded(spec.dims[-1]),
        "HIDDEN": spec.layers - 1,
        "ACTIVATION": spec.activation,
        "PRECISION": precision,
        "BLOCK_M": block_rows(spec, backward),
        "FAST_TANH": precision == "tf32" and FAST_TANH_WITH_TF32,
    }


def _layer_pointers(params: tuple[torch.Tensor, ...]) -> list[torch.Tensor]:
    """w0, b0, .. w3, b3 for the kernels: the parameters, then the first ones again for unused slots."""
    return [*params, *params[: 2 * (MAX_HIDDEN_LAYERS + 1) - len(params)]]


def kernel_precision(device: torch.device) -> str:
    """`tl.dot`'s input precision for float32 tensors on `device`: "ieee" on the CPU (the
    interpreter), "tf32" where torch's own float32 products may use TF32, `FLOAT32_PRECISION` otherwise."""
    if device.type != "cuda" or INTERPRETED:
        return "ieee"
    return "tf32" if torch.backends.cuda.matmul.allow_tf32 else FLOAT32_PRECISION


class TritonMLPFunction(torch.autograd.Function):
    """`apply(spec, x, weight0, bias0, weight1, ...)`: the MLP `spec` of `x` `[N, in]` (float32,
    contiguous) with torch's `nn.Linear` parameters (contiguous); saves only `x` and the parameters
    for its backward. `spec` comes from `mlp_spec` (an architecture the kernels cover)."""

    @staticmethod
    def forward(ctx, spec: MLPSpec, x: torch.Tensor, *params: torch.Tensor) -> torch.Tensor:
        precision = kernel_precision(x.device)
        ctx.spec, ctx.precision = spec, precision
        ctx.save_for_backward(x, *params)
        n_rows = x.shape[0]
        out = torch.empty(n_rows, spec.dims[-1], dtype=x.dtype, device=x.device)
        if n_rows:
            constants = _constants(spec, precision)
            grid = (triton.cdiv(n_rows, constants["BLOCK_M"]),)
            _forward_kernel[grid](x, out, n_rows, *_layer_pointers(params), **constants, num_warps=NUM_WARPS)
        return out

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x, *params = ctx.saved_tensors
        spec: MLPSpec = ctx.spec
        constants = _constants(spec, ctx.precision, backward=True)
        n_rows = x.shape[0]
        programs = backward_programs(x.device, triton.cdiv(n_rows, constants["BLOCK_M"]))
        partial = torch.empty(programs, sum(p.numel() for p in params), dtype=x.dtype, device=x.device)
        input_grad = bool(ctx.needs_input_grad[1])
        grad_x = torch.empty_like(x) if input_grad else None
        if programs:
            _backward_kernel[(programs,)](
                x,
                grad_out.contiguous(),
                x if grad_x is None else grad_x,  # not written without GRAD_X
                partial,
                n_rows,
                *_layer_pointers(tuple(params)),
                **constants,
                GRAD_X=input_grad,
                num_warps=NUM_WARPS,
            )
        sums = partial.sum(dim=0).split([p.numel() for p in params])
        return (None, grad_x, *(s.view_as(p) for s, p in zip(sums, params)))


class FusedMLP(MLP):
    """An rsl-rl `MLP` (the same modules, adopted from `mlp`, so the same parameters and state_dict
    keys) whose forward runs the fused kernels where they serve: float32 on a device of `DEVICES`
    (CUDA, or the CPU under Triton's interpreter), outside autocast, TorchScript, tracing and export;
    elsewhere the modules one after another."""

    def __init__(self, mlp: MLP) -> None:
        nn.Sequential.__init__(self, *mlp)  # not MLP.__init__: no new layers, no random draws
        self.spec = mlp_spec(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if torch.jit.is_scripting() or not self._fusable(x):
            for layer in self:
                x = layer(x)
            return x
        return self._fused(x)

    @torch.jit.unused
    def _fusable(self, x: torch.Tensor) -> bool:
        return (
            x.dtype == torch.float32
            and x.device.type in DEVICES
            # parameters elsewhere than the input: torch's modules raise its one-line error, where the
            # kernels would read another device's addresses
            and all(p.device == x.device for p in self.parameters())
            and self[0].weight.dtype == torch.float32
            and not torch.is_autocast_enabled(x.device.type)
            and not torch.jit.is_tracing()
            and not torch.compiler.is_compiling()
            and not torch.compiler.is_exporting()
            # vmap and the other functorch transforms (the opponent pool's snapshots act through vmap):
            # the kernels' autograd function has no batching rule
            and not torch._C._are_functorch_transforms_active()
        )

    @torch.jit.unused
    def _fused(self, x: torch.Tensor) -> torch.Tensor:
        # The kernels read columns past a narrower input as zeros: refuse it, as nn.Linear does.
        if x.shape[-1] != self.spec.dims[0]:
            raise ValueError(f"FusedMLP: input of {x.shape[-1]} features, the first layer takes {self.spec.dims[0]}")
        rows = x.reshape(-1, x.shape[-1]).contiguous()
        # The kernels read row-major parameters (a no-op for nn.Linear's own; a copy, in autograd, otherwise).
        params = [p.contiguous() for p in self.layer_parameters()]
        out = TritonMLPFunction.apply(self.spec, rows, *params)
        return out.reshape(*x.shape[:-1], out.shape[-1])

    @torch.jit.unused
    def layer_parameters(self) -> list[torch.Tensor]:
        """The parameters in the order the kernels take them: weight0, bias0, weight1, ..."""
        return [p for layer in list(self)[0::2] for p in (layer.weight, layer.bias)]


def kernel_view(mlp: nn.Module | None) -> tuple[MLPSpec, list[torch.Tensor]] | None:
    """What the PPO kernels (fused_ppo.py) read of a `FusedMLP`, or of Individual Learning's `BatchedMLP`
    with a spec (`FusedIndividualMLPModel`): its `MLPSpec` and parameters (weight0, bias0, weight1, ...);
    None for any other MLP."""
    if isinstance(mlp, FusedMLP):
        return mlp.spec, mlp.layer_parameters()
    if isinstance(mlp, StackedMLP) and isinstance(mlp.spec, MLPSpec):
        return mlp.spec, mlp.layer_parameters()
    if isinstance(mlp, BatchedMLP) and isinstance(mlp.spec, MLPSpec):
        layers = cast(list[BatchedLinear], list(mlp.layers))
        return mlp.spec, [p for layer in layers for p in (layer.weight, layer.bias)]
    return None


class FusedMLPModel(MLPModel):
    """rsl-rl's `MLPModel` with a `FusedMLP` (see the module doc); its arguments are `MLPModel`'s.
    `fused = True` tells `AquariumPPO` to try the fused loss (`fused_ppo.FusedPPOLoss`) with it."""

    mlp: MLP  # declared: rsl-rl's class sets it in __init__, where type inference does not follow
    fused = True

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.mlp = FusedMLP(self.mlp)


class FusedIndividualMLPModel(IndividualMLPModel):
    """Individual Learning's `IndividualMLPModel` for the fused PPO kernels (`train.fused_mlp` with
    `sharing = "individual"`): the same `BatchedMLP` (parameters, state_dict, torch's forward), its
    `MLPSpec` (`stacked_mlp_spec`) checked when it is built; `AquariumPPO` runs its rollout step and its
    loss in fused_ppo.py's kernels, one program per network's rows."""

    fused = True

    mlp: BatchedMLP  # declared: IndividualMLPModel sets it in __init__

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.mlp.spec = stacked_mlp_spec(self.mlp)


class FusedStackedMLPModel(StackedMLPModel):
    """A population's `StackedMLPModel` for the fused PPO kernels (`train.fused_mlp`): torch's forward,
    its `MLPSpec` (`population_mlp_spec`) checked when it is built; `AquariumPPO` runs its rollout step
    and its loss in fused_ppo.py's kernels, one program per run's rows."""

    fused = True

    mlp: StackedMLP  # declared: StackedMLPModel sets it in __init__

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.mlp.spec = population_mlp_spec(self.mlp)
