"""Dict observations that hold pictures beside vectors: a camera and a robot's joint readings, say,
read by an SB3 ``MultiInputPolicy`` (its ``CombinedExtractor`` sends each image key through a CNN
and concatenates the rest flattened).

oodmon's agent reads every dict observation flattened (``Agent.view``, in the order gymnasium
flattens the dict's keys) and gives the policy the dict back. Of a dict with pictures, the
detectors and the logs read the vector keys' numbers (:meth:`DictPictures.vectors`: the dynamics
model is fitted on them), and the frames detector and the log's frame channel the first picture
(:meth:`DictPictures.picture`, ``StepContext.picture``): a shift in the physics and one in the
camera (a dirty lens) are each seen by one of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium
import numpy as np

__all__ = ["DictPictures", "dict_pictures", "is_picture_space"]


def is_picture_space(space: gymnasium.Space) -> bool:
    """Whether SB3's ``CombinedExtractor`` reads ``space`` of a dict as an image (through a CNN):
    bytes of 0-255 in three dimensions, channels first or last (``is_image_space`` without its
    channel check, as the extractor calls it)."""
    from stable_baselines3.common.preprocessing import is_image_space

    return isinstance(space, gymnasium.spaces.Box) and is_image_space(space, check_channels=False)


@dataclass(frozen=True)
class DictPictures:
    """Where a flattened dict observation's numbers sit: ``positions`` those of its vector keys (in
    the dict's order; ``own_shape`` their count), ``picture_slice`` those of its first picture,
    ``picture_key``, of ``picture_shape``.

    Example:
        >>> space = gymnasium.spaces.Dict({"camera": gymnasium.spaces.Box(0, 255, (2, 2, 1), np.uint8),
        ...                                "speed": gymnasium.spaces.Box(-1, 1, (1,))})
        >>> parts = dict_pictures(space)
        >>> flat = gymnasium.spaces.flatten(space, {"camera": np.full((2, 2, 1), 7, np.uint8),
        ...                                         "speed": np.array([0.5], np.float32)})
        >>> parts.vectors(flat).tolist(), parts.picture(flat)[..., 0].tolist()
        ([0.5], [[7, 7], [7, 7]])
    """

    positions: np.ndarray = field(compare=False, repr=False)
    picture_key: str
    picture_slice: slice
    picture_shape: tuple[int, ...]

    @property
    def own_shape(self) -> tuple[int, ...]:
        """The shape of what the detectors read: the vector keys' numbers."""
        return (len(self.positions),)

    def vectors(self, flat: np.ndarray) -> np.ndarray:
        """The vector keys' numbers of a flattened observation: what the detectors read and the logs keep."""
        return np.asarray(flat)[..., self.positions]

    def picture(self, flat: np.ndarray) -> np.ndarray:
        """The first picture of a flattened observation, as the env gave it (bytes)."""
        return np.asarray(flat)[self.picture_slice].astype(np.uint8).reshape(self.picture_shape)


def dict_pictures(space: gymnasium.spaces.Space) -> DictPictures | None:
    """The parts of ``space``'s flattened observations, if it is a dict that holds a picture and a
    vector at least; ``None`` for a dict without pictures, or a space of discrete values."""
    if not isinstance(space, gymnasium.spaces.Dict):
        return None
    positions, pictures, start = [], [], 0
    for key, sub in space.spaces.items():
        size = gymnasium.spaces.flatdim(sub)
        if is_picture_space(sub):
            pictures.append((key, slice(start, start + size), tuple(sub.shape)))
        else:
            positions.extend(range(start, start + size))
        start += size
    if not pictures or not positions:
        return None
    key, where, shape = pictures[0]
    return DictPictures(np.asarray(positions, dtype=np.intp), key, where, shape)
