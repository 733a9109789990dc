"""The Warp kernels against the float64 reference (tests/reference_model.py) for the ego-spec options
(/work/notes/ego-spec.md): observation_frame "ego", action_frame "ego", spawn_heading "random".

Compared exactly as tests/kernels/test_kernels_vs_reference.py compares (its helpers, random states with edge
cases and tolerances are reused, nothing is loosened): each step's reference input is the kernel's state,
the random draws (respawn positions, replication ages, and now the drawn headings of respawned prey and
newborns) are read from the kernel's post-step state. The ego layout has no angle columns, so every
observation value is compared plainly to 1e-5.

Configs are built inside the tests (not at import), so that a config the env does not accept fails its
own tests instead of the module's collection.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("aquarium_warp")
import reference_model as ref  # noqa: E402
import test_heuristics  # noqa: E402
from test_kernels_vs_reference import (  # noqa: E402
    NUM_WORLDS,
    check_observations_after_set_state,
    check_step,
    compare_observations,
    fail_if,
    kernel_step,
    make_config,
    random_actions,
    random_world,
    read_worlds,
    set_worlds,
    world_config,
)

from aquarium_warp import AquariumConfig, BatchedAquarium  # noqa: E402
from aquarium_warp.config import FlowConfig  # noqa: E402

EGO = dict(observation_frame="ego", action_frame="ego", spawn_heading="random")
ROLLOUT_STEPS = 32


@functools.cache
def configs() -> dict:
    """name -> (config, events the rollout must see: "respawns" / "births")."""
    flow_grid = [[[1.5, -0.5], [0.0, 2.0], [-1.0, 0.5]], [[0.25, 1.0], [-2.0, -1.5], [1.0, 0.0]]]
    out = {
        # everything ego, a small crowded world with several predators: captures and respawns every few steps
        "ego_respawns": (make_config(width=220.0, height=200.0, prey_count=14, predator_count=4, **EGO), {"respawns"}),
        # ego observations for a policy that acts in world directions (the own block holds hx, hy)
        "ego_obs_world_actions": (
            make_config(
                width=300.0,
                height=260.0,
                prey_count=12,
                predator_count=3,
                observation_frame="ego",
                action_frame="world",
                spawn_heading="random",
            ),
            {"respawns"},
        ),
        # the world layout with ego actions (each option on its own)
        "world_obs_ego_actions": (
            make_config(
                width=260.0, height=240.0, prey_count=12, predator_count=3, action_frame="ego", spawn_heading="random"
            ),
            {"respawns"},
        ),
        # "-1..1", FOV off / wide, unusual slot counts (empty blocks, more slots than neighbours)
        "ego_signed_slots": (
            make_config(
                width=260.0,
                height=250.0,
                prey_count=10,
                predator_count=4,
                observation_range="-1..1",
                prey=dict(view_distance=80.0, fov_angle=200.0, predator_slots=3, prey_slots=1),
                predator=dict(view_distance=math.inf, fov_angle=360.0, predator_slots=0, prey_slots=3),
                **EGO,
            ),
            set(),
        ),
        "ego_signed_world_actions": (
            make_config(
                width=240.0,
                height=220.0,
                prey_count=10,
                predator_count=3,
                observation_range="-1..1",
                fov_enabled=False,
                observation_frame="ego",
                action_frame="world",
            ),
            set(),
        ),
        # an observed, time-varying current: rotated into the ego frame, clipped per component
        "ego_vortex_observed": (
            make_config(
                width=300.0,
                height=260.0,
                prey_count=14,
                predator_count=2,
                observe_flow=True,
                flow=FlowConfig(
                    "vortex", centre=(10.0, 250.0), strength=3.0, core_radius=40.0, amplitude=0.5, period=7.0
                ),
                **EGO,
            ),
            set(),
        ),
        # per-world values and currents (one faster than its prey: clipped), "-1..1", world actions
        "ego_per_world_flow_observed": (
            make_config(
                width=260.0,
                height=240.0,
                prey_count=(12, 5, 9, 12),
                predator_count=(2, 3, 1, 3),
                observe_flow=True,
                observation_range="-1..1",
                observation_frame="ego",
                action_frame="world",
                spawn_heading="random",
                prey=dict(
                    max_speed=(4.0, 2.0, 6.0, 3.0),
                    fov_angle=(120.0, 360.0, 90.0, 200.0),
                    view_distance=(100.0, math.inf, 60.0, 140.0),
                ),
                predator=dict(max_speed=(5.0, 7.0, 3.0, 5.0), view_distance=(200.0, 90.0, math.inf, 120.0)),
                flow=(
                    FlowConfig(),
                    FlowConfig("uniform", velocity=(2.5, -1.0)),
                    FlowConfig("grid", grid=flow_grid, amplitude=1.0, period=5.0),
                    FlowConfig("vortex", centre=(130.0, 0.0), strength=-4.0, core_radius=60.0),
                ),
            ),
            set(),
        ),
        # newborns take a drawn heading and zero velocity
        "ego_reproduction": (
            make_config(
                width=240.0,
                height=200.0,
                prey_count=6,
                predator_count=2,
                prey_reproduction=True,
                max_prey=12,
                prey_replication_age=4,
                predator_starvation_steps=40,
                **EGO,
            ),
            {"births"},
        ),
        # more slots than one cell takes (capacity 43 > 32): cell lists of several cells by default
        "ego_many_agents": (make_config(width=400.0, height=360.0, prey_count=40, predator_count=3, **EGO), set()),
    }
    # the same small worlds cut into cells: the staged path with ring searches across cell borders
    for name in ("ego_respawns", "ego_reproduction", "ego_per_world_flow_observed"):
        cfg, events = out[name]
        out[name + "_cells"] = (dataclasses.replace(cfg, grid_cell_size=40.0), events)
    return out


NAMES = [
    "ego_respawns",
    "ego_obs_world_actions",
    "world_obs_ego_actions",
    "ego_signed_slots",
    "ego_signed_world_actions",
    "ego_vortex_observed",
    "ego_per_world_flow_observed",
    "ego_reproduction",
    "ego_many_agents",
    "ego_respawns_cells",
    "ego_reproduction_cells",
    "ego_per_world_flow_observed_cells",
]
# one-cell worlds step fused by default ("auto"); they run the staged launches too
SINGLE_CELL = [
    "ego_respawns",
    "ego_obs_world_actions",
    "world_obs_ego_actions",
    "ego_signed_slots",
    "ego_signed_world_actions",
    "ego_vortex_observed",
    "ego_per_world_flow_observed",
    "ego_reproduction",
]
STEP_CASES = [(name, "auto") for name in NAMES] + [(name, "stages") for name in SINGLE_CELL]
_ENVS: dict = {}


def get_env(name: str, device: str, step_kernel: str = "auto") -> BatchedAquarium:
    if (name, step_kernel) not in _ENVS:
        _ENVS[name, step_kernel] = BatchedAquarium(
            configs()[name][0], num_worlds=NUM_WORLDS, device=device, seed=0, step_kernel=step_kernel
        )
    return _ENVS[name, step_kernel]


def test_config_list_is_complete():
    assert sorted(NAMES) == sorted(configs())
    assert set(SINGLE_CELL) == {n for n in NAMES if not n.endswith("_cells") and n != "ego_many_agents"}


def test_cell_layouts_take_the_intended_paths():
    """The one-cell configs step fused under "auto"; the others have several cells (staged)."""
    from aquarium_warp.env import grid_dims

    for name in NAMES:
        several = grid_dims(configs()[name][0]) != (1, 1)
        assert several == (name not in SINGLE_CELL), name


@pytest.fixture
def events(monkeypatch):
    """Tallies what the reference's steps saw (respawns, births) and the kernel's drawn headings of those
    fresh prey (read from the kernel's post-step state, which check_step passes as respawn_heading /
    newborn_heading)."""
    seen = {"respawns": 0, "births": 0, "fresh_headings": []}
    step = ref.step

    def recording_step(cfg, *args, **kwargs):
        result = step(cfg, *args, **kwargs)
        info = result[-1]
        seen["respawns"] += len(info["respawned"])
        seen["births"] += len(info["births"])
        if ref.spawn_heading(cfg) == "random":
            for slot in info["respawned"]:
                seen["fresh_headings"].append(np.asarray(kwargs["respawn_heading"][slot], np.float64))
            for _, child in info["births"]:
                seen["fresh_headings"].append(np.asarray(kwargs["newborn_heading"][child], np.float64))
        return result

    monkeypatch.setattr(ref, "step", recording_step)
    return seen


def check_fresh_headings(name: str, seen: dict) -> None:
    """Drawn headings of respawned prey and newborns: unit vectors, not all the same."""
    h = np.array(seen["fresh_headings"]).reshape(-1, 2)
    if len(h):
        np.testing.assert_allclose(np.linalg.norm(h, axis=1), 1.0, atol=1e-6, err_msg=name)
    if len(h) >= 2:
        assert np.ptp(h, axis=0).max() > 0.1, f"{name}: every fresh prey got the same heading {h[0]}"


# --------------------------------------------------------------------------------------------------
# Kernel vs reference
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_ego_observations_after_set_state(name, device):
    check_observations_after_set_state(
        name, configs()[name][0], get_env(name, device), np.random.default_rng(5000 + NAMES.index(name))
    )


@pytest.mark.parametrize("name", ["ego_respawns", "ego_signed_slots", "ego_per_world_flow_observed", "ego_many_agents"])
def test_ego_observations_after_reset(name, device):
    """The observations of a fresh episode (random spawn headings) against the reference's of that state."""
    cfg, env = configs()[name][0], get_env(name, device)
    env.reset(seed=17)
    after = read_worlds(env)
    errors = []
    for w in range(env.num_worlds):
        r_obs, r_mask, r_slots = ref.observe(world_config(cfg, w), after[w], with_slots=True, world_step=0)
        k_obs = {k: v[w].detach().cpu().numpy() for k, v in env.observations.items()}
        k_mask = {k: v[w].detach().cpu().numpy() for k, v in env.observation_mask.items()}
        compare_observations(cfg, f"[{name} reset world {w}]", k_obs, k_mask, r_obs, r_mask, r_slots, errors)
    fail_if(errors, name)


