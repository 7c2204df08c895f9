"""Every metric against hand-computed values on tiny synthetic logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from oodmon.replay import EpisodeLog, RunLog, alarm_events, compute_metrics, fpr_at_tpr


def _episode(k, variant, scores, shifted, alarm, onset=0):
    scores = np.asarray(scores, float)
    alarm = np.asarray(alarm, bool)
    return EpisodeLog(episode=k, env_id="oodmon/CartPole-v1", variant=variant, onset=onset, seed=k, total_return=0.0,
                      length=len(scores), alarms=len(alarm_events(alarm)), first_alarm_step=None, scores=scores,
                      shifted=np.asarray(shifted, bool), alarm=alarm)


def _log(episodes, method="m"):
    return RunLog(Path("x.mcap"), "cartpole", method, 1.0, {}, episodes, True)


ID = _log([
    _episode(0, "cartpole", [0.1, 0.2, 0.3], [0, 0, 0], [0, 0, 0]),
    _episode(1, "cartpole", [0.4, 0.2, 0.1], [0, 0, 0], [0, 1, 0]),
])
SHIFTED = _log([
    # onset 1: step 0 is ID, steps 1.. are OOD; alarm at step 0 is early, then one at step 2.
    _episode(0, "cartpole:length=2.0", [0.35, 0.5, 0.6, 0.25], [0, 1, 1, 1], [1, 0, 1, 1], onset=1),
    # onset 2: never alarms.
    _episode(1, "cartpole:length=2.0", [0.05, 0.15, 0.45, 0.3], [0, 0, 1, 1], [0, 0, 0, 0], onset=2),
])


def test_id_row_false_alarm_rate_and_counts():
    rows = {m.variant: m for m in compute_metrics([ID, SHIFTED])}
    assert rows["cartpole"].false_alarm_rate == 0.5  # one of two ID episodes alarmed
    assert (rows["cartpole"].episodes, rows["cartpole"].steps) == (2, 6)
    assert rows["cartpole"].auroc is None and rows["cartpole"].detection_rate is None


def test_shifted_row_by_hand():
    m = {m.variant: m for m in compute_metrics([ID, SHIFTED])}["cartpole:length=2.0"]
    # ID steps: 6 from the ID runs + 3 before the onsets; OOD steps: 5.
    negatives = [0.1, 0.2, 0.3, 0.4, 0.2, 0.1, 0.35, 0.05, 0.15]
    positives = [0.5, 0.6, 0.25, 0.45, 0.3]
    assert (m.id_steps, m.ood_steps, m.episodes, m.steps) == (9, 5, 2, 8)
    # AUROC: the fraction of (OOD, ID) pairs ranked right, ties counting one half.
    pairs = [(p > n) + 0.5 * (p == n) for p in positives for n in negatives]
    assert m.auroc == pytest.approx(np.mean(pairs))
    # AUPR (average precision): over the distinct thresholds, descending, the gain in recall
    # times the precision there (tied ID and OOD scores enter together: 0.3 is both).
    ap, recall_before = 0.0, 0.0
    for threshold in sorted(set(positives + negatives), reverse=True):
        caught = sum(p >= threshold for p in positives)
        flagged = caught + sum(n >= threshold for n in negatives)
        recall = caught / len(positives)
        ap += (recall - recall_before) * caught / flagged
        recall_before = recall
    assert m.aupr == pytest.approx(ap)
    # FPR at 95% TPR: to catch all 5 OOD steps the threshold goes down to 0.25, above which lie
    # the ID scores 0.3, 0.35 and 0.4: 3 of 9.
    assert m.fpr_at_95_tpr == pytest.approx(3 / 9)
    assert m.early_alarm_rate == 0.5  # episode 0 alarmed at step 0 < onset 1
    assert m.detection_rate == 0.5  # episode 0 alarmed again at step 2 >= onset; episode 1 never
    assert m.delay_mean == 1.0 and m.delay_median == 1.0  # 2 - 1


def test_alarm_events_are_rising_edges_and_fpr_helper():
    assert alarm_events(np.array([1, 1, 0, 1, 0, 0, 1, 1], bool)).tolist() == [0, 3, 6]
    assert fpr_at_tpr(np.array([0, 1, 0, 1]), np.array([0.2, 0.8, 0.9, 0.1])) == 1.0


def test_methods_and_tasks_are_kept_apart():
    other = _log([_episode(0, "cartpole", [9.0, 9.0], [0, 0], [1, 1])], method="other")
    rows = compute_metrics([ID, SHIFTED, other])
    assert [(r.method, r.variant) for r in rows] == [("m", "cartpole"), ("m", "cartpole:length=2.0"), ("other", "cartpole")]
    assert rows[2].false_alarm_rate == 1.0
