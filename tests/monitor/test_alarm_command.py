"""A shell command at each episode's first alarm (`AlarmCommand`, `oodmon run --on-alarm`): run once an
episode with what the alarm says, not waited for, its failures warned of and never the run's."""

from __future__ import annotations

import os
import sys
import time

import pytest

from oodmon.agents import load
from oodmon.cli import main
from oodmon.envs import parse_variant
from oodmon.errors import InvalidParameterError
from oodmon.monitor import AlarmCommand, AlarmCommandWarning, AlarmEvent, MemorySink, Monitor, Threshold

SPEC = "cartpole:length=2.0"


def test_the_command_runs_once_per_alarmed_episode_with_what_its_first_alarm_says(tmp_path):
    out = tmp_path / "alarms.txt"
    command = AlarmCommand(f'echo "$OODMON_EPISODE|$OODMON_STEP|$OODMON_CAUSE|$OODMON_RULE|$OODMON_TAG" >> {out}',
                           env={"OODMON_TAG": "robot-3"})
    sink = MemorySink()
    with Monitor(load("cartpole", "ensemble"), threshold=4.6, sinks=[sink], callbacks=[command]) as monitor:
        records = [monitor.run_episode(parse_variant(SPEC).make(onset_step=10), seed=seed, max_steps=80)
                   for seed in range(3)]
    assert command.close() == "ran 3 times (episodes 0, 1, 2), each exited 0"
    assert all(r.alarms for r in records) and sum(r.alarms for r in records) > 3  # more alarms than commands
    rule = sink.alarms[0].rule
    assert sorted(out.read_text().splitlines()) == [f"{r.episode}|{r.first_alarm_step}|{r.first_alarm_cause}|{rule}|robot-3"
                                                    for r in records]


def test_the_policy_acts_on_while_the_command_runs_and_close_waits_for_it(tmp_path):
    out = tmp_path / "late.txt"
    command = AlarmCommand(f"sleep 1; echo late >> {out}")
    command(AlarmEvent(0, 41, 7.25, 4.5, "score > threshold", "dynamics"))
    assert not out.exists()  # back at once: the command sleeps a second before it writes
    assert command.close() == "ran 1 time (episode 0), each exited 0" and out.read_text() == "late\n"


def test_the_command_runs_in_a_session_of_its_own_so_a_ctrl_c_of_the_monitor_does_not_cut_it(tmp_path):
    out = tmp_path / "session.txt"
    command = AlarmCommand(f'"{sys.executable}" -c "import os; print(os.getsid(0))" > {out}')
    command(AlarmEvent(0, 41, 7.25, 4.5, "score > threshold", "dynamics"))
    command.close()
    assert int(out.read_text()) != os.getsid(0)  # the terminal's SIGINT goes to the monitor's group, not to it


def test_a_failing_or_slow_command_is_a_warning_and_left_running_after_the_wait():
    failing = AlarmCommand("exit 3")
    for episode in (0, 1):
        failing(AlarmEvent(episode, 5, 7.0, 4.5, "score > threshold"))
    with pytest.warns(AlarmCommandWarning, match=r"exited other than 0 2 time\(s\) \(episode 0: exit 3; episode 1: exit 3\)"):
        assert failing.close() == "ran 2 times (episodes 0, 1), 2 exited other than 0"
    slow = AlarmCommand("sleep 3", wait=0.2)
    slow(AlarmEvent(4, 5, 7.0, 4.5, "score > threshold"))
    started = time.monotonic()
    with pytest.warns(AlarmCommandWarning, match=r"1 alarm command\(s\) still running after 0.2 s \(episodes 4\)"):
        assert slow.close() == "ran 1 time (episode 4), 1 still running"
    assert time.monotonic() - started < 2.5  # it did not wait for the command's 3 s
    assert AlarmCommand("true").close() == "never ran (no alarm)"


@pytest.mark.parametrize("command, env, wait", [
    ("", None, 10.0), ("  ", None, 10.0), (None, None, 10.0), ("true", None, -1), ("true", None, True),
    ("true", ["TAG"], 10.0), ("true", {"A=B": "1"}, 10.0), ("true", {"": "1"}, 10.0), ("true", {1: "1"}, 10.0),
], ids=["empty", "blank", "none", "negative-wait", "bool-wait", "env-list", "env-name-with-equals", "env-empty-name",
        "env-number-name"])
def test_an_empty_command_bad_variables_or_a_bad_wait_are_refused(command, env, wait):
    with pytest.raises(InvalidParameterError, match="is not allowed"):
        AlarmCommand(command, env=env, wait=wait)


def test_run_on_alarm_runs_the_command_at_each_episodes_first_alarm_and_says_how_they_ended(tmp_path, capsys):
    threshold = tmp_path / "t.json"
    Threshold(4.6, "chosen_std", 3, "episode", 0.05, 45, 9_000, task="cartpole", method="ensemble",
              detector="spread").save(threshold)
    out, log = tmp_path / "hook.txt", tmp_path / "run.mcap"
    argv = ["run", "--threshold", str(threshold), "--variant", SPEC, "--onset", "20", "--episodes", "2",
            "--mcap", str(log), "--on-alarm", f'echo "$OODMON_EPISODE $OODMON_VARIANT $OODMON_LOG" >> {out}; exit 4']
    assert main(argv) == 0  # the command's failure is not the run's
    said = capsys.readouterr()
    assert "2 of 2 episodes raised an alarm" in said.out
    assert "--on-alarm: ran 2 times (episodes 0, 1), 2 exited other than 0" in said.out
    assert "oodmon: warning: the alarm command exited other than 0 2 time(s) (episode 0: exit 4; episode 1: exit 4)" \
        in said.err
    assert sorted(out.read_text().splitlines()) == [f"0 {SPEC} {log}", f"1 {SPEC} {log}"]
    assert main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "1", "--on-alarm", "true"]) == 2
    assert "--on-alarm runs its command at an alarm, and a run without --threshold raises none" in capsys.readouterr().err
