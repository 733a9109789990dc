"""The viewer's web server: a Starlette app (served by uvicorn) with the page, its files and one
WebSocket per page.

One loop advances the simulation on a thread of its own (a one-thread executor: the simulation is
never touched from two threads, and the event loop stays free to answer pages while a large world
steps) and publishes a snapshot of the displayed world at up to `fps` per second. Each page has a
sender that packs the newest snapshot for that page (its view rectangle, at most `max_agents` agents)
whenever the previous frame has gone out: a slow page gets fewer frames, never a backlog.

Frame (binary, little-endian): uint32 n_header, the header's JSON (n_header bytes, padded with spaces
to a multiple of 4), then float32 [n, 6] (x, y, heading x, heading y, velocity x, velocity y), uint32
[n] slots, then, when the flow overlay is on, float32 [rows, cols, 2] currents (rows, cols in the header).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import os
import time

import numpy as np
from starlette.applications import Starlette
from starlette.responses import HTMLResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from ..metrics import SwarmMetrics
from ..render import Renderer
from .messages import MessageError, parse_message
from .recording import Recorder, asset
from .simulation import Simulation

STATIC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")


def select_agents(snapshot: dict, rect, max_agents: int, human: int | None) -> np.ndarray:
    """The slots a page is sent: live agents inside `rect` (x0, y0, x1, y1; None: all), every predator
    and the human's agent always, prey thinned by a fixed stride down to `max_agents` in all."""
    alive = snapshot["alive"]
    position = snapshot["position"]
    prey_capacity = snapshot["header"]["prey_capacity"]
    keep = alive.copy()
    if rect is not None:
        x0, y0, x1, y1 = rect
        keep &= (position[:, 0] >= x0) & (position[:, 0] <= x1) & (position[:, 1] >= y0) & (position[:, 1] <= y1)
    slots = np.flatnonzero(keep)
    if len(slots) > max_agents:
        predators = slots[slots >= prey_capacity][:max_agents]
        prey = slots[slots < prey_capacity]
        budget = max(0, max_agents - len(predators))
        stride = -(-len(prey) // budget) if budget else len(prey) + 1
        slots = np.concatenate([prey[::stride], predators])
    if human is not None and alive[human] and human not in slots:
        slots = np.append(slots, human)
    return slots.astype(np.uint32)


def pack_frame(snapshot: dict, rect, max_agents: int) -> bytes:
    header = snapshot["header"]
    human = header["human"]["slot"] if header["human"] else None
    slots = select_agents(snapshot, rect, max_agents, human)
    agents = np.concatenate(
        [snapshot["position"][slots], snapshot["heading"][slots], snapshot["velocity"][slots]], axis=1
    ).astype("<f4")
    flow = snapshot["flow"]
    header = {
        **header,
        "type": "frame",
        "n": len(slots),
        "alive_total": int(snapshot["alive"].sum()),
        "flow_shape": None if flow is None else list(flow.shape[:2]),
        "sent_at": time.time(),
    }
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 4)
    parts = [np.uint32(len(text)).astype("<u4").tobytes(), text, agents.tobytes(), slots.astype("<u4").tobytes()]
    if flow is not None:
        parts.append(flow.astype("<f4").tobytes())
    return b"".join(parts)


class _Page:
    """One connected page: its socket, view rectangle and a flag that a newer snapshot is waiting."""

    def __init__(self, socket: WebSocket):
        self.socket = socket
        self.rect: tuple[float, float, float, float] | None = None
        self.fresh = asyncio.Event()


