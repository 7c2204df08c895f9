"""``oodmon bench``: the paper's protocol, run under the monitor and scored by replaying its logs.

For one task, each method and each trial:

1. a model: trial 0 is the shipped agent (if the zoo has one); other trials are trained with their
   seed (cached, resumable);
2. the variants where it fails (the paper's step 3), from ``evaluate_variants`` on a few episodes;
3. a threshold calibrated on held-out ID episodes (so that the logs carry alarms too);
4. cells: ID episodes, and episodes of every failing variant (shifted from step 0, as in the
   paper), each cell a monitored run writing one MCAP log;
5. the scores, by replaying those logs: per-step AUROC per (method, trial, variant).

With ``protocol="monitor"`` (the monitor's own benchmark) step 4 changes: each shifted episode
starts in the ID world and shifts at a random onset (uniform in the task's :data:`ONSETS`, drawn
per episode from its seed), and there are at least as many ID episodes as a false-alarm rate
needs (200 by default in the CLI). Replay then gives, per variant, the share of episodes alarmed
before they failed and the delays from the onset (``oodmon.replay.compute_monitor_metrics``), and
the false-alarm rate with its interval. Thresholds, fitted detectors and failing variants are
shared with the paper's protocol; the logs live apart (``.../monitor/``).

The report puts, per variant, our AUROC mean and std over trials beside the paper's, and the
best AUROC per method beside the paper's best. A cell whose log is complete is not run again,
so an interrupted bench resumes; cells run in ``workers`` processes, or as Ray tasks on a Ray
cluster (``executor="ray"``, ``address``; Ray is the optional extra ``oodmon[ray]``).

Your own stable-baselines3 models (``sb3=(paths...)``, ``env_id``) are benched as the one method
``sb3`` with one trial: nothing is trained, and the paper has no figures for them.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from oodmon import seeds
from oodmon.agents import evaluate_variants, load_agent, train, zoo_dir, zoo_names
from oodmon.agents.recipes import recipe_for
from oodmon.envs.grid import Variant, parse_variant, select_variants
from oodmon.errors import ConfigError
from oodmon.monitor.alarms import check_window
from oodmon.paper import paper_auc_per_trial
from oodmon.hashing import file_sha256
from oodmon.outputs import safe_filename

if TYPE_CHECKING:
    from oodmon.replay import MonitorMetrics

__all__ = ["ONSETS", "PAPER_METHOD", "PROTOCOLS", "BenchConfig", "BenchResult", "alarms_per_variant", "best_per_method", "paper_label",
           "paper_only_variants", "run_bench"]

#: The bench's protocols: the paper's (shifted from step 0, per-step AUROC) and the monitor's own.
PROTOCOLS = ("paper", "monitor")
#: Per task, the range [low, high) a shifted episode's onset is drawn from under the monitor's
#: protocol: after the ID start-up (Pendulum's agents have swung the pole up by step 100 of 200),
#: early enough that the rest of the episode can show the failure. Pong: decisions into the game.
ONSETS = {"cartpole": (20, 200), "pendulum": (100, 150), "pong": (100, 1000)}

#: Our method names as the paper's tables name them.
PAPER_METHOD = {"dropout": "mc_dropout", "dropconnect": "mc_dropconnect", "ensemble": "ensemble"}


@dataclass(frozen=True)
class BenchConfig:
    """What to run. ``variants`` is ``"paper"`` or a list of spec strings."""

    task: str
    methods: tuple[str, ...] = ("dropout", "dropconnect", "ensemble")
    trials: int = 5
    variants: str | tuple[str, ...] = "paper"
    episodes: int = 5
    id_episodes: int = 10
    eval_episodes: int = 3
    calibration_episodes: int = 45  # the fewest that bound the rate at far 0.05 with confidence 0.9
    far: float = 0.05
    confidence: float | None = 0.9  # see oodmon.monitor.threshold; None: the rate bounded on average only
    score: str = "chosen_std"  # the paper's; pre_squash_std detects far better on Pendulum
    window: int = 1  # the alarm rule's averaging window (alarms only; the AUROCs score single steps)
    out: str = "runs/bench"
    workers: int = 0  # 0: all cores
    train_steps: int | None = None  # override the recipes' steps for trials > 0 (smoke tests)
    executor: str = "local"  # "local" (worker processes) or "ray" (tasks on a Ray cluster)
    address: str | None = None  # the Ray cluster; None starts a local one
    bind: str = "127.0.0.1"  # the address a local Ray cluster listens on: loopback unless opened on purpose
    detectors: tuple[str, ...] = ("spread",)  # whose per-step AUROC is reported; learned ones are fitted per trial
    alarm_detector: str = "spread"  # the detector the monitor's alarm reads
    obs_noise: float = 0.0  # sensor noise in every monitored env (fit, calibration, cells), see envs
    fit_episodes: int = 0  # ID episodes the learned detectors are fitted on (0: the task's default)
    protocol: str = "paper"  # or "monitor": random onsets, alarms before failure (see the module docstring)
    rule: str = "consecutive"  # the alarm rule: consecutive, cusum or martingale (oodmon.monitor.sequential)
    consecutive: int | None = None  # m of the consecutive rule (None: 3 for spread, 1 for a learned detector)
    all_variants: bool = False  # monitor every variant, not only those the agent fails on (Pong: no failure to wait for)
    sb3: tuple[str, ...] = ()  # your own SB3 model files instead of oodmon agents (the method "sb3", one trial)
    env_id: str | None = None  # the gymnasium env id the sb3 models act in
    mean: bool = False  # deploy the sb3 ensemble's mean decision, not the first model's

    def __post_init__(self) -> None:
        from oodmon.monitor.threshold import DETECTOR_NAMES

        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"protocol={self.protocol!r} is not allowed; use {' or '.join(PROTOCOLS)}")
        from oodmon.monitor.sequential import RULES

        if self.rule not in RULES:
            raise ConfigError(f"rule={self.rule!r} is not allowed; choose one of {', '.join(RULES)}")

        for name in (*self.detectors, self.alarm_detector):
            if name not in DETECTOR_NAMES:
                raise ConfigError(f"unknown detector {name!r}; choose from {', '.join(DETECTOR_NAMES)}")
        if self.alarm_detector not in self.detectors:
            raise ConfigError(f"the alarm reads the {self.alarm_detector} detector: add it to the detectors")
        if self.sb3:
            if self.env_id is None:
                raise ConfigError("sb3 models need env_id: the gymnasium env id they act in (e.g. CartPole-v1)")
            if self.methods != ("sb3",) or self.trials != 1:
                raise ConfigError("sb3 models are benched as one method ('sb3') and one trial: nothing is trained")
        elif "spread" not in self.detectors:
            raise ConfigError("the bench's agents all have samples: keep spread among the detectors")
        from oodmon.monitor.threshold import conformal_rank

        conformal_rank(self.calibration_episodes, self.far, self.confidence)  # enough episodes, before any work

    @property
    def m(self) -> int:
        """m of the consecutive rule the thresholds are calibrated for."""
        from oodmon.monitor.alarms import default_consecutive

        return default_consecutive(self.alarm_detector) if self.consecutive is None else self.consecutive

    @property
    def learned(self) -> tuple[str, ...]:
        """The detectors to fit per trial (``combined`` brings its members)."""
        names = [d for d in self.detectors if d != "spread"]
        if "combined" in names and self.task == "pong":
            names = [d for d in names if d != "dynamics"]
        return tuple(names)

    def cache_key(self) -> str:
        """What the cached thresholds and logs of a (method, trial) depend on beyond the weights:
        score, alarm rule, target rate and confidence, calibration episodes, detectors and sensor noise."""
        parts = [self.score, f"far{self.far:g}", f"n{self.calibration_episodes}",
                 "marginal" if self.confidence is None else f"conf{self.confidence:g}"]
        if self.window != 1:
            parts.append(f"w{self.window}")
        if self.m != 3:
            parts.append(f"m{self.m}")
        if self.rule != "consecutive":
            parts.append(self.rule)
        if self.learned:
            parts.append("+".join(self.detectors) + f"-alarm-{self.alarm_detector}")
        if self.obs_noise:
            parts.append(f"noise{self.obs_noise:g}")
        return "-".join(parts)

    def variant_list(self) -> list[Variant]:
        return select_variants(self.task, self.variants, shifted_only=True)


@dataclass(frozen=True)
class Row:
    """One (method, variant, detector): our AUROC per trial beside the paper's."""

    method: str
    variant: str
    aurocs: dict[int, float]
    paper: list[float] | None
    detector: str = "spread"

    @property
    def mean(self) -> float:
        return float(np.mean(list(self.aurocs.values())))

    @property
    def std(self) -> float:
        return float(np.std(list(self.aurocs.values())))


