"""Read the MCAP logs that ``oodmon run``, the demo or the bench wrote: files only, any machine.

A finished log has an index: replay reads each episode's ``/oodmon/episode`` message and its
``/oodmon/episode_scores`` arrays through it, without decoding step messages. An unfinished log
(a crashed run) has no index, or a torn one: replay streams it and keeps every episode whose
episode message and scores arrived before the tear, with a warning saying how much was
recovered; wherever the file ends. Chunks are read with their CRCs checked, so a damaged one
ends the readable part as a tear does instead of decoding as other scores. Only the JSON
topics replay needs are decoded; alarms (``foxglove.Log``) and frames (``foxglove.RawImage``) are
protobuf and are skipped. An episode the run was stopped inside (``interrupted``, Ctrl-C) is kept
apart in :attr:`RunLog.interrupted`, out of the metrics. Nothing is ever written into the input
files.
"""

from __future__ import annotations

import contextlib
import json
import math
import shlex
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import BinaryIO

import numpy as np

from oodmon.envs.readings import reading_names as layout_names
from oodmon.errors import LogFormatError
from oodmon.monitor import logformat
from oodmon.monitor.alarms import Region
from oodmon.monitor.logformat import decode_array
from oodmon.monitor.records import EpisodeRecord
from oodmon.replay.parts import missing_parts, without_copies
from oodmon.validation import is_finite_real, is_whole

__all__ = ["EpisodeLog", "MissingPartWarning", "NewerFormatWarning", "RecoveryWarning", "RunLog", "SkippedLogWarning",
           "read_compared", "read_frames", "read_log", "read_logs", "read_steps"]

_MAGIC = logformat.MCAP_MAGIC
#: How a Rerun recording (.rrd) begins ("RRF2" from rerun-sdk 0.41; the digit left out, so that
#: another version's is told too): a file a run wrote beside its MCAP log, handed to replay by mistake.
_RERUN_MAGIC = b"RRF"
_EPISODE, _SCORES, _STEP = logformat.EPISODE, logformat.EPISODE_SCORES, logformat.STEP
_START = logformat.EPISODE_START
_FRAME = logformat.FRAME


class RecoveryWarning(UserWarning):
    """A damaged log was read up to its last complete episode."""


class SkippedLogWarning(UserWarning):
    """A file was not read: named twice, or found in a folder but not an oodmon log."""


class MissingPartWarning(UserWarning):
    """A split log's part below the highest one read is not among the logs (:mod:`oodmon.replay.parts`)."""


class NewerFormatWarning(UserWarning):
    """A log was written in a newer log format than this oodmon knows; it is read as the newest it knows."""


@dataclass(frozen=True)
class EpisodeLog(EpisodeRecord):
    """One logged episode: its record and its per-step arrays.

    Attributes (besides :class:`~oodmon.monitor.records.EpisodeRecord`'s):
        scores: (length,) the uncertainty score of each step.
        shifted: (length,) whether each step's observation came from the shifted world.
        alarm: (length,) whether the alarm rule held at each step.
        detector_scores: every detector's (length,) scores by name; a log older than format 3
            has one, the alarm's (``spread``), equal to ``scores``.
        rewards: (length,) each step's reward, or ``None`` (logs older than format 4).
        ended_ns: when its record was logged, as it ended (the MCAP message's log time: the
            writing machine's clock, ns since 1970), or ``None`` (a log read from elsewhere).
    """

    scores: np.ndarray = field(repr=False, kw_only=True)
    shifted: np.ndarray = field(repr=False, kw_only=True)
    alarm: np.ndarray = field(repr=False, kw_only=True)
    detector_scores: dict[str, np.ndarray] = field(default_factory=dict, repr=False, kw_only=True)
    rewards: np.ndarray | None = field(default=None, repr=False, kw_only=True)
    ended_ns: int | None = field(default=None, repr=False, kw_only=True)

    def scores_of(self, detector: str | None) -> np.ndarray:
        """The per-step scores of ``detector`` (``None``: the alarm's).

        Raises:
            LogFormatError: the log has no scores of that detector.
        """
        if detector is None:
            return self.scores
        if detector not in self.detector_scores:
            from difflib import get_close_matches

            close = get_close_matches(detector, list(self.detector_scores), n=1)
            raise LogFormatError(f"episode {self.episode} has no scores of detector {detector!r}"
                                 + (f" (did you mean {close[0]!r}?)" if close else "")
                                 + f"; it has {', '.join(self.detector_scores) or 'none'}")
        return self.detector_scores[detector]


