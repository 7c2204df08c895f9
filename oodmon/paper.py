"""The paper's numbers as data: its grids of OOD variants and its per-trial AUC tables.

The source is Mohammed and Valdenegro-Toro, *Benchmark for Out-of-Distribution Detection in Deep
Reinforcement Learning* (2021). The project keeps its own copy, ``oodmon/paper_tables.json``, so
that nothing is fetched at run time; the envs read the grid from it and replay compares its AUCs
with ours.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from typing import Any

__all__ = ["paper_auc_per_trial", "paper_grid_data"]


@cache
def _tables() -> dict[str, Any]:
    return json.loads(resources.files("oodmon").joinpath("paper_tables.json").read_text())


def paper_grid_data() -> dict[str, Any]:
    """The paper's Table 1 by task: defaults and OOD values, or Pong's corruption severities.

    Example:
        >>> paper_grid_data()["cartpole"]["defaults"]["length"]
        0.5
    """
    return _tables()["grid"]


def paper_auc_per_trial() -> dict[str, Any]:
    """The paper's appendix AUCs: task -> method -> variant label -> five trials.

    Example:
        >>> max(paper_auc_per_trial()["cartpole"]["ensemble"]["length=2.0"])
        0.993
    """
    return _tables()["auc_per_trial"]
