"""The Warp kernels (aquarium_warp.BatchedAquarium; CPU, or AQUARIUM_TEST_DEVICE) against the float64 numpy
reference of tests/reference_model.py.

Every test sets several worlds at once, each to its own random state (positions on a 0.5 grid, so that
squared distances at the start of a step are exact in float32 and ties are ties in both), with injected
edge cases: exact overlaps, agents across the seams, zero velocities, exact distance ties, agents exactly at
contact distance and at view distance, displacements of exactly half the world. The kernel's float32 inputs
are fed to the reference as float64. Random draws (respawn positions, replication ages of respawned and
newborn prey) belong to the kernels: the reference reads them from the kernel's post-step state, and the
capture draws of density dilution and the attack draws of predator confusion from the kernels' own draw
functions (`capture_draws`, `attack_draws`, before the step).

Tolerances: 1e-5 for positions (as fractions of width/height, torus-aware), velocities, accelerations,
headings and observation values; angle values (own heading, bearing) are compared on the circle, because
-atan2 jumps from 180 to -180 degrees at "exactly west", where float32 and float64 may fall on either side.
A heading is V'/|V'|, so its float32 error grows as 1/|V'|: its tolerance does too, and it is not compared at
all where |V'| < 1e-4 (the direction of a rounding residue). Observations after a step are checked against the
reference's observe() of the kernel's own post-step state (same inputs, no float32 drift), after the state
itself was checked against the reference's step. Rollouts re-sync the reference to the kernel's state each step.

Known disagreements have one strict test each (test_quarter_turn_actions_are_exact,
test_fov_boundary_is_inclusive_at_exactly_90_degrees); the random states avoid their triggers where they are
artificial (A = 0 with V exactly equal to an axis-aligned D).
"""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
import pytest

torch = pytest.importorskip("torch")
aquarium_warp = pytest.importorskip("aquarium_warp")
import reference_model as ref  # noqa: E402
import warp as wp  # noqa: E402

from aquarium_warp import AquariumConfig, BatchedAquarium  # noqa: E402
from aquarium_warp.config import FlowConfig  # noqa: E402
from aquarium_warp.kernels.capture import attack_draw, capture_draw  # noqa: E402
from aquarium_warp.kernels.common import WorldParams  # noqa: E402
from aquarium_warp.kernels.state import WorldCounters  # noqa: E402

TOL = 1e-5
NUM_WORLDS = 4
MAX_REPORTED = 25


# --------------------------------------------------------------------------------------------------
# Configurations
# --------------------------------------------------------------------------------------------------
def make_config(prey=None, predator=None, **world) -> AquariumConfig:
    base = AquariumConfig()
    return AquariumConfig(
        prey=dataclasses.replace(base.prey, **(prey or {})),
        predator=dataclasses.replace(base.predator, **(predator or {})),
        **world,
    )


CONFIGS = {
    # docs/model.md defaults in a small, crowded world (predator view 200 > half diagonal 198.5)
    "defaults_dense": make_config(width=300.0, height=260.0, prey_count=14, predator_count=2),
    # FOV off, infinite view distances, more observed slots of other agents
    "fov_off_inf_view": make_config(
        width=300.0,
        height=220.0,
        prey_count=12,
        predator_count=3,
        fov_enabled=False,
        prey=dict(view_distance=math.inf, predator_slots=2, prey_slots=2),
        predator=dict(view_distance=math.inf, predator_slots=2, prey_slots=3),
    ),
    # "-1..1" range, several predators, unusual slot counts, a FOV wider than 180 and a full 360 one
    "signed_slots_wide_fov": make_config(
        width=260.0,
        height=250.0,
        prey_count=10,
        predator_count=4,
        observation_range="-1..1",
        prey=dict(view_distance=80.0, fov_angle=200.0, predator_slots=3, prey_slots=1),
        predator=dict(view_distance=150.0, fov_angle=360.0, predator_slots=0, prey_slots=3),
    ),
    # permanent removal of captured prey, short starvation limit, smaller share radius, narrow FOV
    "respawn_off_starvation": make_config(
        width=220.0,
        height=180.0,
        prey_count=12,
        predator_count=3,
        respawn_captured_prey=False,
        catch_share_radius=70.0,
        predator_starvation_steps=6,
        prey=dict(fov_angle=60.0),
    ),
    # reproduction with a cap that binds; replication ages 3..5
    "reproduction": make_config(
        width=240.0,
        height=200.0,
        prey_count=6,
        predator_count=2,
        prey_reproduction=True,
        max_prey=12,
        prey_replication_age=4,
        predator_starvation_steps=40,
    ),
}
# Flow fields (docs/model.md "Flow fields"), and per-world values: every world of the batch has its own
# (compared world by world with the reference on that world's values).
FLOW_GRID = [[[1.5, -0.5], [0.0, 2.0], [-1.0, 0.5]], [[0.25, 1.0], [-2.0, -1.5], [1.0, 0.0]]]  # [2, 3, 2]
CONFIGS["vortex_time_varying"] = make_config(
    width=300.0,
    height=260.0,
    prey_count=14,
    predator_count=2,
    flow=FlowConfig("vortex", centre=(10.0, 250.0), strength=3.0, core_radius=40.0, amplitude=0.5, period=7.0),
)
CONFIGS["per_world_flow_and_values"] = make_config(
    width=260.0,
    height=240.0,
    prey_count=(12, 5, 9, 12),
    predator_count=(2, 3, 1, 3),
    prey_reward=(1.0, 0.5, 2.0, 1.0),
    catch_share_radius=(100.0, 40.0, 0.0, 150.0),
    predator_starvation_steps=(3000, 5, 8, 3000),
    prey=dict(
        max_speed=(4.0, 2.0, 6.0, 3.0),
        radius=(20.0, 10.0, 25.0, 15.0),
        fov_angle=(120.0, 360.0, 90.0, 200.0),
        view_distance=(100.0, math.inf, 60.0, 140.0),
        bounce_strength=(1.0, 0.0, 2.0, 0.5),
        mass=(3.0, 1.0, 8.0, 3.0),
    ),
    predator=dict(
        max_speed=(5.0, 7.0, 3.0, 5.0),
        view_distance=(200.0, 90.0, math.inf, 120.0),
        max_acceleration=(0.6, 1.5, 0.3, 0.6),
        fov_angle=(150.0, 60.0, 360.0, 180.0),
    ),
    flow=(
        FlowConfig(),
        FlowConfig("uniform", velocity=(2.5, -1.0)),
        FlowConfig("grid", grid=FLOW_GRID, amplitude=1.0, period=5.0),
        FlowConfig("vortex", centre=(130.0, 0.0), strength=-4.0, core_radius=60.0),
    ),
)
# These worlds are one cell each by default (SINGLE_CELL_CAPACITY); the same worlds cut into cells
# exercise the ring search and the capture searches across cell borders.
CONFIGS["defaults_dense_cells"] = dataclasses.replace(CONFIGS["defaults_dense"], grid_cell_size=40.0)
CONFIGS["respawn_off_starvation_cells"] = dataclasses.replace(CONFIGS["respawn_off_starvation"], grid_cell_size=45.0)
CONFIGS["reproduction_cells"] = dataclasses.replace(CONFIGS["reproduction"], grid_cell_size=50.0)
CONFIGS["per_world_flow_and_values_cells"] = dataclasses.replace(
    CONFIGS["per_world_flow_and_values"], grid_cell_size=30.0
)
# The observed current (two values after the own 5-tuple), in both ranges; world 1's uniform current
# (2.5 px/step) is faster than its prey (2 px/step), so the prey's value there is clipped.
CONFIGS["vortex_observed"] = dataclasses.replace(CONFIGS["vortex_time_varying"], observe_flow=True)
CONFIGS["per_world_flow_observed_signed"] = dataclasses.replace(
    CONFIGS["per_world_flow_and_values"], observe_flow=True, observation_range="-1..1"
)
# Capture confusion (docs/model.md step 5), per world: none (every contact captures), confusion
# alone, a lower base chance with confusion, and a predator that never captures; in worlds of one cell
# and of cells (the confusion search across cell borders).
CONFIGS["capture_confusion_per_world"] = make_config(
    width=240.0,
    height=220.0,
    prey_count=14,
    predator_count=3,
    capture_probability=(1.0, 1.0, 0.7, 0.0),
    capture_confusion=(0.0, 1.5, 4.0, 2.0),
    confusion_radius=(100.0, 60.0, 35.5, 100.0),
    # a contact that does not capture costs the prey this much (world 3's predator never captures)
    prey_contact_penalty=(0.0, 5.0, 0.0, 7.5),
)
# Types slower than 1 px/step in some worlds: fresh agents (respawned prey here) start at min(1, s), per world.
CONFIGS["slow_fresh_agents"] = make_config(
    width=300.0,
    height=260.0,
    prey_count=14,
    predator_count=2,
    prey=dict(max_speed=(0.5, 4.0, 0.25, 1.0)),
    predator=dict(max_speed=(0.75, 5.0, 3.0, 0.5)),
)
CONFIGS["capture_confusion_per_world_cells"] = dataclasses.replace(
    CONFIGS["capture_confusion_per_world"], grid_cell_size=30.0
)
# Predator confusion (docs/model.md step 5, capture rule "confusion"), per world: Olson's strength c = 1
# in a narrow window, a lower base chance with no handling time, every prey in view (360 degrees,
# unlimited view, the whole window) and a density-dilution world in the same batch; in worlds of one
# cell and of cells smaller than the predators' views (the visibility search across many cells).
CONFIGS["predator_confusion_per_world"] = make_config(
    width=240.0,
    height=220.0,
    prey_count=14,
    predator_count=3,
    capture_rule=("confusion", "confusion", "confusion", "dilution"),
    capture_probability=(1.0, 0.8, 1.0, 0.7),
    capture_confusion=(1.0, 2.0, 4.0, 4.0),
    confusion_angle=(15.0, 45.0, 180.0, 15.0),
    handling_steps=(3, 0, 2, 3),
    prey_contact_penalty=(2.0, 0.0, 3.0, 0.5),  # a contact under handling or a failed attack costs the prey
    predator=dict(view_distance=(200.0, 120.0, math.inf, 200.0), fov_angle=(150.0, 90.0, 360.0, 150.0)),
)
CONFIGS["predator_confusion_per_world_cells"] = dataclasses.replace(
    CONFIGS["predator_confusion_per_world"], grid_cell_size=30.0
)


