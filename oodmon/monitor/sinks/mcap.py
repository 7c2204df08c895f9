"""Log a monitored run to an MCAP file that replay, Foxglove and Rerun can read.

Channels (their schemas and encodings are defined once, in :mod:`oodmon.monitor.logformat`):

- ``/oodmon/step``: JSON (schema ``oodmon.Step``, JSON Schema), one message per step.
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
system) at every episode end, so a crash, even SIGKILL, loses at most the running episode;
``close`` writes the summary and index.
"""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.monitor import logformat

#: A Foxglove (or Lichtblick) layout for these logs: score, threshold and every detector plotted,
#: the frames, the alarms. Layouts -> Import from file.
FOXGLOVE_LAYOUT = Path(__file__).with_name("foxglove_layout.json")
from oodmon.monitor.alarms import AlarmEvent
from oodmon.monitor.logformat import EPISODE_SCHEMA, EPISODE_SCORES_SCHEMA, STEP_SCHEMA
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord

__all__ = ["EPISODE_SCHEMA", "EPISODE_SCORES_SCHEMA", "STEP_SCHEMA", "McapSink"]  # schemas re-exported

def _json_number(value: float) -> float | None:
    """``value``, or ``None`` where it is not finite: NaN (no threshold) and infinity (the score of a
    NaN observation) are not JSON, and Foxglove's parser refuses them."""
    return value if math.isfinite(value) else None


def _step_json(record: StepRecord) -> str:
    """A step's message, every non-finite number written as ``null`` (the score arrays keep them)."""
    data = record.to_json()
    data["threshold"] = _json_number(data["threshold"])  # NaN in every run without a threshold
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
    """Writes the run to ``path`` (created with its folder; an existing file is replaced).

    Example:
        >>> import tempfile, os
        >>> sink = McapSink(os.path.join(tempfile.mkdtemp(), "run.mcap"))
        >>> sink.path.name
        'run.mcap'
    """

    def __init__(self, path: str | Path, *, compression: str = "zstd") -> None:
        self.path = Path(path)
        self.compression = compression
        self._writer = None
        self._file = None

    def open(self, run: RunInfo) -> None:
        from foxglove_schemas_protobuf.Log_pb2 import Log
        from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
        from mcap.writer import CompressionType, Writer
        from mcap_protobuf.schema import register_schema

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        compression = CompressionType.ZSTD if self.compression == "zstd" else CompressionType.NONE
        writer = Writer(self._file, compression=compression)
        writer.start(profile="", library="oodmon")

        def json_channel(topic: str, schema: dict[str, Any]) -> int:
            schema_id = writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            return writer.register_channel(topic, "json", schema_id)

        self._step_channel = json_channel(logformat.STEP, STEP_SCHEMA)
        self._episode_channel = json_channel(logformat.EPISODE, EPISODE_SCHEMA)
        self._scores_channel = json_channel(logformat.EPISODE_SCORES, EPISODE_SCORES_SCHEMA)
        self._alarm_channel = writer.register_channel(logformat.ALARM, "protobuf", register_schema(writer, Log))
        self._frame_channel = writer.register_channel(logformat.FRAME, "protobuf", register_schema(writer, RawImage))
        self._log, self._image = Log, RawImage
        writer.add_metadata(logformat.RUN_METADATA, run.to_strings() | {"format_version": str(logformat.FORMAT_VERSION)})
        # The header and the run's metadata reach the disk now: a run killed before its first
        # episode ends leaves an MCAP file that says what ran (and holds no episode), not 0 bytes.
        writer.flush()
        self._writer = writer
        self._sequence = 0
        self._scores: list[float] = []
        self._shifted: list[bool] = []
        self._alarm: list[bool] = []
        self._detector_scores: defaultdict[str, list[float]] = defaultdict(list)

    def _add(self, channel: int, data: bytes, now: int) -> None:
        self._writer.add_message(channel, log_time=now, publish_time=now, data=data, sequence=self._sequence)
        self._sequence += 1

    def write_step(self, record: StepRecord) -> None:
        now = time.time_ns()
        self._add(self._step_channel, _step_json(record).encode(), now)
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

    def write_alarm(self, event: AlarmEvent) -> None:
        now = time.time_ns()
        message = self._log(
            level=self._log.WARNING, name="oodmon",
            message=f"OOD alarm: episode {event.episode} step {event.step}: score {event.score:.4g} ({event.rule}, "
                    f"threshold {event.threshold:.4g})",
        )
        message.timestamp.FromNanoseconds(now)
        self._add(self._alarm_channel, message.SerializeToString(), now)

    def end_episode(self, record: EpisodeRecord) -> None:
        now = time.time_ns()
        self._writer.flush()  # closes the chunk of step messages
        scores = logformat.encode_episode_scores(record.episode, self._scores, self._shifted, self._alarm,
                                                 self._detector_scores, record.rewards)
        self._add(self._episode_channel, json.dumps(record.to_json()).encode(), now)
        self._add(self._scores_channel, json.dumps(scores).encode(), now)
        # A small chunk of its own, written at once: from here on the episode survives a crash,
        # and replay reads it through the index without decompressing the step messages.
        self._writer.flush()
        self._scores, self._shifted, self._alarm, self._detector_scores = [], [], [], defaultdict(list)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.finish()
            self._writer = None
        if self._file is not None:
            self._file.close()
            self._file = None
