"""What acts: uncertainty-aware policies (MC Dropout, MC DropConnect, ensembles).

Built so far: the stochastic layers and the estimators that turn a network (or K of them) into
the deployed action plus the K samples behind it. Training recipes and the shipped zoo are next
(see the agents issue).
"""

from __future__ import annotations

from oodmon.agents.estimators import EnsembleEstimator, Estimate, MCEstimator, UncertaintyEstimator
from oodmon.agents.layers import DropConnectLinear, add_dropout, is_stochastic, mc_sampling, to_dropconnect

__all__ = [
    "DropConnectLinear",
    "EnsembleEstimator",
    "Estimate",
    "MCEstimator",
    "UncertaintyEstimator",
    "add_dropout",
    "is_stochastic",
    "mc_sampling",
    "to_dropconnect",
]
