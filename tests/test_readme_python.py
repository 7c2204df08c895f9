"""The first Python blocks of the documentation (docs/environments.md's environments and variant
specs, docs/agents.md's agents, docs/monitor.md's monitor) run as written, one after another in a
fresh folder, as a reader pastes them; the later blocks run in the tests of their pages (the
deployed process in tests/agents/test_sb3_models.py)."""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = ("environments.md", "agents.md", "monitor.md")


def test_the_documentations_first_python_blocks_run_as_written(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", "\n".join((DOCS / page).read_text() for page in PAGES), re.DOTALL)
    names = ["OOD environments", "variant specs", "agents", "monitor"]
    assert "gymnasium.make(\"oodmon/CartPole-v1\", length=2.0)" in blocks[0] and "paper_grid" in blocks[1]
    assert "agent.estimate(obs)" in blocks[2] and "Monitor(agent, threshold" in blocks[3]
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for name, block in zip(names, blocks[:4]):  # 7 s, most of it the monitor block's 50 calibration episodes
        exec(compile(block, f"docs {name} block", "exec"), namespace)
    estimate = namespace["estimate"]
    assert estimate.samples.shape == (5, 1, 2) and estimate.action.shape == (1,)  # the ensemble's 5 members
    # the monitor block: its episode shifts at step 100 and the alarm callback printed what it saw
    record = namespace["record"]
    printed = capsys.readouterr().out
    assert "AlarmEvent(episode=0" in printed and record.length > 100
    # ...read off the shipped detectors' best (CartPole: combined), which sees the longer pole at once
    assert namespace["threshold"].detector == "combined" and printed.startswith("combined ")
    alarm = next(line for line in printed.splitlines() if line.startswith("AlarmEvent("))
    step = int(re.search(r"step=(\d+),", alarm).group(1))
    assert 100 < step <= 105, alarm  # the first alarm within 5 steps of the onset (measured: step 101)
    assert (tmp_path / "runs/x.mcap").stat().st_size > 0 and (tmp_path / "runs/x.rrd").stat().st_size > 0
