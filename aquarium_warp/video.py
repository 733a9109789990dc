"""MP4 videos of Aquarium worlds, written through imageio-ffmpeg (its bundled ffmpeg; nothing else to
install). Needs the `video` extra: `pip install 'aquarium-warp[video]'`.

```python
from aquarium_warp.video import record, write_video
record(env, {"prey": prey, "predator": predator}, steps=600, path="demo.mp4", view_cones=True)
write_video(list_of_frames, "frames.mp4", fps=30)
```

`record` runs the episode loop (`rollout.rollout`) with a `Frames` observer writing into `video_file`.
"""

from __future__ import annotations

import contextlib
import errno
import fractions
import math
import os
import signal
import subprocess
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sized
from typing import NoReturn

import numpy as np

from .atomic import atomic_path, os_error_cause, partial_name
from .render import Renderer, check_frame
from .rollout import Drivers, Observer, rollout

# x264's presets, fastest first
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")


def _frame_iter(frames, num_frames):
    if callable(frames):
        if num_frames is None:
            raise ValueError("a callable `frames` needs num_frames (it is called as frames(i), i < num_frames)")
        for i in range(num_frames):
            frame = frames(i)
            if frame is None:  # the callable may end the video early
                return
            yield frame
    else:
        for i, frame in enumerate(frames):
            if num_frames is not None and i >= num_frames:
                return
            yield frame


def _check_frame(frame, expected_shape) -> np.ndarray:
    frame = check_frame(frame, "video frame")
    if expected_shape is not None and frame.shape != expected_shape:
        raise ValueError(f"video frames must all have one shape: got {list(frame.shape)} after {list(expected_shape)}")
    return frame


def check_video_path(path) -> None:
    """ffmpeg picks the container from the file name's extension, and tells that it cannot write the file
    only after it started: refuse a name that does not end in .mp4, and a file that cannot be created,
    up front (one `ValueError`). Creating it is the test: a folder's permissions may allow what its file
    system refuses (a read-only mount, /proc)."""
    if os.path.splitext(str(path))[1].lower() != ".mp4":
        raise ValueError(f"cannot write {path}: the file name must end in .mp4 (an H.264 MP4 video)")
    folder = os.path.dirname(os.path.abspath(str(path)))
    if not os.path.isdir(folder):
        raise ValueError(f"cannot write {path}: folder {folder} does not exist")
    if os.path.isdir(path):
        raise ValueError(f"cannot write {path}: it is a folder")
    probe = partial_name(path)
    try:
        with open(probe, "wb"):
            pass
        os.remove(probe)
    except OSError as error:
        raise ValueError(f"cannot write {path}: {os_error_cause(error)}") from None


def write_video(
    frames: Iterable[np.ndarray] | Callable[[int], np.ndarray | None],
    path,
    fps: float = 30,
    progress: bool = True,
    num_frames: int | None = None,
    quality: float = 7,
    preset: str | None = None,
) -> int:
    """Write RGB uint8 frames `[H, W, 3]` to an H.264 MP4 file at `path`; returns the frame count.

    `frames` is an iterable of frames, or a callable called as `frames(i)` for `i < num_frames` (it may
    return None to stop early). `num_frames` also caps an iterable and sizes the progress bar (tqdm,
    when installed and `progress`). Frames of odd width or height are padded by one edge pixel (the
    yuv420p format most players need works on 2 x 2 blocks). `quality`: 1 (smallest) to 10 (best), or
    None for ffmpeg's default. `preset`: x264's speed for size trade (one of `PRESETS`, "ultrafast" the
    fastest and largest file), None for its default ("medium").
    """
    if num_frames is not None and (isinstance(num_frames, bool) or not isinstance(num_frames, int) or num_frames < 0):
        raise ValueError(f"num_frames={num_frames!r} must be None or an integer >= 0")
    total = num_frames if num_frames is not None else (len(frames) if isinstance(frames, Sized) else None)
    count = 0
    with video_file(path, fps=fps, progress=progress, total=total, quality=quality, preset=preset) as add:
        for frame in _frame_iter(frames, num_frames):
            add(frame)
            count += 1
    return count


