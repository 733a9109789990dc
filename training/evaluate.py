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
Recurrent policies act through `RecurrentOpponent` (hidden state per agent slot, reset where the
slot's episode ends).

Cross-play (`cross_play`, `aquarium-warp eval --cross-play`): every prey spec against every predator
spec, globs such as `run/model_*.pt` expanded to every checkpoint in training order; the pairs run
through `evaluate_policies`, and the result adds `[prey][predator]` matrices (mean and std over
seeds) of captures per prey, reward per prey and per predator, and prey survival (the fraction of
prey not captured in an episode), Elo ratings fitted to the survival matrix (`elo_ratings`),
`write_cross_play` (CSV/JSON) and `plot_cross_play` (heatmap).

The episodes run as parallel worlds (at most `max_worlds` at once; more episodes continue in the
same worlds, whose random streams differ per episode). Each world's episodes are recorded when they
end, so extinction (respawn off) is handled too.

Figures (matplotlib, imported only here): `plot_distributions` (per-episode values per policy),
`plot_cross_play` and
`plot_training_curves` (from `progress.csv` or TensorBoard events of several runs, mean and std band
over the runs of each label, against world episodes).
"""

from __future__ import annotations

import csv
import glob
import json
import math
import os
import re
import shlex
import sys
import warnings

import numpy as np
import torch

from ..atomic import atomic_open, write_figure
from ..bench.machine import git_info, machine_info
from ..checks import is_int
from ..config import AquariumConfig
from ..device import resolve_device
from ..drivers import is_heuristic, make_drivers
from ..env import BatchedAquarium
from ..json_records import json_safe
from ..metrics import EPISODE_METRICS, EpisodeMetrics

METRICS = ("captures_per_prey", "reward_per_prey", "reward_per_predator") + tuple(
    f"swarm_{name}" for name in EPISODE_METRICS)


def parse_spec(spec: str) -> tuple[str, str]:
    """`"LABEL=SPEC"` -> `(label, spec)`; a bare spec is its own label (a file: its run directory's name)."""
    if "=" in spec and not os.path.exists(spec):
        label, value = spec.split("=", 1)
        return label, value
    if is_heuristic(spec):
        return spec.lower(), spec
    path = os.path.normpath(spec)
    parts = path.split(os.sep)
    if len(parts) >= 3 and parts[-2] == "exported":  # run/exported/policy.pt: the run's name
        label = parts[-3]
    elif len(parts) >= 4 and parts[-3] == "exported":  # run/exported/<team>/policy.pt (both teams learned)
        label = f"{parts[-4]}-{parts[-2]}"
    else:
        label = os.path.splitext(parts[-1])[0]
    return label, spec


def common_policy_env(specs, fallback: AquariumConfig) -> AquariumConfig:
    """The world every trained policy among `specs` was trained in (`fallback` if none is trained);
    a `ValueError` names two specs whose worlds differ."""
    from .config import env_config
    from .export import policy_world

    first = None
    for spec in specs:
        _, value = parse_spec(spec)
        if is_heuristic(value):
            continue
        world = env_config({"env": policy_world(value)})
        if first is None:
            first = (spec, world)
        elif world.to_dict() != first[1].to_dict():
            a, b = first[1].to_dict(), world.to_dict()
            differ = ", ".join(f"{k} {a[k]!r} vs {b[k]!r}" for k in a if a[k] != b[k])
            raise ValueError(f"policies {first[0]!r} and {spec!r} were trained in different worlds ({differ})")
    return first[1] if first is not None else fallback


def run_episodes(env_cfg: AquariumConfig, prey: str, predator: str, episodes: int, seed: int, device=None,
                 max_worlds: int = 1024, deterministic: bool = True, metrics_every: int = 10,
                 blind_to: dict[str, str] | None = None) -> list[dict]:
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
    dev = env.torch_device
    Pc, P = env.prey_capacity, env.predator_capacity
    prey_captures = torch.zeros(W, Pc, dtype=torch.int32, device=dev)
    prey_reward = torch.zeros(W, Pc, dtype=torch.float64, device=dev)
    predator_reward = torch.zeros(W, P, dtype=torch.float64, device=dev)
    captured = env.state.torch.captured[:, :Pc]
    swarm = EpisodeMetrics(env, every=metrics_every)  # per-episode swarm metrics (aquarium_warp.metrics)
    swarm.begin()
    per_world = math.ceil(episodes / W)
    done_count = np.zeros(W, dtype=np.int64)
    records: list[tuple[int, int, dict]] = []
    max_total_steps = per_world * env_cfg.max_steps
    steps = 0
    while done_count.min() < per_world:
        if steps >= max_total_steps + env_cfg.max_steps:  # pragma: no cover - defensive
            raise RuntimeError("evaluation did not finish its episodes")
        actions = {t: drivers[t]() for t in ("prey", "predator")}
        _, rewards, _, _, info = env.step(actions, validate=False)
        swarm.update(info)
        steps += 1
        prey_captures += captured
        prey_reward += rewards["prey"]
        predator_reward += rewards["predator"]
        ended = info["episode_ended"]
        if not bool(ended.any()):
            continue
        idx = torch.nonzero(ended).flatten()
        pc, pr, dr = (prey_captures[idx].cpu().numpy(), prey_reward[idx].cpu().numpy(),
                      predator_reward[idx].cpu().numpy())
        caps = info["episode_captures"][idx].cpu().numpy()
        swarm_values = swarm.ended_values[idx].cpu().numpy()
        lengths = info["episode_length"][idx].cpu().numpy()
        for k, w in enumerate(idx.cpu().numpy().tolist()):
            if done_count[w] < per_world:
                records.append((int(done_count[w]), w, {
                    "prey_captures": pc[k].tolist(), "prey_rewards": pr[k].tolist(),
                    "predator_rewards": dr[k].tolist(), "captures": int(caps[k]), "length": int(lengths[k]),
                    **{f"swarm_{name}": float(swarm_values[k, m]) for m, name in enumerate(EPISODE_METRICS)}}))
            done_count[w] += 1
        prey_captures[idx] = 0
        prey_reward[idx] = 0
        predator_reward[idx] = 0
    env.close()
    records.sort(key=lambda r: (r[0], r[1]))
    out = []
    prey_n, pred_n = env_cfg.prey_count, env_cfg.predator_count
    for i, (_, _, rec) in enumerate(records[:episodes]):
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
    return {"mean": float(np.mean(seed_means)) if seed_means else float("nan"),
            "std_over_seeds": float(np.std(seed_means)) if seed_means else float("nan"),
            "std_over_episodes": float(np.std(flat)) if flat else float("nan"),
            "seed_means": seed_means}


def evaluate_policies(prey, predator, env: AquariumConfig | None = None, episodes: int = 200, seeds=(0,),
                      device=None, max_worlds: int = 1024, deterministic: bool = True, progress=None,
                      blind_to: dict[str, str] | None = None) -> dict:
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
                records = run_episodes(env, prey_value, pred_value, episodes, int(seed), device=device,
                                       max_worlds=max_worlds, deterministic=deterministic, blind_to=blind_to)
                for m in METRICS:
                    group[m].append([r[m] for r in records])
                for r in records:
                    r.update({"prey_policy": prey_label, "prey_spec": prey_value, "predator_policy": pred_label,
                              "predator_spec": pred_value, "seed": int(seed)})
                episodes_out.extend(records)
    summary = []
    for (prey_label, pred_label), group in groups.items():
        row = {"prey_policy": prey_label, "predator_policy": pred_label, "seeds": len(group[METRICS[0]]),
               "episodes_per_seed": episodes}
        for m in METRICS:
            s = summarize(group[m])
            row[f"{m}_mean"], row[f"{m}_std"] = s["mean"], s["std_over_seeds"]
            row[f"{m}_episode_std"] = s["std_over_episodes"]
        summary.append(row)
    return {"summary": summary, "episodes": episodes_out,
            "protocol": {"episodes": episodes, "seeds": [int(s) for s in seeds], "max_steps": env.max_steps,
                         "deterministic": deterministic, "blind_to": dict(blind_to or {}), "env": env.to_dict()},
            **run_provenance(device)}


def run_provenance(device=None) -> dict:
    """What a result file records of the run that made it: this process's command line, the commit
    (`git_info`) and the machine (`machine_info`: device name and versions)."""
    return {"command": shlex.join([os.path.basename(sys.argv[0]), *sys.argv[1:]]), "git": git_info(),
            "machine": machine_info(resolve_device(device))}


PROVENANCE_KEYS = ("command", "git", "machine")


def write_results(result: dict, out_dir: str) -> dict[str, str]:
    """`summary.csv`, `summary.json` (summary + protocol) and `episodes.json` into `out_dir`."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {"csv": os.path.join(out_dir, "summary.csv"), "json": os.path.join(out_dir, "summary.json"),
             "episodes": os.path.join(out_dir, "episodes.json")}
    rows = result["summary"]
    if rows:
        with atomic_open(paths["csv"], newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    with atomic_open(paths["json"]) as f:
        # Strict JSON: an undefined value (NaN, e.g. local alignment without linked prey) is null.
        json.dump(json_safe({"summary": rows, "protocol": result["protocol"],
                             **{k: result[k] for k in PROVENANCE_KEYS if k in result}}), f, indent=1)
    with atomic_open(paths["episodes"]) as f:
        json.dump(json_safe(result["episodes"]), f)
    return paths


# ---------------------------------------------------------------------------------------------- cross-play
CROSS_PLAY_METRICS = ("captures_per_prey", "reward_per_prey", "reward_per_predator", "prey_survival")


def expand_specs(specs) -> list[str]:
    """Specs with glob patterns (e.g. `run/model_*.pt`, optionally `LABEL=run/model_*.pt`) replaced by
    the files they match, in natural order (model_2 before model_10), each labelled by its file name
    (`LABEL/model_2` under a label). Other specs stay as they are."""
    out = []
    for spec in specs:
        label, value = parse_spec(spec)
        if is_heuristic(value) or os.path.exists(value) or not glob.has_magic(value):
            out.append(spec)
            continue
        paths = glob.glob(value)
        if not paths:
            raise ValueError(f"policy spec {spec!r}: no file matches the pattern")

        def natural(path):
            return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", os.path.basename(path))]

        for path in sorted(paths, key=natural):
            name = os.path.splitext(os.path.basename(path))[0]
            out.append(f"{label}/{name}={path}" if spec != value else f"{name}={path}")
    return out


def cross_play(prey, predator, env: AquariumConfig | None = None, episodes: int = 200, seeds=(0,), device=None,
               max_worlds: int = 1024, deterministic: bool = True, progress=None, rating: bool = True) -> dict:
    """Every prey spec against every predator spec (globs expanded by `expand_specs`) under the
    evaluation protocol of `evaluate_policies` (which plays the pairs). `env=None`: the common world of
    the trained policies (`common_policy_env`), else docs/model.md's.

    Returns `evaluate_policies`' result plus `"cross_play"`: the row (prey) and column (predator)
    labels and, per metric of `CROSS_PLAY_METRICS`, `[prey][predator]` matrices of the mean and std over
    seeds of the per-seed means. `prey_survival` is the fraction of the `prey_count` first prey slots
    not captured in an episode. With `rating`, `"rating"`: `elo_ratings` of that survival matrix."""
    prey, predator = expand_specs([prey] if isinstance(prey, str) else prey), \
        expand_specs([predator] if isinstance(predator, str) else predator)
    if env is None:
        env = common_policy_env(prey + predator, AquariumConfig())
    result = evaluate_policies(prey, predator, env, episodes=episodes, seeds=seeds, device=device,
                               max_worlds=max_worlds, deterministic=deterministic, progress=progress)
    rows = list(dict.fromkeys(parse_spec(p)[0] for p in prey))
    cols = list(dict.fromkeys(parse_spec(p)[0] for p in predator))
    by_pair = {(r["prey_policy"], r["predator_policy"]): r for r in result["summary"]}
    survival: dict[tuple[str, str], dict[int, list[float]]] = {}
    for record in result["episodes"]:
        alive = [c == 0 for c in record["prey_captures"][:env.prey_count]]
        survival.setdefault((record["prey_policy"], record["predator_policy"]), {}).setdefault(
            record["seed"], []).append(sum(alive) / len(alive))
    matrices = {}
    for metric in CROSS_PLAY_METRICS:
        mean, std = np.zeros((len(rows), len(cols))), np.zeros((len(rows), len(cols)))
        for i, a in enumerate(rows):
            for j, b in enumerate(cols):
                if metric == "prey_survival":
                    s = summarize(list(survival[(a, b)].values()))
                    mean[i, j], std[i, j] = s["mean"], s["std_over_seeds"]
                    by_pair[(a, b)].update(prey_survival_mean=s["mean"], prey_survival_std=s["std_over_seeds"])
                else:
                    mean[i, j], std[i, j] = by_pair[(a, b)][f"{metric}_mean"], by_pair[(a, b)][f"{metric}_std"]
        matrices[metric] = {"mean": mean.tolist(), "std": std.tolist()}
    result["cross_play"] = {"prey": rows, "predator": cols, "matrices": matrices}
    if rating:
        games = len(result["protocol"]["seeds"]) * episodes * env.prey_count
        prey_r, pred_r = elo_ratings(np.array(matrices["prey_survival"]["mean"]), games)
        result["rating"] = {"basis": "prey_survival", "games_per_pair": games,
                            "prey": dict(zip(rows, prey_r.tolist())), "predator": dict(zip(cols, pred_r.tolist()))}
    return result


def elo_ratings(score: np.ndarray, games, mean: float = 1500.0, iterations: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Elo-scale ratings of row players (prey) and column players (predators) from `score[i, j]`, the
    row player's expected score against column player j (here: prey survival), each pair over `games`
    games (a number or a matrix). Maximum likelihood of the Elo model `score = 1 / (1 + 10 **
    ((R_col - R_row) / 400))` (Bradley-Terry with soft outcomes) by Newton's method; only rating
    differences are identified, so the ratings are shifted to average `mean`. Scores of exactly 0 or 1
    are moved half a game inward, which keeps the ratings finite."""
    score = np.asarray(score, dtype=np.float64)
    if score.ndim != 2 or score.size == 0 or not np.all((score >= 0) & (score <= 1)):
        raise ValueError(f"score must be a non-empty matrix of values in [0, 1], got shape {score.shape}")
    n = np.broadcast_to(np.asarray(games, dtype=np.float64), score.shape)
    if not np.all(n > 0):
        raise ValueError("games must be > 0 for every pair")
    score = np.clip(score, 0.5 / n, 1 - 0.5 / n)
    P, Q = score.shape
    k = math.log(10) / 400
    signs = np.zeros((P, Q, P + Q))  # d(R_row - R_col) / dR
    signs[np.arange(P)[:, None], np.arange(Q)[None, :], np.arange(P)[:, None]] = 1
    signs[np.arange(P)[:, None], np.arange(Q)[None, :], P + np.arange(Q)[None, :]] = -1
    r = np.zeros(P + Q)
    for _ in range(iterations):
        expected = 1 / (1 + np.exp(-k * (signs @ r)))
        gradient = k * np.einsum("pq,pqr->r", n * (score - expected), signs)
        weight = k * k * n * expected * (1 - expected)
        hessian = np.einsum("pq,pqr,pqs->rs", weight, signs, signs)
        # The Hessian is singular along the common shift; the least-norm step leaves that shift alone.
        step = np.linalg.lstsq(hessian, gradient, rcond=None)[0]
        r += step
        if np.max(np.abs(step)) < 1e-9:
            break
    r += mean - r.mean()
    return r[:P], r[P:]


def write_cross_play(result: dict, out_dir: str) -> dict[str, str]:
    """`write_results`' files plus `cross_play.csv` (one row per prey/predator pair: means and stds over
    seeds) and `cross_play.json` (labels, matrices, rating, protocol) into `out_dir`."""
    paths = write_results(result, out_dir)
    cp = result["cross_play"]
    paths["cross_play_csv"] = os.path.join(out_dir, "cross_play.csv")
    paths["cross_play_json"] = os.path.join(out_dir, "cross_play.json")
    with atomic_open(paths["cross_play_csv"], newline="") as f:
        writer = csv.writer(f)
        columns = [(m, s) for m in CROSS_PLAY_METRICS for s in ("mean", "std")]
        writer.writerow(["prey_policy", "predator_policy"] + [f"{m}_{s}" for m, s in columns])
        for i, a in enumerate(cp["prey"]):
            for j, b in enumerate(cp["predator"]):
                writer.writerow([a, b] + [cp["matrices"][m][s][i][j] for m, s in columns])
    with atomic_open(paths["cross_play_json"]) as f:
        json.dump(json_safe({**cp, "rating": result.get("rating"), "protocol": result["protocol"],
                             **{k: result[k] for k in PROVENANCE_KEYS if k in result}}), f, indent=1)
    return paths


# ---------------------------------------------------------------------------------------------- figures
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_distributions(result: dict, path: str) -> str:
    """Box plots of the per-episode captures and rewards per prey for every policy pair."""
    plt = _pyplot()
    pairs = list(dict.fromkeys((r["prey_policy"], r["predator_policy"]) for r in result["episodes"]))
    predators = {p for _, p in pairs}
    labels = [a if len(predators) == 1 else f"{a}\nvs {b}" for a, b in pairs]
    fig, axes = plt.subplots(1, 2, figsize=(max(6.0, 1.6 * len(pairs) + 3), 4.2))
    for ax, metric, title in ((axes[0], "captures_per_prey", "captures per prey per episode"),
                              (axes[1], "reward_per_prey", "reward per prey per episode")):
        data = [[r[metric] for r in result["episodes"] if (r["prey_policy"], r["predator_policy"]) == pair]
                for pair in pairs]
        ax.boxplot(data, showmeans=True)
        ax.set_xticks(range(1, len(labels) + 1), labels)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{result['protocol']['episodes']} episodes x {len(result['protocol']['seeds'])} seeds, "
                 f"{result['protocol']['max_steps']} steps")
    fig.tight_layout()
    write_figure(fig, path, dpi=120)
    plt.close(fig)
    return path


def plot_cross_play(result: dict, path: str, metric: str = "captures_per_prey") -> str:
    """Heatmap of a cross-play matrix (prey rows, predator columns), each cell `mean +- std` over seeds
    (the mean alone with one seed)."""
    plt = _pyplot()
    cp = result["cross_play"]
    mean, std = np.array(cp["matrices"][metric]["mean"]), np.array(cp["matrices"][metric]["std"])
    fig, ax = plt.subplots(figsize=(1.8 * len(cp["predator"]) + 3, 0.6 * len(cp["prey"]) + 2.2))
    image = ax.imshow(mean, cmap="viridis", aspect="auto")
    fig.colorbar(image, ax=ax, label=metric.replace("_", " "))
    ax.set_xticks(range(len(cp["predator"])), cp["predator"], rotation=30, ha="right")
    ax.set_yticks(range(len(cp["prey"])), cp["prey"])
    ax.set_xlabel("predator policy")
    ax.set_ylabel("prey policy")
    middle = (np.nanmax(mean) + np.nanmin(mean)) / 2
    protocol = result["protocol"]
    several = len(protocol["seeds"]) > 1
    for i in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            # one seed has no spread: its std of 0 would read as a measured one
            text = f"{mean[i, j]:.3g}" + (f"\n± {std[i, j]:.2g}" if several else "")
            ax.text(j, i, text, ha="center", va="center", fontsize=8,
                    color="black" if mean[i, j] > middle else "white")
    ax.set_title(f"{metric.replace('_', ' ')}: {protocol['episodes']} episodes x {len(protocol['seeds'])} seeds")
    fig.tight_layout()
    write_figure(fig, path, dpi=120)
    plt.close(fig)
    return path


def read_run_curve(run_dir: str) -> dict[str, np.ndarray]:
    """Training curve of one run: columns of `progress.csv` (or of the progress CSV file given, e.g. one
    team's `progress_<team>.csv` of a run of both teams), or (without it) the Episode/* scalars of its
    TensorBoard events. Keys: world_episodes, captures_per_prey, reward_per_agent."""
    csv_path = run_dir if run_dir.endswith(".csv") else os.path.join(run_dir, "progress.csv")
    if os.path.isfile(csv_path):
        with open(csv_path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))

        def col(name):
            return np.array([float(r[name]) if r.get(name) not in (None, "") else np.nan for r in rows])

        return {"iteration": col("iteration"), "world_episodes": col("world_episodes"),
                "captures_per_prey": col("captures_per_prey"), "reward_per_agent": col("reward_per_agent")}
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(run_dir)
    acc.Reload()
    tags = set(acc.Tags().get("scalars", []))
    if "Episode/captures_per_prey" not in tags:
        raise ValueError(f"{run_dir}: no progress.csv and no Episode/captures_per_prey in TensorBoard events")
    config_path = os.path.join(run_dir, "config.json")
    scale = None
    if os.path.isfile(config_path):
        with open(config_path, encoding="utf-8") as f:
            saved = json.load(f)
        cfg = saved["config"]
        from .config import env_config

        scale = cfg["train"]["num_worlds"] * cfg["runner"]["num_steps_per_env"] / env_config(cfg).max_steps
    caps = acc.Scalars("Episode/captures_per_prey")
    rews = ({e.step: e.value for e in acc.Scalars("Episode/reward_per_agent")}
            if "Episode/reward_per_agent" in tags else {})
    it = np.array([e.step for e in caps], dtype=float)
    return {"iteration": it, "world_episodes": (it + 1) * scale if scale else it,
            "captures_per_prey": np.array([e.value for e in caps]),
            "reward_per_agent": np.array([rews.get(e.step, np.nan) for e in caps])}


