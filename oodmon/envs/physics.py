"""OOD-CartPole and OOD-Pendulum: the standard classic-control envs with other physics.

A variant is the default env with other numbers (the paper's Table 1). The shift may begin
mid-episode: with ``onset_step=N`` the first N ``step()`` calls of every episode run the default
physics and the rest the shifted physics, so one episode holds in-distribution steps and then
OOD steps; ``reset(options={"onset_step": n})`` sets the onset of that episode alone. Every
``info`` (from ``reset`` and ``step``) has ``info["shifted"]``: whether the observation returned
came from the shifted world (always False for the default physics).

Observation and action spaces are those of the default env, so one trained agent acts in every
variant. For Pendulum this is a deliberate choice: ``max_speed`` and ``max_torque`` change where
the physics clips (the angular velocity, the applied torque), not the spaces. A policy trained
on the default env commands torques in [-2, 2]; a smaller ``max_torque`` clips them (a weak
actuator), a larger one changes nothing the policy can reach. A larger ``max_speed`` lets the
observed angular velocity leave the default space's [-8, 8]: that out-of-range reading is part
of the shift a monitor should see.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from gymnasium.envs.classic_control.pendulum import PendulumEnv

from oodmon.envs.checks import check_onset_step, check_physics, episode_onset
from oodmon.errors import InvalidParameterError

__all__ = ["CARTPOLE_DEFAULTS", "CARTPOLE_OBS_SPREAD", "PENDULUM_DEFAULTS", "PENDULUM_OBS_SPREAD", "PHYSICS_DEFAULTS",
           "ShiftedCartPole",
           "ShiftedPendulum"]

#: CartPole's physics parameters and their defaults (gymnasium's CartPole-v1). ``length`` is
#: half the pole's length, in metres; masses in kg; gravity in m/s^2; force_mag in newtons;
#: ``tau`` the time between two decisions, in seconds (a controller that runs slower or faster).
CARTPOLE_DEFAULTS: dict[str, float] = {
    "gravity": 9.8,
    "masscart": 1.0,
    "masspole": 0.1,
    "length": 0.5,
    "force_mag": 10.0,
    "tau": 0.02,
}

#: Pendulum's physics parameters and their defaults (gymnasium's Pendulum-v1): gravity g in
#: m/s^2, mass m in kg, length l in m, max_speed in rad/s, max_torque in N m, ``dt`` the time
#: between two decisions in seconds.
PENDULUM_DEFAULTS: dict[str, float] = {
    "g": 10.0,
    "m": 1.0,
    "l": 1.0,
    "max_speed": 8.0,
    "max_torque": 2.0,
    "dt": 0.05,
}

#: Each task's physics parameters and their defaults: what its variants set (``cartpole:length=2.0``),
#: updating what the env derives from them. Pong has none (its variants corrupt the picture).
PHYSICS_DEFAULTS: dict[str, dict[str, float]] = {"cartpole": CARTPOLE_DEFAULTS, "pendulum": PENDULUM_DEFAULTS}


#: The std of each observation dimension over ID episodes of the shipped ensembles (20 episodes,
#: 10,000 CartPole and 4,000 Pendulum steps): the unit of ``obs_noise``.
CARTPOLE_OBS_SPREAD = (0.17, 0.20, 0.020, 0.20)   # x, x_dot, theta, theta_dot
PENDULUM_OBS_SPREAD = (0.47, 0.28, 1.46)          # cos(theta), sin(theta), theta_dot


def check_obs_noise(env_id: str, obs_noise: object) -> float:
    """``obs_noise`` as a float in [0, 10], or :class:`InvalidParameterError`."""
    if isinstance(obs_noise, bool) or not isinstance(obs_noise, (int, float, np.integer, np.floating)) \
            or not 0.0 <= float(obs_noise) <= 10.0:
        raise InvalidParameterError(
            f"obs_noise={obs_noise!r} is not allowed for {env_id}; it is the sensor noise's std as a fraction of "
            "each observation dimension's ID spread, a number in [0, 10] (0.01: 1%)"
        )
    return float(obs_noise)


class _ShiftPhysics:
    """Switches an env's physics attributes from the defaults to the shifted values at the onset.

    Subclasses set ``ENV_ID`` and ``DEFAULTS`` and may override :meth:`_derive` to recompute
    quantities that the parent env computes once from the parameters.
    """

    ENV_ID: ClassVar[str]
    DEFAULTS: ClassVar[Mapping[str, float]]
    OBS_SPREAD: ClassVar[tuple[float, ...]]

    def __init__(self, *, onset_step: int = 0, obs_noise: float = 0.0, render_mode: str | None = None,
                 **physics: float) -> None:
        super().__init__(render_mode=render_mode)  # the gymnasium env beside this class (CartPoleEnv, PendulumEnv)
        self._init_shift(physics, onset_step, obs_noise)

    def _init_shift(self, physics: Mapping[str, object], onset_step: int, obs_noise: float = 0.0) -> None:
        self.onset_step = self._configured_onset = check_onset_step(self.ENV_ID, onset_step)
        self.obs_noise = check_obs_noise(self.ENV_ID, obs_noise)
        self._noise_std = self.obs_noise * np.asarray(self.OBS_SPREAD, dtype=np.float32)
        self.shifted_physics = check_physics(self.ENV_ID, self.DEFAULTS, physics)
        self._steps = 0
        self._shift_active = False
        self._set_physics(shifted=onset_step == 0)

    def _set_physics(self, shifted: bool) -> None:
        values = self.shifted_physics if shifted else self.DEFAULTS
        for name, value in values.items():
            setattr(self, name, value)
        self._derive()
        self._shift_active = shifted

    @property
    def shifted(self) -> bool:
        """Whether the world differs from the default one now (never, for the ID env)."""
        return self._shift_active and self.shifted_physics != dict(self.DEFAULTS)

    def _derive(self) -> None:
        """Recompute quantities the parent env derives from the physics parameters."""

    def _begin_episode(self, info: dict[str, Any]) -> dict[str, Any]:
        self._steps = 0
        self._set_physics(shifted=self.onset_step == 0)
        info["shifted"] = self.shifted
        return info

    def _begin_step(self) -> None:
        if not self._shift_active and self._steps >= self.onset_step:
            self._set_physics(shifted=True)
        self._steps += 1

    def _sensed(self, obs: np.ndarray) -> np.ndarray:
        """What the sensors report: the state plus Gaussian noise of ``obs_noise`` x the ID spread
        per dimension, drawn from the env's seeded generator (none drawn when ``obs_noise`` is 0,
        so noiseless episodes are those of the standard env)."""
        if self.obs_noise == 0.0:
            return obs
        noise = self.np_random.normal(size=obs.shape).astype(np.float32) * self._noise_std
        return (obs + noise).astype(obs.dtype)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.onset_step, options = episode_onset(self.ENV_ID, self._configured_onset, options)
        obs, info = super().reset(seed=seed, options=options)
        return self._sensed(obs), self._begin_episode(info)

    def step(self, action):
        self._begin_step()
        obs, reward, terminated, truncated, info = super().step(action)
        info["shifted"] = self.shifted
        return self._sensed(obs), reward, terminated, truncated, info


class ShiftedCartPole(_ShiftPhysics, CartPoleEnv):
    """CartPole-v1 with other gravity, masses, pole length, push force or time step.

    Registered as ``oodmon/CartPole-v1`` (500 steps per episode). ``total_mass`` and
    ``polemass_length`` follow the parameters, so every change really changes the dynamics.

    Args:
        gravity: m/s^2, default 9.8.
        masscart: kg, default 1.0.
        masspole: kg, default 0.1.
        length: half the pole's length in m, default 0.5.
        force_mag: the push of each action in N, default 10.0.
        tau: seconds between two decisions (the Euler step), default 0.02.
        onset_step: index of the first ``step()`` of each episode that runs the shifted physics.
        obs_noise: sensor noise: Gaussian, its std this fraction of each observation dimension's
            ID spread (:data:`CARTPOLE_OBS_SPREAD`), in the ID and the shifted world alike. The
            physics is unchanged (termination uses the true state).
        render_mode: as in gymnasium's CartPole.

    Raises:
        UnknownParameterError: a parameter CartPole does not have.
        InvalidParameterError: a value that is not a finite number > 0, a negative onset, or an
            ``obs_noise`` outside [0, 10].

    Example:
        >>> import gymnasium, oodmon
        >>> env = gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=10)
        >>> obs, info = env.reset(seed=0)
        >>> info["shifted"], env.unwrapped.length
        (False, 0.5)
        >>> for i in range(11):  # step indices 0..9 run the default physics, 10 the shifted one
        ...     obs, reward, terminated, truncated, info = env.step(i % 2)
        >>> info["shifted"], env.unwrapped.length
        (True, 2.0)
    """

    ENV_ID = "oodmon/CartPole-v1"
    DEFAULTS = CARTPOLE_DEFAULTS
    OBS_SPREAD = CARTPOLE_OBS_SPREAD

    def _derive(self) -> None:
        self.total_mass = self.masspole + self.masscart
        self.polemass_length = self.masspole * self.length


class ShiftedPendulum(_ShiftPhysics, PendulumEnv):
    """Pendulum-v1 with other gravity, mass, length, speed limit, torque limit or time step.

    Registered as ``oodmon/Pendulum-v1`` (200 steps per episode). The spaces stay those of the
    default env; see the module docstring for what that means for ``max_speed`` and
    ``max_torque``.

    Args:
        g: gravity in m/s^2, default 10.0.
        m: the pole's mass in kg, default 1.0.
        l: the pole's length in m, default 1.0.
        max_speed: the angular velocity's clip in rad/s, default 8.0.
        max_torque: the applied torque's clip in N m, default 2.0.
        dt: seconds between two decisions (the integration step), default 0.05.
        onset_step: index of the first ``step()`` of each episode that runs the shifted physics.
        obs_noise: sensor noise as a fraction of each dimension's ID spread
            (:data:`PENDULUM_OBS_SPREAD`); see :class:`ShiftedCartPole`.
        render_mode: as in gymnasium's Pendulum.

    Raises:
        UnknownParameterError, InvalidParameterError: as :class:`ShiftedCartPole` does.

    Example:
        >>> import gymnasium, oodmon
        >>> env = gymnasium.make("oodmon/Pendulum-v1", g=50)
        >>> obs, info = env.reset(seed=0)
        >>> info["shifted"], env.unwrapped.g, env.action_space.high.tolist()
        (True, 50.0, [2.0])
    """

    ENV_ID = "oodmon/Pendulum-v1"
    DEFAULTS = PENDULUM_DEFAULTS
    OBS_SPREAD = PENDULUM_OBS_SPREAD

