"""Validation of env parameters, shared by the physics envs, OOD-Pong and the variant parser.

Each check raises an :mod:`oodmon.errors` error whose message names the parameter, the value
received and what is allowed.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Iterable, Mapping

import gymnasium
import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError, UnknownParameterError
from oodmon.validation import is_whole

__all__ = ["LONG_EPISODE", "PHYSICS_RANGE", "check_onset_step", "episode_onset", "check_physics", "has_time_limit",
           "positive_number", "reject_unknown", "space_mismatch", "step_naming_refusal",
           "tensor_hint", "warn_if_endless"]

#: A physics parameter may be at most this many times its default, or this many times smaller (the
#: paper's grid spans 0.05 to 20 times); further out the simulation overflows (``length=1e308``).
PHYSICS_RANGE = 1000.0


def space_mismatch(expected: object, given: object, *,
                   spaces: tuple[str, ...] = ("observation_space", "action_space")) -> str | None:
    """The first of ``spaces`` that ``given`` (an env or an SB3 model) has of another type, shape or
    number of actions than ``expected`` (a dict space: other keys, or one of them another space);
    ``None`` if none. Bounds may differ: a policy acts in an env of the same shapes (oodmon's
    variants keep the default env's spaces, and a user's env may bound its observations otherwise).

    Example:
        >>> import gymnasium
        >>> space_mismatch(gymnasium.make("CartPole-v1"), gymnasium.make("Pendulum-v1"))
        'observation_space'
    """
    for what in spaces:
        if not _same_kind(getattr(expected, what), getattr(given, what)):
            return what
    return None


def _same_kind(ours: object, theirs: object) -> bool:
    """Whether two spaces are of one type, shape and number of actions (dicts: key by key)."""
    if type(ours) is not type(theirs) or getattr(ours, "shape", None) != getattr(theirs, "shape", None) \
            or getattr(ours, "n", None) != getattr(theirs, "n", None):
        return False
    inner = getattr(ours, "spaces", None)
    if isinstance(inner, dict):  # gymnasium's Dict
        theirs_inner = theirs.spaces
        return inner.keys() == theirs_inner.keys() and all(_same_kind(inner[k], theirs_inner[k]) for k in inner)
    return True


def tensor_hint(action: object) -> str:
    """What to say of an action that is a torch tensor (an env takes numbers or arrays), else nothing."""
    return " (a torch tensor: return a number, .item(), or an array, .numpy())" if hasattr(action, "detach") else ""


def step_naming_refusal(env: gymnasium.Env, action: object, *, step: int, episode: str = "an episode",
                        seed: int | None = None) -> tuple:
    """``env.step(action)`` of a policy's ``action``. Where the env raises on an action that is not
    of its action space (a ``Box``: numbers of another shape; any other space: what its ``contains``
    refuses), a :class:`~oodmon.errors.ConfigError` names the action, the ``step`` of the
    ``episode`` ("at step 7 of an episode (seed 3)") and the env's words; an error of the env's
    own, on a good action, is raised as it is.

    The first action of a plain policy is checked where the policy is loaded; this says which
    later one the env refused (a policy that returns ``None`` or a tensor in some states), where a
    traceback of the env's ``step`` said only what it asserted. Nothing is formatted unless the
    env raises: the monitor's loop calls it at every step.
    """
    try:
        return env.step(action)
    except Exception as error:
        space = env.action_space
        if not _in_space(space, action):
            seeded = "" if seed is None else f" (seed {seed})"
            raise ConfigError(f"the policy returned {action!r} at step {step} of {episode}{seeded}, which the env "
                              f"refused ({type(error).__name__}: {error}); its actions are {space}"
                              f"{tensor_hint(action)}") from error
        raise


def _in_space(space: object, action: object) -> bool:
    """Whether ``action`` is one of ``space``'s: for a ``Box``, numbers of its shape (any float
    width and any value: gymnasium's ``contains`` refuses a float64 array of a float32 space, which
    envs take, and values past the bounds, which most clip), else the space's ``contains``."""
    if isinstance(space, gymnasium.spaces.Box):
        try:
            array = np.asarray(action)
        except Exception:  # noqa: BLE001 (not even an array)
            return False
        return array.shape == space.shape and array.dtype.kind in "biuf"
    try:
        return bool(space.contains(action))
    except Exception:  # noqa: BLE001 (an action contains() cannot even read)
        return False


def has_time_limit(env: object) -> bool:
    """Whether ``env`` or an env it wraps ends its episodes after a number of steps (a gymnasium
    ``TimeLimit``, as ``gymnasium.make`` adds for an id registered with ``max_episode_steps``).

    Example:
        >>> import gymnasium
        >>> from gymnasium.envs.classic_control.cartpole import CartPoleEnv
        >>> has_time_limit(gymnasium.make("CartPole-v1")), has_time_limit(CartPoleEnv())
        (True, False)
    """
    from gymnasium.wrappers import TimeLimit

    while env is not None:
        if isinstance(env, TimeLimit):
            return True
        env = getattr(env, "env", None)
    return False


#: Steps after which an ID episode (fitting, calibration, validation: each played whole) is said to
#: be probably endless; a Pong game, the longest of oodmon's own, is a few thousand decisions.
LONG_EPISODE = 100_000


