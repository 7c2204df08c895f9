"""A run's files as replay finds them: a split log's part missing among the logs read is warned of,
not counted in silence, and a copy of a log is read once."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import pytest

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import McapSink, Monitor
from oodmon.replay import MissingPartWarning, RunLog, SkippedLogWarning, compute_metrics, missing_parts, read_logs
from tests.helpers import run_cli


@pytest.fixture(scope="module")
def split_run(tmp_path_factory) -> Path:
    """A CartPole run of 5 episodes, 30 steps each, split into a file per episode; its folder."""
    folder = tmp_path_factory.mktemp("split")
    env = parse_variant("cartpole:length=2.0").make(onset_step=10, max_episode_steps=30)
    with Monitor(load("cartpole", "ensemble"), threshold=3.0, sinks=[McapSink(folder / "run.mcap", split_episodes=1)]) as m:
        for seed in range(5):
            m.run_episode(env, seed=seed, variant="cartpole:length=2.0")
    return folder


def _copy(split_run: Path, tmp_path: Path, parts: list[int]) -> Path:
    """A folder holding only these parts of the split run."""
    folder = tmp_path / "copy"
    folder.mkdir(parents=True)
    for part in parts:
        shutil.copy(split_run / f"run-{part:05d}.mcap", folder)
    return folder


def _read(*paths, category: type[Warning] = MissingPartWarning) -> tuple[list[RunLog], list[str]]:
    """The logs read and the messages of the warnings of ``category`` their reading gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        logs = read_logs(list(paths))
    return logs, [str(w.message) for w in caught if w.category is category]


def test_every_part_carries_its_runs_id_and_a_whole_run_reads_without_a_warning(split_run):
    logs, warned = _read(split_run)
    ids = {log.metadata["run_id"] for log in logs}
    assert len(logs) == 5 and len(ids) == 1 and len(ids.pop()) == 32
    assert warned == [] and missing_parts(logs) == []


def test_parts_missing_between_those_read_are_named_with_the_episodes_they_held(split_run, tmp_path):
    folder = _copy(split_run, tmp_path, [0, 2, 4])
    logs, warned = _read(folder)
    assert [e.episode for log in logs for e in log.episodes] == [0, 2, 4]
    (gap,) = missing_parts(logs)
    assert gap.missing == (range(1, 2), range(3, 4)) and gap.count == 2 and gap.episodes == 2
    assert gap.files == (folder / "run-00001.mcap", folder / "run-00003.mcap")
    assert warned == [f"parts 1, 3 ({folder}/run-00001.mcap, {folder}/run-00003.mcap) of the split log of "
                      f"{folder}/run-00000.mcap and 2 more part(s) are not among the logs read: the 2 episode(s) they "
                      "held are not counted"]
    # the first parts missing: counted from episode 0
    (gap,) = missing_parts(_read(_copy(split_run, tmp_path / "late", [3, 4]))[0])
    assert gap.missing == (range(0, 3),) and gap.episodes == 3


def test_a_lost_last_part_cannot_be_told_and_renamed_parts_stay_one_run(split_run, tmp_path):
    assert _read(_copy(split_run, tmp_path, [0, 1, 2]))[1] == []  # as a run of three episodes
    folder = _copy(split_run, tmp_path / "renamed", [0, 1, 3])
    (folder / "run-00003.mcap").rename(folder / "heavy-cart.mcap")  # its id still says whose part it is
    (gap,) = missing_parts(_read(folder)[0])
    assert gap.missing == (range(2, 3),) and gap.episodes == 1
    assert gap.files == ()  # the parts read no longer say what the missing one was called


def test_two_runs_in_one_folder_are_told_apart_by_their_ids(split_run, tmp_path):
    folder = _copy(split_run, tmp_path, [0, 1, 2, 3, 4])
    env = parse_variant("cartpole").make(max_episode_steps=20)
    with Monitor(load("cartpole", "ensemble"), threshold=3.0, sinks=[McapSink(folder / "other.mcap", split_episodes=1)]) as m:
        for seed in range(3):
            m.run_episode(env, seed=seed)
    (folder / "other-00001.mcap").unlink()
    logs, warned = _read(folder)
    assert len(logs) == 7 and len(warned) == 1 and "part 1 (" in warned[0] and "other-00000.mcap" in warned[0]


def _old(path: str, part: int, **metadata) -> RunLog:
    """A log of a split run written before parts carried the run's id."""
    return RunLog(Path(path), "cartpole", "ensemble", 3.0, {"part": str(part), "command": "run", **metadata}, [], True)


