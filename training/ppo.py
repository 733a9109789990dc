"""`AquariumPPO`: rsl-rl's PPO with two small additions, plugged in by `algorithm.class_name`.

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
"""

from __future__ import annotations

from collections.abc import Generator

import torch

from . import _rsl  # noqa: F401
from rsl_rl.algorithms import PPO
from rsl_rl.storage import RolloutStorage
from rsl_rl.utils import resolve_optimizer


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


class GroupedRolloutStorage(RolloutStorage):
    """Rollout storage whose feed-forward mini-batches hold whole groups of `group_size` consecutive rows."""

    def __init__(self, group_size: int, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if self.num_envs % group_size != 0:
            raise ValueError(f"num_envs={self.num_envs} is not a multiple of minibatch_group_size={group_size}")
        self.group_size = group_size

    def mini_batch_generator(self, num_mini_batches: int, num_epochs: int = 8) -> Generator:
        G = self.group_size
        groups = self.num_envs * self.num_transitions_per_env // G
        groups_per_batch = groups // num_mini_batches
        if groups_per_batch < 1:
            raise ValueError(f"{groups} row groups cannot fill {num_mini_batches} mini-batches")
        perm = torch.randperm(num_mini_batches * groups_per_batch, requires_grad=False, device=self.device)
        indices = (perm.unsqueeze(1) * G + torch.arange(G, device=self.device)).reshape(-1)
        mini_batch_size = groups_per_batch * G

        observations = self.observations.flatten(0, 1)
        actions = self.actions.flatten(0, 1)
        values = self.values.flatten(0, 1)
        returns = self.returns.flatten(0, 1)
        old_actions_log_prob = self.actions_log_prob.flatten(0, 1)
        advantages = self.advantages.flatten(0, 1)
        old_distribution_params = tuple(p.flatten(0, 1) for p in self.distribution_params)

        for _ in range(num_epochs):
            for i in range(num_mini_batches):
                batch_idx = indices[i * mini_batch_size:(i + 1) * mini_batch_size]
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

    def __init__(self, actor, critic, storage, critic_lr_scale: float = 1.0, minibatch_group_size: int = 1,
                 optimizer: str = "adam", learning_rate: float = 0.001, **kwargs) -> None:
        super().__init__(actor, critic, storage, optimizer=optimizer, learning_rate=learning_rate, **kwargs)
        if not (isinstance(critic_lr_scale, (int, float)) and critic_lr_scale > 0):
            raise ValueError(f"critic_lr_scale={critic_lr_scale!r} must be a number > 0")
        if isinstance(minibatch_group_size, bool) or not isinstance(minibatch_group_size, int) \
                or minibatch_group_size < 1:
            raise ValueError(f"minibatch_group_size={minibatch_group_size!r} must be an integer >= 1")
        if minibatch_group_size > 1 and (actor.is_recurrent or critic.is_recurrent):
            raise ValueError("minibatch_group_size > 1 is for feed-forward models only")
        self.critic_lr_scale = float(critic_lr_scale)
        self.minibatch_group_size = minibatch_group_size
        optimizer_class = _scaled_optimizer_class(resolve_optimizer(optimizer))
        self.optimizer = optimizer_class([
            {"params": list(self.actor.parameters()), "lr_scale": 1.0, "name": "actor"},
            {"params": list(self.critic.parameters()), "lr_scale": self.critic_lr_scale, "name": "critic"},
        ], lr=learning_rate)
        if minibatch_group_size > 1:
            old = self.storage
            self.storage = GroupedRolloutStorage(
                minibatch_group_size, old.training_type, old.num_envs, old.num_transitions_per_env,
                old.observations[0], old.actions_shape, old.device)