@dataclass(frozen=True)
class BenchResult:
    rows: list[Row]
    failing: dict[str, dict[int, list[str]]]
    detection: dict[str, dict[str, float | None]]
    #: The monitor's protocol only: the alarm's figures per (method, variant), trials pooled.
    alarms: list[MonitorMetrics] = field(default_factory=list)

    def to_json(self) -> dict:
        data = {
            "rows": [asdict(r) | {"mean": r.mean, "std": r.std} for r in self.rows],
            "failing": self.failing,
            "monitor": self.detection,
        }
        if self.alarms:
            from oodmon.replay import monitor_summary

            data["alarms"] = [m.to_dict() for m in [*self.alarms, *monitor_summary(self.alarms)]]
        return data


def paper_label(task: str, method: str, spec: str) -> str | None:
    """The label of ``spec`` in the paper's per-trial table for ``method``, if it has one.

    Example:
        >>> paper_label("cartpole", "ensemble", "cartpole:length=2.0")
        'length=2.0'
        >>> paper_label("cartpole", "dropconnect", "cartpole:masscart=9.0")
        'masscart=9.0 (text says pole mass 9)'
    """
    if method not in PAPER_METHOD:  # your own SB3 models: the paper has no figures for them
        return None
    table = paper_auc_per_trial().get(task, {}).get(PAPER_METHOD[method], {})
    variant = parse_variant(spec)
    if variant.task == "pong":
        key = f"{variant.corruption}@{variant.severity}"
    else:
        name, value = variant.params[0]
        key = f"{name}={value!r}"
    for label in table:
        if label == key or label.startswith(key + " "):
            return label
    return None


