"""The Stable-Baselines3 `VecEnv` (`aquarium_warp.interop.sb3`) with SB3's own wrappers and PPO: dones,
infos and terminal observations (against the same-step Gymnasium env, itself checked against a
per-row reference), `VecMonitor` against per-life returns computed by hand, `VecVideoRecorder`,
rendering, torch threads, and a short PPO run."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from rows_reference import life_returns

from aquarium_warp import AquariumConfig
from aquarium_warp.interop.gymnasium import AquariumVectorEnv
from aquarium_warp.render import render_world

sb3 = pytest.importorskip("stable_baselines3", reason="needs the interop extra: pip install -e '.[interop]'")
from stable_baselines3.common.vec_env import VecMonitor, VecVideoRecorder  # noqa: E402

from aquarium_warp.interop.sb3 import AquariumSB3VecEnv  # noqa: E402

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


@pytest.fixture
def torch_threads():
    """Restore torch's thread count after a test that lets the env change it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def test_dones_infos_and_terminal_observations(torch_threads):
    vec = AquariumSB3VecEnv(DYNAMIC, num_worlds=2)
    gym_vec = AquariumVectorEnv(DYNAMIC, num_worlds=2, autoreset_mode="same_step")
    try:
        vec.seed(np.int64(4))  # what PPO(seed=4) does (a NumPy integer too)
        assert np.array_equal(vec.reset(), gym_vec.reset(seed=4)[0])
        assert vec.get_attr("render_mode") == [None] * vec.num_envs
        assert vec.env_is_wrapped(object, [0, 1]) == [False] * 2
        rng = np.random.default_rng(3)
        seen = dict(terminated=0, truncated=0)
        for step in range(90):
            actions = rng.integers(0, 16, vec.num_envs)
            obs, rewards, dones, infos = vec.step(actions)
            g_obs, g_rewards, term, trunc, g_infos = gym_vec.step(actions)
            assert np.array_equal(obs, g_obs) and np.array_equal(rewards, g_rewards), f"step {step}"
            assert np.array_equal(dones, term | trunc) and len(infos) == vec.num_envs
            assert [i for i, info in enumerate(infos) if info] == np.flatnonzero(dones).tolist()
            for i in np.flatnonzero(dones):
                assert infos[i]["TimeLimit.truncated"] == bool(trunc[i])
                assert np.array_equal(infos[i]["terminal_observation"], g_infos["final_obs"][i])
                # A dead agent's last observation is zeros; a truncated one's is real (not all zeros).
                assert infos[i]["terminal_observation"].any() == bool(trunc[i])
            assert np.array_equal(vec.active, gym_vec.rows.active.numpy())
            seen["terminated"] += int(term.sum())
            seen["truncated"] += int(trunc.sum())
        assert all(v > 0 for v in seen.values()), seen
    finally:
        vec.close()
        gym_vec.close()


@pytest.mark.parametrize("config", [DYNAMIC, RESPAWN], ids=["respawn-off", "respawn"])
def test_vec_monitor_counts_lives_with_their_returns(config, torch_threads):
    """SB3's `VecMonitor` logs exactly the agents' lives, each with its return computed by hand from
    `BatchedAquarium` stepped directly (float32 sums, as VecMonitor's): no episode for an empty slot."""
    vec = VecMonitor(AquariumSB3VecEnv(config, num_worlds=3))
    actions = np.random.default_rng(5).integers(0, 16, (3 * config.max_steps, vec.num_envs))
    vec.seed(11)
    vec.reset()
    logged = []
    for a in actions:
        *_, infos = vec.step(a)
        logged.append([(i, float(info["episode"]["r"])) for i, info in enumerate(infos) if "episode" in info])
    by_hand = life_returns(config, 3, 11, actions)
    assert logged == by_hand
    assert vec.episode_count == sum(map(len, by_hand)) > vec.num_envs
    vec.close()


