"""Sinks: MCAP and Rerun files read back with the stock readers, crash safety, failing sinks."""

from __future__ import annotations

import base64
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.errors import InvalidParameterError, LogFormatError
from oodmon.monitor import McapSink, MemorySink, Monitor, RerunSink, SinkWarning
from oodmon.replay import read_log, read_logs
from oodmon.replay.reader import read_compared


@pytest.fixture(scope="module")
def agent():
    return load("cartpole", "dropout")


def _run(agent, sinks, episodes=3, strict=False):
    env = parse_variant("cartpole:length=2.0").make(onset_step=30)
    with Monitor(agent, threshold=3.0, sinks=sinks, strict=strict) as monitor:
        return [monitor.run_episode(env, seed=s, variant="cartpole:length=2.0") for s in range(episodes)]


def test_mcap_holds_every_step_of_every_episode_and_the_run_metadata(agent, tmp_path):
    memory = MemorySink()
    records = _run(agent, [memory, McapSink(tmp_path / "run.mcap")])
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
        by_topic: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages():
            by_topic.setdefault(channel.topic, []).append((schema, message))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert schemas == {"oodmon.Step": "jsonschema", "oodmon.Episode": "jsonschema", "foxglove.Log": "protobuf",
                       "foxglove.RawImage": "protobuf", "oodmon.EpisodeScores": "jsonschema",
                       "oodmon.EpisodeStart": "jsonschema"}
    steps = [json.loads(m.data) for _, m in by_topic["/oodmon/step"]]
    assert len(steps) == sum(r.length for r in records) == len(memory.steps)
    assert steps == [s.to_json() for s in memory.steps]
    episodes = [json.loads(m.data) for _, m in by_topic["/oodmon/episode"]]
    assert episodes == [r.to_json() for r in records]
    starts = [json.loads(m.data) for _, m in by_topic["/oodmon/episode_start"]]
    assert starts == [{k: r.to_json()[k] for k in ("episode", "env_id", "variant", "onset", "seed", "obs_noise")}
                      for r in records]
    first_steps = {}
    for _, message in by_topic["/oodmon/step"]:
        first_steps.setdefault(json.loads(message.data)["episode"], message.sequence)
    assert all(m.sequence < first_steps[json.loads(m.data)["episode"]] for _, m in by_topic["/oodmon/episode_start"])
    assert {"episode", "step", "action", "mean", "std", "score", "threshold", "alarm", "shifted", "observation"} <= set(steps[0])
    # Each episode's score arrays, beside its step messages, hold the same numbers.
    for (_, message), record in zip(by_topic["/oodmon/episode_scores"], records, strict=True):
        row = json.loads(message.data)
        steps_of_episode = [s for s in memory.steps if s.episode == record.episode]
        scores = np.frombuffer(base64.b64decode(row["score_f64"]), "<f8")
        assert row["length"] == record.length and scores.tolist() == [s.score for s in steps_of_episode]
        assert np.frombuffer(base64.b64decode(row["shifted_u8"]), np.uint8).tolist() == [s.shifted for s in steps_of_episode]
        assert np.frombuffer(base64.b64decode(row["alarm_u8"]), np.uint8).tolist() == [s.alarm for s in steps_of_episode]
    alarms = by_topic.get("/oodmon/alarm", [])
    assert len(alarms) == sum(r.alarms for r in records)
    run = metadata["oodmon.run"]
    assert run["task"] == "cartpole" and run["method"] == "dropout" and run["threshold"] == "3.0"
    assert run["policy_hash"].startswith("sha256:") and "version.torch" in run


def test_a_split_log_replays_as_the_one_file_of_the_same_run(agent, tmp_path):
    """split_episodes=2 over 5 episodes: three finished files of whole episodes (no empty fourth),
    whose folder replays to the metrics of the same run in one file; split_mb starts a file after
    the episode that takes one past the size."""
    from oodmon.errors import InvalidParameterError
    from oodmon.replay import compute_metrics

    split = McapSink(tmp_path / "split" / "run.mcap", split_episodes=2)
    _run(agent, [split, McapSink(tmp_path / "one.mcap")], episodes=5)
    assert [p.name for p in split.paths] == ["run-00000.mcap", "run-00001.mcap", "run-00002.mcap"]
    assert sorted(p.name for p in (tmp_path / "split").iterdir()) == [p.name for p in split.paths]
    logs = read_logs([tmp_path / "split"])
    assert [[e.episode for e in log.episodes] for log in logs] == [[0, 1], [2, 3], [4]]
    assert all(log.complete for log in logs) and [log.metadata["part"] for log in logs] == ["0", "1", "2"]
    assert "part" not in read_log(tmp_path / "one.mcap").metadata
    assert compute_metrics(logs) == compute_metrics([read_log(tmp_path / "one.mcap")])
    _run(agent, [McapSink(tmp_path / "even" / "run.mcap", split_episodes=2)], episodes=4)
    assert len(list((tmp_path / "even").iterdir())) == 2  # the run ended with its part: no empty third file
    by_size = McapSink(tmp_path / "mb" / "run.mcap", split_mb=0.02)
    _run(agent, [by_size], episodes=4)
    sizes = [p.stat().st_size for p in by_size.paths]
    assert len(sizes) >= 2 and all(size >= 20_000 for size in sizes[:-1])
    assert sum(len(read_log(p).episodes) for p in by_size.paths) == 4
    for bad in ({"split_episodes": 0}, {"split_episodes": 1.5}, {"split_mb": 0}, {"split_mb": float("inf")},
                {"flush_seconds": -1}, {"flush_seconds": float("nan")}):
        with pytest.raises(InvalidParameterError, match="is not allowed"):
            McapSink(tmp_path / "x.mcap", **bad)


def test_alarms_are_foxglove_logs(agent, tmp_path):
    from foxglove_schemas_protobuf.Log_pb2 import Log

    with Monitor(agent, threshold=0.0, consecutive=1, sinks=[McapSink(tmp_path / "a.mcap")]) as monitor:
        monitor.run_episode(parse_variant("cartpole:length=2.0").make(), seed=0)
    with open(tmp_path / "a.mcap", "rb") as f:
        logs = [m for _, c, m in make_reader(f).iter_messages(topics=["/oodmon/alarm"])]
    message = Log.FromString(logs[0].data)
    assert message.level == Log.WARNING and message.message.startswith("OOD alarm: episode 0 step 0: score ")
    assert message.message.endswith("; cause: spread")  # the monitor's alarm read the spread alone

    episode = read_log(tmp_path / "a.mcap").episodes[0]  # and the episode's record keeps the first one's (format 7)
    assert episode.first_alarm_step == 0 and episode.first_alarm_cause == "spread"
    older = read_log(Path(__file__).parents[1] / "data" / "cartpole-ensemble-length2.mcap").episodes[0]
    assert older.first_alarm_step == 104 and older.first_alarm_cause is None  # a log before format 7: not known


