"""The tests of "a whole number" and "a number" that oodmon's argument checks use."""

from __future__ import annotations

import math
import numbers

__all__ = ["is_finite_real", "is_real", "is_whole"]


def is_whole(value: object, minimum: int = 1) -> bool:
    """``value`` is an integer (Python's or numpy's, not a bool) of at least ``minimum``.

    Example:
        >>> is_whole(3), is_whole(0), is_whole(0, minimum=0), is_whole(True), is_whole(2.0)
        (True, False, True, False, False)
    """
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= minimum


def is_real(value: object) -> bool:
    """``value`` is a real number (Python's or numpy's, not a bool; NaN and infinities too).

    Example:
        >>> is_real(0.5), is_real(3), is_real(float("nan")), is_real(True), is_real("1")
        (True, True, True, False, False)
    """
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_finite_real(value: object) -> bool:
    """``value`` is a real number that is finite (not a bool, NaN or an infinity): a figure a
    person's file or a spec may give.

    Example:
        >>> is_finite_real(0.5), is_finite_real(float("inf")), is_finite_real(float("nan")), is_finite_real(False)
        (True, False, False, False)
    """
    return is_real(value) and math.isfinite(value)
