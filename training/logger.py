"""The training log: rsl-rl's logger (TensorBoard) plus one CSV row per iteration (`progress.csv`, or
`progress_<team>.csv` when both teams learn; columns `CSV_FIELDS`), the swarm metrics' time series over
training (`swarm.csv` beside it: the iteration and `SWARM_FIELDS`, in iterations where episodes ended)
and a tqdm bar or a console line."""

from __future__ import annotations

import contextlib
import csv
import datetime
import io
import os
import statistics
from collections import deque
from typing import TYPE_CHECKING

import torch
from rsl_rl.utils.logger import Logger

from ..atomic import atomic_open
from ..metrics import EPISODE_METRICS
from . import _rsl  # noqa: F401

if TYPE_CHECKING:
    from tqdm import tqdm

CSV_FIELDS = [
    "iteration",
    "agent_steps",
    "world_steps",
    "world_episodes",
    "episodes_logged",
    "captures",
    "captures_per_prey",
    "reward_per_agent",
    "opponent_reward_per_agent",
    "episode_length",
    "mean_row_reward",
    "value_loss",
    "surrogate_loss",
    "entropy",
    "learning_rate",
    "fps",
    "collect_time",
    "learn_time",
]
SWARM_FIELDS = ["iteration"] + [f"Swarm/{name}" for name in EPISODE_METRICS]


