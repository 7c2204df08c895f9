"""Metrics from logged episodes, per (task, method, variant).

Per step (the paper's view): OOD steps are the steps of a shifted run from its onset on (their
``shifted`` flag); ID steps are all steps of the ID runs of the same task and method plus the
steps before the onset of this variant's runs. AUROC (the paper's metric), AUPR with OOD as the
positive class, and the false-positive rate at 95% true-positive rate.

Per episode (the monitor's view): an alarm is a rising edge of the logged alarm flag. ID runs
give the episode-level false-alarm rate (episodes with any alarm). Shifted runs give the
detection rate (episodes with an alarm at or after the onset, of those in which the shift began:
an episode that ended before its onset had nothing to detect) and the delay from the onset to
the first such alarm; alarms before the onset are counted as early (false) alarms.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from oodmon.envs.readings import reading_label
from oodmon.envs.shift import parse_any_variant, same_env
from oodmon.errors import OodmonError
from oodmon.replay.failures import failure_known, failure_step, id_failures
from oodmon.replay.reader import EpisodeLog, RunLog

if TYPE_CHECKING:
    from oodmon.monitor.threshold import Stretches

__all__ = ["EpisodeAlarms", "MonitorMetrics", "VariantMetrics", "alarm_events", "average_precision",
           "compute_all_metrics", "compute_metrics", "compute_monitor_metrics", "ended_before_onset", "detectors_in",
           "env_of_variant", "failed_episodes", "first_reading", "fpr_at_tpr", "id_stretches", "is_id_episode",
           "is_id_variant", "longer_than_calibration", "made_from_episodes", "monitor_row", "off_calibration_noise",
           "pooled_fits", "pooled_noise", "pooled_thresholds", "pooled_weights", "rankable", "roc_points",
           "shifted_alarms"]


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
    #: the episodes the alarm rates count (those of the runs whose alarm read ``detector``): their
    #: denominator, which ``oodmon check`` weighs a rate's change by; ``None`` without alarm rates
    alarm_episodes: int | None = None
    #: the delays of the episodes the alarm detected, in steps (``delay_mean`` is their mean): what
    #: ``oodmon check`` weighs a change of the mean delay by
    delays: tuple[int, ...] = ()
    #: of ``alarm_episodes``, those in which the shift began (the others ended before their onset:
    #: nothing to detect): the detection rate's denominator; ``None`` without alarm rates
    shifted_episodes: int | None = None

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


def rankable(scores: np.ndarray) -> np.ndarray:
    """Scores that can be ranked: an infinite one (the monitor scores a NaN or infinite observation
    +inf) or a NaN one (a score that could not be computed) as the largest float, the most shifted;
    -inf as the smallest.

    Example:
        >>> rankable(np.array([0.5, np.inf, np.nan]))[1:] == np.finfo(np.float64).max
        array([ True,  True])
    """
    scores = np.asarray(scores, dtype=np.float64)
    if np.isfinite(scores).all():
        return scores
    top = np.finfo(np.float64).max
    return np.nan_to_num(scores, nan=top, posinf=top, neginf=-top)


def fpr_at_tpr(labels: np.ndarray, scores: np.ndarray, tpr: float = 0.95) -> float:
    """The false-positive rate at the first threshold that reaches ``tpr``.

    Example:
        >>> fpr_at_tpr(np.array([0, 0, 1, 1]), np.array([0.1, 0.6, 0.5, 0.9]))
        0.5
    """
    fprs, tprs = roc_points(labels, rankable(scores))
    return float(fprs[np.searchsorted(tprs, tpr, side="left")])


def _positives_by_threshold(labels: np.ndarray, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """False and true positives (float64 counts) at each distinct score taken as the threshold, from
    the largest down: ``sklearn.metrics``' own counts (their order inside a tie does not change a
    count at the tie's end)."""
    order = np.argsort(scores, kind="stable")[::-1]
    scores, labels = scores[order], np.asarray(labels)[order]
    ends = np.concatenate([np.flatnonzero(np.diff(scores)), [len(scores) - 1]])
    tps = np.cumsum(labels, dtype=np.float64)[ends]
    return 1 + ends.astype(np.float64) - tps, tps


def _rates(counts: np.ndarray) -> np.ndarray:
    return counts / counts[-1] if counts[-1] > 0 else np.full(counts.shape, np.nan)  # (one class only: undefined)


