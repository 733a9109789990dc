"""The episode loop (`aquarium_warp.rollout`): hooks called once per step in order, the outputs the env
returned, early stops and the two forms of drivers; and every loop ported onto it (swarm metrics, the
swarm-size study, the studies' rollouts, evaluation, videos) against a plain loop written out here, as
each one stepped before the port: the same actions, the same numbers."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.drivers import make_driver, make_drivers
from aquarium_warp.heuristics import heuristic_actions
from aquarium_warp.metrics import EPISODE_METRICS, EpisodeMetrics, SwarmMetrics, rollout_metrics
from aquarium_warp.render import Renderer
from aquarium_warp.rollout import Observer, Progress, StepViews, random_actions, rollout

CFG = AquariumConfig(prey_count=6, predator_count=2, max_steps=12, width=300, height=300)


def constant(env: BatchedAquarium, team: str, action: int, calls: list):
    """A driver of `team` that asks for `action` in every slot and notes its calls."""
    slots = env.prey_capacity if team == "prey" else env.predator_capacity
    actions = torch.full((env.num_worlds, slots), action, dtype=torch.int32)

    def drive() -> torch.Tensor:
        calls.append(team)
        return actions

    return drive


class Counting(Observer):
    """Notes every hook call, with clones of what each step's result held."""

    def __init__(self, name: str, log: list):
        self.name, self.log, self.seen = name, log, []

    def on_start(self, env):
        self.log.append((self.name, "start", env.state.torch.position.clone()))

    def on_step(self, env, step, result):
        assert result is env.outputs
        self.log.append((self.name, "step", step))
        self.seen.append(
            (result.rewards["prey"].clone(), result.info["captures"].clone(), env.state.torch.position.clone())
        )

    def on_end(self, env):
        self.log.append((self.name, "end", None))


def test_hooks_in_order_once_per_step_and_the_outputs_the_env_returned():
    """4 steps, constant actions (prey 3, predators 5), two observers: start, then per step the drivers
    prey then predator and the observers in order, then end; each step's rewards, captures and
    positions are those of the same env stepped by hand with the same actions."""
    env = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=1)
    calls: list = []
    log: list = []
    first, second = Counting("a", log), Counting("b", log)
    drivers = {"prey": constant(env, "prey", 3, calls), "predator": constant(env, "predator", 5, calls)}
    assert rollout(env, drivers, 4, [first, second]) == 4
    assert calls == ["prey", "predator"] * 4
    assert [(name, hook) for name, hook, _ in log] == [("a", "start"), ("b", "start")] + [
        (name, "step") for _ in range(4) for name in "ab"
    ] + [("a", "end"), ("b", "end")]
    assert [value for _, hook, value in log if hook == "step"] == [0, 0, 1, 1, 2, 2, 3, 3]

    manual = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=1)
    manual.reset()
    assert torch.equal(log[0][2], manual.state.torch.position)  # started after the reset
    actions = {
        "prey": torch.full((2, manual.prey_capacity), 3, dtype=torch.int32),
        "predator": torch.full((2, manual.predator_capacity), 5, dtype=torch.int32),
    }
    for k in range(4):
        _, rewards, _, _, info = manual.step(actions)
        for seen in (first.seen[k], second.seen[k]):
            assert torch.equal(seen[0], rewards["prey"]) and torch.equal(seen[1], info["captures"])
            assert torch.equal(seen[2], manual.state.torch.position)


def test_until_reset_zero_steps_and_the_policy_form():
    env = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=2)
    log: list = []
    counting = Counting("a", log)
    # `until` is asked after each step: True after the third stops there.
    assert rollout(env, lambda obs: heuristic_actions(env), 10, [counting], until=lambda: len(counting.seen) == 3) == 3
    assert [hook for _, hook, _ in log] == ["start", "step", "step", "step", "end"]
    # No steps: start and end only; without reset the state is kept.
    before = env.state.torch.position.clone()
    log.clear()
    assert rollout(env, {}, 0, [counting], reset=False) == 0
    assert [hook for _, hook, _ in log] == ["start", "end"] and torch.equal(before, env.state.torch.position)
    # A function of the observations gets the env's current ones.
    seen = []

    def policy(obs):
        seen.append(obs)
        return heuristic_actions(env)

    rollout(env, policy, 2)
    assert len(seen) == 2 and all(obs is env.observations for obs in seen)


def test_bad_arguments_and_validation():
    env = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=0)
    drivers = {"prey": constant(env, "prey", 99, []), "predator": constant(env, "predator", 0, [])}
    with pytest.raises(ValueError, match="steps"):
        rollout(env, drivers, -1)
    with pytest.raises(ValueError, match="drivers"):
        rollout(env, 3, 1)
    with pytest.raises(ValueError, match="every"):
        Progress(print, every=0)
    with pytest.raises(ValueError):  # action 99 is out of range: checked with validate=True
        rollout(env, drivers, 1, validate=True)


