"""The monitor with a shipped agent: records equal the estimator's numbers; alarms, callbacks,
the wrapper, and the false-alarm guarantee on fresh ID episodes."""

from __future__ import annotations

import re
import warnings
from dataclasses import replace

import gymnasium
import numpy as np
import pytest

from oodmon.agents import load
from oodmon.envs import Variant, parse_variant
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor import (
    MemorySink, Monitor, MonitoredEnv, Threshold, calibrate_agent, episode_statistic, id_episode_scores,
)
from oodmon.monitor.detectors import CombinedDetector, SpreadDetector
from oodmon.monitor.scores import score_function


@pytest.fixture(scope="module")
def agent():
    return load("cartpole", "ensemble")


def test_records_equal_what_the_estimator_computes(agent):
    sink = MemorySink()
    env = parse_variant("cartpole:length=2.0").make(onset_step=20)
    with Monitor(agent, threshold=4.0, sinks=[sink]) as monitor:
        record = monitor.run_episode(env, seed=5, variant="cartpole:length=2.0")
    # Replay the same episode with the estimator alone.
    obs, info = env.reset(seed=5)
    for step in sink.steps:
        estimate = agent.estimate(obs)
        assert step.action == int(estimate.action[0])
        np.testing.assert_allclose(step.mean, estimate.mean[0], rtol=1e-6)
        np.testing.assert_allclose(step.std, estimate.std[0], rtol=1e-6)
        assert step.score == pytest.approx(float(estimate.std[0][step.action]), rel=1e-6)
        assert step.shifted == info["shifted"] and step.observation == pytest.approx(obs.tolist())
        obs, _, terminated, truncated, info = env.step(step.action)
    assert terminated or truncated
    assert [s.step for s in sink.steps] == list(range(record.length))
    assert [s.shifted for s in sink.steps] == [t > 20 for t in range(record.length)]  # obs k comes from step k-1
    assert record.total_return == record.length and sink.episodes == [record]
    assert sink.closed and sink.run.task == "cartpole" and sink.run.policy_hash.startswith("sha256:")


def test_a_spread_detector_given_keeps_its_score_unless_the_monitor_is_asked_for_another(agent):
    # Monitor(detectors=[SpreadDetector("margin_std")]) scored chosen_std, the default, without a word.
    given = [SpreadDetector("margin_std")]
    sink = MemorySink()
    with Monitor(agent, detectors=given, sinks=[sink]) as monitor:
        monitor.run_episode(parse_variant("cartpole").make(), seed=3, max_steps=30)
    assert monitor.score_name == "margin_std" and sink.run.score == "margin_std"
    obs, _ = gymnasium.make("oodmon/CartPole-v1").reset(seed=3)
    assert sink.steps[0].score == pytest.approx(float(score_function("margin_std")(agent.estimate(obs))[0]), rel=1e-6)
    assert sink.steps[0].score != pytest.approx(sink.steps[0].std[sink.steps[0].action])  # not chosen_std
    asked = Monitor(agent, score="chosen_std", detectors=given)  # a score asked for is the one scored
    assert asked.score_name == "chosen_std" and asked.detectors["spread"].score_name == "chosen_std"
    assert Monitor(agent).score_name == "chosen_std"  # and with no spread given, the default


def test_alarms_reach_callbacks_and_do_not_stop_the_policy_unless_asked(agent):
    sink = MemorySink()
    seen = []
    env = Variant("cartpole").make()
    with Monitor(agent, threshold=0.0, consecutive=2, sinks=[sink], callbacks=[seen.append]) as monitor:
        record = monitor.run_episode(env, seed=0)
    assert record.length == 500 and record.alarms == 1 and record.first_alarm_step == 1  # one long excursion
    assert seen == sink.alarms and seen[0].step == 1
    with Monitor(agent, threshold=0.0, consecutive=2, callbacks=[lambda event: True]) as monitor:
        stopped = monitor.run_episode(env, seed=0)
    assert stopped.length == 2  # the callback asked to stop at the alarm


def test_an_alarm_says_what_raised_its_score(agent):
    """``AlarmEvent.cause``: the alarm's detector; for ``combined`` the member ranked highest at the
    step the rule fired; a reading that is not finite. The log's and the command line's alarm text
    carry it (``AlarmEvent.text``)."""
    from oodmon.monitor.alarms import AlarmTracker
    from oodmon.monitor.detectors import DetectorSet
    from oodmon.monitor.detectors.base import Detector

    class Stuck(Detector):  # a member whose score jumps at step 3
        name, learned = "stuck", False

        def __init__(self) -> None:
            self.steps = 0

        def reset(self) -> None:
            self.steps = 0

        def score(self, context) -> float:
            self.steps += 1
            return 50.0 if self.steps > 3 else 0.0

    combined = CombinedDetector(["spread", "stuck"]).fit_reference({"spread": np.linspace(0, 1e3, 50),
                                                                     "stuck": np.zeros(50)})
    detectors = DetectorSet([SpreadDetector(), Stuck(), combined])
    sink = MemorySink()
    with Monitor(agent, threshold=5.0, detectors=detectors, detector="combined", sinks=[sink]) as monitor:
        monitor.run_episode(Variant("cartpole").make(), seed=0, max_steps=10)
    assert [(a.step, a.cause) for a in sink.alarms] == [(3, "stuck")]
    assert sink.alarms[0].text().endswith("; cause: stuck")
    with Monitor(agent, threshold=0.0, consecutive=2, sinks=[sink]) as monitor:  # the spread alone
        monitor.run_episode(Variant("cartpole").make(), seed=0, max_steps=5)
    assert sink.alarms[-1].cause == "spread"
    with Monitor(agent, threshold=5.0, detectors=detectors, detector="combined", sinks=[sink]) as monitor:
        monitor.begin_episode(seed=0)
        monitor.step(np.full(4, np.nan, np.float32), action=0)
    assert sink.alarms[-1].cause == "a reading that is not finite"
    assert AlarmTracker(1.0, consecutive=1).update(0, 0, 2.0)[1].cause == ""  # a tracker on its own does not know
    # A deployed env's info["oodmon"] says it at every step the alarm holds, and nothing before.
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"),
                       Monitor(agent, threshold=5.0, detectors=detectors, detector="combined"))
    env.reset(seed=0)
    telemetry = [env.step()[-1]["oodmon"] for _ in range(6)]
    env.close()
    assert [t["alarm"] for t in telemetry] == [False] * 3 + [True] * 3
    assert [t.get("cause") for t in telemetry] == [None] * 3 + ["stuck"] * 3


