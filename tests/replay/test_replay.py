"""Replay of recorded logs: pinned numbers, equality with the online run, damaged files, check."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.errors import LogFormatError
from oodmon.monitor import McapSink, MemorySink, Monitor
from oodmon.replay import RecoveryWarning, compute_metrics, read_log

DATA = Path(__file__).parent.parent / "data"
LOGS = sorted(DATA.glob("*.mcap"))


from tests.helpers import run_cli as _cli


def test_recorded_logs_give_their_pinned_numbers():
    rows = {m.variant: m for m in compute_metrics(read_log(p) for p in LOGS)}
    assert set(rows) == {"cartpole", "cartpole:length=2.0"}
    id_row, shifted = rows["cartpole"], rows["cartpole:length=2.0"]
    assert (id_row.episodes, id_row.steps, id_row.false_alarm_rate) == (3, 1500, 1.0)
    assert (shifted.episodes, shifted.steps, shifted.id_steps, shifted.ood_steps) == (3, 1009, 1803, 706)
    assert shifted.auroc == pytest.approx(0.9526348122974144, abs=1e-12)
    assert shifted.aupr == pytest.approx(0.9586463257152119, abs=1e-12)
    assert shifted.detection_rate == 1.0 and shifted.early_alarm_rate == 0.0
    assert shifted.delay_mean == pytest.approx(10 / 3) and shifted.delay_median == 4.0


def test_fast_path_equals_the_step_messages():
    from mcap.reader import make_reader

    log = read_log(DATA / "cartpole-ensemble-length2.mcap")
    with open(DATA / "cartpole-ensemble-length2.mcap", "rb") as f:
        steps = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/oodmon/step"])]
    for episode in log.episodes:
        mine = [s for s in steps if s["episode"] == episode.episode]
        assert episode.scores.tolist() == [s["score"] for s in mine]
        assert episode.shifted.tolist() == [s["shifted"] for s in mine]
        assert episode.alarm.tolist() == [s["alarm"] for s in mine]


def test_replay_equals_online(tmp_path):
    agent = load("cartpole", "dropout")
    memory = MemorySink()
    env = parse_variant("cartpole:length=2.0").make(onset_step=40)
    with Monitor(agent, threshold=3.5, sinks=[memory, McapSink(tmp_path / "run.mcap")]) as monitor:
        online = [monitor.run_episode(env, seed=s, variant="cartpole:length=2.0") for s in range(4)]
    log = read_log(tmp_path / "run.mcap")
    assert log.complete and log.task == "cartpole" and log.method == "dropout" and log.threshold == 3.5
    for record, replayed in zip(online, log.episodes, strict=True):
        assert (replayed.length, replayed.alarms, replayed.first_alarm_step, replayed.total_return) == (
            record.length, record.alarms, record.first_alarm_step, record.total_return)
        mine = [s for s in memory.steps if s.episode == record.episode]
        np.testing.assert_array_equal(replayed.scores, [s.score for s in mine])
        assert replayed.alarm.sum() == sum(s.alarm for s in mine)
        # Format 4: each step's reward and whether the env ended the episode (the pole fell).
        np.testing.assert_array_equal(replayed.rewards, record.rewards)
        assert replayed.rewards.sum() == record.total_return and replayed.terminated is record.terminated
        assert record.terminated is (record.length < 500)


def test_logs_older_than_format_4_have_no_rewards_and_no_failures():
    from oodmon.replay import failure_step

    for log in (read_log(p) for p in LOGS):
        assert all(e.rewards is None and e.terminated is None for e in log.episodes)
        assert all(failure_step(e, "cartpole") is None for e in log.episodes)


def test_a_log_of_a_newer_format_is_read_with_a_warning(tmp_path, monkeypatch):
    """A log written by a newer oodmon (a format this one does not know) is read as the newest
    format it knows, and replay says so instead of passing over what is new in it in silence."""
    import warnings

    from oodmon.monitor import logformat
    from oodmon.replay import NewerFormatWarning

    agent = load("cartpole", "dropout", seed=0)
    with monkeypatch.context() as future:
        future.setattr(logformat, "FORMAT_VERSION", logformat.FORMAT_VERSION + 1)
        with Monitor(agent, sinks=[McapSink(tmp_path / "future.mcap")]) as monitor:
            monitor.run_episode(parse_variant("cartpole").make(), seed=0, max_steps=30)
    with pytest.warns(NewerFormatWarning, match=rf"log format {logformat.FORMAT_VERSION + 1} \(oodmon .*\), newer than "
                                               rf"this oodmon's {logformat.FORMAT_VERSION}"):
        log = read_log(tmp_path / "future.mcap")
    assert len(log.episodes) == 1 and log.episodes[0].length == 30
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # today's logs: no warning
        read_log(DATA / "cartpole-ensemble-length2.mcap")


def test_truncated_file_is_read_up_to_its_last_complete_episode(tmp_path):
    source = DATA / "cartpole-ensemble-length2.mcap"
    raw = source.read_bytes()
    whole = read_log(source)
    for cut in (len(raw) - 100, len(raw) * 2 // 3, len(raw) // 3):
        (tmp_path / "torn.mcap").write_bytes(raw[:cut])
        with pytest.warns(RecoveryWarning, match=r"unfinished or damaged .* recovered \d+ complete episode"):
            log = read_log(tmp_path / "torn.mcap")
        assert not log.complete and len(log.episodes) <= len(whole.episodes)
        for torn, full in zip(log.episodes, whole.episodes):
            np.testing.assert_array_equal(torn.scores, full.scores)
    assert len(log.episodes) < len(whole.episodes)


def test_replay_never_writes_into_its_inputs(tmp_path):
    copies = []
    for path in LOGS:
        shutil.copy(path, tmp_path / path.name)
        copies.append(tmp_path / path.name)
    before = {p: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns) for p in copies}
    assert _cli("replay", str(tmp_path)).returncode == 0
    assert _cli("check", str(tmp_path), "--baseline", str(tmp_path / "b.json"), "--update").returncode == 0
    assert {p: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns) for p in copies} == before


@pytest.mark.parametrize(
    "content, words",
    [
        (b"hello, not a log", "is not an MCAP file"),
        (None, "is an MCAP file but not an oodmon log"),
    ],
)
def test_files_that_are_not_oodmon_logs_get_one_line(tmp_path, content, words):
    path = tmp_path / "other.mcap"
    if content is None:
        from mcap.writer import Writer

        with open(path, "wb") as f:
            writer = Writer(f)
            writer.start()
            schema = writer.register_schema("x", "jsonschema", b"{}")
            channel = writer.register_channel("/x", "json", schema)
            writer.add_message(channel, log_time=0, data=b"{}", publish_time=0)
            writer.finish()
    else:
        path.write_bytes(content)
    with pytest.raises(LogFormatError, match=words):
        read_log(path)
    result = _cli("replay", str(path))
    lines = [l for l in result.stderr.splitlines() if l.strip()]
    assert result.returncode == 2 and len(lines) == 1 and words in lines[0]


def test_replay_formats():
    table = _cli("replay", *map(str, LOGS))
    assert table.returncode == 0 and "cartpole:length=2.0" in table.stdout and "0.953" in table.stdout
    rows = json.loads(_cli("replay", str(DATA), "--json").stdout)
    assert [r["auroc"] for r in rows] == [None, pytest.approx(0.9526348122974144)]
    csv = _cli("replay", str(DATA), "--csv").stdout.splitlines()
    assert csv[0].startswith("task,method,detector,variant,episodes,steps,auroc") and len(csv) == 3
    markdown = _cli("replay", str(DATA), "--markdown").stdout.splitlines()
    assert markdown[0].startswith("| task | method | detector | variant") and markdown[1].startswith("|---|")


def test_a_detector_the_logs_do_not_hold_is_one_line_naming_those_they_do():
    misspelt = _cli("replay", str(DATA), "--detector", "sprad")
    assert misspelt.returncode == 2 and misspelt.stderr.strip() == (
        "oodmon: error: episode 0 has no scores of detector 'sprad' (did you mean 'spread'?); it has spread")
    other = _cli("replay", str(DATA), "--detector", "dynamics")
    assert other.returncode == 2 and other.stderr.strip().endswith("detector 'dynamics'; it has spread")


def test_replay_episodes_lists_every_episode_with_its_alarm_and_failure():
    rows = json.loads(_cli("replay", str(DATA), "--episodes", "--json").stdout)
    logs = [read_log(p) for p in LOGS]
    assert len(rows) == sum(len(log.episodes) for log in logs) == 6
    for row, episode in zip(rows, [e for log in logs for e in log.episodes], strict=True):
        assert (row["episode"], row["variant"], row["length"], row["alarms"], row["first_alarm_step"]) == (
            episode.episode, episode.variant, episode.length, episode.alarms, episode.first_alarm_step)
        if row["variant"] == "cartpole":  # ID: no onset, delay or failure
            assert row["onset"] is None and row["delay"] is None and row["failure_step"] is None
        else:
            assert row["delay"] == episode.first_alarm_step - episode.onset
    shifted = compute_metrics(logs)[1]
    delays = [r["delay"] for r in rows if r["variant"] == "cartpole:length=2.0"]
    assert np.mean(delays) == pytest.approx(shifted.delay_mean) and np.median(delays) == shifted.delay_median
    table = _cli("replay", str(DATA), "--episodes")
    assert table.returncode == 0 and "6 episode(s) of 2 log(s), 6 alarmed" in table.stdout
    csv = _cli("replay", str(DATA), "--episodes", "--csv").stdout.splitlines()
    assert csv[0].startswith("log,episode,variant,seed,onset,length,return,alarms") and len(csv) == 7
    refused = _cli("replay", str(DATA), "--episodes", "--monitor")
    assert refused.returncode == 2 and "not allowed with argument" in refused.stderr


def test_check_exit_codes_and_what_fell(tmp_path):
    baseline = tmp_path / "baseline.json"
    assert _cli("check", str(DATA), "--baseline", str(baseline), "--update").returncode == 0
    ok = _cli("check", str(DATA), "--baseline", str(baseline))
    assert ok.returncode == 0 and "ok: 2 rows" in ok.stdout
    data = json.loads(baseline.read_text())
    again = _cli("check", str(DATA), "--baseline", str(baseline), "--update")  # a baseline replaced: said so
    assert again.returncode == 0 and "(replacing the baseline it held: 2 rows)" in again.stdout
    assert json.loads(baseline.read_text()) == data
    # logs with a row the baseline lacks: that row was counted among those "at or above" it
    only_id = tmp_path / "id-only.json"
    written = _cli("check", str(DATA / "cartpole-ensemble-id.mcap"), "--baseline", str(only_id), "--update")
    assert written.returncode == 0
    both = _cli("check", str(DATA), "--baseline", str(only_id))
    assert both.returncode == 0 and (f"ok: 1 rows at or above {only_id}; 1 row(s) of the logs the baseline lacks, "
                                     "compared with nothing (--update writes them in)") in both.stdout.replace("\n", "")
    # one false alarm fewer of the same 3 episodes: beyond the tolerance, within chance (said, no fall)
    baseline.write_text(json.dumps(dict(data, metrics=dict(data["metrics"], **{"cartpole/ensemble/cartpole": {
        "false_alarm_rate": 2 / 3, "alarm_episodes": 3}}))))
    chance = _cli("check", str(DATA), "--baseline", str(baseline))
    assert chance.returncode == 0 and "1 move(s) beyond the tolerance were within chance" in chance.stdout
    assert ("within chance: cartpole/ensemble/cartpole: false_alarm_rate rose from 0.6667 to 1 (2/3 to 3/3 episodes, "
            "one-sided p = 0.5; tolerance 0.02)") in chance.stderr
    data["metrics"]["cartpole/ensemble/cartpole:length=2.0"]["auroc"] = 0.99
    data["metrics"]["cartpole/ensemble/cartpole"]["false_alarm_rate"] = 0.5
    baseline.write_text(json.dumps(data))
    fell = _cli("check", str(DATA), "--baseline", str(baseline))
    assert fell.returncode == 1
    assert "cartpole/ensemble/cartpole:length=2.0: auroc fell from 0.99 to 0.9526" in fell.stderr
    assert "cartpole/ensemble/cartpole: false_alarm_rate rose from 0.5 to 1" in fell.stderr
    assert _cli("check", str(DATA), "--baseline", str(baseline), "--tolerance", "0.6").returncode == 0
    missing = _cli("check", str(DATA), "--baseline", str(tmp_path / "none.json"))
    assert missing.returncode == 2 and "does not exist" in missing.stderr


def test_check_against_a_baseline_of_other_logs_says_whose_rows_each_holds(tmp_path):
    """Logs of another agent or env than the baseline's printed a FELL line per row, "missing from
    the logs", and nothing more (2026-12-07): a note now names the agents of each."""
    baseline = tmp_path / "baseline.json"
    assert _cli("check", str(DATA), "--baseline", str(baseline), "--update").returncode == 0
    data = json.loads(baseline.read_text())
    fell = _cli("check", str(DATA), "--baseline", str(baseline))
    assert fell.returncode == 0 and "none of" not in fell.stderr
    other = {key.replace("cartpole/ensemble/", "Reacher-v5/sb3/"): row for key, row in data["metrics"].items()}
    baseline.write_text(json.dumps(dict(data, metrics=other)))
    fell = _cli("check", str(DATA), "--baseline", str(baseline))
    assert fell.returncode == 1 and fell.stderr.count("FELL Reacher-v5/sb3/") == 2
    assert (f"oodmon: note: none of {baseline}'s 2 rows is in these logs: theirs are of cartpole/ensemble, the "
            "baseline's of Reacher-v5/sb3 (a baseline of other logs?") in fell.stderr


