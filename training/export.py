"""Export of trained policies (TorchScript, ONNX) and `load_policy`, which maps observations to actions.

```python
from aquarium_warp.training import load_policy

policy = load_policy("runs/prey/exported/policy.pt")     # or policy.onnx, or a checkpoint model_N.pt
actions = policy(obs)            # obs [N, L] float32 tensor (or numpy) -> actions [N] int64, same device
policy.meta                      # team, observation_size, action_count, group_size, sharing, env config
```

Exported files (written by `export_policy`, next to a `policy.json` with the same metadata):
- `policy.pt`, TorchScript: `forward(obs [N, L]) -> actions [N] int64` (argmax) and `logits(obs)`
  `-> [N, action_count]`; the metadata is embedded as the extra file `aquarium_policy.json`.
- `policy.onnx`: input `obs` `[N, L]`, outputs `actions` `[N]` int64 and `logits` `[N, action_count]`,
  the metadata in the model's `metadata_props`; `load_policy` runs it with onnxruntime (on the CPU).

Individual Learning policies (`group_size` S > 1) take rows in world-major slot order: N must be a
multiple of S, row `k` acting for slot `k % S` (one world of the PettingZoo env: its S agents in
slot order).

`load_policy(..., deterministic=False, seed=s)` samples actions from the logits with its own torch
generator instead of taking the argmax.
"""

from __future__ import annotations

import copy
import json
import os
import warnings
import zipfile

import numpy as np
import torch
import torch.nn as nn

from . import _rsl  # noqa: F401

META_NAME = "aquarium_policy.json"


class ExportablePolicy(nn.Module):
    """The actor's observation normaliser and MLP: `forward(obs) -> argmax actions [N]`, `logits(obs)`."""

    def __init__(self, actor: nn.Module) -> None:
        super().__init__()
        self.obs_normalizer = copy.deepcopy(actor.obs_normalizer).cpu()
        self.mlp = copy.deepcopy(actor.mlp).cpu()
        self.eval()

    @torch.jit.export
    def logits(self, obs: torch.Tensor) -> torch.Tensor:
        return self.mlp(self.obs_normalizer(obs))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.argmax(self.logits(obs), dim=-1)


class _OnnxPolicy(nn.Module):
    def __init__(self, policy: ExportablePolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, obs: torch.Tensor):
        logits = self.policy.logits(obs)
        return torch.argmax(logits, dim=-1), logits


def policy_meta(config: dict, slots: int, observation_size: int, action_count: int) -> dict:
    """Metadata stored with an exported policy."""
    train = config["train"]
    return {
        "format_version": 1,
        "team": train["team"],
        "observation_size": int(observation_size),
        "action_count": int(action_count),
        "sharing": train["sharing"],
        "group_size": int(slots) if train["sharing"] == "individual" else 1,
        "env": config.get("env", {}),
        "config": config,
    }


def export_policy(actor: nn.Module, meta: dict, out_dir: str, formats=("jit", "onnx")) -> dict[str, str]:
    """Write the actor as `policy.pt` (TorchScript) and/or `policy.onnx` plus `policy.json` into
    `out_dir`; returns `{format: path}`."""
    os.makedirs(out_dir, exist_ok=True)
    module = ExportablePolicy(actor)
    meta_text = json.dumps(meta, indent=1, default=str)
    with open(os.path.join(out_dir, "policy.json"), "w", encoding="utf-8") as f:
        f.write(meta_text)
    paths = {}
    if "jit" in formats:
        path = os.path.join(out_dir, "policy.pt")
        with warnings.catch_warnings():  # TorchScript is deprecated in torch >= 2.10, still supported
            warnings.simplefilter("ignore", DeprecationWarning)
            scripted = torch.jit.script(module)
            torch.jit.save(scripted, path, _extra_files={META_NAME: meta_text})
        paths["jit"] = path
    if "onnx" in formats:
        paths["onnx"] = _export_onnx(module, meta, meta_text, os.path.join(out_dir, "policy.onnx"))
    return paths


