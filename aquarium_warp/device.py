"""The machine an env runs on: Warp's initialisation, device names, free memory and CPU threads."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
from collections.abc import Callable

import torch
import warp as wp

# Warp's initialisation, kernel registration and module loading (compiling) are not thread-safe: two
# threads building envs at once crashed the process. Everything that may load a module (recording a
# launch loads its kernel's module) holds this lock; stepping built envs in parallel needs no lock.
WARP_SETUP_LOCK = threading.RLock()

# What Warp's native library prints during init on a machine without the NVIDIA driver.
_NO_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"
_warp_ready = False
_init_messages = ""  # what init printed while silenced


def _wants_cuda(device) -> bool:
    return (
        (device.type == "cuda")
        if isinstance(device, torch.device)
        else (isinstance(device, str) and device.startswith("cuda"))
    )


def _init_warp(device=None) -> None:
    """Initialise Warp once. Its native library warns on stderr when no CUDA driver is found, also
    for users who never asked for CUDA; unless `device` names CUDA, that warning is held back (kept
    for the error that `resolve_device` raises if CUDA is asked for later) and anything else printed
    during init is passed on."""
    with WARP_SETUP_LOCK:
        if not _warp_ready:
            _init_warp_once(device)


def _init_warp_once(device) -> None:
    global _warp_ready, _init_messages
    wp.config.log_level = wp.LOG_WARNING  # no banner
    if _wants_cuda(device):
        wp.init()
    else:
        sys.stderr.flush()
        saved = os.dup(2)
        with tempfile.TemporaryFile(mode="w+b") as captured:
            os.dup2(captured.fileno(), 2)
            try:
                wp.init()
            finally:
                os.dup2(saved, 2)
                os.close(saved)
            captured.seek(0)
            _init_messages = captured.read().decode(errors="replace")
        others = [line for line in _init_messages.splitlines(keepends=True) if _NO_DRIVER_WARNING not in line]
        if others:
            sys.stderr.write("".join(others))
    _warp_ready = True


def resolve_device(device) -> str:
    """Warp device name for `device`: None picks "cuda:0" when CUDA is present, else "cpu"."""
    _init_warp(device)
    if device is None:
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if isinstance(device, torch.device):
        device = str(device) if device.type == "cpu" or device.index is not None else f"{device.type}:0"
    if not isinstance(device, str):
        raise ValueError(f"device={device!r} must be None, a string like 'cpu' or 'cuda:0', or a torch.device")
    if device == "cuda":
        device = "cuda:0"
    names = [d.alias for d in wp.get_devices()]
    if device not in names:
        driver = f" ({_init_messages.strip()})" if _NO_DRIVER_WARNING in _init_messages and _wants_cuda(device) else ""
        raise ValueError(f"device={device!r} is not available; available devices: {names}{driver}")
    return device


def make_current(device: torch.device) -> None:
    """Make a CUDA `device` torch's current one in this process (a process-wide switch, like TF32), so
    that what torch places on the current device (timing events, pinned copies, Triton launches) is on
    the run's card and not on cuda:0; the CPU changes nothing."""
    if device.type == "cuda":
        torch.cuda.set_device(device)


def free_bytes(device: str) -> int:
    """Bytes free on a resolved Warp `device`: the GPU's free memory, or the host's available pages."""
    dev = wp.get_device(device)
    if dev.is_cuda:
        return dev.free_memory
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")


def resolve_cpu_threads(cpu_threads) -> int:
    """Worker threads for CPU shards: None gives one per core this process may run on."""
    if cpu_threads is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if isinstance(cpu_threads, bool) or not isinstance(cpu_threads, int) or cpu_threads < 1:
        raise ValueError(f"cpu_threads={cpu_threads!r} must be None or an integer >= 1")
    return cpu_threads


_TORCH_STREAMS: dict[int, wp.Stream] = {}


def synchronize(device: str | torch.device) -> None:
    """Wait for torch's work on `device` (a CUDA device; nothing to wait for on the CPU), so that a host
    clock read next counts it."""
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def torch_stream(device: torch.device) -> wp.Stream | None:
    """Torch's current stream on a CUDA `device` as a Warp stream (None on the CPU): Warp work launched
    there is ordered with torch's and is captured with it into torch's CUDA graphs. Made once per torch
    stream (making one, with the event it synchronises through, every step costs host time)."""
    if device.type != "cuda":
        return None
    current = torch.cuda.current_stream(device)
    stream = _TORCH_STREAMS.get(current.cuda_stream)
    if stream is None:
        stream = _TORCH_STREAMS[current.cuda_stream] = wp.stream_from_torch(current)
    return stream


class TorchStreamLaunches:
    """Warp kernel launches on torch's current stream (ordered with torch's work, and captured with it
    in torch's CUDA graphs), each recorded once per key: a key names the buffers a launch reads, so a
    caller whose buffers change (another tensor, another liveness mask) gets a new recording. Recording
    converts the tensors to Warp arrays; replaying costs only the launch."""

    def __init__(self, device: str):
        self.device = device
        self._torch_device = torch.device(device)
        self._recorded: dict = {}

    def run(self, key, kernel, dim, inputs: Callable[[], list]) -> None:
        """Launch `kernel` over `dim` threads with `inputs()` (tensors become Warp arrays; other values
        pass as they are), recorded under `key` on its first run."""
        launch = self._recorded.get(key)
        if launch is None:
            args = [wp.from_torch(x) if isinstance(x, torch.Tensor) else x for x in inputs()]
            launch = self._recorded[key] = wp.launch(kernel, dim=dim, inputs=args, device=self.device, record_cmd=True)
        launch.launch(stream=torch_stream(self._torch_device))
