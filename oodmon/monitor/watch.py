"""``oodmon.watch``: a deployed policy's monitor, ready in one call.

It fits the learned detectors on ID episodes of the policy, calibrates the alarm threshold on
others, and returns a :class:`~oodmon.monitor.Monitor` (or, given ``env``, that env wrapped in a
:class:`~oodmon.monitor.MonitoredEnv`)::

    import oodmon
    monitor = oodmon.watch(["dqn0.zip", "dqn1.zip"], "CartPole-v1")   # or SB3 models, an Agent, a function
    record = monitor.run_episode(gymnasium.make("CartPole-v1"), seed=0)

``save="dqn.json"`` keeps the calibration (the threshold, and the detectors in ``dqn.json.detectors/``,
as ``oodmon calibrate --out dqn.json`` writes them); ``threshold="dqn.json"`` at a later start reads
it and runs no episode, and loads the SB3 models it names where no policy is given
(``oodmon.watch(threshold="dqn.json", env=gymnasium.make("CartPole-v1"))``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import gymnasium

from oodmon.agents.agent import Agent
from oodmon.envs.grid import ENV_IDS
from oodmon.envs.registration import task_of_env
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import AlarmEvent
from oodmon.monitor.detectors.dynamics import MAX_UPDATES, check_max_updates
from oodmon.monitor.sinks.base import Sink
from oodmon.monitor.threshold import DEFAULT_CONFIDENCE, Threshold
from oodmon.progress import Progress
from oodmon.validation import check_max_steps, is_whole

__all__ = ["as_agent", "watch"]


def as_agent(policy: Any, env_id: str | None = None, *, mean: bool = False, seed: int | None = None,
             masks: str | None = None, vec_normalize: Any = None, frame_stack: int | None = None,
             imports: Sequence[str] = (), unsafe_load_pickles: bool = False) -> Agent:
    """An :class:`~oodmon.agents.Agent` of ``policy``: an Agent as it is; SB3 model files (a path
    or a list of them) or SB3 models in memory (one or a list), acting in ``env_id``; any other
    function ``obs -> action``, a plain policy (:func:`~oodmon.agents.plain.plain_agent`, which
    the learned detectors watch; ``weights=`` there binds its thresholds to its weights). ``masks``:
    the MC masks of one SB3 model with dropout (``sampled``, ``fixed`` or ``fixed-decisions``, see
    :func:`~oodmon.agents.sb3.load_sb3`); an Agent keeps the masks it was loaded with.
    ``vec_normalize``: SB3 models trained inside ``VecNormalize``: its statistics file (or the
    VecNormalize itself, for models in memory, which otherwise use the one they were trained in;
    see :func:`~oodmon.agents.sb3.sb3_agent`), or ``"none"``. ``frame_stack``: SB3 models trained
    inside ``VecFrameStack``: its ``n_stack`` (the env given to :func:`watch` must then give stacked
    observations: wrap it in :class:`~oodmon.agents.frame_stack.FrameStack`). ``imports``,
    ``unsafe_load_pickles``: how SB3 model files are read (see :func:`~oodmon.agents.sb3.load_sb3`).

    Raises:
        ConfigError: SB3 models or a plain policy without ``env_id``, something that is none of
            these, an Agent loaded with other masks than ``masks``, or ``vec_normalize`` with an
            Agent or a plain policy (see :func:`~oodmon.agents.plain.plain_agent` for what it refuses).
    """
    if isinstance(policy, Agent):
        if vec_normalize is not None or frame_stack is not None or unsafe_load_pickles or imports:
            raise ConfigError("vec_normalize, frame_stack, imports and unsafe_load_pickles are for SB3 models; an "
                              "oodmon Agent sees the observations it was made with")
        if env_id is not None and policy.env_id not in (None, env_id):
            raise ConfigError(f"the agent acts in {policy.env_id}, not {env_id}")
        if env_id is not None and policy.env_id is None and task_of_env(env_id) != policy.task:
            # an oodmon agent acts in its task's env (oodmon's or gymnasium's id of it), nowhere else
            raise ConfigError(f"the {policy.task} agent acts in {ENV_IDS.get(policy.task, policy.task)}, not "
                              f"{env_id}: leave the env id out")
        own = getattr(policy.estimator, "masks", None)
        if masks is not None and masks != (own or "sampled"):
            raise ConfigError(f"the agent was loaded with {own or 'no MC'} masks, not {masks!r}: load it with "
                              f"masks={masks!r} (oodmon.agents.load, load_agent or load_sb3)")
        return policy
    if callable(policy):  # a function obs -> action (an SB3 model is not callable; its policy network is: said there)
        from oodmon.agents.plain import plain_agent

        if env_id is None:
            raise ConfigError("give the gymnasium env id your policy acts in, e.g. watch(policy, 'CartPole-v1')")
        if mean or masks is not None or vec_normalize is not None or frame_stack is not None or imports \
                or unsafe_load_pickles:
            raise ConfigError("mean, masks, vec_normalize, frame_stack, imports and unsafe_load_pickles are for SB3 "
                              "models; a plain policy acts on the env's observations as they are")
        return plain_agent(policy, env_id)
    items = list(policy) if isinstance(policy, (list, tuple)) else [policy]
    if env_id is None:
        raise ConfigError("give the gymnasium env id your models act in, e.g. watch(models, 'CartPole-v1')")
    if items and all(isinstance(item, (str, Path)) for item in items):
        from oodmon.agents.sb3 import load_sb3

        return load_sb3(items, env_id, mean=mean, seed=seed, masks=masks, vec_normalize=vec_normalize,
                        frame_stack=frame_stack, imports=imports, unsafe_load_pickles=unsafe_load_pickles)
    from oodmon.agents.sb3 import sb3_agent

    return sb3_agent(items, env_id, mean=mean, seed=seed, masks=masks, vec_normalize=vec_normalize,
                     frame_stack=frame_stack)


def watch(policy: Any = None, env_id: str | None = None, *, env: gymnasium.Env | None = None, far: float = 0.05,
          confidence: float | None = DEFAULT_CONFIDENCE, episodes: int = 50, fit_episodes: int | None = None,
          detector: str | None = None, mean: bool = False, sinks: Sequence[Sink] = (),
          callbacks: Sequence[Callable[[AlarmEvent], Any]] = (), seed: int | None = None,
          on_progress: Progress | None = None, masks: str | None = None, vec_normalize: Any = None,
          frame_stack: int | None = None, threshold: str | Path | None = None, save: str | Path | None = None,
          warmup: int = 0, imports: Sequence[str] = (), unsafe_load_pickles: bool = False, workers: int = 1,
          dynamics_updates: int | None = MAX_UPDATES, max_steps: int | None = None, fit_explore: float = 0.0,
          reading_names: Sequence[str] | None = None) -> Any:
    """Fit, calibrate and return the monitor of ``policy`` (see :func:`as_agent` for what it takes).

    The learned detectors are fitted on ``fit_episodes`` ID episodes of the deployed policy (``None``:
    :data:`~oodmon.monitor.detectors.DEFAULT_FIT_EPISODES`, and in an env oodmon has no variants of
    as many more as hold :data:`~oodmon.monitor.detectors.DEFAULT_FIT_STEPS` steps), the
    threshold on ``episodes`` others (``far``, ``confidence`` as in
    :func:`~oodmon.monitor.calibrate_agent`; the alarm reads ``detector``, by default the task's
    best; ``scaled_spread``, which reads an ensemble's members or an MC policy's fixed sub-networks
    (``masks="fixed"`` or ``"fixed-decisions"``), is then fitted too, as ``oodmon calibrate --detector scaled_spread`` fits
    it). ``env``: wrap this env (the one you step) and return the
    :class:`~oodmon.monitor.MonitoredEnv` instead of the bare monitor; its ``info["oodmon"]``
    says what the monitor saw at every step. Given ``env`` without ``env_id``, the ID episodes are
    of the id gymnasium made ``env`` by (``watch(act, env=gymnasium.make("CartPole-v1"))``),
    where it was made with that id's own arguments; of SB3 models in memory without either, the id
    of the env they learned in (``watch(model)`` after ``model.learn``), alike.
    ``on_progress(stage, done, total)`` reports progress
    (see :mod:`oodmon.progress`). ``masks``, ``vec_normalize``, ``frame_stack``, ``imports``,
    ``unsafe_load_pickles``: see :func:`as_agent`.
    ``warmup``: the alarm looks at no finite score of an episode's first ``warmup`` steps (see
    :mod:`oodmon.monitor.alarms`; the calibration says when one would lower the threshold much).
    ``dynamics_updates``: the dynamics model's fit stops after the whole epochs that hold at most
    this many Adam updates (``None``: every epoch; see :func:`~oodmon.monitor.detectors.fit_detectors`).
    ``fit_explore``: the share of the fitting steps that take a random action instead of the
    policy's (its ``explore``), for a policy whose actions will not all be its own deterministic
    ones: a learning model's exploration (:class:`~oodmon.monitor.sb3_callback.MonitorCallback`;
    not the states it comes to visit as it learns), one deployed as it samples (docs/your-policy.md,
    "Inside SB3"); the threshold is calibrated on the policy's own actions.
    ``max_steps``: the calibration episodes' time limit instead of the env's own, for a deployment
    whose runs are longer (see :func:`~oodmon.monitor.validate_threshold`'s, which checks it).
    ``workers``: processes that play the fitting and calibration episodes side by side (0: one per
    core; see :func:`~oodmon.monitor.calibrate_agent`: a policy that draws nothing gets the same
    detectors and threshold).
    ``reading_names``: the name of each number of your env's observations, by index (a robot's
    ``["knee angle", "knee velocity", ...]``): an alarm names its readings by them (see
    :class:`~oodmon.monitor.Monitor`'s), and the threshold ``save`` writes keeps them; with
    ``threshold``, they come before the file's.

    A calibration is minutes of ID episodes, which a deployed process cannot run at every start:
    ``save`` writes the threshold to that file and the fitted detectors to ``<save>.detectors/``
    (as ``oodmon calibrate --out`` does, so ``oodmon run --threshold`` reads them too; stopped by
    Ctrl-C or a worker's death, it keeps beside that file what it did, as ``oodmon calibrate``
    does, and the same call goes on from it to what one never stopped gives), and
    ``threshold`` reads such a file and the detectors beside it (else the agent's shipped ones)
    instead of fitting and calibrating: no episode runs. The file must have been calibrated on this
    policy (the hash of its weights; its MC masks, which the policy is loaded with by default);
    ``policy`` may then be left out where the file names it: the SB3 model files it records, loaded
    as they were when it was calibrated (see :func:`_recorded_policy`; as ``oodmon run --threshold``
    alone loads them), or the shipped agent of its task and method;
    ``far``, ``confidence`` and ``episodes`` are then the file's, and ``warmup``, ``max_steps``,
    ``fit_episodes``, ``dynamics_updates`` and ``fit_explore`` are refused (the file's warm-up, episodes and fitted
    detectors are what it was calibrated with).

    Raises:
        ConfigError, InvalidParameterError: as :func:`as_agent` and the calibration, before any
            episode runs where they can be told from the arguments; ``env`` without ``env_id``
            made without gymnasium's registry or with other arguments than its id's;
            ``threshold`` and ``save`` both given; ``threshold`` with ``warmup``, ``max_steps``, ``fit_episodes``,
            ``dynamics_updates`` or ``fit_explore``; a
            ``threshold`` file of another policy, or whose detectors are missing; a ``save`` path
            that is one of the files it reads, or holds a file that is no threshold (a threshold
            there is replaced).
    """
    from oodmon.monitor.alarms import check_warmup
    from oodmon.monitor.calibration import calibrate_agent, save_calibration
    from oodmon.kept import KeptFit
    from oodmon.monitor.detectors import DetectorSet, fit_agent_detectors, fitting_notes
    from oodmon.monitor.detectors.fitting import check_can_have, check_explore, fit_settings, fitted_when_named
    from oodmon.monitor.scores import DEFAULT_SCORE
    from oodmon.monitor.monitor import Monitor, check_reading_names
    from oodmon.monitor.monitored_env import MonitoredEnv, check_env_of, check_one_env
    from oodmon.side_by_side import resolve_workers
    from oodmon.monitor.threshold import conformal_rank
    from oodmon.outputs import check_output_dir, check_output_file, replaced_file

    if threshold is not None and save is not None:
        raise ConfigError("give threshold= (read a calibration made before) or save= (write the one made now), not both")
    check_reading_names(reading_names)
    if policy is None and threshold is None:
        raise ConfigError("give the policy to watch (SB3 model files or models, an oodmon Agent, a function obs -> "
                          "action), or threshold= a calibration of it, which names SB3 models or a shipped agent")
    if env is not None:
        check_one_env(env)  # (an id given as env=, a vector env: said before any fit)
    if env_id is None and env is not None and not isinstance(policy, Agent):
        env_id = _id_of(env.spec, type(env.unwrapped).__name__)  # watch(act, env=gymnasium.make("CartPole-v1"))
    elif env_id is None and env is None and not isinstance(policy, Agent) and not callable(policy):
        env_id = _trained_in(policy)  # watch(model) of an SB3 model in memory: the id of the env it learned in
    if threshold is not None and warmup:
        raise ConfigError("a threshold file's warm-up is the one it was calibrated for: leave warmup= out, or "
                          "calibrate anew with it (save=)")
    if threshold is not None and max_steps is not None:
        raise ConfigError("a threshold file's episodes are those it was calibrated on (its max_steps): leave max_steps= "
                          "out, or calibrate anew with it (save=)")
    fitting = [name for name, value, default in (("fit_episodes", fit_episodes, None),
                                                 ("dynamics_updates", dynamics_updates, MAX_UPDATES),
                                                 ("fit_explore", fit_explore, 0.0))
               if value != default]
    if threshold is not None and fitting:  # (oodmon calibrate refuses its options of a fit where it fits none)
        names, many = " and ".join(f"{name}=" for name in fitting), len(fitting) > 1
        them = "them" if many else "it"
        raise ConfigError(f"{names} shape{'' if many else 's'} a fit of the detectors, and a threshold file's detectors "
                          f"are those fitted beside it: leave {them} out, or fit and calibrate anew with {them} (save=)")
    if threshold is not None:
        agent, alarm_threshold, detectors = _calibrated(policy, env_id, threshold, mean=mean, seed=seed, masks=masks,
                                                        vec_normalize=vec_normalize, frame_stack=frame_stack,
                                                        imports=imports, unsafe_load_pickles=unsafe_load_pickles)
        if alarm_threshold.step_mode_warning:  # (as `oodmon run` warns of it)
            warnings.warn(alarm_threshold.step_mode_warning, UserWarning, stacklevel=2)
    else:
        if not is_whole(episodes):
            raise InvalidParameterError(f"episodes={episodes!r} is not allowed; give a whole number >= 1 of ID "
                                        "calibration episodes")
        conformal_rank(episodes, far, confidence)  # too few episodes: said before minutes of work
        check_warmup(warmup)
        check_max_steps(max_steps)
        resolve_workers(workers, episodes)
        # (fit_agent_detectors would say "episodes=", after loading the models)
        if fit_episodes is not None and not is_whole(fit_episodes, 3):
            raise InvalidParameterError(f"fit_episodes={fit_episodes!r} is not allowed; fitting the detectors needs a "
                                        "whole number >= 3 of ID episodes (two thirds fit, one third ranks)")
        check_max_updates(dynamics_updates, "dynamics_updates")
        fit_explore = check_explore(fit_explore, "fit_explore")
        if save is not None:  # an unwritable path, or one that holds a model or a log: said now, not after the calibration
            files = [*(policy if isinstance(policy, (list, tuple)) else [policy]), vec_normalize]
            check_output_file(save, parameter="save", inputs=[("a file it reads", path) for path in files
                                                              if isinstance(path, (str, Path))])
            replaced_file(save, parameter="save", holds="threshold", read=Threshold.load)
            check_output_dir(f"{save}.detectors", parameter="save (its detectors folder)", create=False)
        agent = as_agent(policy, env_id, mean=mean, seed=seed, masks=masks, vec_normalize=vec_normalize,
                         frame_stack=frame_stack, imports=imports, unsafe_load_pickles=unsafe_load_pickles)
    if env is not None:
        check_env_of(agent, env)  # an env of another task: said now, not at its first step after the calibration
    if threshold is None:
        check_can_have(detector, agent)  # (a plain policy's spread: said before the fit, not after it)

        def fit(episodes_file: Path | None) -> DetectorSet:
            return fit_agent_detectors(agent, detectors=fitted_when_named(detector),  # as the CLI fits them
                                       episodes=fit_episodes, on_progress=on_progress, workers=workers,
                                       dynamics_updates=dynamics_updates, max_steps=max_steps, kept=episodes_file,
                                       explore=fit_explore)

        # With save=, stopped (Ctrl-C, a worker's death), it keeps what it did beside that file, as
        # `oodmon calibrate` does beside --out, and the same call goes on from it.
        kept_fit = None if save is None else KeptFit(f"{save}.detectors", fit_settings(
            agent, fitted_when_named(detector), score=DEFAULT_SCORE, episodes=fit_episodes,
            dynamics_updates=dynamics_updates, obs_noise=0.0, max_steps=max_steps, workers=workers,
            explore=fit_explore))
        detectors = fit(None) if kept_fit is None else kept_fit.fit(agent.estimator, fit)
        for note in fitting_notes(detectors):  # what the fit leaves unwatched, as calibrate prints it
            warnings.warn(note, stacklevel=2)
        try:
            alarm_threshold = calibrate_agent(agent, episodes, far, detectors=detectors, detector=detector,
                                              confidence=confidence, on_progress=on_progress, warmup=warmup,
                                              workers=workers, max_steps=max_steps, reading_names=reading_names,
                                              kept=None if save is None else f"{save}.kept.npz")
        except (KeyboardInterrupt, BrokenProcessPool):
            if kept_fit is not None:
                kept_fit.keep()
            raise
        if save is not None:  # the pair whole, or the earlier one (a full disk)
            save_calibration(alarm_threshold, save, detectors)
            Path(f"{save}.kept.npz").unlink(missing_ok=True)
            kept_fit.clear()
    monitor = Monitor(agent, alarm_threshold, detectors=detectors, detector=detector, sinks=sinks, callbacks=callbacks,
                      reading_names=reading_names)
    return monitor if env is None else MonitoredEnv(env, monitor)


def _trained_in(policy: Any) -> str | None:
    """The env id of SB3 models in memory, for ``watch(model)`` without one: the id of the env the
    first one holds (``model.get_env()``, the env it learned in, through VecNormalize and the
    like; see :func:`_id_of`); ``None`` for models without an env (loaded from files) and what is
    no SB3 model (file names: their env id is needed, as before)."""
    first = policy[0] if isinstance(policy, (list, tuple)) and policy else policy
    get_env = getattr(first, "get_env", None)
    venv = get_env() if callable(get_env) else None
    if venv is None:
        return None
    return _id_of(venv.get_attr("spec", [0])[0], type(venv.get_attr("unwrapped", [0])[0]).__name__, models=True)


def _id_of(spec: Any, name: str, *, models: bool = False) -> str:
    """The env id to play fresh ID episodes of, for ``watch`` without one: the id gymnasium made the
    env (of ``spec``, its ``name``; the ``models``' own env, else the one given) by, where it was
    made with that id's own arguments (a ``render_mode`` aside), since fitting and calibration play
    ``gymnasium.make(id)``.

    Raises:
        ConfigError: an env made without the registry, or with other arguments (another time
            limit): they may be the deployed world's or the ID world's, which only the caller knows.
    """
    what, call = ("the env your model learned in", "watch(model, {!r})") if models else (
        "this env", "watch(policy, {!r}, env=env)")
    if spec is None:
        raise ConfigError(f"give the gymnasium env id your policy acts in: {what}, a {name}, was made without "
                          "gymnasium's registry, and oodmon plays fresh ID episodes of the env to fit its detectors "
                          f"and calibrate (gymnasium.make(id)); register it, gymnasium.register('my_envs/{name}-v0', "
                          f"entry_point={name}, max_episode_steps=N), and give {call.format(f'my_envs/{name}-v0')}")
    own = gymnasium.spec(spec.id)
    given = {key: value for key, value in spec.kwargs.items() if key != "render_mode"}
    if given != {key: value for key, value in own.kwargs.items() if key != "render_mode"} \
            or spec.max_episode_steps != own.max_episode_steps:
        made = ", ".join([*(f"{key}={value!r}" for key, value in given.items()),
                          *([f"max_episode_steps={spec.max_episode_steps}"]
                            if spec.max_episode_steps != own.max_episode_steps else [])])
        raise ConfigError(f"give the gymnasium env id your policy acts in: {what} was made as "
                          f"gymnasium.make({spec.id!r}, {made}), and fitting and calibration play the in-distribution "
                          f"world, gymnasium.make(id): {call.format(spec.id)} if that is {spec.id!r} as registered "
                          "(these arguments the deployed world's), else register an id with them "
                          "(gymnasium.register(..., kwargs=...)) and give it")
    return spec.id


def _recorded_policy(threshold: Threshold, path: str | Path, env_id: str | None, *, masks: str | None,
                     **loading: Any) -> tuple[Any, str | None, dict[str, Any]]:
    """``(policy, env_id, loading)`` for :func:`as_agent` of the policy the threshold at ``path``
    was calibrated on, where :func:`watch` was given none: the SB3 model files it records
    (:func:`~oodmon.monitor.threshold.recorded_sb3`: where they were, else beside it) in its
    env, with its VecNormalize statistics, VecFrameStack depth and ``mean`` unless given; or the
    shipped agent of its task and method. ``imports`` and ``unsafe_load_pickles`` are never read
    from the file (they run code): give them where the models need them.

    Raises:
        ConfigError: a threshold of your own policy, a plain one or SB3 models it does not record
            (written before 2026-12-07), an ``env_id`` other than its own, or files it names that
            are gone.
    """
    from oodmon.agents.agent import load, zoo_names
    from oodmon.monitor.threshold import recorded_sb3
    from oodmon.names import PLAIN_METHOD

    recorded = threshold.sb3
    if threshold.models and recorded is not None:
        if env_id is not None and env_id != recorded["env_id"]:
            raise ConfigError(f"{path} was calibrated on SB3 models in {recorded['env_id']}, not {env_id}: leave the "
                              "env id out, or give the models and the threshold calibrated there")
        sb3, gone = recorded_sb3(threshold, path, vec_normalize=loading.get("vec_normalize"),
                                 frame_stack=loading.get("frame_stack"), mean=loading.get("mean", False))
        if gone:
            raise ConfigError(f"{path} was calibrated on SB3 models loaded from files that are neither there nor "
                              f"beside it: {', '.join(gone)}; give them where they are now: watch(['model.zip', ...], "
                              f"{recorded['env_id']!r}, threshold=..., vec_normalize=...)")
        given = {key: sb3[key] for key in ("vec_normalize", "frame_stack", "mean")}
        return sb3["models"], sb3["env_id"], loading | given
    if f"{threshold.task}-{threshold.method}" in zoo_names():  # (weights of its own are refused by their hash)
        return load(threshold.task, threshold.method, seed=loading.get("seed"), masks=masks), env_id, loading
    kind = "your own SB3 models, and does not record how they were loaded (written before 2026-12-07)" \
        if threshold.method == "sb3" else "your own policy, which it cannot load (a function's code)" \
        if threshold.method == PLAIN_METHOD else f"a {threshold.task}/{threshold.method} agent oodmon does not ship"
    raise ConfigError(f"{path} was calibrated on {kind}: give the policy, watch(policy, env_id, threshold=...)")


def _calibrated(policy: Any, env_id: str | None, path: str | Path, *, masks: str | None, **loading: Any) -> tuple:
    """``(agent, threshold, detectors)`` of a calibration made before: the threshold file at
    ``path`` and the detectors beside it (``<path>.detectors/``), else the agent's shipped ones."""
    from oodmon.monitor.detectors import detectors_for
    from oodmon.monitor.threshold import Threshold

    found = Threshold.load(path)
    if masks is None and not isinstance(policy, Agent):
        masks = found.masks  # an SB3 model with dropout, loaded with the masks it was calibrated with
    if policy is None:
        policy, env_id, loading = _recorded_policy(found, path, env_id, masks=masks, **loading)
    agent = as_agent(policy, env_id, masks=masks, **loading)
    beside = Path(f"{path}.detectors")
    detectors = detectors_for(agent, beside if (beside / "detectors.json").is_file() else None)
    if found.detector != "spread" and (detectors is None or found.detector not in detectors):
        raise ConfigError(f"{path} reads the {found.detector} detector, fitted beside it in {beside}, which is missing: "
                          "copy that folder along with the file, or calibrate again (watch(..., save=...))")
    return agent, found, detectors
