"""Hand-written controllers that solve the default CartPole and Pendulum, to exercise variants.

They show what a variant does to a competent policy without a trained agent: ``oodmon envs
show``, the tests of the physics and the demo use them. Their gains were tuned by hand on the
default envs (CartPole: 500 of 500 steps; Pendulum: about -140 per episode) and left alone, so a
variant that breaks them really changes the dynamics.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import gymnasium
import numpy as np

__all__ = ["REFERENCE_CONTROLLERS", "Rollout", "cartpole_controller", "pendulum_controller", "rollout"]


def cartpole_controller(obs: np.ndarray) -> int:
    """Push toward the side the pole falls to: a linear rule on cart velocity and pole angle.

    Example:
        >>> cartpole_controller(np.array([0.0, 0.0, 0.05, 0.0]))
        1
    """
    _, x_dot, theta, theta_dot = (float(v) for v in obs)
    return int(0.5 * x_dot + 10.0 * theta + 1.0 * theta_dot > 0)


def pendulum_controller(obs: np.ndarray) -> np.ndarray:
    """Energy-shaping swing-up, then a PD controller near the top (torques clipped to [-2, 2]).

    With the default physics, theta'' = 15 sin(theta) + 3 u; the swing-up pushes along the
    angular velocity until the energy ``0.5 theta'^2 + 15 cos(theta)`` reaches the top's 15.

    Example:
        >>> pendulum_controller(np.array([1.0, 0.0, 0.0], np.float32))
        array([-0.], dtype=float32)
    """
    cos, sin, theta_dot = (float(v) for v in obs)
    theta = math.atan2(sin, cos)
    if cos > 0.85:
        torque = -(10.0 * theta + 2.0 * theta_dot)
    else:
        energy = 0.5 * theta_dot**2 + 15.0 * cos
        direction = math.copysign(1.0, theta_dot) if abs(theta_dot) > 1e-3 else 1.0
        torque = direction * (15.0 - energy)
    return np.array([min(max(torque, -2.0), 2.0)], dtype=np.float32)


#: The reference controller of each physics task.
REFERENCE_CONTROLLERS: dict[str, Callable[[np.ndarray], object]] = {
    "cartpole": cartpole_controller,
    "pendulum": pendulum_controller,
}


@dataclass(frozen=True)
class Rollout:
    """One episode of a controller in an env.

    Attributes:
        observations: (steps + 1, obs_dim) every observation, from reset's to the last.
        rewards: (steps,) the reward of each step.
        shifted: (steps + 1,) whether each observation came from the shifted world.
    """

    observations: np.ndarray
    rewards: np.ndarray
    shifted: np.ndarray

    @property
    def total_return(self) -> float:
        """The episode's return, the sum of its rewards."""
        return float(self.rewards.sum())

    @property
    def length(self) -> int:
        """The number of steps the episode lasted."""
        return len(self.rewards)


def rollout(env: gymnasium.Env, controller: Callable[[np.ndarray], object], seed: int) -> Rollout:
    """Run one episode of ``controller`` in ``env`` from ``reset(seed=seed)``.

    Example:
        >>> import oodmon
        >>> env = gymnasium.make("oodmon/CartPole-v1")
        >>> rollout(env, cartpole_controller, seed=0).length
        500
    """
    obs, info = env.reset(seed=seed)
    observations, rewards, shifted = [obs], [], [info["shifted"]]
    while True:
        obs, reward, terminated, truncated, info = env.step(controller(obs))
        observations.append(obs)
        rewards.append(reward)
        shifted.append(info["shifted"])
        if terminated or truncated:
            break
    return Rollout(np.asarray(observations), np.asarray(rewards, dtype=np.float64), np.asarray(shifted))
