"""The paper's evaluation protocol and figures.

Protocol (paper, section 6): every policy pair plays `episodes` episodes of `max_steps` steps for each
of several seeds; for each prey agent, captures per episode and the undiscounted reward per episode
are collected, averaged over the prey of the episode, then over the episodes of a seed; the table
reports the mean and the standard deviation of these per-seed means over the seeds.

```python
from aquarium_warp.training.evaluate import evaluate_policies
result = evaluate_policies(prey=["random", "turnaway", "PS=runs/ps/exported/policy.pt"],
                           predator=["naivchase"], env=AquariumConfig(prey_count=6),
                           episodes=200, seeds=[0, 1, 2, 3, 4], device="cuda:0")
result["summary"]    # one row per (prey, predator) pair: means and stds over seeds
```

A policy spec is a heuristic name ("random", "turnaway" for prey, "naivchase" or
"naivchase-noconfusion" (chasing the nearest visible prey) for predators), the path of an exported
policy or training checkpoint, optionally labelled `LABEL=SPEC`. Specs with the same label are pooled
(e.g. one trained policy per training seed): their per-seed means together give the mean and std.
Recurrent policies act through `drivers.RecurrentOpponent` (hidden state per agent slot, reset where the
slot's episode ends).

The episodes run as parallel worlds (at most `max_worlds` at once; more episodes continue in the
same worlds, whose random streams differ per episode). Each world's episodes are recorded when they
end, so extinction (respawn off) is handled too.

Cross play and Elo ratings: `cross_play.py`; the figures: `plots.py`.
"""

from __future__ import annotations

import csv
import json
import math
import os

import numpy as np
import torch

from ..atomic import atomic_open
from ..checks import is_int
from ..config import AquariumConfig
from ..device import resolve_device
from ..drivers import is_heuristic, make_drivers, parse_spec
from ..env import BatchedAquarium, StepResult
from ..metrics import EPISODE_METRICS, EpisodeMetrics
from ..records import json_safe, provenance
from ..rollout import Observer, rollout

METRICS = ("captures_per_prey", "reward_per_prey", "reward_per_predator") + tuple(
    f"swarm_{name}" for name in EPISODE_METRICS
)


class EpisodeRecords(Observer):
    """Records the first `per_world` episodes of every world of `env` as they end (one host sync per
    step: whether any ended): per-slot prey captures and rewards, predator rewards, the world's
    captures and length, and the episode's swarm metrics from `swarm` (an observer placed before this
    one). `done` turns True once every world has finished its `per_world` episodes."""

    def __init__(self, env: BatchedAquarium, swarm: EpisodeMetrics, per_world: int):
        dev, W = env.torch_device, env.num_worlds
        Pc, P = env.prey_capacity, env.predator_capacity
        self.swarm, self.per_world = swarm, per_world
        self.prey_captures = torch.zeros(W, Pc, dtype=torch.int32, device=dev)
        self.prey_reward = torch.zeros(W, Pc, dtype=torch.float64, device=dev)
        self.predator_reward = torch.zeros(W, P, dtype=torch.float64, device=dev)
        self.captured = env.state.torch.captured[:, :Pc]
        self.done_count = np.zeros(W, dtype=np.int64)
        self.records: list[tuple[int, int, dict]] = []  # (the world's episode number, world, record)

    @property
    def done(self) -> bool:
        return bool(self.done_count.min() >= self.per_world)

    def on_step(self, env: BatchedAquarium, step: int, result: StepResult) -> None:
        rewards, info = result.rewards, result.info
        self.prey_captures += self.captured
        self.prey_reward += rewards["prey"]
        self.predator_reward += rewards["predator"]
        ended = info["episode_ended"]
        if not bool(ended.any()):
            return
        idx = torch.nonzero(ended).flatten()
        pc, pr, dr = (
            self.prey_captures[idx].cpu().numpy(),
            self.prey_reward[idx].cpu().numpy(),
            self.predator_reward[idx].cpu().numpy(),
        )
        caps = info["episode_captures"][idx].cpu().numpy()
        swarm_values = self.swarm.ended_values[idx].cpu().numpy()
        lengths = info["episode_length"][idx].cpu().numpy()
        for k, w in enumerate(idx.cpu().numpy().tolist()):
            if self.done_count[w] < self.per_world:
                self.records.append(
                    (
                        int(self.done_count[w]),
                        w,
                        {
                            "prey_captures": pc[k].tolist(),
                            "prey_rewards": pr[k].tolist(),
                            "predator_rewards": dr[k].tolist(),
                            "captures": int(caps[k]),
                            "length": int(lengths[k]),
                            **{f"swarm_{name}": float(swarm_values[k, m]) for m, name in enumerate(EPISODE_METRICS)},
                        },
                    )
                )
            self.done_count[w] += 1
        self.prey_captures[idx] = 0
        self.prey_reward[idx] = 0
        self.predator_reward[idx] = 0


