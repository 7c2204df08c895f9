"""``OODMON_TORCH_THREADS``: how many torch threads an oodmon command may use, read in one place.

Every command honours it (training as much as calibration, the monitor and the bench), so that a
job run beside a training keeps to its share of the cores.
"""

from __future__ import annotations

import os

from oodmon.errors import ConfigError

__all__ = ["MAX_THREADS", "torch_threads"]

#: The largest value accepted: more threads than any machine oodmon runs on has cores.
MAX_THREADS = 1024


def torch_threads(default: int | None = None) -> int | None:
    """The value of ``OODMON_TORCH_THREADS`` as an int, or ``default`` where it is not set.

    Raises:
        ConfigError: the value is not a whole number from 1 to :data:`MAX_THREADS`.

    Example:
        >>> import os
        >>> from unittest import mock
        >>> with mock.patch.dict(os.environ, {"OODMON_TORCH_THREADS": "2"}):
        ...     torch_threads()
        2
        >>> with mock.patch.dict(os.environ):
        ...     _ = os.environ.pop("OODMON_TORCH_THREADS", None)
        ...     torch_threads(default=1)
        1
    """
    value = os.environ.get("OODMON_TORCH_THREADS")
    if value is None:
        return default
    text = value.strip()
    if not text.isdigit() or not 1 <= int(text) <= MAX_THREADS:
        raise ConfigError(f"OODMON_TORCH_THREADS={value!r} is not allowed; give a whole number from 1 to {MAX_THREADS}")
    return int(text)
