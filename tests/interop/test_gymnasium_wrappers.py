"""Gymnasium's vector wrappers (every name in `gymnasium.wrappers.vector.__all__`) on `AquariumVectorEnv`,
each checked against a twin env stepped with the same seed and actions, unwrapped; `gym.make_vec`; and
Gymnasium's episode statistics against per-life returns computed by hand."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space
from gymnasium.wrappers import vector as vw
from rows_reference import life_returns

import aquarium_warp  # noqa: F401 - registers the env for gym.make_vec
from aquarium_warp import AquariumConfig
from aquarium_warp.interop.gymnasium import AquariumVectorEnv, make_vector_env
from aquarium_warp.render import render_world

CONFIG = AquariumConfig(width=200.0, height=200.0, prey_count=6, predator_count=2, max_steps=12)
# Respawn off, starvation, reproduction: slots empty and refill, worlds end early.
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
W, STEPS = 2, 30  # 2.5 world episodes: ends, reset steps and respawns
L = CONFIG.observation_size("prey")
DIRECTIONS = CONFIG.action_count


def env(**kwargs) -> AquariumVectorEnv:
    return AquariumVectorEnv(CONFIG, num_worlds=W, **kwargs)


def to_direction(a):
    """A Box action in [-1, 1] per row as a direction index (the adapter that makes Box-action wrappers apply)."""
    return np.minimum(((np.asarray(a) + 1.0) * DIRECTIONS / 2).astype(np.int64), DIRECTIONS - 1)


def box_actions(e):
    single = spaces.Box(-1.0, 1.0, (), np.float32)
    return vw.TransformAction(
        e, func=to_direction, action_space=batch_space(single, e.num_envs), single_action_space=single
    )


def run_twins(wrapped, raw_actions=lambda a: a, steps: int = STEPS, seed: int = 3):
    """Step `wrapped` and an unwrapped twin (same seed; the twin takes `raw_actions(a)`) with the same
    random actions of the wrapper's action space; yields (wrapped outputs, twin outputs) per step,
    the resets first."""
    twin = env(**({"render_mode": "rgb_array"} if wrapped.render_mode else {}))
    wrapped.action_space.seed(seed)
    try:
        yield wrapped.reset(seed=seed), twin.reset(seed=seed)
        for _ in range(steps):
            a = wrapped.action_space.sample()
            raw = raw_actions(np.copy(a))  # first: a wrapper may transform `a` in place
            yield wrapped.step(a), twin.step(raw)
    finally:
        wrapped.close()
        twin.close()


def check_equal_except(out, ref, changed=()):
    """Step or reset outputs equal in every place not in `changed` (indices into the tuple)."""
    for k, (x, y) in enumerate(zip(out, ref)):
        if k in changed or isinstance(x, (dict, list)):
            continue
        assert np.array_equal(np.asarray(x), np.asarray(y)), k


# name -> check(tmp_path), one per wrapper in gymnasium.wrappers.vector.__all__
CHECKS = {}
# name -> why it does not apply to this env
NOT_APPLICABLE = {
    "FilterObservation": "filters the keys of Dict/Tuple observations; the rows' observation is one Box",
    "GrayscaleObservation": "converts RGB image observations [H, W, 3]; the rows observe a vector",
    "ResizeObservation": "resizes image observations; the rows observe a vector",
    "JaxToNumpy": "converts a JAX env's arrays; this env returns numpy or torch (array_type=)",
    "JaxToTorch": "converts a JAX env's arrays; this env returns numpy or torch (array_type=)",
}


def check(name):
    def register(fn):
        CHECKS[name] = fn
        return fn

    return register


@check("TransformObservation")
def _(tmp_path):
    for out, ref in run_twins(vw.TransformObservation(env(), func=lambda o: 2.0 * o)):
        assert np.array_equal(out[0], 2.0 * ref[0])
        check_equal_except(out, ref, changed=(0,))


@check("VectorizeTransformObservation")
def _(tmp_path):
    wrapped = vw.VectorizeTransformObservation(
        env(),
        wrapper=gym.wrappers.TransformObservation,
        func=lambda o: -o,
        observation_space=spaces.Box(-1.0, 1.0, (L,), np.float32),
    )
    for out, ref in run_twins(wrapped):
        assert np.array_equal(out[0], -ref[0])
        check_equal_except(out, ref, changed=(0,))


@check("FlattenObservation")
def _(tmp_path):
    for out, ref in run_twins(vw.FlattenObservation(env())):
        check_equal_except(out, ref)  # already flat: unchanged


@check("ReshapeObservation")
def _(tmp_path):
    for out, ref in run_twins(vw.ReshapeObservation(env(), shape=(L, 1))):
        assert out[0].shape == (W * 8, L, 1) and np.array_equal(out[0][..., 0], ref[0])
        check_equal_except(out, ref, changed=(0,))


@check("RescaleObservation")
def _(tmp_path):
    low = env().single_observation_space.low[0]
    for out, ref in run_twins(vw.RescaleObservation(env(), min_obs=np.float32(-2.0), max_obs=np.float32(2.0))):
        assert np.allclose(out[0], -2.0 + (ref[0] - low) * 4.0 / (1.0 - low), atol=1e-6, rtol=0)
        assert out[0].min() >= -2.0 and out[0].max() <= 2.0
        check_equal_except(out, ref, changed=(0,))


@check("DtypeObservation")
def _(tmp_path):
    for out, ref in run_twins(vw.DtypeObservation(env(), dtype=np.float64)):
        assert out[0].dtype == np.float64 and np.array_equal(out[0], ref[0])
        check_equal_except(out, ref, changed=(0,))


@check("NormalizeObservation")
def _(tmp_path):
    wrapped = vw.NormalizeObservation(env())
    seen = []
    for out, ref in run_twins(wrapped):
        seen.append(ref[0].astype(np.float64))
        check_equal_except(out, ref, changed=(0,))
    # Its running statistics (float32, as the observations) are those of every observation returned.
    stacked = np.concatenate(seen)
    assert np.allclose(wrapped.obs_rms.mean, stacked.mean(axis=0), rtol=1e-5, atol=1e-6)
    assert np.allclose(wrapped.obs_rms.var, stacked.var(axis=0), rtol=1e-4, atol=1e-6)


@check("TransformAction")
def _(tmp_path):
    for out, ref in run_twins(box_actions(env()), raw_actions=to_direction):
        check_equal_except(out, ref)


@check("VectorizeTransformAction")
def _(tmp_path):
    wrapped = vw.VectorizeTransformAction(
        env(), wrapper=gym.wrappers.TransformAction, func=lambda a: (a + 1) % 16, action_space=spaces.Discrete(16)
    )
    for out, ref in run_twins(wrapped, raw_actions=lambda a: (a + 1) % 16):
        check_equal_except(out, ref)


@check("ClipAction")
def _(tmp_path):
    wrapped = vw.ClipAction(box_actions(env()))
    wrapped.action_space = spaces.Box(-3.0, 3.0, (W * 8,), np.float32)  # sample beyond the bounds: clipped
    for out, ref in run_twins(wrapped, raw_actions=lambda a: to_direction(np.clip(a, -1.0, 1.0))):
        check_equal_except(out, ref)


@check("RescaleAction")
def _(tmp_path):
    wrapped = vw.RescaleAction(box_actions(env()), min_action=0.0, max_action=1.0)
    for out, ref in run_twins(wrapped, raw_actions=lambda a: to_direction(2.0 * np.asarray(a) - 1.0)):
        check_equal_except(out, ref)


@check("TransformReward")
def _(tmp_path):
    for out, ref in run_twins(vw.TransformReward(env(), func=lambda r: 3.0 * r)):
        if len(out) == 5:
            assert np.array_equal(out[1], 3.0 * ref[1])
        check_equal_except(out, ref, changed=(1,))


@check("VectorizeTransformReward")
def _(tmp_path):
    wrapped = vw.VectorizeTransformReward(env(), wrapper=gym.wrappers.TransformReward, func=lambda r: r - 1.0)
    for out, ref in run_twins(wrapped):
        if len(out) == 5:
            assert np.array_equal(out[1], ref[1] - 1.0)
        check_equal_except(out, ref, changed=(1,))


@check("ClipReward")
def _(tmp_path):
    clipped = 0
    for out, ref in run_twins(vw.ClipReward(env(), min_reward=-0.5, max_reward=0.5)):
        if len(out) == 5:
            assert np.array_equal(out[1], np.clip(ref[1], -0.5, 0.5))
            clipped += int((out[1] != ref[1]).sum())
        check_equal_except(out, ref, changed=(1,))
    assert clipped > 0  # captures (penalty -1) were clipped


@check("NormalizeReward")
def _(tmp_path):
    scales = []
    for out, ref in run_twins(vw.NormalizeReward(env(), gamma=0.9)):
        if len(out) == 5 and ref[1].any():
            nonzero = ref[1] != 0
            scale = ref[1][nonzero] / out[1][nonzero]  # one positive scale for every row of a step
            assert np.allclose(scale, scale[0], rtol=1e-6) and scale[0] > 0
            scales.append(scale[0])
        check_equal_except(out, ref, changed=(1,))
    assert len(set(scales)) > 1  # the statistics move


@check("RecordEpisodeStatistics")
def _(tmp_path):
    episodes = 0
    for out, ref in run_twins(vw.RecordEpisodeStatistics(env())):
        check_equal_except(out, ref)
        if len(out) == 5:
            ended = out[2] | out[3]
            assert ("episode" in out[4]) == bool(ended.any())
            if ended.any():
                assert np.array_equal(out[4]["_episode"], ended)
                episodes += int(ended.sum())
    assert episodes > 0  # the returns themselves: test_episode_statistics_are_per_life_returns


@check("DictInfoToList")
def _(tmp_path):
    for out, ref in run_twins(vw.DictInfoToList(env())):
        infos = out[-1]
        assert isinstance(infos, list) and len(infos) == W * 8
        assert [info["active"] for info in infos] == ref[-1]["active"].tolist()
        check_equal_except(out, ref)


@check("ArrayConversion")
def _(tmp_path):
    pytest.importorskip("array_api_compat", reason="Gymnasium's array conversions need array-api-compat")
    import array_api_compat.numpy as xnp
    import array_api_compat.torch as xtorch

    for out, ref in run_twins(vw.ArrayConversion(env(), env_xp=xnp, target_xp=xtorch)):
        assert isinstance(out[0], torch.Tensor) and torch.equal(out[0], torch.from_numpy(ref[0]))
        assert torch.equal(out[-1]["active"], torch.from_numpy(ref[-1]["active"]))


@check("NumpyToTorch")
def _(tmp_path):
    pytest.importorskip("array_api_compat", reason="Gymnasium's array conversions need array-api-compat")
    for out, ref in run_twins(vw.NumpyToTorch(env())):
        for x, y in zip(out[:-1], ref[:-1]):
            assert isinstance(x, torch.Tensor) and torch.equal(x, torch.from_numpy(np.asarray(y)))


@check("RecordVideo")
def _(tmp_path):
    pytest.importorskip("moviepy", reason="Gymnasium's RecordVideo needs moviepy")
    import imageio

    wrapped = vw.RecordVideo(
        env(render_mode="rgb_array"),
        str(tmp_path / "videos"),
        record_first_only=True,
        episode_trigger=lambda episode: episode == 0,
        video_length=8,
    )
    frames = []
    for out, ref in run_twins(wrapped, steps=10):
        check_equal_except(out, ref)
        if len(frames) < 9:
            frames.append(render_world(wrapped.unwrapped.aquarium, 0))
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1
    video = np.stack(list(imageio.get_reader(str(videos[0])).iter_data()))
    assert video.shape == (9, *frames[0].shape)  # the reset's frame and 8 steps', of world 0
    # The frames are world 0's (compressed: compare the mean colour per frame, not pixels).
    assert np.allclose(video.mean(axis=(1, 2, 3)), [f.mean() for f in frames], atol=3.0)


@check("HumanRendering")
def _(tmp_path):
    pytest.importorskip("cv2", reason="Gymnasium's HumanRendering needs opencv")
    pytest.importorskip("pygame", reason="Gymnasium's HumanRendering needs pygame")
    import os

    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # a window without a display
    wrapped = vw.HumanRendering(env(render_mode="rgb_array"))
    for out, ref in run_twins(wrapped, steps=3):
        check_equal_except(out, ref)
        assert wrapped.window is not None


def test_every_vector_wrapper_is_checked_or_does_not_apply():
    assert set(CHECKS) | set(NOT_APPLICABLE) == set(vw.__all__) and not set(CHECKS) & set(NOT_APPLICABLE)


@pytest.mark.parametrize("name", sorted(CHECKS))
def test_vector_wrapper_on_the_next_step_env(name, tmp_path):
    CHECKS[name](tmp_path)


OBSERVATION_WRAPPERS = {
    "TransformObservation": dict(func=lambda o: o),
    "VectorizeTransformObservation": dict(wrapper=gym.wrappers.TransformObservation, func=lambda o: o),
    "FlattenObservation": {},
    "ReshapeObservation": dict(shape=(L, 1)),
    "RescaleObservation": dict(min_obs=np.float32(0.0), max_obs=np.float32(1.0)),
    "DtypeObservation": dict(dtype=np.float64),
    "NormalizeObservation": {},
}


@pytest.mark.parametrize("name", sorted(OBSERVATION_WRAPPERS))
def test_observation_wrappers_refuse_same_step(name):
    """Gymnasium's observation wrappers take next-step envs only (their own check): the reason next-step
    is the default."""
    same = env(autoreset_mode="same_step")
    with pytest.raises(ValueError, match="autoreset_mode"):
        getattr(vw, name)(same, **OBSERVATION_WRAPPERS[name])
    same.close()


def test_same_step_wrappers_keep_final_observations():
    """The wrappers that take a same-step env run on it; `final_obs` stays aligned with `_final_obs`."""
    wrapped = vw.DictInfoToList(
        vw.NormalizeReward(vw.RecordEpisodeStatistics(box_actions(env(autoreset_mode="same_step"))), gamma=0.9)
    )
    wrapped.reset(seed=0)
    finals = 0
    for _ in range(STEPS):
        _, _, terminations, truncations, infos = wrapped.step(wrapped.action_space.sample())
        for i, info in enumerate(infos):
            ended = bool(terminations[i] or truncations[i])
            assert ("final_obs" in info) == ended and ("episode" in info) == ended
            if ended:
                assert info["final_obs"].shape == (L,) and ("active" in info["final_info"])
                finals += 1
    assert finals > 0
    wrapped.close()


@pytest.mark.parametrize("config", [CONFIG, DYNAMIC], ids=["respawn", "respawn-off"])
def test_episode_statistics_are_per_life_returns_same_step(config):
    """`RecordEpisodeStatistics` on the same-step env logs exactly the agents' lives, with the returns
    computed by hand from `BatchedAquarium` stepped directly (no episode for an empty slot)."""
    vec = vw.RecordEpisodeStatistics(AquariumVectorEnv(config, num_worlds=3, autoreset_mode="same_step"))
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 16, (3 * config.max_steps, vec.num_envs))
    vec.reset(seed=7)
    logged = []
    for a in actions:
        *_, infos = vec.step(a)
        logged.append([(i, infos["episode"]["r"][i]) for i in np.flatnonzero(infos.get("_episode", []))])
    vec.close()
    by_hand = life_returns(config, 3, 7, actions, dtype=np.float64)
    assert logged == by_hand and sum(map(len, by_hand)) > vec.num_envs


def test_episode_statistics_are_per_life_returns_next_step():
    """Next-step with respawn off: a life starts at a reset or a birth, never mid-step, so the statistics
    are exact too. The env discards one step of a world that ended (its reset step): the hand
    computation's simulation does not take it."""
    vec = vw.RecordEpisodeStatistics(AquariumVectorEnv(DYNAMIC, num_worlds=1))
    rng = np.random.default_rng(1)
    vec.reset(seed=2)
    logged, taken, reset_step = [], [], False
    for _ in range(4 * DYNAMIC.max_steps):
        a = rng.integers(0, 16, vec.num_envs)
        *_, infos = vec.step(a)
        if not reset_step:
            taken.append(a)
        logged += [(i, infos["episode"]["r"][i]) for i in np.flatnonzero(infos.get("_episode", []))]
        reset_step = bool(vec.unwrapped.aquarium.outputs.info["episode_ended"][0]) and not reset_step
    vec.close()
    by_hand = [life for step in life_returns(DYNAMIC, 1, 2, np.array(taken), dtype=np.float64) for life in step]
    assert logged == by_hand and len(by_hand) > vec.num_envs
    assert len(taken) < 4 * DYNAMIC.max_steps  # some world ended: reset steps were taken


