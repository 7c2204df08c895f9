"""What a training exports: the agent as it ships (fp16 where its recipe says), the choice among
a run's snapshots by replaying them (scores cached by the sha256 of their weights), and the
model files with their metadata."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file
from stable_baselines3.common.base_class import BaseAlgorithm

from oodmon import seeds
from oodmon.agents.checkpoints import Run
from oodmon.agents.evaluation import episode_returns
from oodmon.agents.networks import Architecture, estimator_for, modules_from_sb3
from oodmon.agents.recipes import Recipe, recipe_differences, recipe_metadata
from oodmon.agents.serialization import save_modules
from oodmon.envs.grid import Variant
from oodmon.hashing import file_sha256
from oodmon.jsonfile import write_json
from oodmon.progress import Progress
from oodmon.versions import library_versions, machine

__all__ = ["SELECTION_SEED", "as_shipped", "recipe_differences", "select_snapshot", "write_agent"]

#: First seed of the episodes that choose among snapshots (``Recipe.select_top``): apart from the
#: ID return's (:data:`oodmon.seeds.ID_RETURN`), so that the reported return is not the one the
#: choice maximised (see :mod:`oodmon.seeds` for why it is not yet a named range).
SELECTION_SEED = seeds.SNAPSHOT_SELECTION


def as_shipped(models: list[BaseAlgorithm], arch: Architecture, recipe: Recipe, seed: int,
                bounds: dict[str, Any]):
    """The agent's modules as they will be saved, and its policy: the action of its MC or ensemble
    decision, on weights rounded to fp16 where they ship so (in Pong that changes whole games).
    ``bounds``: the ``action_low``/``action_high`` of a DDPG agent."""
    modules = modules_from_sb3(models, arch)
    if recipe.cnn:
        with torch.no_grad():
            for tensor in modules.state_dict().values():
                if tensor.is_floating_point():
                    tensor.copy_(tensor.half().float())
    estimator = estimator_for(modules, arch, recipe.n_samples, seed=seed, **bounds)
    if arch.algorithm == "dqn":
        return modules, lambda obs: int(estimator.estimate(obs).action[0])
    return modules, lambda obs: estimator.estimate(obs).action[0]


def select_snapshot(run: Run, model: BaseAlgorithm, arch: Architecture, seed: int,
                     bounds: dict[str, Any], report: Progress) -> dict[str, Any] | None:
    """Play each of the run's candidate snapshots as shipped on ``select_episodes`` ID episodes
    (seeds from :data:`SELECTION_SEED`); load the best into ``model`` and describe the choice.
    None, with ``model`` untouched, where there are no snapshots to choose from.

    A candidate already played by an earlier export (same weights, episodes, seeds and MC samples:
    ``runs/<run>/selection.json``) keeps its score instead of being played again: the replays are
    deterministic, so the score would be the same. Delete that file after changing how an agent
    decides (its MC sampling, say), since the scores then no longer hold."""
    recipe = run.recipe
    candidates = run.candidates()
    if not candidates:
        return None
    cache_path = run.folder / "selection.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    setting = {"episodes": recipe.select_episodes, "seed": SELECTION_SEED, "n_samples": recipe.n_samples,
               "member_seed": seed}
    for candidate in candidates:
        candidate["sha256"] = file_sha256(candidate["path"])
        known = cache.get(candidate["sha256"])
        if known is not None and all(known.get(k) == v for k, v in setting.items()):
            candidate["selection_return_mean"] = known["selection_return_mean"]
    to_play = [c for c in candidates if "selection_return_mean" not in c]
    stage, total, done = f"{run.name} choosing among {len(candidates)} snapshots: episodes", (
        len(to_play) * recipe.select_episodes), [0]

    def count(*_: object) -> None:
        done[0] += 1
        report(stage, done[0], total)

    report(stage, 0, total)
    for candidate in to_play:
        model.policy.load_state_dict(load_file(str(candidate["path"])), strict=False)
        _, policy = as_shipped([model], arch, recipe, seed, bounds)
        returns = episode_returns(policy, Variant(recipe.task), recipe.select_episodes, seed=SELECTION_SEED,
                                  on_progress=count)
        candidate["selection_return_mean"] = round(float(np.mean(returns)), 2)
        cache[candidate["sha256"]] = {"steps": candidate["steps"], **setting,
                                      "selection_return_mean": candidate["selection_return_mean"]}
        write_json(cache_path, cache)  # after each candidate: a kill loses one at most
    chosen = max(candidates, key=lambda c: c["selection_return_mean"])  # first of equals: the better evaluated
    model.policy.load_state_dict(load_file(str(chosen["path"])), strict=False)
    described = [{k: v for k, v in c.items() if k not in ("path", "sha256")} for c in candidates]
    return {"chosen": described[candidates.index(chosen)], "candidates": described,
            "episodes": recipe.select_episodes, "seed": SELECTION_SEED}


def write_agent(root: Path, recipe: Recipe, runs: list[Run], models: list[BaseAlgorithm], modules: Any,
                arch: Architecture, *, seed: int, selection: dict[str, Any] | None, id_returns: Any,
                bounds: dict[str, Any], command: str) -> None:
    """Save the agent's modules (fp16 for CNN recipes) and its metadata into ``root``."""
    task, method = recipe.task, recipe.method
    metadata = {
        "task": task, "method": method, "algorithm": recipe.algorithm, "architecture": arch.to_json(),
        "ensemble": ("bootstrapped heads on a shared torso" if arch.shared_torso else "independent members")
        if method == "ensemble" else None,
        "n_members": arch.n_members, **recipe_metadata(recipe),
        "seed": seed, "training_steps": [int(m.num_timesteps) for m in models],
        "wall_time_s": round(sum(run.state["wall_time_s"] for run in runs), 1),
        "selected_checkpoints": [selection["chosen"]] if selection else [run.state.get("best") for run in runs],
        "checkpoint_selection": selection and {k: v for k, v in selection.items() if k != "chosen"},
        "training_complete": all(run.finished for run in runs),
        "recipe_notes": recipe.notes, "versions": library_versions(), "machine": machine(),
        "command": command,
        "id_return_mean": round(float(np.mean(id_returns)), 2), "id_episodes": len(id_returns),
        "id_returns": [round(float(r), 2) for r in id_returns],
        **bounds,
    }
    save_modules(root, modules, metadata, half=recipe.cnn)
