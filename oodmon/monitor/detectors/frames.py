"""``frames``: how far a camera frame's image statistics are from the ID frames'.

A corrupted camera changes the picture itself before it changes anything the policy computes:
noise adds high-frequency energy, blur takes it away, both shift the brightness. Each step's
newest frame (the last of a stack of frames) is summarised by five numbers: its mean and standard
deviation, and the logarithms of its Laplacian's variance and of its mean absolute horizontal and
vertical differences (sharpness). A step's value is ``log(1 + d^2)``, d the Mahalanobis distance
of those five from the ID frames' (mean and Ledoit-Wolf covariance fitted on ID episodes), and the
score its mean over the episode's last ``window`` steps, as the other learned detectors have it.
The logarithm keeps one odd ID frame from dominating a window: Pong's first frame of some games
is nearly blank (std 12 against 47) and lies at d^2 ~ 10^7 from the fit, where a corrupted
frame lies at 10^3-10^5 and a usual ID frame below 30. For the same reason an episode's window
starts full of the fit frames' median value instead of empty: the first frame alone is not a
window's mean.

It reads the observation only, so it watches any policy, an SB3 model of a user's as much as an
oodmon agent; it needs image observations (two dimensions or more). Its blind spot, measured in
``tests/monitor/test_frames.py``: pixelate@2 (2-pixel blocks) changes the statistics hardly at
all, while every other Pong corruption, severity 1 included, lies above every fresh ID frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, RecentMean, StepContext, Trajectory

__all__ = ["FramesDetector", "channels_last", "frame_statistics", "is_picture", "newest_frame"]

#: The statistics of one frame, in the order :func:`frame_statistics` returns them.
STATISTICS = ("mean", "std", "log_laplacian_var", "log_dx", "log_dy")


def channels_last(shape: tuple[int, ...]) -> bool:
    """Whether an image observation of ``shape`` holds its channels last, (H, W, C), as SB3 tells
    (its smallest dimension is the last): an RGB picture (64, 64, 3), or SB3's Atari stack
    (84, 84, 4). Pong's (4, 84, 84) holds them first.

    Example:
        >>> channels_last((84, 84, 4)), channels_last((4, 84, 84)), channels_last((84, 84))
        (True, False, False)
    """
    return len(shape) == 3 and shape[-1] < min(shape[:2])


#: The fewest pixels on each side of a picture of numbers other than bytes (a normalised frame);
#: smaller arrays of floats are stacked vectors (CartPole's state 4 deep is (4, 4)), not pictures.
PICTURE_SIDE = 16


def is_picture(shape: tuple[int, ...], dtype: object) -> bool:
    """Whether observations of ``shape`` and ``dtype`` are images the frames detector reads: bytes
    of two or more dimensions (Pong's (4, 84, 84), an RGB (64, 64, 3)), or floats whose newest frame
    is at least :data:`PICTURE_SIDE` pixels each way; not vectors, nor vectors stacked (4, 4).

    Example:
        >>> is_picture((4, 84, 84), np.uint8), is_picture((64, 64), np.float32), is_picture((4, 4), np.float32)
        (True, True, False)
    """
    if len(shape) < 2:
        return False
    if np.dtype(dtype) == np.uint8:
        return True
    frame = shape[:2] if channels_last(shape) else shape[-2:]
    return min(frame) >= PICTURE_SIDE


def newest_frame(obs: np.ndarray) -> np.ndarray:
    """The picture a step's observation shows now: for a stack of frames its newest (the last plane
    of a channel-first stack such as Pong's (4, 84, 84), the last channel of a channel-last one such
    as SB3's Atari (84, 84, 4)), for an RGB picture (H, W, 3) the picture itself, else ``obs``."""
    array = np.asarray(obs)
    if channels_last(array.shape):
        return array if array.shape[-1] == 3 else array[..., -1]
    return array.reshape(-1, *array.shape[-2:])[-1] if array.ndim >= 3 else array


def frame_statistics(obs: np.ndarray) -> np.ndarray:
    """The five image statistics (:data:`STATISTICS`) of :func:`newest_frame` of ``obs``, in grey
    (an RGB picture's mean over its channels).

    Raises:
        ConfigError: ``obs`` has fewer than two dimensions (not an image).

    Example:
        >>> flat = np.full((4, 8, 8), 100, np.uint8)
        >>> frame_statistics(flat).round(2).tolist()
        [100.0, 0.0, -6.91, -6.91, -6.91]
    """
    import cv2

    array = np.asarray(obs)
    frame = newest_frame(array)
    if frame.ndim < 2 or min(frame.shape[:2]) < 2:
        raise ConfigError(f"the frames detector needs image observations of 2 x 2 pixels or more; got shape {array.shape}")
    if frame.ndim == 3:  # RGB: its grey
        frame = frame.mean(axis=-1, dtype=np.float32)
    if frame.dtype not in (np.uint8, np.float32):
        frame = frame.astype(np.float32)
    # OpenCV sums in float64 without temporaries: a third of the time of the numpy equivalents
    # (np.diff, np.abs, .var), which this once used; the statistics agree to 3e-7 relative.
    mean, std = cv2.meanStdDev(frame)
    _, laplacian_std = cv2.meanStdDev(cv2.Laplacian(frame, cv2.CV_32F))
    height, width = frame.shape
    across = cv2.norm(frame[:, 1:], frame[:, :-1], cv2.NORM_L1) / (height * (width - 1))
    down = cv2.norm(frame[1:], frame[:-1], cv2.NORM_L1) / ((height - 1) * width)
    eps = 1e-3
    return np.array([mean[0, 0], std[0, 0], math.log(laplacian_std[0, 0] ** 2 + eps),
                     math.log(across + eps), math.log(down + eps)], np.float64)


class FramesDetector(Detector):
    """``log(1 + d^2)``, d the Mahalanobis distance of each frame's image statistics from the ID frames'.

    It reads the step's picture: the observation, or a dict observation's picture beside the
    vectors the other detectors read (``StepContext.picture``).

    Args:
        window: the step's score is the mean distance over the episode's last ``window`` steps
            (1: each step's own; default 20).
    """

    name = "frames"
    learned = True

    def __init__(self, *, window: int = 20) -> None:
        self._recent = RecentMean(window)
        self.window = window
        self._mean: np.ndarray | None = None
        self._precision: np.ndarray | None = None
        self._typical = 0.0  # the fit frames' median value: what a new episode's window starts with

    @property
    def fitted(self) -> bool:
        return self._mean is not None

    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> FramesDetector:
        """Fit the statistics' mean and covariance on every acted-on frame of ID ``trajectories``."""
        from sklearn.covariance import LedoitWolf

        stats = np.stack([frame_statistics(obs) for t in trajectories for obs in t.seen[:-1]])
        self._mean = stats.mean(axis=0)
        self._precision = np.linalg.inv(LedoitWolf().fit(stats).covariance_)
        self._typical = float(np.median(self._values(stats)))
        return self

    def _values(self, stats: np.ndarray) -> np.ndarray:
        centred = np.atleast_2d(stats) - self._mean
        # The quadratic form row by row: for the one frame of a step this costs a third of einsum's
        return np.log1p(((centred @ self._precision) * centred).sum(axis=1))

    def reset(self) -> None:
        self._recent.fill(self._typical)

    def score(self, context: StepContext) -> float:
        self.check_fitted()
        return self._recent.add(float(self._values(frame_statistics(context.seen))[0]))

    def config(self) -> dict[str, Any]:
        return {"window": self.window}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"mean": self._mean, "precision": self._precision, "typical": np.array([self._typical])}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> FramesDetector:
        detector = cls(**config)
        if any(name not in tensors for name in ("mean", "precision", "typical")):
            raise ConfigError("the frames detector's tensors are incomplete")
        mean, precision = np.asarray(tensors["mean"], np.float64), np.asarray(tensors["precision"], np.float64)
        if mean.shape != (len(STATISTICS),) or precision.shape != (len(STATISTICS),) * 2:
            raise ConfigError(f"the frames detector's tensors have shapes {mean.shape} and {precision.shape}; "
                              f"expected ({len(STATISTICS)},) and {(len(STATISTICS),) * 2}")
        detector._mean, detector._precision = mean, precision
        detector._typical = float(np.asarray(tensors["typical"]).reshape(-1)[0])
        return detector
