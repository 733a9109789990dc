"""The hardware floors of PPO training (`aquarium_warp/bench/floors.py`): the update's and the rollout's
arithmetic and bytes counted by hand for small networks and small worlds, the card table, and the
floor's reading (unknown card: n/a)."""

from __future__ import annotations

import os

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest

from aquarium_warp.bench.floors import (
    CARD_PEAKS,
    CardPeaks,
    Floor,
    card_peaks,
    linear_scaling,
    matmul_shapes,
    mlp_flops,
    ppo_rollout_work,
    ppo_update_work,
    rollout_work,
    simulation_bytes,
    update_work,
)


def test_mlp_flops_count_forward_weight_and_input_gradients():
    shapes = [(3, 4), (4, 2)]
    assert mlp_flops(shapes, backward=False) == 2 * (12 + 8)
    # backward: the weights' gradients of both layers, the input gradient of the second only
    assert mlp_flops(shapes) == 2 * (12 + 8) + 2 * (12 + 8) + 2 * 8


def test_cards_are_looked_up_by_their_exact_name():
    assert card_peaks("NVIDIA H100 80GB HBM3") == CardPeaks("H100 SXM", 67e12, 494.5e12, 3.35e12)
    assert card_peaks("NVIDIA H200") == CardPeaks("H200 SXM", 67e12, 494.5e12, 4.8e12)
    for other in ("NVIDIA H100 PCIe", "NVIDIA H200 NVL", "cpu", "x86_64"):
        assert card_peaks(other) is None
    assert all(0 < p.fp32_flops < p.tf32_flops and p.bandwidth > 0 for p in CARD_PEAKS.values())


def test_update_work_and_its_floor():
    shapes = [[(3, 4), (4, 2)], [(3, 4), (4, 1)]]
    work = ppo_update_work(shapes, samples=100, epochs=5, mini_batches=4, sample_bytes=40, parameter_bytes=200)
    assert work.flops == 5 * 100 * (mlp_flops(shapes[0]) + mlp_flops(shapes[1]))
    assert work.bytes == 5 * 100 * 40 + 5 * 4 * 9 * 200
    peaks = CardPeaks(
        "card", fp32_flops=work.flops / 0.002, tf32_flops=work.flops / 0.0005, bandwidth=work.bytes / 0.001
    )
    floor = Floor(work, peaks)
    assert floor.flop_seconds == pytest.approx(0.002) and floor.byte_seconds == pytest.approx(0.001)
    assert floor.seconds == pytest.approx(0.002) and floor.bound == "arithmetic"
    assert floor.fraction(0.008) == pytest.approx(0.25)
    assert "floor 2 ms on card (arithmetic" in floor.describe(0.008) and "25% reached" in floor.describe(0.008)
    record = floor.record({"update": 0.004, "iteration": 0.008})
    assert record["fraction_of_update"] == pytest.approx(0.5) and record["fraction_of_iteration"] == pytest.approx(0.25)
    assert record["tf32"] is False and record["flops_peak"] == peaks.fp32_flops
    # TF32 products (train.tf32): the arithmetic at the tensor cores' peak, here under the bytes' time
    tf32 = Floor(work, peaks, tf32=True)
    assert tf32.flop_seconds == pytest.approx(0.0005) and tf32.bound == "memory"
    assert tf32.seconds == pytest.approx(0.001) and "tf32" in tf32.describe() and tf32.record()["tf32"] is True
    memory = Floor(work, CardPeaks("slow memory", work.flops / 0.001, work.flops / 0.0001, work.bytes / 0.003))
    assert memory.bound == "memory" and memory.seconds == pytest.approx(0.003)
    with pytest.raises(ValueError, match="epochs=0 must be >= 1"):
        ppo_update_work(shapes, samples=100, epochs=0, mini_batches=4, sample_bytes=40, parameter_bytes=200)


def test_an_unknown_card_has_no_floor():
    work = ppo_update_work([[(3, 4)]], samples=10, epochs=1, mini_batches=1, sample_bytes=4, parameter_bytes=4)
    floor = Floor(work, card_peaks("cpu"))
    assert floor.seconds is None and floor.fraction(1.0) is None
    assert floor.describe(1.0).startswith("floor n/a")
    assert floor.record({"iteration": 1.0})["fraction_of_iteration"] is None


def test_linear_scaling():
    assert linear_scaling(4, 1e7, 3.8e7) == {"ideal_speedup": 4, "speedup": 3.8, "fraction_of_ideal": 0.95}
    with pytest.raises(ValueError, match="gpus=0 must be >= 1"):
        linear_scaling(0, 1e7, 1e7)


