"""Videos in the training log (`train.video_every = N`): every N iterations a short evaluation episode
of one world, played by the current policies, rendered by the project's rasteriser (`render.Renderer`:
Warp kernels from the device state) and logged through the rsl-rl logger's writer.

- TensorBoard: the frames as an animated GIF image summary, which is what TensorBoard shows as a video
  (the format of `SummaryWriter.add_video`; that method needs moviepy 1.x for the GIF, so the GIF is
  encoded here with Pillow instead), tag `Video/episode`.
- Weights & Biases (or another rsl-rl `LogWriter`): also an MP4 in `<log_dir>/videos/`, uploaded with
  the writer's `save_video`, as rsl-rl's own logger does with the videos it finds.

The episode runs in a world of its own (the run's world settings, seed `train.seed`, so every video
starts from the same state), never in the training worlds, and draws nothing from torch's random
stream: logging videos leaves the training run unchanged. Learners act by their argmax; a non-learning
team plays as in training.
"""

from __future__ import annotations

import io
import os
import pathlib

import numpy as np

from ..env import BatchedAquarium
from ..render import Renderer
from ..rollout import rollout
from ..video import Frames

TAG = "Video/episode"


class EpisodeVideo:
    """Renders episodes of one world of `env_cfg` on `device`: `record(drivers)` -> frames
    `[steps + 1, H, W, 3]` uint8 (the first state, then the state after each step)."""

    def __init__(self, env_cfg, device, seed: int, steps: int, width_px: int = 256, fps: float = 15):
        self.env = BatchedAquarium(env_cfg, num_worlds=1, device=device, seed=seed)
        self.renderer = Renderer(self.env, width_px=min(width_px, max(1, round(env_cfg.width))))
        self.steps, self.fps = int(steps), float(fps)

    def record(self, make_drivers) -> np.ndarray:
        """`make_drivers(env)` -> `{team: driver}` (callables returning a team's actions `[1, slots]`),
        built after the reset so that recurrent drivers start with zero states."""
        self.env.reset()
        frames: list[np.ndarray] = []
        rollout(self.env, make_drivers(self.env), self.steps, [Frames(self.renderer, frames.append)], reset=False)
        return np.stack(frames)

    def log(self, writer, frames: np.ndarray, iteration: int, log_dir: str | None) -> None:
        """Write `frames` to `writer` (see the module doc) at step `iteration`."""
        from rsl_rl.utils.log_writer import LogWriter

        writer._get_file_writer().add_summary(gif_summary(TAG, frames, self.fps), iteration)
        if isinstance(writer, LogWriter) and log_dir is not None:
            from ..video import write_video

            path = os.path.join(log_dir, "videos", f"iteration_{iteration}.mp4")
            os.makedirs(os.path.dirname(path), exist_ok=True)
            write_video(frames, path, fps=self.fps, progress=False)
            writer.save_video(pathlib.Path(path), iteration)  # rsl-rl reads `.name`

    def close(self) -> None:
        self.env.close()


def gif_bytes(frames: np.ndarray, fps: float) -> bytes:
    """`frames` `[T, H, W, 3]` uint8 as an animated GIF (Pillow), looping."""
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
    return buffer.getvalue()


def gif_summary(tag: str, frames: np.ndarray, fps: float):
    """A TensorBoard image summary holding `frames` `[T, H, W, 3]` uint8 as an animated GIF."""
    from tensorboard.compat.proto.summary_pb2 import Summary

    T, H, W, C = frames.shape
    image = Summary.Image(height=H, width=W, colorspace=C, encoded_image_string=gif_bytes(frames, fps))
    return Summary(value=[Summary.Value(tag=tag, image=image)])


__all__ = ["EpisodeVideo", "gif_bytes", "gif_summary", "TAG"]
