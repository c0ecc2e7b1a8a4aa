"""The ``plantsim`` command line: parse, call, report."""

from plantsim.cli.app import main

__all__ = ["main"]
