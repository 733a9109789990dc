"""Statistics over seeds (`aquarium_warp.statistics`) against values computed by hand: Student-t
quantiles from the printed tables, the mean's 95% interval, Welch's interval of a difference and the
TOST equivalence test; the flow study's differences against still water."""

from __future__ import annotations

import csv
import json
import math

import pytest

from aquarium_warp.cli import main
from aquarium_warp.statistics import (
    compare,
    difference,
    equivalence,
    interval,
    mean_interval,
    seed_stats,
    t_quantile,
)


@pytest.mark.parametrize(
    "p, df, expected",
    [
        (0.975, 1, 12.706205),
        (0.975, 2, 4.302653),
        (0.975, 4, 2.776445),
        (0.975, 30, 2.042272),
        (0.95, 10, 1.812461),
        (0.995, 5, 4.032143),
        (0.025, 4, -2.776445),
        (0.5, 3, 0.0),
        (0.975, 1e5, 1.959988),
    ],
)
def test_t_quantiles_match_the_tables(p, df, expected):
    assert t_quantile(p, df) == pytest.approx(expected, abs=1e-6)


def test_t_quantile_refuses_what_has_none():
    for p, df in ((0.0, 3), (1.0, 3), (0.5, 0), (0.5, math.inf)):
        with pytest.raises(ValueError):
            t_quantile(p, df)


def test_seed_stats_mean_and_its_interval():
    # mean 2, sample std 1, t(0.975, 2 df) = 4.302653: half-width 4.302653 / sqrt(3); NaN seeds left out
    stats = seed_stats([1.0, 2.0, 3.0, math.nan])
    assert stats["mean"] == 2.0 and stats["std"] == 1.0 and stats["n"] == 3
    assert stats["sem"] == pytest.approx(1 / math.sqrt(3))
    assert stats["ci95"] == pytest.approx(4.302653 / math.sqrt(3), rel=1e-6)
    assert stats["seeds"] == [1.0, 2.0, 3.0, None]
    one = seed_stats([5.0])
    assert one["mean"] == 5.0 and one["std"] == 0.0 and math.isnan(one["sem"]) and one["ci95"] is None
    assert math.isnan(mean_interval([])[0])


def test_interval_is_the_t_interval():
    # mean 2, sample std 1, t(0.975, 2 df) = 4.302653: half-width 4.302653 / sqrt(3)
    out = interval([1.0, 2.0, 3.0])
    assert out["mean"] == 2.0 and out["n"] == 3
    assert out["ci95"] == pytest.approx(4.302653 / math.sqrt(3), rel=1e-6)
    assert interval([5.0])["ci95"] is None


def test_welch_difference_by_hand():
    # a = 1, 2, 3 (mean 2, var 1); b = 4..7 (mean 5.5, var 5/3): se^2 = 1/3 + 5/12 = 3/4,
    # df = (3/4)^2 / ((1/3)^2 / 2 + (5/12)^2 / 3) = 243/49, t(0.975, 243/49) = 2.576958
    d = difference([1.0, 2.0, 3.0], [4.0, 5.0, 6.0, 7.0])
    assert d["difference"] == -3.5 and d["se"] == pytest.approx(math.sqrt(0.75))
    assert d["df"] == pytest.approx(243 / 49)
    half = 2.576958 * math.sqrt(0.75)
    assert d["low"] == pytest.approx(-3.5 - half, abs=1e-6) and d["high"] == pytest.approx(-3.5 + half, abs=1e-6)
    assert (d["n_a"], d["n_b"]) == (3, 4)
    # Two constant conditions: the interval is the point.
    assert difference([1.0, 1.0], [3.0, 3.0, 3.0]) == pytest.approx(
        {"difference": -2.0, "low": -2.0, "high": -2.0, "confidence": 0.95, "se": 0.0, "df": None, "n_a": 2, "n_b": 3}
    )
    with pytest.raises(ValueError, match="at least two values"):
        difference([1.0], [2.0, 3.0])


def test_paired_difference_by_hand():
    # matched differences 0.5, 1, 0.5, 1: mean 0.75, sample var 1/12, se = sqrt(1/12 / 4) = sqrt(1/48),
    # df = 3, t(0.975, 3) = 3.182446; the fifth pair has a NaN and is left out
    a, b = [1.0, 2.0, 3.0, 4.0, math.nan], [0.5, 1.0, 2.5, 3.0, 7.0]
    d = difference(a, b, paired=True)
    assert d["difference"] == pytest.approx(0.75) and d["se"] == pytest.approx(math.sqrt(1 / 48))
    assert d["df"] == 3.0 and (d["n_a"], d["n_b"]) == (4, 4)
    half = 3.182446 * math.sqrt(1 / 48)
    assert d["low"] == pytest.approx(0.75 - half, abs=1e-6) and d["high"] == pytest.approx(0.75 + half, abs=1e-6)
    # Welch on the same values ignores the pairing: a wider interval
    welch = difference(a, b)
    assert welch["high"] - welch["low"] > d["high"] - d["low"]
    # TOST on the pairs: t(0.95, 3) = 2.353363, 90% interval 0.75 ± 0.339679 = [0.410321, 1.089679]
    e = equivalence(a, b, margin=1.2, paired=True)
    assert e["high"] == pytest.approx(0.75 + 2.353363 * math.sqrt(1 / 48), abs=1e-6) and e["equivalent"] is True
    assert equivalence(a, b, margin=1.0, paired=True)["equivalent"] is False
    with pytest.raises(ValueError, match="one value of b per value of a"):
        difference([1.0, 2.0, 3.0], [1.0, 2.0], paired=True)
    with pytest.raises(ValueError, match="at least two pairs"):
        difference([1.0, math.nan], [2.0, 3.0], paired=True)


