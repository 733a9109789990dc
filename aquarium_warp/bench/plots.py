"""The figures of a run: throughput and time per agent-step against agents in flight (with the
peers and the bandwidth bound), and the share of each stage of the step."""

from __future__ import annotations

import statistics
from pathlib import Path

from ..atomic import write_figure
from .stages import STAGE_LABELS, STAGES


def plot_results(result: dict, stem: str | Path) -> list[Path]:
    """Log-log figures next to the JSON: agent-steps/s and ns per agent-step vs agents in flight (one
    line per series; the load series, whose agents in flight hardly change, vs agents per world), and
    the share of each stage of the step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stem = Path(stem)
    machine = result["machine"]
    where = f"{machine['device_name']} ({machine['device']})"
    commit = (result.get("git") or {}).get("commit") or "unknown"
    stamp = (
        f"random actions, observations on; warp {machine['warp']}, torch {machine['torch']}"
        + (f", vmas {machine['vmas']}" if machine.get("vmas") else "")
        + f"; commit {commit[:10]}"
    )
    ok = [p for p in result["points"] if p.get("status") == "ok"]
    series = {
        "agents": ("aquarium-warp: 1 world of N agents", "tab:blue", "o"),
        "worlds": ("aquarium-warp: W worlds x 17 agents", "tab:orange", "s"),
    }
    load_pts = [p for p in ok if p["series"] == "load"]
    if load_pts:
        load = (result.get("settings") or {}).get("load_agents") or round(
            statistics.median(p["agents"] for p in load_pts)
        )
        series["load"] = (f"aquarium-warp: ~{load:,} agents in flight as worlds of N (x = N)", "tab:purple", "D")
    x_key = {"load": "agents_per_world"}  # the other series: agents in flight
    vmas = [v for v in result["peers"]["vmas"].get("points", []) if v.get("status") == "ok"]
    original = result["peers"]["original"]
    bw = result["copy_bandwidth"]["bytes_per_s"]
    paths = []
    for kind in ("throughput", "per_agent"):
        fig, ax = plt.subplots(figsize=(8.5, 7))
        value = (lambda r: r) if kind == "throughput" else (lambda r: 1e9 / r)
        for key, (label, color, marker) in series.items():
            pts = [p for p in ok if p["series"] == key]
            if not pts:
                continue
            x = x_key.get(key, "agents")
            xs = [p[x] for p in pts]
            ax.plot(xs, [value(p["agent_steps_per_s"]) for p in pts], marker=marker, color=color, label=label)
            eager = [(p[x], p["eager"]["agent_steps_per_s"]) for p in pts if p.get("eager")]
            if eager:
                ax.plot(
                    *zip(*[(x, value(y)) for x, y in eager]),
                    marker=marker,
                    color=color,
                    linestyle="--",
                    alpha=0.6,
                    label=label + " (eager, no graph)",
                )
            bound = [value(bw / p["bytes_per_agent_step"]) for p in pts]
            ax.plot(
                xs,
                bound,
                color=color,
                linestyle=":",
                alpha=0.7,
                label=f"bound: copy bandwidth / bytes per agent-step ({key})",
            )
        for key, label, color, marker in (
            ("agents", "VMAS simple_tag: 1 env of N agents", "tab:green", "^"),
            ("worlds", "VMAS simple_tag: W envs x 17 agents", "tab:red", "v"),
        ):
            pts = [v for v in vmas if v["series"] == key]
            if pts:
                ax.plot(
                    [v["agents"] for v in pts],
                    [value(v["agent_steps_per_s"]) for v in pts],
                    marker=marker,
                    color=color,
                    label=label,
                )
        if original.get("agent_steps_per_s"):
            ax.plot(
                [17],
                [value(original["agent_steps_per_s"])],
                marker="*",
                markersize=14,
                color="black",
                linestyle="none",
                label="original marl-aquarium (CPU, 17 agents)",
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(
            "agents stepped at once (worlds x agents per world)"
            + ("; load series: agents per world" if load_pts else "")
        )
        ax.set_ylabel("agent-steps per second" if kind == "throughput" else "ns per agent-step")
        ax.set_title(
            ("Throughput" if kind == "throughput" else "Time per agent-step") + f" on {where}\n{stamp}", fontsize=10
        )
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, frameon=False)
        fig.tight_layout()
        path = stem.parent / f"{stem.name}_{kind}.png"
        write_figure(fig, path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths.append(path)

    staged = [p for p in ok if p.get("stages_ms")]
    if staged:
        panels = ("agents", "worlds") + (("load",) if any(p["series"] == "load" for p in staged) else ())
        fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.5), sharey=True)
        names = list(STAGES) + ["heuristics"]
        colors = plt.get_cmap("tab10").colors  # type: ignore[attr-defined]  # a ListedColormap
        for ax, key in zip(axes, panels):
            pts = [p for p in staged if p["series"] == key]
            if not pts:
                ax.set_visible(False)
                continue
            xs = list(range(len(pts)))
            bottom = [0.0] * len(pts)
            for j, name in enumerate(names):
                vals = [
                    (p["stages_ms"].get(name, 0.0) if name != "heuristics" else p.get("heuristics_ms", 0.0)) or 0.0
                    for p in pts
                ]
                totals = [p["stage_sum_ms"] + (p.get("heuristics_ms") or 0.0) for p in pts]
                share = [100 * v / t if t else 0.0 for v, t in zip(vals, totals)]
                ax.bar(
                    xs,
                    share,
                    bottom=bottom,
                    color=colors[j % 10],
                    label=STAGE_LABELS[name],
                    hatch="//" if name == "heuristics" else None,
                )
                bottom = [b + s for b, s in zip(bottom, share)]
            ax.set_xticks(xs)
            ax.set_xticklabels(
                [f"{p['agents']:,}" if key == "agents" else f"{p['worlds']:,}x{p['agents_per_world']:,}" for p in pts],
                rotation=45,
                ha="right",
                fontsize=8,
            )
            ax.set_title(series[key][0].split(" (")[0], fontsize=10)
            ax.set_xlabel("agents" if key == "agents" else "worlds x agents")
        axes[0].set_ylabel("share of step + heuristics time, %")
        handles, labels = next(a for a in axes if a.get_visible()).get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7.5)
        fig.suptitle(f"Where the step's time goes on {where}\n{stamp}", fontsize=10)
        fig.tight_layout(rect=(0, 0.12, 1, 0.93))
        path = stem.parent / f"{stem.name}_stages.png"
        write_figure(fig, path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths.append(path)
    return paths