def roc_points(labels: np.ndarray, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ROC curve of ``scores`` (finite: see :func:`rankable`) for 0/1 ``labels`` (1: shifted), as
    (false-positive rates, true-positive rates) from (0, 0): ``sklearn.metrics.roc_curve``'s points
    (collinear ones dropped) to the bit, without importing sklearn, which took a second of each
    ``oodmon replay``'s start (2026-12-04). Its area, the AUROC: ``np.trapezoid(tpr, fpr)``, equal
    to ``sklearn.metrics.auc`` (``tests/replay/test_metrics.py`` compares the three with sklearn's).

    Example:
        >>> fpr, tpr = roc_points(np.array([0, 0, 1, 1]), np.array([0.1, 0.6, 0.5, 0.9]))
        >>> fpr.tolist(), tpr.tolist(), float(np.trapezoid(tpr, fpr))
        ([0.0, 0.0, 0.5, 0.5, 1.0], [0.0, 0.5, 0.5, 1.0, 1.0], 0.75)
    """
    return _roc_of(*_positives_by_threshold(labels, scores))


def _roc_of(fps: np.ndarray, tps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`roc_points` of the counts :func:`_positives_by_threshold` gives."""
    if len(fps) > 2:  # a point between two on one line adds nothing: kept are the curve's corners
        corners = np.concatenate([[True], np.logical_or(np.diff(fps, 2), np.diff(tps, 2)), [True]])
        fps, tps = fps[corners], tps[corners]
    return _rates(np.concatenate([[0.0], fps])), _rates(np.concatenate([[0.0], tps]))


def average_precision(labels: np.ndarray, scores: np.ndarray) -> float:
    """The area under the precision-recall curve as ``sklearn.metrics.average_precision_score``
    takes it (no interpolation), to the bit, for 0/1 ``labels`` of both kinds.

    Example:
        >>> average_precision(np.array([0, 0, 1, 1]), np.array([0.1, 0.4, 0.35, 0.8]))
        0.8333333333333333
    """
    return _average_precision_of(*_positives_by_threshold(labels, scores))


def _average_precision_of(fps: np.ndarray, tps: np.ndarray) -> float:
    """:func:`average_precision` of the counts :func:`_positives_by_threshold` gives."""
    flagged = tps + fps
    precision = np.concatenate([np.where(flagged != 0, np.divide(tps, flagged), 0.0)[::-1], [1.0]])
    recall = np.concatenate([(tps / tps[-1])[::-1], [0.0]])
    return float(max(0.0, -np.sum(np.diff(recall) * precision[:-1])))


def detectors_in(logs: Iterable[RunLog]) -> list[str]:
    """The detectors whose scores every one of ``logs`` holds, in the first log's order."""
    logs = list(logs)
    if not logs:
        return []
    common = set.intersection(*(set(log.detectors) for log in logs))
    return [name for name in logs[0].detectors if name in common]


def pooled_weights(logs: Iterable[RunLog]) -> dict[tuple[str, str], dict[str, list[Path]]]:
    """The (task, method) groups whose logs hold runs of more than one policy's weights (the
    ``policy_hash`` each run recorded; runs that recorded none are not counted): their logs by
    weights. Replay pools a group's logs in one row per variant, so such a row's AUROC ranks one
    policy's ID steps against another's shifted ones (the bench's trials, or a model retrained
    into the same folder of logs). An SB3 model's logs before 2026-12-04 recorded the hash of its
    files, which later logs of the same files record beside their weights' (``about.files_hash``):
    both count as one policy's. So do a plain policy's logs before 2026-12-06, which recorded its
    name alone, and later ones, which record its code too and the name beside (``about.name_hash``).

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> def run(name, weights):
        ...     return RunLog(Path(name), "cartpole", "sb3", 1.0, {"policy_hash": weights}, [], True)
        >>> pooled_weights([run("a.mcap", "sha256:aa"), run("b.mcap", "sha256:bb"), run("c.mcap", "sha256:aa")])
        {('cartpole', 'sb3'): {'sha256:aa': [PosixPath('a.mcap'), PosixPath('c.mcap')], 'sha256:bb': [PosixPath('b.mcap')]}}
        >>> later = RunLog(Path("d.mcap"), "cartpole", "sb3", 1.0, {"policy_hash": "sha256:dd",
        ...                                                          "about.files_hash": "sha256:bb"}, [], True)
        >>> pooled_weights([run("b.mcap", "sha256:bb"), later])  # b.mcap's files, logged before 2026-12-04
        {}
        >>> named = RunLog(Path("e.mcap"), "cartpole", "plain", 1.0, {"policy_hash": "name:act"}, [], True)
        >>> coded = RunLog(Path("f.mcap"), "cartpole", "plain", 1.0, {"policy_hash": "name:act code:0f1e",
        ...                                                           "about.name_hash": "name:act"}, [], True)
        >>> pooled_weights([named, coded])  # a plain policy's, logged before 2026-12-06 and after
        {}
    """
    logs = list(logs)
    # an earlier log's hash -> the same files' weights, or the same plain policy's name and code
    weights_of = {log.metadata[key]: log.metadata.get("policy_hash") for log in logs
                  for key in ("about.files_hash", "about.name_hash") if log.metadata.get(key)}

    def weights(log: RunLog) -> str | None:
        recorded = log.metadata.get("policy_hash")
        return weights_of.get(recorded, recorded)

    return _pooled((log, (log.task, log.method), weights(log)) for log in logs)


def pooled_fits(logs: Iterable[RunLog]) -> dict[tuple[str, str, str], dict[str, list[Path]]]:
    """The (task, method, detector) rows whose logs were scored by more than one fit of that
    learned detector (the fingerprint each run recorded, ``fitted.<detector>``, logs since
    2026-11-29), within (task, method) groups of one policy's weights (:func:`pooled_weights` says
    the rest): their logs by fit. Two fits' scores are on two scales, so such a row's AUROC ranks
    one fit's scores against another's (detectors refitted between runs)."""
    logs = list(logs)
    mixed = pooled_weights(logs)
    return _pooled((log, (log.task, log.method, name), log.metadata.get(f"fitted.{name}"))
                   for log in logs if (log.task, log.method) not in mixed for name in log.detectors)


def pooled_thresholds(logs: Iterable[RunLog]) -> dict[tuple[str, str], dict[str, list[Path]]]:
    """The (task, method) groups whose runs raised their alarms by more than one threshold (the
    detector the alarm read, its value and its rule; runs without one are not counted): their logs
    by threshold, e.g. ``combined > 5.74836 (score > threshold)``. ``replay --monitor`` counts a
    variant's alarms together whatever threshold raised them, so such a row mixes two monitors
    (:func:`compute_metrics` gives each detector's row the alarms of the runs whose alarm read it).

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> def run(name, detector, threshold):
        ...     metadata = {"detector": detector, "rule": "score > threshold"}
        ...     return RunLog(Path(name), "cartpole", "ensemble", threshold, metadata, [], True)
        >>> runs = [run("a.mcap", "spread", 4.67), run("b.mcap", "combined", 5.75), run("c.mcap", "spread", 4.67)]
        >>> for threshold, paths in pooled_thresholds(runs)[("cartpole", "ensemble")].items():
        ...     print(threshold, [p.name for p in paths])
        spread > 4.67 (score > threshold) ['a.mcap', 'c.mcap']
        combined > 5.75 (score > threshold) ['b.mcap']
        >>> pooled_thresholds(runs[:1] + runs[2:])  # one threshold: nothing pooled
        {}
    """
    return _pooled((log, (log.task, log.method), f"{log.detector} > {log.threshold:.6g} ({log.metadata.get('rule', '')})")
                   for log in logs if log.has_threshold)


def pooled_noise(logs: Iterable[RunLog]) -> dict[tuple[str, str], dict[str, list[Path]]]:
    """The (task, method) groups whose episodes were played at more than one sensor noise (each
    episode's ``obs_noise``, logs since format 8; older logs' read as 0): their logs by noise, a log
    under each noise it played. A noisy sensor moves every detector's ID scores (and the learned
    ones', fitted without noise, far), so a row that pools them ranks one world's steps against
    another's.

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> from oodmon.monitor.records import EpisodeRecord
        >>> def run(name, *noises):
        ...     played = [EpisodeRecord(0, "oodmon/CartPole-v1", "cartpole", 0, 0, 9.0, 9, 0, None, obs_noise=n) for n in noises]
        ...     return RunLog(Path(name), "cartpole", "ensemble", 1.0, {}, played, True)
        >>> pooled_noise([run("a.mcap", 0.0), run("b.mcap", 0.01, 0.01)])
        {('cartpole', 'ensemble'): {'0': [PosixPath('a.mcap')], '0.01': [PosixPath('b.mcap')]}}
        >>> pooled_noise([run("a.mcap", 0.05), run("b.mcap", 0.05)])  # one noise: nothing pooled
        {}
    """
    played = sorted(((noise, log) for log in logs for noise in log.noises),
                    key=lambda pair: pair[0])  # the quietest first
    return _pooled((log, (log.task, log.method), f"{noise:g}") for noise, log in played)


def made_from_episodes(logs: Iterable[RunLog]) -> dict[tuple[str, str], dict[str, int]]:
    """The (task, method) groups with episodes played in the ID env (an ID variant, or a shift's
    steps before its onset) from a reset seed the run's threshold or the fitted detector its alarm
    reads was made from (``about.threshold_seeds``, logs since 2026-12-01): how many, by use
    (``calibration``, ``reference``, ``detector fitting``). A threshold is the largest statistic of
    its calibration episodes (or near it) and a detector learned its fitting episodes: they alarm
    less often than fresh ones, so such episodes' false alarms read low (``oodmon run`` warns of
    them; ``oodmon validate`` refuses them).

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> from oodmon.monitor.records import EpisodeRecord
        >>> def episode(seed, variant="cartpole", onset=0):
        ...     return EpisodeRecord(seed, "oodmon/CartPole-v1", variant, onset, seed, 1.0, 1, 0, None)
        >>> log = RunLog(Path("a.mcap"), "cartpole", "ensemble", 4.6,
        ...              {"about.threshold_seeds": '{"calibration":[0,45]}'},
        ...              [episode(43), episode(44), episode(45), episode(1, "cartpole:length=2.0"),
        ...               episode(2, "cartpole:length=2.0", onset=100)], True)
        >>> made_from_episodes([log])
        {('cartpole', 'ensemble'): {'calibration': 3}}
    """
    counts: dict[tuple[str, str], dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for log in logs:
        used = _threshold_seeds(log)
        for episode in log.episodes if used else ():
            if episode.seed is None or not (episode.onset > 0 or is_id_episode(episode, log.task)):
                continue
            for use, (first, end) in used.items():
                if first <= episode.seed < end:
                    counts[(log.task, log.method)][use] += 1
    return {group: dict(by_use) for group, by_use in counts.items()}


def off_calibration_noise(logs: Iterable[RunLog]) -> dict[tuple[str, str], dict[str, list[Path]]]:
    """The (task, method) groups with episodes played at another sensor noise than the run's
    threshold was calibrated in (``about.threshold_obs_noise``, logs since 2026-12-05 of thresholds
    that record it): their logs by ``played X, calibrated in Y``. A threshold's false-alarm bound
    is for its calibration's world, and even 0.1% noise put a noiseless CartPole threshold above
    every fresh ID episode (2026-12-05), so those logs' false alarms say nothing of the bound.

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> from oodmon.monitor.records import EpisodeRecord
        >>> played = [EpisodeRecord(0, "oodmon/CartPole-v1", "cartpole", 0, 0, 9.0, 9, 0, None, obs_noise=0.01)]
        >>> log = RunLog(Path("a.mcap"), "cartpole", "ensemble", 1.0, {"about.threshold_obs_noise": "0"}, played, True)
        >>> off_calibration_noise([log])
        {('cartpole', 'ensemble'): {'played 0.01, calibrated in 0': [PosixPath('a.mcap')]}}
    """
    return _logs_by_label(logs, "about.threshold_obs_noise", float, lambda log, calibrated: [
        f"played {noise:g}, calibrated in {calibrated:g}" for noise in sorted(log.noises - {calibrated})])


def longer_than_calibration(logs: Iterable[RunLog]) -> dict[tuple[str, str], dict[str, list[Path]]]:
    """The (task, method) groups with ID episodes longer than the longest of their threshold's
    calibration episodes (``about.threshold_longest_episode``, logs since 2026-12-05 of thresholds
    that record it): their logs by ``N past L steps``. The bound is for episodes like the
    calibration's; a run of 5,000 steps put the docs' own CartPole controller's 500-step threshold
    above its target (2026-12-05), so those episodes' false alarms say nothing of it.

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> from oodmon.monitor.records import EpisodeRecord
        >>> played = [EpisodeRecord(e, "CartPole-v1", "CartPole-v1", 0, 0, n, n, 0, None) for e, n in enumerate([600, 90])]
        >>> log = RunLog(Path("a.mcap"), "cartpole", "plain", 1.0, {"about.threshold_longest_episode": "500"}, played, True)
        >>> longer_than_calibration([log])
        {('cartpole', 'plain'): {'1 past 500 steps': [PosixPath('a.mcap')]}}
        >>> longer_than_calibration([RunLog(Path("b.mcap"), "cartpole", "plain", 1.0,
        ...                                 {"about.threshold_longest_episode": "-5"}, played, True)])
        {}
    """
    def past(log: RunLog, longest: int) -> list[str]:
        if longest < 0:  # a damaged record says nothing
            return []
        longer = sum(episode.length > longest for episode in log.episodes if is_id_episode(episode, log.task))
        return [f"{longer} past {longest:,} steps"] if longer else []

    return _logs_by_label(logs, "about.threshold_longest_episode", int, past)


def id_stretches(logs: Iterable[RunLog], longer: Mapping[tuple[str, str], Any] | None = None
                 ) -> dict[tuple[str, str], tuple[Stretches, float]]:
    """What ``validate --max-steps`` counts, of logged runs: for each (task, method) group whose ID
    episodes ran longer than their threshold's longest calibration episode
    (:func:`longer_than_calibration`), its ID episodes cut into stretches as long as a calibration
    episode on average (``about.threshold_mean_episode``), each alarmed where an alarm was raised
    in it, with each episode's stretches counted as a cluster (:class:`Stretches`), and the
    threshold's target rate (``about.threshold_far``); ``longer``: those groups, where the caller
    has them already (:func:`longer_than_calibration` of ``logs``). A deployment runs for hours
    without a reset, and its own log then says whether the per-episode bound held there. Logs that
    record neither (before 2026-12-05), or a group whose logs record two thresholds' figures, say
    nothing.

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> from oodmon.monitor.records import EpisodeRecord
        >>> alarm = np.zeros(1200, bool); alarm[700:720] = True  # one alarm, raised at step 700
        >>> played = [EpisodeLog(0, "CartPole-v1", "CartPole-v1", 0, 0, 1200.0, 1200, 1, 700, scores=np.zeros(1200),
        ...                      shifted=np.zeros(1200, bool), alarm=alarm)]
        >>> about = {"about.threshold_longest_episode": "500", "about.threshold_mean_episode": "500",
        ...          "about.threshold_far": "0.05"}
        >>> (stretches, far), = id_stretches([RunLog(Path("a.mcap"), "cartpole", "plain", 1.0, about, played, True)]).values()
        >>> stretches.length, stretches.alarmed, stretches.total, far
        (500, 1, 2, 0.05)
    """
    from oodmon.monitor.threshold import Stretches

    logs = list(logs)
    if longer is None:
        longer = longer_than_calibration(logs)
    grouped: dict[tuple[str, str], dict[tuple[int, float], list]] = defaultdict(lambda: defaultdict(list))
    for log in logs:
        if (log.task, log.method) not in longer:
            continue
        try:
            length, far = int(log.metadata["about.threshold_mean_episode"]), float(log.metadata["about.threshold_far"])
        except (KeyError, ValueError):
            continue
        if length >= 1 and 0 < far < 1:
            grouped[(log.task, log.method)][(length, far)] += [
                (episode.length, alarm_events(episode.alarm).tolist()) for episode in log.episodes
                if is_id_episode(episode, log.task)]
    return {group: (Stretches.of(episodes, length), far) for group, by_threshold in grouped.items()
            if len(by_threshold) == 1 for (length, far), episodes in by_threshold.items() if episodes}


def _logs_by_label(logs: Iterable[RunLog], key: str, parse: Callable[[str], Any],
                   labels: Callable[[RunLog, Any], list[str]]) -> dict[tuple[str, str], dict[str, list[Path]]]:
    """The logs by (task, method), then by each label ``labels(log, value)`` gives them, where
    ``value`` is their metadata's ``key`` read by ``parse``; a log that records none (or NaN), or a
    damaged one, says nothing."""
    found: dict[tuple[str, str], dict[str, list[Path]]] = defaultdict(lambda: defaultdict(list))
    for log in logs:
        try:
            value = parse(log.metadata[key])
        except (KeyError, ValueError):
            continue
        if value != value:  # NaN
            continue
        for label in labels(log, value):
            found[(log.task, log.method)][label].append(log.path)
    return {group: dict(by) for group, by in found.items()}


def _threshold_seeds(log: RunLog) -> dict[str, tuple[int, int]]:
    """The seed ranges a log's threshold was made from, by use (none where the log records none,
    or a damaged record: what cannot be read says nothing)."""
    import json

    try:
        used = json.loads(log.metadata.get("about.threshold_seeds", "{}"))
    except (ValueError, RecursionError):  # (a damaged record may nest deeper than the parser goes)
        return {}
    if not isinstance(used, dict):
        return {}
    return {use: (seeds[0], seeds[1]) for use, seeds in used.items()
            if isinstance(seeds, list) and len(seeds) == 2 and all(type(seed) is int for seed in seeds)}


def _pooled(entries: Iterable[tuple[RunLog, tuple, str | None]]) -> dict[tuple, dict[str, list[Path]]]:
    """Of (log, group, what it was made with) entries, the groups made with more than one, their
    logs by what; a log that recorded nothing (``None``, ``unknown``) is not counted."""
    groups: dict[tuple, dict[str, list[Path]]] = defaultdict(lambda: defaultdict(list))
    for log, group, made_with in entries:
        if made_with and made_with != "unknown":
            groups[group][made_with].append(log.path)
    return {group: dict(by) for group, by in groups.items() if len(by) > 1}


def _episodes_by_variant(logs: Iterable[RunLog]) -> dict[tuple[str, str, str], list[tuple[RunLog, EpisodeLog]]]:
    """Every episode of ``logs`` with its log, grouped by (task, method, variant)."""
    groups: dict[tuple[str, str, str], list[tuple[RunLog, EpisodeLog]]] = defaultdict(list)
    for log in logs:
        for episode in log.episodes:
            groups[(log.task, log.method, episode.variant)].append((log, episode))
    return groups


def _thresholded(pairs: Sequence[tuple[RunLog, EpisodeLog]]) -> bool:
    """Whether every run of a (task, method, variant)'s episodes had a threshold: only then are its
    alarms the monitor's (a run without one raised none)."""
    return all(log.has_threshold for log, _ in pairs)


def ended_before_onset(episode: Any) -> bool:
    """Whether a shifted variant's episode (an :class:`EpisodeLog`, or the monitor's
    :class:`~oodmon.monitor.records.EpisodeRecord`) ended before its onset: the shift never began in
    it (the metrics count it among the variant's episodes and its early alarms, not among those
    the detection rate and "shifted episodes alarmed" count).

    Example:
        >>> from oodmon.monitor.records import EpisodeRecord
        >>> ended_before_onset(EpisodeRecord(0, "oodmon/CartPole-v1", "cartpole:length=2.0", 600, 0, 500.0, 500, 0, None))
        True
    """
    return not is_id_variant(episode.variant) and episode.length <= episode.onset


def _onset_alarms(episode: EpisodeLog) -> tuple[int | None, int | None]:
    """The step of ``episode``'s first alarm if it came before its onset (an early, false alarm),
    and the step of its first alarm at or after the onset (``None``: none)."""
    events = alarm_events(episode.alarm)
    after = events[events >= episode.onset]
    return (int(events[0]) if len(events) and events[0] < episode.onset else None), int(after[0]) if len(after) else None


@dataclass(frozen=True)
class EpisodeAlarms:
    """One shifted episode's alarm against its shift and failure, in steps since its onset: the
    first alarm before the onset (negative; ``None``: none), the first at or after it, the failure
    (:func:`failure_step`) and the episode's last step. What the monitor's figures count and
    :func:`~oodmon.replay.plots.plot_alarm_timeline` draws."""

    early: int | None
    first: int | None
    failure: int | None
    end: int

    @classmethod
    def of(cls, episode: EpisodeLog, task: str, failure: str | None = None) -> EpisodeAlarms:
        """Example:
            >>> from oodmon.replay.reader import EpisodeLog
            >>> alarm = np.zeros(9, bool); alarm[[2, 6]] = True
            >>> e = EpisodeLog(episode=0, env_id="", variant="cartpole:length=2.0", onset=5, seed=0, total_return=9.0,
            ...                length=9, alarms=2, first_alarm_step=2, terminated=True, scores=np.zeros(9),
            ...                shifted=np.arange(9) >= 5, alarm=alarm)
            >>> EpisodeAlarms.of(e, "cartpole")
            EpisodeAlarms(early=-3, first=1, failure=3, end=3)
        """
        early, first = _onset_alarms(episode)
        failed = failure_step(episode, task, failure)
        onset = episode.onset
        return cls(None if early is None else early - onset, None if first is None else first - onset,
                   None if failed is None else failed - onset, episode.length - 1 - onset)

    @property
    def before_failure(self) -> bool:
        """Alarmed at or after the onset and before the failure (a failed episode)."""
        return self.failure is not None and self.first is not None and self.first < self.failure

    @property
    def lead(self) -> int | None:
        """The warning the alarm gave: steps from the first alarm at or after the onset to the
        failure, in an episode alarmed before it (else ``None``)."""
        return self.failure - self.first if self.before_failure else None


def shifted_alarms(logs: Iterable[RunLog], failure: str | None = None
                   ) -> dict[tuple[str, str, str], list[EpisodeAlarms]]:
    """:class:`EpisodeAlarms` of every shifted episode, by (task, method, variant), of the
    variants whose runs all had a threshold (the others raised no alarms to draw); ``failure``:
    what fails in an env oodmon has no variants of (:data:`FAILURES`)."""
    return {key: [EpisodeAlarms.of(e, key[0], failure) for _, e in pairs]
            for key, pairs in sorted(_episodes_by_variant(logs).items())
            if not _is_id_group(key[0], key[2], [e for _, e in pairs]) and _thresholded(pairs)}


def env_of_variant(variant: str) -> str:
    """The env (oodmon's task, or your own env's id) a logged variant is of.

    Example:
        >>> env_of_variant("cartpole:length=2.0"), env_of_variant("my_envs:MyEnv-v0:friction=0.2")
        ('cartpole', 'my_envs:MyEnv-v0')
    """
    return variant if is_id_variant(variant) else variant.rpartition(":")[0]


def is_id_variant(variant: str) -> bool:
    """Whether a logged variant is in-distribution: an oodmon task's default env, or an env
    oodmon has no variants of as it is (a user's own env id); not a shift of that env
    (``Acrobot-v1:LINK_MASS_2=3.0``, :mod:`oodmon.envs.shift`). An env's id alone is taken for the
    policy's own: whether it is another env (:class:`~oodmon.envs.shift.AnotherEnv`) a log's
    episodes say (:func:`is_id_episode`).

    Example:
        >>> is_id_variant("cartpole"), is_id_variant("cartpole:length=2.0"), is_id_variant("Acrobot-v1")
        (True, False, True)
        >>> is_id_variant("Acrobot-v1:LINK_MASS_2=3.0")
        False
    """
    try:
        return parse_any_variant(variant).is_id
    except OodmonError:
        return True


def is_id_episode(episode: EpisodeLog, task: str) -> bool:
    """Whether a logged episode of a log of ``task`` (its policy's task or env id) is of the
    policy's own world as it is (:func:`is_id_variant`): not a shift, nor another env deployed as
    its shifted world (:class:`~oodmon.envs.shift.AnotherEnv`: named by that env's id alone, each of
    its steps logged shifted). Both are asked: an env made without gymnasium's registry is named
    by its class, which is not the task, and its ID steps are not shifted; an episode of another
    env logged before 2026-12-06 had no shifted step, and is an ID one still. An episode read
    without its steps (a monitor's :class:`~oodmon.monitor.records.EpisodeRecord`): by its variant.

    Example:
        >>> def e(variant, shifted):
        ...     return EpisodeLog(episode=0, env_id="", variant=variant, onset=0, seed=0, total_return=3.0, length=3,
        ...                       alarms=0, first_alarm_step=None, scores=np.zeros(3), shifted=np.full(3, shifted),
        ...                       alarm=np.zeros(3, bool))
        >>> own = "MiniGrid-DistShift1-v0"
        >>> is_id_episode(e(own, False), own), is_id_episode(e("MiniGrid-DistShift2-v0", True), own)
        (True, False)
        >>> is_id_episode(e("DistShiftEnv", False), own)  # an env made without the registry, named by its class
        True
    """
    return is_id_variant(episode.variant) and not _another_env(episode.variant, task, [episode])


def _is_id_group(task: str, variant: str, episodes: Iterable[EpisodeLog]) -> bool:
    """Whether a (task, method, variant)'s episodes are ID ones (:func:`is_id_episode`), the
    variant parsed once."""
    return is_id_variant(variant) and not _another_env(variant, task, episodes)


def _another_env(variant: str, task: str, episodes: Iterable[EpisodeLog]) -> bool:
    """Whether episodes named ``variant``, an env's id alone, are of another env than ``task``'s
    deployed as its shifted world: their steps say so."""
    return not same_env(variant, task) and any(
        (shifted := getattr(episode, "shifted", None)) is not None and shifted.any() for episode in episodes)


def compute_metrics(logs: Iterable[RunLog], detector: str | None = None) -> list[VariantMetrics]:
    """Metrics per (task, method, variant) over all episodes of ``logs``, in a stable order.

    ``detector``: whose scores the per-step metrics (AUROC, AUPR, FPR@95TPR) rank (default: the
    one the alarm of a (task, method, variant)'s last run read, in every run's scores of it). The
    alarm metrics (false alarms, early alarms, detections, delays) are the runs' alarms: each
    detector's row counts those of the runs whose alarm read it, over
    their episodes (``None`` where no run's alarm read it), and every row of a (task, method,
    variant) with a run that had no threshold (:attr:`RunLog.has_threshold`) gives ``None``: it
    raised none.

    Raises:
        LogFormatError: a log without scores of ``detector``.
    """
    grouped = _episodes_by_variant(logs)
    groups = {key: [e for _, e in pairs] for key, pairs in grouped.items()}
    # Without ``detector``, the last log of a group names the one ranked, whose scores every run of
    # the group gives (a run's alarm scores are those of the detector it read: runs whose alarms
    # read two detectors would otherwise be ranked on two scales).
    names = {key: detector or pairs[-1][0].detector for key, pairs in grouped.items()}
    scores_of = {id(e): e.scores_of(None if detector is None and log.detector == names[key] else names[key])
                 for key, pairs in grouped.items() for log, e in pairs}
    thresholded = {key: _thresholded(pairs) for key, pairs in grouped.items()}
    id_scores: dict[tuple[str, str], np.ndarray] = {}
    for (task, method, variant), episodes in groups.items():
        if _is_id_group(task, variant, episodes):
            id_scores[(task, method)] = np.concatenate([scores_of[id(e)] for e in episodes])
    results = []
    for (task, method, variant), episodes in sorted(groups.items()):
        name = names[(task, method, variant)]
        # the episodes of the runs whose alarm read this detector's scores against a threshold
        # (a run without one raised none: the group's alarms are then not told)
        alarmed = [e for log, e in grouped[(task, method, variant)] if log.detector == name]
        alarms = bool(alarmed) and thresholded[(task, method, variant)]
        is_id = _is_id_group(task, variant, episodes)
        steps = sum(e.length for e in episodes)
        if is_id:
            far = float(np.mean([len(alarm_events(e.alarm)) > 0 for e in alarmed])) if alarms else None
            results.append(VariantMetrics(task, method, variant, len(episodes), steps, steps, 0,
                                          None, None, None, far, None, None, None, None, name,
                                          len(alarmed) if alarms else None))
            continue
        before = np.concatenate([scores_of[id(e)][~e.shifted] for e in episodes])
        ood = np.concatenate([scores_of[id(e)][e.shifted] for e in episodes])
        negatives = np.concatenate([id_scores.get((task, method), np.array([])), before])
        auroc = aupr = fpr95 = None
        if len(negatives) and len(ood):
            labels = np.concatenate([np.zeros(len(negatives)), np.ones(len(ood))])
            scores = rankable(np.concatenate([negatives, ood]))
            counts = _positives_by_threshold(labels, scores)  # one sort for AUROC, AUPR and FPR@95TPR
            fprs, tprs = _roc_of(*counts)
            auroc = float(np.trapezoid(tprs, fprs))
            aupr = _average_precision_of(*counts)
            fpr95 = float(fprs[np.searchsorted(tprs, 0.95, side="left")])
        early_rate = detection_rate = delay_mean = delay_median = None
        delays: list[int] = []
        began = [e for e in alarmed if not ended_before_onset(e)]  # (one that ended before it has no alarm after it)
        if alarms:
            early, firsts = zip(*(_onset_alarms(e) for e in alarmed))
            delays = [int(first - e.onset) for first, e in zip(firsts, alarmed) if first is not None]
            early_rate = float(np.mean([e is not None for e in early]))
            detection_rate = len(delays) / len(began) if began else None
            if delays:
                delay_mean, delay_median = float(np.mean(delays)), float(np.median(delays))
        results.append(VariantMetrics(
            task, method, variant, len(episodes), steps, len(negatives), len(ood), auroc, aupr, fpr95, None,
            early_rate, detection_rate, delay_mean, delay_median, name, len(alarmed) if alarms else None,
            tuple(delays), len(began) if alarms else None,
        ))
    return results


def compute_all_metrics(logs: Iterable[RunLog]) -> list[VariantMetrics]:
    """:func:`compute_metrics` for every detector the logs hold (``spread`` alone for older logs).

    Each agent's (task, method) rows come from the detectors all of its logs hold: logs of agents
    watched by other detectors (a Pendulum agent's beside your CartPole model's ``combined``) may
    be replayed together without losing any agent's rows."""
    by_agent: dict[tuple[str, str], list[RunLog]] = defaultdict(list)
    for log in logs:
        by_agent[(log.task, log.method)].append(log)
    held = {agent: detectors_in(group) for agent, group in by_agent.items()}
    names = dict.fromkeys(name for names in held.values() for name in names)  # in the logs' order
    return [m for name in names
            for m in compute_metrics([log for agent, group in by_agent.items() if name in held[agent] for log in group],
                                     name)]


# -- the monitor's own benchmark ----------------------------------------------------------------

def failed_episodes(logs: Iterable[RunLog]) -> dict[str, int]:
    """Per shifted variant of ``logs`` (CartPole and Pendulum), how many of its episodes failed after
    the onset (:func:`failure_step`). The paper's protocol scores every step of a shifted episode as
    shifted, so an episode the agent survives adds steps that look ID by design. Pong has no
    failure here, and no entry. Pendulum's failure needs a pole swung up at the onset, which an
    episode shifted from its first step (the paper's protocol) seldom has: its count means something
    only for later onsets (the bench counts CartPole's alone).

    Example:
        >>> from oodmon.replay.reader import EpisodeLog, RunLog
        >>> def e(terminated):
        ...     return EpisodeLog(episode=0, env_id="", variant="cartpole:masscart=9.0", onset=0, seed=0,
        ...                       total_return=9.0, length=9, alarms=0, first_alarm_step=None, terminated=terminated,
        ...                       scores=np.zeros(9), shifted=np.ones(9, bool), alarm=np.zeros(9, bool))
        >>> failed_episodes([RunLog("x.mcap", "cartpole", "dropconnect", 1.0, {}, [e(True), e(False), e(True)], True)])
        {'cartpole:masscart=9.0': 2}
    """
    return {variant: sum(failure_step(e, task) is not None for _, e in pairs)
            for (task, _, variant), pairs in _episodes_by_variant(logs).items()
            if failure_known(task) and not _is_id_group(task, variant, [e for _, e in pairs])}


@dataclass(frozen=True)
class MonitorMetrics:
    """What the alarm did in one (task, method, variant), episode by episode (the monitor's benchmark).

    ID variant: ``false_alarms`` of ``episodes`` raised any alarm; ``far_low``/``far_high`` is the
    95% Clopper-Pearson interval of that rate; ``failed`` of them the env ended (:func:`id_failures`;
    ``None`` where that is no failure). Shifted variants: ``alarmed`` episodes had an alarm at
    or after the onset, of the :attr:`shifted_episodes` in which the shift began (``never_shifted``
    ended before their onset; :func:`ended_before_onset`), ``early`` ones of all ``episodes`` an
    alarm before it, a false alarm; ``failed`` episodes failed after
    the onset (:func:`failure_step`) and ``before_failure`` of them were alarmed before the failure
    step. Delays are in steps from the onset to the first alarm at or after it, over alarmed
    episodes (``None`` when none); leads (the warning) from that alarm to the failure, over the
    episodes alarmed before the failure. ``causes``: what raised the first alarm
    (:attr:`~oodmon.monitor.alarms.AlarmEvent.cause`), counted over the alarmed episodes with no
    alarm before the onset, whose logs say it (format 7 on), the most frequent first.
    ``readings``: over the same first alarms, the reading each named first (the one the dynamics
    model predicted worst, :attr:`~oodmon.monitor.alarms.AlarmEvent.readings`; format 10 on), as
    ``[2] (pole angle)`` where the env's layout is known (:mod:`oodmon.envs.readings`), the most
    frequent first: which sensor the shift moved, across episodes. A first alarm naming none is not
    counted. ``early_starts``: the ID starts of the ``early`` episodes, ``seed@step`` of each one's first
    alarm, sorted and each once: the bench's variants play the same seeds, so their steps before
    the onset are the same ID steps, and a pooled row's ``early`` counts one start once per variant.
    """

    task: str
    method: str
    variant: str
    episodes: int
    false_alarms: int | None = None
    far_low: float | None = None
    far_high: float | None = None
    early: int | None = None
    alarmed: int | None = None
    failed: int | None = None
    before_failure: int | None = None
    delay_median: float | None = None
    delay_p90: float | None = None
    delays: tuple[int, ...] = ()
    lead_median: float | None = None
    leads: tuple[int, ...] = ()
    causes: dict[str, int] = field(default_factory=dict)
    never_shifted: int = 0
    early_starts: tuple[str, ...] = ()
    readings: dict[str, int] = field(default_factory=dict)

    @property
    def is_id(self) -> bool:
        return self.false_alarms is not None

    @property
    def shifted_episodes(self) -> int:
        """The episodes in which the shift began: those ``alarmed`` counts."""
        return self.episodes - self.never_shifted

    @property
    def false_alarm_rate(self) -> float | None:
        return None if self.false_alarms is None else self.false_alarms / self.episodes

    @property
    def before_failure_rate(self) -> float | None:
        return None if self.before_failure is None or not self.failed else self.before_failure / self.failed

    def to_dict(self) -> dict[str, object]:
        return asdict(self) | {"delays": list(self.delays), "leads": list(self.leads), "early_starts": list(self.early_starts),
                               "false_alarm_rate": self.false_alarm_rate,
                               "before_failure_rate": self.before_failure_rate,
                               "shifted_episodes": None if self.is_id else self.shifted_episodes}


def compute_monitor_metrics(logs: Iterable[RunLog], failure: str | None = None) -> list[MonitorMetrics]:
    """The monitor's benchmark figures per (task, method, variant) from the logs' alarms
    (the alarm the runs raised, whatever detector it read), in a stable order. A (task, method,
    variant) with a run that had no threshold (:attr:`RunLog.has_threshold`) is left out: it raised
    no alarms to count. ``failure``: what fails in an env oodmon has no variants of
    (:data:`FAILURES`; none: its failure columns are ``None``)."""
    from oodmon.monitor.threshold import clopper_pearson

    results = []
    for (task, method, variant), pairs in sorted(_episodes_by_variant(logs).items()):
        if not _thresholded(pairs):
            continue
        if _is_id_group(task, variant, [e for _, e in pairs]):
            alarmed = sum(len(alarm_events(e.alarm)) > 0 for _, e in pairs)
            low, high = clopper_pearson(alarmed, len(pairs))
            results.append(MonitorMetrics(task, method, variant, len(pairs), false_alarms=alarmed,
                                          far_low=low, far_high=high,
                                          failed=id_failures([e for _, e in pairs], task, failure)))
            continue
        episodes = [EpisodeAlarms.of(e, task, failure) for _, e in pairs]
        known = failure_known(task, failure)  # else failed and alarmed before failure are None: blank, not "0 failed"
        first_alarms = [pair for pair, e in zip(pairs, episodes) if e.early is None and e.first is not None]
        causes = Counter(logged.first_alarm_cause for _, logged in first_alarms if logged.first_alarm_cause)
        readings = Counter(first_reading(logged, log.reading_names_of(logged)) for log, logged in first_alarms
                           if logged.first_alarm_readings)
        results.append(monitor_row(task, method, variant, len(episodes), sum(e.early is not None for e in episodes),
                                   sum(e.failure is not None for e in episodes) if known else None,
                                   sum(e.before_failure for e in episodes) if known else None,
                                   [e.first for e in episodes if e.first is not None],
                                   [e.lead for e in episodes if e.lead is not None], causes,
                                   sum(ended_before_onset(e) for _, e in pairs),
                                   [f"{logged.seed}@{logged.onset + e.early}" for (_, logged), e in zip(pairs, episodes)
                                    if e.early is not None], readings))
    return results


def first_reading(episode: EpisodeLog, names: Sequence[str] = ()) -> str:
    """The reading an episode's first alarm named first (:attr:`EpisodeLog.first_alarm_readings`),
    for :attr:`MonitorMetrics.readings`, with its name in ``names`` (by index:
    :meth:`RunLog.reading_names_of`) where there is one.

    Example:
        >>> from oodmon.replay.reader import EpisodeLog
        >>> e = EpisodeLog(episode=0, env_id="oodmon/CartPole-v1", variant="cartpole:obs.stuck[2]=1", onset=5,
        ...                seed=0, total_return=9.0, length=9, alarms=1, first_alarm_step=6, scores=np.zeros(9),
        ...                shifted=np.zeros(9, bool), alarm=np.zeros(9, bool),
        ...                first_alarm_readings=((2, -269.0), (3, 4.0)))
        >>> first_reading(e, ["cart position", "cart velocity", "pole angle"]), first_reading(e)
        ('[2] (pole angle)', '[2]')
    """
    index = episode.first_alarm_readings[0][0]
    return reading_label(index, names[index] if index < len(names) else "")


def monitor_row(task: str, method: str, variant: str, episodes: int, early: int, failed: int | None,
                before_failure: int | None, delays: Sequence[int], leads: Sequence[int] = (),
                causes: Mapping[str, int] | None = None, never_shifted: int = 0,
                early_starts: Iterable[str] = (), readings: Mapping[str, int] | None = None) -> MonitorMetrics:
    """The :class:`MonitorMetrics` of shifted episodes from their counts, the delays of the
    alarmed ones and the leads of those alarmed before their failure (medians and the delays' 90th
    percentile computed here, for one variant or several pooled); ``failed`` and
    ``before_failure`` are ``None`` where no failure is defined (:func:`failure_known`);
    ``causes``: how many first alarms each cause raised; ``never_shifted``: how many of the
    ``episodes`` ended before their onset; ``early_starts``: the ID starts of the early alarms
    (kept each once); ``readings``: how many first alarms named each reading first."""
    return MonitorMetrics(task, method, variant, episodes, early=early, alarmed=len(delays), failed=failed,
                          before_failure=before_failure,
                          delay_median=float(np.median(delays)) if len(delays) else None,
                          delay_p90=float(np.quantile(delays, 0.9)) if len(delays) else None, delays=tuple(delays),
                          lead_median=float(np.median(leads)) if len(leads) else None, leads=tuple(leads),
                          causes=dict(Counter(causes or {}).most_common()), never_shifted=never_shifted,
                          early_starts=tuple(sorted(set(early_starts))),
                          readings=dict(Counter(readings or {}).most_common()))
