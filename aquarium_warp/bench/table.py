"""The printed table of a run and its progress lines."""

from __future__ import annotations

from .stages import STAGES
from .summary import SERIES


def _si(x: float | None) -> str:
    return "-" if x is None else f"{x:.3g}"


def _ns_per_agent(ms: float | None, agents: int) -> str:
    return "-" if ms is None else f"{ms * 1e6 / agents:.3g}"


def format_row(row: dict) -> str:
    """One line of progress: a point's step time, throughput and graph speed-up, or why it did not run."""
    head = f"{row['series']:6s} {row['worlds']:6d} x {row['agents_per_world']:7d}"
    if row.get("status") != "ok":
        return f"{head}  {row['status']}: {row.get('note')}"
    eager = f"{row['graph_speedup']:.2f}x" if row.get("graph_speedup") else "n/a"
    return (
        f"{head}  {row['step_ms']:9.3f} ms  {row['agent_steps_per_s']:10.3e} agent-steps/s  "
        f"{row['ns_per_agent_step']:9.2f} ns/agent  eager/graph {eager}"
    )


def format_table(result: dict) -> str:
    """The printed table of a run: every point by stage, the bandwidth, the peers and the flatness."""
    lines = []
    cols = (
        "series",
        "worlds x agents",
        "step ms",
        "agent-steps/s",
        "ns/agent",
        "graph",
        "act",
        "mot",
        "grid",
        "capt",
        "pop",
        "obs",
        "fused",
        "heur",
        "MiB",
        "B/agent",
        "BW frac",
        "xVMAS",
        "xorig",
    )
    lines.append(
        "{:6s} {:>16s} {:>9s} {:>13s} {:>9s} {:>6s} | {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} | "
        "{:>6s} | {:>8s} {:>7s} {:>7s} {:>8s} {:>8s}".format(*cols)
    )
    lines.append("       (stage columns and heur: ns per agent-step)")
    for p in result["points"]:
        head = f"{p['series']:6s} {p['worlds']:>7d} x {p['agents_per_world']:<7d}"
        if p.get("status") != "ok":
            lines.append(f"{head} {p['status']}: {p.get('note')}")
            continue
        st = p.get("stages_ms", {})
        r = p.get("ratios", {})
        lines.append(
            "{} {:9.3f} {:13.3e} {:9.2f} {:>6s} | {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} {:>6s} | "
            "{:>6s} | {:>8s} {:7.0f} {:7.3f} {:>8s} {:>8s}".format(
                head,
                p["step_ms"],
                p["agent_steps_per_s"],
                p["ns_per_agent_step"],
                f"{p['graph_speedup']:.2f}x" if p.get("graph_speedup") else "n/a",
                *(_ns_per_agent(st.get(s), p["agents"]) for s in STAGES),
                _ns_per_agent(p.get("heuristics_ms"), p["agents"]),
                _si(p["memory"]["arrays_bytes"] / 2**20),
                p["bytes_per_agent_step"],
                p.get("fraction_of_copy_bandwidth", float("nan")),
                _si(r.get("vs_vmas")),
                _si(r.get("vs_original")),
            )
        )
    bw = result["copy_bandwidth"]
    lines.append(
        f"copy bandwidth {bw['bytes_per_s'] / 1e9:.1f} GB/s (read + write); graph = eager/graph step time; "
        "B/agent: byte model; BW frac: achieved / copy bandwidth"
    )
    original = result["peers"]["original"]
    if original.get("agent_steps_per_s"):
        lines.append(
            f"original marl-aquarium 0.1.10 (CPU, default config): {original['agent_steps_per_s']:.3e} "
            f"agent-steps/s ({original['status']})"
        )
    vmas = result["peers"]["vmas"]
    for v in vmas.get("points", []):
        if v.get("status") == "ok":
            lines.append(
                f"VMAS {v['scenario']} {v['series']:6s} {v['envs']:6d} envs x {v['agents_per_env']:5d}: "
                f"{v['step_ms']:10.3f} ms  {v['agent_steps_per_s']:.3e} agent-steps/s"
            )
    load = (result.get("settings") or {}).get("load_agents")
    if load and any(p["series"] == "load" for p in result["points"]):
        lines.append(f"load series: worlds = max(1, round({load:,} / agents per world)), ~{load:,} agents in flight")
    summ = result.get("summary") or {}
    for series in SERIES:
        flat = summ.get(f"{series}_per_agent_time_ratio")
        if flat:
            (lo, hi), (ns_lo, ns_hi) = flat["agents_per_world"], flat["ns_per_agent_step"]
            lines.append(
                f"per-agent time flatness, {series} series: {lo:,} -> {hi:,} agents per world: "
                f"{ns_lo:.3g} -> {ns_hi:.3g} ns/agent-step, max/min {flat['ratio']:.2f} "
                f"over {flat['points']} points"
            )
    return "\n".join(lines)
