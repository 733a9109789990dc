"""Settings options written once (`arguments.option` on a dataclass field): the parser, its defaults
and help come from the field, and the parsed options give back the settings; each study built that
way takes its dataclass's defaults when no option is given."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import pytest

from aquarium_warp.arguments import (
    add_options,
    choice_list,
    from_options,
    list_text,
    number_list,
    option,
    positive_int,
    word_list,
)
from aquarium_warp.studies import common, flow, fov_view, group_hunting, many_eyes, phase, swarm, swarm_size


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


@dataclass
class Run:
    cells: list[str] = field(
        default_factory=lambda: ["a", "b"],
        metadata=option("cells", parse=choice_list(("a", "b", "c")), shown="a and b"),
    )
    part: str = field(default="all", metadata=option("part", choices=("one", "all")))
    sets: list[str] = field(default_factory=list, metadata=option("sets", repeated=True, metavar="K=V"))
    size: tuple[float, float] = field(
        default=(8.0, 6.0),
        metadata=option("size", parse=lambda text, flag: tuple(map(float, text.split("x"))), shown="8x6"),
    )


def test_choices_repeats_and_a_default_read_as_text():
    p = argparse.ArgumentParser()
    add_options(p, Run)
    helps = {a.option_strings[0]: a.help for a in p._actions if a.option_strings and a.dest != "help"}
    assert helps == {
        "--cells": "cells (default a and b)",
        "--part": "part (default all)",
        "--sets": "sets",
        "--size": "size (default 8x6)",
    }
    # The namespace holds a parsed option's default as the text `parse` reads: the list's, else `shown`.
    assert (p.parse_args([]).cells, p.parse_args([]).size) == ("a,b", "8x6")
    assert from_options(Run, p.parse_args([])) == Run()
    args = p.parse_args("--cells c,a --part one --sets x=1 --sets y=2 --size 3x4".split())
    assert from_options(Run, args) == Run(["c", "a"], "one", ["x=1", "y=2"], (3.0, 4.0))
    assert p.parse_args([]).sets == [] and Run().sets == []  # the default list is not appended to
    for text, message in (
        ("a,d", "--cells='a,d': choose from a, b, c"),
        ("", "--cells='': choose from"),
        ("a,a", "repeats 'a'"),
    ):
        with pytest.raises(ValueError, match=message):
            from_options(Run, p.parse_args(["--cells", text]))
    with pytest.raises(SystemExit):
        p.parse_args(["--part", "two"])


def test_only_the_named_options():
    p = argparse.ArgumentParser()
    add_options(p, Run, ("part", "sets"))
    assert [a.dest for a in p._actions if a.option_strings and a.dest != "help"] == ["part", "sets"]
    assert from_options(Run, p.parse_args(["--part", "one"]), ("part", "sets"), cells=["c"]) == Run(["c"], "one")


def test_a_list_default_reads_back_as_itself():
    assert list_text([100.0, 0.0, 4.5, 2]) == "100,0,4.5,2"
    values = [0.1234567891, 1e-7, 3.0]
    assert number_list(list_text(values), float, "x", 0.0) == values


@pytest.mark.parametrize("module, settings", [(swarm, swarm.SwarmStudy), (phase, phase.PhaseStudy)])
def test_the_task_studies_without_options_are_their_defaults(module, settings):
    p = argparse.ArgumentParser()
    module.add_arguments(p)
    assert module.check(p.parse_args([])) == settings()


def test_swarm_size_and_fov_view_without_options_are_their_defaults():
    p = argparse.ArgumentParser()
    swarm_size.add_arguments(p)
    args = p.parse_args([])
    assert from_options(swarm_size.SwarmSizeStudy, args, out=args.out) == swarm_size.SwarmSizeStudy()
    p = argparse.ArgumentParser()
    fov_view.add_arguments(p)
    study = from_options(fov_view.FovView, p.parse_args([])).study(p.parse_args([]))
    assert study == swarm_size.SwarmSizeStudy(
        prey=[32],
        fov_angles=[60.0, 120.0, 240.0, 360.0],
        view_distances=[50.0, 100.0, 200.0, 400.0],
        one_batch=True,
        kind="fov-view",
        out="fov_view",
    )


def test_eval_options_take_the_paper_protocol_and_the_grid_its_own():
    """`aquarium-warp eval` without options: the paper's 200 episodes x 5 seeds, random and TurnAway prey
    against NaivChase; --grid: 50 episodes x 3 seeds per cell over the grid's cells; --cross-play: the
    paper's protocol against three predators."""
    from aquarium_warp.cli import build_parser
    from aquarium_warp.training.cli import EVAL_RUNS, EvalOptions, GridCells

    def parse(*argv):
        args = build_parser().parse_args(["eval", *argv])
        return from_options(EvalOptions, args), from_options(GridCells, args)

    options, grid = parse()
    assert (options.kind, options.episodes_per_seed, options.evaluation_seeds) == ("eval", 200, [0, 1, 2, 3, 4])
    assert (options.prey, options.predator, options.sets, options.figures) == (None, None, [], True)
    assert EVAL_RUNS["eval"]["prey"] == ("random", "turnaway") and EVAL_RUNS["eval"]["predator"] == ("naivchase",)
    options, grid = parse("--grid")
    assert (options.kind, options.episodes_per_seed, options.evaluation_seeds) == ("grid", 50, [0, 1, 2])
    assert len(grid.cells()) == 4 * 3 * 3 * 3 and grid.grid_views == [100.0, 200.0, 10000.0]
    options, _ = parse("--cross-play", "--episodes", "3", "--seeds", "7", "8", "--set", "env.a=1", "--no-figures")
    assert (options.kind, options.episodes_per_seed, options.evaluation_seeds) == ("cross-play", 3, [7, 8])
    assert (options.sets, options.figures) == (["env.a=1"], False)
    assert EVAL_RUNS["cross-play"]["predator"] == ("naivchase", "naivchase-noconfusion", "random")
    with pytest.raises(ValueError, match=r"^--grid-fovs='90,\.\.\.': write at least two terms"):
        parse("--grid-fovs", "90,...")
