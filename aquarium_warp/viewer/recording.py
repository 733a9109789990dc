"""Recordings of the viewer: the MP4 of the displayed world (drawn by the Warp rasteriser with the
page's overlays, written by `video.write_video`) and a trajectory file that the static replay page plays.

Trajectory file (JSON): `{"format": "aquarium-warp-replay", "version": 1, "meta": {...}, "frames": [...]}`;
`meta` holds the world's size, `prey_capacity`, the agent types' radius / view distance / fov and the
teams' policies; each frame holds the header values the live page shows (step, captures, polarization,
groups) and the live agents: `slot`, `x`, `y` (px, 0.1 px), `hx`, `hy` (unit heading, 0.001), `vx`,
`vy` (px/step, 0.01). A slot below `prey_capacity` is a prey, else a predator.
"""

from __future__ import annotations

import json
import os
import queue
import threading
from importlib import resources

import numpy as np

from ..atomic import atomic_open
from ..video import check_video_path, write_video

FORMAT = "aquarium-warp-replay"
VERSION = 1
# the header values that a frame of a trajectory keeps
FRAME_KEYS = ("step", "episode", "episode_captures", "polarization", "groups", "prey_alive", "predator_alive")


def trajectory_frame(snapshot: dict) -> dict:
    """The trajectory frame of a `Simulation.snapshot`: its live agents, rounded (files stay small)."""
    alive = np.flatnonzero(snapshot["alive"])
    p, h, v = snapshot["position"][alive], snapshot["heading"][alive], snapshot["velocity"][alive]
    frame = {key: snapshot["header"][key] for key in FRAME_KEYS}
    frame.update(
        slot=alive.tolist(),
        x=np.round(p[:, 0], 1).tolist(),
        y=np.round(p[:, 1], 1).tolist(),
        hx=np.round(h[:, 0], 3).tolist(),
        hy=np.round(h[:, 1], 3).tolist(),
        vx=np.round(v[:, 0], 2).tolist(),
        vy=np.round(v[:, 1], 2).tolist(),
    )
    human = snapshot["header"]["human"]
    frame["human"] = None if human is None else human["slot"]
    return frame


def trajectory_meta(snapshot: dict) -> dict:
    header = snapshot["header"]
    return {key: header[key] for key in ("width", "height", "prey_capacity", "types", "specs", "world")}


class Recorder:
    """Writes `path` (MP4) and `path` with `.json` (the trajectory) from the snapshots it is given.

    The MP4's frames are drawn and encoded on a thread of its own (from `Renderer.freeze` copies of the
    world, through `write_video` with x264's "veryfast" preset: a third of the default's CPU time for a
    file about 30% larger), so the simulation goes on meanwhile; it waits only when that thread falls 16
    frames behind. `close()` finishes both files and returns their paths.
    """

    def __init__(self, path: str, renderer, fps: float = 30):
        check_video_path(path)
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise ValueError(f"cannot record to {path}: folder {folder} does not exist")
        self.path, self.json_path = path, os.path.splitext(path)[0] + ".json"
        self._renderer = renderer
        self._frames: queue.Queue = queue.Queue(maxsize=16)  # the simulation waits when this thread falls behind
        self._trajectory: list[dict] = []
        self._meta: dict | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._encode, args=(fps,), daemon=True)
        self._thread.start()

    def _encode(self, fps: float) -> None:
        def frames():
            while (item := self._frames.get()) is not None:
                frozen, overlays = item
                yield self._renderer.render(
                    frozen=frozen,
                    view_cones=overlays["view_cones"],
                    hit_boxes=overlays["hit_boxes"],
                    velocities=overlays["velocities"],
                    draw_flow=overlays["flow"],
                )

        try:
            write_video(frames(), self.path, fps=fps, progress=False, preset="veryfast")
        except (ValueError, OSError, RuntimeError) as error:  # reported by close(), not lost with the thread
            self._error = error
            while self._frames.get() is not None:  # let the simulation thread go on
                pass

    def add(self, snapshot: dict, overlays: dict) -> None:
        """One frame: the displayed world as it is now, drawn with `overlays`, and its trajectory frame."""
        if self._meta is None:
            self._meta = trajectory_meta(snapshot)
        self._trajectory.append(trajectory_frame(snapshot))
        self._frames.put((self._renderer.freeze(snapshot["header"]["world"]), dict(overlays)))

    def close(self) -> tuple[str, str]:
        self._frames.put(None)
        self._thread.join()
        write_trajectory(self.json_path, self._meta or {}, self._trajectory)
        if self._error is not None:
            raise ValueError(f"recording {self.path} failed: {self._error}")
        return self.path, self.json_path


def write_trajectory(path: str, meta: dict, frames: list[dict]) -> None:
    with atomic_open(path) as f:
        json.dump({"format": FORMAT, "version": VERSION, "meta": meta, "frames": frames}, f, separators=(",", ":"))


def read_trajectory(path: str) -> dict:
    """A trajectory file, checked for its format (ValueError naming the file otherwise)."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except (OSError, ValueError) as error:
        raise ValueError(f"--replay {path}: cannot read a trajectory file ({error})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != VERSION:
        raise ValueError(f"--replay {path}: not an {FORMAT} file of version {VERSION}")
    if not data.get("frames"):
        raise ValueError(f"--replay {path}: the trajectory has no frames")
    return data


def asset(name: str) -> str:
    """The text of one of the page's files (`aquarium_warp/viewer/static/`)."""
    return (resources.files(__package__) / "static" / name).read_text(encoding="utf-8")


def replay_page(trajectory: dict) -> str:
    """A self-contained HTML page (script, style and trajectory inline) that plays `trajectory`
    without a server: open it from disk or put it on any static site."""
    data = json.dumps(trajectory, separators=(",", ":")).replace("</", "<\\/")  # no early </script>
    page = asset("index.html")
    page = page.replace('<link rel="stylesheet" href="static/viewer.css">', f"<style>{asset('viewer.css')}</style>")
    page = page.replace(
        '<script src="static/webgl.js"></script>',
        f'<script id="replay-data" type="application/json">{data}</script>\n<script>{asset("webgl.js")}</script>',
    )
    page = page.replace('<script src="static/viewer.js"></script>', f"<script>{asset('viewer.js')}</script>")
    return page


def write_replay_page(trajectory_path: str, out: str) -> None:
    if not out.endswith(".html"):
        raise ValueError(f"--out {out}: the replay page's name must end in .html")
    folder = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(folder):
        raise ValueError(f"--out {out}: folder {folder} does not exist")
    page = replay_page(read_trajectory(trajectory_path))
    with atomic_open(out) as f:
        f.write(page)


def record_trajectory(simulation, steps: int, path: str) -> int:
    """Step `simulation` (a `viewer.simulation.Simulation`) `steps` times without a server and write the
    trajectory of its displayed world to `path` (the current state, then one frame per step); returns
    the frame count. The docs' replays of the shipped policies are made with it (docs/viewer.md)."""
    snapshot = simulation.snapshot()
    frames = [trajectory_frame(snapshot)]
    for _ in range(steps):
        simulation.step()
        frames.append(trajectory_frame(simulation.snapshot()))
    write_trajectory(path, trajectory_meta(snapshot), frames)
    return len(frames)
