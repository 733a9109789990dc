"""Per-world parameters and flow fields (issue 18): a batch whose worlds differ equals, world by world,
batches of each world's own config (bit for bit on the CPU); live counts per world; `set_params`
between steps; samplers; bad per-world values rejected by name and world; hand-computed currents."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.config import FlowConfig
from aquarium_warp.heuristics import HeuristicPolicy
from aquarium_warp.metrics import EpisodeMetrics, SwarmMetrics
from aquarium_warp.per_world import Choice, LogUniform, Uniform
from aquarium_warp.render import Renderer

BASE = AquariumConfig(width=300.0, height=260.0, prey_count=12, predator_count=2)
# Live prey per world differ; the prey slots stay 12 in the batch and in each world's own batch
# (reproduction up to max_prey = 12), because random draws are keyed by slot and predator slots
# follow the prey slots.
PER_WORLD = dataclasses.replace(
    BASE,
    prey_count=(12, 5, 9),
    prey_reproduction=True,
    max_prey=12,
    prey_replication_age=30,
    prey_reward=(1.0, 0.25, 2.0),
    catch_share_radius=(100.0, 0.0, 150.0),
    predator_reward=(10.0, 4.0, 10.0),
    prey=dataclasses.replace(
        BASE.prey,
        max_speed=(4.0, 2.5, 6.0),
        fov_angle=(120.0, 360.0, 80.0),
        view_distance=(100.0, math.inf, 60.0),
        radius=(20.0, 12.0, 25.0),
    ),
    predator=dataclasses.replace(BASE.predator, max_acceleration=(0.6, 1.2, 0.3), mass=(10.0, 4.0, 10.0)),
    flow=(
        FlowConfig(),
        FlowConfig("vortex", centre=(150.0, 5.0), strength=2.0, core_radius=50.0),
        FlowConfig("uniform", velocity=(-1.5, 0.5), amplitude=0.5, period=9.0),
    ),
)


def random_actions(gen: torch.Generator, worlds: int, prey: int, predators: int) -> dict:
    return {
        "prey": torch.randint(0, 16, (worlds, prey), generator=gen, dtype=torch.int32),
        "predator": torch.randint(0, 16, (worlds, predators), generator=gen, dtype=torch.int32),
    }


def world_slice(env, w: int, prey: int, predators: int) -> dict:
    """World w's live-slot arrays (prey slots [0, prey), predator slots after the batch's prey slots)."""
    t, Pc = env.state.torch, env.prey_capacity
    slots = list(range(prey)) + list(range(Pc, Pc + predators))
    out = {name: getattr(t, name)[w, slots].clone() for name in ("position", "velocity", "alive", "starvation")}
    out["reward"] = t.reward[w, slots].clone()
    out["obs_prey"] = t.obs_prey[w, :prey].clone()
    out["obs_predator"] = t.obs_predator[w, :predators].clone()
    out["episode_return"] = t.episode_return[w, slots].clone()
    return out


def test_batch_of_different_worlds_equals_a_batch_per_world_config():
    """World k of a per-world batch steps as world k of a batch of `PER_WORLD.world(k)`, bit for bit
    (the random streams are keyed by the world's index, so every batch has the same number of worlds)."""
    W, steps = PER_WORLD.num_worlds, 60
    batch = BatchedAquarium(PER_WORLD, W, device="cpu", seed=5)
    singles = [BatchedAquarium(PER_WORLD.world(k), W, device="cpu", seed=5) for k in range(W)]
    gen = torch.Generator().manual_seed(1)
    for step in range(steps):
        actions = random_actions(gen, W, batch.prey_capacity, batch.predator_capacity)
        batch.step(actions)
        for k, single in enumerate(singles):
            single.step(
                {
                    "prey": actions["prey"][:, : single.prey_capacity],
                    "predator": actions["predator"][:, : single.predator_capacity],
                }
            )
            mine = world_slice(batch, k, single.prey_capacity, single.predator_capacity)
            theirs = world_slice(single, k, single.prey_capacity, single.predator_capacity)
            for name in mine:
                assert torch.equal(mine[name], theirs[name]), f"step {step} world {k}: {name} differs"
    assert batch.state.torch.alive[:, :12].sum(dim=1).tolist() != [12, 12, 12]


def identical(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Bit-for-bit equal, NaN where the other is NaN (an undefined metric, e.g. local alignment without
    linked prey, is NaN in both)."""
    return torch.equal(a, b) or bool((torch.isnan(a) & torch.isnan(b)).all())


def test_metrics_and_frames_of_a_per_world_batch_equal_each_world_config():
    """Swarm metrics (linking distance: each world's 2.5 prey radii), episode metrics (captures per
    prey: each world's prey count) and frames (each world's hit boxes and view cones) of a per-world
    batch equal, world by world, those of a batch of that world's own config (same states)."""
    cfg = dataclasses.replace(PER_WORLD, max_steps=25)
    W = cfg.num_worlds
    batch = BatchedAquarium(cfg, W, device="cpu", seed=5)
    singles = [BatchedAquarium(cfg.world(k), W, device="cpu", seed=5) for k in range(W)]
    envs = [batch] + singles
    episodes = [EpisodeMetrics(env, nn_range=150.0) for env in envs]
    for e in episodes:
        e.begin()
    gen = torch.Generator().manual_seed(2)
    for _ in range(40):  # one episode ends in every world, the next one is under way
        actions = random_actions(gen, W, batch.prey_capacity, batch.predator_capacity)
        for env, e in zip(envs, episodes):
            out = env.step(
                {
                    "prey": actions["prey"][:, : env.prey_capacity],
                    "predator": actions["predator"][:, : env.predator_capacity],
                }
            )
            e.update(out.info)
    assert SwarmMetrics(batch).linking_distance == (50.0, 30.0, 62.5)
    swarm = SwarmMetrics(batch, nn_range=150.0).compute()
    batch_episodes = episodes[0].result()
    renderer = Renderer(batch, 150, 130)
    for k, single in enumerate(singles):
        theirs = SwarmMetrics(single, nn_range=150.0).compute()
        for name, value in swarm.items():
            assert identical(value[k], theirs[name][k]), f"world {k}: {name}"
        single_episodes = episodes[1 + k].result()
        assert batch_episodes["episodes"][k] == 1
        for name, value in batch_episodes.items():
            assert identical(value[k], single_episodes[name][k]), f"world {k}: episode {name}"
        for options in ({"hit_boxes": True}, {"view_cones": True}):
            frame = renderer.render(k, **options)
            assert np.array_equal(frame, Renderer(single, 150, 130).render(k, **options)), (k, options)
    per_prey = batch_episodes["captures"] / torch.tensor([12.0, 5.0, 9.0], dtype=torch.float64)
    assert torch.equal(batch_episodes["captures_per_prey"], per_prey)


def test_swarm_size_sweep_in_one_batch_equals_one_batch_per_size():
    """Prey counts 4..64 in one batch of capacity 64, heuristic policies reading each world's own
    parameters: per size, the prey's survival and the capture rate agree with one batch per size.
    Prey draws are keyed by slot, so the prey start where they start in the batch of their size
    (checked exactly); predator slots follow the prey slots, so their draws differ and the capture
    rates agree statistically (within 4 standard errors over 24 worlds x 150 steps, fixed seeds)."""
    sizes, repeats, steps = (4, 16, 64), 24, 150
    counts = tuple(n for n in sizes for _ in range(repeats))
    base = dataclasses.replace(BASE, width=400.0, height=400.0, predator_count=2)
    sweep = BatchedAquarium(dataclasses.replace(base, prey_count=counts), len(counts), device="cpu", seed=9)
    start = sweep.state.torch.position.clone()

    def run(env):
        prey, predator = HeuristicPolicy("turnaway", env, "prey"), HeuristicPolicy("naivchase", env, "predator")
        captures = torch.zeros(env.num_worlds, steps)
        for k in range(steps):
            out = env.step({"prey": prey(), "predator": predator()})
            captures[:, k] = out.info["captures"]
        return captures

    sweep_captures = run(sweep)
    for s, n in enumerate(sizes):
        worlds = slice(s * repeats, (s + 1) * repeats)
        alone = BatchedAquarium(dataclasses.replace(base, prey_count=n), len(counts), device="cpu", seed=9)
        assert torch.equal(alone.state.torch.position[worlds, :n], start[worlds, :n])
        captures = run(alone)
        a, b = sweep_captures[worlds].mean(dim=1), captures[worlds].mean(dim=1)  # per world
        error = math.sqrt((a.var() + b.var()) / repeats)
        assert abs(float(a.mean() - b.mean())) <= 4 * error + 1e-9, (n, float(a.mean()), float(b.mean()))
        assert float(a.mean()) > 0.0
    # More prey, more captures: the sizes are not all the same world.
    rates = [float(sweep_captures[s * repeats : (s + 1) * repeats].mean()) for s in range(len(sizes))]
    assert rates[0] < rates[1] < rates[2]


def test_set_params_between_steps_equals_a_batch_built_with_them():
    """`set_params` writes into the arrays the recorded launches read: after it, the env steps as one
    built with the new values (live counts from the next reset)."""
    W = 3
    target = dataclasses.replace(
        PER_WORLD, prey_reproduction=False, max_prey=BASE.max_prey, prey_replication_age=BASE.prey_replication_age
    )
    env = BatchedAquarium(BASE, W, device="cpu", seed=2)
    step_before = env._shards.programs["step"]
    env.set_params(
        prey_count=PER_WORLD.prey_count,
        predator_count=PER_WORLD.predator_count,
        prey_reward=PER_WORLD.prey_reward,
        catch_share_radius=PER_WORLD.catch_share_radius,
        predator_reward=PER_WORLD.predator_reward,
        flow=PER_WORLD.flow,
        **{f"prey_{n}": getattr(PER_WORLD.prey, n) for n in ("max_speed", "fov_angle", "view_distance", "radius")},
        **{f"predator_{n}": getattr(PER_WORLD.predator, n) for n in ("max_acceleration", "mass")},
    )
    assert env._shards.programs["step"] is step_before  # nothing recorded again
    assert env.config == target
    env.reset()
    twin = BatchedAquarium(target, W, device="cpu", seed=2)
    assert twin.prey_capacity == env.prey_capacity
    gen = torch.Generator().manual_seed(3)
    for _ in range(30):
        actions = random_actions(gen, W, env.prey_capacity, env.predator_capacity)
        a, b = env.step(actions), twin.step(actions)
        assert torch.equal(a.observations["prey"], b.observations["prey"])
        assert torch.equal(a.rewards["predator"], b.rewards["predator"])
        assert torch.equal(env.state.torch.position, twin.state.torch.position)
    # One world changed mid-run: the other worlds go on as before.
    env.set_params(world=1, prey_max_speed=1.0, flow=FlowConfig("uniform", velocity=(3.0, 0.0)))
    actions = random_actions(gen, W, env.prey_capacity, env.predator_capacity)
    env.step(actions)
    twin.step(actions)
    assert torch.equal(env.state.torch.position[[0, 2]], twin.state.torch.position[[0, 2]])
    assert not torch.equal(env.state.torch.position[1], twin.state.torch.position[1])
    assert float(env.state.torch.velocity[1, :5].norm(dim=-1).max()) <= 1.0 + 1e-6


def test_bad_values_per_world_are_rejected_by_field_and_world():
    speeds = (4.0,) * 7 + (-1.0,) + (4.0,) * 2
    with pytest.raises(ValueError, match=r"world 7: prey\.max_speed=-1\.0 is out of range: must be"):
        AquariumConfig(prey=dataclasses.replace(BASE.prey, max_speed=speeds))
    with pytest.raises(ValueError, match=r"world 2: catch_share_radius=nan is out of range"):
        dataclasses.replace(BASE, catch_share_radius=(100.0, 50.0, float("nan")))
    with pytest.raises(ValueError, match=r"give one value per world"):
        dataclasses.replace(BASE, prey_reward=(1.0, 2.0), predator_reward=(1.0, 2.0, 3.0))
    env = BatchedAquarium(BASE, 10, device="cpu", seed=4)
    twin = BatchedAquarium(BASE, 10, device="cpu", seed=4)
    config, types_before = env.config, env.agent_types.numpy().copy()
    with pytest.raises(ValueError, match=r"world 7: prey\.max_speed=-1\.0 is out of range"):
        env.set_params(world=7, prey_max_speed=-1.0)
    with pytest.raises(ValueError, match=r"world 3: predator\.fov_angle=nan is out of range: must be in \(0, 360\]"):
        env.set_params(world=[1, 3], predator_fov_angle=[90.0, float("nan")])
    with pytest.raises(ValueError, match=r"world 0: prey_count=13 is out of range: must be an integer in \[1, 12\]"):
        env.set_params(world=0, prey_count=13)
    with pytest.raises(ValueError, match=r"unknown per-world parameter 'width'"):
        env.set_params(width=10.0)
    for world in (True, [2, 2], [1.5], "a", 10):  # a flag, a repeat (which value would hold?), no index
        with pytest.raises(ValueError, match=r"must be None, an integer or distinct integers in \[0, 9\]"):
            env.set_params(world=world, prey_max_speed=3.0)
    with pytest.raises(ValueError, match=r"world 5: prey\.max_speed=140\.0 is out of range: must be smaller than half"):
        env.set_params(world=5, prey_max_speed=140.0)  # 140 + the world's 0 current < 130 fails
    # Nothing changed, and the env still steps as its twin.
    assert env.config is config
    assert np.array_equal(env.agent_types.numpy(), types_before)
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        actions = random_actions(gen, 10, env.prey_capacity, env.predator_capacity)
        assert torch.equal(env.step(actions).observations["prey"], twin.step(actions).observations["prey"])


def test_samplers_draw_per_world_values_in_range_from_the_seed():
    cfg = dataclasses.replace(
        BASE,
        prey_count=Choice((4, 8, 12)),
        prey_reward=Uniform(0.5, 2.0),
        prey=dataclasses.replace(BASE.prey, view_distance=LogUniform(30.0, 300.0)),
    )
    env = BatchedAquarium(cfg, 64, device="cpu", seed=11)
    assert set(env.config.prey_count) == {4, 8, 12} and env.prey_capacity == 12
    assert all(0.5 <= r <= 2.0 for r in env.config.prey_reward)
    assert all(30.0 <= v <= 300.0 for v in env.config.prey.view_distance)
    assert torch.equal(env.alive["prey"].sum(dim=1), torch.tensor(env.config.prey_count))
    again = BatchedAquarium(cfg, 64, device="cpu", seed=11)
    assert again.config == env.config
    assert BatchedAquarium(cfg, 64, device="cpu", seed=12).config != env.config
    with pytest.raises(ValueError, match=r"a sampler's range: prey\.max_speed=200\.0 is out of range"):
        dataclasses.replace(BASE, prey=dataclasses.replace(BASE.prey, max_speed=Uniform(1.0, 200.0)))
    env.set_params(world=[0, 1], prey_fov_angle=Uniform(30.0, 60.0), rng=np.random.default_rng(0))
    assert all(30.0 <= a <= 60.0 for a in env.config.prey.fov_angle[:2])
    assert env.config.prey.fov_angle[2:] == (120.0,) * 62


def test_a_dict_in_a_per_world_field_other_than_flow_is_named():
    with pytest.raises(ValueError, match=r"world 0: prey_reward=\{'x': 1\} is out of range"):
        AquariumConfig(prey_reward=[{"x": 1}])


def test_set_params_draws_anew_from_the_envs_own_generator():
    """Without `rng`, samplers draw from the env's generator: new values at every call, the same
    sequence for the same seed (and again after a seeded reset), not the config's own draws."""
    cfg = dataclasses.replace(BASE, prey_reward=Uniform(0.5, 2.0))

    def draws(env) -> list:
        return [env.set_params(prey_reward=Uniform(0.5, 2.0)).prey_reward for _ in range(3)]

    env = BatchedAquarium(cfg, 8, device="cpu", seed=11)
    first = draws(env)
    assert len(set(first)) == 3  # every call draws anew
    again = BatchedAquarium(cfg, 8, device="cpu", seed=11)
    assert first[0] != again.config.prey_reward  # not a repeat of the construction's draw
    assert draws(again) == first
    assert draws(BatchedAquarium(cfg, 8, device="cpu", seed=12)) != first
    env.reset(seed=11)
    assert draws(env) == first


# --------------------------------------------------------------------------------------------------
# Hand-computed currents (docs/model.md "Flow fields"): the drift of a lone agent is P' - P - V'.
# --------------------------------------------------------------------------------------------------
def drift(flow: FlowConfig, position, world_step: int = 0, size=(800.0, 800.0)) -> np.ndarray:
    cfg = AquariumConfig(width=size[0], height=size[1], prey_count=1, predator_count=1, flow=flow)
    env = BatchedAquarium(cfg, 1, device="cpu", seed=0)
    # The predator far from the prey (no capture), both at rest.
    env.set_state(
        world=0,
        position=torch.tensor([position, [position[0] + 400.0 - size[0] * (position[0] >= 400.0), position[1]]]),
        velocity=torch.zeros(2, 2),
        world_step=world_step,
    )
    env.step({"prey": torch.zeros(1, 1, dtype=torch.int32), "predator": torch.zeros(1, 1, dtype=torch.int32)})
    t = env.state.torch
    d = (t.position[0, 0] - torch.tensor(position) - t.velocity[0, 0]).double().numpy()
    return (d + 0.5 * np.array(size)) % np.array(size) - 0.5 * np.array(size)  # torus-shortest


def test_vortex_at_the_core_edge():
    # d = (50, 0), rho = r_c: g = 1, C = w (-d_y, d_x) / rho = (0, 2): clockwise on screen (y down).
    c = drift(FlowConfig("vortex", centre=(100.0, 100.0), strength=2.0, core_radius=50.0), [150.0, 100.0])
    assert np.allclose(c, [0.0, 2.0], atol=1e-4)


def test_vortex_across_the_seam():
    # Q = (790, 400), P = (10, 400): the shortest d = (20, 0) crosses x = 0; g = 20/50, C = 2 * 0.4 * (0, 1).
    c = drift(FlowConfig("vortex", centre=(790.0, 400.0), strength=2.0, core_radius=50.0), [10.0, 400.0])
    assert np.allclose(c, [0.0, 0.8], atol=1e-4)


def test_grid_bilinear_at_a_cell_corner_across_the_wrap():
    # 2 x 2 cells over 800 x 800, centres at 200 and 600. P = (700, 0): u = 1.25 (columns 1 and 0 across
    # the wrap, fx = 0.25), r = -0.5 (rows 1 and 0 across the wrap, fy = 0.5).
    # C = 0.125 G00 + 0.375 G01 + 0.125 G10 + 0.375 G11 = (0.125 - 0.375, 0.75 - 1.5).
    grid = [[[1.0, 0.0], [0.0, 2.0]], [[-3.0, 0.0], [0.0, -4.0]]]
    c = drift(FlowConfig("grid", grid=grid), [700.0, 0.0])
    assert np.allclose(c, [-0.25, -0.75], atol=1e-4)


def test_time_variation_scales_the_current():
    # t = 1, T = 4: 1 + a sin(pi / 2) = 1 + 0.5; at t = 2 the sine is 0.
    flow = FlowConfig("uniform", velocity=(1.0, -2.0), amplitude=0.5, period=4.0)
    assert np.allclose(drift(flow, [300.0, 300.0], world_step=1), [1.5, -3.0], atol=1e-4)
    assert np.allclose(drift(flow, [300.0, 300.0], world_step=2), [1.0, -2.0], atol=1e-4)


def test_per_world_flows_given_as_dicts_become_flow_configs():
    cfg = dataclasses.replace(BASE, flow=({"kind": "uniform", "velocity": (1.0, 0.0)}, {"kind": "none"}))
    assert all(isinstance(f, FlowConfig) for f in cfg.flow)
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu")
    env.reset()
    env.step(None)
    env.set_params(flow=[{"kind": "none"}, {"kind": "uniform", "velocity": (0.0, 1.0)}])
    env.step(None)
    with pytest.raises(ValueError, match=r"flow\[0\]\.nope"):
        dataclasses.replace(BASE, flow=({"nope": 1.0}, {"kind": "none"}))


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"prey_max_speed": Choice(())}, r"prey_max_speed=\(\).*non-empty tuple"),
        ({"prey_max_speed": Uniform(2.0, 1.0)}, r"prey_max_speed=\(2.0, 1.0\).*low <= high"),
        ({"prey_max_speed": LogUniform(-1.0, 2.0)}, r"prey_max_speed=\(-1.0, 2.0\).*0 < low"),
        ({"prey_max_speed": Uniform(2.0, 3.0), "rng": 5}, r"rng=5 must be a numpy.random.Generator"),
    ],
)
def test_set_params_refuses_bad_samplers_and_rng_and_stays_usable(fields, message):
    env = BatchedAquarium(BASE, num_worlds=3, device="cpu")
    env.reset()
    before = env.config
    with pytest.raises(ValueError, match=message):
        env.set_params(**fields)
    assert env.config == before
    env.step(None)


