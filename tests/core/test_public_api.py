"""The env's public read and write API (`StepResult`, `outputs`, `actions`, `set_actions`,
`record_program`) and reseeding as a write into device data: no shard, array or launch is made again."""

from __future__ import annotations

import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.env import StepResult
from aquarium_warp.heuristics import heuristic_actions
from aquarium_warp.kernels import motion
from aquarium_warp.rollout import random_actions as rollout_random_actions

CFG = AquariumConfig(max_steps=30, prey_count=6, predator_count=2)


def random_actions(env: BatchedAquarium, seed: int) -> dict[str, torch.Tensor]:
    return rollout_random_actions(env.config, env.num_worlds, torch.Generator().manual_seed(seed), "cpu")


def test_step_returns_the_outputs_record():
    env = BatchedAquarium(CFG, num_worlds=3, device="cpu", seed=1)
    result = env.step(random_actions(env, 0))
    assert isinstance(result, StepResult) and result is env.outputs
    obs, rewards, terminated, truncated, info = result
    assert obs is env.observations and info is result.info
    assert rewards["prey"].shape == (3, env.prey_capacity) and terminated["predator"].shape == (3, 2)
    assert truncated["prey"].dtype == torch.bool and info["captures"].shape == (3,)
    # The record holds views of the buffers: a later step's values appear in it.
    for k in range(1, 5):
        env.step(random_actions(env, k))
    assert result.rewards["prey"].data_ptr() == env.state.torch.reward.data_ptr()
    assert torch.equal(result.rewards["prey"], env.state.torch.reward[:, : env.prey_capacity])


def test_writing_the_action_buffers_equals_passing_actions():
    a = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=4)
    b = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=4)
    for k in range(12):
        actions = random_actions(a, k)
        a.step(actions)
        for t in ("prey", "predator"):
            b.actions[t].copy_(actions[t])
        b.step()
        assert torch.equal(a.state.torch.position, b.state.torch.position)
        assert torch.equal(a.outputs.rewards["prey"], b.outputs.rewards["prey"])
    b.set_actions(random_actions(b, 99))
    assert torch.equal(b.actions["prey"], random_actions(b, 99)["prey"])


def test_reseeding_writes_device_data_and_rebuilds_nothing():
    env = BatchedAquarium(CFG, num_worlds=4, device="cpu", seed=0)
    heuristic_actions(env)  # records the policies' launches
    shards = env.shards
    commands = [list(shard.programs["step"]) for shard in shards]
    arrays = {name: array.ptr for name, array in env.state.arrays().items()}
    env.reset(seed=123)
    assert all(a is b for a, b in zip(env.shards, shards))
    assert all(a is b for shard, before in zip(env.shards, commands) for a, b in zip(shard.programs["step"], before))
    assert {name: array.ptr for name, array in env.state.arrays().items()} == arrays
    # ... and gives the run of a fresh env with that seed, heuristic actions included.
    fresh = BatchedAquarium(CFG, num_worlds=4, device="cpu", seed=123)
    for _ in range(40):
        env.step(heuristic_actions(env))
        fresh.step(heuristic_actions(fresh))
        assert torch.equal(env.state.torch.position, fresh.state.torch.position)
        assert torch.equal(env.outputs.rewards["predator"], fresh.outputs.rewards["predator"])


def test_record_program_runs_on_every_shard():
    """A program recorded through the env runs on each shard's worlds (two shards here)."""
    env = BatchedAquarium(CFG, num_worlds=64, device="cpu", seed=2, cpu_threads=2)
    assert len(env.shards) == 2
    # The twin launches a step stage by stage, so its first command is the motion launch.
    twin = BatchedAquarium(CFG, num_worlds=64, device="cpu", seed=2, cpu_threads=2, step_kernel="stages")
    actions = random_actions(env, 5)
    env.set_actions(actions)
    twin.set_actions(actions)
    # The motion kernel alone, launched through a program of its own, moves the agents as the step's
    # first launch does.
    program = env.record_program(
        lambda shard: [
            shard.record(
                motion.motion_stage(False)[1],
                (shard.num_worlds, env.capacity),
                [shard.world, shard.types, env.action_directions, shard.state.actions, shard.state.worlds],
                [shard.state.agents, shard.state.scratch, shard.state.outputs],
            )
        ]
    )
    program.run()
    twin.shards[0].programs["step"][0]()
    twin.shards[1].programs["step"][0]()
    assert torch.equal(env.state.torch.position, twin.state.torch.position)
    assert not torch.equal(
        env.state.torch.position, BatchedAquarium(CFG, num_worlds=64, device="cpu", seed=2).state.torch.position
    )