def warn_if_endless(env: object, steps: int) -> None:
    """Warn, once per episode (at ``steps == LONG_EPISODE``), that an ID episode of ``env`` has
    not ended, naming the fix where the env has no time limit (:func:`has_time_limit`)."""
    if steps != LONG_EPISODE:
        return
    spec = getattr(env, "spec", None)
    name = spec.id if spec is not None else type(env).__name__
    fix = (f"; {name} has no time limit: register it with max_episode_steps (gymnasium.register(..., "
           "max_episode_steps=N))" if not has_time_limit(env) else "")
    warnings.warn(f"an ID episode of {name} has run {steps:,} steps and not ended: fitting, calibration and validation "
                  f"play whole episodes{fix}", UserWarning, stacklevel=3)


def reject_unknown(owner: str, given: Iterable[str], allowed: Iterable[str]) -> None:
    """Raise :class:`UnknownParameterError` if ``given`` holds a name not in ``allowed``.

    Args:
        owner: what the parameters belong to, for the message (``"oodmon/CartPole-v1"``).
        given: the names the caller passed.
        allowed: the names ``owner`` accepts.

    Example:
        >>> reject_unknown("oodmon/CartPole-v1", ["lenght"], ["gravity", "length"])
        Traceback (most recent call last):
        ...
        oodmon.errors.UnknownParameterError: oodmon/CartPole-v1 has no parameter 'lenght'; ...
    """
    allowed = list(allowed)
    for name in given:
        if name not in allowed:
            raise UnknownParameterError(
                f"{owner} has no parameter {name!r}; it takes {', '.join(allowed)}"
            )


def positive_number(owner: str, name: str, value: object, default: float | None = None) -> float:
    """Return ``value`` as a float if it is a finite number > 0, else raise.

    Args:
        owner: what the parameter belongs to, for the message.
        name: the parameter's name.
        value: what the caller passed.
        default: the parameter's default value, quoted in the message when given.

    Raises:
        InvalidParameterError: ``value`` is not a number, not finite, or not > 0.

    Example:
        >>> positive_number("oodmon/CartPole-v1", "length", 2)
        2.0
    """
    hint = f" (the default is {default!r})" if default is not None else ""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidParameterError(
            f"{owner}: {name}={value!r} is not allowed; {name} must be a number > 0{hint}"
        )
    number = float(value)
    if not (math.isfinite(number) and number > 0):
        raise InvalidParameterError(
            f"{owner}: {name}={number!r} is not allowed; {name} must be a finite number > 0{hint}"
        )
    return number


def check_onset_step(owner: str, onset_step: object) -> int:
    """Return ``onset_step`` if it is an integer >= 0, else raise :class:`InvalidParameterError`.

    The onset is the index of the first ``step()`` call of an episode that runs in the shifted
    world (0: the whole episode, as in the paper).

    Example:
        >>> check_onset_step("oodmon/CartPole-v1", 100)
        100
    """
    if not is_whole(onset_step, 0):
        raise InvalidParameterError(
            f"{owner}: onset_step={onset_step!r} is not allowed; onset_step must be an integer >= 0 "
            "(0 shifts the whole episode, N shifts it from the N-th step on)"
        )
    return int(onset_step)


def check_physics(owner: str, defaults: Mapping[str, float], overrides: Mapping[str, object]) -> dict[str, float]:
    """Validate physics overrides against an env's defaults; return the full parameter set.

    Args:
        owner: the env id, for messages.
        defaults: every physics parameter of the env with its default value.
        overrides: the parameters the caller changed.

    Returns:
        ``defaults`` updated with ``overrides``, every value a positive float.

    Example:
        >>> check_physics("oodmon/Pendulum-v1", {"g": 10.0, "l": 1.0}, {"g": 50})
        {'g': 50.0, 'l': 1.0}
    """
    try:
        reject_unknown(owner, overrides, defaults)
    except UnknownParameterError as error:
        from difflib import get_close_matches

        unknown = next(name for name in overrides if name not in defaults)
        close = get_close_matches(unknown, list(defaults), n=1)
        gym_id = owner.removeprefix("oodmon/")
        hint = (f"did you mean {close[0]!r}?" if close else  # (else an attribute of gymnasium's env, not its physics)
                f"another attribute of the env is shifted on gymnasium's id of it, {gym_id}:NAME=VALUE, for a policy "
                f"of your own there (--sb3 or --policy, --env {gym_id})")
        raise UnknownParameterError(f"{error}; {hint}") from None
    physics = dict(defaults)
    for name, value in overrides.items():
        physics[name] = positive_number(owner, name, value, defaults[name])
        low, high = defaults[name] / PHYSICS_RANGE, defaults[name] * PHYSICS_RANGE
        if not low <= physics[name] <= high:
            raise InvalidParameterError(
                f"{owner}: {name}={physics[name]!r} is not allowed; {name} must lie within {PHYSICS_RANGE:g} times "
                f"its default {defaults[name]!r} either way ({low:g} to {high:g}): beyond, the simulation overflows"
            )
    return physics


def episode_onset(owner: str, configured: int, options: dict | None) -> tuple[int, dict | None]:
    """The onset of the episode a ``reset(options=...)`` starts, and the options left for the parent env.

    ``options={"onset_step": n}`` shifts this episode from step n on (the monitor's benchmark draws
    a random onset per episode); without it the env's own ``onset_step`` holds. Other options
    pass through.

    Example:
        >>> episode_onset("oodmon/CartPole-v1", 0, {"onset_step": 40})
        (40, None)
        >>> episode_onset("oodmon/CartPole-v1", 5, {"low": -0.1})
        (5, {'low': -0.1})
    """
    if not options or "onset_step" not in options:
        return configured, options
    rest = {k: v for k, v in options.items() if k != "onset_step"}
    return check_onset_step(owner, options["onset_step"]), rest or None
