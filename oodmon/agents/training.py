"""Train an uncertainty-aware agent from its recipe, resumably, and save it in the model format.

One loop for every task and method. A training directory holds::

    runs/<run>/checkpoint.pt       weights, optimizer states and step counters: tensors and plain
                                   numbers, read back with ``torch.load(weights_only=True)``
    runs/<run>/replay_buffer.npz   the replay buffer as arrays (``np.load(allow_pickle=False)``), so
                                   that a resumed run goes on where it was
    runs/<run>/policy.safetensors  the last checkpoint's weights alone (fp16 for CNN recipes): small
                                   enough to commit, and enough to resume (with a fresh buffer) where
                                   the two above are gone
    runs/<run>/state.json          steps done, wall time, finished or not
    runs/<run>/best_policy.safetensors  the weights of the best evaluation so far
    runs/<run>/snapshots/<steps>.safetensors  the weights of every evaluation, for recipes that
                                   choose among them at export (``Recipe.select_top``)
    runs/<run>/selection.json      what each snapshot scored when played again at export, by the
                                   sha256 of its weights, so that the next export replays only new ones
    train_log.jsonl                one line per evaluation: steps, mean greedy return, wall time
    model.json, model.safetensors  the finished agent (see ``serialization``)

``<run>`` is ``main`` (MC methods, bootstrapped heads) or ``member<k>`` (independent ensemble
members). Running the same command again resumes: finished runs are skipped, an interrupted run
continues from its last checkpoint, and the final export is redone.

Nothing in a training directory is unpickled: a crafted file there cannot run code. Older
trainings kept SB3's ``checkpoint.zip`` and ``replay_buffer.pkl`` (pickles); they are ignored
with a warning (the run resumes from ``policy.safetensors`` with a fresh buffer) unless
``train(..., load_pickles=True)`` (``oodmon train --unsafe-load-pickles``) says the user trusts them.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch
from stable_baselines3 import DDPG, DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import NormalActionNoise
from safetensors.torch import load_file, save_file
from stable_baselines3.common.torch_layers import NatureCNN

from oodmon.agents.agent import Agent, load_agent
from oodmon.agents.evaluation import episode_returns
from oodmon.agents.networks import estimator_for, modules_from_sb3
from oodmon.agents.policies import BootstrappedDQN, UncertainDQNPolicy, UncertainTD3Policy
from oodmon.agents.recipes import Recipe, recipe_for
from oodmon.agents.serialization import save_modules
from oodmon.envs.grid import ENV_IDS, Variant
from oodmon.errors import ConfigError
from oodmon.threads import torch_threads
from oodmon.versions import library_versions
from oodmon.hashing import file_sha256

__all__ = ["ID_EPISODES", "architecture", "train"]

#: Episodes of the default env behind a saved model's ``id_return_mean``.
ID_EPISODES = {"cartpole": 20, "pendulum": 20, "pong": 10}

#: First seed of the episodes behind ``id_return_mean``, and of those that choose among snapshots
#: (``Recipe.select_top``): apart, so that the reported return is not the one the choice maximised.
ID_SEED, SELECTION_SEED = 100_000, 50_000

#: ``report(run name, steps done, steps total)``; while choosing among snapshots (``Recipe.select_top``)
#: ``report(name, episodes done, episodes total, "episodes")``.
Reporter = Callable[..., None]


#: The replay buffer's arrays that a checkpoint keeps (``next_observations`` is None where the
#: buffer saves memory by reading the next observation from the following row, as Pong's does).
_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
#: The SB3 counters a resumed run must go on from (schedules, target updates, policy delay).
_COUNTERS = ("num_timesteps", "_n_updates", "_episode_num", "_n_calls")


def _load_pickled_checkpoint(recipe: Recipe, folder: Path, env: gymnasium.Env, *, with_buffer: bool) -> BaseAlgorithm:
    """SB3's own ``checkpoint.zip`` and ``replay_buffer.pkl`` of an older training. These are pickles:
    loading them runs whatever code they hold. Only ever called with ``load_pickles=True``."""
    model = _algorithm_class(recipe).load(folder / "checkpoint.zip", env=env, device="cpu")
    buffer = folder / "replay_buffer.pkl"
    if with_buffer and buffer.exists():
        model.load_replay_buffer(buffer)
    return model


def architecture(recipe: Recipe, env: gymnasium.Env) -> dict[str, Any]:
    """The architecture record (see ``networks``) of a recipe's agent in ``env``."""
    discrete = isinstance(env.action_space, gymnasium.spaces.Discrete)
    ensemble = recipe.method == "ensemble"
    return {
        "algorithm": recipe.algorithm,
        "obs_shape": list(env.observation_space.shape),
        "n_outputs": int(env.action_space.n) if discrete else int(np.prod(env.action_space.shape)),
        "cnn": recipe.cnn,
        "net_arch": list(recipe.net_arch),
        "stochastic": None if ensemble else recipe.method,
        "drop_p": recipe.drop_p,
        "last_only": recipe.last_only,
        "n_members": recipe.n_members if ensemble else 1,
        "shared_torso": ensemble and recipe.shared_torso,
    }


