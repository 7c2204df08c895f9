"""Runs killed with SIGKILL at seeded random moments: every finished episode replays, alarms and
frames included, and the recovery warning counts them right. One driver process imports oodmon
once and forks each monitored run from it, so thirteen kills take seconds."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from oodmon.replay import RecoveryWarning, read_log
from tests.helpers import once_per_run

DRIVER = r"""
import json, os, select, signal, sys, time
import numpy as np
import torch
torch.set_num_threads(1)  # no thread pool in the parent: forking stays safe
from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import McapSink, Monitor

folder, plan = sys.argv[1], json.loads(sys.argv[2])
agents = {"cartpole": load("cartpole", "ensemble"), "pong": load("pong", "ensemble")}
results = []
for k, (task, delay) in enumerate(plan):
    path = os.path.join(folder, f"{task}-{k}.mcap")
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the monitored run
        os.close(read)
        try:
            spec = "cartpole:length=2.0" if task == "cartpole" else "pong:gaussian_noise@5"
            env = parse_variant(spec).make(onset_step=20)
            monitor = Monitor(agents[task], threshold=4.6 if task == "cartpole" else 0.0, consecutive=1,
                              sinks=[McapSink(path)]).open()
            os.write(write, b"o")
            for episode in range(10_000):
                monitor.run_episode(env, seed=episode, variant=spec, max_steps=None if task == "cartpole" else 25)
                os.write(write, b"e")
        finally:
            os._exit(0)
    os.close(write)
    got = b""
    while not got.startswith(b"o"):
        got += os.read(read, 1)
    end = time.monotonic() + delay
    while (left := end - time.monotonic()) > 0:
        if select.select([read], [], [], left)[0]:
            got += os.read(read, 4096)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    while select.select([read], [], [], 0)[0] and (more := os.read(read, 4096)):
        got += more
    os.close(read)
    results.append({"path": path, "task": task, "finished": got.count(b"e")})
print(json.dumps(results))
"""


def _kill_runs(folder) -> list[dict]:
    rng = np.random.default_rng(20261123)
    # Kill times in seconds after the monitor opened: a run finishes about 2 CartPole episodes in its
    # first 0.1 s and a 25-step Pong episode in its first 0.3 s (2026-11-27), several at these.
    plan = [("cartpole", 0.0)] + [("cartpole", float(d)) for d in rng.uniform(0.2, 0.8, 9)] + [
        ("pong", float(d)) for d in rng.uniform(0.4, 1.0, 3)]
    out = subprocess.run([sys.executable, "-c", DRIVER, str(folder), json.dumps(plan)], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def killed(tmp_path_factory, worker_id):
    """The thirteen killed runs, once for the whole run (9 s; its tests only read their logs)."""
    return once_per_run(tmp_path_factory, worker_id, "killed", _kill_runs)


def _topics(path) -> dict[str, int]:
    counts: dict[str, int] = {}
    channels: dict[int, str] = {}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Channel):
                    channels[record.id] = record.topic
                elif isinstance(record, Message):
                    counts[channels[record.channel_id]] = counts.get(channels[record.channel_id], 0) + 1
        except Exception:  # noqa: BLE001  (the torn end)
            pass
    return counts


def test_every_finished_episode_of_a_killed_run_replays(killed):
    assert len(killed) == 13
    for run in killed:
        with pytest.warns(RecoveryWarning) as caught:
            log = read_log(run["path"])
        recovered = len(log.episodes)
        # The episode may have reached the disk an instant before the kill, its report not.
        assert run["finished"] <= recovered <= run["finished"] + 1, run
        assert f"recovered {recovered} complete episode(s), {sum(e.length for e in log.episodes)} steps" in str(
            caught[0].message)
        assert log.task == run["task"] and log.method == "ensemble" and not log.complete
        for episode in log.episodes:
            # the observation acted on at step `onset` is the last one of the ID world
            assert len(episode.scores) == episode.length and episode.shifted[episode.onset + 1:].all()
        assert [e.episode for e in log.episodes] == list(range(recovered))


@pytest.mark.filterwarnings("ignore::oodmon.replay.RecoveryWarning")
def test_the_killed_runs_held_alarms_and_frames(killed):
    cartpole = [r for r in killed if r["task"] == "cartpole" and r["finished"] > 0]
    assert len(cartpole) >= 8 and all(_topics(r["path"]).get("/oodmon/alarm", 0) > 0 for r in cartpole)
    assert sum(sum(e.alarms for e in read_log(r["path"]).episodes) for r in cartpole) > 0
    pong = [r for r in killed if r["task"] == "pong"]
    assert all(r["finished"] > 0 and _topics(r["path"]).get("/oodmon/frame", 0) >= 25 * r["finished"] for r in pong)


def test_a_run_killed_before_its_first_episode_ended_is_an_oodmon_log_with_no_episode(killed):
    first = killed[0]
    assert first["finished"] == 0
    with pytest.warns(RecoveryWarning, match="recovered 0 complete episode"):
        log = read_log(first["path"])
    assert log.episodes == [] and log.metadata["task"] == "cartpole" and log.metadata["policy_hash"].startswith("sha256:")


UNCLOSED = """
import sys
from oodmon.agents import load
from oodmon.envs import Variant
from oodmon.monitor import McapSink, Monitor
monitor = Monitor(load("cartpole", "dropout"), threshold=3.0, sinks=[McapSink(sys.argv[1])]).open()
for episode in range(2):
    monitor.run_episode(Variant("cartpole").make(), seed=episode)