@dataclass(frozen=True)
class RunLog:
    """One log file: the run's metadata and its complete episodes.

    ``episodes`` holds the episodes that ended by themselves (or by an alarm callback);
    ``interrupted`` those the run was stopped inside, which metrics leave out.
    """

    path: Path
    task: str
    method: str
    threshold: float  # NaN: the run had no threshold, and so raised no alarms
    metadata: dict[str, str]
    episodes: list[EpisodeLog]
    complete: bool
    interrupted: list[EpisodeLog] = field(default_factory=list)

    @property
    def has_threshold(self) -> bool:
        """Whether the run compared its scores with a threshold (``oodmon run --threshold``): a run
        without one raised no alarms, so its alarm figures say nothing."""
        return not np.isnan(self.threshold)

    @property
    def detector(self) -> str:
        """The detector the run's alarm read (``spread`` in logs older than format 3)."""
        return self.metadata.get("detector", "spread")

    @cached_property
    def reading_names(self) -> tuple[str, ...]:
        """The names of a dict observation's readings, or of those its run was given, by index, as
        the run's detectors read them (``about.reading_names``, logs since 2026-12-07); none where
        the log records none, or a damaged record (what cannot be read says nothing). Read once."""
        try:
            names = json.loads(self.metadata.get("about.reading_names", "[]"))
        except (ValueError, RecursionError):
            return ()
        return tuple(names) if isinstance(names, list) and all(isinstance(n, str) for n in names) else ()

    def reading_names_of(self, episode: EpisodeLog) -> tuple[str, ...]:
        """The names of ``episode``'s readings by index: the log's own (:attr:`reading_names`), else
        those of its env's known layout (:func:`~oodmon.envs.readings.reading_names`)."""
        return self.reading_names or layout_names(episode.env_id)

    @property
    def noises(self) -> set[float]:
        """The sensor noises its complete episodes were played at (``obs_noise``; 0 before format 8)."""
        return {e.obs_noise for e in self.episodes}

    @property
    def detectors(self) -> list[str]:
        """Every detector whose scores the log holds."""
        named = self.metadata.get("detectors")
        return named.split(",") if named else [self.detector]


_ROW_FIELDS = {"episode": int, "env_id": str, "variant": str, "onset": int, "return": (int, float), "length": int,
               "alarms": int}


def _episode(path: Path, row: dict, arrays: dict, alarm_detector: str = "spread",
             ended_ns: int | None = None) -> EpisodeLog:
    """An episode from its record and its arrays (:func:`_decoded`'s keys), both checked;
    ``ended_ns``: its record's log time."""
    for name, kind in _ROW_FIELDS.items():
        if not isinstance(row.get(name), kind) or isinstance(row.get(name), bool):
            raise LogFormatError(f"{path}: episode record {row.get('episode', '?')!r} has {name}={row.get(name)!r}; "
                                 "not a log oodmon wrote (or a damaged one)")
    noise = row.get("obs_noise", 0.0)  # format 8; before it, none recorded
    if not is_finite_real(noise) or noise < 0:
        raise LogFormatError(f"{path}: episode record {row['episode']!r} has obs_noise={noise!r}; not a log oodmon "
                             "wrote (or a damaged one)")
    readings, readings_steps = _first_alarm_readings(path, row)
    region = _first_alarm_region(path, row)
    scores, shifted, alarm, rewards = arrays["score"], arrays["shifted"], arrays["alarm"], arrays["rewards"]
    detectors = arrays["detectors"] or {alarm_detector: scores}
    if any(len(a) != row["length"] for a in (scores, shifted, alarm, *detectors.values(),
                                             *([] if rewards is None else [rewards]))):
        raise LogFormatError(f"{path}: episode {row['episode']} has length {row['length']} but "
                             f"{len(scores)} scores; the log is damaged")
    return EpisodeLog(
        episode=row["episode"], env_id=row["env_id"], variant=row["variant"], onset=row["onset"],
        seed=row.get("seed"), total_return=float(row["return"]), length=row["length"], alarms=row["alarms"],
        first_alarm_step=row.get("first_alarm_step"), interrupted=bool(row.get("interrupted", False)),
        terminated=row.get("terminated") if isinstance(row.get("terminated"), bool) else None,
        first_alarm_cause=row.get("first_alarm_cause") if isinstance(row.get("first_alarm_cause"), str) else None,
        obs_noise=float(noise), first_alarm_readings=readings, first_alarm_readings_steps=readings_steps,
        first_alarm_region=region, scores=scores, shifted=shifted, alarm=alarm, detector_scores=detectors,
        rewards=rewards, ended_ns=ended_ns,
    )


