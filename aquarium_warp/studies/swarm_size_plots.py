"""The figures of the swarm-size study (`aquarium_warp.studies.swarm_size`), drawn from its `swarm_size.json`
summary alone: captures (dilution), polarization and groups, spacing, nearest-neighbour
distributions and, when populations change, the populations over an episode; of the FOV x
view-distance study (`fov_view.json`), a heatmap of captures per prey."""

from __future__ import annotations

import os

import numpy as np

from ..atomic import write_figure


def _curves(summary: dict) -> list[tuple[str | None, list[dict]]]:
    """Results grouped into one curve per (fov angle, view distance), each sorted by prey count."""
    groups: dict[tuple, list] = {}
    for e in summary["results"]:
        groups.setdefault((e["fov_angle"], e["view_distance"]), []).append(e)
    several = len(groups) > 1
    out = []
    for (fov, view), entries in groups.items():
        label = f"prey FOV {fov:g}°, view {view:g} px" if several else None
        out.append((label, sorted(entries, key=lambda e: e["prey"])))
    return out


def _band(ax, entries, metric, label, color, log_y=False):
    n = np.array([e["prey"] for e in entries], dtype=float)
    mean = np.array(
        [np.nan if e["metrics"][metric]["mean"] is None else e["metrics"][metric]["mean"] for e in entries], dtype=float
    )
    std = np.array(
        [0.0 if e["metrics"][metric]["std"] is None else e["metrics"][metric]["std"] for e in entries], dtype=float
    )
    std = np.nan_to_num(std)
    lo, hi = mean - std, mean + std
    if log_y:
        floor = np.nanmin(mean[mean > 0]) / 10 if np.any(mean > 0) else 1e-6
        lo = np.maximum(lo, floor)
    ax.plot(n, mean, "o-", color=color, label=label, ms=4, lw=1.5)
    ax.fill_between(n, lo, hi, color=color, alpha=0.2, lw=0)
    return n, mean


def _baseline(ax, entries, metric, label="uniform random prey (same N)"):
    """Dotted line of the uniform-random reference of `metric`, where the entries have one."""
    if not all("uniform_baseline" in e for e in entries):
        return
    n = np.array([e["prey"] for e in entries], dtype=float)
    values = np.array(
        [np.nan if e["uniform_baseline"].get(metric) is None else e["uniform_baseline"][metric] for e in entries],
        dtype=float,
    )
    ax.plot(n, values, "k:", lw=1.2, label=label)


