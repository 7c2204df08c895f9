"""What acts: uncertainty-aware DQN and DDPG policies (MC Dropout, MC DropConnect, ensembles).

- :func:`load` a shipped agent by task and method, or :func:`load_agent` one from a directory;
  an :class:`Agent` gives the deployed action and the K samples behind it (:class:`Estimate`).
- :func:`train` an agent from its recipe (:mod:`oodmon.agents.recipes`), resumably.
- :class:`MCEstimator` and :class:`EnsembleEstimator` sample networks of your own, including
  users' SB3 models and torch networks with dropout layers.
- :func:`plain_agent` runs a policy of any kind, a function ``obs -> action``, which the learned
  detectors watch.
"""

from __future__ import annotations

from oodmon.agents.agent import Agent, load, load_agent, zoo_dir, zoo_names
from oodmon.agents.estimators import EnsembleEstimator, Estimate, MCEstimator, UncertaintyEstimator
from oodmon.agents.evaluation import RANDOM_RETURN, SOLVED_RETURN, VariantResult, episode_returns, evaluate_variants
from oodmon.agents.networks import estimator_from_sb3
from oodmon.agents.layers import DropConnectLinear, add_dropout, is_stochastic, mc_sampling, to_dropconnect
from oodmon.agents.plain import plain_agent
from oodmon.agents.recipes import METHODS, RECIPES, Recipe, recipe_for


def __getattr__(name: str):
    """``train`` is imported on first use: the monitor and replay never need the training loop."""
    if name == "train":
        from oodmon.agents.training import train

        return train
    raise AttributeError(f"module 'oodmon.agents' has no attribute {name!r}")

__all__ = [
    "METHODS",
    "RANDOM_RETURN",
    "RECIPES",
    "SOLVED_RETURN",
    "Agent",
    "DropConnectLinear",
    "EnsembleEstimator",
    "Estimate",
    "MCEstimator",
    "Recipe",
    "UncertaintyEstimator",
    "VariantResult",
    "add_dropout",
    "episode_returns",
    "estimator_from_sb3",
    "evaluate_variants",
    "is_stochastic",
    "load",
    "load_agent",
    "mc_sampling",
    "plain_agent",
    "recipe_for",
    "to_dropconnect",
    "train",
    "zoo_dir",
    "zoo_names",
]
