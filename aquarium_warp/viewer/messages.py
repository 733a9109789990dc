"""The messages a viewer page may send, checked before anything acts on them.

A message is a JSON object with a `type` and that type's fields, nothing else:

    {"type": "play"} {"type": "pause"} {"type": "step"} {"type": "reset"}
    {"type": "speed", "value": 0.1..16}                      simulation steps per displayed frame
    {"type": "world", "index": 0..worlds-1}
    {"type": "overlays", "view_cones": b, "hit_boxes": b, "velocities": b, "flow": b}
    {"type": "view", "rect": [x0, y0, x1, y1]}               the part of the world the page shows (px)
    {"type": "policy", "team": "prey"|"predator", "spec": "..."}
    {"type": "human", "team": "prey"|"predator"|null}
    {"type": "keys", "dx": -1|0|1, "dy": -1|0|1}              the held arrow keys (screen axes)
    {"type": "record", "on": b}
    {"type": "inspect", "slot": 0..capacity-1 | null}         the agent whose observation the page shows
    {"type": "move", "slot": 0..capacity-1, "x": px, "y": px} put a live agent there (the page's drag)

`parse_message` returns the checked dict or raises `MessageError` naming what is wrong; the server
answers that with an error message and keeps going. Policy specs are checked against the allowed
policies by the simulation (`Simulation.allowed_spec`), which knows them; a move's position and the
slot's life by the env's state API (`env.set_state`).
"""

from __future__ import annotations

import json
import math

from ..agent_types import TYPES

MAX_MESSAGE_CHARS = 8192
MAX_SPEC_CHARS = 1024
SPEED_RANGE = (0.1, 16.0)
OVERLAYS = ("view_cones", "hit_boxes", "velocities", "flow")


class MessageError(ValueError):
    """A page's message that the viewer refuses (the text says why)."""


def _boolean(message: dict, name: str) -> bool:
    value = message[name]
    if not isinstance(value, bool):
        raise MessageError(f"{name}={value!r} must be true or false")
    return value


def _number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MessageError(f"{name}={value!r} must be a finite number")
    return float(value)


def _unit_step(value, name: str) -> int:
    if isinstance(value, bool) or value not in (-1, 0, 1) or not isinstance(value, int):
        raise MessageError(f"{name}={value!r} must be -1, 0 or 1")
    return int(value)


# type -> the fields it must have (and may have: no others)
FIELDS: dict[str, tuple[str, ...]] = {
    "play": (),
    "pause": (),
    "step": (),
    "reset": (),
    "speed": ("value",),
    "world": ("index",),
    "overlays": OVERLAYS,
    "view": ("rect",),
    "policy": ("team", "spec"),
    "human": ("team",),
    "keys": ("dx", "dy"),
    "record": ("on",),
    "inspect": ("slot",),
    "move": ("slot", "x", "y"),
}


def _slot(value, capacity: int, allow_none: bool = False):
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < capacity:
        raise MessageError(f"slot={value!r} must be an integer in [0, {capacity - 1}]")
    return value


def parse_message(text, num_worlds: int, capacity: int) -> dict:
    """The checked message of the page's text `text` (see the module's list) for an env of `num_worlds`
    worlds of `capacity` agent slots each; `MessageError` otherwise."""
    if not isinstance(text, str):
        raise MessageError("messages must be JSON text, not binary")
    if len(text) > MAX_MESSAGE_CHARS:
        raise MessageError(f"message of {len(text)} characters: at most {MAX_MESSAGE_CHARS}")
    try:
        message = json.loads(text)
    except ValueError as error:  # json's errors (and RecursionError's parent) are ValueErrors
        raise MessageError(f"message is not JSON: {error}") from None
    if not isinstance(message, dict):
        raise MessageError("message must be a JSON object with a 'type'")
    kind = message.get("type")
    if not isinstance(kind, str) or kind not in FIELDS:
        raise MessageError(f"type={kind!r} must be one of {sorted(FIELDS)}")
    fields = FIELDS[kind]
    given = set(message) - {"type"}
    if given != set(fields):
        missing, extra = sorted(set(fields) - given), sorted(given - set(fields))
        raise MessageError(f"{kind} message: missing fields {missing}, unknown fields {extra}")
    out: dict = {"type": kind}
    if kind == "speed":
        value = _number(message["value"], "speed")
        if not SPEED_RANGE[0] <= value <= SPEED_RANGE[1]:
            raise MessageError(f"speed={value!r} must be in [{SPEED_RANGE[0]}, {SPEED_RANGE[1]}]")
        out["value"] = value
    elif kind == "world":
        index = message["index"]
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < num_worlds:
            raise MessageError(f"world index={index!r} must be an integer in [0, {num_worlds - 1}]")
        out["index"] = index
    elif kind == "overlays":
        out.update({name: _boolean(message, name) for name in OVERLAYS})
    elif kind == "view":
        rect = message["rect"]
        if not isinstance(rect, list) or len(rect) != 4:
            raise MessageError(f"rect={rect!r} must be a list [x0, y0, x1, y1]")
        x0, y0, x1, y1 = (_number(v, "rect") for v in rect)
        if not (x0 < x1 and y0 < y1):
            raise MessageError(f"rect={rect!r} must have x0 < x1 and y0 < y1")
        out["rect"] = (x0, y0, x1, y1)
    elif kind == "policy":
        out["team"] = _team(message["team"], allow_none=False)
        spec = message["spec"]
        if not isinstance(spec, str) or not spec.strip() or len(spec) > MAX_SPEC_CHARS or "\x00" in spec:
            raise MessageError(f"policy spec must be a non-empty string of at most {MAX_SPEC_CHARS} characters")
        out["spec"] = spec.strip()
    elif kind == "human":
        out["team"] = _team(message["team"], allow_none=True)
    elif kind == "keys":
        out["dx"], out["dy"] = _unit_step(message["dx"], "dx"), _unit_step(message["dy"], "dy")
    elif kind == "record":
        out["on"] = _boolean(message, "on")
    elif kind == "inspect":
        out["slot"] = _slot(message["slot"], capacity, allow_none=True)
    elif kind == "move":
        out["slot"] = _slot(message["slot"], capacity)
        out["x"], out["y"] = _number(message["x"], "x"), _number(message["y"], "y")
    return out


def _team(value, allow_none: bool):
    if value is None and allow_none:
        return None
    if value not in TYPES:
        raise MessageError(f"team={value!r} must be one of {list(TYPES) + ([None] if allow_none else [])}")
    return value
