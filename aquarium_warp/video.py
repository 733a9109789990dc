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
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sized

import numpy as np

from .atomic import atomic_path
from .render import Renderer, check_frame
from .rollout import Drivers, Observer, rollout


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
    """ffmpeg picks the container from the file name's extension, and fails only after it started
    without one: refuse a name that does not end in .mp4 up front."""
    if os.path.splitext(str(path))[1].lower() != ".mp4":
        raise ValueError(f"cannot write {path}: the file name must end in .mp4 (an H.264 MP4 video)")


def write_video(
    frames: Iterable[np.ndarray] | Callable[[int], np.ndarray | None],
    path,
    fps: float = 30,
    progress: bool = True,
    num_frames: int | None = None,
    quality: float = 7,
) -> int:
    """Write RGB uint8 frames `[H, W, 3]` to an H.264 MP4 file at `path`; returns the frame count.

    `frames` is an iterable of frames, or a callable called as `frames(i)` for `i < num_frames` (it may
    return None to stop early). `num_frames` also caps an iterable and sizes the progress bar (tqdm,
    when installed and `progress`). Frames of odd width or height are padded by one edge pixel (the
    yuv420p format most players need works on 2 x 2 blocks). `quality`: 1 (smallest) to 10 (best), or
    None for ffmpeg's default.
    """
    if num_frames is not None and (isinstance(num_frames, bool) or not isinstance(num_frames, int) or num_frames < 0):
        raise ValueError(f"num_frames={num_frames!r} must be None or an integer >= 0")
    total = num_frames if num_frames is not None else (len(frames) if isinstance(frames, Sized) else None)
    count = 0
    with video_file(path, fps=fps, progress=progress, total=total, quality=quality) as add:
        for frame in _frame_iter(frames, num_frames):
            add(frame)
            count += 1
    return count


@contextlib.contextmanager
def video_file(
    path, fps: float = 30, progress: bool = True, total: int | None = None, quality: float = 7
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
    check_video_path(path)
    folder = os.path.dirname(os.path.abspath(str(path)))
    if not os.path.isdir(folder):
        raise ValueError(f"cannot write {path}: folder {folder} does not exist")
    bar = None
    if progress:
        try:
            from tqdm import tqdm

            bar = tqdm(total=total, unit="frame", desc=os.path.basename(str(path)))
        except ImportError:
            pass
    writer = None
    shape = None
    count = 0
    # ffmpeg writes a partial file, renamed when the video is whole (a kill or a full disk leaves none)
    with atomic_path(path) as partial:

        def add(frame: np.ndarray) -> None:
            nonlocal writer, shape, count
            frame = _check_frame(frame, shape)
            shape = frame.shape
            h, w = shape[:2]
            if writer is None:
                writer = imageio_ffmpeg.write_frames(
                    partial,
                    (w + w % 2, h + h % 2),
                    fps=fps,
                    quality=quality,
                    codec="libx264",
                    pix_fmt_in="rgb24",
                    pix_fmt_out="yuv420p",
                    macro_block_size=1,
                )
                writer.send(None)  # start ffmpeg
            if h % 2 or w % 2:
                frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
            writer.send(np.ascontiguousarray(frame).tobytes())
            count += 1
            if bar is not None:
                bar.update(1)

        try:
            yield add
        finally:
            if writer is not None:
                writer.close()
            if bar is not None:
                bar.close()
        if count == 0:
            raise ValueError("write_video got no frames")


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