def test_monitored_env_wrapper_lets_the_policy_act_or_takes_yours(agent):
    sink = MemorySink()
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), Monitor(agent, sinks=[sink]))
    env.reset(seed=1)
    for _ in range(10):
        env.step()
    obs, *_ = env.step(0)  # the user's action; the monitor still logs the policy's
    env.close()
    assert len(sink.steps) == 11 and sink.episodes[0].length == 11 and sink.closed
    assert np.isnan(sink.steps[0].threshold) and not any(s.alarm for s in sink.steps)


def test_a_deployed_envs_info_says_what_a_windowed_rule_compares_and_nothing_more_under_each_score(agent):
    """Under a rule with a window the alarm compares the mean of the last scores with the threshold,
    which ``info["oodmon"]["score"]`` is not: ``compared`` holds it (NaN until the window fills);
    a rule that compares each score adds nothing (the sequential rules' statistic: test_sinks)."""
    sink = MemorySink()
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), Monitor(agent, threshold=1e9, window=3, sinks=[sink]))
    env.reset(seed=1)
    compared = [env.step()[-1]["oodmon"]["compared"] for _ in range(6)]
    env.close()
    scores = [s.score for s in sink.steps]
    np.testing.assert_allclose(compared, [np.nan, np.nan, *[np.mean(scores[k - 2:k + 1]) for k in range(2, 6)]])
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), Monitor(agent, threshold=1e9))
    env.reset(seed=1)
    assert "compared" not in env.step()[-1]["oodmon"]
    env.close()


def test_an_episode_begun_before_the_last_one_ended_ends_it_and_is_logged(agent, tmp_path):
    # A loop of your own that never called end_episode: each begin_episode dropped the running
    # episode's record, and the log held 10 steps under no episode (replay: none) (2026-12-01)
    from oodmon.monitor import McapSink
    from oodmon.replay import read_log

    sink, log = MemorySink(), tmp_path / "loop.mcap"
    env = Variant("cartpole").make()
    with Monitor(agent, sinks=[sink, McapSink(log)]) as monitor:
        for seed in range(2):
            obs, _ = env.reset(seed=seed)
            monitor.begin_episode(env_id="oodmon/CartPole-v1", variant="cartpole", seed=seed)
            for _ in range(5):
                obs, *_ = env.step(monitor.step(obs))
        monitor.begin_episode(env_id="oodmon/CartPole-v1", variant="cartpole", seed=9)  # no step: forgotten
    assert [(e.episode, e.seed, e.length, e.interrupted) for e in sink.episodes] == [(0, 0, 5, False), (1, 1, 5, False)]
    assert [(e.seed, e.length) for e in read_log(log).episodes] == [(0, 5), (1, 5)]


@pytest.mark.parametrize("noise", [-0.1, float("nan"), "0.01", True])
def test_a_loop_of_your_own_gives_its_sensor_noise_as_a_number_at_least_zero(agent, noise):
    monitor = Monitor(agent)
    with pytest.raises(InvalidParameterError, match=r"obs_noise=.* is not allowed; it is the env's sensor noise"):
        monitor.begin_episode(variant="cartpole", obs_noise=noise)
    monitor.begin_episode(variant="cartpole", obs_noise=0.02)
    monitor.step(np.zeros(4, np.float32))
    assert monitor.end_episode().obs_noise == 0.02
    monitor.close()


