"""PPO's mini-batch loss and its gradients as two Triton kernels: one for the actor, one for the critic.

rsl-rl's mini-batch step (`AquariumPPO._mini_batch_step`) gathers the mini-batch's rows from the
rollout storage, runs the actor (which also draws a sample the loss never reads) and the critic, builds
the clipped surrogate, the value loss and the entropy from some twenty elementwise and reduction
kernels, and back-propagates through all of them. With fused MLPs (`fused_mlp.FusedMLP`) and a
categorical actor, `FusedPPOLoss` computes the same loss and the same gradients in two persistent
kernels that each read only the mini-batch's own rows of the storage (through its indices) and write
one row of partial sums per program:

- actor: per tile of `BLOCK_M` rows, the observations gathered by index, the hidden activations and
  the logits, their log-softmax, the taken action's log-probability, the entropy, the ratio and the
  clipped surrogate; then the gradient of `surrogate_loss - entropy_coef * entropy` with respect to
  the logits, back through the MLP into gradient accumulators held in registers (as
  `fused_mlp._backward_kernel` does).
- critic: the value, the (clipped, `use_clipped_value_loss`) squared error against the return, and
  `value_loss_coef` times its gradient, back through the critic's MLP.

Where torch's `max` (of the two surrogates, of the two value losses) meets a tie it splits the
gradient in halves, and `clamp` passes it at its bounds; the kernels do the same. The sums of the
partial rows (in a fixed order, so the gradients are deterministic) become the parameters' `.grad`,
and the loss means come with them; what follows, the gradient all-reduce of several ranks, the
clipping of the gradient norms and the optimizer step, is rsl-rl's (`AquariumPPO._apply_gradients`).

`FusedPPOLoss.unsupported(alg)` says why a learner cannot use it (it then keeps the autograd path
through the fused MLPs): the kernels cover a `FusedMLPModel` actor with `CategoricalDistribution` and
a `FusedMLPModel` critic of one output, or Individual Learning's `FusedIndividualMLPModel` pair (its
`BatchedMLP`'s networks stacked in each parameter: program `(p, g)` takes network g's rows, those of
slot g of every world, and reads its slice of the `[slots, in, out]` weights), each on one
observation group without normalisation, float32 without autocast, and the fixed learning-rate
schedule (the adaptive one reads the KL divergence of every mini-batch, which these kernels do not
compute).

Unlike the autograd path, no action is sampled during the update: torch's random generator is not
advanced there (a fused run's later draws differ from an unfused one's, as they already did).

The rollout's side of PPO, `FusedAct`: rsl-rl's `PPO.act` runs the actor, its log-softmax, the
sampler, the log-probability and the critic, about a dozen kernels, then `process_env_step` and
`add_transition` copy the step's observations, actions, values, log-probabilities, distribution
parameters, rewards (bootstrapped on time-outs) and dones into the storage one tensor at a time, some
ten kernels more. `FusedAct` draws the sampler's `Exp(1)` noise as `CategoricalDistribution.sample`
does (one torch kernel, the same generator draws), then one kernel (`_act_kernel`) computes both MLPs
per tile of rows and writes every field of the storage's current step once, and the learning team's
int32 actions for the simulation; after the step three elementwise kernels write the rewards,
bootstrapped on time-outs as rsl-rl rounds them, and one copy the dones. The sampled action is
`argmax(p / noise)` as there, with the probabilities from the in-kernel log-softmax of the loss
kernels (Triton's `exp` and `log`, not torch's: the values agree to float32 rounding, the bits need
not, so a fused run's trajectory is its own, as the fused update's already was).
"""

from __future__ import annotations

import torch
import triton
import triton.language as tl

from . import fused_mlp
from .distribution import CategoricalDistribution
from .fused_mlp import (
    NUM_WARPS,
    MLPSpec,
    _backward_tile,
    _constants,
    _group_layers,
    _hidden,
    _layer,
    _layer_pointers,
    _output_layer,
    _partial_row,
    _rows,
    _store_gradients,
    _zero_gradients,
    backward_programs,
    block_rows,
    kernel_precision,
    kernel_view,
)

ACTOR_SUMS = 2  # the actor's partial rows end with the sums of the clipped surrogate and the entropy
CRITIC_SUMS = 1  # the critic's with the sum of the value loss


