"""Argument checks at construction: one checker per kind of value, each raising
:class:`~sb3_pola.common.errors.HyperparameterError` (a ``ValueError``) that names the public argument and the
allowed range, e.g. ``batch_size must be an int >= 1, got 0``.

SB3 checks its own arguments where it builds the model (``PPO``'s ``batch_size > 1``...); these checks run before
the dataset is loaded, so a bad value fails at once rather than inside ``learn`` after the dynamics fit.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Collection, Mapping
from typing import Any

from sb3_pola.common.errors import HyperparameterError


def _interval(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    """The range in words: ``>= 1``, ``> 0``, ``in (0, 1]``..."""
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
    if low is not None:
        return f"{'>' if low_open else '>='} {low}"
    if high is not None:
        return f"{'<' if high_open else '<='} {high}"
    return "finite"


def _inside(value: float, low: float | None, high: float | None, low_open: bool, high_open: bool) -> bool:
    if not math.isfinite(value):
        return False
    if low is not None and (value < low or (low_open and value == low)):
        return False
    return not (high is not None and (value > high or (high_open and value == high)))


def check_int(name: str, value: Any, low: int | None = None, high: int | None = None, optional: bool = False) -> int | None:
    """An integer in ``[low, high]`` (``None`` allowed with ``optional``).

    :param name: the argument's public name, used in the message
    :param value: the value given
    :param low: smallest allowed value
    :param high: largest allowed value
    :param optional: ``None`` is allowed
    :return: the value
    :raises HyperparameterError: not an int, or out of range
    """
    if value is None and optional:
        return None
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if not ok or not _inside(float(value), low, high, False, False):
        none = "None or " if optional else ""
        raise HyperparameterError(f"{name} must be {none}an int {_interval(low, high, False, False)}, got {value!r}")
    return int(value)


def check_float(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    optional: bool = False,
) -> float | None:
    """A finite real number in the given interval (``None`` allowed with ``optional``).

    :param name: the argument's public name
    :param value: the value given
    :param low: lower bound
    :param high: upper bound
    :param low_open: the lower bound itself is excluded
    :param high_open: the upper bound itself is excluded
    :param optional: ``None`` is allowed
    :return: the value as a float
    :raises HyperparameterError: not a real number, or out of range
    """
    if value is None and optional:
        return None
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not ok or not _inside(float(value), low, high, low_open, high_open):
        none = "None or " if optional else ""
        raise HyperparameterError(f"{name} must be {none}a number {_interval(low, high, low_open, high_open)}, got {value!r}")
    return float(value)


def check_float_or_schedule(name: str, value: Any, low: float, low_open: bool = False) -> float | Callable[[float], float]:
    """A number above ``low`` or a schedule (a callable of the remaining progress, checked at its start value 1).

    :param name: the argument's public name
    :param value: a number or a callable
    :param low: lower bound
    :param low_open: ``low`` itself is excluded
    :return: the value
    :raises HyperparameterError: a number out of range, or a schedule whose start value is
    """
    if callable(value):
        try:
            start = value(1.0)
        except Exception:  # a schedule of another signature: SB3 calls it later and says so then
            return value
        if isinstance(start, numbers.Real) and not _inside(float(start), low, None, low_open, False):
            raise HyperparameterError(
                f"{name} must be a number {_interval(low, None, low_open, False)} or a schedule of such numbers; "
                f"the schedule gives {start!r} at the start"
            )
        return value
    if not isinstance(value, numbers.Real) or isinstance(value, bool) or not _inside(float(value), low, None, low_open, False):
        raise HyperparameterError(
            f"{name} must be a number {_interval(low, None, low_open, False)} or a schedule, got {value!r}"
        )
    return float(value)


def check_choice(name: str, value: Any, choices: Collection[Any]) -> Any:
    """One of ``choices``.

    :param name: the argument's public name
    :param value: the value given
    :param choices: the allowed values
    :return: the value
    :raises HyperparameterError: not one of them
    """
    if value not in choices:
        raise HyperparameterError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def check_keys(name: str, given: Mapping[str, Any], known: Collection[str]) -> None:
    """The keys of a dict argument (``dynamics_kwargs``...) are all known ones.

    :param name: the argument's public name
    :param given: the dict given
    :param known: the accepted keys
    :raises HyperparameterError: an unknown key, named with the known ones
    """
    if not isinstance(given, Mapping):
        raise HyperparameterError(f"{name} must be a dict or None, got {given!r}")
    unknown = [key for key in given if key not in known]
    if unknown:
        raise HyperparameterError(
            f"{name} has unknown key(s) {', '.join(map(repr, unknown))}; known: {', '.join(sorted(known))}"
        )


__all__ = ["check_choice", "check_float", "check_float_or_schedule", "check_int", "check_keys"]