def world_config(cfg, w: int):
    """The config the reference runs world ``w`` on: the world's own values with the batch's slot
    counts (a scalar config is its own)."""
    if not cfg.per_world_fields:
        return cfg
    own = cfg.world(w)
    return types.SimpleNamespace(
        **{f.name: getattr(own, f.name) for f in dataclasses.fields(own)},
        prey_capacity=cfg.prey_capacity,
        capacity=cfg.capacity,
    )


# Worlds of one cell step in one fused launch by default (`step_kernel="auto"`); their step tests run
# the staged launches too, so the reference checks both paths.
STEP_CASES = [(name, "auto") for name in CONFIGS] + [
    (name, "stages") for name in CONFIGS if not name.endswith("_cells")
]
_ENVS: dict = {}


def get_env(name: str, device: str, step_kernel: str = "auto") -> BatchedAquarium:
    if (name, step_kernel) not in _ENVS:
        _ENVS[name, step_kernel] = BatchedAquarium(
            CONFIGS[name], num_worlds=NUM_WORLDS, device=device, seed=0, step_kernel=step_kernel
        )
    return _ENVS[name, step_kernel]


# --------------------------------------------------------------------------------------------------
# Random world states with edge cases
# --------------------------------------------------------------------------------------------------
def _f32(x):
    return np.asarray(x, np.float64).astype(np.float32)


def _grid_wrap(cfg, p):
    return np.array([p[0] % cfg.width, p[1] % cfg.height], np.float64)


def _random_unit(rng):
    a = rng.uniform(0, 2 * math.pi)
    return np.array([math.cos(a), math.sin(a)])


def random_world(rng, cfg, world_step_range=(0, 40)) -> dict:
    """One world's state as float32 / bool / int32 numpy arrays, shaped [C, ...]."""
    C, Pc = cfg.capacity, cfg.prey_capacity
    W, H = cfg.width, cfg.height
    pos = np.stack([rng.integers(0, int(2 * W), C) / 2.0, rng.integers(0, int(2 * H), C) / 2.0], axis=1)
    alive = rng.random(C) < 0.85
    if cfg.prey_reproduction:
        alive[: cfg.prey_count] = rng.random(cfg.prey_count) < 0.9
        alive[cfg.prey_count : Pc] = rng.random(Pc - cfg.prey_count) < 0.6
    alive[rng.integers(0, Pc)] = True
    alive[Pc + rng.integers(0, C - Pc)] = True

    def same_type_live(slot):
        rng_slots = range(Pc) if slot < Pc else range(Pc, C)
        return [j for j in rng_slots if alive[j] and j != slot]

    def radius(slot):
        return ref.type_cfg(cfg, slot).radius

    live = np.flatnonzero(alive)
    # exact overlaps (same type and across types)
    for _ in range(2):
        a, b = rng.choice(live, 2, replace=False)
        pos[b] = pos[a]
    # agents on / across the seams
    for _ in range(3):
        a = rng.choice(live)
        pos[a, rng.integers(0, 2)] = rng.choice([0.0, 0.5, W - 0.5 if rng.random() < 0.5 else H - 0.5])
    pos[:, 0] %= W
    pos[:, 1] %= H
    # exactly at contact distance (= r_i + r_j, not a contact) and just inside (a contact), often across a seam
    for inside in (False, True):
        a = rng.choice(live)
        others = same_type_live(a)
        if others:
            b = rng.choice(others)
            r = radius(a) + radius(b)
            d = np.array([0.6 * r, 0.8 * r]) * rng.choice([-1.0, 1.0], 2)
            if rng.random() < 0.5:
                d = d[::-1]
            if inside:
                d = d - np.sign(d) * 0.5
            if rng.random() < 0.5:
                pos[a] = [rng.choice([0.0, W - 0.5]), pos[a, 1]]
            pos[b] = _grid_wrap(cfg, pos[a] + d)
    # distance ties around an agent: (3,4)*k, (-4,3)*k, (0,-5)*k
    a = rng.choice(live)
    k = rng.choice([2.0, 4.0, 6.0, 10.0])
    for off in ((3.0, 4.0), (-4.0, 3.0), (0.0, -5.0)):
        b = rng.choice(live)
        if b != a:
            pos[b] = _grid_wrap(cfg, pos[a] + k * np.array(off))
    # exactly half the world apart on one axis
    if (W / 2) % 0.5 == 0:
        a, b = rng.choice(live, 2, replace=False)
        pos[b] = _grid_wrap(cfg, pos[a] + np.array([W / 2, 0.0]))
    # exactly at view distance of an observer (inclusive)
    a = rng.choice(live)
    v = ref.type_cfg(cfg, a).view_distance
    if math.isfinite(v) and 2 * v == int(2 * v):
        b = rng.choice(live)
        if b != a:
            pos[b] = _grid_wrap(cfg, pos[a] + np.array([0.6 * v, -0.8 * v]))

    vel = np.zeros((C, 2))
    acc = np.zeros((C, 2))
    heading = np.zeros((C, 2))
    for i in range(C):
        t = ref.type_cfg(cfg, i)
        u = rng.random()
        if u < 0.15:
            vel[i] = 0.0
        elif u < 0.3:
            vel[i] = t.max_speed * np.array([(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)][rng.integers(0, 4)])
        else:
            vel[i] = _random_unit(rng) * t.max_speed * rng.uniform(0.0, 1.0)
        u = rng.random()
        axis_full_speed = np.count_nonzero(vel[i]) == 1 and np.linalg.norm(vel[i]) == t.max_speed
        if u < 0.15 and not axis_full_speed:  # A = 0 with V = D exactly: see test_quarter_turn_actions_are_exact
            acc[i] = 0.0
        else:
            acc[i] = _random_unit(rng) * t.max_acceleration * (1.0 if u < 0.8 else rng.uniform(0.0, 1.5))
        sp = np.linalg.norm(vel[i])
        heading[i] = vel[i] / sp if sp > 0 and rng.random() < 0.8 else _random_unit(rng)
    # some pairs moving identically (they stay overlapped after the move)
    a, b = rng.choice(live, 2, replace=False)
    if (a < Pc) == (b < Pc):
        pos[b], vel[b], acc[b], heading[b] = pos[a], vel[a], acc[a], heading[a]
    heading[~alive] = (-1.0, 0.0)

    if cfg.prey_reproduction:
        lo = math.ceil(0.75 * cfg.prey_replication_age)
        hi = math.floor(1.25 * cfg.prey_replication_age)
        rep = rng.integers(lo, hi + 1, C)
        age = rep - rng.integers(-1, 3, C)
        age = np.maximum(age, 0)
    else:
        rep = rng.integers(150, 251, C)
        age = rng.integers(0, 300, C)
    limit = cfg.predator_starvation_steps
    starvation = np.where(rng.random(C) < 0.3, limit, rng.integers(0, limit + 1, C))
    starvation[:Pc] = 0
    rep[Pc:] = 0
    age[Pc:] = 0
    # Handling times (drawn last, so that the other configs' states stay as they were).
    handling = np.zeros(C, np.int64)
    if ref.capture_rule(cfg) == "confusion":
        H = int(cfg.handling_steps)
        handling[Pc:] = np.where(rng.random(C - Pc) < 0.4, rng.integers(0, H + 1, C - Pc), 0)
    for arr in (vel, acc, age, rep, starvation, handling):
        arr[~alive] = 0
    return {
        "position": _f32(pos),
        "velocity": _f32(vel),
        "acceleration": _f32(acc),
        "heading": _f32(heading),
        "alive": alive.astype(bool),
        "age": age.astype(np.int32),
        "replication_age": rep.astype(np.int32),
        "starvation": starvation.astype(np.int32),
        "handling": handling.astype(np.int32),
        "world_step": int(rng.integers(*world_step_range)),
    }


