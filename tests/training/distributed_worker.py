"""One rank of a tiny torchrun training run for tests/training/test_distributed.py.

`torchrun --nproc_per_node=2 tests/training/distributed_worker.py OUT TEAM ITERATIONS TAG [resume]` trains (or
resumes) the run in `OUT/run` and writes `OUT/<TAG>_rank<r>.json`: this rank's seed, a hash of every
learner's parameters after each iteration, each adapter's episode-statistics snapshots (sums and counts
before the reduction over ranks) and hashes of the final simulation state and parameters.
`AQUARIUM_WORKER_GPU=shared`: every rank on GPU 0, through gloo; `own`: rank r on GPU r, through NCCL.
`AQUARIUM_WORKER_TRAIN`: further train settings, as JSON.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys

import numpy as np
import torch

from aquarium_warp.training import Trainer, make_config


def digest(obj) -> str:
    """SHA-256 of every tensor and array in `obj` (dicts in key order)."""
    h = hashlib.sha256()

    def walk(x) -> None:
        if isinstance(x, torch.Tensor):
            h.update(x.detach().cpu().contiguous().numpy().tobytes())
        elif isinstance(x, np.ndarray):
            h.update(x.tobytes())
        elif isinstance(x, dict):
            for key in sorted(x):
                h.update(str(key).encode())
                walk(x[key])
        elif isinstance(x, (list, tuple)):
            for item in x:
                walk(item)
        else:
            h.update(repr(x).encode())

    walk(obj)
    return h.hexdigest()


def parameters(trainer: Trainer) -> dict:
    """Each learner's actor and critic state (parameters and normaliser statistics)."""
    return {
        team: {"actor": learner.alg.actor.state_dict(), "critic": learner.alg.critic.state_dict()}
        for team, learner in trainer.learners.items()
    }


def share_one_gpu() -> None:
    """Every rank trains on GPU 0 (its local rank reads 0) and the ranks talk through gloo: NCCL wants
    a GPU per rank, and a test machine may have one GPU."""
    from aquarium_warp.training import distributed

    world = distributed.world

    def init(rank_device: str, rank: int, size: int) -> str:
        torch.cuda.set_device(torch.device(rank_device))
        if not torch.distributed.is_initialized():
            torch.distributed.init_process_group(backend="gloo", rank=rank, world_size=size)
        return "gloo"

    def one_gpu_world() -> tuple[int, int, int]:
        rank, _, size = world()
        return rank, 0, size

    distributed.world = one_gpu_world
    distributed.init = init


def main() -> None:
    out, team, iterations, tag = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    run_dir = os.path.join(out, "run")
    gpu = os.environ.get("AQUARIUM_WORKER_GPU")
    if gpu == "shared":
        share_one_gpu()
    if sys.argv[5:] == ["resume"]:
        trainer = Trainer.resume(run_dir)
    else:
        train = {
            "team": team,
            "num_worlds": 4,
            "iterations": 4,
            "export": [],
            **({"device": "cuda"} if gpu else {}),
            **json.loads(os.environ.get("AQUARIUM_WORKER_TRAIN", "{}")),
        }
        config = make_config(
            "tiny",
            {"env": {"max_steps": 20}, "train": train, "runner": {"num_steps_per_env": 16, "save_interval": 100}},
        )
        trainer = Trainer(config, log_dir=run_dir)
    record: dict = {
        "rank": trainer.rank,
        "seed": trainer.seed,
        "params": {},
        "stats": {},
        # The graphs each learner's algorithm would allow on CUDA (the CPU captures none).
        "graphable": {
            name: [learner.alg.rollout_graphable, learner.alg.graphable] for name, learner in trainer.learners.items()
        },
    }
    for name, learner in trainer.learners.items():
        take = learner.vec_env.episode_stats_snapshot
        record["stats"][name] = []

        def snapshot(take=take, name=name) -> torch.Tensor:
            values = take()
            record["stats"][name].append(values.tolist())
            return values

        learner.vec_env.episode_stats_snapshot = snapshot
    after = trainer.after_iteration

    def after_iteration(iteration: int) -> None:
        after(iteration)
        record["params"][iteration] = digest(parameters(trainer))

    trainer.after_iteration = after_iteration
    trainer.train(iterations)
    loop = trainer.runner.loop
    record["graphs"] = [loop.graphs, loop.update_graphs]  # what the loop replayed: rollout, updates
    record["final_params"] = digest(parameters(trainer))
    record["final_sim"] = digest(trainer.env.state_dict()["tensors"])
    with open(os.path.join(out, f"{tag}_rank{trainer.rank}.json"), "w", encoding="utf-8") as f:
        json.dump(record, f)
    trainer.close()


if __name__ == "__main__":
    main()