def test_check_over_a_torn_log_says_its_rows_were_read_in_part(tmp_path):
    """A regression check over a killed run's log compared its recovered episodes alone and printed
    FELL lines as if the agent had got worse; the summary now says a log was torn (2026-11-27)."""
    folder = tmp_path / "logs"
    folder.mkdir()
    for log in LOGS:
        shutil.copyfile(log, folder / log.name)
    baseline = tmp_path / "baseline.json"
    assert "tolerance 0.02\n" in _cli("check", str(folder), "--baseline", str(baseline), "--update").stdout
    torn = folder / "cartpole-ensemble-length2.mcap"
    torn.write_bytes(torn.read_bytes()[: torn.stat().st_size // 2])
    fell = _cli("check", str(folder), "--baseline", str(baseline))
    assert fell.returncode == 1 and "unfinished or damaged" in fell.stderr
    assert fell.stderr.rstrip().endswith("fell below " + str(baseline) + " (1 of the 2 logs was torn and read in part, "
                                         "as the warning above says: its rows lack the episodes lost)")
    again = _cli("check", str(folder), "--baseline", str(tmp_path / "torn.json"), "--update")
    assert "(1 of the 2 logs was torn" in again.stdout.replace("\n", "")


def test_a_log_named_twice_is_read_once_and_a_foreign_file_in_a_folder_is_skipped(tmp_path):
    from oodmon.replay import SkippedLogWarning, read_logs

    folder = tmp_path / "logs"
    folder.mkdir()
    for log in LOGS:
        shutil.copyfile(log, folder / log.name)
    (folder / "notes.mcap").write_text("not a log")
    with pytest.warns(SkippedLogWarning) as caught:
        logs = read_logs([folder, folder / LOGS[0].name, str(folder / LOGS[0].name)])
    messages = [str(w.message) for w in caught]
    assert len(logs) == len(LOGS) and sorted(log.path.name for log in logs) == sorted(p.name for p in LOGS)
    assert sum("named more than once" in m for m in messages) == 2
    assert any("skipped" in m and "notes.mcap" in m and "not an MCAP file" in m for m in messages)
    metrics = compute_metrics(logs)
    assert [m.episodes for m in metrics] == [m.episodes for m in compute_metrics([read_log(p) for p in LOGS])]
    with pytest.raises(LogFormatError, match="notes.mcap is not an MCAP file"):
        read_logs([folder / "notes.mcap"])  # named on its own, a bad file is an error


def test_an_interrupted_episode_is_logged_as_such_and_left_out_of_the_metrics(tmp_path):
    agent = load("cartpole", "ensemble")
    env = parse_variant("cartpole:length=2.0").make(onset_step=20)

    class Stop(Exception):
        pass

    def stop_at_first_alarm(event):
        raise Stop

    with Monitor(agent, threshold=4.6, sinks=[McapSink(tmp_path / "cut.mcap")]) as monitor:
        finished = monitor.run_episode(env, seed=0, variant="cartpole:length=2.0")
        monitor.callbacks.append(stop_at_first_alarm)
        with pytest.raises(Stop):
            monitor.run_episode(env, seed=1, variant="cartpole:length=2.0")
    log = read_log(tmp_path / "cut.mcap")
    assert [e.episode for e in log.episodes] == [0] and not log.episodes[0].interrupted
    assert [e.episode for e in log.interrupted] == [1] and log.interrupted[0].length < finished.length
    assert compute_metrics([log])[0].episodes == 1


def test_replay_monitor_prints_the_alarm_figures_of_the_monitors_benchmark(tmp_path):
    """`replay --monitor`: false alarms with their interval, alarms before failure, delays; the
    JSON is compute_monitor_metrics of the logs plus one pooled row per agent."""
    from oodmon.replay import compute_monitor_metrics

    agent = load("cartpole", "dropout")
    with Monitor(agent, threshold=3.5, sinks=[McapSink(tmp_path / "shifted.mcap")]) as monitor:
        env = parse_variant("cartpole:length=2.0").make()
        for seed, onset in ((0, 30), (1, 60)):
            monitor.run_episode(env, seed=seed, variant="cartpole:length=2.0", options={"onset_step": onset})
    with Monitor(agent, threshold=3.5, sinks=[McapSink(tmp_path / "id.mcap")]) as monitor:
        monitor.run_episode(parse_variant("cartpole").make(), seed=0, variant="cartpole")
    logs = [read_log(tmp_path / "id.mcap"), read_log(tmp_path / "shifted.mcap")]
    assert [e.onset for e in logs[1].episodes] == [30, 60]
    done = _cli("replay", "--monitor", "--json", str(tmp_path))
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    expected = [m.to_dict() for m in compute_monitor_metrics(logs)]
    assert rows[:2] == json.loads(json.dumps(expected))
    assert rows[2]["variant"] == "all shifted" and rows[2]["episodes"] == 2
    table = _cli("replay", "--monitor", str(tmp_path))
    assert "alarmed before failure" in table.stdout and "failed:" in table.stderr
    refused = _cli("replay", "--monitor", "--csv", str(tmp_path))
    assert refused.returncode != 0 and "--monitor" in refused.stderr


def test_replay_says_when_a_row_pools_the_logs_of_several_policies_weights(tmp_path):
    """Logs of one task and method from two policies' weights (a model retrained into the same folder
    of logs): replay pools them in one row per variant, and says so, naming each weights' logs; the
    logs of one policy alone get no such note."""
    from oodmon.replay import pooled_weights

    first, retrained = load("cartpole", "ensemble"), load("cartpole", "ensemble")
    retrained.metadata["policy_hash"] = "sha256:" + "b" * 64  # what a retrained model's files hash to
    for name, agent, spec in (("old.mcap", first, "cartpole"), ("new.mcap", retrained, "cartpole:length=2.0")):
        with Monitor(agent, threshold=4.6, sinks=[McapSink(tmp_path / name)]) as monitor:
            monitor.run_episode(parse_variant(spec).make(), seed=0, variant=spec)
    logs = [read_log(tmp_path / "old.mcap"), read_log(tmp_path / "new.mcap")]
    pooled = pooled_weights(logs)
    assert list(pooled) == [("cartpole", "ensemble")]
    assert sorted(pooled["cartpole", "ensemble"].values()) == [[tmp_path / "new.mcap"], [tmp_path / "old.mcap"]]
    for view in ([], ["--monitor"]):
        done = _cli("replay", *view, str(tmp_path))
        assert done.returncode == 0, done.stderr
        assert "the cartpole/ensemble rows pool the logs of 2 policies' weights (sha256:bbbbbbbb" in done.stderr
        assert "new.mcap" in done.stderr and "old.mcap" in done.stderr
    alone = _cli("replay", str(tmp_path / "old.mcap"))
    assert alone.returncode == 0 and "pool the logs" not in alone.stderr
    assert pooled_weights([logs[0], read_log(tmp_path / "old.mcap")]) == {}


def test_replay_says_when_a_variants_alarms_came_from_runs_of_two_thresholds(tmp_path):
    """Runs of one agent under two thresholds (recalibrated between them): `--monitor` counts a
    variant's alarms together, and replay says so, naming each threshold's logs; one threshold's
    logs alone get no such note."""
    agent = load("cartpole", "ensemble")
    for name, threshold in (("strict.mcap", 4.6), ("loose.mcap", 5.2)):
        with Monitor(agent, threshold=threshold, sinks=[McapSink(tmp_path / name)]) as monitor:
            monitor.run_episode(parse_variant("cartpole:length=2.0").make(onset_step=10), seed=0,
                                variant="cartpole:length=2.0")
    for view in ([], ["--monitor"]):
        done = _cli("replay", *view, str(tmp_path))
        assert done.returncode == 0, done.stderr
        assert ("oodmon: note: the cartpole/ensemble logs raised their alarms by 2 thresholds (spread > 5.2 (score > "
                "threshold for 3 consecutive steps): ") in done.stderr
        assert "loose.mcap" in done.stderr and "strict.mcap" in done.stderr
    alone = _cli("replay", "--monitor", str(tmp_path / "loose.mcap"))
    assert alone.returncode == 0 and "thresholds" not in alone.stderr


def test_replay_says_when_a_row_pools_the_scores_of_two_fits_of_a_detector(tmp_path):
    """One policy's logs scored by two fits of its dynamics detector (refitted between runs): the
    log records each fit's fingerprint, and replay says that the dynamics rows pool two scales."""
    from oodmon.monitor.detectors import DynamicsDetector, collect
    from oodmon.replay import pooled_fits

    agent = load("cartpole", "ensemble")
    episodes = collect(agent, parse_variant("cartpole").make(), 1, seed=0)
    fits = [DynamicsDetector(2, epochs=2, seed=seed).fit(episodes) for seed in (0, 1)]
    for name, fit in (("first.mcap", fits[0]), ("refit.mcap", fits[1])):
        with Monitor(agent, detectors=[fit], sinks=[McapSink(tmp_path / name)]) as monitor:
            monitor.run_episode(parse_variant("cartpole").make(), seed=0, variant="cartpole")
    logs = [read_log(tmp_path / "first.mcap"), read_log(tmp_path / "refit.mcap")]
    assert [log.metadata["fitted.dynamics"] for log in logs] == [fit.fingerprint() for fit in fits]
    assert "fitted.spread" not in logs[0].metadata  # spread learns nothing
    assert sorted(pooled_fits(logs)["cartpole", "ensemble", "dynamics"].values()) == [
        [tmp_path / "first.mcap"], [tmp_path / "refit.mcap"]]
    done = _cli("replay", str(tmp_path))
    assert done.returncode == 0, done.stderr
    assert "the cartpole/ensemble dynamics rows pool the logs of 2 fits of the dynamics detector" in done.stderr
    assert pooled_fits([logs[0], read_log(tmp_path / "first.mcap")]) == {}


def test_each_episode_logs_its_sensor_noise_and_replay_says_when_a_row_pools_two(tmp_path):
    """Every episode records the sensor noise of the env it was played in (format 8): by
    run_episode and by MonitoredEnv, in its start message too, so a torn log's running episode
    keeps it. Replay lists it, names a shared noise in the table's title, and says when a row pools
    episodes of two noises; logs older than format 8 read as noiseless."""
    from oodmon.monitor import MonitoredEnv

    agent = load("cartpole", "ensemble")
    with Monitor(agent, threshold=4.6, sinks=[McapSink(tmp_path / "quiet.mcap")]) as monitor:
        quiet = monitor.run_episode(parse_variant("cartpole").make(), seed=0)
    with Monitor(agent, threshold=4.6, sinks=[McapSink(tmp_path / "noisy.mcap")], segment_steps=4) as monitor:
        noisy = [monitor.run_episode(parse_variant("cartpole").make(obs_noise=0.05), seed=1, max_steps=10)]
        env = MonitoredEnv(parse_variant("cartpole:length=2.0").make(onset_step=3, obs_noise=0.05), monitor)
        env.reset(seed=2)
        for _ in range(10):
            env.step()
    assert quiet.obs_noise == 0.0 and noisy[0].obs_noise == 0.05
    logs = {name: read_log(tmp_path / f"{name}.mcap") for name in ("quiet", "noisy")}
    assert [e.obs_noise for e in logs["quiet"].episodes] == [0.0]
    assert [(e.variant, e.obs_noise) for e in logs["noisy"].episodes] == [("cartpole", 0.05)]
    assert [(e.variant, e.obs_noise) for e in logs["noisy"].interrupted] == [("cartpole:length=2.0", 0.05)]  # closed inside it
    assert all(e.obs_noise == 0.0 for path in LOGS for e in read_log(path).episodes)  # format 7 and older

    alone = _cli("replay", "--episodes", str(tmp_path / "noisy.mcap"))
    assert alone.returncode == 0, alone.stderr
    assert "sensor noise 0.05" in alone.stdout and "sensor noises" not in alone.stderr
    both = _cli("replay", str(tmp_path))
    assert both.returncode == 0, both.stderr
    assert ("oodmon: note: the cartpole/ensemble rows pool episodes played at 2 sensor noises (0: "
            in both.stderr) and "0.05: " in both.stderr and "noisy.mcap" in both.stderr
    rows = json.loads(_cli("replay", "--episodes", "--json", str(tmp_path)).stdout)
    assert sorted(row["obs_noise"] for row in rows) == [0.0, 0.05, 0.05]
    csv = _cli("replay", "--episodes", "--csv", str(tmp_path)).stdout.splitlines()
    # the noise where format 8 put it (last then), the first alarm's readings after it (format 10), and
    # where in the picture after those (format 12)
    assert csv[0].endswith(",ended,obs_noise,first_alarm_readings,first_alarm_region") and sorted(
        line.split(",")[-3] for line in csv[1:]) == ["0.0", "0.05", "0.05"]
    assert "noise" in _cli("replay", "--episodes", str(tmp_path)).stdout  # a column where they differ
    import io

    from rich.console import Console

    from oodmon.replay.report import episode_rows, episodes_table

    for width in (80, 120, 200):  # narrow (< 150): each variant's cell says its noise; a column squeezed the
        shown = io.StringIO()     # variants out of sight at 80 (2026-12-05)
        Console(width=width, file=shown).print(episodes_table(episode_rows(list(logs.values())), "x", width=width))
        text = shown.getvalue()
        assert max(len(line) for line in text.splitlines()) <= width
        if width == 80:
            assert text.count("ID,") == 2 and text.count("length=2.0") == 1 and text.count("noise") == 3, text
        elif width == 120:
            assert "ID, noise 0 " in text and "ID, noise 0.05 " in text and "length=2.0, noise 0.05" in text, text
        else:
            assert "┃ noise ┃" in text, text

    baseline = tmp_path / "quiet.json"  # a regression check of noisy logs against a noiseless baseline says so
    assert _cli("check", str(tmp_path / "quiet.mcap"), "--baseline", str(baseline), "--update").returncode == 0
    assert json.loads(baseline.read_text())["obs_noise"] == {"cartpole/ensemble": [0.0]}
    said = "oodmon: note: the cartpole/ensemble logs were played at sensor noise 0.05, the baseline's at 0: "
    assert said in _cli("check", str(tmp_path / "noisy.mcap"), "--baseline", str(baseline)).stderr
    assert said[:30] not in _cli("check", str(tmp_path / "quiet.mcap"), "--baseline", str(baseline)).stderr
    baseline.write_text(json.dumps(json.loads(baseline.read_text()) | {"obs_noise": {"cartpole/ensemble": [-1]}}))
    refused = _cli("check", str(tmp_path / "quiet.mcap"), "--baseline", str(baseline))
    assert refused.returncode == 2 and "obs_noise={'cartpole/ensemble': [-1]} is not allowed" in refused.stderr

    raw, recovered = (tmp_path / "noisy.mcap").read_bytes(), []
    for cut in range(len(raw) // 3, len(raw), 40):  # a killed run: its running episode from its start message
        (tmp_path / "torn.mcap").write_bytes(raw[:cut])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                recovered += read_log(tmp_path / "torn.mcap").interrupted
            except LogFormatError:
                pass
    assert recovered and all(e.obs_noise == 0.05 for e in recovered)


def test_the_replay_table_is_readable_at_80_columns():
    import io

    from rich.console import Console

    from oodmon.replay.metrics import VariantMetrics
    from oodmon.replay.report import to_table

    def row(method, variant, detector, auroc, far=None, detected=None, delay=None):
        return VariantMetrics("pendulum", method, variant, 10, 2000, 1000, 1000, auroc, auroc and auroc - 0.1,
                              auroc and 1 - auroc, far, None if far is not None else 0.0, detected, delay, delay,
                              detector)

    metrics = [row("dropconnect", "pendulum", "combined", None, far=0.02),
               row("dropconnect", "pendulum:max_speed=0.4,max_torque=0.25", "dynamics", 0.98765),
               row("ensemble", "pendulum:l=0.05", "combined", 0.91234, detected=0.9, delay=3.0)]
    for width, narrow in ((80, True), (220, False)):
        buffer = io.StringIO()
        Console(width=width, file=buffer).print(to_table(metrics, "replay", width=width))
        lines = buffer.getvalue().splitlines()
        assert max(len(line) for line in lines) <= width
        text = buffer.getvalue()
        assert "0.988" in text and "0.912" in text and "…" not in text
        if narrow:  # the variant wraps instead of being cut; the alarm's figures in one column
            assert "max_torque=0.25" in text.replace("\n", "").replace("│", "").replace(" ", "")
            assert "FA 2%" in text and "90% in 3" in text
        else:
            assert "pendulum:max_speed=0.4,max_torque=0.25" in text


def test_a_log_from_before_the_episode_scores_channel_is_read_from_its_step_messages(tmp_path):
    """Logs older than format 3 have no per-episode score arrays: replay rebuilds each episode's
    scores (every detector's), shifts and alarms from its step messages. Here a log of today with
    that channel left out, as such a log was; also torn (the recovery reads the same way)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from oodmon.monitor import logformat
    from oodmon.monitor.detectors import detectors_for

    agent = load("cartpole", "ensemble", seed=0)
    env = parse_variant("cartpole:length=2.0").make(onset_step=10)
    with Monitor(agent, threshold=3.5, detectors=detectors_for(agent), detector="spread",
                 sinks=[McapSink(tmp_path / "today.mcap")]) as monitor:
        for seed in range(3):
            monitor.run_episode(env, seed=seed, variant="cartpole:length=2.0")
    with open(tmp_path / "today.mcap", "rb") as source, open(tmp_path / "old.mcap", "wb") as target:
        reader, writer = make_reader(source), Writer(target)
        writer.start(profile="", library="test")
        for item in reader.iter_metadata():
            writer.add_metadata(item.name, dict(item.metadata))
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.topic == logformat.EPISODE_SCORES:
                continue
            if channel.id not in channels:
                schema_id = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schema_id)
            writer.add_message(channels[channel.id], log_time=message.log_time, publish_time=message.publish_time,
                               data=message.data)
        writer.finish()
    today, old = read_log(tmp_path / "today.mcap"), read_log(tmp_path / "old.mcap")
    assert len(old.episodes) == len(today.episodes) == 3 and old.complete
    for rebuilt, written in zip(old.episodes, today.episodes):
        assert rebuilt.length == written.length and rebuilt.alarms == written.alarms
        np.testing.assert_array_equal(rebuilt.scores, written.scores)
        np.testing.assert_array_equal(rebuilt.shifted, written.shifted)
        np.testing.assert_array_equal(rebuilt.alarm, written.alarm)
        assert rebuilt.detector_scores.keys() == written.detector_scores.keys() == {"spread", "dynamics", "features",
                                                                                    "combined"}
        for name, values in written.detector_scores.items():
            np.testing.assert_allclose(rebuilt.detector_scores[name], values, rtol=1e-6)
    raw = (tmp_path / "old.mcap").read_bytes()
    (tmp_path / "torn.mcap").write_bytes(raw[:len(raw) - 200])  # the footer and summary gone
    with pytest.warns(RecoveryWarning, match="recovered 3 complete episode"):
        torn = read_log(tmp_path / "torn.mcap")
    np.testing.assert_array_equal(np.concatenate([e.scores for e in torn.episodes]),
                                  np.concatenate([e.scores for e in today.episodes]))


def _rewrite(source: Path, target: Path, *, message=None, metadata=None) -> None:
    """``source`` written again record by record into ``target``, each JSON message's row through
    ``message(topic, row) -> bytes`` and the run's metadata through ``metadata(dict) -> dict``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(source, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        runs = [dict(m.metadata) for m in reader.iter_metadata() if m.name == "oodmon.run"]
        records = [(channel.topic, m.log_time, m.data) for _, channel, m in reader.iter_messages()]
    with open(target, "wb") as f:
        writer = Writer(f)
        writer.start()
        channels = {}
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            registered = writer.register_schema(schema.name, schema.encoding, schema.data) if schema else 0
            channels[channel.topic] = writer.register_channel(channel.topic, channel.message_encoding, registered)
        for topic, log_time, data in records:
            if message is not None and topic.startswith("/oodmon/") and topic not in ("/oodmon/alarm", "/oodmon/frame"):
                data = message(topic, json.loads(data))
            writer.add_message(channels[topic], log_time=log_time, data=data, publish_time=log_time)
        writer.add_metadata("oodmon.run", runs[0] if metadata is None else metadata(runs[0]))
        writer.finish()


def _damage_scores(topic, row):
    if topic == "/oodmon/episode_scores":
        row["score_f64"] = "not base64 at all"
    return json.dumps(row).encode()


def _shorten_scores(topic, row):
    if topic == "/oodmon/episode" and row["episode"] == 1:
        row["length"] += 1
    return json.dumps(row).encode()


def _not_json(topic, row):
    return b"\xff not json" if topic == "/oodmon/episode" else json.dumps(row).encode()


def _negative_noise(topic, row):
    if topic == "/oodmon/episode":
        row["obs_noise"] = -0.5
    return json.dumps(row).encode()


def _no_episode(topic, row):
    if topic == "/oodmon/episode":
        del row["episode"]
    return json.dumps(row).encode()


@pytest.mark.parametrize("edit, words", [
    ({"message": _damage_scores}, "the score arrays of episode 0 are damaged"),
    ({"message": _shorten_scores}, "episode 1 has length 501 but 500 scores; the log is damaged"),
    ({"message": _not_json}, "a /oodmon/episode message is not JSON"),
    ({"message": _no_episode}, "a /oodmon/episode message has no episode number"),
    ({"message": _negative_noise}, "episode record 0 has obs_noise=-0.5; not a log oodmon wrote"),
    ({"metadata": lambda run: run | {"threshold": "high"}}, "its run metadata has threshold='high', not a number"),
    ({"metadata": lambda run: {k: v for k, v in run.items() if k not in ("task", "method")}}, None),
], ids=["scores", "length", "json", "episode", "noise", "threshold", "metadata-only"])
def test_a_damaged_oodmon_log_is_one_clear_error_naming_the_file(tmp_path, edit, words):
    """A log whose records oodmon's own reader cannot trust: read_log names the file and what is
    wrong, and ``oodmon replay`` prints that one line with exit code 2 (no traceback)."""
    source = DATA / "cartpole-ensemble-id.mcap"
    assert read_log(source).episodes  # the undamaged file reads
    path = tmp_path / "damaged.mcap"
    _rewrite(source, path, **edit)
    if words is None:  # run metadata without task or method: still a log, read and labelled unknown
        log = read_log(path)
        assert (log.task, log.method) == ("unknown", "unknown") and len(log.episodes) == len(read_log(source).episodes)
        return
    with pytest.raises(LogFormatError, match=re.escape(words)) as raised:
        read_log(path)
    assert str(path) in str(raised.value)
    result = _cli("replay", str(path))
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1 and words in lines[0] and "Traceback" not in result.stderr


def test_folders_and_unreadable_paths_are_said_plainly(tmp_path):
    from oodmon.replay import read_logs

    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(LogFormatError, match="empty holds no .mcap files"):
        read_logs([empty])
    with pytest.raises(LogFormatError, match="is a folder; give the .mcap files in it"):
        read_log(empty)
    with pytest.raises(LogFormatError, match="none.mcap does not exist"):
        read_log(tmp_path / "none.mcap")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "a.mcap").write_text("not a log")
    with pytest.warns(Warning, match="skipped"), pytest.raises(LogFormatError, match="no oodmon log among"):
        read_logs([foreign])


def test_replay_and_check_of_logs_leave_torch_and_sklearn_unimported_and_keep_blas_to_one_thread(tmp_path):
    """A command that plays no policy reads logs only: torch, a second of its start, is not imported
    (before 2026-12-04 every command imported it to set its threads, and replay's episode-use words
    came from a module that imports the agents), nor is sklearn (another second: replay ranks steps
    itself, as sklearn does); numpy's BLAS is still held to OODMON_TORCH_THREADS."""
    import os
    import subprocess
    import sys

    code = ("import sys, json; from oodmon.cli import main; from threadpoolctl import threadpool_info; "
            "logs = sys.argv[1:3]; codes = [main(['replay', *logs]), main(['replay', '--monitor', *logs])]; "
            "ranked = 'sklearn' in sys.modules; "
            "codes += [main(['check', sys.argv[1], '--baseline', sys.argv[3], '--update']), "
            "main(['check', sys.argv[1], '--baseline', sys.argv[3]])]; "
            "print(json.dumps([codes, 'torch' in sys.modules, ranked, "
            "sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'})]), file=sys.stderr)")
    env = {**os.environ, "OODMON_TORCH_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", code, str(DATA / "cartpole-ensemble-id.mcap"),
                           str(DATA / "cartpole-ensemble-length2.mcap"), str(tmp_path / "baseline.json")],
                          capture_output=True, text=True, env=env, timeout=120)
    codes, torch_imported, sklearn_imported, blas = json.loads(done.stderr.strip().splitlines()[-1])
    assert (codes, torch_imported, sklearn_imported, blas) == ([0, 0, 0, 0], False, False, [1]), done.stderr[-2000:]
