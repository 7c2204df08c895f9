"""Per-step uncertainty scores: one number per observation from an :class:`Estimate`.

- ``chosen_std`` (default): the std across samples of the chosen action's Q-value (DQN), or of
  the action (DDPG; the mean over action dimensions when there are several). This is the
  paper's score: how unsure the policy is about what it actually does.
- ``mean_std``: the std averaged over all actions (DQN) or action dimensions (DDPG).
- ``max_std``: the largest std over actions or action dimensions.
- ``margin_std`` (DQN): the std across samples of the chosen action's margin, its Q-value minus the
  best other action's. A sample that shifts every Q-value alike (the state's value) does not move the
  margin, and the margin is what the decision rests on: with two actions it is the std of Q0 - Q1.
- ``pre_squash_std`` (DDPG): the std of the actor's output before its tanh, averaged over action
  dimensions. A saturated tanh makes samples agree exactly when the actor pushes hard, which is
  what it does in many failing worlds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from oodmon.errors import ConfigError, UnknownParameterError, unknown

if TYPE_CHECKING:  # importing it would load torch, which replay does not need
    from oodmon.agents.estimators import Estimate

__all__ = ["DEFAULT_SCORE", "SCORES", "check_score", "score_function"]


def _chosen_std(estimate: Estimate) -> np.ndarray:
    if estimate.action.ndim == 1 and estimate.action.dtype.kind in "iu":  # integer actions (np.issubdtype's test, 2 us sooner)
        return estimate.std[np.arange(len(estimate.action)), estimate.action]
    return estimate.std.mean(axis=1)


#: What a score that does not apply to a policy's actions needs, by name.
_NEEDS = {"pre_squash_std": "score 'pre_squash_std' needs an actor that ends in tanh (DDPG); use chosen_std",
          "margin_std": "score 'margin_std' needs discrete actions (DQN); use chosen_std or pre_squash_std"}


def _pre_squash_std(estimate: Estimate) -> np.ndarray:
    if estimate.pre_squash_std is None:
        raise ConfigError(_NEEDS["pre_squash_std"])
    return estimate.pre_squash_std.mean(axis=1)


def _margin_std(estimate: Estimate) -> np.ndarray:
    action = estimate.action
    if not (action.ndim == 1 and action.dtype.kind in "iu"):
        raise ConfigError(_NEEDS["margin_std"])
    samples = estimate.samples  # (K, batch, n)
    if samples.shape[2] < 2:
        raise ConfigError("score 'margin_std' needs at least two actions")
    rows = np.arange(len(action))
    others = samples.copy()
    others[:, rows, action] = -np.inf
    return (samples[:, rows, action] - others.max(axis=2)).std(axis=0)


#: Score functions by name: Estimate -> (batch,) scores.
SCORES: dict[str, Callable[["Estimate"], np.ndarray]] = {
    "chosen_std": _chosen_std,
    "mean_std": lambda estimate: estimate.std.mean(axis=1),
    "max_std": lambda estimate: estimate.std.max(axis=1),
    "pre_squash_std": _pre_squash_std,
    "margin_std": _margin_std,
}
DEFAULT_SCORE = "chosen_std"


def check_score(name: str, algorithm: str) -> None:
    """Refuse, before any work, a score unknown or not of the actions of an ``algorithm``'s
    policy (``dqn``: discrete, ``ddpg``: a tanh actor): what its first step would refuse.

    Example:
        >>> check_score("margin_std", "dqn")
        >>> check_score("margin_std", "ddpg")
        Traceback (most recent call last):
        ...
        oodmon.errors.ConfigError: score 'margin_std' needs discrete actions (DQN); use chosen_std or pre_squash_std
    """
    score_function(name)
    if (name, algorithm) in (("margin_std", "ddpg"), ("pre_squash_std", "dqn")):
        raise ConfigError(_NEEDS[name])


def score_function(name: str) -> Callable[["Estimate"], np.ndarray]:
    """The score function called ``name``.

    Raises:
        UnknownParameterError: not one of :data:`SCORES`.

    Example:
        >>> from oodmon.agents.estimators import Estimate
        >>> est = Estimate(np.array([1]), np.zeros((2, 1, 2)), np.zeros((1, 2)), np.array([[0.5, 2.0]]))
        >>> score_function("chosen_std")(est).tolist(), score_function("mean_std")(est).tolist()
        ([2.0], [1.25])
    """
    if name not in SCORES:
        raise UnknownParameterError(unknown("score", name, SCORES))
    return SCORES[name]
