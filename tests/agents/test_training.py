"""Training smoke tests (tens of steps), resuming, and the SB3 networks the estimators sample."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from oodmon.agents import load_agent
from oodmon.agents.layers import DropConnectLinear
from oodmon.agents.networks import estimator_for, modules_from_sb3
from oodmon.agents.recipes import recipe_for
from oodmon.agents.algorithms import new_model as _new_model
from oodmon.agents.algorithms import training_env as _training_env
from oodmon.agents.checkpoints import Run as _Run
from oodmon.agents.training import architecture, train
from oodmon.envs import pong
from oodmon.errors import ConfigError, InvalidParameterError, UnknownParameterError

CASES = [("cartpole", "dropout"), ("cartpole", "ensemble"), ("pendulum", "dropconnect"), ("pendulum", "ensemble"),
         ("pong", "ensemble")]


@pytest.mark.parametrize("task, method", CASES, ids=lambda x: x)
def test_training_runs_and_saves_a_loadable_agent(tmp_path, task, method, monkeypatch):
    steps = {"pong": 64, "pendulum": 120}.get(task, 300)
    recipe = recipe_for(task, method)
    if task == "pong":  # one game per evaluation, per snapshot at export and in ID (5 games of an untrained agent, not 11)
        recipe = dataclasses.replace(recipe, eval_episodes=1, select_episodes=1)
        # Each game cut at 100 agent steps (ALE's frame limit, as its 30 minutes cut a long game): an
        # untrained agent's whole game is some 770 steps of 2 ms, and this test is about what is saved.
        monkeypatch.setattr(pong, "_MAX_FRAMES", 100 * pong.FRAME_SKIP)
    elif (task, method) == ("pendulum", "ensemble"):  # 5 members of [64, 64], not [400, 300] (15 ms a gradient step)
        recipe = dataclasses.replace(recipe, net_arch=[64, 64])
    id_episodes = 1 if task == "pong" else 2
    agent = train(task, method, tmp_path, total_steps=steps, id_episodes=id_episodes, recipe=recipe)
    meta = json.loads((tmp_path / "model.json").read_text())
    for key in ("task", "method", "algorithm", "architecture", "seed", "training_steps", "wall_time_s", "versions",
                "id_return_mean", "id_episodes", "n_samples"):
        assert key in meta
    assert meta["task"] == task and meta["method"] == method
    assert all(s >= steps for s in meta["training_steps"])
    assert meta["id_episodes"] == id_episodes and len(meta["id_returns"]) == id_episodes
    # Pong's recipe chooses among its evaluation snapshots (at 32 and 64 steps here) at export.
    assert (meta["checkpoint_selection"] and len(meta["checkpoint_selection"]["candidates"])) == (2 if task == "pong" else None)
    assert len(meta["training_steps"]) == (5 if method == "ensemble" and task != "pong" else 1)
    assert meta["versions"]["torch"].startswith(torch.__version__.split("+")[0])
    assert meta["machine"].endswith(f"torch {torch.backends.cpu.get_cpu_capability()}")  # the CPU kind it trained on
    # The weights a run keeps on disk are fp16 where they ship so (Pong), to keep committed runs small.
    kept = sorted((tmp_path / "runs").glob("*/**/*.safetensors"))
    assert kept and {t.dtype for f in kept for t in load_file(str(f)).values()} == (
        {torch.float16} if task == "pong" else {torch.float32})
    loaded = load_agent(tmp_path, task=task)
    obs = np.zeros(loaded.estimator.obs_shape, np.float32)
    estimate = loaded.estimate(obs)
    assert estimate.samples.shape[0] == (5 if method == "ensemble" else 20)
    assert agent.metadata == loaded.metadata


def test_interrupted_training_resumes_from_its_checkpoint(tmp_path):
    seen: list[int] = []

    def interrupt_after_checkpoint(run, done, total):
        seen.append(done)
        if done >= 600:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train("cartpole", "dropout", tmp_path, total_steps=1000, on_progress=interrupt_after_checkpoint, id_episodes=2)
    state = json.loads((tmp_path / "runs" / "main" / "state.json").read_text())
    # due at half the steps (500), written when the next rollout starts (CartPole trains every 256 steps)
    assert state["finished"] is False and state["steps"] == 512
    assert not (tmp_path / "model.json").exists()

    resumed: list[int] = []
    train("cartpole", "dropout", tmp_path, total_steps=1000, on_progress=lambda run, done, total: resumed.append(done),
          id_episodes=2)
    assert resumed[0] == 512  # it started from the checkpoint, not from zero
    state = json.loads((tmp_path / "runs" / "main" / "state.json").read_text())
    assert state["finished"] is True and state["steps"] >= 1000
    assert not (tmp_path / "runs" / "main" / "replay_buffer.npz").exists()  # dropped once finished
    # Running the finished command again trains nothing more.
    again: list[int] = []
    train("cartpole", "dropout", tmp_path, total_steps=1000, on_progress=lambda run, done, total: again.append(done),
          id_episodes=2)
    assert min(again) == state["steps"]


def test_a_checkpoint_on_a_full_disk_is_one_error_naming_it_and_the_last_one_is_kept(tmp_path, monkeypatch):
    """torch.save on a full disk raises its own RuntimeError (measured on a 600 KB tmpfs: "[enforce fail
    at inline_container.cc:672] . unexpected pos ..."), which reached `oodmon train` as a traceback
    and left its part file filling the disk."""
    real_save, calls = torch.save, []

    def full_disk(obj, f):  # the first checkpoint (at 512 steps) written, the next one not
        calls.append(f)
        if len(calls) == 1:
            return real_save(obj, f)
        Path(f).write_bytes(b"\0" * 1000)
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 281408 vs 281296")

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(OSError, match=r"runs/main/checkpoint\.pt could not be written \(\[enforce fail .* MB free on "
                                      r"its disk\)$"):
        train("cartpole", "dropout", tmp_path, total_steps=1000, id_episodes=2)
    run = tmp_path / "runs" / "main"
    assert json.loads((run / "state.json").read_text())["steps"] == 512 and not list(run.glob("tmp-*"))
    monkeypatch.setattr(torch, "save", real_save)
    resumed: list[int] = []
    train("cartpole", "dropout", tmp_path, total_steps=1000, on_progress=lambda run, done, total: resumed.append(done),
          id_episodes=2)
    assert resumed[0] == 512  # from the checkpoint the failure left whole


def test_a_run_begun_by_another_recipe_is_not_resumed(tmp_path):
    """Resuming mixes two trainings if the recipe changed in between (a new drop probability, other
    steps): the run's state.json records its recipe, and another is a clear error. A state written
    before oodmon recorded the recipe is resumed as before."""
    from oodmon.agents.recipes import recipe_record

    recipe = recipe_for("cartpole", "dropout")
    folder = tmp_path / "runs" / "main"
    folder.mkdir(parents=True)
    state = {"steps": 500, "wall_time_s": 1.0, "finished": False, "seed": 0, "recipe": recipe_record(recipe)}
    (folder / "state.json").write_text(json.dumps(state))
    assert _Run(recipe, tmp_path, "main", 0).state["steps"] == 500
    with pytest.raises(ConfigError, match=r"holds a training by another recipe \(drop_p: 0.1 -> 0.3\): resuming it would "
                                          r"mix the two. Train into"):
        _Run(dataclasses.replace(recipe, drop_p=0.3), tmp_path, "main", 0)
    del state["recipe"]
    (folder / "state.json").write_text(json.dumps(state))
    assert _Run(dataclasses.replace(recipe, drop_p=0.3), tmp_path, "main", 0).state["steps"] == 500


def test_an_ensemble_member_resumes_in_an_ensemble_of_another_size_but_not_of_another_network(tmp_path):
    """Member k trains alone with the same seed whatever the ensemble's size, so a 5-member
    training's member goes on in a 20-member one; a member of another network or learning rate
    is still refused."""
    from oodmon.agents.recipes import recipe_record

    five = recipe_for("pendulum", "ensemble")
    folder = tmp_path / "runs" / "member3"
    folder.mkdir(parents=True)
    state = {"steps": 500, "wall_time_s": 1.0, "finished": False, "seed": 3, "recipe": recipe_record(five)}
    (folder / "state.json").write_text(json.dumps(state))
    twenty = dataclasses.replace(five, n_members=20)
    assert _Run(twenty, tmp_path, "member3", 3).state["steps"] == 500
    with pytest.raises(ConfigError, match=r"another recipe \(net_arch: \[400, 300\] -> \[64, 64\]\)"):
        _Run(dataclasses.replace(twenty, net_arch=[64, 64]), tmp_path, "member3", 3)
    with pytest.raises(ConfigError, match=r"another recipe \(learning_rate: 0.001 -> 0.0003\)"):
        _Run(dataclasses.replace(twenty, hyperparams=five.hyperparams | {"learning_rate": 3e-4}), tmp_path, "member3", 3)


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
def test_mc_network_is_the_sb3_q_network_with_stochastic_layers(method):
    recipe = recipe_for("cartpole", method)
    env = _training_env(recipe)
    model = _new_model(recipe, env, seed=0)
    arch = architecture(recipe, env)
    modules = modules_from_sb3([model], arch)
    obs = np.random.default_rng(0).normal(size=(6, 4)).astype(np.float32)
    model.policy.set_training_mode(False)
    with torch.no_grad():
        sb3_q = model.policy.q_net(torch.as_tensor(obs)).numpy()
        ours = modules["network"].eval()(torch.as_tensor(obs)).numpy()
    np.testing.assert_allclose(ours, sb3_q, atol=1e-6)
    stochastic = [m for m in modules["network"] if isinstance(m, (torch.nn.Dropout, DropConnectLinear))]
    # last_only: one stochastic layer, at the output; full depth (CartPole DropConnect): every layer
    linear = [m for m in modules["network"] if isinstance(m, torch.nn.Linear)]
    assert len(stochastic) == (1 if recipe.last_only else len(linear))
    estimate = estimator_for(modules, arch, n_samples=20, seed=0).estimate(obs)
    assert (estimate.std > 0).all()
    np.testing.assert_allclose(estimate.mean, sb3_q, atol=0.5 * np.abs(sb3_q).max() + 1e-3)


def test_independent_ensemble_members_are_the_sb3_members(tmp_path):
    recipe = recipe_for("cartpole", "ensemble")
    env = _training_env(recipe)
    models = [_new_model(recipe, env, seed=k) for k in range(5)]
    arch = architecture(recipe, env)
    estimate = estimator_for(modules_from_sb3(models, arch), arch).estimate(np.ones((3, 4), np.float32))
    with torch.no_grad():
        expected = np.stack([m.policy.q_net(torch.ones(3, 4)).numpy() for m in models])
    np.testing.assert_allclose(estimate.samples, expected, atol=1e-6)


def test_unknown_task_or_method():
    with pytest.raises(UnknownParameterError, match="unknown method 'bayes'; choose one of dropout, dropconnect, ensemble"):
        recipe_for("cartpole", "bayes")
    with pytest.raises(UnknownParameterError, match="unknown task 'hopper'"):
        recipe_for("hopper", "dropout")


def test_training_resumes_from_the_weights_alone_when_the_big_checkpoint_is_gone(tmp_path):
    def interrupt(run, done, total):
        if done >= 600:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train("cartpole", "dropconnect", tmp_path, total_steps=1000, on_progress=interrupt, id_episodes=2)
    main = tmp_path / "runs" / "main"
    (main / "checkpoint.pt").unlink()
    (main / "replay_buffer.npz").unlink()
    assert (main / "policy.safetensors").stat().st_size < 400_000
    saved = load_file(str(main / "policy.safetensors"))
    assert "q_net.q_net.0.weight" in saved and not any("target" in k for k in saved)
    recipe = recipe_for("cartpole", "dropconnect").shortened(1000)
    model = _Run(recipe, tmp_path, "main", 0).load_or_create(_training_env(recipe))
    for name, tensor in model.policy.q_net.state_dict().items():
        torch.testing.assert_close(tensor, saved[f"q_net.{name}"])
        torch.testing.assert_close(model.policy.q_net_target.state_dict()[name], tensor)
    assert model.num_timesteps == 512 and model.learning_starts == 512 + recipe.hyperparams["learning_starts"]
    resumed: list[int] = []
    agent = train("cartpole", "dropconnect", tmp_path, total_steps=1000, id_episodes=2,
                  on_progress=lambda run, done, total: resumed.append(done))
    assert resumed[0] == 512 and agent.metadata["training_steps"][0] >= 1000


def test_export_only_ships_an_unfinished_training_honestly(tmp_path):
    with pytest.raises(ConfigError, match="nothing to export .* no checkpoint yet"):
        train("cartpole", "dropout", tmp_path / "empty", total_steps=1000, export_only=True)

    def interrupt(run, done, total):
        if done >= 600:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train("cartpole", "dropout", tmp_path, total_steps=1000, on_progress=interrupt, id_episodes=2)
    agent = train("cartpole", "dropout", tmp_path, total_steps=1000, export_only=True, id_episodes=2)
    meta = agent.metadata
    assert meta["training_complete"] is False and meta["training_steps"] == [512] and meta["recipe_steps"] == 1000
    state = json.loads((tmp_path / "runs" / "main" / "state.json").read_text())
    assert state["steps"] == 512 and state["finished"] is False  # exporting trained nothing


def test_export_ships_the_snapshot_that_plays_best_as_shipped(tmp_path, monkeypatch):
    import oodmon.agents.export as export
    import oodmon.agents.training as training
    from dataclasses import replace

    from oodmon.agents.evaluation import episode_returns
    from oodmon.envs.grid import Variant

    monkeypatch.setattr(training, "recipe_for",
                        lambda task, method: replace(recipe_for(task, method), select_top=2, eval_every=500))
    reports: list[tuple] = []
    agent = train("cartpole", "dropconnect", tmp_path, total_steps=1500, id_episodes=2,
                  on_progress=lambda *args: reports.append(args))
    snapshots = sorted((tmp_path / "runs" / "main" / "snapshots").iterdir())
    assert [p.name for p in snapshots] == ["1000.safetensors", "1500.safetensors", "500.safetensors"]
    log = [json.loads(line) for line in (tmp_path / "train_log.jsonl").read_text().splitlines()]
    best_two = sorted(log, key=lambda x: -x["eval_return_mean"])[:2]

    selection = agent.metadata["checkpoint_selection"]
    assert selection["episodes"] == 2 and selection["seed"] == export.SELECTION_SEED != training.ID_SEED
    assert [c["steps"] for c in selection["candidates"]] == [x["steps"] for x in best_two]
    chosen = agent.metadata["selected_checkpoints"][0]
    assert chosen["selection_return_mean"] == max(c["selection_return_mean"] for c in selection["candidates"])
    # The shipped agent is the chosen snapshot: it replays the return that chose it.
    replay = load_agent(tmp_path, task="cartpole", seed=0)
    returns = episode_returns(replay.act, Variant("cartpole"), 2, seed=export.SELECTION_SEED)
    assert float(np.mean(returns)) == pytest.approx(chosen["selection_return_mean"], abs=0.01)
    episodes = [r for r in reports if r[0].endswith("snapshots: episodes")]
    assert episodes[-1][1:] == (4, 4)  # progress of the choice, counted in episodes


def test_export_does_not_play_a_snapshot_again_that_an_earlier_export_scored(tmp_path, monkeypatch):
    import oodmon.agents.training as training
    from dataclasses import replace

    monkeypatch.setattr(training, "recipe_for",
                        lambda task, method: replace(recipe_for(task, method), select_top=2, eval_every=500))
    first = train("cartpole", "dropconnect", tmp_path, total_steps=1000, id_episodes=1).metadata["checkpoint_selection"]
    cache_path = tmp_path / "runs" / "main" / "selection.json"
    cache = json.loads(cache_path.read_text())
    assert sorted(entry["steps"] for entry in cache.values()) == sorted(c["steps"] for c in first["candidates"])

    # Mark the candidate that lost as the best: an export that reads the cache ships it, unplayed.
    loser = min(first["candidates"], key=lambda c: c["selection_return_mean"])
    for entry in cache.values():
        if entry["steps"] == loser["steps"]:
            entry["selection_return_mean"] = 1e6
    cache_path.write_text(json.dumps(cache))
    with open(tmp_path / "train_log.jsonl", "a") as log:  # an evaluation's line cut short by a kill or a full disk
        log.write('{"run": "main", "steps": 15')
    reports: list[tuple] = []
    with pytest.warns(UserWarning, match=r"train_log.jsonl: skipped a line cut short .*'\{\"run\": \"main\", \"steps\": 15'"):
        again = train("cartpole", "dropconnect", tmp_path, total_steps=1000, id_episodes=1, export_only=True,
                      on_progress=lambda *args: reports.append(args)).metadata
    assert again["selected_checkpoints"][0]["steps"] == loser["steps"]
    assert [r[1:] for r in reports if r[0].endswith(": episodes")] == [(0, 0)]

    # Other selection settings (more episodes) do not reuse those scores.
    monkeypatch.setattr(training, "recipe_for", lambda task, method: replace(
        recipe_for(task, method).shortened(1000), select_top=2, eval_every=500, select_episodes=3))
    reports.clear()
    with pytest.warns(UserWarning, match="skipped a line cut short"):  # still there: read, never rewritten
        train("cartpole", "dropconnect", tmp_path, id_episodes=1, export_only=True,
              on_progress=lambda *args: reports.append(args))
    assert [r[1:] for r in reports if r[0].endswith(": episodes")][-1] == (6, 6)


def _interrupted_training(tmp_path, method="dropout"):
    def interrupt(run, done, total):
        if done >= 600:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train("cartpole", method, tmp_path, total_steps=1000, on_progress=interrupt, id_episodes=2)
    recipe = recipe_for("cartpole", method).shortened(1000)
    return recipe, tmp_path / "runs" / "main"


def test_a_resumed_run_has_the_weights_optimizer_counters_and_buffer_it_was_stopped_with(tmp_path):
    recipe, main = _interrupted_training(tmp_path)
    assert {p.name for p in main.iterdir()} >= {"checkpoint.pt", "replay_buffer.npz", "policy.safetensors"}
    assert not list(main.glob("*.zip")) and not list(main.glob("*.pkl"))
    # What the checkpoint at step 512 held, read without unpickling, is what a resumed model holds.
    saved = torch.load(main / "checkpoint.pt", weights_only=True)
    model = _Run(recipe, tmp_path, "main", 0).load_or_create(_training_env(recipe))
    assert model.num_timesteps == 512 and saved["counters"]["num_timesteps"] == 512
    assert model._n_updates == saved["counters"]["_n_updates"] > 0
    for name, tensor in model.policy.state_dict().items():
        torch.testing.assert_close(tensor, saved["parameters"]["policy"][name])
    steps_of_adam = [s["step"] for s in model.policy.optimizer.state_dict()["state"].values()]
    assert steps_of_adam and all(float(step) == model._n_updates for step in steps_of_adam)
    # Written as the next rollout starts, after the last one's gradient steps: every transition is in.
    buffer = model.replay_buffer
    assert buffer.pos == 512 and not buffer.full
    with np.load(main / "replay_buffer.npz", allow_pickle=False) as data:
        np.testing.assert_array_equal(buffer.observations[:512], data["observations"])
        np.testing.assert_array_equal(buffer.rewards[:512], data["rewards"])
    assert np.abs(buffer.observations[:512]).sum() > 0 and model.learning_starts < 512  # no refill needed


def test_resuming_one_checkpoint_twice_trains_the_same_weights(tmp_path):
    # Two resumes of one checkpoint agree (and with a training never stopped: test_training_resume.py).
    _interrupted_training(tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    at_checkpoint = load_file(str(tmp_path / "a" / "runs" / "main" / "policy.safetensors"))
    for folder in ("a", "b"):
        train("cartpole", "dropout", tmp_path / folder, total_steps=1000, id_episodes=2)
    first, second = (load_file(str(tmp_path / f / "runs" / "main" / "policy.safetensors")) for f in ("a", "b"))
    assert first.keys() == second.keys() == at_checkpoint.keys() and first
    for name in first:
        torch.testing.assert_close(first[name], second[name], rtol=0, atol=0)
    # and both trained on from the checkpoint (step 512 of 1000) rather than stopping there
    assert any(not torch.equal(first[name], at_checkpoint[name]) for name in first)


PICKLE_BOMB = """
import pickle, sys
class Bomb:
    def __reduce__(self):
        return (open, (sys.argv[2], "w"))
