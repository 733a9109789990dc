"""The suite: every point of the sweeps, the peers, then the JSON, the figures and the table."""

from __future__ import annotations

import dataclasses
import datetime
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import warp as wp

from ..atomic import atomic_open, check_output_dir
from ..device import resolve_device
from ..records import command_line, git_info, json_safe, machine_info
from .bandwidth import copy_bandwidth
from .byte_model import step_byte_model
from .peers import Peers, add_ratios, measure_original_peer, measure_vmas_peer
from .plots import plot_results
from .point import measure_point
from .settings import BenchSettings
from .stages import STAGE_LABELS
from .summary import summary
from .sweeps import sweep_points
from .table import format_row, format_table


def run_bench(settings: BenchSettings, peers: Peers | None = None) -> dict:
    """Run the whole suite, write the JSON and figures, print the table; returns the JSON's content.
    `peers`: the measuring code of the peers that `settings` asks for (`peers.Peers`)."""
    peers = peers or Peers()
    peers.check(settings)
    check_output_dir(settings.out_dir, "--out-dir")  # before the suite runs, not after
    log: Callable[..., None] = (lambda *a: None) if settings.quiet else (lambda *a: print(*a, flush=True))
    device = resolve_device(settings.device)
    cuda = wp.get_device(device).is_cuda
    if cuda:
        try:  # freed memory goes back to the device at once, so free-memory deltas are per point
            wp.set_mempool_release_threshold(device, 0)
        except Exception:  # noqa: BLE001
            pass
    started = time.perf_counter()
    machine = machine_info(device)
    log(f"aquarium-warp bench on {device} ({machine['device_name']}), warp {machine['warp']}, torch {machine['torch']}")
    bandwidth = copy_bandwidth(device, settings.copy_bytes)
    log(f"copy bandwidth: {bandwidth['bytes_per_s'] / 1e9:.1f} GB/s (read + write)")

    points: list[dict[str, Any]] = []
    for series, cfg, worlds in sweep_points(settings):
        if settings.budget_s is not None and time.perf_counter() - started > settings.budget_s:
            points.append(
                {
                    "series": series,
                    "worlds": worlds,
                    "agents_per_world": cfg.capacity,
                    "agents": worlds * cfg.capacity,
                    "status": "skipped",
                    "note": "suite time budget spent",
                }
            )
            continue
        row = measure_point(series, cfg, worlds, device, settings)
        if row["status"] == "ok":
            row["fraction_of_copy_bandwidth"] = row["achieved_bytes_per_s"] / bandwidth["bytes_per_s"]
        points.append(row)
        log(format_row(row))

    original = measure_original_peer(settings, peers.original)
    if original.get("agent_steps_per_s"):
        log(
            f"  original marl-aquarium 0.1.10 (CPU, default, {original['status']}): "
            f"{original['agent_steps_per_s']:.3e} agent-steps/s"
        )
    else:
        log(f"  original marl-aquarium: {original['note']}")
    vmas = measure_vmas_peer(settings, device, log, started, peers.vmas)
    if vmas["status"] != "ok":
        log(f"  VMAS: {vmas['note']}")
    add_ratios(points, original, vmas)

    out_dir = Path(settings.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = device.replace(":", "")
    result: dict[str, Any] = {
        "benchmark": "aquarium-warp scaling: agent-steps/s of BatchedAquarium.step (random actions, observations on)",
        "created_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command_line(),
        "machine": machine,
        "git": git_info(settings.git_commit),
        "settings": {k: v for k, v in dataclasses.asdict(settings).items() if k not in ("quiet",)},
        "method": {
            "throughput": f"median of {settings.repeats} runs of >= {settings.seconds} s after {settings.warmup_steps} "
            "warm-up steps; actions from a pool of 8 random sets drawn beforehand; agents counted as "
            "slots (worlds x capacity)",
            "stages": STAGE_LABELS,
            "bandwidth": "achieved = bytes_per_agent_step (step_byte_model) x agent-steps/s; fraction of the "
            "measured copy bandwidth (both count bytes read + written)",
            "byte_model": (step_byte_model.__doc__ or "").strip(),
        },
        "copy_bandwidth": bandwidth,
        "points": points,
        "peers": {"original": original, "vmas": vmas},
        "summary": summary(points, original, vmas),
        "wall_s": None,
    }
    figures: list[Path] = []
    unwritten: OSError | None = None
    if settings.plots:
        try:
            figures = plot_results(result, out_dir / f"scaling_{tag}")
        except OSError as error:  # a full disk: the run fails, once its measurements are kept in the JSON
            unwritten = error
        except Exception as error:  # noqa: BLE001 - a figure that cannot be drawn is no failed run
            log(f"figures failed: {type(error).__name__}: {error}")
    result["figures"] = [Path(f).name for f in figures]  # next to the JSON
    result["wall_s"] = time.perf_counter() - started
    path = out_dir / f"scaling_{tag}.json"
    with atomic_open(path) as f:
        f.write(json.dumps(json_safe(result), indent=2) + "\n")
    result["json"] = str(path)
    log("")
    log(format_table(result))
    log(f"wrote {path}" + (f" and {len(figures)} figures" if figures else "") + f" in {result['wall_s']:.0f} s")
    if unwritten is not None:
        raise unwritten
    return result


def replot(json_path: str | Path) -> list[Path]:
    """Redraw the figures of a scaling JSON next to it (e.g. after fetching a GPU run's results)."""
    path = Path(json_path)
    result = json.loads(path.read_text())
    stem = path.with_suffix("")
    figures = plot_results(result, stem)
    result["figures"] = [f.name for f in figures]
    with atomic_open(path) as f:
        f.write(json.dumps(json_safe(result), indent=2) + "\n")
    return figures