@triton.jit
def _gather(ptr, samples, valid, COLS: tl.constexpr, COLS_P: tl.constexpr):
    """Rows `samples` of a row-major `[*, COLS]` matrix, zero where not `valid` and in the padding."""
    c = tl.arange(0, COLS_P)
    mask = valid[:, None] & (c[None, :] < COLS)
    return tl.load(ptr + samples[:, None] * COLS + c[None, :], mask=mask, other=0.0)


@triton.jit
def _group_rows(tile, group, n_rows, BLOCK_M: tl.constexpr, GROUPS: tl.constexpr, BLOCKED: tl.constexpr):
    """Network `group`'s rows of tile `tile` and which are valid: interleaved (row `k` is network
    `k % GROUPS`'s: Individual Learning's slots) or, with BLOCKED, in GROUPS equal consecutive blocks
    (a population's runs)."""
    local = tile * BLOCK_M + tl.arange(0, BLOCK_M)
    if BLOCKED:
        per_group = n_rows // GROUPS
        return (group * per_group + local).to(tl.int64), local < per_group
    rows = (local * GROUPS + group).to(tl.int64)
    return rows, rows < n_rows


@triton.jit
def _tile_forward(
    obs_ptr, index_ptr, offset, n_rows, tile, group, w0, b0, w1, b1, w2, b2, w_out, b_out,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    FAST_TANH: tl.constexpr, GROUPS: tl.constexpr, TRANSPOSED: tl.constexpr, BLOCKED: tl.constexpr,
):  # fmt: skip
    """Network `group`'s mini-batch rows of tile `tile`: rows `(tile * BLOCK_M + i) * GROUPS + group`,
    or with BLOCKED (a population's runs) `group * n_rows / GROUPS + tile * BLOCK_M + i` (row r is
    sample `index_ptr[offset + r]` of the flattened storage; one network: every row): which are
    `valid`, their `samples`, the gathered input `x`, the hidden activations and the MLP's output `y`
    (padded)."""
    rows, valid = _group_rows(tile, group, n_rows, BLOCK_M, GROUPS, BLOCKED)
    samples = tl.load(index_ptr + offset + rows, mask=valid, other=0).to(tl.int64)
    x = _gather(obs_ptr, samples, valid, IN, IN_P)
    a1, a2, a3 = _hidden(x, w0, b0, w1, b1, w2, b2, IN, IN_P, H, HIDDEN, ACTIVATION, PRECISION, FAST_TANH, TRANSPOSED)
    return valid, samples, x, a1, a2, a3, _layer(a3, w_out, b_out, H, H, OUT, OUT_P, PRECISION, TRANSPOSED)


@triton.jit
def _max_weights(a, b):
    """The shares of the gradient of `max(a, b)` that go to `a` and to `b`: all to the larger, halves
    at a tie (torch's `maximum`)."""
    to_a = tl.where(a > b, 1.0, tl.where(a == b, 0.5, 0.0))
    return to_a, 1.0 - to_a


