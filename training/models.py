"""Individual Learning: one set of network parameters per agent slot, computed as ONE batched network.

`IndividualMLPModel` is an rsl-rl `MLPModel` whose MLP is a `BatchedMLP`: every layer holds a weight
tensor `[S, in, out]` (S = agent slots of the learning team) and runs as one `baddbmm` over the slot
dimension, so the S networks cost one kernel per layer and no Python loop over agents. Plug it in as
the actor's and the critic's `class_name` ("aquarium_warp.training.models:IndividualMLPModel") with
`num_agents=S`.

Row layout. The model needs no agent id: it relies on the adapter's world-major row order (row
`w * S + s` is slot `s` of world `w`), so any batch whose size is a multiple of S and that holds whole
worlds in slot order maps row `k` to network `k % S`. Rollout batches have this layout; for the PPO
update, `AquariumPPO(minibatch_group_size=S)` shuffles whole (step, world) groups instead of single
rows, which keeps it (and gives every slot's network the same number of samples per mini-batch).
Exported policies keep the same contract: observations `[W * S, L]` in world-major slot order.

The observation normaliser (if enabled) stays shared across slots.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn as nn
from rsl_rl.models import MLPModel
from rsl_rl.utils import resolve_nn_activation
from tensordict import TensorDict

from . import _rsl  # noqa: F401

# Rows per product in the weight gradient (see `_BatchedLinearFunction`).
WEIGHT_GRAD_CHUNK = 512


class _BatchedLinearFunction(torch.autograd.Function):
    """`baddbmm(bias, x, weight)` whose weight gradient is summed over chunks of rows. The plain
    gradient `x^T @ grad` is one product per slot with a long reduction (all G rows) and a tiny
    output, which cuBLAS runs on a handful of thread blocks (the H200 spent half of an IL update
    there); chunks of `WEIGHT_GRAD_CHUNK` rows give it S x G / 512 products to spread, then a sum."""

    @staticmethod
    def forward(ctx, x, weight, bias):
        ctx.save_for_backward(x, weight)
        return torch.baddbmm(bias.unsqueeze(1), x, weight)

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        S, G, n_in = x.shape
        n_out = grad.shape[-1]
        grad_x = torch.bmm(grad, weight.transpose(1, 2))
        chunks = G // WEIGHT_GRAD_CHUNK if G % WEIGHT_GRAD_CHUNK == 0 and G > WEIGHT_GRAD_CHUNK else 1
        rows = G // chunks
        grad_weight = (
            torch.bmm(x.reshape(S * chunks, rows, n_in).transpose(1, 2), grad.reshape(S * chunks, rows, n_out))
            .view(S, chunks, n_in, n_out)
            .sum(dim=1)
        )
        return grad_x, grad_weight, grad.sum(dim=1)


class BatchedLinear(nn.Module):
    """S independent linear layers: `weight [S, in, out]`, `bias [S, out]`, applied to `x [S, G, in]`.

    Initialised slot by slot like `nn.Linear` (uniform in +-1/sqrt(in) for weight and bias)."""

    def __init__(self, groups: int, in_features: int, out_features: int) -> None:
        super().__init__()
        self.groups, self.in_features, self.out_features = groups, in_features, out_features
        self.weight = nn.Parameter(torch.empty(groups, in_features, out_features))
        self.bias = nn.Parameter(torch.empty(groups, out_features))
        bound = 1.0 / math.sqrt(in_features) if in_features > 0 else 0.0
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if torch.jit.is_scripting() or not torch.is_grad_enabled():
            return torch.baddbmm(self.bias.unsqueeze(1), x, self.weight)
        return self._forward_with_chunked_backward(x)

    @torch.jit.unused
    def _forward_with_chunked_backward(self, x: torch.Tensor) -> torch.Tensor:
        return _BatchedLinearFunction.apply(x, self.weight, self.bias)

    def extra_repr(self) -> str:
        return f"groups={self.groups}, in_features={self.in_features}, out_features={self.out_features}"


class BatchedMLP(nn.Module):
    """S MLPs of identical shape evaluated at once. Input `[B, L]` with `B = G * S` rows in world-major
    slot order (row `k` uses network `k % S`); output `[B, out]` (or `[B, *out]` for a shaped output)."""

    spec: Any = None  # the fused kernels' `MLPSpec` of it, where `fused_mlp.FusedIndividualMLPModel` set one
    __jit_ignored_attributes__ = ["spec"]  # (TorchScript types no `Any` attribute: exports leave it out)

    def __init__(self, groups: int, input_dim: int, output_dim, hidden_dims, activation: str = "elu") -> None:
        super().__init__()
        if isinstance(groups, bool) or not isinstance(groups, int) or groups < 1:
            raise ValueError(f"num_agents={groups!r} must be an integer >= 1")
        self.groups = groups
        self.input_dim = input_dim
        hidden = [input_dim if d == -1 else int(d) for d in hidden_dims]
        self.output_shape = [int(output_dim)] if isinstance(output_dim, int) else [int(d) for d in output_dim]
        out_total = 1
        for d in self.output_shape:
            out_total *= d
        dims = [input_dim] + hidden + [out_total]
        self.layers = nn.ModuleList([BatchedLinear(groups, a, b) for a, b in zip(dims[:-1], dims[1:])])
        self.activation = resolve_nn_activation(activation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        rows = x.shape[0]
        if rows % self.groups != 0:
            raise ValueError(
                f"Individual-Learning model: batch of {rows} rows is not a multiple of the "
                f"{self.groups} agent slots (rows must be whole worlds in slot order)"
            )
        h = x.reshape(rows // self.groups, self.groups, x.shape[-1]).transpose(0, 1)  # [S, G, L]
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            h = layer(h)
            if i < last:
                h = self.activation(h)
        out = h.transpose(0, 1).reshape([rows] + self.output_shape)
        return out


class GroupedMLPModel(MLPModel):
    """rsl-rl `MLPModel` whose MLP is several networks of one shape evaluated at once: `make_mlp(groups,
    input_dim, head, hidden_dims, activation)` builds it (Individual Learning's `BatchedMLP`, a
    population's `StackedMLP`), their number given by the keyword argument `GROUPS_ARGUMENT`. Everything
    else (observation groups, normalisation, distribution, export) is `MLPModel`'s."""

    GROUPS_ARGUMENT = "groups"

    def __init__(
        self,
        obs: TensorDict,
        obs_groups: dict[str, list[str]],
        obs_set: str,
        output_dim: int,
        hidden_dims=(256, 256, 256),
        activation: str = "elu",
        obs_normalization: bool = False,
        distribution_cfg: dict | None = None,
        **groups: int,
    ) -> None:
        unknown = sorted(set(groups) - {self.GROUPS_ARGUMENT})
        if unknown:
            raise TypeError(f"{type(self).__name__} takes no argument {unknown[0]!r}")
        super().__init__(
            obs,
            obs_groups,
            obs_set,
            output_dim,
            hidden_dims=hidden_dims,
            activation=activation,
            obs_normalization=obs_normalization,
            distribution_cfg=distribution_cfg,
        )
        count = groups.get(self.GROUPS_ARGUMENT, 1)
        setattr(self, self.GROUPS_ARGUMENT, count)
        head = self.distribution.input_dim if self.distribution is not None else output_dim
        # Replaces the shared MLP that MLPModel built (its parameters are discarded).
        self.mlp = self.make_mlp(count, self._get_latent_dim(), head, hidden_dims, activation)

    def make_mlp(self, groups: int, input_dim: int, head: int, hidden_dims, activation: str) -> nn.Module:
        raise NotImplementedError


class IndividualMLPModel(GroupedMLPModel):
    """rsl-rl `MLPModel` with separate parameters per agent slot (Individual Learning); see the module doc.

    Extra argument: `num_agents` (S, the learning team's slots per world)."""

    GROUPS_ARGUMENT = "num_agents"
    num_agents: int

    def make_mlp(self, groups: int, input_dim: int, head: int, hidden_dims, activation: str) -> nn.Module:
        mlp = BatchedMLP(groups, input_dim, head, hidden_dims, activation)
        if self.distribution is not None:
            self.distribution.init_mlp_weights(mlp)
        return mlp


def hidden_state_to(hidden, device):
    """A copy of an rsl-rl `HiddenState` (None, a GRU tensor or an LSTM `(h, c)` tuple) on `device`,
    detached: checkpoints store it on the CPU and the trainer restores it onto its device."""
    if hidden is None:
        return None
    if isinstance(hidden, (tuple, list)):
        return tuple(h.detach().to(device, copy=True) for h in hidden)
    return hidden.detach().to(device, copy=True)


class StackedMLP(nn.Module):
    """The MLPs of K runs (a population, `population.py`) evaluated at once. Layer `l` holds weights
    `[K, out, in]` and biases `[K, out]`: network k's slices are an `nn.Linear`'s own parameters, so
    each run's rsl-rl `MLP` can view them (`population.share_parameters`). Input `[B, L]` with
    `B = K * R` rows in run-major order (rows `[k * R, (k + 1) * R)` are run k's); one batched
    product per layer (`baddbmm`)."""

    spec: Any = None  # the fused kernels' `MLPSpec` of it, where a fused model set one
    __jit_ignored_attributes__ = ["spec"]

    def __init__(self, runs: int, input_dim: int, output_dim, hidden_dims, activation: str = "elu") -> None:
        super().__init__()
        if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
            raise ValueError(f"runs={runs!r} must be an integer >= 1")
        self.runs = runs
        hidden = [input_dim if d == -1 else int(d) for d in hidden_dims]
        self.output_shape = [int(output_dim)] if isinstance(output_dim, int) else [int(d) for d in output_dim]
        dims = [input_dim, *hidden, math.prod(self.output_shape)]
        # Values come from the runs' own networks (`share_parameters`); zeros until then.
        self.weights = nn.ParameterList([nn.Parameter(torch.zeros(runs, b, a)) for a, b in zip(dims[:-1], dims[1:])])
        self.biases = nn.ParameterList([nn.Parameter(torch.zeros(runs, b)) for b in dims[1:]])
        self.activation = resolve_nn_activation(activation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        rows = x.shape[0]
        if rows % self.runs != 0:
            raise ValueError(f"population model: a batch of {rows} rows is not {self.runs} runs' equal shares")
        h = x.reshape(self.runs, rows // self.runs, x.shape[-1])
        last = len(self.weights) - 1
        chunked = torch.is_grad_enabled() and not torch.jit.is_scripting()
        for i, (weight, bias) in enumerate(zip(self.weights, self.biases)):
            if chunked:  # the weight gradient summed over chunks of rows, as Individual Learning's layers
                h = _BatchedLinearFunction.apply(h, weight.transpose(1, 2), bias)
            else:
                h = torch.baddbmm(bias.unsqueeze(1), h, weight.transpose(1, 2))
            if i < last:
                h = self.activation(h)
        return h.reshape([rows] + self.output_shape)

    def layer_parameters(self) -> list[torch.Tensor]:
        """The parameters in the order the kernels take them: weight0, bias0, weight1, ..."""
        return [p for pair in zip(self.weights, self.biases) for p in pair]


class StackedMLPModel(GroupedMLPModel):
    """rsl-rl `MLPModel` over a `StackedMLP`: the actor or critic of every run of a population (see
    `population.py`). Extra argument `runs` (K). With observation normalisation the population gives it
    the runs' own normalisers (`RunNormalization`)."""

    GROUPS_ARGUMENT = "runs"
    runs: int

    def make_mlp(self, groups: int, input_dim: int, head: int, hidden_dims, activation: str) -> nn.Module:
        return StackedMLP(groups, input_dim, head, hidden_dims, activation)  # values: the runs' own networks


class RunNormalization(nn.Module):
    """The observation normalisers of a population's runs as one module of the stacked model
    (`StackedMLPModel`): each run's own rsl-rl `EmpiricalNormalization` (the run's model's, so its
    checkpoints hold it) on the run's block of rows. `forward(x [K * R, L])` normalises run k's rows
    `[k R, (k + 1) R)` with run k's statistics; `update(x)` takes the rollout flattened step-major
    (`[T * K * n, L]`, `n` rows per run and step) and updates each run's normaliser on its own rows in
    the order its run alone would see them. Each normaliser's tensors stay the same objects (CUDA
    graphs read them), though rsl-rl's update rebinds its `_std`."""

    def __init__(self, normalizers: list[nn.Module], rows: int) -> None:
        super().__init__()
        self.normalizers = nn.ModuleList(normalizers)
        self.rows = rows  # each run's rows per step

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        blocks = x.chunk(len(self.normalizers))
        return torch.cat([normalizer(block) for normalizer, block in zip(self.normalizers, blocks)])

    @torch.jit.unused
    def update(self, x: torch.Tensor) -> None:
        K, n = len(self.normalizers), self.rows
        steps = x.reshape(-1, K, n, x.shape[-1])
        for k, normalizer in enumerate(self.normalizers):
            own: Any = normalizer  # an rsl-rl EmpiricalNormalization
            std = own._std
            own.update(steps[:, k].reshape(-1, x.shape[-1]))
            if own._std is not std:  # rsl-rl rebinds it; graphs hold the old tensor
                std.copy_(own._std)
                own._std = std
