"""`aquarium-warp study coevolution` (`benchmarks/coevolution.py`) on the CPU: the generations' iterations by hand (and
the committed run's uneven choice they replace), training in stretches equals one run, the aggregation over training
seeds and the declared comparisons against values computed by hand, the option checks, a rerun that runs nothing
(and more seeds that run only the new one), and a two-seed run end to end."""

from __future__ import annotations

import csv
import json
import math
import os

import numpy as np
import pytest

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
pytest.importorskip("rsl_rl")
from aquarium_warp.studies import coevolution

T2 = 4.302653  # t(0.975) with 2 degrees of freedom: three seeds


@pytest.mark.parametrize(
    "iterations, generations, expected",
    [
        (212, 6, [35, 71, 106, 141, 177, 212]),  # the committed H200 run's size: 35.33, 70.67, 106, ...
        (40, 3, [13, 27, 40]),  # --tiny's: 13.33, 26.67, 40
        (10, 4, [3, 5, 8, 10]),  # 2.5 and 7.5 round up
        (7, 2, [4, 7]),  # 3.5 rounds up
        (5, 5, [1, 2, 3, 4, 5]),
    ],
)
def test_generation_iterations_by_hand(iterations, generations, expected):
    assert coevolution.generation_iterations(iterations, generations) == expected


def test_the_committed_runs_uneven_generations_are_gone():
    # The committed run saved every 212 // 6 = 35 iterations and at the end (model_0, 35, ..., 210, 211)
    # and took indices round(linspace(0, 7, 6)) = 0, 1, 3, 4, 6, 7 of those 8: the policies after 1, 36,
    # 106, 141, 211 and 212 iterations, a near-untrained first one and two one iteration apart.
    old = [1, 36, 106, 141, 211, 212]
    assert np.diff([0] + old).tolist() == [1, 35, 70, 35, 70, 1]
    new = coevolution.generation_iterations(212, 6)
    assert np.diff([0] + new).tolist() == [35, 36, 35, 35, 36, 35]
    assert coevolution.checkpoint_after("run", 35) == os.path.join("run", "model_34.pt")


def test_generations_out_of_range_are_refused():
    with pytest.raises(ValueError, match=r"--generations=7 must be in \[2, 6\]"):
        coevolution.generation_iterations(6, 7)
    with pytest.raises(ValueError, match="generations=1"):
        coevolution.generation_iterations(6, 1)


@pytest.mark.parametrize(
    "options, match",
    [
        (["--seeds", "0"], "--seeds"),
        (["--seeds", "0", "0"], "--seeds"),
        (["--seeds", "0", "-1"], "--seeds"),
        (["--eval-seeds", "1000003"], "--eval-seeds"),
        (["--generations", "41"], "--generations"),
        (["--jobs", "0"], r"--jobs=0 must be an integer >= 1"),
    ],
)
def test_bad_options_are_refused(tmp_path, options, match):
    with pytest.raises(ValueError, match=match):
        coevolution.main(["--tiny", "--out-dir", str(tmp_path), *options])
    assert not os.listdir(tmp_path)


@pytest.mark.slow
def test_training_in_stretches_equals_one_run(tmp_path):
    """The generations are checkpoints of one run: training to 2, 5 and 7 iterations in turn gives the
    parameters of 7 iterations at once, and the checkpoints after 2 and 5 iterations."""
    import torch

    from aquarium_warp.training import Trainer, make_config

    config = make_config(
        "tiny",
        {
            "train": {
                "team": "both",
                "num_worlds": 4,
                "iterations": 7,
                "quiet": True,
                "export": [],
                "pool_every": 2,
                "pool_size": 2,
                "pool_fraction": 0.3,
            },
            "env": {"max_steps": 20, "predator_count": 2},
            "runner": {"num_steps_per_env": 8, "save_interval": 8},
        },
    )
    whole = Trainer(config, str(tmp_path / "whole"))
    whole.train()
    stretches = Trainer(config, str(tmp_path / "stretches"))
    coevolution.train_generations(stretches, [2, 5, 7])
    for team in ("prey", "predator"):
        a, b = whole.learners[team].alg.save(), stretches.learners[team].alg.save()
        for part in ("actor_state_dict", "critic_state_dict"):
            assert all(torch.equal(a[part][k], b[part][k]) for k in a[part])
    for n in (2, 5, 7):
        saved = torch.load(coevolution.checkpoint_after(str(tmp_path / "stretches"), n), weights_only=False)
        assert saved["iter"] == n
    whole.close()
    stretches.close()