def test_rrd_holds_the_scalars(agent, tmp_path):
    memory = MemorySink()
    _run(agent, [memory, RerunSink(tmp_path / "run.rrd")], episodes=2)
    frame = _rrd_table(tmp_path / "run.rrd")
    scores = frame[["step", "/score:Scalars:scalars"]].dropna()
    assert len(scores) == len(memory.steps)
    np.testing.assert_allclose([v[0] for v in scores["/score:Scalars:scalars"]], [s.score for s in memory.steps], rtol=1e-6)
    band = frame["/uncertainty/Q0:Scalars:scalars"].dropna().iloc[0]
    first = memory.steps[0]
    np.testing.assert_allclose(band, [first.mean[0], first.mean[0] - first.std[0], first.mean[0] + first.std[0]], rtol=1e-6)
    assert frame["/threshold:Scalars:scalars"].dropna().iloc[0][0] == 3.0
    returns = frame["/episode/return:Scalars:scalars"].dropna()
    assert len(returns) == 2
    spread = frame["/detectors/spread:Scalars:scalars"].dropna()  # every detector has a series
    np.testing.assert_allclose([v[0] for v in spread], [s.scores["spread"] for s in memory.steps], rtol=1e-6)
    # Timelines per episode and per step within it beside the global one.
    scored = frame.dropna(subset=["/score:Scalars:scalars"])
    assert scored["episode"].tolist() == [s.episode for s in memory.steps]
    assert scored["step_in_episode"].tolist() == [s.step for s in memory.steps]
    run = frame["/run:TextDocument:text"].dropna().iloc[0][0]  # the run's metadata: versions and command too
    assert "versions: " in run and "torch" in run and "command: " in run


def _logged_compared(rrd, mcap):
    """``/compared`` of an ``.rrd`` (episode, step in episode, value) and the ``compared`` of an
    MCAP log's step messages (``null`` read as NaN), with the messages."""
    frame = _rrd_table(rrd).dropna(subset=["/compared:Scalars:scalars"])
    drawn = [(e, s, v[0]) for e, s, v in zip(frame["episode"], frame["step_in_episode"],
                                             frame["/compared:Scalars:scalars"])]
    with open(mcap, "rb") as f:
        messages = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages() if c.topic == "/oodmon/step"]
    return drawn, [np.nan if m["compared"] is None else m["compared"] for m in messages], messages


def test_the_logs_of_a_rule_with_a_window_hold_the_mean_the_alarm_compares(agent, tmp_path):
    """A rule with a window compares the mean of its last w scores with the threshold; the viewers
    showed the raw score alone against it, crossing where no alarm came (Pong's features, 200
    steps). The ``.rrd``'s ``/compared`` holds that mean, NaN until the window fills, episode by
    episode; the MCAP log's step messages hold it as ``compared`` (format 9), ``null`` until then,
    which the Foxglove layout plots."""
    from oodmon.monitor.alarms import trailing_mean

    memory = MemorySink()
    env = parse_variant("cartpole:length=2.0").make(onset_step=30)
    sinks = [memory, RerunSink(tmp_path / "w.rrd"), McapSink(tmp_path / "w.mcap")]
    with Monitor(agent, threshold=3.0, window=5, sinks=sinks) as monitor:
        for seed in range(2):
            monitor.run_episode(env, seed=seed, variant="cartpole:length=2.0")
    expected = []
    for episode in (0, 1):  # (the window starts again with each episode)
        steps = [s for s in memory.steps if s.episode == episode]
        means_of = [np.nan] * 4 + trailing_mean(np.array([s.score for s in steps]), 5).tolist()  # NaN until full
        expected += [(episode, step.step, mean) for step, mean in zip(steps, means_of)]
    drawn, logged, messages = _logged_compared(tmp_path / "w.rrd", tmp_path / "w.mcap")
    assert [(e, s) for e, s, _ in drawn] == [(e, s) for e, s, _ in expected]
    np.testing.assert_allclose([v for _, _, v in drawn], [m for _, _, m in expected], rtol=1e-6)  # NaN where NaN
    alarmed = [s.step for s in memory.steps if s.episode == 0 and s.alarm]
    assert alarmed and all(m > 3.0 for e, s, m in expected if e == 0 and s in alarmed)  # what the alarm compared
    assert [(m["episode"], m["step"]) for m in messages] == [(e, s) for e, s, _ in expected]
    np.testing.assert_allclose(logged, [m for _, _, m in expected], rtol=1e-12)
    assert [{k: v for k, v in m.items() if k != "compared"} for m in messages] == [s.to_json() for s in memory.steps]
    _run(agent, [RerunSink(tmp_path / "each.rrd")], episodes=1)  # each step's own score: no such series
    assert "/compared:Scalars:scalars" not in _rrd_table(tmp_path / "each.rrd").columns
    # (an MCAP log of such a rule holds no compared: test_mcap_holds_every_step_of_every_episode_and_the_run_metadata)
    # with a warm-up the alarm's window fills from the warm-up's end (AlarmTracker keeps no score before it)
    from oodmon.monitor import Threshold

    warm = Threshold(value=3.0, score="chosen_std", consecutive=1, mode="episode", far=0.05, n_episodes=45,
                     n_steps=900, window=5, warmup=10)
    memory = MemorySink()
    with Monitor(agent, threshold=warm, sinks=[memory, RerunSink(tmp_path / "warm.rrd")]) as monitor:
        monitor.run_episode(env, seed=0, variant="cartpole:length=2.0")
    frame = _rrd_table(tmp_path / "warm.rrd")
    got = [v[0] for v in frame.dropna(subset=["/compared:Scalars:scalars"])["/compared:Scalars:scalars"]]
    scores = np.array([s.score for s in memory.steps])
    np.testing.assert_allclose(got, [np.nan] * 14 + trailing_mean(scores[10:], 5).tolist(), rtol=1e-6)


