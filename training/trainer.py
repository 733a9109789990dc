"""PPO training of one team with rsl-rl's `OnPolicyRunner` over `AquariumVecEnv`.

```python
from aquarium_warp.training import Trainer, make_config

trainer = Trainer(make_config("paper", {"train": {"device": "cuda:0"}}), log_dir="runs/paper_ps_s0")
trainer.train()                    # up to the config's total iterations; checkpoints every save_interval
trainer.export()                   # runs/paper_ps_s0/exported/policy.pt, policy.onnx, policy.json
# later, or after a crash:
Trainer.resume("runs/paper_ps_s0").train()     # continues from the newest checkpoint
```

The log directory receives rsl-rl's TensorBoard events, `config.json` (the config; the run id, which its
checkpoints carry too, so that a resume never continues one run in another's directory; the command, commit,
machine and library versions (`aquarium_warp.records.provenance`); under `path` the matrix path
(`fast_path.FastPath.record`: `train.fused_mlp` and `train.tf32` as requested and as resolved, and why);
under `cuda_graphs` what the training loop captures: the rollout, each learner's update; with the fused
MLP, under `fused_loss` and `fused_act`, whether each learner's update runs the fused loss and its rollout
the fused step, or why not), `progress.csv` (one row per iteration: episode statistics, losses, speed)
and checkpoints `model_<i>.pt`, which hold the state after iteration i (0-based; the runner's `iter`
entry is the next iteration, `i + 1`).

A checkpoint holds, besides rsl-rl's (actor, critic, optimizer, iteration), under `infos["aquarium"]`:
the run config and id, the simulation's `state_dict` (every world's agents and step counters, i.e. the
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
resume each rank restores its own (the same number of processes is required). On CUDA (NCCL) each
rank replays its rollout from CUDA graphs and its update from graphs cut at each gradient all-reduce
(`loop.SplitGraph`); `train.graph_update=true` captures the update as one graph with the all-reduce
inside, as one process does.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import os
import time
import uuid

import torch

from ..agent_types import OTHER, TYPES
from ..atomic import atomic_open
from ..device import make_current, resolve_device, synchronize
from ..drivers import make_driver
from ..env import BatchedAquarium
from ..records import provenance
from ..seeding import rank_seed, seed_process
from . import (
    _rsl,  # noqa: F401
    distributed,
)
from .checkpoints import global_rng_state, newest_readable_checkpoint, read_checkpoint, restore_global_rng_state
from .config import (
    RESUMABLE_SETTINGS,
    default_opponent,
    env_config,
    learning_teams,
    runner_config,
    team_settings,
    total_iterations,
    validate,
)
from .drivers import LearnerActions, policy_driver
from .export import export_policy, policy_from_actor, policy_meta
from .fast_path import resolve_fast_path
from .memory import check_training_memory
from .run_dir import check_same_run
from .runner import AquariumRunner, Learner
from .stop import StopRequest
from .vec_env import AquariumVecEnv


def run_config(config: dict) -> dict:
    """`config` as a run holds it (`Trainer.config`, its checkpoints' config): a validated copy, a
    one-team run's default opponent filled in."""
    config = copy.deepcopy(config)
    validate(config)
    train = config["train"]
    if train["opponent"] is None and len(learning_teams(config)) == 1:
        train["opponent"] = default_opponent(train["team"])
    return config


class Trainer:
    """Builds the simulator, the opponent (or, with `train.team = "both"`, a learner per team and the
    opponent pool), the adapters and the rsl-rl runner of a run config; trains, checkpoints, resumes
    and exports. `log_dir=None`: no TensorBoard, CSV or checkpoints. `run_id`: the run this one
    continues (`resume`); None: a new run, with a new id."""

    def __init__(self, config: dict, log_dir: str | None = None, run_id: str | None = None):
        self.config = config = run_config(config)
        self.teams = learning_teams(config)
        self.log_dir = log_dir
        self.run_id = run_id or uuid.uuid4().hex[:16]
        self.stop = StopRequest()
        # Seconds of each start-up stage (`train --verbose`): the build's here, the first iteration's and the
        # graph captures' added by `train`.
        self.startup: dict[str, float] = {}
        start = time.perf_counter()
        device = self._setup_process()
        self._setup_env(device)
        self.startup["env build (Warp modules loaded)"] = time.perf_counter() - start
        start = time.perf_counter()
        opponents = self._setup_opponents()
        self._setup_adapters(opponents)
        self._setup_runner()
        if log_dir is not None and self.rank == 0:
            self._write_run_record()
        self._setup_pool()
        self._setup_video()
        if log_dir is not None:  # the git state of the repository holding this source (rsl-rl searches upward)
            self.runner.add_git_repo_to_log(__file__)
        self.startup["opponent, adapters, policy and runner"] = time.perf_counter() - start
        self._first_iteration: float | None = None  # when the first `train` call began, until its first iteration ends

    def _setup_process(self) -> str:
        """This process's rank, the run's processes (torchrun: one per GPU or CPU share, each with its own
        worlds and seed) and the seed of its draws, global generators seeded; returns its device."""
        train = self.config["train"]
        self.rank, local_rank, self.world_size = distributed.world()
        if self.world_size > 1 and train["loop"] == "rsl-rl":
            raise ValueError("train.loop='rsl-rl' runs in one process; a torchrun run needs train.loop='fast'")
        device = distributed.rank_device(train["device"], local_rank) if self.world_size > 1 else train["device"]
        self.seed = rank_seed(train["seed"], self.rank)
        seed_process(self.seed)
        return device

    def _setup_env(self, device: str) -> None:
        """The simulator, once the whole run's memory is known to fit (before anything is allocated)."""
        train = self.config["train"]
        check_training_memory(self.config, resolve_device(device))
        self.env = BatchedAquarium(
            env_config(self.config), num_worlds=train["num_worlds"], device=device, seed=self.seed
        )
        self.device = self.env.torch_device
        make_current(self.device)
        self.path = resolve_fast_path(self.config, self.device.type)  # train.fused_mlp and train.tf32 resolved
        if self.path.tf32:
            torch.backends.cuda.matmul.allow_tf32 = True  # a process-wide switch of torch's

    def _setup_opponents(self) -> dict:
        """Each learning team's opponent: the other learner (both teams learn; the training loop writes its
        actions) or the run's opponent policy (`self.opponent`)."""
        train = self.config["train"]
        if len(self.teams) == 2:
            self.opponent = None
            return {team: LearnerActions() for team in TYPES}
        self.opponent = make_driver(
            train["opponent"],
            self.env,
            OTHER[train["team"]],
            deterministic=train["opponent_deterministic"],
            seed=self.seed,
        )
        return {train["team"]: self.opponent}

    def _setup_adapters(self, opponents: dict) -> None:
        """An adapter per learning team over the one simulator (`self.vec_envs`; the first, `self.vec_env`,
        steps the worlds and samples the swarm metrics: one per world is enough) and its runner config."""
        config, train = self.config, self.config["train"]
        self.vec_envs = {
            team: AquariumVecEnv(
                self.env,
                team,
                opponents[team],
                reward_scale=team_settings(config, team)["reward_scale"],
                cfg=config,
                metrics_every=int(train["metrics_every"]) if i == 0 else 0,
                critic=team_settings(config, team)["critic"],
                randomize=train["randomize"] if i == 0 else None,
                randomize_seed=self.seed,
            )
            for i, team in enumerate(self.teams)
        }
        if len(self.teams) == 2:
            for team in TYPES:
                opponents[team].vec_env = self.vec_envs[OTHER[team]]
        self.vec_env = self.vec_envs[self.teams[0]]
        self.runner_cfgs = {
            team: runner_config(config, v.slots, v.action_count, self.device.type, team=team)
            for team, v in self.vec_envs.items()
        }
        self.runner_cfg = self.runner_cfgs[self.teams[0]]
        self.total_iterations = total_iterations(config)

    def _setup_runner(self) -> None:
        """The rsl-rl runner of every learner (`self.learners`), driven by this trainer (`runner.RunOwner`)."""
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the networks (config.json has them)
            self.runner = AquariumRunner(
                self.vec_env,
                copy.deepcopy(self.runner_cfg),
                log_dir=self.log_dir,
                device=str(self.device),
                trainer=self,
                quiet=self.config["train"]["quiet"],
                others=[(self.vec_envs[t], copy.deepcopy(self.runner_cfgs[t])) for t in self.teams[1:]],
            )
        self.learners = {learner.team: learner for learner in self.runner.learners}

    def _write_run_record(self) -> None:
        """`config.json` in the log directory: the run's id, config, runner configs and provenance, its
        processes' seeds, the CUDA graphs the training loop will capture and the fused paths it takes."""
        assert self.log_dir is not None
        config, train = self.config, self.config["train"]
        os.makedirs(self.log_dir, exist_ok=True)
        record = {
            "run_id": self.run_id,
            "config": config,
            "runner_cfg": self.runner_cfg if len(self.teams) == 1 else self.runner_cfgs,
            "total_iterations": self.total_iterations,
            **provenance(str(self.device)),  # the command, commit, machine and versions of the run
        }
        if self.world_size > 1:  # rank r simulates with seed rank_seed(train.seed, r)
            record["distributed"] = {
                "world_size": self.world_size,
                "seeds": [rank_seed(train["seed"], r) for r in range(self.world_size)],
            }
        rollout_graphs, update_graphs = self.runner.graph_plan()  # what the training loop will capture
        record["cuda_graphs"] = {"rollout": rollout_graphs, "update": dict(zip(self.teams, update_graphs))}
        record["path"] = self.path.record()
        if self.path.fused_mlp:
            # per learner: its update's fused loss and its rollout's fused step (True), or why not
            from .fused_ppo import FusedAct, FusedPPOLoss

            for key, fused in (("fused_loss", FusedPPOLoss), ("fused_act", FusedAct)):
                record[key] = {learner.team: fused.unsupported(learner.alg) or True for learner in self.runner.learners}
        with atomic_open(os.path.join(self.log_dir, "config.json")) as f:
            json.dump(record, f, indent=1, default=str)

    def _setup_pool(self) -> None:
        """The opponent pool (`train.pool_every`; both teams learn), else None."""
        train = self.config["train"]
        self.pool = None
        if train["pool_every"]:
            from .pool import OpponentPool

            self.pool = OpponentPool(
                {t: (learner.alg.get_policy(), learner.vec_env) for t, learner in self.learners.items()},
                size=int(train["pool_size"]),
                sampling=train["pool_sampling"],
                fractions={t: float(team_settings(self.config, t)["pool_fraction"]) for t in TYPES},
            )

    def _setup_video(self) -> None:
        """The training video's recorder (`train.video_every`), else None."""
        train = self.config["train"]
        self.video = None
        if train["video_every"]:
            from .episode_video import EpisodeVideo

            self.video = EpisodeVideo(env_config(self.config), self.device, self.seed, int(train["video_steps"]))

    # ------------------------------------------------------------------ construction from checkpoints
    @classmethod
    def resume(cls, path: str, log_dir: str | None = None, changes: dict | None = None) -> Trainer:
        """A trainer restored from a checkpoint, or from the newest checkpoint of a run directory.
        `changes` may alter train settings that do not affect the state (iterations, episodes,
        quiet, export, videos); the log directory defaults to the checkpoint's and must not hold
        another run (`run_dir.check_same_run`)."""
        if os.path.isdir(path):
            checkpoint_path, checkpoint = newest_readable_checkpoint(path)
        else:
            checkpoint_path, checkpoint = path, read_checkpoint(path)
        state = checkpoint["infos"]["aquarium"]
        config = copy.deepcopy(state["config"])
        if changes:
            bad = [k for k in changes.get("train", {}) if k not in RESUMABLE_SETTINGS]
            bad += [k for k in changes if k != "train"]
            if bad:
                raise ValueError(
                    f"a resumed run keeps its config; only train.{sorted(RESUMABLE_SETTINGS)} may change, not {bad}"
                )
            config["train"].update(changes.get("train", {}))
        if log_dir is None:
            log_dir = os.path.dirname(os.path.abspath(checkpoint_path))
        # before the trainer rewrites the directory's config.json
        run_id = check_same_run(log_dir, checkpoint_path, state)
        trainer = cls(config, log_dir=log_dir, run_id=run_id)
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
            "hidden_states": {
                name: hidden_state_to(getattr(learner.alg, name).get_hidden_state(), "cpu")
                for name in ("actor", "critic")
            },
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
        state = {
            "config": self.config,
            "run_id": self.run_id,
            "seed": self.seed,
            "rng": global_rng_state(self.device),
        }
        learners = self.runner.learners
        if len(learners) == 1:
            return {**state, **self._learner_state(learners[0], with_env=True)}
        return {
            **state,
            "pool": self.pool.state_dict() if self.pool is not None else None,
            "teams": {l.team: self._learner_state(l, with_env=i == 0) for i, l in enumerate(learners)},
        }

    def load_extra_state(self, state: dict) -> None:
        """Restore `extra_state()`; of a torchrun run's checkpoint (`world_size`, the other ranks'
        states under `ranks`), this rank's own part."""
        saved_size = int(state.get("world_size", 1))
        if saved_size != self.world_size:
            raise ValueError(
                f"the checkpoint holds the state of {saved_size} process(es) (torchrun's WORLD_SIZE), "
                f"this run has {self.world_size}: resume with the same number of processes"
            )
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
        restore_global_rng_state(state["rng"], self.device)

    def load(self, path: str) -> None:
        """Restore the whole training state from a checkpoint of this run's config."""
        self.runner.load(path, map_location=str(self.device))
        if self.log_dir and self.rank == 0:
            for learner in self.runner.learners:
                learner.logger.keep_rows_before(self.runner.current_learning_iteration)

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
        if "first iteration" not in self.startup:
            self._first_iteration = time.perf_counter()
        # Our loop stops at an iteration boundary on SIGINT or SIGTERM (`stop.py`); rsl-rl's cannot, and
        # torchrun's ranks could see a signal at different iterations (their all-reduces would wait forever).
        graceful = self.runner.loop_kind == "fast" and self.world_size == 1
        catching = self.stop.catching() if graceful else contextlib.nullcontext()
        with catching:
            self.runner.learn(
                iterations, init_at_random_ep_len=fresh and bool(self.config["train"]["init_at_random_ep_len"])
            )

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
        if self._first_iteration is not None:
            synchronize(self.device)  # (once: the first iteration's work done)
            self.startup["first iteration"] = time.perf_counter() - self._first_iteration
            self._first_iteration = None
        if self.pool is not None and (iteration + 1) % int(train["pool_every"]) == 0:
            self.pool.snapshot()
        writer = self.runner.logger.writer
        if self.video is not None and writer is not None and (iteration + 1) % int(train["video_every"]) == 0:
            self.video.log(writer, self.video.record(self.video_drivers), iteration, self.log_dir)

    def video_drivers(self, env: BatchedAquarium) -> dict:
        """Every team's driver in a video's world: the learners' current actors (argmax), and for a
        one-team run the opponent as in training."""
        train = self.config["train"]
        drivers = {
            team: policy_driver(
                policy_from_actor(self.learners[team].alg.get_policy(), self.policy_meta(team), self.device), env, team
            )
            for team in self.teams
        }
        if self.opponent is not None:
            other = OTHER[train["team"]]
            drivers[other] = make_driver(
                train["opponent"], env, other, deterministic=train["opponent_deterministic"], seed=self.seed
            )
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
        return {
            team: export_policy(
                self.learners[team].alg.get_policy(), self.policy_meta(team), os.path.join(out_dir, team), formats
            )
            for team in self.teams
        }

    def close(self) -> None:
        if self.video is not None:
            self.video.close()
        self.vec_env.close()
        if self.runner.loop is not None:
            self.runner.loop.release_graphs()  # before the process group goes (see release_graphs)
        if self.world_size > 1:
            distributed.close()
