"""``python -m cliff_terrain``: the same as the ``cliff-terrain`` command."""

import sys

from .cli import main

sys.exit(main())
