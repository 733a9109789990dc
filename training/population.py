"""Populations: K independent training runs in one process (`aquarium-warp train --runs K`, `Population`).

A study needs many trainings (seeds, conditions, controls), and one small training leaves a GPU
almost idle. A population trains K runs together, each as if it trained alone:

- **Worlds.** One `BatchedAquarium` of K x W worlds, seeded with the K runs' seeds (`seeding.seed_groups`):
  run k owns worlds `[k W, (k + 1) W)`, whose random streams are those of a batch of W worlds seeded
  with its seed, and its condition is its worlds' per-world parameters (`AquariumConfig.stack`). The
  opponent heuristic is keyed per run the same way.
- **Rows.** One `AquariumVecEnv` (`runs=K`) over all worlds: run k's rows are the k-th of K equal blocks
  (world-major within), its rewards scaled by its own `reward_scale`, its episode statistics summed
  apart.
- **Learners.** Each run has its own PPO (`AquariumPPO`, built as `Trainer` builds it, from the run's
  seed): networks, optimizer state, learning-rate schedule, random draws. Two ways to step them:
  * `RunLoop` (the CPU's): every call of the training loop made for each run in turn on its block of
    rows, with torch's CPU generator switched to the run's own state; run k's parameters equal, bit
    for bit, those of the same config trained alone (`tests/training/test_population.py`);
  * `StackedPPO` (CUDA's): the runs' networks are slices of stacked parameters (`models.StackedMLP`,
    weights `[K, out, in]`; each run's `nn.Linear` views its slice), so the rollout step is one
    batched forward (or one fused kernel, `fused_ppo`'s programs per run's block of rows) for all
    runs, and the update one loss, one backward and one optimizer step for all: each run's loss is the
    mean over its own samples, its advantages normalised over its own rollout, its mini-batches its
    own permutation, its gradient norm clipped on its own. Random draws (sampling, permutations) come
    from one generator for all runs, so trajectories are not those of the runs alone; their
    statistics are (see `benchmarks/population.py` for the equivalence check).
- **Outputs.** Run k writes `run-<k>/` as if trained alone: `config.json`, `progress.csv`, TensorBoard,
  checkpoints `model_<i>.pt` in `Trainer`'s format (so `Trainer.resume("run-<k>")` continues it alone)
  and `exported/`. `population.json` in the population's directory lists the runs.
- **Isolation.** A run whose losses or parameters stop being finite stops alone: it is reported, its
  outputs end with its last finite checkpoint, its parameters are put back to that state and frozen
  (its optimizer state cleared), and its worlds go on being simulated under them; a run whose budget
  (`train.episodes` or `train.iterations`) is spent stops the same way, with its final checkpoint.

What may differ between runs: `train.seed`, `train.reward_scale`, the budget (`train.episodes`,
`train.iterations`) and every env parameter that may differ per world. What cannot share a process
(another slot count, observation layout or team setup) is refused naming the difference; both teams
learning, opponent pools, recurrent networks, centralised critics, Individual Learning, domain
randomisation, the adaptive learning rate, videos, several processes and rsl-rl's runner loop are
refused in one line each, saying why. Observation normalisation is each run's own (`RunNormalization`
on CUDA; the fused kernels do not take it, so such runs take torch's products).
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import re
import uuid
from collections.abc import Callable, Iterator, Sequence

import numpy as np
import torch
from rsl_rl.storage import RolloutStorage
from rsl_rl.utils import resolve_callable

from ..agent_types import OTHER, TYPES
from ..arguments import check_int
from ..atomic import atomic_open
from ..config import AquariumConfig
from ..device import make_current, resolve_device
from ..drivers import is_heuristic, make_driver
from ..env import BatchedAquarium
from ..records import provenance
from ..seeding import seed_process
from . import _rsl  # noqa: F401
from .checkpoints import global_rng_state, read_checkpoint, restore_global_rng_state, write_checkpoint
from .config import (
    config_difference,
    default_opponent,
    env_config,
    runner_config,
    team_settings,
    total_iterations,
    validate,
)
from .export import export_policy, policy_meta
from .fast_path import resolve_fast_path
from .logger import AquariumLogger
from .loop import TrainingLoop
from .memory import check_training_memory
from .ppo import AquariumPPO
from .run_dir import check_same_run
from .stop import StopRequest
from .vec_env import AquariumVecEnv

# The train settings that may differ between a population's runs (everything else is the same).
RUN_SETTINGS = ("seed", "reward_scale", "episodes", "iterations")
LOSSES = ("value", "surrogate", "entropy")


def run_configs(config: dict, runs: int) -> list[dict]:
    """`train --runs K`: K copies of `config`, run k seeded `train.seed + k`."""
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise ValueError(f"runs={runs!r} must be an integer >= 1")
    configs = []
    for k in range(runs):
        config_k = copy.deepcopy(config)
        config_k["train"]["seed"] = int(config["train"]["seed"]) + k
        configs.append(config_k)
    return configs


def unsupported(config: dict) -> str | None:
    """Why a run of `config` cannot be trained in a population (None: it can)."""
    train, runner = config["train"], config["runner"]
    team_blocks = config.get("teams") or {}
    reasons = [
        (train["team"] == "both", "both teams learning (each team's learner would need its own stacked networks)"),
        (bool(train["pool_every"]), "an opponent pool (its snapshots play some worlds of every run)"),
        (train["loop"] != "fast", "train.loop='rsl-rl' (rsl-rl's runner trains one learner)"),
        (bool(train["randomize"]), "domain randomisation (its draws are keyed by one run's seed)"),
        (bool(train["video_every"]), "training videos (one world's episode per run is not recorded yet)"),
        (train["sharing"] != "parameter", "Individual Learning (a population stacks one network per run)"),
        (train["critic"] != "local", "a centralised critic (its observation group is not stacked)"),
        (bool(team_blocks), "per-team blocks (teams.*)"),
        (
            not train["opponent_deterministic"] and not is_heuristic(train["opponent"], OTHER[train["team"]]),
            "a trained opponent that samples its actions (its draws would come from one generator for all runs)",
        ),
    ]
    for part in ("actor", "critic"):
        model = runner.get(part, {})
        name = str(model.get("class_name", "MLPModel"))
        reasons.append(("RNN" in name or "Recurrent" in name, f"recurrent networks ({part}.class_name={name!r})"))
    if runner.get("algorithm", {}).get("schedule") == "adaptive":
        reasons.append((True, "the adaptive learning-rate schedule (decided on the host from each run's KL)"))
    for refused, why in reasons:
        if refused:
            return why
    return None


def check_runs(configs: list[dict]) -> None:
    """One-line ValueErrors: a run a population cannot train, or two runs that cannot share a process."""
    if not configs:
        raise ValueError("a population needs at least one run")
    for k, config in enumerate(configs):
        validate(config)
        why = unsupported(config)
        if why is not None:
            raise ValueError(f"run {k}: a population does not train {why}; train it alone (--runs 1)")
    # The env is checked by AquariumConfig.stack, which knows what may differ per world.
    base = {section: value for section, value in configs[0].items() if section != "env"}
    for k, config in enumerate(configs[1:], start=1):
        other = {section: value for section, value in config.items() if section != "env"}
        key = config_difference(base, other, RUN_SETTINGS + ("quiet",))
        if key is not None:
            raise ValueError(
                f"runs 0 and {k} differ in {key}: runs of one population differ only in "
                f"train.{'/'.join(RUN_SETTINGS)} and per-world env parameters"
            )
    seen: dict[str, int] = {}
    for k, config in enumerate(configs):  # one seed in another condition is another run; twice the same is not
        same = copy.deepcopy(config)
        same["train"].pop("quiet", None)
        key = json.dumps(same, sort_keys=True, default=str)
        if key in seen:
            raise ValueError(f"runs {seen[key]} and {k} are the same run (the same config): give each its own seed")
        seen[key] = k


def group_key(config: dict) -> str | None:
    """What runs that may share a population have in common (None: `config` trains alone): the config
    without the settings runs may differ in (`RUN_SETTINGS`, per-world env parameters but the agent
    counts). Runs of one key pass `check_runs` together, but for the same run given twice."""
    from ..per_world import PER_WORLD_FIELDS, PER_WORLD_TYPE_FIELDS

    if unsupported(config) is not None:
        return None
    shared = copy.deepcopy(config)
    for name in (*RUN_SETTINGS, "quiet", "device"):
        shared["train"].pop(name, None)
    env = shared.get("env") or {}
    for name in PER_WORLD_FIELDS:
        if name not in ("prey_count", "predator_count"):
            env.pop(name, None)
    for team in TYPES:
        for name in PER_WORLD_TYPE_FIELDS:
            (env.get(team) or {}).pop(name, None)
    return json.dumps(shared, sort_keys=True, default=str)


MAX_POPULATION = 64  # runs per process at most: the H200 gained 8% from 64 to 256 (population_h200_6b8873a)


def population_groups(
    configs: Sequence[dict], alone: Sequence[bool], device: str, runs_per_process: int | None,
    report: Callable[[str], None] | None,
) -> list[tuple[list[int], str]]:  # fmt: skip
    """Indices of `configs` (the trainings of a study's pending tasks) in the groups that train together,
    the largest first, each with why its size ("up to 8: given"; "" alone): configs of one
    `population.group_key` in populations of `runs_per_process` (None: `population_size` on
    `device`), each config flagged in `alone` (it continues a kept state) or that trains alone in a group
    of its own. The choice is reported."""
    if runs_per_process is not None:
        check_int("runs_per_process", runs_per_process)
    keyed: dict[str, list[int]] = {}
    groups: list[tuple[list[int], str]] = []
    for k, config in enumerate(configs):
        key = None if alone[k] else group_key(config)
        if key is None:
            groups.append(([k], ""))
        else:
            keyed.setdefault(key, []).append(k)
    for members in keyed.values():
        size, why = (runs_per_process, "given") if runs_per_process else population_size(configs[members[0]], device)
        groups.extend((members[j : j + size], f"up to {size}: {why}") for j in range(0, len(members), size))
        if report is not None and size > 1:
            report(f"  trainings: {len(members)} runs in populations of up to {size} ({why}), one process per device")
    groups.sort(key=lambda group: len(group[0]), reverse=True)
    return groups


def population_size(config: dict, device: str) -> tuple[int, str]:
    """Runs of `config` per process and why: as many as 80% of `device`'s free memory holds
    (`training.memory`), at most `MAX_POPULATION`; one on the CPU (its runs would take turns)."""
    from .memory import available_bytes, training_bytes

    if not device.startswith("cuda"):
        return 1, "the CPU"
    config = copy.deepcopy(config)
    config["train"]["device"] = device
    each, free = training_bytes(config)["total"], available_bytes(device)
    size = max(1, min(MAX_POPULATION, int(0.8 * free // max(each, 1))))
    return size, f"{each / 2**30:.2f} GiB per run, {free / 2**30:.0f} GiB free on {device}"


def _slice_state(value, runs: int, k: int, sizes: set[int]):
    """Run k's part of a state (nested dicts, tensors, numpy arrays): arrays whose first dimension is
    one of `sizes` (worlds or rows of all runs) cut to the k-th of `runs` equal blocks."""
    if isinstance(value, dict):
        return {key: _slice_state(v, runs, k, sizes) for key, v in value.items()}
    shape = getattr(value, "shape", None)
    if shape and len(shape) > 0 and shape[0] in sizes and shape[0] % runs == 0:
        block = shape[0] // runs
        part = value[k * block : (k + 1) * block]
        return part.clone() if isinstance(part, torch.Tensor) else part.copy()
    return copy.deepcopy(value)


def _join_states(parts: list, sizes: set[int]):
    """The inverse of `_slice_state` over every run's part: blocks joined in run order."""
    first = parts[0]
    if isinstance(first, dict):
        return {key: _join_states([p[key] for p in parts], sizes) for key in first}
    shape = getattr(first, "shape", None)
    if shape and len(shape) > 0 and shape[0] * len(parts) in sizes:
        if isinstance(first, torch.Tensor):
            return torch.cat(parts)
        return np.concatenate(parts)
    return first


def _compact(state: dict) -> dict:
    """A state dict whose tensors own their memory: a run's parameters are views of all runs'
    (`StackedPPO`), and saving a view would save every run's."""
    return {k: _compact(v) if isinstance(v, dict) else (v.clone() if isinstance(v, torch.Tensor) else v)
            for k, v in state.items()}  # fmt: skip


class RunLoop:
    """The runs' PPO learners as one learner of the training loop, each called in turn on its own block
    of rows with torch's CPU generator switched to its own state (see the module doc): the reference,
    bit for bit as the runs alone on the CPU."""

    def __init__(self, algs: list[AquariumPPO], rng_states: list[torch.Tensor]):
        self.runs = algs
        self.rng_states = rng_states
        self.active = [True] * len(algs)  # runs still learning
        first = algs[0]
        self.device, self.num_mini_batches = first.device, first.num_mini_batches
        self.storage = self  # the training loop clears "the storage": every run's

    # the interface `TrainingLoop` calls (see `AquariumPPO`)
    feed_forward = True
    rollout_graphable = graphable = False  # a generator switch per run is host work
    is_multi_gpu = False

    @property
    def capturable_optimizer(self) -> bool:
        return all(alg.capturable_optimizer for alg in self.runs)

    @property
    def learning_rate(self) -> float:
        return self.runs[0].learning_rate

    @contextlib.contextmanager
    def run(self, k: int) -> Iterator[AquariumPPO]:
        """Run k's learner, with torch's CPU generator in run k's state meanwhile."""
        outside = torch.get_rng_state()
        torch.set_rng_state(self.rng_states[k])
        try:
            yield self.runs[k]
        finally:
            self.rng_states[k] = torch.get_rng_state()
            torch.set_rng_state(outside)

    def _block(self, x: torch.Tensor, k: int) -> torch.Tensor:
        n = x.shape[0] // len(self.runs)
        return x[k * n : (k + 1) * n]

    def train_mode(self) -> None:
        for alg in self.runs:
            alg.train_mode()

    def act_into(self, obs, env_actions: torch.Tensor) -> None:
        for k in range(len(self.runs)):
            with self.run(k) as alg:
                alg.act_into(self._block(obs, k), self._block(env_actions, k))

    def process_env_step(self, obs, rewards, dones, extras) -> None:
        for k in range(len(self.runs)):
            with self.run(k) as alg:
                block = {key: self._block(v, k) for key, v in extras.items() if isinstance(v, torch.Tensor)}
                alg.process_env_step(self._block(obs, k), self._block(rewards, k), self._block(dones, k), block)

    def compute_returns(self, obs) -> None:
        for k in range(len(self.runs)):
            with self.run(k) as alg:
                alg.compute_returns(self._block(obs, k))

    def mini_batch_indices(self) -> tuple[torch.Tensor, int]:
        """Each run's own draw (`AquariumPPO.mini_batch_indices`), run after run: `(indices, size)`
        with each run's indices (into its own rollout) one block after another; `size` is K times a
        run's mini-batch size."""
        parts, size = [], 0
        for k in range(len(self.runs)):
            with self.run(k) as alg:
                indices, size = alg.mini_batch_indices()
                parts.append(indices)
        return torch.cat(parts), size * len(self.runs)

    def update_on_device(self, indices: torch.Tensor, mini_batch_size: int) -> torch.Tensor:
        """Every learning run's update; `[K * 3]` losses (NaN for runs that no longer learn)."""
        K = len(self.runs)
        losses = torch.full((K, 3), float("nan"), dtype=torch.float64, device=self.device)
        for k, own in enumerate(indices.view(K, -1)):
            if self.active[k]:
                with self.run(k) as alg:
                    losses[k] = alg.update_on_device(own, mini_batch_size // K)
        return losses.view(-1)

    def finish_update(self) -> None:
        for k in range(len(self.runs)):
            with self.run(k) as alg:
                alg.finish_update()

    def clear(self) -> None:
        for alg in self.runs:
            alg.storage.clear()

    def freeze(self, k: int) -> None:
        """Run k stops learning (its parameters stay; the caller restores them)."""
        self.active[k] = False

    def run_rng_state(self, k: int) -> torch.Tensor:
        return self.rng_states[k]

    def set_run_rng_state(self, k: int, state: torch.Tensor) -> None:
        self.rng_states[k] = state.cpu()

    def sync_run_optimizer(self, k: int, to_run: bool = True) -> None:
        """(Each run steps its own optimizer: nothing to copy.)"""


class StackedPPO(AquariumPPO):
    """The runs' PPO as one: stacked networks (`models.StackedMLPModel`), one storage of every run's
    rows, and rsl-rl's rollout (or `fused_ppo`'s) over them; what makes each run its own is here: the
    advantages normalised per run, each run's own permutation, losses that are means over one run's
    samples, and each run's gradient norm clipped on its own (see the module doc)."""

    normalize_advantage_per_mini_batch: bool  # declared: rsl-rl's PPO sets it

    def __init__(self, *args, runs: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.num_runs = runs
        self.loss_shape = (runs, 3)
        # Runs still learning; a stopped run's gradients are zeroed, so Adam (its state cleared) leaves it.
        self.learning = torch.ones(runs, dtype=torch.bool, device=self.device)
        self.per_run: list[AquariumPPO] = []  # the runs' own learners (views of these parameters), for files

    # --- each run's advantages, permutations, losses and gradient norms
    def compute_returns(self, obs) -> None:
        per_mini_batch = self.normalize_advantage_per_mini_batch
        self.normalize_advantage_per_mini_batch = True  # rsl-rl's returns and advantages, not normalised
        try:
            super().compute_returns(obs)
        finally:
            self.normalize_advantage_per_mini_batch = per_mini_batch
        if not per_mini_batch:
            st = self.storage
            T, K = st.num_transitions_per_env, self.num_runs
            adv = st.advantages.view(T, K, -1)
            mean = adv.mean(dim=(0, 2), keepdim=True)
            std = adv.std(dim=(0, 2), keepdim=True)
            st.advantages = ((adv - mean) / (std + 1e-8)).view_as(st.advantages)

    def mini_batch_indices(self) -> tuple[torch.Tensor, int]:
        """Each run's permutation of its own samples (as `ppo.mini_batch_indices` draws one run's),
        drawn together: `(indices, size)` as `RunLoop.mini_batch_indices` gives them."""
        st, K = self.storage, self.num_runs
        per_run = st.num_envs // K * st.num_transitions_per_env
        batch = per_run // self.num_mini_batches
        if batch < 1:
            raise ValueError(f"{per_run} samples per run cannot fill {self.num_mini_batches} mini-batches")
        draws = torch.rand(K, batch * self.num_mini_batches, device=self.device)
        return torch.argsort(draws, dim=1).view(-1), batch * K

    def _storage_indices(self, indices: torch.Tensor, size: int) -> torch.Tensor:
        """Each run's indices into its own rollout (step-major, `t * R + j`) as indices into the whole
        storage, mini-batch by mini-batch, each mini-batch's rows run by run (`MLPSpec.blocked`)."""
        st, K = self.storage, self.num_runs
        R, N = st.num_envs // K, st.num_envs
        local = indices.view(K, self.num_mini_batches, size // K)
        run = torch.arange(K, device=indices.device).view(K, 1, 1)
        flat = local // R * N + run * R + local % R
        return flat.transpose(0, 1).reshape(-1)

    def update_on_device(self, indices: torch.Tensor, mini_batch_size: int) -> torch.Tensor:
        """`AquariumPPO.update_on_device` over each run's own permutation, every run's losses apart:
        `[K * 3]` float64 means."""
        return super().update_on_device(self._storage_indices(indices, mini_batch_size), mini_batch_size).view(-1)

    def _mini_batch_step(
        self, observations, actions, old_values, advantages, returns, old_actions_log_prob, old_distribution_params
    ) -> torch.Tensor:
        """One mini-batch of every run (`AquariumPPO._mini_batch_step` with each loss a mean over one
        run's rows); returns `[K, 3]` detached losses."""
        K = self.num_runs
        self.actor(observations, masks=None, hidden_state=None, stochastic_output=True)
        log_prob = self.actor.get_output_log_prob(actions)
        values = self.critic(observations, masks=None, hidden_state=None)
        entropy = self.actor.output_entropy
        ratio = torch.exp(log_prob - torch.squeeze(old_actions_log_prob))
        advantage = torch.squeeze(advantages)
        surrogate = torch.max(
            -advantage * ratio, -advantage * torch.clamp(ratio, 1.0 - self.clip_param, 1.0 + self.clip_param)
        )
        if self.use_clipped_value_loss:
            clipped = old_values + (values - old_values).clamp(-self.clip_param, self.clip_param)
            value_loss = torch.max((values - returns).pow(2), (clipped - returns).pow(2))
        else:
            value_loss = (returns - values).pow(2)
        per_run = torch.stack(
            [value_loss.view(K, -1).mean(dim=1), surrogate.view(K, -1).mean(dim=1), entropy.view(K, -1).mean(dim=1)],
            dim=1,
        )
        loss = (per_run[:, 1] + self.value_loss_coef * per_run[:, 0] - self.entropy_coef * per_run[:, 2]).sum()
        self.optimizer.zero_grad()
        loss.backward()
        self._apply_gradients()
        return per_run.detach().double()

    def _apply_gradients(self) -> None:
        """Each run's actor and critic gradient norms clipped as `clip_grad_norm_` clips one network's
        (`max_norm / (norm + 1e-6)`, at most 1); runs that stopped learning get none; Adam steps all."""
        for model in (self.actor, self.critic):
            grads = [p.grad for p in model.parameters() if p.grad is not None]
            norms = torch.stack([g.flatten(1).norm(dim=1) for g in grads])  # [parameters, K]
            total = torch.linalg.vector_norm(norms, dim=0)
            scale = torch.clamp(self.max_grad_norm / (total + 1e-6), max=1.0)
            for g in grads:
                keep = self.learning.view(-1, *([1] * (g.dim() - 1)))
                g.copy_(torch.where(keep, g * scale.view_as(keep), 0.0))
        self.optimizer.step()

    # --- the runs' own learners share these parameters and this optimizer state
    def stacked_parameters(self) -> list[tuple[torch.Tensor, str]]:
        """The stacked parameters in the order of a run's own (its MLP's layers: weight, bias, ...)."""
        return [(p, part) for part in ("actor", "critic") for p in getattr(self, part).mlp.layer_parameters()]

    def freeze(self, k: int) -> None:
        """Run k stops learning: no gradient, and its optimizer state cleared (so Adam leaves it)."""
        self.learning[k] = False
        for p, _ in self.stacked_parameters():
            for value in self.optimizer.state.get(p, {}).values():
                if isinstance(value, torch.Tensor) and value.dim() > 0 and value.shape[0] == self.num_runs:
                    value[k].zero_()

    def sync_run_optimizer(self, k: int, to_run: bool = True) -> None:
        """Copy run k's slices of the stacked optimizer state into its own learner's optimizer (for its
        checkpoint), or back (`to_run=False`, after loading one)."""
        run = self.per_run[k]
        own = [p for group in run.optimizer.param_groups for p in group["params"]]
        stacked = [p for p, _ in self.stacked_parameters()]
        for p_run, p_all in zip(own, stacked):
            state = self.optimizer.state.get(p_all)
            if to_run:
                if state:
                    run.optimizer.state[p_run] = {
                        name: (v[k].clone() if isinstance(v, torch.Tensor) and v.dim() > 0 else copy.deepcopy(v))
                        for name, v in state.items()
                    }
            elif p_run in run.optimizer.state:
                loaded = run.optimizer.state[p_run]
                if not state:  # Adam's state before its first step: made here, as its step would
                    state = self.optimizer.state[p_all] = {
                        name: (torch.zeros_like(p_all) if isinstance(v, torch.Tensor) and v.dim() > 0 else
                               v.clone().to(self.device) if isinstance(v, torch.Tensor) else v)
                        for name, v in loaded.items()
                    }  # fmt: skip
                for name, v in loaded.items():
                    if isinstance(v, torch.Tensor) and v.dim() > 0:
                        state[name][k].copy_(v)
                    elif isinstance(v, torch.Tensor):
                        state[name].copy_(v.to(state[name].device, state[name].dtype))

    def run_rng_state(self, k: int) -> torch.Tensor:
        return torch.get_rng_state()  # (one generator for all runs)

    def set_run_rng_state(self, k: int, state: torch.Tensor) -> None:
        torch.set_rng_state(state.cpu())


def share_parameters(stacked, runs: list) -> None:
    """Copy each run's network into its slice of a `models.StackedMLP`, then make the run's parameters
    views of those slices (the same Parameter objects: the run's optimizer keeps them)."""
    layers = [list(run.mlp)[0::2] for run in runs]  # each run's nn.Linear layers
    for layer, (weight, bias) in enumerate(zip(stacked.weights, stacked.biases)):
        for k, linears in enumerate(layers):
            with torch.no_grad():
                weight.data[k].copy_(linears[layer].weight)
                bias.data[k].copy_(linears[layer].bias)
            linears[layer].weight.data = weight.data[k]
            linears[layer].bias.data = bias.data[k]


class Population:
    """K runs trained in one process (see the module doc). `configs`: the runs' configs (as `Trainer`
    takes one); `log_dir`: the population's directory, run k's files in `run-<k>/` (None: no files).
    `stacked`: the runs' learners as `StackedPPO` (default on CUDA) or `RunLoop` (default on the CPU)."""

    def __init__(
        self,
        configs: list[dict],
        log_dir: str | None = None,
        stacked: bool | None = None,
        run_dirs: list[str] | None = None,
        run_ids: list[str | None] | None = None,
    ):
        if run_dirs is not None and (log_dir is not None or len(run_dirs) != len(configs)):
            raise ValueError("run_dirs names each run's own directory (one per config), instead of log_dir")
        self.run_dirs = run_dirs
        # Each run's id (as `Trainer`'s): in its config.json and checkpoints, so that a resume can tell it.
        self.run_ids = [i or uuid.uuid4().hex[:16] for i in (run_ids or [None] * len(configs))]
        configs = [copy.deepcopy(c) for c in configs]
        for config in configs:
            if config["train"]["opponent"] is None and config["train"]["team"] != "both":
                config["train"]["opponent"] = default_opponent(config["train"]["team"])
        check_runs(configs)
        self.configs, self.log_dir, self.stop = configs, log_dir, StopRequest()
        self.K = K = len(configs)
        base, train = configs[0], configs[0]["train"]
        self.team = team = train["team"]
        self.seeds = tuple(int(c["train"]["seed"]) for c in configs)
        seed_process(self.seeds[0])
        device = resolve_device(train["device"])
        W = int(train["num_worlds"])
        whole = copy.deepcopy(base)
        whole["train"]["num_worlds"] = K * W
        check_training_memory(whole, device)  # every run's worlds and rows, before anything is allocated
        envs = [env_config(c).draw(W, s) for c, s in zip(configs, self.seeds)]
        for k, env in enumerate(envs):
            for name in ("prey_count", "predator_count", "prey_capacity", "predator_capacity"):
                if getattr(env, name) != getattr(envs[0], name):
                    raise ValueError(
                        f"runs 0 and {k} differ in {name} ({getattr(envs[0], name)!r} and {getattr(env, name)!r}): "
                        "a population's runs share their agents' slots (train them apart, --runs 1)"
                    )
        env_cfg = AquariumConfig.stack(envs, W)
        self.env = BatchedAquarium(env_cfg, num_worlds=K * W, device=device, seed=self.seeds)
        self.device = self.env.torch_device
        make_current(self.device)
        self.path = resolve_fast_path(base, self.device.type)  # the runs' one path (`check_runs`: same settings)
        if self.path.tf32:
            torch.backends.cuda.matmul.allow_tf32 = True
        other = OTHER[team]
        # A heuristic draws from the env's streams, keyed per run as alone; a trained opponent acts by argmax
        # (`unsupported`), so the seed goes unused.
        self.opponent = make_driver(
            train["opponent"], self.env, other, deterministic=train["opponent_deterministic"], seed=self.seeds[0]
        )
        scales = [float(team_settings(c, team)["reward_scale"]) for c in configs]
        self.vec_env = AquariumVecEnv(
            self.env,
            team,
            self.opponent,
            reward_scale=scales,
            cfg=base,
            metrics_every=int(train["metrics_every"]),
            runs=K,
        )
        v = self.vec_env
        self.rows = v.num_envs // K
        self.runner_cfgs = [runner_config(c, v.slots, v.action_count, self.device.type) for c in configs]
        for cfg in self.runner_cfgs:
            cfg["multi_gpu"] = None  # (what rsl-rl's runner sets for one process)
        self.totals = [total_iterations(c) for c in configs]
        self.stacked = self.device.type == "cuda" if stacked is None else bool(stacked)
        algs, rng_states = [], []
        observations = v.get_observations()
        for k, (seed, cfg) in enumerate(zip(self.seeds, self.runner_cfgs)):
            # As `Trainer` builds a run alone: torch seeded with the run's seed, then rsl-rl's construction.
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                view = _RowsView(v, self.rows, observations[k * self.rows : (k + 1) * self.rows])
                with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the networks
                    algs.append(resolve_callable(cfg["algorithm"]["class_name"]).construct_algorithm(
                        view.get_observations(), view, cfg, str(self.device)))  # fmt: skip
                rng_states.append(torch.get_rng_state())
        self.runs = algs
        self.learner: RunLoop | StackedPPO = (
            self._stacked_learner(algs, observations) if self.stacked else RunLoop(algs, rng_states)
        )
        self.iteration = 0  # iterations completed
        self.active = [True] * K  # runs still training (not stopped, budget not spent)
        self.stopped: dict[int, str] = {}  # run -> why it stopped early
        self.last_checkpoint: list[str | None] = [None] * K
        self.loop: TrainingLoop | None = None  # made by `train`, after the episodes' starts are spread
        self.loggers = [self._logger(k) for k in range(K)]
        if self.writes:
            self._write_records()

    def _stacked_learner(self, algs: list[AquariumPPO], observations) -> StackedPPO:
        """The runs' learners stacked (`StackedPPO`): built from run 0's rsl-rl config with each model's
        class replaced by its stacked twin, the runs' networks copied in and then viewing it."""
        cfg = self.runner_cfgs[0]
        model_class = "aquarium_warp.training.fused_mlp:FusedStackedMLPModel" if self.path.fused_mlp else (
            "aquarium_warp.training.models:StackedMLPModel")  # fmt: skip
        models = {}
        with torch.random.fork_rng(devices=[]):  # its own initial draws are overwritten below
            for part in ("actor", "critic"):
                kwargs = {k: v for k, v in cfg[part].items() if k != "class_name"}
                model = resolve_callable(model_class)(observations, cfg["obs_groups"], part, 1, runs=self.K, **kwargs)
                models[part] = model.to(self.device)
        for part in ("actor", "critic"):
            share_parameters(models[part].mlp, [getattr(alg, part) for alg in algs])
            if models[part].obs_normalization:  # each run's own normaliser, on its own rows
                from .models import RunNormalization

                normalizers = [getattr(alg, part).obs_normalizer for alg in algs]
                models[part].obs_normalizer = RunNormalization(normalizers, self.rows).to(self.device)
        alg_cfg = {k: v for k, v in cfg["algorithm"].items() if k != "class_name"}
        storage = RolloutStorage(
            "rl", self.vec_env.num_envs, cfg["num_steps_per_env"], observations, [1], str(self.device)
        )
        stacked = StackedPPO(
            models["actor"], models["critic"], storage, runs=self.K, device=str(self.device), multi_gpu_cfg=None,
            **alg_cfg,
        )  # fmt: skip
        for alg in algs:  # their own rollouts are never filled: give back the memory
            alg.storage = alg.fused_act = alg.fused_loss = None
        stacked.per_run = algs
        return stacked

    # ------------------------------------------------------------------ files
    @property
    def writes(self) -> bool:
        """Whether the runs write files (a `log_dir`, or each run its own of `run_dirs`)."""
        return self.log_dir is not None or self.run_dirs is not None

    def run_dir(self, k: int) -> str:
        """Run k's directory: `run_dirs[k]`, or `<log_dir>/run-<k>`."""
        if self.run_dirs is not None:
            return self.run_dirs[k]
        if self.log_dir is None:
            raise ValueError("this population has no log_dir: its runs write no files")
        return os.path.join(self.log_dir, f"run-{k}")

    def _logger(self, k: int) -> AquariumLogger:
        path = self.run_dir(k) if self.writes else None
        v = self.vec_env
        logger = AquariumLogger(
            log_dir=path,
            cfg=self.runner_cfgs[k],
            env_cfg=v.cfg,
            num_envs=self.rows,
            is_distributed=False,
            gpu_world_size=1,
            gpu_global_rank=0,
            device=str(self.device),
            csv_path=os.path.join(path, "progress.csv") if path else None,
            slots=v.slots,
            max_steps=v.max_episode_length,
            quiet=True,  # the population prints one line per iteration for all runs
            bar=False,
        )
        return logger

    def policy_meta(self, k: int) -> dict:
        v = self.vec_env
        return policy_meta(self.configs[k], v.slots, v.observation_size, v.action_count, team=self.team)

    def _write_records(self) -> None:
        record = provenance(str(self.device))
        population = {
            "runs": self.K,
            "seeds": list(self.seeds),
            "learner": "stacked" if self.stacked else "per-run",
            "run_dirs": [f"run-{k}" for k in range(self.K)] if self.run_dirs is None else self.run_dirs,
            "stopped": {str(k): why for k, why in self.stopped.items()},  # runs that failed, and why
        }
        if self.log_dir is not None:
            os.makedirs(self.log_dir, exist_ok=True)
            with atomic_open(os.path.join(self.log_dir, "population.json")) as f:
                json.dump({**population, **record}, f, indent=1, default=str)
        for k in range(self.K):
            os.makedirs(self.run_dir(k), exist_ok=True)
            with atomic_open(os.path.join(self.run_dir(k), "config.json")) as f:
                json.dump(
                    {
                        "config": self.configs[k],
                        "run_id": self.run_ids[k],
                        "runner_cfg": self.runner_cfgs[k],
                        "total_iterations": self.totals[k],
                        "population": {**population, "run": k},
                        "path": self.path.record(),
                        **record,
                    },
                    f,
                    indent=1,
                    default=str,
                )

    def run_state(self, k: int, whole: dict | None = None) -> dict:
        """Run k's checkpoint, as `Trainer` writes one for a run alone (see `trainer.py`); `whole`: the
        adapter's `state_dict()` of every run, where the caller saves several runs at once."""
        self.learner.sync_run_optimizer(k)
        alg = self.runs[k]
        saved = _compact(alg.save())
        saved["iter"] = self.iteration
        v, W = self.vec_env, self.env.num_worlds
        whole = v.state_dict(with_env=True) if whole is None else whole
        vec = _slice_state(whole, self.K, k, {W, v.num_envs})
        env_k = vec["env"]
        env_k.update(config=env_config(self.configs[k]).draw(W // self.K, self.seeds[k]).to_dict(),
                     num_worlds=W // self.K, seed=self.seeds[k])  # fmt: skip
        rng = global_rng_state(self.device)
        rng["torch"] = self.learner.run_rng_state(k).clone()
        saved["infos"] = {
            "aquarium": {
                "config": self.configs[k],
                "run_id": self.run_ids[k],
                "seed": self.seeds[k],
                "rng": rng,
                "runner_cfg": self.runner_cfgs[k],
                "policy_meta": self.policy_meta(k),
                "vec_env": vec,
                "logger": self.loggers[k].state_dict(),
                "hidden_states": {"actor": None, "critic": None},
                "population": {"runs": self.K, "run": k, "seeds": list(self.seeds)},
            }
        }
        return saved

    def _checkpoint_path(self, k: int) -> str | None:
        return os.path.join(self.run_dir(k), f"model_{self.iteration - 1}.pt") if self.writes else None

    def save(self, runs: list[int]) -> None:
        """The checkpoints of `runs` of the iterations completed (`model_<i>.pt`, i the last one); the
        simulation's state is read once for all of them."""
        if not self.writes or not runs:
            return
        whole = self.vec_env.state_dict(with_env=True)
        for k in runs:
            path = os.path.join(self.run_dir(k), f"model_{self.iteration - 1}.pt")
            write_checkpoint(self.run_state(k, whole), path)
            self.last_checkpoint[k] = path

    def export(self, k: int, formats=None, out_dir: str | None = None) -> dict:
        """Run k's policy into `out_dir` (default: its run directory's `exported/`), in `formats` (default:
        the config's)."""
        formats = self.configs[k]["train"]["export"] if formats is None else formats
        out_dir = os.path.join(self.run_dir(k), "exported") if out_dir is None else out_dir
        actor = self.runs[k].get_policy()
        # Parameters that own their memory meanwhile: the files must hold this run's network, not its view of all.
        views = [(p, p.data) for p in actor.parameters()]
        for p, data in views:
            p.data = data.clone()
        try:
            return export_policy(actor, self.policy_meta(k), out_dir, formats)
        finally:
            for p, data in views:
                p.data = data

    # ------------------------------------------------------------------ training
    def train(self, iterations: int | None = None) -> None:
        """Train every run up to its budget (or `iterations` more iterations at most), or until SIGINT
        or SIGTERM (`stop.py`); every running run's state of the last completed iteration is saved at
        the end. Iteration `i` is logged while the device runs `i + 1`, as `Trainer` does."""
        total = max(self.totals) if iterations is None else min(max(self.totals), self.iteration + iterations)
        save_every = int(self.runner_cfgs[0]["save_interval"])
        if self.writes:
            for logger in self.loggers:
                with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl reports storing git state
                    logger.init_logging_writer()
        if self.loop is None:
            train = self.configs[0]["train"]
            if self.iteration == 0 and train["init_at_random_ep_len"]:
                self._spread_episode_starts()
            self.loop = TrainingLoop(
                [(self.learner, self.vec_env)],
                self.runner_cfgs[0]["num_steps_per_env"],
                graphs=bool(train["cuda_graphs"]),
                graph_update=train["graph_update"],
            )
        self.learner.train_mode()
        pending = None  # the previous iteration's record, logged while this one runs
        with self.stop.catching():
            while self.iteration < total and any(self.active):
                it = self.iteration
                record = self.loop.iteration()
                self.iteration = it + 1
                if pending is not None:
                    self._finish(*pending)
                pending = (it, record)
                ending = [k for k in range(self.K) if self.active[k] and self.iteration >= self.totals[k]]
                signalled = self.stop.signum is not None
                if ending or signalled or it % save_every == 0:
                    self._finish(*pending)  # a checkpoint's progress.csv holds its own iteration
                    pending = None
                    due = signalled or it % save_every == 0
                    self.save([k for k in range(self.K) if self.active[k] and (k in ending or due)])
                    for k in ending:
                        if self.active[k]:
                            self._stop_run(k, None)
                if signalled:
                    break
            if pending is not None:
                self._finish(*pending)
        # the state of the last iteration, where no checkpoint holds it yet
        unsaved = [k for k in range(self.K) if self.last_checkpoint[k] != self._checkpoint_path(k)]
        self.save([k for k in unsaved if self.active[k] and self.iteration > 0])
        for logger in self.loggers:
            if logger.writer is not None:
                logger.stop_logging_writer()

    def _spread_episode_starts(self) -> None:
        """rsl-rl's `init_at_random_ep_len` (the worlds' step counters drawn, which spreads their
        truncations), each run drawing for its own rows from its own generator where it has one."""
        v, n = self.vec_env, self.rows
        rows = v.episode_length_buf
        high = int(v.max_episode_length)
        if isinstance(self.learner, RunLoop):
            parts = []
            for k in range(self.K):
                with self.learner.run(k):
                    parts.append(torch.randint_like(rows[k * n : (k + 1) * n], high=high))
            v.episode_length_buf = torch.cat(parts)
        else:
            v.episode_length_buf = torch.randint_like(rows, high=high)

    def _finish(self, it: int, record) -> None:
        """Log iteration `it` (waiting for it) and stop the runs whose losses are no longer finite."""
        values, times = record.read()
        losses = [values[3 * k : 3 * k + 3] for k in range(self.K)]
        self._log(it, values[3 * self.K :], losses, times)
        for k in range(self.K):
            bad = [name for name, x in zip(LOSSES, losses[k]) if not math.isfinite(x)]
            if self.active[k] and bad:
                self._stop_run(k, f"non-finite {', '.join(bad)} loss at iteration {it}")

    def _stop_run(self, k: int, why: str | None) -> None:
        """Run k stops: its budget is spent (`why` None), or it failed (`why`: it is reported, and its
        parameters go back to its last checkpoint's, whose files are its outputs)."""
        self.active[k] = False
        self.learner.freeze(k)
        if why is None:
            return
        last = self.last_checkpoint[k]
        if last is not None:
            saved = torch.load(last, map_location=str(self.device), weights_only=False)
            self.runs[k].actor.load_state_dict(saved["actor_state_dict"])  # in place: the stacked slices too
            self.runs[k].critic.load_state_dict(saved["critic_state_dict"])
        self.stopped[k] = why
        where = f"; its outputs end with {self.last_checkpoint[k]}" if self.last_checkpoint[k] else ""
        print(f"run {k} (seed {self.seeds[k]}) stopped: {why}{where}", flush=True)
        if self.writes:
            self._write_records()

    def _log(self, it: int, stats: list[float], losses: list[list[float]], times) -> None:
        v = self.vec_env
        size = v.episode_stats_size // self.K
        captures = []
        for k in range(self.K):
            if not self.active[k]:
                continue
            means, episodes, row_reward = v.decode_episode_stats(stats[k * size : (k + 1) * size])
            self.loggers[k].log_iteration(
                it, 0, self.totals[k], times[0], times[1], dict(zip(LOSSES, losses[k])),
                self.learner.learning_rate, means, episodes, row_reward,
            )  # fmt: skip
            if "Episode/captures_per_prey" in means:
                captures.append(means["Episode/captures_per_prey"])
        if self.configs[0]["train"]["quiet"]:
            return
        total = max(self.totals)
        steps = self.runner_cfgs[0]["num_steps_per_env"] * v.num_envs
        parts = [f"it {it + 1}/{total}", f"runs {sum(self.active)}/{self.K}"]
        if captures:
            parts.append(f"captures/prey {min(captures):.3f}-{max(captures):.3f}")
        parts.append(f"{steps / max(1e-9, sum(times)):.3g} agent-steps/s")
        print(" | ".join(parts), flush=True)

    def load(self, states: list[dict], going: list[int], stopped: dict[int, str]) -> None:
        """Restore every run from its checkpoint (`run_state`'s format): runs `going` continue (all at
        one iteration), the others are finished, or `stopped` (failed, and why)."""
        v = self.vec_env
        sizes = {self.env.num_worlds, v.num_envs}
        for k, state in enumerate(states):
            self.runs[k].load(state, None, True)  # in place: the stacked parameters too
            self.learner.sync_run_optimizer(k, to_run=False)
            own = state["infos"]["aquarium"]
            self.loggers[k].load_state_dict(own["logger"])
            self.learner.set_run_rng_state(k, own["rng"]["torch"])
        vec = _join_states([s["infos"]["aquarium"]["vec_env"] for s in states], sizes)
        vec["env"].update(config=self.env.config.to_dict(), num_worlds=self.env.num_worlds, seed=self.seeds)
        v.load_state_dict(vec)
        self.iteration = int(states[going[0]]["iter"]) if going else max(int(s["iter"]) for s in states)
        if going:  # the global generators (numpy, Python, CUDA) as the running runs left them
            restore_global_rng_state({**states[going[0]]["infos"]["aquarium"]["rng"], "torch": torch.get_rng_state()},
                                     self.device)  # fmt: skip
        for k in range(self.K):
            if k not in going:
                self.active[k] = False
                self.learner.freeze(k)
                if k in stopped:
                    self.stopped[k] = stopped[k]
        if self.log_dir is not None:
            for k in going:
                self.loggers[k].keep_rows_before(self.iteration)

    def close(self) -> None:
        if self.loop is not None:
            self.loop.release_graphs()
        self.vec_env.close()


class _RowsView:
    """What rsl-rl's `construct_algorithm` reads of an env, for one run's block of rows."""

    def __init__(self, vec_env: AquariumVecEnv, rows: int, observations):
        self.num_envs, self.num_actions, self._obs = rows, vec_env.num_actions, observations

    def get_observations(self):
        return self._obs


def is_population(path: str) -> bool:
    """Whether `path` is a population's directory (`population.json`)."""
    return os.path.isfile(os.path.join(path, "population.json"))


def _iterations(run_dir: str) -> dict[int, str]:
    """Run directory's checkpoints: `{i: path of model_<i>.pt}`."""
    found = {}
    for name in os.listdir(run_dir) if os.path.isdir(run_dir) else []:
        match = re.fullmatch(r"model_(\d+)\.pt", name)
        if match:
            found[int(match.group(1))] = os.path.join(run_dir, name)
    return found


def resume_population(log_dir: str, changes: dict | None = None) -> Population:
    """A population restored from its directory: every run still training continues from the newest
    iteration that all of them have a readable checkpoint of; a finished or stopped run is restored
    from its last checkpoint and stays stopped. `changes` may alter `train.iterations`, `episodes`,
    `quiet` and `export` of every run (as `Trainer.resume`)."""
    with open(os.path.join(log_dir, "population.json"), encoding="utf-8") as f:
        record = json.load(f)
    K, stopped = int(record["runs"]), {int(k): why for k, why in (record.get("stopped") or {}).items()}
    found = [_iterations(os.path.join(log_dir, f"run-{k}")) for k in range(K)]
    missing = [k for k, f in enumerate(found) if not f]
    if missing:
        raise ValueError(f"{log_dir}: run(s) {missing} have no checkpoint model_<i>.pt to resume from")
    newest = [read_checkpoint(f[max(f)]) for f in found]
    configs = [copy.deepcopy(c["infos"]["aquarium"]["config"]) for c in newest]
    allowed = {"iterations", "episodes", "quiet", "export"}
    bad = sorted(set((changes or {}).get("train", {})) - allowed)
    if bad or set(changes or {}) - {"train"}:
        raise ValueError(f"a resumed population keeps its config; only train.{sorted(allowed)} may change, not {bad}")
    for config in configs:
        config["train"].update((changes or {}).get("train", {}))
    totals = [total_iterations(c) for c in configs]
    # Runs still training: the newest iteration each of them has (a run's model_<i> holds i + 1 iterations).
    going = [k for k in range(K) if k not in stopped and max(found[k]) + 1 < totals[k]]
    common = set.intersection(*(set(found[k]) for k in going)) if going else set()
    if going and not common:
        raise ValueError(f"{log_dir}: runs {going} have no checkpoint of one iteration in common to resume from")
    at = max(common) if common else None
    paths = [found[k][at] if k in going and at is not None else found[k][max(found[k])] for k in range(K)]
    states = [read_checkpoint(path) if path != found[k][max(found[k])] else newest[k] for k, path in enumerate(paths)]
    # Each run's checkpoint is of the run its folder holds (its config.json, its newest checkpoint).
    run_ids = [check_same_run(os.path.join(log_dir, f"run-{k}"), paths[k], states[k]["infos"]["aquarium"])
               for k in range(K)]  # fmt: skip
    population = Population(configs, log_dir=log_dir, run_ids=run_ids)
    for k, path in enumerate(paths):
        population.last_checkpoint[k] = path
    population.load(states, going, stopped)
    return population
