"""Registers oodmon's envs with gymnasium; ``import oodmon`` runs it once."""

from __future__ import annotations

from typing import Any

import gymnasium

__all__ = ["TASK_OF_ENV", "env_id_of", "make_env", "obs_noise_of_env", "onset_of_env", "register_envs", "task_of_env",
           "variant_of_env"]

#: The oodmon task whose variants shift an env: gymnasium's own ids and oodmon's (the same
#: physics, observations and spaces; oodmon's can shift).
TASK_OF_ENV = {"CartPole-v1": "cartpole", "oodmon/CartPole-v1": "cartpole",
               "Pendulum-v1": "pendulum", "oodmon/Pendulum-v1": "pendulum", "oodmon/Pong-v5": "pong"}


def task_of_env(env_id: str) -> str | None:
    """The oodmon task of a gymnasium env id, or ``None`` (an env oodmon has no variants of).

    Example:
        >>> task_of_env("CartPole-v1"), task_of_env("Acrobot-v1")
        ('cartpole', None)
    """
    return TASK_OF_ENV.get(env_id)


def make_env(env_id: str, **kwargs: Any) -> gymnasium.Env:
    """``gymnasium.make(env_id, **kwargs)`` for an id a user gave; one gymnasium cannot make (not
    registered, a namespace of a package not installed, ``module:Id`` whose module does not import)
    is said in one line.

    Raises:
        ConfigError: naming the id and gymnasium's or Python's reason.
    """
    from oodmon.errors import ConfigError

    if isinstance(env_id, str) and env_id.startswith("ALE/") and env_id not in gymnasium.registry:
        try:  # gymnasium knows Atari's ids once ale_py registers them (oodmon's Pong does it too)
            import ale_py

            gymnasium.register_envs(ale_py)
        except ImportError:
            pass  # said by gymnasium below: "Namespace ALE not found"
    try:
        return gymnasium.make(env_id, **kwargs)
    except gymnasium.error.Error as error:
        raise ConfigError(f"env {env_id!r}: {error}") from None
    except ModuleNotFoundError as error:  # my_envs:MyEnv-v0, or a module the env's own module imports
        raise ConfigError(f"env {env_id!r}: {error}" + ("" if ":" not in env_id else
                          " (put the folder that holds the module on PYTHONPATH)")) from None


def env_id_of(env: gymnasium.Env) -> str:
    """The id ``env`` was made with, or its class name for an env made without the registry."""
    return env.spec.id if env.spec is not None else type(env.unwrapped).__name__


def variant_of_env(env: gymnasium.Env) -> str:
    """The variant spec a monitor records for ``env``: the shift an oodmon env was made with
    (``cartpole:length=2.0``), the task for an unshifted one or for gymnasium's own id of it
    (``CartPole-v1`` -> ``cartpole``), the shift of your own env (a
    :class:`~oodmon.envs.shift.ShiftAttributes` among its wrappers: ``Acrobot-v1:LINK_MASS_2=3.0``),
    else the env's id (an env oodmon has no variants of, whose episodes replay counts as
    in-distribution).

    Example:
        >>> variant_of_env(gymnasium.make("oodmon/CartPole-v1", length=2.0))
        'cartpole:length=2.0'
        >>> variant_of_env(gymnasium.make("CartPole-v1")), variant_of_env(gymnasium.make("Acrobot-v1"))
        ('cartpole', 'Acrobot-v1')
    """
    from oodmon.envs.grid import ENV_IDS, Variant

    shift, faults = _shift_wrapper(env), ()
    if shift is not None:
        if shift.shift.env_id not in ENV_IDS.values() or any(not name.startswith("obs.") for name, _ in shift.shift.params):
            return shift.shift.spec
        faults = shift.shift.params  # sensor faults of oodmon's own env (a variant's: cartpole:obs.stuck[3]=1)
    base, spec_id = env.unwrapped, env_id_of(env)
    task = task_of_env(spec_id)
    if task is None:
        return spec_id
    physics = getattr(base, "shifted_physics", None)
    if physics is not None and hasattr(base, "DEFAULTS"):
        changed = {name: value for name, value in physics.items() if base.DEFAULTS.get(name) != value}
        return Variant(task, tuple(sorted(changed.items())), faults=faults).spec
    named = getattr(base, "corruption_named", None)  # Pong: (corruption, severity, params) as made
    if named is not None and named[0] is not None:
        corruption, severity, params = named
        return Variant(task, tuple(sorted(params.items())), corruption, severity).spec
    return Variant(task, faults=faults).spec


def wrappers_of(env: gymnasium.Env) -> list[gymnasium.Wrapper]:
    """``env``'s wrappers, from the outermost (``env`` itself, if it is one) in; ``env.unwrapped`` is
    what they wrap.

    Example:
        >>> [type(w).__name__ for w in wrappers_of(gymnasium.make("Acrobot-v1"))]
        ['TimeLimit', 'OrderEnforcing', 'PassiveEnvChecker']
    """
    found = []
    while isinstance(env, gymnasium.Wrapper):
        found.append(env)
        env = env.env
    return found


def _shift_wrapper(env: gymnasium.Env):
    """The :class:`~oodmon.envs.shift.ShiftAttributes` among ``env``'s wrappers, or ``None``."""
    from oodmon.envs.shift import ShiftAttributes

    return next((wrapper for wrapper in wrappers_of(env) if isinstance(wrapper, ShiftAttributes)), None)


def onset_of_env(env: gymnasium.Env) -> int:
    """The onset of ``env``'s current episode: the step its shift begins at (oodmon's envs, or a
    :class:`~oodmon.envs.shift.ShiftAttributes` among its wrappers), else 0.

    Example:
        >>> env = gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=30)
        >>> onset_of_env(env), onset_of_env(gymnasium.make("Acrobot-v1"))
        (30, 0)
    """
    shift = _shift_wrapper(env)
    return int(shift.onset_step if shift is not None else getattr(env.unwrapped, "onset_step", 0))


def obs_noise_of_env(env: gymnasium.Env) -> float:
    """The sensor noise of ``env``: oodmon's CartPole's and Pendulum's ``obs_noise`` (the noise's std
    as a fraction of each observation dimension's ID spread), else 0.

    Example:
        >>> noisy = gymnasium.make("oodmon/CartPole-v1", obs_noise=0.01)
        >>> obs_noise_of_env(noisy), obs_noise_of_env(gymnasium.make("Acrobot-v1"))
        (0.01, 0.0)
    """
    from oodmon.envs.physics import _ShiftPhysics

    return float(env.unwrapped.obs_noise) if isinstance(env.unwrapped, _ShiftPhysics) else 0.0


def register_envs() -> None:
    """Register ``oodmon/CartPole-v1``, ``oodmon/Pendulum-v1`` and ``oodmon/Pong-v5``.

    Idempotent. Episode limits are those of the standard envs: 500 steps for CartPole-v1, 200 for
    Pendulum-v1, and ALE's 108,000 frames for Pong.
    """
    specs = [
        dict(id="oodmon/CartPole-v1", entry_point="oodmon.envs.physics:ShiftedCartPole",
             max_episode_steps=500, reward_threshold=475.0),
        dict(id="oodmon/Pendulum-v1", entry_point="oodmon.envs.physics:ShiftedPendulum",
             max_episode_steps=200),
        dict(id="oodmon/Pong-v5", entry_point="oodmon.envs.pong:CorruptedPong"),
    ]
    for spec in specs:
        if spec["id"] not in gymnasium.registry:
            gymnasium.register(**spec)
