"""What the commands print besides their results: progress lines and bars, and tables as wide as
their columns."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager

from rich.console import Console

from oodmon.progress import unit_of

#: The lock of each progress display running now, held across this process's forks (see
#: :func:`_progress`).
_DISPLAY_LOCKS: list = []


def _hold_displays() -> None:
    for lock in _DISPLAY_LOCKS:
        lock.acquire()


def _release_displays() -> None:
    for lock in reversed(_DISPLAY_LOCKS):
        lock.release()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_hold_displays, after_in_parent=_release_displays, after_in_child=_release_displays)


class OutputClosed(KeyboardInterrupt):
    """The reader of the command's output went away (``oodmon run | head -3``: ``head`` ended):
    taken as Ctrl-C is (a run's logs finished, its cut episode marked interrupted), said on stderr,
    exit code 141 (a shell's for a process ended by SIGPIPE). Before (2026-12-06), rich's console
    ended the command with ``SystemExit(1)``, saying nothing, an exit code that reads as a
    regression check's fall (and a ``print``'s ``BrokenPipeError`` would have been said as an
    error, 2)."""


class StopsWhenOutputCloses:
    """The program's standard output (``sys.stdout``), raising :class:`OutputClosed` the first time a
    write or flush meets a closed pipe; its descriptor then reads to ``/dev/null``, so that what is
    still written, and the flush at Python's exit, goes nowhere quietly."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._closed()

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._closed()

    def _closed(self) -> None:
        try:
            nowhere = os.open(os.devnull, os.O_WRONLY)
            os.dup2(nowhere, self._stream.fileno())
            os.close(nowhere)
        except (OSError, ValueError):  # (a stream without a descriptor: each write meets the pipe again)
            pass
        raise OutputClosed

    def __getattr__(self, name: str):  # isatty, fileno, encoding, ... as the stream's
        return getattr(self._stream, name)


def _table_console() -> Console:
    """A console for tables: the terminal's width, or a wide one when output goes to a file or pipe
    (rich would otherwise cut columns to 80 characters)."""
    console = Console()
    return console if console.is_terminal else Console(width=220)


@contextmanager
def _progress(*, transient: bool = True) -> Iterator[Callable[..., None]]:
    """An ``on_progress(stage, done, total, note=None)`` for long work (see :mod:`oodmon.progress`;
    ``note``: a latest figure to show beside the stage): rich bars on a terminal; where stderr is a
    file (a job under nohup), where a bar would only appear at the end, a dated line per stage at
    most once a minute, at its start and at its end, with a rate in the stage's unit (from its
    second line on: the first has none to give).

    The bars are redrawn by a thread of rich's, ten times a second, holding the display's lock
    while it writes to stderr. A command forks its workers (``oodmon.side_by_side``) while that
    thread runs: forked in the middle of a redraw, a worker would inherit rich's locks and
    stderr's held by a thread it does not have, and wait for ever at its first line to stderr (a
    warning of its env). So every fork waits for the redraw to end: the display's lock is held
    across it (``os.register_at_fork``, as Python's ``logging`` holds its own).

    The display starts at the first report: an error said before any stage began is one line
    (rich's display, stopped, leaves a blank line where stderr is a file: before 2026-12-05 it
    came before such an error too)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    stderr = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    # Where stderr is a file, the dated lines below are the progress: a bar kept at the end
    # (``transient=False``, train's) was drawn there once, cut to 80 characters.
    with ExitStack() as started:
        progress: Progress | None = None  # the display, from the first report on (reports come from one thread)
        bars: dict[str, int] = {}
        last_line: dict[str, tuple[float, int]] = {}  # name -> (time, done) of its last plain line

        notes: dict[str, str] = {}  # name -> its latest note (training: the last evaluation return)

        def report(name: str, done: int, total: int, note: str | None = None) -> None:
            nonlocal progress
            if progress is None:
                progress = started.enter_context(
                    Progress(*columns, console=stderr, transient=transient or not stderr.is_terminal))
                started.enter_context(_held_at_forks(progress.live))
            total = total or None  # 0: not known in advance
            if name not in bars:
                bars[name] = progress.add_task(name, total=total)
            if note is not None:
                notes[name] = note
                progress.update(bars[name], description=f"{name} ({note})")
            progress.update(bars[name], completed=done, total=total)
            if stderr.is_terminal:
                return
            now = time.monotonic()
            then, before = last_line.get(name, (None, done))
            finished = total is not None and done >= total and before < total
            if then is None or now - then >= 60 or finished:
                rate = (done - before) / (now - then) if then is not None and now > then else None
                counted = unit_of(name)
                speed = ("" if rate is None else f", {rate:.1f} {counted}/s" if rate >= 1 or rate == 0
                         else f", {rate * 60:.1f} {counted}/min")  # none yet on a stage's first line
                left = (total - done) / rate if rate and total is not None and total > done else None
                eta = "" if left is None else f", about {left / 60:.0f} min left" if left >= 90 else f", about {left:.0f} s left"
                noted = f", {notes[name]}" if name in notes else ""
                of = "" if total is None else f"/{total}"
                print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {name}: {done}{of} {counted}{speed}{eta}{noted}",
                      file=sys.stderr, flush=True)
                last_line[name] = (now, done)

        yield report


@contextmanager
def _held_at_forks(live) -> Iterator[None]:
    """``live``'s lock (the one its refresh thread redraws under) held across every fork while in the block."""
    lock = getattr(live, "_lock", None)  # (rich's own; without it, forks go on as before)
    if lock is not None:
        _DISPLAY_LOCKS.append(lock)
    try:
        yield
    finally:
        if lock is not None:
            _DISPLAY_LOCKS.remove(lock)


def _stretches_said(stretches, far: float) -> str:
    """What a run's ID stretches say beside the threshold's target ``far``, as `run` and `replay`
    say it: '7 of 102 alarmed, 6.9% (95% interval 2.3%-15.1%, each episode's stretches counted as
    one cluster, design effect 1.1); target 0.05: consistent with the target'."""
    from oodmon.monitor.threshold import verdict_of

    verdict = {"above": "ABOVE the target", "below": "below the target",
               "consistent": "consistent with the target"}[verdict_of(stretches.low, stretches.high, far)]
    return (f"{stretches.alarmed:,} of {stretches.total:,} alarmed, {stretches.rate:.1%} (95% interval "
            f"{stretches.low:.1%}-{stretches.high:.1%}{_clustered('stretches', stretches.design_effect)}); target "
            f"{far:g}: {verdict}")


def _clustered(units: str, design_effect: float | None) -> str:
    """The words ', each episode's steps counted as one cluster, design effect 3.2' of an interval over
    units that come in episodes (``None``: independent episodes, no words)."""
    if design_effect is None:
        return ""
    return f", each episode's {units} counted as one cluster, design effect {design_effect:.3g}"