def test_progress_reports_every_n_steps_and_the_rest_at_the_end():
    env = BatchedAquarium(CFG, num_worlds=1, device="cpu", seed=0)
    reported: list = []
    rollout(env, lambda obs: heuristic_actions(env), 7, [Progress(reported.append, every=3)])
    assert reported == [3, 3, 1]


def test_step_views_hold_the_state_before_and_after_each_step():
    env = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=4)
    views = []
    rollout(
        env,
        make_drivers({"prey": "turnaway", "predator": "naivchase"}, env),
        5,
        [
            StepViews(
                lambda v: views.append(
                    (v.step, v.before_position, v.before_alive, v.position.clone(), v.captured.clone())
                )
            )
        ],
    )
    manual = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=4)
    manual.reset()
    t = manual.state.torch
    for _, before_position, before_alive, position, captured in views:
        assert torch.equal(before_position, t.position) and torch.equal(before_alive, t.alive)
        manual.step(heuristic_actions(manual))
        assert torch.equal(position, t.position) and torch.equal(captured, t.captured[:, : manual.prey_capacity])
    assert [v[0] for v in views] == list(range(5))


def test_random_actions_cover_every_slot_in_range():
    cfg = AquariumConfig(prey_count=5, predator_count=2)
    a = random_actions(cfg, 3, torch.Generator().manual_seed(0), "cpu")
    b = random_actions(cfg, 3, torch.Generator().manual_seed(0), "cpu")
    assert a["prey"].shape == (3, 5) and a["predator"].shape == (3, 2) and a["prey"].dtype == torch.int32
    assert all(torch.equal(a[t], b[t]) and 0 <= int(a[t].min()) and int(a[t].max()) < cfg.action_count for t in a)


# ------------------------------------------------------------------------------------ the ported loops
def manual_episode_metrics(env, act, steps, every, trace=()):
    """`rollout_metrics` as it stepped before the port."""
    episodes = EpisodeMetrics(env, every=every, trace=trace)
    obs = env.reset()
    episodes.begin()
    for _ in range(steps):
        obs, _, _, _, info = env.step(act(obs), validate=False)
        episodes.update(info)
    return episodes


def assert_same(a, b):
    assert set(a) == set(b)
    for k in a:
        x, y = a[k], b[k]
        if isinstance(x, torch.Tensor):
            assert torch.equal(x.nan_to_num(-7.0), y.nan_to_num(-7.0)), k
        elif isinstance(x, np.ndarray):
            assert np.array_equal(x, y, equal_nan=True), k
        else:
            assert x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y)), k


def test_rollout_metrics_equals_the_plain_loop():
    cfg = CFG.replace(respawn_captured_prey=False)
    env = BatchedAquarium(cfg, num_worlds=3, device="cpu", seed=3)
    out = rollout_metrics(env, lambda obs: heuristic_actions(env), steps=30, every=2, trace=("prey_alive",))
    plain = BatchedAquarium(cfg, num_worlds=3, device="cpu", seed=3)
    episodes = manual_episode_metrics(plain, lambda obs: heuristic_actions(plain), 30, 2, trace=("prey_alive",))
    expected = episodes.result()
    expected["trace_prey_alive"] = episodes.traces()["prey_alive"]
    expected["trace_steps"] = torch.tensor(episodes.trace_steps)
    assert_same(out, expected)
    assert torch.equal(env.state.torch.position, plain.state.torch.position)


def test_swarm_size_setting_equals_the_plain_loop():
    from aquarium_warp.studies.swarm_size import SwarmSizeStudy, run_setting

    study = SwarmSizeStudy(
        prey=[6], seeds=3, episode_steps=30, metrics_every=5, respawn=False, device="cpu", seed=2, figures=False
    )
    setting = study.settings()[0]
    progress: list = []
    result = run_setting(study, setting, "cpu", progress=progress.append)
    assert progress == [25, 5]
    env = BatchedAquarium(setting["config"], num_worlds=3, device="cpu", seed=2)
    prey, predator = make_driver("turnaway", env, "prey"), make_driver("naivchase", env, "predator")
    episodes = EpisodeMetrics(env, metrics=SwarmMetrics(env), every=5)
    env.reset()
    episodes.begin()
    for _ in range(30):
        _, _, _, _, info = env.step({"prey": prey(), "predator": predator()}, validate=False)
        episodes.update(info)
    worlds = {k: v.double().numpy() for k, v in episodes.result().items()}
    for name, per_seed in result["per_seed"].items():  # one episode per seed: its world's value
        assert np.array_equal(per_seed, worlds[name], equal_nan=True), name