def stack_worlds(worlds: list) -> dict:
    out = {name: np.stack([w[name] for w in worlds]) for name in ref.FIELDS}
    out["world_step"] = np.array([w["world_step"] for w in worlds], np.int32)
    return out


def set_worlds(env, worlds: list) -> None:
    env.set_state(world=None, **stack_worlds(worlds))


def state_views(env):
    return env.state.torch if hasattr(env.state, "torch") else env.state


def read_worlds(env) -> list:
    """The kernel's state per world as numpy arrays (float32 / bool / int32)."""
    t = state_views(env)
    fields = {name: getattr(t, name).detach().cpu().numpy().copy() for name in ref.FIELDS}
    steps = t.world_step.detach().cpu().numpy().copy()
    out = []
    for w in range(env.num_worlds):
        d = {name: fields[name][w] for name in ref.FIELDS}
        d["world_step"] = int(steps[w])
        out.append(d)
    return out


def random_actions(rng, cfg, n_worlds) -> np.ndarray:
    return rng.integers(0, cfg.action_count, (n_worlds, cfg.capacity))


@wp.kernel
def read_capture_draws(world: WorldParams, counters: WorldCounters, draws: wp.array2d(dtype=float)):
    w, i = wp.tid()
    draws[w, i] = capture_draw(world, counters, w, i)


@wp.kernel
def read_attack_draws(world: WorldParams, counters: WorldCounters, draws: wp.array2d(dtype=float)):
    w, i = wp.tid()
    draws[w, i] = attack_draw(world, counters, w, i)


def kernel_draws(env, kernel, slots: int) -> np.ndarray:
    """``[W, slots]``: the draws of ``kernel`` for each slot in the env's next step, by the kernels' own
    draw function (read before the step: they are keyed by its step counter)."""
    out = []
    for shard in env.shards:
        draws = wp.zeros((shard.num_worlds, slots), dtype=float, device=env.device)
        wp.launch(kernel, dim=draws.shape, inputs=[shard.world, shard.state.worlds, draws], device=env.device)
        out.append(draws.numpy())
    return np.concatenate(out)


def capture_draws(env) -> np.ndarray:
    """``[W, prey_capacity]``: the draws that decide each prey's contact (density dilution)."""
    return kernel_draws(env, read_capture_draws, env.prey_capacity)


def attack_draws(env) -> np.ndarray:
    """``[W, capacity]``: the draws that decide each predator slot's attack (predator confusion)."""
    return kernel_draws(env, read_attack_draws, env.capacity)


def kernel_step(env, actions: np.ndarray):
    Pc = env.config.prey_capacity
    a = torch.as_tensor(actions, dtype=torch.int64).to(getattr(env, "torch_device", "cpu"))
    return env.step({"prey": a[:, :Pc].contiguous(), "predator": a[:, Pc:].contiguous()})


# --------------------------------------------------------------------------------------------------
# Comparison helpers (collect every mismatch, then fail with all of them)
# --------------------------------------------------------------------------------------------------
def slot_name(cfg, slot: int) -> str:
    Pc = cfg.prey_capacity
    return f"slot {slot} (prey #{slot})" if slot < Pc else f"slot {slot} (predator #{slot - Pc})"


def fmt(x) -> str:
    return np.array2string(np.asarray(x), precision=7, floatmode="maxprec", separator=", ")


def fail_if(errors: list, context: str) -> None:
    if errors:
        shown = "\n  ".join(errors[:MAX_REPORTED])
        more = f"\n  ... and {len(errors) - MAX_REPORTED} more" if len(errors) > MAX_REPORTED else ""
        pytest.fail(
            f"{context}: {len(errors)} mismatch(es) between kernel and reference:\n  {shown}{more}", pytrace=False
        )


def describe_world(cfg, start: dict) -> str:
    lines = []
    for i in range(cfg.capacity):
        if start["alive"][i]:
            lines.append(
                f"{slot_name(cfg, i)}: p={fmt(start['position'][i])} v={fmt(start['velocity'][i])} "
                f"a={fmt(start['acceleration'][i])} h={fmt(start['heading'][i])}"
            )
    return "; ".join(lines)


def ill_conditioned_heading(reference: dict, i: int, kernel: dict | None = None) -> bool:
    """V' so close to zero (in either implementation, but not exactly zero in both) that its direction is
    rounding noise. The systematic case of this (a quarter-turn action cancelling a velocity exactly) has its
    own strict test, test_fresh_prey_sent_right_stops_and_keeps_its_heading."""
    r = float(np.linalg.norm(reference["velocity"][i]))
    k = r if kernel is None else float(np.linalg.norm(np.asarray(kernel["velocity"][i], np.float64)))
    return max(r, k) < 1e-4 and not (r == 0.0 and k == 0.0)


def compare_state(cfg, where: str, kernel: dict, reference: dict, errors: list) -> None:
    for i in range(cfg.capacity):
        if bool(kernel["alive"][i]) != bool(reference["alive"][i]):
            errors.append(
                f"{where} {slot_name(cfg, i)} alive: kernel={kernel['alive'][i]} reference={reference['alive'][i]}"
            )
            continue
        if not reference["alive"][i]:
            continue
        k = kernel["position"][i].astype(np.float64)
        r = reference["position"][i]
        frac = (k - r) / np.array([cfg.width, cfg.height])
        frac -= np.round(frac)
        if np.any(np.abs(frac) > TOL) or not (0 <= k[0] < cfg.width and 0 <= k[1] < cfg.height):
            errors.append(f"{where} {slot_name(cfg, i)} position: kernel={fmt(k)} reference={fmt(r)}")
        for name in ("velocity", "acceleration", "heading"):
            tol = TOL
            if name == "heading":
                if ill_conditioned_heading(reference, i, kernel):
                    continue
                # the heading is V' / |V'|: float32 errors of V' (~1e-6) grow by 1 / |V'|
                tol = TOL + 2e-6 / float(np.linalg.norm(reference["velocity"][i]) or 1.0)
            k = kernel[name][i].astype(np.float64)
            r = reference[name][i]
            if np.any(np.abs(k - r) > tol):
                errors.append(f"{where} {slot_name(cfg, i)} {name}: kernel={fmt(k)} reference={fmt(r)}")
        names = ("age", "replication_age") if i < cfg.prey_capacity else ("starvation", "handling")
        for name in names:
            if int(kernel[name][i]) != int(reference[name][i]):
                errors.append(
                    f"{where} {slot_name(cfg, i)} {name}: kernel={kernel[name][i]} reference={reference[name][i]}"
                )