@pytest.mark.parametrize("name, step_kernel", STEP_CASES)
def test_ego_single_step_from_random_states(name, step_kernel, events, device):
    cfg, env = configs()[name][0], get_env(name, device, step_kernel)
    rng = np.random.default_rng(6000 + NAMES.index(name))
    errors = []
    for rep in range(3):
        worlds = [random_world(rng, world_config(cfg, w)) for w in range(env.num_worlds)]
        set_worlds(env, worlds)
        check_step(name, cfg, env, worlds, random_actions(rng, cfg, env.num_worlds), errors, f" #{rep}")
    fail_if(errors, name)
    check_fresh_headings(name, events)


@pytest.mark.slow
@pytest.mark.parametrize("name, step_kernel", STEP_CASES)
def test_ego_rollout_resynced_each_step(name, step_kernel, events, device):
    """ROLLOUT_STEPS steps with random actions, each step's reference input the kernel's state. Ego actions
    turn from each agent's own heading, so a constant action per world makes agents circle; worlds whose
    episode ends auto-reset (random headings) and go on. The configs meant to respawn or give birth must."""
    cfg, expected_events = configs()[name]
    env = get_env(name, device, step_kernel)
    rng = np.random.default_rng(7000 + NAMES.index(name))
    errors = []
    worlds = [random_world(rng, world_config(cfg, w)) for w in range(env.num_worlds)]
    set_worlds(env, worlds)
    starts = read_worlds(env)
    for k in range(ROLLOUT_STEPS):
        actions = random_actions(rng, cfg, env.num_worlds)
        actions[:, ::2] = rng.integers(0, cfg.action_count, (env.num_worlds, 1))
        starts = check_step(name, cfg, env, starts, actions, errors, f" step {k}")
        if errors:
            break
    fail_if(errors, name)
    for event in sorted(expected_events):
        assert events[event] > 0, f"{name}: no {event} in {ROLLOUT_STEPS} steps"
    check_fresh_headings(name, events)