def _first_alarm_readings(path: Path, row: dict) -> tuple[tuple[tuple[int, float], ...], int]:
    """An episode record's ``first_alarm_readings`` and ``first_alarm_readings_steps`` (format 10;
    none, over 1 step, in older logs), checked: pairs of a whole index and a finite residual."""
    readings, steps = row.get("first_alarm_readings", []), row.get("first_alarm_readings_steps", 1)
    pairs = readings if isinstance(readings, list) else [None]
    if not all(isinstance(pair, list) and len(pair) == 2 and is_whole(pair[0], 0) and is_finite_real(pair[1])
               for pair in pairs) or not is_whole(steps, 1):
        raise LogFormatError(f"{path}: episode record {row['episode']!r} has first_alarm_readings={readings!r} over "
                             f"{steps!r} steps; not a log oodmon wrote (or a damaged one)")
    return tuple((int(index), float(residual)) for index, residual in pairs), int(steps)


def _first_alarm_region(path: Path, row: dict) -> Region | None:
    """An episode record's ``first_alarm_region`` (format 12; ``None`` in older logs, and for
    none), checked: whole pixels inside a picture of at least one.

    Example:
        >>> _first_alarm_region(Path("x.mcap"), {"first_alarm_region": {"top": 28, "left": 21, "height": 7,
        ...                                      "width": 14, "rows": 84, "columns": 84}}).text()
        'rows 28-34, columns 21-34 of the 84x84 picture'
    """
    region = row.get("first_alarm_region")
    if region is None:
        return None
    fields = Region._fields
    if not (isinstance(region, dict) and set(region) == set(fields)
            and all(is_whole(region[name], 0) for name in fields)
            and all(is_whole(region[name], 1) for name in ("height", "width", "rows", "columns"))
            and region["top"] + region["height"] <= region["rows"]
            and region["left"] + region["width"] <= region["columns"]):
        raise LogFormatError(f"{path}: episode record {row.get('episode', '?')!r} has first_alarm_region={region!r}; "
                             "not a log oodmon wrote (or a damaged one)")
    return Region(*(int(region[name]) for name in fields))


class _Collector:
    """Gathers episode rows and score arrays (or, from older logs, step messages) by episode."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows: dict[int, dict] = {}
        self.scores: dict[int, list[dict]] = {}  # an episode's score messages: one, or its segments (format 6)
        self.steps: dict[int, list[dict]] = {}
        self.starts: dict[int, dict] = {}  # format 5: where each episode ran, from its first step
        self.ended: dict[int, int] = {}  # each episode record's log time
        # format 11: the step messages that raised an alarm, of episodes whose record has not come
        # (a torn log's running episode replays its first alarm's cause from one before its last segment)
        self.raised: dict[int, list[dict]] = {}

    def keep_raised(self, steps: list[bytes]) -> None:
        """Of step messages about to be dropped undecoded (:func:`_recover`), keep those that
        raised an alarm (``raised``, format 11; rare), for an episode whose record has not come."""
        for data in steps:
            if b'"raised"' in data:
                try:
                    row = json.loads(data)
                except (ValueError, UnicodeDecodeError):
                    continue
                if isinstance(row, dict) and isinstance(row.get("episode"), int) and row["episode"] not in self.rows:
                    self.raised.setdefault(row["episode"], []).append(row)

    def add(self, topic: str, data: bytes, log_time: int | None = None) -> None:
        """Keep one message of ``topic`` (logged at ``log_time``); messages of topics replay does
        not read are ignored without being decoded (alarms and frames are protobuf, not JSON)."""
        if topic not in (_EPISODE, _SCORES, _STEP, _START):
            return
        try:
            row = json.loads(data)
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise LogFormatError(f"{self.path}: a {topic} message is not JSON; not a log oodmon wrote (or a damaged "
                                 "one)") from None
        if not isinstance(row, dict) or not isinstance(row.get("episode"), int):
            raise LogFormatError(f"{self.path}: a {topic} message has no episode number; not a log oodmon wrote")
        if topic == _EPISODE:
            self.rows[row["episode"]] = row
            self.raised.pop(row["episode"], None)
            if log_time is not None:
                self.ended[row["episode"]] = int(log_time)
        elif topic == _SCORES:
            self.scores.setdefault(row["episode"], []).append(row)
        elif topic == _STEP:
            self.steps.setdefault(row["episode"], []).append(row)
        elif topic == _START:
            self.starts[row["episode"]] = row

    def arrays_of(self, episode: int) -> dict | None:
        """The episode's arrays (:func:`_decoded`'s keys): from its score message or segments, or
        from its step messages in logs older than format 2; ``None`` where they are not all there."""
        if episode in self.scores:
            messages = self.scores[episode]
            if len(messages) == 1 and "start" not in messages[0]:
                return _decoded(self.path, episode, messages[0])
            return _segments(self.path, episode, messages)
        steps = self.steps.get(episode)
        if not steps or len(steps) != self.rows[episode].get("length"):
            return None
        names = steps[0].get("scores", {}) if isinstance(steps[0].get("scores"), dict) else {}
        return _arrays([r["score"] for r in steps], [r["shifted"] for r in steps], [r["alarm"] for r in steps],
                       {name: [r.get("scores", {}).get(name, float("nan")) for r in steps] for name in names})


def _arrays(score, shifted, alarm, detectors: dict, rewards=None) -> dict:
    """An episode's arrays as :func:`_decoded` gives them, from sequences of numbers and flags."""
    return {"score": np.asarray(score, np.float64), "shifted": np.asarray(shifted, bool),
            "alarm": np.asarray(alarm, bool),
            "detectors": {name: np.asarray(values, np.float64) for name, values in detectors.items()},
            "rewards": None if rewards is None else np.asarray(rewards, np.float64)}