def _training_env(recipe: Recipe) -> gymnasium.Env:
    env = gymnasium.make(ENV_IDS[recipe.task])
    if recipe.reward_clip:
        env = gymnasium.wrappers.TransformReward(env, lambda r: float(np.sign(r)))
    return env


def _new_model(recipe: Recipe, env: gymnasium.Env, seed: int) -> BaseAlgorithm:
    arch = architecture(recipe, env)
    policy_kwargs: dict[str, Any] = {
        "net_arch": list(recipe.net_arch),
        "stochastic": arch["stochastic"],
        "drop_p": recipe.drop_p,
        "last_only": recipe.last_only,
    }
    if recipe.cnn:
        policy_kwargs["features_extractor_class"] = NatureCNN
    common: dict[str, Any] = dict(seed=seed, device="cpu", verbose=0, **recipe.hyperparams)
    if recipe.algorithm == "ddpg":
        n = env.action_space.shape[0]
        scale = recipe.action_noise * (env.action_space.high - env.action_space.low) / 2
        common["action_noise"] = NormalActionNoise(np.zeros(n), scale * np.ones(n))
    elif arch["shared_torso"]:
        policy_kwargs["n_heads"] = recipe.n_members
    policy = UncertainTD3Policy if recipe.algorithm == "ddpg" else UncertainDQNPolicy
    return _algorithm_class(recipe)(policy, env, policy_kwargs=policy_kwargs, **common)


def _algorithm_class(recipe: Recipe) -> type[BaseAlgorithm]:
    if recipe.algorithm == "ddpg":
        return DDPG
    return BootstrappedDQN if recipe.method == "ensemble" and recipe.shared_torso else DQN


class _RunCallback(BaseCallback):
    """Checkpoints, evaluations and progress reports during one SB3 ``learn`` call."""

    def __init__(self, run: _Run, report: Reporter) -> None:
        super().__init__()
        self.run, self.report = run, report

    def _on_step(self) -> bool:
        steps, recipe = self.num_timesteps, self.run.recipe
        if steps % 500 == 0:
            self.report(self.run.name, steps, recipe.total_steps)
        if steps % recipe.eval_every == 0:
            mean = self.run.evaluate(self.model, steps)
            if self.run.on_evaluation is not None:
                self.run.on_evaluation(self.run.name, steps, mean)
        if steps % recipe.checkpoint_every == 0:
            self.run.checkpoint(self.model, finished=False)
        return True


