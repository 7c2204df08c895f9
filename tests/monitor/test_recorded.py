"""A deployment oodmon cannot play: detectors fitted and the alarm calibrated on recorded episodes."""

from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import oodmon
from oodmon.envs import parse_variant
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor import (MemorySink, Monitor, Threshold, calibrate_on_episodes, fit_on_episodes,
                            validate_on_episodes, watch_recorded)
from oodmon.monitor.detectors import DetectorSet
from oodmon.monitor.recorded import FewRecordedStepsWarning
from tests.helpers import RALLY, ball_pictures, load_script, once_per_run

# (the tests fit on few recorded steps on purpose: the warning of it is tested once, below)
pytestmark = pytest.mark.filterwarnings("ignore::oodmon.monitor.recorded.FewRecordedStepsWarning")

DISCRETE = gymnasium.spaces.Discrete(2)
STEPS = 200  # each recorded episode's limit: the robot's runs


#: scripts/recorded_deployment.py: the "robot" (a hand-tuned CartPole controller, which oodmon never
#: runs) and its own loop, which records each episode as (observations, actions)
_SCRIPT = load_script("recorded_deployment")[1]
_controller = _SCRIPT.controller


def _record(count: int, seed: int, spec: str = "cartpole", onset: int = 0):
    """``count`` recorded episodes of the robot, at most :data:`STEPS` long."""
    return _SCRIPT.record(count, seed, STEPS, spec, onset)


def _first_alarms(monitor, episodes) -> list[int | None]:
    """Each episode's first alarmed step, the monitor fed step by step as a deployment feeds it."""
    firsts = []
    with monitor:
        for observations, actions in episodes:
            monitor.begin_episode()
            first = None
            for step, (obs, action) in enumerate(zip(observations, actions)):
                monitor.step(obs, action=action)
                if monitor.last_step.alarm and first is None:
                    first = step
            monitor.end_episode()
            firsts.append(first)
    return firsts


@pytest.fixture(scope="module")
def calibration(tmp_path_factory, worker_id):
    """A threshold (far 0.1, confidence 0.9) saved with its detectors: fitted on 60 recorded ID
    episodes, calibrated on 45 others (reset seeds 0-59 and 1,000-1,044)."""
    def make(folder):
        path = folder / "robot.json"
        watch_recorded(_record(60, 0), _record(45, 1000), action_space=DISCRETE, far=0.1, save=path,
                       reading_names=["x", "v", "theta", "omega"])
        return str(path)

    return once_per_run(tmp_path_factory, worker_id, "recorded_calibration", make)


def test_the_threshold_keeps_its_promise_on_fresh_episodes_and_alarms_at_a_shift(calibration):
    """Fresh recorded ID episodes (seeds no fit or calibration saw) alarm at the rate the threshold
    promises, and a pole four times as long from step 50 is alarmed at once. With confidence 0.9
    the false-alarm rate is at most 0.1: of 100 fresh episodes, more than 20 alarmed would have
    probability under 0.002 at that rate (binomial). When written: the threshold 7.07, 4 of 100
    alarmed; each of 10 shifted episodes alarmed at step 51, the first transition of the new physics
    that the monitor scored."""
    threshold = Threshold.load(calibration)
    assert (threshold.detector, threshold.n_episodes, threshold.far, threshold.confidence) == ("combined", 45, 0.1, 0.9)
    assert threshold.reading_names == ["x", "v", "theta", "omega"] and threshold.longest_episode == STEPS
    assert len(threshold.episode_hashes) == 45
    validation = validate_on_episodes(calibration, _record(100, 50_000))
    assert (validation.total, validation.far, validation.verdict) == (100, 0.1, "below")
    assert validation.alarmed <= 20 and validation.low <= validation.alarmed / 100 <= validation.high
    fresh = _first_alarms(watch_recorded(threshold=calibration), _record(100, 50_000))  # the deployed loop counts alike
    assert sum(first is not None for first in fresh) == validation.alarmed
    shifted = _first_alarms(watch_recorded(threshold=calibration), _record(10, 60_000, "cartpole:length=2.0", 50))
    assert all(first is not None and 50 <= first <= 55 for first in shifted), shifted


