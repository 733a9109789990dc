"""`AquariumPPO`: rsl-rl's PPO with a few additions, plugged in by `algorithm.class_name`.

1. Separate actor and critic learning rates (the paper's "Actor alpha" 0.001 and "Critic alpha" 0.003).
   rsl-rl builds ONE optimizer with ONE learning rate for both networks, and scaling the value-loss
   coefficient would not emulate a second rate: Adam normalises each parameter's gradient by its own
   running RMS, so a constant factor on the critic's loss cancels (the actor and critic share no
   parameters). Instead the optimizer is rebuilt with two parameter groups, actor and critic, whose
   group `lr_scale` (1 and `critic_lr_scale`) multiplies the common learning rate inside `step()`.
   `learning_rate` stays the actor's rate, and rsl-rl's adaptive-KL schedule, which writes one `lr`
   into every group, keeps the ratio. The value-loss coefficient stays an ordinary loss weight.
2. `minibatch_group_size=G`: mini-batches are drawn as whole groups of G consecutive rows (one world's
   agent slots at one step) instead of single rows. Individual Learning needs this (see
   `models.IndividualMLPModel`); with G=1 the update is rsl-rl's exactly.
3. `update_on_device(indices)`: rsl-rl's `PPO.update` for feed-forward models, the same operations in
   the same order (with several ranks, its gradient all-reduce and rank 0's adaptive learning rate),
   with the mini-batch indices drawn beforehand (`mini_batch_indices()`, the same random
   draw as the storage's generator) and the mean losses kept on the device instead of `.item()` after
   every mini-batch. Without host synchronisation the whole update (fixed learning-rate schedule) can
   be captured as one CUDA graph, or with several ranks as graphs cut at its all-reduces (`training/loop.py`);
   `capturable_optimizer=True` builds the optimizer with `capturable=True` for that. On the CPU the
   parameters it produces equal rsl-rl's bit for bit (`tests/training/test_training_loop.py`).
4. With fused actor and critic (`train.fused_mlp`: `FusedMLPModel`, or Individual Learning's
   `FusedIndividualMLPModel`), `update_on_device` takes each mini-batch's
   loss and gradients from `fused_ppo.FusedPPOLoss` (`fused_loss`) where it serves, then clips and
   steps as rsl-rl does (`_apply_gradients`); `FusedPPOLoss.unsupported` says why it does not serve.
   Where it serves, the rollout's `act` and `process_env_step` run `fused_ppo.FusedAct` (`fused_act`):
   one kernel samples and writes the storage's step, whose rewards and dones follow in four more.
"""

from __future__ import annotations

from collections.abc import Generator

import torch
import torch.nn as nn
from rsl_rl.algorithms import PPO
from rsl_rl.storage import RolloutStorage
from rsl_rl.utils import resolve_optimizer

from . import _rsl  # noqa: F401


def _scaled_optimizer_class(base: type) -> type:
    """A subclass of the torch optimizer `base` whose parameter groups may carry an `lr_scale`."""

    class GroupScaled(base):
        def step(self, closure=None):
            saved = [group["lr"] for group in self.param_groups]
            for group in self.param_groups:
                group["lr"] = group["lr"] * group.get("lr_scale", 1.0)
            try:
                return super().step(closure)
            finally:
                for group, lr in zip(self.param_groups, saved):
                    group["lr"] = lr

    GroupScaled.__name__ = GroupScaled.__qualname__ = f"GroupScaled{base.__name__}"
    return GroupScaled


def flat_samples(storage: RolloutStorage) -> tuple:
    """The rollout's samples as rsl-rl's mini-batch generator flattens them (step-major): observations,
    actions, values, returns, action log-probabilities, advantages, distribution parameters."""
    return (
        storage.observations.flatten(0, 1),
        storage.actions.flatten(0, 1),
        storage.values.flatten(0, 1),
        storage.returns.flatten(0, 1),
        storage.actions_log_prob.flatten(0, 1),
        storage.advantages.flatten(0, 1),
        tuple(p.flatten(0, 1) for p in storage.distribution_params),
    )


def mini_batch_size(storage: RolloutStorage, num_mini_batches: int, group_size: int = 1) -> int:
    """Samples per mini-batch: whole groups of `group_size` rows, as many as fit `num_mini_batches` times."""
    groups = storage.num_envs * storage.num_transitions_per_env // group_size
    if groups // num_mini_batches < 1:
        raise ValueError(f"{groups} row groups cannot fill {num_mini_batches} mini-batches")
    return groups // num_mini_batches * group_size


