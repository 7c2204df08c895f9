"""The ``oodmon`` program's entry point, outside the ``oodmon`` package so that it runs before it.

``import oodmon`` registers the environments and takes Python's first half second. Ctrl-C in it
printed Python's own traceback of the import (about 40 lines), and SIGTERM in it ended the process
by the signal, saying nothing; nothing of oodmon's could catch them, since the command's code is
in the package being imported. Here both end the program as they end a command stopped as it
starts: one line, "nothing was written", exit code 130 or 143 (since 2026-12-06). Then
:func:`oodmon.cli.console` runs the command.
"""

import atexit
import signal
import sys

NOT_BEGUN = "it was stopped as it started: nothing was written"


class _Terminated(KeyboardInterrupt):
    """SIGTERM before oodmon's own handler is set (:mod:`oodmon.monitor.stopping` sets it later)."""


def _terminated(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # (once: the process is ending)
    raise _Terminated


def _stops_ignored() -> None:
    """Ctrl-C and SIGTERM ignored for the rest of Python's exit: the process ends with the command's
    exit code a moment later. Python's finalization gives each signal with a handler of Python's
    its default action back before it tears down the modules, torch's among them (0.7 s of the
    exit's 0.75 s after a calibrate's last line, measured 2026-12-06), and a SIGTERM then ended the
    process by the signal (-15): 21 of 21 sent 0.05-0.5 s after that line. An ignored signal keeps
    its disposition there; so do threads other than the main one, which a blocked one would not."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def hold_stops_at_exit() -> None:
    """Register :func:`_stops_ignored` as the last of the exit's clean-ups (they run in the reverse
    order of registration: call this first; once, later calls do nothing). Before it,
    :func:`oodmon.cli.console`'s handler ends a stopped exit at once with the command's code."""
    global _HELD
    if not _HELD:
        atexit.register(_stops_ignored)
        _HELD = True


_HELD = False


def main() -> int:
    """``oodmon.cli.console()``, its import stopped by Ctrl-C or SIGTERM in one line."""
    hold_stops_at_exit()
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
