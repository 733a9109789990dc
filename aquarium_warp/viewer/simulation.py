"""The viewer's simulation: a `BatchedAquarium`, the two teams' drivers, the human's agent and the
snapshots of the displayed world that the server streams (`WorldView`, shared with `attach`). No web code
here (the tests drive it directly).

Every method runs on one thread (the server's simulation thread), so no locking is needed.
"""

from __future__ import annotations

import dataclasses
import os
import time

import numpy as np
import torch

from .. import pretrained
from ..agent_types import TYPES
from ..config import AquariumConfig
from ..drivers import HEURISTICS, is_heuristic, make_drivers, teams_world
from ..env import BatchedAquarium, action_directions
from ..metrics import SwarmMetrics
from .flow import FlowSampler

TYPE_PREY, TYPE_PREDATOR = 1, 0  # the codes the page and replay files use (kernels.common's PREY / PREDATOR)


@dataclasses.dataclass
class ViewOptions:
    """What `aquarium-warp view` was started with (its options, checked by `validate`)."""

    prey_policy: str = "turnaway"
    predator_policy: str = "naivchase"
    prey: int | None = None  # None: the trained policies' world's, else 16
    predators: int | None = None
    width: float | None = None
    height: float | None = None
    worlds: int = 1
    seed: int = 0
    device: str | None = None
    policy_dir: str | None = None
    human: str | None = None


