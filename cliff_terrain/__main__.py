"""``python -m cliff_terrain``: the same as the ``cliff-terrain`` command."""

import sys

from .cli import main

# Guarded: Dask's worker processes start by importing the parent's __main__ (multiprocessing "spawn").
if __name__ == "__main__":
    sys.exit(main())
