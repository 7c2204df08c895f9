"""Every metric against hand-computed values on tiny synthetic logs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from oodmon.replay import EpisodeLog, RunLog, alarm_events, compute_metrics, fpr_at_tpr


def _episode(k, variant, scores, shifted, alarm, onset=0):
    scores = np.asarray(scores, float)
    alarm = np.asarray(alarm, bool)
    return EpisodeLog(episode=k, env_id="oodmon/CartPole-v1", variant=variant, onset=onset, seed=k, total_return=0.0,
                      length=len(scores), alarms=len(alarm_events(alarm)), first_alarm_step=None, scores=scores,
                      shifted=np.asarray(shifted, bool), alarm=alarm)


def _log(episodes, method="m"):
    return RunLog(Path("x.mcap"), "cartpole", method, 1.0, {}, episodes, True)


ID = _log([
    _episode(0, "cartpole", [0.1, 0.2, 0.3], [0, 0, 0], [0, 0, 0]),
    _episode(1, "cartpole", [0.4, 0.2, 0.1], [0, 0, 0], [0, 1, 0]),
])
SHIFTED = _log([
    # onset 1: step 0 is ID, steps 1.. are OOD; alarm at step 0 is early, then one at step 2.
    _episode(0, "cartpole:length=2.0", [0.35, 0.5, 0.6, 0.25], [0, 1, 1, 1], [1, 0, 1, 1], onset=1),
    # onset 2: never alarms.
    _episode(1, "cartpole:length=2.0", [0.05, 0.15, 0.45, 0.3], [0, 0, 1, 1], [0, 0, 0, 0], onset=2),
])


def test_id_row_false_alarm_rate_and_counts():
    rows = {m.variant: m for m in compute_metrics([ID, SHIFTED])}
    assert rows["cartpole"].false_alarm_rate == 0.5  # one of two ID episodes alarmed
    assert (rows["cartpole"].episodes, rows["cartpole"].steps) == (2, 6)
    assert rows["cartpole"].auroc is None and rows["cartpole"].detection_rate is None


def test_shifted_row_by_hand():
    m = {m.variant: m for m in compute_metrics([ID, SHIFTED])}["cartpole:length=2.0"]
    # ID steps: 6 from the ID runs + 3 before the onsets; OOD steps: 5.
    negatives = [0.1, 0.2, 0.3, 0.4, 0.2, 0.1, 0.35, 0.05, 0.15]
    positives = [0.5, 0.6, 0.25, 0.45, 0.3]
    assert (m.id_steps, m.ood_steps, m.episodes, m.steps) == (9, 5, 2, 8)
    # AUROC: the fraction of (OOD, ID) pairs ranked right, ties counting one half.
    pairs = [(p > n) + 0.5 * (p == n) for p in positives for n in negatives]
    assert m.auroc == pytest.approx(np.mean(pairs))
    # AUPR (average precision): over the distinct thresholds, descending, the gain in recall
    # times the precision there (tied ID and OOD scores enter together: 0.3 is both).
    ap, recall_before = 0.0, 0.0
    for threshold in sorted(set(positives + negatives), reverse=True):
        caught = sum(p >= threshold for p in positives)
        flagged = caught + sum(n >= threshold for n in negatives)
        recall = caught / len(positives)
        ap += (recall - recall_before) * caught / flagged
        recall_before = recall
    assert m.aupr == pytest.approx(ap)
    # FPR at 95% TPR: to catch all 5 OOD steps the threshold goes down to 0.25, above which lie
    # the ID scores 0.3, 0.35 and 0.4: 3 of 9.
    assert m.fpr_at_95_tpr == pytest.approx(3 / 9)
    assert m.early_alarm_rate == 0.5  # episode 0 alarmed at step 0 < onset 1
    assert m.detection_rate == 0.5  # episode 0 alarmed again at step 2 >= onset; episode 1 never
    assert m.delay_mean == 1.0 and m.delay_median == 1.0  # 2 - 1


def test_alarm_events_are_rising_edges_and_fpr_helper():
    assert alarm_events(np.array([1, 1, 0, 1, 0, 0, 1, 1], bool)).tolist() == [0, 3, 6]
    assert fpr_at_tpr(np.array([0, 1, 0, 1]), np.array([0.2, 0.8, 0.9, 0.1])) == 1.0


def test_methods_and_tasks_are_kept_apart():
    other = _log([_episode(0, "cartpole", [9.0, 9.0], [0, 0], [1, 1])], method="other")
    rows = compute_metrics([ID, SHIFTED, other])
    assert [(r.method, r.variant) for r in rows] == [("m", "cartpole"), ("m", "cartpole:length=2.0"), ("other", "cartpole")]
    assert rows[2].false_alarm_rate == 1.0


# -- the monitor's own benchmark: failures, alarms before them, delays ------------------------

def _run(k, variant, onset, alarm, *, terminated=None, rewards=None):
    alarm = np.asarray(alarm, bool)
    n = len(alarm)
    return EpisodeLog(episode=k, env_id="", variant=variant, onset=onset, seed=k, total_return=0.0, length=n,
                      alarms=len(alarm_events(alarm)), first_alarm_step=None, terminated=terminated,
                      scores=np.zeros(n), shifted=np.arange(n) > onset, alarm=alarm,
                      rewards=None if rewards is None else np.asarray(rewards, float))


def test_failure_is_the_env_ending_the_episode_or_pendulums_reward_collapsing():
    from oodmon.replay import failure_step
    from oodmon.replay.failures import PENDULUM_FAILURE_REWARD, PENDULUM_FAILURE_WINDOW

    assert failure_step(_run(0, "cartpole:length=2.0", 3, [0] * 9, terminated=True), "cartpole") == 8
    assert failure_step(_run(0, "cartpole:length=2.0", 3, [0] * 9, terminated=False), "cartpole") is None
    assert failure_step(_run(0, "cartpole:length=2.0", 9, [0] * 9, terminated=True), "cartpole") is None  # before onset
    assert PENDULUM_FAILURE_WINDOW == 10 and PENDULUM_FAILURE_REWARD == -1.0
    # Upright (reward ~0) until step 30, then -3 per step: the mean of the last 10 steps
    # (steps 25..34 at step 34: 5 x 0 + 5 x -3 = -1.5; at step 33: 4 x -3 / 10 = -1.2; at 32: -0.9).
    upright_then_falls = [-0.01] * 30 + [-3.0] * 30
    assert failure_step(_run(0, "pendulum:m=5.0", 20, [0] * 60, rewards=upright_then_falls), "pendulum") == 33
    # Not yet swung up at the onset: no failure counted.
    assert failure_step(_run(0, "pendulum:m=5.0", 20, [0] * 60, rewards=[-5.0] * 60), "pendulum") is None
    assert failure_step(_run(0, "pendulum:m=5.0", 20, [0] * 60, rewards=None), "pendulum") is None
    assert failure_step(_run(0, "pong:motion_blur@3", 5, [0] * 60, terminated=True), "pong") is None


def test_a_run_without_a_threshold_has_no_alarm_figures():
    """Its alarm flags are all off because nothing was compared, not because nothing was seen: the
    per-step metrics stand, the alarm columns are empty, and the monitor's figures leave it out."""
    from oodmon.replay import compute_monitor_metrics

    unthresholded = [RunLog(Path("x.mcap"), "cartpole", "m", float("nan"), {}, log.episodes, True) for log in (ID, SHIFTED)]
    assert not unthresholded[0].has_threshold and ID.has_threshold
    with_threshold = {m.variant: m for m in compute_metrics([ID, SHIFTED])}
    rows = {m.variant: m for m in compute_metrics(unthresholded)}
    assert rows["cartpole:length=2.0"].auroc == with_threshold["cartpole:length=2.0"].auroc is not None
    assert with_threshold["cartpole:length=2.0"].detection_rate == 0.5
    assert all((m.false_alarm_rate, m.early_alarm_rate, m.detection_rate, m.delay_mean, m.delay_median)
               == (None,) * 5 for m in rows.values())
    # One run of a variant without a threshold: that variant's alarms are not counted; the other's are.
    mixed = {m.variant: m for m in compute_metrics([ID, unthresholded[1]])}
    assert mixed["cartpole"].false_alarm_rate == 0.5 and mixed["cartpole:length=2.0"].detection_rate is None
    assert [m.variant for m in compute_monitor_metrics([ID, unthresholded[1]])] == ["cartpole"]
    assert compute_monitor_metrics(unthresholded) == []


