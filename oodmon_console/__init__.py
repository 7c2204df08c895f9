"""The ``oodmon`` program's entry point, outside the ``oodmon`` package so that it runs before it.

``import oodmon`` registers the environments and takes Python's first half second. Ctrl-C in it
printed Python's own traceback of the import (about 40 lines), and SIGTERM in it ended the process
by the signal, saying nothing; nothing of oodmon's could catch them, since the command's code is
in the package being imported. Here both end the program as they end a command stopped as it
starts: one line, "nothing was written", exit code 130 or 143 (since 2026-12-06). Then
:func:`oodmon.cli.console` runs the command.
"""

import signal
import sys

NOT_BEGUN = "it was stopped as it started: nothing was written"


class _Terminated(KeyboardInterrupt):
    """SIGTERM before oodmon's own handler is set (:mod:`oodmon.monitor.stopping` sets it later)."""


def _terminated(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # (once: the process is ending)
    raise _Terminated


def main() -> int:
    """``oodmon.cli.console()``, its import stopped by Ctrl-C or SIGTERM in one line."""
    before = signal.signal(signal.SIGTERM, _terminated)
    try:
        from oodmon.cli import console
    except KeyboardInterrupt as stop:
        said = "stopped by SIGTERM" if isinstance(stop, _Terminated) else "interrupted"
        print(f"oodmon: {said}; {NOT_BEGUN}", file=sys.stderr)
        return 143 if isinstance(stop, _Terminated) else 130
    finally:
        signal.signal(signal.SIGTERM, before)  # (the command sets its own once it begins)
    return console()
