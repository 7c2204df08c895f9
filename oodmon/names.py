"""The names every layer shares: the tasks, the uncertainty methods and the MC masks.

A module of its own, importing nothing, so that the command line can offer them as choices
without loading torch or gymnasium. ``oodmon.envs.TASKS`` and ``oodmon.agents.METHODS`` are these.
"""

from __future__ import annotations

__all__ = ["BEST_DETECTOR", "FIXED_MASKS", "MASKS", "METHODS", "PLAIN_METHOD", "TASKS", "fixed_masks"]

#: The tasks, each one env of the paper (CartPole, Pendulum: physics shifts; Pong: corrupted frames).
TASKS: tuple[str, ...] = ("cartpole", "pendulum", "pong")

#: The uncertainty methods, for every task.
METHODS: tuple[str, ...] = ("dropout", "dropconnect", "ensemble")

#: The detector an alarm reads by default where it is fitted, by task (measured: the reasons are
#: beside its use, ``oodmon.monitor.detectors.fitting``; an env oodmon has not measured: ``combined``).
BEST_DETECTOR: dict[str, str] = {"cartpole": "combined", "pendulum": "dynamics", "pong": "combined"}

#: The method of a policy of any kind, a function obs -> action (``oodmon.agents.plain``): its
#: agent's, its thresholds' and its logs'.
PLAIN_METHOD = "plain"

#: How an MC estimator draws its masks: ``sampled`` anew at every decision (MC Dropout and
#: DropConnect as the paper samples them), or ``fixed``: K masks drawn once, so that sample k is the
#: same sub-network at every decision, the action still decided by K freshly sampled masks; or
#: ``fixed-decisions``: the K fixed sub-networks decide too, by their mean, in the same pass (an
#: implicit ensemble of K sub-networks, as Masksembles; see ``oodmon.agents.estimators.MCEstimator``).
MASKS: tuple[str, ...] = ("sampled", "fixed", "fixed-decisions")

#: The masks drawn once (sample k one sub-network at every decision).
FIXED_MASKS: tuple[str, ...] = ("fixed", "fixed-decisions")


def fixed_masks(masks: str | None) -> bool:
    """Whether ``masks`` (an estimator's, a threshold's; None: not an MC estimator) are drawn once.

    Example:
        >>> fixed_masks("fixed-decisions"), fixed_masks("sampled"), fixed_masks(None)
        (True, False, False)
    """
    return masks in FIXED_MASKS
