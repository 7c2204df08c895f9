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

__all__ = [
    "ConfigError",
    "InvalidParameterError",
    "LogFormatError",
    "ModelFormatError",
    "OodmonError",
    "SpecError",
    "UnknownParameterError",
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
