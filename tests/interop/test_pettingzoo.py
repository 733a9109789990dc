"""The PettingZoo environment (`aquarium_warp.aquarium_v1`): PettingZoo's own test suite on the default
config and on a config where agents are removed (permanent capture, starvation) and added
(reproduction), plus keyword mapping, spaces, seeding, copies, episode length and rendering."""

from __future__ import annotations

import dataclasses
import importlib.util
import warnings

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, parallel_seed_test, render_test, seed_test
from pettingzoo.test.state_test import state_test

from aquarium_warp import AgentTypeConfig, AquariumConfig, aquarium_v1
from aquarium_warp.config import default_prey

# Agents leave (permanent capture, starvation after 60 steps without a catch) and join (prey replicate
# after 15..25 steps); freed slots are refilled under fresh names. Episodes last at most 400 steps.
DYNAMIC = dict(
    keep_prey_count_constant=False,
    predator_count=3,
    predator_max_age=60,
    procreate=True,
    prey_replication_age=20,
    max_prey_count=20,
    max_time_steps=400,
)
CONFIGS = {"default": {}, "dynamic": DYNAMIC}
CYCLES = 300


def _render_available() -> str | None:
    """Why rendering cannot be tested here (None: it can)."""
    if importlib.util.find_spec("aquarium_warp.render") is None:
        return "aquarium_warp.render is not there yet (written in parallel; integrated later)"
    from aquarium_warp import render

    if not hasattr(render, "render_world"):
        return "aquarium_warp.render has no render_world yet"
    return None


def _random_actions(env, rng):
    return {a: int(rng.integers(env.action_space(a).n)) for a in env.agents}


# ----------------------------------------------------------------------------- PettingZoo's tests
@pytest.mark.parametrize("name", CONFIGS)
def test_parallel_api(name):
    parallel_api_test(aquarium_v1.parallel_env(**CONFIGS[name]), num_cycles=CYCLES)


def test_parallel_api_full_episodes():
    # Short episodes: truncation of everyone, then reset, inside the test.
    parallel_api_test(aquarium_v1.parallel_env(max_time_steps=40), num_cycles=100)


@pytest.mark.parametrize("name", CONFIGS)
@pytest.mark.slow
def test_aec_api(name):
    api_test(aquarium_v1.env(**CONFIGS[name]), num_cycles=CYCLES)


@pytest.mark.parametrize("name", CONFIGS)
def test_seed(name):
    kwargs = CONFIGS[name]
    parallel_seed_test(lambda: aquarium_v1.parallel_env(**kwargs), num_cycles=CYCLES)
    seed_test(lambda: aquarium_v1.env(**kwargs), num_cycles=50)


@pytest.mark.parametrize("name", CONFIGS)
def test_state(name):
    kwargs = CONFIGS[name]
    state_test(aquarium_v1.env(**kwargs), aquarium_v1.parallel_env(**kwargs), num_cycles=20)


def test_max_cycles():
    # `max_cycles` is an alias of max_time_steps / max_steps: exactly that many steps per episode.
    max_cycles_test(aquarium_v1)
    assert aquarium_v1.parallel_env(max_cycles=7).config.max_steps == 7


@pytest.mark.parametrize("name", CONFIGS)
def test_render(name):
    reason = _render_available()
    if reason:
        pytest.skip(reason)
    if importlib.util.find_spec("pygame") is None:
        pytest.skip("render_mode='human' needs pygame (the 'video' extra)")
    kwargs = CONFIGS[name]
    render_test(lambda render_mode=None: aquarium_v1.env(render_mode=render_mode, **kwargs))


def test_render_rgb_array():
    reason = _render_available()
    if reason:
        pytest.skip(reason)
    env = aquarium_v1.parallel_env(render_mode="rgb_array", width=400, height=300, draw_view_cones=True)
    env.reset(seed=0)
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.shape == (300, 400, 3)
    env.close()


def test_render_without_mode_warns_and_returns_none():
    env = aquarium_v1.parallel_env(render_mode=None)
    env.reset(seed=0)
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        assert env.render() is None


# ----------------------------------------------------------------------------- construction
def test_factories_and_metadata():
    par = aquarium_v1.parallel_env(fps=30)
    assert isinstance(par, ParallelEnv) and isinstance(par, aquarium_v1.raw_env)
    assert par.unwrapped is par
    assert par.metadata == {
        "name": "aquarium_v1",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 30,
        "is_parallelizable": True,
    }
    assert par.render_mode == "human"  # marl-aquarium's default; nothing is drawn until render()
    aec = aquarium_v1.env(prey_count=5)
    assert isinstance(aec, AECEnv)
    assert isinstance(aec.unwrapped, aquarium_v1.raw_env) and aec.unwrapped.config.prey_count == 5
    assert aquarium_v1.raw_env().aquarium.device == "cpu"


