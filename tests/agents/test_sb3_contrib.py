"""sb3-contrib's models as your own policy: QR-DQN, TQC, TRPO, ARS and CrossQ load, act as their own
predict() does and are watched by the learned detectors (several TQCs are an ensemble, as SACs are,
and several QR-DQNs, as DQNs are); a RecurrentPPO's LSTM state is carried through each episode; a
MaskablePPO decides among the actions each step's masks allow."""

from __future__ import annotations

import json
import sys

import gymnasium
import numpy as np
import pytest
import sb3_contrib

from oodmon.agents.sb3 import load_sb3, sb3_agent, sb3_algorithm
from oodmon.cli import main
from oodmon.errors import ConfigError
from oodmon.replay import read_log
from tests.helpers import load_script, saved_ensemble_acts_as_its_members


def _model(algorithm: str, env_id: str, **extra):
    policy = "LinearPolicy" if algorithm == "ARS" else "MlpPolicy"
    if algorithm in ("QRDQN", "TQC", "CrossQ"):
        extra.setdefault("buffer_size", 1000)
    extra.setdefault("seed", 0)
    return getattr(sb3_contrib, algorithm)(policy, gymnasium.make(env_id), **extra)


@pytest.mark.parametrize("algorithm, env_id", [("QRDQN", "CartPole-v1"), ("TQC", "Pendulum-v1"), ("TRPO", "CartPole-v1"),
                                               ("ARS", "CartPole-v1"), ("CrossQ", "Pendulum-v1")])
def test_contrib_policies_load_and_act_as_their_own_predict_with_no_samples(algorithm, env_id, tmp_path):
    """Each one told from its file's data JSON (TRPO's policy module is SB3's own actor-critic, PPO's:
    told by the hyperparameters only TRPO saves), loaded by sb3-contrib, its decisions its own
    predict(deterministic=True)'s; a plain policy (no samples), named as what it is in the metadata."""
    _model(algorithm, env_id).save(tmp_path / "model.zip")
    assert sb3_algorithm(tmp_path / "model.zip") == (algorithm,)
    agent = load_sb3([tmp_path / "model.zip"], env_id)
    assert agent.estimator is None and agent.metadata["algorithm"] == algorithm.lower()
    loaded = getattr(sb3_contrib, algorithm).load(tmp_path / "model.zip", device="cpu")
    env = gymnasium.make(env_id)
    obs = env.reset(seed=0)[0]
    for _ in range(20):
        action = agent.act(obs)
        assert np.allclose(action, loaded.predict(obs, deterministic=True)[0])
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs = env.reset()[0]


def test_several_tqc_models_are_an_ensemble_of_their_deterministic_actions_as_sacs_are(tmp_path):
    """TQC's actor is SAC's (a Gaussian whose mean, squashed by a tanh, is its deterministic action):
    several TQC files are an ensemble whose samples are each model's predict(deterministic=True),
    the first acting; one TQC has no samples."""
    models = [_model("TQC", "Pendulum-v1", learning_starts=100, policy_kwargs={"net_arch": [32, 32], "n_critics": 2},
                     seed=k) for k in range(3)]
    models[0].learn(200)  # a trained actor's means reach past the tanh's linear range
    paths = saved_ensemble_acts_as_its_members(models, tmp_path, "Pendulum-v1", steps=30)
    assert load_sb3(paths[:1], "Pendulum-v1").estimator is None


def test_several_qrdqn_models_are_an_ensemble_of_their_quantiles_means(tmp_path):
    """A QR-DQN's Q-values are the means of each action's quantiles (what its predict() takes the
    argmax of): several QR-DQN files are an ensemble whose samples are each model's Q-values; the
    first model acts; one QR-DQN has no samples."""
    import torch

    models = [_model("QRDQN", "CartPole-v1", learning_starts=50, policy_kwargs={"net_arch": [32, 32], "n_quantiles": 7},
                     seed=k) for k in range(3)]
    models[0].learn(300)
    paths = [tmp_path / f"qrdqn{k}.zip" for k in range(3)]
    for model, path in zip(models, paths):
        model.save(path)
    agent = load_sb3(paths, "CartPole-v1")
    assert agent.estimator is not None and agent.estimator.n_samples == 3 and agent.estimator.kind == "q_values"
    env = gymnasium.make("CartPole-v1")
    obs, _ = env.reset(seed=0)
    for _ in range(30):
        with torch.no_grad():
            theirs = [m.policy.quantile_net(torch.as_tensor(obs[None])).mean(dim=1)[0].numpy() for m in models]
        np.testing.assert_allclose(agent.estimate(obs).samples[:, 0], theirs, rtol=1e-5, atol=1e-6)
        assert agent.act(obs) == int(models[0].predict(obs, deterministic=True)[0])
        obs, _, terminated, truncated, _ = env.step(agent.act(obs))
        if terminated or truncated:
            obs, _ = env.reset()
    assert load_sb3(paths[:1], "CartPole-v1").estimator is None


