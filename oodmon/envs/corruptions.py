"""The four image corruptions of OOD-Pong, written from their formulas, and a frozen region.

The paper used the ``imagecorruptions`` package (Michaelis et al., 2019), which no longer imports
on a current environment and draws from numpy's global random state. These are the same formulas
with numpy/OpenCV, drawing from a ``numpy.random.Generator`` so that a seeded env gives the same
frames every time. Each works on an HxWxC (or HxW) uint8 frame and returns a new uint8 frame of
the same shape.

Severities 1..5 take the paper's values (its Table 1 and Appendix A), which this project keeps
in ``oodmon/paper_tables.json``. :class:`FrozenRegion` (a part of the camera frozen, the rest live)
is not the paper's: it takes its parameters, no severity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import ClassVar

import numpy as np

from oodmon.envs.checks import positive_number, reject_unknown
from oodmon.errors import InvalidParameterError, UnknownParameterError, unknown
from oodmon.paper import paper_grid_data
from oodmon.validation import is_whole

__all__ = [
    "CORRUPTIONS",
    "Corruption",
    "FrozenRegion",
    "GaussianNoise",
    "ImpulseNoise",
    "MotionBlur",
    "Pixelate",
    "make_corruption",
    "severity_params",
]


@dataclass(frozen=True)
class Corruption:
    """Base of the corruptions: a frozen record of parameters that corrupts frames.

    Call it with a uint8 frame and a generator: ``corruption(frame, rng)``.
    """

    name: ClassVar[str]

    def __call__(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        raise NotImplementedError

    def begin_episode(self) -> None:
        """An episode begins (the env's reset): a corruption that remembers frames forgets them."""

    def params(self) -> dict[str, float]:
        """The corruption's parameters by name, e.g. ``{"sigma": 0.18}``."""
        return {f.name: getattr(self, f.name) for f in _parameters(type(self))}


def _parameters(cls: type[Corruption]) -> list:
    """A corruption's parameters: its dataclass fields but its state (``init=False``)."""
    return [f for f in fields(cls) if f.init]


def _in_unit_interval(owner: str, name: str, value: object, *, closed: bool) -> float:
    number = positive_number(owner, name, value)
    if number > 1 or (number == 1 and not closed):
        allowed = "0 < {0} <= 1" if closed else "0 < {0} < 1"
        raise InvalidParameterError(
            f"{owner}: {name}={number!r} is not allowed; it must satisfy {allowed.format(name)}"
        )
    return number


@dataclass(frozen=True)
class GaussianNoise(Corruption):
    """Additive gaussian noise: ``clip(x/255 + N(0, sigma), 0, 1) * 255``.

    Args:
        sigma: standard deviation on pixel values scaled to [0, 1]; severities 1..5 are
            0.08, 0.12, 0.18, 0.26, 0.38.

    Example:
        >>> frame = np.full((4, 4), 128, np.uint8)
        >>> GaussianNoise(0.1)(frame, np.random.default_rng(0)).shape
        (4, 4)
    """

    sigma: float
    name: ClassVar[str] = "gaussian_noise"

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", positive_number(self.name, "sigma", self.sigma))

    def __call__(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        # In place: drawing the noise is most of the cost, every temporary array adds to it.
        noisy = rng.standard_normal(frame.shape, dtype=np.float32)
        noisy *= np.float32(self.sigma * 255.0)
        noisy += frame
        np.clip(noisy, 0.0, 255.0, out=noisy)
        return np.rint(noisy, out=noisy).astype(np.uint8)


@dataclass(frozen=True)
class ImpulseNoise(Corruption):
    """Salt-and-pepper noise: a fraction ``p`` of the values set to 0 or 255, half each.

    As in ``imagecorruptions`` (scikit-image's ``random_noise(mode="s&p")``), every channel value
    is drawn on its own.

    Args:
        p: the fraction of values replaced, 0 < p <= 1; severities 1..5 are 0.03, 0.06, 0.09,
            0.17, 0.27.
    """

    p: float
    name: ClassVar[str] = "impulse_noise"

    def __post_init__(self) -> None:
        object.__setattr__(self, "p", _in_unit_interval(self.name, "p", self.p, closed=True))

    def __call__(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        u = rng.random(frame.shape, dtype=np.float32)
        out = frame.copy()
        out[u < self.p / 2] = 0
        out[(u >= self.p / 2) & (u < self.p)] = 255
        return out


#: The longest motion blur, in pixels: the diagonal of Pong's 210x160 frame, rounded up.
MAX_BLUR_RADIUS = math.ceil(math.hypot(210, 160))


@dataclass(frozen=True)
class MotionBlur(Corruption):
    """Motion blur: a one-sided gaussian kernel along a random direction.

    The kernel has ``2 * radius + 1`` taps with weights ``exp(-i^2 / (2 sigma^2))``, i = 0, 1, ...,
    normalised to sum 1, laid along an angle drawn uniformly from [-45, 45] degrees for each frame;
    borders repeat the edge pixels. This is ``imagecorruptions``' ``_motion_blur``, computed as
    one OpenCV filter instead of a sum of shifted copies.

    Args:
        radius: kernel radius in pixels, an integer from 1 to :data:`MAX_BLUR_RADIUS` (265).
        sigma: the kernel's gaussian standard deviation in pixels.
        Severities 1..5 are (10, 3), (15, 5), (15, 8), (15, 12), (20, 15).
    """

    radius: int
    sigma: float
    name: ClassVar[str] = "motion_blur"

    def __post_init__(self) -> None:
        radius = positive_number(self.name, "radius", self.radius)
        if radius != int(radius):
            raise InvalidParameterError(
                f"{self.name}: radius={self.radius!r} is not allowed; radius must be a whole number of pixels >= 1"
            )
        if radius > MAX_BLUR_RADIUS:  # (radius=100000 tried to allocate a kernel of 596 GiB)
            raise InvalidParameterError(
                f"{self.name}: radius={self.radius!r} is not allowed; radius must be at most {MAX_BLUR_RADIUS} pixels, "
                "the diagonal of Pong's 210x160 frame (a longer blur's taps only repeat the border)"
            )
        object.__setattr__(self, "radius", int(radius))
        object.__setattr__(self, "sigma", positive_number(self.name, "sigma", self.sigma))

    def kernel(self, angle_deg: float) -> np.ndarray:
        """The 2-D correlation kernel for one angle, anchored at its centre."""
        width = 2 * self.radius + 1
        taps = np.exp(-(np.arange(width) ** 2) / (2 * self.sigma**2))
        taps /= taps.sum()
        # imagecorruptions' offsets: tap i shifts the image by (dx, dy), so the output at (y, x)
        # takes the input at (y - dy, x - dx).
        sin, cos = math.sin(math.radians(angle_deg)), math.cos(math.radians(angle_deg))
        size = 2 * width + 1
        kernel = np.zeros((size, size), np.float32)
        centre = width
        for i, weight in enumerate(taps):
            dy = -math.ceil(i * sin - 0.5)
            dx = -math.ceil(i * cos - 0.5)
            kernel[centre - dy, centre - dx] += weight
        return kernel

    def __call__(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        import cv2  # (imported where used: see oodmon.envs.pong.to_agent_view)

        angle = rng.uniform(-45.0, 45.0)
        blurred = cv2.filter2D(
            frame.astype(np.float32), -1, self.kernel(angle), borderType=cv2.BORDER_REPLICATE
        )
        return np.rint(np.clip(blurred, 0.0, 255.0)).astype(np.uint8)


@dataclass(frozen=True)
class Pixelate(Corruption):
    """Pixelation: downscale by ``factor`` with a box filter, then upscale with nearest neighbour.

    Args:
        factor: the downscale factor, 0 < factor < 1; severities 1..5 are 0.6, 0.5, 0.4, 0.3,
            0.25. Factor 0.5 turns the frame into constant 2x2 blocks.
    """

    factor: float
    name: ClassVar[str] = "pixelate"

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "factor", _in_unit_interval(self.name, "factor", self.factor, closed=False)
        )

    def __call__(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        import cv2

        height, width = frame.shape[:2]
        small = (max(1, int(width * self.factor)), max(1, int(height * self.factor)))
        down = cv2.resize(frame, small, interpolation=cv2.INTER_AREA)
        return cv2.resize(down, (width, height), interpolation=cv2.INTER_NEAREST).reshape(frame.shape)


#: The raw frame the camera delivers: Pong's 210 rows x 160 columns.
FRAME_ROWS, FRAME_COLUMNS = 210, 160


@dataclass(frozen=True)
class FrozenRegion(Corruption):
    """A part of the camera frozen: a rectangle of the raw frame held at what the first corrupted
    frame of the episode showed there, the rest live (dead sensor rows, a stuck part of the image).
    Not one of the paper's corruptions: no severities. The whole frame frozen is the sensor fault
    ``pong:obs.stuck=1``; a part, ``pong:frozen_region:top=0,left=107,height=210,width=53`` (the
    agent's own third: its paddle, and the ball on its side).

    Args:
        top, left: the rectangle's first row and column in the 210x160 raw frame, whole numbers >= 0.
        height, width: its size in pixels, whole numbers >= 1, inside the frame.

    Example:
        >>> frozen = FrozenRegion(top=0, left=0, height=1, width=2)
        >>> rng = np.random.default_rng(0)
        >>> frozen(np.full((2, 3), 7, np.uint8), rng).tolist()    # the first frame: held as it is
        [[7, 7, 7], [7, 7, 7]]
        >>> frozen(np.full((2, 3), 9, np.uint8), rng).tolist()    # later frames: the region still shows 7
        [[7, 7, 9], [9, 9, 9]]
        >>> frozen.begin_episode()                                # the next episode holds its own first frame
        >>> frozen(np.full((2, 3), 9, np.uint8), rng)[0].tolist()
        [9, 9, 9]
    """

    top: int
    left: int
    height: int
    width: int
    name: ClassVar[str] = "frozen_region"
    _held: list = field(default_factory=list, init=False, repr=False, compare=False)  # [region] once held

    def __post_init__(self) -> None:
        for name, least, most in (("top", 0, FRAME_ROWS - 1), ("left", 0, FRAME_COLUMNS - 1),
                                  ("height", 1, FRAME_ROWS), ("width", 1, FRAME_COLUMNS)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or (
                    not math.isfinite(value) or value != int(value) or not least <= value <= most):
                raise InvalidParameterError(f"{self.name}: {name}={value!r} is not allowed; it must be a whole number of "
                                            f"pixels from {least} to {most}")
            object.__setattr__(self, name, int(value))
        if self.top + self.height > FRAME_ROWS or self.left + self.width > FRAME_COLUMNS:
            raise InvalidParameterError(
                f"{self.name}: rows {self.top}-{self.top + self.height - 1} and columns {self.left}-"
                f"{self.left + self.width - 1} leave the {FRAME_ROWS}x{FRAME_COLUMNS} frame"
            )

    def begin_episode(self) -> None:
        self._held.clear()

    def __call__(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        region = (slice(self.top, self.top + self.height), slice(self.left, self.left + self.width))
        if not self._held:
            self._held.append(frame[region].copy())
        out = frame.copy()
        out[region] = self._held[0]
        return out


#: The corruptions by name.
CORRUPTIONS: dict[str, type[Corruption]] = {
    cls.name: cls for cls in (GaussianNoise, ImpulseNoise, MotionBlur, Pixelate, FrozenRegion)
}


def severity_params(name: str, severity: object) -> dict[str, float]:
    """The paper's parameters of corruption ``name`` at ``severity`` (1..5).

    Example:
        >>> severity_params("motion_blur", 3)
        {'radius': 15, 'sigma': 8}
    """
    cls = _corruption_class(name)
    severities = paper_grid_data()["pong"]["severities"]
    if name not in severities:
        raise InvalidParameterError(
            f"{name} is not one of the paper's corruptions and has no severities; give its parameters "
            f"({', '.join(f.name for f in _parameters(cls))}), e.g. pong:{name}:"
            + ",".join(f"{f.name}=N" for f in _parameters(cls))
        )
    if not is_whole(severity) or severity > 5:
        raise InvalidParameterError(
            f"{name}: severity={severity!r} is not allowed; severity must be an integer from 1 to 5"
        )
    value = severities[name]["values"][int(severity) - 1]
    values = value if isinstance(value, list) else [value]
    return {f.name: v for f, v in zip(_parameters(cls), values, strict=True)}


def make_corruption(name: str, severity: int | None = None, **params: float) -> Corruption:
    """Build a corruption from its name and either a severity or its parameters.

    Args:
        name: ``gaussian_noise``, ``impulse_noise``, ``motion_blur``, ``pixelate`` (the paper's) or
            ``frozen_region`` (its parameters only).
        severity: 1..5, the paper's values.
        **params: the corruption's own parameters instead of a severity (``sigma=0.2``).

    Raises:
        UnknownParameterError: an unknown corruption or a parameter it does not take.
        InvalidParameterError: a severity outside 1..5, both or neither of severity and
            parameters, or a parameter value outside its range.

    Example:
        >>> make_corruption("pixelate", 3)
        Pixelate(factor=0.4)
        >>> make_corruption("gaussian_noise", sigma=0.2)
        GaussianNoise(sigma=0.2)
    """
    cls = _corruption_class(name)
    names = [f.name for f in _parameters(cls)]
    if severity is not None and params:
        raise InvalidParameterError(
            f"{name}: give either severity=1..5 or its parameters ({', '.join(names)}), not both"
        )
    if severity is None:
        reject_unknown(name, params, names)
        missing = [n for n in names if n not in params]
        if missing:
            raise InvalidParameterError(
                f"{name}: give {'severity=1..5 or ' if cls is not FrozenRegion else ''}all of its parameters "
                f"({', '.join(names)}); "
                f"missing {', '.join(missing)}"
            )
        return cls(**params)
    return cls(**severity_params(name, severity))


def _corruption_class(name: object) -> type[Corruption]:
    if name not in CORRUPTIONS:
        raise UnknownParameterError(
            unknown("corruption", name, CORRUPTIONS)
        )
    return CORRUPTIONS[name]  # type: ignore[index]
