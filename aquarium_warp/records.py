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

# git runs here: in a source checkout it finds the repository of this code, in an installed
# package (no repository) it reports "git failed".
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


def git_info(commit: str | None = None) -> dict:
    """The repository's commit and whether tracked files differ from it (`commit`, else the environment's
    `AQUARIUM_WARP_COMMIT`, overrides: a copy without git history, e.g. on a lent GPU machine, names it)."""
    commit = commit or os.environ.get("AQUARIUM_WARP_COMMIT")
    if commit:
        return {"commit": commit, "dirty": None, "source": "given"}
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=PACKAGE_DIR, timeout=30)
        if head.returncode != 0:
            return {"commit": "unknown", "dirty": None, "source": "git failed"}
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            cwd=PACKAGE_DIR,
            timeout=30,
        )
        return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip()), "source": "git"}
    except (OSError, subprocess.SubprocessError):
        return {"commit": "unknown", "dirty": None, "source": "no git"}


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
    """`command` (default `command_line()`), `git` (`commit` overrides, for a copy without git history)
    and `machine`: what a result file records of the run that made it on `device`."""
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
