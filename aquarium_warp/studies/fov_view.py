"""`aquarium-warp study fov-view`: captures per prey over prey field-of-view angle x view distance, the
swarm-size study (`swarm_size.SwarmSizeStudy`, `kind="fov-view"`) with one prey count, every setting
in one batch by default. Writes `fov_view.csv/json` and a heatmap (`swarm_size_plots`)."""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass, field

from ..arguments import add_options, from_options, number_list, option, plural, positive_int
from ..atomic import check_output_dir
from ..records import command_line
from .swarm_size import RUN_OPTIONS, SwarmSizeStudy, add_output_arguments, run_swarm_size_study

HELP = "captures per prey over prey field of view x view distance"
DESCRIPTION = (
    "Run every (prey FOV angle, view distance) and seed as worlds of one batch (per-world parameters), "
    "one episode each, and write fov_view.csv/json and a heatmap into --out."
)


@dataclass
class FovView:
    """The options in which `study fov-view` differs from `study swarm-size` (the others: `RUN_OPTIONS`)."""

    fov_angles: list[float] = field(
        default_factory=lambda: [60.0, 120.0, 240.0, 360.0],
        metadata=option(
            "prey field-of-view angles, degrees (list)",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, 360.0, low_open=True),
            flag="--fov",
        ),
    )
    view_distances: list[float] = field(
        default_factory=lambda: [50.0, 100.0, 200.0, 400.0],
        metadata=option(
            "prey view distances, px (list)",
            parse=lambda text, flag: number_list(text, float, flag, 0.0, low_open=True),
            flag="--view",
        ),
    )
    prey: int = field(default=32, metadata=option("prey per world", type=positive_int))
    per_setting: bool = field(default=False, metadata=option("one batch per setting instead (for timing)"))

    def study(self, args: argparse.Namespace) -> SwarmSizeStudy:
        """The swarm-size study of this sweep, with the shared options of `args`."""
        return from_options(
            SwarmSizeStudy,
            args,
            RUN_OPTIONS,
            prey=[self.prey],
            fov_angles=self.fov_angles,
            view_distances=self.view_distances,
            one_batch=not self.per_setting,
            kind="fov-view",
            out=args.out,
        )


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, FovView)
    add_options(p, SwarmSizeStudy, RUN_OPTIONS)
    add_output_arguments(p, "fov_view")


def run(args: argparse.Namespace) -> int:
    """`aquarium-warp study fov-view`: captures per prey over prey FOV angle x view distance."""
    study = from_options(FovView, args).study(args)
    print(
        f"aquarium-warp study fov-view: {study.prey[0]} prey, FOV {study.fov_angles} x view "
        f"{study.view_distances}, {plural(study.seeds, 'seed')}, episodes of "
        f"{plural(study.episode_steps, 'step')} -> {study.out}"
    )
    check_output_dir(study.out, "--out")
    summary = run_swarm_size_study(study, progress=not args.no_progress, command=command_line(args.argv))
    print(
        f"wrote {os.path.join(study.out, 'fov_view.csv')}, fov_view.json and {len(summary.get('figures', []))} "
        f"figure(s) in {summary['wall_time_s']:.1f} s on {summary['machine']['device_name']} ({summary['path']})"
    )
    return 0
