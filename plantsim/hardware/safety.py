"""Safety stops for the physical rig: whatever ends a run, the hardware is left safe.

A :class:`SafeStop` is a registry of stop actions, each a ``(name, stop, verify)``
triple: ``stop()`` makes one device safe (the servo's torque off, the LiDAR's laser
off) and ``verify()`` reads back that it is (Torque Enable = 0). Used as a context
manager it runs every action when its block ends, for any reason: a normal end, an
exception, Ctrl-C (``KeyboardInterrupt``), SIGTERM or SIGHUP (turned into
:class:`~plantsim.errors.Terminated`, a ``KeyboardInterrupt``, so the code inside
unwinds through its ``finally`` blocks and journals exactly as after Ctrl-C), or a
lost link (the device's ``stop`` reconnects). Each action is tried ``attempts``
times; a further Ctrl-C or SIGTERM while the actions run is held back until they are
done, so a second, impatient Ctrl-C cannot leave the servo powered.

A library must not print: the outcome is a :class:`SafeStopReport` on
:attr:`SafeStop.report`. When an action cannot be confirmed, the report's
:meth:`~SafeStopReport.warning` is the one line a command prints to stderr; if the
block ended normally, :class:`~plantsim.errors.UnsafeStopError` is raised as well, and
if an exception is in flight the line is added to it as a note (its traceback shows
it). Example::

    with SafeStop() as safety:
        turntable = ServoTurntable.connect(port)
        safety.register(*turntable.stop_action())
        run_scan(...)
    # safety.report.safe is True, or the user has been told

Python runs a signal's handler at the next bytecode, wherever that is. When it lands in
a finaliser, a weakref callback or an import lock's callback, the interpreter prints
the handler's exception ("Exception ignored in ...") and goes on as if nothing had
happened. So the handlers also record the signal (:mod:`plantsim.interrupts`), and
:func:`~plantsim.interrupts.raise_if_signalled` raises it again: the scan loops call
it after every line, so a swallowed SIGTERM still stops the scan within a line. A
block that ends normally after a swallowed signal runs its stop actions for that
signal and then raises it.

Signal handlers can only be installed from the main thread; elsewhere the stop
actions still run on exit, and SIGTERM keeps its previous handling.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import threading
import time
from typing import Callable

from plantsim import interrupts
from plantsim.errors import Terminated, UnsafeStopError

_log = logging.getLogger(__name__)

_SIGNAL_NAMES = {signal.SIGTERM: "SIGTERM", signal.SIGHUP: "SIGHUP", signal.SIGINT: "Ctrl-C"}


@dataclasses.dataclass(frozen=True)
class StopAction:
    """One device's way to safety.

    Attributes:
        name: what is made safe, as the user knows it ("servo torque", "LiDAR laser").
        stop: makes it safe; may raise (a failed attempt is retried).
        verify: reads back whether it is safe; None means a ``stop`` that returns is
            taken as confirmation.
        advice: what the user must do by hand when it cannot be confirmed.
    """

    name: str
    stop: Callable[[], None]
    verify: Callable[[], bool] | None = None
    advice: str = "make it safe by hand (switch off its power supply)"

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        if not callable(self.stop):
            raise ValueError(f"stop must be callable, got {self.stop!r}")
        if self.verify is not None and not callable(self.verify):
            raise ValueError(f"verify must be callable or None, got {self.verify!r}")


@dataclasses.dataclass(frozen=True)
class StopOutcome:
    """The result of one :class:`StopAction`.

    Attributes:
        name: the action's name.
        confirmed: True when ``verify`` read back a safe state (or ``stop`` returned
            and there is no ``verify``).
        attempts: attempts made (1 when the first one succeeded).
        detail: the last failure ("" when confirmed).
        advice: the action's advice to the user.
    """

    name: str
    confirmed: bool
    attempts: int
    detail: str = ""
    advice: str = ""


@dataclasses.dataclass(frozen=True)
class SafeStopReport:
    """What the safety stop did.

    Attributes:
        reason: why the run ended: "normal end", "Ctrl-C", "SIGTERM", "SIGHUP" or
            "error: <exception>".
        outcomes: one per registered action, in the order they ran.
    """

    reason: str
    outcomes: tuple[StopOutcome, ...]

    @property
    def safe(self) -> bool:
        """True when every action was confirmed."""
        return all(o.confirmed for o in self.outcomes)

    @property
    def unconfirmed(self) -> tuple[StopOutcome, ...]:
        return tuple(o for o in self.outcomes if not o.confirmed)

    def warning(self) -> str:
        """One line for the user when something is not confirmed safe ("" when safe)."""
        if self.safe:
            return ""
        parts = [f"{o.name} NOT confirmed off after {o.attempts} attempt{'s' * (o.attempts != 1)} "
                 f"({o.detail}): {o.advice}" for o in self.unconfirmed]
        return "DANGER: " + "; ".join(parts)

    def summary(self) -> str:
        """One line: each action and whether it was confirmed."""
        return ", ".join(f"{o.name} {'off (confirmed)' if o.confirmed else 'NOT CONFIRMED'}"
                         for o in self.outcomes) or "nothing to stop"


class SafeStop:
    """Runs registered stop actions when its block ends, however it ends.

    Args:
        attempts: tries per action before it is reported unconfirmed.
        retry_interval_s: pause between tries, s.
        signals: signals turned into :class:`~plantsim.errors.Terminated` inside the
            block (main thread only). SIGINT keeps raising ``KeyboardInterrupt`` (through
            a handler that also records it, when Python's own handler is in place).
        sleep: the pause function (tests pass a fake one).
    """

    def __init__(self, *, attempts: int = 3, retry_interval_s: float = 0.1,
                 signals: tuple[int, ...] = (signal.SIGTERM, signal.SIGHUP),
                 sleep: Callable[[float], None] = time.sleep):
        if isinstance(attempts, bool) or not isinstance(attempts, int) or attempts < 1:
            raise ValueError(f"attempts must be an integer >= 1, got {attempts!r}")
        if not (isinstance(retry_interval_s, (int, float)) and 0 <= retry_interval_s <= 60):
            raise ValueError(f"retry_interval_s must be in [0, 60] s, got {retry_interval_s!r}")
        self.attempts = attempts
        self.retry_interval_s = float(retry_interval_s)
        self._signals = tuple(signals)
        self._sleep = sleep
        self._actions: list[StopAction] = []
        self._previous_handlers: dict[int, object] = {}
        self.report: SafeStopReport | None = None

    # --- registry ---------------------------------------------------------------------

    def register(self, name: str | StopAction, stop: Callable[[], None] | None = None,
                 verify: Callable[[], bool] | None = None, *, advice: str | None = None) -> StopAction:
        """Adds an action (a :class:`StopAction`, or its fields); returns it.

        Actions run in reverse order of registration (the last device set up is
        stopped first), like ``contextlib.ExitStack``.
        """
        if isinstance(name, StopAction):
            action = name
        else:
            fields = {"advice": advice} if advice is not None else {}
            action = StopAction(name, stop, verify, **fields)
        self._actions.append(action)
        return action

    def unregister(self, action: StopAction) -> None:
        """Removes an action (a device closed cleanly and made safe by its owner)."""
        self._actions = [a for a in self._actions if a is not action]

    @property
    def actions(self) -> tuple[StopAction, ...]:
        return tuple(self._actions)

    # --- running ----------------------------------------------------------------------

    def stop_all(self, reason: str = "normal end") -> SafeStopReport:
        """Runs every action now (Ctrl-C and SIGTERM are held back meanwhile)."""
        with _signals_held():
            outcomes = tuple(self._run(action) for action in reversed(self._actions))
        self.report = SafeStopReport(reason, outcomes)
        for outcome in self.report.unconfirmed:
            _log.error("%s not confirmed safe after %d attempts: %s", outcome.name, outcome.attempts,
                       outcome.detail)
        _log.info("safety stop (%s): %s", reason, self.report.summary())
        return self.report

    def _run(self, action: StopAction) -> StopOutcome:
        detail = ""
        for attempt in range(1, self.attempts + 1):
            try:
                action.stop()
                if action.verify is None or action.verify():
                    return StopOutcome(action.name, True, attempt, "", action.advice)
                detail = "the read-back says it is still on"
            except (Exception, KeyboardInterrupt) as exc:  # any failure of one attempt: retry, report it
                # (KeyboardInterrupt here can only come from code, not from Ctrl-C, which
                # is held back: stopping the hardware goes first either way.)
                detail = f"{type(exc).__name__}: {exc}"
            _log.warning("%s: stop attempt %d of %d failed: %s", action.name, attempt, self.attempts, detail)
            if attempt < self.attempts:
                self._sleep(self.retry_interval_s)
        return StopOutcome(action.name, False, self.attempts, detail, action.advice)

    def __enter__(self) -> "SafeStop":
        if threading.current_thread() is threading.main_thread():
            interrupts.clear()
            for signum in self._signals:
                self._previous_handlers[signum] = signal.signal(signum, _raise_terminated)
            if signal.SIGINT not in self._signals and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
                self._previous_handlers[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_interrupt)
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        # A signal whose exception was swallowed (see the module's docstring) still ends the block as that
        # signal; one whose exception is the one unwinding the block has been honoured.
        swallowed = None if isinstance(exc, KeyboardInterrupt) else interrupts.pending()
        interrupts.clear()
        try:
            reason = _reason(exc) if swallowed is None else _SIGNAL_NAMES.get(swallowed, f"signal {swallowed}")
            report = self.stop_all(reason)
        finally:
            for signum, handler in self._previous_handlers.items():
                signal.signal(signum, handler)
            self._previous_handlers.clear()
        if swallowed is not None:
            if exc is None:
                interrupt = interrupts.interrupt_for(swallowed)
                if not report.safe:
                    interrupt.add_note(report.warning())
                raise interrupt
            exc.add_note(f"{reason} had arrived as well")
        if not report.safe:
            if exc is None:
                raise UnsafeStopError(report.warning(), report=report)
            exc.add_note(report.warning())
        return False


def _raise_terminated(signum, frame) -> None:
    interrupts.record(signum)
    raise Terminated(signum)


def _raise_interrupt(signum, frame) -> None:
    interrupts.record(signum)
    raise KeyboardInterrupt


def _reason(exc: BaseException | None) -> str:
    if exc is None:
        return "normal end"
    if isinstance(exc, Terminated):
        return _SIGNAL_NAMES.get(exc.signum, f"signal {exc.signum}")
    if isinstance(exc, KeyboardInterrupt):
        return "Ctrl-C"
    return f"error: {type(exc).__name__}: {exc}"


class _signals_held:
    """Holds SIGINT/SIGTERM/SIGHUP back while the stop actions run (main thread only).

    A signal that arrives meanwhile is logged, not raised: the run is ending anyway,
    and raising it would abort the stop it interrupted.
    """

    def __enter__(self):
        self.pending: list[int] = []
        self.previous = {}
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                handler = signal.getsignal(signum)
                if handler in (signal.SIG_IGN, None):
                    continue
                self.previous[signum] = signal.signal(signum, self._hold)
        return self

    def _hold(self, signum, frame) -> None:
        self.pending.append(signum)
        _log.warning("%s received while stopping the hardware; stopping first",
                     _SIGNAL_NAMES.get(signum, signum))

    def __exit__(self, exc_type, exc, tb) -> bool:
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)
        if self.pending and exc is None:
            _log.info("held-back signals after the safety stop: %s", self.pending)
        return False