def test_the_alarm_names_its_readings_and_the_log_keeps_the_episodes(calibration):
    """The monitor of recorded episodes logs like any other: its alarm names the reading the
    dynamics model predicted worst, by the threshold's names."""
    sink = MemorySink()
    _first_alarms(watch_recorded(threshold=calibration, sinks=[sink]), _record(1, 61_000, "cartpole:length=2.0", 50))
    assert len(sink.episodes) == 1 and sink.alarms and sink.alarms[0].cause in ("dynamics", "drift")
    assert sink.alarms[0].readings and "(" in sink.alarms[0].text()


def test_a_calibration_on_the_fitting_episodes_is_refused():
    fit = _record(6, 0)
    with pytest.warns(FewRecordedStepsWarning, match="fitted on 1,200 recorded steps .6 episodes., fewer than the "
                                                     "45,000"):
        detectors = fit_on_episodes(fit, DISCRETE, dynamics_updates=20)
    assert list(detectors.names) == ["dynamics", "drift", "combined"]
    assert detectors.fitted_for["action_space"] == {"discrete": 2} and len(detectors.fitted_for["episode_hashes"]) == 6
    with pytest.raises(ConfigError, match="episode 20 of the calibration episodes .2 in all. is one the detectors"):
        calibrate_on_episodes(detectors, [*_record(20, 100), fit[2], fit[4]], far=0.1)


def test_box_actions_and_a_saved_set_read_back(tmp_path):
    """A deployment of continuous actions (a Pendulum torque); the set saved and loaded scores alike."""
    env = gymnasium.make("Pendulum-v1", max_episode_steps=60)
    episodes = []
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        observations, actions = [obs], []
        for _ in range(60):
            action = np.clip(-2.0 * obs[2:3] - 1.0 * obs[1:2], -2, 2).astype(np.float32)
            obs, *_ = env.step(action)
            observations.append(obs)
            actions.append(action)
        episodes.append((np.array(observations), np.array(actions)))  # the last observation too
    detectors = fit_on_episodes(episodes, env.action_space, dynamics_updates=20)
    assert detectors.fitted_for["action_space"] == {"box": [1]}
    detectors.save(tmp_path / "set")
    again = DetectorSet.load(tmp_path / "set")
    assert again.fingerprint("combined") == detectors.fingerprint("combined")
    with pytest.raises(ConfigError, match="actions are of shape \\(2,\\) each"):
        fit_on_episodes([(o, np.c_[a, a]) for o, a in episodes], env.action_space)
    flat = fit_on_episodes([(o, a[:, 0]) for o, a in episodes], env.action_space, dynamics_updates=20)  # (T,) torques
    assert flat.fingerprint("combined") == detectors.fingerprint("combined")


@pytest.mark.parametrize("episodes, words", [
    (None, "a list of episodes"),
    (5, "a list of episodes, each .observations, actions. as arrays; got int$"),
    ([], "a list of episodes.*empty"),
    ([(np.zeros((5, 4)),)], "episode 0 of episodes is a pair"),
    ([(np.zeros((5, 4)), np.zeros(3))], "5 observations and 3 actions"),
    ([(np.zeros(5), np.zeros(5))], "of shape \\(5,\\); give one row per step"),
    ([(np.zeros((5, 4)), np.zeros(5)), (np.zeros((5, 3)), np.zeros(5))], "episode 1 .* of shape \\(3,\\), the first"),
    ([(np.zeros((5, 4)), np.array([0, 1, 2, 0, 1]))], "the action at step 2, 2, is not of the action space Discrete"),
    ([(np.zeros((5, 4)), np.full(5, 0.5))], "the action at step 0"),
    ([(np.zeros((5, 4)), np.zeros((5, 2)))], "one whole number per step"),
    ([(np.array([["a"] * 4] * 5), np.zeros(5))], "must be numbers"),
])
def test_recorded_episodes_that_are_not_episodes_are_refused_naming_what(episodes, words):
    with pytest.raises(ConfigError, match=words):
        fit_on_episodes(episodes, DISCRETE)


