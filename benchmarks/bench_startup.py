"""Start-up times of whole commands (`aquarium-warp --help`, `import aquarium_warp`, `train --preset paper`
with one iteration and whole), each a fresh process, from cold and warm kernel caches, for one or more
source trees in turn: `aquarium_warp.bench.startup` (its doc says what each command and cache is).

    python benchmarks/bench_startup.py --device cuda:0 --tree /tmp/old-tree --tree . --repeats 5
    python benchmarks/bench_startup.py --device cpu --commands help,import,train-1 --caches warm

Prints a table and writes startup_<device>.json into --out-dir (default: the current directory).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from aquarium_warp.bench.startup import main

if __name__ == "__main__":
    sys.exit(main())