def test_an_episode_in_another_sensor_noise_than_the_thresholds_is_warned_of_once_a_noise(agent):
    # A noiseless threshold alarmed in 100 of 100 fresh ID episodes at noise 0.01 (2026-12-05), and
    # in Python nothing said so: only the CLI's run and replay did.
    from oodmon.monitor import OffCalibrationNoiseWarning

    noisy = Threshold(6.0, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", method="ensemble",
                      obs_noise=0.01)
    old = Threshold(6.0, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", method="ensemble")
    played = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with Monitor(agent, noisy) as monitor:
            for noise in (0.01, 0.0, 0.0, 0.02, 0.01, 0.02):
                monitor.run_episode(gymnasium.make("oodmon/CartPole-v1", obs_noise=noise), seed=1, max_steps=3)
                played.append(monitor.last_step is not None)
        with Monitor(agent, old) as monitor:  # no noise recorded: calibrated without (0), as `oodmon run` reads it
            monitor.run_episode(gymnasium.make("oodmon/CartPole-v1"), seed=1, max_steps=3)
            monitor.run_episode(gymnasium.make("oodmon/CartPole-v1", obs_noise=0.05), seed=1, max_steps=3)
        with Monitor(agent, 6.0) as monitor:  # a bare number is no calibration: nothing to compare
            monitor.run_episode(gymnasium.make("oodmon/CartPole-v1", obs_noise=0.05), seed=1, max_steps=3)
    said = [str(w.message) for w in caught if issubclass(w.category, OffCalibrationNoiseWarning)]
    assert all(played) and len(said) == 3, said  # 0 and 0.02 under the noisy threshold, 0.05 under the old one
    assert said[0].startswith("this episode plays sensor noise obs_noise=0, and the threshold was calibrated with 0.01")
    assert "obs_noise=0.02," in said[1] and "`oodmon calibrate --obs-noise 0.02`" in said[1]
    assert "obs_noise=0.05, and the threshold was calibrated with 0:" in said[2]
    with pytest.warns(OffCalibrationNoiseWarning) as direct, Monitor(agent, noisy) as monitor:  # a loop of your own
        monitor.begin_episode(variant="cartpole", obs_noise=0.03)
    assert direct[0].filename == __file__  # the line that began the episode


def test_an_episode_past_the_longest_calibration_episode_is_warned_of_once(agent):
    # A run longer than the calibration's episodes is not what the bound speaks of: the docs' own
    # CartPole controller, calibrated on 500 steps, alarmed in 9.2% of 500-step stretches of runs of
    # 5,000 (2026-12-05).
    from oodmon.monitor import LongerThanCalibrationWarning

    def threshold(**fields):
        return Threshold(1e9, "chosen_std", 1, "episode", 0.05, 20, 10_000, task="cartpole", method="ensemble",
                         **fields)

    def warned(threshold, steps: int, episodes: int = 2) -> list[str]:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with Monitor(agent, threshold) as monitor:
                for seed in range(episodes):
                    monitor.run_episode(gymnasium.make("oodmon/CartPole-v1", max_episode_steps=steps), seed=seed)
        return [str(w.message) for w in caught if issubclass(w.category, LongerThanCalibrationWarning)]

    said = warned(threshold(longest_episode=500), 520)
    assert said == ["episode 0 has run past 500 steps, the longest of the threshold's calibration episodes: its "
                    "false-alarm bound is for episodes like those (`oodmon validate THRESHOLD --max-steps N` counts its "
                    "false alarms in runs N steps long, `oodmon calibrate --max-steps N` calibrates on them)"]  # once
    assert warned(threshold(longest_episode=500), 500) == []  # as long as the longest: no word
    assert warned(threshold(), 520) == []  # a file that records none (written before 2026-12-05)
    assert warned(replace(threshold(longest_episode=500), mode="step"), 520) == []  # a bound on steps, not episodes
    assert warned(1e9, 520) == []  # a bare number: no calibration
    assert calibrate_agent(agent, 11, 0.2, detector="spread", confidence=None, max_steps=40).longest_episode == 40


def test_a_monitored_env_stepped_with_no_episode_running_says_to_reset_it(agent):
    # before its first reset, after its episode ended, after close: it said "Monitor.step before
    # begin_episode", a method an env's user never calls (2026-12-01)
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1", length=0.05), Monitor(agent))  # falls at once
    said = r"step\(\) with no episode running: reset\(\) the env first"
    with pytest.raises(ConfigError, match=said):
        env.step()
    env.reset(seed=0)
    ended = False
    while not ended:
        _, _, terminated, truncated, _ = env.step()
        ended = terminated or truncated
    with pytest.raises(ConfigError, match=said):
        env.step()
    env.reset(seed=1)
    env.step(0)
    env.close()
    with pytest.raises(ConfigError, match=said):
        env.step()


@pytest.mark.parametrize("arguments, words", [
    ({"threshold": float("nan")}, "threshold=nan is not allowed; give a number"),  # a NaN threshold never alarms
    ({"threshold": "abc"}, "threshold='abc' is not allowed"),
    ({"sinks": MemorySink()}, r"sinks is a list: sinks=\[MemorySink\(...\)\]"),
    ({"callbacks": print}, r"callbacks is a list: callbacks=\[print\], not one on its own"),
    # (2026-12-05: these failed at the first alarm, or as a warning at every step, mid-run)
    ({"callbacks": "print"}, r"callbacks='print': give a list of functions"),
    ({"callbacks": [print, 1]}, r"callbacks=\[<built-in function print>, 1\]: give a list of functions"),
    ({"sinks": ["runs/x.mcap"]}, r"sinks holds 'runs/x.mcap', which is no sink \(it lacks open, write_step"),
    ({"detectors": "dynamics"}, r"detectors='dynamics' is not allowed; give fitted detectors .* detector='dynamics'"),
    ({"detectors": ["dynamics"]}, r"detectors=\['dynamics'\] is not allowed"),
])
def test_a_monitor_given_what_it_cannot_use_says_so_in_one_error(agent, arguments, words):
    """Found by calling the public API with odd arguments (2026-11-27): a NaN threshold was taken and
    silenced every alarm; a sink on its own, a callback on its own or a detector's name raised
    Python's TypeError or AttributeError from deep inside."""
    with pytest.raises(ConfigError, match=words):
        Monitor(agent, **arguments)


def test_api_values_that_were_taken_silently_are_refused():
    from oodmon.errors import InvalidParameterError
    from oodmon.monitor import McapSink

    with pytest.raises(InvalidParameterError, match="compression='rar' is not allowed"):  # was written uncompressed
        McapSink("x.mcap", compression="rar")
    with pytest.raises(InvalidParameterError, match="n_samples=0 is not allowed"):  # was the recipe's 20
        load("cartpole", "dropout", n_samples=0)
    assert load("cartpole", "ensemble", n_samples=0).estimator.n_samples == 5  # ensembles ignore it, as documented


def test_seeds_and_counts_of_odd_kinds_are_refused_or_taken_as_python_ints(agent):
    """Found by calling the public API with odd arguments (2026-12-05): a negative or float seed of
    the ID episodes reached gymnasium's reset (its own error, after the reference episodes of a
    sequential rule had run), and numpy's integers, which every other count takes, were refused
    there (the detectors' fitting too); a count of numpy's was saved into a detector's JSON config,
    which then failed to write."""
    import json

    import oodmon
    from oodmon.monitor import calibrate, validate_threshold
    from oodmon.monitor.detectors.dynamics import DynamicsDetector

    for seed in (-1, 2.5, float("nan"), "7", 2**32, 10**30):  # (the largest: the CLI's --seed, numpy's legacy seeding)
        with pytest.raises(InvalidParameterError, match=f"seed={seed!r} is not allowed; give a whole number from 0 to "
                                                        "4294967295"):
            calibrate_agent(agent, 50, seed=seed)
        with pytest.raises(InvalidParameterError, match="seed="):
            id_episode_scores(agent, 1, seed=seed)
    threshold = calibrate([np.zeros(5)] * 45, 0.05, consecutive=3, task="cartpole", method="ensemble")
    with pytest.raises(InvalidParameterError, match="seed=-1 is not allowed"):
        validate_threshold(agent, threshold, 1, seed=-1)
    with pytest.raises(InvalidParameterError, match="threshold=4.0 is not allowed; give a Threshold"):
        validate_threshold(agent, 4.0, 1)
    # numpy's integers play the episodes Python's do
    assert [s.tolist() for s in id_episode_scores(agent, 2, seed=np.int64(700_000))] == [
        s.tolist() for s in id_episode_scores(agent, 2, seed=700_000)]
    with pytest.raises(InvalidParameterError, match="episodes=nan is not allowed"):
        oodmon.watch(agent, episodes=float("nan"))
    from oodmon.monitor.detectors.fitting import fit_agent_detectors

    for seed in (-1, 10**30):  # (10**30 failed in torch's generator, after the episodes were played)
        with pytest.raises(InvalidParameterError, match=f"seed={seed} is not allowed"):
            fit_agent_detectors(agent, detectors=["dynamics"], episodes=3, seed=seed)
    fitted = fit_agent_detectors(agent, detectors=["dynamics"], episodes=3, seed=np.int64(600_000), max_steps=20)
    assert type(fitted.fitted_for["seed"]) is int and json.dumps(fitted.fitted_for)
    config = DynamicsDetector(2, max_updates=np.int64(300)).config()
    assert config["max_updates"] == 300 and type(config["max_updates"]) is int and json.dumps(config)


def test_step_before_begin_episode_is_an_error(agent):
    with pytest.raises(ConfigError, match="Monitor.step before begin_episode"):
        Monitor(agent).step(np.zeros(4, np.float32))


def test_calibrated_threshold_keeps_its_false_alarm_rate_on_fresh_id_episodes():
    # 19 calibration episodes at far = 0.2 (rank ceil(20 * 0.8) = 16), then 60 fresh ID episodes.
    # Seeded MC sampling: the same numbers every run (unseeded, this test failed now and then).
    agent = load("cartpole", "dropout", seed=0)
    threshold = calibrate_agent(agent, 19, far=0.2, consecutive=3, confidence=None)
    fresh = id_episode_scores(agent, 60, seed=500_000)
    rate = np.mean([episode_statistic(s, 3) > threshold.value for s in fresh])
    # The guarantee is over calibrations: given one, the false-alarm rate is Beta(4, 16) (mean 0.2,
    # std 0.087), and 60 episodes add binomial noise (std 0.052): 0.2 + 2.6 * 0.101 is above the
    # rate of all but about 1% of (calibration, fresh episodes) draws.
    assert rate <= 0.2 + 2.6 * 0.101
    assert threshold.n_episodes == 19 and threshold.n_steps == 19 * 500
    # It holds for the K samples per decision it was calibrated with: the spread's scale is K's. The
    # same policy drawing another K is refused (a CartPole DropConnect spread threshold of K=20,
    # 0 of 100 fresh ID episodes alarmed, read 6 of 100 with K=5), or with force warned.
    assert threshold.samples == agent.estimator.n_samples == 20
    Monitor(load("cartpole", "dropout", n_samples=20, seed=1), threshold)
    with pytest.raises(ConfigError, match="calibrated with 20 samples per decision, and this policy draws 5"):
        Monitor(load("cartpole", "dropout", n_samples=5, seed=1), threshold)
    with pytest.warns(UserWarning, match="draws 5"):
        Monitor(load("cartpole", "dropout", n_samples=5, seed=1), threshold, force=True)
    with pytest.raises(InvalidParameterError, match="samples=0"):
        Threshold(1.0, "chosen_std", 3, "episode", 0.05, 20, 100, samples=0)


@pytest.mark.parametrize("log_observations", [True, False], ids=["logged", "scores-only"])
def test_observations_and_frames_are_logged_only_when_asked(agent, log_observations):
    sink = MemorySink()
    obs = np.array([0.01, 0.0, 0.02, 0.0], np.float32)
    frame = np.full((84, 84), 7, np.uint8)
    with Monitor(agent, threshold=4.0, sinks=[sink], log_observations=log_observations) as monitor:
        monitor.begin_episode(variant="cartpole")
        monitor.step(obs, frame=frame)
        monitor.end_episode()
    (record,) = sink.steps
    if log_observations:
        assert record.observation == pytest.approx(obs.tolist()) and np.array_equal(record.frame, frame)
    else:  # calibration: scores only, no frames kept in memory
        assert record.observation is None and record.frame is None
    assert record.score == pytest.approx(float(agent.estimate(obs).std[0][record.action]), rel=1e-6)


def test_monitored_env_reports_every_step_in_info_and_why_an_alarm_ended_the_episode(agent):
    sink = MemorySink()
    monitor = Monitor(agent, threshold=0.0, sinks=[sink], callbacks=[lambda event: True])
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1", length=2.0), monitor, variant="cartpole:length=2.0")
    env.reset(seed=0)
    infos, truncated = [], False
    while not truncated:
        *_, terminated, truncated, info = env.step()
        infos.append(info["oodmon"])
        assert not terminated
    # Threshold 0: every score is above it, the alarm fires at step 2 (m = 3), the callback ends the episode.
    assert [i["step"] for i in infos] == [0, 1, 2] and len(sink.steps) == 3 and sink.episodes[0].length == 3
    for telemetry, record in zip(infos, sink.steps):
        assert telemetry["scores"] == record.scores and telemetry["score"] == record.score
        assert telemetry["alarm"] == record.alarm and telemetry["threshold"] == 0.0 and telemetry["detector"] == "spread"
    assert "ended_by_alarm" in infos[-1] and f"step {infos[-1]['step']}" in infos[-1]["ended_by_alarm"]
    # the alarm log's line for the alarm, its cause at the end
    assert infos[-1]["ended_by_alarm"].endswith("(score > threshold for 3 consecutive steps); cause: spread")
    assert all("ended_by_alarm" not in i for i in infos[:-1])
    env.close()


def test_a_reset_no_step_follows_logs_no_episode(agent):
    """Vector envs reset after the last episode (SB3's evaluate_policy): no phantom 0-step episode."""
    sink = MemorySink()
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), Monitor(agent, sinks=[sink]))
    env.reset(seed=0)
    env.reset(seed=1)  # reset twice: the first, empty, episode is forgotten
    for _ in range(3):
        env.step()
    env.reset(seed=2)  # ends the 3-step episode; the new one gets no step before close
    env.close()
    assert [(e.episode, e.length, e.seed, e.interrupted) for e in sink.episodes] == [(0, 3, 1, False)]