def angle_columns(cfg, type_config) -> set:
    """Columns compared on the circle: the world layout's own heading and bearings. The ego layout has no
    angles (headings and bearings are unit-vector components), so every column is compared plainly."""
    if ref.observation_frame(cfg) == "ego":
        return set()
    k = type_config.predator_slots + type_config.prey_slots
    return {3} | {ref.own_size(cfg) + ref.TUPLE_SIZE * s + 4 for s in range(k)}


def compare_observations(cfg, where: str, k_obs: dict, k_mask: dict, r_obs: dict, r_mask: dict, r_slots: dict, errors):
    period = 2.0 if cfg.observation_range == "-1..1" else 1.0
    Pc = cfg.prey_capacity
    for key, t, first in (("prey", cfg.prey, 0), ("predator", cfg.predator, Pc)):
        ko = np.asarray(k_obs[key], np.float64)
        km = np.asarray(k_mask[key], bool)
        if ko.shape != r_obs[key].shape or km.shape != r_mask[key].shape:
            errors.append(
                f"{where} {key} observation shape: kernel={ko.shape}/{km.shape} "
                f"reference={r_obs[key].shape}/{r_mask[key].shape}"
            )
            continue
        angles = sorted(angle_columns(cfg, t))
        own = ref.own_size(cfg)
        for row in range(ko.shape[0]):
            slot = first + row
            diff = np.abs(ko[row] - r_obs[key][row])
            diff[angles] = np.minimum(diff[angles], np.abs(period - diff[angles]))
            if not np.array_equal(km[row], r_mask[key][row]):
                errors.append(
                    f"{where} observer {slot_name(cfg, slot)} mask: kernel={km[row].astype(int).tolist()} "
                    f"reference={r_mask[key][row].astype(int).tolist()} "
                    f"(reference sees slots {r_slots[key][row].tolist()})"
                )
            bad = np.flatnonzero(diff > TOL)
            if bad.size:
                parts = []
                for c in bad[:6]:
                    if c < own:
                        label = f"own[{c}]"
                    else:
                        s, e = divmod(c - own, ref.TUPLE_SIZE)
                        label = f"obs-slot {s} (agent {r_slots[key][row][s]})[{e}]"
                    parts.append(f"{label} kernel={ko[row][c]:.7g} reference={r_obs[key][row][c]:.7g}")
                errors.append(
                    f"{where} observer {slot_name(cfg, slot)} values: "
                    + "; ".join(parts)
                    + f" (reference sees slots {r_slots[key][row].tolist()})"
                )


def compare_flags(cfg, where, name, kernel: dict, reference: np.ndarray, errors, tol=None):
    k = np.concatenate([np.asarray(kernel["prey"]), np.asarray(kernel["predator"])])
    for i in range(cfg.capacity):
        if tol is None:
            ok = bool(k[i]) == bool(reference[i])
        else:
            ok = abs(float(k[i]) - float(reference[i])) <= tol * max(1.0, abs(float(reference[i])))
        if not ok:
            errors.append(f"{where} {slot_name(cfg, i)} {name}: kernel={k[i]} reference={reference[i]}")


def check_step(
    name: str, cfg, env, starts: list, actions: np.ndarray, errors: list, step_label: str = "", infos=None
) -> list:
    """Step the kernel env (already holding ``starts``) and compare every world with the reference
    (whose per-world info dicts are appended to ``infos``, if given). Returns the kernel's post-step
    worlds."""
    draws = capture_draws(env)
    attack = attack_draws(env)
    obs, rewards, terminated, truncated, info = kernel_step(env, actions)
    k_obs = {k: v.detach().cpu().numpy().copy() for k, v in obs.items()}
    k_mask = {k: v.detach().cpu().numpy().copy() for k, v in env.observation_mask.items()}
    k_rew = {k: v.detach().cpu().numpy().copy() for k, v in rewards.items()}
    k_term = {k: v.detach().cpu().numpy().copy() for k, v in terminated.items()}
    k_trunc = {k: v.detach().cpu().numpy().copy() for k, v in truncated.items()}
    k_caps = info["captures"].detach().cpu().numpy().copy()
    after = read_worlds(env)
    batch_cfg = cfg
    for w in range(env.num_worlds):
        cfg = world_config(batch_cfg, w)
        where = f"[{name}{step_label} world {w}]"
        start = starts[w]
        r_new, r_rew, r_term, r_trunc, r_cap, r_info = ref.step(
            cfg,
            start,
            actions[w],
            start["world_step"],
            respawn_position=after[w]["position"],
            respawn_replication_age=after[w]["replication_age"],
            newborn_replication_age=after[w]["replication_age"],
            respawn_heading=after[w]["heading"],  # read only with spawn_heading "random" (the kernel's draw)
            newborn_heading=after[w]["heading"],
            capture_draw=draws[w],
            attack_draw=attack[w],
        )
        if infos is not None:
            infos.append((w, start, r_info))
        n_before = len(errors)
        pick = lambda d, w=w: {k: v[w] for k, v in d.items()}  # noqa: E731
        compare_flags(cfg, where, "reward", pick(k_rew), r_rew, errors, tol=1e-6)
        compare_flags(cfg, where, "terminated", pick(k_term), r_term, errors)
        compare_flags(cfg, where, "truncated", pick(k_trunc), r_trunc, errors)
        if int(k_caps[w]) != r_info["captures"]:
            errors.append(
                f"{where} captures: kernel={int(k_caps[w])} reference={r_info['captures']} {r_info['capturers']}"
            )
        if r_info["episode_over"]:
            if after[w]["world_step"] != 0:
                errors.append(
                    f"{where} the episode ended but the world did not auto-reset (world_step={after[w]['world_step']})"
                )
        else:
            if after[w]["world_step"] != r_info["world_step"]:
                errors.append(f"{where} world_step: kernel={after[w]['world_step']} reference={r_info['world_step']}")
            compare_state(cfg, where, after[w], r_new, errors)
            lo = math.ceil(0.75 * cfg.prey_replication_age)
            hi = math.floor(1.25 * cfg.prey_replication_age)
            for slot in r_info["respawned"] + [child for _, child in r_info["births"]]:
                if not lo <= int(after[w]["replication_age"][slot]) <= hi:
                    errors.append(
                        f"{where} {slot_name(cfg, slot)} new replication_age "
                        f"{after[w]['replication_age'][slot]} not in [{lo}, {hi}]"
                    )
            r_obs, r_mask, r_slots = ref.observe(cfg, after[w], with_slots=True, world_step=after[w]["world_step"])
            compare_observations(cfg, where, pick(k_obs), pick(k_mask), r_obs, r_mask, r_slots, errors)
            for key, first in (("prey", 0), ("predator", cfg.prey_capacity)):
                for row in range(r_mask[key].shape[0]):
                    if ill_conditioned_heading(r_new, first + row, after[w]):
                        continue
                    if not np.array_equal(r_mask[key][row], r_info["observation_mask"][key][row]):
                        errors.append(
                            f"{where} observer {slot_name(cfg, first + row)}: the mask from the kernel's state "
                            f"{r_mask[key][row].astype(int).tolist()} differs from the reference's own step "
                            f"{r_info['observation_mask'][key][row].astype(int).tolist()} (a near-threshold case?)"
                        )
        if len(errors) > n_before:
            errors.append(
                f"{where} start of step (world_step {start['world_step']}, actions {actions[w].tolist()}, "
                f"alive {start['alive'].astype(int).tolist()}): {describe_world(cfg, start)}"
            )
    return after


# --------------------------------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------------------------------
def check_observations_after_set_state(name: str, cfg, env, rng, repeats: int = 3) -> None:
    """`repeats` times: random states set into every world, stored as given, observed as the reference
    observes them."""
    errors = []
    for rep in range(repeats):
        worlds = [random_world(rng, world_config(cfg, w)) for w in range(env.num_worlds)]
        set_worlds(env, worlds)
        after = read_worlds(env)
        for w in range(env.num_worlds):
            where = f"[{name} set_state #{rep} world {w}]"
            for field in ref.FIELDS:
                if not np.array_equal(after[w][field][worlds[w]["alive"]], worlds[w][field][worlds[w]["alive"]]):
                    errors.append(f"{where} set_state did not store {field}")
            r_obs, r_mask, r_slots = ref.observe(
                world_config(cfg, w), worlds[w], with_slots=True, world_step=after[w]["world_step"]
            )
            k_obs = {k: v[w].detach().cpu().numpy() for k, v in env.observations.items()}
            k_mask = {k: v[w].detach().cpu().numpy() for k, v in env.observation_mask.items()}
            n_before = len(errors)
            compare_observations(cfg, where, k_obs, k_mask, r_obs, r_mask, r_slots, errors)
            if len(errors) > n_before:
                errors.append(
                    f"{where} state: alive {worlds[w]['alive'].astype(int).tolist()} {describe_world(cfg, worlds[w])}"
                )
    fail_if(errors, name)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_observations_after_set_state(name, device):
    check_observations_after_set_state(
        name, CONFIGS[name], get_env(name, device), np.random.default_rng(1000 + list(CONFIGS).index(name))
    )


