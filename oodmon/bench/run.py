"""``run_bench``: prepare every (method, trial), run the cells not yet logged, replay the logs."""

from __future__ import annotations

from concurrent.futures import FIRST_COMPLETED, wait
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from oodmon import seeds
from oodmon.bench.cache import (Source, _cell_log, _ensure_model, _ensure_model_dir_current, _id_return,
                                _log_is_complete, _monitored, _prepare_trial, _refuse_detectors_it_cannot_have,
                                _refuse_to_train_for_hours, _weights_sha256)
from oodmon.bench.cells import Relay, _execute, check_ray_address, on_ray, ray_for, stopping_pool
from oodmon.bench.config import PAPER_METHOD, BenchConfig, BenchResult, Row, paper_label
from oodmon.paper import paper_auc_per_trial
from oodmon.progress import Progress
from oodmon.side_by_side import usable_cores, worker_context
from oodmon.threads import limit_threads, set_threads

def _train_missing_models(config: BenchConfig, trials: list[tuple[str, int]], workers: int, report: Progress) -> None:
    """Train the trials' models that are not cached yet, ``workers`` at a time in processes of their
    own (each training on OODMON_TORCH_THREADS threads, one where it is not set: ``train`` reads it): the
    long part of a five-trial bench, on every core; with ``executor="ray"``, as tasks on the Ray
    cluster (the cells' cluster). Each training checkpoints and resumes (``oodmon.agents.train``)."""
    if config.users_own:
        return
    # (a cached model, or a begun training, of another recipe is set aside first)
    missing = [(m, t) for m, t in trials if not (_ensure_model_dir_current(config, m, t) / "model.json").exists()]
    if not missing:
        return
    stage = "trained trial models"
    report(stage, 0, len(missing))
    for done, _ in enumerate(_per_trial(_ensure_model, missing, config, workers, report), 1):
        report(stage, done, len(missing))


def _prepare_trials(config: BenchConfig, trials: list[tuple[str, int]], workers: int,
                    report: Progress) -> dict[tuple[str, int], tuple[Source, Path, list[str], Path | None]]:
    """Each trial's model, fitted detectors, threshold and failing variants (:func:`_prepare_trial`,
    cached), the trials side by side as their trainings are (each seeded by itself: the same as
    one after the other, which they were before 2026-11-30). One trial (``--trials 1``, one method)
    is prepared here, its episodes side by side where its agent draws nothing (:func:`_prepare_trial`)."""
    stage = "models, detectors, thresholds and failing variants of trials"
    report(stage, 0, len(trials))
    if len(trials) == 1 and config.executor != "ray":
        (method, trial), = trials
        prepared_one = _prepare_trial(config, method, trial, report, workers)
        report(stage, 1, 1)
        return {(method, trial): prepared_one}
    prepared = {}
    for key, trial_parts in _per_trial(_prepare_keyed, trials, config, workers, report):
        prepared[key] = trial_parts
        report(stage, len(prepared), len(trials))
    return {key: prepared[key] for key in trials}  # in the trials' order


def _per_trial(function: Callable[..., Any], trials: list[tuple[str, int]], config: BenchConfig, workers: int,
               report: Progress) -> Iterator[Any]:
    """``function(config, method, trial, on_progress)`` for each trial, its results as they come:
    as Ray tasks of one CPU (``executor="ray"``), in ``workers`` processes of the bench's own, or
    here one after the other (one worker, or one trial); the workers' progress reaches ``report``."""
    jobs = [(function, config, method, trial) for method, trial in trials]
    if config.executor == "ray":  # the cluster's, even one: the machine of this command may be the least of them
        yield from on_ray(_in_worker, jobs, config, workers, report)
        return
    if workers <= 1 or len(jobs) == 1:
        for method, trial in trials:
            yield function(config, method, trial, report)
        return
    progress = worker_context().SimpleQueue()  # each worker's own, relayed here as it comes
    with stopping_pool(min(workers, len(jobs)), progress) as pool:
        pending = {pool.submit(_in_worker, *job, Relay()) for job in jobs}
        while pending:
            finished, pending = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
            while not progress.empty():
                report(*progress.get())
            for future in finished:
                yield future.result()


def _in_worker(function: Callable[..., Any], config: BenchConfig, method: str, trial: int, on_progress: Progress) -> Any:
    """``function(config, method, trial, on_progress)`` in a worker process or a Ray task: torch and
    numpy's BLAS on one thread in a worker process, one of several side by side (as the cells; a
    process forked from one whose torch had run on two threads can hang in its first parallel
    region: ``oodmon.side_by_side``), and on ``OODMON_TORCH_THREADS`` threads in a Ray task,
    one where it is not set (a Ray worker of another machine does not have this command's setting).
    A training (``oodmon.agents.train``) sets its threads from ``OODMON_TORCH_THREADS`` again itself."""
    if config.executor == "ray":
        limit_threads()
    else:
        set_threads(1)
    return function(config, method, trial, on_progress)


