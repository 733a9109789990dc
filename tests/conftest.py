"""Shared test setup: quiet Warp, CPU by default; `AQUARIUM_TEST_DEVICE=cuda:0` reruns the suite on a GPU."""

import os

import pytest
import warp as wp

wp.config.quiet = True
wp.config.log_level = getattr(wp, "LOG_WARNING", wp.config.log_level)
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")


@pytest.fixture(scope="session")
def device() -> str:
    """Device the env tests run on: CPU in CI, a GPU when AQUARIUM_TEST_DEVICE names one."""
    return os.environ.get("AQUARIUM_TEST_DEVICE", "cpu")


@pytest.fixture
def one_thread():
    """Small networks run fastest (and reproducibly) on one torch thread."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