class Viewer:
    """The server's state: the simulation, its thread, the pages and the recording."""

    def __init__(
        self,
        simulation: Simulation,
        *,
        fps: float = 30,
        max_agents: int = 20000,
        record: str | None = None,
        record_dir: str = ".",
    ):
        self.simulation = simulation
        self.fps, self.max_agents, self.record_dir = fps, max_agents, record_dir
        self._thread = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="aquarium-view")
        self.pages: set[_Page] = set()
        self.snapshot: dict | None = None
        self.recorder: Recorder | None = None
        self._record_path = record
        self._metrics: SwarmMetrics | None = None
        self._renderer: Renderer | None = None
        self.frames = 0  # snapshots published (tests and the benchmark read it)
        self.tick_seconds = 0.0  # time of the last tick on the simulation thread

    async def call(self, function, *args):
        """Run `function(*args)` on the simulation thread."""
        return await asyncio.get_running_loop().run_in_executor(self._thread, function, *args)

    # ------------------------------------------------------------------ simulation thread
    def _tick(self) -> dict:
        start = time.perf_counter()
        sim = self.simulation
        stepped = sim.advance()
        assert sim.env is not None  # built with the simulation
        if self._metrics is None or self._metrics.env is not sim.env:
            self._metrics = SwarmMetrics(sim.env)
        snapshot = sim.snapshot(self._metrics)
        snapshot["header"]["recording"] = self.recorder is not None
        if self.recorder is not None and stepped:
            self.recorder.add(snapshot, sim.overlays)
        self.tick_seconds = time.perf_counter() - start
        return snapshot

    def _start_recording(self, path: str | None = None) -> str:
        if self.recorder is not None:
            return self.recorder.path
        if path is None:
            path = os.path.join(self.record_dir, time.strftime("aquarium-%Y%m%d-%H%M%S.mp4"))
        if self._renderer is None or self._renderer.env is not self.simulation.env:
            self._renderer = Renderer(self.simulation.env)
        self.recorder = Recorder(path, self._renderer, fps=self.fps)
        return path

    def _stop_recording(self) -> tuple[str, str] | None:
        recorder, self.recorder = self.recorder, None
        return None if recorder is None else recorder.close()

    def _apply(self, message: dict) -> str | None:
        """A checked message, on the simulation thread; returns a notice for the page, if any."""
        if message["type"] == "record":
            if message["on"]:
                return f"recording to {self._start_recording()}"
            paths = self._stop_recording()
            return None if paths is None else f"wrote {paths[0]} and {paths[1]}"
        env = self.simulation.env
        self.simulation.apply(message)
        if self.recorder is not None and self.simulation.env is not env:  # a new world: a new recording
            paths = self._stop_recording()
            return f"the teams' world changed: wrote {paths[0]} and {paths[1]}" if paths else None
        return None

    # ------------------------------------------------------------------ event loop
    async def run(self) -> None:
        """Tick at up to `fps` per second while the server runs and publish each snapshot to the pages."""
        if self._record_path is not None:
            await self.call(self._start_recording, self._record_path)
        period = 1.0 / self.fps
        while True:
            start = time.perf_counter()
            self.snapshot = await self.call(self._tick)
            self.frames += 1
            for page in self.pages:
                page.fresh.set()
            await asyncio.sleep(max(0.0, period - (time.perf_counter() - start)))

    async def close(self) -> None:
        try:
            paths = await self.call(self._stop_recording)
            if paths is not None:
                print(f"aquarium-warp view: wrote {paths[0]} and {paths[1]}")
        except ValueError as error:  # a failed recording is reported; the server still shuts down cleanly
            print(f"aquarium-warp view: {error}")
        self._thread.shutdown(wait=True)

    async def _send_frames(self, page: _Page) -> None:
        while True:
            await page.fresh.wait()
            page.fresh.clear()
            if self.snapshot is not None:
                await page.socket.send_bytes(pack_frame(self.snapshot, page.rect, self.max_agents))

    async def page_socket(self, socket: WebSocket) -> None:
        """One page: send it the choices, then frames; answer its messages (errors go back to it)."""
        await socket.accept()
        page = _Page(socket)
        sim = self.simulation
        await socket.send_text(
            json.dumps({"type": "hello", "choices": await self.call(sim.policy_choices), "max_agents": self.max_agents})
        )
        self.pages.add(page)
        sender = asyncio.create_task(self._send_frames(page))
        try:
            while True:
                received = await socket.receive()
                if received["type"] == "websocket.disconnect":
                    break
                try:
                    message = parse_message(received.get("text"), sim.env.num_worlds)  # type: ignore[union-attr]
                    if message["type"] == "view":
                        page.rect = message["rect"]
                        continue
                    notice = await self.call(self._apply, message)
                except (MessageError, ValueError) as error:  # the page's mistake: tell it, keep serving
                    await socket.send_text(json.dumps({"type": "error", "message": str(error)}))
                    continue
                if notice:
                    await socket.send_text(json.dumps({"type": "notice", "message": notice}))
                if message["type"] == "policy":  # the page's lists may show a new file
                    await socket.send_text(
                        json.dumps(
                            {
                                "type": "hello",
                                "choices": await self.call(sim.policy_choices),
                                "max_agents": self.max_agents,
                            }
                        )
                    )
        except WebSocketDisconnect:
            pass
        finally:
            self.pages.discard(page)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                await sender


def make_app(viewer: Viewer) -> Starlette:
    """The Starlette app of `viewer`: `/` the page, `/static/` its files, `/ws` the pages' sockets."""

    async def index(request):
        return HTMLResponse(asset("index.html"))

    @contextlib.asynccontextmanager
    async def lifespan(app):
        loop_task = asyncio.create_task(viewer.run())
        try:
            yield
        finally:
            loop_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await loop_task
            await viewer.close()

    return Starlette(
        routes=[
            Route("/", index),
            Mount("/static", StaticFiles(directory=STATIC), name="static"),
            WebSocketRoute("/ws", viewer.page_socket),
        ],
        lifespan=lifespan,
    )
