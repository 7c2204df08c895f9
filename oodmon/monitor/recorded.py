"""A deployment oodmon cannot play: its detectors fitted, and its alarm calibrated, on episodes you recorded.

Every other way to a threshold plays ID episodes in a gymnasium env (``oodmon calibrate``,
:func:`oodmon.watch`), or reads oodmon's own logs of them (``oodmon recalibrate``). A robot, a
plant or a trading system has no such env: what it has is its own records of normal running.
Given them as arrays, each episode ``(observations, actions)`` (``(T, ...)`` each, or the
observations one longer, the last after the last action), this module fits the learned detectors
on some (:func:`fit_on_episodes`), calibrates the alarm on others (:func:`calibrate_on_episodes`)
and checks it on fresh ones (:func:`validate_on_episodes`). :func:`watch_recorded` fits and
calibrates, and returns the :class:`~oodmon.monitor.Monitor` that watches the deployment step by
step, the policy never run by oodmon::

    monitor = oodmon.watch_recorded(fit, calibration, action_space=gymnasium.spaces.Discrete(2),
                                    save="runs/robot.json")
    with monitor:
        monitor.begin_episode()
        for ...:                               # your control loop
            monitor.step(obs, action=a)        # the action your policy took
            if monitor.last_step.alarm: ...    # (or callbacks=[...], called at each alarm)
        monitor.end_episode()

The detectors read the observations and the actions: of vectors, the ``dynamics`` model, its
``drift``, and ``combined`` of them; of a camera's pictures, the camera's detectors (``frames``,
``stillness``, their ``combined``; ``vanishing`` and ``motion`` where named). What a policy's
samples give (``spread``, ``features``) needs the policy, which oodmon does not have here.

The threshold's promise is the usual one (:mod:`oodmon.monitor.threshold`), over episodes like the
calibration ones: they must be others than the fitting ones (the detectors learned those, and read
them low), which the fitted set records by a hash of each and :func:`calibrate_on_episodes`
checks; the threshold records its own episodes' hashes, and :func:`validate_on_episodes` counts
neither.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import AlarmEvent
from oodmon.monitor.calibration import Validation, _counted
from oodmon.monitor.detectors.dynamics import MAX_UPDATES, check_max_updates
from oodmon.monitor.detectors.store import DetectorSet
from oodmon.monitor.sinks.base import Sink
from oodmon.monitor.threshold import DEFAULT_CONFIDENCE, Threshold
from oodmon.progress import Progress
from oodmon.seeds import DETECTOR_FIT, check_seed

__all__ = ["FewRecordedStepsWarning", "calibrate_on_episodes", "episode_hash", "fit_on_episodes", "load_records",
           "save_records", "validate_on_episodes", "watch_recorded"]

#: The detectors that read the policy at each step, which oodmon does not run here.
POLICY_READ = ("spread", "features", "scaled_spread")

#: What ``fitted_for`` calls the hashes of the episodes a set was fitted on (:func:`episode_hash`).
FITTED_EPISODES = "episode_hashes"


class FewRecordedStepsWarning(UserWarning):
    """The dynamics model was fitted on episodes of fewer recorded steps than a played fit's hold in
    an env oodmon has no variants of (:data:`~oodmon.monitor.detectors.DEFAULT_FIT_STEPS`): there it missed
    more shifts (Acrobot, 2026-11-29: fitted on about 10,000 steps it alarmed 17 of 70 shifted
    episodes, on 45,000 steps 49 of 70, docs/your-policy.md "Shift your own env")."""


class _Spaces(gymnasium.Env):
    """An env of which oodmon knows the spaces only: what deciding which detectors a policy can have
    reads of one (:func:`~oodmon.monitor.detectors.fitting.default_detectors`). It never steps."""

    def __init__(self, observation_space: gymnasium.Space, action_space: gymnasium.Space) -> None:
        self.observation_space, self.action_space = observation_space, action_space


def _no_policy(obs: Any) -> None:
    """The policy oodmon does not run: it stands for the deployment's in choosing the detectors."""


