"""A categorical action distribution for rsl-rl (which ships only continuous ones).

Plugged in through the actor's `distribution_cfg`:

```python
"distribution_cfg": {"class_name": "aquarium_warp.training.distribution:CategoricalDistribution",
                     "num_categories": 16}
```

`MLPModel` builds it with `output_dim = env.num_actions = 1` and sizes the MLP head to `input_dim =
num_categories` logits. Actions travel through rsl-rl as float category indices `[N, 1]` (its rollout
storage keeps actions as floats); `log_prob`, `entropy` and `kl_divergence` reduce to `[N]`; the
deterministic output is the argmax; `params` are the normalised logits (log-probabilities), which the
rollout storage keeps for the adaptive-KL learning-rate schedule.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.modules.distribution import Distribution

from . import _rsl  # noqa: F401  (sets GIT_PYTHON_REFRESH before rsl_rl is imported)


class CategoricalDistribution(Distribution):
    """Categorical distribution over `num_categories` actions for a single discrete action (`output_dim=1`).

    - `sample()` -> `[N, 1]` float category indices (`torch.multinomial`'s draw, global RNG).
    - `deterministic_output(logits)` -> `[N, 1]` float argmax (ties: the lower index).
    - `log_prob(actions [N, 1])`, `entropy`, `kl_divergence(old, new)` -> `[N]` (natural log).
    - `params` -> `(log_probs [N, K],)`: log-softmax of the logits.
    - `std` -> `[N, 1]` perplexity `exp(entropy)`, the effective number of actions in [1, K]: rsl-rl logs
      it as "Policy/mean_std"; a Gaussian's std has no meaning here.
    - `mean` -> the mode (argmax), `[N, 1]` float.

    `init_logit_scale` multiplies the last layer's initial weights (and zeroes its bias) so that the
    initial policy is close to uniform (0.01 as in common PPO practice; 1 keeps the default init).
    """

    def __init__(self, output_dim: int, num_categories: int = 16, init_logit_scale: float = 0.01) -> None:
        super().__init__(output_dim)
        if output_dim != 1:
            raise ValueError(
                f"CategoricalDistribution models one discrete action: output_dim (env.num_actions) "
                f"must be 1, got {output_dim}"
            )
        if isinstance(num_categories, bool) or not isinstance(num_categories, int) or num_categories < 1:
            raise ValueError(f"num_categories={num_categories!r} must be an integer >= 1")
        self.num_categories = num_categories
        self.init_logit_scale = float(init_logit_scale)
        self._log_probs: torch.Tensor | None = None
        self._probs: torch.Tensor | None = None

    # ------------------------------------------------------------------ rsl-rl Distribution API
    def update(self, mlp_output: torch.Tensor) -> None:
        self._log_probs = torch.log_softmax(mlp_output, dim=-1)
        self._probs = self._log_probs.exp()

    def _current(self) -> tuple[torch.Tensor, torch.Tensor]:
        """`(log_probs, probs)` of the last `update`."""
        if self._log_probs is None or self._probs is None:
            raise RuntimeError("CategoricalDistribution has no logits yet: update(mlp_output) comes first")
        return self._log_probs, self._probs

    def sample(self) -> torch.Tensor:
        _, probs = self._current()
        flat = probs.reshape(-1, self.num_categories)
        # torch.multinomial's own draw for one sample, argmax(p / Exp(1)), in three kernels instead of its
        # dozen (it first checks the probabilities on the device: softmax's always pass): the same
        # indices from the same generator state, which it leaves where multinomial leaves it.
        index = torch.argmax(flat / torch.empty_like(flat).exponential_(1), dim=-1, keepdim=True)
        return index.reshape(*probs.shape[:-1], 1).to(probs.dtype)

    def deterministic_output(self, mlp_output: torch.Tensor) -> torch.Tensor:
        return torch.argmax(mlp_output, dim=-1, keepdim=True).to(mlp_output.dtype)

    def as_deterministic_output_module(self) -> nn.Module:
        return ArgmaxOutput()

    @property
    def input_dim(self) -> int:
        return self.num_categories

    @property
    def mean(self) -> torch.Tensor:
        log_probs, _ = self._current()
        return torch.argmax(log_probs, dim=-1, keepdim=True).to(log_probs.dtype)

    @property
    def std(self) -> torch.Tensor:
        return self.entropy.exp().unsqueeze(-1)

    @property
    def entropy(self) -> torch.Tensor:
        log_probs, probs = self._current()
        return -(probs * log_probs).sum(dim=-1)

    @property
    def params(self) -> tuple[torch.Tensor, ...]:
        return (self._current()[0],)

    def log_prob(self, outputs: torch.Tensor) -> torch.Tensor:
        index = outputs[..., :1].long()
        return torch.gather(self._current()[0], -1, index).squeeze(-1)

    def kl_divergence(self, old_params: tuple[torch.Tensor, ...], new_params: tuple[torch.Tensor, ...]) -> torch.Tensor:
        old = torch.log_softmax(old_params[0], dim=-1)  # idempotent on log-probabilities
        new = torch.log_softmax(new_params[0], dim=-1)
        return (old.exp() * (old - new)).sum(dim=-1)

    def init_mlp_weights(self, mlp: nn.Module) -> None:
        """Scale the last layer (the last module with a weight: `nn.Linear` or a per-agent batched layer)."""
        if self.init_logit_scale == 1.0:
            return
        last = None  # (weight, bias) of the last module with a weight
        for module in mlp.modules():
            weight = getattr(module, "weight", None)
            if isinstance(weight, torch.Tensor):
                last = (weight, getattr(module, "bias", None))
        if last is None:
            return
        weight, bias = last
        with torch.no_grad():
            weight.mul_(self.init_logit_scale)
            if bias is not None:
                bias.zero_()


class ArgmaxOutput(nn.Module):
    """Export-friendly deterministic output: the argmax category as a float `[N, 1]` (rsl-rl's action layout)."""

    def forward(self, mlp_output: torch.Tensor) -> torch.Tensor:
        return torch.argmax(mlp_output, dim=-1, keepdim=True).to(mlp_output.dtype)
