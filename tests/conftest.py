"""Shared test setup: quiet Warp, CPU by default; `AQUARIUM_TEST_DEVICE=cuda:0` runs the device-aware tests on a
GPU (`pytest -m gpu` selects them: every test that takes the `device` fixture, `cuda_device` included)."""

import os

import pytest
import warp as wp

wp.config.quiet = True
wp.config.log_level = getattr(wp, "LOG_WARNING", wp.config.log_level)
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
# Triton's interpreter runs the fused MLP's Triton kernels on CPU tensors (tests/training/test_fused_mlp.py). Triton
# reads it when it is first imported, which any module may do (torch's compiler does), so here, before them all;
# a GPU run (AQUARIUM_TEST_DEVICE=cuda:N) compiles the kernels instead.
if not os.environ.get("AQUARIUM_TEST_DEVICE", "cpu").startswith("cuda"):
    os.environ.setdefault("TRITON_INTERPRET", "1")


@pytest.fixture(scope="session")
def device() -> str:
    """Device the env tests run on: CPU in CI, a GPU when AQUARIUM_TEST_DEVICE names one."""
    return os.environ.get("AQUARIUM_TEST_DEVICE", "cpu")


@pytest.fixture(scope="session")
def cuda_device(device: str) -> str:
    """The GPU of AQUARIUM_TEST_DEVICE, for the tests that need CUDA (CUDA graphs): they skip on the CPU."""
    if not device.startswith("cuda"):
        pytest.skip("needs CUDA: AQUARIUM_TEST_DEVICE=cuda:N")
    return device


def pytest_itemcollected(item: pytest.Item) -> None:
    """`gpu` marks the tests that run on AQUARIUM_TEST_DEVICE, read from the fixtures they take; a
    `learning` test (it trains for tens of seconds) is `slow` too, so the fast loop leaves it out."""
    if "device" in getattr(item, "fixturenames", ()):
        item.add_marker(pytest.mark.gpu)
    if item.get_closest_marker("learning") is not None and item.get_closest_marker("slow") is None:
        item.add_marker(pytest.mark.slow)


@pytest.fixture
def one_thread():
    """Small networks run fastest (and reproducibly) on one torch thread."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def staged_copy(tmp_path, monkeypatch):
    """The package as a staged copy without git history (as on a lent GPU machine): `records.git_info`
    finds no checkout, so only a supplied commit names the code."""
    from aquarium_warp import records

    staged = tmp_path / "staged-copy"
    staged.mkdir()
    monkeypatch.setattr(records, "PACKAGE_DIR", staged)
    monkeypatch.delenv("AQUARIUM_WARP_COMMIT", raising=False)
    return staged
