"""The result writers record commit, command, device and versions (issue #29), as
`tests/app/test_results_provenance.py` reads them from the committed files."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import pytest
from test_results_provenance import missing

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def test_study_run_record_records_provenance():
    from aquarium_warp.studies.common import run_record

    @dataclasses.dataclass
    class Settings:
        seeds: int = 1

    record = run_record("flow", Settings(), "cpu", 1.0, 0.0, 1.0, 1, "aquarium-warp study flow --device cpu")
    assert missing(record) == ()
    assert record["command"] == "aquarium-warp study flow --device cpu" and record["git"]["commit"]


def test_swarm_size_study_records_provenance(tmp_path):
    from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_swarm_size_study

    study = SwarmSizeStudy(
        prey=[4], seeds=1, episode_steps=5, metrics_every=5, device="cpu", out=str(tmp_path), figures=False
    )
    summary = run_swarm_size_study(study, progress=False, command="aquarium-warp study swarm-size --prey 4")
    written = json.loads((tmp_path / "swarm_size.json").read_text())
    assert missing(written) == ()
    assert written["command"] == summary["command"] == "aquarium-warp study swarm-size --prey 4"


def test_evaluation_files_record_provenance(tmp_path):
    pytest.importorskip("rsl_rl")
    import aquarium_warp.training as training
    from aquarium_warp import AquariumConfig

    if Path(training.__path__[0]).resolve().parent != Path(__file__).resolve().parents[2]:
        pytest.skip("aquarium_warp.training is installed from another checkout")
    from aquarium_warp.training.evaluate import evaluate_policies, write_results

    result = evaluate_policies(
        ["turnaway"], ["naivchase"], AquariumConfig(max_steps=5), episodes=1, seeds=[0], device="cpu", max_worlds=1
    )
    write_results(result, str(tmp_path))
    assert missing(json.loads((tmp_path / "summary.json").read_text())) == ()


def _script(name: str):
    sys.path.insert(0, str(BENCHMARKS))
    try:
        return __import__(name)
    finally:
        sys.path.remove(str(BENCHMARKS))


def test_bench_multi_gpu_records_provenance(tmp_path, monkeypatch):
    bench = _script("bench_multi_gpu")
    monkeypatch.setattr(
        bench,
        "run_point",
        lambda g, team, mode, args: {
            "gpus": g,
            "team": team,
            "mode": mode,
            "captured": {"rollout": False, "update": {team: False}},
            "agent_steps_per_s": 1.0,
            "wall_seconds": 1.0,
        },
    )
    bench.main(["--device", "cpu", "--gpus", "1", "--teams", "prey", "--out-dir", str(tmp_path)])
    data = json.loads((tmp_path / "multi_gpu_cpu.json").read_text())
    assert missing(data) == ()
    assert data["command"].endswith("--device cpu --gpus 1 --teams prey --out-dir " + str(tmp_path))


def test_bench_training_records_provenance_and_the_floor(tmp_path, monkeypatch, capsys, staged_copy):
    pytest.importorskip("rsl_rl")
    bench = _script("bench_training")
    floor = {"seconds": None, "fraction_of_iteration": None, "fraction_of_update": None}
    rollout = {"seconds": None, "fraction_of_rollout": None}
    point = {
        "rows": 6,
        "iteration_ms": 1.0,
        "agent_steps_per_s": 1.0,
        "floor": floor,
        "floor_text": "floor n/a (...)",
        "rollout_floor": rollout,
        "rollout_floor_text": "floor n/a (rollout)",
    }
    monkeypatch.setattr(
        bench,
        "measure_in_subprocess",
        lambda args, w, sharing, loop, variant: {
            "worlds": w,
            "sharing": sharing,
            "loop": loop,
            "variant": variant,
            **point,
        },
    )
    argv = ["--device", "cpu", "--worlds", "4", "--loops", "fast", "--sharing", "parameter"]
    bench.main([*argv, "--commit", "abc1234", "--out-dir", str(tmp_path)])
    data = json.loads((tmp_path / "training_cpu.json").read_text())
    assert missing(data) == ()
    assert data["git"] == {"commit": "abc1234", "dirty": None, "modified": None, "source": "argument"}
    assert data["points"][0]["floor"] == floor and data["points"][0]["rollout_floor"] == rollout
    out = capsys.readouterr().out
    assert "floor n/a (...)" in out and "floor n/a (rollout)" in out


@pytest.mark.slow
def test_profile_training_records_provenance_and_every_kernel(tmp_path, capsys, staged_copy):
    pytest.importorskip("rsl_rl")
    profile = _script("profile_training")
    argv = ["--device", "cpu", "--worlds", "2", "--variant", "default", "--warmup", "1", "--top", "3"]
    profile.main([*argv, "--commit", "abc1234", "--out-dir", str(tmp_path)])
    data = json.loads((tmp_path / "profile_training_cpu_2.json").read_text())
    assert missing(data) == ()
    assert data["git"] == {"commit": "abc1234", "dirty": None, "modified": None, "source": "argument"}
    assert data["time"] == "self CPU time" and set(data["phase_ms"]) == {"policy", "env", "storage", "update"}
    names = {k["name"] for k in data["kernels"]}
    assert "aten::addmm" in names and all(k["ms"] > 0 and k["launches"] >= 1 for k in data["kernels"])
    assert data["ms"] == pytest.approx(sum(k["ms"] for k in data["kernels"]))
    for bad, named in ((["--worlds", "0"], "--worlds"), (["--warmup", "-1"], "--warmup")):
        with pytest.raises(SystemExit):
            profile.main(["--device", "cpu", *bad, "--out-dir", str(tmp_path / "bad")])
        assert named in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()  # refused before anything is written


class _LimitReached(BaseException):
    """What a time limit does to a benchmark: it ends the script between points (not an error it reports)."""


def _second_point_ends_the_script(point):
    """A point function that returns `point(*args)` for its first call and ends the script at its second."""
    calls = []

    def run(*args):
        calls.append(args)
        if len(calls) == 2:
            raise _LimitReached
        return point(*args)

    return run


def test_bench_multi_gpu_keeps_the_points_measured_before_a_limit(tmp_path, monkeypatch):
    bench = _script("bench_multi_gpu")
    point = {"captured": {"rollout": False, "update": {"prey": False}}, "agent_steps_per_s": 1.0, "wall_seconds": 1.0}
    monkeypatch.setattr(
        bench,
        "run_point",
        _second_point_ends_the_script(lambda g, team, mode, args: {"gpus": g, "team": team, "mode": mode, **point}),
    )
    with pytest.raises(_LimitReached):
        bench.main(["--device", "cpu", "--gpus", "1,2", "--teams", "prey", "--out-dir", str(tmp_path)])
    data = json.loads((tmp_path / "multi_gpu_cpu.json").read_text())
    assert [(p["gpus"], p["agent_steps_per_s"]) for p in data["points"]] == [(1, 1.0)]
    assert data["points"][0]["vs_one_same_mode"]["speedup"] == 1.0
    assert missing(data) == ()


def test_bench_training_keeps_the_points_measured_before_a_limit(tmp_path, monkeypatch):
    pytest.importorskip("rsl_rl")
    bench = _script("bench_training")
    floor = {"seconds": None, "fraction_of_iteration": None, "fraction_of_update": None}
    monkeypatch.setattr(
        bench,
        "measure_in_subprocess",
        _second_point_ends_the_script(
            lambda args, w, sharing, loop, variant: {
                "worlds": w,
                "sharing": sharing,
                "loop": loop,
                "variant": variant,
                "rows": 6 * w,
                "iteration_ms": 1.0,
                "agent_steps_per_s": 2.0,
                "floor": floor,
                "floor_text": "floor n/a (...)",
                "rollout_floor": {"seconds": None, "fraction_of_rollout": None},
                "rollout_floor_text": "floor n/a (rollout)",
            }
        ),
    )
    argv = ["--device", "cpu", "--worlds", "4,8", "--loops", "fast", "--sharing", "parameter"]
    with pytest.raises(_LimitReached):
        bench.main([*argv, "--commit", "abc1234", "--out-dir", str(tmp_path)])
    data = json.loads((tmp_path / "training_cpu.json").read_text())
    assert [(p["worlds"], p["agent_steps_per_s"]) for p in data["points"]] == [(4, 2.0)]
    assert missing(data) == ()


def test_bench_fused_update_keeps_the_points_measured_before_a_limit(tmp_path, monkeypatch, staged_copy):
    pytest.importorskip("rsl_rl")
    pytest.importorskip("triton")  # the fused MLP's kernels
    bench = _script("bench_fused_update")
    monkeypatch.setattr(bench, "build_seconds", lambda preset, worlds, device: {"trainer": 1.0})
    monkeypatch.setattr(
        bench,
        "measure",
        _second_point_ends_the_script(
            lambda preset, w, device, repeats, profile: {"worlds": w, "seconds": {"torch eager": 0.5}}
        ),
    )
    out = tmp_path / "fused.json"
    with pytest.raises(_LimitReached):
        bench.main(["--device", "cpu", "--worlds", "4,8", "--out", str(out), "--commit", "abc123"])
    data = json.loads(out.read_text())
    assert data["build_seconds"] == {"trainer": 1.0}
    assert data["points"] == [{"worlds": 4, "seconds": {"torch eager": 0.5}}]
    assert data["git"]["commit"] == "abc123"


def test_bench_fused_update_compile_only_times_the_build_and_no_point(tmp_path, monkeypatch, capsys):
    pytest.importorskip("rsl_rl")
    pytest.importorskip("triton")  # the fused MLP's kernels
    bench = _script("bench_fused_update")
    monkeypatch.setattr(bench, "build_seconds", lambda preset, worlds, device: {"trainer": 1.0})
    monkeypatch.setattr(bench, "measure", lambda *args: pytest.fail("--compile-only measured a point"))
    out = tmp_path / "fused.json"
    assert bench.main(["--device", "cpu", "--compile-only", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["points"] == []


@pytest.mark.slow
def test_bench_multi_gpu_names_where_a_run_past_its_time_waited():
    """A run past its time: its ranks (the launcher's children) print their stacks on SIGABRT, the whole
    tree is killed, and the error says so with those stacks; a failed run names its output."""
    bench = _script("bench_multi_gpu")
    rank = "import time\ndef waiting_for_peers():\n    time.sleep(600)\nwaiting_for_peers()"
    launcher = f"import subprocess, sys; subprocess.run([sys.executable, '-c', {rank!r}])"
    started = time.perf_counter()
    with pytest.raises(RuntimeError, match=r"(?s)timed out after 2 s; where the ranks waited.*waiting_for_peers"):
        bench.run_ranks([sys.executable, "-c", launcher], dict(os.environ), timeout=2)
    assert time.perf_counter() - started < 30
    with pytest.raises(RuntimeError, match=r"(?s)failed:.*exit seven"):
        bench.run_ranks([sys.executable, "-c", "import sys; sys.exit('exit seven')"], dict(os.environ), timeout=30)


def test_training_run_config_records_provenance(tmp_path):
    """A training run's config.json (the result file of `aquarium-warp train`) records its command,
    commit, machine and versions."""
    from aquarium_warp.training import Trainer, make_config

    changes = {"train": {"num_worlds": 2, "iterations": 1, "quiet": True, "export": []}}
    Trainer(make_config("tiny", changes), log_dir=str(tmp_path)).close()
    written = json.loads((tmp_path / "config.json").read_text())
    assert missing(written) == ()
    assert written["config"]["train"]["num_worlds"] == 2


def _progress(path: Path, captures: list[float]) -> None:
    """A run folder whose progress.csv has one row per iteration (NaN: no episode ended)."""
    path.mkdir(parents=True)
    rows = ["iteration,world_episodes,captures_per_prey,reward_per_agent"]
    rows += [f"{i},{i},{'' if c != c else c},{'' if c != c else -c}" for i, c in enumerate(captures)]
    (path / "progress.csv").write_text("\n".join(rows) + "\n")


def test_compare_curves_hand_made_runs(tmp_path):
    """benchmarks/compare_curves.py on hand-made curves: the final means, the difference and its
    interval, equivalence within the margin and the envelope fraction, as computed by hand."""
    compare_curves = _script("compare_curves")
    nan = float("nan")
    for seed, level in enumerate((4.0, 5.0, 6.0)):  # reference: flat curves at 4, 5, 6 (mean 5)
        _progress(tmp_path / f"ref-s{seed}", [nan] + [level] * 9)
    for seed, level in enumerate((5.0, 5.2, 4.8)):  # close: mean 5, inside [4, 6] everywhere
        _progress(tmp_path / f"close-s{seed}", [nan] + [level] * 9)
    for seed, level in enumerate((9.0, 9.1, 8.9)):  # far: mean 9, outside [4, 6] everywhere
        _progress(tmp_path / f"far-s{seed}", [nan] + [level] * 9)
    out = tmp_path / "cmp.json"
    argv = [
        "--reference",
        f"ref={tmp_path}/ref-s*",
        "--variant",
        f"close={tmp_path}/close-s*",
        f"far={tmp_path}/far-s*",
    ]
    assert (
        compare_curves.main(argv + ["--final-fraction", "0.2", "--margin", "0.2", "--smooth", "1", "--out", str(out)])
        == 0
    )
    data = json.loads(out.read_text())
    assert missing(data) == ()
    ref, close, far = (data["conditions"][k] for k in ("ref", "close", "far"))
    assert ref["final"]["mean"] == pytest.approx(5.0) and ref["final"]["seeds"] == [4.0, 5.0, 6.0]
    assert close["difference"]["difference"] == pytest.approx(0.0, abs=1e-12)
    assert far["difference"]["difference"] == pytest.approx(4.0)
    assert far["difference"]["low"] > 0  # the interval excludes zero
    assert close["equivalence"]["margin"] == pytest.approx(1.0)  # 20% of the reference's mean
    assert far["equivalence"]["equivalent"] is False
    assert close["inside_envelope"] == 1.0 and far["inside_envelope"] == 0.0
    with pytest.raises(SystemExit):
        compare_curves.main(["--reference", f"ref={tmp_path}/none-*", "--variant", f"far={tmp_path}/far-s*"])


def test_fused_default_verdicts_by_hand():
    """benchmarks/fused_default.py's report on hand-made seed values: margins (absolute and relative to
    torch's mean), the Welch difference, the three verdicts and the all-or-nothing decision."""
    fused_default = _script("fused_default")
    torch_seeds = [1.0, 1.02, 0.98, 1.0, 1.0]  # mean 1.0
    rows = []

    def add(setup, path, measure, values):
        rows.extend({"setup": setup, "path": path, "seed": s, "measure": measure, "value": v}
                    for s, v in enumerate(values))  # fmt: skip

    for setup, measure in (("recipe", "prey_vs_naivchase"), ("both", "prey_vs_naivchase"), ("recipe", "curve")):
        add(setup, "torch", measure, torch_seeds)
        add(setup, "fused", measure, [v + 0.01 for v in torch_seeds])  # shifted by 0.01: equivalent
    add("both", "torch", "predator_vs_turnaway", torch_seeds)
    add("both", "fused", "predator_vs_turnaway", [v + 0.5 for v in torch_seeds])  # far beyond 10%: different
    add("both", "torch", "curve", torch_seeds)
    add("both", "fused", "curve", [0.6, 1.6, 0.8, 1.3, 0.95])  # mean 1.05, wide: inconclusive
    out = fused_default.report(argparse.Namespace(seeds=[0, 1, 2, 3, 4]), rows)
    m = out["measures"]
    assert m["E1"]["margin"] == pytest.approx(0.20) and m["E2"]["margin"] == pytest.approx(0.10)
    assert m["E1"]["difference_95"]["difference"] == pytest.approx(0.01)
    assert (m["E1"]["verdict"], m["E2"]["verdict"], m["C1"]["verdict"]) == ("equivalent",) * 3
    assert m["E3"]["verdict"] == "different" and m["E3"]["difference_95"]["low"] > 0.10
    assert m["C2"]["verdict"] == "inconclusive"
    assert out["decision"] == "the default stays torch's float32 path"


def test_fused_default_followup_decisions_by_hand():
    """The follow-up's report (`fused_default_followup.md`) on hand-made seed values: each candidate
    against torch, `fused` pooled with the first check's both-teams rows, and the three decisions."""
    fused_default = _script("fused_default")
    torch_seeds = [1.0, 1.02, 0.98, 1.0, 1.0, 1.01, 0.99, 1.0, 1.0, 1.0]  # mean 1.0
    measures = ("prey_vs_naivchase", "predator_vs_turnaway", "curve")

    def rows_of(shift: dict, seeds=range(5, 15), spread=torch_seeds) -> list[dict]:
        return [{"setup": "both", "path": path, "seed": s, "measure": m, "value": v + shift.get((path, m), 0.0)}
                for path in ("torch", "fused", "fused_fp32") for m in measures
                for s, v in zip(seeds, spread)]  # fmt: skip

    prior = rows_of({}, range(5), torch_seeds[:5]) + [{"setup": "recipe", "path": "fused", "seed": 0,
                                                       "measure": "curve", "value": 9.0}]  # fmt: skip
    args = argparse.Namespace(seeds=list(range(5, 15)))
    out = fused_default.report_followup(args, rows_of({}), prior)
    assert out["decision"] == "the fused path with TF32 products becomes the CUDA default"
    assert out["prior_seeds"] == [0, 1, 2, 3, 4]
    assert out["pooled"]["E3"]["torch"]["n"] == 15 and out["pooled"]["E3"]["margin"] == pytest.approx(0.10)
    # fused's predators far off (as in the first check); fused_fp32 alike torch: the float32 default
    out = fused_default.report_followup(args, rows_of({("fused", "predator_vs_turnaway"): 0.5}), prior)
    assert out["candidates"]["fused"]["E3"]["verdict"] == "different"
    assert out["candidates"]["fused_fp32"]["E3"]["verdict"] == "equivalent"
    assert out["decision"] == "the fused path with float32 products becomes the CUDA default"
    # the new seeds alike, but the first check's fused predators far off: the pooled test refuses TF32
    far_prior = [dict(r, value=r["value"] + (3.0 if (r["path"], r["measure"]) == ("fused", "predator_vs_turnaway")
                                             else 0.0)) for r in prior]  # fmt: skip
    out = fused_default.report_followup(args, rows_of({}), far_prior)
    assert out["candidates"]["fused"]["E3"]["verdict"] == "equivalent"
    assert out["pooled"]["E3"]["verdict"] != "equivalent"
    assert out["decision"] == "the fused path with float32 products becomes the CUDA default"
    out = fused_default.report_followup(args, rows_of({("fused", "curve"): 0.5, ("fused_fp32", "curve"): 0.5}), prior)
    assert out["decision"] == "the default stays torch's float32 path"


def test_grid_ratios_by_hand(tmp_path, capsys):
    """benchmarks/grid_ratios.py on a hand-made grid: per-cell ratios at the pairing's mean (evaluation seeds
    and runs pooled), per field of view and in all; the 0.6x and 1.3x counts; --by-run splits a label by its
    run folder."""
    grid_ratios = _script("grid_ratios")
    cells = [{"prey_count": 6, "prey_view_distance": 100.0, "prey_fov_angle": fov, "predator_max_speed": 5.0}
             for fov in (120.0, 360.0)]  # fmt: skip

    def pairing(prey, predator, runs: dict[str, list[float]], side: str = "prey") -> dict:
        """`runs`: the `side`'s file -> its value per cell (the same at both evaluation seeds)."""
        count = len(next(iter(runs.values())))  # the grid's first cells
        pooled = [sum(v[c] for v in runs.values()) / len(runs) for c in range(count)]
        return {"prey": prey, "predator": predator, "cells": list(range(count)), "stats": [{"mean": m} for m in pooled],
                "runs": [{"prey_spec": prey, "predator_spec": predator, f"{side}_spec": spec,
                          "values": [[v, v] for v in per_cell]} for spec, per_cell in runs.items()]}  # fmt: skip

    def write(side: str, pairings: list[dict]) -> None:
        (tmp_path / f"grid_{side}").mkdir()
        (tmp_path / f"grid_{side}" / "grid.json").write_text(json.dumps({"cells": cells, "pairings": pairings}))

    run = "/o/runs/general-prey-s{}/exported/prey/policy.pt".format
    # 120 deg: TurnAway 2, the runs 3 and 1; 360 deg: TurnAway 2, the runs 0.8 and 1.2
    write("prey", [pairing("turnaway", "naivchase", {"turnaway": [2.0, 2.0]}),
                   pairing("prey-any", "naivchase", {run(0): [3.0, 0.8], run(1): [1.0, 1.2]})])  # fmt: skip
    assert grid_ratios.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    # 120 deg: (3 + 1) / 2 / 2 = 1.0; 360 deg: (0.8 + 1.2) / 2 / 2 = 0.5, at most 0.6x
    assert "prey prey-any vs naivchase, 120 deg: cells   1, mean ratio 1.000, at most 0.6x   0, below 1x   0" in out
    assert "prey prey-any vs naivchase, 360 deg: cells   1, mean ratio 0.500, at most 0.6x   1, below 1x   1" in out
    assert "prey prey-any vs naivchase, all: cells   2, mean ratio 0.750, at most 0.6x   1, below 1x   1" in out
    assert grid_ratios.main([str(tmp_path), "--by-run", "--fov", "360"]) == 0
    out = capsys.readouterr().out
    assert "prey prey-any:general-prey-s0 vs naivchase, 360 deg: cells   1, mean ratio 0.400" in out
    assert "prey prey-any:general-prey-s1 vs naivchase, 360 deg: cells   1, mean ratio 0.600, at most 0.6x   1" in out
    write("predator", [pairing("turnaway", "naivchase", {"naivchase": [2.0]}, "predator"),
                       pairing("turnaway", "predator-any", {"p.pt": [2.6]}, "predator")])  # fmt: skip
    assert grid_ratios.main([str(tmp_path)]) == 0
    assert "predator predator-any vs turnaway: cells   1, mean ratio 1.300, at least 1.3x   1, above 1x   1" in (
        capsys.readouterr().out
    )
    with pytest.raises(SystemExit):
        grid_ratios.main([str(tmp_path / "none")])


def test_fused_default_refuses_a_missing_prior_and_another_plans_folder(tmp_path, capsys):
    """fused_default.py checks its --prior and its seeds and keeps one plan per --out (the plans' files share
    names), before anything trains."""
    fused_default = _script("fused_default")
    out = tmp_path / "out"
    with pytest.raises(SystemExit):
        fused_default.main(["--plan", "followup", "--out", str(out), "--prior", str(tmp_path / "none.csv")])
    assert "--prior" in capsys.readouterr().err and not out.exists()
    with pytest.raises(SystemExit):
        fused_default.main(["--out", str(out), "--seeds", "3"])
    assert "at least 2 distinct training seeds" in capsys.readouterr().err and not out.exists()
    out.mkdir()
    (out / "plan.txt").write_text("first\n")
    with pytest.raises(SystemExit):
        fused_default.main(["--plan", "followup", "--out", str(out), "--steps", "eval"])
    assert "holds the 'first' plan's runs" in capsys.readouterr().err
    assert (out / "plan.txt").read_text() == "first\n"