def test_run_episode_reports_each_step_for_progress_within_long_episodes():
    seen = []
    with Monitor(load("cartpole", "ensemble"), threshold=1e9) as monitor:
        record = monitor.run_episode(Variant("cartpole").make(), seed=0, max_steps=40,
                                     on_progress=lambda *args: seen.append(args))
    assert seen == [("decisions", n, 40) for n in range(1, record.length + 1)] and record.length == 40


def test_watch_takes_a_shipped_agent_with_its_own_env_id_and_refuses_another(agent):
    """A shipped agent acts in its task's env: the env id given beside it (oodmon's or gymnasium's
    name of that env) is checked, not silently ignored."""
    from oodmon.monitor.watch import as_agent

    assert as_agent(agent, "CartPole-v1") is agent and as_agent(agent, "oodmon/CartPole-v1") is agent
    for other in ("Pendulum-v1", "NoSuchEnv-v0"):
        with pytest.raises(ConfigError, match=f"the cartpole agent acts in oodmon/CartPole-v1, not {other}"):
            as_agent(agent, other)


def test_watch_given_a_threshold_alone_loads_the_shipped_agent_it_names_or_says_what_to_give(tmp_path):
    """``oodmon.watch(threshold=...)`` without the policy (as ``oodmon run --threshold`` alone): the
    shipped agent of the threshold's task and method, with its masks; a threshold of a policy it
    cannot load asks for it (SB3 models it names: tests/agents/test_sb3_models.py)."""
    import oodmon
    from oodmon.monitor import Threshold

    path = tmp_path / "t.json"
    Threshold(1e9, "chosen_std", 1, "episode", 0.05, 45, 9_000, task="cartpole", method="dropconnect",
              detector="spread", masks="fixed").save(path)
    monitor = oodmon.watch(threshold=path)
    assert (monitor.agent.task, monitor.agent.method, monitor.agent.estimator.masks) == ("cartpole", "dropconnect",
                                                                                         "fixed")
    assert monitor.run_episode(Variant("cartpole").make(), seed=0, max_steps=20).length == 20
    for method, words in (("plain", "your own policy, which it cannot load"),
                          ("sb3", "your own SB3 models, and does not record how they were loaded"),
                          ("dropout", "a pong-x/dropout agent oodmon does not ship")):
        task = "pong-x" if method == "dropout" else "cartpole"
        Threshold(1.0, "chosen_std", 1, "episode", 0.05, 45, 9_000, task=task, method=method,
                  detector="dynamics").save(path)
        with pytest.raises(ConfigError, match=re.escape(f"calibrated on {words}") + r".*give the policy, watch\("):
            oodmon.watch(threshold=path)