@pytest.mark.parametrize("name, step_kernel", STEP_CASES)
def test_single_step_from_random_states(name, step_kernel, device):
    cfg, env = CONFIGS[name], get_env(name, device, step_kernel)
    rng = np.random.default_rng(2000 + list(CONFIGS).index(name))
    errors = []
    for rep in range(3):
        worlds = [random_world(rng, world_config(cfg, w)) for w in range(env.num_worlds)]
        set_worlds(env, worlds)
        check_step(name, cfg, env, worlds, random_actions(rng, cfg, env.num_worlds), errors, f" #{rep}")
    fail_if(errors, name)


@pytest.mark.parametrize("name, step_kernel", STEP_CASES)
def test_rollout_resynced_each_step(name, step_kernel, device):
    """Several steps in a row; each step's reference input is the kernel's state (no float32 drift).
    Worlds whose episode ends auto-reset and go on from their new episode."""
    cfg, env = CONFIGS[name], get_env(name, device, step_kernel)
    rng = np.random.default_rng(3000 + list(CONFIGS).index(name))
    errors = []
    worlds = [random_world(rng, world_config(cfg, w)) for w in range(env.num_worlds)]
    set_worlds(env, worlds)
    starts = read_worlds(env)
    for k in range(6):
        actions = random_actions(rng, cfg, env.num_worlds)
        # steer half of the agents with one action per world so that they keep turning the same way
        actions[:, ::2] = rng.integers(0, cfg.action_count, (env.num_worlds, 1))
        starts = check_step(name, cfg, env, starts, actions, errors, f" step {k}")
        if errors:
            break
    fail_if(errors, name)


def confusion_events(cfg, infos: list) -> dict:
    """Counts, over the reference's steps of predator-confusion worlds, of what the rule can do: attacks
    that capture or fail, predators skipping a step while handling, attacks across the torus seam, and
    attacks whose predator had a prey within its view distance but outside its field of view."""
    events = dict.fromkeys(("captures", "failures", "handling", "across the seam", "prey outside the FOV"), 0)
    for w, start, info in infos:
        own = world_config(cfg, w)
        if ref.capture_rule(own) != "confusion":
            continue
        moved = info["moved"]
        events["handling"] += sum(1 for p in ref.predator_slots(own) if start["alive"][p] and start["handling"][p] > 0)
        for p, (target, captured) in info["attacks"].items():
            events["captures" if captured else "failures"] += 1
            raw = np.abs(moved["position"][target] - moved["position"][p])
            events["across the seam"] += int(raw[0] > own.width / 2 or raw[1] > own.height / 2)
            behind = [
                q
                for q in ref.prey_slots(own)
                if q != target
                and moved["alive"][q]
                and ref.torus_distance(own, moved["position"][p], moved["position"][q]) <= own.predator.view_distance
                and not ref.is_visible(own, moved, p, q)
            ]
            events["prey outside the FOV"] += int(bool(behind))
    return events


@pytest.mark.parametrize("name", ["predator_confusion_per_world", "predator_confusion_per_world_cells"])
def test_predator_confusion_rollout_covers_every_event(name, device):
    """Twelve steps of predator confusion against the reference (each step from the kernel's state), in
    which attacks capture and fail, predators wait out handling times, attacks reach across the seam and
    predators with a field of view below 360 degrees leave prey out of their count."""
    cfg, env = CONFIGS[name], get_env(name, device)
    rng = np.random.default_rng(5000)
    errors, infos = [], []
    starts = [random_world(rng, world_config(cfg, w)) for w in range(env.num_worlds)]
    set_worlds(env, starts)
    starts = read_worlds(env)
    for k in range(12):
        starts = check_step(
            name, cfg, env, starts, random_actions(rng, cfg, env.num_worlds), errors, f" step {k}", infos
        )
        if errors:
            break
    fail_if(errors, name)
    events = confusion_events(cfg, infos)
    assert all(n > 0 for n in events.values()), events


@pytest.mark.parametrize(
    "name, step_kernel", [("reproduction", "auto"), ("reproduction", "stages"), ("reproduction_cells", "auto")]
)
def test_rewards_and_episode_returns_bit_for_bit_with_newborns(name, step_kernel, device):
    """Rewards and episode sums have no pass of their own (the share and respawn passes and
    reproduction finish them): every slot's reward and episode sum equal a float32 computation from
    the reference's captures, sharers and births bit for bit (predators' shares summed in slot order,
    which is the lists' order in worlds of one cell; in worlds of cells, to within rounding), from
    episode sums set at random (-0.0 included). Where an episode ends, the ended returns are the sums
    over the slots, in slot order."""
    if device != "cpu":
        pytest.skip(f"bit for bit on the CPU (a GPU may contract float operations), not {device}")
    cfg, env = CONFIGS[name], get_env(name, device, step_kernel)
    rng = np.random.default_rng(4000 + list(CONFIGS).index(name))
    f32 = np.float32
    t = state_views(env)
    births = ended = 0
    errors: list = []
    for rep in range(8):
        worlds = [random_world(rng, cfg) for _ in range(env.num_worlds)]
        for w in worlds:  # most prey old enough to reproduce, so that births happen
            w["age"][: cfg.prey_capacity] = np.maximum(
                w["age"][: cfg.prey_capacity], rng.integers(0, 8, cfg.prey_capacity)
            )
        if rep % 4 == 3:  # some worlds end their episode in this step
            for w in worlds[::2]:
                w["world_step"] = cfg.max_steps - 1
        set_worlds(env, worlds)
        start_return = rng.normal(0.0, 30.0, (env.num_worlds, cfg.capacity)).astype(np.float32)
        start_return[:, ::3] = 0.0
        start_return[:, 1::5] = -0.0
        t.episode_return.copy_(torch.from_numpy(start_return))
        starts = read_worlds(env)
        actions = random_actions(rng, cfg, env.num_worlds)
        _, rewards, _, _, _ = kernel_step(env, actions)
        k_rew = np.concatenate([rewards["prey"].cpu().numpy(), rewards["predator"].cpu().numpy()], axis=1)
        k_return = t.episode_return.cpu().numpy()
        k_ended = t.episode_ended.cpu().numpy()
        k_ended_return = t.ended_return.cpu().numpy()
        after = read_worlds(env)
        for w in range(env.num_worlds):
            where = f"[{name} {step_kernel} #{rep} world {w}]"
            r_new, _, _, _, r_cap, r_info = ref.step(
                cfg,
                starts[w],
                actions[w],
                starts[w]["world_step"],
                respawn_position=after[w]["position"],
                respawn_replication_age=after[w]["replication_age"],
                newborn_replication_age=after[w]["replication_age"],
            )
            births += len(r_info["births"])
            want = np.zeros(cfg.capacity, np.float32)
            for i in range(cfg.prey_capacity):
                r = f32(-f32(cfg.prey_capture_penalty)) if r_cap[i] else f32(0.0)
                want[i] = r + f32(cfg.prey_reward) if r_new["alive"][i] else r
            for prey in sorted(r_info["sharers"]):
                sharers = r_info["sharers"][prey]
                for p in sharers:
                    want[p] = want[p] + f32(cfg.predator_reward) / f32(len(sharers))
            got = k_rew[w]
            exact = np.arange(cfg.capacity) < cfg.prey_capacity
            if not name.endswith("_cells"):
                exact[:] = True
            bad = (exact & (got.view(np.int32) != want.view(np.int32))) | (~exact & ~np.isclose(got, want, 1e-6))
            for i in np.flatnonzero(bad):
                errors.append(f"{where} {slot_name(cfg, i)} reward: kernel={got[i]!r} float32={want[i]!r}")
            sums = start_return[w] + got  # float32, one add per slot
            if k_ended[w]:
                ended += 1
                prey_sum = predator_sum = f32(0.0)
                for i in range(cfg.capacity):
                    if i < cfg.prey_capacity:
                        prey_sum = f32(prey_sum + sums[i])
                    else:
                        predator_sum = f32(predator_sum + sums[i])
                if (
                    k_ended_return[w].view(np.int32).tolist()
                    != np.array([predator_sum, prey_sum]).view(np.int32).tolist()
                ):
                    errors.append(
                        f"{where} ended_return: kernel={k_ended_return[w].tolist()} float32={[predator_sum, prey_sum]}"
                    )
                sums = np.zeros_like(sums)  # the next episode's sums start at +0.0
            for i in np.flatnonzero(k_return[w].view(np.int32) != sums.view(np.int32)):
                errors.append(
                    f"{where} {slot_name(cfg, i)} episode_return: kernel={k_return[w][i]!r} "
                    f"float32={sums[i]!r} (start {start_return[w][i]!r} + reward {got[i]!r})"
                )
    fail_if(errors, name)
    assert births > 0 and ended > 0


