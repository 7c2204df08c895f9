"""scripts/deployment_world.py: the table docs/monitor.md shows is the one its committed results
make (the script writes results/deployment/cartpole-ensemble.json and prints that table)."""

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