def test_what_the_detectors_cannot_read_is_refused():
    with pytest.raises(ConfigError, match="Discrete counted from 0 or a Box"):
        fit_on_episodes(_record(3, 0), gymnasium.spaces.MultiDiscrete([2, 2]))
    with pytest.raises(ConfigError, match="the spread detector reads the policy's samples or features, which recorded"):
        fit_on_episodes(_record(3, 0), DISCRETE, detectors=["spread"])
    with pytest.raises(ConfigError, match="detectors is a list of the detectors' names"):
        fit_on_episodes(_record(3, 0), DISCRETE, detectors="dynamics")
    with pytest.raises(ConfigError, match="3 at least|at least 3"):
        fit_on_episodes([(np.full((5, 4), np.nan), np.zeros(5))] * 2 + _record(1, 0), DISCRETE)


def test_watch_recorded_says_what_it_needs(calibration, tmp_path):
    with pytest.raises(ConfigError, match="give fit_episodes, calibration_episodes, action_space"):
        watch_recorded()
    with pytest.raises(ConfigError, match="leave out fit_episodes, save"):
        watch_recorded(_record(3, 0), threshold=calibration, save=tmp_path / "t.json")
    alone = tmp_path / "alone.json"
    shutil.copy(calibration, alone)
    with pytest.raises(ConfigError, match="detectors, fitted beside it in .*alone.json.detectors, are missing"):
        watch_recorded(threshold=alone)
    with pytest.raises(ConfigError, match="not fitted on recorded episodes"):
        calibrate_on_episodes(DetectorSet([], fitted_for={}), _record(22, 0))
    with pytest.raises(ConfigError, match="too few|episodes"):  # far 0.01 at confidence 0.9 needs 230
        calibrate_on_episodes(DetectorSet.load(f"{calibration}.detectors"), _record(5, 7000), far=0.01)
    with pytest.raises(ConfigError, match="threshold= is the path of a calibration saved before"):
        watch_recorded(threshold=Threshold.load(calibration))
    with pytest.raises(ConfigError, match="the alarm reads the \\['combined'\\] detector, which the set does not have"):
        calibrate_on_episodes(DetectorSet.load(f"{calibration}.detectors"), _record(22, 7000), detector=["combined"])
    assert oodmon.watch_recorded is watch_recorded
    assert json.loads((tmp_path / "alone.json").read_text())["detector"] == "combined"


def test_the_same_episodes_recorded_or_played_fit_the_same_detectors():
    """Recorded with the observation after each episode's last action, the episodes a played fit
    collects give the very detectors that fit gives (their fingerprints: every tensor alike)."""
    from oodmon.monitor.detectors import fit_detectors
    from oodmon.monitor.detectors.fitting import collect

    env = gymnasium.make("CartPole-v1", max_episode_steps=100)
    played = collect(_controller, env, 6, seed=600_000)  # fit_detectors' default seed
    recorded = fit_on_episodes([(t.observations, t.actions) for t in played], DISCRETE,
                               detectors=["dynamics", "combined"], dynamics_updates=30)
    fitted = fit_detectors(_controller, env, detectors=["dynamics", "combined"], episodes=6, dynamics_updates=30)
    assert recorded.fingerprint("combined") == fitted.fingerprint("combined")
    assert played[0].observations.shape == (101, 4) and recorded.fitted_for["seed"] is None  # no reset seeds known


class _StandInRobot:
    """What the docs' block calls ``robot``: CartPole under the controller, its pole four times as
    long from step 50."""

    def __init__(self) -> None:
        self.env = parse_variant("cartpole:length=2.0").make(onset_step=50, max_episode_steps=STEPS)
        self.obs, _ = self.env.reset(seed=70_000)
        self.over = False

    def observe(self):
        return self.obs

    def done(self) -> bool:
        return self.over

    def policy(self, obs) -> int:
        return _controller(obs)

    def act(self, action):
        self.obs, _, terminated, truncated, _ = self.env.step(action)
        self.over = terminated or truncated
        return self.obs


def test_the_docs_block_runs_as_written(tmp_path, monkeypatch, capsys):
    """docs/your-policy.md's "A deployment oodmon cannot play": its records (60 fitting, 30
    calibration and 30 fresh episodes of 200 steps) made here, a stand-in robot in its loop; the
    validation prints its count, and the monitor alarms at the first step of the longer pole's
    physics and logs the episode."""
    from oodmon.replay import read_log

    text = (Path(__file__).resolve().parents[2] / "docs" / "your-policy.md").read_text()
    block = re.search(r"```python\n(.*?)```", text[text.index("## A deployment oodmon cannot play"):], re.S).group(1)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    from oodmon.monitor import save_records

    save_records("runs/robot_records.npz", _record(120, 0))
    exec(compile(block, "docs/your-policy.md's block", "exec"), {"robot": _StandInRobot()})
    assert Threshold.load("runs/robot.json").n_episodes == 30
    checked, alarm = capsys.readouterr().out.splitlines()
    assert re.fullmatch(r"\d of 30 fresh episodes alarmed \(95% interval .*\); the target 0.1: (below|consistent)",
                        checked), checked
    assert alarm.startswith("episode 0 step 51: score ") and "cause: dynamics; reading [3] (omega)" in alarm, alarm
    episodes = read_log("runs/robot.mcap").episodes
    assert len(episodes) == 1 and episodes[0].first_alarm_step == 51


