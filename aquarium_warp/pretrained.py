"""Trained policies shipped with the package (`aquarium_warp/policies/`), each loadable by a short name
wherever a policy file is taken: `aquarium-warp eval`, `video`, `study`, `train --predator-policy`, and in
Python `aquarium_warp.training.export.load_policy` (for the PettingZoo env: `world(name)` gives the
config to build it with, and the loaded policy maps its observations to actions).

    aquarium-warp eval --prey turnaway constant prey-b --predator naivchase --episodes 50
    aquarium-warp video --prey-policy prey-b --out prey-b.mp4

`policies/index.json` lists each name with its team, its file (TorchScript; `onnx`: the same policy as
ONNX), the world it was trained in (`env`; a policy of randomised worlds: `training_range`, the ranges
its worlds were drawn from) and how it was made (the command, commit, device and its evaluation).

The general policies `prey-any` and `predator-any` (trained over randomised worlds,
docs/general-policies.md) are what a policy option means by "learned" (`for_team`):

    aquarium-warp view --prey-policy learned --predator-policy learned
"""

from __future__ import annotations

import functools
import json
import os

DIRECTORY = os.path.join(os.path.dirname(os.path.abspath(__file__)), "policies")


@functools.cache
def index() -> dict[str, dict]:
    """`{name: entry}` of the shipped policies (empty when none is shipped)."""
    path = os.path.join(DIRECTORY, "index.json")
    if not os.path.isfile(path):
        return {}
    with open(path, encoding="utf-8") as f:
        return json.load(f)["policies"]


# The shipped policy of each team that acts in any world of its training range: the default learned one.
LEARNED = "learned"
GENERAL = {"prey": "prey-any", "predator": "predator-any"}


def names(team: str | None = None) -> list[str]:
    """The shipped policies' names (of `team` only, if given; an entry without a team is a prey's)."""
    return sorted(n for n, e in index().items() if team is None or e.get("team", "prey") == team)


def for_team(spec, team: str):
    """`spec`, or for "learned" (any case; an existing file of that name wins) `team`'s general policy."""
    if isinstance(spec, str) and spec.lower() == LEARNED and not os.path.exists(spec):
        return GENERAL[team]
    return spec


def resolve(spec):
    """The file of a shipped policy's name (case-insensitive), or `spec` unchanged: an existing path
    always wins over a name."""
    if isinstance(spec, str) and not os.path.exists(spec):
        entry = index().get(spec.lower())
        if entry is not None:
            return os.path.join(DIRECTORY, entry["file"])
    return spec


def is_policy_file(spec) -> bool:
    """Whether `spec` is an existing policy file or a shipped policy's name."""
    return isinstance(spec, str) and os.path.isfile(resolve(spec))


def world(name: str):
    """The `AquariumConfig` a shipped policy was trained in (ValueError for an unknown name)."""
    from .config import AquariumConfig

    entry = index().get(name.lower()) if isinstance(name, str) else None
    if entry is None:
        raise ValueError(f"pretrained policy {name!r} is unknown: shipped are {names()}")
    return AquariumConfig.from_dict(entry["env"])