class Simulation:
    """The worlds on view. `apply(message)` acts on a checked page message (`messages.parse_message`);
    `advance()` steps by the speed (when playing), `snapshot()` returns the displayed world."""

    records = True  # the viewer offers recording (an attached run does not: see `attach`)

    def __init__(self, options: ViewOptions):
        self.options = options
        self.specs = {
            "prey": pretrained.for_team(options.prey_policy, "prey"),
            "predator": pretrained.for_team(options.predator_policy, "predator"),
        }
        # Policy files the command line named may be chosen again on the page, wherever they are.
        self._given_files = {
            os.path.realpath(pretrained.resolve(spec)) for spec in self.specs.values() if not is_heuristic(spec)
        }
        for team in self.specs:
            self.specs[team] = self.allowed_spec(team, self.specs[team])
        self.env: BatchedAquarium | None = None
        self._build(self.specs)
        self.world = 0
        self.playing = True
        self.speed = 1.0
        self._step_credit = 0.0  # fractional steps owed at speeds below 1
        self._single_steps = 0
        self.human: str | None = None
        self.human_slot = 0
        self._human_action = 0
        self.human_stats = {"captures": 0, "reward": 0.0, "steps": 0}
        if options.human is not None:
            self.set_human(options.human)

    # ------------------------------------------------------------------ policies
    def policy_choices(self) -> dict[str, list[str]]:
        """What the page offers per team: heuristics, shipped names, files under --policy-dir and
        files given on the command line."""
        files = sorted(self._given_files)
        directory = self.options.policy_dir
        if directory:
            for root, _, names in os.walk(directory):
                files += sorted(os.path.join(root, n) for n in names if n.endswith((".pt", ".onnx")))
        return {team: list(HEURISTICS[team]) + pretrained.names(team) + sorted(set(files)) for team in self.specs}

    def allowed_spec(self, team: str, spec: str) -> str:
        """`spec` if a page may choose it for `team`: a heuristic of the team, a shipped policy's name,
        or a file under --policy-dir or given on the command line; ValueError otherwise (so nothing a
        page sends opens any other file). "learned" is the team's general policy (`pretrained.for_team`)."""
        spec = pretrained.for_team(spec, team)
        if is_heuristic(spec, team):
            return spec
        if spec.lower() in pretrained.names(team):
            return spec.lower()
        path = os.path.realpath(spec)
        directory = self.options.policy_dir
        inside = directory is not None and os.path.commonpath([path, os.path.realpath(directory)]) == os.path.realpath(
            directory
        )
        if path not in self._given_files and not inside:
            where = f"under --policy-dir {directory}" if directory else "(no --policy-dir was given)"
            raise ValueError(
                f"{team} policy {spec!r} is not allowed: choose a heuristic {list(HEURISTICS[team])}, a "
                f"shipped policy {pretrained.names(team)}, a file given on the command line or a file {where}"
            )
        if not os.path.isfile(path):
            raise ValueError(f"{team} policy file {spec!r} does not exist")
        return path

    def _config(self, specs: dict[str, str]) -> AquariumConfig:
        """The trained policies' world (their metadata, as `video` takes it), else docs/model.md's; the
        command line's counts and sizes override it."""
        o = self.options
        return teams_world(specs, prey_count=o.prey, predator_count=o.predators, width=o.width, height=o.height)

    def _build(self, specs: dict[str, str]) -> None:
        """Drivers for `specs` (and a new env when their world differs from the current one's); the
        current ones stay when anything fails (the ValueError says what)."""
        env = self.env
        try:
            config = self._config(specs)
            if env is None or env.config.to_dict() != config.to_dict():
                env = BatchedAquarium(
                    config, num_worlds=self.options.worlds, device=self.options.device, seed=self.options.seed
                )
            drivers = make_drivers(specs, env, seed=self.options.seed)
            for driver in drivers.values():
                driver()  # a policy whose observations do not fit this world fails here, not in a step
        except Exception as error:  # whatever a user's file makes torch, onnx or the loaders raise: keep the teams
            if env is not None and env is not self.env:
                env.close()
            if self.env is None:  # at start-up: the command line's policies must work
                raise ValueError(str(error)) from error
            raise ValueError(f"cannot run {specs}: {error}") from error
        if env is not self.env:
            if self.env is not None:
                self.env.close()
            self.env = env
            self._directions = torch.from_numpy(action_directions(config.action_count))
            self.view = WorldView(env)
            self.world = min(getattr(self, "world", 0), env.num_worlds - 1)
            self.human_slot = 0
        self.drivers, self.specs = drivers, dict(specs)

    def set_policy(self, team: str, spec: str) -> None:
        spec = self.allowed_spec(team, spec)
        self._build({**self.specs, team: spec})

    # ------------------------------------------------------------------ human play
    def _team_slots(self, team: str) -> tuple[int, int]:
        env = self._env
        return (0, env.prey_capacity) if team == "prey" else (env.prey_capacity, env.capacity)

    @property
    def _env(self) -> BatchedAquarium:
        assert self.env is not None  # built in __init__
        return self.env

    def set_human(self, team: str | None) -> None:
        """Hand the first live agent of `team` in the displayed world to the keyboard (None: no human)."""
        self.human = team
        self.human_stats = {"captures": 0, "reward": 0.0, "steps": 0}
        if team is None:
            return
        first, end = self._team_slots(team)
        alive = self._env.state.torch.alive[self.world, first:end].cpu()
        self.human_slot = int(torch.nonzero(alive).flatten()[0]) if bool(alive.any()) else 0
        heading = self._env.state.torch.heading[self.world, first + self.human_slot].cpu()
        self._human_action = int(torch.argmax(self._directions @ heading))  # keep going the way it faces

    def set_keys(self, dx: int, dy: int) -> None:
        """The held arrow keys: the heading of the 16 (or action_count) nearest their direction (screen
        y points down, as the world's does); no key keeps the last heading (there is no 'stop' action)."""
        if dx or dy:
            want = torch.tensor([dx, dy], dtype=torch.float32)
            self._human_action = int(torch.argmax(self._directions @ (want / want.norm())))

    def human_agent(self) -> int | None:
        """The slot (in the env's slot order) of the human's agent, or None."""
        return None if self.human is None else self._team_slots(self.human)[0] + self.human_slot

    # ------------------------------------------------------------------ stepping
    def apply(self, message: dict) -> None:
        """Act on a checked page message; a ValueError (e.g. a policy that is not allowed) changes nothing."""
        kind = message["type"]
        if kind == "play":
            self.playing = True
        elif kind == "pause":
            self.playing = False
        elif kind == "step":
            self.playing = False
            self._single_steps += 1
        elif kind == "reset":
            self._env.reset()
            self.view.forget_metrics()  # a new state at the same step count
        elif kind == "speed":
            self.speed = message["value"]
        elif kind == "world":
            self.world = message["index"]
            self.view.forget_metrics()  # the other world's values
            if self.human is not None:
                self.set_human(self.human)
        elif kind == "policy":
            self.set_policy(message["team"], message["spec"])
        elif kind == "human":
            self.set_human(message["team"])
        elif kind == "keys":
            self.set_keys(message["dx"], message["dy"])
        elif kind == "move":
            move_agent(self._env, self.world, message["slot"], message["x"], message["y"])
            self.view.forget_metrics()

    def step(self) -> None:
        """One step of every world: the drivers' actions, the human's for its agent."""
        actions = {team: driver() for team, driver in self.drivers.items()}
        if self.human is not None:
            actions[self.human] = actions[self.human].clone()  # the drivers' buffers are theirs
            actions[self.human][self.world, self.human_slot] = self._human_action
        _, rewards, _, _, info = self._env.step(actions, validate=False)
        w = self.world
        if self.human is not None:
            stats = self.human_stats
            stats["steps"] += 1
            reward = float(rewards[self.human][w, self.human_slot])
            stats["reward"] += reward
            if self.human == "prey":
                stats["captures"] += int(self._env.state.torch.captured[w, self.human_slot])
            else:  # a capture the predator took part in: its share of the capture reward
                stats["captures"] += int(int(info["captures"][w]) > 0 and reward > 0)

    def advance(self) -> int:
        """Steps owed since the last call: `speed` per call while playing (fractions carried over),
        plus single steps asked for; returns how many were taken."""
        count = self._single_steps
        self._single_steps = 0
        if self.playing:
            self._step_credit += self.speed
            count += int(self._step_credit)
            self._step_credit -= int(self._step_credit)
        for _ in range(count):
            self.step()
        return count

    def snapshot(self, flow: bool = False, inspect=()) -> dict:
        """The displayed world now (`WorldView.snapshot`) with the header values of the controls."""
        snap = self.view.snapshot(self.world, flow, inspect)
        snap["header"].update(
            controls=True,
            playing=self.playing,
            speed=self.speed,
            specs=dict(self.specs),
            human=None if self.human is None else {"team": self.human, "slot": self.human_agent(), **self.human_stats},
        )
        return snap


