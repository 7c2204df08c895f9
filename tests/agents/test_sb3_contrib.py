"""sb3-contrib's models as your own policy: QR-DQN, TQC, TRPO, ARS and CrossQ load, act as their own
predict() does and are watched by the learned detectors (several TQCs are an ensemble, as SACs are);
RecurrentPPO and MaskablePPO are refused with why, before anything is unpickled."""

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
from tests.helpers import saved_ensemble_acts_as_its_members


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


def test_recurrent_and_maskable_ppo_are_refused_with_why_and_several_contrib_models_are_no_ensemble(tmp_path):
    sb3_contrib.RecurrentPPO("MlpLstmPolicy", gymnasium.make("CartPole-v1"), seed=0).save(tmp_path / "lstm.zip")
    with pytest.raises(ConfigError, match="RecurrentPPO decides from its LSTM's state as well as the observation"):
        load_sb3([tmp_path / "lstm.zip"], "CartPole-v1")
    sb3_contrib.MaskablePPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0).save(tmp_path / "masked.zip")
    with pytest.raises(ConfigError, match="MaskablePPO decides among the actions the env's action masks allow"):
        load_sb3([tmp_path / "masked.zip"], "CartPole-v1")
    models = [_model("QRDQN", "CartPole-v1"), _model("QRDQN", "CartPole-v1")]
    with pytest.raises(ConfigError, match="several models form an ensemble.*got QRDQN, QRDQN"):
        sb3_agent(models, "CartPole-v1")


def test_a_tqc_is_calibrated_and_alarms_when_gravity_grows(tmp_path, capsys):
    """The command-line path of the README: `calibrate --sb3` fits the learned detectors for a TQC
    (a little trained: it barely swings the pendulum, whose fall under gravity the dynamics model
    reads whatever the policy's skill; a heavier pole it would not see, its torques being small), and
    `run` with gravity five times Pendulum's from step 50 alarms in both episodes, after the onset."""
    model = _model("TQC", "Pendulum-v1", learning_starts=100, policy_kwargs={"net_arch": [32, 32], "n_critics": 2})
    model.learn(300)
    model.save(tmp_path / "tqc.zip")
    common = ["--sb3", str(tmp_path / "tqc.zip"), "--env", "Pendulum-v1"]
    assert main(["calibrate", *common, "--episodes", "10", "--far", "0.1", "--confidence", "none",
                 "--warmup", "20", "--fit-episodes", "9", "--out", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["detector"] == "dynamics"
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--variant", "pendulum:g=50.0",
                 "--onset", "50", "--episodes", "2", "--mcap", str(tmp_path / "x.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "x.mcap"), "--episodes", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 2 and all(row["first_alarm_step"] is not None and row["first_alarm_step"] >= 50 for row in rows)


def test_without_sb3_contrib_its_models_are_refused_naming_what_to_install(tmp_path, monkeypatch):
    _model("TQC", "Pendulum-v1").save(tmp_path / "tqc.zip")
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)  # as where it is not installed: its import fails
    with pytest.raises(ConfigError, match=r"a TQC model is loaded by sb3-contrib, which is not installed: pip install "
                                          r"sb3-contrib \(or 'oodmon\[contrib\]'\)"):
        load_sb3([tmp_path / "tqc.zip"], "Pendulum-v1")