class _Run:
    """One SB3 model being trained: its folder, checkpoints and log."""

    def __init__(self, recipe: Recipe, root: Path, name: str, seed: int) -> None:
        self.on_evaluation: Callable[[str, int, float], None] | None = None  # see train()
        self.recipe, self.root, self.name, self.seed = recipe, root, name, seed
        self.folder = root / "runs" / name
        self.folder.mkdir(parents=True, exist_ok=True)
        self.state_path = self.folder / "state.json"
        self.state = json.loads(self.state_path.read_text()) if self.state_path.exists() else {
            "steps": 0, "wall_time_s": 0.0, "finished": False, "seed": seed}
        self._started = time.monotonic()
        self._wall_before = self.state["wall_time_s"]

    @property
    def finished(self) -> bool:
        return bool(self.state["finished"])

    def load_or_create(self, env: gymnasium.Env, *, with_buffer: bool = True,
                       load_pickles: bool = False) -> BaseAlgorithm:
        """The full checkpoint if there is one; else the last weights (``policy.safetensors``, small
        enough to commit) with a fresh buffer and optimizer; else a new model. Legacy pickled
        checkpoints are read only with ``load_pickles``."""
        legacy = self.folder / "checkpoint.zip"
        if legacy.exists() and not (self.folder / "checkpoint.pt").exists():
            if load_pickles:
                return _load_pickled_checkpoint(self.recipe, self.folder, env, with_buffer=with_buffer)
            warnings.warn(f"{legacy} (and replay_buffer.pkl) are pickles, which oodmon does not load: a crafted one "
                          "runs code. Resuming from policy.safetensors with a fresh buffer instead; pass "
                          "--unsafe-load-pickles to load them if you made them yourself", UserWarning, stacklevel=2)
        model = _new_model(self.recipe, env, self.seed)
        checkpoint = self.folder / "checkpoint.pt"
        if checkpoint.exists():
            saved = torch.load(checkpoint, map_location="cpu", weights_only=True)  # tensors and numbers only
            model.set_parameters(saved["parameters"], exact_match=True, device="cpu")
            for name, value in saved["counters"].items():
                setattr(model, name, int(value))
            if not (with_buffer and self._load_buffer(model)):
                self._refill(model)
            return model
        weights = self.folder / "policy.safetensors"
        if weights.exists() and self.state["steps"] > 0:
            model.policy.load_state_dict(load_file(str(weights)), strict=False)
            for online, target in (("q_net", "q_net_target"), ("actor", "actor_target"), ("critic", "critic_target")):
                if hasattr(model.policy, target):
                    getattr(model.policy, target).load_state_dict(getattr(model.policy, online).state_dict())
            model.num_timesteps = int(self.state["steps"])
            self._refill(model)
        return model

    def _refill(self, model: BaseAlgorithm) -> None:
        """Fill the empty replay buffer again before learning goes on."""
        model.learning_starts = model.num_timesteps + self.recipe.hyperparams.get("learning_starts", 0)

    def _load_buffer(self, model: BaseAlgorithm) -> bool:
        """Put ``replay_buffer.npz`` into ``model``'s buffer; False where it is missing or belongs to
        another checkpoint (a kill between the two writes)."""
        path = self.folder / "replay_buffer.npz"
        if not path.exists():
            return False
        buffer = model.replay_buffer
        with np.load(path, allow_pickle=False) as data:
            if int(data["num_timesteps"]) != model.num_timesteps:
                return False
            size = int(data["size"])
            for name in _BUFFER_ARRAYS:
                if name in data.files:
                    getattr(buffer, name)[:size] = data[name]
            buffer.pos, buffer.full = int(data["pos"]), bool(data["full"])
        return True

    def train(self, report: Reporter, *, export_only: bool = False, load_pickles: bool = False) -> BaseAlgorithm:
        self._started = time.monotonic()  # wall time counts from here: members train one after another
        env = _training_env(self.recipe)
        if export_only and self.state["steps"] == 0:
            raise ConfigError(f"nothing to export in {self.folder}: no checkpoint yet; train first")
        model = self.load_or_create(env, with_buffer=not export_only, load_pickles=load_pickles)
        report(self.name, model.num_timesteps, self.recipe.total_steps)
        if not self.finished and not export_only:
            remaining = self.recipe.total_steps - model.num_timesteps
            if remaining > 0:
                model.learn(remaining, callback=_RunCallback(self, report), reset_num_timesteps=False)
            self.checkpoint(model, finished=True)
            report(self.name, model.num_timesteps, self.recipe.total_steps)
        self.restore_best(model)
        return model

    def checkpoint(self, model: BaseAlgorithm, *, finished: bool) -> None:
        # Write to temporary names and rename, so that a kill mid-write leaves the last good files.
        counters = {name: int(getattr(model, name)) for name in _COUNTERS if hasattr(model, name)}
        torch.save({"parameters": model.get_parameters(), "counters": counters}, self.folder / "tmp-checkpoint.pt")
        os.replace(self.folder / "tmp-checkpoint.pt", self.folder / "checkpoint.pt")
        if finished:
            (self.folder / "replay_buffer.npz").unlink(missing_ok=True)  # not needed once the run is done
        else:
            buffer = model.replay_buffer
            size = buffer.buffer_size if buffer.full else buffer.pos
            arrays = {name: getattr(buffer, name)[:size] for name in _BUFFER_ARRAYS
                      if isinstance(getattr(buffer, name, None), np.ndarray)}
            with open(self.folder / "tmp-replay_buffer.npz", "wb") as f:
                np.savez(f, size=size, pos=buffer.pos, full=buffer.full, num_timesteps=model.num_timesteps, **arrays)
            os.replace(self.folder / "tmp-replay_buffer.npz", self.folder / "replay_buffer.npz")
        for legacy in ("checkpoint.zip", "replay_buffer.pkl"):  # superseded: never to be unpickled by accident
            (self.folder / legacy).unlink(missing_ok=True)
        save_file(self._kept_weights(model), str(self.folder / "tmp-policy.safetensors"))
        os.replace(self.folder / "tmp-policy.safetensors", self.folder / "policy.safetensors")
        self.state.update(
            steps=int(model.num_timesteps), finished=finished,
            wall_time_s=round(self._wall_before + time.monotonic() - self._started, 1),
        )
        self.state_path.write_text(json.dumps(self.state, indent=1))

    def evaluate(self, model: BaseAlgorithm, steps: int) -> float:
        """Log the greedy policy's mean return; keep the weights of the best evaluation so far; return
        the mean."""
        returns = episode_returns(
            lambda obs: model.predict(obs, deterministic=True)[0], Variant(self.recipe.task),
            self.recipe.eval_episodes, seed=10_000 + steps,
        )
        mean = float(np.mean(returns))
        line = {"run": self.name, "steps": steps, "eval_return_mean": mean,
                "wall_time_s": round(self._wall_before + time.monotonic() - self._started, 1)}
        with open(self.root / "train_log.jsonl", "a") as log:
            log.write(json.dumps(line) + "\n")
        best = self.state.get("best")
        if best is None or mean >= best["eval_return_mean"]:
            save_file(self._kept_weights(model), str(self.folder / "best_policy.safetensors"))
            self.state["best"] = {"steps": steps, "eval_return_mean": mean}
        if self.recipe.select_top:
            (self.folder / "snapshots").mkdir(exist_ok=True)
            save_file(self._kept_weights(model), str(self.folder / "snapshots" / f"{steps}.safetensors"))
        return mean

    def _kept_weights(self, model: BaseAlgorithm) -> dict[str, torch.Tensor]:
        """The policy's weights as the run keeps them on disk: without its target networks (copies,
        made again on load), and in fp16 for CNN recipes, as they ship. The export rounds a CNN's
        weights to fp16 anyway, so this changes no exported agent and halves the committed files;
        resuming from ``policy.safetensors`` alone starts from weights rounded by at most 2**-11 of
        their size, far less than the fresh replay buffer such a resume starts with."""
        weights = {k: v.detach().contiguous() for k, v in model.policy.state_dict().items() if "_target" not in k}
        if self.recipe.cnn:
            weights = {k: v.half() if v.is_floating_point() else v for k, v in weights.items()}
        return weights

    def candidates(self) -> list[dict[str, Any]]:
        """The ``select_top`` best evaluations whose weights are on disk, best first: their steps,
        evaluation return and weights file."""
        log = self.root / "train_log.jsonl"
        lines = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
        best = self.state.get("best") or {}
        found = []
        for line in sorted((x for x in lines if x["run"] == self.name), key=lambda x: -x["eval_return_mean"]):
            path = self.folder / "snapshots" / f"{line['steps']}.safetensors"
            if not path.exists() and line["steps"] == best.get("steps"):
                path = self.folder / "best_policy.safetensors"  # evaluated before snapshots were kept
            if path.exists() and all(c["steps"] != line["steps"] for c in found):
                found.append({"steps": line["steps"], "eval_return_mean": line["eval_return_mean"], "path": path})
        return found[: self.recipe.select_top]

    def restore_best(self, model: BaseAlgorithm) -> None:
        """Load the weights of the best evaluation into ``model`` (DQN and DDPG are unstable:
        the last weights are often not the best ones)."""
        path = self.folder / "best_policy.safetensors"
        if self.state.get("best") and path.exists():
            model.policy.load_state_dict(load_file(str(path)), strict=False)


