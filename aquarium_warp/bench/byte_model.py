"""The byte model: the bytes one step must move per agent slot, kernel by kernel (a lower bound
that the bandwidth check compares with the measured copy bandwidth)."""

from __future__ import annotations

from ..config import AquariumConfig

F32 = I32 = 4  # float32 and int32 (Warp's `int`), bytes
VEC2 = 8  # wp.vec2 (two float32)
BOOL = 1
Traffic = dict[str, float]  # {"read": bytes, "write": bytes} per agent slot


def step_byte_model(cfg: AquariumConfig, dims: tuple[int, int] | None = None, cuda: bool = True) -> dict:
    """Bytes one `step()` must move per agent slot, stage by stage (reads and writes of DRAM).

    Counted: every array element that a kernel thread reads or writes for its own agent (or cell, or
    world, divided among the world's slots), once per launch. The grid stage follows the step's path
    (`grid_path`): whole-world lists (one-cell worlds, no build), rank per slot (small worlds on
    CUDA), cell counts and their prefix sum (larger worlds on CUDA) or counting sort (the CPU). Not
    counted: gathers of other agents' data during neighbour searches (cell ranges, neighbours'
    positions, speeds, slots), which small worlds keep in cache (one world of 1M agents does not:
    Nsight Compute measures 1.5x the model's total there, `benchmarks/profile_step.py`), rare events
    (captures, respawns, episode ends), and the per-type parameter structs. A lower bound for this
    algorithm, not for any algorithm.
    Returns `{"stages": {stage: {"read": B, "write": B}}, "read", "write", "total"}` per agent slot,
    with `cells_per_world` and `grid_path` (the build's description).
    """
    from ..env import grid_dims
    from ..shard import grid_build

    C, P, Pc = cfg.capacity, cfg.predator_count, cfg.prey_capacity
    dims_x, dims_y = dims if dims is not None else grid_dims(cfg)
    cells = dims_x * dims_y / C  # grid cells per agent slot
    pred = P / C  # share of slots that are predators
    prey = Pc / C
    per_world = 1.0 / C
    stages: dict[str, Traffic] = {}

    # Action copy-in (env.step): int32 action of every slot copied from the caller's tensor.
    stages["actions"] = {"read": I32, "write": I32}

    # motion.integrate_motion, (W, C) threads. Reads: alive, action, contact partner and offset
    # (found by the last observation pass), position, velocity, acceleration. Writes: position,
    # velocity, acceleration, heading, and clears the step's reward, terminated, truncated and
    # captured flags (and the world's capture count).
    stages["motion"] = {
        "read": BOOL + I32 + I32 + VEC2 + 3 * VEC2,
        "write": 4 * VEC2 + F32 + 3 * BOOL + per_world * I32,
    }

    # Grid build (cell lists of the final positions), once per step: captures search the cell lists
    # of the start-of-step positions, which are the last step's.
    path = grid_build(cfg, (dims_x, dims_y), cuda)
    build: list[Traffic]
    if path == "whole-world":
        # One cell per world: the lists are fixed and the searches read the state itself.
        build = []
    elif path == "rank":
        # rank_into_cells_per_world: per slot read alive and position (the rest of its world is read
        # through the cache); write the sorted agent index and position; and the range of every cell,
        # empty ones included.
        build = [{"read": BOOL + VEC2, "write": I32 + VEC2 + 2 * I32 * cells}]
    elif path == "count":
        # compute_cell_keys: read position, alive; write the key and the arrival order (an atomic
        # read-modify-write of the cell's count, zero beforehand).
        keys: Traffic = {"read": VEC2 + BOOL + I32, "write": I32 + I32 + I32}
        # array_scan of the counts into the cell ends: read and write one int32 per cell.
        scan: Traffic = {"read": I32 * cells, "write": I32 * cells}
        # drop_into_cells: read key, arrival order and the cell's start; write the scratch entry; and
        # zero the counts for the next build (one int32 per cell).
        drop: Traffic = {"read": 3 * I32, "write": I32 + I32 * cells}
        # order_cells: read the scratch entry, its key, its cell's range and the cell's other scratch
        # entries (cached) and the position; write the entry and the position.
        order: Traffic = {"read": 3 * I32 + VEC2, "write": I32 + VEC2}
        build = [keys, scan, drop, order]
    else:
        # sort_into_cells_per_world (the CPU's counting sort): clear the counts (a pass writing cells);
        # per agent read alive and position, write its key and count it (read-modify-write of the
        # cell's count); a prefix sum over the cells (read count, write start and end); per agent
        # read the key, position and the cell's cursor, write the sorted agent index, position and
        # the cursor.
        build = [
            {"read": 0.0, "write": I32 * cells},
            {"read": BOOL + VEC2 + I32, "write": I32 + I32},
            {"read": 4 * cells, "write": 8 * cells},
            {"read": I32 + VEC2 + I32, "write": I32 + VEC2 + I32},
        ]
    stages["grid"] = {"read": sum(b["read"] for b in build), "write": sum(b["write"] for b in build)}

    # Captures and starvation. detect_contacts, a few threads per predator (rows of its search
    # square): read alive and position (the neighbour walk is a gather). resolve_captures, one
    # thread per prey slot: read alive and captured, read-modify-write age (without capture
    # confusion; with it, contacted prey also read their neighbours, few per step). share_capture_rewards, one
    # thread per predator: read alive and position, read-modify-write starvation, write reward, and
    # read-modify-write its episode return (docs/model.md step 8). respawn_captured_prey, one thread per
    # prey slot: read captured, then step 8: read reward and alive, write reward (the survival
    # reward) and read-modify-write the episode return.
    stages["captures"] = {
        "read": (
            pred * (BOOL + VEC2)
            + prey * (BOOL + BOOL + I32)
            + pred * (BOOL + VEC2 + I32 + F32)
            + prey * (BOOL + F32 + BOOL + F32)
        ),
        "write": prey * I32 + pred * (F32 + I32 + F32) + prey * (F32 + F32),
    }
    # Population, episode end. finish_world_step reads the world's step, captures, episode captures
    # and both alive counts and writes episode_ended, step and episode captures; close_ended_episodes
    # reads episode_ended once per world (it truncates and respawns ended worlds).
    stages["population"] = {
        "read": per_world * (5 * I32 + 2 * BOOL),
        "write": per_world * (BOOL + 2 * I32),
    }
    if cfg.prey_reproduction:
        # reproduce_prey, one thread per world: reads alive, age and replication age of each prey slot.
        stages["population"]["read"] += prey * (BOOL + 2 * I32)

    # Observations: the observation kernel, one thread per slot: read alive, its position, heading
    # and velocity (from the state, by slot); write its observation row
    # (float32), the mask and slot of each neighbour slot, and the contact partner and offset.
    obs_floats = prey * cfg.observation_size("prey") + pred * cfg.observation_size("predator")
    slots = prey * (cfg.prey.predator_slots + cfg.prey.prey_slots) + pred * (
        cfg.predator.predator_slots + cfg.predator.prey_slots
    )
    stages["observations"] = {"read": BOOL + 3 * VEC2, "write": F32 * obs_floats + slots * (BOOL + I32) + I32 + VEC2}
    read = sum(s["read"] for s in stages.values())
    write = sum(s["write"] for s in stages.values())
    return {
        "stages": stages,
        "read": read,
        "write": write,
        "total": read + write,
        "cells_per_world": dims_x * dims_y,
        "grid_path": GRID_PATHS[path],
    }


# The byte model's name for each way of making the step's cell lists (`shard.grid_build`).
GRID_PATHS = {
    "whole-world": "whole-world lists (no build)",
    "rank": "rank per slot (CUDA)",
    "count": "cell counts + prefix sum (CUDA)",
    "counting": "counting sort (CPU)",
}