# --------------------------------------------------------------------------------------------------
# Spawn headings and defaults
# --------------------------------------------------------------------------------------------------
def _reset_state(cfg, num_worlds, device, seed=0):
    env = BatchedAquarium(cfg, num_worlds=num_worlds, device=device, seed=seed)
    env.reset()
    return env, {
        k: v.cpu().numpy().copy()
        for k, v in (
            (k, getattr(env.state.torch, k)) for k in ("position", "velocity", "heading", "alive", "replication_age")
        )
    }


def test_random_spawn_headings_at_episode_start(device):
    """spawn_heading "random": every live agent's heading is a unit vector, velocity = heading * 1 (both
    types), headings differ and cover all four quadrants (prey and predators each); the paper layout's
    draws (positions, replication ages) are unchanged, because the angle is drawn after them."""
    kw = dict(prey_count=16, predator_count=2, prey_reproduction=True, max_prey=20)
    env, st = _reset_state(AquariumConfig(**kw, spawn_heading="random"), 48, device)
    _, paper = _reset_state(AquariumConfig(**kw), 48, device)
    Pc = env.prey_capacity
    alive = st["alive"]
    assert alive[:, :16].all() and not alive[:, 16:Pc].any() and alive[:, Pc:].all()
    np.testing.assert_array_equal(st["alive"], paper["alive"])
    np.testing.assert_array_equal(st["position"][alive], paper["position"][alive])
    np.testing.assert_array_equal(st["replication_age"][alive], paper["replication_age"][alive])
    for name, cols in (("prey", slice(0, Pc)), ("predator", slice(Pc, None))):
        h = st["heading"][:, cols][alive[:, cols]].astype(np.float64)
        v = st["velocity"][:, cols][alive[:, cols]].astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(h, axis=1), 1.0, atol=1e-6, err_msg=name)
        np.testing.assert_array_equal(v, h, err_msg=f"{name}: velocity != heading * 1")
        quadrants = {(bool(x > 0), bool(y > 0)) for x, y in h}
        assert len(quadrants) == 4, f"{name}: headings cover only quadrants {quadrants}"
        assert len({tuple(x) for x in h}) > len(h) // 2, f"{name}: headings repeat"
        # uniform angles: the mean of n unit vectors is about 1 / sqrt(n) long; 4 / sqrt(n) is a 1e-7 event
        assert np.linalg.norm(h.mean(axis=0)) < 4.0 / math.sqrt(len(h)), name
    # the paper layout: prey west, predators north, at speed 1
    assert (paper["heading"][:, :16] == [-1.0, 0.0]).all() and (paper["velocity"][:, :16] == [-1.0, 0.0]).all()
    assert (paper["heading"][:, Pc:] == [0.0, -1.0]).all() and (paper["velocity"][:, Pc:] == [0.0, -1.0]).all()