def _moving_average(y: np.ndarray, window: int) -> np.ndarray:
    """NaN-aware trailing moving average over `window` entries (iterations without episodes are NaN)."""
    if window <= 1:
        return y
    ok = ~np.isnan(y)
    values = np.where(ok, y, 0.0).cumsum()
    counts = ok.astype(float).cumsum()
    values[window:] = values[window:] - values[:-window]
    counts[window:] = counts[window:] - counts[:-window]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, values / np.maximum(counts, 1), np.nan)


def plot_training_curves(curves: dict[str, list[str]], path: str, smooth: int = 1) -> str:
    """`curves`: label -> run directories or progress CSV files (glob patterns allowed). Mean and std
    band over the runs of each label, per iteration, against world episodes; each run's curve is first
    smoothed by a trailing moving average over `smooth` iterations."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    empty: list[str] = []  # labels of which no run logged an ended episode (nothing to draw)
    for label, patterns in curves.items():
        runs = sorted({d for p in patterns for d in (glob.glob(p) or [p])
                       if os.path.isdir(d) or (d.endswith(".csv") and os.path.isfile(d))})
        if not runs:
            raise ValueError(f"curves {label!r}: no run directory matches {patterns}")
        data = [read_run_curve(d) for d in runs]
        n = min(len(d["iteration"]) for d in data)
        x = data[0]["world_episodes"][:n]
        for ax, metric in ((axes[0], "captures_per_prey"), (axes[1], "reward_per_agent")):
            ys = np.stack([_moving_average(d[metric][:n], smooth) for d in data])
            with warnings.catch_warnings():  # all-NaN columns (no episode ended yet) stay NaN
                warnings.simplefilter("ignore", category=RuntimeWarning)
                mean, std = np.nanmean(ys, axis=0), np.nanstd(ys, axis=0)
            ok = ~np.isnan(mean)
            line, = ax.plot(x[ok], mean[ok], label=f"{label} ({len(runs)} run{'s' if len(runs) > 1 else ''})")
            ax.fill_between(x[ok], (mean - std)[ok], (mean + std)[ok], color=line.get_color(), alpha=0.2)
            if not ok.any() and metric == "captures_per_prey":  # said once per label
                empty.append(label)
    if empty:
        note = (f"no episode ended in the runs of {', '.join(map(repr, empty))} ({n} iteration(s) logged; an "
                "episode lasts env.max_steps steps): their curves are empty; train longer")
        warnings.warn(note, stacklevel=2)
        fig.text(0.5, 0.01, note, ha="center", va="bottom", fontsize=8, wrap=True)
    axes[0].set_title("captures per prey per episode")
    axes[1].set_title("reward per agent per episode (learning team)")
    for ax in axes:
        ax.set_xlabel("world episodes")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    write_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
