"""A fit that explores (``fit_detectors(..., explore=P)``, ``--fit-explore``, ``--explore``,
``oodmon.watch(..., fit_explore=P)``): its episodes take a random action at a share P of their
steps, drawn the same in any process, and the detectors fitted on them read another action than
the policy's as ID where those fitted on its own actions alone read it as a shift."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import oodmon
from oodmon.agents.plain import plain_agent
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor import Monitor, MonitoredEnv, calibrate_agent
from oodmon.monitor.detectors import collect, fit_detectors
from oodmon.monitor.detectors.fitting import Explorer, fit_settings


def balance(obs) -> int:
    """A hand-written CartPole controller that keeps the pole up for the whole 500 steps."""
    x, velocity, angle, spin = obs
    return int(angle + 0.5 * spin + 0.05 * x + 0.1 * velocity > 0)


@pytest.fixture(scope="module")
def agent():
    return plain_agent(balance, "CartPole-v1")


def _differing(trajectories) -> tuple[int, int]:
    """Steps whose action is not the controller's at the observation acted on, and all steps."""
    differ = sum(int(balance(obs) != action) for t in trajectories for obs, action in zip(t.observations, t.actions))
    return differ, sum(len(t) for t in trajectories)


def test_a_fit_that_explores_takes_random_actions_at_its_share_of_steps_alike_in_any_process(agent):
    """At explore=0.2 a random one of CartPole's two actions replaces the controller's at 20% of
    the steps, so 10% of the actions differ from the controller's (half the random ones are its
    own): 3 episodes of 500 steps, 1,500 draws, 150 expected, a binomial standard deviation of 11.6;
    the test allows four either side. The draws are the episode's own: two processes play the same."""
    env = gymnasium.make("CartPole-v1")
    own = collect(agent, env, 3)
    assert _differing(own) == (0, 1500)
    explored = collect(agent, env, 3, explore=0.2)
    differ, steps = _differing(explored)
    assert abs(differ - 0.1 * steps) <= 4 * np.sqrt(steps * 0.1 * 0.9), (differ, steps)
    side_by_side = collect(agent, env, 3, explore=0.2, workers=2)
    assert all(np.array_equal(a.actions, b.actions) and np.array_equal(a.observations, b.observations)
               for a, b in zip(explored, side_by_side))
    assert not np.array_equal(collect(agent, env, 1, explore=0.2, seed=1)[0].actions[:100], explored[0].actions[:100])


def test_the_explorer_draws_among_the_actions_a_masked_policy_may_take():
    class OnlyTheLast(gymnasium.Wrapper):
        def action_masks(self):
            return np.array([False, False, True])

    env = OnlyTheLast(gymnasium.make("FrozenLake-v1").unwrapped)  # (Discrete(4) actions: a mask of its first 3)
    env.action_space = gymnasium.spaces.Discrete(3)
    explorer = Explorer(env, 0.5, masked=True)
    explorer.begin(0)
    assert {int(explorer.action(0)) for _ in range(200)} == {0, 2}
    with pytest.raises(ConfigError, match=r"a Discrete action space; this env's is Box"):
        Explorer(gymnasium.make("Pendulum-v1"), 0.1, masked=True)


def test_detectors_fitted_on_some_random_actions_read_a_policy_that_explores_as_id(agent):
    """The controller watched by its dynamics model (fitted on 15 episodes, its fit capped at 500
    Adam updates: 50 of its 100 epochs, half the time; the threshold on 20 others at 10% false
    alarms, on average over calibrations) plays 30 fresh ID episodes taking a random action at 5%
    of its steps. Fitted on its own actions, the model reads those as a shift:
    at least 24 of 30 alarmed (measured 30). Fitted with explore=0.1, it reads them as it reads the
    controller's own episodes: at most 8 of 30 each, the 10% target's binomial 99th percentile of 30
    episodes (measured 1 and 4; uncapped, 30, 1 and 2). The threshold is calibrated on the
    controller's own actions both times. (Fitted uncapped on 10 episodes, the model without
    exploring alarmed 9 of 30: one this unsure reads little as a shift.)"""
    env = gymnasium.make("CartPole-v1")
    alarmed = {}
    for explore in (0.0, 0.1):
        detectors = fit_detectors(agent, env, episodes=15, detectors=["dynamics"], explore=explore, dynamics_updates=500)
        assert detectors.fitted_for.get("explore") == (explore or None)
        threshold = calibrate_agent(agent, 20, 0.1, detectors=detectors, detector="dynamics", confidence=None)
        monitor = Monitor(agent, threshold, detectors=detectors, detector="dynamics")
        for way, share in (("own", 0.0), ("exploring", 0.05)):
            watched, rng = MonitoredEnv(gymnasium.make("CartPole-v1"), monitor.twin()), np.random.default_rng(1)
            count = 0
            for episode in range(30):
                obs, _ = watched.reset(seed=5000 + episode)
                done, alarm = False, False
                while not done:
                    action = int(rng.integers(2)) if rng.random() < share else balance(obs)
                    obs, _, terminated, truncated, info = watched.step(action)
                    done, alarm = terminated or truncated, alarm or info["oodmon"]["alarm"]
                count += alarm
            alarmed[explore, way] = count
    assert alarmed[0.0, "exploring"] >= 24, alarmed
    assert alarmed[0.1, "exploring"] <= 8 and alarmed[0.1, "own"] <= 8 and alarmed[0.0, "own"] <= 8, alarmed


