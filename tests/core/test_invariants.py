"""Invariants over long random rollouts, checked after every step of several configurations.

State: positions inside the world, speeds within each type's max speed, nothing NaN/inf, alive counts
within capacity and equal to the state's counters. Observations: inside the declared range, own values
and every filled neighbour slot consistent with the state (slot index, type, position, distance, bearing,
speed, visibility, nearest-first order), unused slots exactly zero with a false mask, dead agents' rows all
zero. Rewards: only the allowed values; each capture's predator reward adds up to `predator_reward`.
Flags: terminated only on the step an agent dies, truncated for every live agent exactly when the episode
ended; episode statistics in `info` agree with what the test accumulates itself. The envs run on the
`device` fixture's device and every check runs there too (the checker's own tensors live on the env's device)."""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, replace

import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium

TYPES = ("prey", "predator")
TYPE_CODE = {"prey": 1, "predator": 0}


def cfg_with(prey=None, predator=None, **world) -> AquariumConfig:
    base = AquariumConfig()
    return AquariumConfig(
        prey=replace(base.prey, **(prey or {})), predator=replace(base.predator, **(predator or {})), **world
    )


@dataclass
class Case:
    cfg: AquariumConfig
    num_worlds: int
    steps: int
    expect: tuple = ()  # events the rollout must exercise: "time_limit", "captures", "starved", "births", ...


CASES = {
    "default": Case(AquariumConfig(max_steps=100), 4, 400, ("time_limit",)),
    "default_dense": Case(AquariumConfig(width=300.0, height=300.0, max_steps=100), 4, 300, ("time_limit", "captures")),
    "respawn_off_starvation": Case(
        AquariumConfig(
            width=300.0,
            height=300.0,
            prey_count=12,
            predator_count=4,
            respawn_captured_prey=False,
            predator_starvation_steps=15,
            max_steps=200,
        ),
        4,
        300,
        ("captures", "starved", "extinct", "prey_terminated"),
    ),
    "reproduction": Case(
        AquariumConfig(
            width=400.0,
            height=400.0,
            prey_count=4,
            predator_count=2,
            prey_reproduction=True,
            max_prey=12,
            prey_replication_age=10,
            respawn_captured_prey=False,
            max_steps=80,
        ),
        4,
        300,
        ("time_limit", "births", "captures"),
    ),
    "fov_off_inf_view": Case(
        cfg_with(
            width=500.0,
            height=400.0,
            prey_count=10,
            predator_count=2,
            fov_enabled=False,
            max_steps=100,
            prey=dict(view_distance=math.inf),
            predator=dict(view_distance=math.inf),
        ),
        4,
        300,
        ("time_limit", "captures"),
    ),
    "signed_observations": Case(
        AquariumConfig(
            width=400.0, height=400.0, prey_count=10, predator_count=2, observation_range="-1..1", max_steps=60
        ),
        4,
        300,
        ("time_limit", "captures"),
    ),
    "400_agents": Case(
        AquariumConfig(prey_count=390, predator_count=10, max_steps=100), 1, 250, ("time_limit", "captures")
    ),
}


@pytest.fixture(scope="module", autouse=True)
def single_threaded_torch():
    """The checks are many small torch ops: on 2 cores, intra-op threads only add hand-off overhead."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# --------------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------------
def unscale(x: torch.Tensor, signed: bool) -> torch.Tensor:
    return (x + 1.0) / 2.0 if signed else x


def circle_gap(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Distance of two angle values in [0, 1] on the circle (0 and 1 are the same angle)."""
    d = (a.double() - b.double()).abs() % 1.0
    return torch.minimum(d, 1.0 - d)


def angle_value(v: torch.Tensor) -> torch.Tensor:
    """docs/model.md's angle: -atan2(y, x) in degrees mapped from [-180, 180] to [0, 1]."""
    v = v.double()
    return 0.5 - torch.atan2(v[..., 1], v[..., 0]) / (2.0 * math.pi)


