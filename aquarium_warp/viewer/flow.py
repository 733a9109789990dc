"""The flow's current sampled on a coarse grid of one world, for the page's flow overlay: the page
draws arrows itself, so it needs vectors, not the rasteriser's pixels."""

from __future__ import annotations

import sys

import numpy as np
import warp as wp

from ..kernels.common import WorldParams, current
from ..shard import WARP_SETUP_LOCK


@wp.kernel
def sample_current(world: WorldParams, w: int, world_step: wp.array(dtype=wp.int32), cell_x: float, cell_y: float,
                   out: wp.array2d(dtype=wp.vec2)):
    """One thread per grid cell: the current (px/step) at the cell's centre, at the world's step counter
    (the one the next move adds). `w`: the world's index in `world`'s shard."""
    i, j = wp.tid()
    centre = wp.vec2((float(j) + 0.5) * cell_x, (float(i) + 0.5) * cell_y)
    out[i, j] = current(world, world.values[w], centre, world_step[w])


class FlowSampler:
    """`sample(world)`: `[rows, cols, 2]` float32 currents at the centres of a `rows x cols` grid."""

    def __init__(self, env, rows: int = 16, cols: int = 16):
        self._env, self.rows, self.cols = env, rows, cols
        self._out = wp.zeros((rows, cols), dtype=wp.vec2, device=env.device)
        with WARP_SETUP_LOCK:  # load here, not at the first launch, which runs on the viewer's thread
            wp.load_module(sys.modules[__name__], device=env.device)

    def sample(self, world: int) -> np.ndarray:
        env = self._env
        shard = next(s for s in env.shards if s.w0 <= world < s.w1)
        cell_x, cell_y = float(env.config.width) / self.cols, float(env.config.height) / self.rows
        wp.launch(sample_current, dim=(self.rows, self.cols),
                  inputs=[shard.world, world - shard.w0, shard.state.worlds.world_step, cell_x, cell_y],
                  outputs=[self._out], device=env.device)
        return self._out.numpy().copy()
