"""The ``plantsim`` command line: parse, call, report."""

import os as _os
import sys as _sys


def command_of(args: list[str]) -> str | None:
    """The command named on a command line (the first word that is not an option), or None.

    Args:
      args: the arguments after the program's name.
    """
    return next((arg for arg in args if not arg.startswith("-")), None)


def _single_threaded_blas_for_a_scan(argv: list[str]) -> None:
    """One OpenBLAS thread for a ``plantsim scan`` process, unless the user chose otherwise.

    A scan's matrix products are (n, 3) by (3, 3): OpenBLAS's worker threads cannot
    speed them up, and spinning while they wait cost ~0.15 s of CPU per scan of the
    bundled maize on a 2-core machine (and time on a busy one). The setting must
    precede numpy's import, so it is made here, before the command line module loads;
    a user's own ``OPENBLAS_NUM_THREADS`` is left as it is.
    """
    if command_of(argv[1:]) == "scan" and "numpy" not in _sys.modules:
        _os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


_single_threaded_blas_for_a_scan(_sys.argv)

from plantsim.cli.app import main  # noqa: E402  (after the thread setting)


def run() -> None:
    """The ``plantsim`` program (and ``python -m plantsim``): runs the command line, ends the process.

    A finished ``plantsim scan`` ends without Python's teardown
    (:func:`plantsim.cli.app.exit_without_teardown`); other commands exit as usual.
    Call :func:`main` instead to stay in the process.
    """
    code = main()
    if command_of(_sys.argv[1:]) == "scan":
        from plantsim.cli.app import exit_without_teardown

        exit_without_teardown(code)
    _sys.exit(code)


__all__ = ["main", "run"]