"""


def test_a_script_that_never_closes_its_monitor_leaves_a_finished_log(tmp_path):
    import warnings

    subprocess.run([sys.executable, "-c", UNCLOSED, str(tmp_path / "open.mcap")], check=True, timeout=120)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecoveryWarning)  # finished: read through its index, no recovery
        log = read_log(tmp_path / "open.mcap")
    assert log.complete and len(log.episodes) == 2


def _interrupted_at(method, call: int):
    """``method`` (a Monitor's) that raises KeyboardInterrupt at its ``call``-th call, as Ctrl-C
    there would; ``.calls``: the count so far, in a list to reset."""
    calls = [0]

    def interrupted(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == call:
            raise KeyboardInterrupt
        return method(self, *args, **kwargs)

    interrupted.calls = calls
    return interrupted


def test_ctrl_c_in_oodmon_run_exits_130_and_marks_the_cut_episode(tmp_path, monkeypatch, capsys):
    """The log is finished, the cut episode marked; the run's closing table of the episodes played
    whole is printed as at its end (before 2026-12-05 it was not: 175 CartPole episodes of `run
    --episodes 1000`, Ctrl-C after 10 s, and nothing said of them), and where no log was written,
    Ctrl-C no longer says "every finished episode is in the logs"."""
    from oodmon.cli import main
    from oodmon.monitor import Monitor

    interrupted_at_step_700 = _interrupted_at(Monitor.step, 700)
    calls = interrupted_at_step_700.calls
    monkeypatch.setattr(Monitor, "step", interrupted_at_step_700)
    code = main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "5", "--mcap",
                 str(tmp_path / "cut.mcap")])
    out, err = capsys.readouterr()
    assert code == 130 and err.strip().splitlines() == [
        "oodmon: interrupted; every finished episode is in the logs, the cut one is marked interrupted; the 1 "
        "episode played whole is in the table above"]
    assert "interrupted: cartpole/ensemble in cartpole" in out and f"written to {tmp_path / 'cut.mcap'}" in out
    log = read_log(tmp_path / "cut.mcap")
    assert log.complete and [e.length for e in log.episodes] == [500] and len(log.interrupted) == 1
    assert log.interrupted[0].length == 199
    calls[0] = 0  # no log: said so, not "in the logs"
    assert main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "5"]) == 130
    out, err = capsys.readouterr()
    assert err.strip().splitlines()[-1] == ("oodmon: interrupted; the 1 episode played whole is in the table above; no "
                                            "log was written (--mcap or --rrd keeps every step)")
    assert re.search(r"│\s+0 │\s+0 │\s+500\.0 │\s+500 │", out)  # its row
    calls[0] = 600  # cut in the first episode: no table, nothing played whole to say
    assert main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "5"]) == 130
    out, err = capsys.readouterr()
    assert "interrupted:" not in out and err.strip().splitlines()[-1] == (
        "oodmon: interrupted; no log was written (--mcap or --rrd keeps every step)")


def test_sigterm_stops_oodmon_run_as_ctrl_c_does_and_exits_143(tmp_path, monkeypatch, capsys):
    """A service manager stops a process with SIGTERM. Python's default dies at once: the run's log was
    torn and its running episode lost (measured: `oodmon run --episodes 1000 --mcap`, SIGTERM after
    12 s, replayed 89 episodes with a recovery warning). oodmon takes it as Ctrl-C: the log is
    finished, the cut episode marked interrupted; a second SIGTERM during that is ignored, and the
    handler before the command is back after it."""
    import os
    import signal

    from oodmon.cli import main
    from oodmon.monitor import Monitor

    step = Monitor.step
    calls = [0]

    def terminated_at_step_700(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == 700:
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)  # the second: ignored while the command cleans up
        return step(self, *args, **kwargs)

    monkeypatch.setattr(Monitor, "step", terminated_at_step_700)
    before = signal.getsignal(signal.SIGTERM)
    code = main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "5", "--mcap",
                 str(tmp_path / "cut.mcap")])
    assert signal.getsignal(signal.SIGTERM) == before
    assert code == 143 and capsys.readouterr().err.strip().splitlines() == [
        "oodmon: stopped by SIGTERM; every finished episode is in the logs, the cut one is marked interrupted; the 1 "
        "episode played whole is in the table above"]
    log = read_log(tmp_path / "cut.mcap")
    assert log.complete and [e.length for e in log.episodes] == [500] and len(log.interrupted) == 1
    assert log.interrupted[0].length == 199  # the handler runs as os.kill returns: step 700 is not taken


def test_a_run_whose_output_is_closed_stops_as_on_ctrl_c_and_says_so_on_stderr(tmp_path):
    """`oodmon run ... | head -2`: the reader of its output gone, the program stops as on Ctrl-C
    (its log finished, the cut episode marked interrupted), says so on stderr, and ends with 141
    (a shell's code for SIGPIPE). Before (2026-12-06): exit 1, which reads as a regression check's
    fall, and nothing said (rich's console raised SystemExit(1) at its next print)."""
    from oodmon.monitor.threshold import Threshold

    threshold, log = tmp_path / "t.json", tmp_path / "run.mcap"
    Threshold(0.0, "chosen_std", 1, "episode", 0.05, 45, 9_000, task="cartpole", method="ensemble",
              detector="spread").save(threshold)  # (an alarm in every episode: a line each)
    program = subprocess.Popen([str(Path(sys.executable).with_name("oodmon")), "run", "--threshold", str(threshold),
                                "--max-steps", "30", "--episodes", "100000", "--mcap", str(log)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    read = [program.stdout.readline() for _ in range(2)]
    program.stdout.close()  # as head does, having read its lines
    try:
        code = program.wait(timeout=120)  # (not stopped, it would play on for many minutes)
    finally:
        program.kill()
    err = program.stderr.read()
    program.stderr.close()
    assert code == 141, err
    assert all(line.startswith("ALARM episode ") for line in read), read
    assert err.strip().splitlines()[-1].startswith(
        "oodmon: stopped: its output was closed (the reader of its pipe ended; what it printed since went nowhere); "
        "every finished episode is in the logs, the cut one is marked interrupted"), err
    recorded = read_log(log)
    assert recorded.complete and len(recorded.episodes) >= 2 and len(recorded.interrupted) == 1
    # its help to a pipe already closed: one line, 141 (before this was handled there: a traceback)
    reading, writing = os.pipe()
    os.close(reading)
    try:
        helped = subprocess.run([str(Path(sys.executable).with_name("oodmon")), "run", "--help"], stdout=writing,
                                stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(writing)
    assert (helped.returncode, helped.stderr) == (
        141, "oodmon: stopped: its output was closed (the reader of its pipe ended)\n")
    # started with no standard output at all (`>&-`: Python's sys.stdout is None): as before, quietly
    listed = subprocess.run([str(Path(sys.executable).with_name("oodmon")), "envs", "--task", "pong"],
                            preexec_fn=lambda: os.close(1), stderr=subprocess.PIPE, text=True, timeout=60)
    assert (listed.returncode, listed.stderr) == (0, "")


def test_a_sigterm_that_library_code_raised_again_as_its_own_keyboard_interrupt_is_still_terminated():
    """Ray's ray.wait, a SIGTERM coming in it, raised a KeyboardInterrupt of its own in place of
    Terminated (`oodmon bench --executor ray` said "interrupted", 130): stop_on_sigterm raises
    Terminated from it. A Ctrl-C, no SIGTERM having come, stays a KeyboardInterrupt."""
    import os
    import signal

    from oodmon.monitor import Terminated, stop_on_sigterm

    def library_wait():  # as Ray's: whatever came in it, a KeyboardInterrupt of its own
        try:
            os.kill(os.getpid(), signal.SIGTERM)
        except KeyboardInterrupt:
            raise KeyboardInterrupt("interrupted in the library") from None

    with pytest.raises(Terminated) as stopped, stop_on_sigterm():
        library_wait()
    assert type(stopped.value.__cause__) is KeyboardInterrupt and stopped.value.args == ("interrupted in the library",)
    with pytest.raises(KeyboardInterrupt) as interrupted, stop_on_sigterm():
        raise KeyboardInterrupt
    assert type(interrupted.value) is KeyboardInterrupt


def test_a_sigterm_handler_a_library_sets_for_good_is_put_back_and_its_exit_taken_as_sigterm():
    """ray.init sets a SIGTERM handler of its own for the rest of the process (``sys.exit(15)``):
    sigterm_handler_kept puts back the one before it, and turns the SystemExit(15) of a SIGTERM in
    the block into what that one raises (Terminated, inside stop_on_sigterm). Another exit stays."""
    import os
    import signal
    import sys

    from oodmon.monitor import Terminated, stop_on_sigterm
    from oodmon.monitor.stopping import sigterm_handler_kept

    def library_init(send: bool):  # as ray.init: its own handler for good, which exits
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))
        if send:
            os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM)
    with stop_on_sigterm():
        inside = signal.getsignal(signal.SIGTERM)
        with sigterm_handler_kept():
            library_init(send=False)
        assert signal.getsignal(signal.SIGTERM) is inside
        with pytest.raises(Terminated) as stopped, sigterm_handler_kept():
            library_init(send=True)
        assert type(stopped.value.__context__) is SystemExit
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN  # once: a second SIGTERM as the process cleans up
        signal.signal(signal.SIGTERM, inside)
        with pytest.raises(SystemExit), sigterm_handler_kept():
            sys.exit(3)  # not a SIGTERM: as it was
    assert signal.getsignal(signal.SIGTERM) is before


def test_stop_on_sigterm_lets_a_deployed_loop_of_your_own_finish_its_log(tmp_path):
    """docs/your-policy.md's deployed process, stopped by its service manager: inside stop_on_sigterm, SIGTERM
    raises Terminated in the loop, and closing the env finishes the log with the cut episode marked
    (without it the process died, its log torn). Outside the block SIGTERM is handled as before."""
    import os
    import signal

    import gymnasium

    from oodmon.agents import load
    from oodmon.monitor import McapSink, Monitor, MonitoredEnv, Terminated, stop_on_sigterm

    before = signal.getsignal(signal.SIGTERM)
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"),
                       Monitor(load("cartpole", "ensemble"), sinks=[McapSink(tmp_path / "deployed.mcap")]))
    steps = 0
    with pytest.raises(Terminated), stop_on_sigterm():
        env.reset(seed=0)
        while True:
            env.step()
            steps += 1
            if steps == 50:
                os.kill(os.getpid(), signal.SIGTERM)
    env.close()
    assert signal.getsignal(signal.SIGTERM) == before and issubclass(Terminated, KeyboardInterrupt)
    log = read_log(tmp_path / "deployed.mcap")
    assert log.complete and not log.episodes and [e.length for e in log.interrupted] == [50]


def test_ctrl_c_says_what_each_command_leaves_behind(tmp_path, monkeypatch, capsys):
    """Ctrl-C in `oodmon calibrate` said "every finished episode is in the logs", `oodmon run`'s
    words, though calibrate writes no log and no threshold until it ends; now each command says
    what it keeps."""
    from oodmon.cli import main
    from oodmon.monitor import Monitor

    def interrupted(self, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(Monitor, "step", interrupted)
    code = main(["calibrate", "--task", "cartpole", "--method", "dropout", "--out", str(tmp_path / "t.json")])
    assert code == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
        "oodmon: interrupted; no threshold file or detectors were written (they are written when the calibration "
        "ends; those at --out are as they were): run the command again")
    assert not (tmp_path / "t.json").exists()

    # train stopped before its first checkpoint said "the last checkpoint is kept" (2026-12-06)
    from oodmon.agents.checkpoints import Run

    def stopped_at(steps):  # a run stopped as it starts, its last checkpoint at that step (0: none)
        def load_or_create(self, *args, **kwargs):
            self.state["steps"] = steps
            raise KeyboardInterrupt
        return load_or_create

    monkeypatch.setattr(Run, "load_or_create", stopped_at(0))
    train = ["train", "--task", "cartpole", "--method", "dropout", "--out", str(tmp_path / "m"), "--steps", "3000"]
    assert main(train) == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
        "oodmon: interrupted; no checkpoint was written yet (the first after 1,500 steps): the same command starts "
        "the training again")  # (3,000 steps: a checkpoint every 1,500, as train cuts the recipe's 10,000)
    monkeypatch.setattr(Run, "load_or_create", stopped_at(1500))
    assert main(train) == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
        "oodmon: interrupted; the last checkpoint is kept: the same command resumes from it")

    # ... and so of a training stopped before its runs began (in torch's import, its first second; 2026-12-06),
    # unless an earlier one had left a checkpoint there
    import oodmon.agents.training

    def stopped_before(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(oodmon.agents.training, "train", stopped_before)
    train[train.index("--out") + 1] = str(tmp_path / "new")
    assert main(train) == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
        "oodmon: interrupted; nothing was trained yet: the same command starts the training")
    (tmp_path / "new" / "runs" / "main").mkdir(parents=True)
    (tmp_path / "new" / "runs" / "main" / "checkpoint.pt").write_bytes(b"")
    assert main(train) == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
        "oodmon: interrupted; the last checkpoint is kept: the same command resumes from it")

    # a command stopped before it began (torch imported as the threads are set) says that nothing was written
    import oodmon.cli

    monkeypatch.setattr(oodmon.cli, "limit_threads", stopped_before)
    run = ["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "2", "--mcap", str(tmp_path / "r.mcap")]
    for argv in (train, run, ["validate", str(tmp_path / "t.json")]):
        assert main(argv) == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
            "oodmon: interrupted; it was stopped as it started: nothing was written"), argv

    def terminated_in_torchs_import(*args, **kwargs):  # (a service manager's stop in the command's first second)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # (the signal's handler runs before this ends)

    monkeypatch.setattr(oodmon.cli, "limit_threads", terminated_in_torchs_import)

    def default(signum, frame):  # what SIGTERM did here before oodmon's handler: the process ended, saying nothing
        raise RuntimeError("SIGTERM reached the process before oodmon's handler")

    before = signal.signal(signal.SIGTERM, default)
    try:
        assert main(run) == 143 and capsys.readouterr().err.strip().splitlines()[-1] == (
            "oodmon: stopped by SIGTERM; it was stopped as it started: nothing was written")
    finally:
        signal.signal(signal.SIGTERM, before)
    monkeypatch.undo()  # ... and run, stopped as it loads its agent, that it wrote no log yet (2026-12-06)
    import oodmon.cli.run

    monkeypatch.setattr(oodmon.cli.run, "_load_agent", stopped_before)
    assert main(run) == 130 and capsys.readouterr().err.strip().splitlines()[-1] == (
        "oodmon: interrupted; nothing was written: it was stopped before its first episode")
    assert not (tmp_path / "r.mcap").exists()