def test_make_vec():
    S = CONFIG.capacity
    vec = gym.make_vec("aquarium/Aquarium-v1", num_envs=2 * S, config=CONFIG, autoreset_mode="same_step")
    twin = AquariumVectorEnv(CONFIG, num_worlds=2, autoreset_mode="same_step")
    try:
        assert isinstance(vec, AquariumVectorEnv) and vec.num_envs == 2 * S and vec.rows.num_worlds == 2
        assert vec.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP and vec.spec.id == "aquarium/Aquarium-v1"
        assert np.array_equal(vec.reset(seed=1)[0], twin.reset(seed=1)[0])
    finally:
        vec.close()
        twin.close()
    # AquariumConfig fields as keywords; a team's rows.
    prey = gym.make_vec("aquarium/Aquarium-v1", num_envs=3 * 6, prey_count=6, team="prey", opponent="naivchase")
    assert prey.rows.num_worlds == 3 and prey.rows.config.prey_count == 6 and prey.num_envs == 18
    assert prey.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    prey.close()
    assert gym.spec("aquarium/Aquarium-v1").entry_point is None  # multi-agent: no single-agent gym.make
    for kwargs, match in [
        (
            dict(num_envs=5),
            r"^num_envs=5 must be a positive multiple of 17 \(the rows of one world: its agent slots\)$",
        ),
        (dict(num_envs=0), "num_envs=0 must be a positive multiple"),
        (dict(num_envs=34, num_worlds=2), "num_envs"),
        (dict(num_envs=34, config="default"), "config must be an AquariumConfig"),
        (dict(num_envs=34, team="fish"), "team='fish' must be one of"),
    ]:
        with pytest.raises(ValueError, match=match):
            make_vector_env(**kwargs)
    with pytest.raises(TypeError):
        gym.make_vec("aquarium/Aquarium-v1", num_envs=17, prey_cout=3)


def test_render_frames_per_row():
    vec = env(render_mode="rgb_array")
    try:
        vec.reset(seed=0)
        frames = vec.render()
        assert len(frames) == vec.num_envs
        assert frames[0] is frames[7] and frames[8] is frames[15]  # one frame per world, shared by its rows
        assert np.array_equal(frames[8], render_world(vec.aquarium, 1)) and not np.array_equal(frames[0], frames[8])
    finally:
        vec.close()
    unrendered = env()
    assert unrendered.render() is None
    unrendered.close()