def test_original_keywords_map_onto_config():
    env = aquarium_v1.env(
        width=600,
        height=400,
        max_time_steps=123,
        action_count=8,
        predator_count=2,
        prey_count=10,
        predator_observe_count=2,
        prey_observe_count=4,
        fov_enabled=False,
        keep_prey_count_constant=False,
        prey_radius=10,
        prey_max_acceleration=0.9,
        prey_max_velocity=3.0,
        prey_view_distance=50,
        prey_replication_age=100,
        prey_max_steer_force=0.5,
        prey_fov=90,
        prey_reward=2,
        prey_punishment=7,
        max_prey_count=30,
        predator_max_acceleration=0.7,
        predator_radius=15,
        predator_max_velocity=8.0,
        predator_view_distance=300,
        predator_max_steer_force=0.4,
        predator_max_age=100,
        predator_fov=100,
        predator_reward=20,
        catch_radius=50,
        procreate=True,
        observable_walls=2,
        caption="x",
        fps=10,
        draw_force_vectors=True,
        draw_action_vectors=False,
        draw_view_cones=True,
        draw_hit_boxes=True,
        draw_death_circles=False,
        render_mode="rgb_array",
    )
    cfg = env.unwrapped.config
    assert (cfg.width, cfg.height, cfg.max_steps, cfg.action_count) == (600, 400, 123, 8)
    assert (cfg.predator_count, cfg.prey_count, cfg.max_prey) == (2, 10, 30)
    assert not cfg.fov_enabled and not cfg.respawn_captured_prey and cfg.prey_reproduction
    assert (cfg.prey_replication_age, cfg.prey_reward, cfg.prey_capture_penalty) == (100, 2, 7)
    assert (cfg.predator_reward, cfg.catch_share_radius, cfg.predator_starvation_steps) == (20, 50, 100)
    for t in (cfg.prey, cfg.predator):
        assert (t.predator_slots, t.prey_slots) == (2, 4)
    p, q = cfg.prey, cfg.predator
    assert (p.radius, p.max_acceleration, p.max_speed, p.view_distance, p.max_steering_force, p.fov_angle) == (
        10,
        0.9,
        3.0,
        50,
        0.5,
        90,
    )
    assert (q.radius, q.max_acceleration, q.max_speed, q.view_distance, q.max_steering_force, q.fov_angle) == (
        15,
        0.7,
        8.0,
        300,
        0.4,
        100,
    )
    assert q.bounce_strength == 1.0 and p.bounce_strength == 1.0  # predator: max velocity / 8, as the original
    assert env.unwrapped.metadata["render_fps"] == 10
    assert env.observation_space("prey_0").shape == (5 + 6 * 6,) == env.observation_space("predator_0").shape
    assert env.action_space("predator_1") == spaces.Discrete(8)
    # The defaults are marl-aquarium's, which equal AquariumConfig's.
    assert aquarium_v1.parallel_env().config == AquariumConfig()


def test_own_names_and_config():
    cfg = AquariumConfig(prey_count=8, max_steps=50)
    assert aquarium_v1.parallel_env(config=cfg).config is cfg
    assert aquarium_v1.parallel_env(config=cfg, prey_count=8, max_time_steps=50).config is cfg  # agreeing
    env = aquarium_v1.parallel_env(
        respawn_captured_prey=False,
        catch_share_radius=70,
        predator_bounce_strength=0.3,
        predator_max_velocity=8.0,
        prey_mass=4.0,
    )
    c = env.config
    assert not c.respawn_captured_prey and c.catch_share_radius == 70 and c.prey.mass == 4.0
    assert c.predator.bounce_strength == 0.3 and c.predator.max_speed == 8.0  # given: not max velocity / 8
    prey = dataclasses.replace(default_prey(), prey_slots=5)
    env = aquarium_v1.parallel_env(prey=prey, prey_radius=20)
    assert env.config.prey == prey
    assert env.observation_space("prey_0").shape == (41,) and env.observation_space("predator_0").shape == (29,)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(keep_prey_count_constant=True, respawn_captured_prey=False),
        dict(max_cycles=4, max_time_steps=5),
        dict(max_steps=4, max_time_steps=5),
        dict(prey_max_velocity=3.0, prey_max_speed=4.0),
        dict(predator_observe_count=2, prey_predator_slots=1),
        dict(config=AquariumConfig(prey_count=8), prey_count=9),
        dict(config=AquariumConfig(), catch_radius=5),
        dict(prey=AgentTypeConfig(4.0, 0.6, 1.0, 3.0, 20.0, 100.0, 120.0, 1.0), prey_radius=25),
    ],
)
def test_contradicting_keywords_raise(kwargs):
    with pytest.raises(ValueError, match="contradict"):
        aquarium_v1.parallel_env(**kwargs)