def _decoded(path: Path, episode: int, message: dict) -> dict:
    """An episode-scores message's arrays, decoded (``None`` for rewards it does not hold)."""
    try:
        return {"score": decode_array(message["score_f64"], "<f8"),
                "shifted": decode_array(message["shifted_u8"], np.uint8).astype(bool),
                "alarm": decode_array(message["alarm_u8"], np.uint8).astype(bool),
                "detectors": {name: decode_array(text, "<f8") for name, text in message.get("detectors_f64", {}).items()},
                "rewards": decode_array(message["reward_f64"], "<f8") if "reward_f64" in message else None}
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise LogFormatError(f"{path}: the score arrays of episode {episode} are damaged ({error})") from None


def _segments(path: Path, episode: int, messages: list[dict]) -> dict:
    """An episode's segments (format 6), decoded and joined in the order of their ``start``: the
    arrays of the steps from 0 on. Rewards only where every segment holds them.

    Raises:
        LogFormatError: segments that do not follow one another, or that hold other detectors.
    """
    if not all(isinstance(m.get("start", 0), int) for m in messages):
        raise LogFormatError(f"{path}: a score segment of episode {episode} has no whole start step; the log is damaged")
    messages = sorted(messages, key=lambda m: m.get("start", 0))
    parts = [_decoded(path, episode, m) for m in messages]
    at = 0
    for message, part in zip(messages, parts):
        if message.get("start", 0) != at or set(part["detectors"]) != set(parts[0]["detectors"]):
            raise LogFormatError(f"{path}: the score segments of episode {episode} do not follow one another "
                                 f"(one starts at step {message.get('start', 0)!r}, after {at} steps); the log is damaged")
        at += len(part["score"])
    return _joined(parts)


def _joined(parts: list[dict]) -> dict:
    """Arrays (:func:`_decoded`'s keys) of consecutive steps, one after the other; rewards only
    where every part has them."""
    rewards = None if any(p["rewards"] is None for p in parts) else np.concatenate([p["rewards"] for p in parts])
    return {"score": np.concatenate([p["score"] for p in parts]),
            "shifted": np.concatenate([p["shifted"] for p in parts]),
            "alarm": np.concatenate([p["alarm"] for p in parts]),
            "detectors": {name: np.concatenate([p["detectors"][name] for p in parts]) for name in parts[0]["detectors"]},
            "rewards": rewards}


def _format_version(metadata: dict[str, str] | None) -> int | None:
    """The log format a run's metadata records (``None``: none, as before format 3)."""
    version = (metadata or {}).get("format_version", "")
    return int(version) if version.isdigit() else None


def _assemble(path: Path, metadata: dict[str, str] | None, found: _Collector, complete: bool) -> RunLog:
    if metadata is None:
        raise LogFormatError(f"{path} is an MCAP file but not an oodmon log (no oodmon.run metadata)" + (
            "" if complete else ", or one cut off before its run metadata reached the disk"))
    version = _format_version(metadata)
    if version is not None and version > logformat.FORMAT_VERSION:
        writer = metadata.get("version.oodmon")
        warnings.warn(f"{path} is in log format {version}" + (f" (oodmon {writer})" if writer else "")
                      + f", newer than this oodmon's {logformat.FORMAT_VERSION}: it is read as format "
                      f"{logformat.FORMAT_VERSION}, and what is new in it is left out; upgrade oodmon to read it whole",
                      NewerFormatWarning, stacklevel=3)
    episodes, interrupted = [], []
    for k in sorted(found.rows):
        arrays = found.arrays_of(k)
        if arrays is not None:
            episode = _episode(path, found.rows[k], arrays, metadata.get("detector", "spread"), found.ended.get(k))
            (interrupted if episode.interrupted else episodes).append(episode)
    try:
        threshold = float(metadata.get("threshold", "nan"))
    except ValueError:
        raise LogFormatError(f"{path}: its run metadata has threshold={metadata['threshold']!r}, not a number") from None
    return RunLog(path, metadata.get("task", "unknown"), metadata.get("method", "unknown"), threshold, metadata,
                  episodes, complete, interrupted)


