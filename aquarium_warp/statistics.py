"""Statistics over seeds, as every study reports them: each measure is first reduced to one value per
seed (a training seed, or a block of worlds), then

- `seed_stats`: the mean over seeds with its std, s.e.m. and the half-width of its 95% Student-t
  interval (`mean_interval`); `interval`: the mean, that half-width, n and the values, as the result
  files write them;
- `difference`: the difference of two conditions' means with its 95% interval (Welch: unequal
  variances, Welch-Satterthwaite degrees of freedom; or `paired`: the t interval of matched differences,
  for two measurements of the same seeds);
- `compare`: `difference` of each measure between two conditions' per-seed rows;
- `equivalence`: the two one-sided tests (TOST) for a "no effect" claim: the conditions are equivalent
  within ±margin when the 90% interval of the difference lies inside (-margin, margin) (each one-sided
  test at 5%).

Seeds whose value is NaN (a measure undefined in that run) are left out. The Student-t quantiles are
computed here (`t_quantile`, from the regularised incomplete beta function), so the package needs no
SciPy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


# ---------------------------------------------------------------------------------------------- Student t
def _beta_continued_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of the regularised incomplete beta function (Lentz's method)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 1000):
        for numerator in (
            m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)),
        ):
            d = 1.0 + numerator * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + numerator / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def _beta_regularized(x: float, a: float, b: float) -> float:
    """I_x(a, b), the regularised incomplete beta function."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _beta_continued_fraction(a, b, x) / a
    return 1.0 - front * _beta_continued_fraction(b, a, 1.0 - x) / b


def t_tail(t: float, df: float) -> float:
    """P(T > t) for Student's t with `df` degrees of freedom (computed as a tail: no cancellation)."""
    tail = 0.5 * _beta_regularized(df / (df + t * t), df / 2.0, 0.5)
    return tail if t >= 0 else 1.0 - tail


def t_quantile(p: float, df: float) -> float:
    """The `p` quantile of Student's t with `df` > 0 degrees of freedom (df need not be an integer)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p={p!r} must be in (0, 1)")
    if not (df > 0 and math.isfinite(df)):
        raise ValueError(f"df={df!r} must be a finite number > 0")
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    tail = 1.0 - p
    low, high = 0.0, 1.0
    while t_tail(high, df) > tail:  # the tail falls as t grows: bracket the quantile
        low, high = high, 2.0 * high
    for _ in range(200):  # bisection to the last bits of a double
        middle = 0.5 * (low + high)
        if middle in (low, high):
            break
        low, high = (middle, high) if t_tail(middle, df) > tail else (low, middle)
    return 0.5 * (low + high)


# ---------------------------------------------------------------------------------------------- one condition
def finite(values) -> np.ndarray:
    """The values that are numbers, as float64 (NaN and None, a NaN written to JSON, left out)."""
    v = np.asarray(values, dtype=np.float64)
    return v[~np.isnan(v)]


def mean_interval(values: Sequence[float] | np.ndarray, confidence: float = 0.95) -> tuple[float, float | None]:
    """The mean of `values` (NaN left out) and the half-width of its Student-t interval at `confidence`
    (None for fewer than two values; the mean is NaN for none)."""
    v = finite(values)
    n = len(v)
    if n == 0:
        return math.nan, None
    mean = float(v.mean())
    if n < 2:
        return mean, None
    return mean, t_quantile(0.5 + confidence / 2.0, n - 1) * float(v.std(ddof=1)) / math.sqrt(n)


def seed_stats(values) -> dict:
    """Mean, std, s.e.m., the half-width of the mean's 95% Student-t interval (`ci95`) and n over seeds
    (NaN seeds left out) and the per-seed values."""
    v = np.asarray(values, dtype=np.float64)
    ok = finite(v)
    n = len(ok)
    mean, ci95 = mean_interval(ok)
    std = float(ok.std(ddof=1)) if n > 1 else (0.0 if n == 1 else math.nan)
    return {
        "mean": mean,
        "std": std,
        "sem": std / math.sqrt(n) if n > 1 else math.nan,
        "ci95": ci95,
        "n": n,
        "seeds": [None if math.isnan(x) else float(x) for x in v],
    }


def interval(values) -> dict:
    """The finite `values` (NaN and None, a NaN written to JSON, left out): their `mean`, the half-width
    of its 95% Student-t interval (`ci95`, None below two values), `n` and the `values`."""
    v = finite(values).tolist()
    mean, ci95 = mean_interval(v)
    return {"mean": mean, "ci95": ci95, "n": len(v), "values": v}


# ---------------------------------------------------------------------------------------------- two conditions
def _welch(a, b) -> tuple[float, float, float, int, int]:
    """The difference of the means of `a` and `b` (NaN left out), its standard error and the
    Welch-Satterthwaite degrees of freedom, and the two counts."""
    x, y = finite(a), finite(b)
    if len(x) < 2 or len(y) < 2:
        raise ValueError(f"a difference needs at least two values per condition (got {len(x)} and {len(y)})")
    va, vb = float(x.var(ddof=1)) / len(x), float(y.var(ddof=1)) / len(y)
    se = math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / (len(x) - 1) + vb**2 / (len(y) - 1)) if se > 0 else math.inf
    return float(x.mean() - y.mean()), se, df, len(x), len(y)


def _paired(a, b) -> tuple[float, float, float, int, int]:
    """The mean of the matched differences `a[i] - b[i]` (pairs with a NaN left out), its standard error
    and n - 1 degrees of freedom, and the number of pairs (twice, as `_welch` gives two counts)."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"a paired difference needs one value of b per value of a (got {len(x)} and {len(y)})")
    d = finite(x - y)
    if len(d) < 2:
        raise ValueError(f"a paired difference needs at least two pairs (got {len(d)})")
    se = float(d.std(ddof=1)) / math.sqrt(len(d))
    return float(d.mean()), se, len(d) - 1.0 if se > 0 else math.inf, len(d), len(d)


