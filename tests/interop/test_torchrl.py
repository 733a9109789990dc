"""The TorchRL env (specs, agreement with BatchedAquarium stepped directly, deaths, births and auto-resets)
and a short BenchMARL MAPPO run on the `aquarium/predator_prey` task. Needs the torchrl extra, which pip
cannot install beside tensordict 0.15 (see .ci/constraints-torchrl.txt): skipped without it."""

from __future__ import annotations

import tempfile

import pytest
import torch

pytest.importorskip(
    "torchrl",
    reason="needs the torchrl extra: pip install -c .ci/constraints-torchrl.txt "
    "-e '.[torchrl]' (in its own environment)",
)

from torchrl.envs.utils import check_env_specs

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.interop.torchrl import AquariumTorchRLEnv

TYPES = ("prey", "predator")
# Respawn off, starvation and reproduction: agents leave and are born, episodes end early or at 40 steps.
CFG_CHANGES = AquariumConfig(
    width=300.0,
    height=300.0,
    prey_count=6,
    predator_count=2,
    max_steps=40,
    respawn_captured_prey=False,
    predator_starvation_steps=15,
    prey_reproduction=True,
    prey_replication_age=12,
    max_prey=10,
)
CFG_DEFAULT_LIKE = AquariumConfig(width=400.0, height=400.0, prey_count=8, max_steps=30)


@pytest.mark.parametrize("cfg", [CFG_DEFAULT_LIKE, CFG_CHANGES], ids=["respawn", "deaths_and_births"])
def test_check_env_specs(cfg):
    env = AquariumTorchRLEnv(cfg, num_worlds=5, device="cpu", seed=0)
    assert env.batch_size == torch.Size([5])
    assert env.group_map == {
        "prey": [f"prey_{i}" for i in range(env.aquarium.prey_capacity)],
        "predator": [f"predator_{i}" for i in range(cfg.predator_count)],
    }
    check_env_specs(env, seed=0)
    env.close()


def action_policy(num_worlds, slots, seed):
    gen = torch.Generator().manual_seed(seed)
    taken = []

    def policy(td):
        actions = {t: torch.randint(0, 16, (num_worlds, n), generator=gen) for t, n in slots.items()}
        taken.append(actions)
        for t, a in actions.items():
            td.set((t, "action"), a)
        return td

    return policy, taken


def test_rollout_follows_batched_aquarium_through_deaths_births_and_resets():
    W, steps = 16, 100
    env = AquariumTorchRLEnv(CFG_CHANGES, num_worlds=W, device="cpu", seed=3)
    twin = BatchedAquarium(CFG_CHANGES, num_worlds=W, device="cpu", seed=3)
    policy, taken = action_policy(W, env.slots, seed=1)
    rollout = env.rollout(steps, policy=policy, break_when_any_done=False)
    assert rollout.batch_size == torch.Size([W, steps])
    for t in TYPES:
        assert torch.equal(rollout[t, "observation"][:, 0], twin.observations[t])
    deaths = births = ends = 0
    for k in range(steps):
        alive_before = {t: twin.alive[t].clone() for t in TYPES}
        obs, rewards, terminated, truncated, info = twin.step(taken[k])
        nxt = rollout[:, k]["next"]
        for t in TYPES:
            assert torch.equal(nxt[t, "observation"], obs[t]), f"step {k} {t}"
            assert torch.equal(nxt[t, "reward"][..., 0], rewards[t])
            # flags belong to the agents that acted in the step (not to a prey born in it)
            term, trunc = terminated[t] & alive_before[t], truncated[t] & alive_before[t]
            assert torch.equal(nxt[t, "terminated"][..., 0], term)
            assert torch.equal(nxt[t, "truncated"][..., 0], trunc)
            assert torch.equal(nxt[t, "done"][..., 0], term | trunc)
            # live agents may take every action; empty slots only action 0
            mask = nxt[t, "action_mask"]
            assert torch.equal(mask[..., 1:].all(-1), twin.alive[t]) and mask[..., 0].all()
            deaths += int(term.sum())
            births += int((twin.alive[t] & ~alive_before[t] & ~info["episode_ended"][:, None]).sum())
        ended = info["episode_ended"]
        ends += int(ended.sum())
        assert torch.equal(nxt["done"][:, 0], ended)
        # an episode ends by truncation after max_steps, otherwise by termination (no prey or predator left)
        at_limit = ended & (info["episode_length"] == CFG_CHANGES.max_steps)
        assert torch.equal(nxt["truncated"][:, 0], at_limit)
        assert torch.equal(nxt["terminated"][:, 0], ended & ~at_limit)
        # the worlds reset themselves: the next step starts from these observations
        if k + 1 < steps:
            for t in TYPES:
                assert torch.equal(rollout[t, "observation"][:, k + 1], obs[t])
    assert deaths > 0 and births > 0 and ends > W  # the rollout went through all of it
    env.close()


def test_same_seed_same_rollout():
    def run(seed):
        env = AquariumTorchRLEnv(CFG_DEFAULT_LIKE, num_worlds=4, device="cpu", seed=0)
        env.set_seed(seed)
        policy, _ = action_policy(4, env.slots, seed=5)
        out = env.rollout(40, policy=policy, break_when_any_done=False)
        env.close()
        return out

    a, b, c = run(7), run(7), run(8)
    assert (a == b).all()
    assert not torch.equal(a["next", "prey", "observation"], c["next", "prey", "observation"])


def test_benchmarl_mappo_trains_on_the_task():
    pytest.importorskip("benchmarl", reason="needs the torchrl extra (BenchMARL)")
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    from aquarium_warp.interop.benchmarl import AquariumTask

    task = AquariumTask.PREDATOR_PREY.get_task(
        config=dict(
            width=300.0,
            height=300.0,
            prey_count=4,
            predator_count=1,
            max_steps=50,
            respawn_captured_prey=True,
            prey_reproduction=False,
            cpu_threads=1,
        )
    )
    cfg = ExperimentConfig.get_from_yaml()
    cfg.sampling_device = cfg.train_device = cfg.buffer_device = "cpu"
    cfg.on_policy_collected_frames_per_batch = 200  # 4 worlds x 50 steps
    cfg.on_policy_n_envs_per_worker = 4
    cfg.on_policy_n_minibatch_iters = 1
    cfg.on_policy_minibatch_size = 100
    cfg.max_n_iters = 2
    cfg.evaluation = False
    cfg.loggers = []
    cfg.create_json = False
    cfg.checkpoint_at_end = False
    model = MlpConfig.get_from_yaml()
    model.num_cells = [32]
    with tempfile.TemporaryDirectory() as folder:
        cfg.save_folder = folder
        experiment = Experiment(
            task=task,
            algorithm_config=MappoConfig.get_from_yaml(),
            model_config=model,
            critic_model_config=model,
            seed=0,
            config=cfg,
        )
        assert set(experiment.group_map) == {"prey", "predator"}
        before = [p.detach().clone() for p in experiment.policy.parameters()]
        experiment.run()
    assert experiment.n_iters_performed == 2 and experiment.total_frames == 400
    assert any(not torch.equal(a, b) for a, b in zip(before, experiment.policy.parameters()))