def test_a_monitor_that_runs_no_policy_refuses_what_its_detectors_cannot_read(calibration):
    """Given an observation of another shape, or an action the dynamics model was not fitted on,
    the step is refused naming it (before: numpy's broadcast error deep in the detector; a
    discrete action past the last was kept and failed at the next step as an IndexError)."""
    monitor = watch_recorded(threshold=calibration)
    with monitor:
        monitor.begin_episode()
        with pytest.raises(ConfigError, match="observation at step 0 of episode 0 is of shape \\(3,\\); the detectors "
                                              "were fitted on observations of shape \\(4,\\)"):
            monitor.step(np.zeros(3), action=0)
        monitor.step(np.zeros(4, np.float32), action=np.int64(1))
        for bad in (2, -1, 0.5, np.nan, [0, 1], "1"):
            with pytest.raises(ConfigError, match="given at step 1 of episode 0, .*is not one of the 2 discrete"):
                monitor.step(np.zeros(4), action=bad)
        assert monitor.last_step.step == 0  # nothing refused was scored


@pytest.mark.parametrize("bad", [np.zeros(2), np.array([np.inf]), "a"])
def test_a_box_action_of_another_size_or_not_finite_is_refused(bad):
    from oodmon.monitor.detectors import DynamicsDetector
    from oodmon.monitor.detectors.base import Trajectory

    rng = np.random.default_rng(0)
    trajectories = [Trajectory(rng.normal(size=(21, 3)), rng.normal(size=(20, 1))) for _ in range(3)]
    dynamics = DynamicsDetector(None, seed=0, max_updates=5).fit(trajectories)
    with Monitor(None, detectors=DetectorSet([dynamics], fitted_for={"obs_shape": [3]})) as monitor:
        monitor.begin_episode()
        monitor.step(np.zeros(3), action=np.array([0.5]))
        monitor.step(np.zeros(3), action=7.0)  # one number: past the bounds is the env's to clip
        with pytest.raises(ConfigError, match="is not 1 finite number, as the actions"):
            monitor.step(np.zeros(3), action=bad)


@pytest.mark.parametrize("task, variant", [("cartpole", "cartpole:length=2.0"), ("pendulum", "pendulum:m=1.5"),
                                           ("pong", "pong:obs.stuck=1")])
def test_the_measuring_script_prints_its_counts(task, variant, monkeypatch, capsys):
    """scripts/recorded_deployment.py, small: its lines name the threshold, the fresh episodes'
    count with its interval, and each variant's alarms, delays and readings; of discrete actions
    (CartPole's) and of a torque (Pendulum's)."""
    monkeypatch.setattr("sys.argv", ["recorded_deployment.py", "--task", task, "--fit", "6", "--calibration", "22",
                                     "--fresh", "4", "--shifted", "2", "--steps", "80", "--far", "0.1",
                                     "--variants", variant])
    monkeypatch.setattr(_SCRIPT, "limit_threads", lambda: None)
    _SCRIPT.main()
    lines = capsys.readouterr().out.splitlines()
    fitted = "frames, stillness, combined" if task == "pong" else "dynamics, drift, combined"
    assert lines[0].startswith(f"fitted {fitted} on 6 and calibrated on 22 recorded episodes in ")
    assert re.fullmatch(r"fresh ID: \d of 4 alarmed \(.*; target 10% at confidence 0.9\)", lines[1])
    # (fitted on 6 episodes of 80 steps, the detectors are weak: the counts are the main test's)
    assert re.fullmatch(rf"{variant} from step 50: \d of 2 alarmed after the onset, \d before; delays \[.*\]; "
                        r"causes \{.*\}(; first readings \{.*\})?(; regions \{.*\})?", lines[2]), lines[2]


