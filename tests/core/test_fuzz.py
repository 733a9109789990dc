"""Fuzz test of issue 15 (issue 28's CLI path options: `test_fuzz_cli_path_options`): configs drawn
from the whole field space, edges included, are either refused
with a `ValueError` that names a field that was set, or built and stepped; every stepped state must be
finite and respect the model's invariants. Steps mix valid actions with unvalidated out-of-range ones;
some cases first set velocities, accelerations and positions to the edges `set_state` allows, or load
a state dict with one entry changed to an edge value (refused whole, naming it, or taken and stepped).

The cases run in a subprocess (this file run as a script), so a crash fails the test instead of
ending the test run; each case is printed before it runs, so the last one printed names a crash.
Hypothesis draws them with a fixed seed (`derandomize`): CI runs the same cases every time. Worlds
stay tiny, and the observation kernels drawn are few, so a warm Warp kernel cache keeps this fast.

    python tests/core/test_fuzz.py 500    # run 500 cases directly
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import pytest

CASES = 1500
FAST_CASES = 400  # the fewest tried (100 to 400) whose fixed draws reach every share asserted below
ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
TYPE_FIELDS = (
    "max_speed",
    "max_steering_force",
    "max_acceleration",
    "mass",
    "radius",
    "view_distance",
    "fov_angle",
    "bounce_strength",
    "predator_slots",
    "prey_slots",
)


# The fast loop runs FAST_CASES; the full run (slow) all CASES.
@pytest.mark.parametrize("cases", [FAST_CASES, pytest.param(CASES, marks=pytest.mark.slow)])
def test_fuzz_configs_in_a_subprocess(cases):
    pytest.importorskip("hypothesis")
    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, os.path.abspath(__file__), str(cases)], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    elapsed = time.perf_counter() - start
    lines = result.stdout.splitlines()
    last_case = next((line for line in reversed(lines) if line.startswith("case ")), "none")
    assert result.returncode == 0, (
        f"fuzz worker exited with {result.returncode} after {elapsed:.0f} s; "
        f"last case: {last_case}\n{result.stderr[-4000:]}"
    )
    summary = dict(item.split("=") for item in lines[-1].removeprefix("fuzz summary: ").split())
    counts = {k: int(v) for k, v in summary.items()}
    ran = counts["refused"] + counts["config_only"] + counts["stepped"]
    assert ran >= 0.9 * cases, lines[-1]
    # Both outcomes are exercised in earnest, not one of them vacuously.
    assert counts["refused"] >= 0.2 * ran and counts["stepped"] >= 0.2 * ran, lines[-1]
    assert counts["states_set"] >= 0.05 * ran and counts["unvalidated_steps"] >= 0.05 * ran, lines[-1]
    assert counts["states_loaded"] >= 0.01 * ran and counts["loads_refused"] >= 0.01 * ran, lines[-1]


# ------------------------------------------------------------------------------------------ the worker
def field_space():
    """{field: (strategy of valid values, invalid values)}; per-type fields as "prey.x" / "predator.x".
    Valid values: each range's edges, typical values and a draw from the range. Invalid ones: just
    past each edge, NaN, infinities, values beyond float32, the issue's crashing values, wrong types."""
    import numpy as np
    from hypothesis import strategies as st

    nan, inf = math.nan, math.inf

    def real(lo, hi, *edges):
        return st.sampled_from([lo, hi, *edges]) | st.floats(lo, hi)

    def whole(lo, hi, *edges):
        return st.sampled_from([lo, hi, *edges]) | st.integers(lo, hi)

    not_real = [nan, inf, -inf, True, "1", None]
    not_int = [1.5, True, "3", None]
    space = {
        "width": (real(40.000001, 1e7, 41.0, 800.0), [40.0, 1.00000001e7, 0.0, -800.0, *not_real]),
        "height": (real(40.000001, 1e7, 41.0, 800.0), [40.0, 1.00000001e7, 0.0, *not_real]),
        "prey_count": (whole(1, 40, 16) | st.just(np.int64(5)), [0, -1, 2**30, 2**62, *not_int]),
        "predator_count": (whole(1, 6) | st.just(np.int32(2)), [0, -1, 2**30 + 5, *not_int]),
        "action_count": (whole(1, 65536, 2, 16), [0, -3, 65537, 16.0, *not_int]),
        "max_steps": (whole(1, 2**31 - 1, 2, 3, 3000), [0, -1, 2**31, 2**32 + 10, 10.5, nan, None]),
        "fov_enabled": (st.booleans() | st.just(np.bool_(False)), [1, 0, "True", None, np.float64(1.0)]),
        "respawn_captured_prey": (st.booleans(), [1, 0, "False", None]),
        "prey_reproduction": (st.booleans(), [1, "True", None]),
        "prey_reward": (real(-1e30, 1e30, 0.0, 1e-45, 1.0), [1e39, -1e39, *not_real]),
        "prey_capture_penalty": (real(-1e30, 1e30, 0.0, 1000.0), [1e39, *not_real]),
        "predator_reward": (real(-1e30, 1e30, 0.0, 10.0), [-1e39, *not_real]),
        "catch_share_radius": (real(1e-15, 1e15, 0.0, 100.0), [-1.0, 1e-30, 1.01e15, *not_real]),
        "capture_probability": (real(0.0, 1.0, 0.5), [-1e-9, 1.0000001, *not_real]),
        "capture_confusion": (real(0.0, 1e15, 4.0), [-1.0, 1.01e15, *not_real]),
        "confusion_radius": (real(1e-15, 1e15, 100.0), [0.0, -1.0, 1e-30, 1.01e15, *not_real]),
        "predator_starvation_steps": (whole(0, 2**31 - 2, 1, 2), [-1, 2**31 - 1, 2**31, 3000.0, *not_int]),
        "prey_replication_age": (whole(1, 1717986917, 2, 3), [0, 1717986918, 2**31 - 1, 200.0, *not_int]),
        "max_prey": (whole(1, 48, 20), [0, -5, 20.0, 2**31, *not_int]),
        "observation_range": (st.sampled_from(["0..1", "-1..1"]), ["0..2", "", 1, None]),
        # 1e-45 and 1e-3 are valid configs whose cell count the env refuses by name.
        "grid_cell_size": (
            st.sampled_from([None, 1e-45, 1e-3, 30.0, 1e6, 1e15]) | st.floats(30.0, 1e15),
            [0.0, -10.0, nan, inf, -inf, True, "50"],
        ),
    }
    for kind in ("prey", "predator"):
        space.update(
            {
                f"{kind}.max_speed": (real(1e-15, 19.9, 0.5, 4.0), [0.0, -1.0, 0.99e-15, 1e8, *not_real]),
                f"{kind}.max_steering_force": (real(1e-15, 1e15, 0.6), [0.0, 0.99e-15, 1.01e15, 1e-30, *not_real]),
                f"{kind}.max_acceleration": (real(1e-15, 1e15, 1.0), [0.0, 0.99e-15, 1.01e15, 1e38, *not_real]),
                f"{kind}.mass": (real(1e-15, 1e15, 3.0), [0.0, -3.0, 1e-45, 1e25, 1e30, 1e39, *not_real]),
                f"{kind}.radius": (real(1e-15, 1e15, 20.0), [0.0, -1.0, 0.99e-15, 1.01e15, *not_real]),
                f"{kind}.view_distance": (real(1e-15, 1e15, 100.0, inf), [0.0, -inf, 1e-30, 1.01e15, nan, True, None]),
                f"{kind}.fov_angle": (
                    real(1e-6, 360.0, 120.0) | st.floats(0.0, 360.0, exclude_min=True),
                    [0.0, -10.0, 360.0001, nan, inf, True],
                ),
                f"{kind}.bounce_strength": (real(1e-15, 1e15, 0.0, 1.0), [-1.0, 1e-30, 1e39, *not_real]),
                # few slot counts: each pair is an observation kernel to compile
                f"{kind}.predator_slots": (st.sampled_from([0, 1, 16]), [-1, 17, 1.0, True, None]),
                f"{kind}.prey_slots": (st.sampled_from([0, 3, 16]), [-1, 17, 3.0, None]),
            }
        )
    return space


