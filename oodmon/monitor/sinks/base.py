"""The sink interface, the in-memory sink, and the group that keeps a failing sink from
stopping the control loop."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import BinaryIO, Protocol

from oodmon.errors import ConfigError
from oodmon.monitor.alarms import AlarmEvent
from oodmon.monitor.records import EpisodeRecord, EpisodeSegment, EpisodeStart, RunInfo, StepRecord

__all__ = ["SINK_METHODS", "MemorySink", "Sink", "SinkGroup", "SinkWarning", "check_existing", "claim_file",
           "refuse_earlier_logs", "refuse_other_files"]


def refuse_earlier_logs(earlier: list[Path], remedy: str) -> None:
    """Raise :class:`~oodmon.errors.ConfigError` if ``earlier`` (files an earlier run left where a log
    is to be written) is not empty, naming the first and ``remedy`` (how to replace them anyway):
    a run started again after a crash must not replace the log of the run that crashed."""
    if earlier:
        from oodmon.errors import ConfigError

        more = f" (and {len(earlier) - 1} more part(s) of a split log)" if len(earlier) > 1 else ""
        raise ConfigError(f"{earlier[0]} exists{more}: the log of an earlier run; give another path, or {remedy} "
                          "to replace it")


def refuse_other_files(paths: list[Path], magic: bytes, kind: str) -> None:
    """Raise :class:`~oodmon.errors.ConfigError` if a file of ``paths`` (files a sink would write
    onto) is not a log of its ``kind``: it does not begin with ``magic`` (an empty file, or one that
    stops within it, is a log torn at its start). Even ``overwrite=True`` replaces only logs: a
    model or a threshold at the path is a name typed wrong, and would be lost. A folder there is
    refused too: no file can take its place."""
    from oodmon.errors import ConfigError
    from oodmon.jsonfile import special_file

    for path in paths:
        if path.is_dir():
            raise ConfigError(f"{path} is a folder; give the log a file name (in it, say)")
        special = special_file(path)
        if special is not None:  # /dev/null reads as an empty file, a log torn at its start, which overwrite removed
            raise ConfigError(f"{path} is {special}, not a file: a log written there would remove it; give a file name")
        try:
            with open(path, "rb") as file:
                head = file.read(len(magic))
        except OSError:  # a file it may not read: the write says why
            continue
        if not magic.startswith(head):
            raise ConfigError(f"{path} exists and is not {kind} (it begins {head!r}): a log written there would "
                              "replace it; give another path")


def check_existing(paths: list[Path], *, magic: bytes, kind: str, overwrite: bool, remedy: str) -> None:
    """A sink's check of the files already where it writes (``paths``), when it is made and at
    open: any that is no log of its ``kind`` is refused (:func:`refuse_other_files`), and without
    ``overwrite`` any at all (:func:`refuse_earlier_logs`, naming ``remedy``)."""
    refuse_other_files(paths, magic, kind)
    if not overwrite:
        refuse_earlier_logs(paths, remedy)


def claim_file(path: Path) -> BinaryIO:
    """``path`` opened for writing if no file is there, in one step (``O_EXCL``): a run whose check
    found none cannot then write into another's. Two ``oodmon run`` with one log name, started
    together, both passed the checks before either wrote, and wrote one file between them that
    replay could not read (measured: "an MCAP file but not an oodmon log"); now the later one's
    sink fails, saying so.

    Raises:
        ConfigError: a file came to ``path`` since this run checked it.
    """
    try:
        return open(path, "xb")
    except FileExistsError:
        from oodmon.errors import ConfigError

        raise ConfigError(f"{path} appeared after this run checked it (another run writing there?): not written "
                          "over; give each run a log of its own ({start} in oodmon run's names)") from None


class Sink(Protocol):
    """Where the monitor's records go. Every method may raise; :class:`SinkGroup` contains it.

    A sink may also have ``begin_episode(start: EpisodeStart)``, called with an episode's first
    step, before it (:class:`~oodmon.monitor.sinks.mcap.McapSink` logs it), and
    ``write_segment(segment: EpisodeSegment)``, called every ``Monitor(segment_steps=)`` steps of a
    long episode and at its end (``McapSink`` writes the segment's arrays and drops them); sinks
    without them are not asked.
    """

    def open(self, run: RunInfo) -> None: ...
    def write_step(self, record: StepRecord) -> None: ...
    def write_alarm(self, event: AlarmEvent) -> None: ...
    def end_episode(self, record: EpisodeRecord) -> None: ...
    def close(self) -> None: ...


#: The methods every :class:`Sink` has, which :class:`SinkGroup` checks its sinks for.
SINK_METHODS = ("open", "write_step", "write_alarm", "end_episode", "close")


class MemorySink:
    """Keeps every record in lists; for tests and notebooks.

    Example:
        >>> sink = MemorySink()
        >>> sink.steps, sink.episodes, sink.alarms
        ([], [], [])
    """

    def __init__(self) -> None:
        self.run: RunInfo | None = None
        self.steps: list[StepRecord] = []
        self.alarms: list[AlarmEvent] = []
        self.episodes: list[EpisodeRecord] = []
        self.closed = False

    def open(self, run: RunInfo) -> None:
        self.run = run

    def write_step(self, record: StepRecord) -> None:
        self.steps.append(record)

    def write_alarm(self, event: AlarmEvent) -> None:
        self.alarms.append(event)

    def end_episode(self, record: EpisodeRecord) -> None:
        self.episodes.append(record)

    def close(self) -> None:
        self.closed = True


class SinkWarning(RuntimeWarning):
    """A sink failed; the monitor goes on without the record it could not write."""


class SinkGroup:
    """Calls every sink; a sink that raises is warned about and counted, and the others go on.

    With ``strict=True`` the first failure is raised instead (tests, CI). A sink that failed to
    write keeps being called: a full disk may have room again at the next episode. A sink whose
    ``open`` failed is left out of the run but for its ``close`` (it has nowhere to write: each of
    its calls failed again, warned as "'McapSink' object has no attribute '_part'").
    """

    def __init__(self, sinks: list[Sink], *, strict: bool = False) -> None:
        self.sinks = list(sinks)
        for sink in self.sinks:  # else each of its calls failed as a warning, and the run logged nothing there
            lacking = [method for method in SINK_METHODS if not callable(getattr(sink, method, None))]
            if lacking:
                raise ConfigError(f"sinks holds {sink!r:.60}, which is no sink (it lacks {', '.join(lacking)}): give "
                                  "McapSink, RerunSink or MemorySink objects, or your own with the Sink methods")
        self.strict = strict
        self.failures: dict[str, int] = {}
        self._unopened: set[int] = set()  # the ids of the sinks whose open failed in this run

    def _call(self, method: str, *args: object, sinks: list[Sink] | None = None) -> None:
        for sink in self.sinks if sinks is None else sinks:
            if self._unopened and method != "close" and id(sink) in self._unopened:
                continue
            try:
                getattr(sink, method)(*args)
            except Exception as error:  # noqa: BLE001  (any failure of a sink is contained)
                if self.strict:
                    raise
                name = type(sink).__name__
                self.failures[name] = self.failures.get(name, 0) + 1
                left_out = method == "open"
                if left_out:
                    self._unopened.add(id(sink))
                if self.failures[name] == 1 or self.failures[name] % 1000 == 0 or left_out:
                    warnings.warn(f"{name}.{method} failed ({error}); {self.failures[name]} failure(s) so far, "
                                  + ("it is left out of this run, " if left_out else "") + "the monitor goes on",
                                  SinkWarning, stacklevel=3)

    def open(self, run: RunInfo) -> None:
        self._unopened = set()  # a Monitor opened again: each sink is tried again
        self._call("open", run)

    def begin_episode(self, start: EpisodeStart) -> None:
        # optional: a sink of your own need not have it
        self._call("begin_episode", start, sinks=[sink for sink in self.sinks if hasattr(sink, "begin_episode")])

    def write_step(self, record: StepRecord) -> None:
        self._call("write_step", record)

    def write_segment(self, segment: EpisodeSegment) -> None:
        # optional, as begin_episode
        self._call("write_segment", segment, sinks=[sink for sink in self.sinks if hasattr(sink, "write_segment")])

    def write_alarm(self, event: AlarmEvent) -> None:
        self._call("write_alarm", event)

    def end_episode(self, record: EpisodeRecord) -> None:
        self._call("end_episode", record)

    def close(self) -> None:
        self._call("close")
