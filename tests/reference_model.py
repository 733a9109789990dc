"""Independent plain-numpy, float64 reference implementation of docs/model.md for ONE world.

This module is the test oracle for the Warp kernels. It is written for clarity, not speed: every
neighbour search is a brute-force loop over the world's slots, every quantity is float64.

Conventions (see docs/model.md and the project's decisions):

* ``cfg`` is anything with the attributes of ``aquarium_warp.AquariumConfig`` (a frozen dataclass or a
  ``types.SimpleNamespace``). Only attributes are read: width, height, prey_count, predator_count,
  action_count, max_steps, fov_enabled, respawn_captured_prey, prey_reward, prey_capture_penalty,
  predator_reward, catch_share_radius, predator_starvation_steps, prey_reproduction, max_prey,
  observation_range, prey_capacity, capacity, and per type (cfg.prey / cfg.predator): max_speed,
  max_steering_force, max_acceleration, mass, radius, view_distance, fov_angle (degrees),
  bounce_strength, predator_slots, prey_slots; optionally `flow` (an `aquarium_warp.config.FlowConfig`) and
  `observe_flow` (absent: False); the capture rule's `capture_rule` ("dilution" | "confusion", absent:
  "dilution"), `capture_probability` (absent: 1.0), `capture_confusion` (absent: 0.0), `confusion_radius`
  (dilution), `confusion_angle` and `handling_steps` (confusion); the ego-spec options `observation_frame`
  ("world" | "ego", absent: "world"), `action_frame` ("world" | "ego", absent: "world") and
  `spawn_heading` ("paper" | "random", absent: "paper"), so configs written before those options keep
  their meaning.
  A batch with per-world values is compared world by world on `world_config`s (one world's values, the
  batch's slot counts).
* Slots ``[0, prey_capacity)`` are prey, ``[prey_capacity, capacity)`` are predators.
* A world state is a dict of numpy arrays (see ``FIELDS``); dead slots are ignored everywhere.
* Type code in observations: predator 0, prey 1.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

PREDATOR_TYPE = 0.0
PREY_TYPE = 1.0
OWN_SIZE = 5
EGO_OWN_SIZE = 2  # [type, speed]
TUPLE_SIZE = 6  # both layouts: world [type, x, y, distance, bearing, speed], ego [present, distance, f, r, vf, vr]

VECTOR_FIELDS = ("position", "velocity", "acceleration", "heading")
INT_FIELDS = ("age", "replication_age", "starvation", "handling")
FIELDS = VECTOR_FIELDS + ("alive",) + INT_FIELDS

FRESH_PREY_HEADING = (-1.0, 0.0)
NEWBORN_HEADING = (-1.0, 0.0)
FRESH_PREDATOR_HEADING = (0.0, -1.0)


# --------------------------------------------------------------------------------------------------
# Slots, types, state containers
# --------------------------------------------------------------------------------------------------
def prey_capacity(cfg) -> int:
    return int(cfg.prey_capacity)


def capacity(cfg) -> int:
    return int(cfg.capacity)


def is_prey(cfg, slot: int) -> bool:
    return 0 <= slot < prey_capacity(cfg)


def type_cfg(cfg, slot: int):
    return cfg.prey if is_prey(cfg, slot) else cfg.predator


def type_code(cfg, slot: int) -> float:
    return PREY_TYPE if is_prey(cfg, slot) else PREDATOR_TYPE


def prey_slots(cfg) -> range:
    return range(prey_capacity(cfg))


def predator_slots(cfg) -> range:
    return range(prey_capacity(cfg), capacity(cfg))


def same_type_slots(cfg, slot: int) -> range:
    return prey_slots(cfg) if is_prey(cfg, slot) else predator_slots(cfg)


def observation_frame(cfg) -> str:
    return str(getattr(cfg, "observation_frame", "world"))


def action_frame(cfg) -> str:
    return str(getattr(cfg, "action_frame", "world"))


def spawn_heading(cfg) -> str:
    return str(getattr(cfg, "spawn_heading", "paper"))


def own_size(cfg) -> int:
    """Length of the own block. World frame: the 5-tuple, then the two observed current values with
    `observe_flow`. Ego frame: [type, speed], then [hx, hy] only with world actions (a policy needs the
    heading to pick world directions), then the two current values with `observe_flow`."""
    flow = 2 if getattr(cfg, "observe_flow", False) else 0
    if observation_frame(cfg) == "ego":
        return EGO_OWN_SIZE + (2 if action_frame(cfg) == "world" else 0) + flow
    return OWN_SIZE + flow


def observation_length(cfg, type_config) -> int:
    return own_size(cfg) + TUPLE_SIZE * (int(type_config.predator_slots) + int(type_config.prey_slots))


def empty_state(cfg) -> dict:
    """All slots dead, every field zero."""
    c = capacity(cfg)
    return {
        "position": np.zeros((c, 2), np.float64),
        "velocity": np.zeros((c, 2), np.float64),
        "acceleration": np.zeros((c, 2), np.float64),
        "heading": np.zeros((c, 2), np.float64),
        "alive": np.zeros(c, bool),
        "age": np.zeros(c, np.int64),
        "replication_age": np.zeros(c, np.int64),
        "starvation": np.zeros(c, np.int64),
        "handling": np.zeros(c, np.int64),
    }


def as_state(cfg, state: Mapping[str, Any]) -> dict:
    """Copy of ``state`` as float64 / bool / int64 numpy arrays (accepts numpy or CPU torch tensors).

    Missing fields are filled with zeros (``alive``: False)."""
    out = empty_state(cfg)
    c = capacity(cfg)
    for name in FIELDS:
        if name not in state or state[name] is None:
            continue
        value = state[name]
        if hasattr(value, "detach"):
            value = value.detach().cpu().numpy()
        value = np.array(value, copy=True)
        expected = (c, 2) if name in VECTOR_FIELDS else (c,)
        if value.shape != expected:
            raise ValueError(f"state[{name!r}] has shape {value.shape}, expected {expected}")
        out[name] = value.astype(out[name].dtype)
    return out


def copy_state(state: Mapping[str, np.ndarray]) -> dict:
    return {k: np.array(v, copy=True) for k, v in state.items()}


# --------------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------------
def torus_axis_delta(d: float, length: float) -> float:
    """Minimum-image displacement on one axis: if d > L/2: d -= L; elif d < -L/2: d += L."""
    if d > length / 2.0:
        d -= length
    elif d < -length / 2.0:
        d += length
    return d


def torus_delta(cfg, a, b) -> np.ndarray:
    """Torus-shortest displacement from point ``a`` to point ``b``."""
    dx = float(b[0]) - float(a[0])
    dy = float(b[1]) - float(a[1])
    return np.array([torus_axis_delta(dx, float(cfg.width)), torus_axis_delta(dy, float(cfg.height))], np.float64)


def norm(v) -> float:
    x, y = float(v[0]), float(v[1])
    return math.sqrt(x * x + y * y)


def torus_distance(cfg, a, b) -> float:
    return norm(torus_delta(cfg, a, b))


def wrap_axis(x: float, length: float) -> float:
    """True modulo into [0, L)."""
    r = math.fmod(x, length)
    if r < 0.0:
        r += length
    if r >= length:  # r + L rounded up to L for a tiny negative r
        r -= length
    return r


def wrap(cfg, p) -> np.ndarray:
    return np.array([wrap_axis(float(p[0]), float(cfg.width)), wrap_axis(float(p[1]), float(cfg.height))])


def clamp_length(v, max_length: float) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = norm(v)
    if n > max_length:
        return v * (max_length / n)
    return v.copy()


# (sin, cos) of the quarter turns 0, 90, 180, 270 degrees, exactly
_QUARTER_TURNS = ((0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0))


def desired_velocity(action: int, action_count: int, max_speed: float) -> np.ndarray:
    """theta = 2 pi a / n (clockwise on screen from 'up'); D = s (sin theta, -cos theta).

    Quarter turns (up, right, down, left) are exact: float sin/cos leave residues like cos(pi/2) = 6e-17, and
    a fresh prey (V = (-1, 0), A = 0) sent right would get V' = (0, +-1e-16) and a heading decided by
    rounding noise instead of V' = 0 (heading kept)."""
    a, n = int(action), int(action_count)
    if (4 * a) % n == 0:
        sin_t, cos_t = _QUARTER_TURNS[((4 * a) // n) % 4]
    else:
        theta = 2.0 * math.pi * a / n
        sin_t, cos_t = math.sin(theta), math.cos(theta)
    return np.array([max_speed * sin_t, -max_speed * cos_t], np.float64)


def ego_components(u, heading) -> np.ndarray:
    """(u.f, u.r): the components of the world vector ``u`` along the forward axis f = h and the right axis
    r = (-hy, hx) (h turned 90 degrees clockwise on screen, y down) of the heading h."""
    ux, uy = float(u[0]), float(u[1])
    hx, hy = float(heading[0]), float(heading[1])
    return np.array([hx * ux + hy * uy, -hy * ux + hx * uy], np.float64)


def ego_desired_velocity(action: int, action_count: int, max_speed: float, heading) -> np.ndarray:
    """action_frame "ego": action a points at theta = 2 pi a / n clockwise from the heading h (not from
    "up"): D = s (cos theta f + sin theta r) with f = h, r = (-hy, hx). cos and sin come from the world
    table's (sin theta, -cos theta), whose quarter turns are exact, so a = 0 gives exactly s h. The
    heading is used as stored (a unit vector up to the state's rounding)."""
    sin_t, minus_cos_t = desired_velocity(action, action_count, 1.0)
    cos_t = -minus_cos_t
    hx, hy = float(heading[0]), float(heading[1])
    forward = np.array([hx, hy], np.float64)
    right = np.array([-hy, hx], np.float64)
    return float(max_speed) * (cos_t * forward + sin_t * right)


def angle_value(dx: float, dy: float) -> float:
    """The reference's angle convention -atan2(dy, dx) in degrees, mapped from [-180, 180] to [0, 1]."""
    return (-math.degrees(math.atan2(dy, dx)) + 180.0) / 360.0


def distance_normaliser(cfg, observer_type) -> float:
    half_diagonal = math.sqrt((cfg.width / 2.0) ** 2 + (cfg.height / 2.0) ** 2)
    return min(float(observer_type.view_distance), half_diagonal)


# --------------------------------------------------------------------------------------------------
# Motion (docs/model.md steps 1-4; everyone reads the start-of-step state)
# --------------------------------------------------------------------------------------------------
def contact_partner(cfg, state: Mapping[str, np.ndarray], i: int):
    """Nearest live same-type agent j != i with torus distance < r_i + r_j (ties: lower slot); None if none."""
    best = None
    best_d = math.inf
    r_i = float(type_cfg(cfg, i).radius)
    for j in same_type_slots(cfg, i):
        if j == i or not state["alive"][j]:
            continue
        d = torus_distance(cfg, state["position"][i], state["position"][j])
        if d < r_i + float(type_cfg(cfg, j).radius) and d < best_d:  # strict '<': lower slot wins ties
            best, best_d = j, d
    return best


def steering_acceleration(cfg, state, i: int, action: int) -> np.ndarray:
    """Steps 1-2: F = clamp(D - V, f); A' = normalize(A + F/m) * k (zero if A + F/m is exactly zero).
    ``state`` is the start-of-step state (its heading turns D with action_frame "ego")."""
    t = type_cfg(cfg, i)
    if action_frame(cfg) == "ego":  # relative to the heading at the start of the step
        desired = ego_desired_velocity(action, cfg.action_count, float(t.max_speed), state["heading"][i])
    else:
        desired = desired_velocity(action, cfg.action_count, float(t.max_speed))
    force = clamp_length(desired - state["velocity"][i], float(t.max_steering_force))
    raw = state["acceleration"][i] + force / float(t.mass)
    n = norm(raw)
    if n == 0.0:
        return np.zeros(2)
    return raw / n * float(t.max_acceleration)


def current(cfg, p, t: int) -> np.ndarray:
    """docs/model.md "Flow fields": the current C(P, t) of ``cfg.flow`` (absent or kind "none": zero) at
    position ``p`` at step ``t``, float64."""
    flow = getattr(cfg, "flow", None)
    kind = "none" if flow is None else flow.kind
    p = np.asarray(p, np.float64)
    c = np.zeros(2)
    if kind == "uniform":
        c = np.asarray(flow.velocity, np.float64)
    elif kind == "vortex":
        d = torus_delta(cfg, np.asarray(flow.centre, np.float64), p)
        rho = norm(d)
        if rho > 0.0:
            g = rho / flow.core_radius if rho < flow.core_radius else flow.core_radius / rho
            c = flow.strength * g * np.array([-d[1], d[0]]) / rho
    elif kind == "grid":
        grid = np.asarray(flow.grid, np.float64)
        rows, cols = grid.shape[:2]
        # cell (i, j) has its centre at ((j + 1/2) W / cols, (i + 1/2) H / rows)
        u = p[0] / cfg.width * cols - 0.5
        r = p[1] / cfg.height * rows - 0.5
        j0, i0 = math.floor(u), math.floor(r)
        fx, fy = u - j0, r - i0
        c = (
            (1 - fx) * (1 - fy) * grid[i0 % rows, j0 % cols]
            + fx * (1 - fy) * grid[i0 % rows, (j0 + 1) % cols]
            + (1 - fx) * fy * grid[(i0 + 1) % rows, j0 % cols]
            + fx * fy * grid[(i0 + 1) % rows, (j0 + 1) % cols]
        )
    if kind != "none" and flow.amplitude != 0.0:
        c = c * (1.0 + flow.amplitude * math.sin(2.0 * math.pi * t / flow.period))
    return c


def motion(cfg, state: Mapping[str, np.ndarray], actions, world_step: int = 0) -> dict:
    """Steps 1-4 for every live agent (the current at step ``world_step`` added to the displacement).
    Returns a new state; alive/age/... are unchanged."""
    start = as_state(cfg, state)
    actions = np.asarray(actions).astype(np.int64)
    new = copy_state(start)
    for i in range(capacity(cfg)):
        if not start["alive"][i]:
            continue
        t = type_cfg(cfg, i)
        acc = steering_acceleration(cfg, start, i, int(actions[i]))
        v = start["velocity"][i]
        partner = contact_partner(cfg, start, i)
        if partner is None:
            v_new = v + acc
        else:
            away = torus_delta(cfg, start["position"][partner], start["position"][i])  # from j to i
            d = norm(away)
            v_new = v.copy() if d == 0.0 else v + float(t.bounce_strength) * (away / d)
        v_new = clamp_length(v_new, float(t.max_speed))
        speed = norm(v_new)
        new["acceleration"][i] = acc
        new["velocity"][i] = v_new
        new["position"][i] = wrap(cfg, start["position"][i] + v_new + current(cfg, start["position"][i], world_step))
        new["heading"][i] = v_new / speed if speed > 0.0 else start["heading"][i]
    return new


# --------------------------------------------------------------------------------------------------
# Observations
# --------------------------------------------------------------------------------------------------
def is_visible(cfg, state: Mapping[str, np.ndarray], i: int, j: int) -> bool:
    """Can observer i see agent j? Distance <= v_i (inclusive) and, with the FOV on and d > 0,
    the angle between heading_i and the displacement i->j is <= fov_i / 2 (inclusive)."""
    if i == j or not state["alive"][i] or not state["alive"][j]:
        return False
    t = type_cfg(cfg, i)
    delta = torus_delta(cfg, state["position"][i], state["position"][j])
    d = norm(delta)
    if not d <= float(t.view_distance):
        return False
    if not cfg.fov_enabled or d == 0.0:
        return True
    h = state["heading"][i]
    cross = float(h[0]) * float(delta[1]) - float(h[1]) * float(delta[0])
    dot = float(h[0]) * float(delta[0]) + float(h[1]) * float(delta[1])
    angle = math.degrees(math.atan2(abs(cross), dot))  # in [0, 180]
    return angle <= float(t.fov_angle) / 2.0


def visible_sorted(cfg, state, i: int, candidates) -> list:
    """Visible agents among ``candidates`` as (distance, slot), sorted by (distance, slot)."""
    out = []
    for j in candidates:
        if is_visible(cfg, state, i, j):
            out.append((torus_distance(cfg, state["position"][i], state["position"][j]), j))
    out.sort()
    return out


def observe_agent(cfg, state: Mapping[str, np.ndarray], i: int, world_step: int = 0):
    """Observation vector and slot mask of one observer (zeros / False when dead); the observed current
    (with `observe_flow`) is the one at step ``world_step``.

    Returns (vector, mask, slots) where ``slots`` lists the observed slot index per observation slot
    (-1 for unused), handy for error messages."""
    t = type_cfg(cfg, i)
    k_pred, k_prey = int(t.predator_slots), int(t.prey_slots)
    vec = np.zeros(observation_length(cfg, t), np.float64)
    mask = np.zeros(k_pred + k_prey, bool)
    slots = np.full(k_pred + k_prey, -1, np.int64)
    if not state["alive"][i]:
        return vec, mask, slots
    signed = str(cfg.observation_range) == "-1..1"
    if not signed and str(cfg.observation_range) != "0..1":
        raise ValueError(f"unknown observation_range {cfg.observation_range!r}")
    if observation_frame(cfg) == "ego":
        _observe_agent_ego(cfg, state, i, world_step, signed, vec, mask, slots)
        return vec, mask, slots
    if observation_frame(cfg) != "world":
        raise ValueError(f"unknown observation_frame {observation_frame(cfg)!r}")

    def emit(values):
        values = np.asarray(values, np.float64)
        return 2.0 * values - 1.0 if signed else values

    w, h = float(cfg.width), float(cfg.height)
    p = state["position"][i]
    hd = state["heading"][i]
    own_speed = norm(state["velocity"][i]) / float(t.max_speed)
    vec[:OWN_SIZE] = emit([type_code(cfg, i), p[0] / w, p[1] / h, angle_value(float(hd[0]), float(hd[1])), own_speed])
    own = own_size(cfg)
    if own > OWN_SIZE:
        c = np.clip(current(cfg, p, world_step) / float(t.max_speed), -1.0, 1.0)
        vec[OWN_SIZE:own] = emit((c + 1.0) / 2.0)
    dist_norm = distance_normaliser(cfg, t)
    blocks = ((predator_slots(cfg), k_pred, 0), (prey_slots(cfg), k_prey, k_pred))
    for candidates, k, first_slot in blocks:
        for n, (d, j) in enumerate(visible_sorted(cfg, state, i, candidates)[:k]):
            tj = type_cfg(cfg, j)
            pj = state["position"][j]
            delta = torus_delta(cfg, p, pj)
            bearing = 0.5 if d == 0.0 else angle_value(float(delta[0]), float(delta[1]))
            tup = [
                type_code(cfg, j),
                pj[0] / w,
                pj[1] / h,
                d / dist_norm,
                bearing,
                norm(state["velocity"][j]) / float(tj.max_speed),
            ]
            s = first_slot + n
            vec[own + TUPLE_SIZE * s : own + TUPLE_SIZE * (s + 1)] = emit(tup)
            mask[s] = True
            slots[s] = j
    return vec, mask, slots


def _observe_agent_ego(cfg, state, i: int, world_step: int, signed: bool, vec, mask, slots) -> None:
    """observation_frame "ego" (ego-spec): fills ``vec`` / ``mask`` / ``slots`` of live observer i.

    Every value is "unsigned" (natural range [0, 1]) or "signed" (natural range [-1, 1]); the range
    "0..1" maps signed values by (x + 1) / 2, "-1..1" maps unsigned values by 2x - 1; unused slots stay 0."""

    def unsigned(x: float) -> float:
        return 2.0 * x - 1.0 if signed else x

    def signed_value(x: float) -> float:
        return x if signed else (x + 1.0) / 2.0

    t = type_cfg(cfg, i)
    s_i = float(t.max_speed)
    p = state["position"][i]
    h = state["heading"][i]  # the heading after the move, as for visibility
    own = [unsigned(type_code(cfg, i)), unsigned(min(norm(state["velocity"][i]) / s_i, 1.0))]
    if action_frame(cfg) == "world":
        own += [signed_value(float(h[0])), signed_value(float(h[1]))]
    if getattr(cfg, "observe_flow", False):
        # rotate first, then clip each ego component (the current's world components are not clipped)
        c = ego_components(current(cfg, p, world_step) / s_i, h)
        own += [signed_value(min(max(float(x), -1.0), 1.0)) for x in c]
    n_own = own_size(cfg)
    assert len(own) == n_own
    vec[:n_own] = own

    dist_norm = distance_normaliser(cfg, t)
    k_pred, k_prey = int(t.predator_slots), int(t.prey_slots)
    blocks = ((predator_slots(cfg), k_pred, 0), (prey_slots(cfg), k_prey, k_pred))
    for candidates, k, first_slot in blocks:
        for n, (d, j) in enumerate(visible_sorted(cfg, state, i, candidates)[:k]):
            s_j = float(type_cfg(cfg, j).max_speed)
            delta = torus_delta(cfg, p, state["position"][j])
            bearing = np.zeros(2) if d == 0.0 else ego_components(delta, h) / d
            relvel = ego_components(state["velocity"][j] - state["velocity"][i], h) / (s_i + s_j)
            tup = [
                unsigned(1.0),  # present
                unsigned(min(d / dist_norm, 1.0)),
                signed_value(float(bearing[0])),
                signed_value(float(bearing[1])),
                signed_value(min(max(float(relvel[0]), -1.0), 1.0)),
                signed_value(min(max(float(relvel[1]), -1.0), 1.0)),
            ]
            slot = first_slot + n
            vec[n_own + TUPLE_SIZE * slot : n_own + TUPLE_SIZE * (slot + 1)] = tup
            mask[slot] = True
            slots[slot] = j


def observe(cfg, state: Mapping[str, np.ndarray], with_slots: bool = False, world_step: int = 0):
    """Observations of every slot of one world.

    Returns (obs, mask) with obs = {"prey": (Pc, Lprey), "predator": (P, Lpred)} and
    mask = {"prey": (Pc, slots_prey), "predator": (P, slots_pred)}; with ``with_slots`` also a third dict of
    the observed slot indices (-1 where unused). ``world_step``: the world's step counter (observed currents)."""
    state = as_state(cfg, state)
    obs, mask, who = {}, {}, {}
    for key, slots, t in (("prey", prey_slots(cfg), cfg.prey), ("predator", predator_slots(cfg), cfg.predator)):
        k = int(t.predator_slots) + int(t.prey_slots)
        obs[key] = np.zeros((len(slots), observation_length(cfg, t)), np.float64)
        mask[key] = np.zeros((len(slots), k), bool)
        who[key] = np.full((len(slots), k), -1, np.int64)
        for row, i in enumerate(slots):
            obs[key][row], mask[key][row], who[key][row] = observe_agent(cfg, state, i, world_step)
    if with_slots:
        return obs, mask, who
    return obs, mask


# --------------------------------------------------------------------------------------------------
# Capture, starvation, ageing, reproduction, rewards, episode end (steps 5-10)
# --------------------------------------------------------------------------------------------------
def find_contacts(cfg, state: Mapping[str, np.ndarray]) -> dict:
    """{prey slot: [overlapping predator slots]} for every live prey overlapped by a live predator."""
    out = {}
    for i in prey_slots(cfg):
        if not state["alive"][i]:
            continue
        capturers = [
            p
            for p in predator_slots(cfg)
            if state["alive"][p]
            and torus_distance(cfg, state["position"][i], state["position"][p])
            < float(cfg.prey.radius) + float(cfg.predator.radius)
        ]
        if capturers:
            out[i] = capturers
    return out


def capture_rule(cfg) -> str:
    return str(getattr(cfg, "capture_rule", "dilution"))


def capture_chance(cfg, state: Mapping[str, np.ndarray], prey: int) -> float:
    """Density dilution: the chance that a contact captures ``prey``, capture_probability / (1 +
    capture_confusion * k), k the other live prey strictly within confusion_radius of it."""
    p0 = float(getattr(cfg, "capture_probability", 1.0))
    c = float(getattr(cfg, "capture_confusion", 0.0))
    if c == 0.0:
        return p0
    k = sum(
        1
        for j in prey_slots(cfg)
        if j != prey
        and state["alive"][j]
        and torus_distance(cfg, state["position"][prey], state["position"][j]) < float(cfg.confusion_radius)
    )
    return p0 / (1.0 + c * k)


def attack_target(cfg, state: Mapping[str, np.ndarray], predator: int):
    """Predator confusion: the prey that ``predator`` attacks, the nearest live prey strictly within
    r_prey + r_predator of it (ties: lower slot); None if none."""
    reach = float(cfg.prey.radius) + float(cfg.predator.radius)
    near = [
        (torus_distance(cfg, state["position"][predator], state["position"][q]), q)
        for q in prey_slots(cfg)
        if state["alive"][q]
    ]
    near = [(d, q) for d, q in near if d < reach]
    return min(near)[1] if near else None


def bearing_angle(u, v) -> float:
    """The angle in degrees, in [0, 180], between the directions of ``u`` and ``v``; 0 where either is zero
    (no direction: within every window)."""
    cross = float(u[0]) * float(v[1]) - float(u[1]) * float(v[0])
    dot = float(u[0]) * float(v[0]) + float(u[1]) * float(v[1])
    if norm(u) == 0.0 or norm(v) == 0.0:
        return 0.0
    return math.degrees(math.atan2(abs(cross), dot))


def prey_seen_near_target(cfg, state: Mapping[str, np.ndarray], predator: int, target: int) -> list:
    """Predator confusion's k: the other live prey that ``predator`` sees (`is_visible`, its heading after
    the move) whose bearing from it lies within confusion_angle of the target's (inclusive)."""
    to_target = torus_delta(cfg, state["position"][predator], state["position"][target])
    return [
        q
        for q in prey_slots(cfg)
        if q != target
        and is_visible(cfg, state, predator, q)
        and bearing_angle(to_target, torus_delta(cfg, state["position"][predator], state["position"][q]))
        <= float(cfg.confusion_angle)
    ]


def attack_chance(cfg, state: Mapping[str, np.ndarray], predator: int, target: int) -> float:
    """Predator confusion: the chance that ``predator``'s attack on ``target`` captures it,
    capture_probability / (1 + capture_confusion * k), k = len(prey_seen_near_target)."""
    p0 = float(getattr(cfg, "capture_probability", 1.0))
    c = float(getattr(cfg, "capture_confusion", 0.0))
    return p0 / (1.0 + c * len(prey_seen_near_target(cfg, state, predator, target)))


def attacks(cfg, state: Mapping[str, np.ndarray], moved: dict, new: dict, attack_draw) -> tuple[dict, dict]:
    """Predator confusion's attacks at the moved positions: ({prey: [predators whose attack captured it]},
    {predator: (target, captured)} of every attack). A handling predator (``state``'s counter > 0) counts
    down in ``new`` and does not attack; an attack that fails (draw u >= its chance) sets ``new``'s
    counter to handling_steps."""
    captures: dict = {}
    outcomes: dict = {}
    for p in predator_slots(cfg):
        if not moved["alive"][p]:
            continue
        if state["handling"][p] > 0:
            new["handling"][p] = state["handling"][p] - 1
            continue
        target = attack_target(cfg, moved, p)
        if target is None:
            continue
        chance = attack_chance(cfg, moved, p, target)
        captured = chance >= 1.0 or (chance > 0.0 and float(_lookup(attack_draw, p, "an attack draw")) < chance)
        outcomes[p] = (target, captured)
        if captured:
            captures.setdefault(target, []).append(p)
        else:
            new["handling"][p] = int(cfg.handling_steps)
    return captures, outcomes


def capture_sharers(cfg, state: Mapping[str, np.ndarray], prey: int, capturers) -> list:
    """Predators strictly within catch_share_radius of the prey, plus all capturers (slot order)."""
    near = {
        p
        for p in predator_slots(cfg)
        if state["alive"][p]
        and torus_distance(cfg, state["position"][prey], state["position"][p]) < float(cfg.catch_share_radius)
    }
    return sorted(near | set(capturers))


def _lookup(source, slot: int, what: str):
    if source is None:
        raise ValueError(f"the reference needs {what} for slot {slot} but none was given")
    if isinstance(source, Mapping):
        if slot not in source:
            raise ValueError(f"the reference needs {what} for slot {slot}; given only for {sorted(source)}")
        return source[slot]
    if hasattr(source, "detach"):
        source = source.detach().cpu().numpy()
    return np.asarray(source)[slot]


def fresh_speed(cfg, slot: int) -> float:
    """A fresh agent's speed: 1 (the paper's (-1, 0) and (0, -1)), or its type's max speed if that is less."""
    return min(1.0, float(type_cfg(cfg, slot).max_speed))


def episode_start_velocity_and_heading(cfg, slot: int, heading=None):
    """(velocity, heading) of a fresh agent at the start of an episode (or a respawned prey).
    "paper": prey west (-1, 0), predators north (0, -1). "random": the kernel's drawn heading
    (cos phi, sin phi), passed in as ``heading``. Both types move along the heading at `fresh_speed`."""
    if spawn_heading(cfg) == "random":
        if heading is None:
            raise ValueError(f"spawn_heading 'random' needs the drawn heading of slot {slot}")
        h = np.asarray(heading, np.float64).copy()
    elif spawn_heading(cfg) != "paper":
        raise ValueError(f"unknown spawn_heading {spawn_heading(cfg)!r}")
    else:
        h = np.array(FRESH_PREY_HEADING if is_prey(cfg, slot) else FRESH_PREDATOR_HEADING)
    return h * fresh_speed(cfg, slot), h


def newborn_heading_of(cfg, heading=None) -> np.ndarray:
    """A newborn's heading (its velocity is zero either way): "paper" west, "random" the drawn one."""
    if spawn_heading(cfg) == "random":
        if heading is None:
            raise ValueError("spawn_heading 'random' needs the drawn heading of a newborn")
        return np.asarray(heading, np.float64).copy()
    return np.array(NEWBORN_HEADING)


def fresh_prey(cfg, state: dict, slot: int, position, replication_age: int, heading=None) -> None:
    """A respawned prey; with spawn_heading "random", ``heading`` is the drawn heading."""
    velocity, fresh_heading = episode_start_velocity_and_heading(cfg, slot, heading)
    state["position"][slot] = np.asarray(position, np.float64)
    state["velocity"][slot] = velocity
    state["acceleration"][slot] = 0.0
    state["heading"][slot] = fresh_heading
    state["alive"][slot] = True
    state["age"][slot] = 0
    state["replication_age"][slot] = int(replication_age)
    state["starvation"][slot] = 0
    state["handling"][slot] = 0


def step(
    cfg,
    state: Mapping[str, np.ndarray],
    actions,
    world_step: int,
    respawn_position=None,
    respawn_replication_age=None,
    newborn_replication_age=None,
    respawn_heading=None,
    newborn_heading=None,
    capture_draw=None,
    attack_draw=None,
):
    """One full step of one world.

    ``world_step``: steps taken this episode BEFORE this step. The random draws belong to the kernels, so they
    are inputs here: ``respawn_position`` / ``respawn_replication_age`` (for respawned prey) and
    ``newborn_replication_age`` (for children), each a mapping slot -> value or an array indexed by slot
    (e.g. the kernel's post-step position / replication_age arrays). Only the needed slots are read; a missing
    one raises ValueError. With spawn_heading "random", the drawn headings are inputs too, the same way:
    ``respawn_heading`` (respawned prey; their velocity is that heading * `fresh_speed`) and ``newborn_heading``
    (children; their velocity stays zero), e.g. the kernel's post-step heading array. "paper" reads neither.
    Under density dilution, ``capture_draw`` (prey slot -> u in [0, 1), read the same way) decides each
    contact whose capture chance p is strictly between 0 and 1: captured iff u < p; under predator
    confusion ``attack_draw`` (predator slot -> u) decides each attack the same way.

    Returns (new_state, rewards (C,), terminated (C,), truncated (C,), captured (C,), info)."""
    start = as_state(cfg, state)
    c = capacity(cfg)
    moved = motion(cfg, start, actions, world_step)
    new = copy_state(moved)

    rewards = np.zeros(c, np.float64)
    terminated = np.zeros(c, bool)
    captured = np.zeros(c, bool)

    # 5. capture (positions after the move): under density dilution a contact captures with its chance, its
    # capturers every predator in contact; under predator confusion each attack does, its capturers the
    # predators whose attack captured it
    captures, attack_outcomes = {}, {}
    if capture_rule(cfg) == "confusion":
        captures, attack_outcomes = attacks(cfg, start, moved, new, attack_draw)
    elif capture_rule(cfg) != "dilution":
        raise ValueError(f"unknown capture_rule {capture_rule(cfg)!r}")
    else:
        for prey, capturers in find_contacts(cfg, moved).items():
            chance = capture_chance(cfg, moved, prey)
            if chance >= 1.0 or (chance > 0.0 and float(_lookup(capture_draw, prey, "a capture draw")) < chance):
                captures[prey] = capturers
    # a contact that does not capture costs the prey `prey_contact_penalty` (whatever the rule)
    for prey in find_contacts(cfg, moved):
        if prey not in captures:
            rewards[prey] -= float(getattr(cfg, "prey_contact_penalty", 0.0))
    all_capturers = set()
    sharers_of = {}
    for prey, capturers in captures.items():
        captured[prey] = True
        rewards[prey] -= float(cfg.prey_capture_penalty)
        sharers = capture_sharers(cfg, moved, prey, capturers)
        sharers_of[prey] = sharers
        for p in sharers:
            rewards[p] += float(cfg.predator_reward) / len(sharers)
        all_capturers.update(capturers)
    respawned = []
    for prey in sorted(captures):
        if cfg.respawn_captured_prey:
            pos = np.asarray(_lookup(respawn_position, prey, "a respawn position"), np.float64)
            rep = int(_lookup(respawn_replication_age, prey, "a respawn replication age"))
            heading = _lookup(respawn_heading, prey, "a respawn heading") if spawn_heading(cfg) == "random" else None
            fresh_prey(cfg, new, prey, pos, rep, heading)
            respawned.append(prey)
        else:
            new["alive"][prey] = False
            terminated[prey] = True

    # 6. starvation
    starved = []
    for p in all_capturers:
        new["starvation"][p] = 0
    for p in predator_slots(cfg):
        if not new["alive"][p]:
            continue
        new["starvation"][p] += 1
        if new["starvation"][p] > int(cfg.predator_starvation_steps):
            new["alive"][p] = False
            terminated[p] = True
            starved.append(p)

    # ageing: every live prey not captured this step
    for i in prey_slots(cfg):
        if new["alive"][i] and not captured[i]:
            new["age"][i] += 1

    # 7. reproduction
    births = []
    if cfg.prey_reproduction:
        free = [i for i in prey_slots(cfg) if not start["alive"][i]]
        live = int(sum(bool(new["alive"][i]) for i in prey_slots(cfg)))
        for parent in prey_slots(cfg):
            if not (start["alive"][parent] and new["alive"][parent]):
                continue  # newborns of this step are not parents; removed prey neither
            if new["age"][parent] < new["replication_age"][parent]:
                continue
            if live + len(births) >= int(cfg.max_prey) or not free:
                continue
            child = free.pop(0)
            rep = int(_lookup(newborn_replication_age, child, "a newborn replication age"))
            new["position"][child] = new["position"][parent]
            new["velocity"][child] = 0.0
            new["acceleration"][child] = 0.0
            drawn = _lookup(newborn_heading, child, "a newborn heading") if spawn_heading(cfg) == "random" else None
            new["heading"][child] = newborn_heading_of(cfg, drawn)
            new["alive"][child] = True
            new["age"][child] = 0
            new["replication_age"][child] = rep
            new["starvation"][child] = 0
            new["handling"][child] = 0
            new["age"][parent] = 0
            births.append((parent, child))

    # 8. survival reward for every prey alive at the end of the step
    for i in prey_slots(cfg):
        if new["alive"][i]:
            rewards[i] += float(cfg.prey_reward)

    # 9. episode end
    new_world_step = int(world_step) + 1
    live_prey = int(new["alive"][: prey_capacity(cfg)].sum())
    live_pred = int(new["alive"][prey_capacity(cfg) :].sum())
    episode_over = new_world_step >= int(cfg.max_steps) or live_prey == 0 or live_pred == 0
    truncated = new["alive"].copy() if episode_over else np.zeros(c, bool)

    # 10. observations at the end-of-step state
    obs, mask, observed = observe(cfg, new, with_slots=True, world_step=new_world_step)
    info = {
        "world_step": new_world_step,
        "episode_over": episode_over,
        "captures": len(captures),
        "capturers": {k: list(v) for k, v in captures.items()},
        "attacks": attack_outcomes,
        "sharers": sharers_of,
        "respawned": respawned,
        "births": births,
        "starved": starved,
        "moved": moved,
        "observations": obs,
        "observation_mask": mask,
        "observed_slots": observed,
    }
    return new, rewards, terminated, truncated, captured, info


# --------------------------------------------------------------------------------------------------
# Random spawn headings (docs/model.md "Randomness"): integer hashing, then the one float32 draw
# --------------------------------------------------------------------------------------------------
PURPOSE_SPAWN, PURPOSE_RESPAWN, PURPOSE_NEWBORN, PURPOSE_HEADING = 1, 2, 3, 5
_U32 = 0xFFFFFFFF


def mix32(h: int) -> int:
    """Murmur3's 32-bit finaliser."""
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & _U32
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & _U32
    return h ^ (h >> 16)


def random_stream(key: int, world: int, episode: int, step: int, slot: int, purpose: int) -> int:
    """The key of the stream of (seed key, world, episode, step, slot, purpose)."""
    h = mix32(key ^ 0x9E3779B9)
    for part in (world, episode, step, slot, purpose):
        h = mix32(h ^ (part & _U32))
    return h


def pcg(s: int) -> int:
    """Warp's `rand_pcg`: the next state of a stream, and the 32 bits a draw takes from it."""
    b = (s * 747796405 + 2891336453) & _U32
    c = (((b >> ((b >> 28) + 4)) ^ b) * 277803737) & _U32
    return (c >> 22) ^ c


def drawn_heading(rng: int) -> np.ndarray:
    """The random spawn heading of a fresh agent whose own stream is `rng`, float32 as the kernels draw it."""
    u = np.float32((pcg(mix32(rng ^ PURPOSE_HEADING)) >> 8) * 2.0**-24)  # exact: 24 bits
    phi = np.float32(np.float32(2.0 * math.pi) * u)
    return np.array([np.cos(phi), np.sin(phi)], np.float32)


# --------------------------------------------------------------------------------------------------
# Heuristic action choice (docs/model.md "Heuristic policies"; ego-spec for action_frame "ego")
# --------------------------------------------------------------------------------------------------
def ego_nearest_action(direction, heading, action_count: int) -> int:
    """The heuristics' action for the world direction ``direction`` (flee / chase) under action_frame "ego".

    The direction d is written in the ego "screen-up" convention u = (d.r, -(d.f)): forward becomes "up"
    (action 0) and right becomes "east" (action n/4), exactly the world table's convention, so the world
    rule (`aquarium_warp.heuristics.nearest_action`: smallest angle, ties to the lower action) applies to u.
    A zero direction keeps the heading: u = (0, -1), action 0."""
    from aquarium_warp.heuristics import nearest_action  # the world rule's float64 reference

    d = np.asarray(direction, np.float64)
    if d[0] == 0.0 and d[1] == 0.0:
        u = np.array([0.0, -1.0])
    else:
        forward, right = ego_components(d, heading)
        u = np.array([right, -forward])
    return int(nearest_action(u, np.array([0.0, -1.0]), int(action_count)))
