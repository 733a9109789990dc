"""Bit-for-bit reproducibility: same seed and actions give identical trajectories (auto-resets included),
different seeds differ, the CPU thread split does not matter, reset/reseed and state_dict round trips
resume exactly. Everything runs on the `device` fixture's device (bit-identical there too: no float atomics,
deterministic sort), except the CPU thread-split test, which only exists on the CPU."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium

TYPES = ("prey", "predator")
# A small world so that captures happen; max_steps 50 so that every world auto-resets several times.
CFG = AquariumConfig(width=400.0, height=360.0, prey_count=12, predator_count=2, max_steps=50)
# Respawn off and a short starvation limit: episodes also end early, at different steps per world.
CFG_EARLY_ENDS = AquariumConfig(
    width=300.0,
    height=300.0,
    prey_count=8,
    predator_count=2,
    max_steps=50,
    respawn_captured_prey=False,
    predator_starvation_steps=12,
)


def make(device, cfg=CFG, num_worlds=8, seed=0, **kw) -> BatchedAquarium:
    return BatchedAquarium(cfg, num_worlds=num_worlds, device=device, seed=seed, **kw)


def action_sequence(env, steps: int, seed: int) -> list[dict]:
    """Random actions drawn on the CPU (the same numbers on every device), placed on the env's device."""
    gen = torch.Generator().manual_seed(seed)
    n = env.config.action_count
    return [
        {
            "prey": torch.randint(0, n, (env.num_worlds, env.prey_capacity), generator=gen).to(env.torch_device),
            "predator": torch.randint(0, n, (env.num_worlds, env.predator_capacity), generator=gen).to(
                env.torch_device
            ),
        }
        for _ in range(steps)
    ]


def snapshot(env, out=None) -> dict:
    """Everything observable after a step (or reset), cloned (on the env's device)."""
    t = env.state.torch
    snap = {
        "position": t.position.clone(),
        "velocity": t.velocity.clone(),
        "acceleration": t.acceleration.clone(),
        "heading": t.heading.clone(),
        "alive": t.alive.clone(),
        "world_step": t.world_step.clone(),
        "episode": t.episode.clone(),
    }
    for k in TYPES:
        snap[f"obs_{k}"] = env.observations[k].clone()
        snap[f"mask_{k}"] = env.observation_mask[k].clone()
        snap[f"slot_{k}"] = env.observed_slot[k].clone()
    if out is not None:
        _, rewards, terminated, truncated, info = out
        ended = info["episode_ended"]
        # The episode statistics are documented as valid only where "episode_ended" is set (elsewhere
        # they hold the last ended episode's values, which a reset does not clear).
        for k in TYPES:
            snap[f"reward_{k}"] = rewards[k].clone()
            snap[f"terminated_{k}"] = terminated[k].clone()
            snap[f"truncated_{k}"] = truncated[k].clone()
            snap[f"return_{k}"] = torch.where(ended, info["episode_return"][k], 0.0)
        snap["captures"] = info["captures"].clone()
        snap["episode_ended"] = ended.clone()
        for k in ("episode_length", "episode_captures"):
            snap[k] = torch.where(ended, info[k], 0)
    return snap


def rollout(env, actions) -> list[dict]:
    return [snapshot(env, env.step(a)) for a in actions]


def assert_identical(a, b, where="") -> None:
    if isinstance(a, list):
        assert len(a) == len(b)
        for i, (x, y) in enumerate(zip(a, b)):
            assert_identical(x, y, f"{where}step {i}: ")
        return
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].device == b[k].device, f"{where}{k}: {a[k].device} vs {b[k].device}"
        assert a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]), f"{where}{k} differs"


def assert_state_dicts_identical(a: dict, b: dict) -> None:
    assert a["config"] == b["config"] and a["num_worlds"] == b["num_worlds"] and a["seed"] == b["seed"]
    assert_identical(a["tensors"], b["tensors"])


@pytest.fixture(scope="module")
def reference_run(device):
    """200 steps of 8 worlds from seed 0 (the trajectory other tests compare against)."""
    env = make(device)
    actions = action_sequence(env, 200, seed=1)
    initial = snapshot(env)
    traj = rollout(env, actions)
    env.close()
    return actions, initial, traj


