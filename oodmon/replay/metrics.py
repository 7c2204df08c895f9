"""Metrics from logged episodes, per (task, method, variant).

Per step (the paper's view): OOD steps are the steps of a shifted run from its onset on (their
``shifted`` flag); ID steps are all steps of the ID runs of the same task and method plus the
steps before the onset of this variant's runs. AUROC (the paper's metric), AUPR with OOD as the
positive class, and the false-positive rate at 95% true-positive rate.

Per episode (the monitor's view): an alarm is a rising edge of the logged alarm flag. ID runs
give the episode-level false-alarm rate (episodes with any alarm). Shifted runs give the
detection rate (episodes with an alarm at or after the onset) and the delay from the onset to
the first such alarm; alarms before the onset are counted as early (false) alarms.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from oodmon.envs.grid import parse_variant
from oodmon.replay.reader import EpisodeLog, RunLog

__all__ = ["VariantMetrics", "alarm_events", "compute_all_metrics", "compute_metrics", "detectors_in", "fpr_at_tpr"]


@dataclass(frozen=True)
class VariantMetrics:
    """The metrics of one (task, method, variant); ``None`` where they do not apply."""

    task: str
    method: str
    variant: str
    episodes: int
    steps: int
    id_steps: int
    ood_steps: int
    auroc: float | None
    aupr: float | None
    fpr_at_95_tpr: float | None
    false_alarm_rate: float | None
    early_alarm_rate: float | None
    detection_rate: float | None
    delay_mean: float | None
    delay_median: float | None
    detector: str = "spread"

    @property
    def key(self) -> str:
        """``task/method/variant``, and ``@detector`` for a detector other than ``spread``."""
        base = f"{self.task}/{self.method}/{self.variant}"
        return base if self.detector == "spread" else f"{base}@{self.detector}"

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


def alarm_events(alarm: np.ndarray) -> np.ndarray:
    """Steps at which an alarm starts (rising edges of the alarm flag).

    Example:
        >>> alarm_events(np.array([0, 1, 1, 0, 1], bool)).tolist()
        [1, 4]
    """
    alarm = np.asarray(alarm, bool)
    previous = np.concatenate([[False], alarm[:-1]])
    return np.flatnonzero(alarm & ~previous)


def fpr_at_tpr(labels: np.ndarray, scores: np.ndarray, tpr: float = 0.95) -> float:
    """The false-positive rate at the first threshold that reaches ``tpr``.

    Example:
        >>> fpr_at_tpr(np.array([0, 0, 1, 1]), np.array([0.1, 0.6, 0.5, 0.9]))
        0.5
    """
    from sklearn.metrics import roc_curve

    fprs, tprs, _ = roc_curve(labels, scores)
    return float(fprs[np.searchsorted(tprs, tpr, side="left")])


def detectors_in(logs: Iterable[RunLog]) -> list[str]:
    """The detectors whose scores every one of ``logs`` holds, in the first log's order."""
    logs = list(logs)
    if not logs:
        return []
    common = set.intersection(*(set(log.detectors) for log in logs))
    return [name for name in logs[0].detectors if name in common]


def compute_metrics(logs: Iterable[RunLog], detector: str | None = None) -> list[VariantMetrics]:
    """Metrics per (task, method, variant) over all episodes of ``logs``, in a stable order.

    ``detector``: whose scores the per-step metrics (AUROC, AUPR, FPR@95TPR) rank (default: the
    one each run's alarm read). The alarm metrics (false alarms, early alarms, detections, delays)
    are the run's alarms: they are given on the rows of the detector the alarm read, and ``None``
    on the rows of the others, which raised no alarm.

    Raises:
        LogFormatError: a log without scores of ``detector``.
    """
    from sklearn.metrics import auc, average_precision_score, roc_curve  # heavy: imported when used

    groups: dict[tuple[str, str, str], list[EpisodeLog]] = defaultdict(list)
    scores_of: dict[int, np.ndarray] = {}
    names: dict[tuple[str, str, str], str] = {}
    alarmed_by: dict[tuple[str, str, str], str] = {}
    for log in logs:
        for episode in log.episodes:
            groups[(log.task, log.method, episode.variant)].append(episode)
            scores_of[id(episode)] = episode.scores_of(detector)
            names[(log.task, log.method, episode.variant)] = detector or log.detector
            alarmed_by[(log.task, log.method, episode.variant)] = log.detector
    id_scores: dict[tuple[str, str], np.ndarray] = {}
    for (task, method, variant), episodes in groups.items():
        if parse_variant(variant).is_id:
            id_scores[(task, method)] = np.concatenate([scores_of[id(e)] for e in episodes])
    results = []
    for (task, method, variant), episodes in sorted(groups.items()):
        name = names[(task, method, variant)]
        alarms = name == alarmed_by[(task, method, variant)]  # the alarm read this detector's scores
        is_id = parse_variant(variant).is_id
        steps = sum(e.length for e in episodes)
        firsts = [alarm_events(e.alarm) for e in episodes]
        if is_id:
            far = float(np.mean([len(f) > 0 for f in firsts])) if alarms else None
            results.append(VariantMetrics(task, method, variant, len(episodes), steps, steps, 0,
                                          None, None, None, far, None, None, None, None, name))
            continue
        before = np.concatenate([scores_of[id(e)][~e.shifted] for e in episodes])
        ood = np.concatenate([scores_of[id(e)][e.shifted] for e in episodes])
        negatives = np.concatenate([id_scores.get((task, method), np.array([])), before])
        auroc = aupr = fpr95 = None
        if len(negatives) and len(ood):
            labels = np.concatenate([np.zeros(len(negatives)), np.ones(len(ood))])
            scores = np.concatenate([negatives, ood])
            fprs, tprs, _ = roc_curve(labels, scores)  # one sort for AUROC and FPR@95TPR
            auroc = float(auc(fprs, tprs))
            aupr = float(average_precision_score(labels, scores))
            fpr95 = float(fprs[np.searchsorted(tprs, 0.95, side="left")])
        early_rate = detection_rate = delay_mean = delay_median = None
        if alarms:
            early = [bool(len(f) and f[0] < e.onset) for f, e in zip(firsts, episodes)]
            detected = [f[f >= e.onset] for f, e in zip(firsts, episodes)]
            delays = [int(d[0] - e.onset) for d, e in zip(detected, episodes) if len(d)]
            early_rate, detection_rate = float(np.mean(early)), float(np.mean([len(d) > 0 for d in detected]))
            if delays:
                delay_mean, delay_median = float(np.mean(delays)), float(np.median(delays))
        results.append(VariantMetrics(
            task, method, variant, len(episodes), steps, len(negatives), len(ood), auroc, aupr, fpr95, None,
            early_rate, detection_rate, delay_mean, delay_median, name,
        ))
    return results


def compute_all_metrics(logs: Iterable[RunLog]) -> list[VariantMetrics]:
    """:func:`compute_metrics` for every detector the logs hold (``spread`` alone for older logs)."""
    logs = list(logs)
    return [m for name in detectors_in(logs) for m in compute_metrics(logs, name)]
