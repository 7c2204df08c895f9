"""``stillness``: how long a sensor has gone unchanged, against the longest it ever did in ID episodes.

A frozen camera shows an ordinary picture, again and again: ``frames`` scores each picture by
itself and sees nothing wrong (Pong DropConnect, ``pong:obs.stuck=1`` from step 200: its frames
alarm rang in 0 of 5 games, 2026-11-30), and neither do the policy's samples or features. What is out of the ordinary
is time: a live camera's picture changes from one step to the next, and when it does not, not for
long. Fitting finds, for each sensor, the longest run of steps its reading stayed exactly the same
in the ID fitting episodes (``longest``); a step's value is the largest, over the sensors, of the
current run minus ``longest``, the steps past the ID record: 0 or less while every sensor has stood
still no longer than it ever did, 1 the step one passes its record, growing by 1 with each step
after. No window: the run is its own memory.

The sensors are the step's picture (its newest frame: a stack of frames moves a frozen frame in at
each step) for image observations, else each reading of the (flattened) observation. Measured on
the shipped Pong DropConnect agent, 33 ID games (seeds 700,000-700,032, some 2,200 steps each):
the newest frame stood still at 0-2.5% of a game's steps (between points), its longest run 0-11
steps. A frozen camera passes the record some ten steps after it freezes; ``combined`` counts each
step past its largest held-out value as a rank, a tenfold rarer p-value (``UNIT_MEMBERS``).

It is fitted by default for pictures, beside ``frames``, and ``combined`` ranks it; for vectors
only when named (the ``dynamics`` model already sees a stuck reading: CartPole's angular velocity
stuck, 10 of 10 alarmed at delay 1). Its blind spot: a sensor that stands still in ID episodes as
long as an episode lasts (a constant reading) is never out of the ordinary.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory
from oodmon.monitor.detectors.frames import is_picture, newest_frame

__all__ = ["StillnessDetector", "longest_runs", "still_steps"]


def longest_runs(still: np.ndarray) -> np.ndarray:
    """Per column of ``still`` (steps, sensors; whether each sensor read the same as at the step
    before), the longest run of steps in a row that it did.

    Example:
        >>> longest_runs(np.array([[True, False], [True, True], [False, True], [True, False]])).tolist()
        [2, 2]
    """
    still = np.asarray(still, bool)
    longest = np.zeros(still.shape[1], np.int64)
    run = np.zeros(still.shape[1], np.int64)
    for row in still:
        run = np.where(row, run + 1, 0)
        np.maximum(longest, run, out=longest)
    return longest


def still_steps(readings: np.ndarray, *, pictures: bool) -> np.ndarray:
    """(T - 1, sensors): whether each sensor of an episode's ``readings`` (T steps) read the same as
    at the step before; a picture's one sensor is its newest frame (:func:`newest_frame`)."""
    if pictures:
        frames = [newest_frame(reading) for reading in readings]
        return np.array([[np.array_equal(a, b)] for a, b in zip(frames[1:], frames[:-1])], bool).reshape(-1, 1)
    flat = np.asarray(readings, np.float64).reshape(len(readings), -1)
    return flat[1:] == flat[:-1]


class StillnessDetector(Detector):
    """The steps an unchanged sensor has stood still past its longest ID run (see the module's text).

    Example:
        >>> moving = Trajectory(np.array([[0.0, 5.0], [1.0, 5.0], [2.0, 6.0], [3.0, 6.0]]), np.zeros(3))
        >>> detector = StillnessDetector().fit([moving])   # reading 0 always moves, reading 1 holds 1 step
        >>> detector.longest.tolist()
        [0, 1]
        >>> [detector.score(StepContext(np.array([x, 7.0]), 0)) for x in (4.0, 4.0, 4.0)]   # reading 0 stuck
        [0.0, 1.0, 2.0]
        >>> detector.reset()
        >>> [detector.score(StepContext(np.array([x, 7.0]), 0)) for x in (5.0, 6.0, 7.0)]   # reading 1 stuck
        [0.0, 0.0, 1.0]
    """

    name = "stillness"
    learned = True

    def __init__(self, *, pictures: bool = False) -> None:
        self.pictures = pictures  # the sensor is the newest frame of a picture, else each reading
        self.longest: np.ndarray | None = None  # (sensors,) the longest ID run of each
        self._last: np.ndarray | None = None  # the last step's readings (a copy)
        self._run: np.ndarray | int | None = None  # each sensor's current run of unchanged steps (a picture's: an int)

    @property
    def fitted(self) -> bool:
        return self.longest is not None

    # -- fitting -----------------------------------------------------------------------------------
    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> StillnessDetector:
        """Find each sensor's longest unchanged run over ID ``trajectories`` (their pictures where
        they hold them, else their observations).

        Raises:
            ConfigError: no episode of two steps or more.
        """
        kept = [t for t in trajectories if len(t.observations) >= 2]
        if not kept:
            raise ConfigError("the stillness detector needs ID episodes of two steps or more to learn how long its "
                              "sensors stand still; got none")
        episodes = [np.asarray(t.seen) for t in kept]
        self.pictures = kept[0].pictures is not None or is_picture(episodes[0].shape[1:], episodes[0].dtype)
        self._set(np.max([longest_runs(still_steps(e, pictures=self.pictures)) for e in episodes], axis=0))
        return self

    def _set(self, longest: np.ndarray) -> None:
        self.longest = np.asarray(longest, np.int64)
        self._record = int(self.longest[0])  # a picture's one record, read at every step
        self._last = self._run = None

    # -- scoring -----------------------------------------------------------------------------------
    def reset(self) -> None:
        self._last = self._run = None

    def score(self, context: StepContext) -> float:
        """The most steps a sensor has stood still past its longest ID run (0 or less: none has)."""
        self.check_fitted()
        seen = context.seen
        if self.pictures:  # one sensor, the newest frame, whole: its run an int (each Pong decision's path)
            frame = newest_frame(np.asarray(seen))
            self._run = self._run + 1 if self._last is not None and np.array_equal(frame, self._last) else 0
            self._last = frame.copy()
            return float(self._run - self._record)
        readings = np.asarray(seen, np.float64).reshape(-1)
        if len(readings) != len(self.longest):
            raise ConfigError(f"the stillness detector was fitted on {len(self.longest)} readings; this "
                              f"observation holds {len(readings)}")
        still = readings == self._last if self._last is not None else np.zeros(len(readings), bool)
        self._run = np.where(still, self._run + 1, 0) if self._run is not None else np.zeros(len(still), np.int64)
        self._last = readings.copy()
        return float((self._run - self.longest).max())

    # -- state -------------------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        return {"pictures": self.pictures}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"longest": self.longest}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> StillnessDetector:
        detector = cls(**config)
        if "longest" not in tensors:
            raise ConfigError("the stillness detector's tensors are incomplete: no 'longest'")
        longest = np.asarray(tensors["longest"])
        if longest.ndim != 1 or len(longest) == 0 or np.any(longest < 0) or (detector.pictures and len(longest) != 1):
            raise ConfigError(f"the stillness detector's longest runs have shape {longest.shape} and must be whole "
                              "numbers >= 0, one per reading (one for a picture)")
        detector._set(longest)
        return detector

