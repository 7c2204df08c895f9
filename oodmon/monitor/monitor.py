"""The runtime monitor: the policy's action, its uncertainty score, the alarm rule, the logs.

Three ways to use it:

- a loop of your own: ``monitor.begin_episode(...)``, then ``action = monitor.step(obs,
  shifted=...)`` (or ``monitor.step(obs, action=a)`` when your own policy acts) and
  ``monitor.add_reward(r)`` per step, then ``monitor.end_episode()``;
- ``monitor.run_episode(env, seed=...)`` runs the whole loop in an env;
- :class:`~oodmon.monitor.monitored_env.MonitoredEnv` wraps an env: ``env.step()`` without an
  action lets the monitored policy act; with an action (yours, say a safe fallback after an
  alarm) the monitor still scores and logs the policy's view of the step.

A :class:`Monitor` is a context manager over a run: it opens its sinks on entry and closes them
(finishing the files) on exit, also after an exception. A monitor that is opened and never
closed (a script that forgets ``close()``) is closed when the interpreter exits, so its files are
finished all the same; an episode cut by an exception or Ctrl-C is logged as ``interrupted``.
"""

from __future__ import annotations

import atexit
import copy
import functools
import json
import math
import shlex
import sys
import warnings
import weakref
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.agent import Agent
from oodmon.agents.estimators import EnsembleEstimator, Estimate, UncertaintyEstimator
from oodmon.envs.checks import step_naming_refusal
from oodmon.envs.readings import reading_names
from oodmon.envs.registration import env_id_of, obs_noise_of_env, onset_of_env, variant_of_env
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import AlarmEvent, AlarmTracker, check_consecutive, check_window, default_consecutive
from oodmon.monitor.detectors import Detector, DetectorSet, SpreadDetector, StepContext
from oodmon.monitor.detectors.frames import is_picture, newest_frame
from oodmon.monitor.records import EpisodeRecord, EpisodeSegment, EpisodeStart, RunInfo, StepRecord
from oodmon.monitor.scores import DEFAULT_SCORE
from oodmon.monitor.sinks.base import Sink, SinkGroup
from oodmon.monitor.threshold import Threshold
from oodmon.progress import Progress
from oodmon.versions import library_versions, machine
from oodmon.hashing import file_sha256, other_weights
from oodmon.validation import is_finite_real, is_real, is_whole

__all__ = ["GIVEN_CHECKED", "SEGMENT_STEPS", "ActionTally", "AlarmCallback", "Monitor", "NonFiniteObservationWarning",
           "OtherActionsWarning", "PolicyCannotAct", "same_action"]

#: Steps of an episode after which the monitor hands its segment on (see ``Monitor(segment_steps=)``):
#: about 10 MB of score arrays in ``McapSink`` with four detectors, 17 minutes at 100 decisions a second.
SEGMENT_STEPS = 100_000

#: An alarm names the readings whose change the dynamics model predicted at least this many of its
#: standard deviations off (:attr:`AlarmEvent.readings`), at most ``MOST_READINGS`` of them. On ID
#: transitions the worst reading stays well below it: 1.43 at most over 10 episodes of the shipped
#: CartPole ensemble, 1.45 of the Pendulum Dropout agent; at the first alarm of a shifted episode it
#: read 9-1,680 (``scripts/alarm_readings.py``, 2026-12-07; docs/monitor.md, "Which reading").
READING_SD = 3.0
MOST_READINGS = 2

#: The first actions given to a monitor (``step(obs, action=...)``) it compares with the policy's own
#: decision at their observation, where that decision draws nothing (:class:`OtherActionsWarning`).
GIVEN_CHECKED = 100

#: Called with each alarm; returning True asks ``run_episode`` / ``MonitoredEnv`` to end the
#: episode (the default is to let the policy go on).
AlarmCallback = Callable[[AlarmEvent], "bool | None"]


def _calibrated_with(threshold: Any) -> str:
    """The words naming the fitted detectors a threshold was calibrated with (its file records their
    hash), to end a message about missing detectors with; ``""`` where it records none."""
    if isinstance(threshold, Threshold) and threshold.detectors_hash:
        return f"; the threshold was calibrated with fitted {threshold.detector} detectors {threshold.detectors_hash[:19]}..."
    return ""


def _given_detectors(detectors: DetectorSet | Sequence[Detector] | None) -> DetectorSet:
    """``Monitor(detectors=...)`` as a set: a DetectorSet, a list of Detector objects, or None (none).

    Raises:
        ConfigError: anything else (a name, one detector on its own, a list holding other things).
    """
    if detectors is None:
        return DetectorSet([])
    if isinstance(detectors, DetectorSet):
        return detectors
    given = None if isinstance(detectors, (str, Detector)) else list(detectors)
    if given is None or not all(isinstance(d, Detector) for d in given):
        raise ConfigError(f"detectors={detectors!r} is not allowed; give fitted detectors (a DetectorSet, e.g. "
                          "detectors_for(agent) or DetectorSet.load(folder), or a list of Detector objects); "
                          "detector='dynamics' names the one the alarm reads")
    return DetectorSet(given)


def policy_hash(agent: Agent | None) -> str:
    """``sha256:<hex>`` of an agent's ``model.safetensors``, or ``"unknown"`` (no file behind it)."""
    if agent is not None and agent.metadata.get("policy_hash"):
        return agent.metadata["policy_hash"]  # models from elsewhere: the hash of their files
    if agent is None or agent.path is None:
        return "unknown"
    path = agent.path / "model.safetensors"
    return "sha256:" + file_sha256(path) if path.exists() else "unknown"


def policy_hash_aliases(agent: Agent | None) -> tuple[str, ...]:
    """Other hashes a threshold or a detector set may have recorded for the same weights: of SB3
    models loaded from files, the hash of the files, which oodmon recorded until 2026-12-04; of a
    plain policy without weights, its name alone, recorded until 2026-12-06 (since, its code too)."""
    metadata = {} if agent is None else agent.metadata
    return tuple(metadata[key] for key in ("files_hash", "name_hash") if metadata.get(key))


def run_about(metadata: dict[str, Any]) -> dict[str, str]:
    """:attr:`RunInfo.about` of a run of the agent with ``metadata``: the command line, the
    machine's CPU kind (:func:`~oodmon.versions.machine`), and the env id, model files,
    VecNormalize statistics, VecFrameStack depth and deployed model (or the ensemble's mean) of a
    model from elsewhere (:mod:`oodmon.agents.sb3`) and the hash of its files (what its logs
    recorded as ``policy_hash`` before 2026-12-04), or the name of a plain policy
    (:mod:`oodmon.agents.plain`) and, of one bound to its code, the ``policy_hash`` of its name
    alone (what its logs recorded before 2026-12-06)."""
    about = {"command": shlex.join(sys.argv), "machine": machine()}
    for key in ("env_id", "policy", "files_hash", "name_hash", "deployed"):
        if metadata.get(key):
            about[key] = str(metadata[key])
    for key in ("models", "vec_normalize", "frame_stack"):
        if metadata.get(key):
            about[key] = json.dumps(metadata[key])
    return about


