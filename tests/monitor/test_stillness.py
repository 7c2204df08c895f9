"""The stillness detector: how long a sensor has gone unchanged, against its longest ID run."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from oodmon.envs import Variant, parse_variant
from oodmon.envs.shift import ShiftAttributes
from oodmon.errors import ConfigError
from oodmon.monitor.detectors import DetectorSet, StepContext, StillnessDetector, Trajectory, collect, fit_detectors
from oodmon.monitor.detectors.combined import UNIT_MEMBERS
from tests.helpers import RandomButtons, scores_along

SHORT_PONG = "PongShortForStillness-v0"  # Pong's games cut at 150 decisions: a calibration in seconds


@pytest.fixture(scope="module")
def pong():
    """Fitted on 5 ID games of Pong's first 300 decisions."""
    return StillnessDetector().fit(collect(RandomButtons(), Variant("pong").make(), 5, seed=600_000, max_steps=300))


def test_a_frozen_camera_passes_the_id_record_and_counts_each_step_past_it(pong):
    """The camera freezes at step 50: from then on the newest frame is the one before, its run one
    step longer at each step. The longest ID run was 4 steps when written (0-4 per game)."""
    assert pong.pictures and pong.longest.shape == (1,)
    record = int(pong.longest[0])
    assert 1 <= record <= 10
    frozen = collect(RandomButtons(1), parse_variant("pong:obs.stuck=1").make(onset_step=50), 1, seed=600_100,
                     max_steps=120)[0]
    scores = scores_along(pong, frozen)
    assert scores[51:] == [k - record for k in range(1, len(scores) - 50)]  # step 50 the first frozen
    assert scores[50 + record + 1] == 1.0  # one step past the record: longer than in any fitting episode
    # Fresh games stand still longer than the 5 fitted ones did (6 steps past the record at most
    # when written), not for ever: a camera frozen three times the record and more lies above them.
    games = collect(RandomButtons(2), Variant("pong").make(), 5, seed=600_200, max_steps=300)
    fresh = [max(scores_along(pong, t)) for t in games]
    assert max(fresh) < scores[50 + 3 * (record + 1)] == 2 * record + 3


def test_a_stuck_reading_of_a_vector_counts_steps_since_each_reading_always_moves():
    """CartPole's readings change at every step: each one's record is 0, and a stuck angular
    velocity scores 1, 2, 3, ... from its first stuck step."""
    controller = lambda obs: int(obs[2] + obs[3] > 0)  # noqa: E731 (a hand-made balance)
    detector = StillnessDetector().fit(collect(controller, Variant("cartpole").make(), 3, seed=0))
    assert not detector.pictures and detector.longest.tolist() == [0, 0, 0, 0]
    stuck = collect(controller, parse_variant("cartpole:obs.stuck[3]=1").make(onset_step=30), 1, seed=10)[0]
    scores = scores_along(detector, stuck)
    assert scores[:31] == [0.0] * 31 and scores[31:36] == [1.0, 2.0, 3.0, 4.0, 5.0]  # step 30 the first stuck
    with pytest.raises(ConfigError, match="fitted on 4 readings; this observation holds 3"):
        detector.score(StepContext(np.zeros(3), 0))


def test_it_saves_and_loads_as_tensors_and_json_with_the_samescores_along(pong, tmp_path):
    DetectorSet([pong]).save(tmp_path)
    loaded = DetectorSet.load(tmp_path)["stillness"]
    assert loaded.fingerprint() == pong.fingerprint() and loaded.pictures
    frozen = collect(RandomButtons(3), parse_variant("pong:obs.stuck=1").make(onset_step=10), 1, seed=0, max_steps=40)[0]
    assert scores_along(loaded, frozen) == scores_along(pong, frozen)


@pytest.mark.parametrize("tensors, config, match", [
    ({}, {}, "no 'longest'"),
    ({"longest": np.array([-1, 2])}, {}, "whole numbers >= 0"),
    ({"longest": np.zeros((2, 2), np.int64)}, {}, "shape \\(2, 2\\)"),
    ({"longest": np.array([1, 2])}, {"pictures": True}, "one for a picture"),
])
def test_a_hand_made_file_of_bad_records_is_refused(tensors, config, match):
    with pytest.raises(ConfigError, match=match):
        StillnessDetector.from_state(config, tensors)


