"""Frames of one world of a `BatchedAquarium`, drawn by Warp kernels from the device state.

```python
from aquarium_warp.render import Renderer, render_world, save_png
frame = render_world(env, world=0, view_cones=True)      # numpy uint8 [height_px, width_px, 3]
renderer = Renderer(env, width_px=512)                    # keeps its device buffers between frames
frame = renderer.render(world=3, hit_boxes=True, velocities=True)
save_png(frame, "frame.png")
```

Fish (prey) are orange, sharks (predators) blue-grey; both are drawn pointing along their heading,
sized from their hit-box radius and anti-aliased. Under 3 image pixels of radius an agent is a plain
oval, under 0.75 one pixel, so agents of a huge world rendered small stay visible as dots. Dead slots
are not drawn. The world is a torus: an agent near an edge is drawn again across the seam. Overlays:
view cones (translucent sectors of radius view distance and angle fov around the heading, a full disc
with `fov_enabled=False`; overlapping cones darken), hit boxes (circle of the radius) and velocity
arrows (velocity x `velocity_scale` steps); with `draw_flow=True` the flow's current (docs/model.md "Flow
fields") as arrows on a grid `flow_spacing` image pixels apart, under the agents (the drift of
`velocity_scale` steps, at most 0.9 grid spacings; none where the current is shorter than a pixel).

The work per frame is two kernel launches (one thread per agent slot, then one per pixel; a third, one
thread per arrow, with `draw_flow`) and, for `render()`, one copy of the image to the host.
"""

from __future__ import annotations

import math
import os
import struct as _struct
import sys
import weakref
import zlib
from typing import Any

import numpy as np
import warp as wp

from .atomic import atomic_open
from .device import WARP_SETUP_LOCK
from .kernels import render as rk
from .kernels.common import PREDATOR, PREY

DEFAULT_MAX_SIZE = 1024

# name: RGB 0..255. The background is marl-aquarium's sea blue, the prey colour its fish orange.
DEFAULT_PALETTE = {
    "background": (172, 206, 231),
    "prey_body": (255, 140, 0),
    "prey_fin": (230, 100, 0),
    "prey_outline": (140, 62, 0),
    "prey_eye": (25, 20, 15),
    "prey_stripe": (215, 105, 0),
    "predator_body": (92, 112, 135),
    "predator_fin": (66, 84, 104),
    "predator_outline": (34, 44, 58),
    "predator_eye": (10, 12, 16),
    "predator_stripe": (62, 78, 98),
    "prey_cone": (255, 225, 80),
    "predator_cone": (230, 40, 40),
    "prey_cone_alpha": 0.35,
    "predator_cone_alpha": 0.25,
    "prey_hit_box": (200, 30, 30),
    "predator_hit_box": (120, 10, 60),
    "velocity": (0, 90, 30),
    "flow": (60, 110, 165),
}


def frame_size(
    config, width_px: int | None = None, height_px: int | None = None, max_size: int = DEFAULT_MAX_SIZE
) -> tuple[int, int]:
    """(width_px, height_px) of a frame: the world's size in px, scaled down so the long side is at most
    `max_size`; one given side sets the other from the world's aspect ratio."""
    for name, value in (("width_px", width_px), ("height_px", height_px), ("max_size", max_size)):
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 32768
        ):
            raise ValueError(f"{name}={value!r} must be None or an integer in [1, 32768]")
    w, h = float(config.width), float(config.height)
    if width_px is not None and height_px is not None:
        return int(width_px), int(height_px)
    if width_px is not None:
        return int(width_px), max(1, round(width_px * h / w))
    if height_px is not None:
        return max(1, round(height_px * w / h)), int(height_px)
    scale = min(1.0, max_size / max(w, h))
    return max(1, round(w * scale)), max(1, round(h * scale))


def _palette(overrides: dict | None) -> rk.Palette:
    colours: dict[str, Any] = dict(DEFAULT_PALETTE)
    for name, value in (overrides or {}).items():
        if name not in colours:
            raise ValueError(f"unknown palette entry {name!r}; known: {sorted(colours)}")
        colours[name] = value
    pal = rk.Palette()
    for name, value in colours.items():
        if not name.endswith("_alpha"):
            setattr(pal, name, wp.vec3(*(float(c) for c in value)))
    alpha = [0.0, 0.0]
    alpha[PREDATOR] = float(colours["predator_cone_alpha"])
    alpha[PREY] = float(colours["prey_cone_alpha"])
    pal.cone_alpha = wp.vec2(*alpha)
    return pal


