"""Each corruption changes a frame by what its formula says, more at each severity, reproducibly."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from oodmon.envs import CORRUPTIONS, GaussianNoise, ImpulseNoise, MotionBlur, Pixelate, make_corruption
from oodmon.envs.corruptions import FrozenRegion, severity_params
from oodmon.errors import InvalidParameterError, UnknownParameterError

SEVERITIES = [1, 2, 3, 4, 5]
SHAPE = (210, 160, 3)  # a raw Atari frame
GREY = np.full(SHAPE, 128, np.uint8)


def _random_frame(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, SHAPE, dtype=np.uint8)


def test_severities_are_the_papers():
    assert [severity_params("gaussian_noise", s)["sigma"] for s in SEVERITIES] == [0.08, 0.12, 0.18, 0.26, 0.38]
    assert [severity_params("impulse_noise", s)["p"] for s in SEVERITIES] == [0.03, 0.06, 0.09, 0.17, 0.27]
    assert [tuple(severity_params("motion_blur", s).values()) for s in SEVERITIES] == [
        (10, 3), (15, 5), (15, 8), (15, 12), (20, 15)]
    assert [severity_params("pixelate", s)["factor"] for s in SEVERITIES] == [0.6, 0.5, 0.4, 0.3, 0.25]


def _clipped_normal_std(centre: float, scale: float) -> float:
    """Std of clip(centre + scale * Z, 0, 255) - centre for a standard normal Z, by quadrature."""
    z = np.linspace(-10, 10, 200_001)
    density = np.exp(-(z**2) / 2) / np.sqrt(2 * np.pi)
    values = np.clip(centre + scale * z, 0, 255) - centre
    mean = np.trapezoid(values * density, z)
    return float(np.sqrt(np.trapezoid(values**2 * density, z) - mean**2))


@pytest.mark.parametrize("severity", SEVERITIES)
def test_gaussian_noise_has_the_formulas_standard_deviation(severity):
    sigma = severity_params("gaussian_noise", severity)["sigma"]
    out = make_corruption("gaussian_noise", severity)(GREY, np.random.default_rng(severity))
    diff = out.astype(np.float64) - 128
    assert abs(diff.mean()) < 0.5
    if severity <= 2:  # 128 +- 4 sigma stays inside [0, 255]: no clipping, the std is sigma * 255
        assert diff.std() == pytest.approx(sigma * 255, rel=0.01)
    # At every severity, the std is that of a normal clipped to the pixel range (plus rounding).
    expected = np.sqrt(_clipped_normal_std(128, sigma * 255) ** 2 + 1 / 12)
    assert diff.std() == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("severity", SEVERITIES)
def test_impulse_noise_changes_the_fraction_p_half_to_black_half_to_white(severity):
    p = severity_params("impulse_noise", severity)["p"]
    out = make_corruption("impulse_noise", severity)(GREY, np.random.default_rng(severity))
    n = out.size
    tolerance = 4 * np.sqrt(p * (1 - p) / n)  # four binomial standard deviations
    assert np.mean(out != 128) == pytest.approx(p, abs=tolerance)
    assert np.mean(out == 0) == pytest.approx(p / 2, abs=tolerance)
    assert np.mean(out == 255) == pytest.approx(p / 2, abs=tolerance)
    assert set(np.unique(out)) <= {0, 128, 255}


def _runs(changes: np.ndarray) -> np.ndarray:
    """Lengths of the runs between the positions where consecutive lines differ."""
    edges = np.concatenate([[0], np.flatnonzero(changes) + 1, [len(changes) + 1]])
    return np.diff(edges)


@pytest.mark.parametrize("severity", SEVERITIES)
def test_pixelate_gives_constant_blocks_of_the_expected_size(severity):
    factor = severity_params("pixelate", severity)["factor"]
    out = make_corruption("pixelate", severity)(_random_frame(), np.random.default_rng(0))
    for axis, size in ((0, SHAPE[0]), (1, SHAPE[1])):
        lines = np.moveaxis(out, axis, 0).reshape(size, -1)
        runs = _runs(np.any(lines[1:] != lines[:-1], axis=1))
        blocks = int(size * factor)
        assert len(runs) == blocks  # as many distinct rows/columns as the downscaled frame has
        assert set(runs) <= {size // blocks, -(-size // blocks)}  # each block 1/factor wide
    if factor in (0.5, 0.25):  # exact block sizes along the 160 columns
        assert set(_runs(np.any(out[:, 1:] != out[:, :-1], axis=(0, 2)))) == {round(1 / factor)}


def _smear(severity: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Blur a single white pixel; return the blurred image's pixel offsets and intensities."""
    frame = np.zeros((121, 121), np.uint8)
    frame[60, 60] = 255
    out = make_corruption("motion_blur", severity)(frame, np.random.default_rng(seed)).astype(np.float64)
    ys, xs = np.nonzero(out)
    return np.stack([xs - 60, 60 - ys], axis=1).astype(np.float64), out[ys, xs]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_motion_blur_smears_energy_along_one_direction(seed):
    spreads = []
    for severity in SEVERITIES:
        offsets, weights = _smear(severity, seed)
        assert weights.sum() == pytest.approx(255, abs=0.5 * len(weights) + 1)  # energy kept (up to rounding)
        assert np.all(offsets[:, 0] <= 0)  # one-sided: the smear trails to one side of the pixel
        centre = np.average(offsets, axis=0, weights=weights)
        cov = np.cov((offsets - centre).T, aweights=weights)
        eigenvalues, eigenvectors = np.linalg.eigh(cov)
        along, across = np.sqrt(eigenvalues[1]), np.sqrt(eigenvalues[0])
        assert across < 0.6 and along > 5 * across  # a line, not a blob
        direction = eigenvectors[:, 1]
        angle = np.degrees(np.arctan2(direction[1], direction[0]))
        angle = (angle + 90) % 180 - 90
        assert -46 <= angle <= 46  # drawn from [-45, 45] degrees
        spreads.append(along)
    assert all(b > a for a, b in zip(spreads, spreads[1:])), spreads  # longer smear each severity


