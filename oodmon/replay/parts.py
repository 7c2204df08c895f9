"""A run's files as replay finds them: a split log's parts that it was not given (a file lost, or
left behind in a copy), and copies of a log that it was given twice.

A run split into files of whole episodes (``oodmon run --mcap-split-episodes N``,
``--mcap-split-mb``) writes ``<stem>-00000.mcap``, ``<stem>-00001.mcap``, ... each a complete log
with its part number (``part``) and, since 2026-11-29, its run's id (``run_id``). Each is read as
a log of its own, so a part missing from the folder would only make the rows hold fewer episodes,
in silence. :func:`missing_parts` names the parts below the highest one read that are not among
the logs: ``read_logs`` warns of them, and ``oodmon check`` says its rows lack their episodes. A
lost *last* part cannot be told from a run that ended before it. And a copy of a log under the
folder replayed (the same ``run_id`` and part in two files) would count its episodes twice:
:func:`without_copies` keeps one.
"""

from __future__ import annotations

import re
import warnings
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from oodmon.replay.reader import RunLog

__all__ = ["MissingParts", "missing_parts", "without_copies"]

_PART_NAME = re.compile(r"(?P<stem>.+)-(?P<part>\d{5,})")


@dataclass(frozen=True)
class MissingParts:
    """The parts of one split run that are not among the logs read, though a later part is."""

    read: tuple[Path, ...]  # the parts read, by part number
    missing: tuple[range, ...]  # the runs of part numbers not read, each below the highest read
    files: tuple[Path, ...]  # the files the run wrote the first few to (none if the parts read were renamed)
    episodes: int | None  # how many episodes they held, where the parts around them tell

    @property
    def count(self) -> int:
        """How many parts are missing."""
        return sum(len(numbers) for numbers in self.missing)

    def __str__(self) -> str:
        """E.g. ``part 1 (logs/run-00001.mcap) of the split log of logs/run-00000.mcap and 1 more
        part(s) is not among the logs read: the 2 episode(s) it held are not counted``."""
        one = self.count == 1
        numbers = ", ".join(str(r[0]) if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in self.missing)
        more = ", ..." if len(self.files) < self.count else ""
        where = f" ({', '.join(str(f) for f in self.files)}{more})" if self.files else ""
        read = f"{self.read[0]}" + (f" and {len(self.read) - 1} more part(s)" if len(self.read) > 1 else "")
        held = "its episodes" if self.episodes is None else f"the {self.episodes} episode(s) {'it' if one else 'they'} held"
        return (f"part{'' if one else 's'} {numbers}{where} of the split log of {read} {'is' if one else 'are'} not "
                f"among the logs read: {held} are not counted")


def missing_parts(logs: Iterable[RunLog]) -> list[MissingParts]:
    """The split runs among ``logs`` that lack a part below their highest one read.

    A run's parts are the logs with its ``run_id``; in logs written before it (2026-11-29), those
    of one folder whose names are ``<stem>-NNNNN`` of one stem and whose metadata but ``part`` are
    the same. A run whose part numbers repeat (two runs it cannot tell apart) is passed over.

    Example:
        >>> from oodmon.replay.reader import RunLog
        >>> def part(n):
        ...     return RunLog(Path(f"logs/run-{n:05d}.mcap"), "cartpole", "ensemble", 3.0,
        ...                   {"part": str(n), "run_id": "ab12"}, [], True)
        >>> [gap.missing for gap in missing_parts([part(0), part(2), part(3), part(7)])]
        [(range(1, 2), range(4, 7))]
        >>> missing_parts([part(0), part(1)])  # a lost last part cannot be told
        []
    """
    runs: dict[tuple, list[tuple[int, RunLog]]] = defaultdict(list)
    for log in logs:
        number = log.metadata.get("part", "")
        if not (number.isascii() and number.isdigit()):
            continue
        named = _PART_NAME.fullmatch(log.path.stem)
        if "run_id" in log.metadata:
            key: tuple = ("run_id", log.metadata["run_id"])
        else:
            same = tuple(sorted((k, v) for k, v in log.metadata.items() if k != "part"))
            key = ("named", log.path.parent.resolve(), named["stem"] if named else log.path.stem, log.path.suffix, same)
        runs[key].append((int(number), log))
    found = []
    for parts in runs.values():
        by_number = dict(parts)
        numbers = sorted(by_number)
        if len(numbers) < len(parts):
            continue
        gaps = [range(before + 1, after) for before, after in zip([-1, *numbers], numbers) if after > before + 1]
        if gaps:
            found.append(_gap(by_number, gaps))
    return found


def _gap(by_number: dict[int, RunLog], gaps: list[range]) -> MissingParts:
    """A run's missing parts (runs of numbers), the files they were written to and the episodes they held."""
    read = [by_number[n].path for n in sorted(by_number)]
    named = [_PART_NAME.fullmatch(p.stem) for p in read]
    places = {(p.parent, m["stem"] if m else None, p.suffix) for p, m in zip(read, named)}
    files: tuple[Path, ...] = ()
    if len(places) == 1 and None not in {stem for _, stem, _ in places}:
        ((folder, stem, suffix),) = places
        first = [n for numbers in gaps for n in numbers[:5]][:5]
        files = tuple(folder / f"{stem}-{n:05d}{suffix}" for n in first)
    episodes: int | None = 0
    for numbers in gaps:  # the episodes between the parts read around each run of missing ones
        first = _episode_numbers(by_number[numbers[-1] + 1])
        last = _episode_numbers(by_number[numbers[0] - 1]) if numbers[0] else [-1]
        if episodes is None or not first or not last:
            episodes = None
        else:
            episodes += min(first) - max(last) - 1
    return MissingParts(tuple(read), tuple(gaps), files, episodes)


def _episode_numbers(log: RunLog) -> list[int]:
    """The numbers of a log's episodes, ended or interrupted (a run numbers them on across its parts)."""
    return [episode.episode for episode in (*log.episodes, *log.interrupted)]


def without_copies(logs: list[RunLog]) -> list[RunLog]:
    """``logs`` with each run's log (or part) once: two files of one ``run_id`` and part are a copy
    (a backup folder beside the logs, both under the folder replayed), whose episodes would count
    twice. The one holding more complete episodes is kept, then a whole one (a finished log over a
    copy taken while it was written), the others skipped with a
    :class:`~oodmon.replay.reader.SkippedLogWarning` each."""
    from oodmon.replay.reader import SkippedLogWarning  # the reader imports this module

    by_run: dict[tuple[str, str], list[RunLog]] = {}
    for log in logs:
        if "run_id" in log.metadata:
            by_run.setdefault((log.metadata["run_id"], log.metadata.get("part", "")), []).append(log)
    skipped: set[int] = set()
    for (run_id, part), copies in by_run.items():
        if len(copies) == 1:
            continue
        kept = max(copies, key=lambda log: (len(log.episodes), log.complete))
        for log in copies:
            if log is not kept:
                skipped.add(id(log))
                why = (", which holds more episodes" if len(kept.episodes) > len(log.episodes)
                       else ", which is whole" if kept.complete and not log.complete else "")
                warnings.warn(f"skipped {log.path}: a copy of {kept.path} (the same run, {run_id[:8]}..."
                              f"{f', part {part}' if part else ''}){why}; its episodes are read once",
                              SkippedLogWarning, stacklevel=3)
    return [log for log in logs if id(log) not in skipped]