def test_logs_of_agents_watched_by_other_detectors_replay_together():
    """Each agent keeps the rows of every detector its own logs hold, whatever the others hold."""
    from dataclasses import replace

    from oodmon.replay import compute_all_metrics

    def watched(log, task, method, names):
        episodes = [replace(e, detector_scores={name: e.scores * (k + 1) for k, name in enumerate(names)})
                    for e in log.episodes]
        return RunLog(Path("x.mcap"), task, method, 1.0, {"detectors": ",".join(names), "detector": names[-1]},
                      episodes, True)

    mine = [watched(log, "cartpole", "sb3", ["spread", "combined"]) for log in (ID, SHIFTED)]
    other = [watched(log, "pendulum", "dropconnect", ["dynamics", "spread"]) for log in (ID, SHIFTED)]
    rows = {(m.task, m.detector) for m in compute_all_metrics(mine + other) if m.auroc is not None}
    assert rows == {("cartpole", "spread"), ("cartpole", "combined"), ("pendulum", "dynamics"), ("pendulum", "spread")}
    alarmed = [(m.task, m.detector) for m in compute_all_metrics(mine + other) if m.detection_rate is not None]
    assert alarmed == [("pendulum", "spread"), ("cartpole", "combined")]  # each run's own alarm detector
    # Within one agent, a detector only some of its logs hold is left out (its ID steps would be missing).
    partial = [watched(ID, "cartpole", "sb3", ["spread"]), mine[1]]
    assert {m.detector for m in compute_all_metrics(partial)} == {"spread"}


