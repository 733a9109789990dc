"""The episode loop: a `BatchedAquarium`, a driver per team and observers. Swarm metrics, the studies'
measures, evaluation's per-episode records and video frames all watch this one loop.

```python
from aquarium_warp.drivers import make_drivers
from aquarium_warp.metrics import EpisodeMetrics
from aquarium_warp.rollout import rollout

drivers = make_drivers({"prey": "turnaway", "predator": "naivchase"}, env, seed=0)
episodes = EpisodeMetrics(env, every=10)          # an observer
rollout(env, drivers, steps=env.config.max_steps, observers=[episodes])
episodes.result()                                   # one episode per world
```

Every step takes each driver's actions (in the order of `drivers`), makes one `env.step` and calls
every observer's `on_step` (in the order of `observers`). The loop itself reads nothing back from the
device: whatever synchronises with the host is an observer's doing. Observers (`Observer` subclasses):

- `metrics.EpisodeMetrics`: swarm metrics averaged per episode;
- `StepViews`: a `StepView` of every step (positions before and after it), for the studies' measures;
- `Progress`: steps taken, for a progress bar;
- `video.Frames`: rendered frames of one world, for a video;
- evaluation's per-episode records (`training.evaluate.run_episodes`).

`random_actions` draws uniformly random actions for every slot from a torch generator (the benchmarks'
action pools and tests).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping

import torch

from .config import AquariumConfig
from .drivers import Driver
from .env import BatchedAquarium, StepResult

# A function of the observations returning every team's actions (the older form of a policy).
Policy = Callable[[Mapping[str, torch.Tensor]], Mapping[str, torch.Tensor]]
Drivers = Mapping[str, Driver] | Policy


class Observer:
    """What `rollout` calls on each of its observers; every hook does nothing unless overridden."""

    def on_start(self, env: BatchedAquarium) -> None:
        """Before the first step (after the reset, where the rollout resets)."""

    def on_step(self, env: BatchedAquarium, step: int, result: StepResult) -> None:
        """After step `step` (0-based); `result` is the env's outputs (views overwritten by the next step)."""

    def on_end(self, env: BatchedAquarium) -> None:
        """After the last step."""


def rollout(
    env: BatchedAquarium,
    drivers: Drivers,
    steps: int,
    observers: Iterable[Observer] = (),
    *,
    reset: bool = True,
    validate: bool = False,
    until: Callable[[], bool] | None = None,
) -> int:
    """Step `env` `steps` times with the actions of `drivers` and tell `observers`; returns the steps taken.

    `drivers`: `{team: driver}` (`drivers.make_drivers`; each a callable returning its team's actions),
    or one function of the observations returning every team's actions. `reset`: start with
    `env.reset()` (else from the current state). `validate`: check every step's actions (`env.step`).
    `until`: asked after every step; True stops the rollout early."""
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"steps={steps!r} must be an integer >= 0")
    act = _actions(env, drivers)
    observers = tuple(observers)
    if reset:
        env.reset()
    for observer in observers:
        observer.on_start(env)
    taken = 0
    while taken < steps:
        result = env.step(act(), validate=validate)
        for observer in observers:
            observer.on_step(env, taken, result)
        taken += 1
        if until is not None and until():
            break
    for observer in observers:
        observer.on_end(env)
    return taken


def _actions(env: BatchedAquarium, drivers: Drivers) -> Callable[[], Mapping[str, torch.Tensor]]:
    """The step's actions as one call, from either form of `drivers`."""
    if isinstance(drivers, Mapping):
        teams = tuple(drivers.items())
        return lambda: {team: drive() for team, drive in teams}
    if callable(drivers):
        return lambda: drivers(env.observations)
    raise ValueError(
        f"drivers={drivers!r} must be {{team: driver}} or a function of the observations returning every team's actions"
    )


@dataclasses.dataclass
class StepView:
    """One step of a rollout, as the measures see it: positions and live slots before the step
    (`before_*`, copies), the state after it (`position`, `velocity`, `alive`, views valid until the next
    step; the rest in `env.state.torch`) and the prey captured in the step (`captured` `[W, Pc]`).
    Positions `[W, C, 2]` px, prey slots first; `step` counts from 0."""

    env: BatchedAquarium
    before_position: torch.Tensor
    before_alive: torch.Tensor
    position: torch.Tensor
    velocity: torch.Tensor
    alive: torch.Tensor
    captured: torch.Tensor
    step: int


class StepViews(Observer):
    """Calls `callback(StepView)` after every step (copying the positions and live slots once a step)."""

    def __init__(self, callback: Callable[[StepView], None]):
        self.callback = callback

    def on_start(self, env: BatchedAquarium) -> None:
        t = env.state.torch
        self._before = (t.position.clone(), t.alive.clone())

    def on_step(self, env: BatchedAquarium, step: int, result: StepResult) -> None:
        t = env.state.torch
        self.callback(
            StepView(env, *self._before, t.position, t.velocity, t.alive, t.captured[:, : env.prey_capacity], step)
        )
        self._before = (t.position.clone(), t.alive.clone())  # the next step's state before it


class Progress(Observer):
    """Reports the steps taken to `advance(n)`: every `every` steps, and the rest at the end."""

    def __init__(self, advance: Callable[[int], object], every: int = 1):
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"every={every!r} must be an integer >= 1")
        self.advance, self.every = advance, every
        self._pending = 0

    def on_start(self, env: BatchedAquarium) -> None:
        self._pending = 0

    def on_step(self, env: BatchedAquarium, step: int, result: StepResult) -> None:
        self._pending += 1
        if self._pending == self.every:
            self.advance(self._pending)
            self._pending = 0

    def on_end(self, env: BatchedAquarium) -> None:
        if self._pending:
            self.advance(self._pending)
            self._pending = 0


def random_actions(
    cfg: AquariumConfig,
    worlds: int,
    generator: torch.Generator,
    device: torch.device | str,
) -> dict[str, torch.Tensor]:
    """One uniformly random action per slot of both types from `generator`, as int32 (the env's own
    action dtype: a timed step copies them in without a conversion)."""
    return {
        t: torch.randint(0, cfg.action_count, (worlds, n), generator=generator, device=device, dtype=torch.int32)
        for t, n in (("prey", cfg.prey_capacity), ("predator", cfg.predator_capacity))
    }
