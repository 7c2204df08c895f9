"""``OODMON_TORCH_THREADS``: how many torch threads an oodmon command may use, read in one place.

Every command honours it (training as much as calibration, the monitor and the bench), and uses
one thread where it is not set, so that jobs side by side keep to their share of the cores; a
script or a process of your own that plays agents calls :func:`limit_torch_threads` first (torch's
default is a thread per core, and two such processes on two cores ran 22 times slower than two on
one thread each: see there).
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


def limit_torch_threads(default: int | None = 1) -> int | None:
    """Set torch's threads to ``OODMON_TORCH_THREADS``, or to ``default`` where it is not set
    (``None``: leave torch's own choice, a thread per core); the number set, or ``None``.

    The default is one: a monitored decision is a batch of one, which a second thread does not
    speed up, and processes side by side each with a thread per core slow each other down many
    times over. Measured with ``benchmarks/torch_threads.py`` (shipped Pong DropConnect agent,
    two cores, 2026-11-28): alone, 0.91 s per 1,000 monitored decisions on one thread against 1.05 on
    torch's two; two processes side by side, 1.05 against 23.3 (each kept a torch OpenMP thread as
    busy as its main thread).

    Raises:
        ConfigError: the value is not a whole number from 1 to :data:`MAX_THREADS`.
    """
    threads = torch_threads(default=default)
    if threads is None:
        return None
    import torch

    torch.set_num_threads(threads)
    return threads
