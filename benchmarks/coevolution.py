"""`python benchmarks/coevolution.py ...`: `aquarium-warp study coevolution ...` under the name that the
committed results (`benchmarks/results/coevolution_*`) record; the study is `aquarium_warp/studies/coevolution.py`."""

import sys

from aquarium_warp.studies.coevolution import main

if __name__ == "__main__":
    sys.exit(main())
