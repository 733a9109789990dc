"""Start-up: the wall time of whole commands, each a fresh process, from a cold kernel cache and a warm one.

Commands (`COMMANDS`, `--commands` picks):

- `help`: `aquarium-warp --help` (run as `python -m aquarium_warp --help`: the script's imports);
- `import-torch-warp`: `python -c "import torch, warp"`, the floor the next two add to;
- `import`: `python -c "import aquarium_warp"`;
- `import-env`: `python -c "from aquarium_warp import BatchedAquarium"` (the simulator, torch and Warp);
- `train-1`: `aquarium-warp train --preset paper --iterations 1 --device D`;
- `train`: `aquarium-warp train --preset paper --device D`.

The train commands write into a fresh temporary log directory (exports included, as a user's run).

Caches: "cold" runs each get an empty Warp kernel cache (`WARP_CACHE_PATH`) and Triton cache
(`TRITON_CACHE_DIR`) of their own; "warm" runs share one pair per tree, filled by one untimed run of the
command first. Python's bytecode caches are warm in both (a tree's first run writes them).

Trees (`--tree PATH`, repeatable): source trees (checkouts or copies holding `aquarium_warp/`, `kernels/`
and `training/`), each run with `PYTHONPATH` at a staged view of it (`stage_tree`: the package's folders as
the installed package maps them), so an old and a new tree compare in one call; the runs alternate between
the trees, repeat by repeat. Without `--tree`: the installed package.

    python benchmarks/bench_startup.py --device cuda:0 --tree /tmp/old --tree . --repeats 5

Prints a table (median, min and max seconds per command, cache and tree) and writes `startup_<device>.json`
into `--out-dir` (every run's seconds, the trees with their commits, the command, commit and machine).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from ..atomic import atomic_open, check_output_dir
from ..records import command_line, git_info, json_safe, provenance
from .timing import wall_clock

PYTHON_COMMANDS = {
    "help": ["-m", "aquarium_warp", "--help"],
    "import-torch-warp": ["-c", "import torch, warp"],
    "import": ["-c", "import aquarium_warp"],
    "import-env": ["-c", "from aquarium_warp import BatchedAquarium"],
}
TRAIN_COMMANDS = {
    "train-1": ["--preset", "paper", "--iterations", "1"],
    "train": ["--preset", "paper"],
}
COMMANDS = (*PYTHON_COMMANDS, *TRAIN_COMMANDS)
CACHES = ("cold", "warm")
# The folders of a tree that the installed package maps into `aquarium_warp` (pyproject's package-dir).
MAPPED = {"kernels": "kernels", "training": "training"}


def stage_tree(tree: Path, into: Path) -> Path:
    """A folder to put on `PYTHONPATH` so that `import aquarium_warp` imports `tree`'s code: `into/aquarium_warp/`
    links every entry of `tree/aquarium_warp/` and `tree`'s mapped folders (`MAPPED`). Returns `into`."""
    missing = [p for p in ("aquarium_warp/__init__.py", *MAPPED.values()) if not (tree / p).exists()]
    if missing:
        raise ValueError(f"--tree {tree}: not a source tree of aquarium-warp (no {', '.join(missing)})")
    package = into / "aquarium_warp"
    package.mkdir(parents=True)
    for entry in (tree / "aquarium_warp").iterdir():
        if entry.name not in MAPPED and entry.name != "__pycache__":
            (package / entry.name).symlink_to(entry.resolve())
    for name, folder in MAPPED.items():
        (package / name).symlink_to((tree / folder).resolve(), target_is_directory=True)
    return into


def command_argv(name: str, device: str, log_dir: str) -> list[str]:
    """The process of command `name` (`COMMANDS`), run by this interpreter."""
    if name in PYTHON_COMMANDS:
        return [sys.executable, *PYTHON_COMMANDS[name]]
    return [sys.executable, "-m", "aquarium_warp", "train", *TRAIN_COMMANDS[name], "--device", device,
            "--log-dir", log_dir]  # fmt: skip


def run_once(argv: list[str], env: dict[str, str], timeout: float, cwd: Path) -> float:
    """Seconds one run of `argv` in folder `cwd` took, wall clock; a failed run raises with the end of what
    it printed. (`cwd` holds no tree: `python -c` and `-m` import from their folder first.)"""
    done: list[subprocess.CompletedProcess] = []
    seconds = wall_clock(lambda: done.append(subprocess.run(argv, env=env, cwd=cwd, capture_output=True, text=True,
                                                             timeout=timeout)))  # fmt: skip
    if done[0].returncode != 0:
        tail = (done[0].stdout + done[0].stderr)[-2000:]
        raise RuntimeError(f"{' '.join(argv)} exited with {done[0].returncode}:\n{tail}")
    return seconds


class Tree:
    """A tree the commands run from: its label, its `PYTHONPATH` entry (None: the installed package) and
    its warm caches."""

    def __init__(self, label: str, path: Path | None, scratch: Path, commit: str | None = None):
        self.label, self.path = label, path
        self.pythonpath = None if path is None else str(stage_tree(path, scratch / f"tree-{label}"))
        self.warm = {name: str(scratch / f"warm-{label}" / name) for name in ("warp", "triton")}
        self.git = git_info(commit, repository=path) if path is not None else git_info(commit)

    def env(self, caches: dict[str, str]) -> dict[str, str]:
        env = dict(os.environ, WARP_CACHE_PATH=caches["warp"], TRITON_CACHE_DIR=caches["triton"])
        if self.pythonpath is not None:
            env["PYTHONPATH"] = os.pathsep.join(filter(None, [self.pythonpath, env.get("PYTHONPATH")]))
        return env