#: A monitored run writing to {sink} (at sys.argv[1]) that prints "e" as each episode ends, to be killed.
UNTIL_KILLED = """
import sys
import torch
torch.set_num_threads(1)
from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import McapSink, Monitor, RerunSink
env = parse_variant("cartpole:length=2.0").make(onset_step=20)
monitor = Monitor(load("cartpole", "ensemble"), threshold=4.6, consecutive=1, sinks=[{sink}]).open()
for episode in range(10_000):
    monitor.run_episode(env, seed=episode)
    print("e", flush=True)
"""
SPLIT = UNTIL_KILLED.format(sink="McapSink(sys.argv[1], split_episodes=3)")


def test_a_killed_split_run_leaves_its_finished_parts_whole_and_recovers_the_last(tmp_path):
    """A run split into files of 3 episodes, SIGKILLed after its 7th: parts 0 and 1 are finished
    logs (read through their index, no recovery), the third is recovered, and the folder replays
    every finished episode once, numbered on across the files."""
    import warnings

    from oodmon.replay import read_logs

    run = subprocess.Popen([sys.executable, "-c", SPLIT, str(tmp_path / "long.mcap")], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(7):
            assert run.stdout.readline() == "e\n"
    finally:
        run.kill()
        run.wait()
    finished = 7 + run.stdout.read().count("e")  # it may have gone on a little before the kill
    run.stdout.close()
    parts = sorted(p.name for p in tmp_path.iterdir())
    assert parts == [f"long-{k:05d}.mcap" for k in range(len(parts))] and len(parts) in (finished // 3, finished // 3 + 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecoveryWarning)  # finished parts: no recovery
        whole = [read_log(tmp_path / name) for name in parts[:finished // 3]]
    assert len(whole) >= 2 and all(log.complete and len(log.episodes) == 3 for log in whole)
    assert [log.metadata["part"] for log in whole] == [str(k) for k in range(len(whole))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecoveryWarning)  # the last part, torn
        logs = read_logs([tmp_path])
    episodes = sorted(e.episode for log in logs for e in log.episodes)
    assert finished <= len(episodes) <= finished + 1 and episodes == list(range(len(episodes)))  # one more may be on disk


def test_a_log_torn_inside_a_long_episode_keeps_its_steps_on_disk_as_an_interrupted_episode(tmp_path):
    """Format 5: an episode's start goes to the log with its first step and its steps reach the
    disk every flush_seconds, so a log torn inside an episode (what a SIGKILL leaves: the bytes on
    disk, copied here mid-episode) replays that episode's steps on disk, kept as interrupted with
    its alarms, and its metrics leave it out."""
    import shutil

    from oodmon.agents import load
    from oodmon.envs import parse_variant
    from oodmon.monitor import McapSink, MemorySink, Monitor
    from oodmon.replay import compute_metrics
    from tests.helpers import tear_inside_episode_one

    env = parse_variant("cartpole:length=2.0").make(onset_step=20)
    memory = MemorySink()
    monitor = Monitor(load("cartpole", "ensemble"), threshold=3.0,
                      sinks=[McapSink(tmp_path / "run.mcap", flush_seconds=0), memory]).open()
    monitor.run_episode(env, seed=0, variant="cartpole:length=2.0")
    shutil.copy(tmp_path / "run.mcap", tmp_path / "between.mcap")  # torn between two episodes
    log, steps = tear_inside_episode_one(monitor, env, "cartpole:length=2.0", tmp_path, memory)
    (cut,) = log.interrupted
    assert (cut.episode, cut.length, cut.variant, cut.onset, cut.seed) == (1, 40, "cartpole:length=2.0", 20, 1)
    assert cut.scores.tolist() == [s.score for s in steps] and cut.alarm.tolist() == [s.alarm for s in steps]
    assert cut.detector_scores["spread"].tolist() == [s.scores["spread"] for s in steps]
    assert (cut.alarms, cut.first_alarm_step) == (memory.episodes[1].alarms, memory.episodes[1].first_alarm_step) \
        and cut.alarms >= 1  # as the monitor counted them (the cut episode's record, written at close)
    assert np.isnan(cut.total_return) and cut.interrupted and [e.episode for e in log.episodes] == [0]
    assert compute_metrics([log]) == compute_metrics([read_log(tmp_path / "run.mcap")])  # out of the metrics
    from oodmon.replay.report import episode_rows

    with pytest.warns(RecoveryWarning, match="1 complete episode.*; no step of a running episode had reached the disk"):
        between = read_log(tmp_path / "between.mcap")
    assert between.interrupted == [] and len(between.episodes) == 1
    listed = episode_rows([log])[1]  # `oodmon replay --episodes` lists it
    assert (listed["ended"], listed["length"], listed["return"], listed["alarms"]) == ("interrupted", 40, None, cut.alarms)


LONG = """
import sys
import gymnasium
import torch
torch.set_num_threads(1)
import oodmon
from oodmon.agents import load
from oodmon.monitor import McapSink, Monitor
env = gymnasium.make("oodmon/CartPole-v1", max_episode_steps=10**9)  # the pole kept up: no end
sink = McapSink(sys.argv[1], flush_seconds=0.05)
monitor = Monitor(load("cartpole", "ensemble"), threshold=3.0, sinks=[sink]).open()
obs, info = env.reset(seed=1)
monitor.begin_episode(env_id="oodmon/CartPole-v1", variant="cartpole", seed=1)
for step in range(10**9):  # an episode that never ends, as a deployed policy's
    obs, reward, terminated, truncated, info = env.step(monitor.step(obs))
    monitor.add_reward(reward)
    if terminated:
        obs, info = env.reset()
    if step == 100:
        at_100 = sink._flushed
    elif step > 100 and sink._flushed != at_100:  # a flush since step 100: steps 0..step are on disk
        print(step, flush=True)
"""


def test_a_never_ending_episode_killed_replays_its_steps_up_to_the_last_flush(tmp_path):
    """A deployed policy's one long episode, SIGKILLed: before format 5 replay found no episode
    in its log; now its steps up to the last flush (every 0.05 s here, 10 s by default) replay."""
    run = subprocess.Popen([sys.executable, "-c", LONG, str(tmp_path / "long.mcap")], stdout=subprocess.PIPE, text=True)
    try:
        flushed_at = int(run.stdout.readline())  # the child has flushed every step up to this one
    finally:
        run.kill()
        run.wait()
        run.stdout.close()
    with pytest.warns(RecoveryWarning, match="recovered 0 complete episode"):
        log = read_log(tmp_path / "long.mcap")
    (cut,) = log.interrupted
    assert cut.length > flushed_at > 100 and (cut.episode, cut.variant, cut.seed) == (0, "cartpole", 1)
    assert not cut.shifted.any() and len(cut.scores) == cut.length and np.isfinite(cut.scores).all()


RRD = UNTIL_KILLED.format(sink="RerunSink(sys.argv[1])")


def test_a_killed_runs_rrd_opens_and_holds_the_episodes_that_ended_before_the_kill(tmp_path):
    """Rerun writes its file from a thread of its own and a footer at the end: a SIGKILLed run's .rrd
    has no footer (``rerun rrd verify`` says so unless ``--check-footers false``), but ``rerun rrd``
    reads it, and it holds the episodes that ended two seconds before the kill, in
    order, none missing. Measured on 2026-11-28: this run's 123 episodes, 121 in the file (twice);
    ``oodmon run --rrd`` killed after 25 s, 1,759 of the 1,770 its MCAP log held (its last 0.2 s)."""
    import os
    import re
    import time

    path = tmp_path / "killed.rrd"
    run = subprocess.Popen([sys.executable, "-c", RRD, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(5):
            assert run.stdout.readline() == "e\n"
        time.sleep(2.0)  # the run goes on, episode after episode, while its first five reach the file
    finally:
        run.kill()
        run.wait()
    finished = 5 + run.stdout.read().count("e")
    run.stdout.close()
    rerun = os.path.join(os.path.dirname(sys.executable), "rerun")
    verify = [rerun, "rrd", "verify", str(path)]
    strict = subprocess.run(verify, capture_output=True, text=True, timeout=120)
    assert strict.returncode != 0 and "Missing RRD footer" in strict.stdout + strict.stderr
    loose = subprocess.run([*verify[:3], "--check-footers", "false", str(path)], capture_output=True, text=True,
                           timeout=120)
    assert loose.returncode == 0 and "verified without error" in loose.stdout + loose.stderr
    printed = subprocess.run([rerun, "rrd", "print", "-vvv", str(path)], capture_output=True, text=True, timeout=120)
    logged = sorted({int(n) for n in re.findall(r"episode (\d+) \(cartpole", printed.stdout)})
    assert finished > 5 and logged == list(range(len(logged))) and 5 <= len(logged) <= finished


def test_an_interrupted_calibration_keeps_its_episodes_and_the_same_command_goes_on_to_the_same_threshold(
        tmp_path, monkeypatch, capsys):
    """Ctrl-C in `calibrate` kept nothing before 2026-12-05: the calibration episodes played whole
    are now kept beside --out, and the same command plays only the rest, to the threshold of an
    uninterrupted calibration (an ensemble draws nothing: the same scores); the file is then removed.
    Another calibration's file is not read, and said so."""
    from oodmon.cli import main
    from oodmon.monitor import Monitor, Threshold

    command = ["calibrate", "--task", "cartpole", "--method", "ensemble", "--detector", "combined", "--far", "0.1",
               "--episodes", "22", "--max-steps", "100"]
    assert main([*command, "--out", str(tmp_path / "whole.json")]) == 0
    whole = Threshold.load(tmp_path / "whole.json")
    out, kept = tmp_path / "thr.json", tmp_path / "thr.json.kept.npz"
    run_episode = Monitor.run_episode
    interrupted_in_episode_10 = _interrupted_at(run_episode, 10)
    calls = interrupted_in_episode_10.calls
    monkeypatch.setattr(Monitor, "run_episode", interrupted_in_episode_10)
    capsys.readouterr()
    assert main([*command, "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"oodmon: interrupted; no threshold file was written (those at --out are as they were); the 9 of the 22 "
        f"calibration episodes played whole are kept in {kept}: the same command goes on from them")
    assert not out.exists() and kept.is_file()
    monkeypatch.undo()
    played = []
    monkeypatch.setattr(Monitor, "run_episode", lambda self, *a, **k: played.append(k["seed"]) or run_episode(self, *a, **k))
    assert main([*command, "--out", str(out)]) == 0
    assert "kept calibration episodes: 9/22 episodes" in capsys.readouterr().err
    assert played == list(range(whole.episode_seeds["calibration"][0] + 9, whole.episode_seeds["calibration"][1]))
    assert Threshold.load(out) == whole and not kept.exists()
    # another calibration's episodes (another seed) are not read, and are replaced when it is interrupted
    calls[0] = 0
    monkeypatch.setattr(Monitor, "run_episode", interrupted_in_episode_10)
    assert main([*command, "--out", str(out), "--seed", "123456"]) == 130
    monkeypatch.undo()
    capsys.readouterr()
    assert main([*command, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert (f"oodmon: warning: {kept} holds the episodes of another calibration (its seed differs); it is not read, "
            "and is replaced") in err and "kept calibration episodes" not in err
    assert Threshold.load(out) == whole and not kept.exists()


def test_a_kept_episodes_file_that_is_no_such_file_is_not_read_and_runs_no_code(tmp_path):
    """Read with numpy's allow_pickle=False: a pickled object in it is refused, not run."""
    from oodmon.monitor.calibration import KeptEpisodesWarning, read_kept_episodes

    made_by = {"seed": 1}
    assert read_kept_episodes(tmp_path / "none.npz", made_by) == []
    (tmp_path / "text.npz").write_text("not numpy")
    np.savez(tmp_path / "object.npz", made_by=np.array([object()], dtype=object), scores=np.ones(3), lengths=[3])
    np.savez(tmp_path / "short.npz", made_by=np.array(json.dumps(made_by)), scores=np.ones(3), lengths=[2])
    for name in ("text", "object", "short"):
        with pytest.warns(KeptEpisodesWarning, match="it is not read, and is replaced"):
            assert read_kept_episodes(tmp_path / f"{name}.npz", made_by) == []
    np.savez(tmp_path / "good.npz", made_by=np.array(json.dumps(made_by)), scores=np.arange(5.0), lengths=[2, 3])
    assert [list(s) for s in read_kept_episodes(tmp_path / "good.npz", made_by)] == [[0.0, 1.0], [2.0, 3.0, 4.0]]
    # torn (a copy cut short) or a bit flipped: zipfile's BadZipFile ("Bad CRC-32") crashed the command before
    # 2026-12-05 (scripts/fuzz_readers.py --only kept_calibration: 1,402 damaged copies, now every one said)
    good = (tmp_path / "good.npz").read_bytes()
    flipped = bytearray(good)
    flipped[good.index(b"\x93NUMPY") + 200] ^= 4  # (in the scores' data)
    for name, data in (("torn", good[:len(good) // 2]), ("flipped", bytes(flipped))):
        (tmp_path / f"{name}.npz").write_bytes(data)
        with pytest.warns(KeptEpisodesWarning, match="it is not read, and is replaced"):
            assert read_kept_episodes(tmp_path / f"{name}.npz", made_by) == []


FIT = ["fit-detectors", "--task", "cartpole", "--method", "ensemble", "--episodes", "12", "--dynamics-updates", "40",
       "--max-steps", "100"]


def _fitted_files(folder) -> tuple[bytes, bytes]:
    return (folder / "detectors.json").read_bytes(), (folder / "detectors.safetensors").read_bytes()


def _counting_steps(monkeypatch, interrupt_at: int | None = None) -> list[int]:
    """The fitting's env steps counted (by the seed of their episode), and Ctrl-C at step ``interrupt_at``."""
    import oodmon.monitor.detectors.fitting as fitting

    step, seeds = fitting.step_naming_refusal, []

    def counted(env, action, **where):
        seeds.append(where["seed"])
        if len(seeds) == interrupt_at:
            raise KeyboardInterrupt
        return step(env, action, **where)

    monkeypatch.setattr(fitting, "step_naming_refusal", counted)
    return seeds


def test_an_interrupted_fit_keeps_its_episodes_and_the_same_command_fits_the_same_detectors(
        tmp_path, monkeypatch, capsys):
    """Ctrl-C in `fit-detectors` (and in `calibrate`'s fitting) kept nothing before 2026-12-05:
    the fitting episodes played whole are now kept beside --out, and the same command plays only
    the rest, to the bytes of an uninterrupted fit; the file is then removed. Interrupted in the
    fit itself, every episode is kept and none is played again."""
    from oodmon.cli import main
    from oodmon.monitor.detectors.dynamics import DynamicsDetector
    from oodmon.seeds import DETECTOR_FIT

    assert main([*FIT, "--out", str(tmp_path / "whole")]) == 0
    whole = _fitted_files(tmp_path / "whole")
    out, kept = tmp_path / "d", tmp_path / "d.kept.npz"
    _counting_steps(monkeypatch, interrupt_at=5 * 100 + 40)  # (every ID episode lasts its 100 steps): in episode 5
    capsys.readouterr()
    assert main([*FIT, "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"oodmon: interrupted; no detectors were written (those at --out are as they were); the 5 detector fitting "
        f"episodes played whole are kept in {kept}: the same command goes on from them")
    assert kept.is_file() and not out.exists()  # (before 2026-12-06: an empty folder)
    monkeypatch.undo()
    played = _counting_steps(monkeypatch)
    assert main([*FIT, "--out", str(out)]) == 0
    assert "kept detector fitting episodes: 5/5 episodes" in capsys.readouterr().err
    assert sorted(set(played)) == [DETECTOR_FIT + episode for episode in range(5, 12)]  # the rest only
    assert _fitted_files(out) == whole and not kept.exists()

    # Ctrl-C in the dynamics model's fit: all 12 episodes kept, none played again
    fit = DynamicsDetector.fit

    def interrupted_fit(self, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(DynamicsDetector, "fit", interrupted_fit)
    other = tmp_path / "e"
    assert main([*FIT, "--out", str(other)]) == 130
    assert "the 12 detector fitting episodes played whole are kept in" in capsys.readouterr().err
    monkeypatch.setattr(DynamicsDetector, "fit", fit)
    played.clear()
    assert main([*FIT, "--out", str(other)]) == 0
    assert played == [] and _fitted_files(other) == whole and not (tmp_path / "e.kept.npz").exists()


def test_kept_fitting_episodes_read_back_field_for_field_and_another_fits_are_not_read(tmp_path, monkeypatch):
    """Every field of the episodes (the estimates the held-out ones keep, an MC agent's samples and
    features among them) reads back as it was kept; a file of another fit, a damaged one or one of
    Python objects is not read, and episodes too large to keep are said, not written."""
    import dataclasses

    import oodmon.monitor.detectors.fitting as fitting
    from oodmon.agents import load
    from oodmon.kept import KeptEpisodesWarning

    agent = load("cartpole", "dropout")
    env = agent.make_env()
    played = fitting.collect(agent, env, 3, max_steps=25, estimates_from=1, with_member_values=False)
    made_by = {"policy": "p", "seed": 1}
    path = tmp_path / "kept.npz"
    assert fitting._keep_trajectories(path, made_by, played) == 3
    back = fitting.read_kept_trajectories(path, made_by)
    assert len(back) == 3 and back[0].estimates is None and len(back[2].estimates) == len(played[2]) == 25
    for ours, theirs in zip(played, back):
        for field in fitting._FIELDS:
            mine, read = getattr(ours, field), getattr(theirs, field)
            assert (mine is None and read is None) or (np.array_equal(mine, read) and mine.dtype == read.dtype), field
        for mine, read in zip(ours.estimates or (), theirs.estimates or ()):
            for field in dataclasses.fields(mine):
                a, b = getattr(mine, field.name), getattr(read, field.name)
                assert (a is None and b is None) or (np.array_equal(a, b) and a.shape == b.shape), field.name
    assert back[2].estimates[3].features is not None  # (kept once, in the trajectory's features)

    with pytest.warns(KeptEpisodesWarning, match=r"holds the episodes of another fitting \(its seed differs\)"):
        assert fitting.read_kept_trajectories(path, {"policy": "p", "seed": 2}) == []
    np.savez(tmp_path / "short.npz", made_by=np.array(json.dumps(made_by)), episodes=np.array(2),
             **{"0.observations": np.zeros((3, 4)), "0.actions": np.zeros(2, dtype=np.int64)})
    with pytest.warns(KeptEpisodesWarning, match=r"holds no fitting episodes an interrupted fitting kept \(KeyError"):
        assert fitting.read_kept_trajectories(tmp_path / "short.npz", made_by) == []
    odd = [dataclasses.replace(played[0], observations=np.array([{"x": 1}] * 26, dtype=object))]
    with pytest.warns(UserWarning, match=r"the 1 detector fitting episodes played whole are not kept: 0.observations "
                                         r"holds Python objects"):
        assert fitting._keep_trajectories(tmp_path / "odd.npz", made_by, odd) == 0
    monkeypatch.setattr(fitting, "KEEP_AT_MOST", 1000)
    with pytest.warns(UserWarning, match=r"not kept: 0.0 GB, more than oodmon keeps on an interrupt"):
        assert fitting._keep_trajectories(tmp_path / "big.npz", made_by, played) == 0
    assert not (tmp_path / "odd.npz").exists() and not (tmp_path / "big.npz").exists()

    # a full disk when Ctrl-C came: said, nothing kept, and the interrupt goes on as one (calibrate's too)
    import oodmon.kept
    import oodmon.monitor.calibration as calibration

    monkeypatch.undo()  # (KEEP_AT_MOST)

    def full(path, *_):
        raise OSError(28, f"could not write {path}: No space left on device")

    monkeypatch.setattr(oodmon.kept, "write_kept", full)
    monkeypatch.setattr(calibration, "write_kept", full)
    with pytest.warns(UserWarning, match=r"the 3 detector fitting episodes played whole are not kept: .*No space left"):
        assert fitting._keep_trajectories(tmp_path / "full.npz", made_by, played) == 0
    with pytest.warns(UserWarning, match=r"the 2 calibration episodes played whole are not kept: .*No space left"):
        assert calibration._keep_episodes(tmp_path / "full.npz", made_by, [np.ones(3), np.ones(2)]) == 0


def test_a_calibration_stopped_after_its_fit_keeps_the_detectors_and_goes_on_without_fitting_again(
        tmp_path, monkeypatch, capsys):
    """`calibrate` fits detectors first where it needs them (here for a noisy world); stopped in the
    calibration episodes after that, it fitted them again when run again (2026-12-05: "and fits the
    detectors again first"). Now the set is kept beside --out with the episodes, read instead of
    fitting, and the threshold and its detectors are those of a calibration never stopped; another
    fit's set (other fitting episodes) is not read."""
    import oodmon.monitor.detectors.fitting as fitting
    from oodmon.cli import main
    from oodmon.monitor import Monitor, Threshold

    command = ["calibrate", "--task", "cartpole", "--method", "ensemble", "--detector", "combined", "--far", "0.1",
               "--episodes", "22", "--obs-noise", "0.01", "--fit-episodes", "9", "--dynamics-updates", "40",
               "--max-steps", "100"]
    assert main([*command, "--out", str(tmp_path / "whole.json")]) == 0
    whole = Threshold.load(tmp_path / "whole.json")
    # (9 episodes of at most 100 steps: 2 updates an epoch, so 40 updates end the fit at epoch 20)
    capped = "dynamics: the model trained 20 of its 100 epochs, as many as hold the 40 Adam updates"
    assert capped in capsys.readouterr().out
    out, folder = tmp_path / "thr.json", tmp_path / "thr.json.detectors.kept"
    monkeypatch.setattr(Monitor, "run_episode", _interrupted_at(Monitor.run_episode, 6))
    assert main([*command, "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"oodmon: interrupted; no threshold file or detectors were written (those at --out are as they were); the 5 "
        f"of the 22 calibration episodes played whole are kept in {out}.kept.npz, and the detectors it fitted are "
        f"kept in {folder}: the same command goes on from them")
    assert not (tmp_path / "thr.json.detectors").exists()  # (before 2026-12-06: made first, and left empty)
    monkeypatch.undo()

    def no_fitting(*args, **kwargs):
        raise AssertionError("fitted again")

    monkeypatch.setattr(fitting, "collect", no_fitting)
    assert main([*command, "--out", str(out)]) == 0
    said = capsys.readouterr()
    assert f"kept detectors: spread, dynamics, features, combined, fitted before an interrupted calibration ({folder})" \
        in said.err
    assert capped in said.out  # the kept set says how far its fit trained, as the fit did (before: nothing)
    assert Threshold.load(out) == whole and not folder.exists() and not (tmp_path / "thr.json.kept.npz").exists()
    assert _fitted_files(tmp_path / "thr.json.detectors") == _fitted_files(tmp_path / "whole.json.detectors")


def test_a_kept_detectors_folder_of_another_fit_damaged_or_unwritable_is_said_and_not_read(tmp_path, monkeypatch):
    from oodmon.agents import load
    from oodmon.kept import KeptEpisodesWarning, keep_detectors, read_kept_detectors
    from oodmon.monitor.detectors import detectors_for

    shipped = detectors_for(load("cartpole", "ensemble"))
    made_by = {"policy": "p", "episodes": 9}
    assert read_kept_detectors(tmp_path / "none", made_by) == (None, None)  # nothing kept: nothing said
    shipped["dynamics"].epochs_trained = 7  # (as a fit leaves it; a loaded set does not know it)
    assert keep_detectors(tmp_path / "kept", made_by, shipped, {"state": 7})
    shipped["dynamics"].epochs_trained = None
    detectors, state = read_kept_detectors(tmp_path / "kept", made_by)
    assert detectors.fingerprints() == shipped.fingerprints() and state == {"state": 7}
    assert detectors["dynamics"].epochs_trained == 7
    kept_json = tmp_path / "kept" / "kept.json"
    assert json.loads(kept_json.read_text())["epochs_trained"] == {"dynamics": 7}  # the learned one that trained
    older = {key: value for key, value in json.loads(kept_json.read_text()).items() if key != "epochs_trained"}
    kept_json.write_text(json.dumps(older))
    detectors, _ = read_kept_detectors(tmp_path / "kept", made_by)  # kept before the epochs were: read, none known
    assert detectors["dynamics"].epochs_trained is None
    for odd in (-5, 0, 101, 2.5, "7", True):  # (100 epochs: the dynamics model's)
        kept_json.write_text(json.dumps(older | {"epochs_trained": {"dynamics": odd}}))
        with pytest.warns(KeptEpisodesWarning, match=r"holds no detectors an interrupted calibration kept \(dynamics "
                                                     r"trained .* of its 100 epochs\)"):
            assert read_kept_detectors(tmp_path / "kept", made_by) == (None, None)
    kept_json.write_text(json.dumps(older))
    with pytest.warns(KeptEpisodesWarning, match=r"holds the detectors of another fit \(its episodes differs\); it is "
                                                 r"not read, and is replaced"):
        assert read_kept_detectors(tmp_path / "kept", made_by | {"episodes": 12}) == (None, None)
    (tmp_path / "kept" / "detectors.safetensors").write_bytes(b"torn")
    with pytest.warns(KeptEpisodesWarning,
                      match=r"holds no detectors an interrupted calibration kept \(.*\); it is not read, and is "
                            r"replaced"):
        assert read_kept_detectors(tmp_path / "kept", made_by) == (None, None)

    def full(*_):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(type(shipped), "save", full)
    with pytest.warns(UserWarning, match=r"the detectors fitted before the calibration are not kept: .*No space left"):
        assert not keep_detectors(tmp_path / "full", made_by, shipped)


def test_an_mc_agent_stopped_twice_in_one_process_goes_on_to_the_threshold_and_detectors_of_one_never_stopped(
        tmp_path, monkeypatch, capsys):
    """An MC agent's masks are drawn from one stream in one process: kept episodes alone left the
    episodes after them to other draws (as fresh, not the same; 2026-12-05). The kept files now hold
    where the draws stood after the episodes kept, and after the fit: stopped in its fitting
    episodes, then again in its calibration episodes, `calibrate` of the Dropout agent goes on to
    the very threshold and detectors of a calibration never stopped."""
    from oodmon.cli import main
    from oodmon.monitor import Monitor, Threshold

    command = ["calibrate", "--task", "cartpole", "--method", "dropout", "--detector", "combined", "--far", "0.1",
               "--episodes", "22", "--obs-noise", "0.01", "--fit-episodes", "9", "--dynamics-updates", "40",
               "--max-steps", "100"]
    assert main([*command, "--out", str(tmp_path / "whole.json")]) == 0
    out = tmp_path / "thr.json"
    steps = _counting_steps(monkeypatch, interrupt_at=4 * 100 + 40)  # in fitting episode 4 (of 100 steps each)
    assert main([*command, "--out", str(out)]) == 130
    assert len(set(steps)) == 5
    monkeypatch.undo()
    monkeypatch.setattr(Monitor, "run_episode", _interrupted_at(Monitor.run_episode, 6))  # in calibration episode 6
    capsys.readouterr()
    assert main([*command, "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "kept detector fitting episodes: 4/4 episodes" in err and "the 5 of the 22 calibration episodes" in err
    monkeypatch.undo()
    assert main([*command, "--out", str(out)]) == 0
    assert Threshold.load(out) == Threshold.load(tmp_path / "whole.json")
    assert _fitted_files(tmp_path / "thr.json.detectors") == _fitted_files(tmp_path / "whole.json.detectors")


@pytest.mark.filterwarnings("ignore:dynamics. the model trained")  # (short episodes and fit, on purpose)
@pytest.mark.filterwarnings("ignore::oodmon.monitor.threshold.EarlyPeaksWarning")
def test_watch_with_save_stopped_in_its_calibration_goes_on_to_what_one_never_stopped_saves(tmp_path, monkeypatch):
    """`oodmon.watch(..., save=)` is `oodmon calibrate` in Python: stopped (Ctrl-C) in its calibration
    episodes, it keeps the episodes and the detectors it fitted beside `save`, and the same call goes
    on from them (the Dropout agent: its draws too) to the files of a call never stopped."""
    import oodmon
    from oodmon.agents import load
    from oodmon.monitor import Monitor

    def watched(save):
        return oodmon.watch(load("cartpole", "dropout", seed=0), episodes=22, far=0.1, fit_episodes=9,
                            dynamics_updates=40, detector="combined", save=save, max_steps=100)

    watched(tmp_path / "whole.json")
    monkeypatch.setattr(Monitor, "run_episode", _interrupted_at(Monitor.run_episode, 6))
    with pytest.raises(KeyboardInterrupt):
        watched(tmp_path / "thr.json")
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("thr")) == [
        "thr.json.detectors.kept", "thr.json.kept.npz"]  # (before 2026-12-06 also thr.json.detectors, empty)
    monkeypatch.undo()
    monitor = watched(tmp_path / "thr.json")
    assert (tmp_path / "thr.json").read_bytes() == (tmp_path / "whole.json").read_bytes()
    assert _fitted_files(tmp_path / "thr.json.detectors") == _fitted_files(tmp_path / "whole.json.detectors")
    assert monitor.threshold == json.loads((tmp_path / "whole.json").read_text())["value"]
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("thr")) == ["thr.json", "thr.json.detectors"]


def test_a_fit_into_the_current_folder_keeps_its_episodes_beside_it_and_ends_in_one_piece(tmp_path, monkeypatch,
                                                                                        capsys):
    """`fit-detectors --out .`: the folder has no name of its own, and the command fitted, wrote the
    detectors, then stopped with a ValueError saying it had written none (2026-12-05, before)."""
    from oodmon.cli import main

    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    _counting_steps(monkeypatch, interrupt_at=2 * 100 + 40)
    assert main([*FIT, "--out", "."]) == 130
    said = capsys.readouterr().err.strip()
    assert said.endswith(f"the 2 detector fitting episodes played whole are kept in {tmp_path / 'here.kept.npz'}: "
                         "the same command goes on from them"), said
    monkeypatch.undo()
    monkeypatch.chdir(here)
    assert main([*FIT, "--out", "."]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["here"] and (here / "detectors.json").is_file()


def _lean(obs):
    return int(obs[2] + 0.5 * obs[3] > 0)


def _lean_harder(obs):
    return int(obs[2] + 0.9 * obs[3] > 0)


def test_a_python_fit_without_policy_hash_reads_the_episodes_it_kept_and_not_another_policys(tmp_path, monkeypatch):
    """`fit_detectors(policy, env, kept=...)` without ``policy_hash`` keyed its file with none
    (2026-12-05): the episodes another policy kept there were read as this one's. The policy now
    stands for itself: an agent by its weights' hash, an estimator by its weights, a plain policy by
    its name (or its torch module's weights)."""
    import gymnasium

    from oodmon.agents import load
    from oodmon.kept import KeptEpisodesWarning
    from oodmon.monitor.detectors import fit_detectors
    from oodmon.monitor.detectors.fitting import _policy_identity
    from oodmon.seeds import DETECTOR_FIT

    env, kept = gymnasium.make("CartPole-v1"), tmp_path / "fit.kept.npz"
    common = dict(detectors=["dynamics"], episodes=6, max_steps=30, dynamics_updates=2, kept=kept)

    def interrupted_in_episode_3():
        _counting_steps(monkeypatch, interrupt_at=3 * 30 + 5)  # (the controller keeps the pole up)
        with pytest.raises(KeyboardInterrupt):
            fit_detectors(_lean, env, **common)
        assert kept.is_file()
        monkeypatch.undo()
        return _counting_steps(monkeypatch)

    played = interrupted_in_episode_3()
    with pytest.warns(KeptEpisodesWarning, match=r"another fitting \(its policy differs\); it is not read"):
        fit_detectors(_lean_harder, env, **common)
    assert len(set(played)) == 6  # all played again: not the other policy's episodes
    kept.unlink()  # (the caller's, once the detectors are saved)
    played = interrupted_in_episode_3()
    fit_detectors(_lean, env, **common)
    assert sorted(set(played)) == [DETECTOR_FIT + episode for episode in (3, 4, 5)]  # its own kept: the rest only

    # each kind of policy has its own; the same policy loaded twice the same
    ensemble, dropout = load("cartpole", "ensemble"), load("cartpole", "dropout")
    identities = [_policy_identity(_lean, None), _policy_identity(_lean_harder, None),
                  _policy_identity(ensemble, ensemble.estimator), _policy_identity(dropout, dropout.estimator),
                  _policy_identity(ensemble.estimator, ensemble.estimator),
                  _policy_identity(dropout.estimator, dropout.estimator)]
    assert [i.split()[0] for i in identities[:2]] == ["name:_lean", "name:_lean_harder"] and len(set(identities)) == 6
    again = load("cartpole", "dropout").estimator
    assert _policy_identity(again, again) == identities[5]
    # the same weights reading their observations through VecNormalize statistics: another policy
    from oodmon.agents.vec_normalize import ObservationNormalizer

    again.observation_transform = ObservationNormalizer(np.zeros(4), np.ones(4), numbers_sha256="a" * 64)
    normalised = _policy_identity(again, again)
    again.observation_transform = ObservationNormalizer(np.zeros(4), np.full(4, 2.0), numbers_sha256="b" * 64)
    assert len({normalised, _policy_identity(again, again), identities[5]}) == 3