def episode_hash(observations: np.ndarray, actions: np.ndarray) -> str:
    """The first 16 hex digits of the sha256 of an episode's observations and actions (as float64,
    with their shapes): what tells a calibration episode from one the detectors were fitted on.

    Example:
        >>> episode_hash(np.zeros((3, 2)), np.zeros(3)) == episode_hash(np.zeros((3, 2), np.float32), np.zeros(3, int))
        True
    """
    digest = hashlib.sha256()
    for array in (observations, actions):
        array = np.ascontiguousarray(array, np.float64)
        digest.update(repr(array.shape).encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


#: What ``fitted_for`` calls the layout of dict observations (:func:`layout_of`): ``[[key, shape], ...]``.
LAYOUT = "observation_layout"


def layout_of(observations: Mapping[str, Any], *, steps: bool = False) -> list[list]:
    """The layout of a dict observation (a robot's named sensors): each key, in sorted order, with
    the shape of its value at one step (of an episode's, ``steps``: each value's first axis its
    steps); :func:`flattened` puts the values side by side in that order.

    Example:
        >>> layout_of({"velocity": np.zeros((10, 2)), "angle": np.zeros(10)}, steps=True)
        [['angle', []], ['velocity', [2]]]

    Raises:
        ConfigError: no keys, or a key that is not a text.
    """
    if not observations or not all(isinstance(key, str) for key in observations):
        raise ConfigError(f"a dict observation's keys are the names of its readings, texts; got "
                          f"{list(observations)!r:.60}")
    return [[key, list(np.shape(observations[key])[1 if steps else 0:])] for key in sorted(observations)]


def layout_names(layout: Sequence[Sequence]) -> list[str]:
    """The name of each number of a dict observation flattened by ``layout``: a key whose value is
    one number by itself, the others by index (``velocity[1]``).

    Example:
        >>> layout_names([["angle", []], ["velocity", [2]]])
        ['angle', 'velocity[0]', 'velocity[1]']
    """
    names = []
    for key, shape in layout:
        size = int(np.prod(shape))
        names += [key] if size == 1 else [f"{key}[{index}]" for index in range(size)]
    return names


def flattened(observation: Mapping[str, Any], layout: Sequence[Sequence], *, steps: bool = False) -> np.ndarray:
    """A dict observation as one vector of float64 in ``layout``'s order (of an episode's,
    ``steps``: each value ``(T, ...)``, a ``(T, n)`` array).

    Example:
        >>> flattened({"velocity": [0.5, 2.0], "angle": 0.1}, [["angle", []], ["velocity", [2]]])
        array([0.1, 0.5, 2. ])

    Raises:
        ConfigError: keys other than the layout's, a value of another shape, not numbers, or (of an
            episode's) of another number of steps.
    """
    keys = [key for key, _ in layout]
    if sorted(map(str, observation)) != sorted(keys):
        raise ConfigError(f"the observation's keys are {sorted(map(str, observation))}; the detectors were fitted on "
                          f"dicts of {keys}")
    parts = []
    for key, shape in layout:
        value = np.asarray(observation[key])
        if value.dtype.kind not in "biuf":
            raise ConfigError(f"the observation's {key!r} must be numbers; got {value.dtype}")
        if value.shape[1 if steps else 0:] != tuple(shape) or (steps and value.ndim == 0):
            raise ConfigError(f"the observation's {key!r} is of shape {value.shape[1 if steps else 0:]} a step; the "
                              f"detectors were fitted on {tuple(shape)}")
        parts.append(value.reshape(len(value), -1) if steps else value.reshape(-1))
    if steps and len({len(part) for part in parts}) > 1:
        raise ConfigError(f"the observation's values have {sorted({len(part) for part in parts})} steps; give each "
                          "as many as the episode has")
    return np.concatenate(parts, axis=-1).astype(np.float64)


def _flat_episodes(episodes: Any, layout: Sequence[Sequence] | None, what: str) -> Any:
    """``episodes`` with each dict of observations (``{key: (T, ...)}``) flattened by ``layout``
    (:func:`flattened`); others as given, which must then be no dicts.

    Raises:
        ConfigError: a dict where the detectors were fitted on arrays, an array where on dicts, or a
            dict that is not of ``layout``.
    """
    if isinstance(episodes, (str, bytes, Path, np.ndarray)) or not isinstance(episodes, Sequence):
        return episodes  # (refused by _checked_pairs, saying what it is)
    flat = []
    for index, episode in enumerate(episodes):
        observations = episode[0] if isinstance(episode, (tuple, list)) and episode else None
        if isinstance(observations, Mapping) != (layout is not None):
            said = ("dicts of named readings" if layout is not None else "arrays")
            raise ConfigError(f"episode {index} of {what}: its observations are "
                              f"{'a dict' if isinstance(observations, Mapping) else 'no dict'}, and the detectors were "
                              f"fitted on {said}")
        if layout is not None:
            try:
                episode = (flattened(observations, layout, steps=True), *episode[1:])
            except ConfigError as error:
                raise ConfigError(f"episode {index} of {what}: {error}") from None
        flat.append(episode)
    return flat


def _checked_pairs(episodes: Any, what: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """``episodes`` as ``(observations, actions)`` arrays of numbers; ``what`` names them in an error.

    Raises:
        ConfigError: no episodes, or an episode that is not a pair of arrays of numbers.
    """
    if isinstance(episodes, (str, bytes, Path, np.ndarray)) or not isinstance(episodes, Sequence) or not episodes:
        empty = isinstance(episodes, Sequence) and not episodes
        raise ConfigError(f"{what} is a list of episodes, each (observations, actions) as arrays; got "
                          f"{type(episodes).__name__}{' (empty)' if empty else ''}")
    pairs = []
    for index, episode in enumerate(episodes):
        where = f"episode {index} of {what}"
        if not isinstance(episode, (tuple, list)) or len(episode) != 2:
            raise ConfigError(f"{where} is a pair (observations, actions); got {type(episode).__name__}"
                              f"{f' of {len(episode)}' if isinstance(episode, (tuple, list)) else ''}")
        if isinstance(episode[0], Mapping):  # (fitting, calibration and validation flatten them first)
            raise ConfigError(f"{where}: its observations are a dict of named readings; records are kept as arrays: "
                              "flatten each episode's first (oodmon.monitor.recorded.flattened(observations, "
                              "layout_of(observations, steps=True), steps=True))")
        try:
            observations, actions = np.asarray(episode[0]), np.asarray(episode[1])
        except ValueError as error:  # (ragged lists)
            raise ConfigError(f"{where}: its observations and actions must be arrays ({error})") from None
        if observations.dtype.kind not in "biuf" or actions.dtype.kind not in "biuf":
            raise ConfigError(f"{where}: its observations and actions must be numbers; got arrays of "
                              f"{observations.dtype} and {actions.dtype}")
        pairs.append((observations, actions))
    return pairs


def _checked_episodes(episodes: Any, action_space: gymnasium.Space, what: str,
                      shape: tuple[int, ...] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``episodes`` as ``(observations, actions)`` arrays, each action checked against
    ``action_space`` and the observations of one shape (``shape``, where given); ``what`` names
    them in an error (``fit_episodes``).

    Raises:
        ConfigError: no episodes; an episode that is not a pair of arrays; observations of no step or
            of two shapes; as many actions as neither the observations nor one fewer; an action that
            is not of ``action_space``.
    """
    checked = []
    for index, (observations, actions) in enumerate(_checked_pairs(episodes, what)):
        where = f"episode {index} of {what}"
        if observations.ndim < 2 or len(observations) < 2:
            raise ConfigError(f"{where}: its observations are of shape {observations.shape}; give one row per step, "
                              "two steps at least ((T, ...), T >= 2)")
        shape = shape if shape is not None else observations.shape[1:]
        if observations.shape[1:] != shape:
            raise ConfigError(f"{where}: its observations are of shape {observations.shape[1:]}, the first episode's "
                              f"of {shape}")
        if len(actions) not in (len(observations), len(observations) - 1):
            raise ConfigError(f"{where} has {len(observations)} observations and {len(actions)} actions: give the "
                              "action taken at each observation (as many, or one fewer where the last observation "
                              "came after the last action)")
        if isinstance(action_space, gymnasium.spaces.Box) and action_space.shape == (1,) and actions.ndim == 1:
            actions = actions[:, None]  # one number a step, recorded without its axis
        refusal = _action_refusal(actions, action_space)
        if refusal is not None:
            raise ConfigError(f"{where}: {refusal}")
        checked.append((observations, actions))
    return checked


def _action_refusal(actions: np.ndarray, action_space: gymnasium.Space) -> str | None:
    """Why ``actions``, one per step, are not of ``action_space`` (a sentence), or ``None``. A
    ``Box``'s are any finite numbers of its shape (an env clips those past its bounds)."""
    if isinstance(action_space, gymnasium.spaces.Discrete):
        bad = np.flatnonzero((actions != np.round(actions)) | (actions < 0) | (actions >= action_space.n)) \
            if actions.ndim == 1 else [0]
        if len(bad):
            return (f"its actions are of shape {actions.shape}; give one whole number per step of {action_space}"
                    if actions.ndim != 1 else
                    f"the action at step {bad[0]}, {actions[bad[0]].tolist()!r}, is not of the action space "
                    f"{action_space}")
        return None
    shape = tuple(action_space.shape)
    if actions.shape[1:] != shape:
        return f"its actions are of shape {actions.shape[1:]} each, and the action space {action_space} of {shape}"
    bad = np.flatnonzero(~np.isfinite(actions.reshape(len(actions), -1)).all(axis=1))
    return None if not len(bad) else f"the action at step {bad[0]}, {actions[bad[0]].tolist()!r}, is not finite"


def _space_of(detectors: DetectorSet) -> gymnasium.Space:
    """The action space ``detectors`` were fitted for (:func:`fit_on_episodes` records it).

    Raises:
        ConfigError: a set fitted otherwise (on episodes oodmon played, or its own logs).
    """
    recorded = detectors.fitted_for.get("action_space")
    if not isinstance(recorded, dict):
        raise ConfigError("these detectors were not fitted on recorded episodes (fit_on_episodes()): calibrate them on "
                          "episodes of their policy (oodmon calibrate, calibrate_agent)")
    if "discrete" in recorded:
        return gymnasium.spaces.Discrete(int(recorded["discrete"]))
    return gymnasium.spaces.Box(-np.inf, np.inf, tuple(recorded["box"]), np.float32)


def _recorded_space(action_space: gymnasium.Space) -> dict[str, Any]:
    """What a fitted set records of ``action_space`` (:func:`_space_of` reads it)."""
    if isinstance(action_space, gymnasium.spaces.Discrete):
        return {"discrete": int(action_space.n)}
    return {"box": list(action_space.shape)}


def _check_action_space(action_space: Any) -> gymnasium.Space:
    """``action_space`` where the detectors can read its actions: a ``Discrete`` counted from 0, or a
    ``Box``."""
    if isinstance(action_space, gymnasium.spaces.Discrete) and not action_space.start:
        return action_space
    if isinstance(action_space, gymnasium.spaces.Box):
        return action_space
    raise ConfigError(f"action_space is the deployment's gymnasium space of actions, a Discrete counted from 0 or a "
                      f"Box (a vector of numbers); got {action_space!r}: give your actions as one of those (flattened "
                      "into one vector, or a Discrete's counted from 0)")


def fit_on_episodes(episodes: Sequence[tuple[Any, Any]], action_space: gymnasium.Space, *,
                    detectors: Sequence[str] | None = None,
                    seed: int = DETECTOR_FIT, dynamics_updates: int | None = MAX_UPDATES,
                    on_progress: Progress | None = None) -> DetectorSet:
    """The learned detectors of a deployment oodmon cannot play, fitted on ``episodes`` of its normal
    running, each ``(observations, actions)``: the first two thirds fit, the last third ranks them
    for ``combined``, as a played fit does (:func:`~oodmon.monitor.detectors.fit_detectors`).

    Args:
        episodes: the recorded ID episodes, each ``(observations, actions)``: the observations the
            policy acted on, vectors ``(T, n)`` (or ``(T + 1, n)``: the last after the last action)
            or a camera's pictures (bytes ``(T, H, W)``, ``(T, H, W, 3)``, or stacks ``(T, k, H,
            W)`` whose newest frame is the last; floats of 16 pixels or more each way) or a dict of
            named readings (``{"angle": (T,), "velocity": (T, 2)}``, flattened by
            :func:`layout_of`, which the set records: the monitor flattens each step's dict alike,
            and the alarms name its readings ``velocity[1]``), and the
            action it took at each, ``(T,)`` integers of a ``Discrete`` or ``(T, n)`` numbers of a
            ``Box``. Episodes with a reading that is not finite are left out.
        action_space: the actions' gymnasium space: ``Discrete(n)``, read one-hot, or a ``Box``.
        detectors: the detectors to fit (default: ``dynamics``, ``drift`` and ``combined``, as in
            an env oodmon has no variants of; of pictures ``frames``, ``stillness`` and
            ``combined``, and ``vanishing`` or ``motion`` where named).
        seed: seeds the models' fits.
        dynamics_updates: as :func:`~oodmon.monitor.detectors.fit_detectors` takes it.
        on_progress: ``on_progress(stage, done, total)`` (see :mod:`oodmon.progress`).

    Raises:
        ConfigError: episodes that are not as above (said naming the episode), an action space of
            another kind, fewer than 3 episodes that can be fitted on, or a detector that needs the
            policy's samples or features (``spread``, ``features``, ``scaled_spread``).
    """
    from oodmon.monitor.detectors.base import Trajectory
    from oodmon.monitor.detectors.fitting import DEFAULT_FIT_STEPS, _checked_actions, _fitted, _named
    from oodmon.monitor.detectors.frames import is_picture

    action_space = _check_action_space(action_space)
    first = episodes[0][0] if isinstance(episodes, Sequence) and episodes and isinstance(episodes[0], (tuple, list)) \
        and episodes[0] else None
    layout = layout_of(first, steps=True) if isinstance(first, Mapping) else None  # named sensors: flattened
    checked = _checked_episodes(_flat_episodes(episodes, layout, "episodes"), action_space, "episodes")
    check_max_updates(dynamics_updates, "dynamics_updates")
    seed = check_seed(seed)
    shape, dtype = checked[0][0].shape[1:], checked[0][0].dtype
    picture = is_picture(shape, dtype)  # a camera's: the camera's detectors read it
    seen = gymnasium.spaces.Box(0, 255, shape, np.uint8) if picture and dtype == np.uint8 else \
        gymnasium.spaces.Box(-np.inf, np.inf, shape, np.float32)
    spaces = _Spaces(seen, action_space)
    # task "": a deployment oodmon has no variants of (drift fitted beside dynamics by default)
    if detectors is not None and (isinstance(detectors, str) or not isinstance(detectors, Sequence)):
        raise ConfigError(f"detectors is a list of the detectors' names (['dynamics', 'combined']); got "
                          f"{detectors!r:.40}")
    names = _named(_no_policy, spaces, "", detectors)
    policy_read = [name for name in names if name in POLICY_READ]
    if policy_read:
        raise ConfigError(f"the {policy_read[0]} detector reads the policy's samples or features, which recorded "
                          "episodes do not hold (oodmon does not run the policy here): fit dynamics, drift or combined")
    n_actions = _checked_actions(names, _no_policy, spaces)

    usable = [(observations if picture else observations.astype(np.float64), actions)
              for observations, actions in checked if np.isfinite(observations).all()]
    if len(usable) < 3:
        raise ConfigError(f"{len(usable)} of the {len(checked)} episodes can be fitted on (every reading finite); "
                          "fitting needs at least 3 (two thirds fit, one third ranks)")
    trajectories = [Trajectory(observations, actions[:len(observations) - 1]) for observations, actions in usable]
    steps = sum(len(observations) for observations, _ in usable)  # (as a played fit counts them: all its episodes')
    if "dynamics" in names and steps < DEFAULT_FIT_STEPS:
        warnings.warn(f"the detectors are fitted on {steps:,} recorded steps ({len(usable)} episodes), fewer than the "
                      f"{DEFAULT_FIT_STEPS:,} a played fit of an env oodmon has no variants of holds: on Acrobot "
                      "(2026-11-29) a fit on about 10,000 steps alarmed 17 of 70 shifted episodes, one on 45,000 steps "
                      "49 of 70; record more normal running where you can", FewRecordedStepsWarning, stacklevel=2)
    recorded = {"seed": None, "action_space": _recorded_space(action_space),
                FITTED_EPISODES: [episode_hash(*pair) for pair in checked]}
    if layout is not None:
        recorded[LAYOUT] = layout
    return _fitted(trajectories, names, None, None, "chosen_std", n_actions, seed, dynamics_updates, on_progress,
                   policy_hash=None, obs_noise=0.0, workers=1, max_steps=None, recorded=recorded)


def calibrate_on_episodes(detectors: DetectorSet, episodes: Sequence[tuple[Any, Any]], far: float = 0.05, *,
                          detector: str | None = None,
                          confidence: float | None = DEFAULT_CONFIDENCE, consecutive: int | None = None,
                          window: int | None = None, warmup: int = 0, mode: str = "episode",
                          reading_names: Sequence[str] | None = None,
                          on_progress: Progress | None = None) -> Threshold:
    """The alarm threshold of a deployment oodmon cannot play, calibrated on recorded ID
    ``episodes`` (each ``(observations, actions)``, as :func:`fit_on_episodes` takes them) that
    ``detectors`` were not fitted on: each is scored step by step by a :class:`Monitor` of those
    detectors, as the deployment's steps will be, and the threshold is the one
    :func:`~oodmon.monitor.calibrate` makes of those scores (``far``, ``confidence``,
    ``consecutive``, ``window``, ``warmup`` and ``mode`` as there; with probability ``confidence``
    its false-alarm rate over episodes like these is at most ``far``). ``mode="step"`` bounds the
    share of steps above it instead (each episode a cluster of steps): a deployment that runs on
    without episodes, its record cut into stretches.

    ``detector``: the one the alarm reads (default ``combined`` where fitted, else the set's last).
    ``reading_names``: the name of each number of the observations, recorded in the threshold (see
    :class:`~oodmon.monitor.Monitor`).

    Raises:
        ConfigError, InvalidParameterError: episodes as :func:`fit_on_episodes` refuses them, or of
            another observation shape than the detectors', an episode the detectors were fitted on,
            too few episodes for ``far`` and ``confidence``, a detector the set does not have.
    """
    from oodmon.monitor.alarms import default_consecutive, default_window
    from oodmon.monitor.monitor import check_reading_names
    from oodmon.monitor.threshold import calibrate, check_step_episodes, conformal_rank

    if not isinstance(detectors, DetectorSet):
        raise ConfigError(f"detectors is the set fit_on_episodes() returned (or DetectorSet.load); got "
                          f"{type(detectors).__name__}")
    shape, layout = detectors.fitted_for.get("obs_shape"), detectors.fitted_for.get(LAYOUT)
    checked = _checked_episodes(_flat_episodes(episodes, layout, "episodes"), _space_of(detectors), "episodes",
                                None if shape is None else tuple(shape))
    names = check_reading_names(reading_names)
    if names is None and layout is not None:  # a dict's readings named by its keys
        names = tuple(layout_names(layout))
    if detector is None:
        detector = "combined" if "combined" in detectors else detectors.names[-1]
    if not isinstance(detector, str) or detector not in detectors:
        raise ConfigError(f"the alarm reads the {detector} detector, which the set does not have (it has "
                          f"{', '.join(detectors.names)})")
    hashes = [episode_hash(*pair) for pair in checked]
    _check_fresh(hashes, "calibration", {"the detectors were fitted on": detectors.fitted_for.get(FITTED_EPISODES)},
                 "they learned it and read it low, so the threshold's promise would not hold; calibrate on other "
                 "recorded episodes")
    if mode not in ("episode", "step"):
        raise InvalidParameterError(f"mode={mode!r} is not allowed; use 'episode' or 'step'")
    if mode == "episode":  # too few episodes for far: said before they are scored
        conformal_rank(len(checked), far, confidence)
    elif mode == "step" and confidence is not None:
        check_step_episodes(len(checked), far, confidence)
    consecutive = default_consecutive(detector) if consecutive is None else consecutive
    window = default_window(None, detector) if window is None else window
    scored = _scored(detectors, checked, "calibration episodes", on_progress, detector=detector, reading_names=names)
    threshold = calibrate([scores for scores, _ in scored], far, consecutive=consecutive, window=window,
                          detector=detector, confidence=confidence, warmup=warmup, mode=mode,
                          detectors_hash=detectors.fingerprint(detector))
    return replace(threshold, reading_names=None if names is None else list(names),
                   episode_hashes=hashes)


def validate_on_episodes(threshold: Threshold | str | Path, episodes: Sequence[tuple[Any, Any]], *,
                         detectors: DetectorSet | None = None, on_progress: Progress | None = None) -> Validation:
    """The threshold of a deployment oodmon cannot play, checked on fresh recorded ID ``episodes``
    (each ``(observations, actions)``, as :func:`fit_on_episodes` takes them): each is fed to the
    monitor step by step, and those that alarmed are counted beside the target, with their 95%
    interval (a :class:`~oodmon.monitor.Validation`, as ``oodmon validate`` gives it: ``alarmed``,
    ``total``, ``low``, ``high``, ``verdict``). ``threshold``: a :class:`Threshold` with
    ``detectors``, the set it was calibrated with, or the path of one saved beside its detectors
    (``watch_recorded(save=...)``).

    Raises:
        ConfigError: episodes as :func:`fit_on_episodes` refuses them; one the detectors were fitted
            on or the threshold calibrated on (not fresh: the count would read low); a threshold
            without its detectors, or of other ones (the monitor's check).
    """
    if isinstance(threshold, (str, Path)):
        if detectors is not None:
            raise ConfigError("give the threshold's path (its detectors are read from beside it), or a Threshold with "
                              "detectors=, not a path with detectors=")
        threshold, detectors = _saved(threshold)
    if not isinstance(threshold, Threshold) or not isinstance(detectors, DetectorSet):
        raise ConfigError("give the threshold's path, or a Threshold with detectors= the set it was calibrated with "
                          f"(got {type(threshold).__name__} and {type(detectors).__name__})")
    shape, layout = detectors.fitted_for.get("obs_shape"), detectors.fitted_for.get(LAYOUT)
    checked = _checked_episodes(_flat_episodes(episodes, layout, "episodes"), _space_of(detectors), "episodes",
                                None if shape is None else tuple(shape))
    _check_fresh([episode_hash(*pair) for pair in checked], "validation",
                 {"the detectors were fitted on": detectors.fitted_for.get(FITTED_EPISODES),
                  "the threshold was calibrated on": threshold.episode_hashes},
                 "it is not fresh, and would read low; validate on episodes neither saw")
    scored = _scored(detectors, checked, "validation episodes", on_progress, threshold=threshold)
    return _counted(scored, threshold, 0.0, None)


def save_records(path: str | Path, episodes: Sequence[tuple[Any, Any]]) -> Path:
    """Write recorded episodes, each ``(observations, actions)``, to ``path`` (an ``.npz`` of arrays
    ``observations_<i>`` and ``actions_<i>``, no pickles): what :func:`load_records` and the
    commands' ``--records`` read.

    Raises:
        ConfigError: episodes that are not pairs of arrays of numbers (see :func:`fit_on_episodes`).
    """
    from oodmon.outputs import check_output_file, write_whole

    if not isinstance(path, (str, Path)):
        raise ConfigError(f"path is the file to write the records to; got {type(path).__name__}")
    checked = _checked_pairs(episodes, "episodes")
    path = check_output_file(path, parameter="path")  # (empty, a folder, a device: said)
    arrays = {}
    for index, (observations, actions) in enumerate(checked):
        arrays[f"observations_{index}"], arrays[f"actions_{index}"] = observations, actions

    def write(part: Path) -> None:
        with open(part, "wb") as file:  # (np.savez adds .npz to a name without it)
            np.savez(file, **arrays)

    write_whole(path, write)  # (whole or not at all: a kill mid-write leaves the file before)
    return path


def load_records(path: str | Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The recorded episodes :func:`save_records` wrote to ``path``, in their order (read without
    unpickling: an array of Python objects is refused).

    Raises:
        ConfigError: a missing or unreadable file, or one that is not such records.
    """
    import zipfile

    from oodmon.jsonfile import special_file

    if not isinstance(path, (str, Path)):
        raise ConfigError(f"path is a file of recorded episodes; got {type(path).__name__}")
    special = special_file(path)
    if special is not None:  # (/dev/zero would be read for ever)
        raise ConfigError(f"{path} is {special}, not a file of recorded episodes")
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):  # (one array, an .npy)
            raise ValueError("it holds one array")
        with data:
            arrays = {name: data[name] for name in data.files}
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file of recorded episodes (oodmon.monitor.save_records writes "
                          "one)") from None
    except IsADirectoryError:
        raise ConfigError(f"{path} is a folder, not a file of recorded episodes") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise ConfigError(f"{path} is not a file of recorded episodes (an .npz of observations_<i> and "
                          f"actions_<i>, as oodmon.monitor.save_records writes): {error}") from None
    count = sum(name.startswith("observations_") for name in arrays)
    expected = {f"{part}_{index}" for index in range(count) for part in ("observations", "actions")}
    if not count or set(arrays) != expected:
        held = ", ".join(sorted(arrays)[:4]) + (", ..." if len(arrays) > 4 else "")
        raise ConfigError(f"{path} is not a file of recorded episodes: it holds {held or 'nothing'}, not "
                          "observations_<i> and actions_<i> of each episode i from 0 (oodmon.monitor.save_records "
                          "writes them)")
    return [(arrays[f"observations_{index}"], arrays[f"actions_{index}"]) for index in range(count)]


def _check_fresh(hashes: list[str], use: str, made_from: dict[str, Any], why: str) -> None:
    """Refuse, naming the first, the episodes of ``hashes`` (:func:`episode_hash`, each computed
    once) for ``use`` among those whose hashes ``made_from`` holds by what was made from them
    (``{"the detectors were fitted on": [...]}``), saying ``why``."""
    for what, made in made_from.items():
        known = set(made or ())
        found = [index for index, hashed in enumerate(hashes) if hashed in known]
        if found:
            raise ConfigError(f"episode {found[0]} of the {use} episodes ({len(found)} in all) is one {what}: {why}")


def _scored(detectors: DetectorSet, episodes: list[tuple[np.ndarray, np.ndarray]], stage: str,
            on_progress: Progress | None, **monitor: Any) -> list[tuple[np.ndarray, list[int]]]:
    """Each of ``episodes`` fed step by step to a :class:`~oodmon.monitor.Monitor` of ``detectors``
    made with ``monitor`` (as the deployment's steps will be): of each, the alarm detector's per-step
    scores and the steps at which an alarm was raised. ``on_progress(stage, done, total)``."""
    from oodmon.monitor.calibration import _ScoresAndAlarms
    from oodmon.monitor.monitor import Monitor, OffCalibrationWarning

    sink = _ScoresAndAlarms()
    with warnings.catch_warnings(), Monitor(None, detectors=detectors, sinks=[sink], log_observations=False,
                                            **monitor) as watching:
        warnings.simplefilter("ignore", OffCalibrationWarning)  # (episodes longer than calibration's: counted)
        for done, (observations, actions) in enumerate(episodes):
            watching.begin_episode()
            for obs, action in zip(observations, actions):
                watching.step(obs, action=action)
            watching.end_episode()
            if on_progress is not None:
                on_progress(stage, done + 1, len(episodes))
    return sink.episodes


def _saved(path: str | Path) -> tuple[Threshold, DetectorSet]:
    """The threshold at ``path`` and the detectors beside it (``<path>.detectors/``).

    Raises:
        ConfigError: the file is no threshold, or its detectors are missing.
    """
    if not isinstance(path, (str, Path)):
        raise ConfigError(f"threshold= is the path of a calibration saved before (watch_recorded(save=...)); got "
                          f"{type(path).__name__}")
    threshold = Threshold.load(path)
    beside = Path(f"{path}.detectors")
    if not (beside / "detectors.json").is_file():
        raise ConfigError(f"{path}'s detectors, fitted beside it in {beside}, are missing: copy that folder along "
                          "with the file, or fit and calibrate again (save=)")
    return threshold, DetectorSet.load(beside)


def watch_recorded(fit_episodes: Sequence[tuple[Any, Any]] | None = None,
                   calibration_episodes: Sequence[tuple[Any, Any]] | None = None, *,
                   action_space: gymnasium.Space | None = None,
                   far: float = 0.05, confidence: float | None = DEFAULT_CONFIDENCE, detector: str | None = None,
                   sinks: Sequence[Sink] = (), callbacks: Sequence[Callable[[AlarmEvent], Any]] = (),
                   save: str | Path | None = None, threshold: str | Path | None = None, mode: str = "episode",
                   reading_names: Sequence[str] | None = None, on_progress: Progress | None = None) -> Any:
    """The :class:`~oodmon.monitor.Monitor` of a deployment oodmon cannot play, made from its
    recorded ID episodes: the detectors fitted on ``fit_episodes`` (:func:`fit_on_episodes`), the
    threshold calibrated on ``calibration_episodes`` (:func:`calibrate_on_episodes`; ``far``,
    ``confidence``, ``detector``, ``mode``, ``reading_names`` as there). It runs no policy: give it
    each step's observation and the action taken (``monitor.step(obs, action=a)`` between
    ``monitor.begin_episode()`` and ``monitor.end_episode()``). ``sinks``, ``callbacks``: as the
    Monitor's.

    ``save`` writes the threshold there and the detectors to ``<save>.detectors/`` (as ``oodmon
    calibrate --out`` does); ``threshold`` reads such a pair at a later start instead of fitting and
    calibrating (the episodes and the spaces are then left out).

    Raises:
        ConfigError: ``threshold`` with episodes, neither, or ``save`` beside it; what the two
            functions refuse; a ``save`` path that holds a file that is no threshold; a
            ``threshold`` whose detectors are missing.
    """
    from oodmon.monitor.calibration import save_calibration
    from oodmon.monitor.monitor import Monitor, check_reading_names
    from oodmon.outputs import check_output_file, replaced_file

    check_reading_names(reading_names)
    if threshold is not None:
        given = [name for name, value in (("fit_episodes", fit_episodes), ("calibration_episodes",
                                                                             calibration_episodes),
                                          ("action_space", action_space), ("save", save)) if value is not None]
        if given:
            raise ConfigError(f"threshold= reads a calibration made before; leave out {', '.join(given)} (or leave out "
                              "threshold= to fit and calibrate anew)")
        calibration, detectors = _saved(threshold)
    else:
        missing = [name for name, value in (("fit_episodes", fit_episodes), ("calibration_episodes",
                                                                               calibration_episodes),
                                            ("action_space", action_space)) if value is None]
        if missing:
            raise ConfigError(f"give {', '.join(missing)} (recorded ID episodes, each (observations, actions), and "
                              "their action space), or threshold= a calibration saved before")
        if save is not None:  # said now, not after the fit
            check_output_file(save, parameter="save")
            replaced_file(save, parameter="save", holds="threshold", read=Threshold.load)
        detectors = fit_on_episodes(fit_episodes, action_space, on_progress=on_progress)
        calibration = calibrate_on_episodes(detectors, calibration_episodes, far, detector=detector,
                                            confidence=confidence, mode=mode, reading_names=reading_names,
                                            on_progress=on_progress)
        if save is not None:
            save_calibration(calibration, save, detectors)
    return Monitor(None, calibration, detectors=detectors, sinks=sinks, callbacks=callbacks,
                   reading_names=reading_names)