def test_validation_counts_fresh_episodes_only(calibration):
    """Neither the calibration's episodes nor the fit's are counted: both would read low."""
    threshold, detectors = Threshold.load(calibration), DetectorSet.load(f"{calibration}.detectors")
    with pytest.raises(ConfigError, match="episode 2 of the validation episodes .1 in all. is one the threshold was "
                                          "calibrated on: it is not fresh"):
        validate_on_episodes(threshold, [*_record(2, 80_000), *_record(1, 1003)], detectors=detectors)
    with pytest.raises(ConfigError, match="episode 0 of the validation episodes .1 in all. is one the detectors were "
                                          "fitted on"):
        validate_on_episodes(calibration, _record(1, 59))
    with pytest.raises(ConfigError, match="not a path with detectors="):
        validate_on_episodes(calibration, _record(1, 80_000), detectors=detectors)
    with pytest.raises(ConfigError, match="a Threshold with detectors="):
        validate_on_episodes(threshold, _record(1, 80_000))
    validation = validate_on_episodes(threshold, _record(3, 80_000), detectors=detectors)
    assert validation.total == 3 and validation.steps == sum(len(o) for o, _ in _record(3, 80_000))


def test_the_commands_say_where_a_recorded_threshold_is_checked(calibration, capsys, tmp_path, monkeypatch):
    """`oodmon validate` and `oodmon run` of a threshold made from recorded episodes have no env
    nor policy to play (before: "does not record its task; give --task"); given a policy and an env
    that do play the world, they run as for any threshold."""
    from oodmon.cli import main

    for argv in (["validate", calibration, "--episodes", "5"], ["run", "--threshold", calibration, "--episodes", "1"]):
        assert main(argv) == 2
        error = capsys.readouterr().err
        assert "was calibrated on episodes you recorded" in error and "--records FILE" in error, error
    (tmp_path / "robot_policy.py").write_text(
        "def act(obs):\n    return int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["validate", calibration, "--policy", "robot_policy:act", "--env", "CartPole-v1", "--episodes", "3",
                 "--max-steps", str(STEPS)]) == 0
    assert "3 fresh ID episodes" in capsys.readouterr().out


def test_the_monitors_logs_give_back_the_records(calibration, tmp_path):
    """A recorded deployment's own logs (its monitor with an McapSink) read back as the arrays it
    was given (oodmon.replay.episodes_from_logs): they calibrate to the same threshold, and a logged
    episode the detectors were fitted on is refused as the array was."""
    from oodmon.monitor import McapSink
    from oodmon.replay import episodes_from_logs

    records = [*_record(22, 3000), *_record(1, 7)]  # the last: one of the fitting episodes (seeds 0-59)
    _first_alarms(watch_recorded(threshold=calibration, sinks=[McapSink(tmp_path / "robot.mcap")]), records)
    logged = episodes_from_logs([tmp_path / "robot.mcap"])
    assert len(logged) == 23 and all(np.array_equal(o, r[0]) and np.array_equal(a, r[1])
                                     for (o, a), r in zip(logged, records))
    detectors = DetectorSet.load(f"{calibration}.detectors")
    with pytest.raises(ConfigError, match="episode 22 of the calibration episodes .1 in all. is one the detectors"):
        calibrate_on_episodes(detectors, logged, far=0.1)
    assert calibrate_on_episodes(detectors, logged[:22], far=0.1).value == \
        calibrate_on_episodes(detectors, records[:22], far=0.1).value


def _rallies(count: int, seed: int, *, noise: float = 0.0, hidden=range(0)):
    """``count`` recorded episodes of a camera: a ball's rally (tests.helpers.ball_pictures), each
    starting at its own column, one action of two a step; ``noise``: the pictures' pixels moved by
    Gaussian noise of that spread; ``hidden``: columns where the ball is not seen."""
    rng = np.random.default_rng(seed)
    episodes = []
    for _ in range(count):
        start = int(rng.integers(len(RALLY)))
        frames = ball_pictures(RALLY[start:] + RALLY[:start], hidden=hidden).observations
        if noise:
            frames = np.clip(frames + rng.normal(0, noise, frames.shape), 0, 255).astype(np.uint8)
        episodes.append((frames, rng.integers(2, size=len(frames))))
    return episodes


