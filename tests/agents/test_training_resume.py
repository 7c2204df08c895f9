"""A training stopped and resumed ends as the same training never stopped (its own file, so that the
test runner can give it a core of its own beside the other training tests)."""

from __future__ import annotations

import dataclasses
import json

import gymnasium
import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from oodmon.agents.algorithms import EpisodeSoFar
from oodmon.agents.recipes import recipe_for
from oodmon.agents.training import train
from oodmon.envs.grid import ENV_IDS


@pytest.mark.parametrize("task, method, steps", [("cartpole", "dropout", 1000), ("pendulum", "dropout", 420)])
def test_an_interrupted_training_resumed_ends_with_the_weights_of_one_never_interrupted(tmp_path, task, method, steps):
    """The checkpoint holds the random streams and the episode under way: the resumed training
    plays that episode to its step again and draws what the interrupted one would have drawn.
    (Checkpoints fall due at half the steps: CartPole's is written at step 512, where its rollouts
    of 256 steps end; Pendulum's at 210, 10 steps into its second episode. Pendulum's actor and
    critics are [64, 64] instead of the recipe's [400, 300]: the same code resumes them; 12.5 s -> 4.7 s.)"""
    recipe = dataclasses.replace(recipe_for(task, method), net_arch=[64, 64]) if task == "pendulum" else None

    def interrupt(run, done, mean):  # at the last evaluation, before the training's end is written
        if done == steps:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt) as stopped:
        train(task, method, tmp_path / "stopped", total_steps=steps, on_evaluation=interrupt, id_episodes=1,
              recipe=recipe)
    state = json.loads((tmp_path / "stopped" / "runs" / "main" / "state.json").read_text())
    assert not state["finished"] and 0 < state["steps"] < steps
    # (what `oodmon train` says of it: the step of the last checkpoint, and how often they fall due)
    assert stopped.value.checkpoint_steps == [state["steps"]] and stopped.value.checkpoint_every == steps // 2
    saved = torch.load(tmp_path / "stopped" / "runs" / "main" / "checkpoint.pt", weights_only=True)
    assert len(saved["stands"]["actions"]) > 0  # stopped inside an episode, which the resume plays again
    train(task, method, tmp_path / "stopped", total_steps=steps, id_episodes=1, recipe=recipe)
    train(task, method, tmp_path / "straight", total_steps=steps, id_episodes=1, recipe=recipe)
    resumed, straight = (load_file(str(tmp_path / f / "model.safetensors")) for f in ("stopped", "straight"))
    assert resumed.keys() == straight.keys() and resumed
    for name in resumed:
        torch.testing.assert_close(resumed[name], straight[name], rtol=0, atol=0)
    logs = [(tmp_path / f / "train_log.jsonl").read_text().splitlines() for f in ("stopped", "straight")]
    returns = [{json.loads(line)["steps"]: json.loads(line)["eval_return_mean"] for line in log} for log in logs]
    assert returns[0] == returns[1] and len(returns[0]) >= 2  # every evaluation alike, before and after the stop


@pytest.mark.parametrize("task", ["cartpole", "pendulum"])
def test_an_episode_so_far_played_again_stands_where_it_stood(task):
    """The first episode (its reset seeded) and a later one (reset from the generator as it stood):
    a fresh env playing the record again reaches the same observation, and goes on as the first."""
    env = EpisodeSoFar(gymnasium.make(ENV_IDS[task]))
    env.action_space.seed(0)
    obs, _ = env.reset(seed=3)
    for episode in range(2):
        for _ in range(8):  # short of CartPole's fall under random actions
            obs, *_ = env.step(env.action_space.sample())
        record = (env.reset_seed, env.generator_state, list(env.actions))
        assert (record[0] is None) == (episode == 1) and (record[1] is None) == (episode == 0)
        again = EpisodeSoFar(gymnasium.make(ENV_IDS[task]))
        np.testing.assert_array_equal(EpisodeSoFar.replay(again, *record), obs)
        action = env.action_space.sample()
        np.testing.assert_array_equal(again.step(action)[0], env.step(action)[0])
        obs, _ = env.reset()  # the next episode, from the generator as it stands
