"""One SB3 model being trained (:class:`Run`): its folder, checkpoints (tensors and arrays, never
pickles unless asked), resume, evaluations and the snapshots kept for the choice at export. The
files are listed in :mod:`oodmon.agents.training`."""

from __future__ import annotations

import json
import os
import random
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch
from safetensors.torch import load_file, save_file
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger

from oodmon import seeds
from oodmon.agents.algorithms import EpisodeSoFar, algorithm_class, new_model, training_env
from oodmon.agents.evaluation import episode_returns
from oodmon.agents.recipes import Recipe, recipe_differences, recipe_record
from oodmon.envs.grid import Variant
from oodmon.errors import ConfigError
from oodmon.jsonfile import write_json
from oodmon.outputs import write_failure, write_whole
from oodmon.progress import Progress

__all__ = ["Run"]


#: The replay buffer's arrays that a checkpoint keeps (``next_observations`` is None where the
#: buffer saves memory by reading the next observation from the following row, as Pong's does).
_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
#: The SB3 counters a resumed run must go on from (schedules, target updates, policy delay).
_COUNTERS = ("num_timesteps", "_n_updates", "_episode_num", "_n_calls")


def _load_pickled_checkpoint(recipe: Recipe, folder: Path, env: gymnasium.Env, *, with_buffer: bool) -> BaseAlgorithm:
    """SB3's own ``checkpoint.zip`` and ``replay_buffer.pkl`` of an older training. These are pickles:
    loading them runs whatever code they hold. Only ever called with ``load_pickles=True``."""
    model = algorithm_class(recipe).load(folder / "checkpoint.zip", env=env, device="cpu")
    buffer = folder / "replay_buffer.pkl"
    if with_buffer and buffer.exists():
        model.load_replay_buffer(buffer)
    return model


def _append_line(path: Path, record: dict[str, Any]) -> None:
    """``record`` as one JSON line at the end of ``path``, on a line of its own even where the file
    ends in a line cut short (a kill or a full disk while it was written), which would swallow it."""
    try:
        with open(path, "a+b") as log:  # opened at the end; writes go there whatever is read before
            torn = False
            if log.tell() > 0:
                log.seek(-1, os.SEEK_END)
                torn = log.read(1) != b"\n"
            log.write((("\n" if torn else "") + json.dumps(record) + "\n").encode())
    except OSError as error:  # a full disk's error names no file
        raise write_failure(path, error) from None


def _read_lines(path: Path) -> list[dict[str, Any]]:
    """The records of a JSON-lines file (none where it is missing), less any line cut short, with a warning."""
    records = []
    for text in path.read_text().splitlines() if path.exists() else []:
        try:
            records.append(json.loads(text))
        except json.JSONDecodeError:
            warnings.warn(f"{path}: skipped a line cut short (a kill or a full disk while it was written): "
                          f"{text[:60]!r}", UserWarning, stacklevel=3)
    return records


def _write_whole(path: Path, write: Callable[[Path], object]) -> None:
    """``write_whole`` with the run's ``tmp-<name>`` part: a kill mid-write (a session's end stops its
    trainings) leaves the file before; a full disk is one line naming the file, with no part left."""
    write_whole(path, write, part=path.with_name(f"tmp-{path.name}"))


def _save_whole(tensors: dict[str, torch.Tensor], path: Path) -> None:
    """``tensors`` at ``path``, written whole (``_write_whole``)."""
    _write_whole(path, lambda part: save_file(tensors, str(part)))

class _RunCallback(BaseCallback):
    """Checkpoints, evaluations and progress reports during one SB3 ``learn`` call.

    A checkpoint falls due every ``checkpoint_every`` steps and is written when the next rollout
    starts: after the gradient steps of the one that ended (SB3 trains between rollouts), with
    every step's transition in the buffer, so that a resumed training has nothing left undone."""

    def __init__(self, run: Run, report: Progress) -> None:
        super().__init__()
        self.run, self.report = run, report
        self.checkpoint_due = False

    def _on_step(self) -> bool:
        steps, recipe = self.num_timesteps, self.run.recipe
        if steps % 500 == 0:
            self.report(f"{self.run.name} training steps", steps, recipe.total_steps)
        if steps % recipe.eval_every == 0:
            mean = self.run.evaluate(self.model, steps)
            if self.run.on_evaluation is not None:
                self.run.on_evaluation(self.run.name, steps, mean)
        if steps % recipe.checkpoint_every == 0:
            self.checkpoint_due = True
        return True

    def _on_rollout_start(self) -> None:
        if self.checkpoint_due:
            self.run.checkpoint(self.model, finished=False)
            self.checkpoint_due = False