def build_config(changes: dict):
    import dataclasses

    from aquarium_warp import AquariumConfig
    from aquarium_warp.config import default_predator, default_prey

    world = {k: v for k, v in changes.items() if "." not in k}
    for kind, default in (("prey", default_prey), ("predator", default_predator)):
        fields = {k.split(".")[1]: v for k, v in changes.items() if k.startswith(kind + ".")}
        if fields:
            world[kind] = dataclasses.replace(default(), **fields)
    return AquariumConfig(**world)


def check_state(env, rewards=None, stepped: bool = True) -> None:
    """Finite state within docs/model.md's invariants (every world, every slot); the speed and acceleration
    limits hold once a step has clamped them (`stepped`)."""
    import torch

    cfg, t, Pc = env.config, env.state.torch, env.prey_capacity
    for name in ("position", "velocity", "acceleration", "heading", "episode_return"):
        assert torch.isfinite(getattr(t, name)).all(), f"{name} not finite"
    p = t.position.double()
    assert ((p[..., 0] >= 0) & (p[..., 0] < cfg.width) & (p[..., 1] >= 0) & (p[..., 1] < cfg.height)).all(), (
        "position outside the world"
    )
    heading_norm = torch.linalg.vector_norm(t.heading.double(), dim=-1)
    assert ((heading_norm - 1).abs() < 1e-4).all(), f"heading not unit: {heading_norm.min()}..{heading_norm.max()}"
    for kind, slots in (("prey", slice(0, Pc)), ("predator", slice(Pc, None))):
        alive = t.alive[:, slots]
        params = getattr(cfg, kind)
        count = getattr(t, f"{kind}_alive_count")
        assert torch.equal(count, alive.sum(dim=1).to(torch.int32)), f"{kind}_alive_count != live slots"
        if not stepped:
            continue
        speed = torch.linalg.vector_norm(t.velocity[:, slots].double(), dim=-1)[alive]
        # Fresh agents move at speed 1 (docs/model.md "Randomness"), whatever their max speed.
        assert (speed <= max(params.max_speed, 1.0) * (1 + 1e-5)).all(), f"{kind} faster than max_speed"
        acc = torch.linalg.vector_norm(t.acceleration[:, slots].double(), dim=-1)[alive]
        k = params.max_acceleration
        assert ((acc == 0) | ((acc - k).abs() <= 1e-5 * k)).all(), f"{kind} acceleration not 0 or max_acceleration"
    assert (t.age >= 0).all() and (t.starvation >= 0).all() and (t.episode >= 0).all()
    assert ((t.world_step >= 0) & (t.world_step < cfg.max_steps)).all()
    low = -1.0 if cfg.observation_range == "-1..1" else 0.0
    for kind in ("prey", "predator"):
        obs = env.observations[kind]
        assert torch.isfinite(obs).all(), f"{kind} observations not finite"
        assert ((obs >= low - 1e-6) & (obs <= 1 + 1e-6)).all(), f"{kind} observations outside [{low}, 1]"
    if rewards is not None:
        assert all(torch.isfinite(r).all() for r in rewards.values()), "rewards not finite"


