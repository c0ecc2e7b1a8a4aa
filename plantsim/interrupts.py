"""Signals that arrived but whose exception the interpreter swallowed.

Python runs a signal's handler at the next bytecode, wherever that is. When it lands
in a finaliser, a weakref callback or an import lock's callback, the interpreter
prints the handler's exception ("Exception ignored in ...") and goes on as if nothing
had happened. The rig's signal handlers (:class:`plantsim.hardware.safety.SafeStop`)
therefore also :func:`record` each signal, and loops that drive hardware call
:func:`raise_if_signalled` once per line: a swallowed SIGTERM still stops them. Here,
below the scan loops and the hardware layer both, so neither imports the other.
"""

from __future__ import annotations

import signal

from plantsim.errors import Terminated

__all__ = ["raise_if_signalled", "record", "clear", "pending", "interrupt_for"]

# Signals received inside a SafeStop block (main thread) whose exception has not yet ended it.
_received: list[int] = []


def record(signum: int) -> None:
    """Notes that ``signum`` arrived (called by a signal handler, before it raises)."""
    _received.append(signum)


def clear() -> None:
    """Forgets the signals noted (a block starts, or the interrupt reached its end)."""
    _received.clear()


def pending() -> int | None:
    """The first signal noted and not yet cleared, or None."""
    return _received[0] if _received else None


def raise_if_signalled() -> None:
    """Raises again a signal that arrived inside a :class:`~plantsim.hardware.safety.SafeStop`
    block but was swallowed.

    A loop that drives the hardware calls this once per line (the scan loops do): a
    SIGTERM, SIGHUP or Ctrl-C whose exception the interpreter swallowed (its handler
    ran inside a finaliser or a callback) then still stops the loop within one line, as
    :class:`~plantsim.errors.Terminated` or ``KeyboardInterrupt``. Outside a block, or
    when no signal has come, it does nothing.
    """
    if _received:
        raise interrupt_for(_received[0])


def interrupt_for(signum: int) -> KeyboardInterrupt:
    """The exception a signal ends a run with: ``KeyboardInterrupt`` for Ctrl-C, else
    :class:`~plantsim.errors.Terminated`."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)
