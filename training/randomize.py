"""Domain randomisation for training: per-world parameter values drawn at every world's reset.

`--randomize prey_max_speed=2:6` draws each world's value uniformly from [2, 6] (integers for integer
fields), `--randomize prey_count=4,8,12` from the listed values; names are `env.set_params`'s (world
fields such as `prey_reward`, per-type ones as `prey_<field>` / `predator_<field>`; numbers only, not
`flow` or `capture_rule`).

Every world gets a draw when the randomiser is made and a new one each time its episode ends (the
env has then already started the next episode, whose steps use the new values; a live count takes
effect at the world's next reset). The range is checked once, up front: its ends (or every listed
value) through the config's own checks, so each draw is written without the per-world checks
(`env.set_params(validate=False)`). Draws come from `seeding.randomiser_stream(seed)` (a stream of its own,
apart from the config's draws of the same seed): the same seed, the same values for the same sequence of
episode ends. Finding the ended worlds costs one host sync per
step.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..per_world import FLAT_NAMES, INTEGER_FIELDS, Choice, Uniform
from ..seeding import randomiser_stream

if TYPE_CHECKING:  # (torch where the draws are applied: the config's checks parse the specs without it)
    import torch

FIELDS = tuple(n for n in FLAT_NAMES if n not in ("flow", "capture_rule"))


def _number(field: str, text: str, integer: bool):
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"--randomize {field}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"--randomize {field}: {text!r} is not a finite number")
    if integer:
        if value != int(value):
            raise ValueError(f"--randomize {field}: {text!r} is not an integer")
        return int(value)
    return value


def parse_spec(text: str) -> tuple[str, Uniform | Choice]:
    """`"field=low:high"` -> (field, Uniform(low, high)); `"field=a,b,c"` -> (field, Choice((a, b, c)))."""
    field, sep, spec = str(text).partition("=")
    field = field.strip()
    if not sep or not spec.strip():
        raise ValueError(f"--randomize {text!r}: expected FIELD=LOW:HIGH or FIELD=A,B,C")
    if field not in FIELDS:
        raise ValueError(f"--randomize {field}: unknown field; randomisable: {', '.join(FIELDS)}")
    integer = field in INTEGER_FIELDS
    if ":" in spec:
        low, _, high = spec.partition(":")
        low, high = _number(field, low.strip(), integer), _number(field, high.strip(), integer)
        if not low <= high:
            raise ValueError(f"--randomize {field}={spec}: needs low <= high")
        return field, Uniform(low, high)
    return field, Choice(tuple(_number(field, v.strip(), integer) for v in spec.split(",")))


class ParamRandomizer:
    """Draws `specs` ({field: "low:high" or "a,b,c"}, or a list of "field=..." strings) for the worlds of
    `env` at construction and whenever `update(episode_ended)` reports ended episodes."""

    def __init__(self, env, specs, seed: int = 0):
        items = specs.items() if isinstance(specs, dict) else [str(s).partition("=")[::2] for s in specs]
        self.env = env
        self.samplers = dict(parse_spec(f"{k}={v}") for k, v in items)
        for field, sampler in self.samplers.items():
            ends = sampler.values if isinstance(sampler, Choice) else (sampler.low, sampler.high)
            for value in ends:  # the config's checks hold at both ends, so in between (ranges are intervals)
                try:
                    env.set_params(**{field: value}, world=0, validate=True)
                except ValueError as error:
                    raise ValueError(f"--randomize {field}: {value!r} is not allowed: {error}") from None
        self.rng = randomiser_stream(seed)
        # Every world's current draw, kept for checkpoints (the env holds them only as kernel parameters).
        self.values = {
            field: np.zeros(env.num_worlds, dtype=np.int64 if field in INTEGER_FIELDS else np.float64)
            for field in self.samplers
        }
        self._draw(list(range(env.num_worlds)))

    def _draw(self, worlds: list[int]) -> None:
        values = {
            field: sampler.draw(self.rng, len(worlds), field in INTEGER_FIELDS)
            for field, sampler in self.samplers.items()
        }
        self.env.set_params(world=worlds, validate=False, **values)
        for field, drawn in values.items():
            self.values[field][worlds] = drawn

    def state_dict(self) -> dict:
        """The generator's state and every world's current values: a resumed run draws on exactly."""
        return {"rng": self.rng.bit_generator.state, "values": {f: v.copy() for f, v in self.values.items()}}

    def load_state_dict(self, state: dict) -> None:
        if set(state["values"]) != set(self.samplers):
            raise ValueError(f"the checkpoint randomises {sorted(state['values'])}, this run {sorted(self.samplers)}")
        self.rng.bit_generator.state = state["rng"]
        for field, values in state["values"].items():
            self.values[field][:] = values
        self.env.set_params(
            world=list(range(self.env.num_worlds)), validate=False, **{f: v.tolist() for f, v in self.values.items()}
        )

    def update(self, episode_ended: torch.Tensor) -> None:
        """New draws for the worlds whose episode ended (`[W]` bool, the env's `info["episode_ended"]`)."""
        worlds = episode_ended.nonzero().flatten().tolist()  # the host sync
        if worlds:
            self._draw(worlds)