@dataclass(frozen=True)
class Sb3Models:
    """A user's SB3 model files as the bench hands them to its workers, which load them there."""

    paths: tuple[str, ...]
    env_id: str
    mean: bool = False

    def __str__(self) -> str:
        return ", ".join(self.paths)


def _bench_agent(source: str | Sb3Models, task: str, seed: int):
    """The agent of a model directory or of SB3 model files, its MC sampling seeded."""
    if isinstance(source, Sb3Models):
        from oodmon.agents.sb3 import load_sb3

        return load_sb3(source.paths, source.env_id, mean=source.mean, seed=seed)
    return load_agent(source, task=task, seed=seed)


def _weights_sha256(source: Path | Sb3Models) -> str:
    """What a (method, trial)'s cached results were made with: the weights' sha256, or the SB3 files'."""
    if isinstance(source, Sb3Models):
        import hashlib

        return hashlib.sha256("\n".join(file_sha256(p) for p in source.paths).encode()).hexdigest()
    return file_sha256(source / "model.safetensors")


def _model_dir(config: BenchConfig, method: str, trial: int) -> Path:
    """Trial 0 is the shipped agent where the zoo has one; every other model is trained into the
    bench's cache (never into the installed package)."""
    shipped = zoo_dir() / f"{config.task}-{method}"
    if trial == 0 and (shipped / "model.json").exists():
        return shipped
    return Path(config.out) / "models" / f"{config.task}-{method}-trial{trial}"


def _refuse_to_train_for_hours(config: BenchConfig, method: str, trial: int) -> None:
    """A missing Pong model takes hours to train on a CPU: never start that as a side effect of a
    bench; say how to train it instead."""
    if config.sb3:
        return
    path = _model_dir(config, method, trial)
    if (path / "model.json").exists() or not recipe_for(config.task, method).cnn or config.train_steps is not None:
        return
    raise ConfigError(
        f"no {config.task} {method} model for trial {trial} (looked in {path}); a {config.task} agent trains for "
        f"hours, so bench does not train one itself: train it with `oodmon train --task {config.task} --method "
        f"{method} --seed {trial} --out {path}`, or bench fewer trials or other methods (the zoo has: "
        f"{', '.join(n for n in zoo_names() if n.startswith(config.task)) or 'none'})"
    )


def _ensure_model(config: BenchConfig, method: str, trial: int) -> Path | Sb3Models:
    if config.sb3:
        return Sb3Models(tuple(str(Path(p).resolve()) for p in config.sb3), config.env_id, config.mean)
    path = _model_dir(config, method, trial)
    if not (path / "model.json").exists():
        _refuse_to_train_for_hours(config, method, trial)
        train(config.task, method, path, seed=trial, total_steps=config.train_steps)
    return path


