"""The scaling benchmark suite's plumbing (`aquarium_warp.bench`), on the CPU with tiny sweeps."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from aquarium_warp import AquariumConfig
from aquarium_warp import bench
from aquarium_warp.bench import BenchSettings, parse_counts, run_bench, step_byte_model

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def tiny(tmp_path, **changes) -> BenchSettings:
    settings = dict(device="cpu", agents=[16, 64], worlds=[1, 2], seconds=0.02, repeats=2, warmup_steps=2,
                    stage_repeats=3, original=False, vmas=False, out_dir=str(tmp_path), quiet=True,
                    copy_bytes=8 << 20)
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
        assert set(model["stages"]) == set(bench.STAGES)
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
    # Small worlds are ranked per slot on a GPU; large ones take the radix sort, which moves more
    # than ranking or the CPU's counting sort.
    assert gpu["grid_path"] == "rank per slot (CUDA)" and cpu["grid_path"] == "counting sort (CPU)"
    large = bench.density_config(10_000)
    radix = step_byte_model(large, cuda=True)
    assert radix["grid_path"] == "radix sort (CUDA)"
    assert radix["stages"]["grid"]["read"] > step_byte_model(large, cuda=False)["stages"]["grid"]["read"]
    assert radix["stages"]["grid"]["read"] > gpu["stages"]["grid"]["read"]
    # More grid cells per agent clear more cell ranges; reproduction reads the prey's ages.
    assert step_byte_model(cfg, (20, 20))["total"] > step_byte_model(cfg, (5, 5))["total"]
    assert (step_byte_model(AquariumConfig(prey_reproduction=True, max_prey=32))["stages"]["population"]["read"]
            > gpu["stages"]["population"]["read"])
    # A one-world config at the default density models the same order of bytes as the default world.
    assert 0.5 < radix["total"] / gpu["total"] < 2.0


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
        for stage in bench.STAGES[1:]:
            assert p["stages_ms"][stage] == pytest.approx(
                sum(c["ms"] for c in p["commands_ms"] if c["stage"] == stage))
            assert p["stages_ms"][stage] > 0
        assert not [c for c in p["commands_ms"] if c["stage"] == "other"]
        assert p["heuristics_ms"] > 0
        assert p["memory"]["arrays_bytes"] > 0 and p["memory"]["device_bytes"] is None
        model = step_byte_model(AquariumConfig() if key[0] == "worlds" else bench.density_config(16), cuda=False)
        assert p["bytes_per_agent_step"] == pytest.approx(model["total"])
        assert p["fraction_of_copy_bandwidth"] == pytest.approx(
            p["bytes_per_agent_step"] * p["agent_steps_per_s"] / bandwidth)
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
    points = [{"series": "worlds", "worlds": 4, "agents_per_world": 17, "status": "ok", "agent_steps_per_s": 1e6},
              {"series": "agents", "worlds": 1, "agents_per_world": 64, "status": "ok", "agent_steps_per_s": 5e5},
              {"series": "agents", "worlds": 1, "agents_per_world": 99, "status": "skipped"}]
    vmas = {"points": [{"series": "worlds", "envs": 4, "agents_per_env": 17, "status": "ok", "agent_steps_per_s": 1e4}]}
    bench.add_ratios(points, {"agent_steps_per_s": 2e3}, vmas)
    assert points[0]["ratios"] == {"vs_original": 500.0, "vs_vmas": 100.0}
    assert points[1]["ratios"] == {"vs_original": 250.0}
    assert "ratios" not in points[2]
    s = bench.summary(points, {"agent_steps_per_s": 2e3}, vmas)
    assert s["vs_vmas_min_max"] == [100.0, 100.0] and s["best_vs_original"] == 500.0


def test_stored_original_measurement(tmp_path):
    stored = tmp_path / "original.json"
    stored.write_text(json.dumps({"machine": {"cpu": "x"}, "results": {"raw": {"agent_steps_per_s": 3584.0,
                                                                                "env_steps_per_s": 210.8}}}))
    peer = bench.measure_original_peer(tiny(tmp_path, original_json=str(stored)))
    assert peer["status"] == "stored" and peer["agent_steps_per_s"] == 3584.0 and peer["machine"] == {"cpu": "x"}
    assert bench.measure_original_peer(tiny(tmp_path))["status"] == "skipped"


def test_cli_bench(tmp_path):
    from aquarium_warp.cli import main

    out = tmp_path / "cli"
    assert main(["bench", "--device", "cpu", "--agents", "16", "--worlds", "1", "--seconds", "0.01", "--repeats", "1",
                 "--warmup-steps", "1", "--no-original", "--no-plots", "--no-heuristics", "--copy-mib", "4",
                 "--git-commit", "abc123", "--quiet", "--out-dir", str(out)]) == 0
    data = json.loads((out / "scaling_cpu.json").read_text())
    assert data["git"] == {"commit": "abc123", "dirty": None, "source": "given"}
    assert all(p["status"] == "ok" for p in data["points"])
    assert bench.main(["--agents", "a,b", "--quiet"]) == 2


def test_vmas_peer_harness():
    sys.path.insert(0, str(bench.BENCHMARKS))
    import vmas_peer

    assert vmas_peer.split_agents(17) == (16, 1)
    assert vmas_peer.split_agents(1000) == (941, 59)
    if vmas_peer.vmas_version() is None:
        pytest.skip("vmas is not installed")
    r = vmas_peer.measure_vmas(17, 2, "cpu", seconds=0.01, repeats=1, warmup_steps=1, min_steps=1)
    assert r["agents"] == 34 and r["prey_per_env"] == 16 and r["predators_per_env"] == 1
    assert r["agent_steps_per_s"] > 0 and math.isclose(r["agent_steps_per_s"], 34 / (r["step_ms"] / 1e3))
    assert r["observation_floats_per_env"] > 0
