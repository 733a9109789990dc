"""rsl-rl's `OnPolicyRunner` for this package: `AquariumRunner` (a `Learner` per learning team, the fast
training loop, several processes, checkpoints that carry the whole training state) driven by a
`trainer.Trainer`."""

from __future__ import annotations

import contextlib
import io
import os
from typing import TYPE_CHECKING, Protocol

import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils import resolve_callable

from . import (
    _rsl,  # noqa: F401
    distributed,
)
from .checkpoints import write_checkpoint
from .logger import AquariumLogger
from .loop import TrainingLoop, graph_plan
from .vec_env import AquariumVecEnv

if TYPE_CHECKING:
    from .pool import OpponentPool
    from .stop import StopRequest


class RunOwner(Protocol):
    """What the runner asks of the run that drives it (`trainer.Trainer`): its config, its stop request and
    opponent pool, which learners update in an iteration, the work between iterations, and its part of
    a checkpoint."""

    config: dict
    stop: StopRequest
    pool: OpponentPool | None

    def learning(self, iteration: int) -> list[bool] | None: ...

    def after_iteration(self, iteration: int) -> None: ...

    def extra_state(self) -> dict: ...

    def load_extra_state(self, state: dict) -> None: ...


class Learner:
    """One learning team of a run: its adapter, rsl-rl runner config, algorithm (PPO) and logger."""

    def __init__(self, team: str, vec_env: AquariumVecEnv, cfg: dict, alg, logger: AquariumLogger):
        self.team, self.vec_env, self.cfg, self.alg, self.logger = team, vec_env, cfg, alg, logger


class AquariumRunner(OnPolicyRunner):
    """`OnPolicyRunner` whose checkpoints carry the whole training state (see `trainer.py`'s doc) and whose
    iteration counter means "iterations completed" between `learn()` calls.

    `others`: `(vec_env, cfg)` of further learners in the same worlds (`train.team = "both"`); each
    gets its own algorithm (built by rsl-rl's `construct_algorithm`, as the runner builds its own),
    storage, optimizer and logger. `self.learners` lists them all, this runner's own first."""

    # Declared: `load` rebinds rsl-rl's counter from a checkpoint, which its type inference cannot follow.
    current_learning_iteration: int

    def __init__(
        self,
        env: AquariumVecEnv,
        train_cfg: dict,
        log_dir: str | None = None,
        device: str = "cpu",
        trainer: RunOwner | None = None,
        quiet: bool = False,
        others=(),
    ):
        super().__init__(env, train_cfg, log_dir=log_dir, device=device)
        self.trainer = trainer
        several = bool(others)

        def logger(vec_env: AquariumVecEnv, cfg: dict, first: bool) -> AquariumLogger:
            name = f"progress_{vec_env.team}.csv" if several else "progress.csv"
            return AquariumLogger(
                log_dir=log_dir,
                cfg=cfg,
                env_cfg=vec_env.cfg,
                num_envs=vec_env.num_envs,
                is_distributed=self.is_distributed,
                gpu_world_size=self.gpu_world_size,
                gpu_global_rank=self.gpu_global_rank,
                device=self.device,
                csv_path=os.path.join(log_dir, name) if log_dir else None,
                slots=vec_env.slots,
                max_steps=vec_env.max_episode_length,
                quiet=quiet,
                team=vec_env.team if several else None,
                bar=first,
            )

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
        self.graph_update = train.get("graph_update", "auto")
        self.loop: TrainingLoop | None = None

    def graph_plan(self) -> tuple[bool, list[bool | str]]:
        """The CUDA graphs the training loop captures: the rollout's, and per learner how its update is
        captured (`loop.graph_plan`, from `train.loop`, `train.cuda_graphs`, `train.graph_update` and the device)."""
        cuda = self.loop_kind == "fast" and self.cuda_graphs and torch.device(self.device).type == "cuda"
        return graph_plan([learner.alg for learner in self.learners], cuda, self.graph_update)

    def _configure_multi_gpu(self) -> None:
        """rsl-rl's setup of a several-process run (torchrun), with the backend chosen by the device:
        NCCL for `cuda:LOCAL_RANK`, gloo for the CPU (rsl-rl's own accepts CUDA and NCCL only)."""
        self.gpu_global_rank, self.gpu_local_rank, self.gpu_world_size = distributed.world()
        self.is_distributed = self.gpu_world_size > 1
        if not self.is_distributed:
            self.cfg["multi_gpu"] = None
            return
        if self.device not in ("cpu", f"cuda:{self.gpu_local_rank}"):
            raise ValueError(
                f"device {self.device!r} of rank {self.gpu_global_rank}: a torchrun run trains on "
                f"'cpu' or 'cuda:{self.gpu_local_rank}' (LOCAL_RANK)"
            )
        self.cfg["multi_gpu"] = {
            "global_rank": self.gpu_global_rank,
            "local_rank": self.gpu_local_rank,
            "world_size": self.gpu_world_size,
        }
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
                self.env.episode_length_buf, high=int(self.env.max_episode_length)
            )
            for learner in self.learners[1:]:  # the worlds' step counters changed under them too
                learner.vec_env.sync_from_env()
        loop = self.loop
        if loop is None:
            loop = self.loop = TrainingLoop(
                [(learner.alg, learner.vec_env) for learner in self.learners],
                self.cfg["num_steps_per_env"],
                graphs=self.cuda_graphs,
                pool=self.trainer.pool if self.trainer is not None else None,
                # episode statistics are sums and counts, losses become their mean
                reduce=distributed.sum_over_ranks if self.is_distributed else None,
                graph_update=self.graph_update,
            )
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
            for k, (learner, (losses, stats)) in enumerate(zip(self.learners, loop.split(values))):
                losses = [loss / self.gpu_world_size for loss in losses]
                means, episodes, row_reward = learner.vec_env.decode_episode_stats(stats)
                frozen = learning is not None and not learning[k]
                learner.logger.log_iteration(
                    it,
                    start_it,
                    total_it,
                    collect_time,
                    learn_time,
                    None if frozen else dict(zip(("value", "surrogate", "entropy"), losses)),
                    learner.alg.learning_rate,
                    means,
                    episodes,
                    row_reward,
                )

        # Every rank takes part in a save (rank 0 gathers their states), only rank 0 has a writer.
        saves = self.logger.log_dir is not None
        pending = None  # the previous iteration, logged while this one runs on the device
        for it in range(start_it, total_it):
            record = loop.iteration(self.trainer.learning(it) if self.trainer is not None else None)
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
        write_checkpoint(saved, path)
        self.logger.save_model(path, self.current_learning_iteration)

    def load(self, path: str, load_cfg: dict | None = None, strict: bool = True, map_location=None) -> dict:
        loaded = torch.load(path, weights_only=False, map_location=map_location)
        if len(self.learners) == 1:
            load_iteration = self.alg.load(loaded, load_cfg, strict)
        else:
            load_iteration = [
                learner.alg.load(loaded["learners"][learner.team], load_cfg, strict) for learner in self.learners
            ][0]
        if load_iteration:
            self.current_learning_iteration = loaded["iter"]
        infos = loaded.get("infos") or {}
        if self.trainer is not None and "aquarium" in infos and (load_cfg is None or load_cfg.get("iteration")):
            self.trainer.load_extra_state(infos["aquarium"])
        return infos
