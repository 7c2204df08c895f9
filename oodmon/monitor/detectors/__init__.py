"""Detectors: per-step scores of how far the world has moved from the ID one.

- ``spread``: the spread of the policy's own samples (the paper's signal; needs MC or an ensemble).
- ``dynamics``: a probabilistic ensemble dynamics model's surprise at each transition (PEDM).
- ``features``: the Mahalanobis distance of the policy's features (Lee et al., 2018).
- ``frames``: the Mahalanobis distance of each camera frame's image statistics (any policy).
- ``combined``: the largest ID rank of the others' scores (and of ``dynamics``' mean since the
  episode began).
- ``scaled_spread``: an ensemble's spread with each member's values on its own ID footing (DDPG:
  outputs before the tanh over their ID scale; DQN: centred Q-values as ID z-scores; fitted only
  when named).
- ``drift``: a bias of the dynamics model's residuals, reading by reading (a change the policy
  copes with, missed the same way step after step; with ``dynamics``, by default in your own env).
- ``transitions``: the surprise of each (state, action, next state) to the ID ones counted, for
  observations whose values repeat (discrete states; in place of ``dynamics`` for those).
- ``stillness``: how long a sensor (a picture, or each reading) has gone unchanged against its
  longest ID run: a frozen camera (by default for pictures, beside ``frames``).
- ``motion``: how much less the picture's parts moved than they did after the same actions in ID
  episodes: a partly frozen camera (for pictures, fitted only when named).
- ``vanishing``: things that vanish from or appear in parts of the picture where nothing did in ID
  episodes: a frozen part that things cross (for pictures, fitted only when named).

:func:`fit_detectors` fits them for a policy on its own ID episodes; :class:`DetectorSet` runs
them at each step and saves them (safetensors + JSON).
"""

from __future__ import annotations

from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory
from oodmon.monitor.detectors.combined import CombinedDetector
from oodmon.monitor.detectors.drift import DriftDetector
from oodmon.monitor.detectors.dynamics import MIN_LOGVAR, DynamicsDetector
from oodmon.monitor.detectors.features import FeaturesDetector
from oodmon.monitor.detectors.frames import FramesDetector
from oodmon.monitor.detectors.fitting import (
    BEST_DETECTOR, DEFAULT_FIT_EPISODES, DEFAULT_FIT_STEPS, FIT_VERSION, best_detector, collect, default_detectors,
    default_fit_steps, detectors_for, fit_agent_detectors, fit_detectors, fitting_notes, trajectory_scores,
)
from oodmon.monitor.detectors.motion import MotionDetector
from oodmon.monitor.detectors.scaled_spread import ScaledSpreadDetector
from oodmon.monitor.detectors.spread import SpreadDetector
from oodmon.monitor.detectors.stillness import StillnessDetector
from oodmon.monitor.detectors.store import DETECTORS, DetectorSet
from oodmon.monitor.detectors.transitions import TransitionsDetector
from oodmon.monitor.detectors.vanishing import VanishingDetector

__all__ = [
    "BEST_DETECTOR", "DEFAULT_FIT_EPISODES", "DEFAULT_FIT_STEPS", "DETECTORS", "FIT_VERSION", "MIN_LOGVAR",
    "CombinedDetector", "Detector", "DetectorSet", "DriftDetector", "DynamicsDetector", "FeaturesDetector",
    "FramesDetector", "MotionDetector", "ScaledSpreadDetector", "SpreadDetector", "StepContext", "StillnessDetector",
    "Trajectory", "TransitionsDetector", "VanishingDetector", "best_detector", "collect", "default_detectors",
    "default_fit_steps",
    "detectors_for", "fit_agent_detectors", "fit_detectors", "fitting_notes", "trajectory_scores",
]