def check_reading_names(reading_names: Sequence[str] | None) -> tuple[str, ...] | None:
    """``reading_names`` (the :class:`Monitor`'s, :func:`~oodmon.monitor.calibrate_agent`'s) as a
    tuple, or :class:`~oodmon.errors.InvalidParameterError` where it is not a list of texts (their
    count is checked against the first observation, :meth:`Monitor.step`).

    Example:
        >>> check_reading_names(["x", "theta"]), check_reading_names(None)
        (('x', 'theta'), None)
    """
    if reading_names is not None and (isinstance(reading_names, (str, bytes)) or not isinstance(
            reading_names, Sequence) or not all(isinstance(name, str) for name in reading_names)):
        raise InvalidParameterError(f"reading_names={reading_names!r} is not allowed; give a list of texts, the "
                                    "name of each number of the observations by index")
    return None if reading_names is None else tuple(reading_names)


class Monitor:
    """Wraps a deployed policy; scores every step against a calibrated threshold.

    Args:
        policy: a loaded :class:`~oodmon.agents.Agent` or any uncertainty estimator (it acts, and
            its samples give the ``spread`` detector); a plain callable ``obs -> action`` (it acts;
            no samples); or ``None``: the monitor only watches, each action is passed to
            :meth:`step`.
        threshold: a :class:`Threshold` (its detector, score and rule are used), a number, or
            ``None`` (scores are logged, no alarms).
        score: the spread score's name when ``threshold`` is not a :class:`Threshold` (default: the
            score of the ``spread`` detector among ``detectors``, or ``chosen_std``).
        detectors: fitted detectors to run at every step (a :class:`DetectorSet`, e.g. from
            :func:`~oodmon.monitor.detectors.fit_detectors` or ``DetectorSet.load``); ``spread``
            joins them whenever the policy has samples. Every detector's score is logged.
        detector: the detector the alarm reads when ``threshold`` is not a :class:`Threshold`
            (default ``spread``, or the set's last, ``combined`` when it has one).
        consecutive: m of the alarm rule when ``threshold`` is not a :class:`Threshold` (default:
            3 for the spread detector, 1 for a learned one).
        window: the alarm rule's averaging window when ``threshold`` is not a :class:`Threshold`.
        sinks: where records go (:class:`MemorySink`, :class:`McapSink`, :class:`RerunSink`).
        callbacks: called with every :class:`AlarmEvent`.
        strict: a failing sink raises instead of warning.
        log_observations: put what the agent observed into the step records: vector observations
            as numbers, image observations (Pong) as the ``frame`` given to :meth:`step`. Off, the
            records carry scores only (calibration keeps no frames in memory).
        force: use a :class:`Threshold` or detectors made for another task, method, score or
            weights anyway, with a warning (by default that is a :class:`~oodmon.errors.ConfigError`).
        render: put a picture of each CartPole or Pendulum state into the step records (drawn from
            the observation, :func:`~oodmon.envs.preview.draw_state`): the logs' frames, shown by
            Rerun and Foxglove beside the scores. Off by default (benchmarks write no pictures).
        segment_steps: every this many steps of an episode, the rewards the monitor keeps for it
            and the score arrays of sinks that keep them (:class:`McapSink`) are handed on as a
            segment and dropped: an episode that never ends (a policy deployed in an env that
            does not reset) keeps bounded memory. Such an episode's record has ``rewards=None``
            (the log holds them, segment by segment). Default 100,000.
        reading_names: the name of each number of the observations the detectors read, by index
            (a robot's ``("knee angle", "knee velocity", ...)``): an alarm names its readings by
            them (``[5] (knee velocity)``), and the log keeps them for replay. Default: the names
            of an env whose layout is known (:mod:`oodmon.envs.readings`), a dict observation's
            keys; none of any other (its readings by index alone). As many names as the
            observations have numbers (checked at the first step). A :class:`Threshold` that
            records names (``oodmon calibrate --reading-names``) gives them where these are not given.

    Raises:
        ConfigError: the threshold or the detectors were made for another policy or score (see
            ``force``), the threshold names a detector the monitor does not have, or a detector
            needs samples a plain policy does not give.

    Example:
        >>> from oodmon.agents import load
        >>> from oodmon.monitor import MemorySink
        >>> sink = MemorySink()
        >>> with Monitor(load("cartpole", "ensemble"), threshold=4.6, sinks=[sink]) as monitor:
        ...     record = monitor.run_episode(gymnasium.make("oodmon/CartPole-v1", length=2.0), seed=0)
        >>> len(sink.steps) == record.length, record.first_alarm_step is not None
        (True, True)
    """

    def __init__(
        self,
        policy: Agent | UncertaintyEstimator | Callable[[np.ndarray], Any] | None,
        threshold: Threshold | float | None = None,
        *,
        score: str | None = None,
        detectors: DetectorSet | Sequence[Detector] | None = None,
        detector: str | None = None,
        consecutive: int | None = None,
        window: int | None = None,
        sinks: Sequence[Sink] = (),
        callbacks: Sequence[AlarmCallback] = (),
        strict: bool = False,
        log_observations: bool = True,
        force: bool = False,
        render: bool = False,
        segment_steps: int = SEGMENT_STEPS,
        reading_names: Sequence[str] | None = None,
    ) -> None:
        self._made_with = {"policy": policy, "threshold": threshold, "score": score, "detectors": detectors,
                           "detector": detector, "consecutive": consecutive, "window": window, "strict": strict,
                           "log_observations": log_observations, "force": force, "render": render,
                           "segment_steps": segment_steps, "reading_names": reading_names}  # see twin()
        if not is_whole(segment_steps):
            raise InvalidParameterError(f"segment_steps={segment_steps!r} is not allowed; it must be an integer >= 1")
        self._given_names = check_reading_names(reading_names)
        self._names_from = "reading_names (--reading-names)"
        if reading_names is None and isinstance(threshold, Threshold) and threshold.reading_names is not None:
            self._given_names = tuple(threshold.reading_names)
            self._names_from = "the threshold's reading_names (calibrate --reading-names)"
        self._names_checked = self._given_names is None  # against the first observation (step())
        self.segment_steps = segment_steps
        if isinstance(policy, Agent):
            self.agent, self.estimator, self._act = policy, policy.estimator, policy.deploy
        elif isinstance(policy, UncertaintyEstimator):
            self.agent, self.estimator, self._act = None, policy, None
        elif policy is None or callable(policy):
            self.agent, self.estimator, self._act = None, None, policy
        else:
            raise ConfigError(f"the monitor watches an oodmon Agent, an uncertainty estimator, a callable obs -> "
                              f"action, or None (you pass each action to step()); got {type(policy).__name__}")
        self._dicts = self.agent is not None and self.agent.dict_space is not None  # see step()
        self._dict_names: tuple[str, ...] | None = None  # what an alarm names a dict's readings (_readings)
        self._masked = self.agent is not None and self.agent.reads_masks  # see _tell_masks()
        self._own = self.agent is not None and self.agent.reads_own  # a stack, or a dict with pictures: see step()
        self._action_parts = self.agent is not None and self.agent.action_parts is not None  # see step()
        self.policy_hash = policy_hash(self.agent)
        self._aliases = policy_hash_aliases(self.agent)
        if isinstance(threshold, Threshold):
            if score is not None and score != threshold.score:
                raise ConfigError(f"score={score!r} contradicts the threshold file's score {threshold.score!r}")
            if detector is not None and detector != threshold.detector:
                raise ConfigError(f"detector={detector!r} contradicts the threshold file's detector "
                                  f"{threshold.detector!r}")
            meta = self.agent.metadata if self.agent is not None else {}
            differences = threshold.check_matches(task=meta.get("task"), method=meta.get("method"),
                                                  score=threshold.score, policy_hash=self.policy_hash,
                                                  aliases=self._aliases,
                                                  masks=getattr(self.estimator, "masks", None),
                                                  samples=getattr(self.estimator, "n_samples", None))
            notes = self._in_memory_note(threshold.policy_hash) + self._models_note(threshold)
            self._refuse_or_warn("the threshold", differences + notes, force)
            score, consecutive, value = threshold.score, threshold.consecutive, threshold.value
            window, detector = threshold.window, threshold.detector
            rule, reference, warmup = threshold.rule, threshold.reference_scores(), threshold.warmup
        else:
            if threshold is not None and (not is_real(threshold) or math.isnan(threshold)):  # NaN: no alarm, ever
                raise InvalidParameterError(f"threshold={threshold!r} is not allowed; give a number, a Threshold "
                                            "(oodmon.monitor.calibrate, Threshold.load), or None for no alarms")
            value = math.nan if threshold is None else float(threshold)
            rule, reference, warmup = "consecutive", None, 0
        self.threshold = value
        # The world the threshold's bound is for: an episode played in another is warned of, once a noise.
        self._calibration_noise = threshold.calibration_noise if isinstance(threshold, Threshold) else None
        self._noises_warned: set[float] = set()
        # and the episodes it is for: a step past the longest of them is warned of, once
        self._longest = threshold.covered_steps if isinstance(threshold, Threshold) else None
        self._longer_warned = False
        given = _given_detectors(detectors)
        # No score asked for: a spread detector among those given keeps its own.
        self.score_name = score or (given["spread"].score_name if "spread" in given else DEFAULT_SCORE)
        calibrated_with = _calibrated_with(threshold)
        self.detectors = self._detector_set(given, detector, force, calibrated_with)
        self.detector = detector or ("spread" if "spread" in self.detectors else self.detectors.names[-1])
        if self.detector not in self.detectors:
            raise ConfigError(
                f"the alarm reads the {self.detector!r} detector, which this monitor does not have (it has "
                f"{', '.join(self.detectors.names)}); give the fitted detectors (Monitor(detectors=...): an oodmon "
                f"agent's shipped ones are detectors_for(agent); --detectors DIR) or a threshold calibrated for one "
                f"of those{calibrated_with}"
            )
        self._fitted = self.detectors.fingerprints()  # what each learned detector's fit is: the log records it
        if isinstance(threshold, Threshold) and threshold.detectors_hash:
            these = self._fitted.get(self.detector)
            if these != threshold.detectors_hash:
                why = (f"it was calibrated with other fitted {self.detector} detectors ({threshold.detectors_hash[:19]}..., "
                       f"these are {str(these)[:19]}...), whose scores are on another scale (fitting again, "
                       "even by the same command, gives other detectors on another CPU kind or package versions); "
                       "give those it was calibrated with (--detectors DIR, Monitor(detectors=...))")
                self._refuse_or_warn("the threshold", [why], force)
        self.tracker = AlarmTracker(value, default_consecutive(self.detector) if consecutive is None
                                    else check_consecutive(consecutive),
                                    1 if window is None else check_window(window), rule=rule, reference=reference,
                                    warmup=warmup)
        # One on its own, not in a list (list() of one sink said "'MemorySink' object is not iterable").
        if hasattr(sinks, "write_step"):
            raise ConfigError(f"sinks is a list: sinks=[{type(sinks).__name__}(...)], not one on its own")
        if callable(callbacks):
            name = getattr(callbacks, "__name__", type(callbacks).__name__)  # a function's own name, not "function"
            raise ConfigError(f"callbacks is a list: callbacks=[{name}], not one on its own")
        self.sinks = SinkGroup(list(sinks), strict=strict)  # (which refuses what is no sink)
        self.callbacks = list(callbacks)
        if isinstance(callbacks, str) or not all(map(callable, self.callbacks)):  # else said at the first alarm
            raise ConfigError(f"callbacks={callbacks!r:.60}: give a list of functions, each called with the AlarmEvent "
                              "of every alarm")
        self.log_observations = log_observations
        self.render = render
        self.episode = -1
        self._opened = False
        self._in_episode = False
        self._episode_owner: weakref.ref | None = None  # see MonitoredEnv
        self.stop_requested = False
        self.last_step: StepRecord | None = None  # the record of the last step scored
        self.last_cause: str | None = None  # what raised the last step's score, while the alarm rule held there
        self.last_alarm: AlarmEvent | None = None  # the alarm raised at the last step (None: none began there)
        self.stop_event: AlarmEvent | None = None  # the alarm a callback ended the episode with
        self.alarms_raised = 0  # alarms of the whole run
        # Actions given (step(obs, action=...)) before an episode's first alarm, compared with the
        # policy's own decision, and those that differed (OtherActionsWarning); MonitorCallback,
        # which checks its training steps itself, turns it off.
        self.compares_given_actions = True
        self._given = ActionTally(GIVEN_CHECKED)  # (said once: at the last it counts, or at the close)
        # A monitor that runs no policy has no env to tell it the observations' shape, nor a policy's
        # actions: what it is given is checked against the fit (see _check_given)
        shape = self.detectors.fitted_for.get("obs_shape")
        self._watched_shape = tuple(shape) if self.agent is None and self.estimator is None and shape else None
        dynamics = self.detectors["dynamics"] if self._watched_shape and "dynamics" in self.detectors else None
        self._watched_actions = dynamics.action_refusal if dynamics is not None else None
        # a dict of named readings, which the detectors were fitted on flattened (oodmon.watch_recorded)
        layout = self.detectors.fitted_for.get("observation_layout") if self._watched_shape else None
        self._flatten: Callable[[Mapping], np.ndarray] | None = None
        if layout is not None:
            from oodmon.monitor.recorded import flattened

            self._flatten = functools.partial(flattened, layout=layout)

    def twin(self, *, sinks: Sequence[Sink] = (), callbacks: Sequence[AlarmCallback] = ()) -> Monitor:
        """A monitor of the same policy, threshold and alarm rule, with copies of the fitted detectors
        (whose windows and running means are then its own), its own episodes, ``sinks`` and
        ``callbacks``: one for each env of a vector env, since one Monitor follows one env's episode
        (:class:`~oodmon.monitor.monitored_env.MonitoredEnv` refuses a Monitor that another env's
        episode is using). A policy that reads its env beside the observation (a RecurrentPPO's
        memory of the episode, a MaskablePPO's action masks) gets its own of those too
        (:meth:`~oodmon.agents.Agent.twin`).

        Example::

            monitor = oodmon.watch("dqn.zip", "CartPole-v1")
            envs = DummyVecEnv([lambda m=m: MonitoredEnv(gymnasium.make("CartPole-v1"), m)
                                for m in (monitor, monitor.twin(), monitor.twin())])
        """
        made = self._made_with | {"detectors": copy.deepcopy(self._made_with["detectors"])}
        if isinstance(made["policy"], Agent):
            made["policy"] = made["policy"].twin()
        return Monitor(**made, sinks=sinks, callbacks=callbacks)

    def _in_memory_note(self, recorded: str | None) -> list[str]:
        """What to add where SB3 models in memory are refused a threshold or detectors of other
        weights (``recorded``): those made from the models' files before 2026-12-04 recorded the
        files' bytes (``files_hash``), which models in memory do not have."""
        models = [] if self.agent is None else self.agent.metadata.get("models", [])
        in_memory = bool(models) and all(model.get("path") == "(in memory)" for model in models)
        if not in_memory or not other_weights(recorded, self.policy_hash, self._aliases):
            return []
        return ["if it was made from these models' files before 2026-12-04, it recorded the files' bytes, which "
                "models in memory do not have: give the files (oodmon.watch(['model.zip', ...]), load_sb3)"]

    def _models_note(self, threshold: Threshold) -> list[str]:
        """What to add where a threshold calibrated on SB3 model files is refused for other weights:
        which files it was calibrated on, and, where these are the same files, that their order differs
        (the first model acts; the policy's hash counts the order)."""
        if not threshold.models or not other_weights(threshold.policy_hash, self.policy_hash, self._aliases):
            return []
        recorded = [model["sha256"] for model in threshold.models]
        given = [model.get("sha256") for model in (self.agent.metadata.get("models") or [])] if self.agent else []
        files = threshold.sb3_files
        if given != recorded and sorted(map(str, given)) == sorted(recorded):
            return [f"these are its model files in another order (the first acts): give them in its order, --sb3 "
                    f"{files}"]
        if given == recorded:  # the same files: what differs is beside them (VecNormalize statistics)
            return []
        paths = [model.get("path") for model in (self.agent.metadata.get("models") or [])] if self.agent else []
        if paths == [model["path"] for model in threshold.models]:  # (a model trained again into its file)
            return [f"its model file{'s' if len(paths) > 1 else ''} ({files}) changed since it was calibrated: "
                    "other bytes at the same path"]
        return [f"it was calibrated on {len(recorded)} model file{'s' if len(recorded) > 1 else ''}: --sb3 {files}"]

    def _refuse_or_warn(self, what: str, differences: list[str], force: bool, *, plural: bool = False) -> None:
        """Refuse ``what`` (the threshold; the fitted detectors, ``plural``) made for another policy, or
        with ``force`` warn and use it."""
        fit = "do not fit" if plural else "does not fit"
        if differences and not force:
            raise ConfigError(f"{what} {fit} this policy: {'; '.join(differences)}; make "
                              f"{'them' if plural else 'one'} for it (or force {'their' if plural else 'its'} use: "
                              "--force, Monitor(force=True))")
        if differences:
            warnings.warn(f"using {what}, which {fit} this policy: {'; '.join(differences)}", UserWarning,
                          stacklevel=3)

    def _detector_set(self, chosen: DetectorSet, alarm: str | None, force: bool, calibrated_with: str = "") -> DetectorSet:
        """The detectors to run: those given, with ``spread`` (of ``score``) whenever the policy has samples
        (and without a fitted ``combined`` that ranks another spread score, or detectors fitted on another
        kind of MC masks (:meth:`DetectorSet.for_masks`), unless the ``alarm`` reads them: refused);
        ``calibrated_with``: the words naming the fitted detectors the threshold records, said when none are given."""
        if self.estimator is not None and "spread" not in chosen:
            chosen = chosen.with_detector(SpreadDetector(self.score_name))
        else:
            chosen, left_out = chosen.for_score(self.score_name)
            if alarm == "combined" and left_out:
                raise ConfigError(f"the alarm reads the combined detector, but {left_out}")
        chosen, other_masks = chosen.for_masks(getattr(self.estimator, "masks", None))
        if other_masks and alarm is not None and alarm not in chosen:  # spread is never left out
            raise ConfigError(f"the alarm reads the {alarm} detector, but {other_masks}")
        if self.estimator is None:
            needing = [d.name for d in chosen if d.needs_estimate]
            if needing:
                raise ConfigError(f"the {', '.join(needing)} detector(s) need the policy's samples or features; this "
                                  "policy has none (use dynamics)")
        if not len(chosen):
            raise ConfigError("nothing to score: a policy without samples needs fitted detectors, a dynamics "
                              "detector at least (`oodmon fit-detectors`, then --detectors DIR; in Python "
                              f"Monitor(detectors=fit_detectors(...))){calibrated_with}")
        for d in chosen:
            d.check_fitted()
        meta = self.agent.metadata if self.agent is not None else {}
        obs_shape = self.estimator.obs_shape if self.estimator is not None else None
        if self._own:  # the detectors read the env's own observations (of a dict with pictures, its vectors)
            obs_shape = self.agent.own_shape
        differences = chosen.check_fits(task=meta.get("task"), obs_shape=obs_shape, policy_hash=self.policy_hash,
                                        aliases=self._aliases)
        self._refuse_or_warn("the fitted detectors", differences + self._in_memory_note(chosen.fitted_for.get("policy_hash")),
                             force, plural=True)
        return chosen

    # -- the run -----------------------------------------------------------------------------
    def open(self) -> Monitor:
        if not self._opened:
            meta = self.agent.metadata if self.agent is not None else {}
            self.sinks.open(RunInfo(
                task=meta.get("task", "unknown"), method=meta.get("method", "unknown"), score=self.score_name,
                threshold=self.threshold, rule=self.tracker.rule, policy_hash=self.policy_hash,
                versions=library_versions(), detector=self.detector, detectors=tuple(self.detectors.names),
                about=(run_about(meta) | self._samples_about() | self._states_about() | self._threshold_about()
                       | self._names_about()),
                fitted=self._fitted,
            ))
            self._opened = True
            atexit.register(self.close)
        return self

    def _samples_about(self) -> dict[str, str]:
        """The policy's samples per decision (MC samples or ensemble members) and an MC policy's
        masks, which the spread's scale depends on: ``about.samples`` and ``about.masks`` in the log."""
        if self.estimator is None:
            return {}
        masks = getattr(self.estimator, "masks", None)
        return {"samples": str(self.estimator.n_samples)} | ({"masks": masks} if masks else {})

    def _threshold_about(self) -> dict[str, str]:
        """The reset seeds of the ID episodes the threshold (and the fitted detector its alarm
        reads) were made from, by use, as JSON (``about.threshold_seeds``: ``{"calibration": [first,
        end), ...}``): replay says where the log's own ID episodes are among them, whose false
        alarms read low (:func:`~oodmon.replay.metrics.made_from_episodes`); and the sensor noise of
        the world it was calibrated in (``about.threshold_obs_noise``, where the file records it):
        replay says where the log's episodes played another
        (:func:`~oodmon.replay.metrics.off_calibration_noise`); and its longest calibration episode
        (``about.threshold_longest_episode``): replay says where ID episodes ran longer
        (:func:`~oodmon.replay.metrics.longer_than_calibration`), and counts them by stretches as
        long as a calibration episode on average (``about.threshold_mean_episode``) beside its
        target (``about.threshold_far``), as ``validate --max-steps`` does
        (:func:`~oodmon.replay.metrics.id_stretches`)."""
        from oodmon.monitor.calibration import detectors_read, seeds_used

        threshold = self._made_with["threshold"]
        if not isinstance(threshold, Threshold):
            return {}
        used = seeds_used(threshold, detectors_read(threshold, self.detectors))
        about = {} if threshold.obs_noise is None else {"threshold_obs_noise": f"{threshold.obs_noise:g}"}
        if self._longest is not None:  # (episode mode, where the file records it)
            about["threshold_longest_episode"] = str(self._longest)
        if threshold.mean_episode is not None:
            about |= {"threshold_mean_episode": str(threshold.mean_episode), "threshold_far": repr(threshold.far)}
        return about | ({"threshold_seeds": json.dumps(used, separators=(",", ":"))} if used else {})

    def _check_names(self, obs: Any) -> None:
        """``reading_names`` against the first observation the detectors read: one name a number.

        Raises:
            ConfigError: as many names as the observation has numbers they are not.
        """
        numbers = np.asarray(obs).size
        if len(self._given_names) != numbers:
            raise ConfigError(f"{self._names_from} has {len(self._given_names)} name(s); the observations the "
                              f"detectors read have {numbers} number(s) (give one name for each, by index)")
        self._names_checked = True

    def _names_about(self) -> dict[str, str]:
        """The names of the readings given (``reading_names``), or of a dict observation's as the
        detectors read it (:meth:`~oodmon.agents.agent.Agent.dict_reading_names`;
        ``about.reading_names`` in the log, a JSON list): replay names the readings of its alarms
        by them, as the alarms' lines do."""
        names = self._own_names()
        return {"reading_names": json.dumps(list(names))} if names else {}

    def _own_names(self) -> tuple[str, ...]:
        """The names of the readings given (``reading_names``), else of a dict observation's
        (:meth:`~oodmon.agents.agent.Agent.dict_reading_names`, worked out once: a camera's
        thousands of numbers); none where neither is (an env's known layout is named by its id)."""
        if self._given_names is not None:
            return self._given_names
        if self._dicts and self._dict_names is None:
            self._dict_names = self.agent.dict_reading_names()
        return self._dict_names or ()

    def _states_about(self) -> dict[str, str]:
        """The values of each reading of a discrete observation (``about.states`` in the log: ``16``
        for FrozenLake's cell, ``3,5`` for a ``MultiDiscrete([3, 5])``): the steps hold it one-hot
        (:meth:`~oodmon.agents.agent.Agent.view`), which the Rerun sink draws as each reading's value."""
        space = getattr(self.agent, "dict_space", None)
        if isinstance(space, gymnasium.spaces.Discrete):
            return {"states": str(int(space.n))}
        if isinstance(space, gymnasium.spaces.MultiDiscrete) and space.nvec.ndim == 1:
            return {"states": ",".join(str(int(n)) for n in space.nvec)}
        return {}

    def close(self) -> None:
        """End a running episode (as interrupted) and finish the sinks' files. Idempotent."""
        try:
            if self._opened:
                atexit.unregister(self.close)
                try:
                    if self._in_episode and not self.abandon_empty_episode():
                        self.end_episode(interrupted=True)
                finally:
                    self.sinks.close()
                    self._opened = False
        finally:  # (after the files: a warning made an error, -W error, must not leave them unfinished)
            if self._given.partial:  # fewer given than the check counts: said all the same, once
                try:
                    self._say_other_actions()
                finally:
                    self._given.cut()

    def __enter__(self) -> Monitor:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- an episode ----------------------------------------------------------------------------
    def begin_episode(self, *, env_id: str = "", variant: str = "", onset: int = 0, seed: int | None = None,
                      obs_noise: float = 0.0) -> None:
        """Begin an episode. One still running ends here, as an env's reset ends it (with no step
        scored it is forgotten): before 2026-12-01 its record was dropped, so a loop of your own
        that never called :meth:`end_episode` logged steps under no episode, and replay found none.
        ``obs_noise``: the env's sensor noise, recorded with the episode (replay says when it pools
        episodes played at several)."""
        if not is_finite_real(obs_noise) or obs_noise < 0:
            raise InvalidParameterError(f"obs_noise={obs_noise!r} is not allowed; it is the env's sensor noise, a "
                                        "number >= 0 (0: none)")
        self._warn_of_other_noise(float(obs_noise))
        self.open()
        if self._in_episode and not self.abandon_empty_episode():
            self.end_episode()
        self.episode += 1
        self.tracker.reset()
        self.detectors.reset()
        if self.agent is not None:
            self.agent.begin_episode()  # a policy with a memory (RecurrentPPO's) forgets the last episode
        self._prev_obs, self._prev_action = None, None
        self._deployed: Any = None  # the action deployed at the episode's last step
        own = self.agent.env_id if self.agent is not None else None
        if own and variant and variant == own.rpartition(":")[2]:  # the agent's env, registered in a module of yours:
            variant = own  # named by the id you gave (my_envs:MyEnv-v0), as calibration names it; the env knows MyEnv-v0
        self._episode_info = dict(env_id=env_id, variant=variant, onset=onset, seed=seed, obs_noise=float(obs_noise))
        self._episode_task = self.agent.task if self.agent is not None else variant.split(":")[0]  # render's
        self._return, self._length, self._alarms = 0.0, 0, 0
        self._first_alarm: AlarmEvent | None = None  # the episode's first (its step, cause, readings, region)
        self._rewards: list[float] = []  # the current segment's
        self._segment_start = 0  # the step the current segment starts at
        self._in_episode = True
        self.stop_requested = False
        self.last_step, self.last_cause, self.last_alarm = None, None, None
        self.stop_event = None
        self._episode_owner = None  # the MonitoredEnv whose reset began it sets itself here (weakly)

    def _warn_of_other_noise(self, obs_noise: float) -> None:
        """Warn (:class:`OffCalibrationNoiseWarning`, once a noise) when an episode plays another
        sensor noise than the threshold was calibrated with: its false-alarm bound is for that world
        (a noiseless threshold alarmed in 100 of 100 ID CartPole episodes at noise 0.01). ``oodmon
        run`` says it in a note at its end instead."""
        calibrated = self._calibration_noise
        if calibrated is None or obs_noise == calibrated or obs_noise in self._noises_warned:
            return
        self._noises_warned.add(obs_noise)
        warnings.warn(f"this episode plays sensor noise obs_noise={obs_noise:g}, and the threshold was calibrated "
                      f"with {calibrated:g}: its false-alarm bound is for that world (calibrate in this one: "
                      f"`oodmon calibrate --obs-noise {obs_noise:g}`, or calibrate_agent(..., obs_noise={obs_noise:g}); "
                      f"`oodmon validate THRESHOLD --obs-noise {obs_noise:g}` counts its false alarms here)",
                      OffCalibrationNoiseWarning, stacklevel=3)

    def _warn_longer_than_calibration(self) -> None:
        """Warn (:class:`LongerThanCalibrationWarning`, once) that an episode has run past the longest
        of the threshold's calibration episodes: its bound is for episodes like those (the docs' own
        CartPole controller, calibrated on 500 steps, alarmed in 29 of 314 stretches of 500 steps of
        5,000-step runs, as its cart wandered further). ``oodmon run`` says it in a note instead."""
        self._longer_warned = True
        warnings.warn(f"episode {self.episode} has run past {self._longest:,} steps, the longest of the threshold's "
                      "calibration episodes: its false-alarm bound is for episodes like those (`oodmon validate "
                      "THRESHOLD --max-steps N` counts its false alarms in runs N steps long, `oodmon calibrate "
                      "--max-steps N` calibrates on them)", LongerThanCalibrationWarning, stacklevel=3)

    @property
    def in_episode(self) -> bool:
        """Whether an episode has begun and not ended."""
        return self._in_episode

    def abandon_empty_episode(self) -> bool:
        """Forget the running episode if no step of it was scored, and say whether it did.

        A reset that no step follows (a vector env's auto-reset after the last episode, an
        evaluation loop that resets once more) would otherwise log a 0-step episode.
        """
        if not self._in_episode or self._length:
            return False
        self.episode -= 1
        self._in_episode = False
        return True

    def _decide(self, obs: Any, estimate: Estimate | None) -> tuple[Any, Exception | None]:
        """The monitored policy's action at ``obs``, and the error it raised where it could not act on
        a reading that is not finite (the action before it then stands, so that the step is logged)."""
        if self._act is not None:  # a plain policy, or an agent whose samples do not decide
            try:
                return self._act(obs), None
            except Exception as error:
                if _finite(obs) or self._deployed is None:  # a bug of the policy's, or nothing to log the step with
                    raise
                # A policy that cannot act on a NaN or infinite reading (SB3's raise): the step is
                # scored (+inf: an alarm) and logged with the action before it; then the caller hears.
                return self._deployed, error
        if estimate is not None:
            raw = estimate.action[0]
            return (int(raw) if self.estimator.kind == "q_values" else np.asarray(raw)), None
        raise ConfigError("this monitor has no policy to act: pass the deployed action, step(obs, action=a)")

    def _logged(self, obs: Any, frame: np.ndarray | None) -> tuple[list[float] | None, np.ndarray | None]:
        """What the step message keeps of the observation: its readings (a vector, or stacked vectors
        flattened; not a picture) and its frame (a camera's, or with ``render`` a drawing of a
        CartPole or Pendulum state); neither without ``log_observations``."""
        if not self.log_observations:
            return None, None
        observation = None
        if np.ndim(obs) == 1:
            observation = [float(x) for x in obs]
        elif frame is None and np.ndim(obs) > 1 and not is_picture(np.shape(obs), np.asarray(obs).dtype):
            observation = [float(x) for x in np.ravel(obs)]  # stacked vectors (a list of lists, too), flattened
        if self.render and frame is None and np.ndim(obs) == 1:
            frame = self._picture(obs)
        return observation, frame

    def step(self, obs: np.ndarray, *, action: Any = None, shifted: bool = False,
             frame: np.ndarray | None = None) -> int | np.ndarray:
        """Score the observation the policy acts on; log it; return the deployed action.

        ``action``: the action actually deployed at ``obs``, when it is not the monitored
        policy's own (a policy the monitor only watches, a fallback after an alarm); the
        detectors that model transitions use it. A dict observation (an env of an SB3
        ``MultiInputPolicy``) is read flattened, as the agent reads it (:meth:`Agent.view`); of a
        stack (a model trained inside VecFrameStack) the detectors and the log read the newest
        observation (:meth:`Agent.own_observation`). A tuple or dict of actions (:attr:`Agent.action_parts`)
        is returned as the policy gave it, and read flattened (:meth:`Agent.read_action`).
        """
        if not self._in_episode:
            raise ConfigError("Monitor.step before begin_episode: start an episode first (or use run_episode)")
        if self._dicts:
            obs = self.agent.view(obs)
        elif self._flatten is not None and isinstance(obs, Mapping):
            obs = self._flatten(obs)
        estimate = self.estimator.estimate(obs) if self.estimator is not None else None
        cannot_act = None  # the policy's error on a reading that is not finite, when it raised one
        tallied = False  # whether this step's given action was the last the tally of given actions counts
        if action is None:
            action, cannot_act = self._decide(obs, estimate)
        elif self.compares_given_actions and self._given.counting and self._first_alarm is None:
            tallied = self._compare_given(obs, action, estimate)  # (not a fallback's, after an alarm)
        picture = None  # a dict's picture beside the vectors the detectors read: the frames detector's
        if self._own:  # the policy acted on a stack, or a dict with pictures; the detectors and the log read less
            if self.agent.pictures is not None:
                picture = self.agent.pictures.picture(obs)
            obs = self.agent.own_observation(obs)
            if picture is not None:
                frame = _frame(picture)
            elif frame is not None:
                frame = _frame(obs)  # an RGB stack's newest picture, not its last channel
        read = self.agent.read_action(action) if self._action_parts else action  # a tuple of actions: flattened
        if self._watched_shape is not None:
            self._check_given(obs, read)
        if not self._names_checked:
            self._check_names(obs)
        finite = _finite(obs)
        context = None
        if finite:
            context = StepContext(obs, read, estimate, self._prev_obs, self._prev_action, {}, picture)
            scores = self.detectors.score(context)
            self._prev_obs, self._prev_action = obs, read
        else:
            # A NaN or infinite observation (a failed sensor) lies outside any ID data: every detector
            # scores it +inf, so the alarm rule counts it, and none is fed it (a NaN in a detector's
            # window or running mean would hide its scores for the steps after, or the episode). The
            # next finite observation has no previous one, as at an episode's start: the jump across
            # the gap is no one-step transition for the dynamics model to be surprised by.
            scores = dict.fromkeys(self.detectors.names, math.inf)
            self._prev_obs, self._prev_action = None, None
        score = scores[self.detector]
        step = self._length
        alarm, event = self.tracker.update(self.episode, step, score)
        self.last_cause = self._cause(finite) if alarm else None
        if event is not None:
            event = replace(event, cause=self.last_cause, **self._readings(context))
        self.last_alarm = event
        observation, frame = self._logged(obs, frame)
        logged_action = int(read) if isinstance(read, (int, np.integer)) else np.asarray(read).tolist()
        self.last_step = StepRecord(
            episode=self.episode, step=step, action=logged_action,
            mean=estimate.mean[0].tolist() if estimate is not None else [],
            std=estimate.std[0].tolist() if estimate is not None else [], score=score, threshold=self.threshold,
            alarm=alarm, shifted=bool(shifted), observation=observation, frame=frame, scores=scores,
            compared=self.tracker.compared, raised=event,
        )
        if step == 0:  # the episode has a step: where it runs goes to the log before it
            self.sinks.begin_episode(EpisodeStart(self.episode, **self._episode_info))
        elif step - self._segment_start == self.segment_steps:  # a long episode: hand its segment on
            self._end_segment()
        if step == self._longest and not self._longer_warned:  # the first step past every calibration episode
            self._warn_longer_than_calibration()
        self.sinks.write_step(self.last_step)
        self._length += 1  # the step is logged: it counts, whatever a callback below does
        if tallied:  # (after the step is logged)
            self._say_other_actions()
        if event is not None:
            self._alarms += 1
            self.alarms_raised += 1
            if self._first_alarm is None:
                self._first_alarm = event
            self.sinks.write_alarm(event)
            for callback in self.callbacks:
                if callback(event):
                    self.stop_requested = True
                    self.stop_event = event
        self._deployed = action
        if cannot_act is not None:
            raise PolicyCannotAct(
                f"episode {self.episode}: the policy could not act on the observation after step {step - 1}, which "
                f"is not finite ({_shown(obs)}; {type(cannot_act).__name__}): it is scored (+inf) and logged with "
                "the action before it (a failed sensor, a shift that blew the env's physics up?)") from cannot_act
        return action

    def _compare_given(self, obs: Any, action: Any, estimate: Estimate | None) -> bool:
        """Compare an action given to :meth:`step` with the policy's own decision at ``obs``, where
        that decision draws nothing and remembers nothing (an SB3 model's deterministic ``predict``,
        an ensemble's mean); whether it was the last of the :data:`GIVEN_CHECKED` compared, after
        which :meth:`step` warns if some differed."""
        from oodmon.agents.sb3_deployed import DeployedModel

        if type(self._act) is DeployedModel and not self._action_parts:
            own = self._act(obs)
        elif self._act is None and isinstance(self.estimator, EnsembleEstimator) and estimate is not None:
            own = self._decide(obs, estimate)[0]
        else:  # a function of yours, a policy that samples, remembers or reads masks: not asked twice
            self._given.cut()
            return False
        return self._given.add(own, action)

    def _say_other_actions(self) -> None:
        """Warn of the given actions that were not the policy's (:meth:`_compare_given`), if any."""
        if self._given.differed:
            warnings.warn(OtherActionsWarning(
                f"{self._given.differed} of the first {self._given.checked} actions given to the monitor (before any "
                "alarm) were not the policy's own decision at their observation: SB3's predict(obs) samples unless "
                "deterministic=True (a DQN's takes a random action at its exploration rate), and the detectors, "
                "fitted on the policy's own actions, read other actions as a shift (a PPO's sampled actions on "
                "CartPole-v1 alarmed 20 of 20 ID episodes, its deterministic ones none): give predict(obs, "
                "deterministic=True); a policy deployed as it samples is watched as a function of any kind, or "
                "with detectors fitted on some random actions (fit_explore; docs/your-policy.md)"), stacklevel=3)

    def _cause(self, finite: bool) -> str:
        """What raised the alarm's score at this step (:attr:`AlarmEvent.cause`): the alarm's
        detector, or the member that ``combined`` ranked highest."""
        if not finite:
            return "a reading that is not finite"
        return getattr(self.detectors[self.detector], "leader", None) or self.detector

    def _readings(self, context: StepContext | None) -> dict[str, Any]:
        """:attr:`AlarmEvent.readings` of the step ``context`` (``None``: a reading not finite), the
        steps they cover and their names (``readings``, ``readings_steps``, ``reading_names``): the
        readings whose change the set's ``dynamics`` model predicted worst, at least
        :data:`READING_SD` off, at most :data:`MOST_READINGS`; none without a fitted model or a
        step before. Where none is and ``drift`` raised the alarm, its own reading
        (:meth:`~oodmon.monitor.detectors.DriftDetector.largest_bias`), over its window. Where
        ``vanishing`` raised it, where in the picture (``region``). Named
        where the env's layout is known, a dict's by its keys (read flattened). One batch pass of the
        model, at each alarm (not each step)."""
        model = self.detectors["dynamics"] if "dynamics" in self.detectors else None
        readings, steps = (), 1
        if context is not None and context.prev_obs is not None and model is not None and model.fitted:
            before, action = np.asarray(context.prev_obs)[None], np.asarray([context.prev_action])
            residuals = model.standardized_residuals(before, action, np.asarray(context.obs)[None])[0]
            indices = np.arange(len(residuals)) if model.predicted is None else model.predicted
            worst = np.argsort(-np.abs(residuals), kind="stable")[:MOST_READINGS]
            readings = tuple((int(indices[k]), float(residuals[k])) for k in worst if abs(residuals[k]) >= READING_SD)
        drift = self.detectors["drift"] if "drift" in self.detectors and self.last_cause == "drift" else None
        if not readings and context is not None and context.prev_obs is not None and drift is not None:
            bias = drift.largest_bias()
            if bias is not None and abs(bias[1]) >= READING_SD:
                readings, steps = (bias[:2],), bias[2]
        names = (self._own_names() if self._given_names is not None or self._dicts
                 else reading_names(self._episode_info.get("env_id")))
        # a picture's: where things vanished or appeared (the vanishing detector's tiles), where it raised the alarm
        vanishing = self.last_cause == "vanishing" and "vanishing" in self.detectors
        region = self.detectors["vanishing"].where() if vanishing else None
        return {"readings": readings, "readings_steps": steps, "region": region,
                "reading_names": tuple(names[index] if index < len(names) else "" for index, _ in readings)}

    def _picture(self, obs: np.ndarray) -> np.ndarray | None:
        """A picture of a CartPole or Pendulum state (``render``); ``None`` for another env."""
        from oodmon.envs.preview import draw_state

        task = self._episode_task
        return draw_state(task, obs) if task in ("cartpole", "pendulum") else None

    def _check_given(self, obs: Any, action: Any) -> None:
        """Refuse an observation of another shape than the detectors were fitted on, or an action
        the dynamics model cannot read, given to a monitor that runs no policy (``Monitor(None)``):
        said naming the step, not as numpy's error deep in a detector, nor scored as something else
        (a discrete action past the last read as another)."""
        shape = obs.shape if type(obs) is np.ndarray else np.shape(obs)
        if shape != self._watched_shape:
            raise ConfigError(f"the observation at step {self._length} of episode {self.episode} is of shape {shape}; "
                              f"the detectors were fitted on observations of shape {self._watched_shape}")
        refusal = None if self._watched_actions is None else self._watched_actions(action)
        if refusal is not None:
            raise ConfigError(f"the action given at step {self._length} of episode {self.episode}, {_shown(action)}, "
                              f"{refusal}")

    def add_reward(self, reward: float) -> None:
        """The reward of the step just taken (one call per step: replay reads the rewards per step)."""
        self._return += float(reward)  # kept apart from the list: sum() rounds otherwise on Python >= 3.12
        self._rewards.append(float(reward))

    def end_episode(self, *, interrupted: bool = False, terminated: bool | None = None) -> EpisodeRecord:
        """Close the running episode and log its record. ``interrupted``: the run was stopped inside
        it (an exception, Ctrl-C), so it did not end by itself; replay leaves it out of metrics.
        ``terminated``: the env ended it (the pole fell), not a time limit or an alarm; replay's
        monitor metrics count that as the failure."""
        if self._segment_start:  # a segmented episode: its last segment, then a record without rewards
            self._end_segment()
            rewards = None
        else:
            rewards = tuple(self._rewards) if len(self._rewards) == self._length else None
        record = EpisodeRecord(self.episode, total_return=self._return, length=self._length, alarms=self._alarms,
                               interrupted=interrupted, terminated=terminated, **_first_alarm_fields(self._first_alarm),
                               rewards=rewards, **self._episode_info)
        self.sinks.end_episode(record)
        self._in_episode = False
        return record

    def _end_segment(self) -> None:
        """Hand the steps since the last segment to the sinks that keep an episode's arrays (their
        rewards, when every one was given), and drop the rewards kept for them."""
        given = len(self._rewards) == self._length - self._segment_start
        self.sinks.write_segment(EpisodeSegment(self.episode, self._segment_start,
                                                tuple(self._rewards) if given else None))
        self._segment_start, self._rewards = self._length, []

    def _tell_masks(self, env: gymnasium.Env) -> None:
        """After a reset or a step of ``env``: a policy that reads action masks gets those it allows
        now (:meth:`~oodmon.agents.Agent.tell_masks`); nothing for any other."""
        if self._masked:
            self.agent.tell_masks(env)

    def run_episode(self, env: gymnasium.Env, *, seed: int | None = None, variant: str | None = None,
                    max_steps: int | None = None, options: dict | None = None,
                    on_progress: Progress | None = None) -> EpisodeRecord:
        """Run the monitored policy for one episode of ``env``; return the episode's record.

        ``options`` go to ``env.reset`` (oodmon's envs take ``{"onset_step": n}``: this episode
        shifts from step n on). ``on_progress("decisions", steps, max_steps or 0)`` is called after each step
        (progress within long episodes: a Pong game is thousands of decisions). An observation that
        is not finite (a failed sensor, a shift that blew the env's physics up) is scored as any
        (every detector +inf: an alarm); a policy that cannot act on it (SB3's raise) ends the
        episode there, the step logged with the action before it, with a
        :class:`NonFiniteObservationWarning`.
        """
        obs, info = env.reset(seed=seed, options=options)
        self.begin_episode(env_id=env_id_of(env), variant=variant or variant_of_env(env), onset=onset_of_env(env),
                           seed=seed, obs_noise=obs_noise_of_env(env))
        self._tell_masks(env)
        try:
            while True:
                try:
                    action = self.step(obs, shifted=bool(info.get("shifted", False)), frame=_frame(obs))
                except PolicyCannotAct as error:  # the step is logged; the episode ends there
                    warnings.warn(NonFiniteObservationWarning(f"{error}; the episode ends there"), stacklevel=2)
                    terminated = False
                    break
                obs, reward, terminated, truncated, info = step_naming_refusal(env, action, step=self._length,
                                                                               seed=seed)
                self._tell_masks(env)
                self.add_reward(reward)
                if on_progress is not None:
                    on_progress("decisions", self._length, max_steps or 0)
                if terminated or truncated or self.stop_requested or (max_steps and self._length >= max_steps):
                    break
        except BaseException:  # Ctrl-C included: the cut episode is logged, marked as such
            self.end_episode(interrupted=True)
            raise
        return self.end_episode(terminated=bool(terminated))


