"""The named seed ranges never overlap, so an episode is held out of every use but its own."""

from __future__ import annotations

import itertools

from oodmon import seeds
from oodmon.monitor import CALIBRATION_SEED


def test_no_two_ranges_overlap():
    for (a, (a_low, a_high)), (b, (b_low, b_high)) in itertools.combinations(seeds.RANGES.items(), 2):
        assert a_high <= b_low or b_high <= a_low, f"seed ranges {a} and {b} overlap"


def test_each_named_start_is_its_range_and_calibration_uses_it():
    assert seeds.range_of(seeds.CALIBRATION) == "calibration" == seeds.range_of(CALIBRATION_SEED + 99_999)
    assert seeds.range_of(seeds.DETECTOR_FIT + 29) == "detector_fit"
    assert seeds.range_of(seeds.DEMO - 1) == "calibration" and seeds.range_of(0) is None
