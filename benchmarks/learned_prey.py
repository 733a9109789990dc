"""`python benchmarks/learned_prey.py ...`: `aquarium-warp study learned-prey ...` under the name that the
committed results (`benchmarks/results/learned_prey_*`) record; the study is `aquarium_warp/studies/learned_prey.py`."""

import sys

from aquarium_warp.studies.learned_prey import main

if __name__ == "__main__":
    sys.exit(main())