def test_equivalence_is_the_90_percent_interval_inside_the_margin():
    # a: mean 1, var 0.025; b: mean 1, var 0.00625; n = 5 each: se^2 = 0.005 + 0.00125 = 0.00625,
    # df = 0.00625^2 / ((0.005^2 + 0.00125^2) / 4) = 100/17, t(0.95, 100/17) = 1.950163: 90% interval ±0.154173
    a, b = [1.0, 1.2, 0.8, 1.1, 0.9], [1.05, 0.95, 1.0, 1.1, 0.9]
    e = equivalence(a, b, margin=0.3)
    assert e["difference"] == pytest.approx(0.0, abs=1e-12) and e["confidence"] == pytest.approx(0.9)
    assert e["high"] == pytest.approx(1.950163 * math.sqrt(0.00625), abs=1e-6) and e["low"] == pytest.approx(-e["high"])
    # p: the larger one-sided p-value, P(T > 0.3 / se) with 100/17 df
    assert e["equivalent"] is True and e["p"] == pytest.approx(0.0046824, abs=1e-6)
    narrow = equivalence(a, b, margin=0.15)  # the interval reaches past ±0.15
    assert narrow["equivalent"] is False and narrow["p"] > 0.05
    for margin in (0.0, -1.0, math.inf):
        with pytest.raises(ValueError, match="margin"):
            equivalence(a, b, margin)


def test_compare_takes_the_difference_of_each_measure():
    a = [{"x": 1.0, "y": 1.0}, {"x": 2.0, "y": math.nan}, {"x": 3.0, "y": None}]
    b = [{"x": 4.0, "y": 0.0}, {"x": 5.0, "y": 1.0}, {"x": 6.0, "y": 2.0}, {"x": 7.0, "y": 3.0}]
    out = compare(a, b, ("x", "y"))
    assert out["x"] == difference([1.0, 2.0, 3.0], [4.0, 5.0, 6.0, 7.0])
    assert out["y"] is None  # one value of y in a: no interval


def test_the_flow_study_reports_each_current_against_still_water(tmp_path, one_thread):
    out = tmp_path / "flow"
    assert (
        main(
            [
                "study",
                "flow",
                "--kinds",
                "uniform",
                "--strengths",
                "0,2",
                "--seeds",
                "3",
                "--episodes-per-seed",
                "1",
                "--episode-steps",
                "40",
                "--prey",
                "8",
                "--device",
                "cpu",
                "--no-figures",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rows = list(csv.DictReader((out / "flow.csv").open(encoding="utf-8", newline="")))
    effects = json.loads((out / "flow.json").read_text())["current_effects"]
    assert [(e["kind"], e["strength"]) for e in effects] == [("uniform", 2.0)]
    captures = {s: [float(r["captures_per_prey"]) for r in rows if r["strength"] == s] for s in ("0", "2")}
    expected = difference(captures["2"], captures["0"])  # from the CSV's 6 significant digits
    got = effects[0]["differences"]["captures_per_prey"]
    assert got["difference"] == pytest.approx(expected["difference"], rel=1e-4, abs=1e-6)
    assert (got["n_a"], got["n_b"]) == (3, 3)


def test_interval_verdict_by_hand():
    """Inside (-margin, margin): equivalent; excluding 0 otherwise: different; else inconclusive (the
    boundaries belong to the next reading)."""
    from aquarium_warp.statistics import interval_verdict

    assert interval_verdict({"low": -0.19, "high": 0.19}, 0.2) == "equivalent"
    assert interval_verdict({"low": 0.01, "high": 0.15}, 0.2) == "equivalent"  # inside wins over excluding 0
    assert interval_verdict({"low": 0.15, "high": 0.79}, 0.37) == "different"
    assert interval_verdict({"low": -0.5, "high": -0.01}, 0.2) == "different"
    assert interval_verdict({"low": -0.2, "high": 0.1}, 0.2) == "inconclusive"  # touches the margin
    assert interval_verdict({"low": -0.25, "high": 0.3}, 0.2) == "inconclusive"
