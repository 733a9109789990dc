"""`attach(env)`: the viewer on your own env, from any script or training loop.

```python
from aquarium_warp.viewer import attach

viewer = attach(env)          # returns at once; prints nothing; open viewer.url
for _ in range(10_000):
    env.step(actions)         # each step is served as it happens
viewer.close()
```

The page shows one world of `env` as your code steps it: overlays, zoom, the timeline, click-to-inspect
and drag-to-move work; play/pause, speed, teams, human play and recording do not (your loop steps the
env). Snapshots are taken on the thread that steps `env`, right after a step, and only when the viewer
asks for one (at most `fps` a second), so the loop pays for a copy of one world at that rate and never
waits for a page. A dragged agent is put in place just before the next step.
"""

from __future__ import annotations

import socket
import threading

import torch

from ..checks import checked_state_value
from .simulation import WorldView, move_agent


class AttachedRun:
    """The viewer's side of an env stepped by someone else's code (the `Simulation` interface that
    `server.Viewer` uses): `advance()` and `snapshot()` hand over what the stepping thread published."""

    records = False  # frames would have to be drawn on the stepping thread: not offered

    def __init__(self, env, world: int = 0):
        if isinstance(world, bool) or not isinstance(world, int) or not 0 <= world < env.num_worlds:
            raise ValueError(f"world={world!r} must be an integer in [0, {env.num_worlds - 1}]")
        self.env, self.world = env, world
        self.specs = {"prey": "your code", "predator": "your code"}
        self.view = WorldView(env)
        self._lock = threading.Lock()
        self._steps = 0
        self._due = False  # the viewer wants a snapshot after the next step
        self._wanted: tuple[bool, tuple] = (False, ())  # its flow and inspected slots
        self._moves: list[tuple[int, float, float]] = []
        self._stepping = threading.Lock()  # held by a step, and by a snapshot taken while no step runs
        self._stale = False  # the state changed since the last snapshot
        self._latest = self.view.snapshot(world)
        self._original_step = env.step
        env.step = self._step  # an instance attribute: `detach` deletes it and the class's method is back

    def _step(self, *args, **kwargs):
        with self._stepping:
            with self._lock:
                moves, self._moves = self._moves, []
            for slot, x, y in moves:
                try:
                    move_agent(self.env, self.world, slot, x, y)
                except ValueError:  # it died since the drag was checked: nothing to move
                    pass
            result = self._original_step(*args, **kwargs)
            with self._lock:
                self._steps += 1
                due, self._due, self._stale = self._due, False, True
            if due:
                self._publish()
        return result

    def _publish(self) -> None:
        """A snapshot of the state now (with the stepping lock held: no step runs meanwhile)."""
        with self._lock:
            (flow, inspect), world = self._wanted, self.world
        snapshot = self.view.snapshot(world, flow, inspect)
        with self._lock:
            self._latest, self._stale = snapshot, False

    def detach(self) -> None:
        """Give `env.step` back its own method."""
        if self.env.__dict__.get("step") == self._step:
            del self.env.step

    # ------------------------------------------------------------------ the viewer's thread
    def advance(self) -> int:
        """Steps since the last call; the next step publishes a snapshot. When the script has stopped
        stepping (none since the last call) and no step is running, the snapshot is taken here."""
        with self._lock:
            steps, self._steps, self._due, stale = self._steps, 0, True, self._stale
        if steps == 0 and stale and self._stepping.acquire(blocking=False):
            try:
                self._publish()
            finally:
                self._stepping.release()
        return steps

    def snapshot(self, flow: bool = False, inspect=()) -> dict:
        with self._lock:
            self._wanted = (flow, tuple(inspect))
            return self._latest

    def policy_choices(self) -> dict[str, list[str]]:
        return {"prey": [], "predator": []}

    def apply(self, message: dict) -> None:
        kind = message["type"]
        if kind == "world":
            with self._lock:
                self.world, self._due, self._stale = message["index"], True, True
            self.view.forget_metrics()
        elif kind == "move":
            slot, x, y = message["slot"], message["x"], message["y"]
            checked_state_value(self.env, "position", torch.tensor([[x, y]]), torch.float32)
            if not bool(self.env.state.torch.alive[self.world, slot]):
                raise ValueError(f"slot {slot} of world {self.world} holds no live agent")
            with self._lock:
                self._moves.append((slot, x, y))
        else:
            raise ValueError(
                f"{kind}: an attached env is stepped by its own code; the page offers overlays, world, inspect and drag"
            )


class Attached:
    """A running attached viewer: `url`, `viewer` (the `server.Viewer`), `close()` (also on leaving a
    `with` block)."""

    def __init__(self, run: AttachedRun, viewer, server, thread: threading.Thread, url: str):
        self.run, self.viewer, self._server, self._thread, self.url = run, viewer, server, thread, url

    def close(self) -> None:
        self._server.should_exit = True
        self._thread.join(30)
        self.run.detach()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def attach(
    env, *, host: str = "127.0.0.1", port: int = 0, world: int = 0, fps: float = 30, max_agents: int = 100_000
) -> Attached:
    """Serve `env` (a `BatchedAquarium`) in the browser while your code steps it; returns at once.
    `port`: 0 picks a free one (see `.url`); a port in use is refused at once (ValueError).
    `world`: the world shown first (the page can switch)."""
    import uvicorn

    from . import bind
    from .server import Viewer, server_config

    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"port={port!r} must be an integer in [0, 65535] (0: a free one)")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not 1 <= fps <= 120:
        raise ValueError(f"fps={fps!r} must be a number in [1, 120]")
    listening = bind(host, port, "port")
    try:
        run = AttachedRun(env, world)
    except BaseException:
        listening.close()
        raise
    viewer = Viewer(run, fps=fps, max_agents=max_agents)
    server = uvicorn.Server(server_config(viewer))

    def serve() -> None:
        with listening:
            server.run(sockets=[listening])

    thread = threading.Thread(target=serve, name="aquarium-attach", daemon=True)
    thread.start()
    bound = listening.getsockname()
    shown = f"[{bound[0]}]" if listening.family == socket.AF_INET6 else bound[0]
    return Attached(run, viewer, server, thread, f"http://{shown}:{bound[1]}/")
