"""scripts/deployment_world.py: the table docs/monitor.md shows is the one its committed results
make (the script writes results/deployment/cartpole-ensemble.json and prints that table); and
scripts/changed_world.py's figures there are those of results/deployment/changed-world.json."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("deployment_world", ROOT / "scripts" / "deployment_world.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_docs_table_is_the_committed_results():
    script = _script()
    results = json.loads((ROOT / "results" / "deployment" / "cartpole-ensemble.json").read_text())
    table = script.markdown(results).splitlines()
    docs = [line.strip() for line in (ROOT / "docs" / "monitor.md").read_text().splitlines()]
    start = docs.index(table[0])
    assert docs[start:start + len(table)] == table
    assert len(table) == 2 + 3 * 3  # three worlds, three thresholds each
    # what the page says of them: the simulator's alarms in every fresh ID episode of each world,
    # the detectors fitted on the world's logs in none, and see every shift at the next step
    for rows in results["worlds"].values():
        assert rows["simulator"]["false_alarms"] == rows["simulator"]["validated"] == 100
        assert rows["fitted on logs"]["false_alarms"] == 0
        assert all(r["alarmed"] == r["episodes"] == 20 and r["delay_median"] == 1
                   for r in rows["fitted on logs"]["shifts"].values())


def test_the_changed_worlds_figures_in_the_docs_are_the_committed_results():
    """scripts/changed_world.py's results (results/deployment/changed-world.json), as docs/monitor.md
    says them: the change found where the second log begins, the threshold of both logs missing
    most of the longer pole's episodes, that of the first log catching each, neither alarming on ID."""
    results = json.loads((ROOT / "results" / "deployment" / "changed-world.json").read_text())
    docs = " ".join((ROOT / "docs" / "monitor.md").read_text().split())
    change, both, first = results["change"], results["thresholds"]["both logs"], results["thresholds"]["the first log"]
    assert change["warned"] and change["at"] == 60 and change["p_value"] < 0.01
    assert f"p = {change['p_value']:.2g}, at episode {change['at'] + 1} of 100" in docs
    assert f"medians {change['before']:.4g} before, {change['after']:,.0f} after" in docs
    assert f"combined > {both['value']:,.1f}: {both['fresh_id_alarmed']} of 100 fresh ID episodes alarmed, and " \
           f"{both['fresh_longer_alarmed']} of 40 fresh longer-pole ones" in docs
    assert f"combined > {first['value']:.6g}: {first['fresh_id_alarmed']} of 100, and " \
           f"{first['fresh_longer_alarmed']} of 40" in docs
    assert both["fresh_longer_alarmed"] < 10 and first["fresh_longer_alarmed"] == 40
    # a burst: eight longer-pole episodes among 200, found by the burst scan where Pettitt's test does not
    burst, crowd = results["burst"], results["burst"]["burst"]
    every, ids = burst["thresholds"]["all three logs"], burst["thresholds"]["the ID logs alone"]
    assert burst["warned"] and crowd["p_value"] < 0.005 and burst["pettitt_p_value"] > 0.005
    assert (crowd["first"], crowd["last"]) == (burst["first_longer"], burst["first_longer"] + burst["longer"] - 1)
    assert f"{crowd['count']} of the {crowd['size']} highest, episodes {crowd['first'] + 1}-{crowd['last'] + 1} " \
           f"(p = {crowd['p_value']:.2g}; Pettitt's test p = {burst['pettitt_p_value']:.2g})" in docs
    assert f"combined > {every['value']:,.1f}: {every['fresh_id_alarmed']} of 100 fresh ID episodes and " \
           f"{every['fresh_longer_alarmed']} of 40 longer-pole ones alarmed" in docs
    assert f"combined > {ids['value']:.6g}: {ids['fresh_id_alarmed']} of 100 and {ids['fresh_longer_alarmed']} " \
           "of 40" in docs
    assert ids["fresh_longer_alarmed"] == 40 > every["fresh_longer_alarmed"] and every["value"] > 100 * ids["value"]


def test_the_camera_worlds_table_in_the_docs_is_the_committed_results():
    """scripts/camera_world.py's table (results/deployment/pong-camera.json) as docs/monitor.md
    shows it, and what the page says of it: the simulator's threshold alarms every deployment
    game, the recalibrated one sees no corruption, the set fitted on the logged frames sees both
    in every game."""
    spec = importlib.util.spec_from_file_location("camera_world", ROOT / "scripts" / "camera_world.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    results = json.loads((ROOT / "results" / "deployment" / "pong-camera.json").read_text())
    table = module.markdown(results).splitlines()
    docs = [line.strip() for line in (ROOT / "docs" / "monitor.md").read_text().splitlines()]
    start = docs.index(table[0])
    assert docs[start:start + len(table)] == table and len(table) == 5
    rows = results["thresholds"]
    assert rows["the simulator's"]["false_alarms"] == rows["the simulator's"]["games"]
    assert all(shift["alarmed"] == 0 for shift in rows["recalibrated"]["shifts"].values())
    assert all(shift["alarmed"] == shift["games"] for shift in rows["fitted on logs"]["shifts"].values())