def test_reference_run_exercises_resets_and_captures(reference_run):
    _, _, traj = reference_run
    ended = torch.stack([s["episode_ended"] for s in traj])
    assert int(ended.sum()) >= 8 * 3  # every world auto-reset several times
    assert int(torch.stack([s["captures"] for s in traj]).sum()) > 0


def test_same_seed_same_actions_bit_identical(device, reference_run):
    actions, initial, traj = reference_run
    env = make(device)
    try:
        assert_identical(snapshot(env), initial)
        assert_identical(rollout(env, actions), traj)
    finally:
        env.close()


@pytest.mark.parametrize(
    "cfg",
    [
        CFG_EARLY_ENDS,
        CFG.replace(prey_reproduction=True, max_prey=16, prey_replication_age=8, respawn_captured_prey=False),
    ],
    ids=["early_ends", "reproduction"],
)
def test_same_seed_bit_identical_other_configs(device, cfg):
    a, b = make(device, cfg, seed=42), make(device, cfg, seed=42)
    try:
        actions = action_sequence(a, 120, seed=3)
        ta = rollout(a, actions)
        tb = rollout(b, actions)
        assert_identical(ta, tb)
        assert int(torch.stack([s["episode_ended"] for s in ta]).sum()) > 0
    finally:
        a.close()
        b.close()


def test_different_seeds_differ(device, reference_run):
    actions, initial, traj = reference_run
    env = make(device, seed=1)
    try:
        start = snapshot(env)
        # every world starts elsewhere
        for w in range(env.num_worlds):
            assert not torch.equal(start["position"][w], initial["position"][w])
        other = rollout(env, actions[:60])
        assert not torch.equal(other[-1]["position"], traj[59]["position"])
        assert not torch.equal(other[-1]["obs_prey"], traj[59]["obs_prey"])
        # worlds of one batch differ from each other too
        assert not torch.equal(start["position"][0], start["position"][1])
    finally:
        env.close()


@pytest.mark.parametrize("cfg", [CFG, CFG_EARLY_ENDS], ids=["default_like", "early_ends"])
def test_thread_split_does_not_matter(device, cfg):
    if torch.device(device).type != "cpu":
        pytest.skip(f"cpu_threads only splits CPU runs (a GPU env is one shard); the CPU run covers it, not {device}")
    one = make("cpu", cfg, num_worlds=64, seed=9, cpu_threads=1)
    two = make("cpu", cfg, num_worlds=64, seed=9, cpu_threads=2)
    try:
        assert len(one.shards) == 1
        assert len(two.shards) == 2  # the split really happens (>= 32 worlds per thread)
        assert_identical(snapshot(one), snapshot(two))
        actions = action_sequence(one, 80, seed=4)
        assert_identical(rollout(one, actions), rollout(two, actions))
        # reseeding and resetting keep the split irrelevant
        one.reset(seed=10)
        two.reset(seed=10)
        assert_identical(rollout(one, actions[:20]), rollout(two, actions[:20]))
    finally:
        one.close()
        two.close()


def test_reset_twice_same_initial_state(device, reference_run):
    actions, initial, _ = reference_run
    env = make(device)
    try:
        first = env.state_dict()
        rollout(env, actions[:70])  # past an auto-reset: episode counters moved on
        env.reset()
        second = env.state_dict()
        assert_state_dicts_identical(first, second)
        assert_identical(snapshot(env), initial)
        env.reset()
        assert_state_dicts_identical(first, env.state_dict())
    finally:
        env.close()


def test_reset_with_seed_equals_fresh_env(device, reference_run):
    actions, _, _ = reference_run
    env = make(device, seed=3)
    fresh = make(device, seed=7)
    try:
        rollout(env, actions[:30])
        obs = env.reset(seed=7)
        assert env.seed == 7
        assert obs["prey"] is env.observations["prey"]
        assert_state_dicts_identical(env.state_dict(), fresh.state_dict())
        assert_identical(snapshot(env), snapshot(fresh))
        assert_identical(rollout(env, actions[:80]), rollout(fresh, actions[:80]))
        # and reseeding back to the original seed reproduces the original run
        env.reset(seed=0)
        _, initial, traj = reference_run
        assert_identical(snapshot(env), initial)
        assert_identical(rollout(env, actions[:60]), traj[:60])
    finally:
        env.close()
        fresh.close()


