"""Per (method, trial): the model, its fitted detectors, threshold and failing variants, cached in
the bench's folder and set aside when the weights change; the cells' log paths."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from oodmon import seeds
from oodmon.agents import evaluate_variants, load_agent, train, zoo_dir, zoo_names
from oodmon.agents.recipes import recipe_for
from oodmon.agents.serialization import read_metadata
from oodmon.agents.vec_normalize import NO_NORMALIZATION
from oodmon.bench.config import BenchConfig
from oodmon.errors import ConfigError
from oodmon.hashing import file_sha256
from oodmon.jsonfile import read_json, write_json
from oodmon.outputs import safe_filename, write_whole

@dataclass(frozen=True)
class Sb3Models:
    """A user's SB3 model files as the bench hands them to its workers, which load them there."""

    paths: tuple[str, ...]
    env_id: str
    mean: bool = False
    vec_normalize: str | None = None  # their VecNormalize statistics file, or "none"
    frame_stack: int | None = None  # the n_stack of the VecFrameStack they were trained inside
    imports: tuple[str, ...] = ()  # the user's modules imported first (see load_sb3)
    unsafe_load_pickles: bool = False  # loaded as SB3 does, running code the files hold (see load_sb3)

    def __str__(self) -> str:
        return ", ".join(self.paths)


@dataclass(frozen=True)
class PlainPolicy:
    """A user's policy of any kind as the bench hands it to its workers, which import it there."""

    spec: str  # MODULE:NAME (oodmon.agents.plain.policy_by_name)
    env_id: str

    def __str__(self) -> str:
        return self.spec


Source = Path | Sb3Models | PlainPolicy  # what a (method, trial) is benched with


def _bench_agent(source: str | Sb3Models | PlainPolicy, task: str, seed: int, n_samples: int | None = None,
                 masks: str | None = None):
    """The agent of a model directory, of SB3 model files or of a plain policy, its MC sampling
    seeded (``n_samples`` per decision and ``masks``: None, the model's)."""
    if isinstance(source, PlainPolicy):
        from oodmon.agents.plain import plain_agent, policy_by_name

        return plain_agent(policy_by_name(source.spec), source.env_id)
    if isinstance(source, Sb3Models):
        from oodmon.agents.sb3 import load_sb3

        return load_sb3(source.paths, source.env_id, mean=source.mean, seed=seed, masks=masks,
                        vec_normalize=source.vec_normalize, frame_stack=source.frame_stack,
                        imports=source.imports, unsafe_load_pickles=source.unsafe_load_pickles)
    return load_agent(source, task=task, seed=seed, n_samples=n_samples, masks=masks)


def own_policy_agent(config: BenchConfig):
    """The agent of your own SB3 models or policy that a bench of them plays (``config.users_own``),
    its sampling seeded as the calibration's."""
    if not config.users_own:
        raise ValueError("own_policy_agent: the bench plays oodmon's agents, not a policy of yours")
    return _bench_agent(_ensure_model(config, config.methods[0], 0), config.task, seeds.CALIBRATION)


def _weights_sha256(source: Source) -> str:
    """What a (method, trial)'s cached results were made with: the weights' sha256, the SB3 files',
    or a plain policy's: its name, its module's file and its weights' hash (if it has one)."""
    if isinstance(source, PlainPolicy):
        import hashlib
        import importlib.util

        agent = _bench_agent(source, "", 0)  # (imports the module)
        origin = importlib.util.find_spec(source.spec.partition(":")[0]).origin
        code = file_sha256(origin) if origin and Path(origin).is_file() else "no file"
        made_of = f"{source.spec}\n{code}\n{agent.metadata['policy_hash']}"
        return hashlib.sha256(made_of.encode()).hexdigest()
    if isinstance(source, Sb3Models):
        from oodmon.agents.sb3 import models_sha256

        statistics = [] if source.vec_normalize in (None, NO_NORMALIZATION) else [file_sha256(source.vec_normalize)]
        stacked = [] if source.frame_stack is None else [f"frame_stack={source.frame_stack}"]  # other observations
        return models_sha256([file_sha256(p) for p in source.paths] + statistics + stacked, mean=source.mean)
    return file_sha256(source / "model.safetensors")


