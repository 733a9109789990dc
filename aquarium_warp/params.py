"""Per-world parameters on the device: what the kernels read of a batch's config.

`BatchParams` holds three device arrays made from an `AquariumConfig` whose per-world fields are
tuples (one value per world) or scalars (the same in every world):

- `types`: `[W, 2]` `AgentType` (indexed by world and type code), the per-type table;
- `values`: `[W]` `WorldValues`, the world parameters that may differ between worlds;
- `flow_grid`: `[G, rows, cols]` vec2, the distinct grid currents of the batch (G >= 1);

and `max_speed`, a `[W, 2]` float64 torch tensor of each world's max speeds by type code, for torch
code that scales by them (`world_state.WorldState`, also inside CUDA graphs).

The kernels read them every step, so `write(config)` (a copy into the same memory) changes the
worlds between two steps with nothing rebuilt or recorded again, also inside a CUDA graph.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import warp as wp

from .config import AquariumConfig, FlowConfig
from .kernels.common import (
    CAPTURE_CONFUSION,
    CAPTURE_DILUTION,
    FLOW_GRID,
    FLOW_NONE,
    FLOW_UNIFORM,
    FLOW_VORTEX,
    PREDATOR,
    PREY,
    AgentType,
    WorldValues,
)
from .per_world import PER_WORLD_FIELDS, PER_WORLD_TYPE_FIELDS, per_world
from .state import struct_type

# `FlowConfig.kind` -> the kernels' code of the current.
_FLOW_CODES = {"none": int(FLOW_NONE), "uniform": int(FLOW_UNIFORM), "vortex": int(FLOW_VORTEX), "grid": int(FLOW_GRID)}
# `AquariumConfig.capture_rule` -> the kernels' code of the rule.
_CAPTURE_RULE_CODES = {"dilution": int(CAPTURE_DILUTION), "confusion": int(CAPTURE_CONFUSION)}


def cos_half_fov(fov_angle: float) -> float:
    """cos(alpha / 2) for the visibility test; -2 for a full circle (every direction passes)."""
    cosine = math.cos(math.radians(fov_angle / 2.0))
    # cos(90 deg) is 6e-17 in floats: it would exclude the inclusive boundary of a 180-degree cone.
    return -2.0 if fov_angle >= 360 else (0.0 if abs(cosine) < 1e-12 else cosine)


def type_rows(cfg: AquariumConfig, num_worlds: int) -> np.ndarray:
    """`[W, 2]` rows of `AgentType` (numpy structured), column = type code."""
    rows = np.zeros((num_worlds, 2), dtype=struct_type(AgentType).numpy_dtype())
    for code, t in ((PREDATOR, cfg.predator), (PREY, cfg.prey)):
        column = rows[:, int(code)]
        for name in PER_WORLD_TYPE_FIELDS:
            if name != "fov_angle":
                column[name] = per_world(getattr(t, name), num_worlds)
        views = per_world(t.view_distance, num_worlds)
        column["distance_norm"] = [min(v, cfg.max_torus_distance) for v in views]
        column["cos_half_fov"] = [cos_half_fov(a) for a in per_world(t.fov_angle, num_worlds)]
        column["predator_slots"] = t.predator_slots
        column["prey_slots"] = t.prey_slots
    return rows


def flow_grids(flows: list[FlowConfig]) -> tuple[np.ndarray, list[int]]:
    """The distinct grid currents of `flows` as one `[G, rows, cols, 2]` float32 array (a single zero
    cell when there is none), and each flow's index into it (0 for other kinds)."""
    grids: list = []
    index = []
    for flow in flows:
        if flow.kind != "grid":
            index.append(0)
            continue
        if flow.grid not in grids:
            grids.append(flow.grid)
        index.append(grids.index(flow.grid))
    if not grids:
        return np.zeros((1, 1, 1, 2), dtype=np.float32), index
    shapes = {np.shape(g) for g in grids}
    if len(shapes) > 1:
        raise ValueError(f"flow.grid: the grid currents of a batch must share one shape [rows, cols, 2], got {shapes}")
    return np.asarray(grids, dtype=np.float32), index


