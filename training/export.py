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

Recurrent policies (rsl-rl's `RNNModel`, GRU or LSTM; `meta["recurrent"]` holds its type and sizes)
are exported as a step function with explicit states, as rsl-rl's ONNX export of them: `policy.pt`'s
`step(obs [N, L], h [layers, N, H], c [layers, N, H]) -> (logits, h, c)` (`c` is unused and returned
unchanged for a GRU), `forward(obs, h, c) -> (actions, h, c)` and `initial_state(obs) -> (h, c)` (zeros);
`policy.onnx` has inputs `obs`, `h_in` (and `c_in` for an LSTM) and outputs `actions`, `logits`,
`h_out` (and `c_out`). `load_policy` keeps the state of each row between calls (each call is one
step; the first starts from zeros, as rsl-rl's rollouts do) and `policy.reset(dones)` zeroes the rows
whose episode ended (`reset()`: all rows, e.g. after an env reset). `drivers.RecurrentOpponent` does
those resets for a team of a `BatchedAquarium` (evaluation, `aquarium-warp video`).

Individual Learning policies (`group_size` S > 1) take rows in world-major slot order: N must be a
multiple of S, row `k` acting for slot `k % S` (one world of the PettingZoo env: its S agents in
slot order).

`load_policy(..., deterministic=False, seed=s)` samples actions from the logits with its own torch
generator instead of taking the argmax.
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
import os
import warnings
import zipfile
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn as nn

from ..agent_types import TYPES
from ..atomic import atomic_open, atomic_path
from ..config import AquariumConfig
from ..pretrained import resolve
from . import _rsl  # noqa: F401

if TYPE_CHECKING:
    from rsl_rl.models import MLPModel, RNNModel

META_NAME = "aquarium_policy.json"


class ExportablePolicy(nn.Module):
    """The actor's observation normaliser and MLP: `forward(obs) -> argmax actions [N]`, `logits(obs)`."""

    def __init__(self, actor: MLPModel) -> None:
        super().__init__()
        self.obs_normalizer: nn.Module = copy.deepcopy(actor.obs_normalizer).cpu()
        self.mlp: nn.Module = copy.deepcopy(actor.mlp).cpu()
        self.eval()

    @torch.jit.export
    def logits(self, obs: torch.Tensor) -> torch.Tensor:
        return self.mlp(self.obs_normalizer(obs))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.argmax(self.logits(obs), dim=-1)


class _RecurrentPolicy(nn.Module):
    """The actor's observation normaliser, GRU/LSTM and MLP as a step function with explicit per-row
    states (see the module doc); `_GRUPolicy` / `_LSTMPolicy` differ in how the RNN takes its state."""

    def __init__(self, actor: RNNModel) -> None:
        super().__init__()
        self.obs_normalizer: nn.Module = copy.deepcopy(actor.obs_normalizer).cpu()
        self.rnn: nn.RNNBase = copy.deepcopy(actor.rnn.rnn).cpu()  # the torch module inside rsl-rl's RNN wrapper
        self.mlp: nn.Module = copy.deepcopy(actor.mlp).cpu()
        self.num_layers, self.hidden_size = int(self.rnn.num_layers), int(self.rnn.hidden_size)
        self.eval()

    @torch.jit.export
    def initial_state(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Zero states `(h, c)` `[layers, N, H]` for the rows of `obs` `[N, L]`, on its device."""
        h = torch.zeros(self.num_layers, obs.shape[0], self.hidden_size, device=obs.device)
        return h, torch.zeros_like(h)

    def _rnn(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    @torch.jit.export
    def step(
        self, obs: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        y, h, c = self._rnn(self.obs_normalizer(obs).unsqueeze(0), h, c)
        return self.mlp(y.squeeze(0)), h, c

    def forward(
        self, obs: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        logits, h, c = self.step(obs, h, c)
        return torch.argmax(logits, dim=-1), h, c


class _GRUPolicy(_RecurrentPolicy):
    def _rnn(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        y, h = self.rnn(x, h)
        return y, h, c


class _LSTMPolicy(_RecurrentPolicy):
    def _rnn(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        y, (h, c) = self.rnn(x, (h, c))
        return y, h, c


def recurrent_meta(actor: MLPModel) -> dict | None:
    """`{"rnn_type", "num_layers", "hidden_size"}` of a recurrent rsl-rl actor, None for a feed-forward one."""
    if not getattr(actor, "is_recurrent", False):
        return None
    rnn = actor.rnn.rnn
    if not isinstance(rnn, (nn.GRU, nn.LSTM)):
        raise ValueError(f"recurrent actor with a {type(rnn).__name__}: only GRU and LSTM can be exported")
    return {
        "rnn_type": "lstm" if isinstance(rnn, nn.LSTM) else "gru",
        "num_layers": int(rnn.num_layers),
        "hidden_size": int(rnn.hidden_size),
    }


def exportable(actor: MLPModel) -> ExportablePolicy | _GRUPolicy | _LSTMPolicy:
    """The CPU module that `export_policy` scripts: `ExportablePolicy` or a recurrent step function."""
    info = recurrent_meta(actor)
    if info is None:
        return ExportablePolicy(actor)
    return (_LSTMPolicy if info["rnn_type"] == "lstm" else _GRUPolicy)(actor)


class _OnnxPolicy(nn.Module):
    def __init__(self, policy: ExportablePolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, obs: torch.Tensor):
        logits = self.policy.logits(obs)
        return torch.argmax(logits, dim=-1), logits


class _OnnxGRUPolicy(nn.Module):
    def __init__(self, policy: _GRUPolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, obs: torch.Tensor, h_in: torch.Tensor):
        logits, h, _ = self.policy.step(obs, h_in, h_in)  # a GRU has no cell state: `c` goes unused
        return torch.argmax(logits, dim=-1), logits, h


class _OnnxLSTMPolicy(nn.Module):
    def __init__(self, policy: _LSTMPolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, obs: torch.Tensor, h_in: torch.Tensor, c_in: torch.Tensor):
        logits, h, c = self.policy.step(obs, h_in, c_in)
        return torch.argmax(logits, dim=-1), logits, h, c


def policy_meta(config: dict, slots: int, observation_size: int, action_count: int, team: str | None = None) -> dict:
    """Metadata stored with an exported policy of `team` (default: the run's one learning team)."""
    from .config import team_settings

    team = config["train"]["team"] if team is None else team
    train = team_settings(config, team)
    return {
        "format_version": 1,
        "team": team,
        "observation_size": int(observation_size),
        "action_count": int(action_count),
        "sharing": train["sharing"],
        "group_size": int(slots) if train["sharing"] == "individual" else 1,
        "env": config.get("env", {}),
        "config": config,
    }


def export_policy(actor: MLPModel, meta: dict, out_dir: str, formats=("jit", "onnx")) -> dict[str, str]:
    """Write the actor as `policy.pt` (TorchScript) and/or `policy.onnx` plus `policy.json` into
    `out_dir`; returns `{format: path}`."""
    os.makedirs(out_dir, exist_ok=True)
    module = exportable(actor)
    meta = {**meta, "recurrent": recurrent_meta(actor)}
    meta_text = json.dumps(meta, indent=1, default=str)
    with atomic_open(os.path.join(out_dir, "policy.json")) as f:
        f.write(meta_text)
    paths = {}
    if "jit" in formats:
        path = os.path.join(out_dir, "policy.pt")
        with warnings.catch_warnings():  # TorchScript is deprecated in torch >= 2.10, still supported
            warnings.simplefilter("ignore", DeprecationWarning)
            scripted = torch.jit.script(module)
            with atomic_path(path) as partial:
                torch.jit.save(scripted, partial, _extra_files={META_NAME: meta_text})
        paths["jit"] = path
    if "onnx" in formats:
        paths["onnx"] = _export_onnx(module, meta, meta_text, os.path.join(out_dir, "policy.onnx"))
    return paths


def _export_onnx(module: ExportablePolicy | _GRUPolicy | _LSTMPolicy, meta: dict, meta_text: str, path: str) -> str:
    import onnx

    group = int(meta.get("group_size", 1))
    L = int(meta["observation_size"])
    dummy = torch.zeros(2 * group, L)
    batch = torch.export.Dim("worlds", min=1) * group if group > 1 else torch.export.Dim("rows", min=1)
    wrapper: nn.Module
    args: tuple[torch.Tensor, ...]
    if isinstance(module, ExportablePolicy):
        wrapper, args, inputs, outputs = _OnnxPolicy(module), (dummy,), ["obs"], ["actions", "logits"]
        dynamic = {"obs": {0: batch}}
    else:
        state = module.initial_state(dummy)
        if isinstance(module, _LSTMPolicy):
            wrapper, args, names = _OnnxLSTMPolicy(module), (dummy, *state), ["h_in", "c_in"]
        else:
            wrapper, args, names = _OnnxGRUPolicy(module), (dummy, state[0]), ["h_in"]
        inputs = ["obs"] + names
        outputs = ["actions", "logits"] + [n.replace("_in", "_out") for n in names]
        dynamic = {"obs": {0: batch}, **{n: {1: batch} for n in names}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        # torch.export's notes on the RNN's flat weights and on the shared row axis: harmless here.
        warnings.filterwarnings("ignore", message="The tensor attributes", category=UserWarning)
        warnings.filterwarnings("ignore", message="# The axis name", category=UserWarning)
        with _without_torchvision_notes(), atomic_path(path) as partial:
            torch.onnx.export(
                wrapper.eval(),
                args,
                partial,
                input_names=inputs,
                output_names=outputs,
                dynamic_shapes=dynamic,
                opset_version=18,
                dynamo=True,
                external_data=False,
                verbose=False,
            )
            model = onnx.load(partial)
            entry = model.metadata_props.add()
            entry.key, entry.value = META_NAME, meta_text
            onnx.save(model, partial)
    return path


@contextlib.contextmanager
def _without_torchvision_notes():
    """torch.onnx's exporter logs a warning for each torchvision operator it cannot register when
    torchvision is not installed (four lines per export); a policy uses none of them."""
    log = logging.getLogger("torch.onnx._internal.exporter._registration")

    def keep(record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("torchvision is not installed")

    log.addFilter(keep)
    try:
        yield
    finally:
        log.removeFilter(keep)


def world_interface(env: dict, team: str) -> dict[str, object]:
    """What `team`'s observation rows and actions mean in worlds of `env` (an `AquariumConfig.to_dict()`,
    or a run config's `env` section of the fields that differ from the defaults), by each field's
    `--set` name: the frames, observation range, flow observation and slot split
    (`AquariumConfig.with_interface_of`'s fields). Worlds that differ in anything else (arena, counts,
    speeds, views) give a policy observations of the same meaning: cross-play and the studies vary those."""
    # A field missing from a policy's `env` is AquariumConfig's default: it was left out as the default,
    # or the policy predates the field, and each of these fields came with the default that keeps the
    # worlds before it (the shipped prey-a/b/c name no action frame and no flow: "world", off).
    defaults = AquariumConfig()
    names = ("observation_frame", "action_frame", "observation_range", "observe_flow")
    interface = {f"env.{name}": env.get(name, getattr(defaults, name)) for name in names}
    own = env.get(team) or {}
    for name in ("predator_slots", "prey_slots"):
        interface[f"env.{team}.{name}"] = own.get(name, getattr(getattr(defaults, team), name))
    return interface


class LoadedPolicy:
    """A policy loaded by `load_policy`: `policy(obs [N, L]) -> actions [N]` (int64, on obs' device).

    `logits_fn(obs) -> logits`, or for a recurrent policy `logits_fn(obs, (h, c)) -> (logits, (h, c))`
    with the states `[layers, N, H]` that this object keeps between calls (see the module doc)."""

    def __init__(
        self,
        logits_fn,
        meta: dict,
        kind: str,
        device: torch.device,
        deterministic: bool = True,
        seed: int = 0,
        module=None,
    ):
        self._logits_fn, self.meta, self.kind, self.device = logits_fn, meta, kind, torch.device(device)
        self.module = module
        self.deterministic = deterministic
        self.team = meta.get("team")
        self.observation_size = int(meta["observation_size"])
        self.action_count = int(meta["action_count"])
        self.group_size = int(meta.get("group_size", 1))
        self.recurrent = meta.get("recurrent")  # None, or {"rnn_type", "num_layers", "hidden_size"}
        self._state: tuple[torch.Tensor, torch.Tensor] | None = None  # per-row (h, c) of a recurrent policy
        self._generator = None
        if not deterministic:
            self._generator = torch.Generator(device=self.device if self.kind != "onnx" else "cpu")
            self._generator.manual_seed(int(seed))

    def __repr__(self) -> str:
        return (
            f"LoadedPolicy({self.kind}, team={self.team!r}, obs={self.observation_size}, "
            f"actions={self.action_count}, group_size={self.group_size}, deterministic={self.deterministic})"
        )

    def check_compatible(self, team: str, config: AquariumConfig, slots: int) -> None:
        """Raise `ValueError` if this policy cannot act for `team`'s `slots` agents per world of `config`:
        another team, another world interface (`world_interface`) or another observation length."""
        if self.team is not None and team != self.team:
            raise ValueError(f"policy was trained for {self.team!r}, not {team!r}")
        # the action count from the network's output size, which the metadata always records
        trained = {**world_interface(self.meta.get("env", {}), team), "env.action_count": self.action_count}
        given = {**world_interface(config.to_dict(), team), "env.action_count": config.action_count}
        differing = [f"{name} {trained[name]!r} vs {given[name]!r}" for name in trained if trained[name] != given[name]]
        size = config.observation_size(team)
        if differing:
            lengths = (
                f"; observations of length {self.observation_size} vs {size}" if size != self.observation_size else ""
            )
            raise ValueError(
                f"policy's world interface differs from the env's (policy's value vs env's): "
                f"{', '.join(differing)}{lengths}"
            )
        if size != self.observation_size:  # the interface agrees: metadata that does not match its own policy
            raise ValueError(f"policy expects observations of length {self.observation_size}, env gives {size}")
        if self.group_size > 1 and slots != self.group_size:
            raise ValueError(
                f"Individual-Learning policy has {self.group_size} per-slot networks, "
                f"env has {slots} {team} slots per world"
            )

    def logits(self, obs) -> torch.Tensor:
        """Logits `[N, action_count]`; for a recurrent policy this is one step (it advances the state)."""
        obs = torch.as_tensor(obs, dtype=torch.float32)
        if obs.dim() != 2 or obs.shape[1] != self.observation_size:
            raise ValueError(f"observations must be [N, {self.observation_size}], got {list(obs.shape)}")
        if self.recurrent is None:
            return self._logits_fn(obs)
        rows = obs.shape[0]
        if self._state is None:  # a fresh episode for every row, as rsl-rl's rollouts start
            shape = (int(self.recurrent["num_layers"]), rows, int(self.recurrent["hidden_size"]))
            self._state = (torch.zeros(shape, device=self.device), torch.zeros(shape, device=self.device))
        elif self._state[0].shape[1] != rows:
            raise ValueError(
                f"recurrent policy holds hidden states for {self._state[0].shape[1]} rows, got "
                f"{rows}: call reset() first to start over with other rows"
            )
        logits, self._state = self._logits_fn(obs, self._state)
        return logits

    def reset(self, dones=None) -> None:
        """Recurrent policies: zero the hidden state of the rows where `dones [N]` is true (their agent's
        episode ended), or forget every row's state (`dones=None`). Feed-forward policies: nothing."""
        if self._state is None:
            return
        if dones is None:
            self._state = None
            return
        mask = torch.as_tensor(dones).to(self._state[0].device).reshape(-1).bool()
        if mask.numel() != self._state[0].shape[1]:
            raise ValueError(f"dones must have one entry per row ({self._state[0].shape[1]}), got {mask.numel()}")
        h, c = self._state
        self._state = (torch.where(mask.view(1, -1, 1), 0.0, h), torch.where(mask.view(1, -1, 1), 0.0, c))

    @property
    def hidden_state(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Recurrent policies: the rows' `(h, c)` `[layers, N, H]` after the last call (None before);
        assignable (e.g. from a checkpoint)."""
        return self._state

    @hidden_state.setter
    def hidden_state(self, state) -> None:
        if state is None:
            self._state = None
        else:
            h, c = state
            self._state = (torch.as_tensor(h).to(self.device), torch.as_tensor(c).to(self.device))

    def __call__(self, obs) -> torch.Tensor:
        out_device = obs.device if isinstance(obs, torch.Tensor) else torch.device("cpu")
        logits = self.logits(obs)
        if self._generator is None:  # deterministic
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
            raise ValueError(
                f"an Individual-Learning policy acts for exactly {self.group_size} agents "
                f"(every slot, in order), got {len(names)}"
            )
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


def load_policy(
    path: str, device="cpu", deterministic: bool = True, seed: int = 0, team: str | None = None
) -> LoadedPolicy:
    """Load an exported policy (`.pt` TorchScript, `.onnx`) or a training checkpoint (`model_N.pt`).

    Returns a `LoadedPolicy`: call it on observations `[N, L]` to get actions `[N]` (int64). TorchScript
    and checkpoints run on `device`; ONNX runs with onnxruntime on the CPU (inputs are moved there and
    the actions moved back). `team` picks one learner of a checkpoint of both teams (required there);
    for any other file it must be the policy's own team, if given. `path` may name a shipped policy
    (`aquarium_warp.pretrained`)."""
    path = resolve(path)
    if not os.path.isfile(path):
        raise ValueError(f"policy file {path!r} does not exist")
    if team is not None and team not in TYPES:
        raise ValueError(f"team={team!r} must be 'prey', 'predator' or None")
    device = torch.device(device)
    if path.endswith(".onnx"):
        return _checked_team(_load_onnx(path, deterministic, seed), team, path)
    if _is_torchscript(path):
        extra = {META_NAME: ""}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            module = _unreadable_as_value_error(path, torch.jit.load, path, map_location=device, _extra_files=extra)
        module.eval()
        meta = json.loads(extra[META_NAME]) if extra[META_NAME] else _sidecar_meta(path)
        return _checked_team(
            LoadedPolicy(_module_logits(module, device, meta), meta, "jit", device, deterministic, seed, module=module),
            team,
            path,
        )
    return _checked_team(_load_checkpoint(path, device, deterministic, seed, team), team, path)


def _unreadable_as_value_error(path: str, read, *args, **kwargs):
    """`read(*args, **kwargs)`; a damaged or foreign file is a one-line ValueError naming `path`."""
    try:
        return read(*args, **kwargs)
    except Exception as error:  # noqa: BLE001 - torch and onnxruntime raise many kinds for a damaged file
        reason = (str(error).strip().splitlines() or [""])[0][:200]
        raise ValueError(
            f"{path}: not a readable policy file (a TorchScript or ONNX policy, or a training "
            f"checkpoint; {type(error).__name__}: {reason})"
        ) from None


def _checked_team(policy: LoadedPolicy, team: str | None, path: str) -> LoadedPolicy:
    if team is not None and policy.team is not None and policy.team != team:
        raise ValueError(f"{path}: policy was trained for {policy.team!r}, not {team!r}")
    return policy


def _module_logits(module, device: torch.device, meta: dict):
    """`LoadedPolicy`'s `logits_fn` of a TorchScript or `exportable()` module on `device`."""
    if meta.get("recurrent") is not None:

        def step_fn(obs: torch.Tensor, state):
            with torch.inference_mode():
                logits, h, c = module.step(obs.to(device), *state)
            return logits, (h, c)

        return step_fn

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
        raise ValueError(
            "loading .onnx policies needs onnxruntime (pip install onnxruntime); "
            "the TorchScript policy.pt beside it needs nothing extra"
        ) from error
    session = _unreadable_as_value_error(path, ort.InferenceSession, path, providers=["CPUExecutionProvider"])
    custom = session.get_modelmeta().custom_metadata_map
    meta = json.loads(custom[META_NAME]) if META_NAME in custom else _sidecar_meta(path)

    def numpy(x: torch.Tensor) -> np.ndarray:
        return x.detach().to("cpu", torch.float32).contiguous().numpy()

    def logits_fn(obs: torch.Tensor) -> torch.Tensor:
        logits = session.run(["logits"], {"obs": numpy(obs)})[0]
        return torch.from_numpy(np.asarray(logits))

    def step_fn(obs: torch.Tensor, state):
        inputs = {"obs": numpy(obs), "h_in": numpy(state[0])}
        if lstm:
            inputs["c_in"] = numpy(state[1])
        outputs = session.run(["logits", "h_out"] + (["c_out"] if lstm else []), inputs)
        logits, h = (torch.from_numpy(np.asarray(o)) for o in outputs[:2])
        return logits, (h, torch.from_numpy(np.asarray(outputs[2])) if lstm else state[1])

    recurrent = meta.get("recurrent")
    lstm = recurrent is not None and recurrent["rnn_type"] == "lstm"
    return LoadedPolicy(
        logits_fn if recurrent is None else step_fn,
        meta,
        "onnx",
        torch.device("cpu"),
        deterministic,
        seed,
        module=session,
    )


def policy_world(path: str) -> dict:
    """The `env` settings (the run config's section) a policy file was trained in; for a checkpoint of
    both teams no team needs naming (both share the world); `path` may name a shipped policy."""
    path = resolve(path)
    if not path.endswith(".onnx") and os.path.isfile(path) and not _is_torchscript(path):
        checkpoint = _unreadable_as_value_error(path, torch.load, path, map_location="cpu", weights_only=False)
        state = (checkpoint.get("infos") or {}).get("aquarium") if isinstance(checkpoint, dict) else None
        if isinstance(state, dict) and "config" in state:
            return state["config"].get("env", {})
    return load_policy(path).meta.get("env", {})


def actor_from_checkpoint(checkpoint: dict, device="cpu", team: str | None = None) -> tuple[nn.Module, dict]:
    """Rebuild the actor of a training checkpoint (written by `Trainer`); returns `(actor, meta)`.
    `team` picks the learner of a checkpoint of both teams (required there)."""
    from rsl_rl.utils import resolve_class
    from tensordict import TensorDict

    state = (checkpoint.get("infos") or {}).get("aquarium")
    if not state or "config" not in state or ("runner_cfg" not in state and "teams" not in state):
        raise ValueError("checkpoint was not written by aquarium_warp.training (no run config in it)")
    saved = checkpoint
    if "teams" in state:  # both teams learned: one entry per team
        if team not in state["teams"]:
            raise ValueError(f"the checkpoint holds the policies of {sorted(state['teams'])}: name one as team=")
        state, saved = state["teams"][team], checkpoint["learners"][team]
    meta = state["policy_meta"]
    obs = TensorDict({"policy": torch.zeros(1, meta["observation_size"])}, batch_size=[1])
    actor_class, actor_cfg = resolve_class(state["runner_cfg"]["actor"])
    actor = actor_class(obs, {"actor": ["policy"], "critic": ["policy"]}, "actor", 1, **actor_cfg)
    actor.load_state_dict(saved["actor_state_dict"])
    return actor.to(device).eval(), meta


def policy_from_actor(actor: nn.Module, meta: dict, device, deterministic: bool = True, seed: int = 0) -> LoadedPolicy:
    """A `LoadedPolicy` acting with a copy of a trained rsl-rl actor (e.g. the live one of a run)."""
    device = torch.device(device)
    module = exportable(actor).to(device)
    meta = {**meta, "recurrent": recurrent_meta(actor)}
    return LoadedPolicy(
        _module_logits(module, device, meta), meta, "checkpoint", device, deterministic, seed, module=module
    )


def _load_checkpoint(
    path: str, device: torch.device, deterministic: bool, seed: int, team: str | None = None
) -> LoadedPolicy:
    checkpoint = _unreadable_as_value_error(path, torch.load, path, map_location="cpu", weights_only=False)
    if not isinstance(checkpoint, dict) or ("actor_state_dict" not in checkpoint and "learners" not in checkpoint):
        raise ValueError(f"{path}: not a training checkpoint (no actor_state_dict)")
    try:
        actor, meta = actor_from_checkpoint(checkpoint, device, team)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    return policy_from_actor(actor, meta, device, deterministic, seed)
