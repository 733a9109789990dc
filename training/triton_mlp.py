"""The fused MLP's Triton backend (`train.fused_mlp="triton"`): rsl-rl's `MLP` (Linear, activation, ...,
Linear) forward in one Triton kernel, and its backward, which recomputes the hidden activations from
the input, in one more (plus a small sum in torch). `TritonMLPFunction` takes the arguments of
`fused_mlp.FusedMLPFunction`, the Warp backend's (`fused_mlp.FusedMLP` picks one of the two).

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

Architectures: 1 to 3 hidden layers of one width in `HIDDEN_WIDTHS` (the matrix products' tiles
are powers of two of at least 16), an output of at most `MAX_OUTPUT` (padded), any input width;
tanh, relu and elu (alpha 1), whose derivatives are taken from the activation's output as the
Warp kernels do. tanh is made of `exp` (no libdevice function), in a form without overflow and,
for small inputs, a series: accurate in float32.

Precision: on CUDA, float32 products as `FLOAT32_PRECISION` says: "tf32x3" (three TF32 products on the
tensor cores whose sum carries float32's precision; on one H200 at 8d0272d the PPO update with
"ieee", one float32 multiply-add per term, took 2,691 ms at 65,536 worlds against torch's 424 ms) or
"ieee"; the tests on CUDA hold both to torch's float32 tolerance. Where torch's own float32 products
may use TF32 (`torch.backends.cuda.matmul.allow_tf32`, which `train.tf32` sets), the kernels use one
TF32 product too (`input_precision="tf32"`, about 1e-3 relative). Triton's interpreter (the CPU)
computes "ieee".

CUDA graphs: the kernels allocate nothing, read nothing back and launch on torch's current stream;
the row count is not a specialisation of the compiled kernel, so after a first eager call (which
compiles them) a forward and backward are captured in a CUDA graph.

On the CPU there is no Triton backend: `FusedMLP` keeps torch's modules there, except under Triton's
interpreter (`TRITON_INTERPRET=1` before this module is imported), which runs these kernels on CPU
tensors (the tests do that).
"""

import functools

import torch
import triton
import triton.language as tl
from triton.runtime.interpreter import InterpretedFunction

from .fused_mlp import MAX_WIDTH, MLPSpec

HIDDEN_WIDTHS = (16, 32, 64, 128)  # allowed hidden widths (tl.dot's tiles: powers of two >= 16)
MAX_HIDDEN_LAYERS = 3  # the kernels spell out each layer (Triton has no lists of tensors)
MAX_OUTPUT = MAX_WIDTH  # widest output (padded to a power of two >= 16)
PROGRAMS_PER_SM = 2  # persistent backward programs per multiprocessor
INTERPRETER_PROGRAMS = 4  # the interpreter runs programs one after another; a few exercise the partial sums
NUM_WARPS = 4
FLOAT32_PRECISION = "tf32x3"  # tl.dot's input_precision for float32 on CUDA (see the module doc)


@triton.jit
def _activate(z, ACTIVATION: tl.constexpr):
    if ACTIVATION == "tanh":
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
def _load_matrix(ptr, ROWS: tl.constexpr, ROWS_P: tl.constexpr, COLS: tl.constexpr, COLS_P: tl.constexpr):
    """A row-major `[ROWS, COLS]` matrix as a `[ROWS_P, COLS_P]` tile, zero-padded."""
    r = tl.arange(0, ROWS_P)
    c = tl.arange(0, COLS_P)
    return tl.load(ptr + r[:, None] * COLS + c[None, :], mask=(r[:, None] < ROWS) & (c[None, :] < COLS), other=0.0)


@triton.jit
def _load_vector(ptr, N: tl.constexpr, N_P: tl.constexpr):
    i = tl.arange(0, N_P)
    return tl.load(ptr + i, mask=i < N, other=0.0)


@triton.jit
def _store_matrix(ptr, m, ROWS: tl.constexpr, ROWS_P: tl.constexpr, COLS: tl.constexpr, COLS_P: tl.constexpr):
    r = tl.arange(0, ROWS_P)
    c = tl.arange(0, COLS_P)
    tl.store(ptr + r[:, None] * COLS + c[None, :], m, mask=(r[:, None] < ROWS) & (c[None, :] < COLS))


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
):
    """`a @ W^T + b` for torch's `[N_OUT, N_IN]` weight `W` (zero-padded)."""
    w = _load_matrix(w_ptr, N_OUT, N_OUT_P, N_IN, N_IN_P)
    b = _load_vector(b_ptr, N_OUT, N_OUT_P)
    return tl.dot(a, tl.trans(w), input_precision=PRECISION) + b[None, :]


