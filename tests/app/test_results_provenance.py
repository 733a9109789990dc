"""Every committed result JSON records its commit, command, device and versions (issue #29).

A result file gives each of the four either in its own keys, under one of the names the project's
writers use (listed below), or in a `provenance` object added from the repository's evidence
(`benchmarks/results/README.md` says how). A file whose provenance is genuinely unknown in part is
listed in INCOMPLETE with the fields it lacks and why, and the README's "Incomplete provenance" list
names the same files: a new result file without provenance fails here.

The writers' commit comes from `aquarium_warp.records.git_info`, checked here on temporary git checkouts:
read from git with the modified tracked files listed, a supplied commit taken only for a copy without git
and recorded as supplied.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

from aquarium_warp.records import git_info

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
INDEX = RESULTS / "README.md"
FIELDS = ("commit", "command", "device", "versions")

# Where the project's writers put each field (a key path into the JSON), besides `provenance`.
COMMIT_KEYS = (
    ("git_commit",),  # benchmarks/bench_step.py, bench_pettingzoo.py (before the `git` object)
    ("commit",),  # benchmarks/learned_prey.py, bench_viewer.py (before the `git` object)
    ("git", "commit"),  # aquarium_warp.records.git_info: every writer now
)
COMMAND_KEYS = (
    ("command",),  # bench suite, profile_step, bench_training, learned_prey, studies' run_record
    ("settings", "command"),  # benchmarks/coevolution.py (before its top-level `command`)
)
DEVICE_KEYS = (
    ("device_name",),  # bench_step, bench_training, benchmarl_mappo, bench_multi_gpu, coevolution
    ("machine", "device_name"),  # aquarium_warp.records.machine_info
    ("machine", "cpu_model"),  # benchmarks/original_aquarium.py and the first bench_pettingzoo.py (CPU only)
    ("machine", "cpu"),  # benchmarks/bench_viewer.py (CPU only; machine_info's CPU model has this name too)
    ("gpu",),  # benchmarks/bench_per_world.py (before `machine`)
)
# Versions: the `versions` mapping, machine_info's entries, or top-level keys (bench_step, bench_training).
VERSION_KEYS = ("python", "warp", "torch", "rsl_rl")
# A record of versions must name the simulator's: warp (`warp-lang` in `versions`), or, for a measurement
# of the original package alone, marl-aquarium.
SIMULATOR_VERSION = ("warp", "warp-lang", "marl-aquarium")

# Files whose provenance is genuinely unknown in part: {path under benchmarks/results: (fields, why)}.
# Each has a `provenance` object whose null fields say so; the README's "Incomplete provenance" lists them.
_NO_VERSIONS = "versions not recorded by the writer then, nor in the README or the adding commit"
INCOMPLETE: dict[str, tuple[tuple[str, ...], str]] = {
    "benchmarl_cpu/benchmarl_mappo_cpu.json": (("commit",), "the commit it ran at is not recorded anywhere"),
    "coevolution_h200/cross_play.json": (("versions",), _NO_VERSIONS),
    "coevolution_h200/summary.json": (("versions",), _NO_VERSIONS),
    "learned_prey_h200/config_A-long.json": (("versions",), _NO_VERSIONS),
    "learned_prey_h200/config_B-norm.json": (("versions",), _NO_VERSIONS),
    "learned_prey_h200/config_C-wide.json": (("versions",), _NO_VERSIONS),
    "learned_prey_h200/config_D-gamma.json": (("versions",), _NO_VERSIONS),
    "multi_gpu_h200x2/multi_gpu_both.json": (("versions",), "only torch's version recorded, not warp's"),
    "multi_gpu_h200x2/multi_gpu_prey.json": (("versions",), "only torch's version recorded, not warp's"),
    "one_batch_h200/fv_one_batch/fov_view.json": (("command",), "the README gives options in prose, not the command"),
    "one_batch_h200/fv_per_setting/fov_view.json": (("command",), "the README gives options in prose, not the command"),
    "one_batch_h200/ss_one_batch/swarm_size.json": (("command",), "the README gives options in prose, not the command"),
    "one_batch_h200/ss_per_setting/swarm_size.json": (
        ("command",),
        "the README gives options in prose, not the command",
    ),
    "original_cpu.json": (("commit", "command"), "benchmarks/original_aquarium.py recorded neither then"),
    "paper_h200_fast_loop/summary.json": (("versions",), _NO_VERSIONS),
    "per_world_h200/per_world_cuda0_h200.json": (("versions",), _NO_VERSIONS),
    "pettingzoo_cpu.json": (("command",), "benchmarks/bench_pettingzoo.py did not record it then"),
    "redesign_h200/step_new_r1.json": (
        ("command",),
        "round 1 did not run the README's command (its rows stop at 100,000 agents)",
    ),
    "redesign_h200/step_old_r1.json": (
        ("command",),
        "round 1 did not run the README's command (its rows stop at 100,000 agents)",
    ),
    "swarm_size/swarm_size.json": (("commit",), "the commit it ran at is not recorded anywhere"),
}


def _get(data: dict, path: tuple[str, ...]):
    for key in path:
        if not isinstance(data, dict) or key not in data:
            return None
        data = data[key]
    return data


def _known(value) -> bool:
    return value not in (None, "", "unknown", {}, [])


def _own_versions(data: dict) -> dict:
    versions = dict(data["versions"]) if isinstance(data.get("versions"), dict) else {}
    machine = data.get("machine") if isinstance(data.get("machine"), dict) else {}
    for key in VERSION_KEYS:
        for source in (machine, data):
            if key not in versions and isinstance(source.get(key), str):
                versions[key] = source[key]
    return versions


def recorded(data: dict) -> dict:
    """The file's commit, command, device and versions: `provenance` first, then its own keys."""
    prov = data.get("provenance") if isinstance(data.get("provenance"), dict) else {}
    found = {}
    for field, paths in (("commit", COMMIT_KEYS), ("command", COMMAND_KEYS), ("device", DEVICE_KEYS)):
        found[field] = (
            prov[field] if field in prov else next((v for v in (_get(data, p) for p in paths) if _known(v)), None)
        )
    found["versions"] = prov["versions"] if "versions" in prov else _own_versions(data)
    return found


