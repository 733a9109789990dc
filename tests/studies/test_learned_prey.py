"""`benchmarks/learned_prey.py` on the CPU: the 95% interval by hand, and the tiny plan end to end
(trainings, evaluations with the baselines, the record with per-seed values and provenance; a rerun
trains nothing again, and a report keeps result files it finds)."""

from __future__ import annotations

import json
import math
import os
import sys

import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "benchmarks"))
import learned_prey

sys.path.pop(0)


def test_interval_is_the_t_interval():
    # mean 2, sample std 1, t(0.975, 2 df) = 4.302653: half-width 4.302653 / sqrt(3)
    out = learned_prey.interval([1.0, 2.0, 3.0])
    assert out["mean"] == 2.0 and out["n"] == 3
    assert out["ci95"] == pytest.approx(4.302653 / math.sqrt(3), rel=1e-6)
    assert learned_prey.interval([5.0])["ci95"] is None


@pytest.mark.slow
def test_the_tiny_plan_end_to_end(tmp_path):
    out = str(tmp_path / "lp")
    argv = ["--plan", "tiny", "--gpus", "0", "--out", out, "--episodes", "2", "--eval-seeds", "0",
            "--commit", "abc1234"]
    assert learned_prey.main(argv) == 0
    with open(os.path.join(out, "learned_prey_tiny.json"), encoding="utf-8") as f:
        record = json.load(f)
    assert record["commit"] == "abc1234" and "device_name" in record["machine"]
    assert "learned_prey.py" in record["command"]
    rows = {(r["condition"], r["world"]): r for r in record["rows"]}
    assert set(rows) == {("tiny-ego", "A"), ("tiny-world", "B")}
    assert rows[("tiny-ego", "A")]["learned"]["n"] == 2 and len(rows[("tiny-ego", "A")]["learned"]["values"]) == 2
    for row in rows.values():
        assert {"random", "constant", "turnaway"} <= set(row)
    with open(os.path.join(out, "eval", "tiny-ego-A.json"), encoding="utf-8") as f:
        assert json.load(f)["git"]["commit"] == "abc1234"
    # A rerun finds every policy and trains nothing.
    assert learned_prey.main(argv) == 0
    with open(os.path.join(out, "learned_prey_tiny.json"), encoding="utf-8") as f:
        assert json.load(f)["trainings"] == []
    # A report into a folder that already holds a result keeps it.
    results = tmp_path / "results"
    results.mkdir()
    (results / "learned_prey_tiny.json").write_text('{"kept": true}')
    learned_prey.report(out, str(results))
    assert json.loads((results / "learned_prey_tiny.json").read_text()) == {"kept": True}
    assert (results / "curves.csv").exists() and (results / "eval" / "tiny-world-B.json").exists()