def test_monitor_metrics_by_hand():
    from oodmon.replay import compute_monitor_metrics, monitor_summary

    id_log = _log([_run(k, "cartpole", 0, [0] * 20 if k else [0] * 5 + [1] * 3 + [0] * 12) for k in range(4)])
    shifted = _log([
        # onset 5, alarm at 8 (delay 3), fails at 19: alarmed before failure.
        _run(0, "cartpole:length=2.0", 5, [0] * 8 + [1] * 12, terminated=True),
        # onset 5, alarm at 19 = the failure step: too late.
        _run(1, "cartpole:length=2.0", 5, [0] * 19 + [1], terminated=True),
        # early alarm at 2 (before the onset), then one at 12 (delay 7); never fails.
        _run(2, "cartpole:length=2.0", 5, [0, 0, 1] + [0] * 9 + [1] * 8, terminated=False),
        # onset 5, never alarms, fails.
        _run(3, "cartpole:length=2.0", 5, [0] * 20, terminated=True),
    ])
    rows = {m.variant: m for m in compute_monitor_metrics([id_log, shifted])}
    ident = rows["cartpole"]
    assert (ident.false_alarms, ident.episodes, ident.false_alarm_rate) == (1, 4, 0.25)
    assert ident.far_low == pytest.approx(0.00631, abs=1e-4) and ident.far_high == pytest.approx(0.80588, abs=1e-4)
    m = rows["cartpole:length=2.0"]
    assert (m.episodes, m.early, m.alarmed, m.failed, m.before_failure) == (4, 1, 3, 3, 1)
    assert m.delays == (3, 14, 7) and m.delay_median == 7 and m.delay_p90 == pytest.approx(12.6)
    assert m.before_failure_rate == pytest.approx(1 / 3)
    assert m.leads == (11,) and m.lead_median == 11  # the warning: alarm at 8, fall at 19; an alarm at the fall gives none
    (pooled,) = monitor_summary(list(rows.values()))
    assert (pooled.variant, pooled.episodes, pooled.failed, pooled.before_failure) == ("all shifted", 4, 3, 1)
    assert pooled.leads == (11,) and pooled.to_dict()["leads"] == [11]
    assert m.early_starts == ("2@2",)  # episode 2 (seed 2) alarmed at step 2, before its onset 5


def test_an_early_alarm_of_an_id_start_the_variants_share_is_one_start_in_the_pooled_row():
    """The bench's variants play the same seeds, so their steps before the onset are the same ID
    steps: Pendulum Dropout's 16 alarms before the onset in a rerun of 2026-12-03 were one
    episode's (seed 500,004, step 51), once per variant. The pooled row keeps the count and says
    how many starts it is."""
    from oodmon.replay import compute_monitor_metrics, monitor_summary

    def variant(spec, after):  # seed 0 alarms at step 2 in every variant; seed 1 only where the shift is seen
        return _log([_run(0, spec, 5, [0, 0, 1] + [0] * 7), _run(1, spec, 5, [0] * 6 + [after] * 4)])

    rows = compute_monitor_metrics([variant("cartpole:length=2.0", 1), variant("cartpole:gravity=20.0", 0),
                                    _log([_run(0, "cartpole:masscart=5.0", 5, [0, 1] + [0] * 8)])])
    assert [(m.variant, m.early, m.early_starts) for m in rows] == [
        ("cartpole:gravity=20.0", 1, ("0@2",)), ("cartpole:length=2.0", 1, ("0@2",)), ("cartpole:masscart=5.0", 1, ("0@1",))]
    (pooled,) = monitor_summary(rows)
    assert pooled.early == 3 and pooled.early_starts == ("0@1", "0@2") and pooled.to_dict()["early_starts"] == ["0@1", "0@2"]
    # The tables say it too: the pooled row's early cell names its starts, a variant's row does not
    # (its early alarms are its own episodes'), nor a pooled row whose every early alarm is a start of its own.
    import io

    from rich.console import Console

    from oodmon.replay import monitor_markdown, monitor_table
    from oodmon.replay.report import monitor_cells

    assert monitor_cells(pooled)[3] == "3/5 (60%), 2 ID starts"  # 2 + 2 + 1 episodes
    assert [monitor_cells(m)[3] for m in rows] == ["1/2 (50%)", "1/2 (50%)", "1/1 (100%)"]
    assert monitor_cells(monitor_summary(rows[:1])[0])[3] == "1/2 (50%)"
    assert "| 3/5 (60%), 2 ID starts |" in monitor_markdown(rows)
    buffer = io.StringIO()
    Console(width=80, file=buffer).print(monitor_table(rows, "t", width=80))
    text = buffer.getvalue()
    assert [line.split("│")[2].strip() for line in text.splitlines() if "all shifted" in line] == ["3/5 (2)"]
    assert "early: alarmed before the onset, (n): from n ID starts the variants share;" in " ".join(text.split())


