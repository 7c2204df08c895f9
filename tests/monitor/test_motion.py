"""The motion detector: the parts of the picture that move less than they did after the same actions in ID episodes."""

from __future__ import annotations

import numpy as np
import pytest

from oodmon.envs import Variant, parse_variant
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.detectors import DetectorSet, MotionDetector, StepContext, Trajectory, collect, fit_detectors
from tests.helpers import RandomButtons, scores_along


def _lights(actions: np.ndarray, rng: np.random.Generator, *, stuck_from: int | None = None) -> Trajectory:
    """8x8 pictures of two 4x8 halves: the top one changes after action 1 and stays after action 0,
    the bottom one changes at every step; from ``stuck_from`` the top one stays whatever the action."""
    frames = [np.zeros((8, 8), np.uint8)]
    for step, action in enumerate(actions):
        frame = frames[-1].copy()
        if action == 1 and (stuck_from is None or step < stuck_from):
            frame[:4] = rng.integers(1, 255, (4, 8))
        frame[4:] = (frame[4:].astype(np.int64) + 1) % 256
        frames.append(frame)
    return Trajectory(np.array(frames), np.asarray(actions, np.int64))


def test_rates_are_per_action_and_a_part_that_stops_answering_its_action_grows_surprising():
    rng = np.random.default_rng(0)
    fit = [_lights(rng.integers(0, 2, 300), rng) for _ in range(3)]
    detector = MotionDetector(grid=2).fit(fit)
    # (actions + 1 rows) x 4 tiles, rows 0 and 1 the actions', the last one after any action.
    assert detector.rates.shape == (3, 4)
    top_after_0, top_after_1, bottom = detector.rates[0, :2], detector.rates[1, :2], detector.rates[:, 2:]
    assert (top_after_0 == 1e-3).all() and (top_after_1 == 1 - 1e-3).all() and (bottom == 1 - 1e-3).all()
    assert 0.4 < detector.rates[2, 0] < 0.6  # after any action: half the steps
    # Action 0 only: the top half stands still as it always did after 0, a surprise of
    # -log(0.999) a step for each of its two tiles; the bottom half moves.
    quiet = scores_along(detector, _lights(np.zeros(60, np.int64), rng))
    assert quiet[59] == pytest.approx(59 * 2 * -np.log(0.999), rel=1e-9) and quiet[59] < 0.2
    # Action 1 only, the top half stuck from step 30 on: -log(0.001) a step for each of its tiles.
    scores = scores_along(detector, _lights(np.ones(60, np.int64), rng, stuck_from=30))
    assert scores[:31] == [0.0] * 31
    assert scores[31:] == pytest.approx([n * 2 * -np.log(0.001) for n in range(1, 30)], rel=1e-9)
    # An action the fitting episodes never took (2) reads the rates after any action.
    detector.reset()
    detector.score(StepContext(np.zeros((8, 8), np.uint8), 0))
    assert detector.score(StepContext(np.zeros((8, 8), np.uint8), 0, prev_action=2)) == pytest.approx(
        -np.log1p(-detector.rates[2]).sum(), rel=1e-12)


@pytest.fixture(scope="module")
def pong():
    """Fitted on 6 ID games of Pong's first 300 decisions of a random policy."""
    return MotionDetector().fit(collect(RandomButtons(), Variant("pong").make(), 6, seed=610_000, max_steps=300))