def missing(data: dict) -> tuple[str, ...]:
    """The fields the file does not record (null, absent, or versions without the simulator's)."""
    found = recorded(data)
    lacking = [f for f in ("commit", "command", "device") if not (_known(found[f]) and isinstance(found[f], str))]
    versions = found["versions"]
    if not (
        isinstance(versions, dict)
        and any(_known(versions.get(k)) for k in SIMULATOR_VERSION)
        and all(_known(v) for v in versions.values())
    ):
        lacking.append("versions")
    return tuple(lacking)


def result_files() -> list[str]:
    return sorted(p.relative_to(RESULTS).as_posix() for p in RESULTS.rglob("*.json"))


def test_result_files_are_found():
    assert len(result_files()) >= 96


@pytest.mark.parametrize("name", result_files())
def test_result_records_commit_command_device_versions(name):
    data = json.loads((RESULTS / name).read_text(), parse_constant=_reject_constant)
    assert isinstance(data, dict), f"{name}: a result JSON is an object"
    prov = data.get("provenance")
    if prov is not None:
        assert set(prov) == {*FIELDS, "source"}, f"{name}: provenance keys {sorted(prov)}"
        assert isinstance(prov["source"], str) and prov["source"], f"{name}: provenance without its source"
    lacking = missing(data)
    expected = INCOMPLETE.get(name, ((), ""))[0]
    assert lacking == expected, (
        f"{name} lacks {lacking or 'nothing'} but INCOMPLETE says {expected or 'nothing'}: record commit, command, "
        "device and versions (or a `provenance` object; see benchmarks/results/README.md)"
    )
    if lacking:
        assert prov is not None, f"{name}: an incomplete file says so in a provenance object"
        assert "unknown" in prov["source"] or "not recorded" in prov["source"], f"{name}: source must say why"


def test_incomplete_list_names_existing_files():
    assert set(INCOMPLETE) <= set(result_files())


def test_readme_incomplete_list_matches_the_test():
    text = INDEX.read_text()
    section = text.split("## Incomplete provenance", 1)[1].split("\n## ", 1)[0]
    listed = set(re.findall(r"^- `([^`]+\.json)`", section, flags=re.M))
    assert listed == set(INCOMPLETE)


def test_readme_indexes_every_result_folder_and_top_level_file():
    text = INDEX.read_text()
    folders = {p.relative_to(RESULTS).as_posix() + "/" for p in RESULTS.iterdir() if p.is_dir()}
    files = {p.name for p in RESULTS.iterdir() if p.is_file() and p.name != "README.md"}
    absent = sorted(name for name in folders | files if f"`{name}" not in text)
    assert not absent, f"benchmarks/results/README.md does not mention {absent}"