def test_the_monitor_counts_what_raised_each_first_alarm_after_the_onset():
    """``causes``: the logged ``first_alarm_cause`` of each episode first alarmed at or after its
    onset; an episode whose first alarm came before the onset (its cause is the false alarm's), one
    never alarmed, and a log before format 7 (no cause) are not counted."""
    from dataclasses import replace

    from oodmon.replay import compute_monitor_metrics, monitor_summary
    from oodmon.replay.report import monitor_cells

    def caused(episode, cause):
        first = int(np.flatnonzero(episode.alarm)[0]) if episode.alarm.any() else None
        return replace(episode, first_alarm_step=first, first_alarm_cause=cause)

    frozen = _log([caused(_run(k, "pong:obs.stuck=1", 2, [0] * 4 + [1] * 4), cause)
                   for k, cause in enumerate(["stillness", "stillness", "frames", None])])
    noisy = _log([caused(_run(0, "pong:gaussian_noise@3", 2, [0] * 3 + [1] * 5), "frames"),
                  caused(_run(1, "pong:gaussian_noise@3", 2, [1] + [0] * 7), "spread"),  # early: a false alarm's
                  caused(_run(2, "pong:gaussian_noise@3", 2, [0] * 8), None)])  # never alarmed
    rows = {m.variant: m for m in compute_monitor_metrics([frozen, noisy])}
    assert rows["pong:obs.stuck=1"].causes == {"stillness": 2, "frames": 1}
    assert list(rows["pong:obs.stuck=1"].causes) == ["stillness", "frames"]  # the most frequent first
    assert rows["pong:gaussian_noise@3"].causes == {"frames": 1}
    (pooled,) = monitor_summary(list(rows.values()))
    assert pooled.causes == {"frames": 2, "stillness": 2} and pooled.to_dict()["causes"] == {"frames": 2, "stillness": 2}
    assert monitor_cells(rows["pong:obs.stuck=1"])[-1] == "stillness 2, frames 1"
    # At 80 columns (no column for them) the causes go on a line under the variant's name (the
    # log's task is cartpole, so pong's variants keep their env).
    import io

    from rich.console import Console

    from oodmon.replay import monitor_table

    buffer = io.StringIO()
    Console(width=80, file=buffer).print(monitor_table(list(rows.values()), "t", width=80))
    first_column = [line.split("│")[1].strip() for line in buffer.getvalue().splitlines() if line.startswith("│")]
    assert first_column[first_column.index("pong:obs.stuck=1") + 1] == "by stillness 2, frames 1"
    assert first_column[first_column.index("all shifted") + 1] == "by frames 2, stillness 2"
    assert "by: what raised the first alarms" in " ".join(buffer.getvalue().split())


def test_the_monitor_counts_the_reading_each_first_alarm_after_the_onset_named_first():
    """``readings``: over the first alarms ``causes`` counts, the reading each named first (the
    worst), named where the env's layout is known; a first alarm before the onset or naming none is
    not counted, a pooled row adds its variants', and the cell says them after the causes."""
    from dataclasses import replace

    from oodmon.replay import compute_monitor_metrics, monitor_markdown, monitor_summary
    from oodmon.replay.report import monitor_cells

    def named(episode, readings, env_id="oodmon/CartPole-v1"):
        first = int(np.flatnonzero(episode.alarm)[0]) if episode.alarm.any() else None
        return replace(episode, env_id=env_id, first_alarm_step=first, first_alarm_cause="dynamics",
                       first_alarm_readings=readings)

    stuck = _log([named(_run(0, "cartpole:obs.stuck[2]=1", 2, [0] * 3 + [1] * 5), ((2, -269.0), (3, 4.1))),
                  named(_run(1, "cartpole:obs.stuck[2]=1", 2, [0] * 4 + [1] * 4), ((2, 35.0),)),
                  named(_run(2, "cartpole:obs.stuck[2]=1", 2, [1] + [0] * 7), ((3, 5.0),)),  # early: not counted
                  named(_run(3, "cartpole:obs.stuck[2]=1", 2, [0] * 3 + [1] * 5), ())])  # named none
    heavier = _log([named(_run(0, "cartpole:masscart=9.0", 2, [0] * 3 + [1] * 5), ((1, 300.0), (3, 250.0))),
                    named(_run(1, "cartpole:masscart=9.0", 2, [0] * 3 + [1] * 5), ((3, 260.0), (1, 240.0)))])
    rows = {m.variant: m for m in compute_monitor_metrics([stuck, heavier])}
    assert rows["cartpole:obs.stuck[2]=1"].readings == {"[2] (pole angle)": 2}
    assert rows["cartpole:obs.stuck[2]=1"].causes == {"dynamics": 3}  # the one naming none has its cause
    assert rows["cartpole:masscart=9.0"].readings == {"[1] (cart velocity)": 1, "[3] (pole angular velocity)": 1}
    (pooled,) = monitor_summary(list(rows.values()))
    assert pooled.readings == {"[2] (pole angle)": 2, "[1] (cart velocity)": 1, "[3] (pole angular velocity)": 1}
    assert list(pooled.readings)[0] == "[2] (pole angle)"  # the most frequent first
    assert pooled.to_dict()["readings"] == pooled.readings
    assert monitor_cells(rows["cartpole:obs.stuck[2]=1"])[-1] == "dynamics 3; reading [2] (pole angle) 2"
    assert "| dynamics 5; reading [2] (pole angle) 2, [1] (cart velocity) 1, [3] (pole angular velocity) 1 |" in (
        monitor_markdown(list(rows.values())))
    # An env whose layout oodmon does not know: the index alone; a log before format 10: no reading, no words.
    own = _log([named(_run(0, "MyEnv-v0", 2, [0] * 3 + [1] * 5), ((5, 9.0),), env_id="my_envs:MyEnv-v0")])
    old = _log([named(_run(0, "cartpole:length=2.0", 2, [0] * 3 + [1] * 5), ())])
    assert [m.readings for m in compute_monitor_metrics([own, old])] == [{"[5]": 1}, {}]
    assert [monitor_cells(m)[-1] for m in compute_monitor_metrics([own, old])] == [
        "dynamics 1; reading [5] 1", "dynamics 1"]
    # A log of dict observations names them as its run's detectors read them (about.reading_names);
    # names that are no list of text say nothing.
    names = '["arm[0]", "arm[1]", "arm[2]", "arm[3]", "arm[4]", "grip=0"]'
    for about, said in ((names, "[5] (grip=0)"), ('["a", 3]', "[5]"), ("[", "[5]"), ('{"a": 1}', "[5]")):
        dict_log = replace(own, metadata={"about.reading_names": about})
        assert [m.readings for m in compute_monitor_metrics([dict_log])] == [{said: 1}]


