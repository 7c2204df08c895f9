"""What the agent sees: the paper's OOD variants of CartPole, Pendulum and Pong.

``import oodmon`` registers ``oodmon/CartPole-v1``, ``oodmon/Pendulum-v1`` and
``oodmon/Pong-v5`` with gymnasium. Physics shifts and frame corruptions take an
``onset_step`` so that a shift can begin mid-episode; ``info["shifted"]`` marks it.
Your own env is shifted by :class:`ShiftAttributes` (other numbers in its attributes, from an
onset on), named by a spec such as ``Acrobot-v1:LINK_MASS_2=3.0`` (:func:`parse_env_shift`), or
deployed as another registered env (:class:`AnotherEnv`: each of its steps shifted);
:func:`probe_shift` tells whether such a shift changes anything the env returns.
"""

from __future__ import annotations

from oodmon.envs.corruptions import (
    CORRUPTIONS,
    Corruption,
    GaussianNoise,
    ImpulseNoise,
    MotionBlur,
    Pixelate,
    make_corruption,
    severity_params,
)
from oodmon.envs.grid import ENV_IDS, TASKS, Variant, paper_grid, parse_variant
from oodmon.envs.physics import CARTPOLE_DEFAULTS, PENDULUM_DEFAULTS, ShiftedCartPole, ShiftedPendulum
from oodmon.envs.pong import CorruptedPong, to_agent_view
from oodmon.envs.probe import ShiftProbe, probe_shift
from oodmon.envs.registration import register_envs
from oodmon.envs.sensor_faults import DictSensorFaults, SensorFaults
from oodmon.envs.shift import (AnotherEnv, EnvShift, ShiftAttributes, own_variant, parse_any_variant,
                               parse_env_shift)

__all__ = [
    "CARTPOLE_DEFAULTS",
    "CORRUPTIONS",
    "ENV_IDS",
    "PENDULUM_DEFAULTS",
    "TASKS",
    "AnotherEnv",
    "CorruptedPong",
    "Corruption",
    "DictSensorFaults",
    "EnvShift",
    "GaussianNoise",
    "ImpulseNoise",
    "MotionBlur",
    "Pixelate",
    "SensorFaults",
    "ShiftAttributes",
    "ShiftProbe",
    "ShiftedCartPole",
    "ShiftedPendulum",
    "Variant",
    "make_corruption",
    "own_variant",
    "paper_grid",
    "parse_any_variant",
    "parse_env_shift",
    "parse_variant",
    "probe_shift",
    "register_envs",
    "severity_params",
    "to_agent_view",
]

register_envs()