pickle.dump(Bomb(), open(sys.argv[1], "wb"))
"""


def test_a_crafted_pickle_in_the_run_folder_runs_no_code(tmp_path):
    import subprocess
    import sys
    import warnings

    recipe, main = _interrupted_training(tmp_path)
    # An older training's files: SB3's own checkpoint, and a replay buffer pickle that runs code.
    _Run(recipe, tmp_path, "main", 0).load_or_create(_training_env(recipe)).save(main / "checkpoint.zip")
    (main / "checkpoint.pt").unlink()
    (main / "replay_buffer.npz").unlink()
    marker = tmp_path / "pwned"
    subprocess.run([sys.executable, "-c", PICKLE_BOMB, str(main / "replay_buffer.pkl"), str(marker)], check=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = _Run(recipe, tmp_path, "main", 0).load_or_create(_training_env(recipe))
    assert not marker.exists()
    assert any("pickles, which oodmon does not load" in str(w.message) for w in caught)
    assert model.num_timesteps == 512  # resumed from policy.safetensors, with a fresh buffer to refill
    assert model.learning_starts == 512 + recipe.hyperparams["learning_starts"]
    # Only with the explicit flag is the pickle loaded, and then it runs (here: creates the marker).
    with pytest.raises(Exception):
        _Run(recipe, tmp_path, "main", 0).load_or_create(_training_env(recipe), load_pickles=True)
    assert marker.exists()


def test_a_recipe_of_another_task_or_method_is_refused(tmp_path):
    from dataclasses import replace

    from oodmon.errors import ConfigError

    with pytest.raises(ConfigError, match="recipe is for cartpole/dropconnect, not cartpole/dropout"):
        train("cartpole", "dropout", tmp_path, recipe=replace(recipe_for("cartpole", "dropconnect"), last_only=False))


def test_a_sampled_target_reads_the_target_network_as_the_online_one_is_trained(tmp_path, monkeypatch):
    """Recipe.target_samples = K: the TD target is the mean of K MC samples of the target network
    (SampledTargetDQN), whose parameters SB3's target updates still reach; the agent records K, and
    a run of the plain target is not resumed by it."""
    from stable_baselines3.common.utils import polyak_update

    from oodmon.agents.layers import mc_sampling
    from oodmon.agents.policies import SampledTargetDQN
    from oodmon.agents.recipes import recipe_differences

    recipe = dataclasses.replace(recipe_for("cartpole", "dropconnect"), target_samples=4).shortened(300)
    model = _new_model(recipe, _training_env(recipe), seed=0)
    assert isinstance(model, SampledTargetDQN)
    target = model.policy.q_net_target
    assert list(model.q_net_target.parameters()) == list(target.parameters())  # the same tensors, the same order
    obs = torch.tensor(np.random.default_rng(0).standard_normal((6, 4)), dtype=torch.float32)
    torch.manual_seed(1)
    with torch.no_grad():
        sampled = model.q_net_target(obs)
    torch.manual_seed(1)
    with torch.no_grad(), mc_sampling(target):
        by_hand = target.q_net(obs.expand(4, 6, 4)).mean(dim=0)  # K = 4 masks, each shared by the batch
        plain = target(obs)
    assert sampled.shape == (6, 2) and torch.equal(sampled, by_hand) and not torch.allclose(sampled, plain)
    assert not target.training and not any(m.training for m in target.modules())  # left in eval mode
    with torch.no_grad():
        model.policy.q_net.q_net[2].weight.add_(1.0)
    polyak_update(model.q_net.parameters(), model.q_net_target.parameters(), 1.0)  # what SB3's _on_step does
    assert torch.equal(target.q_net[2].weight, model.policy.q_net.q_net[2].weight)
    # trained (stopped and resumed: the resumed model samples its target too) and exported: the agent
    # records K; the plain recipe differs from it by K alone
    recipe = dataclasses.replace(recipe, select_top=0)

    def interrupt(run, done, total):
        if done >= 200:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train("cartpole", "dropconnect", tmp_path, id_episodes=1, recipe=recipe, on_progress=interrupt)
    from oodmon.agents import checkpoints

    resumed = []
    real_new_model = checkpoints.new_model
    monkeypatch.setattr(checkpoints, "new_model", lambda *args, **kwargs: resumed.append(real_new_model(*args, **kwargs))
                        or resumed[-1])
    agent = train("cartpole", "dropconnect", tmp_path, id_episodes=1, recipe=recipe)
    assert resumed and all(isinstance(m, SampledTargetDQN) and m.q_net_target.samples == 4 for m in resumed)
    assert agent.metadata["target_samples"] == 4
    plain_recipe = dataclasses.replace(recipe, target_samples=0)
    assert recipe_differences(agent.metadata, plain_recipe) == ["target_samples: 4 -> 0"]
    with pytest.raises(ConfigError, match="a run begun by another recipe|another recipe"):
        train("cartpole", "dropconnect", tmp_path, id_episodes=1, recipe=plain_recipe)
    for task, method in (("cartpole", "ensemble"), ("pendulum", "dropconnect")):  # nothing to sample; not a DQN
        bad = dataclasses.replace(recipe_for(task, method), target_samples=4)
        with pytest.raises(ConfigError, match="target_samples=4 samples a DQN's dropout or DropConnect"):
            _new_model(bad, _training_env(bad), seed=0)
    with pytest.raises(InvalidParameterError, match="target_samples=0 is not allowed"):
        SampledTargetDQN("MlpPolicy", _training_env(recipe), target_samples=0)


def test_training_refuses_an_agent_it_did_not_make_and_a_run_of_another_seed(tmp_path):
    """A folder holding a shipped (or copied) agent, or a training of another method or seed, is
    refused before any step: the export would replace the agent, or label one seed's model with
    another seed (both measured with `oodmon train --out` before)."""
    from oodmon.agents import zoo_dir

    shipped = tmp_path / "shipped"
    shutil.copytree(zoo_dir() / "cartpole-ensemble", shipped)
    before = {p: p.read_bytes() for p in shipped.rglob("*") if p.is_file()}
    with pytest.raises(ConfigError, match=r"holds a trained agent \(cartpole/ensemble, ID return 500.0\) that no "
                                          r"cartpole/ensemble training in it made"):
        train("cartpole", "ensemble", shipped, total_steps=100)
    assert {p: p.read_bytes() for p in shipped.rglob("*") if p.is_file()} == before

    train("cartpole", "dropout", tmp_path / "t", total_steps=100, id_episodes=1)
    meta = (tmp_path / "t" / "model.json").read_bytes()
    with pytest.raises(ConfigError, match="holds a training with seed 0, not 3"):
        train("cartpole", "dropout", tmp_path / "t", seed=3, total_steps=100, id_episodes=1)
    with pytest.raises(ConfigError, match="cartpole/dropout, .* that no cartpole/ensemble training in it made"):
        train("cartpole", "ensemble", tmp_path / "t", total_steps=100)
    assert (tmp_path / "t" / "model.json").read_bytes() == meta
    # The same training again: its own export, redone (the same command resumes a folder).
    assert train("cartpole", "dropout", tmp_path / "t", total_steps=100, id_episodes=1).metadata["seed"] == 0


def test_training_leaves_nothing_in_the_temp_folder(tmp_path, monkeypatch):
    """SB3's default logger made an empty tempdir/SB3-<time> folder at every ``learn()``: 5,239 of them
    over some days of suites and trainings here, beside the runs that filled the disk."""
    import tempfile

    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    train("cartpole", "dropout", tmp_path / "t", total_steps=100, id_episodes=1)  # ensembles' members: the same Run.train
    assert [p.name for p in temp.iterdir() if p.name.startswith("SB3-")] == []


def test_an_evaluations_line_after_one_cut_short_starts_a_line_of_its_own(tmp_path):
    from oodmon.agents.checkpoints import _append_line, _read_lines

    log = tmp_path / "train_log.jsonl"
    _append_line(log, {"steps": 500})
    with open(log, "a") as f:
        f.write('{"steps": 10')  # a kill mid-line
    _append_line(log, {"steps": 1000})
    assert log.read_text() == '{"steps": 500}\n{"steps": 10\n{"steps": 1000}\n'
    with pytest.warns(UserWarning, match="skipped a line cut short"):
        assert _read_lines(log) == [{"steps": 500}, {"steps": 1000}]
    assert _read_lines(tmp_path / "none.jsonl") == []
