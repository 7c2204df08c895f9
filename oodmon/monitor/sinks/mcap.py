"""Log a monitored run to an MCAP file that replay, Foxglove and Rerun can read.

Channels (their schemas and encodings are defined once, in :mod:`oodmon.monitor.logformat`):

- ``/oodmon/step``: JSON (schema ``oodmon.Step``, JSON Schema), one message per step.
- ``/oodmon/episode_start``: JSON (schema ``oodmon.EpisodeStart``), one message per episode, with
  its first step: its env, variant, onset and seed.
- ``/oodmon/episode``: JSON (schema ``oodmon.Episode``), one message per finished episode.
- ``/oodmon/alarm``: ``foxglove.Log`` (protobuf), one message per alarm, level WARNING.
- ``/oodmon/frame``: ``foxglove.RawImage`` (protobuf), the frame the agent saw (Pong, mono8), or with
  ``Monitor(render=True)`` a picture of a CartPole or Pendulum state (rgb8).
- ``/oodmon/episode_scores``: JSON (schema ``oodmon.EpisodeScores``), one message per episode
  with its per-step score (float64), shifted and alarm flags (uint8), and every detector's scores,
  as base64 arrays. With the
  episode message it is written in a chunk of its own, so that replay reads an episode through
  the file's index without decompressing its step messages.

The run's :class:`~oodmon.monitor.records.RunInfo` is the metadata record ``oodmon.run``, on disk
from :meth:`McapSink.open` on. The writer flushes (closes its chunk and hands it to the operating
system) at every episode end, and within an episode every ``flush_seconds`` (10 s by default),
so a crash, even SIGKILL, loses at most the last seconds of the running episode, which replay
keeps as interrupted; ``close`` writes the summary and index. A long run can be split into files
of whole episodes (``split_episodes``, ``split_mb``; see :class:`McapSink`).
"""

from __future__ import annotations

import glob
import json
import math
import time
import uuid
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.monitor import logformat

#: A Foxglove (or Lichtblick) layout for these logs: score, threshold and every detector plotted,
#: the frames, the alarms. Layouts -> Import from file.
FOXGLOVE_LAYOUT = Path(__file__).with_name("foxglove_layout.json")
from oodmon.monitor.alarms import AlarmEvent, compared_name
from oodmon.monitor.logformat import (
    EPISODE_SCHEMA, EPISODE_SCORES_SCHEMA, EPISODE_START_SCHEMA, MCAP_MAGIC, STEP_SCHEMA,
)
from oodmon.monitor.records import EpisodeRecord, EpisodeSegment, EpisodeStart, RunInfo, StepRecord
from oodmon.monitor.sinks.base import check_existing, claim_file

__all__ = ["EPISODE_SCHEMA", "EPISODE_SCORES_SCHEMA", "EPISODE_START_SCHEMA", "STEP_SCHEMA",
           "McapSink", "existing_parts", "part_path"]  # schemas re-exported


def part_path(path: str | Path, part: int, *, splits: bool) -> Path:
    """The file of part ``part`` (counted from 0) of a log split into parts (``splits``) named after
    ``path`` (``run.mcap``: ``run-00000.mcap``, ...); ``path`` itself if it is not split."""
    path = Path(path)
    return path.with_name(f"{path.stem}-{part:05d}{path.suffix}") if splits else path


def existing_parts(path: str | Path, *, splits: bool) -> list[Path]:
    """The files on disk a log at ``path`` would be written onto: ``path``, or every part of a split
    log of its name (any part number, in order)."""
    path = Path(path)
    if not splits:
        return [path] if path.exists() else []
    pattern = f"{glob.escape(path.stem)}-{'[0-9]' * 5}{glob.escape(path.suffix)}"
    return sorted(path.parent.glob(pattern))


def _json_number(value: float) -> float | None:
    """``value``, or ``None`` where it is not finite: NaN (no threshold) and infinity (the score of a
    NaN observation) are not JSON, and Foxglove's parser refuses them."""
    return value if math.isfinite(value) else None


