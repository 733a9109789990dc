"""Native vector envs (`aquarium_warp.interop.gymnasium`, `aquarium_warp.interop.sb3`): rows against
`BatchedAquarium` stepped directly with the same seed and actions (dead slots, respawns, auto-reset),
against rsl-rl's adapter in team mode, seeding, buffers, bad input, Gymnasium's episode statistics and
a short Stable-Baselines3 PPO run."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium.wrappers.vector import RecordEpisodeStatistics

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.interop.gymnasium import AquariumRows, AquariumVectorEnv

# Respawn off, starvation after 12 steps, reproduction: slots empty and refill, episodes end early.
DYNAMIC = AquariumConfig(
    width=300.0,
    height=300.0,
    prey_count=5,
    predator_count=2,
    max_steps=40,
    respawn_captured_prey=False,
    predator_starvation_steps=12,
    prey_reproduction=True,
    prey_replication_age=8,
    max_prey=9,
)
# Respawn on (the paper's setting): every world ends by truncation at max_steps.
RESPAWN = AquariumConfig(width=200.0, height=200.0, prey_count=6, predator_count=2, max_steps=25)


def expected_rows(env: BatchedAquarium, active: np.ndarray):
    """Rows (predators, then prey slots, per world) of the step `env` just made, from its outputs with a
    per-row loop; `active` (rows live before the step) is updated in place."""
    obs, rew, term, trunc, _ = env.outputs
    captured = env.state.torch.captured[:, : env.prey_capacity].numpy()
    out = {k: [] for k in ("obs", "reward", "terminated", "truncated")}
    row = 0
    for w in range(env.num_worlds):
        for t in ("predator", "prey"):
            alive = env.alive[t][w].numpy()
            for s in range(alive.shape[0]):
                died = bool(term[t][w, s]) or (t == "prey" and bool(captured[w, s]))
                if active[row]:
                    out["terminated"].append(died)
                    out["truncated"].append(bool(trunc[t][w, s]) and not died)
                    out["reward"].append(float(rew[t][w, s]))
                else:  # an empty slot: its row ends (a termination) when the slot is filled again
                    out["terminated"].append(bool(alive[s]))
                    out["truncated"].append(False)
                    out["reward"].append(0.0)
                out["obs"].append(obs[t][w, s].numpy())
                active[row] = bool(alive[s])
                row += 1
    return {k: np.array(v) for k, v in out.items()}


def test_rows_match_batched_aquarium_with_dead_slots_and_refills():
    vec = AquariumVectorEnv(DYNAMIC, num_worlds=3)
    ref = BatchedAquarium(DYNAMIC, num_worlds=3, seed=21)
    try:
        S = 2 + DYNAMIC.prey_capacity
        assert vec.num_envs == 3 * S and vec.single_observation_space.shape == (DYNAMIC.observation_size("prey"),)
        obs, infos = vec.reset(seed=21)
        active = np.concatenate(
            [np.concatenate([ref.alive["predator"][w].numpy(), ref.alive["prey"][w].numpy()]) for w in range(3)]
        )
        assert np.array_equal(infos["active"], active) and not active.all()  # reproduction slots start empty
        assert np.array_equal(
            obs[active],
            np.concatenate([ref.observations["predator"], ref.observations["prey"]], axis=1).reshape(3 * S, -1)[active],
        )
        rng = np.random.default_rng(0)
        seen = dict(empty=0, refilled=0, died=0, truncated=0)
        for step in range(90):  # past two world episodes
            actions = rng.integers(0, 16, vec.num_envs)
            a = actions.reshape(3, S)
            ref.step({"predator": torch.from_numpy(a[:, :2].copy()), "prey": torch.from_numpy(a[:, 2:].copy())})
            was_active = active.copy()
            exp = expected_rows(ref, active)
            obs, rewards, terminations, truncations, infos = vec.step(actions)
            assert np.array_equal(obs, np.stack(exp["obs"])), f"step {step}"
            assert np.array_equal(rewards, exp["reward"].astype(np.float32)), f"step {step}"
            assert np.array_equal(terminations, exp["terminated"]), f"step {step}"
            assert np.array_equal(truncations, exp["truncated"]), f"step {step}"
            assert np.array_equal(infos["active"], active), f"step {step}"
            # Independent of the formula: empty rows show zeros, never both flags.
            assert not obs[~active].any() and not (terminations & truncations).any()
            seen["empty"] += int((~was_active & ~active).sum())
            seen["refilled"] += int((~was_active & active).sum())
            seen["died"] += int((was_active & terminations).sum())
            seen["truncated"] += int(truncations.sum())
        assert all(v > 0 for v in seen.values()), seen
    finally:
        vec.close()
        ref.close()


def test_respawns_and_world_ends_with_respawn_on():
    W = 16
    vec = AquariumVectorEnv(RESPAWN, num_worlds=W, seed=5, array_type="torch")
    try:
        obs, _ = vec.reset()
        assert isinstance(obs, torch.Tensor) and obs.shape == (W * 8, RESPAWN.observation_size("prey"))
        rng = np.random.default_rng(1)
        captures = prey_terminations = caught_at_the_end = 0
        for step in range(1, 4 * RESPAWN.max_steps + 1):
            obs, rewards, terminations, truncations, infos = vec.step(torch.from_numpy(rng.integers(0, 16, W * 8)))
            assert bool(infos["active"].all())  # respawn on: no slot is ever empty
            t, tr = terminations.view(W, 8), truncations.view(W, 8)
            # Every capture ends one prey row (the prey respawns: a new episode in the same row); nothing else ends.
            captures += int(vec.aquarium.outputs.info["captures"].sum())
            prey_terminations += int(t[:, 2:].sum())
            assert not t[:, :2].any()  # predators never starve within 25 steps
            assert not (t & tr).any()  # a prey caught in the last step is terminated, not truncated
            # Every world's episode ends at max_steps: each agent not caught in that step is truncated.
            if step % RESPAWN.max_steps == 0:
                assert bool((t | tr).all()), f"step {step}"
                caught_at_the_end += int(t.sum())
            else:
                assert not tr.any(), f"step {step}"
        assert captures > 0 and prey_terminations == captures and caught_at_the_end > 0
    finally:
        vec.close()


@pytest.mark.slow  # importing rsl-rl and tensordict
def test_team_rows_match_the_rsl_rl_adapter():
    vec_env = pytest.importorskip("aquarium_warp.training.vec_env", reason="needs the training extra (rsl-rl)")
    from aquarium_warp.heuristics import make_policy

    vec = AquariumVectorEnv(DYNAMIC, num_worlds=2, seed=8, team="prey", opponent="naivchase")
    ref_env = BatchedAquarium(DYNAMIC, num_worlds=2, seed=8)
    ref = vec_env.AquariumVecEnv(
        ref_env, team="prey", opponent=make_policy("naivchase", ref_env, "predator"), metrics_every=0
    )
    try:
        assert vec.num_envs == ref.num_envs == 2 * DYNAMIC.prey_capacity
        obs, _ = vec.reset(seed=8)
        assert np.array_equal(obs, ref.get_observations()["policy"].numpy())
        rng = np.random.default_rng(2)
        ended = 0
        for step in range(60):
            actions = rng.integers(0, 16, vec.num_envs)
            obs, rewards, terminations, truncations, _ = vec.step(actions)
            ref_obs, ref_rewards, ref_dones, extras = ref.step(torch.from_numpy(actions).float().unsqueeze(1))
            assert np.array_equal(obs, ref_obs["policy"].numpy()), f"step {step}"
            assert np.array_equal(rewards, ref_rewards.numpy()), f"step {step}"
            assert np.array_equal(terminations | truncations, ref_dones.numpy().astype(bool)), f"step {step}"
            assert np.array_equal(truncations, extras["time_outs"].numpy()), f"step {step}"
            ended += int(terminations.sum())
        assert ended > 0
    finally:
        vec.close()
        ref_env.close()


def test_seeding_and_alternating_buffers():
    vec = AquariumVectorEnv(RESPAWN, num_worlds=2)
    try:
        first = vec.reset(seed=3)[0].copy()
        ref = BatchedAquarium(RESPAWN, num_worlds=2, seed=3)
        assert np.array_equal(first[:2], ref.observations["predator"][0].numpy())  # the episode of seed 3
        ref.close()
        assert not np.array_equal(vec.reset(seed=4)[0], first)
        assert np.array_equal(vec.reset(seed=3)[0], first)
        sequence = [vec.reset()[0].copy() for _ in range(2)]  # unseeded: a sequence fixed by the last seed
        vec.reset(seed=3)
        assert all(np.array_equal(vec.reset()[0], x) for x in sequence)
        assert not np.array_equal(sequence[0], sequence[1]) and not np.array_equal(sequence[0], first)
        # The action spaces are seeded too.
        vec.reset(seed=9)
        a = vec.action_space.sample()
        vec.reset(seed=9)
        assert np.array_equal(a, vec.action_space.sample())
        # Zero copy on the CPU: observations are views of the two buffers, alternating between steps.
        obs1 = vec.step(a)[0]
        kept = obs1.copy()
        obs2 = vec.step(a)[0]
        assert np.shares_memory(obs1, vec.rows._obs[1].numpy()) or np.shares_memory(obs1, vec.rows._obs[0].numpy())
        assert not np.shares_memory(obs1, obs2) and np.array_equal(obs1, kept)  # valid until the step after next
    finally:
        vec.close()
    # The constructor's seed fixes the sequence of unseeded resets.
    x, y = AquariumVectorEnv(RESPAWN, seed=7), AquariumVectorEnv(RESPAWN, seed=7)
    assert np.array_equal(x.reset()[0], y.reset()[0])
    x.close()
    y.close()


def test_bad_input():
    vec = AquariumVectorEnv(RESPAWN, num_worlds=2)
    try:
        n = vec.num_envs
        for actions, match in [
            (np.zeros(n + 1, int), "shape"),
            (np.full(n, 16), r"\[0, 15\]"),
            (np.full(n, -1), r"\[0, 15\]"),
            (np.full(n, 0.5), "fractions"),
            (np.zeros(n, bool), "integers"),
            (["a"] * n, "integers"),
        ]:
            with pytest.raises(ValueError, match=match):
                vec.step(actions)
        # a tensor on another device ("meta": one that every machine has) is refused as BatchedAquarium.step
        # refuses it, before torch would copy it or fail on it; the world does not step
        before = vec.rows.aquarium.state.torch.position.clone()
        with pytest.raises(ValueError, match=r"^actions are on meta, but the env runs on cpu$"):
            vec.step(torch.zeros(n, dtype=torch.int64, device="meta"))
        with pytest.raises(ValueError, match=r"actions\['prey'\] is on meta, but the env runs on cpu"):
            vec.aquarium.step({t: a.to("meta") for t, a in vec.aquarium.actions.items()})
        assert torch.equal(vec.rows.aquarium.state.torch.position, before)
        with pytest.raises(ValueError, match="seed"):
            vec.reset(seed=[1, 2])
        with pytest.raises(ValueError, match="seed"):
            vec.reset(seed=-1)
    finally:
        vec.close()
    for kwargs, match in [
        (dict(team="fish"), "team"),
        (dict(array_type="jax"), "array_type"),
        (dict(team="prey"), "opponent"),
        (dict(opponent="naivchase"), "opponent"),
        (dict(team="prey", opponent="nochase"), "heuristic|name|policy"),
        (dict(validate_actions=1), "validate_actions"),
    ]:
        with pytest.raises(ValueError, match=match):
            AquariumVectorEnv(RESPAWN, **kwargs)
    with pytest.raises(ValueError, match="auto_reset"):
        AquariumRows(aquarium=BatchedAquarium(RESPAWN, auto_reset=False))
    with pytest.raises(ValueError, match="aquarium="):
        AquariumRows(RESPAWN, aquarium=BatchedAquarium(RESPAWN))


def test_gymnasium_episode_statistics_count_row_episodes():
    vec = RecordEpisodeStatistics(AquariumVectorEnv(RESPAWN, num_worlds=2, seed=0))
    try:
        vec.reset()
        lengths = []
        for _ in range(RESPAWN.max_steps):
            *_, infos = vec.step(vec.action_space.sample())
            if "episode" in infos:
                lengths += infos["episode"]["l"][infos["_episode"]].tolist()
        # Every row's episode ended by step max_steps (a capture or the world's end); the longest lasted it all.
        assert len(lengths) >= vec.num_envs and max(lengths) == RESPAWN.max_steps
    finally:
        vec.close()


@pytest.mark.slow
def test_stable_baselines3_ppo_trains_and_seeds(tmp_path):
    sb3 = pytest.importorskip("stable_baselines3", reason="needs the interop extra: pip install -e '.[interop]'")
    from aquarium_warp.interop.sb3 import AquariumSB3VecEnv

    def train(seed):
        vec = AquariumSB3VecEnv(RESPAWN, num_worlds=4)
        model = sb3.PPO("MlpPolicy", vec, n_steps=32, batch_size=256, n_epochs=1, device="cpu", seed=seed)
        model.set_logger(sb3.common.logger.configure(str(tmp_path), []))
        before = [p.detach().clone() for p in model.policy.parameters()]
        model.learn(total_timesteps=2 * 32 * vec.num_envs)  # 2,048 env steps: two PPO iterations
        assert model.num_timesteps == 2 * 32 * vec.num_envs == 2048
        after = [p.detach().clone() for p in model.policy.parameters()]
        assert any(not torch.equal(a, b) for a, b in zip(before, after))
        obs = vec.reset()
        actions, _ = model.predict(obs, deterministic=True)
        assert actions.shape == (vec.num_envs,) and ((0 <= actions) & (actions < 16)).all()
        first = model.rollout_buffer.observations[0].copy()
        vec.close()
        return after, first

    a, first_a = train(0)
    b, first_b = train(0)
    c, first_c = train(1)
    # PPO(seed=...) seeds the env too: the same seed gives the same rollouts and weights, another seed not.
    assert np.array_equal(first_a, first_b) and all(torch.equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(first_a, first_c)


def test_sb3_vec_env_dones_and_infos():
    pytest.importorskip("stable_baselines3", reason="needs the interop extra: pip install -e '.[interop]'")
    from aquarium_warp.interop.sb3 import AquariumSB3VecEnv

    vec = AquariumSB3VecEnv(DYNAMIC, num_worlds=2)
    gym_vec = AquariumVectorEnv(DYNAMIC, num_worlds=2)
    try:
        vec.seed(4)  # what PPO(seed=4) does
        assert np.array_equal(vec.reset(), gym_vec.reset(seed=4)[0])
        assert vec.get_attr("render_mode") == [None] * vec.num_envs
        assert vec.env_is_wrapped(object, [0, 1]) == [False] * 2
        rng = np.random.default_rng(3)
        for step in range(45):
            actions = rng.integers(0, 16, vec.num_envs)
            obs, rewards, dones, infos = vec.step(actions)
            g_obs, g_rewards, term, trunc, _ = gym_vec.step(actions)
            assert np.array_equal(obs, g_obs) and np.array_equal(rewards, g_rewards), f"step {step}"
            assert np.array_equal(dones, term | trunc) and len(infos) == vec.num_envs
            assert [i for i, info in enumerate(infos) if info] == np.flatnonzero(dones).tolist()
            assert all(infos[i]["TimeLimit.truncated"] == bool(trunc[i]) for i in np.flatnonzero(dones))
            assert np.array_equal(vec.active, gym_vec.rows.active.numpy())
    finally:
        vec.close()
        gym_vec.close()