def _first_alarm_fields(event: AlarmEvent | None) -> dict[str, Any]:
    """An :class:`EpisodeRecord`'s fields of its first alarm (none: no alarm)."""
    if event is None:
        return {"first_alarm_step": None}
    return {"first_alarm_step": event.step, "first_alarm_cause": event.cause,
            "first_alarm_readings": event.readings, "first_alarm_readings_steps": event.readings_steps,
            "first_alarm_region": event.region}


def _finite(obs: Any) -> bool:
    """Whether every number of an observation (a dict's too) is finite (an integer observation
    always is: Pong's frames)."""
    if isinstance(obs, dict):
        return all(_finite(value) for value in obs.values())
    obs = np.asarray(obs)
    return obs.dtype.kind not in "fc" or bool(np.isfinite(obs).all())


class NonFiniteObservationWarning(RuntimeWarning):
    """:meth:`Monitor.run_episode` or :meth:`~oodmon.monitor.monitored_env.MonitoredEnv.step` ended
    an episode whose env returned a NaN or infinite reading the policy could not act on."""


class OffCalibrationWarning(UserWarning):
    """An episode the monitor's threshold's false-alarm bound does not speak for: played at another
    sensor noise (:class:`OffCalibrationNoiseWarning`) or longer (:class:`LongerThanCalibrationWarning`)
    than its calibration episodes. ``oodmon run`` and ``validate`` silence both by this class."""