class WorldView:
    """Snapshots of one world of `env` for the pages: its agents, the swarm metrics, the flow and the
    agents the pages inspect. Call from the thread that steps `env`."""

    def __init__(self, env: BatchedAquarium):
        self.env = env
        self.metrics = SwarmMetrics(env, group_metrics=False)  # the page shows the swarm's measures only
        self.flow = FlowSampler(env)
        self._values: tuple[tuple[int, int, int], dict] | None = None  # ((world, episode, step), its metrics)
        self._due = 0.0

    def forget_metrics(self) -> None:
        self._values = None

    def snapshot(self, world: int, flow: bool = False, inspect=()) -> dict:
        """World `world` now: numpy arrays of every slot, the header values the page shows, the flow
        (with `flow`) and `inspect_agent` of each slot in `inspect`."""
        env, w = self.env, world
        s = env.state.torch
        # The swarm metrics (groups: a connected-components pass) may cost more than a step in a large world,
        # and a tick that computes them is a late frame: recomputed only for a new state (not while paused)
        # and when the last result is older than 19x its own cost, they take at most a twentieth of the
        # time (a frame late in every 20 in the largest worlds; the plots update less often there).
        now = time.perf_counter()
        counters = (s.episode, s.world_step, s.episode_captures, s.prey_alive_count, s.predator_alive_count)
        episode, step, captures, prey_alive, predator_alive = torch.stack([c[w] for c in counters]).tolist()  # one read
        state = (w, episode, step)
        if self._values is None or (self._values[0] != state and (self._values[0][0] != w or now >= self._due)):
            values = self.metrics.compute()
            self._values = (state, {k: float(values[k][w]) for k in ("polarization", "groups")})
            self._due = time.perf_counter() + 19 * (time.perf_counter() - now)
        values = self._values[1]
        snap = {
            "position": s.position[w].cpu().numpy().copy(),
            "heading": s.heading[w].cpu().numpy().copy(),
            "velocity": s.velocity[w].cpu().numpy().copy(),
            "alive": s.alive[w].cpu().numpy().copy(),
            "flow": self.flow.sample(w) if flow else None,
            "inspect": {slot: inspect_agent(env, w, slot) for slot in inspect},
        }
        cfg = env.config.world(w) if env.config.per_world_fields else env.config
        snap["header"] = {
            "step": step,
            "episode": episode,
            "world": w,
            "num_worlds": env.num_worlds,
            "width": float(cfg.width),
            "height": float(cfg.height),
            "prey_capacity": env.prey_capacity,
            "types": {t: _type_info(getattr(cfg, t), cfg.fov_enabled) for t in TYPES},
            "episode_captures": captures,
            "polarization": _finite(values["polarization"]),
            "groups": _finite(values["groups"]),
            "prey_alive": prey_alive,
            "predator_alive": predator_alive,
            "controls": False,
            "playing": True,
            "speed": 1.0,
            "specs": None,
            "human": None,
        }
        return snap


def _team_of(env: BatchedAquarium, slot: int) -> tuple[str, int]:
    """(team, index within the team) of an env slot."""
    return ("prey", slot) if slot < env.prey_capacity else ("predator", slot - env.prey_capacity)


def inspect_agent(env: BatchedAquarium, world: int, slot: int) -> dict:
    """What agent `slot` of `world` saw, did and got in the last step: its observation (`env.outputs`,
    the policy's input for the next action), the action it took, its reward and episode return."""
    team, index = _team_of(env, slot)
    s, out = env.state.torch, env.outputs
    return {
        "slot": slot,
        "team": team,
        "alive": bool(s.alive[world, slot]),
        "observation": [round(float(v), 4) for v in out.observations[team][world, index].cpu()],
        "action": int(env.actions[team][world, index]),
        "reward": _finite(out.rewards[team][world, index]),
        "episode_return": _finite(s.episode_return[world, slot]),
    }


def move_agent(env: BatchedAquarium, world: int, slot: int, x: float, y: float) -> None:
    """Put live agent `slot` of `world` at (x, y) through `env.set_state` (which checks the position:
    ValueError, nothing changed, when it lies outside the world)."""
    if not bool(env.state.torch.alive[world, slot]):
        raise ValueError(f"slot {slot} of world {world} holds no live agent")
    position = env.state.torch.position[world].cpu().clone()
    position[slot] = torch.tensor([x, y], dtype=torch.float32)
    env.set_state(world, position=position)


def _finite(value) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None  # JSON has no NaN


def _type_info(t, fov_enabled: bool) -> dict:
    return {
        "radius": float(t.radius),
        "view_distance": float(t.view_distance),
        "fov": float(t.fov_angle) if fov_enabled else 360.0,
    }
