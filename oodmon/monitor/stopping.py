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
from typing import Any

__all__ = ["Terminated", "sigterm_handler_kept", "stop_on_sigterm", "stops_held"]


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the process is, as Ctrl-C raises ``KeyboardInterrupt`` (which it is, so
    that every cleanup Ctrl-C runs runs for it too)."""


@contextmanager
def stop_on_sigterm() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in this process; once: a second SIGTERM
    is ignored while the process cleans up. A process forked inside the block (a worker) dies of
    SIGTERM as usual. After the block, SIGTERM is handled as before it. Signal handlers run in the
    main thread only: in another thread this does nothing.

    Where library code the SIGTERM came in raised a ``KeyboardInterrupt`` of its own in place of
    :class:`Terminated` (Ray's ``ray.wait`` does: ``oodmon bench --executor ray`` stopped by SIGTERM
    said "interrupted" and ended with 130, measured with Ray 2.60), the block raises
    :class:`Terminated` from it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    own, came = os.getpid(), []

    def stop(signum, frame) -> None:
        if os.getpid() != own:  # a forked worker: die as it would have
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        came.append(signum)
        raise Terminated

    before = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    except KeyboardInterrupt as interrupt:
        if came and not isinstance(interrupt, Terminated):
            raise Terminated(*interrupt.args) from interrupt
        raise
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
        _answer(came[0], before[came[0]])


def _answer(signum: int, handler: Any) -> None:
    """Answer a stop that came while another handler stood in for ``handler`` as ``handler`` would
    have: call it (``KeyboardInterrupt``, :class:`Terminated`), or end the process by the signal
    (``SIG_DFL``); an ignored one (``SIG_IGN``, or a handler not set from Python: None) stays so."""
    if callable(handler):
        handler(signum, None)
    elif handler == signal.SIG_DFL:
        os.kill(os.getpid(), signum)


@contextmanager
def sigterm_handler_kept() -> Iterator[None]:
    """Around code that sets a SIGTERM handler of its own for the rest of the process: the block's
    end puts back the one before it. ``ray.init`` sets one that calls ``sys.exit(15)``, and its core
    a C++ one that prints a stack and ends the process (measured with Ray 2.60: ``oodmon bench
    --executor ray`` stopped by SIGTERM ended with 1 or 15, saying nothing of what it kept, where
    the local bench says so and ends with 143). A SIGTERM that the block's handler turned into
    ``SystemExit(15)`` is answered by the handler it would have met (:class:`Terminated` inside
    :func:`stop_on_sigterm`). In another thread than the main one this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before, answered = signal.getsignal(signal.SIGTERM), False
    try:
        yield
    except SystemExit as exit:
        if exit.code != signal.SIGTERM or before is None:
            raise
        signal.signal(signal.SIGTERM, before)
        answered = True  # (what answering set stays: stop_on_sigterm's ignores a second SIGTERM)
        _answer(signal.SIGTERM, before)
        raise
    finally:
        if before is not None and not answered:  # (None: set outside Python, which cannot set it back)
            signal.signal(signal.SIGTERM, before)
