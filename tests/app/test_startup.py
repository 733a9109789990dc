"""Start-up: `aquarium-warp --help` and the light subcommands' help import neither torch nor Warp, `import
aquarium_warp` neither (its public names resolve on first use), the study and bench options are added
when used, `train --verbose` prints the start-up's stages, and the start-up benchmark times whole
commands of a staged tree."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from aquarium_warp.cli import build_parser

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "warp", "rsl_rl", "tensordict", "matplotlib", "tensorboard", "ray")


def imported_after(code: str) -> list[str]:
    """The heavy modules a fresh interpreter holds after running `code`."""
    probe = f"{code}\nimport sys\nprint(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1].replace("'", '"'))


@pytest.mark.parametrize(
    "command",
    [
        "",
        "train",
        "eval",
        "demo",
        "video",
        "view",
        "sweep train",
        "study",
        "study phase",
        "study swarm",
        "study swarm-size",
        "study fov-view",
        "study flow",
        "study group-hunting",
        "study many-eyes",
        "study coevolution",
        "study learned-prey",
        "bench",
    ],
)
def test_help_imports_neither_torch_nor_warp(command):
    argv = [*command.split(), "--help"]
    code = "\n".join(
        [
            "import contextlib, io",
            "from aquarium_warp.cli import main",
            "try:",
            "    with contextlib.redirect_stdout(io.StringIO()):",
            f"        main({argv!r})",
            "except SystemExit:",
            "    pass",
        ]
    )
    assert imported_after(code) == []


def test_importing_the_package_is_light_and_its_names_resolve():
    assert imported_after("import aquarium_warp") == []
    code = (
        "import aquarium_warp\n"
        "from aquarium_warp.config import AquariumConfig\n"
        "from aquarium_warp.env import BatchedAquarium\n"
        "assert aquarium_warp.AquariumConfig is AquariumConfig and aquarium_warp.BatchedAquarium is BatchedAquarium\n"
        "from aquarium_warp import AgentTypeConfig, aquarium_v1\n"
        "assert aquarium_v1.__name__ == 'aquarium_warp.aquarium_v1'"
    )
    assert "torch" in imported_after(code)
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        import aquarium_warp

        aquarium_warp.nothing_here  # noqa: B018


def test_deferred_subcommands_take_the_same_options():
    """The command line's parser adds the study and bench options when used: the same parser as built whole."""
    whole, deferred = build_parser(), build_parser(deferred=True)
    for argv in (["study", "swarm-size", "--seeds", "2"], ["bench", "--device", "cpu", "--repeats", "2"]):
        a, b = vars(whole.parse_args(argv)), vars(deferred.parse_args(argv))
        assert a.keys() == b.keys() and all(a[k] == b[k] for k in a if k != "run")
    commands = next(a.choices for a in build_parser(deferred=True)._actions if hasattr(a, "choices") and a.choices)
    assert "swarm-size" in commands["study"].format_help()


def test_train_verbose_prints_the_start_up_stages(tmp_path, capsys, one_thread):
    from aquarium_warp.cli import main

    assert main(["train", "--preset", "tiny", "--num-worlds", "2", "--iterations", "2", "--export", "none", "--quiet",
                 "--device", "cpu", "--log-dir", str(tmp_path / "run"), "--verbose"]) == 0  # fmt: skip
    last = capsys.readouterr().out.strip().splitlines()[-1]
    number = r"\d+\.\d\d s"
    stages = ["imports", "config", r"env build \(Warp modules loaded\)", "opponent, adapters, policy and runner",
              "first iteration"]  # fmt: skip
    pattern = (
        rf"aquarium-warp train: start-up ({number}) to the first iteration's end "
        rf"\({', '.join(f'{s} ({number})' for s in stages)}\); the whole run ({number})"
    )
    match = re.fullmatch(pattern, last)
    assert match, last
    seconds = [float(g[:-2]) for g in match.groups()]
    total, parts, whole = seconds[0], seconds[1:-1], seconds[-1]
    assert total == pytest.approx(sum(parts), abs=0.03) and whole >= total - 0.01


def test_start_up_benchmark_times_a_staged_tree(tmp_path):
    from aquarium_warp.bench import startup

    out = tmp_path / "out"
    argv = ["--commands", "help,import", "--repeats", "1", "--tree", str(REPO), "--out-dir", str(out)]
    assert startup.main(argv) == 0
    record = json.loads((out / "startup_cpu.json").read_text())
    assert {"command", "git", "machine"} <= record.keys() and "--tree" in record["command"]
    assert record["trees"] == [{"label": "tree0", "path": str(REPO), "git": record["trees"][0]["git"]}]
    rows = {(r["command"], r["cache"], r["tree"]): r["seconds"] for r in record["rows"]}
    assert set(rows) == {(c, k, "tree0") for c in ("help", "import") for k in ("cold", "warm")}
    assert all(len(s) == 1 and 0 < s[0] < 60 for s in rows.values())


def test_a_copy_without_git_is_recorded_at_the_commit_given(tmp_path, capsys):
    from aquarium_warp.bench import startup

    copy = tmp_path / "copy"  # a tree outside any git checkout, as staged on a lent GPU machine
    copy.mkdir()
    for name in ("aquarium_warp", "kernels", "training"):
        (copy / name).symlink_to(REPO / name, target_is_directory=True)
    out = tmp_path / "out"
    argv = ["--commands", "import", "--caches", "warm", "--repeats", "1", "--tree", str(copy), "--out-dir", str(out)]
    assert startup.main([*argv, "--tree-commit", "abc1234"]) == 0
    git = json.loads((out / "startup_cpu.json").read_text())["trees"][0]["git"]
    assert git == {"commit": "abc1234", "dirty": None, "modified": None, "source": "argument"}
    with pytest.raises(SystemExit):
        startup.main([*argv, "--tree-commit", "abc1234", "--tree-commit", "def5678"])
    assert "--tree-commit: 2 given, one per --tree needed (1)" in capsys.readouterr().err


def test_every_timed_run_is_kept_as_it_is_measured(tmp_path):
    """A time limit that stops the benchmark keeps the runs measured so far: the rows go out after each."""
    from aquarium_warp.bench import startup

    tree = startup.Tree("tree0", REPO, tmp_path)
    seen: list[list[dict]] = []
    rows = startup.measure(["import"], [tree], "cpu", 2, tmp_path, 300, ["warm"], lambda line: None, seen.append)
    assert [len(r[0]["seconds"]) for r in seen] == [1, 2] and seen[-1] == rows


def test_a_staged_tree_imports_its_own_code(tmp_path):
    from aquarium_warp.bench.startup import stage_tree

    path = stage_tree(REPO, tmp_path / "stage")
    code = "import aquarium_warp.training.config as c, aquarium_warp.kernels.grid as g; print(c.__file__, g.__file__)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(path), "PATH": "/usr/bin:/bin"}, cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    config, grid = done.stdout.split()
    assert config == str(path / "aquarium_warp" / "training" / "config.py")
    assert Path(grid).resolve() == REPO / "kernels" / "grid.py"
    with pytest.raises(
        ValueError, match=r"^--tree .*: not a source tree of aquarium-warp \(no aquarium_warp/__init__.py"
    ):
        stage_tree(tmp_path, tmp_path / "stage2")