def _trial_dir(config: BenchConfig, method: str, trial: int) -> Path:
    """A (method, trial)'s folder: its threshold, fitted detectors, failing variants and logs."""
    return Path(config.out) / "logs" / f"{config.task}-{config.cache_key()}" / method / f"trial{trial}"


def _cell_log(config: BenchConfig, method: str, trial: int, name: str) -> Path:
    safe = safe_filename(name)
    folder = _trial_dir(config, method, trial)
    return (folder / "monitor" if config.protocol == "monitor" else folder) / f"{safe}.mcap"


def _log_is_complete(path: Path, episodes: int) -> bool:
    from oodmon.replay import read_log

    if not path.exists():
        return False
    try:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            log = read_log(path)
    except Exception:  # noqa: BLE001  (an unreadable log is simply run again)
        return False
    return log.complete and len(log.episodes) == episodes


def episode_onset(onsets: tuple[int, int], seed: int) -> int:
    """The onset of the shifted episode played with ``seed`` under the monitor's protocol: uniform
    in ``[low, high)``, drawn from the seed alone (the same episode, the same onset).

    Example:
        >>> episode_onset((20, 200), 500_000) == episode_onset((20, 200), 500_000)
        True
    """
    return int(np.random.default_rng([seed, 0x0175E7]).integers(*onsets))


def _run_cell(task: str, model: str | Sb3Models, threshold: str, spec: str, episodes: int, seed: int, log: str,
              detectors: str | None = None, obs_noise: float = 0.0, onsets: tuple[int, int] | None = None) -> str:
    """One cell, in a worker process: monitored episodes of one variant into one MCAP log.
    ``onsets``: each shifted episode shifts at a random step in this range (the monitor's protocol)."""
    import torch

    from oodmon.monitor import McapSink, Monitor, Threshold
    from oodmon.monitor.detectors import DetectorSet

    torch.set_num_threads(1)
    agent = _bench_agent(model, task, seed)  # seeded MC sampling: the same cell, the same log
    variant = parse_variant(spec)
    env = variant.make(obs_noise=obs_noise) if obs_noise else variant.make()
    temporary = Path(log).with_suffix(".part")
    temporary.parent.mkdir(parents=True, exist_ok=True)
    fitted = DetectorSet.load(detectors) if detectors else None
    with Monitor(agent, Threshold.load(threshold), detectors=fitted, sinks=[McapSink(temporary)],
                 strict=True) as monitor:
        for episode in range(episodes):
            options = None if onsets is None or variant.is_id else {"onset_step": episode_onset(onsets, seed + episode)}
            monitor.run_episode(env, seed=seed + episode, variant=variant.spec, options=options)
    env.close()
    os.replace(temporary, log)  # a complete log appears whole, or not at all
    return log


def _execute(jobs: list[tuple], config: BenchConfig, workers: int) -> Iterator[str]:
    """Run the cells; yield each finished cell's log path as it completes."""
    if not jobs:
        return
    if config.executor == "local":
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for future in as_completed([pool.submit(_run_cell, *job) for job in jobs]):
                yield future.result()
        return
    if config.executor != "ray":
        raise ConfigError(f"executor={config.executor!r} is not allowed; use 'local' or 'ray'")
    started = _start_ray(config, workers)
    import ray

    try:
        remote = ray.remote(num_cpus=1)(_run_cell)
        pending = [remote.remote(*job) for job in jobs]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        if started:
            ray.shutdown()


def _start_ray(config: BenchConfig, workers: int) -> bool:
    """Connect to ``config.address``, or start a local Ray cluster whose servers listen on
    ``config.bind`` only (loopback by default; Ray would otherwise listen on every interface).
    True where this call started Ray (and so must shut it down)."""
    import os

    loopback = config.address is None and config.bind in ("127.0.0.1", "localhost")
    if loopback:
        # Ray turns a loopback node address into the machine's external one unless it runs as a
        # single-machine cluster; this setting (read when ray is imported, and by its workers)
        # keeps every server of the local cluster on 127.0.0.1.
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    try:
        import ray
        import ray._private.ray_constants as ray_constants
    except ImportError:
        raise ConfigError("--executor ray needs Ray: pip install 'oodmon[ray]'") from None
    if ray.is_initialized():
        return False
    if loopback:
        ray_constants.ENABLE_RAY_CLUSTER = False  # where ray was imported before the setting
    options = {} if config.address or loopback else {"_node_ip_address": config.bind}
    ray.init(address=config.address, num_cpus=None if config.address else workers, include_dashboard=False,
             logging_level="ERROR", log_to_driver=False, **options)
    return True


