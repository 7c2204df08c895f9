"""The log format, defined once: MCAP topics, JSON schemas, encodings and the format version.

The MCAP sink writes with it and replay reads with it. Versions (``format_version`` in the run's
metadata, absent before 3):

1. step, episode, alarm and frame channels;
2. ``/oodmon/episode_scores`` (an episode's arrays in one message) and ``interrupted`` episodes;
3. every detector's score: ``scores`` in step messages, ``detectors_f64`` in episode scores,
   ``detector`` (the one the alarm reads) and ``detectors`` in the run's metadata;
4. ``terminated`` in episode messages (the env ended the episode, the failure of the monitor's
   benchmark) and ``reward_f64`` (each step's reward) in episode scores;
5. ``/oodmon/episode_start`` (an episode's env, variant, onset and seed, written with its first
   step), so that replay keeps the running episode of a torn file, from its step messages on
   disk, as an interrupted episode; within a long episode the writer hands its chunk of step
   messages to the operating system every few seconds (``McapSink(flush_seconds=...)``);
6. an episode's arrays in segments: every ``segment_steps`` steps of a long episode (``Monitor``,
   100,000 by default) its ``/oodmon/episode_scores`` so far are written with ``start`` (the
   first step they hold) and dropped from memory; replay joins an episode's segments in order.
   An episode that never ends then keeps bounded memory in the writer, and a torn log loses at
   most its last segment's steps that had not reached the disk. An episode shorter than a
   segment is written as in format 5 (one message, no ``start``);
7. ``first_alarm_cause`` in episode messages: what raised the first alarm's score (the alarm's
   detector, or the member ``combined`` ranked highest; ``AlarmEvent.cause``);
8. ``obs_noise`` in episode and episode start messages: the env's sensor noise (oodmon's CartPole
   and Pendulum ``obs_noise``; 0 for any other env). Replay reads an older log's episodes as
   noiseless, which they were unless played in a noisy env with ``oodmon bench`` or your own code;
9. ``compared`` in step messages of a run whose alarm rule compares something other than each
   step's score with the threshold (:func:`~oodmon.monitor.alarms.compared_name`): the mean of
   the last scores under a window (``window`` > 1: Pong's default, 200 steps; ``null`` until the
   window fills, in each episode), the statistic of a sequential rule (CUSUM, martingale), which
   Foxglove plots beside the score (the raw score alone crossed the threshold again and again
   where no alarm came). Replay computes a window's mean from the score arrays, as it did for
   older logs;
10. ``first_alarm_readings`` and ``first_alarm_readings_steps`` in episode messages: the readings
   the first alarm named (``AlarmEvent.readings``: ``[index, residual]`` pairs, ``[]`` for none)
   and the steps their residuals cover (``AlarmEvent.readings_steps``); replay reads an older
   log's episodes as naming none.
11. ``raised`` in the step message of each step that raised an alarm: its cause and readings
   (``{"cause", "readings", "readings_steps"}``, as the episode message's first ones), so that the
   running episode of a torn log, whose episode message was never written, replays what raised
   its first alarm and which readings it named where that step's message reached the disk (of a
   long episode's step messages before its last segment, the reader keeps those that hold it).
12. ``first_alarm_region`` in episode messages and ``region`` in ``raised``: where in the picture
   the alarm's events fell (``AlarmEvent.region``, the ``vanishing`` detector's: ``{"top", "left",
   "height", "width", "rows", "columns"}`` in the pixels of the picture it reads; ``null`` or
   absent for none); replay reads an older log's episodes as naming none.

A step message's number that is not finite (the +inf score of a NaN observation, its NaN samples,
a run without threshold) is ``null``: JSON has no NaN; the score arrays keep the values.

A run split into files of whole episodes (``McapSink(split_episodes=...)``, ``split_mb``) gives
each file the run's metadata and ``part`` (0, 1, ...); replay reads each as a log of its own, the
episodes' numbers go on across them, and a part missing below the highest one read is warned of
(:mod:`oodmon.replay.parts`).

Since 2026-11-29 every run's metadata holds ``run_id``, drawn at random when its log is opened
and shared by a split run's parts: replay tells the parts of one run from another's by it, and
reads a copy of a log (the same run and part in two files) once.

Replay reads every version: a log without detector scores has one detector, the one its alarm
read (``spread`` before version 3), whose scores are the ``score`` arrays; a log older than
version 4 has no rewards per step and no ``terminated``, so its failures are unknown; a torn log
older than version 5 loses its running episode.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = [
    "ALARM", "EPISODE", "EPISODE_SCHEMA", "EPISODE_SCORES", "EPISODE_SCORES_SCHEMA", "EPISODE_START",
    "EPISODE_START_SCHEMA", "FORMAT_VERSION", "FRAME", "MCAP_MAGIC",
    "RUN_METADATA", "STEP", "STEP_SCHEMA", "decode_array", "encode_episode_scores",
]

FORMAT_VERSION = 12
STEP, EPISODE, EPISODE_SCORES = "/oodmon/step", "/oodmon/episode", "/oodmon/episode_scores"
EPISODE_START = "/oodmon/episode_start"
ALARM, FRAME = "/oodmon/alarm", "/oodmon/frame"
#: JSON topics replay decodes; the others (protobuf alarms and frames) it skips.
JSON_TOPICS = (EPISODE, EPISODE_SCORES, STEP, EPISODE_START)
RUN_METADATA = "oodmon.run"
#: The bytes an MCAP file begins (and a finished one ends) with.
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _object(title: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    """The JSON schema of one message (an object of ``properties``), as the MCAP channels declare it."""
    return {"type": "object", "title": title, "properties": properties, "required": required}


#: A number of a step message: ``null`` where it is not finite (NaN or infinity are not JSON; the
#: episode's score arrays keep them).
_NUMBER: dict[str, Any] = {"type": ["number", "null"]}
#: A part of the picture (``AlarmEvent.region``, format 12), in its pixels.
_REGION: dict[str, Any] = {"type": ["object", "null"], "description": "where in the picture the alarm's events fell, "
                           "in the pixels of the picture the detector reads (since format 12)",
                           "properties": {name: {"type": "integer"} for name in
                                          ("top", "left", "height", "width", "rows", "columns")}}

STEP_SCHEMA: dict[str, Any] = _object("oodmon.Step", {
    "episode": {"type": "integer"},
    "step": {"type": "integer", "description": "index in the episode of the observation acted on"},
    "action": {"type": ["integer", "array"], "description": "the deployed action"},
    "mean": {"type": "array", "items": _NUMBER, "description": "mean of the samples per action"},
    "std": {"type": "array", "items": _NUMBER, "description": "std of the samples per action"},
    "score": _NUMBER | {"description": "null: infinite (a NaN or infinite observation scores +inf)"},
    "threshold": _NUMBER | {"description": "null: the run had no threshold"},
    "alarm": {"type": "boolean"},
    "shifted": {"type": "boolean", "description": "the shift is active at this step"},
    "observation": {"type": "array", "items": _NUMBER},
    "scores": {"type": "object", "additionalProperties": _NUMBER,
               "description": "every detector's score, by detector name (since format 3)"},
    "compared": _NUMBER | {"description": "what the alarm rule compared with the threshold where that is not the "
                                          "score: a window's mean (null until it fills), a CUSUM or martingale "
                                          "statistic (since format 9)"},
    "raised": {"type": "object", "description": "the alarm raised at this step: its cause, the readings it named "
                                                "([index, residual] each) and the steps they cover (since format 11)",
               "properties": {"cause": {"type": ["string", "null"]},
                              "readings": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
                              "readings_steps": {"type": "integer"}, "region": _REGION}},
}, required=["episode", "step", "action", "mean", "std", "score", "threshold", "alarm", "shifted"])

EPISODE_SCHEMA: dict[str, Any] = _object("oodmon.Episode", {
    "episode": {"type": "integer"},
    "env_id": {"type": "string"},
    "variant": {"type": "string"},
    "onset": {"type": "integer"},
    "seed": {"type": ["integer", "null"]},
    "return": {"type": "number"},
    "length": {"type": "integer"},
    "alarms": {"type": "integer"},
    "first_alarm_step": {"type": ["integer", "null"]},
    "interrupted": {"type": "boolean", "description": "the run was stopped inside this episode (since format 2)"},
    "terminated": {"type": ["boolean", "null"],
                   "description": "the env ended the episode (not a time limit, not an alarm; since format 4)"},
    "first_alarm_cause": {"type": ["string", "null"],
                          "description": "what raised the first alarm's score (since format 7)"},
    "obs_noise": {"type": "number", "description": "the env's sensor noise: its std as a fraction of each observation "
                                                   "dimension's ID spread (since format 8; absent: 0)"},
    "first_alarm_readings": {"type": "array", "items": {"type": "array", "items": {"type": "number"}},
                             "description": "the readings the first alarm named, [index, residual] each: their "
                                            "change's distance from the dynamics model's prediction in its "
                                            "standard deviations (since format 10; absent: none)"},
    "first_alarm_readings_steps": {"type": "integer", "description": "the steps the residuals of first_alarm_readings "
                                                                     "cover: 1, the alarm's; more, the drift "
                                                                     "detector's window (since format 10)"},
    "first_alarm_region": _REGION,
}, required=["episode", "env_id", "variant", "onset", "seed", "return", "length", "alarms", "first_alarm_step"])


def _per_step(values: str) -> dict[str, str]:
    """A field of one value per step of the episode, as base64 of the array's bytes."""
    return {"type": "string", "contentEncoding": "base64", "description": f"{values} per step"}