def test_the_monitor_table_names_the_task_of_each_pooled_row_when_there_are_several():
    from oodmon.replay import compute_monitor_metrics, monitor_markdown

    shifted = {"cartpole": "cartpole:length=2.0", "pendulum": "pendulum:m=5.0"}

    def pooled_cells(*tasks):
        logs = [RunLog(Path("x.mcap"), task, "m", 1.0, {}, [_run(0, shifted[task], 2, [0, 0, 0, 1])], True)
                for task in tasks]
        lines = monitor_markdown(compute_monitor_metrics(logs)).splitlines()
        return [line.split(" | ")[1] for line in lines if "all shifted" in line]

    assert pooled_cells("cartpole") == ["all shifted"]
    assert pooled_cells("cartpole", "pendulum") == ["all shifted (cartpole)", "all shifted (pendulum)"]


def test_your_own_envs_failure_is_told_only_when_you_say_what_it_is():
    # Hopper falls and the env ends the episode (a failure); Acrobot ends it when it reaches its
    # goal (a success): oodmon cannot tell them apart, so it tells neither unless told.
    from oodmon.errors import ConfigError
    from oodmon.replay import compute_monitor_metrics, failure_step
    from oodmon.replay.failures import check_failure

    shift = "Hopper-v5:model.body_mass[1]=8.0"
    fell_after_alarm = _run(0, shift, 3, [0, 0, 0, 0, 1, 0, 0, 0, 0], terminated=True)  # alarm at 4, fell at 8
    fell_unalarmed = _run(1, shift, 3, [0] * 9, terminated=True)
    kept_going = _run(2, shift, 3, [0, 0, 0, 0, 0, 1, 0, 0, 0], terminated=False)
    ids = [_run(k, "Hopper-v5", 0, [0] * 9, terminated=False) for k in range(3, 6)]
    assert failure_step(fell_after_alarm, "Hopper-v5") is None
    assert failure_step(fell_after_alarm, "Hopper-v5", "terminated") == 8
    assert failure_step(kept_going, "Hopper-v5", "terminated") is None
    logs = [RunLog(Path("h.mcap"), "Hopper-v5", "sb3", 1.0, {}, [fell_after_alarm, fell_unalarmed, kept_going, *ids], True)]
    untold, told = (next(m for m in compute_monitor_metrics(logs, failure) if m.variant == shift)
                    for failure in (None, "terminated"))
    assert (untold.alarmed, untold.failed, untold.before_failure) == (2, None, None)
    assert (told.alarmed, told.failed, told.before_failure, told.before_failure_rate) == (2, 2, 1, 0.5)
    assert (untold.leads, told.leads, told.lead_median) == ((), (4,), 4.0)
    with pytest.raises(ConfigError, match="failure='fell': what counts as a failure of your own env, one of terminated"):
        check_failure("fell")


def test_the_id_row_counts_id_episodes_that_failed_where_a_failure_is_the_envs_end():
    # A PPO hopper of ours (300,000 steps) falls after about 280 steps in its own world: the bench
    # said "70/70 failed" of the shifted episodes and nothing of the ID ones, as if the shifts had
    # made it fall. The ID row now says how many ID episodes failed as a shifted one fails.
    import io

    from rich.console import Console

    from oodmon.replay import compute_monitor_metrics, monitor_table

    shift = "Hopper-v5:model.body_mass[1]=8.0"
    ids = [_run(k, "Hopper-v5", 0, [0] * 9, terminated=k < 3) for k in range(4)]  # 3 of 4 fell
    shifted = [_run(4, shift, 3, [0, 0, 0, 0, 1, 0, 0, 0, 0], terminated=True)]
    logs = [RunLog(Path("h.mcap"), "Hopper-v5", "sb3", 1.0, {}, [*ids, *shifted], True)]
    (told_id,) = [m for m in compute_monitor_metrics(logs, "terminated") if m.is_id]
    (untold_id,) = [m for m in compute_monitor_metrics(logs) if m.is_id]
    assert (told_id.false_alarms, told_id.failed, told_id.before_failure_rate) == (0, 3, None)
    assert untold_id.failed is None  # an env's end is no failure unless told
    buffer = io.StringIO()
    Console(width=220, file=buffer).print(monitor_table(compute_monitor_metrics(logs, "terminated"), "t", width=220))
    (id_line,) = [line for line in buffer.getvalue().splitlines() if "│ Hopper-v5 " in line]
    assert "3/4 (75%)" in id_line
    # CartPole: an ID pole that never fell reads 0 of N; Pendulum tells no ID failure (its failure
    # is a fall from a pole swung up at the onset).
    cartpole = [RunLog(Path("c.mcap"), "cartpole", "dropout", 1.0, {},
                       [_run(k, "cartpole", 0, [0] * 9, terminated=False) for k in range(5)], True)]
    pendulum = [RunLog(Path("p.mcap"), "pendulum", "dropout", 1.0, {},
                       [_run(k, "pendulum", 0, [0] * 9, terminated=False, rewards=[-9.0] * 9) for k in range(5)], True)]
    assert [m.failed for m in compute_monitor_metrics(cartpole)] == [0]
    assert [m.failed for m in compute_monitor_metrics(pendulum)] == [None]