def _recurrent(env_id: str):
    return sb3_contrib.RecurrentPPO("MlpLstmPolicy", gymnasium.make(env_id), seed=0, n_steps=64, batch_size=64,
                                    policy_kwargs={"lstm_hidden_size": 16, "net_arch": [16]})


def _recurrent_reference(model, episodes: int, *, forget: bool) -> np.ndarray:
    """The model's actions over ``episodes`` 30-step Pendulum episodes as sb3-contrib deploys it: its
    LSTM's state carried from step to step and, with ``forget``, started anew with each episode."""
    env = gymnasium.make("Pendulum-v1", max_episode_steps=30)
    actions, state, starts = [], None, np.ones(1, dtype=bool)
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        if forget:
            state, starts = None, np.ones(1, dtype=bool)
        done = False
        while not done:
            action, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
            starts = np.zeros(1, dtype=bool)
            actions.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    return np.array(actions)


def test_a_recurrent_ppo_decides_with_its_lstm_state_carried_through_each_episode_and_forgotten_at_the_next(tmp_path):
    """The agent's decisions are sb3-contrib's own deployment's, float for float: the LSTM's state
    carried from step to step, started anew at each episode, whether the env is one `Agent.wrap`
    made (told of each reset) or one the monitor steps unwrapped (told at each episode's start).
    Carrying the state into the next episode decides otherwise (checked: the test can tell)."""
    from oodmon.monitor import MemorySink, Monitor
    from oodmon.monitor.detectors import DynamicsDetector, collect

    model = _recurrent("Pendulum-v1")
    model.save(tmp_path / "lstm.zip")
    agent = load_sb3([tmp_path / "lstm.zip"], "Pendulum-v1")
    assert agent.estimator is None and agent.remembers and agent.metadata["algorithm"] == "recurrentppo"
    expected = _recurrent_reference(model, 2, forget=True)
    assert not np.array_equal(expected, _recurrent_reference(model, 2, forget=False))
    env = agent.wrap(gymnasium.make("Pendulum-v1", max_episode_steps=30))
    actions = []
    for episode in range(2):
        obs, _ = env.reset(seed=episode)
        done = False
        while not done:
            actions.append(agent.act(obs))
            obs, _, terminated, truncated, _ = env.step(actions[-1])
            done = terminated or truncated
    assert np.array_equal(np.array(actions), expected)
    agent.act(obs)  # a step more: the state the monitor's next episode must forget
    dynamics = DynamicsDetector(None, epochs=2, seed=0).fit(collect(agent, gymnasium.make("Pendulum-v1"), 1, seed=0))
    sink = MemorySink()
    with Monitor(agent, detectors=[dynamics], sinks=[sink]) as monitor:
        for episode in range(2):
            monitor.run_episode(gymnasium.make("Pendulum-v1", max_episode_steps=30), seed=episode)
    assert np.array_equal(np.array([step.action for step in sink.steps]), expected)


# scripts/masked_cartpole.py's env (docs/your-policy.md's MaskablePPO): three actions, masks alternating
_, _masked_cartpole = load_script("masked_cartpole")
MASKED = _masked_cartpole.ENV_ID


