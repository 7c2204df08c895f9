"""Plots from the recorded logs: every expected PNG is written and is an image."""

from __future__ import annotations

from pathlib import Path

import cv2

from oodmon.replay import compute_metrics, read_log
from oodmon.replay.plots import plot_roc, plot_trace, write_plots
from tests.helpers import run_cli

DATA = Path(__file__).parent.parent / "data"


def test_replay_plots_writes_roc_trace_and_auroc_vs_shift(tmp_path):
    result = run_cli("replay", str(DATA), "--plots", str(tmp_path))
    assert result.returncode == 0 and "wrote 3 plot(s)" in result.stderr
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["auroc_vs_shift_cartpole.png", "roc_cartpole_length_2.0.png",
                     "trace_ensemble_cartpole_length_2.0.png"]
    for name in names:
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.shape[0] > 300 and image.shape[1] > 350


def test_plots_that_the_logs_cannot_support_are_skipped(tmp_path):
    logs = [read_log(DATA / "cartpole-ensemble-id.mcap")]  # ID only: no shifted steps
    assert plot_roc(logs, "cartpole:length=2.0", tmp_path / "roc.png") is None
    assert plot_trace(logs, "ensemble", "cartpole:length=2.0", tmp_path / "trace.png") is None
    assert write_plots(logs, compute_metrics(logs), tmp_path) == []