def train(
    task: str,
    method: str,
    out: str | Path,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    report: Reporter | None = None,
    command: str = "",
    id_episodes: int | None = None,
    export_only: bool = False,
    load_pickles: bool = False,
    recipe: Recipe | None = None,
    on_evaluation: Callable[[str, int, float], None] | None = None,
) -> Agent:
    """Train (or resume training) the ``task``/``method`` agent into ``out``; return it loaded.

    Args:
        task, method: which recipe (see :mod:`oodmon.agents.recipes`).
        out: the training directory (created; resumed if it holds an unfinished run).
        seed: the trial's seed; ensemble member k uses ``1000 * seed + k``.
        total_steps: override the recipe's steps per run (smoke tests, quick trials).
        report: called with (run, steps done, steps total) as training goes; see :data:`Reporter`.
        on_evaluation: called with (run, steps, mean return) after each periodic evaluation.
        command: the command line that started the training, recorded in the metadata.
        id_episodes: episodes behind ``id_return_mean`` (default :data:`ID_EPISODES` of the task).
        export_only: do not train; export the best checkpoint so far of an unfinished training
            (its metadata says ``training_complete: false``).
        load_pickles: resume from an older training's pickled ``checkpoint.zip`` and
            ``replay_buffer.pkl``. Loading a pickle runs the code it holds: only for files you made.
        recipe: train from this recipe instead of the shipped one of ``task``/``method`` (a sweep
            over drop probabilities, say); its task and method must be those given.
    """
    if recipe is None:
        recipe = recipe_for(task, method)
    elif (recipe.task, recipe.method) != (task, method):
        raise ConfigError(f"recipe is for {recipe.task}/{recipe.method}, not {task}/{method}")
    if total_steps is not None:
        recipe = _shortened(recipe, total_steps)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    report = report or (lambda *args: None)
    torch.set_num_threads(torch_threads(default=1))
    independent = method == "ensemble" and not recipe.shared_torso
    runs = (
        [_Run(recipe, root, f"member{k}", 1000 * seed + k) for k in range(recipe.n_members)]
        if independent else [_Run(recipe, root, "main", seed)]
    )
    for run in runs:
        run.on_evaluation = on_evaluation
    models = [run.train(report, export_only=export_only, load_pickles=load_pickles) for run in runs]

    env = _training_env(recipe)
    arch = architecture(recipe, env)
    ddpg = recipe.algorithm == "ddpg"
    bounds = {"action_low": env.action_space.low.tolist() if ddpg else None,
              "action_high": env.action_space.high.tolist() if ddpg else None}
    selection = None
    if recipe.select_top and len(runs) == 1:
        selection = _select_snapshot(runs[0], models[0], arch, seed, bounds, report)
    modules, policy = _as_shipped(models, arch, recipe, seed, bounds)
    id_returns = episode_returns(policy, Variant(task), id_episodes or ID_EPISODES[task], seed=ID_SEED)
    metadata = {
        "task": task, "method": method, "algorithm": recipe.algorithm, "architecture": arch,
        "ensemble": ("bootstrapped heads on a shared torso" if arch["shared_torso"] else "independent members")
        if method == "ensemble" else None,
        "n_members": arch["n_members"], "drop_p": None if method == "ensemble" else recipe.drop_p,
        "n_samples": arch["n_members"] if method == "ensemble" else recipe.n_samples,
        "seed": seed, "training_steps": [int(m.num_timesteps) for m in models],
        "wall_time_s": round(sum(run.state["wall_time_s"] for run in runs), 1),
        "selected_checkpoints": [selection["chosen"]] if selection else [run.state.get("best") for run in runs],
        "checkpoint_selection": selection and {k: v for k, v in selection.items() if k != "chosen"},
        "training_complete": all(run.finished for run in runs),
        "recipe_steps": recipe.total_steps,
        "hyperparams": {k: v for k, v in recipe.hyperparams.items() if isinstance(v, (int, float, str, bool))},
        "recipe_notes": recipe.notes, "versions": library_versions(), "command": command,
        "id_return_mean": round(float(np.mean(id_returns)), 2), "id_episodes": len(id_returns),
        "id_returns": [round(float(r), 2) for r in id_returns],
        **bounds,
    }
    save_modules(root, modules, metadata, half=recipe.cnn)
    return load_agent(root, task=task)