# ---- aggregation over training seeds, by hand ---------------------------------------------------------
ROWS = ["random", "turnaway", "gen1", "gen2"]
COLS = ["gen1", "gen2", "random", "naivchase"]
# Seed s (0, 1, 2) has captures BASE + s x DELTA: per cell the mean is BASE + DELTA, the sample std |DELTA|.
BASE = np.array([[3.0, 3.2, 2.0, 2.5], [2.2, 2.4, 1.9, 1.6], [1.0, 2.1, 1.5, 1.8], [1.1, 1.3, 1.4, 1.7]])
DELTA = np.array([[0.1, 0.0, 0.2, 0.1], [0.3, -0.1, 0.1, 0.0], [0.2, 0.1, 0.0, 0.3], [0.1, 0.4, 0.0, -0.2]])


def seed_result(seed: int, k: int) -> dict:
    """A hand-made per-seed result: seed `seed`'s value of `k` (0, 1, 2) in the BASE + k DELTA pattern."""
    captures = (BASE + k * DELTA).tolist()
    return {
        "seed": seed,
        "prey": ROWS,
        "predator": COLS,
        "matrices": {"captures_per_prey": captures, "prey_survival": (1 - BASE / 10).tolist()},
        "curves": {"prey/Episode/captures_per_prey": [[0, 1.0 + k], [1, None if k == 2 else 2.0]]},
    }


def test_aggregate_gives_each_cells_mean_and_interval():
    aggregated = coevolution.aggregate([seed_result(s, k) for k, s in enumerate((4, 7, 9))])
    assert aggregated["seeds"] == [4, 7, 9] and aggregated["prey"] == ROWS and aggregated["predator"] == COLS
    m = aggregated["matrices"]["captures_per_prey"]
    # turnaway prey vs gen1 predators: 2.2, 2.5, 2.8 -> mean 2.5, std 0.3, half-width 4.302653 x 0.3 / sqrt(3)
    assert [s[1][0] for s in m["seeds"]] == pytest.approx([2.2, 2.5, 2.8])
    assert m["mean"][1][0] == pytest.approx(2.5) and m["ci95"][1][0] == pytest.approx(T2 * 0.3 / math.sqrt(3))
    assert np.allclose(m["mean"], BASE + DELTA)
    assert np.allclose(m["ci95"], T2 * np.abs(DELTA) / math.sqrt(3))
    assert np.allclose(aggregated["matrices"]["prey_survival"]["ci95"], 0.0)  # the same every seed
    # Training curves: iteration 0 logged 1, 2, 3; iteration 1 logged 2, 2 and nothing (NaN left out).
    curve = coevolution.aggregate_curves([seed_result(s, k) for k, s in enumerate((4, 7, 9))])
    tag = "prey/Episode/captures_per_prey"
    assert curve[tag][0] == pytest.approx((2.0, T2 / math.sqrt(3), 3))
    assert curve[tag][1][0] == 2.0 and curve[tag][1][2] == 2


def test_declared_comparisons_of_two_generations():
    declared = coevolution.declared_comparisons(2)
    assert len(declared) == 8 * 2 - 4
    as_tuples = [(c["family"], c["team"], tuple(c["a"]), tuple(c["b"])) for c in declared]
    assert as_tuples == [
        ("predator-vs-baseline", "predator", ("turnaway", "gen1"), ("turnaway", "random")),
        ("predator-vs-baseline", "predator", ("turnaway", "gen1"), ("turnaway", "naivchase")),
        ("predator-vs-baseline", "predator", ("turnaway", "gen2"), ("turnaway", "random")),
        ("predator-vs-baseline", "predator", ("turnaway", "gen2"), ("turnaway", "naivchase")),
        ("prey-vs-baseline", "prey", ("turnaway", "naivchase"), ("gen1", "naivchase")),
        ("prey-vs-baseline", "prey", ("random", "naivchase"), ("gen1", "naivchase")),
        ("prey-vs-baseline", "prey", ("turnaway", "naivchase"), ("gen2", "naivchase")),
        ("prey-vs-baseline", "prey", ("random", "naivchase"), ("gen2", "naivchase")),
        ("latest-vs-earlier", "predator", ("gen2", "gen2"), ("gen2", "gen1")),
        ("latest-vs-earlier", "prey", ("gen1", "gen2"), ("gen2", "gen2")),
        ("consecutive", "predator", ("gen1", "gen2"), ("gen1", "gen1")),
        ("consecutive", "prey", ("gen1", "gen1"), ("gen2", "gen1")),
    ]
    assert len(coevolution.declared_comparisons(6)) == 44


