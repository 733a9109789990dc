"""Native vector envs (`aquarium_warp.interop.gymnasium`, `aquarium_warp.interop.sb3`): rows against
`BatchedAquarium` stepped directly with the same seed and actions (dead slots, respawns, auto-reset),
against rsl-rl's adapter in team mode, seeding, buffers, bad input, Gymnasium's episode statistics and
a short Stable-Baselines3 PPO run."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode
from rows_reference import RowsReference

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


def check_rows(vec: AquariumVectorEnv, ref: RowsReference, steps: int, seed: int) -> dict:
    """Step `vec` and `ref` with the same random actions; every output equal. Returns counts of what
    happened, for the caller to check the case was covered."""
    obs, infos = vec.reset(seed=seed)
    assert np.array_equal(obs, ref.observations()) and np.array_equal(infos["active"], ref.active)
    assert infos["_active"].all() and infos["_active"].shape == (vec.num_envs,)
    rng = np.random.default_rng(seed)
    seen = dict(empty=0, filled=0, died=0, truncated=0)
    active = ref.active.copy()
    for step in range(steps):
        actions = rng.integers(0, 16, vec.num_envs)
        exp = ref.step(actions)
        obs, rewards, terminations, truncations, infos = vec.step(actions)
        assert np.array_equal(obs, exp["obs"]), f"step {step}"
        assert np.array_equal(rewards, exp["reward"]), f"step {step}"
        assert np.array_equal(terminations, exp["terminated"]), f"step {step}"
        assert np.array_equal(truncations, exp["truncated"]), f"step {step}"
        assert np.array_equal(infos["active"], exp["active"]), f"step {step}"
        ended = terminations | truncations
        if vec.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP and ended.any():
            assert np.array_equal(infos["_final_obs"], ended) and np.array_equal(infos["_final_info"], ended)
            for i in range(vec.num_envs):
                assert (infos["final_obs"][i] is None) == (exp["final_obs"][i] is None), f"step {step} row {i}"
                if exp["final_obs"][i] is not None:
                    assert np.array_equal(infos["final_obs"][i], exp["final_obs"][i]), f"step {step} row {i}"
            assert np.array_equal(infos["final_info"]["active"][ended], truncations[ended])
        else:
            assert "final_obs" not in infos and "final_info" not in infos
        # Independent of the reference: rows that did not act take no reward and no flag; empty rows see zeros.
        assert not (rewards[~active] != 0).any() and not ended[~active].any() and not (terminations & truncations).any()
        assert not obs[terminations].any() or vec.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
        seen["empty"] += int((~active & ~infos["active"]).sum())
        seen["filled"] += int((~active & infos["active"]).sum())
        seen["died"] += int(terminations.sum())
        seen["truncated"] += int(truncations.sum())
        active = infos["active"]
    return seen


def test_same_step_rows_match_the_reference_with_dead_slots_and_births():
    vec = AquariumVectorEnv(DYNAMIC, num_worlds=3, autoreset_mode="same_step")
    ref = RowsReference(DYNAMIC, 3, 21, "same_step")
    try:
        assert vec.num_envs == 3 * (2 + DYNAMIC.prey_capacity)
        assert vec.single_observation_space.shape == (DYNAMIC.observation_size("prey"),)
        assert vec.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
        assert type(vec).metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP  # the class default untouched
        seen = check_rows(vec, ref, 90, seed=21)  # past two world episodes
        assert all(seen[k] > 0 for k in ("empty", "filled", "died", "truncated")), seen
        # The simulation's trajectory is BatchedAquarium's own (with its auto-reset), bit for bit.
        assert torch.equal(vec.aquarium.state.torch.position, ref.ref.state.torch.position)
    finally:
        vec.close()
        ref.close()


@pytest.mark.parametrize("config, seed", [(DYNAMIC, 21), (DYNAMIC, 4), (RESPAWN, 5)])
def test_next_step_rows_match_the_reference(config, seed):
    vec = AquariumVectorEnv(config, num_worlds=1)  # next-step: the default
    ref = RowsReference(config, 1, seed, "next_step")
    try:
        assert vec.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        seen = check_rows(vec, ref, 3 * config.max_steps, seed=seed)
        assert seen["died"] > 0 and seen["truncated"] > 0, seen
        # After the last world end's reset step, the env's world is `ref`'s (BatchedAquarium's auto-reset).
        if not ref.reset_step:
            assert torch.equal(vec.aquarium.state.torch.position, ref.ref.state.torch.position)
    finally:
        vec.close()
        ref.close()


def test_next_step_reset_steps_by_hand():
    """Hand-checked next-step semantics: a world's end, then its reset step (reward 0, no flags, the
    action ignored: two different actions give the same next first observation)."""
    cfg = RESPAWN.replace(max_steps=3, capture_probability=0.0)  # no capture: every agent lives to the end
    envs = [AquariumVectorEnv(cfg, num_worlds=2) for _ in range(2)]
    try:
        for vec in envs:
            vec.reset(seed=0)
        zeros = np.zeros(envs[0].num_envs, int)
        for _ in range(2):
            outs = [vec.step(zeros) for vec in envs]
            assert not outs[0][3].any()
        ends = [vec.step(zeros) for vec in envs]  # step 3 = max_steps: every agent's episode ends
        _, rewards, terminations, truncations, infos = ends[0]
        assert truncations.all() and not terminations.any() and not infos["active"].any()
        assert np.array_equal(ends[0][0], ends[1][0])
        last = ends[0][0].copy()
        reset = [vec.step(np.full(vec.num_envs, a)) for vec, a in zip(envs, (0, 9))]  # the reset step
        for _, rewards, terminations, truncations, infos in reset:
            assert not rewards.any() and not terminations.any() and not truncations.any() and infos["active"].all()
        assert np.array_equal(reset[0][0], reset[1][0]) and not np.array_equal(reset[0][0], last)
        fresh = BatchedAquarium(
            cfg, num_worlds=2, seed=0
        )  # the next episode's first state, as its auto-reset spawns it
        for _ in range(3):
            fresh.step({t: torch.zeros_like(a) for t, a in fresh.actions.items()})
        first = torch.cat([fresh.observations["predator"], fresh.observations["prey"]], dim=1).reshape(
            envs[0].num_envs, -1
        )
        assert np.array_equal(reset[0][0], first.numpy())
        fresh.close()
    finally:
        for vec in envs:
            vec.close()


def test_respawns_and_world_ends_with_respawn_on():
    W = 16
    vec = AquariumVectorEnv(RESPAWN, num_worlds=W, seed=5, array_type="torch", autoreset_mode="same_step")
    try:
        obs, _ = vec.reset()
        assert isinstance(obs, torch.Tensor) and obs.shape == (W * 8, RESPAWN.observation_size("prey"))
        rng = np.random.default_rng(1)
        captures = prey_terminations = caught_at_the_end = 0
        for step in range(1, 4 * RESPAWN.max_steps + 1):
            obs, rewards, terminations, truncations, infos = vec.step(torch.from_numpy(rng.integers(0, 16, W * 8)))
            assert bool(infos["active"].all())  # respawn on, same-step: no slot is ever empty
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
                assert all(isinstance(x, torch.Tensor) for x in infos["final_obs"])
            else:
                assert not tr.any(), f"step {step}"
        assert captures > 0 and prey_terminations == captures and caught_at_the_end > 0
    finally:
        vec.close()


@pytest.mark.slow  # importing rsl-rl and tensordict
def test_team_rows_match_the_rsl_rl_adapter():
    vec_env = pytest.importorskip("aquarium_warp.training.vec_env", reason="needs the training extra (rsl-rl)")
    from aquarium_warp.heuristics import make_policy

    vec = AquariumVectorEnv(
        DYNAMIC, num_worlds=2, seed=8, team="prey", opponent="naivchase", autoreset_mode="same_step"
    )
    ref_env = BatchedAquarium(DYNAMIC, num_worlds=2, seed=8)
    ref = vec_env.AquariumVecEnv(
        ref_env, team="prey", opponent=make_policy("naivchase", ref_env, "predator"), metrics_every=0
    )
    try:
        assert vec.num_envs == ref.num_envs == 2 * DYNAMIC.prey_capacity
        obs, _ = vec.reset(seed=8)
        assert np.array_equal(obs, ref.get_observations()["policy"].numpy())
        rng = np.random.default_rng(2)
        ended = refills = 0
        for step in range(60):
            actions = rng.integers(0, 16, vec.num_envs)
            acted = vec.rows.active.numpy().copy()
            obs, rewards, terminations, truncations, _ = vec.step(actions)
            ref_obs, ref_rewards, ref_dones, extras = ref.step(torch.from_numpy(actions).float().unsqueeze(1))
            assert np.array_equal(obs, ref_obs["policy"].numpy()), f"step {step}"
            assert np.array_equal(rewards, ref_rewards.numpy()), f"step {step}"
            # rsl-rl's adapter also ends an empty row's stretch when its slot is filled; these rows have
            # no episode there.
            ref_dones = ref_dones.numpy().astype(bool)
            assert np.array_equal(terminations | truncations, ref_dones & acted), f"step {step}"
            refills += int((ref_dones & ~acted).sum())
            assert np.array_equal(truncations, extras["time_outs"].numpy()), f"step {step}"
            ended += int(terminations.sum())
        assert ended > 0 and refills > 0
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
        # NumPy integers are seeds as the same Python integers are (simulation and spaces).
        for numpy_seed in (np.int64(9), np.uint32(9), np.int8(9)):
            assert np.array_equal(vec.reset(seed=numpy_seed)[0], vec.reset(seed=9)[0])
            vec.reset(seed=numpy_seed)
            assert np.array_equal(a, vec.action_space.sample())
        # Zero copy on the CPU: observations are views of the two buffers, alternating between steps.
        obs1 = vec.step(a)[0]
        kept = obs1.copy()
        obs2 = vec.step(a)[0]
        assert np.shares_memory(obs1, vec.rows._obs[1].numpy()) or np.shares_memory(obs1, vec.rows._obs[0].numpy())
        assert not np.shares_memory(obs1, obs2) and np.array_equal(obs1, kept)  # valid until the step after next
    finally:
        vec.close()
    # The constructor's seed fixes the sequence of unseeded resets (a NumPy integer too).
    x, y = AquariumVectorEnv(RESPAWN, seed=7), AquariumVectorEnv(RESPAWN, seed=np.int64(7))
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
        # A bad seed: one line naming it and the range, and nothing reset.
        for seed in ([1, 2], -1, np.int64(-1), 2**63, 1.0, True):
            with pytest.raises(ValueError, match=r"^seed=.* must be None or an integer in \[0, 2\*\*63 - 1\]"):
                vec.reset(seed=seed)
        assert torch.equal(vec.rows.aquarium.state.torch.position, before)
        with pytest.raises(ValueError, match=r"^options\['reset_mask'\] is not supported: rows share worlds"):
            vec.reset(options={"reset_mask": np.ones(n, bool)})
        assert torch.equal(vec.rows.aquarium.state.torch.position, before)
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
    for kwargs, match in [
        (dict(autoreset_mode="disabled"), r"^autoreset_mode='disabled' must be AutoresetMode.NEXT_STEP or"),
        (dict(autoreset_mode=AutoresetMode.DISABLED), "autoreset_mode"),
        (dict(render_mode="human"), r"^render_mode='human' must be None or one of \('rgb_array',\)$"),
        (dict(seed=np.float64(1)), "seed"),
    ]:
        with pytest.raises(ValueError, match=match):
            AquariumVectorEnv(RESPAWN, **kwargs)
    with pytest.raises(ValueError, match="auto_reset=False"):
        AquariumRows(aquarium=BatchedAquarium(RESPAWN))
    with pytest.raises(ValueError, match="aquarium="):
        AquariumRows(RESPAWN, aquarium=BatchedAquarium(RESPAWN, auto_reset=False))