def test_a_camera_is_watched_by_the_cameras_detectors():
    """Pictures (bytes) are fitted by the camera's detectors (frames, stillness and their combined;
    vanishing where named); a noisy camera and a frozen one alarm, fresh pictures do not. When
    written: 0 of 20 fresh episodes alarmed (with far 0.1 at confidence 0.9, more than 6 of 20 has
    probability under 0.003); the noisy ones at step 0, the frozen ones at step 1."""
    fit = _rallies(9, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FewRecordedStepsWarning)  # (no dynamics model: none said)
        detectors = fit_on_episodes(fit, DISCRETE)
    assert list(detectors.names) == ["frames", "stillness", "combined"]
    assert detectors.fitted_for["obs_shape"] == [20, 40]
    threshold = calibrate_on_episodes(detectors, _rallies(22, 1), far=0.1)
    assert validate_on_episodes(threshold, _rallies(20, 2), detectors=detectors).alarmed <= 6
    noisy = _first_alarms(Monitor(None, threshold, detectors=detectors), _rallies(3, 3, noise=40.0))
    frozen = [(np.repeat(frames[:1], len(frames), axis=0), actions) for frames, actions in _rallies(3, 4)]
    still = _first_alarms(Monitor(None, threshold, detectors=detectors), frozen)
    assert all(first is not None and first <= 5 for first in noisy), noisy
    assert all(first is not None and first <= 5 for first in still), still
    named = fit_on_episodes(fit, DISCRETE, detectors=["frames", "stillness", "vanishing", "combined"])
    assert "vanishing" in named.names


def test_records_saved_read_back_and_validated_by_the_command(calibration, tmp_path, capsys):
    """save_records / load_records round-trip the arrays (no pickles); `oodmon validate THRESHOLD
    --records FILE` counts them as validate_on_episodes does, its JSON too; files that are not
    records, and a policy beside --records, are refused."""
    from oodmon.cli import main
    from oodmon.monitor import load_records, save_records

    fresh = _record(12, 80_000)
    path = save_records(tmp_path / "fresh", fresh)  # (the name kept as given, no .npz added)
    assert path == tmp_path / "fresh" and all(np.array_equal(o, p) and np.array_equal(a, q)
                                              for (o, a), (p, q) in zip(fresh, load_records(path)))
    expected = validate_on_episodes(calibration, fresh)
    assert main(["validate", calibration, "--records", str(path), "--json"]) in (0, 1)
    said = json.loads(capsys.readouterr().out)
    assert (said["alarmed"], said["total"], said["verdict"]) == (expected.alarmed, 12, expected.verdict)
    assert main(["validate", calibration, "--records", str(path)]) == (1 if expected.verdict == "above" else 0)
    assert f"the recorded episodes of {path}, combined detector" in capsys.readouterr().out
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    np.save(tmp_path / "objects.npy", np.array([object()]), allow_pickle=True)
    np.save(tmp_path / "numbers.npy", np.zeros(3))
    (tmp_path / "text.npz").write_text("observations_0")
    for bad, words in ((tmp_path / "other.npz", "holds x, not observations_<i>"), (tmp_path / "objects.npy", "not"),
                       (tmp_path / "numbers.npy", "it holds one array"), (tmp_path / "text.npz", "not a file of"),
                       (tmp_path / "missing.npz", "no such file")):
        with pytest.raises(ConfigError, match=words):
            load_records(bad)
    assert main(["validate", calibration, "--records", str(path), "--task", "cartpole"]) == 2
    assert "leave out --task" in capsys.readouterr().err


