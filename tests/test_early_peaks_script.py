"""scripts/early_peaks_selection.py counts the calibrations that warn through calibrate's own warning."""

from __future__ import annotations

import sys

import numpy as np

from tests.helpers import load_script


def _main(monkeypatch, capsys, pool: list[np.ndarray]) -> list[str]:
    """The script's output on ``pool`` as its played episodes (the shipped Pendulum ensemble's detectors)."""
    _, script = load_script("early_peaks_selection")
    monkeypatch.setattr(script, "id_episode_scores", lambda *args, **kwargs: pool)
    monkeypatch.setattr(sys, "argv", ["early_peaks_selection.py", "--pool", str(len(pool)), "--n", "45", "--draws", "40"])
    script.main()
    return capsys.readouterr().out.splitlines()


def _share(line: str, after: str) -> float:
    """The percentage printed after ``after`` in ``line``."""
    return float(line.split(after)[1].split("%")[0])


def test_every_set_warns_where_every_episode_peaks_early_and_none_where_none_does(monkeypatch, capsys):
    rng = np.random.default_rng(0)
    peaked = [rng.normal(0.0, 1.0, 200) for _ in range(90)]
    for episode in peaked:
        episode[5] = 12.0  # each episode's highest score in its first 20 steps
    lines = _main(monkeypatch, capsys, peaked)
    assert lines[1] == "40 sets of 45: 100.0% warned (EarlyPeaksWarning)"
    assert lines[2].endswith(", the others -")  # no set that did not warn
    # every episode peaks early, so the warning is the episodes' rule, not a chosen set's chance: the
    # warm-up's threshold keeps the promise as any does (12.1% expected above 0.05, see below)
    assert _share(lines[2], "the sets that warned ") <= 30.0
    steady = [rng.normal(0.0, 1.0, 200) for _ in range(90)]
    lines = _main(monkeypatch, capsys, steady)
    assert lines[1] == "40 sets of 45: 0.0% warned (EarlyPeaksWarning)" and "the sets that warned -" in lines[2]
    # without a warm-up the threshold is the largest of the 45 chosen: above 0.05 of the other 45
    # (3 or more) exceed it when the top 3 of the 90 all lie among them, chance 45*44*43/(90*89*88),
    # 12.1%; over 40 sets the share's sd is 5.2%, so 30% is more than 3 of them away
    assert _share(lines[3], "all sets ") <= 30.0
