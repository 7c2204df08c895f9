"""A shell command run at each episode's first alarm: a page, a message, a hand-over to a safe controller.

An alarm that only a terminal or a log shows waits for someone to look. :class:`AlarmCommand` is an
alarm callback (``Monitor(callbacks=[...])``; ``oodmon run --on-alarm CMD``) that starts a command
of yours the moment an episode's first alarm is raised, with what the alarm says in its
environment (``OODMON_EPISODE``, ``OODMON_STEP``, ``OODMON_SCORE``, ``OODMON_THRESHOLD``,
``OODMON_RULE``, ``OODMON_CAUSE``, ``OODMON_READINGS``: the readings the dynamics model predicted
worst, ``index:residual`` each, space-separated, ``AlarmEvent.readings``, over
``OODMON_READINGS_STEPS`` steps, and ``OODMON_READING_NAMES`` their names, a JSON list in their
order, ``""`` where one has none, ``AlarmEvent.reading_names``; ``OODMON_REGION``: where in the
picture, a JSON object of ``AlarmEvent.region``'s fields, ``top``, ``left``, ``height``,
``width``, ``rows``, ``columns``, empty where it has none; ``OODMON_ALARM``: the alarm's line).
It does not wait for the
command: the policy acts on while it runs, as a sink's failure does not stop the loop
(``docs/monitor.md``). :meth:`AlarmCommand.close` waits for the commands still running (for at most
``wait`` seconds) and says how they ended; a command that cannot start, or exits other than 0, is
a warning (:class:`AlarmCommandWarning`), never an error of the run.

Once an episode, not at every alarm: the rule fires again each time the score comes back above the
threshold (CartPole episodes of a longer pole raised 8-11 alarms each, 2026-12-05), and a page per
rise would bury the first.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
import warnings
from collections.abc import Mapping

from oodmon.errors import InvalidParameterError
from oodmon.monitor.alarms import AlarmEvent
from oodmon.validation import is_real

__all__ = ["AlarmCommand", "AlarmCommandWarning"]


class AlarmCommandWarning(UserWarning):
    """An alarm's command could not start, exited other than 0, or was still running when waited for."""


