"""Expected nearest-neighbour distances of random arrangements on a torus: the nulls that the mean
nearest-neighbour distance of the prey is read against (`SwarmMetrics`' `nn_ratio_point` and
`nn_ratio_hard_disk`).

- Point null (`point_nn_means`): n independent uniform points on the `width` x `height` torus. The
  distance D from a point to the nearest of the n - 1 others has P(D > r) = (1 - a(r) / (W H))^(n - 1),
  a(r) the area of the torus disk of radius r (the disk clipped to the W x H cell centred on it), so
  E[D] = integral of that from 0 to the largest torus distance: exact up to the quadrature
  (trapezoids on `POINT_GRID` radii; 20 times as many change it by less than 1e-11). Above
  `POINT_QUADRATURE_MAX` points, where the disks that matter lie far inside the cell, the integral's
  closed form for an unclipped disk, sqrt(W H) / 2 * Gamma(n) / Gamma(n + 1/2), is taken instead
  wherever the clipped part can change it by less than 1e-12 of its value (it agrees with the quadrature
  to 3e-12 at n = 4,096), so that a world of 100,000 prey gets its table at once.
- Hard-disk null (`hard_disk_nn_means`): n disks of diameter d that may touch but not overlap,
  placed by random sequential addition (each disk uniform, redrawn while it overlaps one already
  placed), the prey that their hit boxes keep apart. No closed form: a seeded Monte Carlo over
  `S = max(32, ceil(HARD_DISK_PREY / N))` independent sequences of N disks (N the largest count asked
  for, about 65,536 disks in all), numpy's generator seeded with `seed`. The first n disks of a
  sequence are an arrangement of n disks, so one set of sequences gives every n <= N; each n's mean
  over the S sequences comes with its standard error (standard deviation over the sequences / sqrt S;
  at N = 32, d = 40 px, 800 x 800: 2,048 sequences, 0.14 % of the mean at n = 32, 0.8 % at n = 2).
  Where random sequential addition cannot place a disk within `HARD_DISK_ROUNDS` draws per sequence
  (a crowded arena: the plane's jamming coverage is 0.547; 40 px disks in 800 x 800 stop at about 210),
  that count and every larger one are NaN. Above `HARD_DISK_MAX_PREY` disks the Monte Carlo (its
  cost grows as S N^2) is not run: those counts are NaN too.

Both are cached per argument set (computed once per process).
"""

from __future__ import annotations

import functools
import math

import numpy as np

POINT_GRID = 20001
POINT_QUADRATURE_MAX = 4096
HARD_DISK_PREY = 65536
HARD_DISK_ROUNDS = 256
HARD_DISK_MAX_PREY = 1024


def torus_disk_area(r: np.ndarray, width: float, height: float) -> np.ndarray:
    """Area (px^2) of the points within torus distance `r` of a point: the disk of radius r clipped
    to the `width` x `height` rectangle centred on it (4 x the quarter disk in [0, W/2] x [0, H/2])."""
    r = np.asarray(r, np.float64)
    a, b = width / 2.0, height / 2.0

    def primitive(x):  # integral of sqrt(r^2 - x^2) dx from 0 to x, for 0 <= x <= r
        sine = np.minimum(x / np.where(r > 0, r, 1.0), 1.0)
        return 0.5 * (x * np.sqrt(np.maximum(r * r - x * x, 0.0)) + r * r * np.arcsin(sine))

    # In the quarter, the disk's height over x is min(b, sqrt(r^2 - x^2)): b up to x0 = sqrt(r^2 - b^2).
    x0 = np.minimum(np.sqrt(np.maximum(r * r - b * b, 0.0)), a)
    x1 = np.minimum(r, a)
    quarter = b * x0 + primitive(x1) - primitive(x0)
    return 4.0 * quarter


@functools.lru_cache(maxsize=64)
def point_nn_means(max_count: int, width: float, height: float) -> np.ndarray:
    """`[max_count + 1]` float64: the expected mean nearest-neighbour distance (px) of n uniform points on
    the `width` x `height` torus at index n (NaN for n < 2)."""
    half_diagonal = math.hypot(width, height) / 2.0
    r = np.linspace(0.0, half_diagonal, POINT_GRID)
    free = 1.0 - torus_disk_area(r, width, height) / (width * height)  # P(a given other point is beyond r)
    log_free = np.log(np.maximum(free, 0.0), where=free > 0, out=np.full_like(free, -np.inf))
    out = np.full(max_count + 1, np.nan)
    # beyond the inscribed radius the disk is clipped: its share of the integral is below this bound
    inscribed = 1.0 - math.pi * (min(width, height) / 2.0) ** 2 / (width * height)
    for n in range(2, max_count + 1):
        if n > POINT_QUADRATURE_MAX:
            closed = 0.5 * math.sqrt(width * height) * math.exp(math.lgamma(n) - math.lgamma(n + 0.5))
            if half_diagonal * inscribed ** (n - 1) < 1e-12 * closed:
                out[n] = closed
                continue
        out[n] = np.trapezoid(np.exp((n - 1) * log_free), r)
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=64)
def hard_disk_nn_means(
    max_count: int, width: float, height: float, diameter: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """`(means, standard_errors)`, each `[max_count + 1]` float64: at index n the expected mean
    nearest-neighbour distance (px) of n non-overlapping disks of `diameter` placed by random sequential
    addition on the `width` x `height` torus, and the standard error of its Monte Carlo estimate
    (NaN for n < 2, from the first count that could not be placed, and above `HARD_DISK_MAX_PREY`)."""
    means = np.full(max_count + 1, np.nan)
    errors = np.full(max_count + 1, np.nan)
    if max_count > HARD_DISK_MAX_PREY:
        placed = hard_disk_nn_means(HARD_DISK_MAX_PREY, width, height, diameter, seed)
        means[: HARD_DISK_MAX_PREY + 1], errors[: HARD_DISK_MAX_PREY + 1] = placed
        means.setflags(write=False)
        errors.setflags(write=False)
        return means, errors
    size = np.array([width, height], np.float64)
    sequences = max(32, -(-HARD_DISK_PREY // max(max_count, 1)))
    rng = np.random.default_rng(seed)
    position = np.zeros((sequences, max_count, 2))
    nearest2 = np.full((sequences, max_count), np.inf)  # squared distance to the nearest placed disk
    d2_min = float(diameter) ** 2
    for m in range(max_count):
        pending = np.arange(sequences)
        for _ in range(HARD_DISK_ROUNDS):
            candidate = rng.uniform(0.0, 1.0, (len(pending), 2)) * size
            offset = position[pending, :m] - candidate[:, None, :]
            offset -= size * np.round(offset / size)
            free = ((offset * offset).sum(axis=-1) >= d2_min).all(axis=1)
            position[pending[free], m] = candidate[free]
            pending = pending[~free]
            if not len(pending):
                break
        if len(pending):
            break  # too crowded: this count and the larger ones stay NaN
        offset = position[:, :m] - position[:, m, None, :]
        offset -= size * np.round(offset / size)
        d2 = (offset * offset).sum(axis=-1)
        np.minimum(nearest2[:, :m], d2, out=nearest2[:, :m])
        if m:
            nearest2[:, m] = d2.min(axis=1)
            per_sequence = np.sqrt(nearest2[:, : m + 1]).mean(axis=1)
            means[m + 1] = per_sequence.mean()
            errors[m + 1] = per_sequence.std(ddof=1) / math.sqrt(sequences)
    means.setflags(write=False)
    errors.setflags(write=False)
    return means, errors
