"""Sensor noise (``obs_noise``): a fraction of each dimension's ID spread, seeded, physics untouched."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import oodmon  # noqa: F401
from oodmon.envs.physics import CARTPOLE_OBS_SPREAD, PENDULUM_OBS_SPREAD
from oodmon.errors import InvalidParameterError


@pytest.mark.parametrize("env_id, spread, action", [("oodmon/CartPole-v1", CARTPOLE_OBS_SPREAD, 0),
                                                     ("oodmon/Pendulum-v1", PENDULUM_OBS_SPREAD, np.zeros(1))])
def test_noise_has_the_asked_std_and_leaves_the_physics_alone(env_id, spread, action):
    noisy, clean = gymnasium.make(env_id, obs_noise=0.5), gymnasium.make(env_id)
    differences = []
    for seed in range(40):
        a, _ = noisy.reset(seed=seed)
        b, _ = clean.reset(seed=seed)
        differences.append(a - b)
        for _ in range(4):
            a, *_ = noisy.step(action)
            b, *_ = clean.step(action)
            differences.append(a - b)  # the true states agree: the noise is on the readings only
    std = np.std(differences, axis=0)
    # 200 draws per dimension: the sample std is within 15% of 0.5 x spread with room to spare.
    np.testing.assert_allclose(std, 0.5 * np.asarray(spread), rtol=0.15)


def test_noise_is_seeded_and_zero_noise_is_the_standard_env():
    one, two = gymnasium.make("oodmon/CartPole-v1", obs_noise=0.01), gymnasium.make("oodmon/CartPole-v1", obs_noise=0.01)
    np.testing.assert_array_equal(one.reset(seed=3)[0], two.reset(seed=3)[0])
    np.testing.assert_array_equal(one.step(1)[0], two.step(1)[0])
    standard = gymnasium.make("CartPole-v1")
    np.testing.assert_array_equal(gymnasium.make("oodmon/CartPole-v1", obs_noise=0).reset(seed=3)[0],
                                  standard.reset(seed=3)[0])


@pytest.mark.parametrize("bad", [-0.1, 11.0, float("nan"), "0.1", True])
def test_bad_noise_is_refused(bad):
    with pytest.raises(InvalidParameterError, match="obs_noise"):
        gymnasium.make("oodmon/CartPole-v1", obs_noise=bad)