def test_random_spawn_headings_after_auto_reset(device):
    """An auto-reset (max_steps 2) spawns the next episode with new random headings (its own spawn stream),
    velocity = heading * 1, at the paper layout's positions."""
    kw = dict(prey_count=12, predator_count=2, max_steps=2)
    envs = [
        BatchedAquarium(AquariumConfig(**kw, spawn_heading=mode), num_worlds=16, device=device, seed=5)
        for mode in ("random", "paper")
    ]
    for env in envs:
        env.reset()
    first = envs[0].state.torch.heading.cpu().numpy().copy()
    zeros = np.zeros((16, envs[0].capacity), np.int64)
    for _ in range(2):
        for env in envs:
            kernel_step(env, zeros)
    st = {k: getattr(envs[0].state.torch, k).cpu().numpy() for k in ("heading", "velocity", "position", "world_step")}
    assert (st["world_step"] == 0).all()  # every world started its second episode
    h = st["heading"].reshape(-1, 2).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(st["velocity"], st["heading"])
    assert len({(bool(x > 0), bool(y > 0)) for x, y in h}) == 4
    assert not np.array_equal(st["heading"], first)  # a new episode, new draws
    np.testing.assert_array_equal(st["position"], envs[1].state.torch.position.cpu().numpy())


def test_drawn_headings_follow_the_documented_formula(device):
    """docs/model.md "Randomness": a random heading is (cos phi, sin phi), phi = fl32(fl32(2 pi) u) for u the
    first draw of mix32(rng ^ PURPOSE_HEADING), rng the agent's own stream, keyed by the slot it takes: the
    spawn stream of its slot at an episode start, and for a newborn the child's slot's newborn stream of
    the step being finished (t + 1), not its parent's."""
    from aquarium_warp.seeding import seed_key

    # replication age 1: every prey of the first step is a parent, its child in a slot free at the start
    cfg = AquariumConfig(
        prey_count=3,
        predator_count=2,
        prey_reproduction=True,
        max_prey=6,
        prey_replication_age=1,
        spawn_heading="random",
    )
    env = BatchedAquarium(cfg, num_worlds=3, device=device, seed=11)
    env.reset()
    key = seed_key(11)

    def state():
        return env.state.torch.heading.cpu().numpy().copy(), env.state.torch.alive.cpu().numpy().copy()

    heading, alive = state()
    for w, slot in zip(*np.nonzero(alive)):
        expected = ref.drawn_heading(ref.random_stream(key, int(w), 0, 0, int(slot), ref.PURPOSE_SPAWN))
        np.testing.assert_allclose(heading[w, slot], expected, rtol=0, atol=2e-7, err_msg=f"world {w} slot {slot}")
    kernel_step(env, np.zeros((3, env.capacity), np.int64))
    heading, after = state()
    births = list(zip(*np.nonzero(after & ~alive)))
    assert len(births) >= 6, births  # 3 per world unless a prey was caught
    for w, child in births:
        expected = ref.drawn_heading(ref.random_stream(key, int(w), 0, 1, int(child), ref.PURPOSE_NEWBORN))
        np.testing.assert_allclose(heading[w, child], expected, rtol=0, atol=2e-7, err_msg=f"world {w} child {child}")