def _episode_so_far(model: BaseAlgorithm) -> EpisodeSoFar | None:
    """The training env's :class:`EpisodeSoFar` under SB3's wrappers (``None``: a model of another env)."""
    env = model.env.envs[0] if hasattr(model.env, "envs") else None
    while env is not None and not isinstance(env, EpisodeSoFar):
        env = getattr(env, "env", None)
    return env


def _where_it_stands(model: BaseAlgorithm) -> dict[str, Any] | None:
    """Every random stream the training draws from and the episode under way, as tensors, numbers
    and strings (``torch.load(weights_only=True)`` reads them back): torch's generator (dropout
    while training), numpy's and Python's global ones (exploration, action noise, the buffer's
    samples), the action space's (random actions), and the env's episode (:class:`EpisodeSoFar`)."""
    episode = _episode_so_far(model)
    if episode is None or not episode.started:
        return None
    _, keys, position, has_gauss, gauss = np.random.get_state()
    version, internal, gauss_next = random.getstate()
    actions = np.stack(episode.actions) if episode.actions else np.zeros(0)
    return {
        "torch": torch.get_rng_state(),
        "numpy": torch.from_numpy(keys.astype(np.int64)), "numpy_rest": [int(position), int(has_gauss), float(gauss)],
        "python": torch.tensor(internal, dtype=torch.int64), "python_rest": [int(version), gauss_next],
        "action_space": json.dumps(model.action_space.np_random.bit_generator.state),
        "reset_seed": episode.reset_seed,
        "env_generator": None if episode.generator_state is None else json.dumps(episode.generator_state),
        "actions": torch.from_numpy(actions),
    }


def _stand_where_it_stood(model: BaseAlgorithm, saved: dict[str, Any]) -> None:
    """Put ``model`` and its env back where :func:`_where_it_stands` found them: the episode played
    again to its step, then every random stream as it was."""
    generator = saved["env_generator"]
    obs = EpisodeSoFar.replay(model.env.envs[0], saved["reset_seed"], generator and json.loads(generator),
                              [a.numpy() for a in saved["actions"]])
    model._last_obs = np.asarray(obs, dtype=model.observation_space.dtype)[None]  # as the VecEnv batches it
    position, has_gauss, gauss = saved["numpy_rest"]
    np.random.set_state(("MT19937", saved["numpy"].numpy().astype(np.uint32), position, has_gauss, gauss))
    version, gauss_next = saved["python_rest"]
    random.setstate((version, tuple(int(v) for v in saved["python"]), gauss_next))
    torch.set_rng_state(saved["torch"])
    model.action_space.np_random.bit_generator.state = json.loads(saved["action_space"])


def run_recipe_differences(state: dict[str, Any], recipe: Recipe) -> list[str]:
    """How the recipe a run's ``state`` records differs from ``recipe`` (empty for runs begun before
    oodmon recorded it: those cannot be told apart). An independent ensemble member trains alone, the
    same whatever the size of its ensemble: the size is not compared (member k of a 5-member training
    is member k of a 20-member one, with the same seed)."""
    if "recipe" not in state:
        return []
    record = state["recipe"]
    if recipe.method == "ensemble" and not recipe.shared_torso:
        record = record | {"architecture": record.get("architecture", {}) | {"n_members": recipe.n_members},
                           "n_samples": recipe.n_members}
    return recipe_differences(record, recipe)


