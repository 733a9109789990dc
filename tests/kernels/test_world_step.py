"""The fused step (`kernels/world_step.py`, `step_kernel="fused"`) against the staged step (a launch per
stage): every array of the state (agents, counters, scratch, outputs, observations, masks, observed
slots) equal bit for bit after every step of hundreds, from random actions of a seeded generator, on
the CPU; on a GPU (`AQUARIUM_TEST_DEVICE`) within float tolerance over a shorter run. A CPU block of
several lanes (Warp's fibers) checks that every stage waits for the one before it. And the option's
errors.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
import warp as wp

import aquarium_warp.shard as shard_module
from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.config import FlowConfig

BASE = AquariumConfig()
SMALL = AquariumConfig(width=260.0, height=240.0, prey_count=12, predator_count=4)
GRID_FLOW = FlowConfig(
    "grid",
    grid=(((1.0, 0.5), (-0.5, 1.0), (0.0, -1.0)), ((2.0, 0.0), (0.5, 0.5), (-1.0, -1.0))),
    amplitude=0.3,
    period=17.0,
)
# name -> (config, worlds, steps, env keywords)
CASES = {
    "default": (BASE, 8, 300, {}),
    "captures often": (SMALL, 8, 300, {}),
    "starvation": (dataclasses.replace(SMALL, predator_starvation_steps=15, width=600.0, height=600.0), 6, 200, {}),
    "reproduction": (
        dataclasses.replace(
            SMALL, prey_count=6, prey_reproduction=True, prey_replication_age=12, max_prey=14, predator_count=2
        ),
        6,
        300,
        {},
    ),
    "respawn off": (dataclasses.replace(SMALL, respawn_captured_prey=False), 6, 300, {}),
    "episode ends": (dataclasses.replace(SMALL, max_steps=23), 6, 200, {}),
    "no auto-reset": (dataclasses.replace(SMALL, max_steps=23), 4, 60, {"auto_reset": False}),
    "per-world values": (
        dataclasses.replace(
            SMALL,
            prey_count=(12, 5, 9),
            prey_reproduction=True,
            max_prey=12,
            prey_replication_age=30,
            prey_reward=(1.0, 0.25, 2.0),
            catch_share_radius=(100.0, 0.0, 150.0),
            predator_reward=(10.0, 4.0, 10.0),
            predator_starvation_steps=(3000, 40, 100),
            prey=dataclasses.replace(
                SMALL.prey,
                max_speed=(4.0, 2.5, 6.0),
                fov_angle=(120.0, 360.0, 80.0),
                view_distance=(100.0, math.inf, 60.0),
                radius=(20.0, 12.0, 25.0),
            ),
            predator=dataclasses.replace(SMALL.predator, max_acceleration=(0.6, 1.2, 0.3), mass=(10.0, 4.0, 10.0)),
            flow=(
                FlowConfig(),
                FlowConfig("vortex", centre=(150.0, 5.0), strength=2.0, core_radius=50.0),
                FlowConfig("uniform", velocity=(-1.5, 0.5), amplitude=0.5, period=9.0),
            ),
        ),
        3,
        300,
        {},
    ),
    "grid flow, observed, signed, other slots": (
        dataclasses.replace(
            SMALL,
            flow=GRID_FLOW,
            observe_flow=True,
            observation_range="-1..1",
            fov_enabled=False,
            prey=dataclasses.replace(SMALL.prey, predator_slots=2, prey_slots=5),
            predator=dataclasses.replace(SMALL.predator, predator_slots=0, prey_slots=2),
        ),
        6,
        300,
        {},
    ),
    "shards": (BASE, 70, 100, {"cpu_threads": 2}),
    "capture confusion, per world": (
        dataclasses.replace(
            SMALL,
            capture_probability=(1.0, 0.8, 0.0, 1.0),
            capture_confusion=(3.0, 1.0, 2.0, 0.0),
            confusion_radius=(100.0, 40.0, 100.0, 100.0),
        ),
        4,
        300,
        {},
    ),
    "predator confusion, per world": (
        dataclasses.replace(
            SMALL,
            capture_rule=("confusion", "confusion", "dilution", "confusion"),
            capture_probability=(1.0, 0.8, 0.8, 1.0),
            capture_confusion=(1.0, 3.0, 1.0, 0.0),
            confusion_angle=(15.0, 60.0, 15.0, 180.0),
            handling_steps=(10, 0, 10, 4),
            predator=dataclasses.replace(SMALL.predator, view_distance=(200.0, math.inf, 200.0, 120.0)),
        ),
        4,
        300,
        {},
    ),
}


def random_actions(gen: torch.Generator, env: BatchedAquarium, device) -> dict:
    worlds, n = env.num_worlds, env.config.action_count
    return {
        "prey": torch.randint(0, n, (worlds, env.prey_capacity), generator=gen, dtype=torch.int32).to(device),
        "predator": torch.randint(0, n, (worlds, env.predator_capacity), generator=gen, dtype=torch.int32).to(device),
    }


def assert_same_state(fused: BatchedAquarium, staged: BatchedAquarium, step: int, exact: bool) -> None:
    for name in fused.state.arrays():
        a, b = getattr(fused.state.torch, name), getattr(staged.state.torch, name)
        if exact or not a.is_floating_point():
            assert torch.equal(a, b), f"{name} differs after step {step}"
        else:
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-3, msg=f"{name} differs after step {step}")


def run_both(cfg: AquariumConfig, worlds: int, steps: int, device: str, **kw) -> None:
    exact = device == "cpu"
    envs = {
        k: BatchedAquarium(cfg, num_worlds=worlds, device=device, seed=11, step_kernel=k, **kw)
        for k in ("fused", "stages")
    }
    assert envs["fused"].step_kernel == "fused" and envs["stages"].step_kernel == "stages"
    assert_same_state(envs["fused"], envs["stages"], 0, exact)
    gen = torch.Generator().manual_seed(5)
    # On a GPU the float results may differ in the last bits (contraction), which chaotic dynamics
    # amplify: a shorter run there.
    for step in range(1, (steps if exact else min(steps, 40)) + 1):
        actions = random_actions(gen, envs["fused"], device)
        for env in envs.values():
            env.step(actions)
        assert_same_state(envs["fused"], envs["stages"], step, exact)
    for env in envs.values():
        env.close()


@pytest.mark.parametrize("case", list(CASES))
def test_fused_step_equals_staged_step(case, device):
    cfg, worlds, steps, kw = CASES[case]
    run_both(cfg, worlds, steps, device, **kw)


def test_cases_exercise_what_they_name():
    """The cases reach what they are named for (captures, deaths, births, ends), so the comparison
    above covers those paths."""

    def totals(cfg, worlds, steps, **kw):
        env = BatchedAquarium(cfg, num_worlds=worlds, device="cpu", seed=11, step_kernel="fused", **kw)
        gen = torch.Generator().manual_seed(5)
        seen = {"captures": 0, "ended": 0, "predator deaths": 0, "births": 0}
        for _ in range(steps):
            before = env.state.torch.alive.clone()
            out = env.step(random_actions(gen, env, "cpu"))
            seen["captures"] += int(out.info["captures"].sum())
            seen["ended"] += int(out.info["episode_ended"].sum())
            seen["predator deaths"] += int(out.terminated["predator"].sum())
            seen["births"] += int((env.state.torch.alive & ~before).sum())
        env.close()
        return seen

    assert totals(*CASES["captures often"][:3])["captures"] > 50
    assert totals(*CASES["starvation"][:3])["predator deaths"] > 0
    assert totals(*CASES["reproduction"][:3])["births"] > 0
    assert totals(*CASES["episode ends"][:3])["ended"] > 0


FIBER_CFG = dataclasses.replace(
    SMALL, prey_count=8, prey_reproduction=True, prey_replication_age=12, max_prey=14, max_steps=60
)  # 18 slots


# name -> (lanes per block, config, worlds): blocks of fewer lanes than slots (lanes stride over one
# world), of one world, of several packed worlds with a partial last block, with worlds past the batch
# and lanes past the last packed world, and packed with other slot counts (a row function per type).
FIBER_BLOCKS = {
    "stride": (4, FIBER_CFG, 4),
    "one world": (32, FIBER_CFG, 4),
    "3 packed, partial last block": (64, FIBER_CFG, 5),
    "7 packed, worlds past the batch": (128, BASE, 4),
    "packed, other slots": (
        64,
        dataclasses.replace(
            FIBER_CFG,
            prey=dataclasses.replace(SMALL.prey, predator_slots=2, prey_slots=5),
            predator=dataclasses.replace(SMALL.predator, predator_slots=0, prey_slots=2),
        ),
        5,
    ),
}


# The fast loop runs one case (packed worlds, a partial last block), the full run every case.
FIBER_FAST = "3 packed, partial last block"


@pytest.mark.parametrize(
    "case", [pytest.param(c, marks=() if c == FIBER_FAST else pytest.mark.slow) for c in FIBER_BLOCKS]
)
def test_blocks_of_several_lanes_wait_between_stages(case, monkeypatch):
    """Blocks of several lanes (Warp runs CPU blocks as fibers that switch only at a barrier): a
    missing barrier lets a lane run a stage before the others have finished the stage before it,
    which changes results, and a wrong lane-to-slot map or row store leaves rows unset or misplaced.
    Captures, births and episode ends happen within the run."""
    lanes, cfg, worlds = FIBER_BLOCKS[case]
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    monkeypatch.setattr(shard_module, "fused_block_dim", lambda capacity, cuda: lanes)
    run_both(cfg, worlds, 150, "cpu")


def test_auto_takes_the_fused_step_where_it_applies(device):
    small = BatchedAquarium(BASE, num_worlds=2, device=device)
    large = BatchedAquarium(AquariumConfig(prey_count=60, predator_count=4), num_worlds=1, device=device)
    assert small.step_kernel == "fused" and len(small.shards[0].programs["step"]) == 1
    assert large.step_kernel == "stages"
    for env in (small, large):
        env.close()


@pytest.mark.parametrize(
    ("cuda", "slots", "expected"),
    [
        (False, 10**7, True),  # the CPU: always, one world per task in cache
        (True, shard_module.AUTO_FUSED_GPU_MAX_SLOTS, True),
        (True, shard_module.AUTO_FUSED_GPU_MAX_SLOTS + 1, False),  # large GPU batches: the staged kernels are faster
    ],
)
def test_auto_on_a_gpu_takes_the_fused_step_for_small_batches_only(cuda, slots, expected):
    assert shard_module.fused_step("auto", (1, 1), cuda, slots) is expected
    assert shard_module.fused_step("fused", (1, 1), cuda, slots) is True
    assert shard_module.fused_step("stages", (1, 1), cuda, slots) is False
    assert shard_module.fused_step("auto", (2, 2), cuda, slots) is False


@pytest.mark.parametrize("value", ["fast", "Fused", "", None, 1])
def test_bad_step_kernel_names_the_option(value):
    with pytest.raises(ValueError, match=r"step_kernel=.*must be one of 'auto', 'fused', 'stages'"):
        BatchedAquarium(BASE, num_worlds=1, device="cpu", step_kernel=value)


def test_fused_on_worlds_of_several_cells_says_why():
    with pytest.raises(ValueError, match=r"step_kernel='fused' needs worlds of one cell.*cells"):
        BatchedAquarium(
            AquariumConfig(prey_count=60, predator_count=4), num_worlds=1, device="cpu", step_kernel="fused"
        )
    with pytest.raises(ValueError, match=r"step_kernel='fused' needs worlds of one cell"):
        BatchedAquarium(
            dataclasses.replace(BASE, grid_cell_size=200.0), num_worlds=1, device="cpu", step_kernel="fused"
        )
