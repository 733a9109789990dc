"""A run directory owned by one run at a time (`aquarium-warp train --log-dir`).

A new run refuses a directory that already holds files unless told to replace the earlier run's
outputs (`--overwrite`); a resumed run continues its own. While a run trains, `<dir>/.lock` holds an
exclusive `flock` and the owner's process id: a second run on the directory is refused. The kernel
drops the lock of a process that dies, so a lock file left by a killed run is taken over, saying so.
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil

from ..atomic import check_output_dir

LOCK_NAME = ".lock"
# What a run writes into its directory (rsl-rl: TensorBoard events, git state; ours: the rest);
# --overwrite removes these and nothing else.
RUN_OUTPUTS = (
    "config.json",
    "progress.csv",
    "progress_*.csv",
    "model_*.pt",
    "events.out.tfevents.*",
    "exported",
    "git",
    "population.json",  # a population's (`population.py`), with its runs' directories
    "run-*",
)


class RunDirectory:
    """The lock of a claimed run directory; `release()` (or the end of the process) frees it."""

    def __init__(self, path: str, handle):
        self.path, self._handle = path, handle

    def release(self) -> None:
        if self._handle is None:
            return
        import fcntl

        # Emptied while still held: an empty lock file is a clean release, one with a pid a dead owner.
        self._handle.truncate(0)
        self._handle.flush()
        fcntl.flock(self._handle, fcntl.LOCK_UN)
        self._handle.close()
        self._handle = None


def claim_run_directory(path: str, resume: bool = False, overwrite: bool = False, say=print) -> RunDirectory:
    """Lock `path` for this process (created if needed), then check it: a new run needs it empty, or
    `overwrite` (the earlier run's outputs are removed first). A one-line ValueError otherwise."""
    import fcntl

    os.makedirs(check_output_dir(path, "--log-dir"), exist_ok=True)
    handle = open(os.path.join(path, LOCK_NAME), "a+", encoding="utf-8")  # held until release()
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        owner = handle.read().strip() or "unknown"
        handle.close()
        raise ValueError(
            f"--log-dir {path}: another run (process {owner}) is using it; wait for it to finish "
            "or choose another directory"
        ) from None
    handle.seek(0)
    previous = handle.read().strip()
    if previous and previous != str(os.getpid()):
        say(f"aquarium-warp train: {path} was locked by process {previous}, which no longer runs; taking it over")
    handle.truncate(0)
    handle.write(str(os.getpid()))
    handle.flush()
    claimed = RunDirectory(path, handle)
    try:
        if not resume:
            _check_new_run(path, overwrite)
    except BaseException:
        claimed.release()
        raise
    return claimed


def _check_new_run(path: str, overwrite: bool) -> None:
    present = sorted(name for name in os.listdir(path) if name != LOCK_NAME)
    if not present:
        return
    if not overwrite:
        listed = ", ".join(present[:4]) + (f" and {len(present) - 4} more" if len(present) > 4 else "")
        raise ValueError(
            f"--log-dir {path} is not empty ({listed}): continue that run with --resume {path}, "
            "replace it with --overwrite, or choose another directory"
        )
    for pattern in RUN_OUTPUTS:
        for item in glob.glob(os.path.join(glob.escape(path), pattern)):
            if os.path.isdir(item):
                shutil.rmtree(item)
            else:
                with contextlib.suppress(FileNotFoundError):
                    os.remove(item)