@triton.jit(do_not_specialize=["offset", "n_rows"])
def _actor_loss_kernel(
    obs_ptr, index_ptr, offset, n_rows, action_ptr, old_log_prob_ptr, advantage_ptr, advantage_stats_ptr,
    partial_ptr, clip, entropy_coef, inv_rows,
    w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    FAST_TANH: tl.constexpr, SUMS: tl.constexpr, GROUPS: tl.constexpr, TRANSPOSED: tl.constexpr,
    BLOCKED: tl.constexpr, NORMALIZE_ADVANTAGES: tl.constexpr,
):  # fmt: skip
    # Mini-batch row r is sample index_ptr[offset + r] of the flattened storage; program (p, g) takes
    # network g's rows (see `_tile_forward`).
    group = tl.program_id(1)
    if GROUPS > 1:
        w0, b0, w1, b1, w2, b2, w3, b3 = _group_layers(group, w0, b0, w1, b1, w2, b2, w3, b3, IN, H, OUT, HIDDEN)
    d0, e0, d1, e1, d2, e2, d_out, e_out = _zero_gradients(IN_P, H, OUT_P)
    surrogate_sum = tl.zeros((BLOCK_M,), dtype=tl.float32)
    entropy_sum = tl.zeros((BLOCK_M,), dtype=tl.float32)
    w_out, b_out = _output_layer(w1, b1, w2, b2, w3, b3, HIDDEN)
    columns = tl.arange(0, OUT_P)
    category = columns[None, :] < OUT
    if NORMALIZE_ADVANTAGES:  # the mini-batch's mean and std (+ 1e-8), computed beforehand
        advantage_mean = tl.load(advantage_stats_ptr)
        advantage_scale = tl.load(advantage_stats_ptr + 1)
    program = tl.program_id(0)
    for tile in range(program, tl.cdiv(n_rows // GROUPS, BLOCK_M), tl.num_programs(0)):
        valid, samples, x, a1, a2, a3, y = _tile_forward(
            obs_ptr, index_ptr, offset, n_rows, tile, group, w0, b0, w1, b1, w2, b2, w_out, b_out,
            IN, IN_P, H, OUT, OUT_P, HIDDEN, ACTIVATION, PRECISION, BLOCK_M, FAST_TANH, GROUPS, TRANSPOSED,
            BLOCKED,
        )  # fmt: skip
        logits = tl.where(category, y, float("-inf"))
        # log-softmax, as torch's: the logits less their log-sum-exp; probabilities its exp
        top = tl.max(logits, axis=1)
        log_sum = top + tl.log(tl.sum(tl.exp(logits - top[:, None]), axis=1))
        log_probs = logits - log_sum[:, None]
        probs = tl.exp(log_probs)
        plogp = tl.where(category, probs * log_probs, 0.0)
        entropy = -tl.sum(plogp, axis=1)
        action = tl.load(action_ptr + samples, mask=valid, other=0.0).to(tl.int32)
        taken = columns[None, :] == action[:, None]
        log_prob = tl.sum(tl.where(taken, log_probs, 0.0), axis=1)
        advantage = tl.load(advantage_ptr + samples, mask=valid, other=0.0)
        if NORMALIZE_ADVANTAGES:
            advantage = (advantage - advantage_mean) / advantage_scale
        ratio = tl.exp(log_prob - tl.load(old_log_prob_ptr + samples, mask=valid, other=0.0))
        low = 1.0 - clip
        high = 1.0 + clip
        surrogate = -advantage * ratio
        surrogate_clipped = -advantage * tl.minimum(tl.maximum(ratio, low), high)
        surrogate_sum += tl.where(valid, tl.maximum(surrogate, surrogate_clipped), 0.0)
        entropy_sum += tl.where(valid, entropy, 0.0)
        # d loss / d log_prob, through max(surrogate, clipped): the clamp passes within [low, high]
        to_plain, to_clipped = _max_weights(surrogate, surrogate_clipped)
        passes = tl.where((ratio >= low) & (ratio <= high), 1.0, 0.0)
        grad_log_prob = inv_rows * ratio * (-advantage) * (to_plain + to_clipped * passes)
        # d / d logits: log_prob's is onehot - probs; -entropy_coef * entropy's is entropy_coef * p (log p + H)
        grad = grad_log_prob[:, None] * (tl.where(taken, 1.0, 0.0) - probs)
        grad += (entropy_coef * inv_rows) * probs * (log_probs + entropy[:, None])
        grad = tl.where(category & valid[:, None], grad, 0.0)
        d0, e0, d1, e1, d2, e2, d_out, e_out, _ = _backward_tile(
            grad, x, a1, a2, a3, w0, w1, w2, w_out, d0, e0, d1, e1, d2, e2, d_out, e_out,
            IN, IN_P, H, OUT, OUT_P, HIDDEN, ACTIVATION, PRECISION, TRANSPOSED,
        )  # fmt: skip
    row = _partial_row(partial_ptr, program * GROUPS + group, SUMS, IN, H, OUT, HIDDEN)
    row = _store_gradients(row, d0, e0, d1, e1, d2, e2, d_out, e_out, IN, IN_P, H, OUT, OUT_P, HIDDEN, TRANSPOSED)
    tl.store(row, tl.sum(surrogate_sum, axis=0))
    tl.store(row + 1, tl.sum(entropy_sum, axis=0))


@triton.jit(do_not_specialize=["offset", "n_rows"])
def _critic_loss_kernel(
    obs_ptr, index_ptr, offset, n_rows, value_ptr, return_ptr, partial_ptr, clip, value_coef, inv_rows,
    w0, b0, w1, b1, w2, b2, w3, b3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    FAST_TANH: tl.constexpr, SUMS: tl.constexpr, GROUPS: tl.constexpr, TRANSPOSED: tl.constexpr,
    BLOCKED: tl.constexpr, CLIPPED: tl.constexpr,
):  # fmt: skip
    group = tl.program_id(1)  # (as in the actor's kernel)
    if GROUPS > 1:
        w0, b0, w1, b1, w2, b2, w3, b3 = _group_layers(group, w0, b0, w1, b1, w2, b2, w3, b3, IN, H, OUT, HIDDEN)
    d0, e0, d1, e1, d2, e2, d_out, e_out = _zero_gradients(IN_P, H, OUT_P)
    loss_sum = tl.zeros((BLOCK_M,), dtype=tl.float32)
    w_out, b_out = _output_layer(w1, b1, w2, b2, w3, b3, HIDDEN)
    first = tl.arange(0, OUT_P)[None, :] == 0
    program = tl.program_id(0)
    for tile in range(program, tl.cdiv(n_rows // GROUPS, BLOCK_M), tl.num_programs(0)):
        valid, samples, x, a1, a2, a3, y = _tile_forward(
            obs_ptr, index_ptr, offset, n_rows, tile, group, w0, b0, w1, b1, w2, b2, w_out, b_out,
            IN, IN_P, H, OUT, OUT_P, HIDDEN, ACTIVATION, PRECISION, BLOCK_M, FAST_TANH, GROUPS, TRANSPOSED,
            BLOCKED,
        )  # fmt: skip
        value = tl.sum(tl.where(first, y, 0.0), axis=1)
        target = tl.load(return_ptr + samples, mask=valid, other=0.0)
        if CLIPPED:  # rsl-rl's clipped value loss: the larger of the two squared errors
            old = tl.load(value_ptr + samples, mask=valid, other=0.0)
            change = value - old
            clipped = old + tl.minimum(tl.maximum(change, -clip), clip)
            plain_loss = (value - target) * (value - target)
            clipped_loss = (clipped - target) * (clipped - target)
            loss = tl.maximum(plain_loss, clipped_loss)
            to_plain, to_clipped = _max_weights(plain_loss, clipped_loss)
            passes = tl.where((change >= -clip) & (change <= clip), 1.0, 0.0)
            slope = 2.0 * (to_plain * (value - target) + to_clipped * passes * (clipped - target))
        else:
            loss = (target - value) * (target - value)
            slope = 2.0 * (value - target)
        loss_sum += tl.where(valid, loss, 0.0)
        grad = tl.where(first & valid[:, None], (value_coef * inv_rows * slope)[:, None], 0.0)
        d0, e0, d1, e1, d2, e2, d_out, e_out, _ = _backward_tile(
            grad, x, a1, a2, a3, w0, w1, w2, w_out, d0, e0, d1, e1, d2, e2, d_out, e_out,
            IN, IN_P, H, OUT, OUT_P, HIDDEN, ACTIVATION, PRECISION, TRANSPOSED,
        )  # fmt: skip
    row = _partial_row(partial_ptr, program * GROUPS + group, SUMS, IN, H, OUT, HIDDEN)
    row = _store_gradients(row, d0, e0, d1, e1, d2, e2, d_out, e_out, IN, IN_P, H, OUT, OUT_P, HIDDEN, TRANSPOSED)
    tl.store(row, tl.sum(loss_sum, axis=0))


@triton.jit(do_not_specialize=["n_rows"])
def _act_kernel(
    obs_ptr, noise_ptr, n_rows,
    obs_out_ptr, action_out_ptr, value_out_ptr, log_prob_out_ptr, log_probs_out_ptr, env_action_ptr,
    w0, b0, w1, b1, w2, b2, w3, b3,
    cw0, cb0, cw1, cb1, cw2, cb2, cw3, cb3,
    IN: tl.constexpr, IN_P: tl.constexpr, H: tl.constexpr, OUT: tl.constexpr, OUT_P: tl.constexpr,
    HIDDEN: tl.constexpr, ACTIVATION: tl.constexpr, PRECISION: tl.constexpr, BLOCK_M: tl.constexpr,
    FAST_TANH: tl.constexpr, GROUPS: tl.constexpr, TRANSPOSED: tl.constexpr, BLOCKED: tl.constexpr,
    CRITIC_H: tl.constexpr, CRITIC_HIDDEN: tl.constexpr, CRITIC_ACTIVATION: tl.constexpr,
):  # fmt: skip
    # The actor's layers are w<l>, b<l>, the critic's cw<l>, cb<l>; both read the same observations.
    # Program (p, g) takes network g's rows of tile p (`_group_rows`; one network: every row).
    group = tl.program_id(1)
    if GROUPS > 1:
        w0, b0, w1, b1, w2, b2, w3, b3 = _group_layers(group, w0, b0, w1, b1, w2, b2, w3, b3, IN, H, OUT, HIDDEN)
        cw0, cb0, cw1, cb1, cw2, cb2, cw3, cb3 = _group_layers(
            group, cw0, cb0, cw1, cb1, cw2, cb2, cw3, cb3, IN, CRITIC_H, 1, CRITIC_HIDDEN
        )
    rows, valid = _group_rows(tl.program_id(0), group, n_rows, BLOCK_M, GROUPS, BLOCKED)
    x = _rows(obs_ptr, rows, n_rows, IN, IN_P)
    _, _, last = _hidden(x, w0, b0, w1, b1, w2, b2, IN, IN_P, H, HIDDEN, ACTIVATION, PRECISION, FAST_TANH, TRANSPOSED)
    w_out, b_out = _output_layer(w1, b1, w2, b2, w3, b3, HIDDEN)
    y = _layer(last, w_out, b_out, H, H, OUT, OUT_P, PRECISION, TRANSPOSED)
    columns = tl.arange(0, OUT_P)
    category = columns[None, :] < OUT
    logits = tl.where(category, y, float("-inf"))
    top = tl.max(logits, axis=1)  # log-softmax as the actor's loss kernel computes it
    log_sum = top + tl.log(tl.sum(tl.exp(logits - top[:, None]), axis=1))
    log_probs = logits - log_sum[:, None]
    noise = _rows(noise_ptr, rows, n_rows, OUT, OUT_P)
    noise = tl.where(category & valid[:, None], noise, 1.0)  # (1: no division by 0 in the padding)
    # torch.multinomial's draw of one sample: argmax(p / Exp(1)), the lowest category at a tie
    score = tl.exp(log_probs) / noise
    # A network gone NaN (a failed run of a population, until it is stopped) still samples a category:
    # its scores count as 0, above the padding's -1, so no action index leaves [0, OUT).
    score = tl.where(category & valid[:, None], tl.where(score == score, score, 0.0), -1.0)
    action = tl.argmax(score, axis=1, tie_break_left=True)
    log_prob = tl.sum(tl.where(columns[None, :] == action[:, None], log_probs, 0.0), axis=1)
    _, _, critic_last = _hidden(
        x, cw0, cb0, cw1, cb1, cw2, cb2, IN, IN_P, CRITIC_H, CRITIC_HIDDEN, CRITIC_ACTIVATION, PRECISION, FAST_TANH,
        TRANSPOSED,
    )  # fmt: skip
    cw_out, cb_out = _output_layer(cw1, cb1, cw2, cb2, cw3, cb3, CRITIC_HIDDEN)
    critic_out = _layer(critic_last, cw_out, cb_out, CRITIC_H, CRITIC_H, 1, 16, PRECISION, TRANSPOSED)
    value = tl.sum(critic_out, axis=1)  # (one column)
    inputs = tl.arange(0, IN_P)
    tl.store(obs_out_ptr + rows[:, None] * IN + inputs[None, :], x, mask=valid[:, None] & (inputs[None, :] < IN))
    tl.store(action_out_ptr + rows, action.to(tl.float32), mask=valid)
    tl.store(env_action_ptr + rows, action.to(tl.int32), mask=valid)
    tl.store(value_out_ptr + rows, value, mask=valid)
    tl.store(log_prob_out_ptr + rows, log_prob, mask=valid)
    tl.store(log_probs_out_ptr + rows[:, None] * OUT + columns[None, :], log_probs, mask=valid[:, None] & category)


def _kernel_view(model) -> tuple[MLPSpec, list[torch.Tensor]]:
    """`fused_mlp.kernel_view` of a model that `FusedPPOLoss.unsupported` accepted."""
    view = kernel_view(model.mlp)
    assert view is not None, "a fused model (FusedPPOLoss.unsupported)"
    return view


def _single_group(model) -> str | None:
    """The one observation group a model reads, or None."""
    groups = list(getattr(model, "obs_groups", []))
    return groups[0] if len(groups) == 1 else None


class FusedPPOLoss:
    """The loss and gradients of `AquariumPPO`'s mini-batches from the two kernels (see the module doc).

    `step(indices, offset, size)` sets every actor and critic parameter's `.grad` to the gradient of
    rsl-rl's loss over mini-batch rows `indices[offset:offset + size]` of the learner's rollout
    storage, and returns the detached `[value loss, surrogate loss, entropy]` means (float64)."""

    def __init__(self, alg) -> None:
        reason = self.unsupported(alg)
        if reason is not None:
            raise ValueError(f"FusedPPOLoss: {reason}")
        self.alg = alg

    @staticmethod
    def unsupported(alg) -> str | None:
        """Why `alg` (an `AquariumPPO`) cannot use the fused loss; None when it can."""
        actor, critic = alg.actor, alg.critic
        actor_view, critic_view = (kernel_view(getattr(model, "mlp", None)) for model in (actor, critic))
        if actor_view is None or critic_view is None:
            return "the actor and the critic must be FusedMLPModel or FusedIndividualMLPModel (train.fused_mlp)"
        if not isinstance(actor.distribution, CategoricalDistribution):
            return "the actor's distribution must be CategoricalDistribution"
        if critic_view[0].dims[-1] != 1:
            return f"the critic must have one output, not {critic_view[0].dims[-1]}"
        groups = max(actor_view[0].groups, critic_view[0].groups)
        if actor_view[0].blocked != critic_view[0].blocked or actor_view[0].groups != critic_view[0].groups:
            return "the actor and the critic must stack the same networks"
        if groups > 1 and not actor_view[0].blocked and getattr(alg, "minibatch_group_size", 1) % groups:
            return f"mini-batches must hold whole worlds of the {groups} networks (minibatch_group_size)"
        for name, model in (("actor", actor), ("critic", critic)):
            if _single_group(model) is None:
                return f"the {name} must read one observation group, not {list(model.obs_groups)}"
            if getattr(model, "obs_normalization", False):
                return f"the {name}'s observation normalisation is not fused"
        if alg.use_mixed_precision:
            return "mixed precision (autocast) is not fused"
        if alg.desired_kl is not None and alg.schedule == "adaptive":
            return "the adaptive learning-rate schedule reads each mini-batch's KL divergence"
        if torch.device(alg.device).type not in fused_mlp.DEVICES:
            return f"the kernels do not take {alg.device} tensors here"
        return None

    def _launch(self, kernel, model, indices, offset: int, size: int, sums: int, inputs, scalars, flags):
        """One model's kernel over the mini-batch (`inputs`: its storage tensors, `scalars` its loss
        constants, `flags` its compile-time switches): its gradients into the parameters' `.grad`;
        returns the `sums` loss sums per network, `[networks, sums]`."""
        spec, params = _kernel_view(model)
        groups = spec.groups
        obs = self.alg.storage.observations[_single_group(model)].flatten(0, 1).contiguous()
        constants = _constants(spec, kernel_precision(obs.device), backward=True)
        # Persistent programs per network (one network: `backward_programs`; S networks share the card).
        programs = backward_programs(obs.device, triton.cdiv(size // groups, constants["BLOCK_M"]) * groups)
        programs = max(1, programs // groups)
        counts = [p.numel() // groups for p in params]  # each network's share of each parameter
        partial = torch.empty(programs * groups, sum(counts) + sums, dtype=torch.float32, device=obs.device)
        kernel[(programs, groups)](
            obs, indices, offset, size, *inputs, partial, *scalars,
            *_layer_pointers(tuple(p.contiguous() for p in params)),
            **constants, **spec.kernel_constants(), **flags, SUMS=sums, num_warps=NUM_WARPS,
        )  # fmt: skip
        total = partial.view(programs, groups, -1).sum(dim=0)  # [networks, parameters + sums]
        for p, g in zip(params, total[:, : sum(counts)].split(counts, dim=1)):
            # The parameter's own strides, as CUDA's fused Adam asks (a copy only for stacked networks,
            # whose slices of `total` are strided; it refused them on an H100 at 853dcd1).
            p.grad = g.reshape(p.shape).contiguous()
        return total[:, sum(counts) :]

    def step(self, indices: torch.Tensor, offset: int, size: int) -> torch.Tensor:
        """The mini-batch's gradients into `.grad`; returns the `[value, surrogate, entropy]` means, or
        for a population's networks (`MLPSpec.blocked`) each run's, `[runs, 3]`: each run's loss is the
        mean over its own rows, as if it trained alone."""
        alg = self.alg
        storage = alg.storage
        flat = {name: getattr(storage, name).flatten(0, 1).contiguous() for name in
                ("actions", "actions_log_prob", "advantages", "values", "returns")}  # fmt: skip
        if alg.normalize_advantage_per_mini_batch:
            with torch.no_grad():
                advantages = flat["advantages"][indices[offset : offset + size]]
                advantage_stats = torch.stack([advantages.mean(), advantages.std() + 1e-8])
        else:
            advantage_stats = flat["advantages"]  # not read
        spec = _kernel_view(alg.actor)[0]
        runs = spec.groups if spec.blocked else 1
        if runs > 1 and alg.normalize_advantage_per_mini_batch:
            raise ValueError("FusedPPOLoss: a population's runs normalise their advantages per run, not per mini-batch")
        rows = size // runs  # each loss is a mean over one run's rows (all rows: one network or slots)
        rate = 1.0 / rows
        actor_sums = self._launch(
            _actor_loss_kernel, alg.actor, indices, offset, size, ACTOR_SUMS,
            (flat["actions"], flat["actions_log_prob"], flat["advantages"], advantage_stats),
            (float(alg.clip_param), float(alg.entropy_coef), rate),
            {"NORMALIZE_ADVANTAGES": bool(alg.normalize_advantage_per_mini_batch)},
        )  # fmt: skip
        critic_sums = self._launch(
            _critic_loss_kernel, alg.critic, indices, offset, size, CRITIC_SUMS,
            (flat["values"], flat["returns"]),
            (float(alg.clip_param), float(alg.value_loss_coef), rate),
            {"CLIPPED": bool(alg.use_clipped_value_loss)},
        )  # fmt: skip
        sums = torch.cat([critic_sums, actor_sums], dim=1)  # [networks, (value, surrogate, entropy)]
        if runs > 1:
            return (sums / rows).double()
        return (sums.sum(dim=0) / rows).double()


class FusedAct:
    """`AquariumPPO`'s rollout step from `_act_kernel` (see the module doc): `act(obs, env_actions)`
    samples the actions of `obs` (a TensorDict of the rollout) and writes the storage's current step
    (observations, actions, values, log-probabilities, distribution parameters) and the int32
    `env_actions`; `store(rewards, dones, time_outs)` adds the step's rewards, bootstrapped on
    time-outs as rsl-rl's `process_env_step` does, and dones, and moves the storage to its next step.
    `unsupported(alg)` says why a learner cannot use it."""

    def __init__(self, alg) -> None:
        reason = self.unsupported(alg)
        if reason is not None:
            raise ValueError(f"FusedAct: {reason}")
        self.alg = alg
        self.group = _single_group(alg.actor)
        storage = alg.storage
        # The int32 actions of a caller that gives no buffer of its own (rsl-rl's runner loop).
        self._env_actions = torch.zeros(storage.num_envs, dtype=torch.int32, device=storage.device)
        self._bootstrap = torch.zeros(storage.num_envs, 1, device=storage.device)  # gamma * values at time-outs
        self._actor, self._critic = _kernel_view(alg.actor), _kernel_view(alg.critic)
        if storage.distribution_params is None:  # as rsl-rl's first `add_transition` makes them
            T, N, K = storage.num_transitions_per_env, storage.num_envs, self._actor[0].dims[-1]
            storage.distribution_params = (torch.zeros(T, N, K, device=storage.device),)

    @staticmethod
    def unsupported(alg) -> str | None:
        """Why `alg` cannot use the fused rollout step; None when it can: where the fused loss serves
        (`FusedPPOLoss.unsupported`), with the actor and the critic reading the one observation group
        the storage keeps, and no RND or symmetry (which read the transition)."""
        reason = FusedPPOLoss.unsupported(alg)
        if reason is not None:
            return reason
        groups = {_single_group(alg.actor), _single_group(alg.critic)}
        if len(groups) != 1 or set(alg.storage.observations.keys()) != groups:
            names = sorted(map(str, groups))
            return f"the actor and the critic must read the storage's one observation group, not {names}"
        if alg.rnd is not None or alg.symmetry is not None:
            return "RND and symmetry read rsl-rl's transition"
        actor, critic = (_kernel_view(model)[0] for model in (alg.actor, alg.critic))
        if (actor.groups, actor.stacked, actor.blocked) != (critic.groups, critic.stacked, critic.blocked):
            return "the actor and the critic must both share their parameters or both be Individual Learning's"
        return None

    def act(self, obs, env_actions: torch.Tensor | None = None) -> torch.Tensor:
        """Sample and store step `storage.step` (see the class doc); returns the stored actions `[N, 1]`."""
        storage = self.alg.storage
        if storage.step >= storage.num_transitions_per_env:
            raise OverflowError("Rollout buffer overflow! You should call clear() before adding new transitions.")
        t = storage.step
        x = obs[self.group].contiguous()
        (actor, actor_params), (critic, critic_params) = self._actor, self._critic
        n_rows, categories = x.shape[0], actor.dims[-1]
        # The kernel reads and writes by these sizes: refused here, not read past an array on the device.
        if x.dim() != 2 or x.shape[1] != actor.dims[0] or n_rows != storage.num_envs:
            raise ValueError(
                f"FusedAct: observations {tuple(x.shape)}, the storage takes [{storage.num_envs}, {actor.dims[0]}]"
            )
        if env_actions is not None and env_actions.numel() != n_rows:
            raise ValueError(f"FusedAct: env_actions of {env_actions.numel()} elements for {n_rows} rows")
        noise = torch.empty(n_rows, categories, dtype=x.dtype, device=x.device).exponential_(1)
        precision = kernel_precision(x.device)
        constants = _constants(actor, precision)
        constants["BLOCK_M"] = min(block_rows(actor), block_rows(critic))
        actions = storage.actions[t]
        # Network g's rows (`_group_rows`: slots interleaved, or runs in blocks): a program per tile and network.
        _act_kernel[(triton.cdiv(n_rows // actor.groups, constants["BLOCK_M"]), actor.groups)](
            x, noise, n_rows,
            storage.observations[self.group][t], actions, storage.values[t], storage.actions_log_prob[t],
            storage.distribution_params[0][t], self._env_actions if env_actions is None else env_actions,
            *_layer_pointers(tuple(p.contiguous() for p in actor_params)),
            *_layer_pointers(tuple(p.contiguous() for p in critic_params)),
            **constants, **actor.kernel_constants(), CRITIC_H=critic.dims[1], CRITIC_HIDDEN=critic.layers - 1,
            CRITIC_ACTIVATION=critic.activation, num_warps=NUM_WARPS,
        )  # fmt: skip
        return actions

    def store(self, rewards: torch.Tensor, dones: torch.Tensor, time_outs: torch.Tensor | None) -> None:
        """The step's rewards (`[N]`; plus gamma times the stored value where `time_outs`) and dones."""
        alg, storage = self.alg, self.alg.storage
        t = storage.step
        if time_outs is None:
            storage.rewards[t].copy_(rewards.view(-1, 1))
        else:
            # rsl-rl's rewards + gamma * (values * time_outs), rounded as it rounds: one fused kernel
            # (addcmul) gave other bits on an H100, its multiply-add contracted into one FMA.
            bootstrap = torch.mul(storage.values[t], time_outs.view(-1, 1), out=self._bootstrap)
            torch.add(rewards.view(-1, 1), bootstrap.mul_(alg.gamma), out=storage.rewards[t])
        storage.dones[t].copy_(dones.view(-1, 1))
        storage.step += 1
