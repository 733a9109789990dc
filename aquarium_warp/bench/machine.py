"""The machine and code a measurement ran on: commit, device, library versions, free memory."""

from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

# git runs here: in a source checkout it finds the repository of this code, in an installed
# package (no repository) it reports "git failed".
PACKAGE_DIR = Path(__file__).resolve().parent


def git_info(commit: str | None = None) -> dict:
    """The repository's commit and whether tracked files differ from it (`commit` overrides)."""
    if commit:
        return {"commit": commit, "dirty": None, "source": "given"}
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=PACKAGE_DIR, timeout=30)
        if head.returncode != 0:
            return {"commit": "unknown", "dirty": None, "source": "git failed"}
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                                text=True, cwd=PACKAGE_DIR, timeout=30)
        return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip()), "source": "git"}
    except (OSError, subprocess.SubprocessError):
        return {"commit": "unknown", "dirty": None, "source": "no git"}


def machine_info(device: str) -> dict:
    """The machine of a measurement: device, CPU, platform and the versions of the libraries."""
    import numpy as np
    import torch
    import warp as wp

    dev = wp.get_device(device)
    info: dict[str, Any] = {"device": device, "device_name": dev.name, "platform": platform.platform(),
            "python": platform.python_version(), "warp": wp.__version__, "torch": torch.__version__,
            "numpy": np.__version__, "vmas": installed_version("vmas"), "cpu_count": os.cpu_count(),
            "cpu_threads_available": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None}
    model = cpu_model()
    if model is not None:
        info["cpu"] = model
    if dev.is_cuda:
        info["device_memory_bytes"] = int(dev.total_memory)
        info["cuda_capability"] = list(torch.cuda.get_device_capability(torch.device(device)))
        info["torch_cuda"] = torch.version.cuda
        try:
            info["driver"] = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                            capture_output=True, text=True, timeout=30).stdout.strip() or None
        except (OSError, subprocess.SubprocessError):
            info["driver"] = None
    return info


def available_bytes(device: str) -> int:
    """Free memory of `device`: the GPU's, or the host's available physical pages."""
    import warp as wp

    dev = wp.get_device(device)
    if dev.is_cuda:
        return int(dev.free_memory)
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError):
        return 1 << 40



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