def _set_aside_if_made_by_other_weights(out: Path, folder: Path, model: Path | Sb3Models) -> None:
    """Keep a (method, trial) folder's cached threshold, failing variants and logs only while they
    belong to the weights in ``model``: a new zoo agent or a retrained model moves the old results
    to ``<out>/set-aside/weights-<old hash>/`` (kept, not deleted, and out of the logs a replay of
    ``<out>/logs`` reads) and the trial is run again."""
    weights = _weights_sha256(model)[:16]
    stamp = folder / "weights.sha256"
    made_by = stamp.read_text().strip() if stamp.exists() else "unknown"
    if folder.exists() and any(folder.iterdir()) and made_by != weights:
        aside = out / "set-aside" / f"weights-{made_by}" / folder.relative_to(out)
        if aside.exists():
            raise ConfigError(f"{folder} holds results of other weights than {model} and {aside} exists; "
                              f"move one of them away and run the bench again")
        print(f"bench: {folder} was made with other weights than {model}; moved to {aside}, running again",
              file=sys.stderr)
        aside.parent.mkdir(parents=True, exist_ok=True)
        os.replace(folder, aside)
    folder.mkdir(parents=True, exist_ok=True)
    stamp.write_text(weights + "\n")


def _prepare_trial(config: BenchConfig, method: str, trial: int,
                   report: Callable[[str, int, int], None]) -> tuple[Path | Sb3Models, Path, list[str], Path | None]:
    """Model, threshold and failing variants of one (method, trial); cached in its folder.
    ``report(stage, done, total)`` counts the episodes of calibration and evaluation."""
    from oodmon.monitor import calibrate_agent

    model = _ensure_model(config, method, trial)
    folder = _trial_dir(config, method, trial)
    _set_aside_if_made_by_other_weights(Path(config.out), folder, model)
    threshold_path, failing_path = folder / f"threshold-{config.cache_key()}.json", folder / "failing.json"
    # Seeded MC sampling (as `oodmon calibrate --seed`): the same bench fits the same detectors and
    # calibrates the same threshold; unseeded, an MC agent's threshold varied from run to run.
    agent = _bench_agent(model, config.task, seeds.CALIBRATION)
    if "spread" in config.detectors and agent.estimator is None:
        raise ConfigError(f"{method} has no samples of its own (one model, or a kind oodmon does not sample): "
                          f"drop spread from the detectors")
    detectors_path = _fit_trial_detectors(config, agent, folder, f"{method} trial {trial}", report)
    if not threshold_path.exists():
        from oodmon.monitor.detectors import DetectorSet

        stage = f"{method} trial {trial}: calibration episodes"
        calibrate_agent(agent, config.calibration_episodes, config.far, score=config.score, window=config.window,
                        detectors=DetectorSet.load(detectors_path) if detectors_path else None,
                        detector=config.alarm_detector, obs_noise=config.obs_noise, confidence=config.confidence,
                        rule=config.rule, consecutive=config.m,
                        on_episode=lambda episode: report(stage, episode + 1, config.calibration_episodes)).save(threshold_path)
    variants = config.variant_list()
    if failing_path.exists() and json.loads(failing_path.read_text()).get("variants") == [v.spec for v in variants]:
        failing = json.loads(failing_path.read_text())["failing"]
    else:
        stage, total, done = f"{method} trial {trial}: evaluation episodes", (len(variants) + 1) * config.eval_episodes, [0]

        def count(spec: str, episode_return: float) -> None:
            done[0] += 1
            report(stage, done[0], total)
        _, results = evaluate_variants(agent.act, config.task, variants, config.eval_episodes, on_episode=count)
        failing = [r.spec for r in results if r.fails]
        failing_path.write_text(json.dumps({"variants": [v.spec for v in variants], "failing": failing,
                                            "returns": {r.spec: r.mean for r in results}}, indent=1))
    return model, threshold_path, failing, detectors_path


#: Fitting episodes per task: Pong's games are long, its detectors fit on their first 1,000 steps.
_FIT = {"pong": {"episodes": 6, "max_steps": 1000}}


