"""`aquarium-warp study fov-view`: captures per prey over prey field-of-view angle x view distance, the
swarm-size study (`swarm_size.SwarmSizeStudy`, `kind="fov-view"`) with one prey count, every setting
in one batch by default. Writes `fov_view.csv/json` and a heatmap (`swarm_size_plots`)."""

from __future__ import annotations

import argparse
import os

from ..arguments import number_list, plural, positive_int
from ..atomic import check_output_dir
from ..records import command_line
from .swarm_size import SwarmSizeStudy, add_run_arguments, run_settings, run_swarm_size_study

HELP = "captures per prey over prey field of view x view distance"
DESCRIPTION = (
    "Run every (prey FOV angle, view distance) and seed as worlds of one batch (per-world parameters), "
    "one episode each, and write fov_view.csv/json and a heatmap into --out."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fov", default="60,120,240,360", help="prey field-of-view angles, degrees (list)")
    p.add_argument("--view", default="50,100,200,400", help="prey view distances, px (list)")
    p.add_argument("--prey", type=positive_int, default=32, help="prey per world (default 32)")
    p.add_argument("--per-setting", action="store_true", help="one batch per setting instead (for timing)")
    add_run_arguments(p, "fov_view")


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study fov-view`: captures per prey over prey FOV angle x view distance."""
    fovs = number_list(args.fov, float, "--fov", 0.0, 360.0, low_open=True)
    views = number_list(args.view, float, "--view", 0.0, low_open=True)
    study = SwarmSizeStudy(
        prey=[args.prey],
        fov_angles=fovs,
        view_distances=views,
        one_batch=not args.per_setting,
        kind="fov-view",
        **run_settings(args),
    )
    print(
        f"aquarium-warp study fov-view: {study.prey[0]} prey, FOV {fovs} x view {views}, "
        f"{plural(study.seeds, 'seed')}, episodes of {plural(study.episode_steps, 'step')} -> {study.out}"
    )
    check_output_dir(study.out, "--out")
    summary = run_swarm_size_study(study, progress=not args.no_progress, command=command_line(args.argv))
    print(
        f"wrote {os.path.join(study.out, 'fov_view.csv')}, fov_view.json and {len(summary.get('figures', []))} "
        f"figure(s) in {summary['wall_time_s']:.1f} s on {summary['machine']['device_name']} ({summary['path']})"
    )
    return 0