def world_rows(cfg: AquariumConfig, num_worlds: int, grid_index: list[int]) -> np.ndarray:
    """`[W]` rows of `WorldValues` (numpy structured)."""
    rows = np.zeros(num_worlds, dtype=struct_type(WorldValues).numpy_dtype())
    for name in PER_WORLD_FIELDS:
        # stored as configured; the capture rule, the confusion angle, the replication age and the flow: below
        if name in rows.dtype.names and name != "capture_rule":
            rows[name] = per_world(getattr(cfg, name), num_worlds)
    rows["capture_rule"] = [_CAPTURE_RULE_CODES[r] for r in per_world(cfg.capture_rule, num_worlds)]
    # The window around the target's bearing is a cone of full angle 2 A: cos A, as the field of view's.
    rows["confusion_cos"] = [cos_half_fov(2.0 * a) for a in per_world(cfg.confusion_angle, num_worlds)]
    ages = per_world(cfg.prey_replication_age, num_worlds)
    rows["replication_age_min"] = [math.ceil(0.75 * r) for r in ages]
    rows["replication_age_max"] = [math.floor(1.25 * r) for r in ages]
    rows["prey_spawn_speed"] = [min(1.0, s) for s in per_world(cfg.prey.max_speed, num_worlds)]
    rows["predator_spawn_speed"] = [min(1.0, s) for s in per_world(cfg.predator.max_speed, num_worlds)]
    flows = per_world(cfg.flow, num_worlds)
    rows["flow_kind"] = [_FLOW_CODES[f.kind] for f in flows]
    rows["flow_vector"] = [f.centre if f.kind == "vortex" else f.velocity for f in flows]
    rows["flow_strength"] = [f.strength for f in flows]
    rows["flow_core_radius"] = [f.core_radius for f in flows]
    rows["flow_amplitude"] = [f.amplitude for f in flows]
    rows["flow_period"] = [f.period for f in flows]
    rows["flow_grid"] = grid_index
    rows["flow_reach"] = [f.reach for f in flows]
    return rows


def max_speeds(cfg: AquariumConfig, num_worlds: int) -> torch.Tensor:
    """`[W, 2]` float64 max speeds per world, by type code (`PREDATOR`, `PREY`), on the CPU."""
    speeds = torch.zeros(num_worlds, 2, dtype=torch.float64)
    for code, t in ((int(PREDATOR), cfg.predator), (int(PREY), cfg.prey)):
        speeds[:, code] = torch.tensor(per_world(t.max_speed, num_worlds), dtype=torch.float64)
    return speeds


class BatchParams:
    """The device arrays of a batch's per-world parameters (see the module's docstring)."""

    def __init__(self, cfg: AquariumConfig, num_worlds: int, device):
        self.num_worlds = num_worlds
        grids, index = flow_grids(per_world(cfg.flow, num_worlds))
        self.flow_grid: wp.array = wp.array(grids, dtype=wp.vec2, device=device)
        self.types: wp.array = wp.array(type_rows(cfg, num_worlds), dtype=AgentType, device=device)
        self.values: wp.array = wp.array(world_rows(cfg, num_worlds, index), dtype=WorldValues, device=device)
        self.max_speed = max_speeds(cfg, num_worlds).to(wp.device_to_torch(device))

    def write(self, cfg: AquariumConfig) -> None:
        """Copy `cfg`'s values into the same arrays (a config of the same batch: its grid currents must
        be those the arrays hold)."""
        grids, index = flow_grids(per_world(cfg.flow, self.num_worlds))
        if grids.shape != tuple(self.flow_grid.shape) + (2,) or not np.array_equal(grids, self.flow_grid.numpy()):
            raise ValueError(
                "flow: set_params cannot change the batch's grid currents (a new grid needs a new env); "
                "uniform and vortex flows, and grids the batch already holds, may be set per world"
            )
        self.types.assign(wp.array(type_rows(cfg, self.num_worlds), dtype=AgentType, device="cpu"))
        self.values.assign(wp.array(world_rows(cfg, self.num_worlds, index), dtype=WorldValues, device="cpu"))
        self.max_speed.copy_(max_speeds(cfg, self.num_worlds))
