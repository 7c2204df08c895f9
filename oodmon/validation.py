"""The one test of "a whole number" that every argument check of oodmon uses."""

from __future__ import annotations

import numbers

__all__ = ["is_whole"]


def is_whole(value: object, minimum: int = 1) -> bool:
    """``value`` is an integer (Python's or numpy's, not a bool) of at least ``minimum``.

    Example:
        >>> is_whole(3), is_whole(0), is_whole(0, minimum=0), is_whole(True), is_whole(2.0)
        (True, False, True, False, False)
    """
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= minimum
