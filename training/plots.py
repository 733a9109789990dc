"""Figures of evaluations and training runs (matplotlib, imported only here): `plot_distributions`
(per-episode values per policy), `plot_cross_play` (a cross-play matrix as a heatmap) and
`plot_training_curves` (from `progress.csv` or TensorBoard events of several runs, mean and std band over
the runs of each label, against world episodes)."""

from __future__ import annotations

import csv
import glob
import json
import os
import warnings

import numpy as np

from ..atomic import write_figure


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
    for ax, metric, title in (
        (axes[0], "captures_per_prey", "captures per prey per episode"),
        (axes[1], "reward_per_prey", "reward per prey per episode"),
    ):
        data = [
            [r[metric] for r in result["episodes"] if (r["prey_policy"], r["predator_policy"]) == pair]
            for pair in pairs
        ]
        ax.boxplot(data, showmeans=True)
        ax.set_xticks(range(1, len(labels) + 1), labels)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    fig.suptitle(
        f"{result['protocol']['episodes']} episodes x {len(result['protocol']['seeds'])} seeds, "
        f"{result['protocol']['max_steps']} steps"
    )
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
            ax.text(j, i, text, ha="center", va="center", fontsize=8, color="black" if mean[i, j] > middle else "white")
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

        return {
            "iteration": col("iteration"),
            "world_episodes": col("world_episodes"),
            "captures_per_prey": col("captures_per_prey"),
            "reward_per_agent": col("reward_per_agent"),
        }
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
    rews = (
        {e.step: e.value for e in acc.Scalars("Episode/reward_per_agent")} if "Episode/reward_per_agent" in tags else {}
    )
    it = np.array([e.step for e in caps], dtype=float)
    return {
        "iteration": it,
        "world_episodes": (it + 1) * scale if scale else it,
        "captures_per_prey": np.array([e.value for e in caps]),
        "reward_per_agent": np.array([rews.get(e.step, np.nan) for e in caps]),
    }


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
        runs = sorted(
            {
                d
                for p in patterns
                for d in (glob.glob(p) or [p])
                if os.path.isdir(d) or (d.endswith(".csv") and os.path.isfile(d))
            }
        )
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
            (line,) = ax.plot(x[ok], mean[ok], label=f"{label} ({len(runs)} run{'s' if len(runs) > 1 else ''})")
            ax.fill_between(x[ok], (mean - std)[ok], (mean + std)[ok], color=line.get_color(), alpha=0.2)
            if not ok.any() and metric == "captures_per_prey":  # said once per label
                empty.append(label)
    if empty:
        note = (
            f"no episode ended in the runs of {', '.join(map(repr, empty))} ({n} iteration(s) logged; an "
            "episode lasts env.max_steps steps): their curves are empty; train longer"
        )
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