def test_random_spawn_headings_depend_on_the_seed_and_reproduce(device):
    cfg = AquariumConfig(prey_count=8, predator_count=2, spawn_heading="random")
    _, a = _reset_state(cfg, 4, device, seed=1)
    _, b = _reset_state(cfg, 4, device, seed=1)
    _, c = _reset_state(cfg, 4, device, seed=2)
    np.testing.assert_array_equal(a["heading"], b["heading"])
    assert not np.array_equal(a["heading"], c["heading"])


@pytest.mark.slow
def test_named_defaults_are_bit_for_bit_the_unnamed_config(device):
    """observation_frame "world", action_frame "world", spawn_heading "paper" named explicitly give the
    same observations, masks, rewards and states, bit for bit, as a config that does not name them, over a
    rollout with captures, respawns and auto-resets (fused and staged)."""
    kw = dict(width=220.0, height=200.0, prey_count=12, predator_count=3, max_steps=15)
    plain = AquariumConfig(**kw)
    named = AquariumConfig(**kw, observation_frame="world", action_frame="world", spawn_heading="paper")
    assert plain == named
    for step_kernel in ("auto", "stages"):
        envs = [
            BatchedAquarium(c, num_worlds=4, device=device, seed=3, step_kernel=step_kernel) for c in (plain, named)
        ]
        obs = [e.reset() for e in envs]
        assert obs[0]["prey"].shape[-1] == 29 and obs[0]["predator"].shape[-1] == 29
        rng = np.random.default_rng(0)
        for k in range(20):
            for key in ("prey", "predator"):
                assert torch.equal(obs[0][key], obs[1][key]), (step_kernel, k, key)
                assert torch.equal(envs[0].observation_mask[key], envs[1].observation_mask[key])
            for name in ref.FIELDS:
                assert torch.equal(getattr(envs[0].state.torch, name), getattr(envs[1].state.torch, name)), name
            actions = random_actions(rng, plain, 4)
            results = [kernel_step(e, actions) for e in envs]
            obs = [r[0] for r in results]
            for key in ("prey", "predator"):
                assert torch.equal(results[0][1][key], results[1][1][key])  # rewards