def test_the_monitor_table_is_readable_at_80_columns():
    """At 80 columns the monitor's ten columns left a variant's name 'cartpol…': the narrow layout
    keeps every name whole (wrapped if need be), the task and method in the title."""
    import io

    from rich.console import Console

    from oodmon.replay import compute_monitor_metrics, monitor_table

    long = "cartpole:force_mag=1.6667,gravity=19.6,length=2.0"
    runs = [_run(k, "cartpole", 0, [0] * 9, terminated=False) for k in range(3)]
    runs += [_run(3 + k, long, 2, [0, 0, 0, 1, 0, 0, 0, 0, 0], terminated=True) for k in range(2)]  # alarm 3, fall 8
    runs += [_run(5, "cartpole:gravity=98.0", 2, [0] * 9, terminated=False)]
    metrics = compute_monitor_metrics([_log(runs, method="dropconnect")])
    for width in (80, 220):
        buffer = io.StringIO()
        Console(width=width, file=buffer).print(monitor_table(metrics, "the alarms", width=width))
        text = buffer.getvalue()
        assert max(len(line) for line in text.splitlines()) <= width and "…" not in text
        if width == 80:
            assert "the alarms, cartpole, dropconnect" in text
            first_column = "".join(line.split("│")[1].strip() for line in text.splitlines() if line.startswith("│"))
            assert "force_mag=1.6667,gravity=19.6,length=2.0" in first_column
            # the shifted row: 0 early, 2/2 alarmed, 2/2 before the fall, lead 5, delay 1/1 (median/p90)
            assert re.search(r"0/2 +│ +2/2 +│ +2/2 +│ +5 +│ +1/1", text), text
            assert "95% interval 0.0%-70.8%" in text.replace("\n", " ") and "3/3" not in text  # the ID row: 0/3
        else:
            assert long in text and "lead median" in text


def test_the_per_episode_table_is_readable_at_80_columns():
    """`replay --episodes` printed each row's whole log path and the env in every variant: a
    terminal showed neither the path nor the figures. What the rows share is in the title; at 80
    columns the logs are numbered (the names in the caption) and no figure is cut."""
    import io

    from rich.console import Console

    from oodmon.replay.report import episode_rows, episodes_table

    folder = "runs/bench/logs/InvertedPendulum-v5-chosen_std-far0.05-n90/sb3/trial0"
    shift = "InvertedPendulum-v5:model.body_mass[2]=20.0"
    from dataclasses import replace

    false_alarm = replace(_run(0, "InvertedPendulum-v5", 0, [0, 1] + [0] * 7, terminated=False), first_alarm_step=1)
    early_then_late = replace(_run(1, shift, 2, [0, 1, 0, 0, 1, 0, 0, 0, 0], terminated=True), first_alarm_step=1,
                              first_alarm_cause="dynamics")
    logs = [RunLog(Path(f"{folder}/InvertedPendulum-v5.mcap"), "InvertedPendulum-v5", "sb3", 1.0, {}, [false_alarm], True),
            RunLog(Path(f"{folder}/heavy.mcap"), "InvertedPendulum-v5", "sb3", 1.0, {}, [early_then_late], True)]
    rows = episode_rows(logs, failure="terminated")
    for width in (80, 220):
        buffer = io.StringIO()
        Console(width=width, file=buffer).print(episodes_table(rows, "2 episodes", width=width))
        text = buffer.getvalue()
        assert max(len(line) for line in text.splitlines()) <= width and "…" not in text
        words = " ".join(text.split())
        assert f"2 episodes, in {folder}, InvertedPendulum-v5" in words
        cells = [[cell.strip() for cell in line.split("│")[1:-1]] for line in text.splitlines() if line.startswith("│")]
        if width == 80:  # log, ep, variant, seed, onset, steps, return, alarm (delay), failed, ended
            assert cells[0] == ["1", "0", "ID", "0", "", "9", "0.0", "1", "", "limit"]  # an alarm in ID: no delay
            assert cells[1][:2] == ["2", "1"] and cells[1][7:] == ["1 (-1)", "8", "env"]  # before its onset at 2
            wrapped = "".join(row[2] for row in cells[1:])  # the variant's name, folded over the row's lines
            assert wrapped == "model.body_mass[2]=20.0"
            assert "logs: 1 InvertedPendulum-v5.mcap; 2 heavy.mcap" in words
        else:
            assert cells[0][:3] == ["InvertedPendulum-v5.mcap", "0", "ID"]
            assert cells[1][:3] == ["heavy.mcap", "1", "model.body_mass[2]=20.0"]
            assert cells[1][-5:] == ["1", "before onset", "dynamics", "8", "terminated"]  # what raised its first alarm