def _export_onnx(module: ExportablePolicy, meta: dict, meta_text: str, path: str) -> str:
    import onnx

    wrapper = _OnnxPolicy(module).eval()
    group = int(meta.get("group_size", 1))
    L = int(meta["observation_size"])
    dummy = torch.zeros(2 * group, L)
    batch = torch.export.Dim("worlds", min=1) * group if group > 1 else torch.export.Dim("rows", min=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        torch.onnx.export(wrapper, (dummy,), path, input_names=["obs"], output_names=["actions", "logits"],
                          dynamic_shapes={"obs": {0: batch}}, opset_version=18, dynamo=True,
                          external_data=False, verbose=False)
    model = onnx.load(path)
    entry = model.metadata_props.add()
    entry.key, entry.value = META_NAME, meta_text
    onnx.save(model, path)
    return path


class LoadedPolicy:
    """A policy loaded by `load_policy`: `policy(obs [N, L]) -> actions [N]` (int64, on obs' device)."""

    def __init__(self, logits_fn, meta: dict, kind: str, device: torch.device, deterministic: bool = True,
                 seed: int = 0, module=None):
        self._logits_fn, self.meta, self.kind, self.device = logits_fn, meta, kind, torch.device(device)
        self.module = module
        self.deterministic = deterministic
        self.team = meta.get("team")
        self.observation_size = int(meta["observation_size"])
        self.action_count = int(meta["action_count"])
        self.group_size = int(meta.get("group_size", 1))
        self._generator = None
        if not deterministic:
            self._generator = torch.Generator(device=self.device if self.kind != "onnx" else "cpu")
            self._generator.manual_seed(int(seed))

    def __repr__(self) -> str:
        return (f"LoadedPolicy({self.kind}, team={self.team!r}, obs={self.observation_size}, "
                f"actions={self.action_count}, group_size={self.group_size}, deterministic={self.deterministic})")

    def check_compatible(self, team: str | None, observation_size: int, action_count: int, slots: int) -> None:
        """Raise `ValueError` if this policy cannot act for `slots` agents per world of that kind."""
        if team is not None and self.team is not None and team != self.team:
            raise ValueError(f"policy was trained for {self.team!r}, not {team!r}")
        if observation_size != self.observation_size:
            raise ValueError(f"policy expects observations of length {self.observation_size}, env gives {observation_size}")
        if action_count != self.action_count:
            raise ValueError(f"policy has {self.action_count} actions, env has {action_count}")
        if self.group_size > 1 and slots != self.group_size:
            raise ValueError(f"Individual-Learning policy has {self.group_size} per-slot networks, "
                             f"env has {slots} {team} slots per world")

    def logits(self, obs) -> torch.Tensor:
        obs = torch.as_tensor(obs, dtype=torch.float32)
        if obs.dim() != 2 or obs.shape[1] != self.observation_size:
            raise ValueError(f"observations must be [N, {self.observation_size}], got {list(obs.shape)}")
        return self._logits_fn(obs)

    def __call__(self, obs) -> torch.Tensor:
        out_device = obs.device if isinstance(obs, torch.Tensor) else torch.device("cpu")
        logits = self.logits(obs)
        if self.deterministic:
            actions = torch.argmax(logits, dim=-1)
        else:
            probs = torch.softmax(logits.to(self._generator.device), dim=-1)
            actions = torch.multinomial(probs, 1, replacement=True, generator=self._generator).squeeze(-1)
        return actions.to(out_device)

    def act(self, observations) -> dict[str, int]:
        """Actions for one team's PettingZoo observations (`{"prey_0": obs, ...}`, e.g. from
        `aquarium_v1.parallel_env`): `{name: action}`. Individual-Learning policies need every slot
        of the team, in slot order (one world)."""
        names = list(observations)
        if not names:
            return {}
        if self.group_size > 1 and len(names) != self.group_size:
            raise ValueError(f"an Individual-Learning policy acts for exactly {self.group_size} agents "
                             f"(every slot, in order), got {len(names)}")
        actions = self(np.stack([np.asarray(observations[name], dtype=np.float32) for name in names]))
        return dict(zip(names, actions.cpu().tolist()))

    def rng_state(self):
        return None if self._generator is None else self._generator.get_state()

    def set_rng_state(self, state) -> None:
        if self._generator is not None and state is not None:
            self._generator.set_state(state.cpu())


def _is_torchscript(path: str) -> bool:
    if not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as z:
        return any(name.endswith("constants.pkl") or "/code/" in name for name in z.namelist())


def load_policy(path: str, device="cpu", deterministic: bool = True, seed: int = 0) -> LoadedPolicy:
    """Load an exported policy (`.pt` TorchScript, `.onnx`) or a training checkpoint (`model_N.pt`).

    Returns a `LoadedPolicy`: call it on observations `[N, L]` to get actions `[N]` (int64). TorchScript
    and checkpoints run on `device`; ONNX runs with onnxruntime on the CPU (inputs are moved there and
    the actions moved back)."""
    if not os.path.isfile(path):
        raise ValueError(f"policy file {path!r} does not exist")
    device = torch.device(device)
    if path.endswith(".onnx"):
        return _load_onnx(path, deterministic, seed)
    if _is_torchscript(path):
        extra = {META_NAME: ""}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            module = torch.jit.load(path, map_location=device, _extra_files=extra)
        module.eval()
        meta = json.loads(extra[META_NAME]) if extra[META_NAME] else _sidecar_meta(path)
        return LoadedPolicy(_module_logits(module, device), meta, "jit", device, deterministic, seed, module=module)
    return _load_checkpoint(path, device, deterministic, seed)


def _module_logits(module, device: torch.device):
    """`obs -> logits` of a TorchScript or `ExportablePolicy` module on `device`."""

    def logits_fn(obs: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            return module.logits(obs.to(device))

    return logits_fn


def _sidecar_meta(path: str) -> dict:
    side = os.path.join(os.path.dirname(path), "policy.json")
    if not os.path.isfile(side):
        raise ValueError(f"{path}: no embedded metadata and no policy.json beside it")
    with open(side, encoding="utf-8") as f:
        return json.load(f)


def _load_onnx(path: str, deterministic: bool, seed: int) -> LoadedPolicy:
    try:
        import onnxruntime as ort
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ValueError("loading .onnx policies needs onnxruntime (pip install onnxruntime); "
                         "the TorchScript policy.pt beside it needs nothing extra") from error
    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    custom = session.get_modelmeta().custom_metadata_map
    meta = json.loads(custom[META_NAME]) if META_NAME in custom else _sidecar_meta(path)

    def logits_fn(obs: torch.Tensor) -> torch.Tensor:
        x = obs.detach().to("cpu", torch.float32).contiguous().numpy()
        logits = session.run(["logits"], {"obs": x})[0]
        return torch.from_numpy(np.asarray(logits))

    return LoadedPolicy(logits_fn, meta, "onnx", torch.device("cpu"), deterministic, seed, module=session)


def actor_from_checkpoint(checkpoint: dict, device="cpu") -> tuple[nn.Module, dict]:
    """Rebuild the actor of a training checkpoint (written by `Trainer`); returns `(actor, meta)`."""
    from rsl_rl.utils import resolve_class
    from tensordict import TensorDict

    state = (checkpoint.get("infos") or {}).get("aquarium")
    if not state or "config" not in state or "runner_cfg" not in state:
        raise ValueError("checkpoint was not written by aquarium_warp.training (no run config in it)")
    meta = state["policy_meta"]
    obs = TensorDict({"policy": torch.zeros(1, meta["observation_size"])}, batch_size=[1])
    actor_class, actor_cfg = resolve_class(state["runner_cfg"]["actor"])
    actor = actor_class(obs, {"actor": ["policy"], "critic": ["policy"]}, "actor", 1, **actor_cfg)
    actor.load_state_dict(checkpoint["actor_state_dict"])
    return actor.to(device).eval(), meta


def _load_checkpoint(path: str, device: torch.device, deterministic: bool, seed: int) -> LoadedPolicy:
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:
        raise ValueError(f"{path}: neither a TorchScript policy nor a training checkpoint ({error})") from error
    if not isinstance(checkpoint, dict) or "actor_state_dict" not in checkpoint:
        raise ValueError(f"{path}: not a training checkpoint (no actor_state_dict)")
    actor, meta = actor_from_checkpoint(checkpoint, device)
    module = ExportablePolicy(actor).to(device)
    return LoadedPolicy(_module_logits(module, device), meta, "checkpoint", device, deterministic, seed,
                        module=module)