_FLOAT = float.__repr__  # what json.dumps writes for a float (np.float64 too, whose own repr is np.float64(...))
_KEYS: dict[str, str] = {}  # a detector's name as a JSON string, made once


def _floats(values) -> str:
    """The floats of ``values`` as json.dumps writes them, joined by its ", "; a value that is not a
    float (an int, np.float32) raises TypeError."""
    return ", ".join(map(_FLOAT, values))


def _step_json(record: StepRecord, compares: bool = False) -> str:
    """A step's message, every non-finite number written as ``null`` (the score arrays keep them):
    the bytes of ``json.dumps(record.to_json())`` with those nulls (:func:`_step_json_dumps`), and
    last what the alarm rule compared with the threshold (``compared``, format 9) where that is
    not the score (``compares``: a window's mean, a sequential rule's statistic).

    Written out for the usual step (whole numbers that are ints, the rest floats in lists or alone,
    all finite), without json.dumps's walk over a dict: at every step this is the MCAP sink's
    largest cost, in the monitor's loop of the shipped CartPole ensemble 12.5 us a step against
    json.dumps's 16.5 (2026-11-30; alone 6.3 us against 8.6: most of either is the floats'
    shortest repr). Any other step, a NaN or infinite number among its floats (a finite repr has
    no "n"), and the step that raised an alarm (``raised``), go through json.dumps."""
    try:
        episode, step, action, alarm, shifted = record.episode, record.step, record.action, record.alarm, record.shifted
        mean, std, observation = record.mean, record.std, record.observation
        if type(episode) is not int or type(step) is not int or type(alarm) is not bool or type(shifted) is not bool \
                or type(mean) is not list or type(std) is not list or (observation is not None and type(observation) is not list):
            return _step_json_dumps(record, compares)
        if record.raised is not None:  # the step that raised an alarm (format 11): rare
            return _step_json_dumps(record, compares)
        if type(action) is int:
            action_text = int.__repr__(action)
        elif type(action) is list:
            action_text = f"[{_floats(action)}]"
        else:
            return _step_json_dumps(record, compares)
        mean_text, std_text, score_text = _floats(mean), _floats(std), _FLOAT(record.score)
        threshold = record.threshold
        text = (f'{{"episode": {int.__repr__(episode)}, "step": {int.__repr__(step)}, "action": {action_text}, '
                f'"mean": [{mean_text}], "std": [{std_text}], "score": {score_text}, '
                f'"threshold": {_FLOAT(threshold) if math.isfinite(threshold) else "null"}, '
                f'"alarm": {"true" if alarm else "false"}, "shifted": {"true" if shifted else "false"}')
        numbers = [action_text, mean_text, std_text, score_text]  # the texts a NaN or an infinity would be in
        if observation is not None:
            observation_text = _floats(observation)
            numbers.append(observation_text)
            text += f', "observation": [{observation_text}]'
        if record.scores:
            parts = []
            for name, value in record.scores.items():
                key = _KEYS.get(name)
                if key is None:
                    if type(name) is not str:  # json.dumps writes a number's key in quotes
                        return _step_json_dumps(record, compares)
                    key = _KEYS[name] = json.dumps(name)
                value_text = _FLOAT(value)
                numbers.append(value_text)
                parts.append(f"{key}: {value_text}")
            text += f', "scores": {{{", ".join(parts)}}}'
        if compares:  # NaN until a window fills: null, as the threshold's
            compared = record.compared
            text += f', "compared": {_FLOAT(compared) if math.isfinite(compared) else "null"}'
    except TypeError:  # a number that is not a float where one is expected: json.dumps says what it makes of it
        return _step_json_dumps(record, compares)
    if "n" in "".join(numbers):  # nan, inf: nulls
        return _step_json_dumps(record, compares)
    return text + "}"


