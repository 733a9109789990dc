"""Arguments: the argparse types, number lists and range checks of every command line and settings
dataclass (`aquarium-warp ...`, the studies, training, the benchmark suite and scripts). Errors name the
option or parameter and the allowed range in one line.

Comma lists of numbers with `...` progressions (`parse_list`):

    parse_list("4,8,16")                                  -> [4.0, 8.0, 16.0]
    parse_list("4,8,...,64", int)                         -> [4, 8, 16, 32, 64]
    parse_list("30,60,...,180")                           -> [30.0, 60.0, ..., 180.0]
    parse_list("16,64,...,1000000", int, last="cap")      -> [16, 64, ..., 262144, 1000000]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Literal

# What a policy option of each team takes (its help text): the heuristics (`drivers.HEURISTICS`), the
# shipped trained policies (`pretrained.names()`) and policy files; written out, so that `--help` imports
# neither (tests/app/test_cli.py checks them against both).
POLICY_SPECS = {
    "prey": "'turnaway', 'boids', 'random', 'constant' (heuristics), 'prey-a', 'prey-b', 'prey-c', 'prey-any' "
    "(shipped trained policies; 'learned': 'prey-any') or a policy file",
    "predator": "'naivchase', 'naivchase-noconfusion' (chases the nearest prey), 'naivchase-mixed' (either, "
    "by world), 'random', 'constant' (heuristics), 'predator-any' (shipped; 'learned': 'predator-any') or a "
    "policy file",
}

# The help of every `--device` option.
DEVICE_HELP = "'cpu', 'cuda:0'; default: CUDA when present"


# ---------------------------------------------------------------------------------------------- argparse types
class Interrupted(KeyboardInterrupt):
    """A signal that ended a command early: the message to print and the shell's exit code for it
    (128 + the signal's number)."""

    def __init__(self, message: str, signum: int):
        super().__init__(message)
        self.exit_code = 128 + signum

    def __reduce__(self):  # from a study's worker process to the main one
        return type(self), (str(self), self.exit_code - 128)


def plural(count: int, noun: str) -> str:
    """ "1 predator", "3 predators" (nouns with a plain -s plural)."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


def policy_spec(team: str) -> Callable[[str], str]:
    """argparse type of a `team` policy option: the spec, "learned" read as the team's general policy
    (`pretrained.for_team`); whether it exists is checked where the policy is loaded."""

    def parse(text: str) -> str:
        from .pretrained import for_team

        return for_team(text, team)

    return parse


def number(allowed: str, ok: Callable[[float], bool]) -> Callable[[str], float]:
    """argparse type: a float for which `ok(value)` holds (NaN never does); `allowed` names the range."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be {allowed}") from None
        if math.isnan(value) or not ok(value):
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be {allowed}")
        return value

    return parse


def int_at_least(low: int) -> Callable[[str], int]:
    """argparse type: an integer >= `low` (any size)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be an integer >= {low}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be an integer >= {low}")
        return value

    return parse


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)  # seeds: any size
positive_float = number("a finite number > 0", lambda v: 0 < v < math.inf)
non_negative_float = number("a finite number >= 0", lambda v: 0 <= v < math.inf)


# ---------------------------------------------------------------------------------------------- values
def check_int(name: str, value, low: int = 1) -> None:
    """A `ValueError` naming `name` unless `value` is an integer >= `low`."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{name}={value!r} must be an integer >= {low}")


