"""``python -m plantsim``: the command line."""

import sys

from plantsim.cli import main

sys.exit(main())
