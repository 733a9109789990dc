"""The configurations of the sweeps: worlds at the default density and their points."""

from __future__ import annotations

import math
from typing import Any

from ..config import AquariumConfig
from .settings import BenchSettings


def split_agents(agents: int) -> tuple[int, int]:
    """(prey, predators) for `agents` agents: about one predator per 16 prey, at least one of each
    (also how `benchmarks/vmas_peer.py` splits VMAS's agents)."""
    if agents < 2:
        raise ValueError(f"agents={agents} must be >= 2 (at least one prey and one predator)")
    predators = max(1, round(agents / 17))
    return agents - predators, predators


def density_config(agents: int, **changes: Any) -> AquariumConfig:
    """About `agents` agents (16 prey per predator) at the default density of 17 per 800 x 800 px."""
    prey, predators = split_agents(agents)
    side = 800.0 * math.sqrt((prey + predators) / 17.0)
    return AquariumConfig(prey_count=prey, predator_count=predators, width=side, height=side, **changes)


def load_worlds(agents_per_world: int, load_agents: int) -> int:
    """Worlds of the load series' point: about `load_agents` agents in flight, at least one world."""
    return max(1, round(load_agents / agents_per_world))


def sweep_points(settings: BenchSettings) -> list[tuple[str, AquariumConfig, int]]:
    """(series, config, worlds) of every point: the agents sweep (one world), the worlds sweep, then
    the load sweep (with `settings.load_agents`: each N of `settings.agents` up to it, in
    `load_worlds(N, load_agents)` worlds)."""
    points = [("agents", density_config(n), 1) for n in settings.agents]
    points += [("worlds", AquariumConfig(), w) for w in settings.worlds]
    if settings.load_agents is not None:
        points += [
            ("load", density_config(n), load_worlds(n, settings.load_agents))
            for n in settings.agents
            if n <= settings.load_agents
        ]
    return points