class Run:
    """One SB3 model being trained: its folder, checkpoints and log.

    Raises:
        ConfigError: the folder holds a run begun by another recipe or with another seed (its
            ``state.json`` says so).
    """

    def __init__(self, recipe: Recipe, root: Path, name: str, seed: int) -> None:
        self.on_evaluation: Callable[[str, int, float], None] | None = None  # see train()
        self.recipe, self.root, self.name, self.seed = recipe, root, name, seed
        self.folder = root / "runs" / name
        self.folder.mkdir(parents=True, exist_ok=True)
        self.state_path = self.folder / "state.json"
        self.state = json.loads(self.state_path.read_text()) if self.state_path.exists() else {
            "steps": 0, "wall_time_s": 0.0, "finished": False, "seed": seed, "recipe": recipe_record(recipe)}
        differences = run_recipe_differences(self.state, recipe)
        if differences:
            raise ConfigError(f"{self.folder} holds a training by another recipe ({'; '.join(differences)}): resuming it "
                              "would mix the two. Train into another folder, or remove that one to start again")
        if self.state.get("seed", seed) != seed:  # its model would be exported under this seed
            raise ConfigError(f"{self.folder} holds a training with seed {self.state['seed']}, not {seed}: resuming it "
                              "would give that seed's model under this one. Train into another folder, or remove that "
                              "one to start again")
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
        model = new_model(self.recipe, env, self.seed)
        checkpoint = self.folder / "checkpoint.pt"
        if checkpoint.exists():
            saved = torch.load(checkpoint, map_location="cpu", weights_only=True)  # tensors and numbers only
            model.set_parameters(saved["parameters"], exact_match=True, device="cpu")
            for name, value in saved["counters"].items():
                setattr(model, name, int(value))
            if not (with_buffer and self._load_buffer(model)):
                self._refill(model)
            elif saved.get("stands") is not None:  # the episode and the random streams too: as if never stopped
                _stand_where_it_stood(model, saved["stands"])
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

    def train(self, report: Progress, *, export_only: bool = False, load_pickles: bool = False) -> BaseAlgorithm:
        self._started = time.monotonic()  # wall time counts from here: members train one after another
        env = training_env(self.recipe)
        if export_only and self.state["steps"] == 0:
            raise ConfigError(f"nothing to export in {self.folder}: no checkpoint yet; train first")
        model = self.load_or_create(env, with_buffer=not export_only, load_pickles=load_pickles)
        report(f"{self.name} training steps", model.num_timesteps, self.recipe.total_steps)
        if not self.finished and not export_only:
            remaining = self.recipe.total_steps - model.num_timesteps
            if remaining > 0:
                # SB3's own logger (verbose=0, no tensorboard) makes an empty tempdir/SB3-<time> folder per
                # learn(): thousands over the test suite and the trainings. Ours records and writes nothing.
                model.set_logger(Logger(folder=None, output_formats=[]))
                model.learn(remaining, callback=_RunCallback(self, report), reset_num_timesteps=False)
            self.checkpoint(model, finished=True)
            report(f"{self.name} training steps", model.num_timesteps, self.recipe.total_steps)
        self.restore_best(model)
        return model

    def checkpoint(self, model: BaseAlgorithm, *, finished: bool) -> None:
        # Write to temporary names and rename, so that a kill mid-write leaves the last good files.
        counters = {name: int(getattr(model, name)) for name in _COUNTERS if hasattr(model, name)}
        stands = None if finished else _where_it_stands(model)  # a finished run is never resumed
        saved = {"parameters": model.get_parameters(), "counters": counters, "stands": stands}
        _write_whole(self.folder / "checkpoint.pt", lambda part: torch.save(saved, part))
        if finished:
            (self.folder / "replay_buffer.npz").unlink(missing_ok=True)  # not needed once the run is done
        else:
            buffer = model.replay_buffer
            size = buffer.buffer_size if buffer.full else buffer.pos
            arrays = {name: getattr(buffer, name)[:size] for name in _BUFFER_ARRAYS
                      if isinstance(getattr(buffer, name, None), np.ndarray)}

            def write_buffer(part: Path) -> None:
                with open(part, "wb") as f:
                    np.savez(f, size=size, pos=buffer.pos, full=buffer.full, num_timesteps=model.num_timesteps, **arrays)

            _write_whole(self.folder / "replay_buffer.npz", write_buffer)
        for legacy in ("checkpoint.zip", "replay_buffer.pkl"):  # superseded: never to be unpickled by accident
            (self.folder / legacy).unlink(missing_ok=True)
        _save_whole(self._kept_weights(model), self.folder / "policy.safetensors")
        self.state.update(
            steps=int(model.num_timesteps), finished=finished,
            wall_time_s=round(self._wall_before + time.monotonic() - self._started, 1),
        )
        write_json(self.state_path, self.state)  # whole: a kill mid-write would leave a state the resume cannot read

    def evaluate(self, model: BaseAlgorithm, steps: int) -> float:
        """Log the greedy policy's mean return; keep the weights of the best evaluation so far; return
        the mean."""
        returns = episode_returns(
            lambda obs: model.predict(obs, deterministic=True)[0], Variant(self.recipe.task),
            self.recipe.eval_episodes, seed=seeds.TRAINING_EVALUATION + steps,
        )
        mean = float(np.mean(returns))
        line = {"run": self.name, "steps": steps, "eval_return_mean": mean,
                "wall_time_s": round(self._wall_before + time.monotonic() - self._started, 1)}
        _append_line(self.root / "train_log.jsonl", line)
        best = self.state.get("best")
        if best is None or mean >= best["eval_return_mean"]:
            _save_whole(self._kept_weights(model), self.folder / "best_policy.safetensors")
            self.state["best"] = {"steps": steps, "eval_return_mean": mean}
        if self.recipe.select_top:
            (self.folder / "snapshots").mkdir(exist_ok=True)
            _save_whole(self._kept_weights(model), self.folder / "snapshots" / f"{steps}.safetensors")
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
        lines = _read_lines(self.root / "train_log.jsonl")
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
