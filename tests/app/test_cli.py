"""The command line a new user meets: --version, `python -m aquarium_warp`, a help text for every option
of every subcommand, no CUDA warning unless CUDA was asked for, `bench` writing to the current directory
and measuring the original only when asked, and a clear error for a logger whose package is missing."""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from aquarium_warp.cli import build_parser, main

REPO = Path(__file__).resolve().parents[2]


def run(*args, cwd=None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "CUDA_VISIBLE_DEVICES"}
    return subprocess.run(
        [sys.executable, "-m", "aquarium_warp", *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=300
    )


def subparsers(parser: argparse.ArgumentParser, path=("aquarium-warp",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from subparsers(child, path + (name,))


def test_every_option_of_every_subcommand_has_help():
    found = {" ".join(path): p for path, p in subparsers(build_parser())}
    # every subcommand is reached, nested ones included
    assert {
        "aquarium-warp demo",
        "aquarium-warp video",
        "aquarium-warp train",
        "aquarium-warp eval",
        "aquarium-warp study swarm-size",
        "aquarium-warp bench",
    } <= set(found)
    missing = [
        f"{name} {'/'.join(a.option_strings) or a.dest}"
        for name, p in found.items()
        for a in p._actions
        if not isinstance(a, argparse._SubParsersAction) and not (a.help or "").strip()
    ]
    assert not missing, f"options without a help text: {missing}"


def test_the_policy_options_name_every_heuristic_and_shipped_policy():
    """Issue 49: `--help` named neither the shipped policies nor the constant and boids heuristics."""
    from aquarium_warp import pretrained
    from aquarium_warp.drivers import HEURISTICS

    names = {team: [*HEURISTICS[team], *pretrained.names(team)] for team in ("prey", "predator")}
    found = {" ".join(path): p for path, p in subparsers(build_parser())}
    options = [
        (command, option, team)
        for command in ("video", "view", "study flow", "study swarm-size")
        for option, team in (("--prey-policy", "prey"), ("--predator-policy", "predator"))
    ]
    options += [("eval", "--prey", "prey"), ("eval", "--predator", "predator")]
    options += [("train", "--prey-policy", "prey"), ("train", "--predator-policy", "predator")]
    for command, option, team in options:
        action = next(a for a in found[f"aquarium-warp {command}"]._actions if option in a.option_strings)
        missing = [name for name in names[team] if f"'{name}'" not in action.help]
        assert not missing, f"{command} {option}: {missing} not in {action.help!r}"


def test_version_matches_the_installed_distribution(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"aquarium-warp {importlib.metadata.version('aquarium-warp')}"


@pytest.mark.slow
def test_python_m_runs_the_command_line_quietly_on_the_cpu():
    """`python -m aquarium_warp` is the CLI; on the CPU nothing is printed to stderr (the Warp
    no-driver warning included, also when the device is left to the default)."""
    result = run("demo", "--worlds", "2", "--steps", "3", "--device", "cpu")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("aquarium-warp demo: 2 worlds x 17 agents on cpu")
    assert result.stderr == ""
    result = run("demo", "--worlds", "2", "--steps", "3")
    assert result.returncode == 0 and result.stderr == ""
    result = run("--help")
    assert result.returncode == 0 and result.stdout.startswith("usage: aquarium-warp")


@pytest.mark.slow
def test_asking_for_cuda_without_a_driver_says_why():
    probe = subprocess.run(
        [
            sys.executable,
            "-c",
            "import warp as wp; wp.config.log_level = wp.LOG_WARNING; wp.init(); print(wp.is_cuda_available())",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if probe.stdout.strip() != "False" or "NVIDIA CUDA driver" not in probe.stderr:
        pytest.skip("this machine has a CUDA driver")
    result = run("demo", "--worlds", "2", "--steps", "3", "--device", "cuda:0")
    assert result.returncode == 2
    assert "device='cuda:0' is not available" in result.stderr and "NVIDIA CUDA driver" in result.stderr


@pytest.mark.slow
def test_bench_writes_to_the_current_directory_without_the_original(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert (
        main(
            [
                "bench",
                "--device",
                "cpu",
                "--agents",
                "16",
                "--worlds",
                "1",
                "--seconds",
                "0.01",
                "--repeats",
                "1",
                "--warmup-steps",
                "1",
                "--no-plots",
                "--no-heuristics",
                "--no-stages",
                "--copy-mib",
                "4",
                "--git-commit",
                "abc123",
                "--quiet",
            ]
        )
        == 0
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scaling_cpu.json"]
    original = json.loads((tmp_path / "scaling_cpu.json").read_text())["peers"]["original"]
    assert original["status"] == "skipped" and "--original" in original["note"]


def test_bench_measures_the_original_only_when_asked():
    from aquarium_warp.bench import add_arguments, settings_from_args

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert settings_from_args(parser.parse_args([])).original is False
    assert settings_from_args(parser.parse_args([])).out_dir == "."
    assert settings_from_args(parser.parse_args(["--original"])).original is True
    assert settings_from_args(parser.parse_args(["--no-original"])).original is False


def test_wandb_logger_without_wandb_names_the_extra(tmp_path, capsys):
    pytest.importorskip("rsl_rl", reason="needs the training extra")
    if importlib.util.find_spec("wandb") is not None:
        pytest.skip("wandb is installed")
    code = main(
        [
            "train",
            "--device",
            "cpu",
            "--num-worlds",
            "2",
            "--iterations",
            "1",
            "--num-steps-per-env",
            "2",
            "--set",
            "runner.logger=wandb",
            "--log-dir",
            str(tmp_path / "run"),
        ]
    )
    assert code == 2
    assert "pip install 'aquarium-warp[wandb]'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before the run started