def test_watch_names_its_own_fit_episodes_argument_when_refusing_it(agent):
    import oodmon

    with pytest.raises(ConfigError, match=r"^fit_episodes=0 is not allowed; fitting the detectors needs"):
        oodmon.watch(agent, "CartPole-v1", fit_episodes=0)  # was "episodes=0 ...", the name of another argument
    with pytest.raises(ConfigError, match=r"^warmup=-5 is not allowed"):  # before any fitting
        oodmon.watch(agent, "CartPole-v1", warmup=-5)
    with pytest.raises(ConfigError, match=r"^max_steps=0 is not allowed"):
        oodmon.watch(agent, "CartPole-v1", max_steps=0)
    with pytest.raises(ConfigError, match=r"^workers=-1 is not allowed"):
        oodmon.watch(agent, "CartPole-v1", workers=-1)
    for bad in (0, 2.5, "all"):  # None trains every epoch; "all" is the command line's word for it
        with pytest.raises(ConfigError, match=rf"^dynamics_updates={bad!r} is not allowed; give an integer >= 1, or "
                                              r"None \(every epoch\)"):
            oodmon.watch(agent, "CartPole-v1", dynamics_updates=bad)


def test_an_env_of_another_task_is_refused_before_any_fitting(agent, monkeypatch):
    """MonitoredEnv and watch(env=...) refuse an env whose spaces are not the agent's, naming both,
    before watch() fits or calibrates anything (the first step would fail after minutes of work)."""
    import oodmon
    from oodmon.monitor import watch as watch_module

    with pytest.raises(ConfigError, match=r"observation_space is Box\(.*\(3,\), float32\), but cartpole/ensemble acts in "
                                          r"oodmon/CartPole-v1, whose observation_space is Box\(.*\(4,\)"):
        MonitoredEnv(gymnasium.make("Pendulum-v1"), Monitor(agent))
    monkeypatch.setattr("oodmon.monitor.detectors.fit_agent_detectors",
                        lambda *a, **k: pytest.fail("fitted detectors for an env it cannot act in"))
    with pytest.raises(ConfigError, match="an env of another task"):
        oodmon.watch(agent, env=gymnasium.make("Pendulum-v1"))
    # A vector env (it raised gymnasium's TypeError after the fitting and the calibration):
    from stable_baselines3.common.vec_env import DummyVecEnv

    vector = DummyVecEnv([lambda: gymnasium.make("CartPole-v1")])
    with pytest.raises(ConfigError, match=r"got a DummyVecEnv \(a vector env\): wrap each of its envs in a MonitoredEnv"):
        oodmon.watch(agent, env=vector)
    from oodmon.monitor.detectors import detectors_for

    watching = Monitor(None, detectors=detectors_for(agent, None).subset(["dynamics"]), detector="dynamics")
    for monitor in (Monitor(agent), watching):  # a monitor that only watches, too
        with pytest.raises(ConfigError, match="got a DummyVecEnv"):
            MonitoredEnv(vector, monitor)
    assert watch_module.as_agent(agent) is agent
    # Bounds may differ (a variant, or a user's env bounding its observations otherwise): same shapes pass.
    wide = gymnasium.make("oodmon/CartPole-v1", length=2.0)
    wide.observation_space = gymnasium.spaces.Box(-10, 10, (4,), np.float32)
    assert MonitoredEnv(wide, Monitor(agent)).env is wide


