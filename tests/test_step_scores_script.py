"""scripts/step_scores.py: per-step scores of fresh ID episodes kept by block, and step-mode calibrations re-drawn from them."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.helpers import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("step_scores")[1]


def test_play_keeps_each_blocks_scores_and_a_stopped_run_goes_on_from_its_blocks(script, tmp_path, monkeypatch, capsys):
    out = tmp_path / "scores"
    argv = ["step_scores.py", "play", "--episodes", "3", "--block", "2", "--workers", "1", "--out", str(out)]
    monkeypatch.setattr("sys.argv", argv)
    script.main()
    assert sorted(p.name for p in out.iterdir()) == ["3000000.npz", "3000002.npz"]
    episodes = script.episodes_of(out)
    assert [len(e) for e in episodes] == [500, 500, 500]  # the shipped ensemble balances every ID pole
    assert all(np.isfinite(e[1:]).all() for e in episodes) and "3/3 episodes" in capsys.readouterr().out
    (out / "3000002.npz").unlink()  # stopped after its first block
    script.main()
    again = script.episodes_of(out)
    assert len(again) == 3 and all(np.array_equal(a, b, equal_nan=True) for a, b in zip(episodes, again))
    assert "3/3 episodes" in capsys.readouterr().out


def test_redraw_counts_the_step_mode_thresholds_above_their_target(script, tmp_path, monkeypatch, capsys):
    """Each threshold read on the other episodes' steps: split conformal's is above far about half the
    time, one of confidence 0.9 less often (here 6 of 40: independent steps leave it a margin of a
    few tenths of a point, within what the other 155 episodes' rate errs by)."""
    rng = np.random.default_rng(0)
    folder = tmp_path / "scores"
    folder.mkdir()
    np.savez_compressed(folder / "0.npz", scores=rng.normal(size=200 * 100), lengths=np.full(200, 100))
    monkeypatch.setattr("sys.argv", ["step_scores.py", "redraw", str(folder), "--n", "45", "--draws", "40"])
    script.main()
    out = capsys.readouterr().out
    assert out.startswith("200 episodes, 20,000 steps; 40 calibrations of 45 episodes each, far=0.05\n")
    confident = re.search(r"confidence 0.9: (\d+) of 40 thresholds above far", out)
    average = re.search(r"confidence None: (\d+) of 40 thresholds above far", out)
    assert int(confident.group(1)) < int(average.group(1)) and 8 <= int(average.group(1)) <= 32, out