def _prepare_keyed(config: BenchConfig, method: str, trial: int, on_progress: Progress
                   ) -> tuple[tuple[str, int], tuple[Source, Path, list[str], Path | None]]:
    """:func:`_prepare_trial`'s parts of one trial, with its key (the workers' results come in any order)."""
    return (method, trial), _prepare_trial(config, method, trial, on_progress)


def run_bench(config: BenchConfig, *, on_progress: Progress | None = None) -> BenchResult:
    """Run (or resume) the bench; return its rows. ``on_progress(stage, done, total)`` reports."""
    from oodmon.replay import compute_metrics, failed_episodes, read_log

    report = on_progress or (lambda stage, done, total: None)
    trials = [(m, t) for m in config.methods for t in range(config.trials)]
    for method, trial in trials:  # before minutes of work on the others
        _refuse_to_train_for_hours(config, method, trial)
    _refuse_detectors_it_cannot_have(config)  # before the trainings, too
    check_ray_address(config)  # before hours of training, too
    workers = config.workers or usable_cores()  # (the cores it may run on: a container's, not its host's)
    with ray_for(config, workers):  # a Ray cluster started (or joined) once for every stage
        _train_missing_models(config, trials, workers, report)
        prepared = _prepare_trials(config, trials, workers, report)

        cells = []
        for (method, trial), (_, _, failing, _) in prepared.items():
            cells.append((method, trial, config.task, config.id_episodes, seeds.BENCH_ID))
            cells += [(method, trial, spec, config.episodes, seeds.BENCH_SHIFTED) for spec in _monitored(config, failing)]
        jobs = []
        for method, trial, spec, episodes, seed in cells:
            log = _cell_log(config, method, trial, spec)
            if not _log_is_complete(log, episodes):
                model, threshold, _, detectors = prepared[(method, trial)]
                jobs.append((config.task, str(model) if isinstance(model, Path) else model, str(threshold), spec, episodes,
                             seed, str(log), None if detectors is None else str(detectors), config.obs_noise,
                             config.onset_range() if config.protocol == "monitor" else None, config.samples,
                             config.masks))
        done = len(cells) - len(jobs)
        report("monitored cells", done, len(cells))
        for _ in _execute(jobs, config, workers):
            done += 1
            report("monitored cells", done, len(cells))

    rows: dict[tuple[str, str, int], dict[str, dict[int, float]]] = {}
    detection: dict[str, dict[str, float | None]] = {}
    every_log = []
    for (method, trial), (_, _, failing, _) in prepared.items():
        logs = [read_log(_cell_log(config, method, trial, spec)) for spec in [config.task, *_monitored(config, failing)]]
        every_log += logs
        # CartPole's failures are the env's own at any onset; Pendulum's need a swung-up pole at the
        # onset, which the paper's protocol (onset 0) has not.
        failed = failed_episodes(logs) if config.task == "cartpole" else {}
        for order, detector in enumerate(config.detectors):
            for m in compute_metrics(logs, detector):
                if m.auroc is not None:
                    per_trial = rows.setdefault((method, m.variant, order), {"auroc": {}, "aupr": {}, "fpr95": {}})
                    per_trial["auroc"][trial], per_trial["aupr"][trial] = m.auroc, m.aupr
                    per_trial["fpr95"][trial] = m.fpr_at_95_tpr
                if detector == config.alarm_detector:
                    key = f"{method}/trial{trial}/{m.variant}"
                    detection[key] = {"false_alarm_rate": m.false_alarm_rate, "detection_rate": m.detection_rate,
                                      "delay_mean": m.delay_mean, "episodes": m.episodes, "failed": failed.get(m.variant)}
    paper = paper_auc_per_trial().get(config.task, {})
    result_rows = []
    for (method, spec, order), per_trial in sorted(rows.items()):
        label = paper_label(config.task, method, spec)
        result_rows.append(Row(method, spec, per_trial["auroc"], paper[PAPER_METHOD[method]][label] if label else None,
                               config.detectors[order], auprs=per_trial["aupr"], fprs=per_trial["fpr95"]))
    failing = {m: {t: prepared[(m, t)][2] for t in range(config.trials)} for m in config.methods}
    id_returns = {m: {t: _id_return(prepared[(m, t)][0]) for t in range(config.trials)} for m in config.methods}
    weights = {m: {t: _weights_sha256(prepared[(m, t)][0]) for t in range(config.trials)} for m in config.methods}
    fitted = {m: {t: _fingerprints(prepared[(m, t)][3]) for t in range(config.trials)} for m in config.methods}
    alarms = []
    if config.protocol == "monitor":
        from oodmon.replay import compute_monitor_metrics

        alarms = compute_monitor_metrics(every_log, failure=config.failure)
    return BenchResult(result_rows, failing, detection, alarms, id_returns, weights, fitted)


def _fingerprints(detectors: Path | None) -> dict[str, str]:
    """The fingerprints of a trial's fitted detectors, by detector (none: no learned detector)."""
    from oodmon.monitor.detectors import DetectorSet

    return {} if detectors is None else DetectorSet.load(detectors).fingerprints()
