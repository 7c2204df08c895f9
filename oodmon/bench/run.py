"""``run_bench``: prepare every (method, trial), run the cells not yet logged, replay the logs."""

from __future__ import annotations

import os
from pathlib import Path

from oodmon import seeds
from oodmon.bench.cache import (Sb3Models, _cell_log, _log_is_complete, _monitored, _prepare_trial,
                                _refuse_to_train_for_hours)
from oodmon.bench.cells import _execute
from oodmon.bench.config import ONSETS, PAPER_METHOD, BenchConfig, BenchResult, Row, paper_label
from oodmon.monitor.alarms import check_window
from oodmon.paper import paper_auc_per_trial
from oodmon.progress import Progress

def run_bench(config: BenchConfig, *, on_progress: Progress | None = None) -> BenchResult:
    """Run (or resume) the bench; return its rows. ``on_progress(stage, done, total)`` reports."""
    from oodmon.replay import compute_metrics, read_log

    report = on_progress or (lambda stage, done, total: None)
    trials = [(m, t) for m in config.methods for t in range(config.trials)]
    check_window(config.window)
    for method, trial in trials:  # before minutes of work on the others
        _refuse_to_train_for_hours(config, method, trial)
    prepared: dict[tuple[str, int], tuple[Path | Sb3Models, Path, list[str], Path | None]] = {}
    for index, (method, trial) in enumerate(trials):
        report("models, detectors, thresholds and failing variants of trials", index, len(trials))
        prepared[(method, trial)] = _prepare_trial(config, method, trial, report)
    report("models, detectors, thresholds and failing variants of trials", len(trials), len(trials))

    cells = []
    for (method, trial), (model, threshold, failing, _) in prepared.items():
        cells.append((method, trial, config.task, config.id_episodes, seeds.BENCH_ID))
        cells += [(method, trial, spec, config.episodes, seeds.BENCH_SHIFTED) for spec in _monitored(config, failing)]
    jobs = []
    for method, trial, spec, episodes, seed in cells:
        log = _cell_log(config, method, trial, spec)
        if not _log_is_complete(log, episodes):
            model, threshold, _, detectors = prepared[(method, trial)]
            jobs.append((config.task, model if isinstance(model, Sb3Models) else str(model), str(threshold), spec, episodes, seed, str(log),
                         None if detectors is None else str(detectors), config.obs_noise,
                         ONSETS[config.task] if config.protocol == "monitor" else None))
    done = len(cells) - len(jobs)
    report("monitored cells", done, len(cells))
    workers = config.workers or os.cpu_count() or 1
    for _ in _execute(jobs, config, workers):
        done += 1
        report("monitored cells", done, len(cells))

    rows: dict[tuple[str, str, int], dict[int, float]] = {}
    detection: dict[str, dict[str, float | None]] = {}
    every_log = []
    for (method, trial), (_, _, failing, _) in prepared.items():
        logs = [read_log(_cell_log(config, method, trial, spec)) for spec in [config.task, *_monitored(config, failing)]]
        every_log += logs
        for order, detector in enumerate(config.detectors):
            for m in compute_metrics(logs, detector):
                if m.auroc is not None:
                    rows.setdefault((method, m.variant, order), {})[trial] = m.auroc
                if detector == config.alarm_detector:
                    key = f"{method}/trial{trial}/{m.variant}"
                    detection[key] = {"false_alarm_rate": m.false_alarm_rate, "detection_rate": m.detection_rate,
                                      "delay_mean": m.delay_mean}
    paper = paper_auc_per_trial().get(config.task, {})
    result_rows = []
    for (method, spec, order), aurocs in sorted(rows.items()):
        label = paper_label(config.task, method, spec)
        result_rows.append(Row(method, spec, aurocs, paper[PAPER_METHOD[method]][label] if label else None,
                               config.detectors[order]))
    failing = {m: {t: prepared[(m, t)][2] for t in range(config.trials)} for m in config.methods}
    alarms = []
    if config.protocol == "monitor":
        from oodmon.replay import compute_monitor_metrics

        alarms = compute_monitor_metrics(every_log)
    return BenchResult(result_rows, failing, detection, alarms)
