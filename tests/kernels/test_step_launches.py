"""The staged step of worlds of several cells launches what it must and no more (issue #20: a large
world on a GPU is launch-bound): no pass of its own for the rewards (the share and respawn passes and
reproduction finish them), no memset before the GPU count build (`drop_into_cells` zeroes the cell
counts after their last read). The count build runs here on the CPU too (it is the GPU's build of
worlds of more than `RANK_SORT_MAX_CAPACITY` slots; the CPU would use its counting sort), against the
CPU's own build: the same state bit for bit, and the counts zero after every program that builds.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

import aquarium_warp.shard as shard_module
from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.bench import command_name, density_config

STAGED = [
    "integrate_motion",
    "detect_contacts",
    "resolve_captures",
    "share_capture_rewards",
    "respawn_captured_prey",
    "finish_world_step",
    "close_ended_episodes",
]
COUNT_BUILD = ["compute_cell_keys", "array_scan", "drop_into_cells", "order_cells"]


@pytest.fixture
def count_build(monkeypatch):
    """Worlds of several cells take the count build on any device."""
    monkeypatch.setattr(
        shard_module, "grid_build", lambda cfg, dims, cuda: "whole-world" if tuple(dims) == (1, 1) else "count"
    )


def step_names(env: BatchedAquarium) -> list[str]:
    return [command_name(c) for c in env.shards[0].programs["step"]]


def test_large_world_step_launches(count_build):
    """One world of 1,000 agents at the default density: 7 staged passes, the 4 commands of the count
    build (no memset) and one observation launch; reproduction adds one."""
    cfg = density_config(1000)
    env = BatchedAquarium(cfg, num_worlds=1, device="cpu", step_kernel="auto")
    assert env.step_kernel == "stages" and env.grid_dims[0] * env.grid_dims[1] > 1
    names = step_names(env)
    assert names[:-1] == STAGED + COUNT_BUILD, names
    assert "observation" in names[-1], names
    assert len(names) == 12 and "zero_" not in names and "collect_rewards" not in names
    repro = BatchedAquarium(
        dataclasses.replace(cfg, prey_reproduction=True, max_prey=cfg.prey_count + 50), num_worlds=1, device="cpu"
    )
    assert step_names(repro)[:-1] == STAGED[:5] + ["reproduce_prey"] + STAGED[5:] + COUNT_BUILD
    # The observe and reset programs build the lists the same way.
    assert [command_name(c) for c in env.shards[0].programs["observe"]][:-1] == COUNT_BUILD
    assert [command_name(c) for c in env.shards[0].programs["reset"]][1:-1] == COUNT_BUILD


def test_cpu_step_launches():
    """The CPU's staged step of worlds of several cells: 7 passes, its counting sort, the observations."""
    env = BatchedAquarium(density_config(1000), num_worlds=2, device="cpu")
    assert step_names(env)[:-1] == STAGED + ["sort_into_cells_per_world"]
    assert len(step_names(env)) == 9


# Worlds with more cells than slots (the zeroing threads stride over the cells), reproduction and
# removal (dead slots, newborns), episodes that end.
CELLS = AquariumConfig(
    width=900.0,
    height=800.0,
    prey_count=30,
    predator_count=6,
    prey_reproduction=True,
    prey_replication_age=6,
    max_prey=60,
    respawn_captured_prey=False,
    max_steps=40,
    grid_cell_size=50.0,
)


def test_count_build_leaves_counts_zero_and_matches_the_cpu_build(monkeypatch):
    envs = {"counting": BatchedAquarium(CELLS, num_worlds=3, device="cpu", seed=4)}
    monkeypatch.setattr(
        shard_module, "grid_build", lambda cfg, dims, cuda: "whole-world" if tuple(dims) == (1, 1) else "count"
    )
    envs["count"] = BatchedAquarium(CELLS, num_worlds=3, device="cpu", seed=4)
    grid = envs["count"].shards[0].grid
    cells = grid.cell_count.shape[0]
    assert cells > 3 * CELLS.capacity  # more cells than slots
    assert "compute_cell_keys" in step_names(envs["count"])

    def counts_zero() -> bool:
        return not grid.cell_count.numpy().any()

    def same_state(step: int) -> None:
        for name in envs["count"].state.arrays():
            a, b = getattr(envs["count"].state.torch, name), getattr(envs["counting"].state.torch, name)
            assert torch.equal(a, b), f"{name} differs after step {step}"

    assert counts_zero()
    same_state(0)
    gen = torch.Generator().manual_seed(2)
    n = CELLS.action_count
    for step in range(1, 121):
        actions = {
            "prey": torch.randint(0, n, (3, CELLS.prey_capacity), generator=gen, dtype=torch.int32),
            "predator": torch.randint(0, n, (3, CELLS.predator_count), generator=gen, dtype=torch.int32),
        }
        for env in envs.values():
            env.step(actions)
        assert counts_zero(), f"cell counts left after step {step}"
        same_state(step)
    for env in envs.values():
        env.reset(seed=9)
    assert counts_zero()
    same_state(-1)
    for env in envs.values():
        env.set_state(world=1, alive=torch.ones(CELLS.capacity, dtype=torch.bool))
    assert counts_zero()
    same_state(-2)
