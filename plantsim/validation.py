"""Type checks for settings, one line naming the key.

Settings come from TOML, the command line and Python; a string where a bool is
meant (``ideal = "false"`` is truthy) or a float where a count is meant must be
refused where the value enters, not misread later. Each checker takes the
owner's name (``"output"``, ``"EvaluationOptions"``), the key and the value and
raises :class:`SettingTypeError` (wrong type; a ``TypeError`` and a ``ValueError``) or ``ValueError`` (right type, out of range)
with one line naming ``owner.key``. They return the value so a
``__post_init__`` can normalise in one statement.

Hand-written rather than pydantic/attrs+cattrs: the settings are frozen
dataclasses already validated in ``__post_init__``, the checks are a handful
of types, and a new required dependency for them would weigh more than this
module.
"""

from __future__ import annotations

import math
import os
from typing import Any, Iterable

__all__ = ["SettingTypeError", "MissingExtraError", "require_extra", "check_bool", "check_int", "check_number", "check_choice", "check_str",
           "check_optional", "check_path"]


class SettingTypeError(TypeError, ValueError):
    """A setting of the wrong type. Also a ``ValueError``, so code (and the CLI)
    that reports bad settings by catching ``ValueError`` reports these too."""


def _where(owner: str, name: str) -> str:
    return f"{owner}.{name}" if owner else name


def check_bool(owner: str, name: str, value: Any) -> bool:
    """``value`` must be True or False (not "false", not 0/1).

    Raises:
      TypeError: any other value.
    """
    if not isinstance(value, bool):
        raise SettingTypeError(f"{_where(owner, name)} must be true or false, got {value!r} "
                        f"({type(value).__name__})")
    return value


def check_int(owner: str, name: str, value: Any, *, minimum: int | None = None,
              maximum: int | None = None) -> int:
    """``value`` must be an integer (not a bool, not a float such as 2.0).

    Raises:
      TypeError: not an integer.
      ValueError: outside [minimum, maximum].
    """
    if isinstance(value, bool) or not isinstance(value, int):
        raise SettingTypeError(f"{_where(owner, name)} must be an integer, got {value!r} "
                        f"({type(value).__name__})")
    _check_range(owner, name, value, minimum, maximum)
    return int(value)


def check_number(owner: str, name: str, value: Any, *, minimum: float | None = None,
                 maximum: float | None = None, strict_minimum: bool = False,
                 unit: str = "") -> float:
    """``value`` must be a finite int or float (not a bool, not a string).

    Args:
      owner, name: where the value came from, for the message.
      value: the value.
      minimum, maximum: inclusive bounds (None: unbounded).
      strict_minimum: the minimum itself is refused (``> minimum``).
      unit: appended to the message ("m", "deg", ...).

    Raises:
      TypeError: not a number.
      ValueError: NaN, infinite, or out of range.
    """
    suffix = f" {unit}" if unit else ""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SettingTypeError(f"{_where(owner, name)} must be a number{suffix}, got {value!r} "
                        f"({type(value).__name__})")
    if not math.isfinite(value):
        raise ValueError(f"{_where(owner, name)} must be finite, got {value!r}")
    if strict_minimum and minimum is not None and not value > minimum:
        raise ValueError(f"{_where(owner, name)} must be > {minimum}{suffix}, got {value!r}")
    _check_range(owner, name, value, None if strict_minimum else minimum, maximum, suffix)
    return float(value)


def _check_range(owner, name, value, minimum, maximum, suffix="") -> None:
    if minimum is not None and value < minimum:
        raise ValueError(f"{_where(owner, name)} must be >= {minimum}{suffix}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{_where(owner, name)} must be <= {maximum}{suffix}, got {value!r}")


def check_str(owner: str, name: str, value: Any) -> str:
    """``value`` must be a string.

    Raises:
      TypeError: any other type.
    """
    if not isinstance(value, str):
        raise SettingTypeError(f"{_where(owner, name)} must be a string, got {value!r} "
                        f"({type(value).__name__})")
    return value


def check_choice(owner: str, name: str, value: Any, choices: Iterable[str]) -> str:
    """``value`` must be one of ``choices`` (strings).

    Raises:
      TypeError: not a string.
      ValueError: not one of the choices (they are listed).
    """
    choices = tuple(choices)
    check_str(owner, name, value)
    if value not in choices:
        raise ValueError(f"{_where(owner, name)} must be one of {', '.join(choices)}, "
                         f"got {value!r}")
    return value


def check_path(owner: str, name: str, value: Any) -> str:
    """``value`` must be a path (str or ``os.PathLike``); returned as str.

    Raises:
      TypeError: any other type.
    """
    if not isinstance(value, (str, os.PathLike)):
        raise SettingTypeError(f"{_where(owner, name)} must be a path (a string), got {value!r} "
                        f"({type(value).__name__})")
    return os.fspath(value)


def check_optional(check, owner: str, name: str, value: Any, *args, **kwargs):
    """None, or whatever ``check(owner, name, value, ...)`` accepts."""
    return None if value is None else check(owner, name, value, *args, **kwargs)


def require_extra(module: str, extra: str, what: str) -> None:
    """Raises one line naming the extra to install when ``module`` cannot be found.

    Checked before any work starts (a study must not run every scan and then
    fail at the plot).

    Raises:
      MissingExtraError: ``module`` is not installed.
    """
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise MissingExtraError(f"{what} needs {module}: pip install 'plantsim[{extra}]'")


from plantsim.errors import PlantSimError  # noqa: E402  (after the checkers: no cycle)


class MissingExtraError(PlantSimError):
    """An optional extra that the asked-for feature needs is not installed."""
