"""``OODMON_TORCH_THREADS``: how many torch threads an oodmon command may use, read in one place.

Every command honours it (training as much as calibration, the monitor and the bench), so that a
job run beside a training keeps to its share of the cores; a script or a process of your own that
plays agents calls :func:`limit_torch_threads` first (torch's default is a thread per core; with two such
processes on two cores, each kept a torch OpenMP thread as busy as its main thread).
"""

from __future__ import annotations

import os

from oodmon.errors import ConfigError

__all__ = ["MAX_THREADS", "limit_torch_threads", "torch_threads"]

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


def limit_torch_threads() -> int | None:
    """Set torch's threads to ``OODMON_TORCH_THREADS`` where it is set (else leave torch's own
    choice); the number set, or ``None``.

    Raises:
        ConfigError: the value is not a whole number from 1 to :data:`MAX_THREADS`.
    """
    threads = torch_threads()
    if threads is None:
        return None
    import torch

    torch.set_num_threads(threads)
    return threads