class Renderer:
    """Draws worlds of `env` into `height_px x width_px` RGB frames; keeps its device buffers.

    `width_px` / `height_px` / `max_size`: the frame size (see `frame_size`). `velocity_scale`: velocity
    arrows show the move of that many steps. `palette`: overrides of `DEFAULT_PALETTE` entries. Frames
    are drawn from the env's current state, on the env's device; on CUDA they are ordered after the
    work on torch's current stream, so state written through `env.state.torch` is seen.
    """

    def __init__(
        self,
        env,
        width_px: int | None = None,
        height_px: int | None = None,
        *,
        max_size: int = DEFAULT_MAX_SIZE,
        velocity_scale: float = 10.0,
        palette: dict | None = None,
        flow_spacing: int = 32,
    ):
        if not (
            isinstance(velocity_scale, (int, float))
            and not isinstance(velocity_scale, bool)
            and math.isfinite(velocity_scale)
            and velocity_scale >= 0
        ):
            raise ValueError(f"velocity_scale={velocity_scale!r} must be a finite number >= 0")
        if isinstance(flow_spacing, bool) or not isinstance(flow_spacing, (int, np.integer)) or flow_spacing < 4:
            raise ValueError(f"flow_spacing={flow_spacing!r} must be an integer >= 4 (image pixels)")
        self._env = env  # a weakref.ref for the renderers that render_world caches per env
        cfg = env.config
        self.width_px, self.height_px = frame_size(cfg, width_px, height_px, max_size)
        self.device = env.device
        H, Wp = self.height_px, self.width_px
        self._body_key = wp.zeros((H, Wp), dtype=wp.int32, device=self.device)
        self._cone_count = wp.zeros((2, H, Wp), dtype=wp.int32, device=self.device)
        self._overlay = wp.zeros((H, Wp), dtype=wp.int32, device=self.device)
        self._image = wp.zeros((H, Wp, 3), dtype=wp.uint8, device=self.device)
        self._palette = _palette(palette)
        with WARP_SETUP_LOCK:  # load the kernels here, not at the first launch, which may run on any thread
            wp.load_module(rk, device=self.device)

        p = rk.RenderParams()
        p.world_width, p.world_height = float(cfg.width), float(cfg.height)
        p.width_px, p.height_px = Wp, H
        p.pixel_width, p.pixel_height = p.world_width / Wp, p.world_height / H
        p.prey_capacity = env.prey_capacity
        pixel = max(p.pixel_width, p.pixel_height)
        p.outline = 1.0 * pixel
        p.ring = 0.6 * pixel
        p.line_px = 0.6
        p.velocity_scale = float(velocity_scale)
        p.flow_spacing = int(flow_spacing)
        self._params = p

    def _set_world_types(self, world: int) -> None:
        """Hit-box radii and view cones of `world`'s own agent types (they may differ between worlds;
        read from the env's config at each frame, so `set_params` changes show)."""
        p, cfg = self._params, self.env.config
        if cfg.per_world_fields:
            cfg = cfg.world(world)
        half_diagonal = 0.5 * math.hypot(cfg.width, cfg.height)
        radius, cone, cos_half = [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]
        for code, t in ((PREDATOR, cfg.predator), (PREY, cfg.prey)):
            radius[code] = float(t.radius)
            cone[code] = float(min(t.view_distance, half_diagonal))  # beyond it the cone covers the world
            full_circle = t.fov_angle >= 360 or not cfg.fov_enabled  # without FOV only the distance limits sight
            cos_half[code] = -2.0 if full_circle else math.cos(math.radians(t.fov_angle / 2.0))
        p.radius, p.cone_radius, p.cos_half_fov = wp.vec2(*radius), wp.vec2(*cone), wp.vec2(*cos_half)

    @property
    def env(self):
        return self._env() if isinstance(self._env, weakref.ref) else self._env

    def check_world(self, world) -> None:
        """Raise ValueError unless `world` is an index of one of the env's worlds."""
        n = self.env.num_worlds
        if isinstance(world, bool) or not isinstance(world, (int, np.integer)) or not 0 <= world < n:
            raise ValueError(f"world={world!r} must be an integer in [0, {n - 1}]")

    def freeze(self, world: int = 0) -> FrozenWorld:
        """A device copy of `world`'s agents and step counter now, which `render(frozen=...)` draws later
        (on any thread) while the env steps on: a recorder draws frames beside the simulation."""
        self.check_world(world)
        env = self.env
        agents, shard = env.state.agents, next(s for s in env.shards if s.w0 <= world < s.w1)
        copy = FrozenWorld(world, world - shard.w0)
        copy.agents = rk.Agents()
        for name in ("position", "velocity", "heading", "alive"):
            row = getattr(agents, name)[world : world + 1]
            setattr(copy.agents, name, wp.clone(row))
        # the step counter at the shard's own index (the flow kernel reads it there); the rest stays 0
        copy.world_step = wp.zeros(copy.shard_index + 1, dtype=wp.int32, device=self.device)
        wp.copy(copy.world_step, shard.state.worlds.world_step, copy.shard_index, copy.shard_index, 1)
        return copy

    def render_device(
        self,
        world: int = 0,
        *,
        view_cones: bool = False,
        hit_boxes: bool = False,
        velocities: bool = False,
        draw_flow: bool = False,
        frozen: FrozenWorld | None = None,
    ) -> wp.array:
        """Draw `world` (or the copy `frozen` of one taken by `freeze`) into the renderer's device image
        and return it: a Warp array `[height_px, width_px, 3]` uint8 on the env's device, overwritten by
        the next frame."""
        if frozen is not None:
            world = frozen.world
        self.check_world(world)
        env = self.env
        p = self._params
        p.world = 0 if frozen is not None else int(world)  # a frozen copy holds its world at row 0
        self._set_world_types(world)
        p.view_cones, p.hit_boxes, p.velocities = int(bool(view_cones)), int(bool(hit_boxes)), int(bool(velocities))
        agents = env.state.agents if frozen is None else frozen.agents
        if wp.get_device(self.device).is_cuda:
            # The state may have been written by torch on its current stream: order the frame after it
            # (the env's own steps already run on this Warp stream).
            import torch

            wp.get_stream(self.device).wait_stream(wp.stream_from_torch(torch.cuda.current_stream(env.torch_device)))
        self._body_key.zero_()
        self._overlay.zero_()
        if view_cones:
            self._cone_count.zero_()
        rk.launch_splat(p, agents, self._body_key, self._cone_count, self._overlay, env.capacity, self.device)
        if draw_flow:
            shard = next(s for s in env.shards if s.w0 <= world < s.w1)
            world_step = shard.state.worlds.world_step if frozen is None else frozen.world_step
            rk.launch_flow(p, shard.world, world - shard.w0, world_step, self._overlay, self.device)
        rk.launch_compose(
            p, self._palette, agents, self._body_key, self._cone_count, self._overlay, self._image, self.device
        )
        return self._image

    def render(
        self,
        world: int = 0,
        *,
        view_cones: bool = False,
        hit_boxes: bool = False,
        velocities: bool = False,
        draw_flow: bool = False,
        frozen: FrozenWorld | None = None,
    ) -> np.ndarray:
        """Draw `world` (or `frozen`, see `render_device`); returns a new numpy uint8 array
        `[height_px, width_px, 3]` (RGB)."""
        image = self.render_device(
            world, view_cones=view_cones, hit_boxes=hit_boxes, velocities=velocities, draw_flow=draw_flow, frozen=frozen
        )
        frame = image.numpy()  # a copy on CUDA (synchronises), a view of the buffer on CPU
        return frame.copy() if not wp.get_device(self.device).is_cuda else frame