def _world_from_agents(cfg, prey, predators, world_step=0):
    """Hand-built world: lists of dicts with pos, vel, acc, heading, age, rep, starve, handling (None = dead
    slot)."""
    C, Pc = cfg.capacity, cfg.prey_capacity
    st = {
        "position": np.zeros((C, 2), np.float32),
        "velocity": np.zeros((C, 2), np.float32),
        "acceleration": np.zeros((C, 2), np.float32),
        "heading": np.tile(np.array([-1.0, 0.0], np.float32), (C, 1)),
        "alive": np.zeros(C, bool),
        "age": np.zeros(C, np.int32),
        "replication_age": np.zeros(C, np.int32),
        "starvation": np.zeros(C, np.int32),
        "handling": np.zeros(C, np.int32),
        "world_step": world_step,
    }
    for slot, a in [(i, a) for i, a in enumerate(prey)] + [(Pc + i, a) for i, a in enumerate(predators)]:
        if a is None:
            continue
        st["position"][slot] = a["pos"]
        st["velocity"][slot] = a.get("vel", (0.0, 0.0))
        st["acceleration"][slot] = a.get("acc", (0.0, 0.0))
        v = np.asarray(st["velocity"][slot], np.float64)
        h = a.get("heading")
        st["heading"][slot] = h if h is not None else (v / np.linalg.norm(v) if np.linalg.norm(v) > 0 else (-1.0, 0.0))
        st["alive"][slot] = True
        st["age"][slot] = a.get("age", 0)
        st["replication_age"][slot] = a.get("rep", 200 if slot < Pc else 0)
        st["starvation"][slot] = a.get("starve", 0)
        st["handling"][slot] = a.get("handling", 0)
    return st


def test_hand_built_worlds_defaults(device):
    """Deterministic scenarios (defaults, 800 x 800): shared capture, bounce across the seam, exact overlap,
    contact ties, a target across the seam in the view cone."""
    cfg = make_config(prey_count=5, predator_count=3, predator_starvation_steps=10)
    env = BatchedAquarium(cfg, num_worlds=4, device=device, seed=3)
    up_prey = dict(vel=(0.0, -4.0), acc=(0.0, -1.0))
    up_pred = dict(vel=(0.0, -5.0), acc=(0.0, -0.6))
    worlds = [
        # capture shared by two predators (one capturer, one within 100), a third too far; prey 1 and 2 bounce
        # across the x seam; prey 3 exactly overlaps prey 4 (no push)
        _world_from_agents(
            cfg,
            [
                dict(pos=(400.0, 400.0), **up_prey),
                dict(pos=(5.0, 100.0)),
                dict(pos=(785.0, 100.0)),
                dict(pos=(600.0, 600.0), vel=(1.0, 0.5)),
                dict(pos=(600.0, 600.0), vel=(0.0, 2.0)),
            ],
            [
                dict(pos=(400.0, 445.0), starve=9, **up_pred),
                dict(pos=(480.0, 405.0), starve=10, **up_pred),
                dict(pos=(400.0, 250.0), starve=3, **up_pred),
            ],
            world_step=17,
        ),
        # two capturers of one prey; predators at exactly contact distance 60 (no bounce) and a tie of prey
        # bounce partners at 30 (the lower slot wins)
        _world_from_agents(
            cfg,
            [
                dict(pos=(500.0, 400.0), **up_prey),
                dict(pos=(100.0, 100.0)),
                dict(pos=(130.0, 100.0)),
                dict(pos=(70.0, 100.0)),
                None,
            ],
            [
                dict(pos=(470.0, 411.0), **up_pred),
                dict(pos=(530.0, 411.0), **up_pred),
                dict(pos=(200.0, 700.0), heading=(1.0, 0.0)),
            ],
            world_step=3,
        ),
        # observers looking across the seams: prey 0 at the right edge heading east sees prey 1 across the seam
        # (30 deg off) but not prey 2 (75 deg off); the predator sees the prey at the top-left across the corner
        _world_from_agents(
            cfg,
            [
                dict(pos=(790.0, 400.0), vel=(2.0, 0.0)),
                dict(pos=(30.0, 380.0)),
                dict(pos=(10.0, 340.0)),
                dict(pos=(5.0, 5.0)),
                None,
            ],
            [
                dict(pos=(760.0, 770.0), vel=(1.0, 1.0)),
                None,
                dict(pos=(300.0, 300.0), vel=(0.0, 0.0), heading=(0.0, 1.0)),
            ],
        ),
        # starvation at the limit: one dies (counter 10 -> 11), one survives (9 -> 10)
        _world_from_agents(
            cfg,
            [dict(pos=(100.0, 700.0), **up_prey), None, None, None, None],
            [dict(pos=(700.0, 100.0), starve=10), dict(pos=(500.0, 100.0), starve=9), None],
        ),
    ]
    set_worlds(env, worlds)
    errors = []
    actions = np.zeros((4, cfg.capacity), np.int64)
    actions[2] = [4, 0, 0, 0, 0, 6, 0, 8]
    check_step("hand_built", cfg, env, worlds, actions, errors)
    fail_if(errors, "hand-built worlds")
    # the headline numbers of the reference (which the kernel matched), spelled out
    _, r0, *_, info0 = ref.step(
        cfg, worlds[0], actions[0], 17, respawn_position={0: (1.0, 1.0)}, respawn_replication_age={0: 200}
    )
    assert r0[0] == -999.0 and r0[cfg.prey_capacity :].tolist() == [5.0, 5.0, 0.0]
    assert info0["capturers"] == {0: [5]} and info0["sharers"] == {0: [5, 6]}
    _, r1, *_, info1 = ref.step(
        cfg, worlds[1], actions[1], 3, respawn_position={0: (1.0, 1.0)}, respawn_replication_age={0: 200}
    )
    assert info1["capturers"] == {0: [5, 6]} and r1[cfg.prey_capacity :].tolist() == [5.0, 5.0, 0.0]
    new3, _, term3, *_ = ref.step(cfg, worlds[3], actions[3], 0)
    assert term3[cfg.prey_capacity :].tolist() == [True, False, False] and new3["starvation"][6] == 10


def test_episode_end_truncation_and_auto_reset(device):
    """World 0 reaches max_steps; world 1's last predator starves; world 2 (respawn off) loses its last prey;
    world 3 goes on."""
    cfg = make_config(
        prey_count=3, predator_count=2, max_steps=50, predator_starvation_steps=5, respawn_captured_prey=False
    )
    env = BatchedAquarium(cfg, num_worlds=4, device=device, seed=7)
    worlds = [
        _world_from_agents(
            cfg,
            [dict(pos=(100.0, 100.0)), dict(pos=(300.0, 100.0)), None],
            [dict(pos=(600.0, 600.0)), dict(pos=(600.0, 300.0))],
            world_step=49,
        ),
        _world_from_agents(
            cfg,
            [dict(pos=(100.0, 100.0)), dict(pos=(300.0, 100.0)), dict(pos=(500.0, 100.0))],
            [dict(pos=(600.0, 600.0), starve=5), None],
            world_step=20,
        ),
        _world_from_agents(
            cfg,
            [None, dict(pos=(300.0, 300.0), vel=(0.0, -4.0), acc=(0.0, -1.0)), None],
            [dict(pos=(300.0, 330.0), vel=(0.0, -5.0), acc=(0.0, -0.6)), dict(pos=(700.0, 700.0))],
            world_step=30,
        ),
        _world_from_agents(
            cfg,
            [dict(pos=(100.0, 100.0)), None, None],
            [dict(pos=(600.0, 600.0), starve=4), dict(pos=(600.0, 100.0), starve=5)],
            world_step=48,
        ),
    ]
    set_worlds(env, worlds)
    errors = []
    after = check_step("episode_end", cfg, env, worlds, np.zeros((4, cfg.capacity), np.int64), errors)
    fail_if(errors, "episode end")
    assert [a["world_step"] for a in after] == [0, 0, 0, 49]
    # the reset worlds hold a fresh episode
    for w in range(3):
        assert after[w]["alive"][: cfg.prey_count].all() and after[w]["alive"][cfg.prey_capacity :].all()