def _as_shipped(models: list[BaseAlgorithm], arch: dict[str, Any], recipe: Recipe, seed: int,
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
    if arch["algorithm"] == "dqn":
        return modules, lambda obs: int(estimator.estimate(obs).action[0])
    return modules, lambda obs: estimator.estimate(obs).action[0]


def _select_snapshot(run: _Run, model: BaseAlgorithm, arch: dict[str, Any], seed: int,
                     bounds: dict[str, Any], report: Reporter) -> dict[str, Any] | None:
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
    name, total, done = f"{run.name} choosing among {len(candidates)} snapshots", (
        len(to_play) * recipe.select_episodes), [0]

    def count(_: float) -> None:
        done[0] += 1
        report(name, done[0], total, "episodes")

    report(name, 0, total, "episodes")
    for candidate in to_play:
        model.policy.load_state_dict(load_file(str(candidate["path"])), strict=False)
        _, policy = _as_shipped([model], arch, recipe, seed, bounds)
        returns = episode_returns(policy, Variant(recipe.task), recipe.select_episodes, seed=SELECTION_SEED,
                                  on_episode=count)
        candidate["selection_return_mean"] = round(float(np.mean(returns)), 2)
        cache[candidate["sha256"]] = {"steps": candidate["steps"], **setting,
                                      "selection_return_mean": candidate["selection_return_mean"]}
        cache_path.write_text(json.dumps(cache, indent=1))  # after each candidate: a kill loses one at most
    chosen = max(candidates, key=lambda c: c["selection_return_mean"])  # first of equals: the better evaluated
    model.policy.load_state_dict(load_file(str(chosen["path"])), strict=False)
    described = [{k: v for k, v in c.items() if k not in ("path", "sha256")} for c in candidates]
    return {"chosen": described[candidates.index(chosen)], "candidates": described,
            "episodes": recipe.select_episodes, "seed": SELECTION_SEED}


def _shortened(recipe: Recipe, total_steps: int) -> Recipe:
    """The recipe cut to ``total_steps``, with its schedule (learning start, checkpoints) scaled and
    at most 2 episodes per snapshot in its choice among snapshots."""
    from dataclasses import replace

    hyper = dict(recipe.hyperparams)
    if "learning_starts" in hyper:
        hyper["learning_starts"] = min(hyper["learning_starts"], max(total_steps // 4, 1))
    if "buffer_size" in hyper:
        hyper["buffer_size"] = min(hyper["buffer_size"], max(total_steps, 1_000))
    every = max(total_steps // 2, 1)
    return replace(recipe, total_steps=total_steps, hyperparams=hyper,
                   checkpoint_every=min(recipe.checkpoint_every, every), eval_every=min(recipe.eval_every, every),
                   select_episodes=min(recipe.select_episodes, 2))