class FrozenWorld:
    """One world's agents (position, velocity, heading, alive as `[1, C]` device arrays) and step counter
    at one moment: `Renderer.freeze`'s copy. `shard_index`: the world's index in its shard."""

    def __init__(self, world: int, shard_index: int):
        self.world, self.shard_index = world, shard_index
        self.agents: Any = None
        self.world_step: Any = None


_renderers: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def render_world(
    env,
    world: int = 0,
    *,
    width_px: int | None = None,
    height_px: int | None = None,
    view_cones: bool = False,
    hit_boxes: bool = False,
    velocities: bool = False,
    draw_flow: bool = False,
) -> np.ndarray:
    """Frame of `world` of `env`: numpy uint8 `[height_px, width_px, 3]` RGB.

    The size defaults to the world's size in px, scaled down so the long side is at most 1024; one given
    side sets the other from the aspect ratio. A renderer (with its device buffers) is cached per env for
    the last size asked, so repeated calls allocate nothing; use `Renderer` to change palette or arrows.
    """
    size = frame_size(env.config, width_px, height_px)
    renderer = _renderers.get(env)
    if renderer is None or (renderer.width_px, renderer.height_px) != size:
        renderer = Renderer(env, *size)
        renderer._env = weakref.ref(env)  # a cache value must not keep its key (the env) alive
        _renderers[env] = renderer
    return renderer.render(
        world, view_cones=view_cones, hit_boxes=hit_boxes, velocities=velocities, draw_flow=draw_flow
    )