def test_fresh_agents_start_at_speed_one_or_their_max_speed_if_less(device):
    """docs/model.md "Spawn headings": at an episode start a live agent moves along its heading at min(1, s)
    of its type and world, in both spawn modes (a world's prey at 0.5 px/step start at 0.5, not 1; types
    of s >= 1, as every default, at 1). Dead slots start as "Randomness" says: position and velocity zero,
    their type's paper heading whatever the spawn mode."""
    for mode in ("paper", "random"):
        cfg = make_config(
            prey_count=(3, 5),
            predator_count=(2, 1),
            spawn_heading=mode,
            prey=dict(max_speed=(0.5, 4.0)),
            predator=dict(max_speed=(5.0, 0.25)),
        )
        env = BatchedAquarium(cfg, num_worlds=2, device=device, seed=3)
        env.reset()
        for w, start in enumerate(read_worlds(env)):
            wcfg = world_config(cfg, w)
            for slot in range(cfg.capacity):
                where = f"{mode} world {w} {slot_name(cfg, slot)}"
                if start["alive"][slot]:
                    velocity, heading = ref.episode_start_velocity_and_heading(wcfg, slot, start["heading"][slot])
                    np.testing.assert_array_equal(start["velocity"][slot], velocity, err_msg=where)
                    np.testing.assert_array_equal(start["heading"][slot], heading, err_msg=where)
                else:
                    paper = ref.FRESH_PREY_HEADING if ref.is_prey(cfg, slot) else ref.FRESH_PREDATOR_HEADING
                    assert start["position"][slot].tolist() == [0.0, 0.0], where
                    assert start["velocity"][slot].tolist() == [0.0, 0.0], where
                    assert start["heading"][slot].tolist() == list(paper), where
        speeds = np.linalg.norm(env.state.torch.velocity.cpu().numpy(), axis=-1)  # a drawn heading: 1 +- 1e-7 long
        Pc = cfg.prey_capacity
        np.testing.assert_allclose(speeds[0], [0.5] * 3 + [0.0] * (Pc - 3) + [1.0, 1.0], rtol=1e-6, err_msg=mode)
        np.testing.assert_allclose(speeds[1], [1.0] * 5 + [0.25, 0.0], rtol=1e-6, err_msg=mode)


def test_quarter_turn_actions_are_exact(device):
    """Actions whose direction is up / right / down / left must give an exact desired velocity D (no sin/cos
    residue such as cos(pi/2) = -4e-8 in float32). The residue matters where a quantity cancels exactly:

    * prey 0, fresh (V = (-1, 0), A = 0, heading (-1, 0)), action "right": F = (5, 0) clamped to (0.6, 0),
      A' = (1, 0), V' = (0, 0) exactly, so the heading stays (-1, 0). With the residue V' = (0, +-eps) and the
      heading becomes (0, +-1), decided by rounding noise (possibly differently on CPU and GPU). Every fresh or
      respawned prey whose first action is "right" (1 in 16) hits this.
    * prey 1: V = (0, -1), action "down": the same, vertically.
    * prey 2 and the predator: V = D exactly (full speed along an axis), A = 0, same action: F = 0, A + F/m = 0
      exactly, A' = 0 (docs/model.md: A' stays zero). With the residue A' becomes a full-length k vector pointing
      along the residue, perpendicular to the motion."""
    cfg = make_config(prey_count=3, predator_count=1)
    env = BatchedAquarium(cfg, num_worlds=1, device=device, seed=0)
    world = _world_from_agents(
        cfg,
        [
            dict(pos=(100.0, 100.0), vel=(-1.0, 0.0)),
            dict(pos=(300.0, 300.0), vel=(0.0, -1.0)),
            dict(pos=(500.0, 100.0), vel=(4.0, 0.0)),
        ],
        [dict(pos=(600.0, 600.0), vel=(0.0, 5.0))],
    )
    set_worlds(env, [world])
    actions = np.array([[4, 8, 4, 8]])
    kernel_step(env, actions)
    after = read_worlds(env)[0]
    r_new, *_ = ref.step(cfg, world, actions[0], 0)
    errors = []
    for i in range(cfg.capacity):
        for name in ("velocity", "acceleration", "heading"):
            k, r = after[name][i].astype(np.float64), r_new[name][i]
            if np.any(np.abs(k - r) > 1e-12):
                errors.append(f"{slot_name(cfg, i)} {name}: kernel={fmt(k)} reference={fmt(r)}")
    fail_if(errors, "quarter-turn actions (exact desired velocity)")


def test_exact_capture_and_share_boundaries_after_the_move(device):
    """Post-move distances that are exact in float32 too: two predators overlapping at distance 0 with zero
    velocity stay exactly in place (no push, V' = V = 0), and a prey cruising up at full speed moves exactly
    (0, -4). Prey 0 ends 20 from predators A, B (captured by both); predators C, D end exactly 100 from it
    (catch_share_radius is strict: no share); prey 1 ends exactly 50 = r_prey + r_pred from A, B (not captured)."""
    cfg = make_config(prey_count=2, predator_count=4)
    env = BatchedAquarium(cfg, num_worlds=1, device=device, seed=0)
    P = np.array([400.0, 400.0])
    cruise = dict(vel=(0.0, -4.0), acc=(0.0, -1.0))
    world = _world_from_agents(
        cfg,
        [dict(pos=tuple(P + (0.0, 24.0)), **cruise), dict(pos=tuple(P + (30.0, -36.0)), **cruise)],
        [
            dict(pos=tuple(P), heading=(0.0, 1.0)),
            dict(pos=tuple(P), heading=(0.0, 1.0)),
            dict(pos=tuple(P + (60.0, 100.0))),
            dict(pos=tuple(P + (60.0, 100.0))),
        ],
    )
    set_worlds(env, [world])
    errors = []
    check_step("exact_boundaries", cfg, env, [world], np.zeros((1, cfg.capacity), np.int64), errors)
    fail_if(errors, "exact capture / share boundaries")
    r_new, r_rew, r_term, r_trunc, r_cap, r_info = ref.step(
        cfg,
        world,
        np.zeros(cfg.capacity, np.int64),
        0,
        respawn_position={0: (0.0, 0.0)},
        respawn_replication_age={0: 200},
    )
    assert r_info["capturers"] == {0: [2, 3]} and r_info["sharers"] == {0: [2, 3]}
    assert r_rew.tolist() == [-999.0, 1.0, 5.0, 5.0, 0.0, 0.0]


def test_fov_boundary_is_inclusive_at_exactly_90_degrees(device):
    """fov_angle 180: a target exactly perpendicular to the heading (dot product exactly 0) is on the cone's
    boundary and visible (docs/model.md: the angle limit includes its boundary). A test with cos(radians(90)) =
    6e-17 > 0 would reject it. fov_angle 360: a target exactly behind is visible."""
    cfg = make_config(prey_count=4, predator_count=2, prey=dict(fov_angle=180.0), predator=dict(fov_angle=360.0))
    env = BatchedAquarium(cfg, num_worlds=1, device=device, seed=0)
    world = _world_from_agents(
        cfg,
        [
            dict(pos=(400.0, 400.0), heading=(1.0, 0.0)),
            dict(pos=(400.0, 350.0)),
            dict(pos=(400.0, 470.0)),
            dict(pos=(399.5, 450.0)),
        ],
        [dict(pos=(600.0, 600.0), heading=(1.0, 0.0)), dict(pos=(500.0, 600.0))],
    )
    set_worlds(env, [world])
    errors = []
    r_obs, r_mask, r_slots = ref.observe(cfg, world, with_slots=True)
    assert r_slots["prey"][0].tolist() == [-1, 1, 2, -1]  # straight up and straight down; not the one behind
    assert r_slots["predator"][0].tolist() == [5, -1, -1, -1]  # exactly behind, 100 away
    k_obs = {k: v[0].detach().cpu().numpy() for k, v in env.observations.items()}
    k_mask = {k: v[0].detach().cpu().numpy() for k, v in env.observation_mask.items()}
    compare_observations(cfg, "[fov boundary]", k_obs, k_mask, r_obs, r_mask, r_slots, errors)
    fail_if(errors, "FOV boundary at exactly 90 degrees")


