"""Which matrix path a run takes: torch's MLP in float32, or the fused Triton MLP, loss and rollout step
(`fused_mlp.py`, `fused_ppo.py`) with TF32 products, from `train.fused_mlp` and `train.tf32`.

Each of the two settings is true, false or "auto" (the default: the follow-up declared in
`benchmarks/fused_default_followup.md` found the fused path with TF32 products equivalent to torch's
float32 path). `resolve_fast_path(config, device_type)` decides:

- `train.fused_mlp="auto"`: the fused path on a CUDA device where Triton imports and the fused kernels
  serve every learning team's config (`fused_config_problem`); torch's MLP everywhere else (the CPU, no
  Triton, a model or loss the kernels do not cover).
- `train.tf32="auto"`: TF32 products wherever the fused MLP runs on CUDA, float32 otherwise; so
  `train.fused_mlp=false` alone gives torch's float32 path and `train.tf32=false` alone the fused
  kernels in float32 (`fused_mlp.FLOAT32_PRECISION`).
- true or false: as given.

The config keeps the requested values; the trainer records the resolved path and its reason in
`config.json` (`FastPath.record`) and prints it first (`FastPath.line`). After the learners are built,
`config.json`'s `fused_loss` and `fused_act` say whether each learner's update and rollout run the fused
kernels (`FusedPPOLoss.unsupported`, `FusedAct.unsupported`, which the config checks here anticipate).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from .config import DISTRIBUTION, TORCH_MLP_MODELS, env_config, learning_teams, team_runner, team_settings

AUTO = "auto"
SWITCHES = ("fused_mlp", "tf32")  # the train settings resolved here
# torch's MLP in float32 on every device: the path of the studies whose committed results were trained
# before "auto" (their run configs set it, so that they keep meaning what they meant).
TORCH_FLOAT32 = {"fused_mlp": False, "tf32": False}


def triton_imports() -> bool:
    """Whether Triton imports in this process (the fused kernels need it)."""
    try:
        importlib.import_module("triton")
    except ImportError:
        return False
    return True


def fused_config_problem(config: dict) -> str | None:
    """Why the fused MLP, loss and rollout step do not serve `config`'s learners, read from the config
    (what `FusedPPOLoss.unsupported` and `FusedAct.unsupported` find on the built learners); None when
    they do. Imports the kernels' module: call it where Triton imports."""
    from .fused_mlp import ACTIVATIONS, widths_problem

    action_count = env_config(config).action_count
    for team in learning_teams(config):
        runner, settings = team_runner(config, team), team_settings(config, team)
        if settings["critic"] != "local":
            return f"the {team} critic reads a second observation group (critic={settings['critic']!r})"
        algorithm = runner.get("algorithm", {})
        if algorithm.get("schedule") == "adaptive" and algorithm.get("desired_kl") is not None:
            return "the adaptive learning-rate schedule reads each mini-batch's KL divergence"
        for key, why in (
            ("use_mixed_precision", "mixed precision (autocast)"),
            ("rnd_cfg", "RND"),
            ("symmetry_cfg", "symmetry"),
        ):
            if algorithm.get(key):
                return f"{why} is not fused (runner.algorithm.{key})"
        for part, outputs in (("actor", action_count), ("critic", 1)):
            model = runner.get(part, {})
            name = model.get("class_name", TORCH_MLP_MODELS[0])
            if name not in TORCH_MLP_MODELS:
                return f"the {team} {part} is {name!r}, not rsl-rl's MLPModel"
            if model.get("obs_normalization"):
                return f"the {team} {part}'s observation normalisation is not fused"
            if model.get("activation", "elu") not in ACTIVATIONS.values():
                return f"the {team} {part}'s activation {model.get('activation')!r} is not tanh, relu or elu"
            problem = widths_problem([*model.get("hidden_dims", []), outputs])
            if problem is not None:
                return f"the {team} {part}'s {problem}"
        distribution = runner.get("actor", {}).get("distribution_cfg", {}).get("class_name", DISTRIBUTION)
        if distribution != DISTRIBUTION:
            return f"the {team} actor's distribution {distribution!r} is not CategoricalDistribution"
    return None


@dataclass(frozen=True)
class FastPath:
    """A run's resolved path: the fused MLP (with the fused loss and rollout step where they serve) or
    torch's, TF32 or float32 products, and why."""

    fused_mlp: bool
    tf32: bool
    reason: str
    requested: tuple[bool | str, bool | str]  # train.fused_mlp, train.tf32 as the config gives them

    def describe(self) -> str:
        products = "TF32" if self.tf32 else "float32"
        return f"fused MLP + loss, {products}" if self.fused_mlp else f"torch {products}"

    def line(self) -> str:
        """The line `train` prints first: `path: <describe> (<reason>)`."""
        return f"path: {self.describe()} ({self.reason})"

    def record(self) -> dict:
        """`config.json`'s `path` entry: the requested settings, the resolved ones and why."""
        return {
            "requested": dict(zip(SWITCHES, self.requested)),
            "fused_mlp": self.fused_mlp,
            "tf32": self.tf32,
            "reason": self.reason,
        }


def _setting(name: str, value: bool | str) -> str:
    return f"train.{name}={str(value).lower() if isinstance(value, bool) else value}"


def resolve_fast_path(config: dict, device_type: str) -> FastPath:
    """The path a run of `config` (validated) takes on a device of type `device_type` ("cpu", "cuda")."""
    fused, tf32 = (config["train"][name] for name in SWITCHES)
    reasons = []
    if fused == AUTO:
        if device_type != "cuda":
            why = device_type
        elif not triton_imports():
            why = "cuda without triton"
        else:
            problem = fused_config_problem(config)
            why = "cuda with triton" if problem is None else problem
        fused = why == "cuda with triton"
        reasons.append(f"auto: {why}")
    else:
        reasons.append(_setting("fused_mlp", fused))
    if tf32 == AUTO:
        tf32 = fused and device_type == "cuda"
        if config["train"]["fused_mlp"] != AUTO:  # else the reason above says it
            reasons.append(f"train.tf32=auto: {'TF32 with the fused MLP on cuda' if tf32 else 'float32'}")
    else:
        reasons.append(_setting("tf32", tf32))
    requested = (config["train"]["fused_mlp"], config["train"]["tf32"])
    return FastPath(bool(fused), bool(tf32), "; ".join(reasons), requested)