class AquariumLogger(Logger):
    """rsl-rl's logger plus a CSV row per iteration and an optional tqdm bar instead of the print.
    With several learners each has one (`team`: its scalars are logged as `<team>/...`, the swarm
    metrics of the worlds once, unprefixed), sharing the first one's writer."""

    # Declared: `load_state_dict` rebinds rsl-rl's buffers from their own `maxlen`.
    rewbuffer: deque[float]
    lenbuffer: deque[float]

    def __init__(
        self,
        *args,
        csv_path: str | None = None,
        slots: int = 1,
        max_steps: int = 1,
        quiet: bool = False,
        team: str | None = None,
        bar: bool = True,
        **kwargs,
    ):
        super().__init__(*args, **kwargs)
        self.csv_path, self.slots, self.max_steps, self.quiet = csv_path, slots, max_steps, quiet
        self.team, self.bar = team, bar
        self._bar: tqdm | None = None

    def _tag(self, key: str) -> str:
        return key if self.team is None or key.startswith("Swarm/") else f"{self.team}/{key}"

    def log(
        self,
        it,
        start_it,
        total_it,
        collect_time,
        learn_time,
        loss_dict,
        learning_rate,
        action_std,
        rnd_weight,
        print_minimal=False,
        width=80,
        pad=40,
    ):
        if self.writer is None:
            return
        means, counts = {}, {}
        for key in dict.fromkeys(k for info in self.ep_extras for k in info):
            values = [
                torch.as_tensor(info[key], dtype=torch.float32).reshape(-1).cpu()
                for info in self.ep_extras
                if key in info
            ]
            cat = torch.cat(values)
            means[key], counts[key] = float(cat.mean()), int(cat.numel())
        mean_row_reward = statistics.mean(self.rewbuffer) if len(self.rewbuffer) else float("nan")
        with contextlib.redirect_stdout(io.StringIO()) if self.quiet else contextlib.nullcontext():
            super().log(
                it,
                start_it,
                total_it,
                collect_time,
                learn_time,
                loss_dict,
                learning_rate,
                action_std,
                rnd_weight,
                print_minimal,
                width,
                pad,
            )
        world_steps = self.tot_timesteps // self.slots
        row = {
            "iteration": it,
            "agent_steps": self.tot_timesteps,
            "world_steps": world_steps,
            "world_episodes": world_steps / self.max_steps,
            "episodes_logged": counts.get("Episode/captures", 0),
            "captures": means.get("Episode/captures", ""),
            "captures_per_prey": means.get("Episode/captures_per_prey", ""),
            "reward_per_agent": means.get("Episode/reward_per_agent", ""),
            "opponent_reward_per_agent": means.get("Episode/opponent_reward_per_agent", ""),
            "episode_length": means.get("Episode/length", ""),
            "mean_row_reward": mean_row_reward,
            "value_loss": loss_dict.get("value", ""),
            "surrogate_loss": loss_dict.get("surrogate", ""),
            "entropy": loss_dict.get("entropy", ""),
            "learning_rate": learning_rate,
            "fps": int(self.cfg["num_steps_per_env"] * self.num_envs / max(1e-9, collect_time + learn_time)),
            "collect_time": collect_time,
            "learn_time": learn_time,
        }
        self._write_row(row)
        if self.quiet:
            self._progress(it, total_it, row)

    @property
    def swarm_path(self) -> str | None:
        return None if self.csv_path is None else os.path.join(os.path.dirname(self.csv_path), "swarm.csv")

    def _write_row(self, row: dict) -> None:
        self._append(self.csv_path, CSV_FIELDS, row)

    @staticmethod
    def _append(path: str | None, fields: list[str], row: dict) -> None:
        if path is not None:
            new = not os.path.isfile(path)
            with open(path, "a", newline="", encoding="utf-8") as f:
                writer = csv.DictWriter(f, fieldnames=fields)
                if new:
                    writer.writeheader()
                writer.writerow(row)

    def log_iteration(
        self,
        it: int,
        start_it: int,
        total_it: int,
        collect_time: float,
        learn_time: float,
        losses: dict | None,
        learning_rate: float,
        episode_means: dict,
        episodes: int,
        mean_row_reward: float,
    ) -> None:
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
            "iteration": it,
            "agent_steps": self.tot_timesteps,
            "world_steps": world_steps,
            "world_episodes": world_steps / self.max_steps,
            "episodes_logged": episodes,
            "mean_row_reward": mean_row_reward if mean_row_reward == mean_row_reward else "",
            "value_loss": losses["value"],
            "surrogate_loss": losses["surrogate"],
            "entropy": losses["entropy"],
            "learning_rate": learning_rate,
            "fps": fps,
            "collect_time": collect_time,
            "learn_time": learn_time,
        }
        for field in ("captures", "captures_per_prey", "reward_per_agent", "opponent_reward_per_agent"):
            row[field] = episode_means.get(f"Episode/{field}", "")
        row["episode_length"] = episode_means.get("Episode/length", "")
        self._write_row(row)
        swarm = {k: v for k, v in episode_means.items() if k in SWARM_FIELDS}
        if swarm:
            self._append(self.swarm_path, SWARM_FIELDS, {"iteration": it, **swarm})
        if self.quiet:
            if self.bar:
                self._progress(it, total_it, row)
            return
        done = it + 1 - start_it
        eta = self.tot_time / max(1, done) * (total_it - start_it - done) if done else 0.0
        parts = [f"it {it + 1}/{total_it}"] + ([self.team] if self.team is not None else [])
        if row["captures_per_prey"] != "":
            parts += [
                f"captures/prey {row['captures_per_prey']:.3f}",
                f"reward/agent {row['reward_per_agent']:.1f}",
                f"opponent reward/agent {row['opponent_reward_per_agent']:.1f}",
            ]
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
        return {
            "tot_timesteps": self.tot_timesteps,
            "tot_time": self.tot_time,
            "rewbuffer": list(self.rewbuffer),
            "lenbuffer": list(self.lenbuffer),
            "cur_reward_sum": self.cur_reward_sum.cpu().clone(),
            "cur_episode_length": self.cur_episode_length.cpu().clone(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.tot_timesteps, self.tot_time = state["tot_timesteps"], state["tot_time"]
        self.rewbuffer = deque(state["rewbuffer"], maxlen=self.rewbuffer.maxlen)
        self.lenbuffer = deque(state["lenbuffer"], maxlen=self.lenbuffer.maxlen)
        self.cur_reward_sum.copy_(state["cur_reward_sum"].to(self.cur_reward_sum.device))
        self.cur_episode_length.copy_(state["cur_episode_length"].to(self.cur_episode_length.device))

    def keep_rows_before(self, iteration: int) -> None:
        """Drop the CSV rows of iterations `iteration` and later (logged after the checkpoint a run
        resumes from)."""
        for path, fields in ((self.csv_path, CSV_FIELDS), (self.swarm_path, SWARM_FIELDS)):
            if path is None or not os.path.isfile(path):
                continue
            with open(path, newline="", encoding="utf-8") as f:
                rows = [r for r in csv.DictReader(f) if int(r["iteration"]) < iteration]
            with atomic_open(path, newline="") as f:
                writer = csv.DictWriter(f, fieldnames=fields)
                writer.writeheader()
                writer.writerows(rows)
