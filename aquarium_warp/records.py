"""What every result file records: the exact command (`command_line`), the commit (`git_info`), the
machine and library versions (`machine_info`), all three at once (`provenance`), written as strict
JSON (`json_safe`). The studies, the benchmark suite, `aquarium-warp eval` and the benchmark scripts
record them through here, and tests/app/test_results_provenance.py reads them back under these names."""

from __future__ import annotations

import math
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

# git runs here: in a source checkout it finds the repository of this code; an installed or staged
# copy (no repository, or files it does not track) has none.
PACKAGE_DIR = Path(__file__).resolve().parent


def json_safe(value: Any) -> Any:
    """`value` with NaN and infinities as None (strict JSON has neither), numpy scalars as Python
    numbers, tuples as lists and dict keys as strings."""
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def command_line(argv: Sequence[str] | None = None, program: str = "aquarium-warp") -> str:
    """The command as typed, shell-quoted: `program` and its arguments `argv` (by default an
    `aquarium-warp` command's); without `argv`, this process's own (its program's file name and arguments)."""
    if argv is None:
        return shlex.join([os.path.basename(sys.argv[0]), *sys.argv[1:]])
    return shlex.join([program, *argv])


def git_info(commit: str | None = None, repository: str | Path | None = None) -> dict:
    """Where a result's code came from, read from git at run time: the commit of the checkout holding
    `repository` (default: this package), `dirty` whether tracked files differ from it and `modified`
    which (`source: "git"`). A supplied commit is taken only where git cannot read a checkout (a staged
    copy without `.git`, as on a lent GPU machine): `commit` (`source: "argument"`), else the environment's
    `AQUARIUM_WARP_COMMIT` (`source: "environment"`); whether that copy matched the commit is then unknown
    (`dirty` and `modified` None). A supplied commit that git contradicts is kept as `supplied`."""
    supplied, source = (commit, "argument") if commit else (os.environ.get("AQUARIUM_WARP_COMMIT"), "environment")
    read = read_checkout(PACKAGE_DIR if repository is None else Path(repository))
    if read is not None:
        if supplied and not read["commit"].startswith(supplied):
            read["supplied"] = supplied
        return read
    if supplied:
        return {"commit": supplied, "dirty": None, "modified": None, "source": source}
    return {"commit": "unknown", "dirty": None, "modified": None, "source": "no git"}


def read_checkout(directory: Path) -> dict | None:
    """`git_info`'s record of the git checkout whose tracked files include `directory`'s, None where git
    cannot tell (no git, no repository, or `directory` not tracked in it: an installed copy)."""

    def git(*args: str) -> str | None:
        run = subprocess.run(["git", *args], capture_output=True, text=True, cwd=directory, timeout=30)
        return run.stdout if run.returncode == 0 else None

    try:
        head, tracked = git("rev-parse", "HEAD"), git("ls-files", "--", ".")
        status = git("status", "--porcelain=v1", "--untracked-files=no") if head and tracked else None
    except (OSError, subprocess.SubprocessError):
        return None
    if head is None or status is None:
        return None
    # Porcelain v1: two status letters and a space, then the path ("old -> new" for a rename).
    modified = sorted(line[3:] for line in status.splitlines() if line.strip())
    return {"commit": head.strip(), "dirty": bool(modified), "modified": modified, "source": "git"}


def machine_info(device: str) -> dict:
    """The machine of a measurement: device, CPU, platform and the versions of the libraries."""
    import torch
    import warp as wp

    dev = wp.get_device(device)
    info: dict[str, Any] = {
        "device": device,
        "device_name": dev.name,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "warp": wp.__version__,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "vmas": installed_version("vmas"),
        "cpu_count": os.cpu_count(),
        "cpu_threads_available": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
    }
    model = cpu_model()
    if model is not None:
        info["cpu"] = model
    if dev.is_cuda:
        info["device_memory_bytes"] = int(dev.total_memory)
        info["cuda_capability"] = list(torch.cuda.get_device_capability(torch.device(device)))
        info["torch_cuda"] = torch.version.cuda
        try:
            info["driver"] = (
                subprocess.run(
                    ["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                    capture_output=True,
                    text=True,
                    timeout=30,
                ).stdout.strip()
                or None
            )
        except (OSError, subprocess.SubprocessError):
            info["driver"] = None
    return info


def provenance(device: str, command: str | None = None, commit: str | None = None) -> dict:
    """`command` (default `command_line()`), `git` (`git_info`: read from git; `commit` names a copy
    without git history) and `machine`: what a result file records of the run that made it on `device`."""
    return {
        "command": command if command is not None else command_line(),
        "git": git_info(commit),
        "machine": machine_info(device),
    }


def installed_version(package: str) -> str | None:
    """The installed version of `package` (a distribution name), None when it is not installed."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def cpu_model() -> str | None:
    """The CPU's model name (Linux), None where /proc/cpuinfo does not tell."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None