def test_bad_values_raise():
    with pytest.raises(ValueError):
        aquarium_v1.parallel_env(prey_count=0)
    with pytest.raises(ValueError):
        aquarium_v1.parallel_env(render_mode="ansi")
    with pytest.raises(ValueError):
        aquarium_v1.parallel_env(config={"prey_count": 3})


def test_unknown_keyword_lists_valid_ones():
    with pytest.raises(TypeError) as info:
        aquarium_v1.parallel_env(prey_cuont=3)
    message = str(info.value)
    assert "prey_cuont" in message
    for name in (
        "prey_count",
        "keep_prey_count_constant",
        "max_time_steps",
        "respawn_captured_prey",
        "config",
        "render_mode",
        "device",
        "seed",
    ):
        assert name in message


def test_unused_original_keywords_warn():
    with pytest.warns(UserWarning, match="observable_walls"):
        aquarium_v1.parallel_env(observable_walls=4)


# ----------------------------------------------------------------------------- names, spaces, API
def test_agent_names_and_spaces():
    env = aquarium_v1.parallel_env(predator_count=2, prey_count=3)
    assert env.possible_agents == ["predator_0", "predator_1", "prey_0", "prey_1", "prey_2"]
    obs, infos = env.reset(seed=0)
    assert env.agents == env.possible_agents and list(obs) == env.agents and set(infos) == set(env.agents)
    for a in env.possible_agents:
        assert env.observation_space(a) is env.observation_space(a)
        assert env.action_space(a) is env.action_space(a)
        assert env.observation_space(a) == spaces.Box(0.0, 1.0, (29,), np.float32)
        assert env.action_space(a) == spaces.Discrete(16)
        assert obs[a].dtype == np.float32 and obs[a].shape == (29,) and env.observation_space(a).contains(obs[a])
    with pytest.raises(KeyError):
        env.action_space("shark_0")
    signed = aquarium_v1.parallel_env(observation_range="-1..1")
    assert signed.observation_space("prey_0") == spaces.Box(-1.0, 1.0, (29,), np.float32)
    obs, _ = signed.reset(seed=0)
    assert all(signed.observation_space(a).contains(o) for a, o in obs.items())
    # Reproduction: possible_agents covers every prey slot it can fill.
    env = aquarium_v1.parallel_env(procreate=True, prey_count=16, max_prey_count=20)
    assert env.possible_agents == ["predator_0"] + [f"prey_{j}" for j in range(20)]
    env.reset(seed=0)
    assert env.agents == env.possible_agents[:17]


def test_close_does_not_exit():
    env = aquarium_v1.env()
    env.reset(seed=0)
    env.close()
    env.close()
    aquarium_v1.parallel_env().close()


def test_reset_seed_reproducible():
    def rollout(env, seed, steps=30):
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(0)
        out = [np.stack([obs[a] for a in env.agents])]
        for _ in range(steps):
            obs, rewards, *_ = env.step(_random_actions(env, rng))
            out.append(np.stack([obs[a] for a in sorted(obs)]))
            out.append(np.array([rewards[a] for a in sorted(rewards)]))
        return out

    a, b = aquarium_v1.parallel_env(), aquarium_v1.parallel_env()
    ra, rb = rollout(a, 7), rollout(b, 7)
    assert all(np.array_equal(x, y) for x, y in zip(ra, rb))
    assert not np.array_equal(rollout(a, 8)[0], ra[0])
    assert all(np.array_equal(x, y) for x, y in zip(rollout(a, 7), ra))  # same env, same seed again
    # Resets without a seed continue a sequence fixed by the last seed, and differ from each other.
    a.reset(seed=3)
    b.reset(seed=3)
    first_a, first_b = a.reset()[0], b.reset()[0]
    assert all(np.array_equal(first_a[k], first_b[k]) for k in first_a)
    second_a = a.reset()[0]
    assert not all(np.array_equal(first_a[k], second_a[k]) for k in first_a)
    # The constructor's seed= is the first episode's seed.
    c = aquarium_v1.parallel_env(seed=7)
    assert np.array_equal(np.stack([c.reset(seed=7)[0][k] for k in c.agents]), ra[0])