def test_render_and_vec_video_recorder(tmp_path, torch_threads):
    pytest.importorskip("moviepy", reason="SB3's VecVideoRecorder needs moviepy")
    imageio = pytest.importorskip("imageio.v2")
    vec = AquariumSB3VecEnv(RESPAWN, num_worlds=2, render_mode="rgb_array", render_world=1)
    assert vec.metadata["render_modes"] == ["human", "rgb_array"] and vec.metadata["render_fps"] == 30
    vec.reset()
    frame = vec.render()
    assert frame.shape == (200, 200, 3) and np.array_equal(frame, render_world(vec.aquarium, 1))
    images = vec.get_images()
    assert len(images) == vec.num_envs and np.array_equal(images[0], render_world(vec.aquarium, 0))
    assert np.array_equal(images[8], frame)
    with pytest.raises(ValueError, match=r"^render\(mode='human'\): this env renders 'rgb_array'"):
        vec.render("human")
    recorder = VecVideoRecorder(vec, str(tmp_path), record_video_trigger=lambda step: step == 0, video_length=8)
    recorder.reset()
    for _ in range(10):
        recorder.step(np.zeros(vec.num_envs, int))
    recorder.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1
    frames = list(imageio.get_reader(str(videos[0])).iter_data())
    assert len(frames) == 9 and frames[0].shape == (200, 200, 3)  # the reset's frame and 8 steps'
    unrendered = AquariumSB3VecEnv(RESPAWN)
    assert unrendered.render() is None and unrendered.get_images() == [None] * unrendered.num_envs
    unrendered.close()
    for kwargs, match in [
        (dict(render_mode="human"), r"^render_mode='human' must be None or one of"),
        (dict(render_world=2), r"^render_world=2 must be an integer in \[0, 1\]$"),
        (dict(render_world=True), "render_world"),
        (dict(torch_threads=0), r"^torch_threads=0 must be 'auto', None or an integer >= 1$"),
        (dict(torch_threads="many"), "torch_threads"),
        (dict(autoreset_mode="next_step"), "autoreset_mode"),
    ]:
        with pytest.raises(ValueError, match=match):
            AquariumSB3VecEnv(RESPAWN, num_worlds=2, **kwargs)


def test_torch_threads(torch_threads, monkeypatch):
    import aquarium_warp.interop.sb3 as sb3_env

    for cores, auto in [(2, 1), (sb3_env.SMALL_CPU_CORES, 1), (sb3_env.SMALL_CPU_CORES + 1, 3)]:
        monkeypatch.setattr(sb3_env, "resolve_cpu_threads", lambda _, cores=cores: cores)
        torch.set_num_threads(3)
        AquariumSB3VecEnv(RESPAWN).close()  # "auto": one torch thread on a small CPU, else unchanged
        assert torch.get_num_threads() == auto, cores
    torch.set_num_threads(3)
    AquariumSB3VecEnv(RESPAWN, torch_threads=None).close()
    assert torch.get_num_threads() == 3
    AquariumSB3VecEnv(RESPAWN, torch_threads=2).close()
    assert torch.get_num_threads() == 2


@pytest.mark.slow
def test_stable_baselines3_ppo_trains_and_seeds(tmp_path, torch_threads):
    def train(seed):
        vec = VecMonitor(AquariumSB3VecEnv(RESPAWN, num_worlds=4))
        model = sb3.PPO("MlpPolicy", vec, n_steps=32, batch_size=256, n_epochs=1, device="cpu", seed=seed)
        model.set_logger(sb3.common.logger.configure(str(tmp_path), []))
        before = [p.detach().clone() for p in model.policy.parameters()]
        model.learn(total_timesteps=2 * 32 * vec.num_envs)  # 2,048 env steps: two PPO iterations
        assert model.num_timesteps == 2 * 32 * vec.num_envs == 2048
        after = [p.detach().clone() for p in model.policy.parameters()]
        assert any(not torch.equal(a, b) for a, b in zip(before, after))
        assert len(model.ep_info_buffer) > 0  # VecMonitor's lives reached PPO's log
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
