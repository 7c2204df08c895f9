"""scripts/frozen_region.py: part of Pong's camera frozen from the onset, the rest live."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from tests.helpers import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("frozen_region")[1]


def test_regions_by_name_or_rows_and_columns(script):
    assert script.region("agent_side") == (slice(0, 210), slice(107, 160))
    assert script.region("10:20,30:40") == (slice(10, 20), slice(30, 40))
    for bad in ("left", "10:20", "20:10,0:5", "0:211,0:5", "a:b,c:d"):
        with pytest.raises(argparse.ArgumentTypeError):
            script.region(bad)


def test_the_region_holds_what_it_showed_at_the_onset_and_the_rest_moves(script):
    from oodmon.envs.pong import CorruptedPong

    frozen = script.FrozenRegion(*script.region("opponent_side"))
    env = CorruptedPong(frozen, onset_step=30)
    env.reset(seed=0)
    raw, seen = [], []
    for _ in range(80):  # the ball is served and crosses the field in this many decisions
        env.step(2)
        raw.append(env.last_clean_frame.copy())
        seen.append(env.last_observed_frame.copy())
    env.close()
    raw, seen = np.array(raw), np.array(seen)
    before, after = slice(0, 30), slice(31, None)  # (step 30's first frame of its skip is the held one)
    assert np.array_equal(seen[before], raw[before])  # untouched before the onset
    assert (seen[after, :, :53] == seen[31, :, :53]).all()  # the left third held from then on
    assert not (raw[after, :, :53] == raw[31, :, :53]).all()  # while the camera's own left third moved
    assert np.array_equal(seen[after, :, 53:], raw[after, :, 53:])  # and the rest is live
    assert not (seen[after, :, 53:] == seen[31, :, 53:]).all()
    frozen.thaw()
    assert frozen.held is None
