"""oodmon: tells when a deployed reinforcement-learning policy has left the world it was trained in.

The package has four parts, in the direction data flows:

- :mod:`oodmon.envs`: the OOD variants the agent acts in (physics shifts, frame corruptions);
- :mod:`oodmon.agents`: uncertainty-aware policies;
- :mod:`oodmon.monitor`: per-step uncertainty against a calibrated threshold, alarms, logs;
- :mod:`oodmon.replay`: metrics and tables from recorded logs.

``import oodmon`` registers the envs with gymnasium::

    >>> import gymnasium, oodmon
    >>> env = gymnasium.make("oodmon/CartPole-v1", length=2.0)

``oodmon.watch(models, env_id)`` fits, calibrates and returns the monitor of any policy
(:mod:`oodmon.monitor.watch`); ``oodmon.watch_recorded(fit, calibration, action_space=...)`` that
of a deployment oodmon cannot play, from its recorded episodes (:mod:`oodmon.monitor.recorded`).
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from oodmon import envs

try:
    __version__ = version("oodmon")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"

__all__ = ["__version__", "envs", "watch", "watch_recorded"]


def __getattr__(name: str):
    """``oodmon.watch`` (:func:`oodmon.monitor.watch.watch`) and ``oodmon.watch_recorded``
    (:func:`oodmon.monitor.recorded.watch_recorded`), imported when first used: ``import oodmon``
    stays light."""
    if name == "watch":
        from oodmon.monitor.watch import watch

        return watch
    if name == "watch_recorded":
        from oodmon.monitor.recorded import watch_recorded

        return watch_recorded
    raise AttributeError(f"module 'oodmon' has no attribute {name!r}")