@triton.jit(do_not_specialize=["n_rows"])
def _forward_kernel(
    x_ptr, out_ptr, n_rows,
    w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
):  # fmt: skip
    # Layer l's weight and bias are w<l>, b<l>; the output layer is layer HIDDEN (later pointers unused).
    rows = (tl.program_id(0) * BLOCK_M + tl.arange(0, BLOCK_M)).to(tl.int64)  # (rows x width may pass 2**31)
    a = _rows(x_ptr, rows, n_rows, IN, IN_P)
    a = _activate(_layer(a, w0, b0, IN, IN_P, H, H, PRECISION), ACTIVATION)
    if HIDDEN >= 2:
        a = _activate(_layer(a, w1, b1, H, H, H, H, PRECISION), ACTIVATION)
    if HIDDEN >= 3:
        a = _activate(_layer(a, w2, b2, H, H, H, H, PRECISION), ACTIVATION)
    if HIDDEN == 1:
        y = _layer(a, w1, b1, H, H, OUT, OUT_P, PRECISION)
    elif HIDDEN == 2:
        y = _layer(a, w2, b2, H, H, OUT, OUT_P, PRECISION)
    else:
        y = _layer(a, w3, b3, H, H, OUT, OUT_P, PRECISION)
    c = tl.arange(0, OUT_P)
    tl.store(out_ptr + rows[:, None] * OUT + c[None, :], y, mask=(rows[:, None] < n_rows) & (c[None, :] < OUT))


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
):
    """For a layer of weight `[ROWS, COLS]` at `w_ptr`, input `a` and output gradient `g`: the
    weight's gradient `g^T a`, the bias's (the column sums of `g`) and the input's, `g W`."""
    w = _load_matrix(w_ptr, ROWS, ROWS_P, COLS, COLS_P)
    dw = tl.dot(tl.trans(g), a, input_precision=PRECISION)
    return dw, tl.sum(g, axis=0), tl.dot(g, w, input_precision=PRECISION)


@triton.jit(do_not_specialize=["n_rows"])
def _backward_kernel(
    x_ptr, grad_out_ptr, grad_x_ptr, partial_ptr, n_rows,
    w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    GRAD_X: tl.constexpr,
):  # fmt: skip
    # Gradient accumulators, in registers across this program's tiles: d<l> for layer l's weight
    # ([out, in], padded), e<l> for its bias; the output layer's are d_out, e_out.
    d0 = tl.zeros((H, IN_P), dtype=tl.float32)
    e0 = tl.zeros((H,), dtype=tl.float32)
    if HIDDEN >= 2:
        d1 = tl.zeros((H, H), dtype=tl.float32)
        e1 = tl.zeros((H,), dtype=tl.float32)
    if HIDDEN >= 3:
        d2 = tl.zeros((H, H), dtype=tl.float32)
        e2 = tl.zeros((H,), dtype=tl.float32)
    d_out = tl.zeros((OUT_P, H), dtype=tl.float32)
    e_out = tl.zeros((OUT_P,), dtype=tl.float32)
    if HIDDEN == 1:
        w_out = w1
    elif HIDDEN == 2:
        w_out = w2
    else:
        w_out = w3
    program = tl.program_id(0)
    programs = tl.num_programs(0)
    for tile in range(program, tl.cdiv(n_rows, BLOCK_M), programs):
        rows = (tile * BLOCK_M + tl.arange(0, BLOCK_M)).to(tl.int64)  # (int64: rows x width may pass 2**31)
        # Recompute the hidden activations a1 (.. a3) of the tile.
        x = _rows(x_ptr, rows, n_rows, IN, IN_P)
        a1 = _activate(_layer(x, w0, b0, IN, IN_P, H, H, PRECISION), ACTIVATION)
        last = a1
        if HIDDEN >= 2:
            a2 = _activate(_layer(a1, w1, b1, H, H, H, H, PRECISION), ACTIVATION)
            last = a2
        if HIDDEN >= 3:
            a3 = _activate(_layer(a2, w2, b2, H, H, H, H, PRECISION), ACTIVATION)
            last = a3
        # Back through the layers; g is the gradient of a layer's output (zero in rows past the end).
        g = _rows(grad_out_ptr, rows, n_rows, OUT, OUT_P)
        dw, db, g = _back(g, last, w_out, OUT, OUT_P, H, H, PRECISION)
        d_out += dw
        e_out += db
        g = g * _slope(last, ACTIVATION)
        if HIDDEN >= 3:
            dw, db, g = _back(g, a2, w2, H, H, H, H, PRECISION)
            d2 += dw
            e2 += db
            g = g * _slope(a2, ACTIVATION)
        if HIDDEN >= 2:
            dw, db, g = _back(g, a1, w1, H, H, H, H, PRECISION)
            d1 += dw
            e1 += db
            g = g * _slope(a1, ACTIVATION)
        dw, db, gx = _back(g, x, w0, H, H, IN, IN_P, PRECISION)
        d0 += dw
        e0 += db
        if GRAD_X:
            c = tl.arange(0, IN_P)
            mask = (rows[:, None] < n_rows) & (c[None, :] < IN)
            tl.store(grad_x_ptr + rows[:, None] * IN + c[None, :], gx, mask=mask)
    # This program's row of partial sums, in the order of the parameters (weight0, bias0, weight1, ...).
    row = partial_ptr + program.to(tl.int64) * (H * IN + H + (HIDDEN - 1) * (H * H + H) + OUT * H + OUT)
    _store_matrix(row, d0, H, H, IN, IN_P)
    _store_vector(row + H * IN, e0, H, H)
    row += H * IN + H
    if HIDDEN >= 2:
        _store_matrix(row, d1, H, H, H, H)
        _store_vector(row + H * H, e1, H, H)
        row += H * H + H
    if HIDDEN >= 3:
        _store_matrix(row, d2, H, H, H, H)
        _store_vector(row + H * H, e2, H, H)
        row += H * H + H
    _store_matrix(row, d_out, OUT, OUT_P, H, H)
    _store_vector(row + OUT * H, e_out, OUT, OUT_P)