@pytest.mark.parametrize("cfg", [CFG, CFG_EARLY_ENDS], ids=["default_like", "early_ends"])
def test_state_dict_round_trip_resumes_bit_identically(device, cfg):
    env = make(device, cfg, seed=5)
    try:
        actions = action_sequence(env, 60, seed=6)
        rollout(env, actions[:30])
        saved = env.state_dict()
        saved_snap = snapshot(env)
        first = rollout(env, actions[30:])  # crosses the auto-reset at step 50
        assert int(torch.stack([s["episode_ended"] for s in first]).sum()) > 0
        env.load_state_dict(saved)
        assert_identical(snapshot(env), saved_snap)
        assert_identical(rollout(env, actions[30:]), first)

        # the saved state is a copy: stepping did not change it, and it loads into another env too,
        # even one built with another seed (the state's seed is adopted)
        other = make(device, cfg, seed=99)
        try:
            other.load_state_dict(saved)
            assert other.seed == 5
            assert_identical(snapshot(other), saved_snap)
            assert_identical(rollout(other, actions[30:]), first)
        finally:
            other.close()
    finally:
        env.close()


def test_load_state_dict_refuses_other_config(device):
    env = make(device, num_worlds=2)
    other = make(device, CFG.replace(prey_count=11), num_worlds=2)
    try:
        before = env.state_dict()
        with pytest.raises(ValueError, match="another config or num_worlds"):
            env.load_state_dict(other.state_dict())
        assert_state_dicts_identical(before, env.state_dict())
    finally:
        env.close()
        other.close()


def test_a_state_saved_before_the_capture_rule_existed_resumes_bit_identically(device):
    """A state_dict from before the confusion capture rule (no `handling` tensor; a config without
    `capture_rule`, `confusion_angle` and `handling_steps`) loads with those at their defaults and zero
    handling, and the run continues as from the full state."""
    env = make(device, num_worlds=3, seed=5)
    try:
        actions = action_sequence(env, 20, seed=6)
        rollout(env, actions[:10])
        saved = env.state_dict()
        assert not saved["tensors"]["handling"].any()  # the default rule never handles
        old = copy.deepcopy(saved)
        del old["tensors"]["handling"]
        for name in ("capture_rule", "confusion_angle", "handling_steps"):
            del old["config"][name]
        first = rollout(env, actions[10:])
        env.load_state_dict(old)
        assert_state_dicts_identical(saved, env.state_dict())
        assert_identical(rollout(env, actions[10:]), first)
    finally:
        env.close()


# Worlds of one cell (the fused step) and cell lists built by rank (at most RANK_SORT_MAX_CAPACITY slots).
CAPTURED_STEP_CASES = {
    "fused": (CFG, {}),
    "stages, rank-sorted cells": (CFG.replace(grid_cell_size=100.0), {}),
}
# More slots: cell lists built by counts and a prefix sum (`wp.utils.array_scan`, whose scratch allocation
# a torch capture refuses).
COUNTED_CELLS = AquariumConfig(
    width=900.0, height=900.0, prey_count=150, predator_count=4, max_steps=50, grid_cell_size=150.0
)


def test_which_steps_a_torch_graph_can_record(device):
    """`step_capturable`: every step but that of worlds whose cell lists are built by counts on a GPU
    (the CPU records no graph at all: vacuously capturable)."""
    for cfg, on_gpu in [*((c, True) for c, _ in CAPTURED_STEP_CASES.values()), (COUNTED_CELLS, False)]:
        env = make(device, cfg, num_worlds=2)
        assert env.step_capturable == (on_gpu or not device.startswith("cuda"))
        env.close()


