"""``motion``: which parts of the picture move after each action, against how often they did in ID episodes.

A partly frozen camera (dead sensor rows, a stuck part of the image) shows live pictures whose
frozen part is an ordinary one: the whole picture never stands still, so ``stillness`` does not see
it, and ``frames`` (image statistics) only when the frozen part hides something it would have shown.
Measured on Pong, a region of the raw frames held from step 200 (``scripts/frozen_region.py``,
2026-11-30, 5 games each, default thresholds): the agent's own third, its paddle and the ball on its
side, alarmed 4 of 5 games after 91-104 (DropConnect) and 30-202 decisions (Dropout), up to 3 points
lost first, and 0 of 5 for the ensemble, which lost 20 points in each game unalarmed.

What a frozen part breaks is that it stops moving where it used to. Fitting splits the newest
frame into ``grid`` x ``grid`` tiles and finds, for each action (the action before the step) and
tile, how often the tile changed in the ID fitting episodes (``rates``; after an action they never
took, or for continuous actions, its rate after any). Each tile keeps the surprise of its current
run of unchanged steps: ``-log(1 - r[a_t, i])`` added at each step it stays the same after action
``a_t``, back to 0 when it changes. A step's value is the sum over the tiles: a tile that seldom
moves adds little while it stands still, the player's paddle that does not answer its moves adds
much, and a part frozen adds all its tiles'. No window: the runs are their own memory, as
``stillness``'s (which this is, for parts of a picture, weighed by how often each moves after the
action taken). Between points the whole picture stands still and every tile's surprise rises for
those steps, as it did in the ID episodes the threshold is calibrated on.

Measured by hand before it was written (the script not kept: Pong, 20 ID games of the shipped
ensemble cut at 1,500 decisions, the first 10 fitting; frozen from step 200, 5 games each; a
threshold at the highest value of the 10 fitting games): with 4 x 4 tiles the agent's third alarmed
29-53 decisions after it froze, the opponent's 15-24, the centre never; 0 of the other 10 ID games
passed the threshold (the DropConnect agent's games, the same way: 39-75 and 13-57 decisions, 4 of
10). With 7 x 7 tiles, 50-72 and 21-52 decisions and 3 of 10 ID games; 12 x 12, 70-98, 44-77, 3 of
10. A window's deficit of changes, as a z-score of the count expected from the actions taken (the
first form tried), alarmed the agent's third in 48-91 decisions with 12 x 12 tiles and 40 steps, and
5 of 10 ID games passed. As shipped (``oodmon calibrate --task pong --method M --detector motion``,
then ``scripts/frozen_region.py``): the agent's third 5 of 5 games at 51-73 decisions (DropConnect),
50-94 (Dropout) and 61-84 (ensemble), 0-2 points lost first; fresh ID games (``oodmon validate``):
DropConnect 28 of 500 (5.6%), Dropout and the ensemble 0 of 100. It is fitted when named
(``fitted_when_named``), not by default.

Tried for the centre, which ``motion`` sees late (the ball alone crosses it; 2026-12-01, the
DropConnect agent, the script not kept): each tile's changes over the last W steps against its ID
rate of change (any action), a Poisson log-likelihood ratio of the deficit summed over the tiles,
fitted on 30 ID games, its threshold the highest of 50 more (rank 50 of 50), 100 fresh ID games and
10 frozen games a region (onset 200). Best for the centre, 8 x 8 tiles and W = 300: 8 of 10 games
at 147-757 decisions (median 291.5), 4 of 100 fresh ID games over the threshold; but the agent's
third at a median 113 and the opponent's at 116, where ``motion`` takes 51-73 and 39-60. 12 x 12
and 16 x 16 tiles, W = 200 or 300: the centre 3-5 of 10. Not kept. What the centre's freeze
breaks is where the ball vanishes, not how often the tiles change: the ``vanishing`` detector sees
it in 4-33 decisions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory
from oodmon.monitor.detectors.frames import newest_frame
from oodmon.validation import is_whole

__all__ = ["MotionDetector", "check_tiles", "tile_changes", "tiles_any"]

#: Tiles per side of the picture: 21-pixel tiles of Pong's 84x84 frames.
GRID = 4
_CLIP = 1e-3  # rates kept inside [_CLIP, 1 - _CLIP]: no tile is certain to move or to stay


def tile_changes(frame: np.ndarray, last: np.ndarray, grid: int) -> np.ndarray:
    """(grid * grid,) whether each tile of ``frame`` (H, W or H, W, C) differs from ``last`` anywhere,
    the tiles row by row, their borders ``linspace`` over each side.

    Example:
        >>> last = np.zeros((4, 4), np.uint8)
        >>> frame = last.copy(); frame[3, 0] = 1
        >>> tile_changes(frame, last, 2).tolist()
        [False, False, True, False]
    """
    moved = frame != last
    return tiles_any(moved.any(axis=2) if moved.ndim == 3 else moved, grid)


def tiles_any(mask: np.ndarray, grid: int) -> np.ndarray:
    """(grid * grid,) whether each tile of the (H, W) boolean ``mask`` holds a true pixel, the tiles
    row by row, their borders ``linspace`` over each side.

    Example:
        >>> tiles_any(np.eye(4, dtype=bool), 2).tolist()
        [True, False, False, True]
    """
    rows = np.linspace(0, mask.shape[0], grid + 1).astype(int)[:-1]
    cols = np.linspace(0, mask.shape[1], grid + 1).astype(int)[:-1]
    return np.logical_or.reduceat(np.logical_or.reduceat(mask, rows, axis=0), cols, axis=1).reshape(-1)


def check_tiles(shape: tuple[int, ...], grid: int, detector: str) -> None:
    """Refuse pictures of ``shape`` that ``grid`` x ``grid`` tiles cannot split: not (H, W) or
    (H, W, C), or less than ``grid`` pixels a side (``tiles_any`` would read a border row again as
    the next tile's).

    Raises:
        ConfigError: naming ``detector`` and the shape.

    Example:
        >>> check_tiles((84, 84, 3), 4, "motion")   # passes
        >>> try:
        ...     check_tiles((3, 84), 4, "motion")
        ... except ConfigError as error:
        ...     str(error).split("; ")[1]
        'these are of shape (3, 84)'
    """
    if len(shape) not in (2, 3) or min(shape[:2]) < grid:
        raise ConfigError(f"the {detector} detector's {grid} x {grid} tiles need pictures, (H, W) or (H, W, C), of at "
                          f"least {grid} pixels a side; these are of shape {tuple(shape)}")


class MotionDetector(Detector):
    """The summed surprise of the picture's tiles standing still, after the actions taken (see the
    module's text).

    Example:
        >>> rng = np.random.default_rng(0)
        >>> frames = rng.integers(0, 2, (200, 14, 14)).astype(np.uint8)   # every tile moves at every step
        >>> detector = MotionDetector(grid=2).fit([Trajectory(frames, np.zeros(199, np.int64))])
        >>> detector.rates.shape, float(detector.rates.min())          # (actions + 1, tiles)
        ((2, 4), 0.999)
        >>> stuck = frames[0].copy()
        >>> [round(detector.score(StepContext(stuck, 0, prev_action=0)), 2) for _ in range(3)]   # 4 tiles x -log(0.001)
        [0.0, 27.63, 55.26]
    """

    name = "motion"
    learned = True

    def __init__(self, *, grid: int = GRID) -> None:
        if not is_whole(grid, 1):
            raise InvalidParameterError(f"the motion detector's grid={grid!r} must be a whole number >= 1")
        self.grid = int(grid)
        self.rates: np.ndarray | None = None  # (actions + 1, tiles): each tile's ID rate of change after each
        # action, the last row after any
        self._last: np.ndarray | None = None  # the last step's newest frame (a copy)
        self._runs: np.ndarray | None = None  # each tile's surprise since it last changed

    @property
    def fitted(self) -> bool:
        return self.rates is not None

    # -- fitting -----------------------------------------------------------------------------------
    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> MotionDetector:
        """Each tile's rate of change after each action over ID ``trajectories`` (their pictures
        where they hold them, else their observations).

        Raises:
            ConfigError: no episode of two steps or more, or pictures smaller than the tiles.
        """
        changes, actions = [], []
        for trajectory in trajectories:
            seen = np.asarray(trajectory.seen)
            if len(seen) < 2:
                continue
            frames = [newest_frame(obs) for obs in seen]
            check_tiles(frames[0].shape, self.grid, self.name)
            changes.append(np.array([tile_changes(b, a, self.grid) for a, b in zip(frames[:-1], frames[1:])]))
            actions.append(_action_rows(np.asarray(trajectory.actions)[:len(frames) - 1]))
        if not changes:
            raise ConfigError("the motion detector needs ID episodes of two steps or more to learn how their pictures "
                              "move; got none")
        changed, taken = np.concatenate(changes).astype(np.float64), np.concatenate(actions)
        overall = changed.mean(axis=0)
        n_actions = int(taken.max()) + 1 if (taken >= 0).any() else 0
        rows = [changed[taken == a].mean(axis=0) if (taken == a).any() else overall for a in range(n_actions)]
        self._set(np.array([*rows, overall]))
        return self

    def _set(self, rates: np.ndarray) -> None:
        self.rates = np.clip(np.asarray(rates, np.float64), _CLIP, 1 - _CLIP)
        self._surprise = -np.log1p(-self.rates)  # of a tile standing still one step, after each action
        self.reset()

    # -- scoring -----------------------------------------------------------------------------------
    def reset(self) -> None:
        self._last = self._runs = None

    def score(self, context: StepContext) -> float:
        """The sum over the tiles of the surprise of their current runs of unchanged steps (0 at an
        episode's first step)."""
        self.check_fitted()
        frame = newest_frame(np.asarray(context.seen))
        last, self._last = self._last, frame.copy()
        if last is None:
            check_tiles(frame.shape, self.grid, self.name)
            self._runs = np.zeros(self.rates.shape[1])
            return 0.0
        if last.shape != frame.shape:
            raise ConfigError(f"the motion detector's pictures changed shape within an episode: {last.shape} then "
                              f"{frame.shape}")
        action = None if context.prev_action is None else np.asarray(context.prev_action)
        row = int(action) if action is not None and action.ndim == 0 and np.issubdtype(action.dtype, np.integer) else -1
        surprise = self._surprise[row if 0 <= row < len(self._surprise) - 1 else -1]
        self._runs = np.where(tile_changes(frame, last, self.grid), 0.0, self._runs + surprise)
        return float(self._runs.sum())

    # -- state -------------------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        return {"grid": self.grid}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"rates": self.rates}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> MotionDetector:
        detector = cls(**config)
        if "rates" not in tensors:
            raise ConfigError("the motion detector's tensors are incomplete: no 'rates'")
        rates = np.asarray(tensors["rates"])
        if (rates.ndim != 2 or len(rates) == 0 or rates.shape[1] != detector.grid ** 2 or not np.isfinite(rates).all()
                or (rates < 0).any() or (rates > 1).any()):
            raise ConfigError(f"the motion detector's rates have shape {rates.shape} and must be rates in [0, 1], one "
                              f"row per action and one more, {detector.grid ** 2} tiles each")
        detector._set(rates)
        return detector


def _action_rows(actions: np.ndarray) -> np.ndarray:
    """Each action's row of the rates: a discrete action its own index; continuous actions -1 (the row after any)."""
    if actions.ndim == 1 and np.issubdtype(actions.dtype, np.integer):
        return actions.astype(np.int64)
    return np.full(len(actions), -1, np.int64)