def _interval(diff: float, se: float, df: float, confidence: float) -> tuple[float, float]:
    half = t_quantile(0.5 + confidence / 2.0, df) * se if se > 0 else 0.0
    return diff - half, diff + half


def difference(
    a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray, confidence: float = 0.95, paired: bool = False
) -> dict:
    """Mean of `a` minus mean of `b` (per-seed values of two conditions, NaN left out) with its Welch
    interval at `confidence`: `difference`, `low`, `high`, `se`, `df` (None where both conditions are
    constant: the interval is the point), `n_a`, `n_b`. `paired`: `a[i]` and `b[i]` measure the same
    seed, and the interval is the t interval of the differences `a[i] - b[i]` (n_a = n_b = the pairs)."""
    diff, se, df, na, nb = _paired(a, b) if paired else _welch(a, b)
    low, high = _interval(diff, se, df, confidence)
    return {
        "difference": diff,
        "low": low,
        "high": high,
        "confidence": confidence,
        "se": se,
        "df": df if math.isfinite(df) else None,
        "n_a": na,
        "n_b": nb,
    }


def compare(a: Sequence[dict], b: Sequence[dict], measures: Sequence[str], confidence: float = 0.95) -> dict:
    """`difference` of each of `measures` between two conditions' per-seed rows (`a` minus `b`; NaN and
    None values left out), None for a measure with fewer than two values in either."""
    out: dict[str, dict | None] = {}
    for m in measures:
        x, y = (finite(np.asarray([r[m] for r in rows], dtype=np.float64)) for rows in (a, b))
        out[m] = difference(x, y, confidence) if len(x) >= 2 and len(y) >= 2 else None
    return out


def equivalence(
    a: Sequence[float], b: Sequence[float], margin: float, alpha: float = 0.05, paired: bool = False
) -> dict:
    """TOST of "`a` and `b` differ by less than `margin`": `equivalent` when the (1 - 2 alpha) Welch
    interval of the difference (`low`, `high`: 90% at the default alpha; `paired`: of the matched
    differences, as in `difference`) lies inside (-margin, margin), i.e. both one-sided tests reject at
    `alpha`; `p` is the larger of their p-values."""
    if not (margin > 0 and math.isfinite(margin)):
        raise ValueError(f"margin={margin!r} must be a finite number > 0")
    if not 0.0 < alpha < 0.5:
        raise ValueError(f"alpha={alpha!r} must be in (0, 0.5)")
    diff, se, df, na, nb = _paired(a, b) if paired else _welch(a, b)
    low, high = _interval(diff, se, df, 1.0 - 2.0 * alpha)
    if se > 0:
        p = max(t_tail((diff + margin) / se, df), t_tail((margin - diff) / se, df))
    else:
        p = 0.0 if abs(diff) < margin else 1.0
    return {
        "difference": diff,
        "low": low,
        "high": high,
        "confidence": 1.0 - 2.0 * alpha,
        "margin": margin,
        "equivalent": bool(-margin < low and high < margin),
        "p": p,
        "n_a": na,
        "n_b": nb,
    }


def interval_verdict(difference_interval: dict, margin: float) -> str:
    """The reading of a difference's interval (`difference`'s `low` and `high`) against an equivalence
    `margin`: "equivalent" when it lies inside (-margin, margin), "different" when it excludes 0 (and does
    not lie inside), else "inconclusive"."""
    low, high = difference_interval["low"], difference_interval["high"]
    if -margin < low and high < margin:
        return "equivalent"
    if low > 0 or high < 0:
        return "different"
    return "inconclusive"