def test_reproduction_cap_counts_prey_after_captures(device):
    """max_prey (5) below prey_count (6), so free slots outnumber what the cap allows.
    World 0: 5 prey alive, prey 0 is captured and removed (respawn off): 4 live after captures, so parent 1 gets
    a child (in slot 5, the only slot free at the start). Its capturer is outside catch_share_radius (10) and
    still gets the whole predator_reward.
    World 1: 3 prey alive and due, slots 3-5 free: children for parents 0 and 1 (slots 3, 4), then 3 + 2 = 5
    reaches the cap and parent 2 keeps its age."""
    cfg = make_config(
        prey_count=6,
        predator_count=1,
        prey_reproduction=True,
        max_prey=5,
        prey_replication_age=4,
        respawn_captured_prey=False,
        catch_share_radius=10.0,
    )
    assert cfg.prey_capacity == 6
    env = BatchedAquarium(cfg, num_worlds=2, device=device, seed=0)
    due = dict(age=3, rep=4)
    worlds = [
        _world_from_agents(
            cfg,
            [
                dict(pos=(100.0, 100.0), age=0, rep=5),
                dict(pos=(300.0, 100.0), **due),
                dict(pos=(500.0, 100.0), age=0, rep=5),
                dict(pos=(100.0, 400.0), age=1, rep=5),
                dict(pos=(300.0, 400.0), age=2, rep=5),
                None,
            ],
            [dict(pos=(100.0, 120.0))],
        ),
        _world_from_agents(
            cfg,
            [
                dict(pos=(100.0, 100.0), **due),
                dict(pos=(300.0, 100.0), **due),
                dict(pos=(500.0, 100.0), **due),
                None,
                None,
                None,
            ],
            [dict(pos=(700.0, 700.0))],
        ),
    ]
    set_worlds(env, worlds)
    errors = []
    after = check_step("reproduction_cap", cfg, env, worlds, np.zeros((2, cfg.capacity), np.int64), errors)
    fail_if(errors, "reproduction cap")
    r0 = ref.step(
        cfg, worlds[0], np.zeros(cfg.capacity, np.int64), 0, newborn_replication_age=after[0]["replication_age"]
    )
    assert r0[5]["births"] == [(1, 5)] and r0[5]["sharers"] == {0: [6]} and r0[1][6] == 10.0
    r1 = ref.step(
        cfg, worlds[1], np.zeros(cfg.capacity, np.int64), 0, newborn_replication_age=after[1]["replication_age"]
    )
    assert r1[5]["births"] == [(0, 3), (1, 4)] and r1[0]["age"][:3].tolist() == [0, 0, 4]


# Live counts per world (docs/model.md "World and agents"): worlds of 12, 5, 1 and 9 prey and 2, 1, 3
# and 2 predators in one batch of capacity 12 + 3, respawn off (so that a world may lose every prey).
LIVE_COUNTS = make_config(
    width=220.0,
    height=200.0,
    prey_count=(12, 5, 1, 9),
    predator_count=(2, 1, 3, 2),
    respawn_captured_prey=False,
    max_steps=30,
    prey=dict(radius=24.0),
    predator=dict(radius=36.0),
)


def live_slots(batch_cfg, w: int) -> np.ndarray:
    """The batch's slots of world `w`'s own agents, in order: its prey slots, then its predator slots."""
    own = batch_cfg.world(w)
    return np.r_[np.arange(own.prey_count), batch_cfg.prey_capacity + np.arange(own.predator_count)]


def alone(world: dict, slots: np.ndarray) -> dict:
    """A batch world's state on `slots` only: the state of that world in a batch of its own counts."""
    return {**{name: world[name][slots] for name in ref.FIELDS}, "world_step": world["world_step"]}


@pytest.mark.parametrize("step_kernel", ["auto", "stages"])
def test_worlds_of_their_own_live_counts_step_as_each_world_alone(step_kernel, device):
    """Each world starts every episode with its own prey and predator counts (slots past them dead) and
    then steps as the reference steps that world alone, in a world of exactly its own slots: the dead
    slots of a larger batch take part in nothing (moves, contacts, captures, rewards, observations,
    the episode's end). The reference's input is the kernel's state each step (on the world's own
    slots), its random draws the kernel's, as in the other rollouts."""
    cfg = LIVE_COUNTS
    env = BatchedAquarium(cfg, num_worlds=4, device=device, seed=5, step_kernel=step_kernel)
    rng = np.random.default_rng(77)
    errors: list = []
    captures = resets = 0

    def check_live_counts(worlds: list, where: str, which=range(4)) -> None:
        for w in which:
            expected = np.zeros(cfg.capacity, bool)
            expected[live_slots(cfg, w)] = True
            if not np.array_equal(worlds[w]["alive"], expected):
                errors.append(f"[{where} world {w}] alive {worlds[w]['alive'].astype(int).tolist()}")

    starts = read_worlds(env)
    check_live_counts(starts, "episode start")
    for k in range(30):
        actions = random_actions(rng, cfg, env.num_worlds)
        draws = capture_draws(env)
        obs, rewards, _, _, info = kernel_step(env, actions)
        k_obs = {t: v.detach().cpu().numpy().copy() for t, v in obs.items()}
        k_mask = {t: v.detach().cpu().numpy().copy() for t, v in env.observation_mask.items()}
        k_rew = np.concatenate([rewards[t].detach().cpu().numpy() for t in ("prey", "predator")], axis=1)
        k_caps = info["captures"].detach().cpu().numpy().copy()
        after = read_worlds(env)
        for w in range(env.num_worlds):
            own, slots = cfg.world(w), live_slots(cfg, w)
            assert (own.prey_capacity, own.capacity) == (own.prey_count, len(slots))
            where = f"[step {k} world {w}]"
            r_new, r_rew, _, _, _, r_info = ref.step(
                own,
                alone(starts[w], slots),
                actions[w][slots],
                starts[w]["world_step"],
                capture_draw=draws[w][slots[: own.prey_count]],
            )
            captures += r_info["captures"]
            if int(k_caps[w]) != r_info["captures"]:
                errors.append(f"{where} captures: kernel={int(k_caps[w])} reference={r_info['captures']}")
            rest = np.ones(cfg.capacity, bool)
            rest[slots] = False
            if np.any(k_rew[w][rest] != 0.0):
                errors.append(f"{where} a slot past the world's counts has a reward: {k_rew[w].tolist()}")
            if np.any(np.abs(k_rew[w][slots] - r_rew) > 1e-6 * np.maximum(1.0, np.abs(r_rew))):
                errors.append(f"{where} rewards: kernel={k_rew[w][slots].tolist()} reference={r_rew.tolist()}")
            if r_info["episode_over"]:  # the next episode starts with the world's own counts again
                resets += 1
                check_live_counts(after, f"step {k} auto-reset", [w])
                continue
            compare_state(own, where, alone(after[w], slots), r_new, errors)
            if np.any(after[w]["alive"][rest]):
                errors.append(f"{where} a slot past the world's counts came alive")
            r_obs, r_mask, r_slots = ref.observe(
                own, alone(after[w], slots), with_slots=True, world_step=after[w]["world_step"]
            )
            rows = {"prey": slice(0, own.prey_count), "predator": slice(0, own.predator_count)}
            compare_observations(
                own,
                where,
                {t: k_obs[t][w][rows[t]] for t in rows},
                {t: k_mask[t][w][rows[t]] for t in rows},
                r_obs,
                r_mask,
                r_slots,
                errors,
            )
        starts = after
        if errors:
            break
    fail_if(errors, "live counts per world")
    assert captures > 0 and resets > 0  # the worlds captured prey, and a world lost all of its prey
