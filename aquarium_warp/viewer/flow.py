"""The flow's current sampled on a coarse grid of one world (`kernels/viewer_flow.py`), for the page's
flow overlay."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import WARP_SETUP_LOCK
from ..kernels import viewer_flow


class FlowSampler:
    """`sample(world)`: `[rows, cols, 2]` float32 currents at the centres of a `rows x cols` grid."""

    def __init__(self, env, rows: int = 16, cols: int = 16):
        self._env, self.rows, self.cols = env, rows, cols
        self._out = wp.zeros((rows, cols), dtype=wp.vec2, device=env.device)
        with WARP_SETUP_LOCK:  # load here, not at the first launch, which runs on the viewer's thread
            wp.load_module(viewer_flow, device=env.device)

    def sample(self, world: int) -> np.ndarray:
        env = self._env
        shard = next(s for s in env.shards if s.w0 <= world < s.w1)
        cell_x, cell_y = float(env.config.width) / self.cols, float(env.config.height) / self.rows
        wp.launch(
            viewer_flow.sample_current,
            dim=(self.rows, self.cols),
            inputs=[shard.world, world - shard.w0, shard.state.worlds.world_step, cell_x, cell_y],
            outputs=[self._out],
            device=env.device,
        )
        return self._out.numpy().copy()
