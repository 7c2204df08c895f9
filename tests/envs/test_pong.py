"""OOD-Pong: the corruption reaches what the agent sees, from the onset on, reproducibly."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import oodmon  # noqa: F401  (registers the envs)
from oodmon.envs import CorruptedPong, GaussianNoise, paper_grid, parse_variant, to_agent_view
from oodmon.errors import InvalidParameterError, UnknownParameterError

SAMPLE = ["pong", "pong:gaussian_noise@5", "pong:impulse_noise@1", "pong:motion_blur@3", "pong:pixelate@4"]


def _play(env: gymnasium.Env, seed: int, steps: int) -> tuple[list[np.ndarray], list[dict]]:
    actions = np.random.default_rng(123)
    obs, info = env.reset(seed=seed)
    observations, infos = [obs], [info]
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(int(actions.integers(6)))
        observations.append(obs)
        infos.append(info)
        assert not (terminated or truncated)
    return observations, infos


@pytest.mark.parametrize("spec", SAMPLE)
def test_a_sample_of_pong_variants_passes_the_env_checker(spec):
    env = parse_variant(spec).make()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    assert env.observation_space.shape == (4, 84, 84) and env.observation_space.dtype == np.uint8
    assert env.action_space.n == 6


def test_the_grid_has_twenty_pong_variants_that_all_make():
    grid = paper_grid("pong")
    assert len(grid) == 20
    for variant in grid:
        env = variant.make()
        assert env.unwrapped.corruption.name == variant.corruption
        env.close()


@pytest.mark.parametrize("spec", SAMPLE[1:])
def test_corruption_reaches_the_observation_but_not_the_game(spec):
    clean_obs, _ = _play(parse_variant("pong").make(), seed=5, steps=30)
    env = parse_variant(spec).make()
    corrupt_obs, infos = _play(env, seed=5, steps=30)
    assert all(info["shifted"] for info in infos)
    assert all(np.abs(c.astype(int) - o).mean() > 0.05 for c, o in zip(clean_obs, corrupt_obs))
    # The game itself is untouched: the clean camera frame is the ID env's frame.
    id_env = parse_variant("pong").make()
    _play(id_env, seed=5, steps=30)
    np.testing.assert_array_equal(env.unwrapped.last_clean_frame, id_env.unwrapped.last_observed_frame)
    assert not np.array_equal(env.unwrapped.last_observed_frame, env.unwrapped.last_clean_frame)


def test_observation_is_the_preprocessed_corrupted_camera_frame():
    env = CorruptedPong(corruption=GaussianNoise(0.3))
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(0)
    # The newest frame of the stack is the agent's view of the corrupted frame (max-pooled with
    # the frame before it, so at least as bright).
    single = to_agent_view([env.last_observed_frame])
    assert np.all(obs[-1].astype(int) >= single.astype(int) - 1)
    # Noise roughens the frame: neighbouring pixels differ far more than in the clean view.
    def roughness(image):
        return np.abs(np.diff(image.astype(int), axis=1)).mean()

    assert roughness(obs[-1]) > 3 * roughness(to_agent_view([env.last_clean_frame]))


def test_same_seed_same_frames_other_seed_other_noise():
    first, _ = _play(parse_variant("pong:gaussian_noise@2").make(), seed=11, steps=10)
    again, _ = _play(parse_variant("pong:gaussian_noise@2").make(), seed=11, steps=10)
    other, _ = _play(parse_variant("pong:gaussian_noise@2").make(), seed=12, steps=10)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert all(not np.array_equal(a, c) for a, c in zip(first, other))


def test_an_env_that_played_other_episodes_plays_a_seed_as_a_new_one_without_loading_the_rom_again(monkeypatch):
    """A seeded reset of the paper's Pong (no sticky actions) reloaded the ROM to seed the emulator's
    generator, 90 ms a reset, though that generator only draws sticky actions; with them it still does."""
    fresh, _ = _play(parse_variant("pong:gaussian_noise@2").make(), seed=11, steps=40)
    used = parse_variant("pong:gaussian_noise@2").make()
    loads = []
    monkeypatch.setattr(used.unwrapped._atari, "load_game", lambda: loads.append(1))
    for seed in (3, 4):  # other episodes first, cut mid-game
        _play(used, seed=seed, steps=60)
    again, _ = _play(used, seed=11, steps=40)
    assert loads == []
    for a, b in zip(fresh, again, strict=True):
        np.testing.assert_array_equal(a, b)
    sticky = CorruptedPong(repeat_action_probability=0.25).unwrapped
    monkeypatch.setattr(sticky._atari, "load_game", lambda: loads.append(1))
    sticky.reset(seed=11)
    assert loads == [1]


def test_onset_mid_episode_corrupts_from_that_step_on():
    onset = 8
    clean, _ = _play(parse_variant("pong").make(), seed=2, steps=15)
    shifted, infos = _play(parse_variant("pong:impulse_noise@5").make(onset_step=onset), seed=2, steps=15)
    flags = [info["shifted"] for info in infos]  # infos[0] is reset's
    assert flags == [False] * (onset + 1) + [True] * (15 - onset)
    for k in range(onset + 1):
        np.testing.assert_array_equal(shifted[k], clean[k])
    for k in range(onset + 1, 16):
        # The newest frame is corrupted; older frames in the stack stay as they were seen.
        assert not np.array_equal(shifted[k][-1], clean[k][-1])
    np.testing.assert_array_equal(shifted[onset + 1][:-1], clean[onset + 1][:-1])


def test_explicit_parameters_and_objects_make_the_same_env():
    by_severity = gymnasium.make("oodmon/Pong-v5", corruption="motion_blur", severity=3)
    by_params = gymnasium.make("oodmon/Pong-v5", corruption="motion_blur", radius=15, sigma=8)
    assert by_severity.unwrapped.corruption == by_params.unwrapped.corruption


def test_render_returns_the_raw_observed_frame():
    env = gymnasium.make("oodmon/Pong-v5", corruption="pixelate", severity=5, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (210, 160, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, env.unwrapped.last_observed_frame)


@pytest.mark.parametrize(
    "kwargs, error, words",
    [
        ({"corruption": "fog", "severity": 1}, UnknownParameterError, "unknown corruption 'fog'; choose one of"),
        ({"corruption": "pixelate", "severity": 7}, InvalidParameterError,
         "severity=7 is not allowed; severity must be an integer from 1 to 5"),
        ({"severity": 3}, InvalidParameterError, "severity and corruption parameters need a corruption"),
        ({"corruption": "pixelate", "sigma": 0.2}, UnknownParameterError, "pixelate has no parameter 'sigma'"),
        ({"corruption": GaussianNoise(0.1), "severity": 2}, InvalidParameterError,
         "a Corruption object carries its own parameters"),
        ({"onset_step": -3}, InvalidParameterError, "onset_step=-3 is not allowed"),
        ({"render_mode": "ansi"}, InvalidParameterError, "render_mode='ansi' is not allowed"),
    ],
)
@pytest.mark.filterwarnings("ignore:.*not in the possible render_modes")
def test_bad_pong_input_is_named(kwargs, error, words):
    with pytest.raises(error) as raised:
        gymnasium.make("oodmon/Pong-v5", **kwargs)
    assert words in str(raised.value)


def test_reset_option_sets_the_onset_of_that_episode_only():
    env = parse_variant("pong:impulse_noise@5").make(onset_step=50)
    flags = []
    for options in ({"onset_step": 1}, None):
        _, info = env.reset(seed=2, options=options)
        shifted = [info["shifted"]]
        for _ in range(3):
            *_, info = env.step(0)
            shifted.append(info["shifted"])
        flags.append(shifted)
    assert flags == [[False, False, True, True], [False] * 4]


def test_a_frozen_region_variant_holds_that_part_of_the_camera_from_the_onset_and_the_rest_moves():
    """``pong:frozen_region:...`` (not the paper's): the left third of the raw frames held from
    step 30 (the opponent's paddle there keeps moving on the camera), each new episode its own."""
    from oodmon.envs import parse_variant

    env = parse_variant("pong:frozen_region:top=0,left=0,height=210,width=53").make(onset_step=30)
    held_by_episode = []
    for seed in (0, 1):
        env.reset(seed=seed)
        raw, seen = [], []
        for _ in range(80):
            env.step(2)
            raw.append(env.unwrapped.last_clean_frame.copy())
            seen.append(env.unwrapped.last_observed_frame.copy())
        raw, seen = np.array(raw), np.array(seen)
        assert np.array_equal(seen[:30], raw[:30])  # untouched before the onset
        held = seen[30, :, :53]
        assert (seen[30:, :, :53] == held).all() and not (raw[30:, :, :53] == raw[30, :, :53]).all()
        assert np.array_equal(seen[30:, :, 53:], raw[30:, :, 53:])  # the rest is live
        held_by_episode.append(held)
    env.close()
    assert not np.array_equal(*held_by_episode)  # another episode, another frame held


def test_the_preview_of_a_frozen_region_outlines_where_it_is_and_leaves_the_frames_as_they_are():
    """One frame cannot show a freeze: `oodmon envs show 'pong:frozen_region:...'` showed two
    identical pictures. The corrupted camera's picture now outlines the region, one pixel wide."""
    from oodmon.envs.preview import OUTLINE, outline_region, pong_preview

    frame = np.zeros((210, 160, 3), np.uint8)
    outlined = outline_region(frame, top=80, left=50, height=70, width=60)
    drawn = np.all(outlined == OUTLINE, axis=-1)
    rows, columns = np.nonzero(drawn)
    assert (rows.min(), rows.max(), columns.min(), columns.max()) == (80, 149, 50, 109)  # its border rows and columns
    assert not drawn[81:149, 51:109].any() and drawn.sum() == 2 * 70 + 2 * 60 - 4  # the border only
    assert not frame.any()  # a copy
    picture = pong_preview(parse_variant("pong:frozen_region:top=80,left=50,height=70,width=60"), steps=5)
    raw_rows = slice(22, 22 + 420)  # the top row's frames, 2x, under their labels
    clean, corrupted = picture[raw_rows, :320], picture[raw_rows, 320:]
    assert not np.all(clean == OUTLINE, axis=-1).any()
    assert np.nonzero(np.all(corrupted == OUTLINE, axis=-1))[0].min() == 160  # the region's top row, 80, at 2x
    other = pong_preview(parse_variant("pong:pixelate@3"), steps=5)[raw_rows, 320:]
    assert not np.all(other == OUTLINE, axis=-1).any()  # only a frozen region is outlined
