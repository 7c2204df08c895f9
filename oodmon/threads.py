"""``OODMON_TORCH_THREADS``: how many threads torch and numpy's BLAS may use in an oodmon command,
read in one place.

Every command honours it (training as much as calibration, the monitor and the bench), and uses
one thread where it is not set, so that jobs side by side keep to their share of the cores; a
script or a process of your own that plays agents calls :func:`limit_threads` first. Both
libraries default to a thread per core: two processes on two cores ran 10 times slower with torch's
(a monitored Pong decision) and 4-5 times slower with numpy's OpenBLAS (a CartPole DropConnect
decision with fixed masks) than with one thread each (see :func:`limit_threads`). The variable
keeps its first name (it covered torch alone until 2026-11-28): the committed results' commands
carry it.
"""

from __future__ import annotations

import os

from oodmon.errors import ConfigError

__all__ = ["MAX_THREADS", "limit_threads", "set_threads", "torch_threads"]

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


def limit_threads(default: int | None = 1, *, torch: bool = True) -> int | None:
    """Set torch's threads and those of numpy's BLAS to ``OODMON_TORCH_THREADS``, or to ``default``
    where it is not set (``None``: leave both their own choice, a thread per core); the number set,
    or ``None``. ``torch=False``: numpy's BLAS only, torch left unimported (a command that plays no
    policy, ``replay`` and ``check``: importing torch was a second of their start, 2026-12-04).

    The default is one: a monitored decision is a batch of one, which a second thread does not
    speed up, and processes side by side each with a thread per core slow each other down many
    times over, each keeping a second thread spinning as busily as its main one (``top -H``; gdb
    finds it in libgomp's barrier for torch, in OpenBLAS's ``blas_thread_server`` for numpy).
    Measured on two cores with ``benchmarks/threads.py`` (2026-11-28):

    - torch (``--case torch``: the shipped Pong DropConnect agent, frames detector): alone, 0.99 s
      per 1,000 monitored decisions on one thread against 0.93 on torch's two; two processes side
      by side, 1.03 against 10.7 (23.3 in an earlier reading, numpy's BLAS then on its two as well);
    - numpy's BLAS (``--case blas``: the shipped CartPole DropConnect agent with fixed masks, whose K
      sub-networks are one matrix product per layer through OpenBLAS): alone, 0.34 s per 1,000
      decisions on either; two processes side by side, 0.34 on one thread against 1.31-1.86 on
      OpenBLAS's two. Under Pong's features detector (``--case blas-pong``) neither is steadily faster.

    numpy's BLAS, which the agents' products go through, is loaded here and limited; so is any
    other BLAS already loaded (opencv and scipy bring OpenBLAS builds of their own), and one loaded
    later starts with ``OPENBLAS_NUM_THREADS``, which this sets too.

    Raises:
        ConfigError: the value is not a whole number from 1 to :data:`MAX_THREADS`.
    """
    threads = torch_threads(default=default)
    if threads is not None:
        set_threads(threads, torch=torch)
    return threads


def set_threads(threads: int, *, torch: bool = True) -> None:
    """Set torch's threads (``torch=False``: not) and those of every BLAS to ``threads``, whatever
    ``OODMON_TORCH_THREADS`` says (a bench's worker process, one of several side by side, takes one);
    :func:`limit_threads` reads the variable first."""
    import numpy  # noqa: F401  (loads its BLAS, which threadpoolctl then finds)
    from threadpoolctl import threadpool_limits

    if torch:
        import torch as torch_module

        torch_module.set_num_threads(threads)
    threadpool_limits(threads, user_api="blas")  # a call, not a with-block: the limit stays
    os.environ["OPENBLAS_NUM_THREADS"] = str(threads)  # read by an OpenBLAS as it loads
