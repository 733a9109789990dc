"""The scaling benchmark with its peers: `aquarium-warp bench` (the package's suite, same options)
plus the peers that only the source tree can measure, in the same run:

* `--original`: the original marl-aquarium 0.1.10 on the CPU (`original_aquarium.py` installs it
  from the package index into a throwaway virtual environment);
* `--vmas`: VMAS's predator-prey scenario `simple_tag` at the agent counts of the agents and worlds
  series, on the same device (`vmas_peer.py`; `pip install vmas`).

    python benchmarks/bench_scaling.py --device cuda:0 --agents 16,64,...,1000000 --worlds 1,16,...,65536 --vmas
    python benchmarks/bench_scaling.py --device cpu --agents 16,64,...,100000 --worlds 1,16,...,4096 --original

Per point: agent-steps/s (median of timed runs), eager vs CUDA graph, time per stage, heuristics,
memory, bytes per agent-step and the achieved fraction of the measured copy bandwidth; ratios to the
peers. Writes scaling_<device>.json and scaling_<device>_{throughput,per_agent,stages}.png into
--out-dir (default: the current directory; the committed results are in benchmarks/results).
`--help` lists every option.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import original_aquarium
import vmas_peer

from aquarium_warp.bench import Peers, main

if __name__ == "__main__":
    sys.exit(main(peers=Peers(original=original_aquarium, vmas=vmas_peer), prog="bench_scaling.py"))