def test_provenance_rules_on_examples():
    full = {"git": {"commit": "abc"}, "command": "x", "machine": {"device_name": "CPU", "warp": "1.19.0"}}
    assert missing(full) == ()
    assert missing({"command": "x"}) == ("commit", "device", "versions")
    assert missing({**full, "git": {"commit": "unknown"}}) == ("commit",)
    assert missing(
        {
            **full,
            "provenance": {
                "commit": None,
                "command": "x",
                "device": "CPU",
                "versions": {"warp": "1.19.0"},
                "source": "unknown",
            },
        }
    ) == ("commit",)
    assert missing({**full, "machine": {"device_name": "CPU", "torch": "2"}}) == ("versions",)


def _git(repo: Path, *args: str) -> str:
    command = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "init.defaultBranch=main", *args]
    return subprocess.run(command, cwd=repo, check=True, capture_output=True, text=True).stdout


@pytest.fixture
def checkout(tmp_path, monkeypatch):
    """A temporary git checkout of two committed files, `a.txt` and `pkg/b.txt`."""
    monkeypatch.delenv("AQUARIUM_WARP_COMMIT", raising=False)
    repo = tmp_path / "repo"
    (repo / "pkg").mkdir(parents=True)
    (repo / "a.txt").write_text("a\n")
    (repo / "pkg" / "b.txt").write_text("b\n")
    _git(repo, "init", "-q")
    _git(repo, "add", "a.txt", "pkg/b.txt")
    _git(repo, "commit", "-q", "-m", "first")
    return repo


def test_a_clean_checkout_is_read_from_git(checkout):
    head = _git(checkout, "rev-parse", "HEAD").strip()
    expected = {"commit": head, "dirty": False, "modified": [], "source": "git"}
    assert git_info(repository=checkout / "pkg") == expected
    (checkout / "new.txt").write_text("untracked\n")  # an untracked file (a result being written) is no change
    assert git_info(repository=checkout) == expected


def test_a_dirty_checkout_records_its_modified_tracked_files(checkout):
    head = _git(checkout, "rev-parse", "HEAD").strip()
    (checkout / "pkg" / "b.txt").write_text("changed\n")
    (checkout / "a.txt").unlink()
    assert git_info(repository=checkout / "pkg") == {
        "commit": head,
        "dirty": True,
        "modified": ["a.txt", "pkg/b.txt"],  # the whole checkout's, named from its root
        "source": "git",
    }
    _git(checkout, "checkout", "--", "a.txt", "pkg/b.txt")
    _git(checkout, "commit", "-q", "--allow-empty", "-m", "second")
    assert git_info(repository=checkout)["commit"] == _git(checkout, "rev-parse", "HEAD").strip() != head


def test_a_supplied_commit_does_not_override_the_checkout(checkout, monkeypatch):
    head = _git(checkout, "rev-parse", "HEAD").strip()
    assert git_info(head[:7], repository=checkout) == {"commit": head, "dirty": False, "modified": [], "source": "git"}
    assert git_info("abc1234", repository=checkout)["supplied"] == "abc1234"  # git's commit is kept, the claim shown
    monkeypatch.setenv("AQUARIUM_WARP_COMMIT", "def5678")
    assert git_info(repository=checkout) == {
        "commit": head,
        "dirty": False,
        "modified": [],
        "source": "git",
        "supplied": "def5678",
    }


def test_a_copy_without_git_records_that_its_commit_was_supplied(tmp_path, checkout, monkeypatch):
    staged = tmp_path / "staged"  # outside any repository
    staged.mkdir()
    unknown = {"dirty": None, "modified": None}
    assert git_info("abc1234", repository=staged) == {"commit": "abc1234", **unknown, "source": "argument"}
    monkeypatch.setenv("AQUARIUM_WARP_COMMIT", "def5678")
    assert git_info(repository=staged) == {"commit": "def5678", **unknown, "source": "environment"}
    assert git_info("abc1234", repository=staged)["commit"] == "abc1234"  # an explicit commit wins
    monkeypatch.delenv("AQUARIUM_WARP_COMMIT")
    assert git_info(repository=staged) == {"commit": "unknown", **unknown, "source": "no git"}
    # A folder inside a checkout that git does not track (an installed or copied package) is no checkout.
    (checkout / "site").mkdir()
    assert git_info("abc1234", repository=checkout / "site")["source"] == "argument"


def test_this_package_is_read_from_its_checkout(monkeypatch):
    monkeypatch.delenv("AQUARIUM_WARP_COMMIT", raising=False)
    info = git_info()
    assert info["source"] in ("git", "no git")  # no git: an installed copy
    if info["source"] == "git":
        assert len(info["commit"]) == 40 and info["dirty"] == bool(info["modified"])


def _reject_constant(name: str):
    raise ValueError(f"not strict JSON: {name}")