def run_cases(cases: int) -> None:
    import numpy as np
    import torch
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import strategies as st

    from aquarium_warp import BatchedAquarium
    from aquarium_warp.checks import LARGEST
    from aquarium_warp.env import grid_dims

    space = field_space()
    names = sorted(space)
    # "drawn" counts Hypothesis's attempts, some of which it abandons while drawing; the outcomes of
    # the cases that ran are "refused", "config_only" (valid, too large to step) and "stepped".
    counts = {
        "drawn": 0,
        "refused": 0,
        "config_only": 0,
        "stepped": 0,
        "states_set": 0,
        "states_loaded": 0,
        "loads_refused": 0,
        "unvalidated_steps": 0,
    }
    vector_edges = [0.0, 1.4e-45, -1.4e-45, 1e-30, -1e-20, 1e-18, 1.0, -3.0, LARGEST, -LARGEST]
    state_dict_edges_float = [math.nan, math.inf, -1e9, 1e9, -1.0, 1e-45, 0.5, 40.0, LARGEST, 1e16]
    state_dict_edges_int = [-(2**31), -1, 0, 1, 2, 2**31 - 1]

    @settings(
        max_examples=cases,
        derandomize=True,
        deadline=None,
        database=None,
        phases=(Phase.explicit, Phase.generate),
        suppress_health_check=list(HealthCheck),
    )
    @given(st.data())
    def case(data):
        counts["drawn"] += 1
        chosen = data.draw(st.lists(st.sampled_from(names), min_size=1, max_size=4, unique=True))
        changes, invalid = {}, []
        for name in chosen:
            valid_values, invalid_values = space[name]
            if data.draw(st.integers(0, 2)) == 0:
                changes[name] = data.draw(st.sampled_from(invalid_values))
                invalid.append(name)
            else:
                changes[name] = data.draw(valid_values)
        print(f"case {counts['drawn']}: {changes!r}", flush=True)
        try:
            cfg = build_config(changes)
        except ValueError as error:
            counts["refused"] += 1
            assert any(name in str(error) for name in chosen), f"error names none of {chosen}: {error}"
            return
        assert not invalid, f"invalid {invalid} accepted"
        dims = grid_dims(cfg)
        if cfg.capacity > 64 or 2**20 < dims[0] * dims[1] < 2**31:
            counts["config_only"] += 1  # valid, but too large to step in a fuzz case
            return
        worlds = data.draw(st.integers(1, 2))
        try:
            env = BatchedAquarium(cfg, num_worlds=worlds, device="cpu", seed=data.draw(st.integers(0, 2**40)))
        except ValueError as error:
            counts["refused"] += 1
            assert "grid_cell_size" in chosen and str(error).startswith("grid_cell_size="), str(error)
            return
        counts["stepped"] += 1
        check_state(env)
        rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
        if data.draw(st.integers(0, 3)) == 0:  # state at the edges set_state allows
            counts["states_set"] += 1
            C = env.capacity
            state = {name: rng.choice(vector_edges, size=(worlds, C, 2)) for name in ("velocity", "acceleration")}
            top = np.nextafter(np.float32([cfg.width, cfg.height]), np.float32(0))  # the largest float32 inside
            state["position"] = np.where(
                rng.random((worlds, C, 2)) < 0.3,
                rng.choice([0.0, 1.0], (worlds, C, 2)) * top,
                rng.random((worlds, C, 2)) * top,
            ).astype(np.float32)
            env.set_state(**state)
            check_state(env, stepped=False)
        if data.draw(st.integers(0, 3)) == 0:  # a state dict with one entry changed to an edge value
            saved = env.state_dict()
            changed = {**saved, "tensors": {k: v.clone() for k, v in saved["tensors"].items()}}
            name = data.draw(st.sampled_from(sorted(changed["tensors"])))
            flat = changed["tensors"][name].view(-1)
            entry = data.draw(st.integers(0, flat.numel() - 1))
            if flat.dtype == torch.bool:
                flat[entry] = not bool(flat[entry])
            else:
                pool = state_dict_edges_float if flat.dtype.is_floating_point else state_dict_edges_int
                flat[entry] = data.draw(st.sampled_from(pool))
            try:
                env.load_state_dict(changed)
                counts["states_loaded"] += 1
            except ValueError as error:
                assert name in str(error), f"error does not name {name}: {error}"
                after = env.state_dict()["tensors"]
                assert all(torch.equal(after[k], v) for k, v in saved["tensors"].items()), "refused load changed state"
                counts["loads_refused"] += 1
            check_state(env, stepped=False)
        n = cfg.action_count
        extremes = np.array([-(2**31), -(10**6), -5, -1, n, 16, 10**6, 2**31 - 1])
        for _ in range(3):
            shapes = {"prey": (worlds, env.prey_capacity), "predator": (worlds, env.predator_capacity)}
            if data.draw(st.integers(0, 3)) == 0:  # unvalidated, out of range: clamped in the kernel
                counts["unvalidated_steps"] += 1
                actions = {t: torch.as_tensor(rng.choice(extremes, size=s)) for t, s in shapes.items()}
                _, rewards, *_ = env.step(actions, validate=False)
            else:
                actions = {t: torch.as_tensor(rng.integers(0, n, size=s)) for t, s in shapes.items()}
                _, rewards, *_ = env.step(actions)
            check_state(env, rewards)
        env.close()

    case()
    print("fuzz summary: " + " ".join(f"{k}={v}" for k, v in counts.items()), flush=True)