INTERPRETED = isinstance(_forward_kernel, InterpretedFunction)  # TRITON_INTERPRET=1 at import
DEVICES = ("cpu", "cuda") if INTERPRETED else ("cuda",)  # the devices whose tensors the kernels take


def check_spec(spec: MLPSpec) -> None:
    """A one-line ValueError where these kernels do not cover `spec`'s widths or depth."""
    hidden = spec.dims[1:-1]
    if not 1 <= len(hidden) <= MAX_HIDDEN_LAYERS or len(set(hidden)) != 1 or hidden[0] not in HIDDEN_WIDTHS:
        raise ValueError(
            f"fused MLP (triton): hidden layers {list(hidden)} must be 1 to {MAX_HIDDEN_LAYERS} layers "
            f"of one width in {list(HIDDEN_WIDTHS)}"
        )
    if spec.dims[-1] > MAX_OUTPUT:
        raise ValueError(f"fused MLP (triton): output width {spec.dims[-1]} must be at most {MAX_OUTPUT}")


def _padded(width: int) -> int:
    """A width as a tile's: the power of two >= 16 at or above it (tl.dot's smallest tile is 16)."""
    return max(16, triton.next_power_of_2(width))


def block_rows(spec: MLPSpec) -> int:
    """Rows per tile: fewer for the widest layers, whose tiles take the most registers."""
    return 32 if spec.dims[1] > 64 else 64


@functools.cache
def _multiprocessors(device: torch.device) -> int:
    return torch.cuda.get_device_properties(device).multi_processor_count


def backward_programs(device: torch.device, tiles: int) -> int:
    """Persistent programs of a backward over `tiles` row tiles: a few per multiprocessor on CUDA."""
    if device.type == "cuda" and not INTERPRETED:
        return min(tiles, PROGRAMS_PER_SM * _multiprocessors(device))
    return min(tiles, INTERPRETER_PROGRAMS)


def _constants(spec: MLPSpec, precision: str) -> dict:
    """The kernels' compile-time arguments for `spec`."""
    return {
        "IN": spec.dims[0],
        "IN_P": _padded(spec.dims[0]),
        "H": spec.dims[1],
        "OUT": spec.dims[-1],
        "OUT_P": _padded(spec.dims[-1]),
        "HIDDEN": spec.layers - 1,
        "ACTIVATION": spec.activation,
        "PRECISION": precision,
        "BLOCK_M": block_rows(spec),
    }


def _layer_pointers(params: tuple[torch.Tensor, ...]) -> list[torch.Tensor]:
    """w0, b0, .. w3, b3 for the kernels: the parameters, then the first ones again for unused slots."""
    return [*params, *params[: 2 * (MAX_HIDDEN_LAYERS + 1) - len(params)]]


class TritonMLPFunction(torch.autograd.Function):
    """`apply(spec, x, weight0, bias0, weight1, ...)`: the MLP `spec` of `x` `[N, in]` (float32,
    contiguous) with torch's `nn.Linear` parameters (contiguous); saves only `x` and the parameters
    for its backward. `spec` must pass `check_spec`."""

    @staticmethod
    def forward(ctx, spec: MLPSpec, x: torch.Tensor, *params: torch.Tensor) -> torch.Tensor:
        if x.device.type != "cuda" or INTERPRETED:
            precision = "ieee"
        else:
            precision = "tf32" if torch.backends.cuda.matmul.allow_tf32 else FLOAT32_PRECISION
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
        constants = _constants(spec, ctx.precision)
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
