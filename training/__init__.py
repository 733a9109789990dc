"""Training on top of `BatchedAquarium`: PPO with rsl-rl (unmodified, as a dependency).

- `vec_env.AquariumVecEnv`: the rsl-rl VecEnv adapter (one learning team, the other driven inside `step()`).
- `distribution.CategoricalDistribution`: discrete actions for rsl-rl's `MLPModel`.
- `models.IndividualMLPModel`: Individual Learning, per-slot parameters in one batched network.
- `fused_mlp.FusedMLPModel`: the MLP as fused Triton kernels (`train.fused_mlp`).
- `ppo.AquariumPPO`: separate actor/critic learning rates, grouped mini-batches.
- `config`: presets (`default`, `paper`, `tiny`) and the rsl-rl runner config.
- `trainer.Trainer`: training, checkpoints, bit-exact resume, export (`runner.AquariumRunner`, rsl-rl's
  runner; `logger.AquariumLogger`, the CSV and console log; `checkpoints`, finding and reading them).
- `population.Population`: K runs in one process (`train --runs K`), each as if trained alone.
- `drivers`: a team driven by a trained policy (`TrainedOpponent`, `RecurrentOpponent`).
- `export.load_policy`: exported policies (TorchScript, ONNX) or checkpoints -> callable obs -> actions.
- `evaluate`: the paper's evaluation protocol; `cross_play`: cross play and Elo ratings; `plots`: the figures.

Submodules import rsl_rl lazily; this package's names resolve on first use.
"""

from __future__ import annotations

import importlib

from . import _rsl  # noqa: F401

_EXPORTS = {
    "AquariumVecEnv": "vec_env",
    "TrainedOpponent": "drivers",
    "CategoricalDistribution": "distribution",
    "IndividualMLPModel": "models",
    "BatchedMLP": "models",
    "AquariumPPO": "ppo",
    "make_config": "config",
    "PRESETS": "config",
    "env_config": "config",
    "Trainer": "trainer",
    "Population": "population",
    "run_configs": "population",
    "resume_population": "population",
    "latest_checkpoint": "checkpoints",
    "export_policy": "export",
    "load_policy": "export",
    "LoadedPolicy": "export",
    "evaluate_policies": "evaluate",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        module = importlib.import_module(f".{_EXPORTS[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
