"""Settings options written once (`arguments.option` on a dataclass field): the parser, its defaults
and help come from the field, and the parsed options give back the settings; each study built that
way takes its dataclass's defaults when no option is given."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import pytest

from aquarium_warp.arguments import add_options, from_options, number_list, option, positive_int, word_list
from aquarium_warp.studies import common, flow, group_hunting, many_eyes


@dataclass
class Settings:
    worlds: int = field(default=64, metadata=option("worlds at once", type=positive_int))
    radii: list[float] = field(
        default_factory=lambda: [100.0, 0.5],
        metadata=option(
            "radii, px (list)", parse=lambda text, flag: number_list(text, float, flag, 0.0, 1e3), flag="--radius"
        ),
    )
    kinds: list[str] = field(default_factory=lambda: ["a", "b"], metadata=option("kinds", parse=word_list))
    baseline: bool = field(default=True, metadata=option("no baseline", negated=True))
    recipe: bool = field(default=False, metadata=option("the recipe"))
    speed: float | None = field(default=None, metadata=option("speed (default the model's)", type=float))
    out: str = "here"  # no option: given to from_options


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    add_options(p, Settings)
    return p


def test_the_options_help_and_defaults_come_from_the_fields():
    helps = {a.option_strings[0]: a.help for a in parser()._actions if a.option_strings and a.dest != "help"}
    assert helps == {
        "--worlds": "worlds at once (default 64)",
        "--radius": "radii, px (list) (default 100,0.5)",
        "--kinds": "kinds (default a,b)",
        "--no-baseline": "no baseline",
        "--recipe": "the recipe",
        "--speed": "speed (default the model's)",
    }
    assert from_options(Settings, parser().parse_args([]), out="here") == Settings()


def test_the_parsed_options_give_the_settings():
    args = parser().parse_args("--worlds 3 --radius 0,7.5 --kinds c --no-baseline --recipe --speed 2".split())
    assert from_options(Settings, args, out="x") == Settings(3, [0.0, 7.5], ["c"], False, True, 2.0, "x")
    with pytest.raises(
        ValueError, match=r"--radius='1,2000': 2000.0 is out of range: every value must be in \[0, 1000\]"
    ):
        from_options(Settings, parser().parse_args(["--radius", "1,2000"]), out="x")


@pytest.mark.parametrize(
    "module, settings, jobs",
    [
        (group_hunting, group_hunting.GroupHuntingStudy, True),
        (many_eyes, many_eyes.ManyEyesStudy, True),
        (flow, flow.FlowStudy, False),
    ],
)
def test_a_study_without_options_runs_with_its_defaults(module, settings, jobs):
    p = argparse.ArgumentParser()
    module.add_arguments(p)
    args = p.parse_args([])
    assert from_options(settings, args, **common.common_settings(args, jobs=jobs)) == settings()
