"""Frame rates of `aquarium-warp view` with a real page (headless system chromium through Selenium, on
the same machine; its WebGL2 runs on SwiftShader there), for worlds at the density of docs/model.md's
world: the server's published and sent frames per second (and bytes per frame, MB/s), the page's received
and drawn frames per second, then with the world paused and the page drawing at every animation frame
(its draw rate for that many agents). Prints a table and writes viewer.json.

    python benchmarks/bench_viewer.py --agents 1000 20000 100000 --seconds 8 --out benchmarks/results/viewer_cpu
    python benchmarks/bench_viewer.py --agents 1000 --record --out /tmp/viewer   # also while recording
    python benchmarks/bench_viewer.py --agents 20000 --renderer canvas2d         # the page's ?renderer=
    python benchmarks/bench_viewer.py --device cuda:0 --browser-flag=--use-gl=angle \
        --browser-flag=--use-angle=gl-egl --browser-flag=--ignore-gpu-blocklist   # a GPU host's GPU (NVIDIA)
    python benchmarks/bench_viewer.py --agents 100000 --page socket   # the server alone: a client that reads
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "app"))
from test_viewer import _browser, serve  # the tests' server thread and browser

from aquarium_warp.records import command_line, git_info, machine_info
from aquarium_warp.viewer.server import Viewer
from aquarium_warp.viewer.simulation import Simulation, ViewOptions


def _rates(page, viewer, seconds: float) -> dict:
    """Per-second rates over `seconds`: frames the server published and sent (and MB sent), steps of
    world 0, frames the page received and drew, the mean size of the frames sent, and the server's
    milliseconds per frame in each stage (`_stage_ms`)."""
    read = "const a = window.aquarium; return [a.framesReceived, a.framesDrawn]"

    def counts():
        sent = viewer.frames_sent, viewer.bytes_sent
        return viewer.frames, sent, int(viewer.simulation.env.state.torch.world_step[0]), page.execute_script(read)

    (frames0, (sent0, bytes0), steps0, (received0, drawn0)), t0 = counts(), time.perf_counter()
    stages0 = dict(viewer.seconds)
    time.sleep(seconds)
    (frames1, (sent1, bytes1), steps1, (received1, drawn1)), t1 = counts(), time.perf_counter()
    elapsed = t1 - t0
    return {
        "server_frames_per_s": round((frames1 - frames0) / elapsed, 2),
        "sent_frames_per_s": round((sent1 - sent0) / elapsed, 2),
        "sent_mb_per_s": round((bytes1 - bytes0) / elapsed / 1e6, 2),
        "bytes_per_frame": round((bytes1 - bytes0) / max(1, sent1 - sent0)),
        "steps_per_s": round((steps1 - steps0) / elapsed, 2),
        "page_frames_received_per_s": round((received1 - received0) / elapsed, 2),
        "page_frames_drawn_per_s": round((drawn1 - drawn0) / elapsed, 2),
        **_stage_ms(viewer, stages0, frames1 - frames0, sent1 - sent0),
    }


def _stage_ms(viewer, before: dict, frames: int, sent: int) -> dict:
    """The server's mean milliseconds per frame in each stage since `before` (`Viewer.seconds`): step,
    snapshot and record per published frame, pack and send per sent frame."""
    per = {"step": frames, "snapshot": frames, "record": frames, "pack": sent, "send": sent}
    return {f"{k}_ms": round((viewer.seconds[k] - before[k]) * 1e3 / max(1, per[k]), 2) for k in per}


def world_options(agents: int, device: str) -> ViewOptions:
    """A world of `agents` (one predator per 100) at docs/model.md's density: 17 agents on 800 x 800 px."""
    predators = max(1, agents // 100)
    side = 800.0 * (agents / 17) ** 0.5
    return ViewOptions(prey=agents - predators, predators=predators, width=side, height=side, device=device)


def measure(
    agents: int,
    seconds: float,
    max_agents: int,
    device: str,
    record: str | None = None,
    query: str = "",
    flags: tuple[str, ...] = (),
) -> dict:
    """The rates of a world of `agents` at docs/model.md's density: while it runs (and records, with
    `record`), then (not recording) paused with the page drawing at every animation frame: how fast the
    page draws that many agents, and the server's send rate of frames that need no step."""
    options = world_options(agents, device)
    predators, side = options.predators, options.width
    start = time.perf_counter()
    say = lambda what: print(f"  {agents} agents: {what} at {time.perf_counter() - start:.1f} s", flush=True)  # noqa: E731
    viewer = Viewer(Simulation(options), max_agents=max_agents, record=record)
    say("simulation built")
    with serve(viewer) as port:
        page = _browser(*flags)
        say("browser started")
        try:
            page.get(f"http://127.0.0.1:{port}/{query}")
            deadline = time.time() + 60
            while page.execute_script("return window.aquarium.framesDrawn") < 3:
                assert time.time() < deadline, "no frame reached the page"
                time.sleep(0.1)
            say("frames drawn")
            running = _rates(page, viewer, seconds)
            paused = None
            if record is None:
                viewer.on_simulation_thread(viewer.simulation.apply, {"type": "pause"})
                page.execute_script("window.aquarium.redrawAlways = true")
                time.sleep(1.0)
                paused = _rates(page, viewer, seconds)
            sent = page.execute_script("return window.aquarium.frame.header.n")
            renderer = page.execute_script("return window.aquarium.renderer")
            gpu = page.execute_script("return window.aquarium.glName")
            console = [e["message"][:300] for e in page.get_log("browser") if e["level"] in ("WARNING", "SEVERE")]
        finally:
            page.quit()
    row = {
        "agents": agents,
        "recording": record is not None,
        "renderer": renderer,
        "gl_renderer": gpu,
        "prey": agents - predators,
        "predators": predators,
        "world_px": round(side),
        "max_agents": max_agents,
        "agents_sent_per_frame": sent,
        **running,
        "console": console[:5],  # the page's first warnings and errors (why WebGL2 was not used, say)
    }
    if paused is not None:
        row.update(
            paused_page_draws_per_s=paused["page_frames_drawn_per_s"],
            paused_sent_frames_per_s=paused["sent_frames_per_s"],
            paused_sent_mb_per_s=paused["sent_mb_per_s"],
            paused_page_frames_received_per_s=paused["page_frames_received_per_s"],
        )
    return row


def measure_server(agents: int, seconds: float, max_agents: int, device: str) -> dict:
    """The server's rates for one page that is a websockets client reading every frame (no browser, so
    no drawing competes for the CPU): running, then paused (frames that need no step)."""
    import threading

    from websockets.sync.client import connect

    options = world_options(agents, device)
    viewer = Viewer(Simulation(options), max_agents=max_agents)
    received, stop = [0], threading.Event()
    with serve(viewer) as port, connect(f"ws://127.0.0.1:{port}/ws", max_size=None) as socket:

        def read() -> None:  # as a page does, offering per-message deflate (websockets' default)
            while not stop.is_set():
                if isinstance(socket.recv(timeout=10), bytes):
                    received[0] += 1

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        time.sleep(2.0)
        rates = []
        for paused in (False, True):
            if paused:
                viewer.on_simulation_thread(viewer.simulation.apply, {"type": "pause"})
                time.sleep(1.0)
            frames0, sent0, bytes0, got0, t0 = (
                viewer.frames,
                viewer.frames_sent,
                viewer.bytes_sent,
                received[0],
                time.perf_counter(),
            )
            stages0 = dict(viewer.seconds)
            time.sleep(seconds)
            elapsed = time.perf_counter() - t0
            rates.append({
                "server_frames_per_s": round((viewer.frames - frames0) / elapsed, 2),
                "sent_frames_per_s": round((viewer.frames_sent - sent0) / elapsed, 2),
                "sent_mb_per_s": round((viewer.bytes_sent - bytes0) / elapsed / 1e6, 2),
                "client_frames_per_s": round((received[0] - got0) / elapsed, 2),
                **_stage_ms(viewer, stages0, viewer.frames - frames0, viewer.frames_sent - sent0),
            })  # fmt: skip
        stop.set()
        reader.join()
    row = {"agents": agents, "page": "socket", "prey": options.prey, "predators": options.predators, **rates[0]}
    return row | {f"paused_{key}": value for key, value in rates[1].items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", type=int, nargs="+", default=[1000, 100000])
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--max-agents", type=int, default=100000)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--out", default=os.path.join("benchmarks", "results", "viewer_cpu"))
    parser.add_argument("--record", action="store_true", help="also measure each size while recording an MP4")
    parser.add_argument(
        "--renderer",
        choices=("auto", "webgl2", "canvas2d"),
        default="auto",
        help="the page's ?renderer= (auto: WebGL2 from 2,000 agents when offered)",
    )
    parser.add_argument(
        "--browser-flag",
        action="append",
        default=[],
        help="a chromium command-line flag (repeat the option); e.g. ANGLE on Vulkan for a GPU host's GPU",
    )
    parser.add_argument(
        "--page",
        choices=("chromium", "socket"),
        default="chromium",
        help="who reads the frames: headless chromium drawing them (default), or a websockets client that "
        "only reads them (the server's own rates)",
    )
    args = parser.parse_args()
    query = f"?renderer={args.renderer}"
    flags = tuple(args.browser_flag)
    rows = []
    for n in args.agents:
        if args.page == "socket":
            rows.append(measure_server(n, args.seconds, args.max_agents, args.device))
        else:
            rows.append(measure(n, args.seconds, args.max_agents, args.device, query=query, flags=flags))
        print(f"  {n} agents: {json.dumps(rows[-1])}", flush=True)
    if args.record and args.page == "chromium":
        with tempfile.TemporaryDirectory() as folder:
            for n in args.agents:
                path = os.path.join(folder, f"{n}.mp4")
                rows.append(measure(n, args.seconds, args.max_agents, args.device, path, query, flags))
    chromium = subprocess.run([shutil.which("chromium") or "chromium", "--version"], capture_output=True, text=True)
    info = machine_info(args.device)
    result = {
        "command": command_line(sys.argv, "python"),
        "git": git_info(),
        "device": args.device,
        "device_name": info["device_name"],
        "versions": {k: info[k] for k in ("python", "warp", "torch")},
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count(),
            "system": platform.platform(),
            "browser": chromium.stdout.strip(),
            "browser_flags": list(flags),
        },
        "rows": rows,
    }
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "viewer.json"), "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    columns = [
        ("agents", "agents"),
        ("recording", "rec"),
        ("renderer", "renderer"),
        ("agents_sent_per_frame", "sent"),
        ("bytes_per_frame", "bytes/frame"),
        ("server_frames_per_s", "server fps"),
        ("sent_frames_per_s", "sent fps"),
        ("page_frames_drawn_per_s", "page fps"),
        ("paused_page_draws_per_s", "paused: draws/s"),
        ("paused_sent_frames_per_s", "paused: sent/s"),
        ("paused_sent_mb_per_s", "paused: MB/s"),
        ("step_ms", "step ms"),
        ("snapshot_ms", "snapshot ms"),
        ("record_ms", "record ms"),
        ("pack_ms", "pack ms"),
        ("send_ms", "send ms"),
    ]
    print(" | ".join(title for _, title in columns))
    for row in rows:
        print(" | ".join(str(row.get(key, "-")) for key, _ in columns))
    return 0


if __name__ == "__main__":
    sys.exit(main())