def _model_dir(config: BenchConfig, method: str, trial: int) -> Path:
    """Trial 0 is the shipped agent where the zoo has one; every other model is trained into the
    bench's cache (never into the installed package)."""
    shipped = zoo_dir() / f"{config.task}-{method}"
    if trial == 0 and not config.resized(method) and (shipped / "model.json").exists():
        return shipped
    return Path(config.out) / "models" / f"{config.task}-{config.model_name(method)}-trial{trial}"


def _refuse_to_train_for_hours(config: BenchConfig, method: str, trial: int) -> None:
    """A missing Pong model takes hours to train on a CPU: never start that as a side effect of a
    bench; say how to train it instead."""
    if config.users_own:
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


def _refuse_detectors_it_cannot_have(config: BenchConfig) -> None:
    """A detector a method's agents cannot have (``scaled_spread`` of sampled MC masks, ``frames``
    of vector observations) was refused when the first trial's detectors were fitted, after the
    other trials' models had trained (CartPole's twelve trial models of a five-trial bench: 17
    minutes on two cores, results/bench/README.md; Pong's: hours each). Said first, of each method's
    shipped agent as the bench loads it (its MC samples and masks; a resized trial is the same kind
    of agent)."""
    from oodmon.monitor.detectors.fitting import cannot_have_any

    if config.users_own:  # nothing is trained: its preparation says so at once
        return
    for method in config.methods:
        shipped = zoo_dir() / f"{config.task}-{method}"
        if not (shipped / "model.json").exists():
            continue
        agent = _bench_agent(shipped, config.task, seeds.CALIBRATION, config.samples, config.masks)
        env = agent.make_env()
        try:
            reason = cannot_have_any(config.detectors, agent, env)
            readings = env.observation_space.dtype.kind == "f"  # oodmon's vector tasks: continuous readings
        finally:
            env.close()
        if reason is not None:
            raise ConfigError(f"the {method} agents cannot have every detector asked for: {reason}")
        if "transitions" in config.detectors and readings:  # (refused by its fit, which finds them distinct)
            raise ConfigError(f"the transitions detector counts states that repeat (discrete observations); "
                              f"{config.task}'s are continuous readings, which it refuses at its fit: use the dynamics "
                              "detector")


def _sb3_files(config: BenchConfig) -> tuple[str, ...]:
    """The bench's SB3 model files, absolute, as SB3's ``load`` finds them (``runs/dqn``: ``runs/dqn.zip``)."""
    from oodmon.agents.sb3 import sb3_file

    return tuple(str(sb3_file(path).resolve()) for path in config.sb3)


def _ensure_model(config: BenchConfig, method: str, trial: int,
                  on_progress: Callable[[str, int, int], None] | None = None) -> Source:
    """The (method, trial)'s model: the SB3 files, the plain policy, the shipped agent, or the cached
    (or now trained) trial model. ``on_progress(stage, done, total)`` follows a training, its stages
    named by the trial."""
    if config.policy:
        return PlainPolicy(config.policy, config.env_id)
    if config.sb3:
        statistics = config.vec_normalize
        if statistics not in (None, NO_NORMALIZATION):
            statistics = str(Path(statistics).resolve())
        return Sb3Models(_sb3_files(config), config.env_id, config.mean, statistics,
                         config.frame_stack, config.imports, config.unsafe_load_pickles)
    path = _ensure_model_dir_current(config, method, trial)
    if not (path / "model.json").exists():
        _refuse_to_train_for_hours(config, method, trial)
        report = None if on_progress is None else (
            lambda stage, done, total: on_progress(f"{method} trial {trial}: {stage}", done, total))
        train(config.task, method, path, seed=trial, recipe=config.recipe(method), on_progress=report)
    return path


def _id_return(model: Source) -> float | None:
    """The model's ID return as its training measured it; ``None`` for SB3 files and a plain policy."""
    if isinstance(model, (Sb3Models, PlainPolicy)):
        return None
    return read_metadata(model).get("id_return_mean")


def _ensure_model_dir_current(config: BenchConfig, method: str, trial: int) -> Path:
    """The (method, trial)'s model folder, a cached model of another recipe set aside first."""
    path = _model_dir(config, method, trial)
    if path.parent == Path(config.out) / "models":  # one the bench trains (not the shipped agent)
        _set_aside_if_made_by_another_recipe(Path(config.out), path, config, method)
    return path


