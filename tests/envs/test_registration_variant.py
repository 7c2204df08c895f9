"""The variant a monitor records is read from the env itself."""

from __future__ import annotations

import gymnasium

import oodmon  # noqa: F401  (registers the envs)
from oodmon.envs import parse_variant
from oodmon.envs.registration import env_id_of, variant_of_env


def test_the_recorded_variant_is_the_envs_own_spec():
    for spec in ("cartpole", "cartpole:length=2.0", "pendulum:g=12.0", "pong", "pong:motion_blur@3"):
        assert variant_of_env(parse_variant(spec).make()) == spec
    # A corruption made with its own parameters is shifted too: its spec, never the ID task's.
    assert variant_of_env(gymnasium.make("oodmon/Pong-v5", corruption="pixelate", factor=0.4)) == "pong:pixelate:factor=0.4"
    assert variant_of_env(gymnasium.make("CartPole-v1")) == "cartpole"
    acrobot = gymnasium.make("Acrobot-v1")
    assert variant_of_env(acrobot) == env_id_of(acrobot) == "Acrobot-v1"