def test_twin_monitors_of_a_recurrent_ppo_each_carry_their_own_envs_memory(tmp_path):
    """A vector env's pattern: a monitor and its twin step two envs in turn. Each has the policy's
    memory of its own env's episode, so each env's decisions are sb3-contrib's own deployment's in
    that env alone (they shared one LSTM state before, each decision reading the other env's last)."""
    from oodmon.monitor import MemorySink, Monitor, MonitoredEnv
    from oodmon.monitor.detectors import DynamicsDetector, collect

    model = _recurrent("Pendulum-v1")
    model.save(tmp_path / "lstm.zip")
    agent = load_sb3([tmp_path / "lstm.zip"], "Pendulum-v1")
    dynamics = DynamicsDetector(None, epochs=2, seed=0).fit(collect(agent, gymnasium.make("Pendulum-v1"), 1, seed=0))
    sinks = [MemorySink(), MemorySink()]
    first = Monitor(agent, detectors=[dynamics], sinks=[sinks[0]])
    envs = [MonitoredEnv(gymnasium.make("Pendulum-v1", max_episode_steps=30), monitor)
            for monitor in (first, first.twin(sinks=[sinks[1]]))]
    for seed, env in enumerate(envs):
        env.reset(seed=seed)
    for _ in range(30):
        for env in envs:
            env.step()
    expected = _recurrent_reference(model, 2, forget=True)  # seed 0's episode, then seed 1's
    for sink, own in zip(sinks, (expected[:30], expected[30:])):
        assert np.array_equal(np.array([step.action for step in sink.steps]), own)


def masks_allow(actions) -> bool:
    """Whether an episode's actions are those the masked CartPole allows, step by step (0 or 2 at even
    steps, 1 or 2 at odd ones)."""
    return all(int(action) != (1 if t % 2 == 0 else 0) for t, action in enumerate(actions))


def test_a_maskable_ppo_decides_among_the_actions_each_steps_masks_allow(tmp_path):
    """Its decisions are its predict() with the masks of the step it acts at, which the envs
    `Agent.wrap` makes, and the monitor of any env it steps, read from the env's action_masks() after
    each reset and step; unmasked, it would take actions the env forbids (checked: the test can
    tell). A decision without new masks, or in an env with no action_masks(), is an error, never a
    decision on stale or no masks."""
    from oodmon.monitor import MemorySink, Monitor, MonitoredEnv
    from oodmon.monitor.detectors import DynamicsDetector, collect

    env_id = MASKED
    model = sb3_contrib.MaskablePPO("MlpPolicy", gymnasium.make(env_id), seed=0, n_steps=64, batch_size=64)
    model.save(tmp_path / "masked.zip")
    agent = load_sb3([tmp_path / "masked.zip"], env_id)
    assert agent.reads_masks and agent.metadata["algorithm"] == "maskableppo"
    env = agent.wrap(gymnasium.make(env_id))
    obs, _ = env.reset(seed=0)
    forbidden_unmasked, done = 0, False
    while not done:
        masks = env.get_wrapper_attr("action_masks")()
        action = agent.act(obs)
        assert masks[action] and action == int(model.predict(obs, action_masks=masks, deterministic=True)[0])
        forbidden_unmasked += not masks[int(model.predict(obs, deterministic=True)[0])]
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
    assert forbidden_unmasked > 0
    agent.act(obs)  # the masks the last step gave
    with pytest.raises(ConfigError, match="none were given for this step"):
        agent.act(obs)  # they served the decision above
    with pytest.raises(ConfigError, match="this env has no action_masks"):
        agent.wrap(gymnasium.make("CartPole-v1")).reset(seed=0)
    played = collect(agent, gymnasium.make(env_id), 2, seed=0)  # an env of yours: told the masks as the monitor tells them
    assert all(masks_allow(t.actions) for t in played)
    # a fit that explores takes random actions among those the masks allow, too (fit_explore)
    explored = collect(agent, gymnasium.make(env_id), 2, seed=0, explore=0.5)
    assert all(masks_allow(t.actions) for t in explored)
    assert not np.array_equal(explored[0].actions[:20], played[0].actions[:20])
    dynamics = DynamicsDetector(3, epochs=2, seed=0).fit(played)
    sink = MemorySink()  # the monitor gives the masks of the env it steps, wrapped or not
    with Monitor(agent, detectors=[dynamics], sinks=[sink]) as monitor:
        monitor.run_episode(agent.wrap(gymnasium.make(env_id)), seed=1)
        monitor.run_episode(gymnasium.make(env_id), seed=2)
        env = MonitoredEnv(gymnasium.make(env_id), monitor)
        env.reset(seed=3)
        done = False
        while not done:
            done = any(env.step()[2:4])
    assert len(sink.episodes) == 3
    assert all(masks_allow([step.action for step in sink.steps if step.episode == e]) for e in range(3))