def test_pong_tells_no_failure_so_its_failed_column_is_blank_not_zero():
    # A lost point is part of an ID game: Pong's monitor row read "failed 0/2 (0%)", as if its games
    # had been watched for a failure and none had come; --failure terminated does not make one either.
    from oodmon.replay import compute_monitor_metrics

    games = [RunLog(Path("p.mcap"), "pong", "dropconnect", 1.0, {},
                    [_run(k, "pong:motion_blur@5", 3, [0, 0, 0, 0, 1, 0], terminated=True) for k in range(2)], True)]
    for failure in (None, "terminated"):
        (row,) = compute_monitor_metrics(games, failure)
        assert (row.alarmed, row.failed, row.before_failure, row.leads) == (2, None, None, ())


def test_each_detectors_row_counts_the_alarms_of_the_runs_whose_alarm_read_it():
    """Two runs of one variant, one alarmed by `spread`, one by `combined`: each row's alarm figures
    are its own run's (before, both runs' alarms went to the row of the last log's detector, and
    the other row had none); pooled_thresholds names the two thresholds for replay's note."""
    from oodmon.replay import pooled_thresholds

    def run(name, detector, threshold, first_alarm):
        alarm = np.zeros(10, bool)
        alarm[first_alarm] = True
        scores = {"spread": np.linspace(0, 1, 10), "combined": np.linspace(1, 2, 10)}
        episode = EpisodeLog(episode=0, env_id="oodmon/CartPole-v1", variant="cartpole:length=2.0", onset=4, seed=0,
                             total_return=10.0, length=10, alarms=1, first_alarm_step=first_alarm,
                             scores=scores[detector], shifted=np.arange(10) >= 4, alarm=alarm, detector_scores=scores)
        metadata = {"detector": detector, "detectors": "spread,combined", "rule": "score > threshold"}
        return RunLog(Path(name), "cartpole", "ensemble", threshold, metadata, [episode], True)

    logs = [run("c.mcap", "combined", 1.5, first_alarm=5), run("s.mcap", "spread", 0.7, first_alarm=8)]
    rows = {m.detector: m for name in ("spread", "combined") for m in compute_metrics(logs, name)}
    assert (rows["spread"].detection_rate, rows["spread"].delay_mean) == (1.0, 4.0)  # s.mcap's alarm alone
    assert (rows["combined"].detection_rate, rows["combined"].delay_mean) == (1.0, 1.0)  # c.mcap's
    assert rows["spread"].episodes == rows["combined"].episodes == 2  # the ranking still reads both runs
    assert rows["spread"].auroc == 1.0  # each run's spread rises from its onset on
    # unnamed, the last log's detector is ranked, in every run's scores of it (before, each run's
    # alarm scores: c.mcap's combined ones, 1 to 2, beside s.mcap's spread, 0 to 1)
    assert compute_metrics(logs) == [rows["spread"]]
    assert {k: [p.name for p in v] for k, v in pooled_thresholds(logs)[("cartpole", "ensemble")].items()} == {
        "combined > 1.5 (score > threshold)": ["c.mcap"], "spread > 0.7 (score > threshold)": ["s.mcap"]}
    assert pooled_thresholds(logs[:1]) == {}


def test_episodes_that_ended_before_their_onset_are_not_counted_as_missed_detections(tmp_path):
    """A shifted episode that ended before its onset never shifted: it was counted as one the alarm
    missed (a run of `--onset 600` on CartPole replayed as detected 0%, 2026-12-01). Its early
    alarm is still a false alarm."""
    from oodmon.replay import compute_monitor_metrics, monitor_summary
    from oodmon.replay.check import baseline_of, find_falls
    from oodmon.replay.report import monitor_cells

    id_log = _log([_run(k, "cartpole", 0, [0] * 20) for k in range(2)])
    shifted = _log([
        _run(0, "cartpole:length=2.0", 5, [0] * 8 + [1] * 12, terminated=True),  # alarmed at 8: delay 3
        _run(1, "cartpole:length=2.0", 5, [0] * 20, terminated=True),  # shifted, never alarmed
        _run(2, "cartpole:length=2.0", 30, [0, 1, 0, 0] + [0] * 16, terminated=True),  # 20 steps, onset 30: early alarm
        _run(3, "cartpole:length=2.0", 30, [0] * 20, terminated=True),  # 20 steps, onset 30
    ])
    m = {m.variant: m for m in compute_metrics([id_log, shifted])}["cartpole:length=2.0"]
    assert (m.episodes, m.alarm_episodes, m.shifted_episodes) == (4, 4, 2)
    assert m.detection_rate == 0.5 and m.delays == (3,)  # of the two that shifted (was 1 of 4)
    assert m.early_alarm_rate == 0.25  # of all four
    row = {r.variant: r for r in compute_monitor_metrics([id_log, shifted])}["cartpole:length=2.0"]
    assert (row.episodes, row.never_shifted, row.shifted_episodes, row.alarmed, row.early) == (4, 2, 2, 1, 1)
    assert monitor_cells(row)[3:5] == ["1/4 (25%)", "1/2 (50%)"]  # early of all episodes, alarmed of those that shifted
    assert (row.to_dict()["shifted_episodes"], row.to_dict()["never_shifted"]) == (2, 2)  # (replay --monitor --json)
    (pooled,) = monitor_summary([row])
    assert (pooled.never_shifted, pooled.shifted_episodes, pooled.alarmed) == (2, 2, 1)
    # none shifted: nothing to detect, no rate (not 0%)
    late = _log([_run(k, "cartpole:length=2.0", 30, [0] * 20, terminated=True) for k in range(3)])
    none = {m.variant: m for m in compute_metrics([id_log, late])}["cartpole:length=2.0"]
    assert none.detection_rate is None and none.shifted_episodes == 0 and none.early_alarm_rate == 0.0
    # a baseline keeps the detection rate's own count, and the check weighs a fall by it: 1 of 2
    # to 0 of 2 is within chance (p = 0.5), as 1 of 4 to 0 of 4 would be too
    baseline = baseline_of([m], 0.02)
    assert baseline["metrics"][m.key]["shifted_episodes"] == 2
    every_one_shifted = baseline_of(compute_metrics([ID, SHIFTED]), 0.02)["metrics"]["cartpole/m/cartpole:length=2.0"]
    assert "shifted_episodes" not in every_one_shifted and every_one_shifted["alarm_episodes"] == 2
    missed = _log([shifted.episodes[1], shifted.episodes[1], *shifted.episodes[2:]])
    (now,) = [r for r in compute_metrics([id_log, missed]) if r.variant == "cartpole:length=2.0"]
    baseline["metrics"][m.key] = {name: baseline["metrics"][m.key][name]  # (the delay goes missing with the alarm)
                                  for name in ("detection_rate", "alarm_episodes", "shifted_episodes")}
    within: list[str] = []
    assert now.detection_rate == 0.0 and find_falls([now], baseline, within=within) == []
    assert any("detection_rate fell from 0.5 to 0 (1/2 to 0/2 episodes" in line for line in within), within


