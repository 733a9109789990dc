"""The device's copy bandwidth, the yardstick of the byte model: bytes a step moves per second as a
share of what a plain copy moves."""

from __future__ import annotations

import functools
import statistics

import torch

from .machine import available_bytes
from .timing import torch_timer


def copy_bandwidth(device: str, nbytes: int | None = None, repeats: int = 10) -> dict:
    """Device-to-device copy bandwidth: a `torch` copy of `nbytes` between two buffers on `device`,
    median of `repeats` timed copies (CUDA events on CUDA). Counts the bytes read plus written, like
    the byte model: `2 * nbytes / time`."""
    tdev = torch.device(device)
    cuda = tdev.type == "cuda"
    if nbytes is None:
        nbytes = (1 << 30) if cuda else (256 << 20)
    nbytes = int(min(nbytes, available_bytes(device) // 4))
    src = torch.empty(nbytes, dtype=torch.uint8, device=tdev)
    src.fill_(1)
    dst = torch.empty_like(src)
    timer, copy = torch_timer(device), functools.partial(dst.copy_, src)
    times = [timer(copy) for _ in range(repeats + 2)][2:]  # after two warm-up copies
    del src, dst, copy
    if cuda:
        torch.cuda.empty_cache()
    t = statistics.median(times)
    return {
        "bytes": nbytes,
        "seconds": t,
        "bytes_per_s": 2 * nbytes / t,
        "method": f"torch copy_ of {nbytes / 2**20:.0f} MiB on {device}, bytes read + written per second, "
        f"median of {repeats}" + ("" if cuda else f" ({torch.get_num_threads()} torch threads)"),
    }