def test_observations_are_copies():
    env = aquarium_v1.parallel_env()
    obs0, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    saved0 = {a: o.copy() for a, o in obs0.items()}
    obs1, *_ = env.step(_random_actions(env, rng))
    saved1 = {a: o.copy() for a, o in obs1.items()}
    env.step(_random_actions(env, rng))
    env.step(_random_actions(env, rng))
    for saved, obs in ((saved0, obs0), (saved1, obs1)):
        for a in saved:
            assert np.array_equal(saved[a], obs[a])
    buffer = env.aquarium.observations["prey"].numpy()
    assert not any(np.shares_memory(o, buffer) for o in obs1.values())
    assert not np.array_equal(saved0["prey_0"], saved1["prey_0"])  # the world did move


def test_episode_ends_after_max_time_steps():
    env = aquarium_v1.parallel_env(max_time_steps=25)
    for seed in (0, 1):
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for step in range(1, 26):
            names = list(env.agents)
            obs, rewards, terminations, truncations, infos = env.step(_random_actions(env, rng))
            assert set(obs) == set(rewards) == set(terminations) == set(truncations) == set(infos) == set(names)
            assert all(isinstance(v, bool) for v in terminations.values())
            assert all(isinstance(v, float) for v in rewards.values())
            assert not any(terminations.values())  # respawn on, starvation after 3000 steps
            if step < 25:
                assert not any(truncations.values()) and env.agents == names
        assert all(truncations.values()) and env.agents == []
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        assert env.state()[-1] == 1.0
        with warnings.catch_warnings(record=True):
            warnings.simplefilter("always")
            assert env.step({}) == ({}, {}, {}, {}, {})


def test_actions_checked():
    env = aquarium_v1.parallel_env(prey_count=3)
    env.reset(seed=0)
    actions = dict.fromkeys(env.agents, 1)
    with pytest.raises(ValueError, match="missing"):
        env.step(dict.fromkeys(env.agents[1:], 1))
    with pytest.raises(ValueError, match="prey_1"):
        env.step({**actions, "prey_1": 16})
    with pytest.raises(ValueError, match="prey_2"):
        env.step({**actions, "prey_2": -1})
    with pytest.raises(ValueError, match="prey_0"):
        env.step({**actions, "prey_0": 1.5})
    with pytest.raises(ValueError, match="prey_0"):
        env.step({**actions, "prey_0": None})
    # numpy integers and 0-d arrays are fine
    obs, *_ = env.step({**actions, "prey_0": np.int64(3), "prey_1": np.array(2)})
    assert set(obs) == set(env.agents)


def test_unknown_agents_and_bool_actions_refused():
    """Issue 28: an action for a name the env never had, or a bool (numpy takes True as 1), is refused
    naming the agent, and the world does not step."""
    env = aquarium_v1.parallel_env(prey_count=3)
    env.reset(seed=0)
    actions = dict.fromkeys(env.agents, 1)
    before = env.state().copy()
    with pytest.raises(ValueError, match=r"unknown agent\(s\) \['prey_99'\]"):
        env.step({**actions, "prey_99": 1})
    with pytest.raises(ValueError, match=r"action True of agent 'prey_0' is not in Discrete\(16\)"):
        env.step({**actions, "prey_0": True})
    with pytest.raises(ValueError, match="prey_1"):
        env.step({**actions, "prey_1": np.bool_(False)})
    assert np.array_equal(env.state(), before)
    env.close()


def test_a_step_before_reset_is_refused_as_the_aec_env_refuses_it():
    env = aquarium_v1.parallel_env(prey_count=3)
    before = env.state().copy()
    with pytest.raises(RuntimeError, match=r"^step\(\) before reset\(\): call reset\(\) first"):
        env.step(dict.fromkeys(env.agents, 1))
    assert np.array_equal(env.state(), before)  # the world did not step
    aec = aquarium_v1.env(prey_count=3)
    with pytest.raises(AssertionError, match="reset"):  # PettingZoo's OrderEnforcingWrapper
        aec.step(1)
    env.reset(seed=0)
    assert set(env.step(dict.fromkeys(env.agents, 1))[0]) == set(env.possible_agents)
    env.close()
    aec.close()