def mini_batch_indices(storage: RolloutStorage, num_mini_batches: int, group_size: int = 1) -> tuple[torch.Tensor, int]:
    """`(indices, mini_batch_size)`: the shuffled sample indices of one update (mini-batch `i` is
    `indices[i * size:(i + 1) * size]`, every epoch), drawn in whole groups of `group_size` consecutive
    rows. With `group_size=1` this is the one `randperm` of rsl-rl's `mini_batch_generator`."""
    G = group_size
    groups_per_batch = mini_batch_size(storage, num_mini_batches, G) // G
    perm = torch.randperm(num_mini_batches * groups_per_batch, requires_grad=False, device=storage.device)
    if G == 1:
        return perm, groups_per_batch
    indices = (perm.unsqueeze(1) * G + torch.arange(G, device=storage.device)).reshape(-1)
    return indices, groups_per_batch * G


def _capturable_options(optimizer: str) -> dict:
    """Optimizer options for a step inside a CUDA graph: capturable state, and for Adam(W) the fused
    CUDA kernel (one launch per parameter group instead of a dozen of foreach launches)."""
    options = {"capturable": True}
    if isinstance(optimizer, str) and optimizer.lower() in ("adam", "adamw"):
        options["fused"] = True
    return options


class GroupedRolloutStorage(RolloutStorage):
    """Rollout storage whose feed-forward mini-batches hold whole groups of `group_size` consecutive rows."""

    def __init__(self, group_size: int, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if self.num_envs % group_size != 0:
            raise ValueError(f"num_envs={self.num_envs} is not a multiple of minibatch_group_size={group_size}")
        self.group_size = group_size

    def mini_batch_generator(self, num_mini_batches: int, num_epochs: int = 8) -> Generator:
        indices, mini_batch_size = mini_batch_indices(self, num_mini_batches, self.group_size)
        (observations, actions, values, returns, old_actions_log_prob, advantages, old_distribution_params) = (
            flat_samples(self)
        )

        for _ in range(num_epochs):
            for i in range(num_mini_batches):
                batch_idx = indices[i * mini_batch_size : (i + 1) * mini_batch_size]
                yield RolloutStorage.Batch(
                    observations=observations[batch_idx],
                    actions=actions[batch_idx],
                    values=values[batch_idx],
                    advantages=advantages[batch_idx],
                    returns=returns[batch_idx],
                    old_actions_log_prob=old_actions_log_prob[batch_idx],
                    old_distribution_params=tuple(p[batch_idx] for p in old_distribution_params),
                )


class AquariumPPO(PPO):
    """rsl-rl PPO with an actor/critic learning-rate ratio and grouped mini-batches (see the module doc).

    Extra arguments: `critic_lr_scale` (critic rate / actor rate, default 1) and
    `minibatch_group_size` (default 1: rsl-rl's row shuffling)."""

    # Declared: this class rebinds both from their own values, which type inference cannot start from.
    storage: RolloutStorage
    learning_rate: float
    loss_shape: tuple[int, ...] = (3,)  # [value, surrogate, entropy] (a population's learner: per run)

    def __init__(
        self,
        actor,
        critic,
        storage,
        critic_lr_scale: float = 1.0,
        minibatch_group_size: int = 1,
        optimizer: str = "adam",
        learning_rate: float = 0.001,
        capturable_optimizer: bool = False,
        **kwargs,
    ) -> None:
        super().__init__(actor, critic, storage, optimizer=optimizer, learning_rate=learning_rate, **kwargs)
        if not (isinstance(critic_lr_scale, (int, float)) and critic_lr_scale > 0):
            raise ValueError(f"critic_lr_scale={critic_lr_scale!r} must be a number > 0")
        if (
            isinstance(minibatch_group_size, bool)
            or not isinstance(minibatch_group_size, int)
            or minibatch_group_size < 1
        ):
            raise ValueError(f"minibatch_group_size={minibatch_group_size!r} must be an integer >= 1")
        if minibatch_group_size > 1 and (actor.is_recurrent or critic.is_recurrent):
            raise ValueError("minibatch_group_size > 1 is for feed-forward models only")
        self.critic_lr_scale = float(critic_lr_scale)
        self.minibatch_group_size = minibatch_group_size
        optimizer_class = _scaled_optimizer_class(resolve_optimizer(optimizer))
        self.optimizer = optimizer_class(
            [
                {"params": list(self.actor.parameters()), "lr_scale": 1.0, "name": "actor"},
                {"params": list(self.critic.parameters()), "lr_scale": self.critic_lr_scale, "name": "critic"},
            ],
            lr=learning_rate,
            **(_capturable_options(optimizer) if capturable_optimizer else {}),
        )
        self.capturable_optimizer = bool(capturable_optimizer)
        self.fused_loss = None  # the fused loss (fused_ppo.py), where it serves (set below)
        if minibatch_group_size > 1:
            old = self.storage
            self.storage = GroupedRolloutStorage(
                minibatch_group_size,
                old.training_type,
                old.num_envs,
                old.num_transitions_per_env,
                old.observations[0],
                old.actions_shape,
                old.device,
            )
        self.fused_act = None  # the fused rollout step (fused_ppo.py), where it serves (set below)
        if all(getattr(model, "fused", False) for model in (self.actor, self.critic)):
            from .fused_ppo import FusedAct, FusedPPOLoss  # (triton: present wherever the models are fused)

            if FusedPPOLoss.unsupported(self) is None:
                self.fused_loss = FusedPPOLoss(self)
            if FusedAct.unsupported(self) is None:
                self.fused_act = FusedAct(self)

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        loaded = super().load(loaded_dict, load_cfg, strict)
        if self.capturable_optimizer:  # a loaded optimizer state carries the saver's flag and step placement
            for group in self.optimizer.param_groups:
                group["capturable"] = True
            for state in self.optimizer.state.values():
                if "step" in state and isinstance(state["step"], torch.Tensor):
                    state["step"] = state["step"].to(self.device, torch.float32)
        return loaded

    # ------------------------------------------------------------------ the rollout step
    def act(self, obs):
        """rsl-rl's `PPO.act`; with `fused_act`, the fused step, which writes the storage's step itself
        (and returns the stored actions)."""
        if self.fused_act is None:
            return super().act(obs)
        return self.fused_act.act(obs)

    def act_into(self, obs, env_actions: torch.Tensor) -> None:
        """`act(obs)` with the actions written into `env_actions` (the adapter's int32 `[W, S]` buffer)."""
        if self.fused_act is None:
            env_actions.copy_(self.act(obs).view(env_actions.shape))  # float -> int32 (exact)
        else:
            self.fused_act.act(obs, env_actions)

    def process_env_step(self, obs, rewards, dones, extras) -> None:
        """rsl-rl's `PPO.process_env_step`; with `fused_act`, the step's rewards and dones into the
        storage (its other fields were written by `act`)."""
        if self.fused_act is None:
            super().process_env_step(obs, rewards, dones, extras)
        else:
            self.fused_act.store(rewards, dones, extras.get("time_outs"))

    # ------------------------------------------------------------------ update without host syncs
    @property
    def feed_forward(self) -> bool:
        """Neither model is recurrent (so `update_on_device` serves)."""
        return not (self.actor.is_recurrent or self.critic.is_recurrent)

    @property
    def rollout_graphable(self) -> bool:
        """Whether `act` and `process_env_step` make no host synchronisation (so a rollout step can be
        captured): feed-forward models, no RND or symmetry. Several ranks and the adaptive schedule
        change only the update."""
        return self.feed_forward and self.rnd is None and self.symmetry is None

    @property
    def graphable(self) -> bool:
        """Whether `update_on_device` can be captured too: a rollout that can, and a fixed learning-rate
        schedule (the adaptive one reads the KL on the host every mini-batch). With several ranks the
        gradients' average over the ranks (rsl-rl's `reduce_parameters`: the gradients concatenated
        into buckets, each all-reduced, divided and copied back) has the same shapes every call and no
        host work, so graphs replay the rest of the update around it (`loop.graph_plan` says how)."""
        return self.rollout_graphable and not (self.desired_kl is not None and self.schedule == "adaptive")

    def mini_batch_indices(self) -> tuple[torch.Tensor, int]:
        """The indices of the next update (see `mini_batch_indices`); call once per update."""
        return mini_batch_indices(self.storage, self.num_mini_batches, self.minibatch_group_size)

    def update_on_device(self, indices: torch.Tensor, mini_batch_size: int) -> torch.Tensor:
        """rsl-rl's `PPO.update` (feed-forward models) over the mini-batches of `indices`; returns the
        mean value, surrogate and entropy losses as a `[3]` float64 tensor on the device. The
        normalisers' update and `storage.clear()` are left to `finish_update()`, which may synchronise.
        The adaptive schedule works too, with one host sync per mini-batch (as in rsl-rl)."""
        if self.actor.is_recurrent or self.critic.is_recurrent or self.rnd or self.symmetry:
            raise ValueError("update_on_device serves feed-forward models without RND or symmetry")
        (observations, actions, values, returns, old_actions_log_prob, advantages, old_distribution_params) = (
            flat_samples(self.storage)
        )
        losses = torch.zeros(self.loss_shape, dtype=torch.float64, device=self.device)
        for _ in range(self.num_learning_epochs):
            for i in range(self.num_mini_batches):
                if self.fused_loss is not None:
                    losses += self.fused_loss.step(indices, i * mini_batch_size, mini_batch_size)
                    self._apply_gradients()
                    continue
                batch_idx = indices[i * mini_batch_size : (i + 1) * mini_batch_size]
                losses += self._mini_batch_step(
                    observations[batch_idx],
                    actions[batch_idx],
                    values[batch_idx],
                    advantages[batch_idx],
                    returns[batch_idx],
                    old_actions_log_prob[batch_idx],
                    tuple(p[batch_idx] for p in old_distribution_params),
                )
        return losses / (self.num_learning_epochs * self.num_mini_batches)

    def finish_update(self) -> None:
        """What rsl-rl's `update()` does after its mini-batches: the observation normalisers learn
        from the rollout, and the storage is cleared."""
        obs = self.storage.observations.flatten(0, 1)
        for model in (self.actor, self.critic):
            normalizer = getattr(model, "obs_normalizer", None)
            std = getattr(normalizer, "_std", None)
            model.update_normalization(obs)
            # rsl-rl's normaliser rebinds `_std` to a new tensor; captured graphs read the old one.
            if normalizer is not None and isinstance(std, torch.Tensor) and normalizer._std is not std:
                std.copy_(normalizer._std)
                normalizer._std = std
        self.storage.clear()

    def _mini_batch_step(
        self, observations, actions, old_values, advantages, returns, old_actions_log_prob, old_distribution_params
    ) -> torch.Tensor:
        """One mini-batch of rsl-rl 5.5.1's `PPO.update` (same operations, same order); returns the
        detached `[value loss, surrogate loss, entropy]`."""
        original_batch_size = observations.batch_size[0]
        if self.normalize_advantage_per_mini_batch:
            with torch.no_grad():
                advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        with torch.amp.autocast(
            device_type=torch.device(self.device).type, enabled=self.use_mixed_precision, dtype=torch.bfloat16
        ):
            self.actor(observations, masks=None, hidden_state=None, stochastic_output=True)
            actions_log_prob = self.actor.get_output_log_prob(actions)
            values = self.critic(observations, masks=None, hidden_state=None)
            distribution_params = tuple(p[:original_batch_size] for p in self.actor.output_distribution_params)
            entropy = self.actor.output_entropy[:original_batch_size]
            if self.desired_kl is not None and self.schedule == "adaptive":
                with torch.inference_mode():
                    kl = self.actor.get_kl_divergence(old_distribution_params, distribution_params)
                    kl_mean = torch.mean(kl)
                    if self.is_multi_gpu:  # several ranks: rank 0 decides on the mean KL of all
                        torch.distributed.all_reduce(kl_mean, op=torch.distributed.ReduceOp.SUM)
                        kl_mean /= self.gpu_world_size
                    if self.gpu_global_rank == 0:
                        if kl_mean > self.desired_kl * 2.0:
                            self.learning_rate = max(1e-5, self.learning_rate / 1.5)
                        elif kl_mean < self.desired_kl / 2.0 and kl_mean > 0.0:
                            self.learning_rate = min(1e-2, self.learning_rate * 1.5)
                    if self.is_multi_gpu:
                        lr_tensor = torch.tensor(self.learning_rate, device=self.device)
                        torch.distributed.broadcast(lr_tensor, src=0)
                        self.learning_rate = lr_tensor.item()
                    for param_group in self.optimizer.param_groups:
                        param_group["lr"] = self.learning_rate
            ratio = torch.exp(actions_log_prob - torch.squeeze(old_actions_log_prob))
            surrogate = -torch.squeeze(advantages) * ratio
            surrogate_clipped = -torch.squeeze(advantages) * torch.clamp(
                ratio, 1.0 - self.clip_param, 1.0 + self.clip_param
            )
            surrogate_loss = torch.max(surrogate, surrogate_clipped).mean()
            if self.use_clipped_value_loss:
                value_clipped = old_values + (values - old_values).clamp(-self.clip_param, self.clip_param)
                value_losses = (values - returns).pow(2)
                value_losses_clipped = (value_clipped - returns).pow(2)
                value_loss = torch.max(value_losses, value_losses_clipped).mean()
            else:
                value_loss = (returns - values).pow(2).mean()
            entropy_mean = entropy.mean()
            loss = surrogate_loss + self.value_loss_coef * value_loss - self.entropy_coef * entropy_mean
        self.optimizer.zero_grad()
        loss.backward()
        self._apply_gradients()
        return torch.stack([value_loss.detach(), surrogate_loss.detach(), entropy_mean.detach()]).double()

    def _apply_gradients(self) -> None:
        """The end of rsl-rl's mini-batch step, from the parameters' gradients: their average over the
        ranks (several), the clipping of each network's gradient norm, the optimizer step."""
        if self.is_multi_gpu:
            self.reduce_parameters()
        nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
        nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
        self.optimizer.step()