def test_logs_before_the_id_are_parts_of_one_run_by_folder_name_and_metadata():
    assert [g.missing for g in missing_parts([_old("a/run-00000.mcap", 0), _old("a/run-00002.mcap", 2)])] == [(range(1, 2),)]
    assert missing_parts([_old("a/run-00000.mcap", 0), _old("b/run-00002.mcap", 2)])[0].read == (Path("b/run-00002.mcap"),)
    other_name = [_old("a/run-00000.mcap", 0), _old("a/other-00001.mcap", 1)]  # another name: another run
    assert [g.read for g in missing_parts(other_name)] == [(Path("a/other-00001.mcap"),)]
    other = _old("a/run-00002.mcap", 2, command="run --seed 1")  # another command: another run
    assert [g.read for g in missing_parts([_old("a/run-00000.mcap", 0), other])] == [(other.path,)]
    same = [_old("a/run-00000.mcap", 0), _old("a/run-00000.mcap", 0), _old("a/run-00002.mcap", 2)]
    assert missing_parts(same) == []  # part 0 twice: two runs it cannot tell apart, passed over
    not_a_number = RunLog(Path("a/y.mcap"), "cartpole", "ensemble", 3.0, {"part": "²"}, [], True)  # isdigit(), not int()
    assert missing_parts([_old("a/x.mcap", 0), not_a_number]) == []
    huge = missing_parts([_old("a/run-00000.mcap", 0), _old("a/run-99999999999.mcap", 99999999999)])
    assert huge[0].count == 99999999998 and len(huge[0].files) == 5  # a damaged part number: named, not listed


def test_replay_warns_and_check_says_its_rows_lack_the_missing_parts_episodes(split_run, tmp_path):
    folder = _copy(split_run, tmp_path, [0, 2, 3, 4])
    whole = run_cli("check", "--update", "--baseline", str(tmp_path / "base.json"), str(split_run))
    assert whole.returncode == 0 and "lack" not in whole.stdout + whole.stderr
    checked = run_cli("check", "--baseline", str(tmp_path / "base.json"), str(folder))
    assert checked.returncode == 0 and checked.stdout.rstrip().endswith(
        "(1 split log lacks a part, as the warning above says: the rows lack its episodes)")
    assert checked.stderr.startswith("oodmon: warning: part 1 (") and checked.stderr.count("\n") == 1
    replayed = run_cli("replay", "--episodes", "--csv", str(folder))
    assert replayed.returncode == 0 and replayed.stderr.count("part 1 (") == 1
    assert compute_metrics(_read(folder)[0])[0].episodes == 4


def test_a_copy_of_a_log_under_the_folder_replayed_is_read_once(split_run, tmp_path):
    """A backup beside the logs (both under the folder replayed) held every episode twice; now the
    copy is skipped with a warning, and a copy taken while the log was written (torn, fewer
    episodes) gives way to the finished log, in whichever order they are found."""
    logs_dir = _copy(split_run, tmp_path / "deployed", [0, 1, 2, 3, 4])
    shutil.copytree(logs_dir, tmp_path / "deployed" / "backup")
    logs, skipped = _read(tmp_path / "deployed", category=SkippedLogWarning)
    skipped.sort()
    assert len(logs) == 5 and {log.path.parent.name for log in logs} == {"backup"}  # sorted: backup/ comes first
    assert len(skipped) == 5 and skipped[0].startswith(f"skipped {logs_dir}/run-00000.mcap: a copy of "
                                                       f"{tmp_path}/deployed/backup/run-00000.mcap (the same run, ")
    assert compute_metrics(logs) == compute_metrics(read_logs([split_run]))
    whole = tmp_path / "one.mcap"
    env = parse_variant("cartpole").make(max_episode_steps=20)
    with Monitor(load("cartpole", "ensemble"), threshold=3.0, sinks=[McapSink(whole)]) as m:
        for seed in range(3):
            m.run_episode(env, seed=seed)
    early = tmp_path / "a-early-copy.mcap"  # found first
    early.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])  # (2/3 of format 10's held all 3 episodes)
    (log,), skipped = _read(early, whole, category=SkippedLogWarning)
    assert log.path == whole and len(log.episodes) == 3
    assert len(skipped) == 1 and skipped[0].startswith(f"skipped {early}: a copy of {whole}")
    assert skipped[0].endswith("which holds more episodes; its episodes are read once")
    with Monitor(load("cartpole", "ensemble"), threshold=3.0, sinks=[McapSink(tmp_path / "two.mcap")]) as m:
        m.run_episode(env, seed=0)  # the same command and episode again: another run, read beside it
    assert len(read_logs([whole, tmp_path / "two.mcap"])) == 2