def run_episodes(
    env_cfg: AquariumConfig,
    prey: str,
    predator: str,
    episodes: int,
    seed: int,
    device=None,
    max_worlds: int = 1024,
    deterministic: bool = True,
    metrics_every: int = 10,
    blind_to: dict[str, str] | None = None,
) -> list[dict]:
    """Play `episodes` episodes of `prey` vs `predator` specs; one dict per episode with per-slot
    prey captures and rewards, predator rewards, the world's captures and length, and the episode's
    swarm metrics (`swarm_<name>`: means over states sampled every `metrics_every` steps).
    `blind_to` (`{team: type}`): that team's trained policy sees no slots of the type (heuristics are
    unaffected: they read the state)."""
    W = max(1, min(episodes, max_worlds))
    env = BatchedAquarium(env_cfg, num_worlds=W, device=device, seed=seed)
    specs = {"prey": prey, "predator": predator}
    blind = {t: v for t, v in (blind_to or {}).items() if not is_heuristic(specs[t], t)}
    drivers = make_drivers(specs, env, seed=seed, deterministic=deterministic, blind_to=blind)
    swarm = EpisodeMetrics(env, every=metrics_every)  # per-episode swarm metrics (aquarium_warp.metrics)
    per_world = math.ceil(episodes / W)
    records = EpisodeRecords(env, swarm, per_world)
    # The env starts in its first episode (no reset); the bound is defensive: every world ends an
    # episode at least every max_steps steps.
    rollout(
        env, drivers, (per_world + 1) * env_cfg.max_steps, [swarm, records], reset=False, until=lambda: records.done
    )
    if not records.done:  # pragma: no cover - defensive
        raise RuntimeError("evaluation did not finish its episodes")
    env.close()
    ordered = sorted(records.records, key=lambda r: (r[0], r[1]))
    out = []
    prey_n, pred_n = env_cfg.prey_count, env_cfg.predator_count
    for i, (_, _, rec) in enumerate(ordered[:episodes]):
        rec["episode"] = i
        # Per prey agent of the episode (the team's initial size: reproduction slots add to the sums).
        rec["captures_per_prey"] = float(sum(rec["prey_captures"])) / prey_n
        rec["reward_per_prey"] = float(sum(rec["prey_rewards"])) / prey_n
        rec["reward_per_predator"] = float(sum(rec["predator_rewards"])) / pred_n
        out.append(rec)
    return out


def summarize(values_per_seed: list[list[float]]) -> dict:
    """Mean and std over seeds of the per-seed means, plus the std over all episodes."""
    seed_means = [float(np.mean(v)) for v in values_per_seed if len(v)]
    flat = [x for v in values_per_seed for x in v]
    return {
        "mean": float(np.mean(seed_means)) if seed_means else float("nan"),
        "std_over_seeds": float(np.std(seed_means)) if seed_means else float("nan"),
        "std_over_episodes": float(np.std(flat)) if flat else float("nan"),
        "seed_means": seed_means,
    }


