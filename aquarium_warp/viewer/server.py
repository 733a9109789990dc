"""The viewer's web server: a Starlette app (served by uvicorn) with the page, its files and one
WebSocket per page.

One loop advances the simulation on a thread of its own (a one-thread executor: the simulation is
never touched from two threads, and the event loop stays free to answer pages while a large world
steps) and publishes a snapshot of the displayed world at up to `fps` per second. Each page has a
sender that packs the newest snapshot for that page (its view rectangle, overlays and inspected agent,
at most `max_agents` agents) whenever the previous frame has gone out: a slow page gets fewer frames,
never a backlog. Overlays and the inspected agent are each page's own; the simulation's controls are
shared by all pages.

Recording: the renderer is built (its kernels compiled, seconds the first time) on a worker thread, from
start-up on; a record click while it is not ready shows the button busy ("preparing") and starts once it
is. Frames are drawn and encoded beside the simulation (`recording.Recorder`), `record_size` pixels on the
long side (768 by default: drawing and encoding a 1024 px frame take about 55 ms of CPU, which on a small
CPU takes the live rate below 30 frames a second). A recording started from a page ends when that page
closes.

Frame (binary, little-endian; about 10 bytes an agent): uint32 n_header, the header's JSON (n_header
bytes, padded with spaces to a multiple of 4), then for the header's `n` agents: uint32 [n] slots, uint16
[n, 2] positions as fractions of the world's size (x = q / 65536 * width: steps of width / 65536 px,
wrapping at the seam as the torus does), uint16 [n] headings as angles (atan2(hy, hx) = q / 65536 * 2 pi),
two bytes of padding when n is odd; when the page's velocity overlay is on (header `velocities`), float16
[n, 2] velocities (px/step); when its flow overlay is on, float32 [rows, cols, 2] currents (rows, cols in
the header's `flow_shape`). `unpack_frame` reads it back. The header's `inspect` holds
`simulation.inspect_agent` of the page's inspected agent.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import json
import os
import time
import weakref

import numpy as np
import uvicorn
from starlette.applications import Starlette
from starlette.responses import HTMLResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect, WebSocketDisconnected
from uvicorn.protocols.utils import ClientDisconnected

from ..render import Renderer
from .messages import OVERLAYS, MessageError, parse_message
from .recording import Recorder, asset

STATIC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")
# what sending to or receiving from a page that has gone raises: Starlette's after the close message,
# uvicorn's when the connection dropped first
GONE = (WebSocketDisconnect, WebSocketDisconnected, ClientDisconnected)


def _in_span(c: np.ndarray, low: float, high: float, size: float) -> np.ndarray:
    """Whether coordinate `c`, or one of its copies a world size `size` away (the torus), lies in [low, high]."""
    return (
        ((c >= low) & (c <= high)) | ((c + size >= low) & (c + size <= high)) | ((c - size >= low) & (c - size <= high))
    )


def select_agents(snapshot: dict, rect, max_agents: int, human: int | None) -> np.ndarray:
    """The slots a page is sent: live agents inside `rect` (x0, y0, x1, y1, counting their copies
    across the torus' seams; None: all), every predator and the human's agent always, prey thinned by
    a fixed stride down to `max_agents` in all."""
    alive = snapshot["alive"]
    position = snapshot["position"]
    header = snapshot["header"]
    prey_capacity = header["prey_capacity"]
    keep = alive.copy()
    if rect is not None:
        x0, y0, x1, y1 = rect
        keep &= _in_span(position[:, 0], x0, x1, header["width"]) & _in_span(position[:, 1], y0, y1, header["height"])
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


QUANTA = 65536  # steps of a position across the world and of a heading around the circle


def pack_frame(
    snapshot: dict,
    rect,
    max_agents: int,
    *,
    flow: bool = True,
    velocities: bool = True,
    inspect: int | None = None,
) -> bytes:
    """The binary frame of `snapshot` for a page showing `rect` (layout: the module's docstring), with
    the velocities when `velocities`, the flow's grid when `flow` (and the snapshot has one) and the
    inspection of slot `inspect` (when the snapshot has it)."""
    header = snapshot["header"]
    human = header["human"]["slot"] if header["human"] else None
    slots = select_agents(snapshot, rect, max_agents, human)
    size = np.array([header["width"], header["height"]])
    position = np.rint(snapshot["position"][slots] * (QUANTA / size)).astype(np.int64) % QUANTA
    heading = snapshot["heading"][slots]
    angle = np.rint(np.arctan2(heading[:, 1], heading[:, 0]) * (QUANTA / (2 * np.pi))).astype(np.int64) % QUANTA
    grid = snapshot["flow"] if flow else None
    header = {
        **header,
        "type": "frame",
        "n": len(slots),
        "alive_total": int(snapshot["alive"].sum()),
        "velocities": velocities,
        "flow_shape": None if grid is None else list(grid.shape[:2]),
        "inspect": snapshot["inspect"].get(inspect),
        "sent_at": time.time(),
    }
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 4)
    parts = [
        np.uint32(len(text)).astype("<u4").tobytes(),
        text,
        slots.astype("<u4").tobytes(),
        position.astype("<u2").tobytes(),
        angle.astype("<u2").tobytes(),
        b"\0\0" * (len(slots) % 2),
    ]
    if velocities:
        parts.append(snapshot["velocity"][slots].astype("<f2").tobytes())
    if grid is not None:
        parts.append(grid.astype("<f4").tobytes())
    return b"".join(parts)


def unpack_frame(data: bytes) -> tuple[dict, dict]:
    """(header, arrays) of a frame of `pack_frame`: `slots`, `position` [n, 2] and `heading` [n, 2]
    (float64, as the quanta give them), `velocity` [n, 2] (float32, or None) and `flow` (or None)."""
    length = int(np.frombuffer(data, "<u4", 1)[0])
    header = json.loads(data[4 : 4 + length])
    n, offset = header["n"], 4 + length
    slots = np.frombuffer(data, "<u4", n, offset)
    offset += 4 * n
    quanta = np.frombuffer(data, "<u2", 2 * n, offset).reshape(n, 2)
    offset += 4 * n
    angle = np.frombuffer(data, "<u2", n, offset) * (2 * np.pi / QUANTA)
    offset += 2 * n + 2 * (n % 2)
    velocity = None
    if header["velocities"]:
        velocity = np.frombuffer(data, "<f2", 2 * n, offset).reshape(n, 2).astype(np.float32)
        offset += 4 * n
    flow = None
    if header["flow_shape"] is not None:
        rows, cols = header["flow_shape"]
        flow = np.frombuffer(data, "<f4", rows * cols * 2, offset).reshape(rows, cols, 2)
    arrays = {
        "slots": slots,
        "position": quanta * (np.array([header["width"], header["height"]]) / QUANTA),
        "heading": np.stack([np.cos(angle), np.sin(angle)], axis=1),
        "velocity": velocity,
        "flow": flow,
    }
    return header, arrays


class _Page:
    """One connected page: its socket, view rectangle, overlays, inspected agent and a flag that a newer
    snapshot is waiting."""

    def __init__(self, socket: WebSocket):
        self.socket = socket
        self.rect: tuple[float, float, float, float] | None = None
        self.overlays = dict.fromkeys(OVERLAYS, False)
        self.inspect: int | None = None
        self.fresh = asyncio.Event()


class Viewer:
    """The server's state: the simulation (a `simulation.Simulation`, or `attach`'s run), its thread,
    the pages and the recording."""

    def __init__(
        self,
        simulation,
        *,
        fps: float = 30,
        max_agents: int = 100_000,
        record: str | None = None,
        record_dir: str = ".",
        record_size: int = 768,
    ):
        self.simulation = simulation
        self.fps, self.max_agents, self.record_dir, self.record_size = fps, max_agents, record_dir, record_size
        self._thread = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="aquarium-view")
        self.pages: set[_Page] = set()
        self.snapshot: dict | None = None
        self.recorder: Recorder | None = None
        self.recording = "off"  # "preparing" (the renderer is being built), "on"
        self._recording_page: _Page | None = None  # the page that started the recording (None: --record)
        self._record_path = record
        self._renderer: tuple[weakref.ref, asyncio.Future] | None = None  # (its env, the Renderer)
        self._tasks: set[asyncio.Task] = set()  # record requests waiting for the renderer
        self.frames = 0  # snapshots published (tests and the benchmark read it)
        self.frames_sent, self.bytes_sent = 0, 0  # to all pages (the benchmark's send rate)
        # Seconds spent in each stage of a frame, summed since start-up (the benchmark's breakdown): on the
        # simulation thread "step", "snapshot" (with the swarm metrics) and "record"; on the event loop
        # "pack" and "send" (over all pages).
        self.seconds = dict.fromkeys(("step", "snapshot", "record", "pack", "send"), 0.0)

    async def call(self, function, *args):
        """Run `function(*args)` on the simulation thread."""
        return await asyncio.get_running_loop().run_in_executor(self._thread, function, *args)

    def on_simulation_thread(self, function, *args):
        """Run `function(*args)` on the simulation thread and return its result (from any other thread:
        scripts and tests that change the state while the viewer runs)."""
        return self._thread.submit(function, *args).result()

    # ------------------------------------------------------------------ simulation thread
    def _tick(self, flow: bool, inspect: list[int], overlays: dict) -> dict:
        sim, seconds = self.simulation, self.seconds
        t0 = time.perf_counter()
        stepped = sim.advance()
        t1 = time.perf_counter()
        snapshot = sim.snapshot(flow, inspect)
        snapshot["header"]["recording"] = self.recording
        t2 = time.perf_counter()
        if self.recorder is not None and stepped:
            self.recorder.add(snapshot, overlays)
        seconds["step"] += t1 - t0
        seconds["snapshot"] += t2 - t1
        seconds["record"] += time.perf_counter() - t2
        return snapshot

    def _start_recording(self, renderer: Renderer, path: str) -> bool:
        """Start recording with `renderer`, if it still draws the simulation's env (a policy switch may
        have changed it meanwhile)."""
        if renderer.env is not self.simulation.env:
            return False
        self.recorder = Recorder(path, renderer, fps=self.fps)
        self.recording = "on"
        return True

    def _stop_recording(self) -> tuple[str, str] | None:
        recorder, self.recorder = self.recorder, None
        try:
            return None if recorder is None else recorder.close()
        finally:
            self.recording = "off"  # once the files are written

    def _apply(self, message: dict) -> str | None:
        """A checked simulation message, on the simulation thread; returns a notice for the page, if any."""
        env = self.simulation.env
        self.simulation.apply(message)
        if self.recorder is not None and self.simulation.env is not env:  # a new world: a new recording
            paths = self._stop_recording()
            return f"the teams' world changed: wrote {paths[0]} and {paths[1]}" if paths else None
        return None

    # ------------------------------------------------------------------ recording (event loop)
    def _renderer_for(self, env) -> asyncio.Future:
        """The renderer of `env`, built on a worker thread (compiling its kernels takes seconds the first
        time: the simulation and the pages go on meanwhile)."""
        if self._renderer is None or self._renderer[0]() is not env:
            build = functools.partial(Renderer, env, max_size=self.record_size)
            future = asyncio.get_running_loop().run_in_executor(None, build)
            future.add_done_callback(lambda f: f.cancelled() or f.exception())  # failures: reported by `record`
            self._renderer = (weakref.ref(env), future)
        return self._renderer[1]

    async def record(self, on: bool, page: _Page | None = None, path: str | None = None) -> str | None:
        """Start (once the renderer is ready) or stop recording; returns a notice. `page`: the page that
        asked (the recording ends when it closes)."""
        if not on:
            self._recording_page = None
            paths = await self.call(self._stop_recording)
            return None if paths is None else f"wrote {paths[0]} and {paths[1]}"
        if self.recording != "off":
            return None
        if path is None:
            path = os.path.join(self.record_dir, time.strftime("aquarium-%Y%m%d-%H%M%S.mp4"))
        self.recording = "preparing"
        try:
            while True:
                renderer = await self._renderer_for(self.simulation.env)
                if page is not None and page not in self.pages:
                    return None  # it closed while the renderer was built
                if await self.call(self._start_recording, renderer, path):
                    self._recording_page = page
                    return f"recording to {path}"
        finally:
            if self.recorder is None:
                self.recording = "off"

    def _recording_overlays(self) -> dict:
        """The overlays a recording draws: its page's (with --record: the first page's, else none)."""
        page = self._recording_page or next(iter(self.pages), None)
        return dict(page.overlays) if page is not None else dict.fromkeys(OVERLAYS, False)

    # ------------------------------------------------------------------ event loop
    async def run(self) -> None:
        """Tick at up to `fps` per second while the server runs and publish each snapshot to the pages."""
        if self._record_path is not None:
            await self.record(True, path=self._record_path)
        elif self.simulation.records:
            self._renderer_for(self.simulation.env)  # ready before the first click
        period = 1.0 / self.fps
        due = time.perf_counter()
        while True:
            flow = any(page.overlays["flow"] for page in self.pages)
            inspect = sorted({page.inspect for page in self.pages if page.inspect is not None})
            self.snapshot = await self.call(self._tick, flow, inspect, self._recording_overlays())
            self.frames += 1
            for page in self.pages:
                page.fresh.set()
            # Ticks keep to a schedule of `fps` a second: a late wake-up (the pages' sending shares this
            # loop) is made up at the next tick instead of adding to every interval; a tick that ran
            # over a whole period starts the schedule again from now.
            now = time.perf_counter()
            due = max(due + period, now)
            await asyncio.sleep(due - now)

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
                t0 = time.perf_counter()
                frame = pack_frame(
                    self.snapshot,
                    page.rect,
                    self.max_agents,
                    flow=page.overlays["flow"],
                    velocities=page.overlays["velocities"],
                    inspect=page.inspect,
                )
                t1 = time.perf_counter()
                await page.socket.send_bytes(frame)
                self.seconds["pack"] += t1 - t0
                self.seconds["send"] += time.perf_counter() - t1
                self.frames_sent += 1
                self.bytes_sent += len(frame)

    async def _hello(self, page: _Page) -> None:
        choices = await self.call(self.simulation.policy_choices)
        await page.socket.send_text(json.dumps({"type": "hello", "choices": choices, "max_agents": self.max_agents}))

    async def _tell(self, page: _Page, kind: str, text: str | None) -> None:
        if text and page in self.pages:
            with contextlib.suppress(*GONE):
                await page.socket.send_text(json.dumps({"type": kind, "message": text}))

    async def _record_for(self, page: _Page, on: bool) -> None:
        try:
            await self._tell(page, "notice", await self.record(on, page))
        except ValueError as error:
            await self._tell(page, "error", str(error))

    async def _handle(self, page: _Page, text) -> None:
        """One message of `page`: its own settings here, the simulation's on the simulation thread."""
        env = self.simulation.env
        message = parse_message(text, env.num_worlds, env.capacity)
        kind = message["type"]
        if kind == "view":
            page.rect = message["rect"]
        elif kind == "overlays":
            page.overlays = {name: message[name] for name in OVERLAYS}
        elif kind == "inspect":
            page.inspect = message["slot"]
        elif kind == "record":  # waits for the renderer: a task of its own, the page's messages go on
            self._tasks.add(task := asyncio.create_task(self._record_for(page, message["on"])))
            task.add_done_callback(self._tasks.discard)
        else:
            await self._tell(page, "notice", await self.call(self._apply, message))
            if kind == "policy":  # the page's lists may show a new file
                await self._hello(page)

    async def page_socket(self, socket: WebSocket) -> None:
        """One page: send it the choices, then frames; answer its messages (errors go back to it)."""
        await socket.accept()
        page = _Page(socket)
        sender = None
        try:
            await self._hello(page)
            self.pages.add(page)
            sender = asyncio.create_task(self._send_frames(page))
            while True:
                received = await socket.receive()
                if received["type"] == "websocket.disconnect":
                    break
                try:
                    await self._handle(page, received.get("text"))
                except (MessageError, ValueError) as error:  # the page's mistake: tell it, keep serving
                    await socket.send_text(json.dumps({"type": "error", "message": str(error)}))
        except GONE:
            pass
        finally:
            self.pages.discard(page)
            if sender is not None:
                sender.cancel()
                with contextlib.suppress(asyncio.CancelledError, *GONE):
                    await sender
            if self._recording_page is page and self.recording == "on":
                try:
                    notice = await self.record(False)
                    print(f"aquarium-warp view: the recording's page closed: {notice}")
                except ValueError as error:  # a failed recording: the page that would show it is gone
                    print(f"aquarium-warp view: {error}")


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


def server_config(viewer: Viewer, **options) -> uvicorn.Config:
    """uvicorn's settings for `viewer`'s app (`options`: host, port and the like). Per-message deflate is
    off: the frames are quantized binary that it shrinks by a fifth at about 70 ms a megabyte, which at
    100,000 agents held the send rate to 8 frames a second."""
    return uvicorn.Config(
        make_app(viewer), log_level="warning", ws="websockets-sansio", ws_per_message_deflate=False, **options
    )
