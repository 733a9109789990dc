"""The PPO update's hardware floor (`training/floors.py`): the arithmetic and bytes counted by hand
for small networks, the card table, and the floor's reading (unknown card: n/a)."""

from __future__ import annotations

import os

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest

from aquarium_warp.training.floors import (
    CARD_PEAKS,
    CardPeaks,
    UpdateFloor,
    card_peaks,
    linear_scaling,
    matmul_shapes,
    mlp_flops,
    ppo_update_work,
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
    floor = UpdateFloor(work, peaks)
    assert floor.flop_seconds == pytest.approx(0.002) and floor.byte_seconds == pytest.approx(0.001)
    assert floor.seconds == pytest.approx(0.002) and floor.bound == "arithmetic"
    assert floor.fraction(0.008) == pytest.approx(0.25)
    assert "floor 2 ms on card (arithmetic" in floor.describe(0.008) and "25% reached" in floor.describe(0.008)
    record = floor.record({"update": 0.004, "iteration": 0.008})
    assert record["fraction_of_update"] == pytest.approx(0.5) and record["fraction_of_iteration"] == pytest.approx(0.25)
    assert record["tf32"] is False and record["flops_peak"] == peaks.fp32_flops
    # TF32 products (train.tf32): the arithmetic at the tensor cores' peak, here under the bytes' time
    tf32 = UpdateFloor(work, peaks, tf32=True)
    assert tf32.flop_seconds == pytest.approx(0.0005) and tf32.bound == "memory"
    assert tf32.seconds == pytest.approx(0.001) and "tf32" in tf32.describe() and tf32.record()["tf32"] is True
    memory = UpdateFloor(work, CardPeaks("slow memory", work.flops / 0.001, work.flops / 0.0001, work.bytes / 0.003))
    assert memory.bound == "memory" and memory.seconds == pytest.approx(0.003)
    with pytest.raises(ValueError, match="epochs=0 must be >= 1"):
        ppo_update_work(shapes, samples=100, epochs=0, mini_batches=4, sample_bytes=40, parameter_bytes=200)


def test_an_unknown_card_has_no_floor():
    work = ppo_update_work([[(3, 4)]], samples=10, epochs=1, mini_batches=1, sample_bytes=4, parameter_bytes=4)
    floor = UpdateFloor(work, card_peaks("cpu"))
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
    with pytest.raises(ValueError, match="collected a rollout"):
        update_work(alg)
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
    trainer.close()
