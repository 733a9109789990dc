"""Comma lists of numbers with `...` progressions: the one parser of every list option
(`aquarium-warp bench --agents`, `aquarium-warp study swarm-size --prey`, the benchmark scripts).

    parse_list("4,8,16")                                  -> [4.0, 8.0, 16.0]
    parse_list("4,8,...,64", int)                         -> [4, 8, 16, 32, 64]
    parse_list("30,60,...,180")                           -> [30.0, 60.0, ..., 180.0]
    parse_list("16,64,...,1000000", int, last="cap")      -> [16, 64, ..., 262144, 1000000]
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal

# What the last term of a progression is: "exact", a term the progression must reach; "cap", a bound
# that ends the list whether or not the progression lands on it.
LastTerm = Literal["exact", "cap"]


def parse_list(text: str | Sequence[float], kind: type = float, name: str = "list", *,
               last: LastTerm = "exact", minimum: float | None = None) -> list:
    """The numbers of `text` ("4,8,16", spaces allowed), each converted by `kind` (int or float).

    An ellipsis continues the progression of the terms before it (at least two, in increasing
    order): geometric when they have a constant ratio above 1, else arithmetic with a constant step.
    With `last="exact"` the progression must reach the last term ("4,8,...,4096" doubles,
    "30,60,...,180" adds 30; "4,8,...,99" is an error), and the ratio gives way to the step when only
    the step reaches it ("2,4,...,10" adds 2). With `last="cap"` the progression runs while it stays
    below the last term, which always ends the list ("16,64,...,1000000" ends 262144, 1000000).
    A sequence of numbers is checked like parsed terms. `minimum`: the smallest value allowed.
    Every error is a ValueError that names `name` and the text.
    """
    what = "integers" if kind is int else "numbers"
    if isinstance(text, (list, tuple)):
        values = [_term(x, kind, f"{name}={text!r} must be a list of {what}") for x in text]
    else:
        values = _parse_text(str(text), kind, name, last, what)
    if minimum is not None and any(v < minimum for v in values):
        raise ValueError(f"{name}={text!r}: every value must be >= {minimum}")
    return values


def _parse_text(text: str, kind: type, name: str, last: LastTerm, what: str) -> list:
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise ValueError(f"{name}={text!r} is empty")
    terms = [_term(p, kind, f"{name}={text!r} must be a comma-separated list of {what}")
             for p in parts if p != "..."]
    if "..." not in parts:
        return terms
    at = parts.index("...")
    if parts.count("...") != 1 or at < 2 or at != len(parts) - 2:
        raise ValueError(f"{name}={text!r}: write at least two terms, '...', then the last term")
    head, end = terms[:-1], terms[-1]
    if any(b <= a for a, b in zip(head, head[1:] + [end])):
        raise ValueError(f"{name}={text!r}: the terms must increase up to the last one")
    for advance in _progressions(head, kind):  # the ratio first: "4,8,...,4096" doubles
        values = list(head)
        while advance(values[-1]) < end and not math.isclose(advance(values[-1]), end):
            values.append(advance(values[-1]))
        if last == "cap":
            return values + [end]
        if math.isclose(advance(values[-1]), end):
            return values + [end]
    reach = f" that reaches {parts[-1]}" if last == "exact" else ""
    raise ValueError(f"{name}={text!r}: the terms before '...' must grow by a constant ratio or step{reach}")


def _progressions(head: list, kind: type) -> list[Callable[[float], float]]:
    """The rules that continue `head`: its constant ratio (above 1), then its constant step."""
    as_kind: Callable[[float], float] = round if kind is int else float
    rules = []
    ratios = [b / a for a, b in zip(head, head[1:])] if head[0] > 0 else []
    if ratios and ratios[0] > 1 and all(math.isclose(r, ratios[0]) for r in ratios):
        rules.append(lambda v: as_kind(v * ratios[0]))
    steps = [b - a for a, b in zip(head, head[1:])]
    if all(math.isclose(d, steps[0]) for d in steps):
        rules.append(lambda v: as_kind(v + steps[0]))
    return rules


def _term(value: object, kind: type, error: str) -> float:
    """One term as `kind`; an integer list refuses fractions ("2.5", 2.5) rather than truncating them."""
    if isinstance(value, bool):
        raise ValueError(error)
    try:
        number = kind(value) if isinstance(value, str) else float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        raise ValueError(error) from None
    if isinstance(number, float) and not math.isfinite(number) or kind is int and number != int(number):
        raise ValueError(error)
    return kind(number)


def check_distinct(name: str, values) -> None:
    """A `ValueError` naming `name` where `values` repeats one: a repeated setting would run twice under
    one name and pool its seeds with its twin's."""
    repeated = sorted({v for v in values if list(values).count(v) > 1}, key=str)
    if repeated:
        raise ValueError(f"{name}={list(values)!r} repeats {', '.join(map(repr, repeated))}: list each value once")
