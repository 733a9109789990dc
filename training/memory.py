"""What a training run needs in memory, estimated before anything is allocated, and refused with the
estimate when the device cannot hold it (the simulation's own check covers its arrays only; rsl-rl's
rollout storage, far larger, would fail minutes later with an allocation traceback).

The estimate counts, per learning team: the rollout storage (rsl-rl's `RolloutStorage`: observations,
the critic's group, actions, rewards, dones, values, log-probabilities, returns, advantages and the
categorical distribution's logits, for `num_steps_per_env` steps of every row), the adapter's two
observation buffers, the update's mini-batch copy and the networks' activations and gradients of one
mini-batch (CUDA graphs replay these same buffers); plus the simulation (`state.estimate_bytes`).
"""

from __future__ import annotations

import os

from ..env import grid_dims
from ..state import estimate_bytes
from .config import env_config, learning_teams, team_runner, team_settings

FLOAT = 4
# Per row and step, besides the observations: actions, rewards, values, log-probabilities, returns,
# advantages (floats) and the done flag (a byte).
ROW_SCALARS = 6


def training_bytes(config: dict) -> dict[str, int]:
    """Bytes of a run of `config` by part: `simulation`, `rollout` (storage and observation buffers of
    every learner), `update` (mini-batch copies, activations, networks) and their `total`."""
    cfg = env_config(config)
    worlds = int(config["train"]["num_worlds"])
    steps = int(config["runner"]["num_steps_per_env"])
    rows_x, cells = grid_dims(cfg)
    parts = {"simulation": estimate_bytes(cfg, worlds, rows_x * cells), "rollout": 0, "update": 0}
    for team in learning_teams(config):
        slots = cfg.prey_capacity if team == "prey" else cfg.predator_count
        obs = cfg.observation_size(team)
        critic = team_settings(config, team)["critic"]
        extra = {"local": 0, "team": slots * obs, "world": 7 * cfg.capacity + 1}[critic]
        rows = worlds * slots
        per_row = FLOAT * (obs + extra + cfg.action_count + ROW_SCALARS) + 1
        parts["rollout"] += steps * rows * per_row + 2 * rows * FLOAT * (obs + extra)
        runner = team_runner(config, team)
        mini_batch = steps * rows // max(1, int(runner.get("algorithm", {}).get("num_mini_batches", 1)))
        widths = [w for net in ("actor", "critic") for w in runner.get(net, {}).get("hidden_dims", [])]
        # the mini-batch's copy and the activations autograd keeps for every layer
        parts["update"] += mini_batch * (per_row + FLOAT * (sum(widths) + cfg.action_count + 1))
    parts["total"] = sum(parts.values())
    return parts


def available_bytes(device: str) -> int:
    """Free memory for a run on `device`: CUDA's free device memory, else the RAM the kernel reports as
    available (free plus reclaimable caches)."""
    if device.startswith("cuda"):
        import torch

        return int(torch.cuda.mem_get_info(torch.device(device))[0])
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")


def check_training_memory(config: dict, device: str) -> None:
    """A one-line ValueError, with the estimate, when the run cannot fit `device` (90% of what is free)."""
    parts = training_bytes(config)
    free = available_bytes(device)
    if parts["total"] <= 0.9 * free:
        return
    worlds = int(config["train"]["num_worlds"])
    fits = int(worlds * 0.9 * free / parts["total"])
    gib = {k: v / 2**30 for k, v in parts.items()}
    raise ValueError(
        f"train.num_worlds={worlds} needs about {gib['total']:.1f} GiB on {device} (simulation "
        f"{gib['simulation']:.1f}, rollout storage {gib['rollout']:.1f}, update {gib['update']:.1f} "
        f"GiB), but only {free / 2**30:.1f} GiB is available: use at most about {fits} worlds, "
        "or a shorter rollout (runner.num_steps_per_env)"
    )
