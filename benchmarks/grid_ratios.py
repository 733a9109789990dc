"""Ratios read from the evaluation grids that `benchmarks/general_policies.py` writes (`grid_prey/grid.json`,
`grid_predator/grid.json` under its `--out`), per cell at the pairing's mean (`training/grid.py`'s
`pairing_means`, as its targets read them):

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
import json
import os
import re
import statistics
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from aquarium_warp.training.grid import FULL_VIEW_RATIO, PREDATOR_RATIO, pairing_means
from aquarium_warp.training.grid_cells import BASELINES, NAIVCHASE


def run_means(result: dict, side: str) -> dict[tuple[str, str], dict[int, float]]:
    """`pairing_means(result)`, with each pairing's files on `side` ("prey" or "predator") that come from a
    training run in place of the pairing: `<label>:<preset>-s<seed>`, its mean over the evaluation seeds
    per cell."""
    means = pairing_means(result)
    for p in result["pairings"]:
        for run in p["runs"]:
            found = re.search(r"([\w-]+-s\d+)[/\\]exported", run[f"{side}_spec"])
            if not found:
                continue
            means.pop((p["prey"], p["predator"]), None)
            label = f"{p[side]}:{found.group(1)}"
            key = (label, p["predator"]) if side == "prey" else (p["prey"], label)
            means[key] = {c: statistics.fmean(v) for c, v in zip(p["cells"], run["values"], strict=True)}
    return means


def summary(ratios: list[float], low: float | None = None, high: float | None = None) -> str:
    parts = [f"cells {len(ratios):3d}", f"mean ratio {statistics.fmean(ratios):.3f}"]
    if low is not None:
        parts += [f"at most {low:g}x {sum(r <= low for r in ratios):3d}"]
        parts += [f"below 1x {sum(r < 1 for r in ratios):3d}"]
    if high is not None:
        parts += [f"at least {high:g}x {sum(r >= high for r in ratios):3d}"]
        parts += [f"above 1x {sum(r > 1 for r in ratios):3d}"]
    return ", ".join(parts)


def _ratios(means: dict, pairing: tuple[str, str], against: tuple[str, str], cells) -> list[float]:
    a, b = means.get(pairing, {}), means.get(against, {})
    return [a[c] / b[c] for c in cells if c in a and c in b and b[c] > 0]


def prey_lines(result: dict, means: dict, fovs: list[float] | None) -> list[str]:
    fov_of = [c["prey_fov_angle"] for c in result["cells"]]
    every = sorted(set(fov_of))
    lines = []
    for label in sorted({p for p, q in means if p not in BASELINES and q in NAIVCHASE}):
        for predator in NAIVCHASE:
            for group in [[f] for f in (fovs or every)] + ([every] if not fovs else []):
                cells = [c for c, f in enumerate(fov_of) if f in group]
                ratios = _ratios(means, (label, predator), ("turnaway", predator), cells)
                if ratios:
                    where = "all" if len(group) > 1 else f"{group[0]:g} deg"
                    lines.append(f"prey {label} vs {predator}, {where}: {summary(ratios, low=FULL_VIEW_RATIO)}")
    return lines


def predator_lines(result: dict, means: dict) -> list[str]:
    cells = range(len(result["cells"]))
    lines = []
    for label in sorted({q for _, q in means if q not in NAIVCHASE}):
        for prey in sorted({p for p, _ in means}):
            ratios = _ratios(means, (prey, label), (prey, "naivchase"), cells)
            if ratios:
                lines.append(f"predator {label} vs {prey}: {summary(ratios, high=PREDATOR_RATIO)}")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", help="general_policies.py's --out (or a results folder holding its grids)")
    p.add_argument("--by-run", action="store_true", help="each training run of a learned label on its own")
    p.add_argument(
        "--fov", type=float, nargs="+", default=None, help="the prey's fields of view (default: each and all)"
    )
    args = p.parse_args(argv)
    grids = {side: os.path.join(args.folder, f"grid_{side}", "grid.json") for side in ("prey", "predator")}
    if not any(os.path.isfile(path) for path in grids.values()):
        p.error(f"folder={args.folder!r} holds neither grid_prey/grid.json nor grid_predator/grid.json")
    lines = []
    for side, path in grids.items():
        if not os.path.isfile(path):
            continue
        with open(path, encoding="utf-8") as f:
            result = json.load(f)
        means = run_means(result, side) if args.by_run else pairing_means(result)
        lines += prey_lines(result, means, args.fov) if side == "prey" else predator_lines(result, means)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