class OffCalibrationNoiseWarning(OffCalibrationWarning):
    """:meth:`Monitor.begin_episode`: the episode plays another sensor noise than the monitor's
    threshold was calibrated with (``Threshold.obs_noise``), so the threshold's false-alarm bound
    does not hold for it. Warned once for each such noise a monitor sees."""


class LongerThanCalibrationWarning(OffCalibrationWarning):
    """:meth:`Monitor.step`: an episode has run past the longest of the monitor's threshold's
    calibration episodes (``Threshold.longest_episode``), so the threshold's false-alarm bound does
    not speak for its steps from there. Warned once per monitor."""


class OtherActionsWarning(UserWarning):
    """:meth:`Monitor.step`: some of the first :data:`GIVEN_CHECKED` actions given to it before an
    alarm were not the policy's own decision at their observation (SB3's ``predict`` samples by
    default), which the detectors, fitted on its own actions, read as a shift. Warned once per
    monitor; compared only where the decision draws nothing (an SB3 model's deterministic one)."""


@dataclass
class ActionTally:
    """The first ``limit`` actions taken that are compared with the policy's own decision (given
    to a :class:`Monitor`, or a learning model's, :class:`~oodmon.monitor.sb3_callback.MonitorCallback`):
    how many were, and how many differed.

    Example:
        >>> tally = ActionTally(2)
        >>> tally.add(1, 1), tally.partial, tally.add(0, 1), tally.counting, tally.differed
        (False, True, True, False, 1)
    """

    limit: int
    checked: int = 0
    differed: int = 0

    @property
    def counting(self) -> bool:
        """Whether it takes more."""
        return self.checked < self.limit

    @property
    def partial(self) -> bool:
        """Whether some were counted, fewer than ``limit``."""
        return 0 < self.checked < self.limit

    def add(self, own: Any, given: Any) -> bool:
        """Count ``given`` against the policy's ``own``; whether that was the last it takes."""
        self.checked += 1
        self.differed += not same_action(own, given)
        return self.checked == self.limit

    def cut(self) -> None:
        """Take no more (a policy whose actions cannot be compared, or one told of those counted)."""
        self.checked = max(self.checked, self.limit)


