"""Ratios read from the evaluation grids that `benchmarks/general_policies.py` writes (`grid_prey/grid.csv`,
`grid_predator/grid.csv` under its `--out`), per cell with the evaluation seeds and the training runs of a
label pooled (as `training/grid.py`'s targets read them):

- prey: each learned label's captures per prey over TurnAway's against each NaivChase kind, by the prey's
  field of view (and all of them): the mean ratio over the cells, the cells at most 0.6x (the 360-degree
  target's ratio) and the cells below 1x;
- predators: each learned label's captures over NaivChase's against each prey: the mean ratio, the cells
  at least 1.3x and the cells above 1x.

`--by-run` splits each learned label by its training run (the `<preset>-s<seed>` folder of its file).

    python benchmarks/grid_ratios.py benchmarks/results/general_coevolved_h200x4_ee8b79d
    python benchmarks/grid_ratios.py benchmarks/results/general_prey_360_pilot_h200x4_686be86 --by-run --fov 360
"""

from __future__ import annotations

import argparse
import collections
import csv
import os
import re
import statistics
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from aquarium_warp.training.grid import FULL_VIEW_RATIO, PREDATOR_RATIO

HEURISTIC_PREY = ("turnaway", "boids", "constant", "random")
HEURISTIC_PREDATORS = ("naivchase", "naivchase-noconfusion")
CELL = ("prey_count", "prey_view_distance", "prey_fov_angle", "predator_max_speed")


def cell_means(path: str, by_run: str | None = None) -> dict[tuple, float]:
    """`{(prey, predator, cell): mean value}` of a grid CSV; `by_run` ("prey" or "predator"): that side's
    learned labels become `<label>:<preset>-s<seed>` of their file's run folder."""
    values = collections.defaultdict(list)
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            names = {"prey": row["prey"], "predator": row["predator"]}
            if by_run:
                run = re.search(r"([\w-]+-s\d+)[/\\]exported", row[f"{by_run}_spec"])
                if run:
                    names[by_run] += ":" + run.group(1)
            values[(names["prey"], names["predator"], tuple(row[k] for k in CELL))].append(float(row["value"]))
    return {key: statistics.fmean(v) for key, v in values.items()}


def summary(ratios: list[float], low: float | None = None, high: float | None = None) -> str:
    parts = [f"cells {len(ratios):3d}", f"mean ratio {statistics.fmean(ratios):.3f}"]
    if low is not None:
        parts += [f"at most {low:g}x {sum(r <= low for r in ratios):3d}"]
        parts += [f"below 1x {sum(r < 1 for r in ratios):3d}"]
    if high is not None:
        parts += [
            f"at least {high:g}x {sum(r >= high for r in ratios):3d}",
            f"above 1x {sum(r > 1 for r in ratios):3d}",
        ]
    return ", ".join(parts)


def prey_lines(means: dict, fovs: list[str] | None) -> list[str]:
    lines = []
    labels = sorted({p for p, q, _ in means if p not in HEURISTIC_PREY and q in HEURISTIC_PREDATORS})
    all_fovs = sorted({c[2] for *_, c in means}, key=float)
    for label in labels:
        for predator in HEURISTIC_PREDATORS:
            for fov in [[f] for f in (fovs or all_fovs)] + ([all_fovs] if not fovs else []):
                cells = [c for p, q, c in means if p == "turnaway" and q == predator and c[2] in fov]
                ratios = [means[(label, predator, c)] / means[("turnaway", predator, c)] for c in cells
                          if (label, predator, c) in means and means[("turnaway", predator, c)] > 0]  # fmt: skip
                if ratios:
                    where = "all" if len(fov) > 1 else f"{float(fov[0]):g} deg"
                    lines.append(f"prey {label} vs {predator}, {where}: {summary(ratios, low=FULL_VIEW_RATIO)}")
    return lines


def predator_lines(means: dict) -> list[str]:
    lines = []
    labels = sorted({q for _, q, _ in means if q not in HEURISTIC_PREDATORS})
    for label in labels:
        for prey in sorted({p for p, _, _ in means}):
            cells = [c for p, q, c in means if p == prey and q == "naivchase"]
            ratios = [means[(prey, label, c)] / means[(prey, "naivchase", c)] for c in cells
                      if (prey, label, c) in means and means[(prey, "naivchase", c)] > 0]  # fmt: skip
            if ratios:
                lines.append(f"predator {label} vs {prey}: {summary(ratios, high=PREDATOR_RATIO)}")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", help="general_policies.py's --out (or a results folder holding its grids)")
    p.add_argument("--by-run", action="store_true", help="each training run of a learned label on its own")
    p.add_argument(
        "--fov", nargs="+", default=None, help="the prey's fields of view to report (default: each, and all)"
    )
    args = p.parse_args(argv)
    fovs = [f"{float(f):.1f}" for f in args.fov] if args.fov else None
    lines = []
    prey_csv = os.path.join(args.folder, "grid_prey", "grid.csv")
    predator_csv = os.path.join(args.folder, "grid_predator", "grid.csv")
    if not (os.path.isfile(prey_csv) or os.path.isfile(predator_csv)):
        p.error(f"folder={args.folder!r} holds neither grid_prey/grid.csv nor grid_predator/grid.csv")
    if os.path.isfile(prey_csv):
        lines += prey_lines(cell_means(prey_csv, "prey" if args.by_run else None), fovs)
    if os.path.isfile(predator_csv):
        lines += predator_lines(cell_means(predator_csv, "predator" if args.by_run else None))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
