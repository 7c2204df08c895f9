"""Run held-out in-distribution episodes of an agent and calibrate its threshold on them.

The calibration episodes use seeds from :data:`CALIBRATION_SEED` on, apart from the seeds of
training's evaluations (10,000 + steps) and of the ID return (100,000 + i), so they are held out.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from oodmon import seeds
from oodmon.agents.agent import Agent
from oodmon.envs.grid import Variant
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import DEFAULT_CONSECUTIVE
from oodmon.monitor.detectors import DetectorSet, best_detector
from oodmon.monitor.monitor import Monitor, policy_hash
from oodmon.monitor.scores import DEFAULT_SCORE, score_function
from oodmon.monitor.sinks.base import MemorySink
from oodmon.monitor.threshold import DETECTOR_NAMES, Threshold, calibrate

__all__ = ["CALIBRATION_SEED", "calibrate_agent", "id_episode_scores"]

CALIBRATION_SEED = seeds.CALIBRATION


def id_episode_scores(agent: Agent, episodes: int, *, seed: int = CALIBRATION_SEED, score: str = DEFAULT_SCORE,
                      on_episode: Callable[[int], None] | None = None, detectors: DetectorSet | None = None,
                      detector: str = "spread", obs_noise: float = 0.0) -> list[np.ndarray]:
    """Per-step scores of ``detector`` in ``episodes`` ID episodes of ``agent``, seeded ``seed``,
    ``seed + 1``, ... (with sensor noise ``obs_noise``, see the envs)."""
    sink = MemorySink()
    env = Variant(agent.task).make(obs_noise=obs_noise) if obs_noise else Variant(agent.task).make()
    with Monitor(agent, score=score, detectors=detectors, detector=detector, sinks=[sink],
                 log_observations=False) as monitor:
        for episode in range(episodes):
            monitor.run_episode(env, seed=seed + episode, variant=agent.task)
            if on_episode is not None:
                on_episode(episode)
    env.close()
    scores: list[list[float]] = [[] for _ in range(episodes)]
    for record in sink.steps:
        scores[record.episode].append(record.score)
    return [np.asarray(s) for s in scores]


def calibrate_agent(agent: Agent, episodes: int = 50, far: float = 0.05, *, consecutive: int = DEFAULT_CONSECUTIVE,
                    mode: str = "episode", score: str = DEFAULT_SCORE, seed: int = CALIBRATION_SEED,
                    on_episode: Callable[[int], None] | None = None, window: int = 1,
                    detectors: DetectorSet | None = None, detector: str | None = None,
                    obs_noise: float = 0.0) -> Threshold:
    """Calibrate ``agent``'s threshold on ``episodes`` held-out ID episodes (see ``threshold``).

    ``detector`` names the detector whose score the alarm will read; a learned one comes from
    ``detectors`` (fitted on other episodes, :func:`~oodmon.monitor.detectors.fit_detectors`).
    By default it is the task's best measured detector when ``detectors`` has it, else ``spread``
    (:func:`~oodmon.monitor.detectors.best_detector`).

    Raises:
        InvalidParameterError, ConfigError: a bad argument, or too few episodes for ``far``; all
            checked before the first episode runs.
    """
    # Every argument is checked before minutes of episodes: a dry run of the calibration on
    # placeholder scores raises what the real one would.
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise InvalidParameterError(f"episodes={episodes!r} is not allowed; give a whole number >= 1 of ID episodes")
    score_function(score)
    if detector is None:
        detector = best_detector(agent.task, detectors)
    if detector not in DETECTOR_NAMES:
        raise InvalidParameterError(f"detector={detector!r} is not allowed; choose one of {', '.join(DETECTOR_NAMES)}")
    if detector != "spread" and (detectors is None or detector not in detectors):
        raise ConfigError(f"calibrating the {detector} detector needs it fitted: pass detectors=fit_detectors(...) "
                          "(`oodmon fit-detectors`)")
    steps = (consecutive if isinstance(consecutive, int) else 1) + (window if isinstance(window, int) else 1) - 1
    calibrate([np.zeros(max(steps, 1))] * episodes, far, consecutive=consecutive, mode=mode, score=score, window=window)
    needed = detectors.subset([detector]) if detectors is not None and detector != "spread" else None
    scores = id_episode_scores(agent, episodes, seed=seed, score=score, on_episode=on_episode, detectors=needed,
                               detector=detector, obs_noise=obs_noise)
    return calibrate(scores, far, consecutive=consecutive, mode=mode, score=score, task=agent.task,
                     method=agent.method, window=window, policy_hash=policy_hash(agent), detector=detector)