@pytest.mark.parametrize("sharing", ["parameter", "individual"])
def test_update_work_of_a_training_run(sharing):
    """The work read from a run's algorithm: its layers, samples and stored fields (observations,
    five scalars per sample, the action distribution's logits)."""
    from aquarium_warp.training import Trainer, make_config

    config = make_config(
        "tiny", {"train": {"num_worlds": 4, "iterations": 1, "quiet": True, "export": [], "sharing": sharing}}
    )
    trainer = Trainer(config)
    alg = trainer.runner.alg
    for work_of in (lambda: update_work(alg), lambda: rollout_work(alg, trainer.env.state)):
        with pytest.raises(ValueError, match="collected a rollout"):
            work_of()
    trainer.train(1)
    actor, critic = matmul_shapes(alg.actor), matmul_shapes(alg.critic)
    obs = actor[0][0]
    actions = actor[-1][1]
    assert [s[1] for s in actor] == [64, 64, actions] and [s[1] for s in critic] == [64, 64, 1]
    work = update_work(alg)
    samples = trainer.vec_env.num_envs * trainer.runner_cfg["num_steps_per_env"]
    epochs, batches = alg.num_learning_epochs, alg.num_mini_batches
    assert (work.samples, work.epochs, work.mini_batches) == (samples, epochs, batches)
    assert work.flops == epochs * samples * (mlp_flops(actor) + mlp_flops(critic))
    parameters = sum(p.numel() for model in (alg.actor, alg.critic) for p in model.parameters())
    assert work.bytes == epochs * samples * 4 * (obs + 5 + actions) + epochs * batches * 9 * 4 * parameters
    # the rollout: forward only; per row the observation read, then stored with the action, value,
    # log-probability, logits, reward (float32 each) and done (bool)
    rows, steps = trainer.vec_env.num_envs, trainer.runner_cfg["num_steps_per_env"]
    rollout = rollout_work(alg, trainer.env.state)
    assert (rollout.samples, rollout.steps) == (samples, steps)
    assert rollout.flops == samples * (mlp_flops(actor, backward=False) + mlp_flops(critic, backward=False))
    stored = 4 * (obs + 4 + actions) + alg.storage.dones.element_size()
    per_step = simulation_bytes(trainer.env.state) + 4 * parameters
    assert rollout.bytes == steps * per_step + rows * steps * (4 * obs + stored)
    trainer.close()


def test_rollout_work_and_its_floor():
    shapes = [[(3, 4), (4, 2)], [(3, 4), (4, 1)]]
    work = ppo_rollout_work(
        shapes, rows=10, steps=8, simulation_bytes=500, observation_bytes=12, stored_bytes=40, parameter_bytes=200
    )
    # forward only, every row of every step; the simulation and the parameters once per step
    assert work.flops == 8 * 10 * (2 * (12 + 8) + 2 * (12 + 4))
    assert work.bytes == 8 * (500 + 200) + 8 * 10 * (12 + 40)
    assert (work.samples, work.steps) == (80, 8)
    peaks = CardPeaks(
        "card", fp32_flops=work.flops / 0.001, tf32_flops=work.flops / 0.0001, bandwidth=work.bytes / 0.002
    )
    floor = Floor(work, peaks)
    assert floor.bound == "memory" and floor.seconds == pytest.approx(0.002)
    record = floor.record({"rollout": 0.004})
    assert record["fraction_of_rollout"] == pytest.approx(0.5)
    assert (record["rollout_flops"], record["rollout_bytes"], record["steps"]) == (work.flops, work.bytes, 8)
    assert "update_flops" not in record
    with pytest.raises(ValueError, match="steps=0 must be >= 1"):
        ppo_rollout_work(
            shapes, rows=10, steps=0, simulation_bytes=0, observation_bytes=0, stored_bytes=0, parameter_bytes=0
        )


def test_simulation_bytes_of_small_worlds():
    """Counted by hand from the field docs of `kernels/state.py` for 3 worlds of the default config."""
    from aquarium_warp import AquariumConfig, BatchedAquarium

    env = BatchedAquarium(AquariumConfig(), num_worlds=3, device="cpu", seed=0)
    W, C, Pc, P = 3, env.capacity, env.prey_capacity, env.predator_capacity
    L_prey, L_pred = env.state.observations.obs_prey.shape[2], env.state.observations.obs_predator.shape[2]
    K_prey, K_pred = env.state.observations.mask_prey.shape[2], env.state.observations.mask_predator.shape[2]
    # position, velocity, acceleration, heading (vec2 float32), alive (bool), age, replication_age,
    # starvation, handling (int32)
    agents = W * C * (4 * 8 + 1 + 4 * 4)
    # world_step, episode, episode_captures, prey and predator alive counts, seed, stream_world ([W] 4
    # bytes) and episode_return ([W, C] float32)
    worlds = W * 7 * 4 + W * C * 4
    actions = W * Pc * 4 + W * P * 4
    # obs (float32), masks (bool), neighbour slots (int32) per observer type
    observations = W * Pc * (4 * L_prey + K_prey + 4 * K_prey) + W * P * (4 * L_pred + K_pred + 4 * K_pred)
    # reward (float32), terminated, truncated (bool) per slot; captures (int32), episode_ended (bool),
    # ended_length, ended_captures (int32) per world; ended_return ([W, 2] float32)
    outputs = W * C * (4 + 1 + 1) + W * (4 + 1 + 4 + 4) + W * 2 * 4
    assert simulation_bytes(env.state) == 2 * (agents + worlds) + actions + observations + outputs
    env.close()
