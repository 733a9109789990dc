"""Regression tests of issue 15: inputs that crashed the process, overflowed silently or corrupted the
state. Cases that could kill the interpreter run in a subprocess, so a crash fails the test instead of
ending the test run."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_python(code: str, timeout: float = 240) -> subprocess.CompletedProcess:
    """Run `code` in a fresh interpreter (fresh Warp: nothing loaded yet), from the repository root."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_envs_built_on_two_threads_at_once():
    """Case 1: two threads constructing envs at the same moment (each loading Warp's modules) crashed
    with a segfault in 5 of 5 runs; construction is now serialised inside the package."""
    result = run_python("""
        import threading
        from aquarium_warp import AquariumConfig, BatchedAquarium
        barrier = threading.Barrier(2)
        envs = []
        def build():
            barrier.wait()
            envs.append(BatchedAquarium(AquariumConfig(prey_count=8), num_worlds=5, device="cpu"))
        threads = [threading.Thread(target=build) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        a, b = envs
        assert (a.state.torch.position == b.state.torch.position).all()
        print("built", len(envs))
    """)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "built 2" in result.stdout