def test_study_rollout_equals_the_plain_loop():
    from aquarium_warp.studies import common

    views: list = []
    out = common.rollout(
        CFG,
        "turnaway",
        "naivchase",
        2,
        7,
        "cpu",
        lambda v: views.append((v.step, v.before_position, v.position.clone())),
        metrics_every=4,
    )
    env = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=7)
    drivers = make_drivers({"prey": "turnaway", "predator": "naivchase"}, env, seed=7)
    episodes = EpisodeMetrics(env, every=4)
    t = env.state.torch
    env.reset()
    episodes.begin()
    expected_views = []
    for step in range(CFG.max_steps):
        position = t.position.clone()
        _, _, _, _, info = env.step({team: drivers[team]() for team in ("prey", "predator")}, validate=False)
        episodes.update(info)
        if step < CFG.max_steps - 1:
            expected_views.append((step, position, t.position.clone()))
    assert len(views) == len(expected_views) == CFG.max_steps - 1
    for (s, a, b), (e, c, d) in zip(views, expected_views):
        assert s == e and torch.equal(a, c) and torch.equal(b, d)
    expected = {
        "captures": info["episode_captures"].numpy().astype(np.float64),
        "length": info["episode_length"].numpy().astype(np.float64),
    }
    expected.update({k: v.double().numpy() for k, v in episodes.result().items()})
    assert_same(out, expected)


def test_run_episodes_equals_the_plain_loop():
    pytest.importorskip("rsl_rl")
    from aquarium_warp.training.evaluate import run_episodes

    cfg = CFG.replace(max_steps=10)
    records = run_episodes(cfg, "turnaway", "naivchase", 5, 4, device="cpu", max_worlds=2, metrics_every=3)
    # Two worlds, three episodes each, every one max_steps long (the env is not reset before the first
    # step); records sorted by (episode number, world), the first five kept.
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu", seed=4)
    drivers = make_drivers({"prey": "turnaway", "predator": "naivchase"}, env, seed=4)
    swarm = EpisodeMetrics(env, every=3)
    swarm.begin()
    captures = torch.zeros(2, env.prey_capacity, dtype=torch.int32)
    prey_reward = torch.zeros(2, env.prey_capacity, dtype=torch.float64)
    predator_reward = torch.zeros(2, env.predator_capacity, dtype=torch.float64)
    expected = []
    for step in range(3 * cfg.max_steps):
        _, rewards, _, _, info = env.step({team: drivers[team]() for team in ("prey", "predator")}, validate=False)
        swarm.update(info)
        captures += env.state.torch.captured[:, : env.prey_capacity]
        prey_reward += rewards["prey"]
        predator_reward += rewards["predator"]
        if step % cfg.max_steps == cfg.max_steps - 1:
            assert bool(info["episode_ended"].all())
            for w in range(2):
                expected.append(
                    (
                        step // cfg.max_steps,
                        w,
                        {
                            "prey_captures": captures[w].tolist(),
                            "prey_rewards": prey_reward[w].tolist(),
                            "predator_rewards": predator_reward[w].tolist(),
                            "captures": int(info["episode_captures"][w]),
                            "length": int(info["episode_length"][w]),
                            **{f"swarm_{n}": float(swarm.ended_values[w, m]) for m, n in enumerate(EPISODE_METRICS)},
                        },
                    )
                )
            captures.zero_()
            prey_reward.zero_()
            predator_reward.zero_()
    assert len(records) == 5
    for i, (record, (_, _, want)) in enumerate(zip(records, sorted(expected, key=lambda r: (r[0], r[1])))):
        assert record["episode"] == i
        assert record["captures_per_prey"] == sum(want["prey_captures"]) / cfg.prey_count
        assert record["reward_per_predator"] == sum(want["predator_rewards"]) / cfg.predator_count
        assert_same({k: record[k] for k in want}, want)


def manual_frames(env, drivers, steps, world=0, **overlays):
    """The frames of the video loops as they were made before the port: the current state, then each step's."""
    renderer = Renderer(env, 64)
    frames = [renderer.render(world, **overlays)]
    for _ in range(steps):
        env.step({team: drive() for team, drive in drivers.items()})
        frames.append(renderer.render(world, **overlays))
    return np.stack(frames)


def test_video_frames_equal_the_plain_loop(monkeypatch):
    from aquarium_warp import video

    written: list = []

    @contextlib.contextmanager
    def frames_kept(path, **kwargs):  # the frames as handed to the file, before H.264 compresses them
        yield written.append

    monkeypatch.setattr(video, "video_file", frames_kept)
    env = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=5)
    drivers = make_drivers({"prey": "turnaway", "predator": "naivchase"}, env, seed=5)
    assert video.record(env, drivers, 6, "unused.mp4", world=1, width_px=64, progress=False, view_cones=True) == 7
    plain = BatchedAquarium(CFG, num_worlds=2, device="cpu", seed=5)
    expected = manual_frames(
        plain, make_drivers({"prey": "turnaway", "predator": "naivchase"}, plain, seed=5), 6, world=1, view_cones=True
    )
    assert np.array_equal(np.stack(written), expected)


def test_training_video_frames_equal_the_plain_loop():
    pytest.importorskip("rsl_rl")
    from aquarium_warp.training.episode_video import EpisodeVideo

    def specs(env):
        return make_drivers({"prey": "turnaway", "predator": "naivchase"}, env, seed=9)

    video = EpisodeVideo(CFG, "cpu", 9, steps=7, width_px=64)
    frames = video.record(specs)
    plain = BatchedAquarium(CFG, num_worlds=1, device="cpu", seed=9)
    plain.reset()
    assert frames.shape[0] == 8 and np.array_equal(frames, manual_frames(plain, specs(plain), 7))
