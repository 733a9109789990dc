"""Regression tests of issue 15: inputs that crashed the process, overflowed silently or corrupted the
state. Cases that could kill the interpreter run in a subprocess, so a crash fails the test instead of
ending the test run."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def run_python(code: str, timeout: float = 240) -> subprocess.CompletedProcess:
    """Run `code` in a fresh interpreter (fresh Warp: nothing loaded yet), from the repository root."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


@pytest.mark.slow
def test_envs_built_on_two_threads_at_once():
    """Case 1: two threads constructing envs at the same moment (each loading Warp's modules) crashed
    with a segfault in 5 of 5 runs; construction is now serialised inside the package."""
    result = run_python("""
        import threading
        from aquarium_warp import AquariumConfig, BatchedAquarium
        barrier = threading.Barrier(2)
        envs = []
        def build():
            barrier.wait()
            envs.append(BatchedAquarium(AquariumConfig(prey_count=8), num_worlds=5, device="cpu"))
        threads = [threading.Thread(target=build) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        a, b = envs
        assert (a.state.torch.position == b.state.torch.position).all()
        print("built", len(envs))
    """)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "built 2" in result.stdout


@pytest.mark.slow
def test_study_settings_built_on_parallel_threads(tmp_path):
    """Case 1: `aquarium-warp study swarm-size --prey 1024,2048,4096 ...` with the default --jobs
    segfaulted on 2 cores: settings built on parallel threads loaded Warp modules at once. Here, in a
    fresh interpreter, settings of one-cell and cell-list worlds (different observation kernels than
    the study's warm-up loads) are built by 2 threads."""
    result = run_python(f"""
        from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_swarm_size_study
        study = SwarmSizeStudy(prey=[8, 40, 48], seeds=1, episode_steps=5, metrics_every=5, device="cpu",
                               out={str(tmp_path)!r}, jobs=2, figures=False)
        summary = run_swarm_size_study(study, progress=False)
        print("settings", len(summary["results"]), "jobs", summary["config"]["jobs"])
    """)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "settings 3 jobs 2" in result.stdout


@pytest.mark.slow
def test_unvalidated_actions_are_clamped_in_the_kernel():
    """Case 4: `step(actions, validate=False)` with an action of 10**6 segfaulted, 16 or -5 read out of
    bounds. The motion kernel clamps the index into [0, action_count - 1]: the same trajectory as a
    twin stepped with the clamped actions through the validated path."""
    result = run_python("""
        import torch
        from aquarium_warp import AquariumConfig, BatchedAquarium
        cfg = AquariumConfig(prey_count=6, predator_count=2, max_steps=50)
        env = BatchedAquarium(cfg, num_worlds=3, device="cpu", seed=4)
        twin = BatchedAquarium(cfg, num_worlds=3, device="cpu", seed=4)
        gen = torch.Generator().manual_seed(1)
        for _ in range(8):
            prey = torch.randint(-10**6, 10**6, (3, 6), generator=gen)
            prey[0, :3] = torch.tensor([16, -5, 2**31 - 1])
            predator = torch.randint(-40, 40, (3, 2), generator=gen, dtype=torch.int32)
            env.step({"prey": prey, "predator": predator}, validate=False)
            twin.step({"prey": prey.clamp(0, 15), "predator": predator.clamp(0, 15)})
            for name, value in env.state_dict()["tensors"].items():
                assert torch.equal(value, twin.state_dict()["tensors"][name]), name
            assert torch.equal(env.observations["prey"], twin.observations["prey"])
        print("clamped")
    """)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "clamped" in result.stdout


@pytest.mark.slow
def test_far_position_in_a_state_dict_is_refused_and_the_env_steps_on():
    """Case 3: `load_state_dict` with one position of (1e9, -1e9) in a 64-prey world segfaulted on the
    next step; it is now refused naming the tensor and the allowed range, and the env steps on as if
    the call had not happened."""
    result = run_python("""
        import torch
        from aquarium_warp import AquariumConfig, BatchedAquarium
        cfg = AquariumConfig(prey_count=64)
        env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=3)
        twin = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=3)
        bad = env.state_dict()
        bad["tensors"]["position"][0, 5] = torch.tensor([1e9, -1e9])
        try:
            env.load_state_dict(bad)
        except ValueError as error:
            print("refused:", error)
        actions = {"prey": torch.zeros(2, 64, dtype=torch.int64), "predator": torch.zeros(2, 1, dtype=torch.int64)}
        for _ in range(3):
            env.step(actions)
            twin.step(actions)
        assert torch.equal(env.state.torch.position, twin.state.torch.position)
        print("stepped")
    """)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "refused: state_dict tensor position must lie in [0, 800.0) x [0, 800.0)" in result.stdout
    assert "stepped" in result.stdout


def test_tiny_grid_cell_size_is_blamed_by_name():
    """Case 10: grid_cell_size=1e-45 reported a 96-digit cell count under `num_worlds`."""
    from aquarium_warp import AquariumConfig, BatchedAquarium

    with pytest.raises(ValueError) as err:
        BatchedAquarium(AquariumConfig(grid_cell_size=1e-45), device="cpu")
    message = str(err.value)
    assert message.startswith("grid_cell_size=1e-45 ") and "at least about 0.0244 px" in message, message
    assert len(message) < 200


