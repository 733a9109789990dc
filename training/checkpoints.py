"""Training checkpoints `model_<i>.pt`, the state after iteration i (what they hold: `trainer.py`'s doc):
writing one, finding the newest readable one of a run, reading one, and the global random states they
carry."""

from __future__ import annotations

import errno
import glob
import os
import random
import re
import warnings

import numpy as np
import torch

from ..atomic import atomic_open


def global_rng_state(device: torch.device) -> dict:
    """The global random states: torch (CPU and `device`'s CUDA), numpy and Python."""
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def restore_global_rng_state(state: dict, device: torch.device) -> None:
    """Restore `global_rng_state(device)`."""
    # RNG states are CPU byte tensors (a checkpoint loaded with map_location="cuda" moved them).
    torch.set_rng_state(state["torch"].cpu())
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"].cpu(), device)


def write_checkpoint(checkpoint: dict, path: str) -> None:
    """Save `checkpoint` to `path` atomically: an interrupted save never leaves a truncated checkpoint
    under a checkpoint's name; a failed write is an `OSError`."""
    with atomic_open(path, "wb") as f:
        try:
            torch.save(checkpoint, f)
        except RuntimeError as error:  # torch's zip writer reports a failed write (a full disk) so
            reason = (str(error).strip().splitlines() or [""])[0][:200]
            raise OSError(errno.EIO, f"writing the checkpoint failed ({reason})", path) from None


def latest_checkpoint(run_dir: str) -> str:
    """The readable checkpoint `model_<i>.pt` with the largest i in `run_dir`; newer ones that cannot be
    read (empty, truncated, corrupt) are skipped with a warning."""
    return newest_readable_checkpoint(run_dir)[0]


def newest_readable_checkpoint(run_dir: str) -> tuple[str, dict]:
    """`(path, checkpoint)` of `latest_checkpoint(run_dir)`."""
    paths = glob.glob(os.path.join(run_dir, "model_*.pt"))
    numbered = sorted(((int(m.group(1)), p) for p in paths if (m := re.search(r"model_(\d+)\.pt$", p))), reverse=True)
    if not numbered:
        raise ValueError(f"no checkpoint model_<i>.pt in {run_dir!r}")
    for _, path in numbered:
        try:
            return path, read_checkpoint(path)
        except ValueError as error:
            warnings.warn(f"skipping {error}", stacklevel=3)
    raise ValueError(f"no readable checkpoint model_<i>.pt in {run_dir!r} ({len(numbered)} found, all broken)")


def read_checkpoint(path: str) -> dict:
    """A training checkpoint of this package; a one-line ValueError for a missing, empty, truncated,
    corrupt or foreign file."""
    if not os.path.isfile(path):
        raise ValueError(f"checkpoint {path!r} does not exist")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # noqa: BLE001 - torch raises many kinds for a damaged file (EOF, unpickling, zip)
        reason = (str(error).strip().splitlines() or [""])[0][:200]
        raise ValueError(
            f"{path}: not a readable checkpoint (empty, truncated or another format: {type(error).__name__}: {reason})"
        ) from None
    state = (checkpoint.get("infos") or {}).get("aquarium") if isinstance(checkpoint, dict) else None
    if not isinstance(state, dict) or "config" not in state:
        raise ValueError(f"{path}: not a checkpoint of aquarium_warp.training")
    return checkpoint