def _step_json_dumps(record: StepRecord, compares: bool = False) -> str:
    """:func:`_step_json` by json.dumps, for any step."""
    data = record.to_json()
    data["threshold"] = _json_number(data["threshold"])  # NaN in every run without a threshold
    if compares:
        data["compared"] = _json_number(record.compared)
    text = json.dumps(data)
    if "NaN" not in text and "Infinity" not in text:  # json.dumps's words for them; no key holds them
        return text
    data["score"] = _json_number(data["score"])  # a NaN observation: scores +inf, its samples NaN
    for name in ("mean", "std", "observation"):
        if name in data:
            data[name] = [_json_number(value) for value in data[name]]
    if "scores" in data:
        data["scores"] = {name: _json_number(value) for name, value in data["scores"].items()}
    return json.dumps(data)


class McapSink:
    """Writes the run to ``path`` (created with its folder).

    A file already at ``path`` (or a part of a split log of its name) is the log of an earlier run,
    and the sink refuses it (:class:`~oodmon.errors.ConfigError`, when it is made): a deployment
    started again after a crash would otherwise replace the log that holds the crash's alarms.
    ``overwrite=True`` replaces it, and at :meth:`open` removes every part an earlier split log of
    that name left (an old part would otherwise join this run's in ``oodmon replay <folder>``). A
    file there that is no MCAP log (a model, a threshold: a name typed wrong) is refused either way.

    A run of days or weeks can be split into files of whole episodes: ``split_episodes=N`` starts
    the next file after every N episodes, ``split_mb=M`` after the episode that takes the file to M
    megabytes (either, or both: whichever comes first). The files are then ``<stem>-00000.mcap``,
    ``<stem>-00001.mcap``, ... beside ``path`` (:attr:`paths`: those written so far), each a
    complete log with the run's metadata (its ``run_id`` among them) and its part number (``part``),
    which ``oodmon replay`` reads together from their folder (and warns of a part missing among
    them: :mod:`oodmon.replay.parts`). A crash then leaves the finished parts whole and indexed, and
    only the last one to recover; the writer's index, which grows with a file, starts anew in each.

    Example:
        >>> import os, shutil, tempfile
        >>> sink = McapSink(os.path.join(tempfile.mkdtemp(), "run.mcap"))
        >>> sink.path.name
        'run.mcap'
        >>> open(sink.path, "wb").close()  # as if an earlier run had written it
        >>> McapSink(sink.path)
        Traceback (most recent call last):
        ...
        oodmon.errors.ConfigError: /.../run.mcap exists: the log of an earlier run; give another path, or ...
        to replace it
        >>> shutil.rmtree(sink.path.parent)
        >>> McapSink("runs/deploy.mcap", split_episodes=100).part_path(3).as_posix()
        'runs/deploy-00003.mcap'
    """

    def __init__(self, path: str | Path, *, compression: str = "zstd", split_episodes: int | None = None,
                 split_mb: float | None = None, flush_seconds: float = 10.0, overwrite: bool = False) -> None:
        from oodmon.errors import InvalidParameterError
        from oodmon.validation import is_real, is_whole

        if split_episodes is not None and not is_whole(split_episodes, 1):
            raise InvalidParameterError(f"split_episodes={split_episodes!r} is not allowed; a whole number >= 1 of "
                                        "episodes per file, or None (one file)")
        if split_mb is not None and not (is_real(split_mb) and 0 < split_mb < math.inf):
            raise InvalidParameterError(f"split_mb={split_mb!r} is not allowed; megabytes > 0 per file, or None "
                                        "(one file)")
        if not (is_real(flush_seconds) and flush_seconds >= 0):
            raise InvalidParameterError(f"flush_seconds={flush_seconds!r} is not allowed; seconds >= 0 between "
                                        "the writes of a long episode's steps to the file")
        if compression not in ("zstd", "none"):  # anything else was written uncompressed, silently
            raise InvalidParameterError(f"compression={compression!r} is not allowed; 'zstd' (the default) or 'none'")
        self.path = Path(path)
        self.compression = compression
        self.flush_seconds = float(flush_seconds)
        self.split_episodes, self.split_mb = split_episodes, split_mb
        self.paths: list[Path] = []  # the files written so far
        self.overwrite = overwrite
        self._check_existing(self.existing_paths())
        self._writer = None
        self._file = None
        self._run: RunInfo | None = None

    @property
    def splits(self) -> bool:
        """Whether the run is written to several files (``split_episodes`` or ``split_mb``)."""
        return self.split_episodes is not None or self.split_mb is not None

    def part_path(self, part: int) -> Path:
        """The file of part ``part`` (counted from 0) of a split run; ``path`` itself if it is not split."""
        return part_path(self.path, part, splits=self.splits)

    def existing_paths(self) -> list[Path]:
        """The files already on disk that this sink would write onto: ``path``, or every part of a
        split log of its name (any part number, in order), left by an earlier run."""
        return existing_parts(self.path, splits=self.splits)

    def _check_existing(self, paths: list[Path]) -> None:
        check_existing(paths, magic=MCAP_MAGIC, kind="an MCAP log", overwrite=self.overwrite,
                       remedy="McapSink(..., overwrite=True)")

    def open(self, run: RunInfo) -> None:
        earlier = self.existing_paths()  # checked again: a file may have come since (this sink's own, opened again)
        self._check_existing(earlier)
        for path in earlier:
            path.unlink()
        self._run = run
        # a rule that compares a window's mean or a sequential statistic: each step message holds it (format 9)
        self._compares = compared_name(run.rule) is not None
        self.paths = []
        # the run's id in its log (each part's): replay tells one run's parts, and copies, by it
        self._run_id = uuid.uuid4().hex
        self._open_part(0)

    def _open_part(self, part: int) -> None:
        from foxglove_schemas_protobuf.Log_pb2 import Log
        from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
        from mcap.writer import CompressionType, Writer
        from mcap_protobuf.schema import register_schema

        path = self.part_path(part)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = claim_file(path)  # an earlier log was refused or removed at open: none may be there now
        self.paths.append(path)
        self._part, self._episodes_in_part = part, 0
        compression = CompressionType.ZSTD if self.compression == "zstd" else CompressionType.NONE
        writer = Writer(self._file, compression=compression)
        writer.start(profile="", library="oodmon")

        def json_channel(topic: str, schema: dict[str, Any]) -> int:
            schema_id = writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            return writer.register_channel(topic, "json", schema_id)

        self._step_channel = json_channel(logformat.STEP, STEP_SCHEMA)
        self._episode_channel = json_channel(logformat.EPISODE, EPISODE_SCHEMA)
        self._scores_channel = json_channel(logformat.EPISODE_SCORES, EPISODE_SCORES_SCHEMA)
        self._start_channel = json_channel(logformat.EPISODE_START, EPISODE_START_SCHEMA)
        self._alarm_channel = writer.register_channel(logformat.ALARM, "protobuf", register_schema(writer, Log))
        self._frame_channel = writer.register_channel(logformat.FRAME, "protobuf", register_schema(writer, RawImage))
        self._log, self._image = Log, RawImage
        writer.add_metadata(logformat.RUN_METADATA, self._run.to_strings()
                            | {"format_version": str(logformat.FORMAT_VERSION), "run_id": self._run_id}
                            | ({"part": str(part)} if self.splits else {}))
        # The header and the run's metadata reach the disk now: a run killed before its first
        # episode ends leaves an MCAP file that says what ran (and holds no episode), not 0 bytes.
        writer.flush()
        self._writer = writer
        self._flushed = time.monotonic()
        self._sequence = 0
        self._scores: list[float] = []
        self._shifted: list[bool] = []
        self._alarm: list[bool] = []
        self._detector_scores: defaultdict[str, list[float]] = defaultdict(list)
        self._segment_start = 0  # the running episode's step the arrays above start at (format 6)

    def _next_part_if_due(self) -> None:
        """A split run's next file, opened by the first step after the last part was finished (so
        that a run ending with a part leaves no empty file)."""
        if self._writer is None and self._run is not None:
            self._open_part(self._part + 1)

    def _add(self, channel: int, data: bytes, now: int) -> None:
        self._writer.add_message(channel, log_time=now, publish_time=now, data=data, sequence=self._sequence)
        self._sequence += 1

    def begin_episode(self, start: EpisodeStart) -> None:
        self._next_part_if_due()
        now = time.time_ns()
        self._add(self._start_channel, json.dumps(start.to_json()).encode(), now)

    def write_step(self, record: StepRecord) -> None:
        self._next_part_if_due()
        now = time.time_ns()
        self._add(self._step_channel, _step_json(record, self._compares).encode(), now)
        self._scores.append(record.score)
        self._shifted.append(record.shifted)
        self._alarm.append(record.alarm)
        columns = self._detector_scores  # a defaultdict(list): a new detector's column starts empty
        for name, value in record.scores.items():
            columns[name].append(value)
        if record.frame is not None:
            frame = record.frame
            colour = frame.ndim == 3  # a drawn state (rgb8) or the agent's grey frame (mono8)
            image = self._image(frame_id="agent_view", width=frame.shape[1], height=frame.shape[0],
                                encoding="rgb8" if colour else "mono8", step=frame.shape[1] * (3 if colour else 1),
                                data=np.ascontiguousarray(frame).tobytes())
            image.timestamp.FromNanoseconds(now)
            self._add(self._frame_channel, image.SerializeToString(), now)
        if time.monotonic() - self._flushed >= self.flush_seconds:  # a long episode: its steps so far to the OS
            self._writer.flush()
            self._flushed = time.monotonic()

    def write_segment(self, segment: EpisodeSegment) -> None:
        """The running episode's arrays since its last segment, as an episode-scores message from
        step ``start`` (format 6; ``Monitor(segment_steps=)``), then dropped from memory."""
        self._next_part_if_due()
        rewards = segment.rewards if segment.rewards is not None and len(segment.rewards) == len(self._scores) else None
        start = self._segment_start
        self._segment_start += len(self._scores)
        self._write_scores(segment.episode, rewards, start, time.time_ns())
        self._writer.flush()  # a segment on disk is a segment a crash does not take
        self._flushed = time.monotonic()

    def _write_scores(self, episode: int, rewards, start: int | None, now: int) -> None:
        """The episode's arrays kept since its start or its last segment, as an episode-scores
        message (from step ``start``; ``None``: the whole episode, as before format 6), then dropped."""
        scores = logformat.encode_episode_scores(episode, self._scores, self._shifted, self._alarm,
                                                 self._detector_scores, rewards, start=start)
        self._add(self._scores_channel, json.dumps(scores).encode(), now)
        self._scores, self._shifted, self._alarm, self._detector_scores = [], [], [], defaultdict(list)

    def write_alarm(self, event: AlarmEvent) -> None:
        self._next_part_if_due()
        now = time.time_ns()
        message = self._log(
            level=self._log.WARNING, name="oodmon",
            message=f"OOD alarm: {event.text()}",
        )
        message.timestamp.FromNanoseconds(now)
        self._add(self._alarm_channel, message.SerializeToString(), now)

    def end_episode(self, record: EpisodeRecord) -> None:
        self._next_part_if_due()  # an episode of no step (cut at once) still has its record
        now = time.time_ns()
        self._writer.flush()  # closes the chunk of step messages
        self._add(self._episode_channel, json.dumps(record.to_json()).encode(), now)
        if not self._segment_start:  # the whole episode in one message, as before format 6
            self._write_scores(record.episode, record.rewards, None, now)
        elif self._scores:  # segments, and steps none took (the monitor hands the last one on: only if that failed)
            self._write_scores(record.episode, None, self._segment_start, now)
        # A small chunk of its own, written at once: from here on the episode survives a crash,
        # and replay reads it through the index without decompressing the step messages.
        self._writer.flush()
        self._flushed = time.monotonic()
        self._segment_start = 0
        self._episodes_in_part += 1
        if (self.split_episodes is not None and self._episodes_in_part >= self.split_episodes
                or self.split_mb is not None and self._file.tell() >= self.split_mb * 1e6):
            self._finish_part()  # summary and index written: this part is a finished log

    def _finish_part(self) -> None:
        if self._writer is not None:
            self._writer.finish()
            self._writer = None
        if self._file is not None:
            self._file.close()
            self._file = None

    def close(self) -> None:
        self._finish_part()
        self._run = None