def _set_aside_if_made_by_another_recipe(out: Path, path: Path, config: BenchConfig, method: str) -> None:
    """A trial model trained by another recipe than today's (a new drop probability, full depth,
    other steps), or a training of one not finished yet, is not today's method: move it (and its
    training state) to
    ``<out>/set-aside/recipe-<n>/models/`` and train the trial again, saying why."""
    from oodmon.agents.checkpoints import run_recipe_differences
    from oodmon.agents.recipes import recipe_differences

    recipe = config.recipe(method)
    if (path / "model.json").exists():
        differences = recipe_differences(json.loads((path / "model.json").read_text()), recipe)
    else:  # a training not finished yet: its runs' state says which recipe began it
        differences = sorted({difference for state in sorted(path.glob("runs/*/state.json"))
                              for difference in run_recipe_differences(json.loads(state.read_text()), recipe)})
    if not differences:
        return
    n = 0
    while (aside := out / "set-aside" / f"recipe-{n}" / path.relative_to(out)).exists():
        n += 1
    print(f"bench: {path} was trained by another recipe ({'; '.join(differences)}); moved to {aside}, training it "
          "again", file=sys.stderr)
    aside.parent.mkdir(parents=True, exist_ok=True)
    os.replace(path, aside)


def _trial_dir(config: BenchConfig, method: str, trial: int) -> Path:
    """A (method, trial)'s folder: its threshold, fitted detectors, failing variants and logs."""
    task = safe_filename(config.task)  # your own env's id may hold '/' (ALE/Breakout-v5) or ':'
    return Path(config.out) / "logs" / f"{task}-{config.cache_key()}" / config.model_name(method) / f"trial{trial}"


def _cell_log(config: BenchConfig, method: str, trial: int, name: str) -> Path:
    safe = safe_filename(name)
    folder = _trial_dir(config, method, trial)
    if config.protocol == "monitor":  # onsets other than the task's: other cells
        folder = folder / ("monitor" if config.onsets is None else f"monitor-onsets{config.onsets[0]}-{config.onsets[1]}")
    return folder / f"{safe}.mcap"


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


def _set_aside_if_made_by_other_weights(out: Path, folder: Path, model: Source) -> None:
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
    write_whole(stamp, lambda part: part.write_text(weights + "\n"))  # a torn stamp would set the trial aside


def _prepare_trial(config: BenchConfig, method: str, trial: int, report: Callable[[str, int, int], None],
                   workers: int = 1) -> tuple[Source, Path, list[str], Path | None]:
    """Model, threshold and failing variants of one (method, trial); cached in its folder.
    ``report(stage, done, total)`` counts the episodes of calibration and evaluation.

    ``workers``: processes that play the fitting's, calibration's and evaluation's episodes side by
    side (``oodmon.side_by_side``), for an agent that draws nothing when it decides (an ensemble, a
    plain policy), which plays each episode as in one process: the same detectors, threshold and
    failing variants. An MC agent's episodes side by side draw from streams of their own, so it plays
    in one process whatever ``workers``: its trial comes out as when it is prepared beside others."""
    from oodmon.monitor import calibrate_agent

    model = _ensure_model(config, method, trial)
    folder = _trial_dir(config, method, trial)
    _set_aside_if_made_by_other_weights(Path(config.out), folder, model)
    threshold_path, failing_path = folder / f"threshold-{config.cache_key()}.json", folder / "failing.json"
    # Seeded MC sampling (as `oodmon calibrate --seed`): the same bench fits the same detectors and
    # calibrates the same threshold; unseeded, an MC agent's threshold varied from run to run.
    agent = _bench_agent(model, config.task, seeds.CALIBRATION, config.samples, config.masks)
    if "spread" in config.detectors and agent.estimator is None:
        raise ConfigError(f"{method} has no samples of its own (one model, or a kind oodmon does not sample): "
                          f"drop spread from the detectors")
    if agent.estimator is not None and agent.estimator.draws:
        workers = 1  # an MC agent: its draws run on from episode to episode, as in a trial prepared beside others
    config.check_env_shifts()  # (here, the policy loaded: your own env may be registered by a module it imports)
    # The three stages draw from that one generator in turn. A stage cached by an earlier run that
    # stopped (killed, or a machine restarted) sets the agent's sampling back to where it stood
    # after that stage, so a resumed bench draws what an uninterrupted one draws.
    detectors_path = _fit_trial_detectors(config, agent, folder, f"{method} trial {trial}", report, workers)
    threshold_state = folder / f"sampling-after-threshold-{config.cache_key()}.json"
    if not threshold_path.exists():
        from oodmon.monitor.detectors import DetectorSet

        stage = f"{method} trial {trial}: calibration episodes"
        threshold = calibrate_agent(
            agent, config.calibration_episodes, config.far, score=config.score, window=config.window,
            detectors=DetectorSet.load(detectors_path) if detectors_path else None,
            detector=config.alarm_detector, obs_noise=config.obs_noise, confidence=config.confidence,
            rule=config.rule, consecutive=config.m, warmup=config.warmup,
            on_progress=lambda _, done, total: report(stage, done, total), workers=workers)
        _continue_sampling(agent, threshold_state, made_now=True)
        threshold.save(threshold_path)  # after the state: a threshold on disk always has its state beside it
    else:
        _continue_sampling(agent, threshold_state, made_now=False)
    variants = config.variant_list()
    cached = _read_json(failing_path)
    if config.own_env:  # no failure is told for your own env: every shift is monitored
        failing = [v.spec for v in variants]
    elif cached is not None and cached.get("variants") == [v.spec for v in variants]:
        failing = cached["failing"]
    else:
        stage = f"{method} trial {trial}: evaluation episodes"
        _, results = evaluate_variants(agent.act, config.task, variants, config.eval_episodes,
                                       on_progress=lambda _, done, total: report(stage, done, total), wrap=agent.wrap,
                                       workers=workers)
        failing = [r.spec for r in results if r.fails]
        write_json(failing_path, {"variants": [v.spec for v in variants], "failing": failing,
                                   "returns": {r.spec: r.mean for r in results}})
    return model, threshold_path, failing, detectors_path