if __name__ == "__main__":
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = getattr(wp, "LOG_WARNING", wp.config.log_level)
    run_cases(int(sys.argv[1]) if len(sys.argv) > 1 else CASES)


# ------------------------------------------------------------------------------ the CLI's path options
class Reached(Exception):
    """Raised where a command would start its long work: its paths were all accepted."""


PATH_OPTIONS = {  # (command line before the option, option, what the path names)
    "train --log-dir": (["train", "--preset", "tiny", "--device", "cpu"], "--log-dir", "folder"),
    "train --config": (["train", "--device", "cpu", "--log-dir", "{tmp}/run"], "--config", "input"),
    "train --resume": (["train"], "--resume", "input"),
    "eval --out": (["eval", "--device", "cpu", "--episodes", "1", "--seeds", "0"], "--out", "folder"),
    "eval --prey": (["eval", "--device", "cpu", "--out", "{tmp}/eval"], "--prey", "input"),
    "video --out": (["video", "--device", "cpu", "--no-progress"], "--out", "file"),
    "video --prey-policy": (
        ["video", "--device", "cpu", "--no-progress", "--out", "{tmp}/v.mp4"],
        "--prey-policy",
        "input",
    ),
    "study swarm-size --out": (["study", "swarm-size", "--prey", "4", "--device", "cpu"], "--out", "folder"),
    "study flow --out": (["study", "flow", "--device", "cpu"], "--out", "folder"),
    "bench --out-dir": (["bench", "--device", "cpu"], "--out-dir", "folder"),
}


