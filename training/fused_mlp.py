"""A fused MLP for rsl-rl's `MLPModel`: the whole network's forward in one kernel, and its backward,
which recomputes the hidden activations from the input, in one more (plus a small sum). Two backends
make the kernels: "warp", this module's Warp tile kernels (`FusedMLPFunction`), and "triton",
`triton_mlp.TritonMLPFunction` (training/triton_mlp.py; the same design in Triton).

`FusedMLPModel` is rsl-rl's `MLPModel` whose `mlp` is a `FusedMLP` of one backend: the same
`nn.Linear` and activation modules (so the same parameters, initialisation and state_dict keys:
checkpoints load into either model and either backend), whose forward runs the backend's autograd
function for float32 inputs on the backend's devices (`backend_function`). `train.fused_mlp`
(config.py: false, "warp" or "triton") switches it on for the actor and the critic of parameter
sharing; Individual Learning keeps its `BatchedMLP`. `MLPSpec`, `mlp_spec` and `ACTIVATIONS` serve
both backends.

The Warp kernels (made per architecture by `mlp_kernel`):

- forward: each block takes row tiles of `spec.rows` rows and runs every layer (`tile_matmul`, bias, activation)
  with the weights read from one flat parameter vector, and writes only the output rows.
- backward: a fixed number of blocks (`launch_blocks`), each taking every `blocks`-th row tile:
  it recomputes the tile's hidden activations (kept in one shared tile), then walks the layers back,
  adding the tile's weight and bias gradients into the block's own row of a `[blocks, parameters]`
  buffer (read, add, write back), and writes the input gradient only when the input requires one;
  torch sums the rows afterwards. One row per block instead of one per tile keeps that buffer small
  (a few MB on a GPU); the atomics touch addresses no other block touches (no contention), and as
  each element's additions come from one thread in program order, the sum does not depend on
  scheduling: the gradients are deterministic on the CPU and, by construction, on a GPU.

The first layer reads its input in column chunks of at most `INPUT_CHUNK`, so any input width fits
shared memory (its weight is stored chunk by chunk, zero-padded, in the flat vector for that).
Hidden and output widths up to `MAX_WIDTH`; activations tanh, relu and elu (alpha 1), whose
derivatives are taken from the activation's output. Rows past the end of the input read as zero:
they add nothing to the gradients, and their outputs are not stored.

CUDA graphs: Warp allocates nothing here (outputs and scratch are torch tensors, shared zero-copy
with `wp.from_torch`), launches on torch's current stream and reads nothing back, so a forward or
backward inside `torch.cuda.graph` is captured. A capture cannot load a kernel module, so each
kernel is loaded at its first, eager, call (`FusedMLPFunction` refuses a first call in a capture).

Shared memory: compiled ahead of time for sm_90 (`wp.compile_aot_module`, no GPU at hand), the
default actor (29-64-64-9, 64-row tiles) takes 125,744 bytes in the backward kernel and 69,168 in the
forward (`MLPSpec.shared_bytes` estimates 133,156): one backward block per H100/H200 multiprocessor.
Smaller `TILE_ROWS` trade that occupancy against per-tile overhead (not measured). Speed, measured on one
H100 (benchmarks/results/fused_update_h100_5b61039/): the PPO update with these kernels takes 3.2x torch's
at 65,536 worlds and 2.1x at 1,024, which is why `train.fused_mlp` is off by default (the Triton
backend is not measured yet).

Arithmetic: float32, with Warp's matrix products and sums in their own order, so the results equal
torch's within float32 rounding, not bit for bit (tests/training/test_fused_mlp.py states the
measured errors). Autocast, other dtypes, TorchScript and ONNX export take the plain torch path.
"""

# (No `from __future__ import annotations`: TorchScript must resolve FusedMLP's annotations as objects.)
import functools
import math
import typing
from dataclasses import dataclass

import torch
import torch.nn as nn
import warp as wp
from rsl_rl.models import MLPModel
from rsl_rl.modules import MLP