def _continue_sampling(agent, state_file: Path, *, made_now: bool) -> None:
    """After a stage of :func:`_prepare_trial`: when it ran now, save where the agent's MC sampling
    stands; when an earlier run made it, set the sampling back to where it stood then. (Caches made
    before the states were saved have none: the sampling goes on from where it is, as then.)"""
    estimator = agent.estimator
    if estimator is None or estimator.sampling_state is None:
        return
    if made_now:
        write_json(state_file, estimator.sampling_state)
    elif (state := _read_json(state_file)) is not None:
        estimator.sampling_state = state


def _read_json(path: Path):
    """The JSON at ``path``; ``None`` when there is none or it cannot be read (it is made again)."""
    try:
        return read_json(path)
    except ConfigError:
        return None


def _fit_trial_detectors(config: BenchConfig, agent, folder: Path, label: str,
                         report: Callable[[str, int, int], None], workers: int = 1) -> Path | None:
    """The (method, trial)'s fitted detectors, fitted once into its folder (cached beside the
    threshold, and set aside with it when the weights change); ``workers`` processes play the
    fitting's episodes (:func:`_prepare_trial`)."""
    if not config.learned:
        return None
    from oodmon.monitor.detectors import fit_agent_detectors

    path = folder / f"detectors-{config.cache_key()}"
    state_file = folder / f"sampling-after-detectors-{config.cache_key()}.json"
    if not (path / "detectors.json").exists():
        # episodes None: the library's default, 90 whole episodes (your own env: on until its steps,
        # default_fit_steps); Pong's were the first 1,000 steps of 6 games until 2026-12-01 (the cache
        # key's "-vanish"). The fitting's own stage names its unit: episodes, then steps where it
        # plays on for them.
        fitted = fit_agent_detectors(agent, detectors=config.learned, score=config.score, obs_noise=config.obs_noise,
                                     on_progress=lambda stage, done, total: report(f"{label}: {stage}", done, total),
                                     episodes=config.fit_episodes or None, workers=workers,
                                     dynamics_updates=config.dynamics_updates, explore=config.fit_explore)
        _continue_sampling(agent, state_file, made_now=True)
        fitted.save(path)  # after the state: fitted detectors on disk always have their state beside them
    else:
        _continue_sampling(agent, state_file, made_now=False)
    return path


def _monitored(config: BenchConfig, failing: list[str]) -> list[str]:
    """The shifted variants a (method, trial) is monitored on: those it fails on, or all of them."""
    return [v.spec for v in config.variant_list()] if config.all_variants else failing
