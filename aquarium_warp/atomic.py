"""Atomic output files and output locations checked up front: the one helper every writer uses.

A file is written under a temporary name in its own folder (`.<name>.<pid>.partial<ext>`: the extension
stays last, so ffmpeg and matplotlib still pick the format from it), flushed to disk, then renamed over
its final name. A full disk or a kill leaves the previous file, or none, never a truncated one; the
partial file of a failed write is removed, and those of dead processes when a folder is checked.

```python
with atomic_open("out/summary.json") as f:
    json.dump(summary, f)
with atomic_path("out/figure.png") as partial:
    fig.savefig(partial)
```
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
from collections.abc import Iterator

_PARTIAL = re.compile(r"\.(\d+)\.partial(\.[^./]*)?$")


def partial_name(path: str) -> str:
    """The temporary name `path` is written under by this process: hidden (a leading dot), so that
    globs such as `run/model_*.pt` never take a file being written for a finished one."""
    folder, name = os.path.split(os.fspath(path))
    root, ext = os.path.splitext(name)
    return os.path.join(folder, f".{root}.{os.getpid()}.partial{ext}")


def _fsync(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path) -> Iterator[str]:
    """Yields the temporary path to write; on success it is synced and renamed over `path`, on any
    error (or interrupt) removed."""
    path = os.fspath(path)
    partial = partial_name(path)
    try:
        yield partial
        _fsync(partial)
        os.replace(partial, path)
    except OSError as error:
        if error.filename != partial:
            raise
        raise OSError(error.errno, error.strerror, path) from None  # the file asked for, not its temporary name
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.remove(partial)


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs) -> Iterator:
    """`open(path, mode)` for writing, atomically (see `atomic_path`); text modes default to UTF-8."""
    if "b" not in mode:
        kwargs.setdefault("encoding", "utf-8")
    with atomic_path(path) as partial:
        with open(partial, mode, **kwargs) as f:
            yield f


def remove_stale_partials(folder: str) -> list[str]:
    """Remove the partial files in `folder` left by processes that no longer run; returns their paths."""
    removed = []
    with contextlib.suppress(OSError):
        for name in os.listdir(folder):
            match = _PARTIAL.search(name)
            if match and not _alive(int(match.group(1))):
                with contextlib.suppress(OSError):
                    os.remove(os.path.join(folder, name))
                    removed.append(os.path.join(folder, name))
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def check_output_dir(path, option: str) -> str:
    """Check, before any long work, that the folder `path` (given as `option`) can be created or written
    in, without creating it: a one-line ValueError naming the option, the path and the cause. Stale
    partial files of dead processes in it are removed. Returns the path."""
    path = os.fspath(path)
    if not path:
        raise ValueError(f"{option} is empty: give a folder")
    existing = os.path.abspath(path)
    while not os.path.exists(existing):  # the folder that would hold the new ones
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise ValueError(f"{option} {path}: cannot write there ({existing} is a file, not a folder)")
    if not os.access(existing, os.W_OK | os.X_OK):
        cause = "read-only file system" if os.statvfs(existing).f_flag & os.ST_RDONLY else "permission denied"
        raise ValueError(f"{option} {path}: cannot write there ({cause} at {existing})")
    if os.path.isdir(path):
        remove_stale_partials(path)
    return path


def check_output_file(path, option: str) -> str:
    """`check_output_dir` for the folder of the file `path` (which must exist: a file name's typo
    should not create folders); refuses a path that is a folder. Returns the path."""
    path = os.fspath(path)
    if not path:
        raise ValueError(f"{option} is empty: give a file name")
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise ValueError(f"{option} {path}: is a folder, not a file name")
    if not os.path.isdir(folder):
        raise ValueError(f"{option} {path}: folder {folder} does not exist")
    check_output_dir(folder, option)
    return path


def os_error_cause(error: OSError) -> str:
    """The cause of a failed file operation, in words ("no space left on device", "Permission denied")."""
    if error.errno == errno.ENOSPC:
        return "no space left on device"
    return error.strerror or str(error)


def describe_os_error(error: OSError) -> str:
    """One line for a failed file operation: the path (where the error has one) and the cause."""
    return f"{error.filename}: {os_error_cause(error)}" if error.filename is not None else os_error_cause(error)


def write_figure(fig, path, **kwargs) -> str:
    """`fig.savefig(path, **kwargs)`, atomically; returns the path."""
    with atomic_path(path) as partial:
        fig.savefig(partial, **kwargs)
    return os.fspath(path)