@pytest.mark.parametrize(
    "dtype,error",
    [(">i8", None), (">i2", None), ("object", "numpy object"), ("<U2", "numpy <U2"), (">f4", "integer dtype")],
)
def test_numpy_actions_of_any_byte_order_or_dtype(dtype, error):
    """Case 10: big-endian or object numpy actions gave torch's message without the action key. Big-endian
    integers are integers (the same step as native ones); other dtypes are refused naming the key."""
    import numpy as np
    import torch

    from aquarium_warp import AquariumConfig, BatchedAquarium

    cfg = AquariumConfig(prey_count=4, max_steps=20)
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=1)
    twin = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=1)
    native = np.arange(8).reshape(2, 4) % cfg.action_count
    predator = np.zeros((2, 1), dtype=np.int64)
    actions = {"prey": native.astype(dtype), "predator": predator}
    if error is None:
        env.step(actions)
        twin.step({"prey": torch.as_tensor(native), "predator": torch.as_tensor(predator)})
        assert torch.equal(env.state.torch.position, twin.state.torch.position)
    else:
        before = env.state_dict()["tensors"]["position"]
        with pytest.raises(ValueError) as err:
            env.step(actions)
        assert "actions['prey']" in str(err.value) and error in str(err.value), str(err.value)
        assert torch.equal(env.state.torch.position, before)


def _one_world(cfg, **fields):
    import torch

    from aquarium_warp import BatchedAquarium

    env = BatchedAquarium(cfg, num_worlds=1, device="cpu", seed=0)
    env.set_state(
        world=0, **{k: torch.as_tensor(v, dtype=getattr(env.state.torch, k).dtype) for k, v in fields.items()}
    )
    return env


def test_tiny_steering_acceleration_is_normalised_exactly():
    """Case 2: a steering force of 1e-30 (now refused), or the smallest allowed force on the heaviest
    allowed mass, gives F / m ~ 1e-30, whose square underflows in float32: the acceleration was NaN.
    From a zero acceleration, docs/model.md step 2 gives A' = k * unit(F) (computed here in float64)."""
    import dataclasses

    import numpy as np
    import torch

    from aquarium_warp import AquariumConfig
    from aquarium_warp.config import default_prey
    from aquarium_warp.env import action_directions

    prey = dataclasses.replace(default_prey(), max_steering_force=1e-15, mass=1e15, max_acceleration=0.5)
    cfg = AquariumConfig(prey_count=2, prey=prey, width=800.0, height=800.0)
    position = [[100.0, 100.0], [500.0, 500.0], [300.0, 700.0]]
    velocity = [[-1.0, 0.0], [0.3, -0.2], [0.0, -1.0]]
    env = _one_world(cfg, position=position, velocity=velocity, acceleration=np.zeros((3, 2)))
    env.step({"prey": torch.tensor([[5, 11]]), "predator": torch.tensor([[0]])})
    directions = action_directions(16).astype(np.float64)
    for slot, action in ((0, 5), (1, 11)):
        force = directions[action] * prey.max_speed - np.array(velocity[slot])
        expected = 0.5 * force / np.linalg.norm(force)
        got = env.state.torch.acceleration[0, slot].double().numpy()
        np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-7)
    assert torch.isfinite(env.state.torch.position).all()


def test_tiny_velocity_gives_a_unit_heading():
    """A velocity too short to square in float32, kept by a contact with bounce strength 0, still gives
    a unit heading along it (the heading was off by up to tens of percent, or NaN-prone)."""
    import dataclasses

    import numpy as np
    import torch

    from aquarium_warp import AquariumConfig
    from aquarium_warp.config import default_prey

    prey = dataclasses.replace(default_prey(), bounce_strength=0.0)
    cfg = AquariumConfig(prey_count=2, prey=prey)
    env = _one_world(
        cfg,
        position=[[100.0, 100.0], [110.0, 100.0], [600.0, 600.0]],
        velocity=[[3e-22, 4e-22], [0.0, -7e-30], [0.0, -1.0]],
    )
    env.step({"prey": torch.tensor([[0, 0]]), "predator": torch.tensor([[0]])})
    heading = env.state.torch.heading[0].double().numpy()
    np.testing.assert_allclose(heading[0], [0.6, 0.8], rtol=1e-6)
    np.testing.assert_allclose(heading[1], [0.0, -1.0], rtol=1e-6)


def test_int32_edges_do_not_overflow():
    """Case 5: max_steps=2**31 ended every episode after one step, predator_starvation_steps=2**31
    likewise, and prey_replication_age=2**31-1 filled max_prey within 5 steps (all now refused). At
    the largest allowed values nothing ends, starves or reproduces early."""
    import math

    import torch

    from aquarium_warp import AquariumConfig, BatchedAquarium

    age = 1717986917
    cfg = AquariumConfig(
        prey_count=8,
        max_prey=12,
        prey_reproduction=True,
        prey_replication_age=age,
        max_steps=2**31 - 1,
        predator_starvation_steps=2**31 - 2,
    )
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=9)
    replication = env.state.torch.replication_age[:, :8]
    assert int(replication.min()) >= math.ceil(0.75 * age) and int(replication.max()) <= 2**31 - 2
    for _ in range(6):
        actions = {
            "prey": torch.zeros(2, env.prey_capacity, dtype=torch.int64),
            "predator": torch.zeros(2, 1, dtype=torch.int64),
        }
        _, _, terminated, truncated, info = env.step(actions)
        assert not info["episode_ended"].any() and not terminated["predator"].any()
    assert (env.state.torch.world_step == 6).all()
    assert torch.equal(env.state.torch.prey_alive_count, torch.tensor([8, 8], dtype=torch.int32))
    assert not env.alive["prey"][:, 8:].any()


@pytest.mark.parametrize("mass", [1e-45, 1e30])
def test_pettingzoo_env_with_a_crashing_mass_is_refused(mass):
    """Case 2: `aquarium_v1.parallel_env(prey_count=64, prey_mass=1e-45)` crashed the first step."""
    from aquarium_warp import aquarium_v1

    with pytest.raises(ValueError, match=r"^prey\.mass=.*\[1e-15, 1e\+15\]"):
        aquarium_v1.parallel_env(prey_count=64, prey_mass=mass)
