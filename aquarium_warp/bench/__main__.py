"""`python -m aquarium_warp.bench`: the same as `aquarium-warp bench`."""

import sys

from .cli import main

sys.exit(main())