def torus_displacement(cfg, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Shortest displacement from a to b, in float32 exactly as the kernels compute it."""
    d = b - a
    out = []
    for axis, length in ((0, cfg.width), (1, cfg.height)):
        x = d[..., axis]
        L = torch.tensor(length, dtype=torch.float32, device=d.device)
        x = torch.where(x > 0.5 * L, x - L, x)
        x = torch.where(x < -0.5 * L, x + L, x)
        out.append(x)
    return torch.stack(out, dim=-1)


@functools.cache
def predator_reward_values(R: float, sharers_max: int, captures: int) -> tuple[float, ...]:
    """Every sum of at most `captures` shares R / n, n in 1..sharers_max."""
    shares = [R / n for n in range(1, sharers_max + 1)]
    values = {0.0}
    for k in range(1, captures + 1):
        for combo in itertools.combinations_with_replacement(shares, k):
            values.add(sum(combo))
    return tuple(sorted(values))


class Checker:
    def __init__(self, env: BatchedAquarium):
        self.env = env
        self.cfg = cfg = env.config
        self.W, self.C, self.Pc, self.P = env.num_worlds, env.capacity, env.prey_capacity, env.predator_capacity
        self.signed = cfg.observation_range == "-1..1"
        self.lo = -1.0 if self.signed else 0.0
        self.dev = dev = env.torch_device  # every tensor the checker makes lives with the env's tensors
        self.steps = torch.zeros(self.W, dtype=torch.int64, device=dev)
        self.captures = torch.zeros(self.W, dtype=torch.int64, device=dev)
        self.returns = {t: torch.zeros(self.W, dtype=torch.float64, device=dev) for t in TYPES}
        self.events = dict.fromkeys(
            ("time_limit", "captures", "starved", "extinct", "prey_terminated", "births", "ended"), 0
        )

    # ---------------------------------------------------------------- state
    def check_state(self) -> None:
        env, cfg, t, Pc = self.env, self.cfg, self.env.state.torch, self.Pc
        for name in ("position", "velocity", "acceleration", "heading"):
            assert torch.isfinite(getattr(t, name)).all(), name
        x, y = t.position[..., 0], t.position[..., 1]
        assert ((x >= 0) & (x < cfg.width) & (y >= 0) & (y < cfg.height)).all(), "position outside the world"
        speed = torch.linalg.vector_norm(t.velocity.double(), dim=-1)
        assert (speed[:, :Pc] <= cfg.prey.max_speed * (1 + 1e-6)).all(), float(speed[:, :Pc].max())
        assert (speed[:, Pc:] <= cfg.predator.max_speed * (1 + 1e-6)).all(), float(speed[:, Pc:].max())
        alive = t.alive
        hnorm = torch.linalg.vector_norm(t.heading.double(), dim=-1)
        assert ((hnorm[alive] - 1.0).abs() < 1e-5).all(), "heading not a unit vector"
        prey_alive = alive[:, :Pc].sum(1)
        pred_alive = alive[:, Pc:].sum(1)
        assert torch.equal(prey_alive.to(torch.int32), t.prey_alive_count)
        assert torch.equal(pred_alive.to(torch.int32), t.predator_alive_count)
        assert (prey_alive <= Pc).all() and (pred_alive <= self.P).all()
        if cfg.prey_reproduction:
            assert (prey_alive <= max(cfg.max_prey, cfg.prey_count)).all()
        assert torch.equal(env.alive["prey"], alive[:, :Pc]) and torch.equal(env.alive["predator"], alive[:, Pc:])

    # ---------------------------------------------------------------- observations
    def check_observations(self, kind: str) -> None:
        env, cfg, t = self.env, self.cfg, self.env.state.torch
        W, Pc = self.W, self.Pc
        tcfg = getattr(cfg, kind)
        Kd, Ky = tcfg.predator_slots, tcfg.prey_slots
        S = Kd + Ky
        obs, mask, slot = env.observations[kind], env.observation_mask[kind], env.observed_slot[kind]
        N = obs.shape[1]
        assert obs.shape == (W, N, 5 + 6 * S) and mask.shape == (W, N, S) and slot.shape == (W, N, S)
        own_slots = torch.arange(N, device=self.dev) + (0 if kind == "prey" else Pc)  # agent slot of each row
        alive = t.alive[:, own_slots]  # [W, N]

        assert torch.isfinite(obs).all()
        assert (obs >= self.lo).all() and (obs <= 1.0).all(), (float(obs.min()), float(obs.max()))
        # dead rows: all zero, no neighbour
        assert (obs[~alive] == 0).all(), "dead agent with a non-zero observation"
        assert not mask[~alive].any() and (slot[~alive] == -1).all()
        # mask and slot agree; unused slots exactly zero
        assert torch.equal(mask, slot >= 0), "observed_slot disagrees with the mask"
        assert (slot >= -1).all() and (slot < self.C).all()
        nb = obs[..., 5:].reshape(W, N, S, 6)
        assert (nb[~mask] == 0).all(), "unused observation slot not zero"
        # filled slots come first in each block
        for a, b in ((0, Kd), (Kd, S)):
            if b - a > 1:
                assert not (mask[..., a + 1 : b] & ~mask[..., a : b - 1]).any(), "gap in an observation block"

        # own 5-tuple of live agents
        pos = t.position[:, own_slots]  # [W, N, 2]
        u = unscale(obs[..., :5], self.signed)
        assert (u[..., 0][alive] == TYPE_CODE[kind]).all()
        assert ((u[..., 1] - pos[..., 0] / cfg.width).abs()[alive] <= 1e-5).all()
        assert ((u[..., 2] - pos[..., 1] / cfg.height).abs()[alive] <= 1e-5).all()
        heading = t.heading[:, own_slots]
        assert (circle_gap(u[..., 3], angle_value(heading))[alive] <= 1e-5).all()
        own_speed = torch.linalg.vector_norm(t.velocity[:, own_slots].double(), dim=-1) / tcfg.max_speed
        assert ((u[..., 4].double() - own_speed.clamp(max=1.0)).abs()[alive] <= 1e-5).all()

        if S == 0 or not mask.any():
            return
        # neighbour slots: right type, alive, not self, no repeats
        idx = slot.clamp(min=0).long()
        wi = torch.arange(W, device=self.dev)[:, None, None].expand_as(idx)
        assert (slot[..., :Kd][mask[..., :Kd]] >= Pc).all(), "non-predator in the predator block"
        assert (slot[..., Kd:][mask[..., Kd:]] < Pc).all(), "non-prey in the prey block"
        assert t.alive[wi, idx][mask].all(), "dead agent observed"
        assert not ((slot == own_slots[None, :, None]) & mask).any(), "agent observes itself"
        srt = slot.sort(dim=-1).values
        assert not ((srt[..., 1:] == srt[..., :-1]) & (srt[..., 1:] >= 0)).any(), "agent observed twice"

        nu = unscale(nb, self.signed)
        m = mask
        block_type = torch.tensor([0] * Kd + [1] * Ky, dtype=obs.dtype, device=self.dev).expand(W, N, S)
        assert (nu[..., 0][m] == block_type[m]).all()
        npos = t.position[wi, idx]  # [W, N, S, 2]
        assert ((nu[..., 1] - npos[..., 0] / cfg.width).abs()[m] <= 1e-5).all()
        assert ((nu[..., 2] - npos[..., 1] / cfg.height).abs()[m] <= 1e-5).all()
        disp = torus_displacement(cfg, pos[:, :, None, :].expand_as(npos), npos)
        dist = torch.linalg.vector_norm(disp.double(), dim=-1)
        norm = min(tcfg.view_distance, cfg.max_torus_distance)
        assert ((nu[..., 3].double() * norm - dist).abs()[m] <= 1e-4 * norm + 1e-3).all(), "observed distance"
        assert (dist[m] <= tcfg.view_distance + 1e-3).all(), "observed beyond the view distance"
        assert (circle_gap(nu[..., 4], angle_value(disp))[m] <= 1e-4).all(), "observed bearing"
        max_speed = torch.tensor(
            [cfg.predator.max_speed] * Kd + [cfg.prey.max_speed] * Ky, dtype=torch.float64, device=self.dev
        )
        nspeed = torch.linalg.vector_norm(t.velocity[wi, idx].double(), dim=-1) / max_speed
        assert ((nu[..., 5].double() - nspeed.clamp(max=1.0)).abs()[m] <= 1e-5).all(), "observed speed"
        if cfg.fov_enabled and tcfg.fov_angle < 360:
            cos_half = math.cos(math.radians(tcfg.fov_angle / 2.0))
            dots = (heading[:, :, None, :].double() * disp.double()).sum(-1)
            assert (dots[m] >= dist[m] * cos_half - 1e-3).all(), "observed outside the field of view"
        # nearest first within each block
        for a, b in ((0, Kd), (Kd, S)):
            if b - a > 1:
                both = m[..., a + 1 : b] & m[..., a : b - 1]
                assert (dist[..., a + 1 : b] >= dist[..., a : b - 1] - 1e-3)[both].all(), "block not nearest first"

    # ---------------------------------------------------------------- one step
    def step(self, actions) -> None:
        env, cfg, t, Pc = self.env, self.cfg, self.env.state.torch, self.Pc
        alive_before = t.alive.clone()
        obs, rewards, terminated, truncated, info = env.step(actions)
        assert obs is env.observations and info["alive"] is env.alive
        ended = info["episode_ended"].clone()
        captures = info["captures"].long()
        alive_after = t.alive  # after auto-reset of ended worlds
        R, Pen, Rp = cfg.prey_reward, cfg.prey_capture_penalty, cfg.predator_reward
        self.steps += 1
        self.captures += captures
        self.events["captures"] += int(captures.sum())

        # ------------------------------------------------------------ rewards
        rp, rq = rewards["prey"], rewards["predator"]
        assert rp.shape == (self.W, Pc) and rq.shape == (self.W, self.P)
        assert torch.isfinite(rp).all() and torch.isfinite(rq).all()
        f32 = lambda v: torch.tensor(v, dtype=torch.float32, device=self.dev)  # noqa: E731
        v_live, v_caught_respawned = f32(R), f32(-Pen) + f32(R)
        v_caught_removed, v_zero = f32(-Pen), f32(0.0)
        allowed = (rp == v_live) | (rp == v_caught_respawned) | (rp == v_caught_removed) | (rp == v_zero)
        assert allowed.all(), rp[~allowed]
        ab_p, ab_q = alive_before[:, :Pc], alive_before[:, Pc:]
        tp, tq = terminated["prey"], terminated["predator"]
        # a prey dead before the step: 0, or the survival reward if it was born this step
        if cfg.prey_reproduction:
            assert ((rp[~ab_p] == v_zero) | (rp[~ab_p] == v_live)).all()
        else:
            assert (rp[~ab_p] == v_zero).all()
        # removed (terminated) prey get exactly the penalty, live ones the survival reward (+ penalty)
        assert (rp[tp] == v_caught_removed).all()
        survivors_p = ab_p & ~tp
        assert ((rp[survivors_p] == v_live) | (rp[survivors_p] == v_caught_respawned)).all()
        # every capture is either a respawned prey or a removed one
        caught = (survivors_p & (rp == v_caught_respawned)).sum(1) + tp.sum(1)
        assert torch.equal(caught, captures), (caught, captures)
        if cfg.respawn_captured_prey:
            assert not tp.any(), "prey terminated although captured prey respawn"
        # predators: nothing for the dead, nothing without captures, and each capture's R is shared out fully
        assert (rq >= 0).all() and (rq[~ab_q] == 0).all()
        assert (rq[captures == 0] == 0).all()
        total = rq.double().sum(1)
        assert torch.allclose(total, captures.double() * Rp, rtol=1e-5, atol=1e-4), (total, captures)
        for w in range(self.W):
            c = int(captures[w])
            if 0 < c <= 3:
                values = predator_reward_values(Rp, int(ab_q[w].sum()), c)
                for r in rq[w].tolist():
                    assert min(abs(r - v) for v in values) <= 1e-4 * Rp, (rq[w], c)

        # ------------------------------------------------------------ terminated
        assert not (tp & ~ab_p).any() and not (tq & ~ab_q).any(), "terminated without being alive"
        assert not (tp & truncated["prey"]).any() and not (tq & truncated["predator"]).any()
        live = ~ended
        for kind, ab, term, sl in (("prey", ab_p, tp, slice(None, Pc)), ("predator", ab_q, tq, slice(Pc, None))):
            died = ab & ~alive_after[:, sl]
            # in worlds that did not end (no reset hid the death), terminated == died this step
            assert torch.equal(term[live], died[live]), kind
        if live.any():
            starved = tq[live]
            if starved.any():
                hunger = t.starvation[:, Pc:][live][starved]
                assert (hunger == cfg.predator_starvation_steps + 1).all()
        self.events["starved"] += int(tq.sum())
        self.events["prey_terminated"] += int(tp.sum())
        if cfg.prey_reproduction:
            self.events["births"] += int((~ab_p & alive_after[:, :Pc])[live].sum())

        # ------------------------------------------------------------ truncated and episode ends
        survivors = {"prey": ab_p & ~tp, "predator": ab_q & ~tq}
        for kind in TYPES:
            tr = truncated[kind]
            assert not tr[live].any(), f"{kind} truncated in a world whose episode did not end"
            if cfg.prey_reproduction and kind == "prey":
                # newborns of the last step are live agents too
                assert (tr[ended] >= survivors[kind][ended]).all()
                assert not (tr & ~survivors[kind] & ab_p).any()
            else:
                assert torch.equal(tr[ended], survivors[kind][ended]), kind
        assert (self.steps <= cfg.max_steps).all()
        assert ended[self.steps == cfg.max_steps].all(), "episode ran past max_steps"
        if live.any():
            assert torch.equal(t.world_step[live].long(), self.steps[live])
            assert (alive_after[live][:, :Pc].any(1)).all() and (alive_after[live][:, Pc:].any(1)).all()
        for w in torch.nonzero(ended).flatten().tolist():
            self.events["ended"] += 1
            length = int(info["episode_length"][w])
            assert length == int(self.steps[w])
            if length == cfg.max_steps:
                self.events["time_limit"] += 1
            else:
                assert not survivors["prey"][w].any() or not survivors["predator"][w].any(), (
                    "episode ended early with both types alive"
                )
                self.events["extinct"] += 1
            assert int(info["episode_captures"][w]) == int(self.captures[w])
            assert int(t.world_step[w]) == 0
        # episode returns, summed by the test over the episode's steps
        for kind in TYPES:
            self.returns[kind] += rewards[kind].double().sum(1)
            for w in torch.nonzero(ended).flatten().tolist():
                got = float(info["episode_return"][kind][w])
                want = float(self.returns[kind][w])
                assert math.isclose(got, want, rel_tol=1e-5, abs_tol=1e-2), (kind, w, got, want)
        self.steps[ended] = 0
        self.captures[ended] = 0
        for kind in TYPES:
            self.returns[kind][ended] = 0.0
        if ended.any():  # reset worlds start fresh
            assert (t.prey_alive_count[ended] == cfg.prey_count).all()
            assert (t.predator_alive_count[ended] == cfg.predator_count).all()

        self.check_state()
        for kind in TYPES:
            self.check_observations(kind)


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.slow
def test_random_rollout_invariants(device, name):
    case = CASES[name]
    env = BatchedAquarium(case.cfg, num_worlds=case.num_worlds, device=device, seed=1234)
    try:
        checker = Checker(env)
        checker.check_state()
        for kind in TYPES:
            checker.check_observations(kind)
        gen = torch.Generator().manual_seed(7)  # drawn on the CPU (same actions on every device), then moved
        n = case.cfg.action_count
        for _ in range(case.steps):
            actions = {
                "prey": torch.randint(0, n, (env.num_worlds, env.prey_capacity), generator=gen),
                "predator": torch.randint(0, n, (env.num_worlds, env.predator_capacity), generator=gen),
            }
            actions = {k: a.to(env.torch_device) for k, a in actions.items()}
            checker.step(actions)
        for event in case.expect:
            assert checker.events[event] > 0, f"the rollout never exercised {event!r}: {checker.events}"
    finally:
        env.close()


def test_reset_mid_episode_restarts_the_statistics(device):
    """A manual reset() starts every world's episode anew: the next ending reports only the new episode."""
    cfg = AquariumConfig(width=300.0, height=300.0, max_steps=40)
    env = BatchedAquarium(cfg, num_worlds=2, device=device, seed=3)
    try:
        checker = Checker(env)
        gen = torch.Generator().manual_seed(1)
        n = cfg.action_count

        def actions():
            return {
                "prey": torch.randint(0, n, (2, env.prey_capacity), generator=gen).to(env.torch_device),
                "predator": torch.randint(0, n, (2, env.predator_capacity), generator=gen).to(env.torch_device),
            }

        for _ in range(25):
            checker.step(actions())
        env.reset()
        checker.steps[:] = 0
        checker.captures[:] = 0
        for kind in TYPES:
            checker.returns[kind][:] = 0.0
        checker.check_state()
        for _ in range(45):
            checker.step(actions())
        assert checker.events["time_limit"] == 2
    finally:
        env.close()