from . import _rsl  # noqa: F401
from .config import FUSED_BACKENDS

TILE_ROWS = (64, 32, 16)  # rows per tile: the most whose tiles fit SHARED_BUDGET (MLPSpec.rows)
SHARED_BUDGET = 200 * 1024  # bytes of a block's shared memory for its tiles (H100/H200: 227 KB a block)
BLOCK_DIM = 128  # CUDA threads per block (the CPU runs a block on one thread)
INPUT_CHUNK = 64  # input columns the first layer reads at once
MAX_WIDTH = 128  # widest hidden or output layer
BLOCKS_PER_SM = 4  # blocks per multiprocessor: enough resident warps to hide latency
CPU_BLOCKS = 4  # the CPU runs blocks one after another; a few exercise the partial sums
ACTIVATIONS = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu"}


@wp.func
def _tanh(x: float) -> float:
    return wp.tanh(x)


@wp.func
def _tanh_slope(y: float) -> float:
    return 1.0 - y * y


@wp.func
def _relu(x: float) -> float:
    return wp.max(x, 0.0)


@wp.func
def _relu_slope(y: float) -> float:
    return wp.where(y > 0.0, 1.0, 0.0)  # as torch's: the gradient passes where the output is > 0


@wp.func
def _elu(x: float) -> float:
    return wp.where(x > 0.0, x, wp.exp(x) - 1.0)


@wp.func
def _elu_slope(y: float) -> float:
    return wp.where(y > 0.0, 1.0, y + 1.0)  # exp(x) = y + 1 where x <= 0


# activation name -> (the activation, its derivative as a function of its output)
_ACTIVATION_FUNCS = {"tanh": (_tanh, _tanh_slope), "relu": (_relu, _relu_slope), "elu": (_elu, _elu_slope)}


