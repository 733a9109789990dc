"""Ctrl-C and SIGTERM during training: the run stops at the next iteration boundary, where the trainer
writes a checkpoint (and the export) and says how to resume (`aquarium_warp.arguments.Interrupted`); a
second signal stops at once.

Signal handlers can only be set from the main thread: elsewhere (a Ray worker's thread, a study's
thread pool) the signals keep their default behaviour.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequest:
    """The first SIGINT or SIGTERM received while `catching()`: `signum` (None: none yet)."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    def _handle(self, signum, frame) -> None:
        if self.signum is not None:  # the second one: stop now
            raise KeyboardInterrupt
        self.signum = signum
        print(
            f"\naquarium-warp train: {signal.Signals(signum).name} received, stopping after this iteration "
            "(a checkpoint is written); send it again to stop at once",
            file=sys.stderr,
            flush=True,
        )

    @contextlib.contextmanager
    def catching(self):
        """SIGINT and SIGTERM set the request instead of ending the process, inside the block."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = {s: signal.signal(s, self._handle) for s in SIGNALS}
        try:
            yield
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
