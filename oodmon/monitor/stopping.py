"""Stopping a monitored process with SIGTERM as with Ctrl-C: its logs finished, its cut episode marked.

A service manager (systemd, Docker, Kubernetes) stops a process with SIGTERM. Python's default is to
die at once, without ``finally`` blocks or ``atexit``: a monitor's MCAP log is then torn (replay
recovers it, but the episode running at the stop is lost where its steps had not reached the
disk). Ctrl-C (``KeyboardInterrupt``) instead unwinds: ``Monitor.run_episode`` logs the cut episode
as interrupted, and ``Monitor.close`` (``with``, or at interpreter exit) finishes the logs.
:func:`stop_on_sigterm` makes SIGTERM do the same. ``oodmon``'s commands run inside it; a process of
your own that deploys a monitored policy can too:

    >>> from oodmon.monitor import stop_on_sigterm
    >>> with stop_on_sigterm():
    ...     pass  # the monitored loop: SIGTERM raises Terminated (a KeyboardInterrupt) in it
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["Terminated", "stop_on_sigterm", "stops_held"]


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the process is, as Ctrl-C raises ``KeyboardInterrupt`` (which it is, so
    that every cleanup Ctrl-C runs runs for it too)."""


@contextmanager
def stop_on_sigterm() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in this process; once: a second SIGTERM
    is ignored while the process cleans up. A process forked inside the block (a worker) dies of
    SIGTERM as usual. After the block, SIGTERM is handled as before it. Signal handlers run in the
    main thread only: in another thread this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    own = os.getpid()

    def stop(signum, frame) -> None:
        if os.getpid() != own:  # a forked worker: die as it would have
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated

    before = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


@contextmanager
def stops_held() -> Iterator[None]:
    """Within the block, Ctrl-C and SIGTERM wait: one that comes is answered as the block ends, by
    the handler it would have met (``KeyboardInterrupt``; :class:`Terminated` inside
    :func:`stop_on_sigterm`). For files written together that a stop must not part: a command's
    threshold and the clean-up of what it replaces. In another thread than the main one, where no
    handler runs, this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    stops = (signal.SIGINT, signal.SIGTERM)
    before = {signum: signal.signal(signum, lambda signum, frame: came.append(signum)) for signum in stops}
    try:
        yield
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)
    if came:
        handler = before[came[0]]
        if callable(handler):
            handler(came[0], None)
        elif handler == signal.SIG_DFL:
            os.kill(os.getpid(), came[0])