@contextlib.contextmanager
def video_file(
    path,
    fps: float = 30,
    progress: bool = True,
    total: int | None = None,
    quality: float = 7,
    preset: str | None = None,
) -> Iterator[Callable[[np.ndarray], None]]:
    """An H.264 MP4 file at `path` written one frame at a time: `with video_file(path) as add: add(frame)`.
    Checks the arguments before ffmpeg starts; the file appears whole when the block ends (a kill or a
    full disk leaves none), and a block that added no frame raises a ValueError. `total`: the frames
    expected, for the progress bar (tqdm, when installed and `progress`); the rest as `write_video`."""
    try:
        import imageio_ffmpeg
    except ImportError as error:  # an optional dependency
        raise ImportError("write_video needs imageio-ffmpeg: pip install 'aquarium-warp[video]'") from error
    if not (isinstance(fps, (int, float)) and not isinstance(fps, bool) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps={fps!r} must be a finite number > 0")
    # imageio-ffmpeg asserts this range; checked here to fail with a ValueError before ffmpeg starts
    if quality is not None and not (
        isinstance(quality, (int, float)) and not isinstance(quality, bool) and 1 <= quality <= 10
    ):
        raise ValueError(f"quality={quality!r} must be None or a number in [1, 10]")
    if preset is not None and preset not in PRESETS:
        raise ValueError(f"preset={preset!r} must be None or one of {list(PRESETS)}")
    check_video_path(path)
    bar = None
    if progress:
        try:
            from tqdm import tqdm

            bar = tqdm(total=total, unit="frame", desc=os.path.basename(str(path)))
        except ImportError:
            pass
    ffmpeg: _Ffmpeg | None = None
    shape = None
    count = 0
    # ffmpeg writes a partial file, renamed when the video is whole (a kill or a full disk leaves none)
    with atomic_path(path) as partial:

        def add(frame: np.ndarray) -> None:
            nonlocal ffmpeg, shape, count
            frame = _check_frame(frame, shape)
            shape = frame.shape
            h, w = shape[:2]
            if ffmpeg is None:
                size = (w + w % 2, h + h % 2)
                ffmpeg = _Ffmpeg(imageio_ffmpeg.get_ffmpeg_exe(), partial, path, size, fps, quality, preset)
            if h % 2 or w % 2:
                frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
            ffmpeg.write(np.ascontiguousarray(frame).tobytes())
            count += 1
            if bar is not None:
                bar.update(1)

        try:
            yield add
        except BaseException:
            if ffmpeg is not None:  # an error or Ctrl-C: no video, and no complaint of ffmpeg's about a cut frame
                ffmpeg.kill()
            raise
        finally:
            if bar is not None:
                bar.close()
        if ffmpeg is not None:
            ffmpeg.finish()
        if count == 0:
            raise ValueError("write_video got no frames")


class _Ffmpeg:
    """imageio-ffmpeg's ffmpeg encoding raw RGB frames from a pipe into `partial` (H.264, yuv420p, as its
    `write_frames`, whose errors are a "Broken pipe" plus a dump of its command and ffmpeg's own output).
    ffmpeg's messages go to a temporary file; a failure is one `OSError` naming `path` and ffmpeg's cause.
    It runs in a session of its own, so that a Ctrl-C reaches only this process, which then kills it."""

    def __init__(
        self, exe: str, partial: str, path, size: tuple[int, int], fps: float, quality: float | None, preset: str | None
    ):
        # imageio-ffmpeg's quality scale: 10 is crf 0 (lossless), 1 is crf 45
        crf = [] if quality is None else ["-crf", str(int((1 - quality / 10) * 51))]
        crf += [] if preset is None else ["-preset", preset]
        command = [exe, "-y", "-f", "rawvideo", "-vcodec", "rawvideo", "-s", f"{size[0]}x{size[1]}"]
        rate = str(fractions.Fraction(fps).limit_denominator())  # as imageio-ffmpeg: 29.97 stays 2997/100
        command += ["-pix_fmt", "rgb24", "-r", rate, "-i", "-", "-an", "-vcodec", "libx264"]
        command += ["-pix_fmt", "yuv420p", *crf, "-v", "error", partial]
        self.path = os.fspath(path)
        self.log = tempfile.TemporaryFile()
        self.process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self.log, start_new_session=True
        )

    def write(self, data: bytes) -> None:
        try:
            self.process.stdin.write(data)  # type: ignore[union-attr]
        except OSError:  # ffmpeg is gone: its own words say why
            self.process.wait()
            self._fail()

    def finish(self) -> None:
        with contextlib.suppress(OSError):  # a failed flush shows in ffmpeg's exit status
            self.process.stdin.close()  # type: ignore[union-attr]
        if self.process.wait() != 0:
            self._fail()
        self.log.close()

    def kill(self) -> None:
        self.process.kill()
        self.process.wait()
        with contextlib.suppress(OSError):
            self.process.stdin.close()  # type: ignore[union-attr]
        self.log.close()

    def _fail(self) -> NoReturn:
        self.log.seek(0)
        lines = [line.strip() for line in self.log.read().decode(errors="replace").splitlines() if line.strip()]
        self.log.close()
        code = self.process.returncode
        if any("No space left" in line for line in lines):
            raise OSError(errno.ENOSPC, "no space left on device", self.path)
        # the last message is ffmpeg's conclusion; a kill (e.g. a file size limit) leaves none
        cause = (
            lines[-1]
            if lines
            else (f"ffmpeg killed by {signal.Signals(-code).name}" if code < 0 else f"ffmpeg exit status {code}")
        )
        raise OSError(errno.EIO, f"ffmpeg could not write the video ({cause})", self.path)