@pytest.mark.slow
def test_fuzz_cli_path_options(tmp_path, monkeypatch, capsys):
    """Issue 28: every path option of the CLI, given paths a user might type (missing, nested, below a
    file, a folder for a file, a file for a folder, too long, odd characters, damaged contents), ends
    either in a one-line error that names the option or the path, or reaches the work; never a traceback."""
    pytest.importorskip("hypothesis")
    pytest.importorskip("rsl_rl")
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    import aquarium_warp.bench.suite
    import aquarium_warp.env
    from aquarium_warp.cli import main

    def reached(*args, **kwargs):
        raise Reached

    monkeypatch.setattr(aquarium_warp.env.BatchedAquarium, "__init__", reached)
    monkeypatch.setattr(aquarium_warp.bench.suite, "copy_bandwidth", reached)
    (tmp_path / "file").write_bytes(b"not a folder")
    (tmp_path / "folder").mkdir()
    (tmp_path / "empty.pt").write_bytes(b"")
    (tmp_path / "garbage.pt").write_bytes(b"\x00\x01garbage")
    (tmp_path / "bad.yaml").write_text("env: [1\n")
    (tmp_path / "list.json").write_text("[1, 2]")
    (tmp_path / "ok.json").write_text('{"env": {"prey_count": 4}}')
    kinds = [
        "missing/nested",
        "file",
        "file/below",
        "folder",
        "empty.pt",
        "garbage.pt",
        "bad.yaml",
        "list.json",
        "ok.json",
        "x" * 300,
        "spaced name/ü.mp4",
        "v.mp4",
        "noext",
        "",
        "/proc/aquarium",
        "/dev/null/x",
    ]
    outcomes = {"refused": 0, "reached": 0}
    counter = iter(range(10**6))

    @settings(max_examples=120, derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(st.sampled_from(sorted(PATH_OPTIONS)), st.sampled_from(kinds))
    def case(name, kind):
        before, option, _ = PATH_OPTIONS[name]
        case_dir = tmp_path / f"case{next(counter)}"
        case_dir.mkdir()
        for item in tmp_path.iterdir():  # each case in a fresh copy, so an accepted path changes nothing later
            if item.is_file():
                (case_dir / item.name).write_bytes(item.read_bytes())
        (case_dir / "folder").mkdir()
        path = kind if kind.startswith("/") or kind == "" else str(case_dir / kind)
        argv = [a.replace("{tmp}", str(case_dir)) for a in before] + [option, path]
        capsys.readouterr()
        try:
            code = main(argv)
        except Reached:
            outcomes["reached"] += 1
            return
        except SystemExit as error:  # argparse
            code = error.code
        err = capsys.readouterr().err.strip()
        assert "Traceback" not in err, (argv, err)
        if code == 0:  # e.g. a resumed run with nothing left to do
            outcomes["reached"] += 1
            return
        assert code in (1, 2) and len(err.splitlines()) >= 1, (argv, code, err)
        last = err.splitlines()[-1]
        named = option in last or (path and path in last) or repr(path) in last or "argument" in last
        assert named, (argv, last)
        outcomes["refused"] += 1

    case()
    assert outcomes["refused"] >= 30 and outcomes["reached"] >= 10, outcomes
