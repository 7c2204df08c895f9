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


def test_roc_and_trace_read_the_variants_own_task(tmp_path):
    """One method's runs of two tasks replayed together: a CartPole variant's ROC and trace take their
    ID steps from the CartPole runs alone (the Pendulum ID run's high scores would sink its AUROC)."""
    import numpy as np
    from sklearn.metrics import roc_auc_score

    from oodmon.replay import EpisodeLog, RunLog
    from oodmon.replay.plots import _labels_and_scores

    def log(task, variant, scores, shifted):
        n = len(scores)
        episode = EpisodeLog(episode=0, env_id="", variant=variant, onset=0, seed=0, total_return=0.0, length=n,
                             alarms=0, first_alarm_step=None, scores=np.asarray(scores, float),
                             shifted=np.full(n, shifted), alarm=np.zeros(n, bool))
        return RunLog(Path(f"{task}.mcap"), task, "dropconnect", 1.0, {}, [episode], True)

    logs = [log("pendulum", "pendulum", [9.0] * 4, False), log("cartpole", "cartpole", [0.1, 0.2, 0.3], False),
            log("cartpole", "cartpole:length=2.0", [0.5, 0.6], True)]
    labels, scores = _labels_and_scores(logs, "dropconnect", "cartpole:length=2.0")
    assert labels.tolist() == [0, 0, 0, 1, 1] and roc_auc_score(labels, scores) == 1.0
    assert plot_trace(logs, "dropconnect", "cartpole:length=2.0", tmp_path / "trace.png") is not None
    assert plot_trace(logs[:1] + logs[2:], "dropconnect", "cartpole:length=2.0", tmp_path / "t.png") is None  # no CartPole ID run