def test_the_command_fits_and_calibrates_on_records(tmp_path, capsys):
    """`oodmon calibrate --records FIT --calibration-records CAL --action-space discrete:2` writes the
    threshold and its detectors as watch_recorded(save=...) does (the same threshold and fit, the
    same episodes); options that shape played episodes or name a policy are refused beside it."""
    from oodmon.cli import main
    from oodmon.monitor import save_records

    fit, calibration = save_records(tmp_path / "fit.npz", _record(9, 0)), save_records(tmp_path / "cal.npz",
                                                                                         _record(22, 1000))
    argv = ["calibrate", "--records", str(fit), "--calibration-records", str(calibration), "--action-space",
            "discrete:2", "--far", "0.1", "--dynamics-updates", "50", "--out", str(tmp_path / "cli.json")]
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert said.startswith("recorded episodes: alarm when score > ") and "fitted on the 9 episodes of" in said
    made = Threshold.load(tmp_path / "cli.json")
    detectors = fit_on_episodes(_record(9, 0), DISCRETE, dynamics_updates=50)
    expected = calibrate_on_episodes(detectors, _record(22, 1000), far=0.1)
    assert (made.value, made.detectors_hash) == (expected.value, expected.detectors_hash)
    saved = DetectorSet.load(tmp_path / "cli.json.detectors")
    assert saved.fingerprint("combined") == detectors.fingerprint("combined")
    assert main(argv + ["--mode", "step", "--out", str(tmp_path / "step.json")]) == 0
    assert Threshold.load(tmp_path / "step.json").mode == "step" and ", step mode, " in capsys.readouterr().out
    for extra, words in ((["--task", "cartpole"], "leave out --task"), (["--episodes", "30"], "leave out --episodes"),
                         (["--far", "0.01"], "needs at least 230 ID calibration episodes")):
        assert main(argv + extra) == 2
        assert words in capsys.readouterr().err
    assert main(["calibrate", "--records", str(fit), "--out", str(tmp_path / "x.json")]) == 2
    assert "goes with --calibration-records" in capsys.readouterr().err
    assert main(["calibrate", "--task", "cartpole", "--method", "ensemble", "--action-space", "box:1",
                 "--out", str(tmp_path / "x.json")]) == 2
    assert "go with --records" in capsys.readouterr().err and not (tmp_path / "x.json").exists()


def test_a_record_without_episodes_is_calibrated_by_step():
    """Step mode: the threshold bounds the share of steps above it, each stretch a cluster; of
    fresh stretches, validation counts steps with their clustered interval. When written: 29 of
    the 4,000 fresh steps above it (0.7%, interval 0.0-4.4%, design effect 29; target 10%)."""
    detectors = fit_on_episodes(_record(9, 0), DISCRETE, dynamics_updates=100)
    threshold = calibrate_on_episodes(detectors, _record(22, 1000), far=0.1, mode="step")
    assert (threshold.mode, threshold.n_episodes) == ("step", 22)
    validation = validate_on_episodes(threshold, _record(20, 90_000), detectors=detectors)
    assert validation.total == 20 * STEPS and validation.design_effect is not None
    assert validation.alarmed / validation.total <= 0.15 and validation.verdict != "above"
    with pytest.raises(InvalidParameterError, match="mode='stretch' is not allowed"):
        calibrate_on_episodes(detectors, _record(22, 1000), far=0.1, mode="stretch")