@dataclass(frozen=True)
class MLPSpec:
    """An MLP's architecture as the kernels see it: the layer widths `dims` (input, hidden...,
    output) and the activation's name; and the layout of its flat parameter vector."""

    dims: tuple[int, ...]
    activation: str

    @property
    def layers(self) -> int:
        return len(self.dims) - 1

    @property
    def chunk(self) -> int:
        """Input columns per chunk of the first layer (the whole input where it fits one)."""
        return min(self.dims[0], INPUT_CHUNK)

    @property
    def chunks(self) -> int:
        return math.ceil(self.dims[0] / self.chunk)

    @property
    def offsets(self) -> tuple[tuple[int, int], ...]:
        """Per layer, where its weight and its bias start in the flat vector. The first weight is
        stored as `[chunks, out, chunk]` (columns zero-padded to whole chunks), the others `[out, in]`."""
        result, offset = [], 0
        for layer in range(self.layers):
            n_in = self.chunks * self.chunk if layer == 0 else self.dims[layer]
            n_out = self.dims[layer + 1]
            result.append((offset, offset + n_out * n_in))
            offset += n_out * n_in + n_out
        return tuple(result)

    @property
    def resident_start(self) -> int:
        """Start of the part of the flat vector that the kernels keep in shared memory: all of it,
        unless the first weight is read in several chunks (then from the first bias on)."""
        return 0 if self.chunks == 1 else self.offsets[0][1]

    @property
    def size(self) -> int:
        """Length of the flat parameter vector."""
        return self.offsets[-1][1] + self.dims[-1]

    def shared_bytes(self, rows: int) -> int:
        """The shared memory the backward kernel's tiles take with `rows` rows per tile (the forward
        takes less): the resident parameters, the hidden activations and output gradients of a row
        tile, one weight gradient, two input chunks and the input gradient's chunk."""
        hidden, dims = sum(self.dims[1:-1]), self.dims
        scratch = max(dims[1] * self.chunk, *(dims[l + 1] * dims[l] for l in range(1, self.layers)))
        return 4 * (self.size - self.resident_start + rows * (2 * hidden + dims[-1] + 3 * self.chunk) + scratch)

    @property
    def rows(self) -> int:
        """Rows per tile: the most of `TILE_ROWS` that fit `SHARED_BUDGET` (0: none fits)."""
        return next((rows for rows in TILE_ROWS if self.shared_bytes(rows) <= SHARED_BUDGET), 0)

    def flat(self, params: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """The flat vector of `params` (`weight0, bias0, weight1, ...`, torch's `[out, in]` weights)."""
        padded = nn.functional.pad(params[0], (0, self.chunks * self.chunk - self.dims[0]))
        parts = [padded.view(self.dims[1], self.chunks, self.chunk).transpose(0, 1).reshape(-1)]
        parts += [p.reshape(-1) for p in params[1:]]
        return torch.cat(parts)

    def unflat(self, vector: torch.Tensor) -> list[torch.Tensor]:
        """`[weight0, bias0, weight1, ...]` of a flat vector (the inverse of `flat`)."""
        out: list[torch.Tensor] = []
        for layer, (w, b) in enumerate(self.offsets):
            n_out = self.dims[layer + 1]
            if layer == 0:
                chunked = vector[w:b].view(self.chunks, n_out, self.chunk).transpose(0, 1)
                out.append(chunked.reshape(n_out, self.chunks * self.chunk)[:, : self.dims[0]])
            else:
                out.append(vector[w:b].view(n_out, self.dims[layer]))
            out.append(vector[b : b + n_out])
        return out


@functools.cache
def mlp_kernel(spec: MLPSpec, backward_pass: bool, input_grad: bool = False) -> wp.Kernel:
    """The forward (`backward_pass=False`) or backward tile kernel of `spec`; the backward writes the
    input gradient only with `input_grad`. Both share one argument list and one body (the backward
    recomputes the forward), specialised at compile time: every tile shape is a constant, and the
    loops over layers unroll.

    Warp reserves shared memory for every tile expression, live or not, so the body writes into
    views of a few tiles made once per block instead of making new ones: `weights` (the resident
    parameters), `hidden` (the activations of a row tile, layer by layer side by side), `grads` (the
    gradients of every layer's output, likewise) and `scratch` (one weight gradient at a time)."""
    L, dims, R, K = spec.layers, spec.dims, spec.rows, spec.chunk
    C, H1, size, start = spec.chunks, dims[1], spec.size, spec.resident_start
    weight_at = [w for w, _ in spec.offsets]  # where each layer's weight and bias start in the flat
    bias_at = [b for _, b in spec.offsets]  # vector (minus `start` in the resident tile)
    activate, slope = _ACTIVATION_FUNCS[spec.activation]
    # Column of layer l's output (l = 1 .. L) in `hidden` (hidden layers) and `grads` (all).
    column = [0, 0] + [sum(dims[1:l]) for l in range(2, L + 1)]
    hidden_width = max(1, sum(dims[1:L]))
    scratch_size = max(dims[1] * K, *(dims[l + 1] * dims[l] for l in range(1, L)))

    @wp.func
    def add_and_activate(z: float, b: float) -> float:
        return activate(z + b)

    @wp.func
    def times_slope(g: float, y: float) -> float:
        return g * slope(y)

    @typing.no_type_check  # Warp's kernel language, which mypy reads as Python and misjudges
    def kernel(
        x: wp.array2d[float],
        params: wp.array[float],
        grad_out: wp.array2d[float],
        chunks: int,
        tiles: int,
        blocks: int,
        out: wp.array2d[float],
        partial: wp.array[float],
        grad_x: wp.array2d[float],
    ):
        block = wp.tid()
        # The parameters stay in shared memory for all the block's row tiles (all but a first-layer
        # weight of several input chunks, which is read chunk by chunk).
        weights = wp.tile_load(params, shape=wp.static(size - start), offset=start, storage="shared")
        hidden = wp.tile_zeros(shape=(R, hidden_width), dtype=float, storage="shared")
        if wp.static(backward_pass):
            grads = wp.tile_zeros(shape=(R, wp.static(column[L] + dims[L])), dtype=float, storage="shared")
            scratch = wp.tile_zeros(shape=scratch_size, dtype=float, storage="shared")
        for tile in range(block, tiles, blocks):
            row = tile * R
            # First layer, input chunk by chunk, summed into layer 1's columns of `hidden` (`chunks`
            # is a launch argument so that this stays a loop: unrolled, every chunk's tiles would
            # take shared memory of their own).
            h = wp.tile_view(hidden, offset=(0, 0), shape=(R, H1))
            wp.tile_assign(h, wp.tile_zeros(shape=(R, H1), dtype=float))
            for c in range(chunks):
                xc = wp.tile_load(x, shape=(R, K), offset=(row, c * K), storage="shared")
                if wp.static(C == 1):
                    wc = wp.tile_view(weights, offset=(0,), shape=(wp.static(H1 * K),))
                else:
                    wc = wp.tile_load(params, shape=wp.static(H1 * K), offset=c * wp.static(H1 * K), storage="shared")
                wp.tile_matmul(xc, wp.tile_transpose(wp.tile_reshape(wc, shape=(H1, K))), h)
            b = wp.tile_view(weights, offset=(wp.static(bias_at[0] - start),), shape=(H1,))
            wp.tile_assign(h, wp.tile_map(add_and_activate, h, wp.tile_broadcast(b, shape=(R, H1))))
            # The other hidden layers, each into its columns of `hidden`.
            for l in range(1, wp.static(L - 1)):
                a = wp.tile_view(hidden, offset=(0, wp.static(column[l])), shape=(R, wp.static(dims[l])))
                w = wp.tile_view(
                    weights, offset=(wp.static(weight_at[l] - start),), shape=(wp.static(dims[l + 1] * dims[l]),)
                )
                w = wp.tile_reshape(w, shape=(wp.static(dims[l + 1]), wp.static(dims[l])))
                b = wp.tile_view(weights, offset=(wp.static(bias_at[l] - start),), shape=(wp.static(dims[l + 1]),))
                h = wp.tile_view(hidden, offset=(0, wp.static(column[l + 1])), shape=(R, wp.static(dims[l + 1])))
                wp.tile_matmul(a, wp.tile_transpose(w), h, beta=0.0)
                wp.tile_assign(
                    h, wp.tile_map(add_and_activate, h, wp.tile_broadcast(b, shape=(R, wp.static(dims[l + 1]))))
                )
            if wp.static(not backward_pass):  # the output layer (the backward needs only its gradient)
                a = wp.tile_view(hidden, offset=(0, wp.static(column[L - 1])), shape=(R, wp.static(dims[L - 1])))
                w = wp.tile_view(
                    weights, offset=(wp.static(weight_at[L - 1] - start),), shape=(wp.static(dims[L] * dims[L - 1]),)
                )
                w = wp.tile_reshape(w, shape=(wp.static(dims[L]), wp.static(dims[L - 1])))
                b = wp.tile_view(weights, offset=(wp.static(bias_at[L - 1] - start),), shape=(wp.static(dims[L]),))
                y = wp.tile_matmul(a, wp.tile_transpose(w)) + wp.tile_broadcast(b, shape=(R, wp.static(dims[L])))
                wp.tile_store(out, y, offset=(row, 0))
            else:
                # Backward, last layer first; `g` is the gradient of a layer's output (before its
                # activation). Each weight and bias gradient of the tile is added to this block's
                # row of `partial` (read, add, write: every element by the same thread each time).
                mine = block * size
                g = wp.tile_view(grads, offset=(0, wp.static(column[L])), shape=(R, wp.static(dims[L])))
                wp.tile_assign(g, wp.tile_load(grad_out, shape=(R, wp.static(dims[L])), offset=(row, 0)))
                # (Views are made afresh, never assigned from one name to another: Warp would copy
                # the view into a tile of another layout.)
                for l in range(wp.static(L - 1), 0, -1):
                    n = wp.static(dims[l + 1] * dims[l])
                    g_out = wp.tile_view(grads, offset=(0, wp.static(column[l + 1])), shape=(R, wp.static(dims[l + 1])))
                    a_in = wp.tile_view(hidden, offset=(0, wp.static(column[l])), shape=(R, wp.static(dims[l])))
                    dw = wp.tile_view(scratch, offset=(0,), shape=(n,))
                    wp.tile_matmul(
                        wp.tile_transpose(g_out),
                        a_in,
                        wp.tile_reshape(dw, shape=(wp.static(dims[l + 1]), wp.static(dims[l]))),
                        beta=0.0,
                    )
                    at = mine + wp.static(weight_at[l])
                    wp.tile_store(partial, wp.tile_load(partial, shape=n, offset=at) + dw, offset=at)
                    at = mine + wp.static(bias_at[l])
                    db = wp.tile_load(partial, shape=wp.static(dims[l + 1]), offset=at) + wp.tile_sum(g_out, axis=0)
                    wp.tile_store(partial, db, offset=at)
                    w = wp.tile_view(weights, offset=(wp.static(weight_at[l] - start),), shape=(n,))
                    g_in = wp.tile_view(grads, offset=(0, wp.static(column[l])), shape=(R, wp.static(dims[l])))
                    wp.tile_matmul(
                        g_out, wp.tile_reshape(w, shape=(wp.static(dims[l + 1]), wp.static(dims[l]))), g_in, beta=0.0
                    )
                    wp.tile_assign(g_in, wp.tile_map(times_slope, g_in, a_in))
                g1 = wp.tile_view(grads, offset=(0, 0), shape=(R, H1))
                at = mine + wp.static(bias_at[0])
                wp.tile_store(partial, wp.tile_load(partial, shape=H1, offset=at) + wp.tile_sum(g1, axis=0), offset=at)
                for c in range(chunks):
                    xc = wp.tile_load(x, shape=(R, K), offset=(row, c * K), storage="shared")
                    dw0 = wp.tile_view(scratch, offset=(0,), shape=(wp.static(H1 * K),))
                    wp.tile_matmul(wp.tile_transpose(g1), xc, wp.tile_reshape(dw0, shape=(H1, K)), beta=0.0)
                    at = mine + c * wp.static(H1 * K)
                    wp.tile_store(partial, wp.tile_load(partial, shape=wp.static(H1 * K), offset=at) + dw0, offset=at)
                    if wp.static(input_grad):
                        if wp.static(C == 1):
                            wc = wp.tile_view(weights, offset=(0,), shape=(wp.static(H1 * K),))
                        else:
                            wc = wp.tile_load(
                                params, shape=wp.static(H1 * K), offset=c * wp.static(H1 * K), storage="shared"
                            )
                        gx = wp.tile_matmul(g1, wp.tile_reshape(wc, shape=(H1, K)))
                        wp.tile_store(grad_x, gx, offset=(row, c * K))

    # The backward is ours: Warp's adjoints would only cost compile time.
    return wp.kernel(kernel, module="unique", module_options={"enable_backward": False})


def launch_blocks(device: torch.device, tiles: int) -> int:
    """Blocks of a launch over `tiles` row tiles: a few per multiprocessor on CUDA (each block loads
    the parameters once, then takes every `blocks`-th tile)."""
    if device.type == "cuda":
        return min(tiles, BLOCKS_PER_SM * torch.cuda.get_device_properties(device).multi_processor_count)
    return min(tiles, CPU_BLOCKS)


class _Launcher:
    """Launches on torch's current stream (one Warp stream per torch stream, as making one costs host
    time), loading each kernel's module at its first use, which must be eager."""

    def __init__(self) -> None:
        self._streams: dict[int, wp.Stream] = {}
        self._loaded: set[tuple[str, str]] = set()

    def __call__(self, kernel: wp.Kernel, blocks: int, inputs: list, device: torch.device) -> None:
        """Launch `blocks` blocks of `kernel` on `inputs` (torch tensors are shared zero-copy)."""
        wp.init()
        wp_device = wp.device_from_torch(device)
        key = (kernel.key, str(wp_device))
        if key not in self._loaded:
            if device.type == "cuda" and torch.cuda.is_current_stream_capturing():
                raise RuntimeError(
                    "FusedMLP: run the model once eagerly (forward and backward) before a CUDA graph capture"
                )
            wp.load_module(kernel.module, device=wp_device, block_dim=BLOCK_DIM)
            self._loaded.add(key)
        stream = None
        if device.type == "cuda":
            current = torch.cuda.current_stream(device)
            stream = self._streams.get(current.cuda_stream)
            if stream is None:
                stream = self._streams[current.cuda_stream] = wp.stream_from_torch(current)
        arrays = [wp.from_torch(a, requires_grad=False) if isinstance(a, torch.Tensor) else a for a in inputs]
        wp.launch_tiled(kernel, dim=blocks, inputs=arrays, block_dim=BLOCK_DIM, device=wp_device, stream=stream)


_launch = _Launcher()


class FusedMLPFunction(torch.autograd.Function):
    """`apply(spec, x, weight0, bias0, weight1, ...)`: the MLP `spec` of `x` `[N, in]` (float32,
    contiguous) with torch's `nn.Linear` parameters; saves only `x` and the parameters for its backward."""

    @staticmethod
    def forward(ctx, spec: MLPSpec, x: torch.Tensor, *params: torch.Tensor) -> torch.Tensor:
        ctx.spec = spec
        ctx.save_for_backward(x, *params)
        out = torch.empty(x.shape[0], spec.dims[-1], dtype=x.dtype, device=x.device)
        _run(mlp_kernel(spec, backward_pass=False), spec, x, params, out=out)
        return out

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x, *params = ctx.saved_tensors
        spec: MLPSpec = ctx.spec
        input_grad = bool(ctx.needs_input_grad[1])
        blocks = launch_blocks(x.device, math.ceil(x.shape[0] / spec.rows))
        partial = torch.zeros(blocks, spec.size, dtype=x.dtype, device=x.device)
        grad_x = torch.empty_like(x) if input_grad else None
        kernel = mlp_kernel(spec, backward_pass=True, input_grad=input_grad)
        _run(kernel, spec, x, tuple(params), grad_out=grad_out.contiguous(), partial=partial, grad_x=grad_x)
        return (None, grad_x, *spec.unflat(partial.sum(dim=0)))


def _run(
    kernel: wp.Kernel,
    spec: MLPSpec,
    x: torch.Tensor,
    params: tuple[torch.Tensor, ...],
    grad_out: torch.Tensor | None = None,
    out: torch.Tensor | None = None,
    partial: torch.Tensor | None = None,
    grad_x: torch.Tensor | None = None,
) -> None:
    """One launch of `kernel` over the rows of `x` (absent outputs: empty tensors)."""
    tiles = math.ceil(x.shape[0] / spec.rows)
    blocks = launch_blocks(x.device, tiles) if partial is None else partial.shape[0]
    unused = torch.empty(0, dtype=x.dtype, device=x.device)
    inputs = [
        x,
        spec.flat(params),
        unused.view(0, 1) if grad_out is None else grad_out,
        spec.chunks,
        tiles,
        blocks,
        unused.view(0, 1) if out is None else out,
        unused if partial is None else partial.view(-1),
        unused.view(0, 1) if grad_x is None else grad_x,
    ]
    _launch(kernel, blocks, inputs, x.device)


def mlp_spec(mlp: nn.Sequential, backend: str) -> MLPSpec:
    """The `MLPSpec` of an rsl-rl `MLP` (Linear, activation, ..., Linear); a one-line ValueError
    names what the fused kernels of `backend` do not cover."""
    modules = list(mlp)
    linears = [m for m in modules[0::2] if isinstance(m, nn.Linear)]
    activations = modules[1::2]
    if len(modules) < 3 or len(modules) % 2 == 0 or len(linears) != len(modules[0::2]):
        raise ValueError(
            f"fused MLP: expected Linear, activation, ..., Linear modules, got {[type(m).__name__ for m in modules]}"
        )
    kinds = {type(m) for m in activations}
    if len(kinds) != 1 or next(iter(kinds)) not in ACTIVATIONS:
        raise ValueError(
            f"fused MLP: activation {sorted(k.__name__ for k in kinds)} is not supported; use tanh, relu or elu"
        )
    if any(isinstance(m, nn.ELU) and m.alpha != 1.0 for m in activations):
        raise ValueError("fused MLP: elu must have alpha 1.0")
    dims = (linears[0].in_features,) + tuple(m.out_features for m in linears)
    if any(not 1 <= d <= MAX_WIDTH for d in dims[1:]):
        raise ValueError(f"fused MLP: layer widths {list(dims[1:])} must be in [1, {MAX_WIDTH}]")
    spec = MLPSpec(dims, ACTIVATIONS[next(iter(kinds))])
    if backend == "triton":
        from .triton_mlp import check_spec  # (an optional dependency, whose module imports this one)

        check_spec(spec)
    elif not spec.rows:
        raise ValueError(
            f"fused MLP: layers {list(dims)} need {spec.shared_bytes(TILE_ROWS[-1])} bytes of shared memory "
            f"at {TILE_ROWS[-1]} rows per tile, over the {SHARED_BUDGET} a block has here"
        )
    return spec


@functools.cache
def backend_function(backend: str) -> tuple[type[torch.autograd.Function], tuple[str, ...]]:
    """The autograd function of `backend` ("warp": `FusedMLPFunction`; "triton":
    `triton_mlp.TritonMLPFunction`) and the device types whose tensors it takes."""
    if backend == "warp":
        return FusedMLPFunction, ("cpu", "cuda")
    from .triton_mlp import DEVICES, TritonMLPFunction  # (an optional dependency, whose module imports this one)

    return TritonMLPFunction, DEVICES


class FusedMLP(MLP):
    """An rsl-rl `MLP` (the same modules, adopted from `mlp`, so the same parameters and state_dict
    keys) whose forward runs the fused kernels of `backend` (one of `FUSED_BACKENDS`) where they serve:
    float32 on a device of the backend's (Warp: the CPU or CUDA; Triton: CUDA, or the CPU under
    Triton's interpreter), outside autocast, TorchScript, tracing and export; elsewhere the modules
    one after another."""

    def __init__(self, mlp: MLP, backend: str) -> None:
        if backend not in FUSED_BACKENDS:
            raise ValueError(f"FusedMLP: backend={backend!r} must be one of {list(FUSED_BACKENDS)}")
        nn.Sequential.__init__(self, *mlp)  # not MLP.__init__: no new layers, no random draws
        self.backend = backend
        self.spec = mlp_spec(self, backend)

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
            and x.device.type in backend_function(self.backend)[1]
            and self[0].weight.dtype == torch.float32
            and not torch.is_autocast_enabled(x.device.type)
            and not torch.jit.is_tracing()
            and not torch.compiler.is_compiling()
            and not torch.compiler.is_exporting()
        )

    @torch.jit.unused
    def _fused(self, x: torch.Tensor) -> torch.Tensor:
        # The kernels read columns past a narrower input as zeros: refuse it, as nn.Linear does.
        if x.shape[-1] != self.spec.dims[0]:
            raise ValueError(f"FusedMLP: input of {x.shape[-1]} features, the first layer takes {self.spec.dims[0]}")
        rows = x.reshape(-1, x.shape[-1]).contiguous()
        params = [p for layer in list(self)[0::2] for p in (layer.weight, layer.bias)]
        out = backend_function(self.backend)[0].apply(self.spec, rows, *params)
        return out.reshape(*x.shape[:-1], out.shape[-1])


class FusedMLPModel(MLPModel):
    """rsl-rl's `MLPModel` with a `FusedMLP` of `backend` (see the module doc); its other arguments
    are `MLPModel`'s."""

    mlp: MLP  # declared: rsl-rl's class sets it in __init__, where type inference does not follow

    def __init__(self, *args, backend: str, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.mlp = FusedMLP(self.mlp, backend)
