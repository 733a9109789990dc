"""Team drivers: the one place that turns a policy spec (a heuristic's name, a policy file or a shipped
policy's name) into the driver of one team of a `BatchedAquarium`: a callable returning that team's
actions `[num_worlds, slots]` for the env's current state. Training opponents, `eval`, `video`, the
studies and the viewer all build their teams here.

```python
from aquarium_warp.drivers import make_driver, make_drivers

prey = make_driver("prey-b", env, "prey")              # a shipped policy (needs the training extra)
predator = make_driver("naivchase", env, "predator")   # a heuristic
env.step({"prey": prey(), "predator": predator()})
drivers = make_drivers({"prey": "turnaway", "predator": "runs/x/exported/policy.pt"}, env, seed=3)
```

Heuristic names (`HEURISTICS`; case, "_" and "-" are ignored): those of `aquarium_warp.heuristics`,
plus "naivchase-noconfusion" (NaivChase chasing the nearest visible prey) and "naivchase-mixed"
(NaivChase with target confusion in the even worlds, chasing the nearest prey in the odd ones: a
training opponent of both kinds, `WorldMix`). Heuristics draw from the env's seed. Trained policies
act by argmax unless `deterministic=False`, then sample with their own `seed` (`make_drivers`:
`seeding.team_seed`, the run's seed for the prey, the next one for the predators).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TypeVar

import torch

from .agent_types import TYPES
from .config import AquariumConfig
from .env import BatchedAquarium
from .heuristics import POLICIES, make_policy, normalise_name
from .pretrained import for_team, is_policy_file
from .pretrained import names as pretrained_names
from .seeding import team_seed

NO_CONFUSION = "naivchase-noconfusion"
MIXED_CONFUSION = "naivchase-mixed"
# Heuristic names by team (compared after `normalise_name`).
HEURISTICS = {"prey": POLICIES["prey"], "predator": POLICIES["predator"] + (NO_CONFUSION, MIXED_CONFUSION)}

Driver = Callable[[], torch.Tensor]
Fallback = TypeVar("Fallback", AquariumConfig, None)


class WorldMix:
    """One team driven by several drivers, each in its own worlds: `drivers[k]` acts in the worlds where
    `choice` (`[num_worlds]` integers) is k. Every driver is called at every step (each decides from
    the state as it would alone; so drivers without state of their own: heuristics, feed-forward
    policies) and their actions are merged on the device."""

    def __init__(self, drivers: Sequence[Driver], choice) -> None:
        self.drivers = list(drivers)
        first = self.drivers[0]()
        self.choice = torch.as_tensor(choice, device=first.device).long().view(-1, 1)
        if self.choice.shape[0] != first.shape[0] or not bool(
            ((self.choice >= 0) & (self.choice < len(self.drivers))).all()
        ):
            raise ValueError(f"choice must give each of the {first.shape[0]} worlds a driver in [0, {len(drivers)})")
        self.actions = torch.empty_like(first)
        # a call is device work only if every driver's is
        self.capturable = all(bool(getattr(d, "capturable", False)) for d in self.drivers)

    def __call__(self) -> torch.Tensor:
        self.actions.copy_(self.drivers[0]())
        for k, driver in enumerate(self.drivers[1:], start=1):
            torch.where(self.choice == k, driver(), self.actions, out=self.actions)
        return self.actions


def is_heuristic(spec, team: str | None = None) -> bool:
    """Whether `spec` names a heuristic of `team` (of either team for None)."""
    teams = TYPES if team is None else (team,)
    return isinstance(spec, str) and any(
        normalise_name(spec) == normalise_name(name) for t in teams for name in HEURISTICS[t]
    )


def check_spec(spec, team: str, option: str | None = None) -> None:
    """A one-line ValueError (naming `option`, e.g. "--prey-policy", else the team) unless `spec` is a
    heuristic of `team`, an existing policy file or a shipped policy's name ("learned": the team's
    general policy, `pretrained.for_team`)."""
    spec = for_team(spec, team)
    if is_heuristic(spec, team) or is_policy_file(spec):
        return
    name = option or f"{team} policy"
    raise ValueError(
        f"{name}={spec!r} is neither a heuristic (a {team} heuristic: {', '.join(HEURISTICS[team])}) "
        f"nor an existing policy file (exported .pt/.onnx or a training checkpoint) nor a shipped "
        f"policy ({', '.join(pretrained_names(team)) or 'none'})"
    )


def make_driver(
    spec,
    env: BatchedAquarium,
    team: str,
    deterministic: bool = True,
    seed: int = 0,
    confusion: bool | None = None,
    blind_to: str | None = None,
) -> Driver:
    """The driver of `team` ("prey" or "predator") of every world of `env` for `spec`.

    `confusion` (NaivChase only; None: the heuristic's default, True) picks NaivChase's target among
    several visible prey. A trained policy (exported file, checkpoint or shipped name; of a checkpoint
    of both teams, its `team` learner) needs the training extra; a recurrent one resets its rows'
    hidden states where their episodes end. `blind_to` ("prey" or "predator"; trained policies only):
    the policy sees its slots of that type empty (the neighbour-ablation control)."""
    if team not in TYPES:
        raise ValueError(f"team={team!r} must be one of {TYPES}")
    if blind_to is not None and blind_to not in TYPES:
        raise ValueError(f"blind_to={blind_to!r} must be None or one of {TYPES}")
    spec = for_team(spec, team)
    check_spec(spec, team)
    if blind_to is not None and is_heuristic(spec, team):
        raise ValueError(
            f"blind_to={blind_to!r} applies to trained policies, not to the heuristic {spec!r} "
            "(heuristics read the state, not observations)"
        )
    if is_heuristic(spec, team):
        key = normalise_name(spec)
        if key == normalise_name(NO_CONFUSION):
            return make_policy("naivchase", env, team, confusion=False)
        if key == normalise_name(MIXED_CONFUSION):
            chasers = [make_policy("naivchase", env, team, confusion=c) for c in (True, False)]
            return WorldMix(chasers, torch.arange(env.num_worlds) % 2)
        return make_policy(spec, env, team, confusion=confusion if key == "naivchase" else None)
    try:  # the training extra is optional
        from .training.drivers import policy_driver
        from .training.export import load_policy
    except ImportError as error:
        raise ValueError(f"trained policies need aquarium_warp.training (importing it failed: {error})") from error
    policy = load_policy(spec, device=env.torch_device, deterministic=deterministic, seed=seed, team=team)
    try:
        return policy_driver(policy, env, team, blind_to=blind_to)
    except ValueError as error:  # a policy that cannot act in this world: say which one
        raise ValueError(f"{team} policy {spec}: {error}") from None


def parse_spec(spec: str) -> tuple[str, str]:
    """`"LABEL=SPEC"` -> `(label, spec)`; a bare spec is its own label (a file: its run directory's name)."""
    if "=" in spec and not os.path.exists(spec):
        label, value = spec.split("=", 1)
        return label, value
    if is_heuristic(spec):
        return spec.lower(), spec
    path = os.path.normpath(spec)
    parts = path.split(os.sep)
    if len(parts) >= 3 and parts[-2] == "exported":  # run/exported/policy.pt: the run's name
        label = parts[-3]
    elif len(parts) >= 4 and parts[-3] == "exported":  # run/exported/<team>/policy.pt (both teams learned)
        label = f"{parts[-4]}-{parts[-2]}"
    else:
        label = os.path.splitext(parts[-1])[0]
    return label, spec


def trained_world(spec: str) -> AquariumConfig:
    """The world the trained policy `spec` (an exported file, a training checkpoint or a shipped name)
    was trained in: its run config's `env` section (the training extra reads it)."""
    try:  # the training extra is optional
        from .training.config import env_config
        from .training.export import policy_world
    except ImportError as error:
        raise ValueError(f"trained policies need aquarium_warp.training (importing it failed: {error})") from error
    return env_config({"env": policy_world(spec)})


def common_world(specs: Iterable[str], fallback: Fallback) -> AquariumConfig | Fallback:
    """The world every trained policy among `specs` (policy specs, `LABEL=SPEC` allowed; heuristics
    are skipped) was trained in, `fallback` where none is trained; a ValueError names two specs whose
    worlds differ."""
    first: tuple[str, AquariumConfig] | None = None
    for spec in specs:
        _, value = parse_spec(spec)
        if is_heuristic(value):
            continue
        world = trained_world(value)
        if first is None:
            first = (spec, world)
        elif world.to_dict() != first[1].to_dict():
            from .training.config import flat_config

            a, b = flat_config(first[1].to_dict()), flat_config(world.to_dict())
            differ = ", ".join(f"{k} {a[k]!r} vs {b[k]!r}" for k in a if a[k] != b.get(k))
            raise ValueError(
                f"policies {first[0]!r} and {spec!r} were trained in different worlds ({differ}): evaluate each "
                "in its own world, one command per policy"
            )
    return first[1] if first is not None else fallback


def teams_world(specs: Mapping[str, str], **changes: float | None) -> AquariumConfig:
    """The world of `{team: spec}`: the trained policies' (`common_world`), else docs/model.md's, with
    the `changes` that are not None (the counts and sizes a command line gives) replaced."""
    files = [spec for team, spec in specs.items() if not is_heuristic(spec, team)]
    world = common_world(files, None) if files else None
    return (world or AquariumConfig()).replace(**{key: value for key, value in changes.items() if value is not None})


def make_drivers(
    specs: Mapping[str, str],
    env: BatchedAquarium,
    seed: int = 0,
    deterministic: bool = True,
    confusion: bool | None = None,
    blind_to: Mapping[str, str] | None = None,
) -> dict[str, Driver]:
    """`{team: driver}` for the teams of `specs`; a trained team samples (if `deterministic=False`) with
    `seeding.team_seed(seed, team)` (`seed` for the prey, `seed + 1` for the predators), so the two teams'
    draws are independent.
    `blind_to` maps a team to the type its trained policy sees no slots of (`make_driver`)."""
    blind_to = blind_to or {}
    return {
        team: make_driver(
            spec,
            env,
            team,
            deterministic=deterministic,
            seed=team_seed(seed, team),
            confusion=confusion,
            blind_to=blind_to.get(team),
        )
        for team, spec in specs.items()
    }