def test_the_logs_of_a_sequential_rule_hold_the_statistic_the_alarm_compares(tmp_path):
    """A CUSUM or martingale rule compares its statistic with the threshold, on a scale of its own:
    the viewers drew the raw score against that threshold. Both logs hold the statistic at every
    step (``/compared``, ``compared``), the path ``sequential_path`` computes from the scores, and
    each first alarm is where it first exceeds the threshold."""
    from oodmon.monitor.detectors import detectors_for
    from oodmon.monitor.sequential import Reference, sequential_path
    from oodmon.monitor.threshold import calibrate

    ensemble = load("cartpole", "ensemble")  # its dynamics detector sees the longer pole (the spread barely)
    watched = {"detectors": detectors_for(ensemble), "detector": "dynamics"}
    memory = MemorySink()
    with Monitor(ensemble, threshold=None, sinks=[memory], **watched) as monitor:  # ID scores: reference, calibration
        for seed in range(6):
            monitor.run_episode(parse_variant("cartpole").make(), seed=100 + seed, max_steps=150)
    id_scores = [np.array([s.score for s in memory.steps if s.episode == e]) for e in range(6)]
    reference = Reference.from_episodes(id_scores[:3])
    env = parse_variant("cartpole:length=2.0").make(onset_step=30)
    for rule in ("cusum", "martingale"):
        threshold = calibrate(id_scores[3:], 0.5, confidence=None, rule=rule, reference=reference, detector="dynamics")
        memory = MemorySink()
        sinks = [memory, RerunSink(tmp_path / f"{rule}.rrd"), McapSink(tmp_path / f"{rule}.mcap")]
        with Monitor(ensemble, threshold=threshold, sinks=sinks, **watched) as monitor:
            record = monitor.run_episode(env, seed=0, variant="cartpole:length=2.0")
        path = sequential_path(rule, reference, np.array([s.score for s in memory.steps]))
        drawn, logged, _ = _logged_compared(tmp_path / f"{rule}.rrd", tmp_path / f"{rule}.mcap")
        np.testing.assert_allclose([v for _, _, v in drawn], path, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(logged, path, rtol=1e-9, atol=1e-12)
        assert record.first_alarm_step is not None and record.first_alarm_step == int(np.argmax(path > threshold.value))
        np.testing.assert_array_equal(read_compared(tmp_path / f"{rule}.mcap", [0, 7])[0], logged)  # (7: none)
        assert list(read_compared(tmp_path / f"{rule}.mcap", [0, 7])) == [0]
    # replay's trace draws it, as logged, on an axis of its own with the threshold (the scores' axis has neither)
    from oodmon.replay import plots

    drawn = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
        assert plots.plot_trace(read_logs([tmp_path / "cusum.mcap"]), "ensemble", "cartpole:length=2.0",
                                tmp_path / "trace.png") is not None
    score_axis, twin = drawn[0].axes
    assert not [line for line in score_axis.get_lines() if line.get_linestyle() == "--"]
    statistic, dashed = twin.get_lines()
    np.testing.assert_array_equal(statistic.get_ydata(), read_compared(tmp_path / "cusum.mcap", [0])[0])
    assert dashed.get_linestyle() == "--" and dashed.get_ydata()[0] == read_logs([tmp_path / "cusum.mcap"])[0].threshold
    assert "the alarm compares the CUSUM statistic (right axis, as logged) with its threshold" in \
           drawn[0].texts[0].get_text().replace("\n", " ")


def _rrd_table(path):
    """A Rerun file's rows by the run's step, a pandas frame (one column per entity and component)."""
    import rerun.chunk as rc

    return rc.RrdReader(path).stream().collect().reader("step").to_pandas()


def _sent_by_steps_alone(monkeypatch) -> None:
    """The Rerun sink sends every 200 steps and never by the clock (its default: every 2,000 steps,
    the file every 10 s, and at an episode's end a tenth of a second after the last send)."""
    import oodmon.monitor.sinks.rerun as rerun_sink

    monkeypatch.setattr(rerun_sink, "FLUSH_EVERY", 200)
    monkeypatch.setattr(rerun_sink, "FILE_FLUSH_SECONDS", 3600.0)
    monkeypatch.setattr(rerun_sink, "END_FLUSH_SECONDS", 3600.0)


def _verify(path, *flags):
    """``rerun rrd verify [flags] path``: its exit code and what it said."""
    rerun = os.path.join(os.path.dirname(sys.executable), "rerun")
    result = subprocess.run([rerun, "rrd", "verify", *flags, str(path)], capture_output=True, text=True)
    return result.returncode, result.stdout + result.stderr


def test_rrd_passes_rerun_verify_and_replay_given_it_says_what_it_is(agent, tmp_path):
    _run(agent, [RerunSink(tmp_path / "run.rrd")], episodes=1)
    code, said = _verify(tmp_path / "run.rrd")
    assert code == 0 and "verified without error" in said
    # the file a run wrote beside its MCAP log, handed to replay by mistake: once "not an MCAP file"
    with pytest.raises(LogFormatError, match=r"run\.rrd is a Rerun recording, which the Rerun viewer shows .*--mcap"):
        read_log(tmp_path / "run.rrd")
    with pytest.raises(LogFormatError, match="holds no .mcap files .its .rrd files are Rerun recordings"):
        read_logs([tmp_path])


def test_an_rrd_without_a_footer_holds_every_step_and_reads_as_a_killed_runs(agent, tmp_path):
    """``footer=False`` (a long run: Rerun keeps the footer's index of chunks in memory until the
    end, scripts/monitor_memory.py): the file has no footer, which Rerun's check says, and every
    step is in it all the same."""
    memory = MemorySink()
    _run(agent, [memory, RerunSink(tmp_path / "long.rrd", footer=False)], episodes=2)
    code, said = _verify(tmp_path / "long.rrd")
    assert code != 0 and "Missing RRD footer" in said
    code, said = _verify(tmp_path / "long.rrd", "--check-footers", "false")
    assert code == 0 and "verified without error" in said
    with pytest.warns(match="RRD file has no footer"):  # Rerun's reader says so, and streams it whole
        frame = _rrd_table(tmp_path / "long.rrd")
    scores = [v[0] for v in frame["/score:Scalars:scalars"].dropna()]
    np.testing.assert_allclose(scores, [s.score for s in memory.steps], rtol=1e-6)
    assert len(frame["/episode/return:Scalars:scalars"].dropna()) == 2
    with pytest.raises(InvalidParameterError, match=r"footer='no' is not allowed; give True .* or False"):
        RerunSink(tmp_path / "other.rrd", footer="no")


def test_a_file_with_a_footer_warns_once_when_its_index_grows_large_and_one_without_never(agent, tmp_path, monkeypatch):
    import oodmon.monitor.sinks.rerun as rerun_sink

    monkeypatch.setattr(rerun_sink, "FOOTER_WARN_CHUNKS", 5)  # a flush here sends 7 columns (7 series)
    _sent_by_steps_alone(monkeypatch)  # (these short runs: a send every 200 steps)
    for footer in (True, False):
        sink = RerunSink(tmp_path / f"footer-{footer}.rrd", footer=footer)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            records = _run(agent, [sink], episodes=6)  # some 450 steps: three flushes
        said = [str(w.message) for w in caught if issubclass(w.category, rerun_sink.FooterMemoryWarning)]
        assert sink.chunks == 7 * -(-sum(r.length for r in records) // rerun_sink.FLUSH_EVERY) >= 2 * 7
        if footer:
            assert len(said) == 1 and "5 chunks so far" in said[0] and "--rrd-no-footer" in said[0]
        else:
            assert said == []


def test_a_slow_policys_steps_are_sent_within_a_flush_period_and_short_episodes_share_columns(agent, tmp_path,
                                                                                              monkeypatch):
    """Sent every FLUSH_EVERY steps or FILE_FLUSH_SECONDS (a file alone; FLUSH_SECONDS with a
    viewer), and at an episode's end only END_FLUSH_SECONDS after the last send: until 2026-12-07,
    at every episode's end and never by the clock, a live viewer of a policy deciding 10 times a
    second saw its steps up to 20 s late (every 200), and each short episode cost a chunk per series
    (an entry each of the footer's index, in memory)."""
    import oodmon.monitor.sinks.rerun as rerun_sink

    monkeypatch.setattr(rerun_sink, "FILE_FLUSH_SECONDS", 0.5)  # (a file alone: 10 s by default, see below)
    monkeypatch.setattr(rerun_sink, "END_FLUSH_SECONDS", 0.3)  # (0.1: room for a busy machine)
    sink = RerunSink(tmp_path / "slow.rrd")
    env = parse_variant("cartpole").make()
    with Monitor(agent, threshold=3.0, sinks=[sink]) as monitor:
        obs, _ = env.reset(seed=0)
        monitor.begin_episode(env_id="oodmon/CartPole-v1", variant="cartpole", seed=0)
        for _ in range(3):  # fast: buffered
            obs, reward, *_ = env.step(monitor.step(obs))
            monitor.add_reward(reward)
        assert sink.chunks == 0 and len(sink._outboxes[0].records) == 3
        time.sleep(0.55)  # a slow policy's next decision: the four steps go out with it
        obs, reward, *_ = env.step(monitor.step(obs))
        monitor.add_reward(reward)
        assert sink.chunks == 7 and sink._outboxes[0].records == []
        monitor.end_episode(interrupted=True)
        assert sink.chunks == 7  # an episode's end just after a send sends nothing
        monitor.begin_episode(env_id="oodmon/CartPole-v1", variant="cartpole", seed=1)
        obs, _ = env.reset(seed=1)
        obs, reward, *_ = env.step(monitor.step(obs))
        monitor.add_reward(reward)
        time.sleep(0.35)
        monitor.end_episode(interrupted=True)  # a slow policy's episode ends: it is whole in the viewer
        assert sink.chunks == 14 and sink._outboxes[0].records == []
    assert sink.chunks == 14  # nothing left to send at close
    _sent_by_steps_alone(monkeypatch)
    short = RerunSink(tmp_path / "short.rrd")
    records = _run(agent, [short], episodes=6)  # some 450 steps: sent at 200, 400 and the close (and each end, before)
    assert short.chunks == 7 * -(-sum(r.length for r in records) // rerun_sink.FLUSH_EVERY) < 7 * len(records)


def test_a_file_is_sent_every_ten_seconds_and_a_served_stream_every_second_beside_it_or_alone(agent, tmp_path,
                                                                                             monkeypatch):
    """A policy deciding 32 times a second, on a clock of the test's: the file gets its steps every
    FILE_FLUSH_SECONDS (10 s, as an MCAP log's flush), a stream a viewer reads each second, also
    when one sink writes both. From 2026-12-07 until later that day a file alone was sent each
    second as well, and a file beside a served stream or a viewer until later still: a chunk per
    series each time, an entry each of the footer's index in memory (at 50 Hz, 525 MB a day against
    72 now: scripts/monitor_memory.py --hz 50)."""
    import types

    import oodmon.monitor.sinks.rerun as rerun_sink

    memory = MemorySink()
    _run(agent, [memory], episodes=12)  # the records a sink is given
    records = memory.steps[:600]
    clock = [1000.0]
    monkeypatch.setattr(rerun_sink, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    sinks = {"alone": RerunSink(tmp_path / "alone.rrd"), "served": RerunSink(serve=True, port=_free_port()),
             "both": RerunSink(tmp_path / "both.rrd", serve=True, port=_free_port())}
    for sink in sinks.values():
        sink.open(memory.run)
    sends = {name: [] for name in sinks}  # the steps after which each sent (7 series, 7 chunks a send)
    file_sends = []  # the steps after which "both" sent to its file
    for n, record in enumerate(records, start=1):
        clock[0] = 1000.0 + n / 32  # (exact in binary: no rounding moves a send by a step)
        for name, sink in sinks.items():
            before, before_file = sink.chunks, sink._file_chunks
            sink.write_step(record)
            if sink.chunks > before:
                sends[name].append(n)
            if name == "both" and sink._file_chunks > before_file:
                file_sends.append(n)
    for sink in sinks.values():
        sink.close()
    assert len(records) == 600 and (rerun_sink.FILE_FLUSH_SECONDS, rerun_sink.FLUSH_SECONDS) == (10.0, 1.0)
    each_second = list(range(32, 600, 32))
    assert sends == {"alone": [320], "served": each_second, "both": each_second} and file_sends == [320]
    # the close sent what was left: to the file 2 sends in all, to the served stream 19
    assert [sink.chunks for sink in sinks.values()] == [2 * 7, 19 * 7, 21 * 7] and sinks["both"]._file_chunks == 2 * 7
    for name in ("alone", "both"):
        frame = _rrd_table(tmp_path / f"{name}.rrd")
        assert len(frame["/score:Scalars:scalars"].dropna()) == 600


FILE_STOPS = """
import resource, signal, sys, time, warnings
import oodmon.monitor.sinks.rerun as rerun_sink
from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import Monitor, RerunSink

rerun_sink.FILE_CHECK_SECONDS = 0.0  # looked at after every send (a second look a second later)
rerun_sink.FLUSH_EVERY = 200  # sends every 200 steps: several each episode
agent, env = load("cartpole", "dropout"), parse_variant("cartpole").make()
for name in sys.argv[1:]:
    full = name.endswith("full.rrd")
    if full:  # a write past the limit fails (EFBIG), as one on a full disk does
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with Monitor(agent, threshold=3.0, sinks=[RerunSink(name)]) as monitor:
            start, after = time.monotonic(), 0
            while True:  # episodes until what is looked for was seen, however busy the machine
                monitor.run_episode(env, seed=0)
                elapsed = time.monotonic() - start
                print(name, round(elapsed, 2), [str(w.message) for w in caught], flush=True)
                after += bool(caught)
                # the full file: three episodes after the warning (or none in a minute); the healthy one:
                # 2.5 s, second looks a second after first ones among its looks
                if (after >= 3 or elapsed > 60) if full else elapsed > 2.5:
                    break
    print(name, "failures", monitor.sinks.failures, flush=True)
"""


def test_a_file_rerun_stops_writing_is_warned_of_while_the_run_goes_on_not_only_at_its_end(tmp_path):
    """Rerun writes the file from a thread of its own: when that writer failed (a full disk; here a
    limit on the file's size) the sink said so only at the run's end, as its close failed: a
    deployment learned of it days late. Now a file that stops growing though steps are sent to it is
    a failure said at once (FILE_CHECK_SECONDS, patched to every send here), and a file written
    well never is, looked at as often."""
    healthy, full = tmp_path / "healthy.rrd", tmp_path / "full.rrd"
    run = subprocess.run([sys.executable, "-c", FILE_STOPS, str(healthy), str(full)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    wrote = [line for line in lines if line.startswith(str(healthy))]
    assert len(wrote) > 5 and all(line.endswith(" []") for line in wrote[:-1])
    assert wrote[-1] == f"{healthy} failures {{}}"
    ran = [line for line in lines if line.startswith(str(full))]
    said = [n for n, line in enumerate(ran) if f"Rerun has written nothing more to {full}" in line]
    assert said and said[0] < len(ran) - 2, run.stdout  # while the run went on, not at its close
    assert "its writer stopped (a full disk?" in ran[said[0]] and ran[-1].startswith(f"{full} failures {{'RerunSink': ")
    assert 0 < full.stat().st_size <= 100_000


class BrokenSink(MemorySink):
    def write_step(self, record):
        raise OSError("No space left on device")


def test_a_sink_refuses_the_log_of_an_earlier_run_unless_told_to_overwrite(agent, tmp_path):
    """A deployment started again after a crash, onto the same paths: the crashed run's log, alarms
    and all, is refused when the sinks are made (before any step), whole or split; overwrite=True
    replaces it and removes the earlier split log's parts, which would join the new run's in replay."""
    from oodmon.errors import ConfigError

    crashed = McapSink(tmp_path / "deploy.mcap")
    _run(agent, [crashed, RerunSink(tmp_path / "deploy.rrd")], episodes=2)
    before = (tmp_path / "deploy.mcap").read_bytes(), (tmp_path / "deploy.rrd").read_bytes()
    with pytest.raises(ConfigError, match=r"deploy\.mcap exists: the log of an earlier run; give another path, "
                                          r"or McapSink\(\.\.\., overwrite=True\) to replace it"):
        McapSink(tmp_path / "deploy.mcap")
    with pytest.raises(ConfigError, match=r"deploy\.rrd exists: .* RerunSink\(\.\.\., overwrite=True\)"):
        RerunSink(tmp_path / "deploy.rrd")
    assert ((tmp_path / "deploy.mcap").read_bytes(), (tmp_path / "deploy.rrd").read_bytes()) == before
    # The same sink opened again (a Monitor closed and used again) would replace its own first run.
    with pytest.raises(ConfigError, match="deploy.mcap exists"):
        _run(agent, [crashed], episodes=1, strict=True)
    assert (tmp_path / "deploy.mcap").read_bytes() == before[0]

    _run(agent, [McapSink(tmp_path / "deploy.mcap", overwrite=True), RerunSink(tmp_path / "deploy.rrd",
                                                                                 overwrite=True)], episodes=1)
    assert len(read_log(tmp_path / "deploy.mcap").episodes) == 1

    split = tmp_path / "split" / "run.mcap"
    _run(agent, [McapSink(split, split_episodes=1)], episodes=3)
    with pytest.raises(ConfigError, match=r"run-00000\.mcap exists \(and 2 more part\(s\) of a split log\)"):
        McapSink(split, split_episodes=1)
    again = McapSink(split, split_episodes=1, overwrite=True)
    assert len(list(split.parent.iterdir())) == 3  # nothing removed before the run starts
    _run(agent, [again], episodes=1)
    assert sorted(p.name for p in split.parent.iterdir()) == ["run-00000.mcap"]
    assert [len(log.episodes) for log in read_logs([split.parent])] == [1]


def test_overwrite_replaces_only_logs_not_a_model_or_a_threshold_at_the_path(agent, tmp_path):
    """overwrite=True is for the log of an earlier run: a file there that is no log of the sink's kind
    (a name typed wrong: a model, a threshold, an MCAP path given to the Rerun sink) is refused either
    way, when the sink is made and again at open; an empty file (a log torn at its start) is replaced."""
    from oodmon.errors import ConfigError

    model, threshold = tmp_path / "policy.zip", tmp_path / "threshold.json"
    model.write_bytes(b"PK\x03\x04" + bytes(100))
    threshold.write_text('{"value": 1.0}')
    for make, path, kind in [(McapSink, model, "an MCAP log"), (McapSink, threshold, "an MCAP log"),
                             (RerunSink, model, r"a Rerun recording \(\.rrd\)")]:
        for overwrite in (False, True):
            with pytest.raises(ConfigError, match=f"{path.name} exists and is not {kind} .*give another path"):
                make(path, overwrite=overwrite)
    (tmp_path / "a-folder").mkdir()
    for make in (McapSink, RerunSink):  # said so (it was "the log of an earlier run"; overwrite=True took it)
        for overwrite in (False, True):
            with pytest.raises(ConfigError, match="a-folder is a folder; give the log a file name"):
                make(tmp_path / "a-folder", overwrite=overwrite)
    mcap = McapSink(tmp_path / "run.mcap")  # made before the file came, as a run that starts later
    (tmp_path / "run.mcap").write_bytes(model.read_bytes())
    with pytest.raises(ConfigError, match="run.mcap exists and is not an MCAP log"):
        _run(agent, [mcap], episodes=1, strict=True)
    _run(agent, [McapSink(tmp_path / "deploy.mcap"), RerunSink(tmp_path / "deploy.rrd")], episodes=1)
    with pytest.raises(ConfigError, match="deploy.mcap exists and is not a Rerun recording"):
        RerunSink(tmp_path / "deploy.mcap", overwrite=True)  # an MCAP log is not the Rerun sink's to replace
    assert model.read_bytes() == b"PK\x03\x04" + bytes(100) and threshold.read_text() == '{"value": 1.0}'
    (tmp_path / "torn.mcap").write_bytes(b"")
    (tmp_path / "torn.rrd").write_bytes(b"RR")
    _run(agent, [McapSink(tmp_path / "torn.mcap", overwrite=True), RerunSink(tmp_path / "torn.rrd", overwrite=True)],
         episodes=1)
    assert len(read_log(tmp_path / "torn.mcap").episodes) == 1 and (tmp_path / "torn.rrd").read_bytes()[:4] == b"RRF2"


def test_a_log_that_appears_after_the_check_is_not_written_over(agent, tmp_path, monkeypatch):
    """Two runs started together with one log name both passed the checks before either wrote, and
    wrote one file between them that neither could replay (measured with `oodmon run`): each sink
    now creates its file only if none is there, so the later one fails instead, saying why."""
    from oodmon.errors import ConfigError

    for make, name in ((McapSink, "other.mcap"), (RerunSink, "other.rrd")):
        sink = make(tmp_path / name)
        monkeypatch.setattr(sink, "existing_paths", lambda: [])  # checked before the other run's file came
        (tmp_path / name).write_bytes(b"\x89MCAP0\r\n the other run's log" if name.endswith("mcap") else b"RRF2 other")
        before = (tmp_path / name).read_bytes()
        with pytest.raises(ConfigError, match=f"{name} appeared after this run checked it .another run writing there"):
            _run(agent, [sink], episodes=1, strict=True)
        assert (tmp_path / name).read_bytes() == before


def test_a_failing_sink_warns_counts_and_the_loop_goes_on(agent, tmp_path):
    good = MemorySink()
    broken = BrokenSink()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        records = _run(agent, [broken, good, McapSink(tmp_path / "ok.mcap")])
    assert len(good.steps) == sum(r.length for r in records) and len(good.episodes) == 3
    messages = [str(w.message) for w in caught if issubclass(w.category, SinkWarning)]
    assert messages and "BrokenSink.write_step failed (No space left on device)" in messages[0]


def test_an_unwritable_path_warns_and_the_loop_goes_on(agent, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    good = MemorySink()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _run(agent, [McapSink(blocker / "run.mcap"), good], episodes=1)
    assert len(good.episodes) == 1
    # One warning: a sink that could not open is left out of the run (each of its calls failed
    # again before, warned as "'McapSink' object has no attribute '_part'").
    messages = [str(w.message) for w in caught if issubclass(w.category, SinkWarning)]
    assert len(messages) == 1 and messages[0].startswith("McapSink.open failed (")
    assert messages[0].endswith("1 failure(s) so far, it is left out of this run, the monitor goes on")


def test_strict_mode_raises(agent):
    with pytest.raises(OSError, match="No space left on device"):
        _run(agent, [BrokenSink()], strict=True)


def test_mcap_passes_rerun_mcap_check(agent, tmp_path):
    _run(agent, [McapSink(tmp_path / "run.mcap")], episodes=1)
    rerun = os.path.join(os.path.dirname(sys.executable), "rerun")
    result = subprocess.run([rerun, "mcap", "check", str(tmp_path / "run.mcap")], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "/oodmon/step" in result.stdout


def test_pong_frames_reach_both_logs_as_the_agent_saw_them(tmp_path):
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    from oodmon.agents.agent import Agent
    from oodmon.agents.networks import build_modules, estimator_for

    arch = {"algorithm": "dqn", "obs_shape": [4, 84, 84], "n_outputs": 6, "cnn": True, "net_arch": [],
            "stochastic": None, "drop_p": 0.1, "last_only": True, "n_members": 3, "shared_torso": True}
    agent = Agent(estimator_for(build_modules(arch), arch), {"task": "pong", "method": "ensemble"}, tmp_path)
    memory = MemorySink()
    env = parse_variant("pong:gaussian_noise@3").make()
    with Monitor(agent, threshold=1.0, sinks=[memory, McapSink(tmp_path / "p.mcap"), RerunSink(tmp_path / "p.rrd")]) as m:
        m.run_episode(env, seed=0, max_steps=6)
    assert len(memory.steps) == 6 and memory.steps[0].observation is None
    with open(tmp_path / "p.mcap", "rb") as f:
        frames = [RawImage.FromString(msg.data) for _, _, msg in make_reader(f).iter_messages(topics=["/oodmon/frame"])]
    assert len(frames) == 6 and (frames[0].width, frames[0].height, frames[0].encoding) == (84, 84, "mono8")
    np.testing.assert_array_equal(np.frombuffer(frames[-1].data, np.uint8).reshape(84, 84), memory.steps[-1].frame)
    table = _rrd_table(tmp_path / "p.rrd")
    assert table.filter(like="/frame").dropna(how="all").shape[0] == 6


def test_a_viewer_that_is_gone_costs_the_run_little_time_and_no_memory(agent, tmp_path):
    import resource

    start = time.monotonic()
    _run(agent, [RerunSink(tmp_path / "alone.rrd")], episodes=3)
    alone = time.monotonic() - start
    memory = MemorySink()
    start = time.monotonic()
    sink = RerunSink(tmp_path / "kept.rrd", connect="rerun+http://127.0.0.1:9/proxy")
    with pytest.warns(SinkWarning, match="no Rerun viewer at rerun\\+http://127.0.0.1:9/proxy"):
        records = _run(agent, [sink, memory], episodes=3)
    assert time.monotonic() - start - alone < 2.0  # the dead viewer's whole cost: at most 2 s
    assert len(memory.episodes) == 3 and sink.dropped == sum(r.length for r in records) == len(memory.steps)
    assert (tmp_path / "kept.rrd").stat().st_size > 0  # the file goes on without the viewer
    # Steps for a dead viewer are dropped and counted, not queued: memory stays flat over 20,000 steps.
    sink = RerunSink(connect="rerun+http://127.0.0.1:9/proxy", connect_timeout=0.1)
    with pytest.warns(SinkWarning):
        monitor = Monitor(agent, threshold=3.0, sinks=[sink]).open()
    env = parse_variant("cartpole").make()
    monitor.run_episode(env, seed=0)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for seed in range(1, 41):
        monitor.run_episode(env, seed=seed)
    monitor.close()
    grown_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert sink.dropped >= 20_000 and grown_kib < 8 * 1024  # the unbounded queue grew ~0.9 KiB a step


def _free_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _viewer_beside(tmp_path, monkeypatch, script: str):
    """A ``rerun`` executable of ``script`` beside a Python that the sink takes for this one, none on PATH."""
    import shutil

    folder = tmp_path / "bin"
    folder.mkdir()
    (folder / "rerun").write_text(script)
    (folder / "rerun").chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(folder / "python"))
    monkeypatch.setattr(shutil, "which", lambda name, *args, **kwargs: None)


def test_a_viewer_that_cannot_start_is_warned_of_with_its_reason_and_the_run_and_its_file_go_on(
        agent, tmp_path, monkeypatch):
    """`oodmon run --spawn` with no Rerun viewer to start ended in rerun's traceback ("Failed to
    find Rerun Viewer executable in PATH": `.venv/bin/oodmon` run without activating the venv, whose
    `bin/` holds the rerun-sdk package's viewer). The sink starts the viewer beside this Python when
    there is one, and where none starts it warns once, saying why, and the run goes on with its
    file: no viewer to start at all, or one that stops at once (no display) with its last line."""
    import shutil

    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))  # nothing beside it
    monkeypatch.setattr(shutil, "which", lambda name, *args, **kwargs: None)
    memory = MemorySink()
    sink = RerunSink(tmp_path / "kept.rrd", spawn=True)
    start = time.monotonic()
    with pytest.warns(SinkWarning, match="no viewer started: no `rerun` executable beside this Python or on PATH .*; "
                                         "the run goes on without it, logging to"):
        records = _run(agent, [sink, memory], episodes=2)
    assert time.monotonic() - start < 10.0  # no wait for a viewer that was never started
    assert sink.dropped == sum(r.length for r in records) == len(memory.steps)
    assert (tmp_path / "kept.rrd").stat().st_size > 0
    port = _free_port()
    _viewer_beside(tmp_path, monkeypatch, f"#!/bin/sh\necho \"$@\" > {tmp_path}/args\n"
                                          "echo 'Error: neither WAYLAND_DISPLAY nor DISPLAY is set.' >&2\nexit 1\n")
    sink = RerunSink(tmp_path / "second.rrd", spawn=True, port=port)
    with pytest.warns(SinkWarning, match=f"no Rerun viewer at rerun\\+http://127.0.0.1:{port}/proxy \\(the viewer "
                                         "started stopped with exit code 1: Error: neither WAYLAND_DISPLAY nor DISPLAY "
                                         "is set.\\); the run goes on"):
        records = _run(agent, [sink], episodes=1)
    assert sink.dropped == records[0].length and (tmp_path / "second.rrd").stat().st_size > 0
    assert (tmp_path / "args").read_text().split() == [f"--port={port}", "--bind=127.0.0.1", "--memory-limit=75%",
                                                       "--server-memory-limit=1GiB", "--expect-data-soon"]


def _where_it_listens(command: list[str], tmp: Path) -> tuple[str | None, str]:
    """The line in which a Rerun executable started with ``command`` says where it listens for gRPC
    connections (None where it stopped before it said so), and what it printed before. Its
    temporary files go to ``tmp`` (a viewer killed leaves its rerun-data-<pid> folder behind)."""
    process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, start_new_session=True,
                               env={**os.environ, "RERUN_APP_ONLY": "true", "TMPDIR": str(tmp)})
    printed = []
    try:
        for line in process.stdout:
            if "Listening for gRPC connections on" in line:
                return line, "".join(printed)
            printed.append(line)
        return None, "".join(printed)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the wrapper script and the executable it starts
        process.wait()
        process.stdout.close()


def test_a_spawned_viewer_listens_on_this_machine_only_unless_told(agent, tmp_path, monkeypatch, capsys):
    """Rerun's viewer listens on every interface unless told otherwise, and `rerun.spawn` does not
    tell it: `oodmon run --spawn` served the run's stream to the network (rerun-sdk 0.41's viewer:
    "Listening for gRPC connections on 0.0.0.0:9876"). The sink starts it with `--bind` (127.0.0.1
    by default) and streams to it there. Checked twice: the installed executable, started with that
    command line, says where it listens; and a stand-in viewer beside this Python (a Rerun gRPC
    server on the port it is given) takes every step of a run.

    The installed viewer needs a display, which CI has not: its gRPC server and its window start in
    two threads, and which of "Listening ..." and the display error comes first is a race (here the
    first, always; on CI once the second, and the viewer had stopped before it said where it
    listens). So the command line is checked with `--serve-grpc` added: the same server without the
    window. Without `--bind` that server says 0.0.0.0 (the check can fail)."""
    from oodmon.cli import main
    from oodmon.monitor.sinks.rerun import viewer_command

    installed = os.path.join(os.path.dirname(sys.executable), "rerun")
    port = _free_port()
    listening, printed = _where_it_listens(viewer_command(installed, "127.0.0.1", port) + ["--serve-grpc"], tmp_path)
    assert listening is not None and f"Listening for gRPC connections on 127.0.0.1:{port}." in listening, printed
    assert "0.0.0.0" not in listening
    # A port of its own for each start. Once (the suite on 3 workers, 2026-12-02) the unbound server
    # stopped without saying where it listens, on the port the killed one before it had held; not
    # seen again in 20 starts so, busy or not. Its words are now shown if it stops again.
    port = _free_port()
    unbound = [part for part in viewer_command(installed, "127.0.0.1", port) if not part.startswith("--bind")]
    said, printed = _where_it_listens(unbound + ["--serve-grpc"], tmp_path)
    assert said is not None and f"on 0.0.0.0:{port}." in said, printed
    port = _free_port()
    viewer_said, _ = _where_it_listens(viewer_command(installed, "127.0.0.1", port), tmp_path)  # the window's race
    assert viewer_said is None or f"on 127.0.0.1:{port}." in viewer_said

    port = _free_port()
    _viewer_beside(tmp_path, monkeypatch, f"#!{sys.executable}\n"
                                          "import os, sys, time\n"
                                          "os.environ.pop('RERUN_APP_ONLY')  # the viewer's; the SDK will not import with it\n"
                                          "import rerun as rr\n"
                                          f"open({str(tmp_path / 'args')!r}, 'w').write(' '.join(sys.argv[1:]))\n"
                                          "port = int(dict(a.split('=', 1) for a in sys.argv[1:] if '=' in a)['--port'])\n"
                                          "rr.init('viewer'); rr.serve_grpc(grpc_port=port); time.sleep(60)\n")
    sink, memory = RerunSink(spawn=True, port=port, connect_timeout=2.0), MemorySink()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", SinkWarning)
            records = _run(agent, [sink, memory], episodes=2)
        assert sink.viewer is not None and sink.viewer.poll() is None  # started, left running after the run
        assert sink.dropped == 0 and len(memory.steps) == sum(r.length for r in records)  # the viewer took them
        assert f"--port={port} --bind=127.0.0.1 " in (tmp_path / "args").read_text()
        assert sink.live_at == f"rerun+http://127.0.0.1:{port}/proxy"
        again = RerunSink(spawn=True, port=port)  # a viewer listening there already takes the stream, as with rerun.spawn
        _run(agent, [again], episodes=1)
        assert again.viewer is None and again.dropped == 0 and again.live_at == sink.live_at
        capsys.readouterr()
        assert main(["run", "--task", "cartpole", "--method", "dropout", "--episodes", "1", "--spawn", "--port",
                     str(port)]) == 0  # the command says where it streams
        assert (f"streaming to the Rerun viewer at rerun+http://127.0.0.1:{port}/proxy (one already running "
                "there)") in capsys.readouterr().out
    finally:
        if sink.viewer is not None:
            sink.viewer.kill()
            sink.viewer.wait()


def test_a_viewer_that_goes_away_mid_run_is_dropped_with_one_warning_and_the_file_goes_on(agent, tmp_path):
    """A viewer that took the first episodes and then died (its process killed): at the next flush
    the sink warns once, drops it and counts what it would have sent; the run and the file go on."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    viewer = subprocess.Popen([sys.executable, "-c", "import rerun as rr, time; rr.init('viewer'); "
                               f"print(rr.serve_grpc(grpc_port={port}), flush=True); time.sleep(120)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert str(port) in viewer.stdout.readline()  # listening
        sink, memory = RerunSink(tmp_path / "kept.rrd", connect=f"rerun+http://127.0.0.1:{port}/proxy"), MemorySink()
        env = parse_variant("cartpole:length=2.0").make(onset_step=30)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with Monitor(agent, threshold=3.0, sinks=[sink, memory]) as monitor:
                for seed in range(2):
                    monitor.run_episode(env, seed=seed)
                assert sink._live is not None and sink.dropped == 0  # the viewer took them
                viewer.kill()
                viewer.wait()
                before = len(memory.steps)
                for seed in range(2, 6):
                    monitor.run_episode(env, seed=seed)
    finally:
        viewer.kill()
        viewer.stdout.close()
    said = [str(w.message) for w in caught if issubclass(w.category, SinkWarning)]
    assert len(said) == 1 and "the Rerun viewer stopped taking data" in said[0] and "logging to" in said[0]
    after = len(memory.steps) - before
    assert sink._live is None and 0 < sink.dropped <= after  # dropped from the flush that failed on
    assert len(memory.episodes) == 6 and sum(e.length for e in memory.episodes) == len(memory.steps)
    frame = _rrd_table(tmp_path / "kept.rrd")
    scores = frame["/score:Scalars:scalars"].dropna()  # every step in the file, the viewer gone or not
    np.testing.assert_allclose([v[0] for v in scores], [s.score for s in memory.steps], rtol=1e-6)


def _listening() -> set[tuple[str, int]]:
    """(address, port) of every TCP socket listening on this machine (from /proc/net)."""
    import ipaddress

    found = set()
    for name in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(name) as f:
            for line in f.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                if state != "0A":
                    continue
                address, port = local.split(":")
                raw = bytes.fromhex(address)
                words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
                ip = ipaddress.ip_address(words)
                if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped:
                    ip = ip.ipv4_mapped
                found.add((str(ip), int(port, 16)))
    return found


def test_what_a_served_stream_keeps_for_later_viewers_is_the_users_to_choose(agent, monkeypatch):
    """Rerun's server keeps a served stream for viewers that connect later, up to its memory limit:
    at oodmon's 512 MiB some 630 MB of the process after 3-5 million CartPole steps
    (scripts/monitor_memory.py --sinks rerun-serve; with --serve-memory 32 it held at 445 MB after
    250,000 steps, with 0 it stayed flat). serve_memory (--serve-memory) reaches the server."""
    import rerun

    limits, real = [], rerun.GrpcServerSink

    def recorded(*args, **kwargs):
        limits.append(kwargs["server_memory_limit"])
        return real(*args, **kwargs)

    monkeypatch.setattr(rerun, "GrpcServerSink", recorded)
    for memory in (None, 0, 64):
        sink = RerunSink(serve=True, port=_free_port(), **({} if memory is None else {"serve_memory": memory}))
        records = _run(agent, [sink], episodes=2, strict=True)
        assert sink.chunks >= 7 and sum(r.length for r in records) > 0  # the steps served as ever
    assert limits == ["512MiB", "0MiB", "64MiB"]
    for bad in (-1, 1.5, True, "64MiB", None):
        with pytest.raises(InvalidParameterError, match=r"serve_memory=.* is not allowed; give the MiB"):
            RerunSink(serve=True, serve_memory=bad)


def test_a_served_stream_listens_on_loopback_only_unless_told(agent):
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    sink = RerunSink(serve=True, port=port)
    with Monitor(agent, threshold=3.0, sinks=[sink], strict=True):
        bound = {address for address, p in _listening() if p == port}
        assert bound == {"127.0.0.1"} and sink.served_at and str(port) in sink.served_at


def test_serving_on_a_port_another_program_listens_on_is_refused_before_the_run(agent, tmp_path):
    """Rerun's server failed on its own thread with a log line, and the run went on serving nothing
    while `oodmon run --serve` said "serving the Rerun stream at ..." (2026-11-27). Now the sink is
    refused as it is made: the command exits 2 before its first episode."""
    import socket

    from oodmon.cli import main
    from oodmon.errors import ConfigError

    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ConfigError, match=rf"cannot serve the Rerun stream on 127.0.0.1:{port} \(Address already in "
                                              r"use\).*Choose another port"):
            RerunSink(serve=True, port=port)
        log = tmp_path / "never.mcap"
        assert main(["run", "--task", "cartpole", "--method", "ensemble", "--serve", "--port", str(port),
                     "--mcap", str(log)]) == 2
        assert not log.exists()  # before the first episode
    with pytest.raises(ConfigError, match="cannot serve the Rerun stream on 256.0.0.1"):
        RerunSink(serve=True, bind="256.0.0.1")


def test_render_logs_a_picture_of_each_cartpole_state_and_is_off_by_default(agent, tmp_path):
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    env = parse_variant("cartpole:length=2.0").make()
    for render, name in ((True, "pictures.mcap"), (False, "plain.mcap")):
        with Monitor(agent, threshold=3.0, sinks=[McapSink(tmp_path / name)], render=render) as monitor:
            record = monitor.run_episode(env, seed=0, max_steps=30)
        with open(tmp_path / name, "rb") as f:
            frames = [RawImage.FromString(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/oodmon/frame"])]
        if not render:
            assert frames == []
            continue
        assert len(frames) == record.length and frames[0].encoding == "rgb8"
        pictures = [np.frombuffer(f.data, np.uint8).reshape(f.height, f.width, 3) for f in frames]
        assert pictures[0].shape == (120, 240, 3)
        assert not np.array_equal(pictures[0], pictures[-1])  # the pole moved: the picture shows it


def test_the_shipped_foxglove_layout_shows_what_the_logs_hold(agent, tmp_path):
    import json

    from oodmon.monitor.sinks.mcap import FOXGLOVE_LAYOUT

    layout = json.loads(FOXGLOVE_LAYOUT.read_text())

    def leaves(node):
        return [node] if isinstance(node, str) else [*leaves(node["first"]), *leaves(node["second"])]
    assert sorted(leaves(layout["layout"])) == sorted(layout["configById"])
    # (a rule with a window: its step messages hold the mean the alarm compares, which the layout plots)
    with Monitor(agent, threshold=0.0, window=2, sinks=[McapSink(tmp_path / "x.mcap")], render=True) as monitor:
        monitor.run_episode(parse_variant("cartpole:length=2.0").make(), seed=0, max_steps=20)
    with open(tmp_path / "x.mcap", "rb") as f:
        messages = {c.topic: m for _, c, m in make_reader(f).iter_messages()}  # (each topic's last)
    step = json.loads(messages["/oodmon/step"].data)
    config = layout["configById"]
    for panel, settings in config.items():
        kind = panel.split("!")[0]
        if kind == "Plot":
            for path in settings["paths"]:
                topic, *fields = path["value"].split(".")
                assert topic == "/oodmon/step"
                value = step
                for field in fields[:-1]:
                    value = value[field]
                assert fields[-1] in value or fields[0] == "scores", path  # scores: the detectors a run has
        elif kind == "RosOut":
            assert settings["topicToRender"] in messages
        elif kind == "Image":
            assert settings["imageMode"]["imageTopic"] in messages
    assert {"score", "threshold", "shifted"} <= set(step) and "spread" in step["scores"]
    assert isinstance(step["compared"], float)  # the last step's: the window full


def _outcome(write, record):
    try:
        return write(record)
    except Exception as error:  # noqa: BLE001  (the outcome compared is the error's type)
        return type(error)


def test_a_step_message_is_the_bytes_json_dumps_writes_for_every_kind_of_value(monkeypatch):
    """The MCAP sink writes the usual step's JSON itself (a quarter less time than json.dumps): for
    steps of every kind of value a monitor or a user's sink hands it (ints, floats, np.float64,
    NaN and infinities, lists of ints, np.float32, bools, numpy bools, names of any characters),
    the same text as json.dumps with its nulls, or the same error; under a rule with a window or a
    sequential one, with what it compares last."""
    from oodmon.monitor.records import StepRecord
    from oodmon.monitor.sinks import mcap
    from oodmon.monitor.sinks.mcap import _step_json, _step_json_dumps

    slow = []  # the steps the sink's own writing handed to json.dumps
    monkeypatch.setattr(mcap, "_step_json_dumps", lambda record, compares=False: slow.append(record) or
                        _step_json_dumps(record, compares))
    rng = np.random.default_rng(20261130)
    floats = [0.0, -0.0, 1.5, -2.25e-7, 1e300, 12.345678901234567, np.float64(0.1), float("nan"), float("inf"),
              -float("inf"), np.float32(0.5), 3, True, None]
    finite = floats[:7]  # what a monitor's step holds; then what json.dumps writes as null, or apart, or refuses

    def pick(values, finite_share=0.92):
        return values[rng.integers(len(finite))] if rng.random() < finite_share else values[rng.integers(len(values))]

    def numbers(n):
        values = [pick(floats) for _ in range(n)]
        kind = rng.random()  # now and then an array or a tuple, which json.dumps refuses or writes as a list
        return values if kind < 0.95 else np.array(values) if kind < 0.975 else tuple(values)

    actions = [lambda: int(rng.integers(-3, 6)), lambda: numbers(int(rng.integers(0, 3))), lambda: np.int64(2),
               lambda: [1, 2], lambda: [[0.5, 1.0]], lambda: True, lambda: (0.5,)]
    names = ["spread", "dynamics", "features", "combined", "drift", "é \"quoted\" \\ name", "info", "nan"]
    outcomes = set()
    for _ in range(3000):
        scores = {names[int(k)]: pick(floats) for k in rng.integers(0, len(names), int(rng.integers(0, 5)))}
        if rng.random() < 0.02:
            scores[7] = 1.0  # a key that is not a string: json.dumps writes it in quotes
        record = StepRecord(
            episode=int(rng.integers(0, 10**6)) if rng.random() < 0.97 else np.int64(4),
            step=int(rng.integers(0, 10**6)), action=actions[int(rng.integers(len(actions)))]() if rng.random() < 0.2
            else actions[0](), mean=numbers(int(rng.integers(0, 4))), std=numbers(int(rng.integers(0, 4))),
            score=pick(floats), threshold=pick(floats, 0.7) if rng.random() < 0.8 else float("nan"),
            alarm=bool(rng.random() < 0.5) if rng.random() < 0.97 else np.bool_(True), shifted=bool(rng.random() < 0.5),
            observation=None if rng.random() < 0.3 else numbers(int(rng.integers(1, 6))), scores=scores,
            compared=pick(floats, 0.7) if rng.random() < 0.8 else float("nan"))
        compares = bool(rng.random() < 0.5)  # a rule with a window or a sequential one: what it compares (format 9)
        expected = _outcome(lambda r: _step_json_dumps(r, compares), record)
        assert _outcome(lambda r: _step_json(r, compares), record) == expected, record
        if isinstance(expected, str):
            json.loads(expected)  # JSON that any parser reads: the nulls, no NaN
        outcomes.add("text" if isinstance(expected, str) else expected.__name__)
    assert outcomes == {"text", "TypeError"}  # np.float32 and the like: json.dumps's error, as before
    assert 3000 - len(slow) > 600 and len(slow) > 600  # both ways taken often (879 written out, 2,121 by json.dumps)