def test_world_state_scales_velocities_by_each_worlds_max_speed():
    from aquarium_warp.world_state import STATE_FIELDS, WorldState

    speeds = (3.0, 4.0)
    cfg = dataclasses.replace(BASE, prey=dataclasses.replace(BASE.prey, max_speed=speeds))
    env = BatchedAquarium(cfg, num_worlds=2, device="cpu")
    env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):  # random actions: every velocity component moves off 0
        env.step(
            {
                k: torch.randint(0, cfg.action_count, a.shape, generator=gen, dtype=torch.int32)
                for k, a in env.actions.items()
            }
        )
    t, Pc, C = env.state.torch, env.prey_capacity, cfg.capacity
    assert bool((t.velocity[:, [0, Pc]].abs() > 0.01).all())  # prey slot 0 and predator slot Pc
    state = WorldState(env)()
    fields = len(STATE_FIELDS)

    def velocity(w: int, state_slot: int) -> list:  # (vx, vy) of a slot in the state's order
        return state[w, state_slot * fields + 3 : state_slot * fields + 5].tolist()

    for w, speed in enumerate(speeds):  # prey slot 0 follows the predators' slots in the state
        assert velocity(w, C - Pc) == pytest.approx((t.velocity[w, 0] / speed).tolist(), abs=1e-6)
    # The same WorldState follows `set_params` (training makes it once, and may replay it in a graph).
    world_state = WorldState(env)
    env.set_params(prey_max_speed=(6.0, 8.0), predator_max_speed=(10.0, 12.0))
    assert env.max_speeds.tolist() == [[10.0, 6.0], [12.0, 8.0]]
    state = world_state()
    for w, (prey_speed, predator_speed) in enumerate(((6.0, 10.0), (8.0, 12.0))):
        assert velocity(w, C - Pc) == pytest.approx((t.velocity[w, 0] / prey_speed).tolist(), abs=1e-6)
        assert velocity(w, 0) == pytest.approx((t.velocity[w, Pc] / predator_speed).tolist(), abs=1e-6)


