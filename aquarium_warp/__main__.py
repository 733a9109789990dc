"""`python -m aquarium_warp ...`: the `aquarium-warp` command line."""

import sys

from .cli import main

sys.exit(main())