def read_log(path: str | Path) -> RunLog:
    """Read one oodmon MCAP log.

    Raises:
        LogFormatError: the file is missing, not MCAP, or not written by oodmon.

    Warns:
        RecoveryWarning: the file is unfinished or torn; its complete episodes are returned.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(_MAGIC))
    except FileNotFoundError:
        raise LogFormatError(f"{path} does not exist") from None
    except IsADirectoryError:
        raise LogFormatError(f"{path} is a folder; give the .mcap files in it") from None
    except OSError as error:
        raise LogFormatError(f"{path} cannot be read ({error.strerror or error})") from None
    if head.startswith(_RERUN_MAGIC):
        viewer = f"rerun {shlex.quote(str(path))}"
        raise LogFormatError(f"{path} is a Rerun recording, which the Rerun viewer shows ({viewer}); oodmon reads the "
                             "run's MCAP log (written with --mcap, McapSink)")
    if head != _MAGIC:
        raise LogFormatError(f"{path} is not an MCAP file (it does not start with the MCAP magic bytes)")
    indexed = _read_indexed(path)
    return _recover(path) if indexed is None else _assemble(path, *indexed, complete=True)


def _read_indexed(path: Path) -> tuple[dict[str, str] | None, _Collector] | None:
    """A finished log's run metadata and messages, read through its index; ``None`` where the
    index cannot be read: no index, or a torn or damaged one (the mcap library then raises
    McapError, EOFError, ValueError, OSError (a seek to a footer's bad offset), struct.error (a
    record cut short) or zstandard's error (a damaged chunk), depending on where the file ends).

    Raises:
        LogFormatError: a finished MCAP file that is not an oodmon log, or whose messages are not oodmon's.
    """
    from mcap.reader import make_reader

    found = _Collector(path)
    metadata = None
    with open(path, "rb") as f:
        try:
            reader = make_reader(f, validate_crcs=True)  # a damaged chunk fails its CRC instead of decoding as garbage
            summary = reader.get_summary()
            empty = summary is not None and summary.statistics is not None and summary.statistics.message_count == 0
            if summary is None or not (summary.chunk_indexes or empty):  # (a monitor closed before any episode: empty)
                return None
            for item in reader.iter_metadata():
                if item.name == logformat.RUN_METADATA:
                    metadata = dict(item.metadata)
            topics = {c.topic for c in summary.channels.values()}
            if _EPISODE not in topics:
                if metadata is not None:  # oodmon registers its channels as it opens the log: a damaged summary
                    return None
                raise LogFormatError(f"{path} is an MCAP file but not an oodmon log (no {_EPISODE} channel)")
            # Logs since the episode_scores channel: read it alone; older ones: the step messages.
            wanted = [_EPISODE, _SCORES] if _SCORES in topics else [_EPISODE, _STEP]
            for _, channel, message in reader.iter_messages(topics=wanted):
                found.add(channel.topic, message.data, message.log_time)
        except LogFormatError:
            raise
        except Exception:  # noqa: BLE001  (streaming the file keeps what is readable: see the docstring)
            return None
    return metadata, found


def _recover(path: Path) -> RunLog:
    """Stream an unfinished or torn file; keep the episodes that arrived whole."""
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader

    found = _Collector(path)
    metadata = None
    channels: dict[int, str] = {}
    torn = None
    # A log with episode scores (format 2 on) needs the step messages of the running episode at
    # the tear only: those since the last episode's scores are kept, undecoded, and the others
    # dropped as they pass (a torn log of a long run held them all, decoded: 619 MB for 43).
    since_scores: list[bytes] = []
    has_scores = False  # the file has an episode scores channel
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False, validate_crcs=True).records:
                if isinstance(record, Channel):
                    channels[record.id] = record.topic
                    has_scores = has_scores or record.topic == _SCORES
                elif isinstance(record, Metadata) and record.name == logformat.RUN_METADATA:
                    metadata = dict(record.metadata)
                elif isinstance(record, Message) and record.channel_id in channels:
                    topic = channels[record.channel_id]
                    if topic == _STEP and has_scores:
                        since_scores.append(record.data)
                        continue
                    if topic == _SCORES:
                        found.keep_raised(since_scores)
                        since_scores.clear()
                    found.add(topic, record.data, record.log_time)
        except LogFormatError:
            raise
        except Exception as error:  # noqa: BLE001  (a torn record ends the readable part)
            torn = error
    for data in since_scores:
        found.add(_STEP, data)
    log = _assemble(path, metadata, found, complete=False)
    cut = [episode for k in sorted(found.starts) if k not in found.rows
           and (episode := _cut_episode(path, found.starts[k], found.steps.get(k, []), log.detector,
                                        found.scores.get(k, []), found.raised.get(k, []))) is not None]
    log.interrupted.extend(cut)
    lost = ("; no step of a running episode had reached the disk (since format 5 they do every few seconds, "
            "McapSink(flush_seconds=...))" if (_format_version(metadata) or 0) >= 5
            else "; a running episode at the tear is lost")
    running = lost if not cut else "".join(
        f"; the running episode {e.episode} is kept as interrupted from its {e.length} steps on disk ({e.alarms} "
        f"alarm(s){'' if e.first_alarm_step is None else f', the first at step {e.first_alarm_step}'})" for e in cut)
    warnings.warn(
        f"{path} is unfinished or damaged ({type(torn).__name__ if torn else 'no summary'}): recovered "
        f"{len(log.episodes)} complete episode(s), {sum(e.length for e in log.episodes)} steps{running}",
        RecoveryWarning, stacklevel=3,
    )
    return log


def _cut_episode(path: Path, start: dict, steps: list[dict], alarm_detector: str,
                 segments: list[dict] = (), raised: list[dict] = ()) -> EpisodeLog | None:
    """The running episode of a torn log (format 5, whose start message says where it ran), from
    its segments' arrays on disk (format 6) and its step messages after them that reached the
    disk, up to a gap: interrupted (so out of the metrics), its return unknown (NaN: rewards come
    with the episode's end), its alarms the rises of the alarm flag, a step's ``null`` score +inf
    (what it stands for), its first alarm's cause and readings from the step message that raised
    it (``raised``: among ``steps``, or the ones of ``raised`` kept from before its last segment).
    ``None`` where no step of it is on disk or its start message is not one oodmon wrote."""
    episode = start.get("episode")
    try:
        done = _segments(path, episode, list(segments)) if segments else None
    except LogFormatError:
        return None  # damaged segments: the running episode stays lost
    first = 0 if done is None else len(done["score"])
    steps = sorted((r for r in steps if isinstance(r.get("step"), int) and r["step"] >= first), key=lambda r: r["step"])
    length = 0
    while length < len(steps) and steps[length]["step"] == first + length:  # up to a chunk that is not there
        length += 1
    if not first + length:
        return None
    steps = steps[:length]

    def numbers(values: list) -> list[float]:
        return [math.inf if v is None else float(v) for v in values]

    if done is not None:
        names = list(done["detectors"])
    else:
        names = list(steps[0]["scores"]) if isinstance(steps[0].get("scores"), dict) else []
    after = _arrays(numbers([r.get("score") for r in steps]), [bool(r.get("shifted")) for r in steps],
                    [bool(r.get("alarm")) for r in steps],
                    {name: numbers([(r.get("scores") or {}).get(name) for r in steps]) for name in names})
    arrays = after if done is None else _joined([done, after])  # the segments' steps first
    alarm = arrays["alarm"]
    rises = np.flatnonzero(alarm & ~np.concatenate([[False], alarm[:-1]]))
    row = {**start, "return": math.nan, "length": len(alarm), "alarms": len(rises),
           "first_alarm_step": int(rises[0]) if len(rises) else None, "interrupted": True}
    if len(rises):
        row |= _raised(path, episode, [*raised, *steps], int(rises[0]))
    try:
        return _episode(path, row, arrays, alarm_detector)  # the row's fields checked as every episode's
    except LogFormatError:
        return None  # a start message oodmon did not write: the running episode stays lost


def _raised(path: Path, episode: object, steps: list[dict], first: int) -> dict:
    """What a torn log's running episode's first alarm, at step ``first``, was raised by and
    which readings it named, as its episode message would have said (``first_alarm_cause``,
    ``first_alarm_readings``, ``first_alarm_readings_steps``, and where in the picture,
    ``first_alarm_region``, format 12), from that step's message (``raised``, format 11); nothing
    where that message is not among ``steps`` (it had not reached the disk), is of an older log, or
    is damaged (the episode is kept without them)."""
    raised = next((r.get("raised") for r in steps if r.get("step") == first), None)
    if not isinstance(raised, dict):
        return {}
    found = {"first_alarm_readings": raised.get("readings", []),
             "first_alarm_readings_steps": raised.get("readings_steps", 1),
             "first_alarm_region": raised.get("region")}
    try:
        _first_alarm_readings(path, {"episode": episode, **found})
        _first_alarm_region(path, {"episode": episode, **found})
    except LogFormatError:
        found = {}
    cause = raised.get("cause")
    return found | ({"first_alarm_cause": cause} if isinstance(cause, str) else {})


def _streamed(f: BinaryIO, topics: Sequence[str]) -> Iterator[tuple[str, bytes]]:
    """The messages of ``topics`` in the log open as ``f``, as (topic, data) in file order, streamed
    (what :func:`read_steps` and :func:`read_compared` read of a log, torn or whole). A torn or
    damaged record raises from the stream: the callers end their reading there (see
    :func:`_recover`)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    channels: dict[int, str] = {}
    for record in StreamReader(f, skip_magic=False, validate_crcs=True).records:
        if isinstance(record, Channel):
            channels[record.id] = record.topic
        elif isinstance(record, Message) and channels.get(record.channel_id) in topics:
            yield channels[record.channel_id], record.data


def read_steps(path: str | Path, episodes: Sequence[int], *, pictures: bool = False) -> dict[int, tuple]:
    """The observations and actions a log's step messages hold, ``(T, ...)`` each, of each of
    ``episodes`` (indices of whole episodes :func:`read_log` returned), in step order (a reading
    that was not finite: NaN): what the learned detectors are fitted on
    (:func:`oodmon.replay.fit_detectors_from_logs`). A picture's observation is logged as its
    frame (the newest of a stack, what the camera's detectors read): an episode whose steps hold
    frames and no readings gives its frames, ``(T, H, W)`` or ``(T, H, W, 3)`` bytes. With
    ``pictures``, each episode's frames come third beside its readings (a dict's picture beside
    its vectors), ``None`` where a step has none. The file is streamed, a torn one up to its tear
    (a whole episode's steps come before its end).

    Raises:
        LogFormatError: a step of those episodes with neither its observation nor a frame, or
            that ``read_log`` would not have read.
    """
    path, wanted = Path(path), set(episodes)
    steps: dict[int, list[tuple[int, list, object]]] = {k: [] for k in wanted}
    frames: dict[tuple[int, object], bytes] = {}  # (episode, step) -> the frame logged right after its step
    last = None
    with open(path, "rb") as f, contextlib.suppress(Exception):  # (a torn record, a damaged message: the end)
        for topic, data in _streamed(f, (_STEP, _FRAME)):
            if topic == _STEP:
                row = json.loads(data)
                last = None
                if row.get("episode") in wanted:
                    steps[row["episode"]].append((row.get("step"), row.get("observation"), row.get("action")))
                    last = (row["episode"], row.get("step"))
            elif last is not None:
                frames[last], last = data, None
    found = {}
    for k in sorted(wanted):
        rows = sorted(steps[k], key=lambda r: r[0] if isinstance(r[0], int) else -1)
        if not rows or [r[0] for r in rows] != list(range(len(rows))):
            raise LogFormatError(f"{path}: the steps of episode {k} are not all there")
        framed, unread = all((k, r[0]) in frames for r in rows), any(r[1] is None for r in rows)
        # (each message dropped as it is decoded: a long log's frames are in memory once, not thrice)
        seen = _pictures(path, k, [frames.pop((k, r[0])) for r in rows]) if framed and (pictures or unread) else None
        if unread:
            if framed:
                found[k] = (seen, _actions(path, k, rows)) + ((seen,) if pictures else ())
                continue
            raise LogFormatError(f"{path}: episode {k}'s steps hold no observation, nor a frame at every step: its "
                                 "detectors cannot be fitted from the log")
        try:  # (a reading that was not finite is logged as null)
            found[k] = (np.asarray([[math.nan if v is None else v for v in r[1]] for r in rows], np.float64),
                        _actions(path, k, rows)) + ((seen,) if pictures else ())
        except (ValueError, TypeError) as error:
            raise LogFormatError(f"{path}: episode {k}'s observations or actions are damaged ({error})") from None
    return found


def read_frames(path: str | Path, steps: Sequence[tuple[int, int]]) -> dict[tuple[int, int], np.ndarray]:
    """The frames a log holds of ``steps`` (``(episode, step)`` pairs: the picture the policy acted
    on there, ``(H, W)`` or ``(H, W, 3)`` bytes, as :func:`read_steps` gives them), those alone in
    memory; a step whose frame is not in the log (no picture logged, a tear before it, a damaged
    frame) is left out. The file is streamed, a torn one up to its tear."""
    wanted, found = set(steps), {}
    last = None
    with open(path, "rb") as f, contextlib.suppress(Exception):  # (a torn record, a damaged message: the end)
        for topic, data in _streamed(f, (_STEP, _FRAME)):
            if topic == _STEP:
                row = json.loads(data)
                last = (row.get("episode"), row.get("step")) if isinstance(row, dict) else None
            elif last in wanted:
                with contextlib.suppress(LogFormatError):
                    found[last] = _pictures(Path(path), last[0], [data])[0]
                last = None
    return found


def read_compared(path: str | Path, episodes: Sequence[int]) -> dict[int, np.ndarray]:
    """What the alarm rule compared with the threshold at each step of each of ``episodes`` (a
    log's step messages' ``compared``, format 9: a window's mean, a CUSUM or martingale
    statistic; ``null`` read as NaN), in step order; an episode whose steps do not all hold it
    (a log before format 9, a rule that compares each score, a step missing) is left out. The file
    is streamed, a torn one up to its tear."""
    wanted = set(episodes)
    rows: dict[int, dict[int, float]] = {k: {} for k in wanted}
    with open(path, "rb") as f, contextlib.suppress(Exception):  # (a torn record, a damaged message: the end)
        for _, data in _streamed(f, (_STEP,)):
            row = json.loads(data)
            value = row.get("compared", "absent")
            if row.get("episode") in wanted and isinstance(row.get("step"), int) and (value is None or (
                    isinstance(value, (int, float)) and not isinstance(value, bool))):
                rows[row["episode"]][row["step"]] = math.nan if value is None else float(value)
    return {k: np.array([steps[t] for t in range(len(steps))]) for k, steps in rows.items()
            if steps and sorted(steps) == list(range(len(steps)))}


def _actions(path: Path, episode: int, rows: list[tuple[int, list, object]]) -> np.ndarray:
    """An episode's logged actions, one per step row."""
    try:
        return np.asarray([r[2] for r in rows])
    except (ValueError, TypeError) as error:
        raise LogFormatError(f"{path}: episode {episode}'s actions are damaged ({error})") from None


def _pictures(path: Path, episode: int, messages: list[bytes]) -> np.ndarray:
    """An episode's logged frames (``foxglove.RawImage``, mono8 or rgb8) as one array of bytes,
    ``(T, H, W)`` or ``(T, H, W, 3)``; each of ``messages`` (at least one) is dropped from the list
    as it is decoded.

    Raises:
        LogFormatError: a frame that is not one of those, or frames of two shapes.
    """
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    pictures = None  # filled in place, one frame at a time (np.stack of a list held each frame twice)
    for step in range(len(messages)):
        image = RawImage()
        try:
            image.ParseFromString(messages[step])
        except Exception as error:  # (protobuf's DecodeError)
            raise LogFormatError(f"{path}: a frame of episode {episode} is damaged ({error})") from None
        messages[step] = None
        channels = {"mono8": 1, "rgb8": 3}.get(image.encoding)
        if channels is None or image.step != image.width * channels or len(image.data) != image.height * image.step:
            raise LogFormatError(f"{path}: a frame of episode {episode} is not a mono8 or rgb8 picture oodmon wrote "
                                 f"({image.encoding!r}, {image.width} x {image.height})")
        shape = (image.height, image.width) + ((3,) if channels == 3 else ())
        if pictures is None:
            pictures = np.empty((len(messages), *shape), np.uint8)
        elif pictures.shape[1:] != shape:
            raise LogFormatError(f"{path}: the frames of episode {episode} are of two shapes")
        pictures[step] = np.frombuffer(image.data, np.uint8).reshape(shape)
    return pictures


def read_logs(paths: Sequence[str | Path]) -> list[RunLog]:
    """Read the logs named by ``paths``: MCAP files, or folders searched for ``*.mcap``.

    Each file is read once, however often it is named (as itself or inside a folder). A file
    inside a folder that is not an oodmon log (a foreign MCAP, a damaged file) is skipped with a
    :class:`SkippedLogWarning`; a file named on its own must be an oodmon log. A copy of a log read
    (another file of the same ``run_id`` and part) is skipped with one too. A split log whose
    parts read skip one (:func:`~oodmon.replay.parts.missing_parts`) gives a :class:`MissingPartWarning`.

    Raises:
        LogFormatError: a named file that is not an oodmon log, a folder with no ``.mcap`` file,
            or no oodmon log at all.
    """
    files: list[tuple[Path, bool]] = []
    seen: set[Path] = set()
    for name in paths:
        path = Path(name)
        named = not path.is_dir()
        found = [path] if named else sorted(path.rglob("*.mcap"))
        if not named and not found:
            recordings = "" if next(path.rglob("*.rrd"), None) is None else (
                " (its .rrd files are Rerun recordings, which the Rerun viewer shows; oodmon reads a run's MCAP log, "
                "written with --mcap)")
            raise LogFormatError(f"{path} holds no .mcap files{recordings}")
        for file in found:
            key = file.resolve()
            if key in seen:
                warnings.warn(f"{file} is named more than once; it is read once", SkippedLogWarning, stacklevel=2)
                continue
            seen.add(key)
            files.append((file, named))
    logs = []
    for file, named in files:
        try:
            logs.append(read_log(file))
        except LogFormatError as error:
            if named:
                raise
            warnings.warn(f"skipped {file}: {error}", SkippedLogWarning, stacklevel=2)
    if not logs:
        raise LogFormatError(f"no oodmon log among {', '.join(str(p) for p in paths)}")
    logs = without_copies(logs)
    for gap in missing_parts(logs):
        warnings.warn(str(gap), MissingPartWarning, stacklevel=2)
    return logs