def test_the_monitor_tables_footnote_says_what_failed_is_for_the_tasks_it_shows_only():
    from oodmon.replay.failures import failure_definition

    cartpole = failure_definition(["cartpole"])
    assert cartpole.startswith("failed: CartPole's episode ended by itself after the onset; the ID row's failed: ID episodes")
    assert "Pendulum" not in cartpole and "--failure" not in cartpole
    both = failure_definition(iter(["pendulum", "cartpole", "pendulum"]))  # any iterable, each task once, oodmon's first
    assert both.startswith("failed: CartPole's episode ended by itself after the onset; Pendulum's mean reward over the "
                           "last 10 steps fell below -1 after the onset")
    assert "where that is a failure (not Pendulum's)" in both
    assert "Pong's not told (blank: a lost point is part of an ID game)" in failure_definition(["pong"])
    own = failure_definition(["MountainCar-v0", "cartpole"])
    assert own.startswith("failed: CartPole's episode ended by itself after the onset; MountainCar-v0's not told (blank) "
                          "unless --failure terminated")
    assert failure_definition(["Hopper-v5"], "terminated").startswith(
        "failed: Hopper-v5's episode ended by itself after the onset (--failure terminated); the ID row's")
    assert failure_definition([]).startswith("failed: not told; ")


def test_roc_points_auroc_and_average_precision_are_sklearns_to_the_bit():
    """replay's ranking metrics, computed without importing sklearn (a second of `oodmon replay`'s
    start before 2026-12-04), equal sklearn.metrics' roc_curve, auc and average_precision_score to
    the bit: seeded random cases of 1 to 3,000 steps each side, continuous scores, scores with
    many ties (five values, two decimals), float32 scores as detectors give them, and all tied."""
    from sklearn.metrics import auc, average_precision_score, roc_curve

    from oodmon.replay.metrics import average_precision, rankable, roc_points

    rng = np.random.default_rng(20261204)
    for case in range(400):
        negatives, positives = (int(n) for n in rng.integers(1, 3000, 2))
        n = negatives + positives
        scores = [rng.normal(size=n), rng.integers(0, 5, n).astype(float), np.round(rng.normal(size=n), 2),
                  np.r_[rng.normal(size=negatives), rng.normal(1, 1, positives)].astype(np.float32).astype(float),
                  np.ones(n)][case % 5]
        labels = np.r_[np.zeros(negatives), np.ones(positives)]
        theirs_fpr, theirs_tpr, _ = roc_curve(labels, scores)
        fpr, tpr = roc_points(labels, scores)
        assert np.array_equal(fpr, theirs_fpr) and np.array_equal(tpr, theirs_tpr), case
        assert float(np.trapezoid(tpr, fpr)) == auc(theirs_fpr, theirs_tpr), case
        assert average_precision(labels, scores) == float(average_precision_score(labels, scores)), case
    # scores the monitor gives a failed sensor (inf) or could not compute (NaN), made rankable first
    scores = rankable(np.array([0.1, np.inf, np.nan, -np.inf, 0.3]))
    labels = np.array([0.0, 1, 1, 0, 0])
    assert np.array_equal(roc_points(labels, scores)[1], roc_curve(labels, scores)[1])
    fpr, tpr = roc_points(np.ones(3), np.arange(3.0))  # no negatives: no false-positive rate, as sklearn's NaNs
    assert np.isnan(fpr).all() and tpr[-1] == 1.0
