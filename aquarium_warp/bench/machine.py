"""Free memory of the device a measurement runs on (what the machine and commit are: `aquarium_warp.records`)."""

from __future__ import annotations

import os


def available_bytes(device: str) -> int:
    """Free memory of `device`: the GPU's, or the host's available physical pages."""
    import warp as wp

    dev = wp.get_device(device)
    if dev.is_cuda:
        return int(dev.free_memory)
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError):
        return 1 << 40