def test_episodes_too_short_to_stand_still_are_refused():
    with pytest.raises(ConfigError, match="two steps or more"):
        StillnessDetector().fit([Trajectory(np.zeros((1, 4)), np.zeros(0))])


def test_pictures_fit_it_by_default_and_combined_counts_its_excess_in_steps():
    """A picture's default set has stillness beside frames; combined ranks it, its excess in steps
    (UNIT_MEMBERS), not in its ID scores' standard deviation (nearly all of them are the same)."""
    fitted = fit_detectors(RandomButtons(), Variant("pong").make(), episodes=3, max_steps=60)
    assert fitted.names == ["frames", "stillness", "combined"]
    combined = fitted["combined"]
    assert combined.members == ["frames", "stillness"] and combined.config()["scale"]["stillness"] == UNIT_MEMBERS[
        "stillness"] == 1.0
    top = combined.rank("stillness", 10.0)  # 10 steps past the record
    assert top - combined.rank("stillness", 2.0) == pytest.approx(8.0)  # one rank a step past the held-out ones


@pytest.fixture(scope="module")
def short_pong():
    if SHORT_PONG not in gymnasium.registry:
        gymnasium.register(SHORT_PONG, entry_point="oodmon.envs.pong:CorruptedPong", max_episode_steps=150)
    return SHORT_PONG


def test_the_monitor_of_a_camera_policy_alarms_a_frozen_camera_soon_after_it_freezes(short_pong):
    """Any policy of pictures (here a random one, in an env oodmon has no variants of): `watch`
    fits frames, stillness and combined, calibrates combined, and a camera frozen from step 50
    alarms within a few steps of passing the ID record. When written (9 fitting and 40
    calibration games of 150 decisions, about 6 s; the record 3 steps): 9 frozen games alarmed at
    step 54, the other at step 4, before it froze; none of 10 fresh ID games. The promise is 10%
    of ID games on average over calibrations (confidence none): of these 20 games played ID until
    step 50 or on, 5 or more alarmed there would have probability 0.04 at 10%."""
    from oodmon import watch

    monitor = watch(RandomButtons(), short_pong, fit_episodes=9, episodes=40, far=0.1, confidence=None)
    assert monitor.detectors.names == ["frames", "stillness", "combined"] and monitor.detector == "combined"
    fresh = [monitor.run_episode(gymnasium.make(short_pong), seed=10_000 + k) for k in range(10)]
    frozen = [monitor.run_episode(ShiftAttributes(gymnasium.make(short_pong), {"obs.stuck": 1}, onset_step=50),
                                  seed=20_000 + k) for k in range(10)]
    early = [r for r in frozen if r.first_alarm_step is not None and r.first_alarm_step <= 50]
    assert sum(r.alarms > 0 for r in fresh) + len(early) <= 4
    record = int(monitor.detectors["stillness"].longest[0])
    late = [r.first_alarm_step for r in frozen if r not in early]  # each of these alarmed after it froze:
    assert all(step is not None and 50 < step <= 50 + record + 3 for step in late)  # within 3 steps past the record


def test_pongs_combined_leaves_the_spread_and_features_out():
    """Pong's shipped agents: their spread and features, weak at every step there, only raised the
    combined threshold (COMBINED_LEAVES_OUT); both are still fitted and scored, outside combined.
    Pong's set holds vanishing too (DEFAULT_ADDS), an env oodmon has no variants of does not."""
    from oodmon.agents import load

    agent = load("pong", "dropconnect")
    fitted = fit_detectors(agent, agent.make_env(), episodes=3, max_steps=20)
    assert fitted.names == ["spread", "features", "frames", "stillness", "vanishing", "combined"]
    assert fitted["combined"].members == ["frames", "stillness", "vanishing"]
    elsewhere = fit_detectors(agent, agent.make_env(), episodes=3, max_steps=20, task="Pong-like")  # not measured
    assert elsewhere["combined"].members == ["spread", "features", "frames", "stillness"]
