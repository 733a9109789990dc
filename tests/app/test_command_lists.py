"""The command lists that README.md and docs/getting-started.md give name every subcommand of
`aquarium-warp` and every study of `aquarium-warp study`, as `build_parser()` defines them."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from aquarium_warp.cli import build_parser

REPO = Path(__file__).resolve().parents[2]


def _choices(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def _listed(path: str, start: str) -> set[str]:
    """The `names` in backticks of the paragraph text from `start` to the next closing parenthesis."""
    text = " ".join((REPO / path).read_text(encoding="utf-8").split())
    at = text.index(start)
    return set(re.findall(r"`([a-z-]+)`", text[at : text.index(")", at)]))


def test_the_readme_names_every_subcommand():
    assert _listed("README.md", "lists the commands (") == set(_choices(build_parser()))


def test_getting_started_names_every_subcommand_and_every_study():
    commands = _choices(build_parser())
    studies = _choices(commands["study"])
    assert _listed("docs/getting-started.md", "lists the commands (") == set(commands) | set(studies)