class Frames(Observer):
    """An observer of the episode loop (`rollout.rollout`) that renders world `world` (`Renderer.render`
    with `overlays`) at the start and after every step, and hands each frame to `add`."""

    def __init__(self, renderer: Renderer, add: Callable[[np.ndarray], object], world: int = 0, **overlays):
        self.renderer, self.add, self.world, self.overlays = renderer, add, world, overlays

    def on_start(self, env) -> None:
        self.add(self.renderer.render(self.world, **self.overlays))

    def on_step(self, env, step: int, result) -> None:
        self.add(self.renderer.render(self.world, **self.overlays))


def record(
    env,
    drivers: Drivers,
    steps: int,
    path,
    world: int = 0,
    *,
    fps: float = 30,
    progress: bool = True,
    width_px: int | None = None,
    height_px: int | None = None,
    view_cones: bool = False,
    hit_boxes: bool = False,
    velocities: bool = False,
    draw_flow: bool = False,
    quality: float = 7,
) -> int:
    """Step `env` `steps` times with `drivers` and write world `world` as an MP4 video at `path`.

    `drivers`: `{team: driver}` (`drivers.make_drivers`), or a function of the env's current
    observations returning the actions dict for `env.step` (`{"prey": [W, prey_capacity], "predator":
    [W, predator_capacity]}` int tensors); every step's actions are checked. The env is not reset: the
    video starts from its current state. Writes `steps + 1` frames (the current state, then the state
    after each step) and returns that count. A world whose episode ends resets itself inside `step()`,
    so the video then continues with the new episode.
    """
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"steps={steps!r} must be an integer >= 0")
    renderer = Renderer(env, width_px, height_px)
    overlays = dict(view_cones=view_cones, hit_boxes=hit_boxes, velocities=velocities, draw_flow=draw_flow)
    renderer.check_world(world)  # before ffmpeg starts
    with video_file(path, fps=fps, progress=progress, total=steps + 1, quality=quality) as add:
        rollout(env, drivers, steps, [Frames(renderer, add, world, **overlays)], reset=False, validate=True)
    return steps + 1