class _SensorFailure(gymnasium.ObservationWrapper):
    """The pole's angle reads NaN at steps [first, first + count) of each episode (a failed sensor)."""

    def __init__(self, env: gymnasium.Env, first: int, count: int) -> None:
        super().__init__(env)
        self.first, self.count, self.t = first, count, 0

    def reset(self, **kwargs):
        self.t = 0
        return super().reset(**kwargs)

    def step(self, action):
        self.t += 1
        return super().step(action)

    def observation(self, obs):
        obs = np.array(obs, dtype=np.float32)
        if self.first <= self.t < self.first + self.count:
            obs[2] = np.nan
        return obs


def test_a_nan_observation_scores_inf_on_every_detector_and_alarms(agent, tmp_path):
    """A failed sensor's NaN made every score NaN (combined: -0.0, its lowest rank), and NaN never
    exceeds a threshold: the monitor stayed silent. Now every detector scores such a step +inf
    without being fed it, the alarm fires (m = 1: at once), the detectors' windows are not
    poisoned, the MCAP step message writes null for what is not finite, and replay ranks it."""
    import json
    import math

    from mcap.reader import make_reader

    from oodmon.monitor import McapSink, Threshold
    from oodmon.monitor.detectors import DetectorSet
    from oodmon.agents import zoo_dir
    from oodmon.replay import compute_metrics, read_log

    detectors = DetectorSet.load(zoo_dir() / "cartpole-ensemble" / "detectors")
    threshold = Threshold(6.0, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", method="ensemble",
                          detector="combined")
    monitor = Monitor(agent, threshold, detectors=detectors, sinks=[McapSink(tmp_path / "nan.mcap")])
    env = MonitoredEnv(_SensorFailure(gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=100), 50, 3), monitor)
    env.reset(seed=0)
    seen = []
    while True:
        _, _, terminated, truncated, info = env.step()
        seen.append(info["oodmon"])
        if terminated or truncated:
            break
    monitor.close()
    assert all(not s["alarm"] for s in seen[:50]) and max(s["score"] for s in seen[:50]) < 6.0  # an ID start
    for s in seen[50:53]:
        assert s["alarm"] and all(math.isinf(v) and v > 0 for v in s["scores"].values())
    # The windowed detectors were not fed the NaN: their scores are finite again from the next step,
    # and the first observation after the gap is no transition from the one before it (the jump
    # across three blind steps scored a dynamics surprise over 2,000 that stayed in its 20-step mean).
    assert all(math.isfinite(v) for s in seen[53:] for v in s["scores"].values())
    assert abs(seen[53]["scores"]["dynamics"] - seen[49]["scores"]["dynamics"]) < 0.5
    with open(tmp_path / "nan.mcap", "rb") as file:
        steps = [json.loads(m.data) for _, _, m in make_reader(file).iter_messages(topics=["/oodmon/step"])]
    assert steps[50]["score"] is None and steps[50]["observation"][2] is None and steps[49]["score"] > 0
    log = read_log(tmp_path / "nan.mcap")
    assert np.isinf(log.episodes[0].scores[50:53]).all()
    row = next(m for m in compute_metrics([log]) if m.variant == "cartpole:length=2.0")
    assert row.auroc is not None and 0.0 <= row.auroc <= 1.0  # sklearn ranked the +inf steps


def test_run_episode_ends_an_episode_whose_policy_cannot_act_on_a_nan_and_alarms_on_it(agent):
    """SB3's PPO raises on a NaN observation (its Categorical's check), and `oodmon run` stopped with
    that traceback when a shift blew the env's physics up. Now the NaN step is scored (+inf: the
    alarm) and logged with the action before it, and the episode ends there with a warning; a
    policy that acts on it goes on as before, and an error on a finite observation is not hidden."""
    from oodmon.monitor import MemorySink, NonFiniteObservationWarning

    def like_sb3(obs):
        if not np.isfinite(obs).all():
            raise ValueError("Expected parameter logits ... but found invalid values")
        return agent.act(obs)

    for policy, length in ((like_sb3, 51), (None, None)):  # None: the agent's own decision
        sink = MemorySink()
        with Monitor(agent, threshold=4.0, consecutive=1, sinks=[sink]) as monitor:  # m = 1: a learned detector's
            monitor._act = policy  # the deployed policy, as an SB3 model's predict() would be
            env = _SensorFailure(gymnasium.make("oodmon/CartPole-v1"), 50, 3)  # NaN angle at steps 50-52
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                record = monitor.run_episode(env, seed=0)
        ends = [w for w in caught if issubclass(w.category, NonFiniteObservationWarning)]
        if length is not None:  # ended at the NaN, which alarmed, logged with the action before it
            assert record.length == 51 and len(ends) == 1 and "not finite ([" in str(ends[0].message)
            assert sink.steps[50].alarm and sink.steps[50].score == np.inf
            assert sink.steps[50].action == sink.steps[49].action
        else:  # oodmon's agents act on a NaN: the episode goes on past the three blind steps
            assert record.length > 53 and not ends and all(s.alarm for s in sink.steps[50:53])

    def broken(obs):
        raise RuntimeError("a bug of the policy's own")

    with Monitor(agent, threshold=4.0, sinks=[sink := MemorySink()]) as monitor:
        monitor._act = broken
        with pytest.raises(RuntimeError, match="a bug of the policy's own"):
            monitor.run_episode(gymnasium.make("oodmon/CartPole-v1"), seed=0)
    assert sink.episodes[-1].interrupted