def measure(
    commands: Sequence[str], trees: list[Tree], device: str, repeats: int, scratch: Path, timeout: float,
    caches: Sequence[str] = CACHES, progress=print, measured=lambda rows: None,
) -> list[dict]:  # fmt: skip
    """Every run's seconds: one row per command, cache and tree (`seconds`: the repeats in order);
    `measured(rows)` gets the rows so far after every timed run (so that a time limit keeps them)."""
    rows: dict[tuple[str, str, str], list[float]] = {
        (c, k, t.label): [] for c in commands for k in caches for t in trees
    }
    count = 0
    for command in commands:
        for cache in caches:
            if cache == "warm":
                for tree in trees:  # fill the tree's caches (untimed)
                    argv = command_argv(command, device, str(scratch / f"log-{count}"))
                    run_once(argv, tree.env(tree.warm), timeout, scratch)
                    count += 1
            for _ in range(repeats):
                for tree in trees:
                    fresh = {name: str(scratch / f"cold-{count}" / name) for name in ("warp", "triton")}
                    log_dir = str(scratch / f"log-{count}")
                    count += 1
                    argv = command_argv(command, device, log_dir)
                    seconds = run_once(argv, tree.env(fresh if cache == "cold" else tree.warm), timeout, scratch)
                    rows[(command, cache, tree.label)].append(seconds)
                    progress(f"  {command:>17} {cache:>4} {tree.label:>10} {seconds:8.2f} s")
                    measured(_listed(rows))
    return _listed(rows)


def _listed(rows: dict[tuple[str, str, str], list[float]]) -> list[dict]:
    return [{"command": c, "cache": k, "tree": t, "seconds": list(s)} for (c, k, t), s in rows.items() if s]


def format_table(rows: list[dict]) -> str:
    lines = [f"{'command':>17} {'cache':>5} {'tree':>10} {'median s':>9} {'min s':>8} {'max s':>8}"]
    for r in rows:
        s = r["seconds"]
        spread = f"{statistics.median(s):9.2f} {min(s):8.2f} {max(s):8.2f}"
        lines.append(f"{r['command']:>17} {r['cache']:>5} {r['tree']:>10} {spread}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="cpu", help="device of the train commands: 'cpu', 'cuda:0' (default cpu)")
    p.add_argument(
        "--commands", default=",".join(COMMANDS), help=f"commands to time, comma-separated: {', '.join(COMMANDS)}"
    )
    p.add_argument("--caches", default=",".join(CACHES), help="kernel caches: cold, warm or both (default both)")
    p.add_argument("--repeats", type=int, default=3, help="timed runs of each command, cache and tree (default 3)")
    p.add_argument(
        "--tree",
        action="append",
        default=[],
        metavar="PATH",
        help="a source tree to run the commands from (repeatable; the runs alternate between them); "
        "default: the installed package",
    )
    p.add_argument(
        "--tree-commit",
        action="append",
        default=[],
        metavar="COMMIT",
        help="the commit of each --tree, in order, for copies without git history (a lent GPU machine's)",
    )
    p.add_argument("--timeout", type=float, default=600.0, help="seconds one run may take (default 600)")
    p.add_argument("--out-dir", default=".", help="folder of startup_<device>.json (default: the current one)")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Start-up times of whole commands, cold and warm kernel caches.")
    add_arguments(p)
    args = p.parse_args(argv)
    commands = [c for c in args.commands.split(",") if c]
    caches = [c for c in args.caches.split(",") if c]
    if not commands or not set(commands) <= set(COMMANDS):
        p.error(f"--commands={args.commands!r}: choose from {', '.join(COMMANDS)}")
    if not caches or not set(caches) <= set(CACHES):
        p.error(f"--caches={args.caches!r}: choose from {', '.join(CACHES)}")
    if args.repeats < 1:
        p.error(f"--repeats={args.repeats}: must be an integer >= 1")
    if args.tree_commit and len(args.tree_commit) != len(args.tree or [None]):
        p.error(f"--tree-commit: {len(args.tree_commit)} given, one per --tree needed ({len(args.tree)})")
    check_output_dir(args.out_dir, "--out-dir")
    with tempfile.TemporaryDirectory(prefix="aquarium-startup-") as scratch:
        try:
            paths: list[Path | None] = [Path(t) for t in args.tree] or [None]
            labels = [f"tree{i}" for i in range(len(paths))] if args.tree else ["installed"]
            commits = args.tree_commit or [None] * len(paths)
            trees = [Tree(label, path, Path(scratch), c) for label, path, c in zip(labels, paths, commits)]
        except ValueError as error:
            p.error(str(error))
        record = {
            **provenance(args.device, command=command_line(list(sys.argv[1:] if argv is None else argv), p.prog)),
            "trees": [{"label": t.label, "path": str(t.path) if t.path else None, "git": t.git} for t in trees],
            "repeats": args.repeats,
            "rows": [],
        }
        os.makedirs(args.out_dir, exist_ok=True)
        path = os.path.join(args.out_dir, f"startup_{args.device.replace(':', '')}.json")

        def write(rows: list[dict]) -> None:
            with atomic_open(path) as f:
                json.dump(json_safe({**record, "rows": rows}), f, indent=1)

        rows = measure(commands, trees, args.device, args.repeats, Path(scratch), args.timeout, caches, measured=write)
    print(format_table(rows))
    print(f"wrote {path}")
    return 0
