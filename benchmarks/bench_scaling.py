"""Scaling benchmark of aquarium-warp: a thin wrapper of `aquarium_warp.bench` (same as `aquarium-warp bench`).

    python benchmarks/bench_scaling.py --device cuda:0 --agents 16,64,...,1000000 --worlds 1,16,...,65536 --vmas
    python benchmarks/bench_scaling.py --device cpu --agents 16,64,...,100000 --worlds 1,16,...,4096

Sweeps agents per world (one world at the default density) and worlds (17 agents each) with random
actions and observations on; per point: agent-steps/s (median of timed runs), eager vs CUDA graph,
time per stage, heuristics, memory, bytes per agent-step and the achieved fraction of the measured
copy bandwidth; peers: with --original, the original marl-aquarium (CPU) and, with --vmas, VMAS
simple_tag (benchmarks/vmas_peer.py). Writes scaling_<device>.json and
scaling_<device>_{throughput,per_agent,stages}.png into --out-dir (default: the current directory;
the committed results are in benchmarks/results). `--help` lists every option.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.bench import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