def test_part_of_pong_frozen_is_short_of_changes_beyond_every_fresh_id_game(pong):
    """The right third of the raw frames (the player's paddle, which a random policy moves at most
    steps) held from step 100 (``pong:frozen_region``, ``scripts/frozen_region.py``'s agent side). When written: 6 fresh ID
    games peaked at 107-198, the frozen games at 82-89 before the freeze, passed the fresh games'
    highest 56-82 steps after it and went on to 472-507."""
    games = collect(RandomButtons(1), Variant("pong").make(), 6, seed=610_100, max_steps=300)
    fresh = [max(scores_along(pong, t)) for t in games]
    frozen = []
    for seed in (610_200, 610_201, 610_202):
        env = parse_variant("pong:frozen_region:top=0,left=107,height=210,width=53").make(onset_step=100)
        frozen.append(scores_along(pong, collect(RandomButtons(seed), env, 1, seed=seed, max_steps=300)[0]))
    ceiling = max(fresh)
    for scores in frozen:
        assert max(scores[:100]) <= ceiling  # before the freeze: an ID game's
        after = np.array(scores[100:])
        assert (after > ceiling).any() and np.argmax(after > ceiling) <= 120 and after.max() > 2 * ceiling


def test_it_saves_and_loads_as_tensors_and_json_with_the_samescores_along(pong, tmp_path):
    DetectorSet([pong]).save(tmp_path)
    loaded = DetectorSet.load(tmp_path)["motion"]
    assert loaded.fingerprint() == pong.fingerprint() and loaded.config() == pong.config()
    game = collect(RandomButtons(3), Variant("pong").make(), 1, seed=0, max_steps=80)[0]
    assert scores_along(loaded, game) == scores_along(pong, game)


@pytest.mark.parametrize("tensors, match", [
    ({}, "no 'rates'"),
    ({"rates": np.full((2, 4), 0.5)}, "16 tiles each"),
    ({"rates": np.full((2, 16), 1.5)}, "rates in \\[0, 1\\]"),
    ({"rates": np.full(16, 0.5)}, "shape \\(16,\\)"),
])
def test_damaged_tensors_are_refused(tensors, match):
    with pytest.raises(ConfigError, match=match):
        MotionDetector.from_state({}, tensors)


def test_bad_settings_vectors_and_short_episodes_are_refused():
    with pytest.raises(InvalidParameterError, match="grid=0"):
        MotionDetector(grid=0)
    with pytest.raises(ConfigError, match="episodes of two steps or more"):
        MotionDetector().fit([Trajectory(np.zeros((1, 84, 84), np.uint8), np.zeros(0, np.int64))])
    rng = np.random.default_rng(0)
    small = _lights(rng.integers(0, 2, 20), rng)  # 8 x 8 pictures: 4 x 4 tiles fit, 9 x 9 would read rows twice
    assert MotionDetector(grid=8).fit([small]).rates.shape == (3, 64)
    with pytest.raises(ConfigError, match="9 x 9 tiles need pictures.* of at least 9 pixels a side; .* shape \\(8, 8\\)"):
        MotionDetector(grid=9).fit([small])
    detector = MotionDetector(grid=4).fit([small])
    with pytest.raises(ConfigError, match="4 x 4 tiles need pictures.* shape \\(3, 8\\)"):
        detector.score(StepContext(np.zeros((3, 8), np.uint8), 0))   # refused at an episode's first picture
    controller = lambda obs: int(obs[2] + obs[3] > 0)  # noqa: E731 (CartPole: a vector, no picture)
    with pytest.raises(ConfigError, match="the motion detector needs image observations"):
        fit_detectors(controller, Variant("cartpole").make(), detectors=["motion"], episodes=3)


def test_named_it_joins_the_default_set_and_combined_ranks_it():
    """``--detector motion`` (fitted_when_named) fits a picture's default set, motion and a combined
    that ranks motion beside frames and stillness; unnamed it is not fitted."""
    from oodmon.monitor.detectors.fitting import fitted_when_named

    fitted = fit_detectors(RandomButtons(), Variant("pong").make(), detectors=fitted_when_named("motion"), episodes=3,
                           max_steps=60)
    assert fitted.names == ["frames", "stillness", "motion", "combined"]
    assert fitted["combined"].members == ["frames", "stillness", "motion"]
    assert "motion" not in fit_detectors(RandomButtons(), Variant("pong").make(), episodes=3, max_steps=20).names
