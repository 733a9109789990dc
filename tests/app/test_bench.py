"""The scaling benchmark suite's plumbing (`aquarium_warp.bench`), on the CPU with tiny sweeps."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from aquarium_warp import AquariumConfig, bench
from aquarium_warp.bench import BenchSettings, parse_counts, run_bench, step_byte_model

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def tiny(tmp_path, **changes) -> BenchSettings:
    settings = dict(
        device="cpu",
        agents=[16, 64],
        worlds=[1, 2],
        seconds=0.02,
        repeats=2,
        warmup_steps=2,
        stage_repeats=3,
        original=False,
        vmas=False,
        out_dir=str(tmp_path),
        quiet=True,
        copy_bytes=8 << 20,
    )
    settings.update(changes)
    return BenchSettings(**settings)


def test_parse_counts():
    assert parse_counts("16,64,...,1000000") == [16, 64, 256, 1024, 4096, 16384, 65536, 262144, 1000000]
    assert parse_counts("1,16,...,65536") == [1, 16, 256, 4096, 65536]
    assert parse_counts("16,64,...,100000")[-2:] == [65536, 100000]
    assert parse_counts("100,200,...,500") == [100, 200, 400, 500]  # geometric: a constant ratio
    assert parse_counts("100,200,300,...,500") == [100, 200, 300, 400, 500]
    assert parse_counts("17") == [17]
    assert parse_counts([3, 5]) == [3, 5]
    for bad in ("", "a,b", "1,...,9", "0,4", "16,8,...,2"):
        with pytest.raises(ValueError):
            parse_counts(bad)


def test_byte_model_counts_every_stage():
    cfg = AquariumConfig()
    gpu = step_byte_model(cfg, cuda=True)
    cpu = step_byte_model(cfg, cuda=False)
    for model in (gpu, cpu):
        # The model counts what each of docs/model.md's stages must move, whichever launches run them.
        assert set(model["stages"]) == set(bench.STAGES) - {"fused"}
        assert model["read"] == pytest.approx(sum(s["read"] for s in model["stages"].values()))
        assert model["write"] == pytest.approx(sum(s["write"] for s in model["stages"].values()))
        assert model["total"] == pytest.approx(model["read"] + model["write"])
        assert all(s["read"] >= 0 and s["write"] >= 0 for s in model["stages"].values())
        # Observation rows must be written: 29 float32 per agent in the default config, plus masks.
        assert model["stages"]["observations"]["write"] >= 4 * 29
        # Motion writes the state's four vec2 fields and clears the step's reward and three flags
        # per slot and the capture count per world.
        assert model["stages"]["motion"]["write"] == pytest.approx(4 * 8 + 4 + 3 + 4 / cfg.capacity)
    assert gpu["stages"]["observations"] == cpu["stages"]["observations"]
    # A default world is one cell: its whole-world lists need no build on either device.
    assert gpu["grid_path"] == cpu["grid_path"] == "whole-world lists (no build)"
    assert gpu["stages"]["grid"] == cpu["stages"]["grid"] == {"read": 0, "write": 0}
    # Small worlds of several cells are ranked per slot on a GPU; large ones count the agents of each
    # cell, which moves more than ranking.
    ranked = step_byte_model(cfg, (3, 3), cuda=True)
    assert ranked["grid_path"] == "rank per slot (CUDA)"
    assert step_byte_model(cfg, (3, 3), cuda=False)["grid_path"] == "counting sort (CPU)"
    assert ranked["stages"]["grid"]["write"] > 0
    # Observers read their own fields from the state by slot, whatever the lists.
    assert ranked["stages"]["observations"] == gpu["stages"]["observations"]
    large = bench.density_config(10_000)
    counted = step_byte_model(large, cuda=True)
    assert counted["grid_path"] == "cell counts + prefix sum (CUDA)"
    assert counted["stages"]["grid"]["read"] > ranked["stages"]["grid"]["read"]
    # More grid cells per agent clear more cell ranges; reproduction reads the prey's ages.
    assert step_byte_model(cfg, (20, 20))["total"] > step_byte_model(cfg, (5, 5))["total"]
    assert (
        step_byte_model(AquariumConfig(prey_reproduction=True, max_prey=32))["stages"]["population"]["read"]
        > gpu["stages"]["population"]["read"]
    )
    # A one-world config at the default density models the same order of bytes as the default world.
    assert 0.5 < counted["total"] / gpu["total"] < 2.0


@pytest.mark.slow
def test_tiny_sweep_writes_json_and_figures(tmp_path):
    result = run_bench(tiny(tmp_path, max_agents_in_flight=40))
    path = tmp_path / "scaling_cpu.json"
    assert Path(result["json"]) == path
    data = json.loads(path.read_text())
    for key in ("device_name", "python", "warp", "torch", "vmas", "cpu_count"):
        assert key in data["machine"]
    assert data["git"]["commit"]
    assert data["copy_bandwidth"]["bytes_per_s"] > 0
    points = {(p["series"], p["worlds"], p["agents_per_world"]): p for p in data["points"]}
    assert set(points) == {("agents", 1, 16), ("agents", 1, 64), ("worlds", 1, 17), ("worlds", 2, 17)}
    skipped = points[("agents", 1, 64)]
    assert skipped["status"] == "skipped" and "max-agents-in-flight" in skipped["note"]
    bandwidth = data["copy_bandwidth"]["bytes_per_s"]
    for key in (("agents", 1, 16), ("worlds", 1, 17), ("worlds", 2, 17)):
        p = points[key]
        assert p["status"] == "ok", p
        assert p["agents"] == p["worlds"] * p["agents_per_world"]
        assert p["agent_steps_per_s"] == pytest.approx(p["agents"] / (p["step_ms"] / 1e3))
        assert p["ns_per_agent_step"] == pytest.approx(1e9 / p["agent_steps_per_s"])
        assert len(p["runs_step_ms"]) == 2
        # CPU: no CUDA graph, so eager vs graph is not applicable.
        assert p["eager"] is None and p["graph_speedup"] is None and p["graph_note"].startswith("n/a")
        # Stage times: every stage present, the stages sum to stage_sum_ms, and the commands to their stage.
        assert set(bench.STAGES) <= set(p["stages_ms"])
        assert p["stage_sum_ms"] == pytest.approx(sum(p["stages_ms"].values()))
        # One-cell worlds take the fused step on the CPU (one command, the "fused" stage); larger ones
        # a launch per stage, where one-cell worlds would build no cell lists (fixed whole-world lists).
        assert p["step_kernel"] == ("fused" if p["cells_per_world"] == 1 else "stages")
        busy = {"fused"} if p["step_kernel"] == "fused" else set(bench.STAGES[1:]) - {"fused"}
        for stage in bench.STAGES[1:]:
            assert p["stages_ms"][stage] == pytest.approx(sum(c["ms"] for c in p["commands_ms"] if c["stage"] == stage))
            assert (p["stages_ms"][stage] > 0) == (stage in busy), (stage, p["step_kernel"])
        assert not [c for c in p["commands_ms"] if c["stage"] == "other"]
        assert p["heuristics_ms"] > 0
        assert p["memory"]["arrays_bytes"] > 0 and p["memory"]["device_bytes"] is None
        model = step_byte_model(AquariumConfig() if key[0] == "worlds" else bench.density_config(16), cuda=False)
        assert p["bytes_per_agent_step"] == pytest.approx(model["total"])
        assert p["fraction_of_copy_bandwidth"] == pytest.approx(
            p["bytes_per_agent_step"] * p["agent_steps_per_s"] / bandwidth
        )
    assert data["peers"]["vmas"]["status"] == "skipped" and data["peers"]["original"]["status"] == "skipped"
    names = sorted(Path(f).name for f in data["figures"])
    assert names == ["scaling_cpu_per_agent.png", "scaling_cpu_stages.png", "scaling_cpu_throughput.png"]
    for name in names:
        blob = (tmp_path / name).read_bytes()
        assert blob.startswith(PNG_MAGIC) and len(blob) > 10_000
    assert "worlds x agents" in bench.format_table(result)
    # The figures can be redrawn from the JSON alone.
    for name in names:
        (tmp_path / name).unlink()
    assert sorted(f.name for f in bench.replot(path)) == names
    assert all((tmp_path / name).exists() for name in names)


def test_sweep_points_load_series():
    base = dict(agents=[16, 64, 100, 300, 1000], worlds=[1, 4])
    assert [s for s, _, _ in bench.sweep_points(BenchSettings(**base))] == ["agents"] * 5 + ["worlds"] * 2
    points = bench.sweep_points(BenchSettings(**base, load_agents=250))
    load = [(cfg.capacity, worlds) for series, cfg, worlds in points if series == "load"]
    # Worlds of N agents hold about 250 agents in all; N > 250 is left out.
    assert (
        load == [(16, round(250 / 16)), (64, round(250 / 64)), (100, round(250 / 100))] == [(16, 16), (64, 4), (100, 2)]
    )
    assert [s for s, _, _ in points] == ["agents"] * 5 + ["worlds"] * 2 + ["load"] * 3
    for series, cfg, _ in points:  # the load series' worlds are the agents series' (default density)
        if series == "load":
            ref = bench.density_config(cfg.capacity)
            assert (cfg.prey_count, cfg.predator_count, cfg.width) == (ref.prey_count, ref.predator_count, ref.width)
    # At least one world: N = L and N just below L both give one world.
    one = bench.sweep_points(BenchSettings(agents=[16, 64, 100], worlds=[1], load_agents=100))
    assert [(cfg.capacity, w) for s, cfg, w in one if s == "load"] == [(16, 6), (64, 2), (100, 1)]
    assert bench.load_worlds(99, 100) == 1 and bench.load_worlds(1000, 100) == 1
    # A load below every N: no load points.
    below = bench.sweep_points(BenchSettings(agents=[16], worlds=[1], load_agents=8))
    assert not [s for s, _, _ in below if s == "load"]
    with pytest.raises(ValueError):
        BenchSettings(agents=[16], worlds=[1], load_agents=0)
    # The command line's --load-agents (default off).
    import argparse

    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    assert bench.settings_from_args(parser.parse_args([])).load_agents is None
    assert bench.settings_from_args(parser.parse_args(["--load-agents", "4000000"])).load_agents == 4_000_000


def test_per_agent_time_ratio_summary():
    def pt(series, n, ns, worlds=1, status="ok"):
        return {
            "series": series,
            "worlds": worlds,
            "agents_per_world": n,
            "agents": worlds * n,
            "status": status,
            "ns_per_agent_step": ns,
            "agent_steps_per_s": 1e9 / ns,
        }

    points = (
        [pt("agents", n, ns) for n, ns in ((256, 90.0), (1024, 40.0), (4096, 12.0), (65536, 10.0))]
        + [pt("worlds", 17, ns, w) for w, ns in ((1, 300.0), (16, 30.0))]
        + [pt("load", n, ns, 4096 // n) for n, ns in ((16, 20.0), (512, 9.0), (1000, 8.0), (2048, 11.0), (4096, 10.0))]
        + [pt("load", 8192, 1.0, status="skipped")]
    )
    s = bench.summary(points, {}, {})
    # Agents: from 1024 (the nearest world >= 1000) to 65536; max / min over 1024, 4096, 65536.
    assert s["agents_per_agent_time_ratio"] == {
        "agents_per_world": [1024, 65536],
        "worlds": [1, 1],
        "ns_per_agent_step": [40.0, 10.0],
        "ratio": 4.0,
        "points": 3,
    }
    # Load: from 1000 exactly to 4096 (the skipped 8192 does not count); the peak is in between.
    assert s["load_per_agent_time_ratio"] == {
        "agents_per_world": [1000, 4096],
        "worlds": [4, 1],
        "ns_per_agent_step": [8.0, 10.0],
        "ratio": 11.0 / 8.0,
        "points": 3,
    }
    assert "worlds_per_agent_time_ratio" not in s  # 17 agents per world: no world of 1000
    # The existing keys stay as they were.
    assert s["agents_ns_per_agent_first_last"] == [90.0, 10.0] and s["worlds_ns_per_agent_first_last"] == [300.0, 30.0]
    assert s["best"]["agents_per_world"] == 1000 and s["best"]["series"] == "load"
    # The only world >= 1000 is the largest: nothing to compare.
    assert "agents_per_agent_time_ratio" not in bench.summary(points[:1] + points[-2:-1], {}, {})
    assert bench.per_agent_time_ratio(points, "agents", 100_000) is None
    assert bench.per_agent_time_ratio(points, "agents", 16)["agents_per_world"] == [256, 65536]


@pytest.mark.slow
def test_tiny_load_sweep(tmp_path):
    result = run_bench(
        tiny(
            tmp_path,
            agents="16,64",
            worlds=[1],
            load_agents=128,
            seconds=0.01,
            repeats=1,
            warmup_steps=1,
            stage_repeats=1,
            heuristics=False,
        )
    )
    points = {(p["series"], p["worlds"], p["agents_per_world"]): p for p in result["points"]}
    assert set(points) == {("agents", 1, 16), ("agents", 1, 64), ("worlds", 1, 17), ("load", 8, 16), ("load", 2, 64)}
    load = [p for p in result["points"] if p["series"] == "load"]
    assert [(p["worlds"], p["agents_per_world"], p["agents"]) for p in load] == [(8, 16, 128), (2, 64, 128)]
    for p in load:
        assert p["status"] == "ok", p
        assert p["ns_per_agent_step"] == pytest.approx(1e9 / p["agent_steps_per_s"])
        assert p["prey_per_world"] + p["predators_per_world"] == p["agents_per_world"]
    data = json.loads((tmp_path / "scaling_cpu.json").read_text())
    assert data["settings"]["load_agents"] == 128
    # No world of 1000 agents: no ratio at the default threshold; from 16 agents per world, the
    # ratio spans both load points.
    assert "load_per_agent_time_ratio" not in result["summary"]
    assert result["summary"]["load_ns_per_agent_first_last"] == [p["ns_per_agent_step"] for p in load]
    s = bench.summary(result["points"], {}, {}, from_agents_per_world=16)
    ns = [p["ns_per_agent_step"] for p in load]
    assert s["load_per_agent_time_ratio"] == {
        "agents_per_world": [16, 64],
        "worlds": [8, 2],
        "ns_per_agent_step": ns,
        "ratio": pytest.approx(max(ns) / min(ns)),
        "points": 2,
    }
    assert s["load_per_agent_time_ratio"]["ratio"] >= 1.0
    # The table prints the load rows, the load and the ratio lines.
    table = bench.format_table({**result, "summary": s})
    rows = [line for line in table.splitlines() if line.startswith("load   ")]
    assert len(rows) == 2 and "8 x 16" in rows[0] and "2 x 64" in rows[1]
    assert "~128 agents in flight" in table
    assert "per-agent time flatness, load series: 16 -> 64 agents per world" in table
    assert "per-agent time flatness" not in bench.format_table(result)
    # The figures include the load series (a third stages panel).
    names = sorted(Path(f).name for f in data["figures"])
    assert names == ["scaling_cpu_per_agent.png", "scaling_cpu_stages.png", "scaling_cpu_throughput.png"]
    for name in names:
        assert (tmp_path / name).read_bytes().startswith(PNG_MAGIC)


@pytest.mark.slow
def test_failures_and_memory_guard_skip_points(tmp_path, monkeypatch):
    import aquarium_warp.env as env_module

    settings = tiny(tmp_path, agents=[16], worlds=[1], plots=False, stages=False, heuristics=False)
    settings.memory_fraction = 1e-12
    row = bench.measure_point("agents", bench.density_config(16), 1, "cpu", settings)
    assert row["status"] == "skipped" and "GiB" in row["note"]

    class Exploding:
        def __init__(self, *args, **kwargs):
            raise RuntimeError("Failed to allocate memory on device")

    monkeypatch.setattr(env_module, "BatchedAquarium", Exploding)
    result = run_bench(tiny(tmp_path, agents=[16], worlds=[1], plots=False))
    assert [p["status"] for p in result["points"]] == ["failed", "failed"]
    assert "allocate" in result["points"][0]["note"]
    assert json.loads((tmp_path / "scaling_cpu.json").read_text())["summary"] == {}


def test_ratios_against_peers():
    points = [
        {"series": "worlds", "worlds": 4, "agents_per_world": 17, "status": "ok", "agent_steps_per_s": 1e6},
        {"series": "agents", "worlds": 1, "agents_per_world": 64, "status": "ok", "agent_steps_per_s": 5e5},
        {"series": "agents", "worlds": 1, "agents_per_world": 99, "status": "skipped"},
    ]
    vmas = {"points": [{"series": "worlds", "envs": 4, "agents_per_env": 17, "status": "ok", "agent_steps_per_s": 1e4}]}
    bench.add_ratios(points, {"agent_steps_per_s": 2e3}, vmas)
    assert points[0]["ratios"] == {"vs_original": 500.0, "vs_vmas": 100.0}
    assert points[1]["ratios"] == {"vs_original": 250.0}
    assert "ratios" not in points[2]
    s = bench.summary(points, {"agent_steps_per_s": 2e3}, vmas)
    assert s["vs_vmas_min_max"] == [100.0, 100.0] and s["best_vs_original"] == 500.0


def test_stored_original_measurement(tmp_path):
    stored = tmp_path / "original.json"
    stored.write_text(
        json.dumps(
            {"machine": {"cpu": "x"}, "results": {"raw": {"agent_steps_per_s": 3584.0, "env_steps_per_s": 210.8}}}
        )
    )
    peer = bench.measure_original_peer(tiny(tmp_path, original_json=str(stored)))
    assert peer["status"] == "stored" and peer["agent_steps_per_s"] == 3584.0 and peer["machine"] == {"cpu": "x"}
    assert bench.measure_original_peer(tiny(tmp_path))["status"] == "skipped"


@pytest.mark.slow
@pytest.mark.slow
def test_peers_are_measured_by_the_harnesses_passed_in(tmp_path):
    """The package measures no peer itself: `run_bench` calls the harnesses that
    benchmarks/bench_scaling.py passes (here stand-ins), and refuses --vmas or --original without them
    before measuring anything."""
    calls = []

    def measure_vmas(agents_per_env, envs, device, seconds, repeats, budget_s):
        calls.append(("vmas", agents_per_env, envs, device))
        return {"scenario": "simple_tag", "step_ms": 1.0, "agent_steps_per_s": 1e3 * agents_per_env * envs}

    def measure_original(seconds, repeats, which, warmup):
        calls.append(("original", which))
        return {
            "agent_steps_per_s": 100.0,
            "env_steps_per_s": 6.0,
            "runs": [{"agent_steps_per_s": 100.0}],
            "seconds": seconds,
            "repeats": repeats,
            "entry_point": "raw_env",
        }

    vmas = SimpleNamespace(SCENARIO="simple_tag", vmas_version=lambda: "0.0", measure_vmas=measure_vmas)
    peers = bench.Peers(original=SimpleNamespace(measure_original=measure_original), vmas=vmas)
    settings = tiny(
        tmp_path, agents=[16], worlds=[1], vmas=True, original=True, plots=False, stages=False, heuristics=False
    )
    result = run_bench(settings, peers)
    assert calls == [("original", "raw"), ("vmas", 16, 1, "cpu"), ("vmas", 17, 1, "cpu")]
    assert [p["status"] for p in result["peers"]["vmas"]["points"]] == ["ok", "ok"]
    ours = result["points"][1]["agent_steps_per_s"]
    assert result["points"][1]["ratios"] == {"vs_original": ours / 100.0, "vs_vmas": ours / 17e3}
    for flag in ("vmas", "original"):
        with pytest.raises(ValueError, match=f"bench_scaling.py --{flag}"):
            run_bench(tiny(tmp_path / flag, **{flag: True}))
        assert not (tmp_path / flag).exists()


def test_cli_bench(tmp_path, staged_copy):
    from aquarium_warp.cli import main

    out = tmp_path / "cli"
    assert (
        main(
            [
                "bench",
                "--device",
                "cpu",
                "--agents",
                "16",
                "--worlds",
                "1",
                "--seconds",
                "0.01",
                "--repeats",
                "1",
                "--warmup-steps",
                "1",
                "--no-original",
                "--no-plots",
                "--no-heuristics",
                "--copy-mib",
                "4",
                "--git-commit",
                "abc123",
                "--quiet",
                "--out-dir",
                str(out),
            ]
        )
        == 0
    )
    data = json.loads((out / "scaling_cpu.json").read_text())
    assert data["git"] == {"commit": "abc123", "dirty": None, "modified": None, "source": "argument"}
    assert all(p["status"] == "ok" for p in data["points"])
    assert bench.main(["--agents", "a,b", "--quiet"]) == 2


def test_vmas_peer_harness():
    sys.path.insert(0, str(BENCHMARKS))
    import vmas_peer

    assert vmas_peer.split_agents(17) == (16, 1)
    assert vmas_peer.split_agents(1000) == (941, 59)
    if vmas_peer.vmas_version() is None:
        pytest.skip("vmas is not installed")
    r = vmas_peer.measure_vmas(17, 2, "cpu", seconds=0.01, repeats=1, warmup_steps=1, min_steps=1)
    assert r["agents"] == 34 and r["prey_per_env"] == 16 and r["predators_per_env"] == 1
    assert r["agent_steps_per_s"] > 0 and math.isclose(r["agent_steps_per_s"], 34 / (r["step_ms"] / 1e3))
    assert r["observation_floats_per_env"] > 0


def _profile_step_module():
    import importlib.util

    path = BENCHMARKS / "profile_step.py"
    spec = importlib.util.spec_from_file_location("profile_step", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_profile_step_reads_ncu_csv():
    """The Nsight Compute summary: metric units scaled, Warp and CUB kernel names shortened, and the
    step totals per agent (a hand-made two-kernel CSV in the layout of `ncu --csv --page raw`)."""
    profile = _profile_step_module()
    metrics = list(profile.METRICS)
    units = {
        "gpu__time_duration.sum": "us",
        "dram__bytes_read.sum": "Mbyte",
        "dram__bytes_write.sum": "Kbyte",
        "lts__t_bytes.sum": "byte",
    }
    values = [
        {
            "gpu__time_duration.sum": "2",
            "dram__bytes_read.sum": "1.5",
            "dram__bytes_write.sum": "500",
            "lts__t_bytes.sum": "4,000,000",
            "smsp__inst_executed.sum": "1,000",
        },
        {
            "gpu__time_duration.sum": "6",
            "dram__bytes_read.sum": "0.5",
            "dram__bytes_write.sum": "1,500",
            "lts__t_bytes.sum": "0",
            "smsp__inst_executed.sum": "3,000",
        },
    ]
    names = [
        "observation_kernel__locals__observe_98279985_cuda_kernel_forward",
        "void cub::DeviceScanKernel<cub::policy_hub<int>, int *>(int *)",
    ]
    quote = lambda row: ",".join(f'"{x}"' for x in row)  # noqa: E731
    lines = [
        "==PROF== Connected to process",
        quote(["ID", "Kernel Name"] + metrics),
        quote(["", ""] + [units.get(m, "") for m in metrics]),
    ]
    for k, (name, v) in enumerate(zip(names, values)):
        lines.append(quote([str(k), name] + [v.get(m, "50") for m in metrics]))
    kernels = profile.parse_ncu_csv("\n".join(lines))
    assert [k["kernel"] for k in kernels] == ["observation_kernel__locals__observe", "DeviceScanKernel"]
    assert kernels[0]["time_ns"] == 2000 and kernels[0]["dram_read_bytes"] == 1.5e6
    assert kernels[0]["dram_write_bytes"] == 5e5 and kernels[0]["l2_bytes"] == 4e6
    totals = profile.summarize(kernels, agents=1000, model_bytes=2000.0, copy_bandwidth=1e12)
    # 8 us of kernels moving 1.5 + 0.5 + 0.5 + 1.5 = 4 MB: 4000 B per agent, 2x the model, 0.5 TB/s.
    assert totals["kernel_time_ms"] == pytest.approx(0.008)
    assert totals["dram_bytes_per_agent_step"] == pytest.approx(4000.0)
    assert totals["dram_over_model"] == pytest.approx(2.0)
    assert totals["dram_bandwidth_tb_s"] == pytest.approx(0.5)
    assert totals["dram_fraction_of_copy"] == pytest.approx(0.5)
    assert totals["warp_instructions_per_agent_step"] == pytest.approx(4.0)
    table = profile.format_table(kernels, totals, 1000)
    assert "DeviceScanKernel" in table and "4000 B per agent-step" in table
    with pytest.raises(RuntimeError, match="no kernel"):
        profile.parse_ncu_csv("==PROF== nothing")
