"""Progress of long work, one shape everywhere: ``on_progress(stage, done, total)``.

Training, calibration, detector fitting, validation, evaluation, the bench and a monitored
episode all report through it. ``stage`` says what is counted and ends with the unit
("calibration episodes", "member0 training steps", "monitored cells"), so that a printer can show
"stage: done/total" and a rate in that unit (:func:`unit_of`); ``total`` is 0 where it is not
known in advance (the decisions of a Pong game).
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["Progress", "unit_of"]

#: ``on_progress(stage, done, total)``.
Progress = Callable[[str, int, int], None]


def unit_of(stage: str) -> str:
    """The unit a stage counts: its last word.

    Example:
        >>> unit_of("dropout trial 0: calibration episodes"), unit_of("")
        ('episodes', '')
    """
    words = stage.split()
    return words[-1] if words else ""