def plot_fov_view(summary: dict, out: str) -> str:
    """The FOV x view-distance study's heatmap of captures per prey (mean over seeds); returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fovs = sorted({e["fov_angle"] for e in summary["results"]})
    views = sorted({e["view_distance"] for e in summary["results"]})
    grid = np.full((len(views), len(fovs)), np.nan)
    for e in summary["results"]:
        mean = e["metrics"]["captures_per_prey"]["mean"]
        grid[views.index(e["view_distance"]), fovs.index(e["fov_angle"])] = np.nan if mean is None else mean
    cfg = summary["config"]
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    image = ax.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
    middle = (np.nanmin(grid) + np.nanmax(grid)) / 2  # dark text on the light (high) end of viridis
    for (row, col), value in np.ndenumerate(grid):
        ax.text(col, row, f"{value:.3g}", ha="center", va="center", fontsize=8, color="k" if value > middle else "w")
    ax.set_xticks(range(len(fovs)), [f"{f:g}" for f in fovs])
    ax.set_yticks(range(len(views)), [f"{v:g}" for v in views])
    ax.set_xlabel("prey field of view (degrees)")
    ax.set_ylabel("prey view distance (px)")
    fig.colorbar(image, ax=ax, label="captures per prey per episode")
    ax.set_title(
        f"{cfg['prey'][0]} prey, {cfg['prey_policy']} vs {cfg['predator_policy']}; "
        f"{cfg['episode_steps']} steps, mean over {cfg['seeds']} seeds",
        fontsize=8,
    )
    fig.tight_layout()
    path = os.path.join(out, "captures_fov_view.png")
    write_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def plot_study(summary: dict, out: str) -> list[str]:
    """Draw the study's figures into `out`; returns their paths."""
    if summary["study"] == "fov-view":
        return [plot_fov_view(summary, out)]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = summary["config"]
    curves = _curves(summary)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    policies = f"{cfg['prey_policy']} prey vs {cfg['predator_policy']}"
    if cfg["predator_policy"].lower() == "naivchase":
        policies += " (confusion)" if cfg["confusion"] else " (nearest)"
    arena = (
        f"constant density ({cfg['reference_prey']} prey per {cfg['world_size'][0]:g}x{cfg['world_size'][1]:g})"
        if cfg["constant_density"]
        else f"fixed {cfg['world_size'][0]:g}x{cfg['world_size'][1]:g} arena"
    )
    subtitle = (
        f"{policies}; {arena}; {cfg['predators']} predator(s); episodes of {cfg['episode_steps']} steps; "
        f"mean ± std over {cfg['seeds']} seeds"
    )
    paths = []

    def finish(fig, name, title):
        fig.suptitle(f"{title}\n{subtitle}", fontsize=9)
        fig.tight_layout()
        path = os.path.join(out, name)
        write_figure(fig, path, dpi=110)
        plt.close(fig)
        paths.append(path)

    def legend(ax, extra=False):
        if extra or any(label for label, _ in curves):
            ax.legend(fontsize=7, frameon=False)

    # 1. Dilution: captures per episode and per prey.
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for k, (label, entries) in enumerate(curves):
        c = colors[k % len(colors)]
        _band(axes[0], entries, "captures", label, c, log_y=True)
        n, per_prey = _band(axes[1], entries, "captures_per_prey", label, c, log_y=True)
        if k == 0 and np.isfinite(per_prey[0]) and per_prey[0] > 0:
            axes[1].plot(n, per_prey[0] * n[0] / n, "k--", lw=1, label="∝ 1/N (constant total: pure dilution)")
    axes[0].set_ylabel("captures per episode")
    axes[1].set_ylabel("captures per prey per episode")
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("prey N")
        ax.grid(True, which="both", alpha=0.3)
    legend(axes[0])
    legend(axes[1], extra=True)
    finish(fig, "captures_vs_size.png", "Captures vs swarm size (dilution / many eyes)")

    # 2. Polarization and groups.
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for k, (label, entries) in enumerate(curves):
        c = colors[k % len(colors)]
        n, _ = _band(axes[0], entries, "polarization", label, c)
        _band(axes[1], entries, "groups", label, c, log_y=True)
        if k == 0:
            _baseline(axes[0], entries, "polarization", "random headings (same N)")
            _baseline(axes[1], entries, "groups")
            axes[1].plot(n, n, color="0.6", ls="--", lw=1, label="every prey alone (N)")
    axes[0].set_ylabel("polarization |mean heading|")
    axes[0].set_ylim(0, 1.02)
    axes[1].set_ylabel(f"groups (links < {cfg['linking_distance']:g} px)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_xlabel("prey N")
        ax.grid(True, which="both", alpha=0.3)
        legend(ax, extra=True)
    finish(fig, "polarization_groups_vs_size.png", "Polarization and number of groups vs swarm size")

    # 3. Spacing: nearest neighbour, cohesion, distance to the predator, largest group.
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    panels = [
        ("nn_mean", "nearest-neighbour distance (px)", True),
        ("cohesion", "mean distance to swarm centroid (px)", False),
        ("predator_distance", "distance to nearest predator (px)", False),
        ("largest_group", "largest group / live prey", False),
    ]
    for k, (label, entries) in enumerate(curves):
        c = colors[k % len(colors)]
        for ax, (metric, _, log_y) in zip(axes.flat, panels):
            n, _ = _band(ax, entries, metric, label, c, log_y=log_y)
        if k == 0:
            for ax, (metric, _, _) in zip(axes.flat, panels):
                _baseline(ax, entries, metric)
    for ax, (_, ylabel, log_y) in zip(axes.flat, panels):
        ax.set_xscale("log", base=2)
        if log_y:
            ax.set_yscale("log")
        ax.set_xlabel("prey N")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes.flat:
        legend(ax, extra=True)
    finish(fig, "spacing_vs_size.png", "Spacing and cohesion vs swarm size")

    # 4. Nearest-neighbour distance distributions.
    edges = np.array(summary["nn_bin_edges"])
    centers = 0.5 * (edges[:-1] + edges[1:])
    label0, entries0 = curves[0]
    fig, ax = plt.subplots(figsize=(10, 4.5))
    cmap = plt.get_cmap("viridis")
    for k, e in enumerate(entries0):
        dist = np.array(e["nn_distribution"], dtype=float)
        beyond = f", {dist[-1]:.0%} beyond" if dist[-1] >= 0.005 else ""
        ax.plot(
            centers[:-1],
            dist[:-1] / (edges[1] - edges[0]),
            color=cmap(k / max(1, len(entries0) - 1)),
            lw=1.3,
            label=f"N={e['prey']}{beyond}",
        )
    contact = 2 * cfg["prey_radius"]
    ax.axvline(contact, color="k", ls=":", lw=1)
    ax.text(contact + 1, ax.get_ylim()[1] * 0.97, "hit boxes touch", fontsize=7, va="top")
    ax.set_xlabel(
        f"nearest-neighbour distance (px; bins of {edges[1] - edges[0]:g} px, last bin: beyond {edges[-2]:g})"
    )
    ax.set_ylabel("probability density (1/px)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, frameon=False, loc="center left", bbox_to_anchor=(1.01, 0.5))
    finish(fig, "nn_distribution.png", "Nearest-neighbour distance distribution" + (f" ({label0})" if label0 else ""))

    # 5. Populations over time (only when they can change).
    if any("population" in e for e in summary["results"]):
        fig, axes = plt.subplots(1, 2, figsize=(10, 4))
        for k, e in enumerate(entries0):
            if "population" not in e:
                continue
            c = cmap(k / max(1, len(entries0) - 1))
            steps = e["population"]["step"]
            axes[0].plot(steps, np.array(e["population"]["prey_alive"]) / e["prey"], color=c, label=f"N={e['prey']}")
            axes[1].plot(steps, e["population"]["predator_alive"], color=c, label=f"N={e['prey']}")
        axes[0].set_ylabel("live prey / initial prey")
        axes[1].set_ylabel("live predators")
        for ax in axes:
            ax.set_xlabel("step")
            ax.grid(True, alpha=0.3)
        axes[0].legend(fontsize=6, frameon=False, ncol=2)
        finish(fig, "population.png", "Populations over the episode (mean over worlds)")
    return paths