def _fit_trial_detectors(config: BenchConfig, agent, folder: Path, label: str,
                         report: Callable[[str, int, int], None]) -> Path | None:
    """The (method, trial)'s fitted detectors, fitted once into its folder (cached beside the
    threshold, and set aside with it when the weights change)."""
    if not config.learned:
        return None
    from oodmon.monitor.detectors import DEFAULT_FIT_EPISODES, fit_agent_detectors

    path = folder / f"detectors-{config.cache_key()}"
    if not (path / "detectors.json").exists():
        fit = dict(_FIT.get(config.task, {"episodes": DEFAULT_FIT_EPISODES, "max_steps": None}))
        if config.fit_episodes:
            fit["episodes"] = config.fit_episodes
        stage = f"{label}: detector fitting episodes"
        fit_agent_detectors(agent, detectors=config.learned, score=config.score, obs_noise=config.obs_noise,
                            on_episode=lambda episode: report(stage, episode + 1, fit["episodes"]), **fit).save(path)
    return path


def _monitored(config: BenchConfig, failing: list[str]) -> list[str]:
    """The shifted variants a (method, trial) is monitored on: those it fails on, or all of them."""
    return [v.spec for v in config.variant_list()] if config.all_variants else failing


def run_bench(config: BenchConfig, *, on_progress: Callable[[str, int, int], None] | None = None) -> BenchResult:
    """Run (or resume) the bench; return its rows. ``on_progress(stage, done, total)`` reports."""
    from oodmon.replay import compute_metrics, read_log

    report = on_progress or (lambda stage, done, total: None)
    trials = [(m, t) for m in config.methods for t in range(config.trials)]
    check_window(config.window)
    for method, trial in trials:  # before minutes of work on the others
        _refuse_to_train_for_hours(config, method, trial)
    prepared: dict[tuple[str, int], tuple[Path | Sb3Models, Path, list[str], Path | None]] = {}
    for index, (method, trial) in enumerate(trials):
        report("models, thresholds, failing variants", index, len(trials))
        prepared[(method, trial)] = _prepare_trial(config, method, trial, report)
    report("models, thresholds, failing variants", len(trials), len(trials))

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


def best_per_method(result: BenchResult, task: str, top: int = 3,
                    detector: str = "spread") -> list[tuple[str, str, float, float | None]]:
    """Per method, the variants with the best single-trial AUROC of ``detector`` (the paper's main
    tables: the spread), with the paper's best trial for the same variant where it reports one."""
    best = []
    for method in sorted({r.method for r in result.rows}):
        rows = sorted((r for r in result.rows if r.method == method and r.detector == detector),
                      key=lambda r: -max(r.aurocs.values()))
        for row in rows[:top]:
            best.append((method, row.variant, max(row.aurocs.values()), max(row.paper) if row.paper else None))
    return best


def paper_only_variants(result: BenchResult, task: str, methods: Iterable[str],
                        ran: Iterable[str] | None = None) -> list[tuple[str, str, float]]:
    """Variants the paper reports for a method that our agents did not fail on (so no AUROC).

    ``ran`` (spec strings) limits this to the variants the bench ran; a variant left out of the
    run is not "not failed"."""
    ours = {(r.method, r.variant) for r in result.rows}
    ran_specs = None if ran is None else list(ran)
    missing = []
    table = paper_auc_per_trial().get(task, {})
    for method in methods:
        for label, values in table.get(PAPER_METHOD.get(method, ""), {}).items():
            if ran_specs is not None and not any(paper_label(task, method, spec) == label for spec in ran_specs):
                continue
            if not any(paper_label(task, method, v) == label for (m, v) in ours if m == method):
                missing.append((method, label, max(values)))
    return missing


def alarms_per_variant(result: BenchResult) -> list[tuple[str, str, float | None, float | None, float | None]]:
    """What the monitor's alarm rule did, per method and variant, averaged over the trials that have
    a value: ``(method, variant, false_alarm_rate, detection_rate, delay_mean)``. The ID variant has
    the false-alarm rate (alarmed ID episodes), the failing ones the detection rate (alarmed
    episodes) and the mean delay in steps to the first alarm of those detected."""
    grouped: dict[tuple[str, str], list[dict[str, float | None]]] = {}
    for key, values in result.detection.items():
        method, _, variant = key.split("/", 2)
        grouped.setdefault((method, variant), []).append(values)

    def mean(values: list[dict[str, float | None]], name: str) -> float | None:
        present = [v[name] for v in values if v[name] is not None]
        return float(np.mean(present)) if present else None

    return [(method, variant, mean(v, "false_alarm_rate"), mean(v, "detection_rate"), mean(v, "delay_mean"))
            for (method, variant), v in sorted(grouped.items(), key=lambda item: (item[0][0], ":" in item[0][1],
                                                                                     item[0][1]))]
