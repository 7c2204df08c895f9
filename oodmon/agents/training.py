"""Train an uncertainty-aware agent from its recipe, resumably, and save it in the model format.

One loop for every task and method, its jobs in modules of their own: :mod:`~oodmon.agents.algorithms`
(a recipe's SB3 env and model), :mod:`~oodmon.agents.checkpoints` (a run: checkpoints, resume,
evaluations), :mod:`~oodmon.agents.export` (the choice among snapshots, the agent as it ships, its
files and metadata); :func:`train` runs them in order. A training directory holds::

    runs/<run>/checkpoint.pt       weights, optimizer states, step counters, every random stream and
                                   the episode under way (its reset and actions): tensors, numbers
                                   and strings, read back with ``torch.load(weights_only=True)``
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
continues from its last checkpoint, and the final export is redone. A checkpoint is written where
a rollout starts (after the gradient steps of the one before) and holds the random streams and the
episode under way, which the resumed run plays again to its step
(:class:`~oodmon.agents.algorithms.EpisodeSoFar`): CartPole and Pendulum trainings resumed after a
kill end with the weights of the same training never stopped, bit for bit (tests/agents); so did
a 2,000-step Pong training killed after its checkpoint at step 1,000 (its emulator draws no random
numbers with sticky actions off, as oodmon's Pong has them). A run
resumed from ``policy.safetensors`` alone (the big checkpoint gone) starts a new buffer and streams.

Nothing in a training directory is unpickled: a crafted file there cannot run code. Older
trainings kept SB3's ``checkpoint.zip`` and ``replay_buffer.pkl`` (pickles); they are ignored
with a warning (the run resumes from ``policy.safetensors`` with a fresh buffer) unless
``train(..., load_pickles=True)`` (``oodmon train --unsafe-load-pickles``) says the user trusts them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from oodmon.agents.agent import Agent, load_agent
from oodmon.agents.algorithms import architecture, training_env
from oodmon.agents.checkpoints import Run
from oodmon.agents.evaluation import episode_returns
from oodmon.agents.export import as_shipped, select_snapshot, write_agent
from oodmon.agents.recipes import Recipe, recipe_for
from oodmon.agents.serialization import read_metadata
from oodmon.envs.grid import Variant
from oodmon.errors import ConfigError, ModelFormatError
from oodmon.progress import Progress
from oodmon.seeds import ID_RETURN as ID_SEED
from oodmon.threads import limit_threads

__all__ = ["ID_EPISODES", "architecture", "train"]

#: Episodes of the default env behind a saved model's ``id_return_mean``.
ID_EPISODES = {"cartpole": 20, "pendulum": 20, "pong": 10}


def _refuse_another_agent(root: Path, task: str, method: str, names: list[str]) -> None:
    """Raise :class:`ConfigError` if ``root`` holds a trained agent (``model.json``) that no run of
    this training (``runs/<name>/state.json``) made: a shipped or copied agent, or another method's
    training, whose files the export would replace (measured: ``oodmon train --out`` a copy of the
    zoo's CartPole ensemble replaced its weights with those of a 200-step training)."""
    meta_path = root / "model.json"
    if not meta_path.is_file() or any((root / "runs" / name / "state.json").is_file() for name in names):
        return
    try:
        meta = read_metadata(root)
        what = f"{meta['task']}/{meta['method']}, ID return {meta.get('id_return_mean')}"
    except ModelFormatError:  # damaged, or another version's: an agent's file all the same
        what = "its model.json"
    raise ConfigError(f"{root} holds a trained agent ({what}) that no {task}/{method} training in it made: training "
                      "there would replace it. Train into another folder (or remove its model.json to train there)")


def train(
    task: str,
    method: str,
    out: str | Path,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    on_progress: Progress | None = None,
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
        on_progress: ``(stage, done, total)`` as training goes (see :mod:`oodmon.progress`): each run's
            "<run> training steps", then the choice among snapshots' episodes where the recipe has one.
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
        recipe = recipe.shortened(total_steps)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    report = on_progress or (lambda *args: None)
    limit_threads()
    independent = method == "ensemble" and not recipe.shared_torso
    names = [f"member{k}" for k in range(recipe.n_members)] if independent else ["main"]
    _refuse_another_agent(root, task, method, names)
    runs = [Run(recipe, root, name, 1000 * seed + k if independent else seed) for k, name in enumerate(names)]
    for run in runs:
        run.on_evaluation = on_evaluation
    try:
        models = [run.train(report, export_only=export_only, load_pickles=load_pickles) for run in runs]
    except KeyboardInterrupt as interrupt:  # what a resume goes on from: each run's steps at its last checkpoint
        interrupt.checkpoint_steps = [int(run.state["steps"]) for run in runs]
        interrupt.checkpoint_every = recipe.checkpoint_every  # (0 steps everywhere: when the first falls due)
        raise

    env = training_env(recipe)
    arch = architecture(recipe, env)
    ddpg = recipe.algorithm == "ddpg"
    bounds = {"action_low": env.action_space.low.tolist() if ddpg else None,
              "action_high": env.action_space.high.tolist() if ddpg else None}
    selection = None
    if recipe.select_top and len(runs) == 1:
        selection = select_snapshot(runs[0], models[0], arch, seed, bounds, report)
    modules, policy = as_shipped(models, arch, recipe, seed, bounds)
    id_returns = episode_returns(policy, Variant(task), id_episodes or ID_EPISODES[task], seed=ID_SEED)
    write_agent(root, recipe, runs, models, modules, arch, seed=seed, selection=selection, id_returns=id_returns,
                bounds=bounds, command=command)
    return load_agent(root, task=task)