def test_comparisons_are_paired_intervals_over_seeds():
    aggregated = coevolution.aggregate([seed_result(s, k) for k, s in enumerate((0, 1, 2))])
    out = {
        (c["family"], c["team"], tuple(c["a"]), tuple(c["b"])): c
        for c in coevolution.compare_cells(aggregated, coevolution.declared_comparisons(2))
    }
    # gen1 predators - random predators, vs TurnAway prey: (2.2 + 0.3 s) - (1.9 + 0.1 s) = 0.3 + 0.2 s
    # -> differences 0.3, 0.5, 0.7: mean 0.5, std 0.2.
    c = out[("predator-vs-baseline", "predator", ("turnaway", "gen1"), ("turnaway", "random"))]
    assert c["differences"] == pytest.approx([0.3, 0.5, 0.7]) and c["a_seeds"] == pytest.approx([2.2, 2.5, 2.8])
    assert c["difference"] == pytest.approx(0.5) and c["n_a"] == 3 and c["df"] == 2
    assert c["low"] == pytest.approx(0.5 - T2 * 0.2 / math.sqrt(3), abs=1e-6)
    assert c["high"] == pytest.approx(0.5 + T2 * 0.2 / math.sqrt(3), abs=1e-6)
    # The arms race: gen2 vs gen2 (1.3 + 0.4 s) against gen2 prey vs gen1 predators (1.1 + 0.1 s):
    # 0.2 + 0.3 s -> 0.2, 0.5, 0.8.
    c = out[("latest-vs-earlier", "predator", ("gen2", "gen2"), ("gen2", "gen1"))]
    assert c["difference"] == pytest.approx(0.5) and c["high"] - c["low"] == pytest.approx(2 * T2 * 0.3 / math.sqrt(3))
    # The new prey against the previous predators: gen1 vs gen1 (1.0 + 0.2 s) - gen2 vs gen1 (1.1 + 0.1 s)
    # = -0.1 + 0.1 s -> -0.1, 0, 0.1.
    c = out[("consecutive", "prey", ("gen1", "gen1"), ("gen2", "gen1"))]
    assert c["difference"] == pytest.approx(0.0, abs=1e-12)
    assert c["high"] == pytest.approx(T2 * 0.1 / math.sqrt(3))


# ---- kept tasks -----------------------------------------------------------------------------------------
def fake_speed(task, device, argv):
    return {
        "points": [
            {"path": p, "agent_steps_per_s": s, "learning_rows_per_s": s / 2}
            for p, s in (("one", 4.0), ("both", 3.0), ("pool", 2.0))
        ],
        "machine": {"device_name": "stand-in"},
    }


def fake_seed(calls):
    """A stand-in for `run_seed` that records the seeds it runs and returns hand-made values."""

    def run_seed(task, device, keep_checkpoints=False):
        calls.append(task["seed"])
        gens = [f"gen{k}" for k in range(1, len(task["generation_iterations"]) + 1)]
        rows, cols = ["random", "turnaway", *gens], [*gens, "random", "naivchase"]
        captures = (np.arange(len(rows) * len(cols)).reshape(len(rows), len(cols)) / 10 + task["seed"]).tolist()
        return {
            "seed": task["seed"],
            "device": device,
            "machine": {},
            "eval_seeds": task["eval_seeds"],
            "agent_steps": 1,
            "train_seconds": 1.0,
            "train_agent_steps_per_s": 1.0,
            "cross_play_seconds": 1.0,
            "prey": rows,
            "predator": cols,
            "matrices": {"captures_per_prey": captures},
            "curves": {"Swarm/groups": [[0, 5.0 + task["seed"]]]},
            "swarm_first_last": {name: [1.0, 2.0 + task["seed"]] for name in coevolution.SWARM},
        }

    return run_seed