class AlarmCommand:
    """Runs ``command`` through the shell (``/bin/sh -c``) at the first alarm of each episode.

    Args:
        command: the shell command, e.g. ``'notify-send "OOD: $OODMON_ALARM"'``.
        env: more variables for its environment (``oodmon run`` gives ``OODMON_VARIANT`` and
            ``OODMON_LOG``), beside the process's own and the alarm's.
        wait: the seconds :meth:`close` waits for the commands still running, all together.

    As a context manager it closes at the end of the block, however the block ends, and keeps what
    :meth:`close` said in :attr:`summary`.

    Raises:
        InvalidParameterError: an empty command, ``env`` not a dict of names, or ``wait`` not a
            number >= 0.

    Example:
        >>> import pathlib, tempfile
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "alarms.txt"
        >>> command = AlarmCommand(f'echo "$OODMON_EPISODE $OODMON_STEP $OODMON_CAUSE" >> {out}')
        >>> command(AlarmEvent(0, 41, 7.25, 4.5, "score > threshold", "dynamics"))
        >>> command(AlarmEvent(0, 60, 8.0, 4.5, "score > threshold", "dynamics"))  # episode 0 again: not run
        >>> command.close(), out.read_text()
        ('ran 1 time (episode 0), each exited 0', '0 41 dynamics\\n')
    """

    def __init__(self, command: str, *, env: Mapping[str, str] | None = None, wait: float = 10.0) -> None:
        if not isinstance(command, str) or not command.strip():
            raise InvalidParameterError(f"command={command!r} is not allowed; give a shell command to run at an "
                                        "episode's first alarm, e.g. 'notify-send \"$OODMON_ALARM\"'")
        if not is_real(wait) or not wait >= 0:
            raise InvalidParameterError(f"wait={wait!r} is not allowed; give the seconds to wait for running "
                                        "commands at close, a number >= 0")
        if env is not None and not (isinstance(env, Mapping) and all(isinstance(k, str) and k and "=" not in k
                                                                     for k in env)):
            raise InvalidParameterError(f"env={env!r:.60} is not allowed; give the command's extra environment "
                                        "variables as a dict of names (no '=') to values")
        self.command, self.wait = command, float(wait)
        self.env = {k: str(v) for k, v in (env or {}).items()}
        self._running: list[tuple[int, subprocess.Popen]] = []  # (episode, process)
        self._done: list[tuple[int, int]] = []  # (episode, exit code)
        self._episodes: set[int] = set()  # the episodes whose first alarm ran it (or tried to)
        self.summary: str | None = None  # what close() said last

    def __enter__(self) -> AlarmCommand:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __call__(self, event: AlarmEvent) -> None:
        self._reap()
        if event.episode in self._episodes:
            return None
        self._episodes.add(event.episode)
        variables = {"OODMON_EPISODE": str(event.episode), "OODMON_STEP": str(event.step),
                     "OODMON_SCORE": repr(float(event.score)), "OODMON_THRESHOLD": repr(float(event.threshold)),
                     "OODMON_RULE": event.rule, "OODMON_CAUSE": event.cause,
                     "OODMON_READINGS": " ".join(f"{index}:{residual!r}" for index, residual in event.readings),
                     "OODMON_READINGS_STEPS": str(event.readings_steps),
                     "OODMON_READING_NAMES": json.dumps([event.reading_names[k] if k < len(event.reading_names) else ""
                                                         for k in range(len(event.readings))]),
                     "OODMON_REGION": "" if event.region is None else json.dumps(event.region._asdict()),
                     "OODMON_ALARM": event.text()}
        try:
            # a session of its own: a Ctrl-C meant for the monitor does not cut a page half sent
            process = subprocess.Popen(self.command, shell=True, stdin=subprocess.DEVNULL, start_new_session=True,
                                       env={**os.environ, **self.env, **variables})
        except OSError as error:  # no shell to run it (the command's own errors are its exit code)
            warnings.warn(AlarmCommandWarning(f"the alarm command of episode {event.episode} could not start: "
                                              f"{error}"), stacklevel=2)
            return None
        self._running.append((event.episode, process))
        return None  # the episode goes on: ending it is for a callback that returns True

    def _reap(self) -> None:
        """Collect the exit codes of the commands that have ended (no process is left a zombie)."""
        still = []
        for episode, process in self._running:
            code = process.poll()
            if code is None:
                still.append((episode, process))
            else:
                self._done.append((episode, code))
        self._running = still

    def close(self) -> str:
        """Wait for the commands still running, for at most ``wait`` seconds in all, and say how
        they ended (one line); a command that exited other than 0, or still runs, is warned of
        (a running one is left running). A second call says it again, of every command run so far."""
        deadline = time.monotonic() + self.wait
        for _, process in self._running:
            try:
                process.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        self._reap()
        self.summary = self._said()
        return self.summary

    def _said(self) -> str:
        """How the commands ended, in one line; the warnings of those that failed or still run."""
        ran = len(self._done) + len(self._running)
        if not ran:
            return "never ran (no alarm)" if not self._episodes else "never started (see the warnings above)"
        episodes = sorted(e for e, _ in self._done) + sorted(e for e, _ in self._running)
        shown = ", ".join(str(e) for e in episodes[:5]) + (", ..." if len(episodes) > 5 else "")
        failed = [(e, code) for e, code in sorted(self._done) if code != 0]
        said = f"ran {ran} time{'s' if ran != 1 else ''} (episode{'s' if ran != 1 else ''} {shown})"
        if failed:
            codes = "; ".join(f"episode {e}: exit {code}" for e, code in failed[:3])
            codes += "; ..." if len(failed) > 3 else ""
            warnings.warn(AlarmCommandWarning(f"the alarm command exited other than 0 {len(failed)} time(s) ({codes})"),
                          stacklevel=3)
            said += f", {len(failed)} exited other than 0"
        if self._running:
            warnings.warn(AlarmCommandWarning(
                f"{len(self._running)} alarm command(s) still running after {self.wait:g} s (episodes "
                f"{', '.join(str(e) for e, _ in self._running[:5])}); left running"), stacklevel=3)
            said += f", {len(self._running)} still running"
        return said if failed or self._running else said + ", each exited 0"
