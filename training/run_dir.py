"""A run directory owned by one run at a time (`aquarium-warp train --log-dir`).

A new run refuses a directory that already holds files unless told to replace the earlier run's
outputs (`--overwrite`); a resumed run continues its own, and is refused a directory whose config.json
or newest checkpoint is of another run (`check_same_run`: the run id, or for files from before run
ids, the config). While a run trains, `<dir>/.lock` holds an exclusive `flock` and the owner's
process id: a second run on the directory is refused. The kernel drops the lock of a process that
dies, so a lock file left by a killed run is taken over, saying what it held.
"""

from __future__ import annotations

import contextlib
import glob
import json
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
    "swarm.csv",
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
        say(f"aquarium-warp train: {_left_lock(path, previous)}; taking it over")
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


def _left_lock(path: str, content: str) -> str:
    """What the unheld lock file of the directory `path` says by its `content`: a dead owner's pid, a
    live process's (which holds no lock on it: a reused pid, or a process that never locked it), or no
    process id at all."""
    pid = int(content) if content.isdigit() else 0
    if not 0 < pid < 2**31:  # 0 would signal our own process group below
        shown = content if len(content) <= 40 else content[:40] + "..."
        return f"the lock file of {path} holds {shown!r}, not a process id"
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return f"{path} was locked by process {pid}, which no longer runs"
    except PermissionError:  # another user's process: it runs
        pass
    return f"the lock file of {path} names process {pid}, which runs but holds no lock on it (a reused process id?)"


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


def check_same_run(log_dir: str, checkpoint_path: str, state: dict) -> str | None:
    """Refuse (a one-line ValueError) to continue the checkpoint `checkpoint_path`, whose
    `infos["aquarium"]` is `state`, in `log_dir` when the directory holds another run: its config.json
    or its newest checkpoint has another run id, or where either has none (files from before run ids),
    another config (the settings a resume may change aside). Returns the run id the resumed run keeps:
    the checkpoint's, else the directory's (None: neither has one)."""
    from .checkpoints import newest_readable_checkpoint
    from .config import RESUMABLE_SETTINGS, config_difference

    run_id = state.get("run_id")
    found = []  # (file, its run id, its config)
    record_path = os.path.join(log_dir, "config.json")
    if os.path.isfile(record_path):
        try:
            with open(record_path, encoding="utf-8") as f:
                record = json.load(f)
            found.append(("config.json", record.get("run_id"), record["config"]))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            raise ValueError(
                f"{record_path} is not a run's config.json: cannot tell which run {log_dir} holds"
            ) from None
    if glob.glob(os.path.join(glob.escape(log_dir), "model_*.pt")):
        try:
            newest_path, newest = newest_readable_checkpoint(log_dir)
        except ValueError:  # none readable: no other run's state to continue from by mistake
            newest_path = None
        if newest_path is not None and not os.path.samefile(newest_path, checkpoint_path):
            other = newest["infos"]["aquarium"]
            found.append((os.path.basename(newest_path), other.get("run_id"), other["config"]))
    for name, other_id, other_config in found:
        if run_id and other_id:
            reason = None if other_id == run_id else f"run {other_id}, the checkpoint's is {run_id}"
        else:
            key = config_difference(state["config"], other_config, RESUMABLE_SETTINGS)
            reason = None if key is None else f"{key} differs from the checkpoint's"
        if reason is not None:
            raise ValueError(
                f"{checkpoint_path} cannot continue in {log_dir}: its {name} is of another run ({reason}); "
                "resume into the checkpoint's own run directory or an empty one"
            )
        run_id = run_id or other_id
    return run_id