def test_a_rerun_runs_nothing_and_more_seeds_run_only_the_new(tmp_path, monkeypatch):
    calls: list[int] = []
    monkeypatch.setattr(coevolution, "run_seed", fake_seed(calls))
    monkeypatch.setattr(coevolution, "measure_speeds", fake_speed)
    argv = ["--tiny", "--out-dir", str(tmp_path), "--seeds", "0", "1", "--no-figures"]
    assert coevolution.main(argv) == 0 and calls == [0, 1]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["tasks"] == {"kept": 0, "run": 3}
    assert summary["settings"]["generation_iterations"] == [13, 27, 40]
    # training seed s plays the evaluation seeds 1_000_003 (s + 1) + 0 and + 1
    assert [s["eval_seeds"] for s in summary["per_seed"]] == [[1_000_003, 1_000_004], [2_000_006, 2_000_007]]
    m = summary["cross_play"]["matrices"]["captures_per_prey"]
    # seeds 0 and 1: values v and v + 1 -> mean v + 0.5, half-width t(0.975, 1) x sqrt(0.5) / sqrt(2)
    assert m["mean"][0][0] == pytest.approx(0.5) and m["ci95"][0][0] == pytest.approx(12.706205 * 0.5, rel=1e-6)
    assert summary["swarm_last"]["groups"]["mean"] == pytest.approx(2.5)
    with open(tmp_path / "comparisons.csv", newline="", encoding="utf-8") as f:
        assert len(list(csv.DictReader(f))) == 8 * 3 - 4

    assert coevolution.main(argv) == 0 and calls == [0, 1]  # the rerun runs nothing
    again = json.loads((tmp_path / "summary.json").read_text())
    assert again["tasks"] == {"kept": 3, "run": 0} and again["cross_play"] == summary["cross_play"]

    assert coevolution.main([*argv, "--seeds", "0", "1", "2"]) == 0 and calls == [0, 1, 2]  # the new seed alone
    assert json.loads((tmp_path / "summary.json").read_text())["cross_play"]["seeds"] == [0, 1, 2]


@pytest.mark.slow
def test_two_seeds_end_to_end_and_a_rerun_that_trains_nothing(tmp_path, monkeypatch):
    """Two tiny seeds trained, evaluated and aggregated (the speed step stood in for: its three
    processes take as long as the rest); the kept generations are the runner's checkpoints."""
    monkeypatch.setattr(coevolution, "measure_speeds", fake_speed)
    out = tmp_path / "coevo"
    argv = [
        "--tiny",
        "--out-dir",
        str(out),
        "--seeds",
        "0",
        "1",
        "--worlds",
        "4",
        "--agent-steps",
        "1920",
        "--steps",
        "8",
        "--max-steps",
        "20",
        "--eval-episodes",
        "1",
        "--eval-seeds",
        "0",
        "--keep-checkpoints",
    ]
    assert coevolution.main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["iterations"] == 6 and summary["settings"]["generation_iterations"] == [2, 4, 6]
    # the checkpoints after 2, 4 and 6 iterations; model_0.pt, which every run saves, is not a generation
    assert sorted(f for f in os.listdir(out / "seed0" / "run") if f.endswith(".pt")) == [
        "model_1.pt",
        "model_3.pt",
        "model_5.pt",
    ]
    rows, cols = summary["cross_play"]["prey"], summary["cross_play"]["predator"]
    assert rows == ["random", "turnaway", "gen1", "gen2", "gen3"]
    assert cols == ["gen1", "gen2", "gen3", "random", "naivchase"]
    for k, seed in enumerate((0, 1)):  # the per-seed values are the seeds' own cross-play means
        own = json.loads((out / f"seed{seed}" / "cross_play.json").read_text())
        assert (
            summary["cross_play"]["matrices"]["captures_per_prey"]["seeds"][k]
            == own["matrices"]["captures_per_prey"]["mean"]
        )
        assert own["protocol"]["seeds"] == [1_000_003 * (seed + 1)]
    assert len(summary["comparisons"]) == 20 and (out / "seed1" / "episode.gif").exists()
    assert (out / "cross_play_generations.png").exists() and (out / "training_curves.png").exists()

    def no_training(task, device, keep_checkpoints=False):
        raise AssertionError(f"seed {task['seed']} ran again")

    monkeypatch.setattr(coevolution, "run_seed", no_training)
    assert coevolution.main(argv) == 0
    again = json.loads((out / "summary.json").read_text())
    assert again["tasks"] == {"kept": 3, "run": 0} and again["cross_play"] == summary["cross_play"]


def test_a_signal_during_a_stretch_leaves_the_seed_unfinished():
    """A SIGTERM ends a stretch early: the seed must stop there, not take one-iteration stretches for the
    later generations (and cross-play checkpoints that were never written)."""
    import signal
    from types import SimpleNamespace

    class Stretches:
        def __init__(self):
            self.iteration, self.calls = 0, []
            self.stop = SimpleNamespace(signum=None)

        def train(self, n):
            self.calls.append(n)
            if len(self.calls) == 2:  # the signal arrives three iterations into the second stretch
                self.iteration += 3
                self.stop.signum = signal.SIGTERM
            else:
                self.iteration += n

    trainer = Stretches()
    with pytest.raises(RuntimeError, match="stopped by signal .* at iteration 5, before generation 2 "):
        coevolution.train_generations(trainer, [2, 5, 7])
    assert trainer.calls == [2, 3]
