"""One training run over several processes (`torchrun --nproc_per_node=G aquarium-warp train ...`).

torchrun starts one process per GPU (or per share of the CPU) and tells each its place through the
environment (`WORLD_SIZE`, `RANK`, `LOCAL_RANK`, and the rendezvous that `init_process_group` reads).
Each process (rank) simulates its own worlds on its own device with its own seed
(`seeding.rank_seed`: `train.seed + RANK`); rsl-rl's PPO keeps the learners identical: parameters
broadcast from rank 0 when learning starts, gradients all-reduced every mini-batch, the observation
normalisers' statistics all-reduced, the adaptive learning rate decided on rank 0. This module holds
the few pieces rsl-rl leaves to us: the rank's device and process-group backend (NCCL on GPUs, gloo
on CPUs), whether the backend's collectives can be captured in a CUDA graph (NCCL's can: with
`train.graph_update=true` the update with its gradient all-reduce is then replayed like one process's),
sums over ranks for the logs, and gathering every rank's training state into rank 0's checkpoint.

Several machines join through torchrun's rendezvous (`--nnodes=N --rdzv-backend=c10d
--rdzv-endpoint=HOST:PORT`, the same command on each); `tests/training/test_distributed.py` starts two
such launchers on one host (gloo on the CPU).
"""

from __future__ import annotations

import os

import torch
import torch.distributed as dist


def world() -> tuple[int, int, int]:
    """`(rank, local rank, world size)` from torchrun's environment; `(0, 0, 1)` outside torchrun."""

    def read(name: str, default: str) -> int:
        value = os.environ.get(name, default)
        try:
            return int(value)
        except ValueError:
            raise ValueError(f"{name}={value!r} must be an integer") from None

    size, rank, local_rank = read("WORLD_SIZE", "1"), read("RANK", "0"), read("LOCAL_RANK", "0")
    if size < 1:
        raise ValueError(f"WORLD_SIZE={size} must be >= 1")
    for name, value in (("RANK", rank), ("LOCAL_RANK", local_rank)):
        if not 0 <= value < size:
            raise ValueError(f"{name}={value} must be in [0, WORLD_SIZE={size})")
    return rank, local_rank, size


def rank_device(device: str | None, local_rank: int) -> str:
    """The device of one rank of a several-process run, from `train.device`: `cuda:LOCAL_RANK` where the
    run asks for CUDA (any index: one GPU per process, chosen by torchrun), the CPU where it asks for
    the CPU; None: CUDA when present."""
    kind = ("cuda" if torch.cuda.is_available() else "cpu") if device is None else str(device).split(":")[0]
    if kind == "cpu":
        return "cpu"
    if kind != "cuda":
        raise ValueError(f"train.device={device!r}: a torchrun run trains on 'cpu' or 'cuda'")
    if local_rank >= torch.cuda.device_count():
        raise ValueError(
            f"train.device={device!r}: LOCAL_RANK={local_rank} needs GPU {local_rank}, but this "
            f"node has {torch.cuda.device_count()}; start at most that many processes per node"
        )
    return f"cuda:{local_rank}"


def init(device: str, rank: int, size: int) -> str:
    """Join the run's process group (NCCL for a CUDA device, gloo for the CPU); its backend."""
    backend = "nccl" if torch.device(device).type == "cuda" else "gloo"
    if backend == "nccl":
        # NVLink multicast (NVLS) stays off: the lent multi-GPU machines do not support it reliably.
        os.environ.setdefault("NCCL_NVLS_ENABLE", "0")
        torch.cuda.set_device(torch.device(device))
    if not dist.is_initialized():
        dist.init_process_group(backend=backend, rank=rank, world_size=size)
    return backend


def collectives_capturable() -> bool:
    """Whether this process's group (if any) runs its collectives on the GPU's streams, so that a CUDA
    graph can capture them: NCCL (from 2.9.6; torch skips the watchdog's bookkeeping of captured work).
    gloo's collectives wait on the host, which a capture refuses."""
    return dist.is_initialized() and dist.get_backend() == "nccl"


def sum_over_ranks(tensor: torch.Tensor) -> None:
    """Replace `tensor` (on this rank's device) by the element-wise sum over every rank's, in place. With
    NCCL the sum is queued on the device in stream order: the host does not wait for it."""
    dist.all_reduce(tensor, op=dist.ReduceOp.SUM)


def to_cpu(obj):
    """`obj` with every tensor in its dicts, lists and tuples moved to the CPU (a rank's state travels
    to rank 0 pickled: its tensors must not name the sender's GPU)."""
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        return {key: to_cpu(value) for key, value in obj.items()}
    if isinstance(obj, tuple) and hasattr(obj, "_fields"):  # a named tuple
        return type(obj)(*(to_cpu(value) for value in obj))
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_cpu(value) for value in obj)
    return obj


def gather_on_first(obj) -> list | None:
    """Every rank's `obj`, in rank order, on rank 0 (None on the others)."""
    out = [None] * dist.get_world_size() if dist.get_rank() == 0 else None
    dist.gather_object(obj, out, dst=0)
    return out


def close() -> None:
    """Leave the process group (at the end of a run)."""
    if dist.is_initialized():
        dist.destroy_process_group()