def test_envs_show_plays_a_policy_that_reads_its_env_in_one_env_at_a_time(tmp_path):
    """`oodmon envs show ENV:NAME=VALUE --sb3` plays the env's own episode and the shifted one with the
    policy: one after the other, so a MaskablePPO reads each env's own masks (played interleaved, it
    decided in one env with the other's masks, and the episodes parted from step 1, long before the
    onset)."""
    from oodmon.envs import parse_env_shift
    from oodmon.envs.probe import probe_shift

    env_id = MASKED
    sb3_contrib.MaskablePPO("MlpPolicy", gymnasium.make(env_id), seed=0, n_steps=64, batch_size=64).save(
        tmp_path / "masked.zip")
    agent = load_sb3([tmp_path / "masked.zip"], env_id)
    probe = probe_shift(parse_env_shift(f"{env_id}:length=5.0"), onset=5, steps=40, policy=agent.act, wrap=agent.wrap)
    assert probe.changed and probe.first_difference == 6  # the first observation after the onset's step


def test_several_contrib_models_but_tqcs_and_qrdqns_are_no_ensemble(tmp_path):
    models = [_model("TRPO", "CartPole-v1"), _model("TRPO", "CartPole-v1")]
    with pytest.raises(ConfigError, match="several models form an ensemble.*got TRPO, TRPO"):
        sb3_agent(models, "CartPole-v1")


@pytest.mark.parametrize("algorithm", ["TQC", "RecurrentPPO"])
def test_a_contrib_policy_is_calibrated_and_alarms_when_gravity_grows(algorithm, tmp_path, capsys):
    """The command-line path of docs/your-policy.md: `calibrate --sb3` fits the learned detectors for a TQC
    (a little trained) or a RecurrentPPO (untrained; its LSTM's state carried through each episode of
    the fitting, the calibration and the run): neither barely swings the pendulum, whose fall under gravity the dynamics model
    reads whatever the policy's skill; a heavier pole it would not see, its torques being small), and
    `run` with gravity five times Pendulum's from step 50 holds the alarm in both episodes within a
    few steps of the onset. (Whether an episode also alarmed before it is chance: a threshold of 10
    episodes at far 0.1 lets about one fresh episode in ten alarm, and the TQC's second did at step
    20 with the dynamics model of fitting version 8; the false-alarm rate is tested elsewhere.)"""
    if algorithm == "TQC":
        model = _model("TQC", "Pendulum-v1", learning_starts=100, policy_kwargs={"net_arch": [32, 32], "n_critics": 2})
        model.learn(300)
    else:
        model = _recurrent("Pendulum-v1")
    model.save(tmp_path / "tqc.zip")
    common = ["--sb3", str(tmp_path / "tqc.zip"), "--env", "Pendulum-v1"]
    assert main(["calibrate", *common, "--episodes", "10", "--far", "0.1", "--confidence", "none",
                 "--warmup", "20", "--fit-episodes", "9", "--out", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["detector"] == "dynamics"
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--variant", "pendulum:g=50.0",
                 "--onset", "50", "--episodes", "2", "--mcap", str(tmp_path / "x.mcap")]) == 0
    episodes = read_log(tmp_path / "x.mcap").episodes
    assert len(episodes) == 2 and all(episode.alarm[50:55].any() for episode in episodes)


def test_without_sb3_contrib_its_models_are_refused_naming_what_to_install(tmp_path, monkeypatch):
    _model("TQC", "Pendulum-v1").save(tmp_path / "tqc.zip")
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)  # as where it is not installed: its import fails
    with pytest.raises(ConfigError, match=r"a TQC model is loaded by sb3-contrib, which is not installed: pip install "
                                          r"sb3-contrib \(or 'oodmon\[contrib\]'\)"):
        load_sb3([tmp_path / "tqc.zip"], "Pendulum-v1")


def test_the_docs_contrib_example_trains_each_model_once_and_refuses_an_unknown_case(tmp_path, monkeypatch, capsys):
    """scripts/sb3_contrib_example.py: an unknown case is refused naming the cases; a model already in
    --out is kept (what the page's figures came from is not trained over)."""
    _, example = load_script("sb3_contrib_example")
    monkeypatch.setattr(sys, "argv", ["sb3_contrib_example.py", "--only", "qrdqn,sonar", "--out", str(tmp_path)])
    with pytest.raises(SystemExit) as stopped:
        example.main()
    assert stopped.value.code == 2 and "unknown case(s) sonar; choose from qrdqn, qrdqn3, tqc, rppo, maskable" in \
        capsys.readouterr().err
    (tmp_path / "tqc.zip").write_bytes(b"kept")
    assert example.train("tqc", tmp_path) == tmp_path / "tqc.zip" and (tmp_path / "tqc.zip").read_bytes() == b"kept"