def test_every_world_field_reaches_the_kernels_by_one_list():
    """`params.world_rows` copies each per-world field that `WorldValues` stores as configured, and
    derives the others (the replication-age window, the flow's columns): a new field in
    `per_world.PER_WORLD_FIELDS` needs a column of its own, or it would never reach the kernels."""
    from aquarium_warp.params import WorldValues, world_rows
    from aquarium_warp.per_world import PER_WORLD_FIELDS

    columns = np.zeros(1, dtype=WorldValues.numpy_dtype()).dtype.names
    derived = {"prey_replication_age": "replication_age_min", "flow": "flow_kind", "confusion_angle": "confusion_cos"}
    assert all(name in columns or derived.get(name) in columns for name in PER_WORLD_FIELDS)
    cfg = AquariumConfig(prey_count=(3, 5), capture_confusion=(0.0, 16.0), confusion_radius=(50.0, 80.0))
    rows = world_rows(cfg, 2, [0, 0])
    assert list(rows["prey_count"]) == [3, 5]
    assert list(rows["capture_confusion"]) == [0.0, 16.0] and list(rows["confusion_radius"]) == [50.0, 80.0]


def test_the_capture_rule_is_a_world_option_like_the_others():
    """`capture_rule`, `confusion_angle` and `handling_steps` go where `capture_confusion` goes: `train
    --set env.capture_rule=confusion`, a tuple per world, `AquariumConfig.stack` of conditions and
    `set_params` between steps (each world's value reaching the kernels' `WorldValues`); a bad value is
    one line naming the field and the world. `--randomize` takes numbers only, so not the rule."""
    from aquarium_warp.training.config import env_config, make_config, parse_assignment
    from aquarium_warp.training.randomize import parse_spec

    sets = [parse_assignment(a) for a in ("env.capture_rule=confusion", "env.handling_steps=3")]
    cfg = env_config(make_config("default", *sets))
    assert (cfg.capture_rule, cfg.handling_steps, cfg.confusion_angle) == ("confusion", 3, 15.0)
    stacked = AquariumConfig.stack([AquariumConfig(), cfg], 2)
    assert stacked.capture_rule == ("dilution", "dilution", "confusion", "confusion")
    assert stacked.handling_steps == (10, 10, 3, 3)
    env = BatchedAquarium(stacked, num_worlds=4, device="cpu")
    values = env.world_values.numpy()
    assert values["capture_rule"].tolist() == [0, 0, 1, 1] and values["handling_steps"].tolist() == [10, 10, 3, 3]
    env.set_params(world=[0, 3], capture_rule=["confusion", "dilution"], confusion_angle=90.0)
    values = env.world_values.numpy()
    assert values["capture_rule"].tolist() == [1, 0, 1, 0]
    cos15 = pytest.approx(math.cos(math.radians(15.0)))
    assert values["confusion_cos"].tolist() == [0.0, cos15, cos15, 0.0]  # 90 degrees: exactly 0, as the FOV's
    with pytest.raises(ValueError, match=r"^world 1: capture_rule='olson' is out of range: must be one of"):
        env.set_params(world=1, capture_rule="olson")
    with pytest.raises(ValueError, match="unknown field"):
        parse_spec("capture_rule=dilution,confusion")