def evaluate_policies(
    prey,
    predator,
    env: AquariumConfig | None = None,
    episodes: int = 200,
    seeds=(0,),
    device=None,
    max_worlds: int = 1024,
    deterministic: bool = True,
    progress=None,
    blind_to: dict[str, str] | None = None,
) -> dict:
    """Evaluate every (prey spec, predator spec) pair; see the module doc. Returns
    `{"summary": [rows], "episodes": [per-episode records]}`. `blind_to` (`{team: type}`): trained
    policies of the team act without their slots of that type (the neighbour-ablation control)."""
    for name, value in (("episodes", episodes), ("max_worlds", max_worlds)):
        if not is_int(value) or value < 1:
            raise ValueError(f"{name}={value!r} must be an integer >= 1")
    seeds = list(seeds)
    if not seeds:
        raise ValueError(f"seeds={seeds!r} must hold at least one seed")
    prey = [prey] if isinstance(prey, str) else list(prey)
    predator = [predator] if isinstance(predator, str) else list(predator)
    env = env if env is not None else AquariumConfig()
    groups: dict[tuple[str, str], dict[str, list]] = {}
    episodes_out = []
    for prey_spec in prey:
        prey_label, prey_value = parse_spec(prey_spec)
        for pred_spec in predator:
            pred_label, pred_value = parse_spec(pred_spec)
            key = (prey_label, pred_label)
            group = groups.setdefault(key, {m: [] for m in METRICS})
            for seed in seeds:
                if progress is not None:
                    progress(f"prey={prey_label} ({prey_value}) vs predator={pred_label} ({pred_value}), seed {seed}")
                records = run_episodes(
                    env,
                    prey_value,
                    pred_value,
                    episodes,
                    int(seed),
                    device=device,
                    max_worlds=max_worlds,
                    deterministic=deterministic,
                    blind_to=blind_to,
                )
                for m in METRICS:
                    group[m].append([r[m] for r in records])
                for r in records:
                    r.update(
                        {
                            "prey_policy": prey_label,
                            "prey_spec": prey_value,
                            "predator_policy": pred_label,
                            "predator_spec": pred_value,
                            "seed": int(seed),
                        }
                    )
                episodes_out.extend(records)
    summary = []
    for (prey_label, pred_label), group in groups.items():
        row = {
            "prey_policy": prey_label,
            "predator_policy": pred_label,
            "seeds": len(group[METRICS[0]]),
            "episodes_per_seed": episodes,
        }
        for m in METRICS:
            s = summarize(group[m])
            row[f"{m}_mean"], row[f"{m}_std"] = s["mean"], s["std_over_seeds"]
            row[f"{m}_episode_std"] = s["std_over_episodes"]
        summary.append(row)
    return {
        "summary": summary,
        "episodes": episodes_out,
        "protocol": {
            "episodes": episodes,
            "seeds": [int(s) for s in seeds],
            "max_steps": env.max_steps,
            "deterministic": deterministic,
            "blind_to": dict(blind_to or {}),
            "env": env.to_dict(),
        },
        **provenance(resolve_device(device)),
    }


PROVENANCE_KEYS = ("command", "git", "machine")


def write_results(result: dict, out_dir: str) -> dict[str, str]:
    """`summary.csv`, `summary.json` (summary + protocol) and `episodes.json` into `out_dir`."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {
        "csv": os.path.join(out_dir, "summary.csv"),
        "json": os.path.join(out_dir, "summary.json"),
        "episodes": os.path.join(out_dir, "episodes.json"),
    }
    rows = result["summary"]
    if rows:
        with atomic_open(paths["csv"], newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    with atomic_open(paths["json"]) as f:
        # Strict JSON: an undefined value (NaN, e.g. local alignment without linked prey) is null.
        json.dump(
            json_safe(
                {
                    "summary": rows,
                    "protocol": result["protocol"],
                    **{k: result[k] for k in PROVENANCE_KEYS if k in result},
                }
            ),
            f,
            indent=1,
        )
    with atomic_open(paths["episodes"]) as f:
        json.dump(json_safe(result["episodes"]), f)
    return paths
