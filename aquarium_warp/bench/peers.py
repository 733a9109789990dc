"""The peers measured in the same run: the original marl-aquarium and VMAS's predator-prey scenario.

Their measuring code lives in the source tree's `benchmarks/` (it installs the original into a
throwaway virtual environment, and VMAS is no dependency), never in the package:
`benchmarks/bench_scaling.py` runs the suite with `Peers(original_aquarium, vmas_peer)`, and
`aquarium-warp bench` measures aquarium-warp alone (or reads a stored measurement of the original).
"""

from __future__ import annotations

import dataclasses
import gc
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from .settings import BenchSettings


class OriginalHarness(Protocol):
    """What the suite uses of `benchmarks/original_aquarium.py`."""

    def measure_original(
        self, seconds: float = ..., repeats: int = ..., which: str = ..., *, warmup: float = ...
    ) -> dict: ...


class VmasHarness(Protocol):
    """What the suite uses of `benchmarks/vmas_peer.py`."""

    SCENARIO: str

    def vmas_version(self) -> str | None: ...

    def measure_vmas(
        self,
        agents_per_env: int,
        envs: int,
        device: str = ...,
        seconds: float = ...,
        repeats: int = ...,
        *,
        budget_s: float | None = ...,
    ) -> dict: ...


@dataclasses.dataclass(frozen=True)
class Peers:
    """The peers' measuring code (modules of `benchmarks/`); None: that peer cannot be measured."""

    original: OriginalHarness | None = None
    vmas: VmasHarness | None = None

    def check(self, settings: BenchSettings) -> None:
        """Refuse, before any measurement, settings that ask for a peer this run cannot measure."""
        if settings.original and not settings.original_json and self.original is None:
            raise ValueError(_needs_harness("--original"))
        if settings.vmas and self.vmas is None:
            raise ValueError(_needs_harness("--vmas"))


def _needs_harness(flag: str) -> str:
    return (
        f"{flag}: the peers are measured by the source tree's benchmark script, "
        f"`python benchmarks/bench_scaling.py {flag} ...` (same options); `aquarium-warp bench` measures "
        "aquarium-warp alone" + (" or reads --original-json" if flag == "--original" else "")
    )


def measure_original_peer(settings: BenchSettings, harness: OriginalHarness | None = None) -> dict:
    """The original marl-aquarium 0.1.10 (raw env, default config, CPU): read from `settings.original_json`,
    else measured by `harness` when `settings.original` asks for it, else why it was not measured."""
    if settings.original_json:
        try:
            stored = json.loads(Path(settings.original_json).read_text())
            raw = stored.get("results", {}).get("raw", stored)
            return {
                "status": "stored",
                "agent_steps_per_s": raw["agent_steps_per_s"],
                "env_steps_per_s": raw["env_steps_per_s"],
                "source": str(settings.original_json),
                "machine": stored.get("machine"),
                "note": "measured earlier, possibly on another machine (see machine)",
            }
        except (OSError, KeyError, ValueError) as error:
            return {"status": "skipped", "note": f"could not read {settings.original_json}: {error}"}
    if not settings.original:
        return {"status": "skipped", "note": "not asked for (--original)"}
    if harness is None:
        raise ValueError(_needs_harness("--original"))
    try:
        result = harness.measure_original(seconds=settings.original_seconds, repeats=3, which="raw", warmup=1.0)
    except Exception as error:  # noqa: BLE001  (no network for the venv, a failing child, ...)
        return {"status": "skipped", "note": f"{type(error).__name__}: {str(error)[:400]}"}
    return {
        "status": "ok",
        "agent_steps_per_s": result["agent_steps_per_s"],
        "env_steps_per_s": result["env_steps_per_s"],
        "runs": [r["agent_steps_per_s"] for r in result["runs"]],
        "seconds": result["seconds"],
        "repeats": result["repeats"],
        "versions": result.get("versions"),
        "entry_point": result["entry_point"],
        "agents": 17,
        "config": "default (16 prey, 1 predator, 800 x 800 px)",
    }


def measure_vmas_peer(
    settings: BenchSettings,
    device: str,
    log: Callable[[str], None],
    started: float | None = None,
    harness: VmasHarness | None = None,
) -> dict:
    """VMAS simple_tag at the agent counts of both sweeps (within the caps), measured by `harness`
    when `settings.vmas` asks for it, or why not."""
    if not settings.vmas:
        return {"status": "skipped", "note": "not asked for (--vmas)", "points": []}
    if harness is None:
        raise ValueError(_needs_harness("--vmas"))
    module = harness
    if module.vmas_version() is None:
        return {"status": "skipped", "note": "vmas is not importable (pip install vmas)", "points": []}
    plan = [("agents", n, 1) for n in settings.agents]
    plan += [("worlds", 17, w) for w in settings.worlds]
    points: list[dict[str, Any]] = []
    for series, n, envs in plan:
        base = {"series": series, "agents_per_env": n, "envs": envs, "agents": n * envs}
        if settings.budget_s is not None and started is not None and time.perf_counter() - started > settings.budget_s:
            points.append({**base, "status": "skipped", "note": "suite time budget spent"})
            continue
        if n > settings.vmas_max_agents_per_env:
            points.append(
                {
                    **base,
                    "status": "skipped",
                    "note": f"{n} agents per env > --vmas-max-agents-per-env {settings.vmas_max_agents_per_env}",
                }
            )
            continue
        if envs > settings.vmas_max_envs or n * envs > settings.max_agents_in_flight:
            points.append({**base, "status": "skipped", "note": "over --vmas-max-envs or --max-agents-in-flight"})
            continue
        try:
            r = module.measure_vmas(
                n,
                envs,
                device,
                seconds=settings.seconds,
                repeats=min(settings.repeats, 3),
                budget_s=settings.vmas_budget_s,
            )
            points.append({**base, "status": "ok", **r})
            log(
                f"  VMAS {module.SCENARIO:10s} {series:6s} {envs:6d} x {n:7d}  {r['step_ms']:10.3f} ms  "
                f"{r['agent_steps_per_s']:11.3e} agent-steps/s"
            )
        except Exception as error:  # noqa: BLE001
            points.append({**base, "status": "failed", "note": f"{type(error).__name__}: {str(error)[:300]}"})
            log(f"  VMAS {series} {envs} x {n}: failed ({type(error).__name__})")
        gc.collect()
    return {
        "status": "ok",
        "scenario": module.SCENARIO,
        "vmas": module.vmas_version(),
        "points": points,
        "split": "predators = max(1, round(N / 17)), prey = N - predators (as ours)",
        "note": "scenario defaults otherwise (2 landmarks, 10 substeps), discrete actions, observations "
        "computed in every step",
    }


def add_ratios(points: list[dict], original: dict, vmas: dict) -> None:
    """Ours over the peers, per point: vs the original (one 17-agent world on the CPU) and vs VMAS at
    the same series, worlds and agents per world."""
    by = {(p["series"], p["envs"], p["agents_per_env"]): p for p in vmas.get("points", []) if p.get("status") == "ok"}
    base = original.get("agent_steps_per_s")
    for row in points:
        if row.get("status") != "ok":
            continue
        ratios: dict[str, float] = {}
        if base:
            ratios["vs_original"] = row["agent_steps_per_s"] / base
        peer = by.get((row["series"], row["worlds"], row["agents_per_world"]))
        if peer:
            ratios["vs_vmas"] = row["agent_steps_per_s"] / peer["agent_steps_per_s"]
            row["vmas_agent_steps_per_s"] = peer["agent_steps_per_s"]
        row["ratios"] = ratios