def check_number(name: str, value, low: float, high: float = math.inf) -> None:
    """A `ValueError` naming `name` unless `value` is a finite number in [low, high]."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not (low <= value <= high)
        or not math.isfinite(value)
    ):
        raise ValueError(f"{name}={value!r} must be a finite number in [{low:g}, {high:g}]")


# ---------------------------------------------------------------------------------------------- number lists

# What the last term of a progression is: "exact", a term the progression must reach; "cap", a bound
# that ends the list whether or not the progression lands on it.
LastTerm = Literal["exact", "cap"]


def parse_list(
    text: str | Sequence[float],
    kind: type = float,
    name: str = "list",
    *,
    last: LastTerm = "exact",
    minimum: float | None = None,
) -> list:
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
    terms = [_term(p, kind, f"{name}={text!r} must be a comma-separated list of {what}") for p in parts if p != "..."]
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


def number_list(text, kind: type, name: str, low: float, high: float | None = None, *, low_open: bool = False) -> list:
    """`parse_list` of an option, each value checked against [low, high] (or (low, high] with
    `low_open`); the error names the option and the allowed range."""
    values = parse_list(text, kind, name)
    for v in values:
        if (v <= low if low_open else v < low) or (high is not None and v > high):
            allowed = f"{'(' if low_open else '['}{low:g}, {'inf)' if high is None else f'{high:g}]'}"
            raise ValueError(f"{name}={text!r}: {v!r} is out of range: every value must be in {allowed}")
    return values


# ---------------------------------------------------------------------------------------------- settings options
# A settings dataclass (a study's) declares each command-line option once, on its field:
#
#     worlds: int = field(default=1024, metadata=option("training worlds per run", type=positive_int))
#
# `add_options(parser, Settings)` adds `--worlds` (help "training worlds per run (default 1024)") and
# `from_options(Settings, args)` builds the settings from the parsed options.
def option(
    help: str,
    *,
    type: Callable[[str], object] | None = None,
    parse: Callable[[str, str], object] | None = None,
    flag: str | None = None,
    negated: bool = False,
    shown: str | None = None,
    choices: Sequence[str] | None = None,
    repeated: bool = False,
    nargs: str | None = None,
    metavar: str | None = None,
) -> dict:
    """The `field(metadata=...)` of a settings field that is a command-line option `flag` (default the
    field's name as `--a-name`): `type` converts and checks the option's text (an argparse type);
    `parse(text, flag)` reads a list option's text instead (its default written as text: the list's,
    else `shown`); a `negated` bool is `--no-<name>` (True unless given), another bool `--<name>` (False
    unless given); `choices` lists the values allowed; a `repeated` option is given once per value
    (`metavar` each), one with `nargs` takes several values at once (argparse's "*" or "+", each
    converted by `type`). The help ends with the default (`shown`, else the field's own; none for a bool,
    a repeated option, None or an empty list)."""
    return {
        "option": {
            "help": help,
            "type": type,
            "parse": parse,
            "flag": flag,
            "negated": negated,
            "shown": shown,
            "choices": choices,
            "repeated": repeated,
            "nargs": nargs,
            "metavar": metavar,
        }
    }


def list_text(values) -> str:
    """A list default as its option's text: `[100.0, 0.0]` -> "100,0" (a float that `:g` would round
    keeps every digit, so that the text reads back as the list)."""
    return ",".join(_number_text(v) if isinstance(v, float) else str(v) for v in values)


def _number_text(value: float) -> str:
    return f"{value:g}" if float(f"{value:g}") == value else repr(value)


def word_list(text: str, flag: str) -> list[str]:
    """A comma list of names ("uniform,vortex"), blanks dropped (the settings check the names)."""
    return [word.strip() for word in text.split(",") if word.strip()]


def choice_list(choices: Sequence[str]) -> Callable[[str, str], list[str]]:
    """`parse` of an option that lists names, each one of `choices` and none twice: a one-line
    `ValueError` naming the option and the choices otherwise."""

    def parse(text: str, flag: str) -> list[str]:
        names = word_list(text, flag)
        if not names or any(name not in choices for name in names):
            raise ValueError(f"{flag}={text!r}: choose from {', '.join(choices)}")
        check_distinct(flag, names)
        return names

    return parse


def _options(settings: type, only: Sequence[str] | None = None) -> list[tuple[dataclasses.Field, dict, str, str]]:
    """`(field, option, flag, dest)` of each field of the `settings` dataclass that is a command-line
    option (of the fields named in `only`, where given; `dest`: argparse's attribute of the flag)."""
    out = []
    for f in dataclasses.fields(settings):
        opt = f.metadata.get("option")
        if opt is not None and (only is None or f.name in only):
            flag = opt["flag"] or ("--no-" if opt["negated"] else "--") + f.name.replace("_", "-")
            out.append((f, opt, flag, flag[2:].replace("-", "_")))
    return out


def _default(f: dataclasses.Field):
    return f.default_factory() if f.default is dataclasses.MISSING else f.default  # type: ignore[operator]


def add_options(
    parser: argparse._ActionsContainer,  # a parser or one of its argument groups
    settings: type,
    only: Sequence[str] | None = None,
) -> None:
    """An option for each field of `settings` declared with `option(...)` (each named in `only`, where
    given), in field order."""
    for f, opt, flag, _ in _options(settings, only):
        default = _default(f)
        if isinstance(default, bool):
            parser.add_argument(flag, action="store_true", help=opt["help"])
            continue
        if opt["repeated"]:
            parser.add_argument(flag, action="append", default=list(default), metavar=opt["metavar"], help=opt["help"])
            continue
        text = list_text(default) if isinstance(default, list) else default
        shown = opt["shown"] or (f"{text:g}" if isinstance(text, float) else text)
        if opt["parse"] is not None and default is not None:
            default = text if isinstance(default, list) else shown  # the text that `parse` reads
        parser.add_argument(
            flag,
            type=opt["type"],
            choices=opt["choices"],
            nargs=opt["nargs"],
            default=default,
            metavar=opt["metavar"],
            help=opt["help"] if default is None or default == [] else f"{opt['help']} (default {shown})",
        )


def from_options(settings: type, args: argparse.Namespace, only: Sequence[str] | None = None, **given):
    """`settings(...)` from the options `add_options(..., only)` added (a list option's text parsed), with
    the fields in `given` (options added elsewhere: seeds, device, output)."""
    values = dict(given)
    for f, opt, flag, dest in _options(settings, only):
        value = getattr(args, dest)
        if opt["negated"]:
            value = not value
        elif opt["parse"] is not None and value is not None:
            value = opt["parse"](value, flag)
        values[f.name] = value
    return settings(**values)