def same_action(own: Any, given: Any) -> bool:
    """Whether ``given`` is the action ``own`` (a float32 network's action and its float64 copy alike).

    Example:
        >>> same_action(1, np.int64(1)), same_action(np.float32([0.3]), [0.30000001]), same_action(0, 1)
        (True, True, False)
    """
    return bool(np.allclose(np.asarray(own, np.float64), np.asarray(given, np.float64), rtol=1e-5, atol=1e-6))


class PolicyCannotAct(RuntimeError):
    """:meth:`Monitor.step`: the monitored policy raised on an observation that is not finite (SB3's
    check of a NaN). The step is scored (+inf) and logged, with the action before it as its action; the
    policy's own error is the ``__cause__``. ``run_episode`` and ``MonitoredEnv`` end the episode there
    with a :class:`NonFiniteObservationWarning`; a loop of your own catches it to do likewise."""


def _shown(obs: Any) -> str:
    """``obs`` in a line: its values, or its shape when it is large."""
    values = np.asarray(obs) if not isinstance(obs, (dict, tuple)) else None
    if values is None or values.size > 8:
        return "shape " + (f"a {type(obs).__name__}" if values is None else str(values.shape))
    return np.array2string(values.reshape(-1), precision=3)


def _frame(obs: np.ndarray) -> np.ndarray | None:
    """The picture to log of an image observation (uint8, three dimensions): its newest frame (see
    :func:`~oodmon.monitor.detectors.frames.newest_frame`), else None (a dict's or a tuple's
    observation too, whose numpy shape a tuple of parts of other shapes does not have)."""
    return newest_frame(obs) if isinstance(obs, np.ndarray) and obs.ndim == 3 and obs.dtype == np.uint8 else None
