"""``vanishing``: things that vanish from, or appear in, a part of the picture where nothing ever did in ID episodes.

A part of the camera frozen in the middle of the picture (``pong:frozen_region``, the centre block
of ``scripts/frozen_region.py``) shows a live picture around a still one that only the ball ever
crossed: the whole picture never stands still (``stillness``), the frozen part seldom moved anyway
(``motion`` weighs its stillness by how often it moved: it saw the centre after 265-957 decisions,
2026-11-30), and each picture is an ordinary one (``frames``). What the freeze breaks is that the
ball now vanishes where it enters the frozen part and appears where it leaves it, in the middle of
the field, where in ID play it only ever vanished at the goals.

Fitting takes the background, each pixel's median over the ID fitting pictures (the newest frame
of each step), and calls a pixel foreground where it differs from it (any channel). A foreground
pixel *vanished* when no foreground pixel is within ``reach`` pixels of it (a square) in the next
picture, and one *appeared* when none was within ``reach`` in the picture before: a thing that
moves less than ``reach`` a step does neither. Each of ``grid`` x ``grid`` tiles is two sensors,
whether something vanished from it and whether something appeared in it at a step, and fitting
counts how often each did over the ID fitting transitions (``events``). A step's value is the
number of events so far in the episode at sensors that never had one in the fitting episodes (0 at
its first steps; no window: an event never seen in ID play is rare enough to keep). A transition
to or from a picture that differs from the background at more than half its pixels is not read:
a different scene, not things moving in it (Pong's reset picture: 6,277 or all 7,056 pixels in 7
of 40 games of the shipped DropConnect agent; noise over the whole picture, which ``frames`` sees
at once).

Measured before it was written (2026-12-01, the script in /tmp, not kept): the shipped Pong
DropConnect agent, 40 ID games (seeds 700,000 on, whole games of 1,990-3,001 decisions) fitting,
40 more held out (710,000 on), 10 games a region frozen from decision 200 (800,000 on). With 12 x
12 tiles and ``reach`` 10, 15 of the 288 sensors had events in the fitting games (the paddles'
columns, the goals, the score) and none of the 40 held-out games had an event elsewhere; the
centre's first event came 3-32 decisions after it froze in 10 of 10 games, the agent's third 1-42,
the opponent's 2-40. With ``reach`` 6 a fast ball (9 pixels a decision) outran it: 9 of 40
held-out games had events at unseen sensors, and the centre's were found in 1 of 10 games; with 8,
2 of 40, the centre 10 of 10 at 24-58. (The prototype left out each episode's first transition
instead of other scenes.) The shipped ensemble's games (40 fitting, 40 held out, cut at 1,200 decisions): the same, 0 of 40 and
the centre 10 of 10 at 5-33. A step's score took 120 us (the fitted detector on 2,553 steps of
a DropConnect game, both cores busy with other work; ``frames`` 30, ``stillness`` 6). Its blind
spots: a frozen part that nothing crosses, and noise over the whole picture (another scene to it:
``frames`` sees that). Motion blur it sees: in the monitor's benchmark its ``combined`` alarmed
every blurred game after 1 decision, 5-6 without it
(``results/monitor/pong-combined-vanishing-<method>.json``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import Region
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory
from oodmon.monitor.detectors.frames import newest_frame
from oodmon.monitor.detectors.motion import check_tiles, tiles_any
from oodmon.validation import is_whole

__all__ = ["VanishingDetector"]

#: Tiles per side of the picture: 7-pixel tiles of Pong's 84x84 frames.
GRID = 12
#: How far, in pixels, a thing may move in a step and still be the same thing (Pong's fastest
#: ball moves 9 pixels a decision of its 84x84 frames).
REACH = 10
#: Pictures with the background at fewer than half their pixels are another scene (see the module's text).
_SCENE = 0.5
#: At most this many pictures make the background (every n-th of the fitting ones).
_BACKGROUND_FRAMES = 5000


class VanishingDetector(Detector):
    """The events so far in the episode of things vanishing or appearing where they never did in
    the ID fitting episodes (see the module's text).

    Example:
        >>> def dot(x):                                  # a dot on a dark 21x21 picture, at column x
        ...     frame = np.zeros((21, 21), np.uint8); frame[10, x] = 255; return frame
        >>> sweep = [dot(x) for x in [*range(21), *range(20, -1, -1)]]   # back and forth along row 10
        >>> detector = VanishingDetector(grid=3, reach=2).fit([Trajectory(np.array(sweep), np.zeros(41))])
        >>> detector.events.tolist()                     # nothing vanished or appeared in the ID sweep
        [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]]
        >>> hidden = [dot(x) if not 7 <= x < 14 else np.zeros((21, 21), np.uint8) for x in range(21)]
        >>> [detector.score(StepContext(frame, 0)) for frame in hidden][5:16]   # hidden in the middle third
        [0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 2.0]
        >>> detector.where()      # the row of tiles where it vanished (x=6, before the hidden third) and appeared (14)
        Region(top=7, left=0, height=7, width=21, rows=21, columns=21)
    """

    name = "vanishing"
    learned = True

    def __init__(self, *, grid: int = GRID, reach: int = REACH) -> None:
        for label, value, least in (("grid", grid, 1), ("reach", reach, 0)):
            if not is_whole(value, least):
                raise InvalidParameterError(f"the vanishing detector's {label}={value!r} must be a whole number >= "
                                            f"{least}")
        self.grid, self.reach = int(grid), int(reach)
        self.background: np.ndarray | None = None  # (H, W) or (H, W, C): each pixel's ID median
        self.events: np.ndarray | None = None  # (2, tiles): the ID transitions with a thing vanished, appeared there
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # the last picture's foreground and its reach
        self._count = 0
        self._where = np.zeros(self.grid ** 2, bool)  # the tiles of the episode's events at sensors without an ID one

    @property
    def fitted(self) -> bool:
        return self.events is not None

    # -- the pictures ------------------------------------------------------------------------------
    def _foreground(self, frame: np.ndarray) -> np.ndarray | None:
        """Where ``frame`` differs from the background, (H, W); ``None`` for another scene."""
        if frame.shape != self.background.shape:
            raise ConfigError(f"the vanishing detector was fitted on pictures of shape {self.background.shape}; this "
                              f"one is of shape {frame.shape}")
        differs = frame != self.background
        if differs.ndim == 3:
            differs = differs.any(axis=2)
        return None if differs.mean() > _SCENE else differs

    def _near(self, foreground: np.ndarray) -> np.ndarray:
        """The pixels within ``reach`` (a square) of a foreground pixel."""
        from scipy.ndimage import maximum_filter

        return maximum_filter(foreground, size=2 * self.reach + 1, mode="constant", cval=False)

    def _advance(self, obs: np.ndarray) -> np.ndarray | None:
        """(2, tiles): whether something vanished from each tile, and appeared in it, from the last
        picture to the one of ``obs`` (its newest frame), which becomes the last; ``None`` at an
        episode's first picture or where either is another scene."""
        foreground = self._foreground(newest_frame(np.asarray(obs)))
        now = (foreground, self._near(foreground)) if foreground is not None else None
        last, self._last = self._last, now
        if last is None or now is None:
            return None
        (was, was_near), (now, now_near) = last, now
        return np.array([tiles_any(was & ~now_near, self.grid), tiles_any(now & ~was_near, self.grid)])

    # -- fitting -----------------------------------------------------------------------------------
    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> VanishingDetector:
        """The background of ID ``trajectories``' pictures (their newest frames), then how often
        something vanished from and appeared in each tile over their transitions.

        Raises:
            ConfigError: no episode of two steps or more, pictures of more than one shape, or
                smaller than the tiles.
        """
        episodes = [t.seen for t in trajectories if len(t.seen) >= 2]
        if not episodes:
            raise ConfigError("the vanishing detector needs ID episodes of two steps or more to learn where things "
                              "vanish in their pictures; got none")
        shapes = {newest_frame(np.asarray(e[0])).shape for e in episodes}
        if len(shapes) > 1:
            raise ConfigError(f"the vanishing detector needs pictures of one shape, (H, W) or (H, W, C); got "
                              f"{sorted(shapes)}")
        check_tiles(next(iter(shapes)), self.grid, self.name)  # (H, W) or (H, W, C), at least a tile a pixel
        # (the pictures are taken episode by episode: Pong's 60 fitting games hold some 140,000)
        every = max(1, sum(map(len, episodes)) // _BACKGROUND_FRAMES)
        sample = np.array([newest_frame(np.asarray(obs)) for seen in episodes for obs in seen[::every]])
        self.background = np.median(sample, axis=0).astype(sample.dtype)
        events = np.zeros((2, self.grid ** 2))
        for seen in episodes:
            self.reset()
            for obs in seen:
                step = self._advance(obs)
                if step is not None:
                    events += step
        self._set(self.background, events)
        return self

    def _set(self, background: np.ndarray, events: np.ndarray) -> None:
        self.background, self.events = background, np.asarray(events, np.float64)
        self._never = self.events == 0
        self.reset()

    # -- scoring -----------------------------------------------------------------------------------
    def reset(self) -> None:
        self._last, self._count = None, 0
        self._where[:] = False

    def score(self, context: StepContext) -> float:
        """The episode's events so far at sensors without an ID event (0 at its first step)."""
        self.check_fitted()
        step = self._advance(context.seen)
        if step is not None:
            unseen = step & self._never
            events = int(unseen.sum())
            if events:
                self._count += events
                self._where |= unseen.any(axis=0)
        return float(self._count)

    def where(self) -> Region | None:
        """Where in the picture the episode's events so far fell (:meth:`score`'s): the bounding
        box of their tiles, in the pixels of the picture it reads; ``None`` before the first. A
        frozen part of the camera shows as its border, where the ball vanishes and appears (the
        shipped Pong ensemble under its default alarm, a part frozen from decision 200: each of the
        22 first alarms it raised in 25 games named a box within 10 pixels of the frozen part,
        docs/detectors.md)."""
        if self.background is None or not self._where.any():
            return None
        rows, columns = self.background.shape[:2]
        tile_rows, tile_columns = np.divmod(np.flatnonzero(self._where), self.grid)
        row_borders = np.linspace(0, rows, self.grid + 1).astype(int)
        column_borders = np.linspace(0, columns, self.grid + 1).astype(int)
        top, bottom = int(row_borders[tile_rows.min()]), int(row_borders[tile_rows.max() + 1])
        left, right = int(column_borders[tile_columns.min()]), int(column_borders[tile_columns.max() + 1])
        return Region(top, left, bottom - top, right - left, int(rows), int(columns))

    # -- state -------------------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        return {"grid": self.grid, "reach": self.reach}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"background": self.background, "events": self.events}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> VanishingDetector:
        detector = cls(**config)
        missing = [key for key in ("background", "events") if key not in tensors]
        if missing:
            raise ConfigError(f"the vanishing detector's tensors are incomplete: no {missing[0]!r}")
        background, events = np.asarray(tensors["background"]), np.asarray(tensors["events"])
        if background.ndim not in (2, 3) or min(background.shape[:2]) < detector.grid or 0 in background.shape:
            raise ConfigError(f"the vanishing detector's background has shape {background.shape}; it must be a "
                              f"picture, (H, W) or (H, W, C), of at least {detector.grid} pixels a side (its tiles)")
        if events.shape != (2, detector.grid ** 2) or not np.isfinite(events).all() or (events < 0).any():
            raise ConfigError(f"the vanishing detector's events have shape {events.shape} and must be counts >= 0 "
                              f"of shape (2, {detector.grid ** 2}): vanished and appeared, per tile")
        detector._set(background, events)
        return detector
