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


def test_space_mismatch_compares_dict_spaces_key_by_key():
    from types import SimpleNamespace

    from gymnasium.spaces import Box, Dict, Discrete

    from oodmon.envs.checks import space_mismatch

    def holder(**spaces):
        return SimpleNamespace(observation_space=Dict(spaces), action_space=Discrete(2))

    ours = holder(a=Box(-1, 1, (2,)), b=Discrete(3))
    assert space_mismatch(ours, holder(a=Box(-5, 5, (2,)), b=Discrete(3))) is None  # bounds may differ
    assert space_mismatch(ours, holder(a=Box(-1, 1, (6,)), b=Discrete(3))) == "observation_space"  # a key's shape
    assert space_mismatch(ours, holder(a=Box(-1, 1, (2,)), b=Discrete(4))) == "observation_space"  # a key's n
    assert space_mismatch(ours, holder(a=Box(-1, 1, (2,)), c=Discrete(3))) == "observation_space"  # other keys
