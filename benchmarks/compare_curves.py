"""Do two training setups learn alike? Their learning curves over seeds, read from the runs'
`progress.csv`, against a reference setup's.

Declared before any comparison is read (#32's check of the fused MLP against torch's):

- primary measure: `--measure` (default `captures_per_prey`, captures per prey per episode) averaged
  over each run's last `--final-fraction` (default 10%) of iterations: one value per seed. Each variant's
  difference from the reference (variant minus reference) with its 95% Welch interval, and a TOST of
  equivalence within `--margin` (default 10%) of the reference's mean;
- the envelope: each curve smoothed over `--smooth` iterations (default 10, NaN-aware trailing mean);
  at every iteration, whether the variant's mean over seeds lies within the reference seeds' [min, max].
  Reported: the fraction of iterations inside.

    python benchmarks/compare_curves.py --reference "torch=runs/torch-s*" \
        --variant "fused=runs/fused-s*" "fused-tf32=runs/fused-tf32-s*" --out curves.json

Prints a table and writes JSON (atomically) with every seed's value.
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.atomic import atomic_open
from aquarium_warp.records import command_line, provenance
from aquarium_warp.statistics import difference, equivalence, seed_stats
from aquarium_warp.training.plots import _moving_average, read_run_curve


def runs(spec: str, option: str) -> tuple[str, list[str]]:
    """`NAME=GLOB` -> (name, the run folders the glob matches, sorted); a one-line error otherwise."""
    name, sep, pattern = spec.partition("=")
    if not sep or not name or not pattern:
        raise SystemExit(f"{option}: {spec!r} is not NAME=GLOB")
    folders = sorted(p for p in glob.glob(pattern) if Path(p, "progress.csv").is_file())
    if len(folders) < 2:
        raise SystemExit(f"{option}: {spec!r} matches {len(folders)} runs with a progress.csv; 2 or more needed")
    return name, folders


def curves(folders: list[str], measure: str) -> np.ndarray:
    """`[seeds, iterations]` of `measure`, cut to the shortest run."""
    columns = [read_run_curve(f)[measure] for f in folders]
    length = min(len(c) for c in columns)
    return np.stack([c[:length] for c in columns])


def final_values(curve: np.ndarray, fraction: float) -> np.ndarray:
    """Per seed: the NaN-aware mean of the last `fraction` of iterations (at least one)."""
    start = curve.shape[1] - max(1, round(fraction * curve.shape[1]))
    return np.nanmean(curve[:, start:], axis=1)


def inside_envelope(reference: np.ndarray, variant: np.ndarray, smooth: int) -> float:
    """Fraction of iterations (where both are defined) at which the variant's smoothed seed mean lies
    within the reference's smoothed seeds' [min, max]."""
    length = min(reference.shape[1], variant.shape[1])
    ref = np.stack([_moving_average(c[:length], smooth) for c in reference])
    with warnings.catch_warnings():  # iterations before any episode ended are NaN in every seed
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(np.stack([_moving_average(c[:length], smooth) for c in variant]), axis=0)
    ok = ~np.isnan(mean) & ~np.isnan(ref).any(axis=0)
    inside = (mean >= ref.min(axis=0)) & (mean <= ref.max(axis=0))
    return float(inside[ok].mean()) if ok.any() else float("nan")


def compare(
    reference: tuple[str, list[str]],
    variants: list[tuple[str, list[str]]],
    measure: str,
    final_fraction: float,
    margin: float,
    smooth: int,
) -> dict:
    ref_curve = curves(reference[1], measure)
    ref_final = final_values(ref_curve, final_fraction)
    out = {reference[0]: {"runs": reference[1], "final": seed_stats(ref_final)}}
    absolute_margin = margin * abs(float(np.nanmean(ref_final)))
    for name, folders in variants:
        curve = curves(folders, measure)
        final = final_values(curve, final_fraction)
        out[name] = {
            "runs": folders,
            "final": seed_stats(final),
            "difference": difference(final, ref_final),
            "equivalence": equivalence(final, ref_final, absolute_margin),
            "inside_envelope": inside_envelope(ref_curve, curve, smooth),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--reference", required=True, help="NAME=GLOB of the reference's run folders")
    parser.add_argument("--variant", nargs="+", required=True, help="NAME=GLOB of each variant's run folders")
    parser.add_argument("--measure", default="captures_per_prey", choices=["captures_per_prey", "reward_per_agent"])
    parser.add_argument("--final-fraction", type=float, default=0.1)
    parser.add_argument("--margin", type=float, default=0.1, help="equivalence margin, a fraction of the reference")
    parser.add_argument("--smooth", type=int, default=10)
    parser.add_argument("--out", type=Path, default=Path("curves.json"))
    parser.add_argument("--commit", default=None, help="the commit measured, for a copy without git history")
    args = parser.parse_args(argv)
    if not 0 < args.final_fraction <= 1:
        parser.error(f"--final-fraction={args.final_fraction} must be in (0, 1]")
    if not args.margin > 0:
        parser.error(f"--margin={args.margin} must be > 0")
    if args.smooth < 1:
        parser.error(f"--smooth={args.smooth} must be an integer >= 1")
    reference = runs(args.reference, "--reference")
    variants = [runs(v, "--variant") for v in args.variant]
    result = compare(reference, variants, args.measure, args.final_fraction, args.margin, args.smooth)
    record = {
        **provenance("cpu", command_line(argv, "benchmarks/compare_curves.py"), args.commit),
        "measure": args.measure,
        "final_fraction": args.final_fraction,
        "margin": args.margin,
        "smooth": args.smooth,
        "reference": reference[0],
        "conditions": result,
    }
    with atomic_open(args.out) as f:
        json.dump(record, f, indent=1)
    ref = result[reference[0]]["final"]
    print(f"{args.measure}, mean of the last {args.final_fraction:.0%} of iterations (95% interval over seeds):")
    print(f"  {reference[0]:12s} {ref['mean']:.4f} +- {ref['ci95']:.4f}  (reference, n={ref['n']})")
    for name, _ in variants:
        c = result[name]
        d, e = c["difference"], c["equivalence"]
        print(
            f"  {name:12s} {c['final']['mean']:.4f} +- {c['final']['ci95']:.4f}  difference {d['difference']:+.4f} "
            f"[{d['low']:+.4f}, {d['high']:+.4f}]  equivalent within +-{e['margin']:.4f}: {e['equivalent']} "
            f"(p={e['p']:.3f})  seed mean inside the reference's envelope at {c['inside_envelope']:.0%} of iterations"
        )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
