"""The flow's current on a coarse grid of one world, for the browser viewer's flow overlay
(`aquarium_warp/viewer/flow.py`): the page draws the arrows itself, so it needs vectors, not pixels."""

import warp as wp

from .common import WorldParams, current


@wp.kernel
def sample_current(
    world: WorldParams,
    w: int,
    world_step: wp.array(dtype=wp.int32),
    cell_x: float,
    cell_y: float,
    out: wp.array2d(dtype=wp.vec2),
):
    """One thread per grid cell: the current (px/step) at the cell's centre, at the world's step counter
    (the one the next move adds). `w`: the world's index in `world`'s shard."""
    i, j = wp.tid()
    centre = wp.vec2((float(j) + 0.5) * cell_x, (float(i) + 0.5) * cell_y)
    out[i, j] = current(world, world.values[w], centre, world_step[w])
