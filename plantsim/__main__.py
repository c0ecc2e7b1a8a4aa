"""``python -m plantsim``: the command line."""

from plantsim.cli import run

run()