@pytest.mark.parametrize("case", CAPTURED_STEP_CASES)
def test_steps_recorded_in_a_torch_graph_equal_eager_steps(cuda_device, case):
    """A training loop captures whole rollouts, simulation steps and heuristic opponents included, in
    one torch CUDA graph (`ShardSet.run` records the launches into torch's capture instead of launching
    Warp's own graph): 20 replays of a graph of 3 steps give the trajectory of 60 eager steps."""
    from aquarium_warp.heuristics import heuristic_actions

    cfg, kw = CAPTURED_STEP_CASES[case]

    def steps(env, n):
        for _ in range(n):
            env.step(heuristic_actions(env, seed=5), validate=False)

    eager = make(cuda_device, cfg, num_worlds=6, **kw)
    steps(eager, 1)  # (the graphed env's warm-up step)
    want = [snapshot(eager)]
    for _ in range(20):
        steps(eager, 3)
        want.append(snapshot(eager))
    graphed = make(cuda_device, cfg, num_worlds=6, **kw)
    stream = torch.cuda.Stream(cuda_device)
    stream.wait_stream(torch.cuda.current_stream(cuda_device))
    with torch.cuda.stream(stream):  # the warm-up on the capturing stream, as the loop's (and torch) do
        steps(graphed, 1)  # (it loads the modules and captures Warp's own step graph)
    torch.cuda.synchronize(cuda_device)
    got = [snapshot(graphed)]
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph, stream=stream):
        steps(graphed, 3)
    for _ in range(20):
        graph.replay()
        got.append(snapshot(graphed))
    assert_identical(want, got)
    assert bool((graphed.state.torch.episode > 0).all())  # the replays reset worlds (max_steps 50) too


def _group(snap: dict, k: int, worlds: int) -> dict:
    """Worlds `[k * worlds, (k + 1) * worlds)` of a snapshot."""
    return {name: value[k * worlds : (k + 1) * worlds] for name, value in snap.items()}


@pytest.mark.parametrize("cfg", [CFG, CFG_EARLY_ENDS], ids=["default_like", "early_ends"])
def test_groups_of_seeds_draw_as_batches_of_their_own(device, cfg):
    """A batch seeded with K seeds is K batches: group k (its worlds, a heuristic keyed per group, its
    samplers) steps bit for bit as a batch of its own seeded with seed k, auto-resets and reseeds included."""
    from aquarium_warp.heuristics import make_policy
    from aquarium_warp.per_world import Uniform

    seeds, worlds = (5, 0, 11), 4
    cfg = cfg.replace(prey=dataclasses.replace(cfg.prey, max_speed=Uniform(1.5, 3.0)))
    together = make(device, cfg, num_worlds=len(seeds) * worlds, seed=seeds, cpu_threads=2)
    alone = [make(device, cfg, num_worlds=worlds, seed=s) for s in seeds]
    chase = make_policy("naivchase", together, "predator", seed=[s + 1 for s in seeds])
    chase_alone = [make_policy("naivchase", env, "predator", seed=s + 1) for env, s in zip(alone, seeds)]
    try:
        assert together.seed == seeds and alone[0].seed == 5
        prey = action_sequence(together, 120, seed=3)
        for k, env in enumerate(alone):  # the samplers: each group's draws are its seed's
            assert together.config.prey.max_speed[k * worlds : (k + 1) * worlds] == env.config.prey.max_speed
        ends = 0
        for t, step in enumerate(prey):
            if t == 60:  # a reseed keeps the groups
                together.reset(seed=[s + 7 for s in seeds])
                for env, s in zip(alone, seeds):
                    env.reset(seed=s + 7)
            step = {"prey": step["prey"], "predator": chase()}
            snap = snapshot(together, together.step(step))
            ends += int(snap["episode_ended"].sum())
            for k, (env, policy) in enumerate(zip(alone, chase_alone)):
                one = {"prey": step["prey"][k * worlds : (k + 1) * worlds], "predator": policy()}
                assert_identical(_group(snap, k, worlds), snapshot(env, env.step(one)), f"group {k}, step {t}: ")
        assert ends >= 2 * len(seeds) * worlds  # auto-resets happened, before and after the reseed
        # the state dict carries the seeds; a copy continues the same trajectory
        state = together.state_dict()
        assert state["seed"] == tuple(s + 7 for s in seeds)
        copy = make(device, together.config, num_worlds=len(seeds) * worlds, seed=0)
        copy.load_state_dict(together.state_dict())
        assert_state_dicts_identical(copy.state_dict(), together.state_dict())
    finally:
        for env in (together, *alone):
            env.close()


def test_groups_of_seeds_refuse_unequal_groups():
    with pytest.raises(ValueError, match="multiple of the number of seeds"):
        make("cpu", num_worlds=5, seed=[1, 2])
    with pytest.raises(ValueError, match=r"seed=-1 must be a non-negative integer"):
        make("cpu", num_worlds=4, seed=[1, -1])
    with pytest.raises(ValueError, match="at least one seed"):
        make("cpu", num_worlds=4, seed=[])
