"""Errors that oodmon raises for input a person can fix.

Every message names the parameter, the value received and what is allowed, so that the
person reading it knows what to change. The CLI prints them as one line and exits non-zero.

The hierarchy::

    OodmonError                        anything oodmon raises on purpose
    ├── ConfigError (ValueError)       bad input: an argument, a flag, a spec string
    │   ├── UnknownParameterError      a name oodmon does not know (parameter, task, corruption)
    │   ├── InvalidParameterError      a known name with a value outside what is allowed
    │   └── SpecError                  a variant spec string that does not parse
    ├── ModelFormatError (ValueError)  a model file that is damaged, another task's, or mismatched
    └── LogFormatError (ValueError)    a log file that is not MCAP, or not written by oodmon

``ConfigError`` derives from ``ValueError`` so that code written against plain Python
conventions (``except ValueError``) still catches it. None of them derive from ``TypeError``:
``gymnasium.make`` rewrites the message of a ``TypeError`` raised by an env's constructor.
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = [
    "ConfigError",
    "InvalidParameterError",
    "LogFormatError",
    "ModelFormatError",
    "OodmonError",
    "SpecError",
    "UnknownParameterError",
    "unknown",
]


class OodmonError(Exception):
    """Base class of every error oodmon raises on purpose."""


class ConfigError(OodmonError, ValueError):
    """Input that oodmon cannot use: an argument, a CLI flag or a spec string."""


class UnknownParameterError(ConfigError):
    """A parameter, task or corruption name that oodmon does not know.

    Example:
        >>> import gymnasium, oodmon
        >>> gymnasium.make("oodmon/CartPole-v1", lenght=2.0)
        Traceback (most recent call last):
        ...
        oodmon.errors.UnknownParameterError: oodmon/CartPole-v1 has no parameter 'lenght'; ...
    """


def unknown(kind: str, name: object, known: Iterable[str], where: str = "") -> str:
    """Words refusing ``name``, not a ``kind`` oodmon knows: the one meant, where it looks misspelt,
    and those there are, as a flag or a variant's parameter is refused (for an
    :class:`UnknownParameterError`, or a CLI option's error). ``where``: words after the name.

    Example:
        >>> unknown("score", "chosen_sd", ("chosen_std", "mean_std"))
        "unknown score 'chosen_sd' (did you mean 'chosen_std'?); choose one of chosen_std, mean_std"
        >>> unknown("method", "bayes", ("dropout", "ensemble"), " in --methods")
        "unknown method 'bayes' in --methods; choose one of dropout, ensemble"
    """
    from difflib import get_close_matches

    known = list(known)
    close = get_close_matches(name, known, n=1) if isinstance(name, str) else []
    return (f"unknown {kind} {name!r}{where}" + (f" (did you mean {close[0]!r}?)" if close else "")
            + f"; choose one of {', '.join(known)}")


class InvalidParameterError(ConfigError):
    """A known parameter whose value is outside what is allowed.

    Example:
        >>> import gymnasium, oodmon
        >>> gymnasium.make("oodmon/CartPole-v1", length=-1.0)
        Traceback (most recent call last):
        ...
        oodmon.errors.InvalidParameterError: oodmon/CartPole-v1: length=-1.0 is not allowed; ...
    """


class SpecError(ConfigError):
    """A variant spec string (``cartpole:length=2.0``, ``pong:pixelate@3``) that does not parse."""


class ModelFormatError(OodmonError, ValueError):
    """A saved model that cannot be loaded: damaged, another task's, or not its own architecture."""


class LogFormatError(OodmonError, ValueError):
    """A log file replay cannot read: missing, not MCAP, or not written by oodmon."""
