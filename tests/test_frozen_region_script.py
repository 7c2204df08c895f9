"""scripts/frozen_region.py: part of Pong's camera frozen from the onset, the rest live."""

from __future__ import annotations

import argparse

import pytest

from tests.helpers import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("frozen_region")[1]


def test_regions_by_name_or_rows_and_columns_are_frozen_region_variants(script):
    assert script.region_variant("agent_side") == "pong:frozen_region:height=210,left=107,top=0,width=53"
    assert script.region_variant("10:20,30:40") == "pong:frozen_region:height=10,left=30,top=10,width=10"
    for bad, why in (("left", "is no region"), ("10:20", "is no region"), ("a:b,c:d", "is no region"),
                     ("20:10,0:5", "height=-10.0 is not allowed"), ("0:211,0:5", "height=211.0 is not allowed")):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            script.region_variant(bad)