# --------------------------------------------------------------------------------------------------
# Heuristics under action_frame "ego"
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("variant", ["default", "no_fov", "small_world"])
def test_ego_heuristics_match_the_brute_force_reference(variant, monkeypatch, device):
    """test_heuristics' all-pairs reference with the ego choice: the same flee / chase direction d, then the
    action nearest to u = (d.r, -(d.f)) (zero d: action 0)."""
    world = {"default": {}, "no_fov": {"fov_enabled": False}, "small_world": {"width": 300.0, "height": 250.0}}
    cfg = AquariumConfig(prey_count=10, predator_count=3, action_frame="ego", **world[variant])
    monkeypatch.setattr(test_heuristics, "nearest_action", ref.ego_nearest_action)
    W = 48
    env = BatchedAquarium(cfg, num_worlds=W, device=device, seed=3)
    rng = np.random.default_rng(11)
    C = env.capacity
    spread = np.where(rng.random((W, 1, 1)) < 0.3, 60.0, 1.0)
    centre = rng.random((W, 1, 2)) * [cfg.width, cfg.height]
    pos = centre + (rng.random((W, C, 2)) - 0.5) * [cfg.width, cfg.height] / spread
    pos = np.round(np.mod(pos, [cfg.width, cfg.height]) * 2) / 2 % [cfg.width, cfg.height]
    angle = rng.random((W, C)) * 2 * np.pi
    heading = np.stack([np.cos(angle), np.sin(angle)], -1).astype(np.float32)
    alive = rng.random((W, C)) < 0.85
    alive[:4, : cfg.prey_count] = False  # nothing to chase: action 0 (keep the heading)
    alive[4:8, cfg.prey_count :] = False  # nothing to flee
    env.set_state(position=pos.astype(np.float32), velocity=heading * 2, heading=heading, alive=alive)
    state = {k: getattr(env.state.torch, k).cpu().numpy().astype(np.float64) for k in ("position", "heading")}
    state["alive"] = env.state.torch.alive.cpu().numpy()
    for name, agent_type, kw in [
        ("turnaway", "prey", {}),
        ("naivchase-nearest", "predator", {"confusion": False}),
        ("naivchase", "predator", {}),
    ]:
        got = test_heuristics.decide(env, name.split("-")[0], agent_type, **kw)
        want = test_heuristics.reference(cfg, state, name, agent_type)
        bad = [
            (w, s, int(got[w, s]), want[w][s])
            for w in range(W)
            for s in range(got.shape[1])
            if int(got[w, s]) not in want[w][s]
        ]
        assert not bad, f"{name}: (world, slot, got, allowed) {bad[:5]}"
        # nothing to flee (worlds 4-7) or chase (worlds 0-3): keep the heading, which is action 0 in ego
        nothing = slice(4, 8) if agent_type == "prey" else slice(0, 4)
        own = slice(0, cfg.prey_capacity) if agent_type == "prey" else slice(cfg.prey_capacity, None)
        assert (got[nothing][state["alive"][nothing, own]] == 0).all(), name