def test_a_monitored_env_ends_the_episode_where_its_policy_cannot_act_on_a_nan(agent, tmp_path):
    """Through MonitoredEnv (oodmon.watch's path) SB3's raise on a NaN reached the caller and the
    alarmed step was never logged. Now, as in `oodmon run`, the step is logged and alarmed with the
    action before it, the env is not stepped, and the episode ends there (truncated) with a warning
    and the reason in info; the next reset starts a new episode. A NaN at an episode's first step
    (no action before it) and an error on a finite observation still reach the caller."""
    from oodmon.monitor import McapSink, MemorySink, NonFiniteObservationWarning, PolicyCannotAct
    from oodmon.replay import read_log

    def like_sb3(obs):
        if not np.isfinite(obs).all():
            raise ValueError("Expected parameter logits ... but found invalid values")
        return agent.act(obs)

    sink = MemorySink()
    monitor = Monitor(agent, threshold=4.0, consecutive=1, sinks=[sink, McapSink(tmp_path / "nan.mcap")])
    monitor._act = like_sb3  # the deployed policy, as an SB3 model's predict() would be
    env = MonitoredEnv(_SensorFailure(gymnasium.make("oodmon/CartPole-v1"), 50, 3), monitor)
    obs, _ = env.reset(seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for step in range(60):
            obs, reward, terminated, truncated, info = env.step()
            if terminated or truncated:
                break
    assert step == 50 and truncated and not terminated and reward == 0.0 and np.isnan(obs[2])
    assert "not finite" in info["oodmon"]["policy_could_not_act"] and info["oodmon"]["alarm"]
    assert [w.filename for w in caught if issubclass(w.category, NonFiniteObservationWarning)] == [__file__]
    assert sink.episodes[-1].length == 51 and not sink.episodes[-1].interrupted
    assert sink.steps[50].alarm and sink.steps[50].score == np.inf and sink.steps[50].action == sink.steps[49].action
    env.reset(seed=1)
    for _ in range(10):
        env.step()
    env.close()  # the episode still running is logged as interrupted
    log = read_log(tmp_path / "nan.mcap")
    assert log.episodes[0].length == 51 and np.isinf(log.episodes[0].scores[50]) and monitor.episode == 1

    # No action before a NaN first step: nothing to log the step with, the policy's error is the caller's.
    first = MonitoredEnv(_SensorFailure(gymnasium.make("oodmon/CartPole-v1"), 0, 3), Monitor(agent, threshold=4.0))
    first.monitor._act = like_sb3
    first.reset(seed=0)
    with pytest.raises(ValueError, match="invalid values"):
        first.step()
    with pytest.raises(PolicyCannotAct, match="after step 0") as raised:  # a loop of your own hears it
        monitor = Monitor(agent, threshold=4.0, consecutive=1)
        monitor._act = like_sb3
        monitor.begin_episode(env_id="oodmon/CartPole-v1")
        monitor.step(np.zeros(4, dtype=np.float32))
        monitor.step(np.full(4, np.nan, dtype=np.float32))
    assert isinstance(raised.value.__cause__, ValueError) and monitor.last_step.alarm


def test_a_nan_score_counts_as_above_the_threshold_in_every_rule():
    """A NaN score (a detector that could not score a finite observation) is never "below": the
    alarm rule and the calibration's episode statistic count it as +inf, and the combined detector
    ranks a NaN member as +inf, not as its lowest rank (it read -0.0)."""
    import math

    from oodmon.agents import zoo_dir
    from oodmon.monitor.alarms import AlarmTracker, episode_statistic
    from oodmon.monitor.detectors import DetectorSet, StepContext

    tracker = AlarmTracker(threshold=1.0, consecutive=2)
    assert [tracker.update(0, step, s)[0] for step, s in enumerate([0.5, float("nan"), float("nan"), 0.5])] == \
        [False, False, True, False]
    assert episode_statistic(np.array([0.5, np.nan, 0.2]), 1) == math.inf
    combined = DetectorSet.load(zoo_dir() / "cartpole-ensemble" / "detectors")["combined"]
    finite = {name: 0.0 for name in combined.members}
    assert math.isfinite(combined.score(StepContext(np.zeros(4), 0, scores=finite)))
    for member in combined.members:
        assert combined.score(StepContext(np.zeros(4), 0, scores=finite | {member: float("nan")})) == math.inf


def test_one_monitor_shared_by_two_envs_is_refused_at_the_first_mixed_step(agent):
    """A vector env of MonitoredEnvs sharing one Monitor logged episodes of 293, 7, 414 and 47 steps
    for four CartPole episodes (the two envs' steps mixed into one episode). Now the first step of
    an env whose Monitor follows another env's episode is refused; one env after another is fine."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    sink = MemorySink()
    monitor = Monitor(agent, sinks=[sink])
    venv = DummyVecEnv([lambda: MonitoredEnv(Variant("cartpole").make(), monitor) for _ in range(2)])
    venv.reset()
    with pytest.raises(ConfigError, match="another MonitoredEnv began .* give each env its own Monitor"):
        venv.step(np.zeros(2, dtype=int))
    first, second = (MonitoredEnv(Variant("cartpole").make(), monitor) for _ in range(2))
    for env, steps in ((first, 5), (second, 6), (first, 7)):  # one after another: each reset takes the monitor over
        env.reset(seed=0)
        for _ in range(steps):
            env.step()
    monitor.close()
    assert [e.length for e in sink.episodes][-3:] == [5, 6, 7]


def _scores(sink: MemorySink) -> dict[str, list[float]]:
    return {name: [step.scores[name] for step in sink.steps] for name in sink.steps[0].scores}


def test_a_twin_monitors_another_env_of_a_vector_env_as_a_monitor_of_its_own_would(agent):
    """monitor.twin(): the same policy, threshold and rule with copies of the fitted detectors, so
    that a vector env's envs, stepped in turn, are each scored as if monitored alone."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from oodmon.monitor.detectors import detectors_for

    detectors = detectors_for(agent, None)  # the shipped dynamics, features and combined
    alone = []
    for seed in (0, 1):
        sink = MemorySink()
        with Monitor(agent, 4.0, detectors=detectors, detector="combined", sinks=[sink]) as monitor:
            monitor.run_episode(Variant("cartpole", {"length": 2.0}).make(onset_step=20), seed=seed)
        alone.append(_scores(sink))
    sinks = [MemorySink(), MemorySink()]
    first = Monitor(agent, 4.0, detectors=detectors, detector="combined", sinks=[sinks[0]])
    monitors = [first, first.twin(sinks=[sinks[1]])]
    assert monitors[1].threshold == 4.0 and monitors[1].detector == "combined" and monitors[1].sinks is not first.sinks
    venv = DummyVecEnv([lambda m=m: MonitoredEnv(Variant("cartpole", {"length": 2.0}).make(onset_step=20), m)
                        for m in monitors])
    venv.seed(0)  # env i: seed i
    obs = venv.reset()
    done = np.zeros(2, bool)
    while not done.all():  # both envs step in turn until each has ended one episode
        obs, _, dones, _ = venv.step(np.array([agent.act(o) for o in obs]))
        done |= dones
    for monitor in monitors:
        monitor.close()
    for sink, expected in zip(sinks, alone):
        assert {name: values[:len(expected[name])] for name, values in _scores(sink).items()} == expected
    # Two Monitors sharing one set of detectors (what twin() copies) mix their windows: other scores.
    shared = [Monitor(agent, 4.0, detectors=detectors, detector="combined", sinks=[MemorySink()]) for _ in range(2)]
    venv = DummyVecEnv([lambda m=m: MonitoredEnv(Variant("cartpole", {"length": 2.0}).make(onset_step=20), m)
                        for m in shared])
    venv.seed(0)
    obs = venv.reset()
    for _ in range(30):
        obs, *_ = venv.step(np.array([agent.act(o) for o in obs]))
    assert _scores(shared[0].sinks.sinks[0])["dynamics"][:30] != alone[0]["dynamics"][:30]


def test_gymnasiums_own_vector_env_of_twins_scores_each_env_as_a_monitor_of_its_own_would(agent):
    """The twins of docs/your-policy.md's "Inside SB3" in gymnasium's SyncVectorEnv (its autoreset
    resets an ended env at the next step): each env's first episode scored as if monitored alone,
    and each log holds whole episodes of its own env, the next begun after the autoreset."""
    from oodmon.monitor.detectors import detectors_for

    detectors = detectors_for(agent, None)
    alone = []
    for seed in (0, 1):
        sink = MemorySink()
        with Monitor(agent, 4.0, detectors=detectors, detector="combined", sinks=[sink]) as monitor:
            monitor.run_episode(Variant("cartpole", {"length": 2.0}).make(onset_step=20), seed=seed)
        alone.append((_scores(sink), sink.episodes[0].length))
    sinks = [MemorySink(), MemorySink()]
    first = Monitor(agent, 4.0, detectors=detectors, detector="combined", sinks=[sinks[0]])
    monitors = [first, first.twin(sinks=[sinks[1]])]
    envs = gymnasium.vector.SyncVectorEnv(
        [lambda m=m: MonitoredEnv(Variant("cartpole", {"length": 2.0}).make(onset_step=20), m) for m in monitors])
    obs, _ = envs.reset(seed=0)  # env i: seed i
    ended = np.zeros(2, int)
    while (ended < 2).any():  # until each env has ended two episodes
        obs, _, terminated, truncated, _ = envs.step(np.array([agent.act(o) for o in obs]))
        ended += terminated | truncated
    envs.close()
    for monitor in monitors:
        monitor.close()
    for sink, (expected, length) in zip(sinks, alone):
        assert {name: values[:len(expected[name])] for name, values in _scores(sink).items()} == expected
        assert sink.episodes[0].length == length and len(sink.episodes) >= 2  # the second after the autoreset
        assert all(episode.length > 1 for episode in sink.episodes[:2])


def test_a_threshold_with_a_warmup_alarms_on_no_finite_score_of_the_first_steps_but_on_a_nan(agent):
    """The threshold file's warm-up reaches the monitor: a threshold every score exceeds alarms first
    at the warm-up's end; a failed sensor in the warm-up alarms at once."""
    from oodmon.monitor import Threshold

    def first_alarms(threshold, env):
        sink = MemorySink()
        with Monitor(agent, threshold, sinks=[sink]) as monitor:
            monitor.run_episode(env, seed=0, max_steps=40)
        return [s.step for s in sink.steps if s.alarm][:4], sink.alarms

    always = Threshold(-1e9, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", method="ensemble", warmup=25)
    steps, events = first_alarms(always, gymnasium.make("oodmon/CartPole-v1"))
    assert steps == [25, 26, 27, 28] and [e.step for e in events] == [25]
    assert events[0].rule == "score > threshold from step 25 of each episode"
    never = Threshold(1e9, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", method="ensemble", warmup=25)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the NaN steps' warnings: their own test's
        steps, events = first_alarms(never, _SensorFailure(gymnasium.make("oodmon/CartPole-v1"), 5, 3))
    assert steps == [5, 6, 7] and [e.step for e in events] == [5]
