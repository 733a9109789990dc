"""PPO training of one team with rsl-rl's `OnPolicyRunner` over `AquariumVecEnv`.

```python
from aquarium_warp.training import Trainer, make_config

trainer = Trainer(make_config("paper", {"train": {"device": "cuda:0"}}), log_dir="runs/paper_ps_s0")
trainer.train()                    # up to the config's total iterations; checkpoints every save_interval
trainer.export()                   # runs/paper_ps_s0/exported/policy.pt, policy.onnx, policy.json
# later, or after a crash:
Trainer.resume("runs/paper_ps_s0").train()     # continues from the newest checkpoint
```

The log directory receives rsl-rl's TensorBoard events, `config.json`, `progress.csv` (one row per
iteration: episode statistics, losses, speed) and checkpoints `model_<i>.pt`, which hold the state
after iteration i (0-based; the runner's `iter` entry is the next iteration, `i + 1`).

A checkpoint holds, besides rsl-rl's (actor, critic, optimizer, iteration), under `infos["aquarium"]`:
the run config, the simulation's `state_dict` (every world's agents and step counters, i.e. the
adapter's `episode_length_buf`), the adapter's row activity and statistics mask, the opponent's own
state (a heuristic's random streams are keyed by the simulation state and its seed), the torch (CPU
and CUDA), numpy and Python RNG states, and the logger's running sums. Resuming on the CPU continues
bit-exactly: the parameters after `n + m` uninterrupted iterations equal those after `n`, save,
resume, `m`.

Both teams (`train.team = "both"`): one learner per team (`Learner`: adapter, rsl-rl config, PPO,
logger) in the same worlds, driven together by `TrainingLoop`; `progress_<team>.csv`; checkpoints hold
`learners: {team: rsl-rl state}`, and under `infos["aquarium"]["teams"]` each learner's part of the
above, plus the opponent pool (`pool.py`); `export()` writes one policy per team.

Several processes (`torchrun`, see `distributed.py`): each rank trains on its own device and worlds with
seed `train.seed + RANK` (listed in `config.json` under `distributed`); rank 0 logs the episode
statistics and swarm metrics summed over all ranks (losses: their mean) and writes the checkpoints,
which hold rank 0's state as above plus `world_size` and the other ranks' states under `ranks`; on
resume each rank restores its own (the same number of processes is required). On CUDA each rank
replays its rollout from CUDA graphs; the update, with its all-reduce, runs eagerly.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import datetime
import errno
import glob
import io
import json
import os
import random
import re
import statistics
import warnings
from collections import deque

import numpy as np
import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils import resolve_callable
from rsl_rl.utils.logger import Logger

from ..atomic import atomic_open
from ..device import resolve_device
from ..drivers import make_driver
from ..env import BatchedAquarium
from . import (
    _rsl,  # noqa: F401
    distributed,
)
from .config import (
    TEAMS,
    default_opponent,
    env_config,
    learning_teams,
    make_config,
    runner_config,
    team_settings,
    total_iterations,
    validate,
)
from .export import export_policy, policy_from_actor, policy_meta
from .loop import TrainingLoop
from .memory import check_training_memory
from .stop import StopRequest
from .vec_env import OTHER, AquariumVecEnv, LearnerActions, policy_driver

CSV_FIELDS = ["iteration", "agent_steps", "world_steps", "world_episodes", "episodes_logged", "captures",
              "captures_per_prey", "reward_per_agent", "opponent_reward_per_agent", "episode_length",
              "mean_row_reward", "value_loss", "surrogate_loss", "entropy", "learning_rate", "fps",
              "collect_time", "learn_time"]


class AquariumLogger(Logger):
    """rsl-rl's logger plus a CSV row per iteration and an optional tqdm bar instead of the print.
    With several learners each has one (`team`: its scalars are logged as `<team>/...`, the swarm
    metrics of the worlds once, unprefixed), sharing the first one's writer."""

    def __init__(self, *args, csv_path: str | None = None, slots: int = 1, max_steps: int = 1,
                 quiet: bool = False, team: str | None = None, bar: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        self.csv_path, self.slots, self.max_steps, self.quiet = csv_path, slots, max_steps, quiet
        self.team, self.bar = team, bar
        self._bar = None

    def _tag(self, key: str) -> str:
        return key if self.team is None or key.startswith("Swarm/") else f"{self.team}/{key}"

    def log(self, it, start_it, total_it, collect_time, learn_time, loss_dict, learning_rate, action_std,
            rnd_weight, print_minimal=False, width=80, pad=40):
        if self.writer is None:
            return
        means, counts = {}, {}
        for key in dict.fromkeys(k for info in self.ep_extras for k in info):
            values = [torch.as_tensor(info[key], dtype=torch.float32).reshape(-1).cpu()
                      for info in self.ep_extras if key in info]
            cat = torch.cat(values)
            means[key], counts[key] = float(cat.mean()), int(cat.numel())
        mean_row_reward = statistics.mean(self.rewbuffer) if len(self.rewbuffer) else float("nan")
        with contextlib.redirect_stdout(io.StringIO()) if self.quiet else contextlib.nullcontext():
            super().log(it, start_it, total_it, collect_time, learn_time, loss_dict, learning_rate, action_std,
                        rnd_weight, print_minimal, width, pad)
        world_steps = self.tot_timesteps // self.slots
        row = {
            "iteration": it, "agent_steps": self.tot_timesteps, "world_steps": world_steps,
            "world_episodes": world_steps / self.max_steps,
            "episodes_logged": counts.get("Episode/captures", 0),
            "captures": means.get("Episode/captures", ""),
            "captures_per_prey": means.get("Episode/captures_per_prey", ""),
            "reward_per_agent": means.get("Episode/reward_per_agent", ""),
            "opponent_reward_per_agent": means.get("Episode/opponent_reward_per_agent", ""),
            "episode_length": means.get("Episode/length", ""),
            "mean_row_reward": mean_row_reward,
            "value_loss": loss_dict.get("value", ""), "surrogate_loss": loss_dict.get("surrogate", ""),
            "entropy": loss_dict.get("entropy", ""), "learning_rate": learning_rate,
            "fps": int(self.cfg["num_steps_per_env"] * self.num_envs / max(1e-9, collect_time + learn_time)),
            "collect_time": collect_time, "learn_time": learn_time,
        }
        self._write_row(row)
        if self.quiet:
            self._progress(it, total_it, row)

    def _write_row(self, row: dict) -> None:
        if self.csv_path is not None:
            new = not os.path.isfile(self.csv_path)
            with open(self.csv_path, "a", newline="", encoding="utf-8") as f:
                writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
                if new:
                    writer.writeheader()
                writer.writerow(row)

    def log_iteration(self, it: int, start_it: int, total_it: int, collect_time: float, learn_time: float,
                      losses: dict | None, learning_rate: float, episode_means: dict, episodes: int,
                      mean_row_reward: float) -> None:
        """The training loop's log of one iteration (`loop.py`): TensorBoard scalars under rsl-rl's
        names, the CSV row, and one console line (or the progress bar when quiet) with what matters
        for this task: captures per prey, the team's reward per agent, agent-steps/s, time left.
        `losses` is None for a learner frozen in this iteration (alternating schedule)."""
        if self.writer is None:
            return
        collection_size = self.cfg["num_steps_per_env"] * self.num_envs * self.gpu_world_size
        iteration_time = collect_time + learn_time
        self.tot_timesteps += collection_size
        self.tot_time += iteration_time
        fps = int(collection_size / max(1e-9, iteration_time))
        for key, value in episode_means.items():
            self.writer.add_scalar(self._tag(key), value, it)
        for key, value in (losses or {}).items():
            self.writer.add_scalar(self._tag(f"Loss/{key}"), value, it)
        self.writer.add_scalar(self._tag("Loss/learning_rate"), learning_rate, it)
        self.writer.add_scalar(self._tag("Perf/total_fps"), fps, it)
        self.writer.add_scalar(self._tag("Perf/collection_time"), collect_time, it)
        self.writer.add_scalar(self._tag("Perf/learning_time"), learn_time, it)
        if mean_row_reward == mean_row_reward:  # not NaN: some row episodes ended
            self.writer.add_scalar(self._tag("Train/mean_reward"), mean_row_reward, it)
        world_steps = self.tot_timesteps // self.slots
        losses = losses or dict.fromkeys(("value", "surrogate", "entropy"), "")
        row = {
            "iteration": it, "agent_steps": self.tot_timesteps, "world_steps": world_steps,
            "world_episodes": world_steps / self.max_steps, "episodes_logged": episodes,
            "mean_row_reward": mean_row_reward if mean_row_reward == mean_row_reward else "",
            "value_loss": losses["value"], "surrogate_loss": losses["surrogate"], "entropy": losses["entropy"],
            "learning_rate": learning_rate, "fps": fps, "collect_time": collect_time, "learn_time": learn_time,
        }
        for field in ("captures", "captures_per_prey", "reward_per_agent", "opponent_reward_per_agent"):
            row[field] = episode_means.get(f"Episode/{field}", "")
        row["episode_length"] = episode_means.get("Episode/length", "")
        self._write_row(row)
        if self.quiet:
            if self.bar:
                self._progress(it, total_it, row)
            return
        done = it + 1 - start_it
        eta = self.tot_time / max(1, done) * (total_it - start_it - done) if done else 0.0
        parts = [f"it {it + 1}/{total_it}"] + ([self.team] if self.team is not None else [])
        if row["captures_per_prey"] != "":
            parts += [f"captures/prey {row['captures_per_prey']:.3f}", f"reward/agent {row['reward_per_agent']:.1f}",
                      f"opponent reward/agent {row['opponent_reward_per_agent']:.1f}"]
        if losses["value"] != "":
            parts += [f"value loss {losses['value']:.4f}", f"entropy {losses['entropy']:.3f}"]
        else:
            parts += ["frozen"]
        parts += [f"{fps:.3g} agent-steps/s", f"left {datetime.timedelta(seconds=int(eta))}"]
        print(" | ".join(parts), flush=True)

    def _progress(self, it, total_it, row) -> None:
        try:
            from tqdm import tqdm
        except ImportError:  # pragma: no cover
            return
        if self._bar is None:
            self._bar = tqdm(total=total_it, initial=it, unit="it", dynamic_ncols=True)
        self._bar.update(1)
        post = {}
        if row["captures_per_prey"] != "":
            post["capt/prey"] = f"{row['captures_per_prey']:.3f}"
            post["rew/agent"] = f"{row['reward_per_agent']:.1f}"
        post["fps"] = row["fps"]
        self._bar.set_postfix(post, refresh=False)

    def close_progress(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def state_dict(self) -> dict:
        return {"tot_timesteps": self.tot_timesteps, "tot_time": self.tot_time,
                "rewbuffer": list(self.rewbuffer), "lenbuffer": list(self.lenbuffer),
                "cur_reward_sum": self.cur_reward_sum.cpu().clone(),
                "cur_episode_length": self.cur_episode_length.cpu().clone()}

    def load_state_dict(self, state: dict) -> None:
        self.tot_timesteps, self.tot_time = state["tot_timesteps"], state["tot_time"]
        self.rewbuffer = deque(state["rewbuffer"], maxlen=self.rewbuffer.maxlen)
        self.lenbuffer = deque(state["lenbuffer"], maxlen=self.lenbuffer.maxlen)
        self.cur_reward_sum.copy_(state["cur_reward_sum"].to(self.cur_reward_sum.device))
        self.cur_episode_length.copy_(state["cur_episode_length"].to(self.cur_episode_length.device))


class Learner:
    """One learning team of a run: its adapter, rsl-rl runner config, algorithm (PPO) and logger."""

    def __init__(self, team: str, vec_env: AquariumVecEnv, cfg: dict, alg, logger: AquariumLogger):
        self.team, self.vec_env, self.cfg, self.alg, self.logger = team, vec_env, cfg, alg, logger


class AquariumRunner(OnPolicyRunner):
    """`OnPolicyRunner` whose checkpoints carry the whole training state (see the module doc) and whose
    iteration counter means "iterations completed" between `learn()` calls.

    `others`: `(vec_env, cfg)` of further learners in the same worlds (`train.team = "both"`); each
    gets its own algorithm (built by rsl-rl's `construct_algorithm`, as the runner builds its own),
    storage, optimizer and logger. `self.learners` lists them all, this runner's own first."""

    def __init__(self, env: AquariumVecEnv, train_cfg: dict, log_dir: str | None = None, device: str = "cpu",
                 trainer: Trainer | None = None, quiet: bool = False, others=()):
        super().__init__(env, train_cfg, log_dir=log_dir, device=device)
        self.trainer = trainer
        several = bool(others)

        def logger(vec_env: AquariumVecEnv, cfg: dict, first: bool) -> AquariumLogger:
            name = f"progress_{vec_env.team}.csv" if several else "progress.csv"
            return AquariumLogger(
                log_dir=log_dir, cfg=cfg, env_cfg=vec_env.cfg, num_envs=vec_env.num_envs,
                is_distributed=self.is_distributed, gpu_world_size=self.gpu_world_size,
                gpu_global_rank=self.gpu_global_rank, device=self.device,
                csv_path=os.path.join(log_dir, name) if log_dir else None, slots=vec_env.slots,
                max_steps=vec_env.max_episode_length, quiet=quiet, team=vec_env.team if several else None,
                bar=first)

        self.logger = logger(env, self.cfg, True)
        self.learners = [Learner(env.team, env, self.cfg, self.alg, self.logger)]
        for vec_env, cfg in others:
            cfg["multi_gpu"] = self.cfg["multi_gpu"]
            alg_class = resolve_callable(cfg["algorithm"]["class_name"])
            alg = alg_class.construct_algorithm(vec_env.get_observations(), vec_env, cfg, self.device)
            self.learners.append(Learner(vec_env.team, vec_env, cfg, alg, logger(vec_env, cfg, False)))
        self._in_learn = False
        train = trainer.config["train"] if trainer is not None else {}
        self.loop_kind = train.get("loop", "fast")
        self.cuda_graphs = bool(train.get("cuda_graphs", True))
        self.loop: TrainingLoop | None = None

    def _configure_multi_gpu(self) -> None:
        """rsl-rl's setup of a several-process run (torchrun), with the backend chosen by the device:
        NCCL for `cuda:LOCAL_RANK`, gloo for the CPU (rsl-rl's own accepts CUDA and NCCL only)."""
        self.gpu_global_rank, self.gpu_local_rank, self.gpu_world_size = distributed.world()
        self.is_distributed = self.gpu_world_size > 1
        if not self.is_distributed:
            self.cfg["multi_gpu"] = None
            return
        if self.device not in ("cpu", f"cuda:{self.gpu_local_rank}"):
            raise ValueError(f"device {self.device!r} of rank {self.gpu_global_rank}: a torchrun run trains on "
                             f"'cpu' or 'cuda:{self.gpu_local_rank}' (LOCAL_RANK)")
        self.cfg["multi_gpu"] = {"global_rank": self.gpu_global_rank, "local_rank": self.gpu_local_rank,
                                 "world_size": self.gpu_world_size}
        distributed.init(self.device, self.gpu_global_rank, self.gpu_world_size)

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        if num_learning_iterations <= 0:
            return
        self._in_learn = True
        try:
            if self.loop_kind == "rsl-rl":
                super().learn(num_learning_iterations, init_at_random_ep_len=init_at_random_ep_len)
            else:
                self._learn_fast(num_learning_iterations, init_at_random_ep_len)
        finally:
            self._in_learn = False
            self.logger.close_progress()
        self.current_learning_iteration += 1  # iterations completed

    def _learn_fast(self, num_learning_iterations: int, init_at_random_ep_len: bool) -> None:
        """`OnPolicyRunner.learn` with `TrainingLoop` doing each iteration (see `loop.py`): the same
        calls in the same order, logging once per iteration."""
        if init_at_random_ep_len:
            self.env.episode_length_buf = torch.randint_like(
                self.env.episode_length_buf, high=int(self.env.max_episode_length))
            for learner in self.learners[1:]:  # the worlds' step counters changed under them too
                learner.vec_env.sync_from_env()
        if self.loop is None:
            self.loop = TrainingLoop([(learner.alg, learner.vec_env) for learner in self.learners],
                                     self.cfg["num_steps_per_env"], graphs=self.cuda_graphs,
                                     pool=self.trainer.pool if self.trainer is not None else None,
                                     # episode statistics are sums and counts, losses become their mean
                                     reduce=distributed.sum_over_ranks if self.is_distributed else None)
        for learner in self.learners:
            learner.alg.train_mode()
            if self.is_distributed:  # every rank starts from rank 0's parameters
                learner.alg.broadcast_parameters()
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl reports storing git state (under git/)
            self.logger.init_logging_writer()
        for learner in self.learners[1:]:
            learner.logger.writer = self.logger.writer
        start_it = self.current_learning_iteration
        total_it = start_it + num_learning_iterations

        def log(it: int, record) -> None:
            values, (collect_time, learn_time) = record.read()  # summed over the ranks (`reduce`)
            # A frozen learner (alternating schedule) logs no losses; a learner's NaN loss is logged.
            learning = self.trainer.learning(it) if self.trainer is not None else None
            for k, (learner, (losses, stats)) in enumerate(zip(self.learners, self.loop.split(values))):
                losses = [loss / self.gpu_world_size for loss in losses]
                means, episodes, row_reward = learner.vec_env.decode_episode_stats(stats)
                frozen = learning is not None and not learning[k]
                learner.logger.log_iteration(it, start_it, total_it, collect_time, learn_time,
                                             None if frozen else dict(zip(("value", "surrogate", "entropy"), losses)),
                                             learner.alg.learning_rate, means, episodes, row_reward)

        # Every rank takes part in a save (rank 0 gathers their states), only rank 0 has a writer.
        saves = self.logger.log_dir is not None
        pending = None  # the previous iteration, logged while this one runs on the device
        for it in range(start_it, total_it):
            record = self.loop.iteration(self.trainer.learning(it) if self.trainer is not None else None)
            self.current_learning_iteration = it
            if self.trainer is not None:
                self.trainer.after_iteration(it)
            if pending is not None:
                log(*pending)
            pending = (it, record)
            if saves and it % self.cfg["save_interval"] == 0:
                log(*pending)  # a checkpoint's progress.csv holds its own iteration
                pending = None
                self.save(os.path.join(self.logger.log_dir, f"model_{it}.pt"))
            if self.trainer is not None and self.trainer.stop.signum is not None:
                break  # SIGINT or SIGTERM: the final checkpoint below holds this iteration
        if pending is not None:
            log(*pending)
        if saves:
            self.save(os.path.join(self.logger.log_dir, f"model_{self.current_learning_iteration}.pt"))
        if self.logger.writer is not None:
            self.logger.stop_logging_writer()

    def completed_iterations(self) -> int:
        return self.current_learning_iteration + 1 if self._in_learn else self.current_learning_iteration

    def save(self, path: str, infos: dict | None = None) -> None:
        if len(self.learners) == 1:
            saved = self.alg.save()
        else:  # one rsl-rl state per team
            saved = {"learners": {learner.team: learner.alg.save() for learner in self.learners}}
        saved["iter"] = self.completed_iterations()
        infos = dict(infos or {})
        if self.trainer is not None:
            infos["aquarium"] = self.trainer.extra_state()
            if self.is_distributed:  # every rank's worlds and random streams, in rank 0's one file
                states = distributed.gather_on_first(distributed.to_cpu(infos["aquarium"]))
                if states is None:
                    return
                infos["aquarium"] = {**states[0], "world_size": self.gpu_world_size, "ranks": states[1:]}
        elif self.is_distributed and self.gpu_global_rank != 0:
            return
        saved["infos"] = infos
        # Atomic: an interrupted save never leaves a truncated checkpoint under a checkpoint's name.
        with atomic_open(path, "wb") as f:
            try:
                torch.save(saved, f)
            except RuntimeError as error:  # torch's zip writer reports a failed write (a full disk) so
                reason = (str(error).strip().splitlines() or [""])[0][:200]
                raise OSError(errno.EIO, f"writing the checkpoint failed ({reason})", path) from None
        self.logger.save_model(path, self.current_learning_iteration)

    def load(self, path: str, load_cfg: dict | None = None, strict: bool = True, map_location=None) -> dict:
        loaded = torch.load(path, weights_only=False, map_location=map_location)
        if len(self.learners) == 1:
            load_iteration = self.alg.load(loaded, load_cfg, strict)
        else:
            load_iteration = [learner.alg.load(loaded["learners"][learner.team], load_cfg, strict)
                              for learner in self.learners][0]
        if load_iteration:
            self.current_learning_iteration = loaded["iter"]
        infos = loaded.get("infos") or {}
        if self.trainer is not None and "aquarium" in infos and (load_cfg is None or load_cfg.get("iteration")):
            self.trainer.load_extra_state(infos["aquarium"])
        return infos


def _rng_state(device: torch.device) -> dict:
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def _set_rng_state(state: dict, device: torch.device) -> None:
    # RNG states are CPU byte tensors (a checkpoint loaded with map_location="cuda" moved them).
    torch.set_rng_state(state["torch"].cpu())
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"].cpu(), device)


def latest_checkpoint(run_dir: str) -> str:
    """The readable checkpoint `model_<i>.pt` with the largest i in `run_dir`; newer ones that cannot be
    read (empty, truncated, corrupt) are skipped with a warning."""
    return _newest_readable_checkpoint(run_dir)[0]


def _newest_readable_checkpoint(run_dir: str) -> tuple[str, dict]:
    paths = glob.glob(os.path.join(run_dir, "model_*.pt"))
    numbered = sorted(((int(m.group(1)), p) for p in paths if (m := re.search(r"model_(\d+)\.pt$", p))),
                      reverse=True)
    if not numbered:
        raise ValueError(f"no checkpoint model_<i>.pt in {run_dir!r}")
    for _, path in numbered:
        try:
            return path, _read_checkpoint(path)
        except ValueError as error:
            warnings.warn(f"skipping {error}", stacklevel=3)
    raise ValueError(f"no readable checkpoint model_<i>.pt in {run_dir!r} ({len(numbered)} found, all broken)")


def _read_checkpoint(path: str) -> dict:
    """A training checkpoint of this package; a one-line ValueError for a missing, empty, truncated,
    corrupt or foreign file."""
    if not os.path.isfile(path):
        raise ValueError(f"checkpoint {path!r} does not exist")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # noqa: BLE001 - torch raises many kinds for a damaged file (EOF, unpickling, zip)
        reason = (str(error).strip().splitlines() or [""])[0][:200]
        raise ValueError(f"{path}: not a readable checkpoint (empty, truncated or another format: "
                         f"{type(error).__name__}: {reason})") from None
    state = (checkpoint.get("infos") or {}).get("aquarium") if isinstance(checkpoint, dict) else None
    if not isinstance(state, dict) or "config" not in state:
        raise ValueError(f"{path}: not a checkpoint of aquarium_warp.training")
    return checkpoint


class Trainer:
    """Builds the simulator, the opponent (or, with `train.team = "both"`, a learner per team and the
    opponent pool), the adapters and the rsl-rl runner of a run config; trains, checkpoints, resumes
    and exports. `log_dir=None`: no TensorBoard, CSV or checkpoints."""

    def __init__(self, config: dict, log_dir: str | None = None):
        config = copy.deepcopy(config)
        validate(config)
        train = config["train"]
        self.teams = learning_teams(config)
        both = len(self.teams) == 2
        if train["opponent"] is None and not both:
            train["opponent"] = default_opponent(train["team"])
        self.config = config
        self.log_dir = log_dir
        self.stop = StopRequest()
        # torchrun: one process (rank) per GPU or CPU share, each with its own worlds and seed.
        self.rank, local_rank, self.world_size = distributed.world()
        if self.world_size > 1 and train["loop"] == "rsl-rl":
            raise ValueError("train.loop='rsl-rl' runs in one process; a torchrun run needs train.loop='fast'")
        device = distributed.rank_device(train["device"], local_rank) if self.world_size > 1 else train["device"]
        self.seed = int(train["seed"]) + self.rank
        torch.manual_seed(self.seed)
        np.random.seed(self.seed % 2**32)
        random.seed(self.seed)

        check_training_memory(config, resolve_device(device))  # the whole run, before anything is allocated
        self.env = BatchedAquarium(env_config(config), num_worlds=train["num_worlds"], device=device,
                                   seed=self.seed)
        self.device = self.env.torch_device
        if train["tf32"] and self.device.type == "cuda":
            torch.backends.cuda.matmul.allow_tf32 = True  # a process-wide switch of torch's
        if both:  # each team's opponent is the other learner, whose actions the training loop writes
            self.opponent = None
            opponents = {team: LearnerActions() for team in TEAMS}
        else:
            self.opponent = make_driver(train["opponent"], self.env, OTHER[train["team"]],
                                        deterministic=train["opponent_deterministic"], seed=self.seed)
            opponents = {train["team"]: self.opponent}
        # The first team's adapter steps the worlds and samples the swarm metrics (one per world is enough).
        self.vec_envs = {team: AquariumVecEnv(self.env, team, opponents[team],
                                              reward_scale=team_settings(config, team)["reward_scale"], cfg=config,
                                              metrics_every=int(train["metrics_every"]) if i == 0 else 0,
                                              critic=team_settings(config, team)["critic"],
                                              randomize=train["randomize"] if i == 0 else None,
                                              randomize_seed=self.seed)
                         for i, team in enumerate(self.teams)}
        if both:
            for team in TEAMS:
                opponents[team].vec_env = self.vec_envs[OTHER[team]]
        self.vec_env = self.vec_envs[self.teams[0]]
        self.runner_cfgs = {team: runner_config(config, v.slots, v.action_count, self.device.type, team=team)
                            for team, v in self.vec_envs.items()}
        self.runner_cfg = self.runner_cfgs[self.teams[0]]
        self.total_iterations = total_iterations(config)
        if log_dir is not None and self.rank == 0:
            os.makedirs(log_dir, exist_ok=True)
            record = {"config": config, "runner_cfg": self.runner_cfg if not both else self.runner_cfgs,
                      "total_iterations": self.total_iterations}
            if self.world_size > 1:  # rank r simulates with seed train.seed + r
                record["distributed"] = {"world_size": self.world_size,
                                         "seeds": [int(train["seed"]) + r for r in range(self.world_size)]}
            with atomic_open(os.path.join(log_dir, "config.json")) as f:
                json.dump(record, f, indent=1, default=str)
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the networks (config.json has them)
            self.runner = AquariumRunner(
                self.vec_env, copy.deepcopy(self.runner_cfg), log_dir=log_dir, device=str(self.device), trainer=self,
                quiet=train["quiet"],
                others=[(self.vec_envs[t], copy.deepcopy(self.runner_cfgs[t])) for t in self.teams[1:]])
        self.learners = {learner.team: learner for learner in self.runner.learners}
        self.pool = None
        if train["pool_every"]:
            from .pool import OpponentPool

            self.pool = OpponentPool({t: (l.alg.get_policy(), l.vec_env) for t, l in self.learners.items()},
                                     size=int(train["pool_size"]), sampling=train["pool_sampling"],
                                     fractions={t: float(team_settings(config, t)["pool_fraction"]) for t in TEAMS})
        self.video = None
        if train["video_every"]:
            from .episode_video import EpisodeVideo

            self.video = EpisodeVideo(env_config(config), self.device, self.seed, int(train["video_steps"]))
        if log_dir is not None:
            import aquarium_warp

            self.runner.add_git_repo_to_log(aquarium_warp.__file__)

    # ------------------------------------------------------------------ construction from checkpoints
    @classmethod
    def resume(cls, path: str, log_dir: str | None = None, changes: dict | None = None) -> Trainer:
        """A trainer restored from a checkpoint, or from the newest checkpoint of a run directory.
        `changes` may alter train settings that do not affect the state (iterations, episodes,
        quiet, export, videos); the log directory defaults to the checkpoint's."""
        if os.path.isdir(path):
            checkpoint_path, checkpoint = _newest_readable_checkpoint(path)
        else:
            checkpoint_path, checkpoint = path, _read_checkpoint(path)
        config = copy.deepcopy(checkpoint["infos"]["aquarium"]["config"])
        if changes:
            allowed = {"iterations", "episodes", "quiet", "export", "loop", "cuda_graphs", "tf32", "video_every",
                       "video_steps"}
            bad = [k for k in changes.get("train", {}) if k not in allowed] + \
                  [k for k in changes if k != "train"]
            if bad:
                raise ValueError(f"a resumed run keeps its config; only train.{sorted(allowed)} may change, not {bad}")
            config["train"].update(changes.get("train", {}))
        trainer = cls(config, log_dir=log_dir if log_dir is not None
                      else os.path.dirname(os.path.abspath(checkpoint_path)))
        trainer.load(checkpoint_path)
        return trainer

    # ------------------------------------------------------------------ state
    def _learner_state(self, learner: Learner, with_env: bool) -> dict:
        from .models import hidden_state_to

        return {
            "runner_cfg": self.runner_cfgs[learner.team],
            "policy_meta": self.policy_meta(learner.team),
            "vec_env": learner.vec_env.state_dict(with_env=with_env),
            "logger": learner.logger.state_dict(),
            # Recurrent models carry each row's GRU/LSTM state from one iteration into the next.
            "hidden_states": {name: hidden_state_to(getattr(learner.alg, name).get_hidden_state(), "cpu")
                              for name in ("actor", "critic")},
        }

    def _load_learner_state(self, learner: Learner, state: dict) -> None:
        from .models import hidden_state_to

        learner.vec_env.load_state_dict(state["vec_env"])
        learner.logger.load_state_dict(state["logger"])
        for name, hidden in state.get("hidden_states", {}).items():
            model = getattr(learner.alg, name)
            if model.is_recurrent:  # reset(hidden_state=None) clears it, as before the first step
                model.reset(hidden_state=hidden_state_to(hidden, self.device))

    def extra_state(self) -> dict:
        """The trainer's part of a checkpoint: run config, RNG states and, per learner, its adapter
        (the simulation once), logger and hidden states; both teams: under `teams`, with the pool."""
        state = {"config": self.config, "seed": self.seed, "rng": _rng_state(self.device)}
        learners = self.runner.learners
        if len(learners) == 1:
            return {**state, **self._learner_state(learners[0], with_env=True)}
        return {**state, "pool": self.pool.state_dict() if self.pool is not None else None,
                "teams": {l.team: self._learner_state(l, with_env=i == 0) for i, l in enumerate(learners)}}

    def load_extra_state(self, state: dict) -> None:
        """Restore `extra_state()`; of a torchrun run's checkpoint (`world_size`, the other ranks'
        states under `ranks`), this rank's own part."""
        saved_size = int(state.get("world_size", 1))
        if saved_size != self.world_size:
            raise ValueError(f"the checkpoint holds the state of {saved_size} process(es) (torchrun's WORLD_SIZE), "
                             f"this run has {self.world_size}: resume with the same number of processes")
        if self.rank > 0:
            state = state["ranks"][self.rank - 1]
        if self.pool is not None:  # first: the adapters' rows depend on which worlds the learners drive
            self.pool.load_state_dict(state["pool"])
        learners = self.runner.learners
        if len(learners) == 1:
            self._load_learner_state(learners[0], state)
        else:
            for learner in learners:  # the first one restores the simulation
                self._load_learner_state(learner, state["teams"][learner.team])
        _set_rng_state(state["rng"], self.device)

    def load(self, path: str) -> None:
        """Restore the whole training state from a checkpoint of this run's config."""
        self.runner.load(path, map_location=str(self.device))
        done = self.runner.current_learning_iteration
        for learner in self.runner.learners:  # drop rows logged after the checkpoint
            csv_path = learner.logger.csv_path
            if self.log_dir and self.rank == 0 and csv_path and os.path.isfile(csv_path):
                with open(csv_path, newline="", encoding="utf-8") as f:
                    rows = [r for r in csv.DictReader(f) if int(r["iteration"]) < done]
                with atomic_open(csv_path, newline="") as f:
                    writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
                    writer.writeheader()
                    writer.writerows(rows)

    @property
    def iteration(self) -> int:
        """Iterations completed."""
        return self.runner.current_learning_iteration

    # ------------------------------------------------------------------ training
    def train(self, iterations: int | None = None) -> None:
        """Run `iterations` more iterations (default: up to the config's total)."""
        if iterations is None:
            iterations = self.total_iterations - self.iteration
        fresh = self.iteration == 0
        # Our loop stops at an iteration boundary on SIGINT or SIGTERM (`stop.py`); rsl-rl's cannot, and
        # torchrun's ranks could see a signal at different iterations (their all-reduces would wait forever).
        graceful = self.runner.loop_kind == "fast" and self.world_size == 1
        catching = self.stop.catching() if graceful else contextlib.nullcontext()
        with catching:
            self.runner.learn(iterations,
                              init_at_random_ep_len=fresh and bool(self.config["train"]["init_at_random_ep_len"]))

    def learning(self, iteration: int) -> list[bool] | None:
        """Which learners update in `iteration` (None: all). Alternating schedule: the teams take turns
        of `train.alternate_every` iterations, prey first; the other team is frozen meanwhile."""
        train = self.config["train"]
        if len(self.teams) == 1 or train["update_schedule"] == "simultaneous":
            return None
        turn = (iteration // int(train["alternate_every"])) % len(self.teams)
        return [i == turn for i in range(len(self.teams))]

    def after_iteration(self, iteration: int) -> None:
        """Between iterations (`iteration` done): the pool's snapshots and the log's video, when due."""
        train = self.config["train"]
        if self.pool is not None and (iteration + 1) % int(train["pool_every"]) == 0:
            self.pool.snapshot()
        writer = self.runner.logger.writer
        if self.video is not None and writer is not None and (iteration + 1) % int(train["video_every"]) == 0:
            self.video.log(writer, self.video.record(self.video_drivers), iteration, self.log_dir)

    def video_drivers(self, env: BatchedAquarium) -> dict:
        """Every team's driver in a video's world: the learners' current actors (argmax), and for a
        one-team run the opponent as in training."""
        train = self.config["train"]
        drivers = {team: policy_driver(policy_from_actor(self.learners[team].alg.get_policy(), self.policy_meta(team),
                                                         self.device), env, team) for team in self.teams}
        if self.opponent is not None:
            other = OTHER[train["team"]]
            drivers[other] = make_driver(train["opponent"], env, other,
                                         deterministic=train["opponent_deterministic"], seed=self.seed)
        return drivers

    def save(self, path: str) -> None:
        self.runner.save(path)

    @property
    def actor(self):
        """The (first) learner's actor."""
        return self.runner.alg.get_policy()

    def policy_meta(self, team: str | None = None) -> dict:
        """Metadata of `team`'s exported policy (default: the first learner's)."""
        vec = self.vec_envs[team or self.teams[0]]
        return policy_meta(self.config, vec.slots, vec.observation_size, vec.action_count, team=vec.team)

    def export(self, out_dir: str | None = None, formats=None) -> dict:
        """Export the current policy (default: `<log_dir>/exported`, the config's formats): `{format:
        path}`. Both teams: one policy per team in `<out_dir>/<team>/`, `{team: {format: path}}`."""
        if out_dir is None:
            if self.log_dir is None:
                raise ValueError("export needs out_dir when the trainer has no log_dir")
            out_dir = os.path.join(self.log_dir, "exported")
        formats = self.config["train"]["export"] if formats is None else formats
        if len(self.teams) == 1:
            return export_policy(self.actor, self.policy_meta(), out_dir, formats)
        return {team: export_policy(self.learners[team].alg.get_policy(), self.policy_meta(team),
                                    os.path.join(out_dir, team), formats) for team in self.teams}

    def close(self) -> None:
        if self.video is not None:
            self.video.close()
        self.vec_env.close()
        if self.world_size > 1:
            distributed.close()


__all__ = ["Trainer", "AquariumRunner", "AquariumLogger", "latest_checkpoint",
           "make_config"]
