"""Log format 6: a long episode's arrays go to the log in segments of ``Monitor(segment_steps=)``
steps and leave memory, so an episode that never ends keeps bounded memory; replay joins the
segments into the episode, finished or torn."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.errors import InvalidParameterError, LogFormatError
from oodmon.monitor import McapSink, MemorySink, Monitor
from oodmon.monitor import logformat
from oodmon.replay import compute_metrics, read_log
from oodmon.replay.reader import _segments
from tests.helpers import tear_inside_episode_one

SPEC = "cartpole:length=2.0"


def _scores_messages(path) -> list[dict]:
    with open(path, "rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[logformat.EPISODE_SCORES])]


def _run(tmp_path, name: str, segment_steps: int, episodes: int = 3):
    env = parse_variant(SPEC).make(onset_step=20)
    memory = MemorySink()
    with Monitor(load("cartpole", "ensemble"), threshold=3.0, sinks=[McapSink(tmp_path / name), memory],
                 segment_steps=segment_steps) as monitor:
        records = [monitor.run_episode(env, seed=seed, variant=SPEC) for seed in range(episodes)]
    return records, memory, read_log(tmp_path / name)


def test_a_segmented_log_replays_as_the_same_episodes_as_a_whole_one(tmp_path):
    # The same seeded episodes (the ensemble decides deterministically), logged whole and in
    # segments of 7 steps: replay gives the same arrays, rewards, returns, alarms and metrics.
    whole_records, _, whole = _run(tmp_path, "whole.mcap", 10**9)
    records, memory, split = _run(tmp_path, "split.mcap", 7)
    assert [r.length for r in records] == [r.length for r in whole_records] and min(r.length for r in records) > 30
    for ours, theirs in zip(split.episodes, whole.episodes, strict=True):
        assert (ours.length, ours.total_return, ours.alarms, ours.first_alarm_step, ours.terminated) == \
            (theirs.length, theirs.total_return, theirs.alarms, theirs.first_alarm_step, theirs.terminated)
        for name in ("scores", "shifted", "alarm", "rewards"):
            assert np.array_equal(getattr(ours, name), getattr(theirs, name)), name
        assert ours.detector_scores.keys() == theirs.detector_scores.keys()
        assert all(np.array_equal(ours.detector_scores[k], theirs.detector_scores[k]) for k in ours.detector_scores)
    assert compute_metrics([split]) == compute_metrics([whole])
    # The log holds each episode's segments, 7 steps each but the last; the whole log one message each.
    messages = _scores_messages(tmp_path / "split.mcap")
    first = [m for m in messages if m["episode"] == 0]
    assert [m["start"] for m in first] == list(range(0, records[0].length, 7))
    assert [m["length"] for m in first[:-1]] == [7] * (len(first) - 1)
    assert all("start" not in m for m in _scores_messages(tmp_path / "whole.mcap"))
    # A segmented episode's record keeps no rewards (the log has them); a short one keeps them all.
    assert all(r.rewards is None for r in records) and all(len(r.rewards) == r.length for r in whole_records)
    assert [e.rewards for e in memory.episodes] == [None] * 3


def test_an_episode_that_never_ends_keeps_at_most_one_segment_in_memory(tmp_path):
    # 400 steps of one episode at 50 steps a segment: the monitor's rewards and the MCAP sink's
    # arrays never hold more than one segment's steps; the 8 segments replay as the 400 steps.
    import gymnasium

    sink = McapSink(tmp_path / "endless.mcap")
    monitor = Monitor(load("pendulum", "ensemble"), sinks=[sink], segment_steps=50).open()
    env = gymnasium.make("Pendulum-v1", max_episode_steps=None)
    obs, _ = env.reset(seed=0)
    monitor.begin_episode(env_id="Pendulum-v1", variant="pendulum", seed=0)
    held, rewards = [], []
    for _ in range(400):
        obs, reward, *_ = env.step(monitor.step(obs))
        monitor.add_reward(reward)
        rewards.append(float(reward))
        held.append((len(monitor._rewards), len(sink._scores), max(map(len, sink._detector_scores.values()))))
    monitor.end_episode(interrupted=True)
    monitor.close()
    assert max(max(h) for h in held) == 50
    (episode,) = read_log(tmp_path / "endless.mcap").interrupted
    assert episode.length == 400 and episode.rewards.tolist() == rewards
    assert len(_scores_messages(tmp_path / "endless.mcap")) == 8


def test_a_log_torn_inside_a_segmented_episode_keeps_its_segments_and_the_steps_after(tmp_path):
    # A copy taken in the middle of an episode that has had 5 segments of 7 steps on disk and 5
    # steps since (flush_seconds=0: each step reaches the disk): replay keeps the episode's 40
    # steps as interrupted, with the monitor's own scores and alarms.
    env = parse_variant(SPEC).make(onset_step=20)
    memory = MemorySink()
    monitor = Monitor(load("cartpole", "ensemble"), threshold=3.0, segment_steps=7,
                      sinks=[McapSink(tmp_path / "run.mcap", flush_seconds=0), memory]).open()
    monitor.run_episode(env, seed=0, variant=SPEC)
    log, steps = tear_inside_episode_one(monitor, env, SPEC, tmp_path, memory)
    (cut,) = log.interrupted
    assert cut.scores.tolist() == [s.score for s in steps] and cut.alarm.tolist() == [s.alarm for s in steps]
    assert cut.shifted.tolist() == [s.shifted for s in steps]
    assert cut.detector_scores["spread"].tolist() == [s.scores["spread"] for s in steps]
    assert (cut.alarms, cut.first_alarm_step) == (memory.episodes[1].alarms, memory.episodes[1].first_alarm_step)
    assert cut.alarms >= 1 and np.isnan(cut.total_return) and [e.episode for e in log.episodes] == [0]
    assert len([m for m in _scores_messages(tmp_path / "run.mcap") if m["episode"] == 1]) == 6  # 5 + its last


def test_segments_that_do_not_follow_one_another_are_a_damaged_log(tmp_path):
    def segment(start: int, length: int) -> dict:
        return logformat.encode_episode_scores(3, [0.5] * length, [False] * length, [False] * length,
                                               {"spread": [0.5] * length}, start=start)

    joined = _segments(tmp_path, 3, [segment(7, 3), segment(0, 7)])  # in the order of their start
    assert len(joined["score"]) == 10 and joined["rewards"] is None
    with pytest.raises(LogFormatError, match="do not follow one another"):
        _segments(tmp_path, 3, [segment(0, 7), segment(8, 3)])
    with pytest.raises(InvalidParameterError, match="segment_steps=0 is not allowed"):
        Monitor(None, segment_steps=0)


def test_a_split_log_of_segmented_episodes_replays_from_its_folder_as_one_whole_log(tmp_path):
    # Files of one episode each (McapSink(split_episodes=1)): an episode's segments stay in its file,
    # and the folder replays as the same episodes and metrics as one unsegmented file.
    from oodmon.replay import read_logs

    (tmp_path / "split").mkdir()
    env = parse_variant(SPEC).make(onset_step=20)
    with Monitor(load("cartpole", "ensemble"), threshold=3.0, segment_steps=7,
                 sinks=[McapSink(tmp_path / "split" / "k.mcap", split_episodes=1)]) as monitor:
        for seed in range(3):
            monitor.run_episode(env, seed=seed, variant=SPEC)
    _, _, whole = _run(tmp_path, "whole.mcap", 10**9)
    parts = read_logs([tmp_path / "split"])
    episodes = [e for log in parts for e in log.episodes]
    assert len(parts) == 3 and [e.length for e in episodes] == [e.length for e in whole.episodes]
    assert all(np.array_equal(a.scores, b.scores) and np.array_equal(a.rewards, b.rewards)
               for a, b in zip(episodes, whole.episodes, strict=True))
    assert compute_metrics(parts) == compute_metrics([whole])
