"""`aquarium-warp view`: a live viewer of the simulation in the browser, with human play, recording,
and static replay pages (docs/viewer.md). Needs the `viewer` extra: `pip install 'aquarium-warp[viewer]'`.

    aquarium-warp view --prey-policy prey-a --human predator        # prints the URL to open
    aquarium-warp view --replay run.json --out run.html             # a page that plays a recording

From Python, `attach(env)` serves your own env while your code steps it (`attached.py`), and
`widget.ViewerWidget` shows it in a notebook.

The server streams agent states (positions, headings, velocities) of one world to the page, which
draws them on a canvas: `server.py` (Starlette app, uvicorn), `simulation.py` (the env and teams),
`messages.py` (what a page may send), `recording.py` (MP4, trajectory, replay page), `static/` (the page).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import re
import signal
import socket

from ..agent_types import TYPES
from ..atomic import check_output_dir


def _port(text: str) -> int:
    if not re.fullmatch(r"\d{1,5}", text) or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be an integer in [1, 65535]")
    return int(text)


def _int_in(low: int, high: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = low - 1
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be an integer in [{low}, {high}]")
        return value

    return parse


def _fps(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if not 1 <= value <= 120:
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: must be a number in [1, 120]")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..arguments import DEVICE_HELP, POLICY_SPECS, non_negative_int, policy_spec, positive_float

    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to serve on (default 127.0.0.1: this machine only; reach it through an SSH tunnel)",
    )
    p.add_argument("--port", type=_port, default=8765, help="port, in [1, 65535] (default 8765)")
    p.add_argument(
        "--prey-policy",
        default="turnaway",
        type=policy_spec("prey"),
        help=f"{POLICY_SPECS['prey']} (default turnaway)",
    )
    p.add_argument(
        "--predator-policy",
        default="naivchase",
        type=policy_spec("predator"),
        help=f"{POLICY_SPECS['predator']} (default naivchase)",
    )
    p.add_argument(
        "--policy-dir", default=None, help="policy files (.pt, .onnx) under this folder may be chosen on the page"
    )
    p.add_argument(
        "--prey",
        type=_int_in(1, 10_000_000),
        default=None,
        help="prey per world, in [1, 10000000] (default: a trained policy's world, else 16)",
    )
    p.add_argument(
        "--predators",
        type=_int_in(1, 1_000_000),
        default=None,
        help="predators per world, in [1, 1000000] (default: a trained policy's world, else 1)",
    )
    p.add_argument("--width", type=positive_float, default=None, help="world width, px (default: the policy's, 800)")
    p.add_argument("--height", type=positive_float, default=None, help="world height, px (default: the policy's, 800)")
    p.add_argument("--worlds", type=_int_in(1, 65536), default=1, help="worlds, in [1, 65536]; the page shows one")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the worlds and the policies")
    p.add_argument("--device", default=None, help=DEVICE_HELP)
    p.add_argument(
        "--human",
        choices=TYPES,
        default=None,
        help="hand one agent of this team to the keyboard from the start (also on the page)",
    )
    p.add_argument(
        "--record",
        default=None,
        metavar="OUT.mp4",
        help="record from the start: the MP4 and OUT.json (the trajectory); stops with the record button or the server",
    )
    p.add_argument("--record-dir", default=".", help="folder of the record button's files (default: here)")
    p.add_argument(
        "--record-size",
        type=_int_in(64, 4096),
        default=768,
        help="the recording's long side in pixels, in [64, 4096] (default 768)",
    )
    p.add_argument("--fps", type=_fps, default=30.0, help="frames per second, in [1, 120] (default 30)")
    p.add_argument(
        "--max-agents",
        type=_int_in(100, 1_000_000),
        default=100_000,
        help="agents sent per frame, in [100, 1000000]: more are thinned (default 100000)",
    )
    p.add_argument(
        "--replay",
        default=None,
        metavar="FILE.json",
        help="no server: write --out, a page that plays this recorded trajectory",
    )
    p.add_argument("--out", default=None, metavar="PAGE.html", help="the replay page to write (with --replay)")


def run(args) -> int:
    """`aquarium-warp view`: serve the viewer (or, with --replay, write a replay page)."""
    from .recording import write_replay_page

    if args.replay is not None or args.out is not None:
        if args.replay is None or args.out is None:
            raise ValueError("--replay FILE.json and --out PAGE.html go together")
        write_replay_page(args.replay, args.out)
        print(f"aquarium-warp view: wrote {args.out}, a page that plays {args.replay}")
        return 0
    try:
        import uvicorn  # noqa: F401 - checked before anything else; `_serve` runs it
    except ImportError as error:  # an optional dependency
        raise ValueError(f"view needs the viewer extra: pip install 'aquarium-warp[viewer]' ({error})") from None
    from ..video import check_video_path

    if args.record is not None:
        try:  # the MP4 and the trajectory beside it: a folder that cannot take them is refused now
            check_video_path(args.record)
        except ValueError as error:
            raise ValueError(f"--record: {error}") from None
    if not os.path.isdir(args.record_dir):
        raise ValueError(f"--record-dir {args.record_dir}: not a folder")
    check_output_dir(args.record_dir, "--record-dir")
    if args.policy_dir is not None and not os.path.isdir(args.policy_dir):
        raise ValueError(f"--policy-dir {args.policy_dir}: not a folder")
    return _serve(args)


def _serve(args) -> int:
    """Build the world and serve it until Ctrl-C."""
    import torch

    from ..arguments import plural
    from .server import Viewer, server_config
    from .simulation import Simulation, ViewOptions

    # Bound before anything else: a port in use is refused at once in one line, before the world is built
    # or "open http://..." printed.
    listening = bind(args.host, args.port, "--port")
    with listening:
        options = ViewOptions(
            prey_policy=args.prey_policy,
            predator_policy=args.predator_policy,
            prey=args.prey,
            predators=args.predators,
            width=args.width,
            height=args.height,
            worlds=args.worlds,
            seed=args.seed,
            device=args.device,
            policy_dir=args.policy_dir,
            human=args.human,
        )
        simulation = Simulation(options)
        env = simulation.env
        assert env is not None
        if env.torch_device.type == "cpu":
            # Warp's CPU shards take every core already; torch's own pool on top (a trained policy's
            # inference) would fight them and the browser for the same cores.
            torch.set_num_threads(1)
        viewer = Viewer(
            simulation,
            fps=args.fps,
            max_agents=args.max_agents,
            record=args.record,
            record_dir=args.record_dir,
            record_size=args.record_size,
        )
        print(
            f"aquarium-warp view: {plural(env.num_worlds, 'world')} of {env.config.prey_count} prey "
            f"({simulation.specs['prey']}) and {plural(env.config.predator_count, 'predator')} "
            f"({simulation.specs['predator']}) on {env.device}"
        )
        print(f"aquarium-warp view: open http://{args.host}:{args.port}/  (Ctrl-C stops)", flush=True)
        serve(_server_class()(server_config(viewer)), sockets=[listening])
    return 0


def bind(host: str, port: int, name: str) -> socket.socket:
    """A listening socket on `host`:`port`; ValueError naming `name` when that address cannot be served."""
    try:
        return socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET)
    except OSError as error:
        cause = os.strerror(error.errno) if error.errno else str(error)  # not create_server's address suffix
        raise ValueError(f"{name} {port}: cannot serve on {host}:{port} ({cause})") from None


def attach(env, **options):
    """Serve `env` in the browser while your code steps it (`attached.attach`: returns at once)."""
    from .attached import attach as serve_env

    return serve_env(env, **options)


def _server_class():
    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, whose signals `serve` takes: uvicorn raises the ones it caught again once it
        has shut down, inside asyncio's runner, where a second Ctrl-C ends in a traceback of the cancelled
        lifespan task (and exit status 0)."""

        @contextlib.contextmanager
        def capture_signals(self):
            yield

    return Server


def serve(server, sockets=None) -> None:
    """Run a uvicorn `server` until SIGINT or SIGTERM: the first shuts it down gracefully, a second at
    once (uvicorn's `handle_exit`); then `Interrupted` with the signal's exit code (130 for Ctrl-C)."""
    from ..arguments import Interrupted

    received: list[int] = []
    log = logging.getLogger("uvicorn.error")
    level = log.level

    def stop(signum, frame) -> None:
        received.append(signum)
        if len(received) > 1:  # a forced exit cancels the app's lifespan, which logs that as a traceback
            log.setLevel(logging.CRITICAL)
        server.handle_exit(signum, frame)

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        server.run(sockets=sockets)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        log.setLevel(level)
    if received:
        name = "interrupted" if received[0] == signal.SIGINT else "terminated (SIGTERM)"
        raise Interrupted(name, received[0])
