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


def test_each_region_plays_its_games_with_the_agent_as_loaded(script, monkeypatch, capsys):
    """An MC agent's draws ran on from region to region, so a region's games depended on the
    regions listed before it; each region now gets the agent as loaded (seeded), the first one
    loaded included, and a region listed twice plays the same games twice."""
    loaded, played = [], []

    def load_agent(method):
        loaded.append(object())
        return loaded[-1]

    monkeypatch.setattr(script, "load_agent", load_agent)
    monkeypatch.setattr(script, "limit_threads", lambda: None)
    monkeypatch.setattr(script.Threshold, "load", lambda path: argparse.Namespace(detector="combined", value=4.5))
    monkeypatch.setattr(script, "frozen_games", lambda agent, threshold, name, args: played.append((name, agent)) or name)
    monkeypatch.setattr("sys.argv", ["frozen_region.py", "--threshold", "t.json", "--regions", "centre,agent_side,centre"])
    script.main()
    assert [name for name, _ in played] == ["centre", "agent_side", "centre"]
    assert [agent for _, agent in played] == loaded and len(set(map(id, loaded))) == 3
    assert "threshold: combined > 4.5" in capsys.readouterr().out