def check_frame(frame, name: str = "frame") -> np.ndarray:
    """`frame` as a numpy array; ValueError (naming it `name`) unless it is RGB uint8 `[H, W, 3]`."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"{name} must be a uint8 [H, W, 3] RGB array, got {frame.dtype} {list(frame.shape)}")
    return frame


def save_png(frame: np.ndarray, path) -> None:
    """Write an RGB uint8 `[H, W, 3]` frame as a PNG file (zlib only, no imaging library)."""
    frame = np.ascontiguousarray(check_frame(frame))
    h, w, _ = frame.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), frame.reshape(h, w * 3)], axis=1)  # filter 0 per row

    def chunk(tag: bytes, data: bytes) -> bytes:
        return _struct.pack(">I", len(data)) + tag + data + _struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    header = _struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)  # 8-bit RGB
    with atomic_open(path, "wb") as f:
        f.write(
            b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(raw.tobytes(), 9))
            + chunk(b"IEND", b"")
        )


class Window:
    """A pygame window showing frames live (needs the `video` extra: `pip install aquarium-warp[video]`).

    ```python
    window = Window(renderer.width_px, renderer.height_px)
    while window.show(renderer.render()):   # False once the window is closed
        env.step(actions)
    ```
    """

    def __init__(self, width_px: int, height_px: int, caption: str = "Aquarium", fps: float | None = 60):
        try:
            import pygame
        except ImportError as error:  # an optional dependency
            raise ImportError("Window needs pygame: pip install 'aquarium-warp[video]'") from error
        # Without a display SDL prints its probing errors and falls back to a driver that shows nothing
        # (a driver asked for by name, SDL_VIDEODRIVER=dummy in the tests, is taken as meant).
        if sys.platform.startswith("linux") and not any(
            os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")
        ):
            raise RuntimeError(
                "a window needs a display, and none was found (DISPLAY and WAYLAND_DISPLAY are "
                "unset): draw frames with render_mode='rgb_array' or write a video instead"
            )
        self._pygame = pygame
        pygame.display.init()  # the display only: pygame.init() also opens audio (ALSA's lines on stderr)
        self._screen = pygame.display.set_mode((int(width_px), int(height_px)))
        pygame.display.set_caption(caption)
        self._clock = pygame.time.Clock()
        self._fps = fps
        self.open = True

    def show(self, frame: np.ndarray) -> bool:
        """Display an RGB frame `[H, W, 3]`; returns False once the user has closed the window."""
        pygame = self._pygame
        if not self.open:
            return False
        for event in pygame.event.get():
            if event.type == pygame.QUIT:
                self.close()
                return False
        surface = pygame.surfarray.make_surface(np.ascontiguousarray(frame.transpose(1, 0, 2)))  # (W, H, 3)
        self._screen.blit(surface, (0, 0))
        pygame.display.flip()
        if self._fps:
            self._clock.tick(self._fps)
        return True

    def close(self) -> None:
        if self.open:
            self._pygame.display.quit()
            self.open = False