def test_a_bad_share_of_random_actions_is_refused_before_any_episode(agent, monkeypatch):
    from oodmon.monitor.detectors import fitting

    monkeypatch.setattr(fitting, "collect", lambda *a, **k: pytest.fail("played the fitting's episodes"))
    env = gymnasium.make("CartPole-v1")
    for bad in (1.0, -0.1, True, "0.1", float("nan")):
        with pytest.raises(InvalidParameterError, match=rf"^explore={bad!r} is not allowed; it is the share of the "
                                                        r"fitting steps that take a random action"):
            fit_detectors(agent, env, episodes=3, explore=bad)
        with pytest.raises(InvalidParameterError, match=rf"^fit_explore={bad!r} is not allowed"):
            oodmon.watch(balance, "CartPole-v1", fit_explore=bad)
    # a fit kept by an interrupted calibration is read again only by a fit that explores alike
    settings = {explore: fit_settings(agent, None, score="chosen_std", episodes=None, dynamics_updates=None,
                                      obs_noise=0.0, max_steps=None, workers=1, explore=explore)
                for explore in (0.0, 0.1)}
    assert "explore" not in settings[0.0] and settings[0.1]["explore"] == 0.1


def test_watch_with_a_threshold_file_refuses_a_fit_that_explores(tmp_path):
    with pytest.raises(ConfigError, match=r"^fit_explore= shapes a fit of the detectors, and a threshold file's "):
        oodmon.watch(balance, "CartPole-v1", threshold=tmp_path / "thr.json", fit_explore=0.1)


def test_the_commands_that_fit_take_a_share_of_random_actions_and_say_it(tmp_path, capsys, monkeypatch):
    """``fit-detectors --explore P`` and ``calibrate --fit-explore P``: recorded in the set, said in
    the line that reports the fit, refused where nothing is played or fitted (as --dynamics-updates)."""
    from oodmon.cli import main
    from oodmon.monitor.detectors import DetectorSet

    fit = ["fit-detectors", "--task", "pendulum", "--method", "dropout", "--only", "dynamics", "--episodes", "3"]
    assert main([*fit, "--explore", "0.25", "--out", str(tmp_path / "det")]) == 0
    assert "on 3 ID episodes, a random action at 25% of their steps; wrote" in capsys.readouterr().out
    assert DetectorSet.load(tmp_path / "det").fitted_for["explore"] == 0.25
    assert main([*fit, "--explore", "1", "--out", str(tmp_path / "all")]) == 2
    assert "argument --explore: 1 is not allowed; give a number >= 0 and < 1 (the share of the fitting steps)" \
        in capsys.readouterr().err
    logs = ["fit-detectors", "--task", "pendulum", "--method", "dropout", "--from-logs", str(tmp_path / "none.mcap")]
    assert main([*logs, "--explore", "0.1", "--out", str(tmp_path / "logs")]) == 2
    assert "--explore shapes the episodes fit-detectors plays, and --from-logs fits on the logs' episodes" \
        in capsys.readouterr().err
    monkeypatch.setattr("oodmon.monitor.calibrate_agent", lambda *a, **k: pytest.fail("calibrated"))
    shipped = ["calibrate", "--task", "pendulum", "--method", "dropout", "--out", str(tmp_path / "t.json")]
    assert main([*shipped, "--fit-explore", "0.1"]) == 2
    assert "--fit-explore shapes a fit of the detectors, and calibrate fits none here: it reads the agent's shipped " \
           "ones; fit them with `oodmon fit-detectors ... --explore 0.1 --out DIR`, then calibrate with --detectors " \
           "DIR" in capsys.readouterr().err