#: An episode's start (format 5): the fields of its episode message known at its first step
#: (``obs_noise`` since format 8).
_START_FIELDS = ["episode", "env_id", "variant", "onset", "seed"]
EPISODE_START_SCHEMA: dict[str, Any] = _object(
    "oodmon.EpisodeStart", {name: EPISODE_SCHEMA["properties"][name] for name in [*_START_FIELDS, "obs_noise"]},
    required=_START_FIELDS)

EPISODE_SCORES_SCHEMA: dict[str, Any] = _object("oodmon.EpisodeScores", {
    "episode": {"type": "integer"},
    "length": {"type": "integer"},
    "start": {"type": "integer",
              "description": "a segment of the episode: the step its arrays start at (since format 6; absent: step 0, "
                             "the whole episode)"},
    "score_f64": _per_step("little-endian float64"),
    "shifted_u8": _per_step("uint8"),
    "alarm_u8": _per_step("uint8"),
    "detectors_f64": {"type": "object", "additionalProperties": {"type": "string", "contentEncoding": "base64"},
                      "description": "per detector name, little-endian float64 per step (since format 3)"},
    "reward_f64": _per_step("little-endian float64 reward") | {
        "description": "little-endian float64 reward per step (since format 4)"},
}, required=["episode", "length", "score_f64", "shifted_u8", "alarm_u8"])


def _encode(values: Sequence[Any], dtype: Any) -> str:
    return base64.b64encode(np.asarray(values, dtype).tobytes()).decode()


def decode_array(text: str, dtype: Any) -> np.ndarray:
    """One base64 array of an episode-scores message."""
    return np.frombuffer(base64.b64decode(text), dtype)


def encode_episode_scores(episode: int, scores: Sequence[float], shifted: Sequence[bool], alarm: Sequence[bool],
                          detectors: Mapping[str, Sequence[float]] | None = None,
                          rewards: Sequence[float] | None = None, start: int | None = None) -> dict[str, Any]:
    """The ``/oodmon/episode_scores`` message of one episode, or of one segment of it from step
    ``start`` (format 6; ``None``: the whole episode, no ``start`` written)."""
    message = {"episode": episode, "length": len(scores)} | ({} if start is None else {"start": start})
    message |= {"score_f64": _encode(scores, "<f8"),
               "shifted_u8": _encode(shifted, np.uint8), "alarm_u8": _encode(alarm, np.uint8)}
    if detectors:
        message["detectors_f64"] = {name: _encode(values, "<f8") for name, values in detectors.items()}
    if rewards is not None:
        message["reward_f64"] = _encode(rewards, "<f8")
    return message