@pytest.mark.parametrize("name", ["gaussian_noise", "impulse_noise", "motion_blur"])
def test_the_change_grows_with_severity(name):
    # A smooth frame, as camera images are.
    blurred = cv2.GaussianBlur(_random_frame(1).astype(np.float32), (0, 0), 3)
    frame = cv2.normalize(blurred, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    change = [
        np.abs(make_corruption(name, s)(frame, np.random.default_rng(0)).astype(float) - frame).mean()
        for s in SEVERITIES
    ]
    assert all(b > a for a, b in zip(change, change[1:])), change
    assert change[0] > 0


def test_pixelate_keeps_less_resolution_at_each_severity():
    # Pixelate's change is its lost resolution. (Its mean absolute change is not monotone: factor
    # 0.6 misaligns the blocks and changes a frame more than the aligned 2x2 blocks of 0.5; the
    # original PIL-based formula does the same.)
    frame = _random_frame(1)
    kept = []
    for severity in SEVERITIES:
        out = make_corruption("pixelate", severity)(frame, np.random.default_rng(0))
        rows = len(np.unique(out.reshape(SHAPE[0], -1), axis=0))
        columns = len(np.unique(out.transpose(1, 0, 2).reshape(SHAPE[1], -1), axis=0))
        kept.append(rows * columns)
    assert kept == [126 * 96, 105 * 80, 84 * 64, 63 * 48, 52 * 40]


@pytest.mark.parametrize("name", [name for name in CORRUPTIONS if name != "frozen_region"])  # the paper's
def test_same_seed_same_frame_other_seed_other_frame(name):
    corruption = make_corruption(name, 3)
    frame = _random_frame()
    a = corruption(frame, np.random.default_rng(7))
    b = corruption(frame, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    assert a.dtype == np.uint8 and a.shape == frame.shape
    if name != "pixelate":  # pixelate draws nothing
        assert not np.array_equal(a, corruption(frame, np.random.default_rng(8)))


def test_explicit_parameters_build_the_same_corruption_as_a_severity():
    assert make_corruption("motion_blur", radius=15, sigma=8) == make_corruption("motion_blur", 3)
    assert make_corruption("gaussian_noise", sigma=0.2) == GaussianNoise(0.2)
    assert make_corruption("impulse_noise", p=0.5) == ImpulseNoise(0.5)
    assert make_corruption("pixelate", factor=0.7) == Pixelate(0.7)
    assert MotionBlur(15.0, 8).radius == 15


@pytest.mark.parametrize("severity", [0, 6, -1, 2.5, "3", True])
def test_severity_outside_one_to_five_is_refused(severity):
    with pytest.raises(InvalidParameterError) as error:
        make_corruption("pixelate", severity)
    assert f"severity={severity!r} is not allowed; severity must be an integer from 1 to 5" in str(error.value)


def test_bad_corruption_input_is_named():
    with pytest.raises(UnknownParameterError,
                       match="unknown corruption 'fog'; choose one of gaussian_noise, impulse_noise, motion_blur, pixelate"):
        make_corruption("fog", 1)
    with pytest.raises(UnknownParameterError, match="pixelate has no parameter 'sigma'; it takes factor"):
        make_corruption("pixelate", sigma=0.1)
    with pytest.raises(InvalidParameterError, match=r"give either severity=1..5 or its parameters \(sigma\), not both"):
        make_corruption("gaussian_noise", 2, sigma=0.1)
    with pytest.raises(InvalidParameterError, match="missing sigma"):
        make_corruption("motion_blur", radius=3)
    with pytest.raises(InvalidParameterError, match=r"p=1.5 is not allowed; it must satisfy 0 < p <= 1"):
        make_corruption("impulse_noise", p=1.5)
    with pytest.raises(InvalidParameterError, match=r"factor=1.0 is not allowed; it must satisfy 0 < factor < 1"):
        make_corruption("pixelate", factor=1.0)
    with pytest.raises(InvalidParameterError, match=r"sigma=-0.1 is not allowed"):
        make_corruption("gaussian_noise", sigma=-0.1)
    with pytest.raises(InvalidParameterError, match="radius must be a whole number of pixels"):
        make_corruption("motion_blur", radius=2.5, sigma=1)
    # A blur longer than the frame's diagonal: refused (radius=100000 tried to allocate 596 GiB).
    with pytest.raises(InvalidParameterError, match="radius must be at most 265 pixels"):
        make_corruption("motion_blur", radius=100000, sigma=1)
    assert make_corruption("motion_blur", radius=265, sigma=1).radius == 265


def test_a_frozen_region_holds_the_first_frame_there_until_the_next_episode():
    frozen = make_corruption("frozen_region", top=10, left=100, height=50, width=60)
    assert frozen == FrozenRegion(10, 100, 50, 60) and frozen.params() == {"top": 10, "left": 100, "height": 50, "width": 60}
    first, later, rng = _random_frame(0), _random_frame(1), np.random.default_rng(0)
    np.testing.assert_array_equal(frozen(first, rng), first)
    out = frozen(later, rng)
    inside = (slice(10, 60), slice(100, 160))
    np.testing.assert_array_equal(out[inside], first[inside])  # the region shows the first frame
    outside = out.copy()
    outside[inside] = later[inside]
    np.testing.assert_array_equal(outside, later)  # the rest is live
    frozen.begin_episode()
    np.testing.assert_array_equal(frozen(later, rng), later)  # a new episode holds its own first frame
    np.testing.assert_array_equal(frozen(first, rng)[inside], later[inside])


@pytest.mark.parametrize("params, match", [
    ({"top": 0, "left": 107, "height": 211, "width": 53},
     "height=211 is not allowed; it must be a whole number of pixels from 1 to 210"),
    ({"top": 0.5, "left": 0, "height": 1, "width": 1}, "top=0.5 is not allowed"),
    ({"top": 200, "left": 0, "height": 20, "width": 1}, "rows 200-219 and columns 0-0 leave the 210x160 frame"),
    ({"top": 0, "left": 107, "height": 210}, "give all of its parameters \\(top, left, height, width\\); missing width"),
])
def test_a_frozen_region_outside_the_frame_or_half_given_is_refused(params, match):
    with pytest.raises(InvalidParameterError, match=match):
        make_corruption("frozen_region", **params)


def test_a_frozen_region_has_no_severities_being_none_of_the_papers():
    with pytest.raises(InvalidParameterError, match="frozen_region is not one of the paper's corruptions and has no "
                                                    "severities; give its parameters \\(top, left, height, width\\)"):
        make_corruption("frozen_region", 3)
