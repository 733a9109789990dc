"""The observed current (docs/model.md "Flow fields", `observe_flow`): two values after the own 5-tuple,
the current at the observer divided by its own max speed, clipped to [-1, 1], mapped by (c + 1) / 2
(and then 2x - 1 in the "-1..1" range); the rest of the row as without it; sizes and spaces grown by 2."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium, aquarium_v1
from aquarium_warp.config import FlowConfig
from aquarium_warp.heuristics import make_policy

# Prey max speed 4, predators 5 (the defaults): a current of (3, -6) px/step is (0.75, -1.5) prey
# speeds (the second clipped to -1) and (0.6, -1.2) predator speeds (clipped likewise).
UNIFORM = AquariumConfig(
    width=300.0,
    height=260.0,
    prey_count=6,
    predator_count=2,
    observe_flow=True,
    flow=FlowConfig("uniform", velocity=(3.0, -6.0)),
)
EXPECTED = {
    "0..1": {"prey": (0.875, 0.0), "predator": (0.8, 0.0)},
    "-1..1": {"prey": (0.75, -1.0), "predator": (0.6, -1.0)},
}


@pytest.mark.parametrize("observation_range", ["0..1", "-1..1"])
def test_uniform_current_observed_by_hand(observation_range):
    cfg = dataclasses.replace(UNIFORM, observation_range=observation_range)
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=3)
    plain = BatchedAquarium(dataclasses.replace(cfg, observe_flow=False), num_worlds=2, device="cpu", seed=3)
    assert env.observation_size == {"prey": 5 + 6 * 4 + 2, "predator": 5 + 6 * 4 + 2}
    for _ in range(3):  # after the reset and after two steps: same state with and without the option
        for t in ("prey", "predator"):
            obs, ref = env.observations[t].numpy(), plain.observations[t].numpy()
            assert obs.shape[-1] == ref.shape[-1] + 2
            np.testing.assert_array_equal(obs[..., :5], ref[..., :5])
            np.testing.assert_array_equal(obs[..., 7:], ref[..., 5:])  # neighbour blocks unchanged
            expected = np.broadcast_to(np.float32(EXPECTED[observation_range][t]), obs[..., 5:7].shape)
            np.testing.assert_array_equal(obs[..., 5:7], expected)
        actions = {
            "prey": torch.full((2, 6), 3, dtype=torch.int32),
            "predator": torch.full((2, 2), 9, dtype=torch.int32),
        }
        env.step(actions)
        plain.step(actions)


def test_vortex_current_observed_by_hand():
    """A steady vortex (centre (100, 100), strength 2, core 50): an agent 25 px right of the centre, in
    the core, feels (0, 2 * 25 / 50) = (0, 1) px/step; 200 px left of it (on a 600 px torus) it feels
    2 * 50 / 200 = 0.5 px/step, (0, -0.5). As prey speeds (4): (0, 0.25) and (0, -0.125)."""
    cfg = AquariumConfig(
        width=600.0,
        height=600.0,
        prey_count=2,
        predator_count=1,
        observe_flow=True,
        flow=FlowConfig("vortex", centre=(100.0, 100.0), strength=2.0, core_radius=50.0),
    )
    env = BatchedAquarium(cfg, num_worlds=1, device="cpu", seed=0)
    position = env.state.torch.position[0].clone()
    position[0] = torch.tensor([125.0, 100.0])
    position[1] = torch.tensor([500.0, 100.0])
    env.set_state(world=0, position=position)
    obs = env.observations["prey"][0, :, 5:7].numpy()
    np.testing.assert_allclose(obs, [[0.5, 0.625], [0.5, 0.4375]], atol=1e-6)


def test_flow_observation_spaces():
    """Every place that states the observation length agrees with the rows: env, PettingZoo, training."""
    pytest.importorskip("rsl_rl")
    from aquarium_warp.training.vec_env import AquariumVecEnv

    par = aquarium_v1.parallel_env(config=UNIFORM)
    obs, _ = par.reset(seed=0)
    for agent, o in obs.items():
        assert par.observation_space(agent).shape == o.shape == (5 + 6 * 4 + 2,)
        assert par.observation_space(agent).contains(o)
    env = BatchedAquarium(UNIFORM, num_worlds=2, device="cpu", seed=0, auto_reset=True)
    vec = AquariumVecEnv(env, "prey", make_policy("naivchase", env, "predator"))
    assert vec.observation_size == 5 + 6 * 4 + 2 == vec.get_observations()["policy"].shape[-1]