def test_records_are_written_whole_and_odd_paths_are_refused(tmp_path):
    """save_records writes beside the file and moves it in (a kill mid-write leaves the file before,
    no part); a folder, an empty name, /dev/zero and a number are refused by name (scripts/fuzz_api.py
    found the first three as Python's errors)."""
    from oodmon.monitor import load_records, save_records

    path = save_records(tmp_path / "r.npz", _record(2, 0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.npz"] and len(load_records(path)) == 2
    (tmp_path / "folder").mkdir()
    for bad, words in ((tmp_path / "folder", "is a folder"), ("", "is a folder"), ("/dev/zero", "dev/zero"),
                       (5, "got int")):
        with pytest.raises(ConfigError, match=words):
            save_records(bad, _record(1, 0))
    for bad, words in ((tmp_path / "folder", "is a folder"), ("/dev/zero", "not a file of recorded episodes"),
                       (5, "got int")):
        with pytest.raises(ConfigError, match=words):
            load_records(bad)


def test_the_script_compares_calibrations(monkeypatch, capsys):
    """scripts/recorded_deployment.py --calibrations: each threshold's share of the fresh episodes
    it alarms is read off the episodes' statistics, which alarm exactly where the monitor does."""
    detectors = fit_on_episodes(_record(6, 0), DISCRETE, dynamics_updates=50)
    threshold = calibrate_on_episodes(detectors, _record(22, 1000), far=0.1)
    sink = MemorySink()
    # a longer pole from step 20 in half of them: some alarm
    episodes = [*_record(4, 40_000), *_record(4, 41_000, "cartpole:length=2.0", 20)]
    firsts = _SCRIPT.watched(_SCRIPT.monitor_of(threshold, detectors, sink), episodes, sink)
    statistics = _SCRIPT.statistics(sink, threshold)
    assert len(statistics) == 8 and list(statistics > threshold.value) == [first is not None for first in firsts]
    assert any(statistics > threshold.value) and not all(statistics > threshold.value)  # (both kinds compared)
    monkeypatch.setattr("sys.argv", ["recorded_deployment.py", "--fit", "6", "--calibration", "22", "--fresh", "6",
                                     "--shifted", "1", "--steps", "60", "--far", "0.1", "--calibrations", "2",
                                     "--variants", "cartpole:length=2.0"])
    monkeypatch.setattr(_SCRIPT, "limit_threads", lambda: None)
    _SCRIPT.main()
    line = capsys.readouterr().out.splitlines()[2]
    assert re.fullmatch(r"2 calibrations of 22 episodes each: thresholds \S+-\S+; their false-alarm rates on the 6 "
                        r"fresh episodes \S+%-\S+% \(median \S+%\); [012] of 2 above the target 0.1 .*", line), line


def _named_sensors(episodes):
    """CartPole's records as a robot's named sensors: the cart's two readings, the pole's two."""
    return [({"pole_speed": o[:, 3], "cart": o[:, :2], "pole_angle": o[:, 2]}, a) for o, a in episodes]


def test_named_sensors_are_flattened_by_their_keys(tmp_path):
    """Dict observations ({key: (T, ...)}) are fitted flattened in their keys' sorted order, which
    here is CartPole's own: the same detectors and threshold as of the arrays. The monitor
    flattens each step's dict alike (the same scores), names the readings by the keys, and refuses
    a dict of other keys, or an array where it was fitted on dicts; records of dicts are not
    saved (they are kept as arrays)."""
    from oodmon.monitor import save_records

    fit, calibration = _record(6, 0), _record(22, 1000)
    arrays = fit_on_episodes(fit, DISCRETE, dynamics_updates=50)
    dicts = fit_on_episodes(_named_sensors(fit), DISCRETE, dynamics_updates=50)
    assert dicts.fitted_for["observation_layout"] == [["cart", [2]], ["pole_angle", []], ["pole_speed", []]]
    assert dicts.fingerprint("combined") == arrays.fingerprint("combined")
    threshold = calibrate_on_episodes(dicts, _named_sensors(calibration), far=0.1)
    assert threshold.value == calibrate_on_episodes(arrays, calibration, far=0.1).value
    assert threshold.reading_names == ["cart[0]", "cart[1]", "pole_angle", "pole_speed"]
    (observations, actions), = _record(1, 9000, "cartpole:length=2.0", 50)
    scores = {}
    for kind, detectors in (("arrays", arrays), ("dicts", dicts)):
        with Monitor(None, threshold if kind == "dicts" else threshold.value, detectors=detectors) as monitor:
            monitor.begin_episode()
            scores[kind] = []
            for step, action in enumerate(actions.tolist()):
                obs = observations[step] if kind == "arrays" else {
                    "cart": observations[step, :2], "pole_angle": observations[step, 2],
                    "pole_speed": observations[step, 3]}
                monitor.step(obs, action=action)
                scores[kind].append(monitor.last_step.score)
    assert scores["dicts"] == scores["arrays"]
    with Monitor(None, threshold, detectors=dicts) as monitor:
        monitor.begin_episode()
        with pytest.raises(ConfigError, match="keys are .'cart', 'pole_angle'.; the detectors were fitted on dicts of"):
            monitor.step({"cart": np.zeros(2), "pole_angle": 0.0}, action=0)
    with pytest.raises(ConfigError, match="episode 0 of episodes: its observations are no dict, and the detectors "
                                          "were fitted on dicts of named readings"):
        validate_on_episodes(threshold, _record(1, 9100), detectors=dicts)
    with pytest.raises(ConfigError, match="its observations are a dict of named readings; records are kept as arrays"):
        save_records(tmp_path / "r.npz", _named_sensors(fit))
    with pytest.raises(ConfigError, match="its observations are a dict, and the detectors were fitted on arrays"):
        validate_on_episodes(calibrate_on_episodes(arrays, calibration, far=0.1), _named_sensors(_record(1, 9100)),
                             detectors=arrays)
