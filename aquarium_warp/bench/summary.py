"""The headline numbers of a run: best point, bandwidth share, how flat per-agent time stays, ratios
to the peers and the graph's speed-up."""

from __future__ import annotations

from typing import Any

SERIES = ("agents", "worlds", "load")
RATIO_FROM_AGENTS_PER_WORLD = 1000  # per-agent time ratios run from this world size (or the next above)


def per_agent_time_ratio(
    points: list[dict], series: str, from_agents_per_world: int = RATIO_FROM_AGENTS_PER_WORLD
) -> dict | None:
    """How flat per-agent time is along one series, from the smallest world of at least
    `from_agents_per_world` agents to the largest world: the two points' agents per world and ns per
    agent-step, and ratio = max / min ns per agent-step over the series' measured points between them
    (inclusive). None when the series has no measured world of that size below its largest."""
    pts = [p for p in points if p.get("status") == "ok" and p["series"] == series]
    start = [p["agents_per_world"] for p in pts if p["agents_per_world"] >= from_agents_per_world]
    if not start:
        return None
    lo, hi = min(start), max(p["agents_per_world"] for p in pts)
    if lo >= hi:
        return None
    span = [p for p in pts if lo <= p["agents_per_world"] <= hi]
    ns = [p["ns_per_agent_step"] for p in span]

    def at(n: int) -> dict:  # the point of that world size (the first, should a size repeat)
        return next(p for p in span if p["agents_per_world"] == n)

    return {
        "agents_per_world": [lo, hi],
        "worlds": [at(lo)["worlds"], at(hi)["worlds"]],
        "ns_per_agent_step": [at(lo)["ns_per_agent_step"], at(hi)["ns_per_agent_step"]],
        "ratio": max(ns) / min(ns),
        "points": len(span),
    }


def summary(
    points: list[dict], original: dict, vmas: dict, from_agents_per_world: int = RATIO_FROM_AGENTS_PER_WORLD
) -> dict:
    """Headline numbers. `<series>_per_agent_time_ratio` (`per_agent_time_ratio`) for every series
    with measured worlds from `from_agents_per_world` agents up to a larger one."""
    ok = [p for p in points if p.get("status") == "ok"]
    out: dict[str, Any] = {}
    if ok:
        best = max(ok, key=lambda p: p["agent_steps_per_s"])
        out["best"] = {k: best[k] for k in ("series", "worlds", "agents_per_world", "agent_steps_per_s")}
        fractions = [p["fraction_of_copy_bandwidth"] for p in ok if "fraction_of_copy_bandwidth" in p]
        if fractions:
            out["max_fraction_of_copy_bandwidth"] = max(fractions)
        for series in SERIES:
            s = [p for p in ok if p["series"] == series]
            if len(s) >= 2:
                out[f"{series}_ns_per_agent_first_last"] = [s[0]["ns_per_agent_step"], s[-1]["ns_per_agent_step"]]
        for series in SERIES:
            flat = per_agent_time_ratio(ok, series, from_agents_per_world)
            if flat is not None:
                out[f"{series}_per_agent_time_ratio"] = flat
        ratios = [p["ratios"]["vs_vmas"] for p in ok if "vs_vmas" in p.get("ratios", {})]
        if ratios:
            out["vs_vmas_min_max"] = [min(ratios), max(ratios)]
        if original.get("agent_steps_per_s"):
            out["best_vs_original"] = best["agent_steps_per_s"] / original["agent_steps_per_s"]
        speedups = [p["graph_speedup"] for p in ok if p.get("graph_speedup")]
        if speedups:
            out["graph_speedup_min_max"] = [min(speedups), max(speedups)]
    return out