def test_aec_out_of_range_action_names_agent_value_and_range():
    env = aquarium_v1.env(prey_count=3)
    env.reset(seed=0)
    agent = env.agent_selection
    for bad in (99, -1, True):
        with pytest.raises(
            ValueError,
            match=rf"action {bad!r} of agent '{agent}' is not in Discrete\(16\): "
            r"must be an integer in \[0, 15\]",
        ):
            env.step(bad)
    env.step(3)  # a valid action still steps
    env.close()


def test_human_render_without_a_display_is_a_clear_error(monkeypatch):
    if importlib.util.find_spec("pygame") is None:
        pytest.skip("render_mode='human' needs pygame (the 'video' extra)")
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    env = aquarium_v1.parallel_env(prey_count=3)  # render_mode "human", marl-aquarium's default
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="a window needs a display.*render_mode='rgb_array'"):
        env.render()
    env.close()


def _place(env, positions):
    """Put every slot at `positions` (slot order: prey slots, then predators), at rest."""
    aq = env.aquarium
    C = aq.capacity
    aq.set_state(
        world=0,
        position=np.asarray(positions, np.float32),
        velocity=np.zeros((C, 2), np.float32),
        acceleration=np.zeros((C, 2), np.float32),
    )


def test_capture_rewards_and_names():
    # prey_0 sits on the predator; every other prey is far away.
    far = [[40.0 + 45.0 * j, 100.0] for j in range(16)]
    for respawn in (True, False):
        env = aquarium_v1.parallel_env(keep_prey_count_constant=respawn)
        env.reset(seed=0)
        _place(env, [[400.0, 600.0]] + far[1:] + [[400.0, 600.0]])
        obs, rewards, terminations, truncations, _ = env.step(dict.fromkeys(env.agents, 0))
        assert rewards["prey_0"] == pytest.approx(-1000.0 + (1.0 if respawn else 0.0))
        assert rewards["predator_0"] == pytest.approx(10.0)
        assert all(rewards[f"prey_{j}"] == 1.0 for j in range(1, 16))
        assert terminations["prey_0"] is (not respawn) and not any(truncations.values())
        assert ("prey_0" in env.agents) is respawn and len(env.agents) == 17 - (not respawn)
        if not respawn:
            assert not obs["prey_0"].any()  # a removed agent's last observation is empty (zeros)
            obs, rewards, *_ = env.step(dict.fromkeys(env.agents, 0))
            assert "prey_0" not in obs and "prey_0" not in rewards


def test_agents_join_and_leave():
    env = aquarium_v1.parallel_env(**DYNAMIC)
    rng = np.random.default_rng(1)
    capacity = env.config.prey_capacity
    born = died = refilled = 0
    for seed in range(3):
        env.reset(seed=seed)
        finished = set()
        while env.agents:
            before = list(env.agents)
            obs, rewards, terminations, truncations, infos = env.step(_random_actions(env, rng))
            newborn = [a for a in env.agents if a not in before]
            assert set(obs) == set(before) | set(newborn) == set(rewards) == set(terminations) == set(infos)
            assert all(a.startswith("prey_") and not terminations[a] for a in newborn)
            assert not finished & set(env.agents), "an agent came back after it finished"
            assert set(env.agents) <= set(env.possible_agents)
            gone = {a for a in obs if terminations[a] or truncations[a]}
            assert not gone & set(env.agents)
            finished |= gone
            born += len(newborn)
            died += sum(terminations.values())
            refilled += sum(int(a.split("_")[1]) >= capacity for a in newborn)
            state = env.state()
            assert env.state_space.contains(state)
            alive_slots = int(state[: 7 * env.config.capacity].reshape(-1, 7)[:, 0].sum())
            assert alive_slots == len(env.agents) or not env.agents
    assert born > 0 and died > 0 and refilled > 0


def test_state_layout():
    env = aquarium_v1.parallel_env(predator_count=2, prey_count=3)
    env.reset(seed=0)
    state = env.state()
    assert state.dtype == np.float32 and state.shape == env.state_space.shape == (7 * 5 + 1,)
    assert env.state_space.contains(state)
    per_slot = state[:-1].reshape(5, 7)
    assert per_slot[:, 0].tolist() == [1.0] * 5
    pos = env.aquarium.state.torch.position[0].numpy()
    np.testing.assert_allclose(per_slot[0, 1:3], pos[3] / 800.0, rtol=1e-6)  # predator_0 is slot 3
    np.testing.assert_allclose(per_slot[2, 1:3], pos[0] / 800.0, rtol=1e-6)  # prey_0 is slot 0
