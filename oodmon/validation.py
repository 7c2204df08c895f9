"""The tests of "a whole number" and "a number" that oodmon's argument checks use, and the words
for a path that is not a file."""

from __future__ import annotations

import math
import numbers
from pathlib import Path

__all__ = ["MOST_STEPS", "check_max_steps", "is_finite_real", "is_real", "is_step_count", "is_whole", "not_a_file"]

#: The most steps a count may name where oodmon keeps that many scores, or plays that many in a
#: dry run: an alarm rule's ``consecutive``, ``window`` and ``warmup``, a detector's ``window``.
#: Ten million, 55 hours of decisions at 50 a second. A larger count (10**30) asked numpy or a
#: deque for more than memory holds, and their errors came as tracebacks (2026-12-05).
MOST_STEPS = 10_000_000


def is_whole(value: object, minimum: int = 1) -> bool:
    """``value`` is an integer (Python's or numpy's, not a bool) of at least ``minimum``.

    Example:
        >>> is_whole(3), is_whole(0), is_whole(0, minimum=0), is_whole(True), is_whole(2.0)
        (True, False, True, False, False)
    """
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= minimum


def check_max_steps(max_steps: object) -> None:
    """``max_steps`` is an episode's time limit (a whole number >= 1) or ``None`` (the env's own).

    Raises:
        InvalidParameterError: it is neither (said before an episode is played; 0 reached
            gymnasium's ``TimeLimit`` from ``fit_agent_detectors`` until 2026-12-05, a ValueError).
    """
    from oodmon.errors import InvalidParameterError

    if max_steps is not None and not is_whole(max_steps):
        raise InvalidParameterError(f"max_steps={max_steps!r} is not allowed; give each episode's time limit, a whole "
                                    "number >= 1 of steps (None: the env's own)")


def is_step_count(value: object, minimum: int = 1) -> bool:
    """``value`` is a whole number (as :func:`is_whole`) from ``minimum`` to :data:`MOST_STEPS`.

    Example:
        >>> is_step_count(20), is_step_count(0), is_step_count(0, minimum=0), is_step_count(10**30)
        (True, False, True, False)
    """
    return is_whole(value, minimum) and value <= MOST_STEPS


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


def not_a_file(path: Path) -> str:
    """What ``path``, which is not a regular file, is instead, in words that follow its name.

    A device or a pipe was said not to exist (``--vec-normalize /dev/zero``, 2026-12-05).

    Example:
        >>> not_a_file(Path("/")), not_a_file(Path("/dev/null")), not_a_file(Path("/no/such/file"))
        ('is a folder', 'is not a regular file (a device or a pipe)', 'does not exist')
    """
    if path.is_dir():
        return "is a folder"
    return "is not a regular file (a device or a pipe)" if path.exists() else "does not exist"
