"""A threshold calibrated on the ID episodes of recorded logs (``oodmon recalibrate``,
``calibrate_from_logs``), and detectors fitted on them (``oodmon fit-detectors --from-logs``,
``fit_detectors_from_logs``): a deployment's own world, where no simulator plays it."""

from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from oodmon.errors import ConfigError, InvalidParameterError, LogFormatError
from oodmon.monitor import Threshold
from oodmon.monitor.calibration import check_fresh
from oodmon.monitor.threshold import calibrate, conformal_rank
from oodmon.replay import EpisodeLog, RunLog, calibrate_from_logs, compute_monitor_metrics, log_episodes, read_log
from oodmon.replay.plots import plot_log_statistics
from oodmon.replay.reader import read_steps
from oodmon.replay.recalibrate import CHANGE_LEVEL, ChangeInLogsWarning, burst, change_in_logs, pettitt
from tests.helpers import run_cli

ZOO = Path(__file__).resolve().parents[2] / "oodmon" / "zoo"
FIT = "sha256:" + "1" * 64


def _episode(index: int, scores: np.ndarray, *, variant: str = "cartpole", alarm: np.ndarray | None = None,
             terminated: bool = False, seed: int | None = None, obs_noise: float = 0.0) -> EpisodeLog:
    alarm = np.zeros(len(scores), bool) if alarm is None else alarm
    return EpisodeLog(episode=index, env_id="oodmon/CartPole-v1", variant=variant, onset=0, seed=seed,
                      total_return=float(len(scores)), length=len(scores), alarms=int(alarm.sum()),
                      first_alarm_step=int(np.argmax(alarm)) if alarm.any() else None, terminated=terminated,
                      obs_noise=obs_noise, scores=scores, shifted=np.full(len(scores), variant != "cartpole"),
                      alarm=alarm, detector_scores={"spread": scores / 2, "dynamics": scores})


def _log(episodes: list[EpisodeLog], *, path: str = "a.mcap", policy: str = "sha256:" + "a" * 64,
         fit: str = FIT, interrupted: int = 0, threshold: float = 1.0, detectors: str = "spread,dynamics") -> RunLog:
    """A log of ``episodes`` whose run alarmed on dynamics above ``threshold`` (NaN: a run without
    one, which records its detector as spread), scoring ``detectors``."""
    metadata = {"policy_hash": policy, "score": "chosen_std", "detector": "spread" if math.isnan(threshold) else
                "dynamics", "detectors": detectors, "fitted.dynamics": fit, "about.samples": "5", "run_id": path}
    stopped = [_episode(99, np.ones(3))] * interrupted
    return RunLog(Path(path), "cartpole", "ensemble", threshold, metadata, episodes, True, stopped)


def test_a_logs_id_episodes_give_the_threshold_their_scores_give_and_record_where_they_came_from():
    rng = np.random.default_rng(0)
    scores = [rng.random(30) for _ in range(50)]
    ids = [_episode(i, s, seed=100 + i if i < 30 else 270 + i) for i, s in enumerate(scores)]  # 100-129, 300-319
    shifted = [_episode(50, rng.random(30) + 5, variant="cartpole:length=2.0", seed=150)]
    log = _log(ids[:30] + shifted, interrupted=2)
    other = _log(ids[30:], path="b.mcap")
    found = log_episodes([log, other])
    assert (len(found.episodes), found.shifted, found.interrupted, found.cut) == (50, 1, 2, 0)
    threshold = calibrate_from_logs([log, other], 0.05)
    expected = calibrate(scores, 0.05, consecutive=1, detector="dynamics")
    assert (threshold.value, threshold.rank, threshold.n_episodes) == (expected.value, expected.rank, 50)
    assert threshold.detector == "dynamics" and threshold.detectors_hash == FIT and threshold.samples == 5
    assert threshold.policy_hash == "sha256:" + "a" * 64 and threshold.obs_noise == 0.0
    # the seeds as runs (the shifted episode's, 150, is not one), each refused by validate in words
    assert threshold.episode_seeds == {"calibration": [100, 130], "calibration 2": [300, 320]}
    with pytest.raises(ConfigError, match=r"include the threshold's calibration episodes \(seeds 300-319\)"):
        check_fresh(threshold, None, 310, 5)
    assert threshold.logs == [{"path": "a.mcap", "run_id": "a.mcap", "episodes": 30},
                              {"path": "b.mcap", "run_id": "b.mcap", "episodes": 20}]
    # another detector's logged scores, and the rule's arguments as calibrate's
    spread = calibrate_from_logs([log, other], 0.1, detector="spread", confidence=None, window=2)
    assert spread.value == calibrate([s / 2 for s in scores], 0.1, consecutive=3, window=2, confidence=None).value
    assert spread.detectors_hash is None
    # a run without a threshold alarmed on nothing: the detector is the one calibrate would choose
    # among those it scored (CartPole's best, combined, where logged; else spread; else the last)
    unalarmed = calibrate_from_logs([_log(ids, threshold=math.nan)], 0.1, confidence=None)
    assert unalarmed.detector == "spread" and unalarmed.value == calibrate(
        [s / 2 for s in scores], 0.1, consecutive=3, confidence=None).value
    assert calibrate_from_logs([_log(ids, threshold=math.nan, detectors="dynamics")], 0.1).detector == "dynamics"


def test_an_episode_an_alarm_may_have_cut_short_counts_above_any_threshold():
    """An episode that ended at the step an alarm began, its env not ending it (a callback that
    stops the episode hears the alarm there), has unknown scores after it: counted +inf. One whose
    alarm held for steps before its end (a time limit inside a long alarm), or whose env ended it,
    is whole."""
    rng = np.random.default_rng(1)
    scores = [rng.random(20) for _ in range(60)]
    rising = np.zeros(20, bool)
    rising[-1] = True
    holding = np.zeros(20, bool)
    holding[-4:] = True
    episodes = [_episode(i, s) for i, s in enumerate(scores)]
    episodes[0] = _episode(0, scores[0], alarm=rising)  # cut: counted above
    episodes[1] = _episode(1, scores[1], alarm=rising, terminated=True)  # the pole fell at the alarm: whole
    episodes[2] = _episode(2, scores[2], alarm=holding)  # an alarm that held to the time limit: whole
    found = log_episodes([_log(episodes)])
    assert found.cut == 1
    threshold = calibrate_from_logs([_log(episodes)], 0.1, confidence=None)
    rank = conformal_rank(60, 0.1, None)
    assert threshold.n_episodes == 60 and threshold.rank == rank == 55
    assert threshold.value == sorted(s.max() for s in scores[1:])[rank - 1]  # the cut one's place is above them all
    left_out = calibrate(scores[1:], 0.1, consecutive=1, confidence=None)
    assert threshold.value > left_out.value  # not as low as leaving it out (rank 54 of 59)
    # where the rank falls among the cut episodes, there is no threshold, and it says why
    with pytest.raises(ConfigError, match="falls among the 1 whose scores are not all known"):
        calibrate_from_logs([_log(episodes[:45])], 0.05)
    with pytest.raises(ConfigError, match="1 of the logs' ID episodes ended at the step an alarm began"):
        calibrate_from_logs([_log(episodes)], 0.05, mode="step", confidence=None)


def test_the_logged_runs_time_limit_is_the_thresholds_where_the_logs_show_one():
    """The one length at which every episode its env did not end (nor an alarm may have cut) ended,
    none longer: the threshold's max_steps, which validate and run then keep. Not where the logs
    show two such lengths, do not say how episodes ended, or every episode fell."""
    rng = np.random.default_rng(4)

    def limit(lengths_and_ends, **log):
        episodes = [_episode(i, rng.random(n), terminated=ended) for i, (n, ended) in enumerate(lengths_and_ends)]
        return calibrate_from_logs([_log(episodes, **log)], 0.1).max_steps

    ran_out = [(60, False)] * 22
    assert limit(ran_out + [(20, True), (35, True)]) == 60
    assert limit(ran_out + [(45, False)]) is None  # two lengths: two limits, or a loop that ended some itself
    assert limit(ran_out + [(61, True)]) is None  # one ran longer: 60 was not a limit
    assert limit([(n, True) for n in range(30, 52)]) is None  # every one fell
    unsaid = [_episode(i, rng.random(60), terminated=False) for i in range(22)]
    unsaid[0] = replace(unsaid[0], terminated=None)  # a log before format 4
    assert calibrate_from_logs([_log(unsaid)], 0.1).max_steps is None
    cut = np.zeros(40, bool)
    cut[-1] = True  # ended at the step an alarm began: not the limit
    episodes = [_episode(i, rng.random(60)) for i in range(40)] + [_episode(40, rng.random(40) + 9, alarm=cut)]
    assert calibrate_from_logs([_log(episodes)], 0.1).max_steps == 60


def test_pettitts_test_rarely_finds_a_change_in_one_worlds_statistics_and_finds_a_lasting_rise_where_it_begins():
    """Seeded draws of episode statistics, at the level each of recalibrate's two tests warns at
    (CHANGE_LEVEL / 2 = 0.005). Of one world (exchangeable, Gumbel: an episode's largest score), p
    below it in at most 10 of 1,000 draws for each size: read 1, 2, 5 and 2 of 1,000 for 22, 45,
    100 and 200 episodes when written (at a true 0.5%, 11 or more of 1,000 come with probability
    0.014). With the last 30 of 100 raised by one standard deviation: found in 244 of 300 draws
    when written (asserted >= 200), the change placed within 10 episodes of the 71st in 91% of
    those (asserted >= 75%). Ties (statistics of three values) and +inf (a cut episode) rank as
    ties."""
    level = CHANGE_LEVEL / 2
    rng = np.random.default_rng(7)
    for n in (22, 45, 100, 200):
        found = sum(pettitt(rng.gumbel(size=n)).p_value < level for _ in range(1000))
        assert found <= 10, (n, found)
    tied = sum(pettitt(rng.integers(0, 3, size=45).astype(float)).p_value < level for _ in range(1000))
    assert tied <= 10
    changes = []
    for _ in range(300):
        values = rng.normal(size=100)
        values[70:] += 1.0
        changes.append(pettitt(values))
    found = [c for c in changes if c.p_value < level]
    assert len(found) >= 200 and all(c.after > c.before for c in found)
    assert np.mean([abs(c.at - 70) <= 10 for c in found]) >= 0.75
    step = pettitt([*rng.random(30), *([math.inf] * 10)])  # ten cut episodes at the end
    assert step.at == 30 and step.after == math.inf and step.p_value < level
    assert pettitt([1.0]).p_value == 1.0
    for odd in ("abc", 3.0, [[1.0, 2.0]], [object()]):
        with pytest.raises(InvalidParameterError, match="values"):
            pettitt(odd)


def test_the_burst_scan_finds_a_short_stretch_of_runs_unlike_the_others_which_pettitt_misses():
    """The highest 5, 10, ... up to a tenth of the statistics crowding into a window, against 1,000
    random orders. Of one world (seeded, 400 draws each of 45 and 200): p < 0.005 in 1 and 2 when
    written (asserted <= 6 each: at a true 0.5%, 7 or more of 400 come with probability 0.005);
    ties at random, 2 of 400. Ten runs raised by three standard deviations in the middle of 200 (a
    fault for a while): found in 99 of 100 draws when written (asserted >= 85), where Pettitt's
    test found none; the stretch said over 5 or more of the ten each time, over their middle six
    (123-128) in 98 of the 99 (asserted 90%). Five runs raised by four (a threshold of far 0.05 on
    200 episodes is their sixth highest: a burst of six sets it): found in 100 of 100 (asserted
    >= 85), the stretch over 4 or 5 of them, over the middle three in 100; scanned at the highest
    tenth alone (the scan before 2026-12-06) the same draws gave 5 of 100."""
    level = CHANGE_LEVEL / 2
    rng = np.random.default_rng(8)
    for n in (45, 200):
        found = sum(burst(rng.gumbel(size=n), seed=i).p_value < level for i in range(400))
        assert found <= 6, (n, found)
    assert sum(burst(rng.integers(0, 3, size=60).astype(float), seed=i).p_value < level for i in range(400)) <= 6
    for raised, by in ((range(120, 130), 3.0), (range(60, 65), 4.0)):
        found = over_half = over_middle = pettitts = 0
        for i in range(100):
            values = rng.normal(size=200)
            values[raised.start:raised.stop] += by
            crowd = burst(values, seed=i)
            if crowd.p_value < level:
                found += 1
                said = range(crowd.first, crowd.last + 1)
                over_half += 2 * len(set(said) & set(raised)) >= len(raised)
                over_middle += said.start <= raised[len(raised) // 4] and said.stop > raised[-1 - len(raised) // 4]
            pettitts += pettitt(values).p_value < level
        assert found >= 85 and over_half == found and over_middle >= 0.9 * found and pettitts <= 15, \
            (raised, found, over_half, over_middle, pettitts)
        assert crowd.sizes == (5, 10, 20)
    assert burst(rng.random(9)) is None  # the highest five would be half of them or more
    assert burst([1.0] * 40).p_value > 0.05  # all tied: no crowd
    for odd in (dict(share=0.5), dict(share=math.nan), dict(permutations=0), dict(seed=-1), dict(values="abc")):
        with pytest.raises(InvalidParameterError, match=next(iter(odd))):
            burst(**({"values": list(range(40))} | odd))


def test_a_change_among_the_logged_episodes_is_warned_of_with_where_it_begins(tmp_path):
    """A world that changed between two logs: the warning names the second log's first episode,
    and the plot is drawn. Logs of one world are not warned of."""
    rng = np.random.default_rng(3)
    before = [_episode(i, rng.random(30)) for i in range(40)]
    after = [_episode(i, rng.random(30) + 0.5) for i in range(30)]
    with pytest.warns(ChangeInLogsWarning, match=r"from b.mcap episode 0 on \(41 of 70 in the order they ended\) "
                                                 r".*; this threshold alarms in 0 of the 40 before and (\d) of the 30 "
                                                 r"since \(its target: 0.05 of the episodes\)") as said:
        threshold = calibrate_from_logs([_log(before), _log(after, path="b.mcap")], 0.05)
    since = int(re.search(r"and (\d) of the 30 since", str(said[0].message)).group(1))
    assert since == sum(e.detector_scores["dynamics"].max() > threshold.value for e in after) <= 3
    found = log_episodes([_log(before), _log(after, path="b.mcap")])
    statistics = change_in_logs(found, threshold)
    assert change_in_logs(found, threshold) is statistics  # (asked again for the plot: not computed again)
    assert statistics.change.at == 40 and statistics.change.after > statistics.change.before
    assert statistics.values.tolist() == [e.detector_scores["dynamics"].max() for e in before + after]
    drawn = plot_log_statistics(statistics, threshold, tmp_path / "statistics.png")
    assert drawn.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with warnings.catch_warnings():
        warnings.simplefilter("error", ChangeInLogsWarning)
        calibrate_from_logs([_log(before), _log([_episode(i, rng.random(30)) for i in range(30)], path="b.mcap")])
    few = change_in_logs(log_episodes([_log(before[:19])]), threshold)
    assert few.change is None and few.burst is None and len(few.values) == 19
    # a fault for a while: 8 runs of 100 read high in the middle of one log, which Pettitt's test
    # hardly sees; the warning names the stretch (the draws of the test above: 96 in 100)
    runs = [_episode(i, rng.random(30) + (3.0 if 50 <= i < 58 else 0.0)) for i in range(100)]
    with pytest.warns(ChangeInLogsWarning, match=r"the 10 highest dynamics statistics of the 100 calibration "
                                                 r"episodes crowd into a stretch of the logs: 8 of them from a.mcap "
                                                 r"episode 5\d to a.mcap episode 5\d .*; this threshold alarms in "
                                                 r"\d of the \d+ in the stretch and 0 of the \d+ elsewhere"):
        calibrate_from_logs([_log(runs)], 0.05)


def test_the_latest_episodes_alone_calibrate_on_the_world_since_a_change():
    """`--last N` (``last=``): the latest N whole ID episodes (of logs without times, as these, in
    the order given); the change warning says how many came since it. Older logs of a policy since
    retrained are left out with them, and said."""
    from oodmon.cli.calibration import _left_out_said

    rng = np.random.default_rng(3)
    before = [_episode(i, rng.random(30)) for i in range(40)]
    after = [_episode(i, rng.random(30) + 0.5) for i in range(30)]
    logs = [_log(before), _log(after, path="b.mcap")]
    with pytest.warns(ChangeInLogsWarning, match=r"calibrate on its latest episodes \(`--last 30`: those since\)"):
        calibrate_from_logs(logs, 0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ChangeInLogsWarning)
        since = calibrate_from_logs(logs, 0.1, last=30)
    assert since.n_episodes == 30 and [log["path"] for log in since.logs] == ["b.mcap"]
    assert since.value == calibrate_from_logs([logs[1]], 0.1).value
    found = log_episodes(logs, last=35)
    assert (len(found.episodes), found.earlier, [str(log.path) for log in found.logs]) == (35, 35, ["a.mcap", "b.mcap"])
    assert found.episodes[0][1] is before[35] and found.episodes[-1][1] is after[-1]
    assert found.left_out() == {"earlier": 35, "shifted": 0, "interrupted": 0}
    assert _left_out_said(found.left_out()) == "left out 35 earlier ID episodes"
    assert _left_out_said({"earlier": 0, "shifted": 2, "interrupted": 1}) == \
           "left out 2 shifted and 1 the run was stopped inside episodes"
    assert _left_out_said({"earlier": 0, "shifted": 0, "interrupted": 0}) is None
    older = _log(before, policy="sha256:" + "b" * 64)  # of the policy before it was retrained
    with pytest.raises(ConfigError, match="the logs are of two policies"):
        log_episodes([older, logs[1]])
    assert log_episodes([older, logs[1]], last=30).logs == [logs[1]]
    assert len(log_episodes(logs, last=1000).episodes) == 70 and log_episodes(logs, last=1000).earlier == 0
    for bad in (0, -1, 1.5, True, "3"):
        with pytest.raises(InvalidParameterError, match="last="):
            log_episodes(logs, last=bad)
    with pytest.raises(InvalidParameterError, match="last= is for logs to read"):
        calibrate_from_logs(log_episodes(logs), last=5)


def test_the_episodes_are_in_the_order_they_ended_whatever_the_logs_names(tmp_path):
    """Two runs' logs whose names sort the other way round (a folder's files are read by name): the
    episodes, the logs and `--last` go by when each episode ended (its record's time in the log),
    which a torn log's recovered episodes keep too."""
    from oodmon.cli import main
    from oodmon.replay import RecoveryWarning

    first, second = tmp_path / "logs" / "z-first.mcap", tmp_path / "logs" / "a-second.mcap"
    for path, seed in ((first, 100), (second, 200)):
        assert main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "3", "--max-steps", "30",
                     "--seed", str(seed), "--mcap", str(path)]) == 0
    found = log_episodes([tmp_path / "logs"])
    assert [episode.seed for _, episode in found.episodes] == [100, 101, 102, 200, 201, 202]
    assert [log.path.name for log in found.logs] == ["z-first.mcap", "a-second.mcap"]
    assert [episode.seed for _, episode in log_episodes([second, first], last=4).episodes] == [102, 200, 201, 202]
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(first.read_bytes()[:-600])  # its summary and index lost
    with pytest.warns(RecoveryWarning):
        recovered = read_log(torn)
    ended = [episode.ended_ns for episode in read_log(first).episodes]
    assert [episode.ended_ns for episode in recovered.episodes] == ended[:len(recovered.episodes)]
    assert len(recovered.episodes) >= 2 and ended == sorted(ended) and ended[0] > 1.7e18  # (ns: after 2023)


def test_detectors_are_not_fitted_on_logs_whose_world_changed_without_a_warning():
    """fit_detectors_from_logs tests the logs' episodes as recalibrate does, under the rule a
    calibration would choose (the detector the runs alarmed on), before it reads their steps."""
    from oodmon.agents import load
    from oodmon.monitor.monitor import policy_hash
    from oodmon.replay import fit_detectors_from_logs

    agent = load("cartpole", "ensemble")
    rng = np.random.default_rng(4)
    before = [_episode(i, rng.random(30)) for i in range(40)]
    after = [_episode(i, rng.random(30) + 0.5) for i in range(30)]
    logs = [_log(before, policy=policy_hash(agent)), _log(after, path="missing/b.mcap", policy=policy_hash(agent))]
    default = change_in_logs(log_episodes(logs))
    assert default.detector == "dynamics" and default.change.at == 40
    with pytest.warns(ChangeInLogsWarning, match=r"the fitting episodes' dynamics statistics change .* Detectors "
                                                 r"fitted on both worlds take both for ID"):
        with pytest.raises(OSError):  # (the logs are made here, in memory: their steps are not on disk)
            fit_detectors_from_logs(agent, logs)
    with warnings.catch_warnings():  # the episodes since the change alone: one world, no warning
        warnings.simplefilter("error", ChangeInLogsWarning)
        with pytest.raises(OSError, match="missing/b.mcap"):
            fit_detectors_from_logs(agent, logs, last=30)
    # logs of shifted runs alone (a killed run's while it alarmed on a shift): said as recalibrate says it;
    # it was "0 of the 0 recorded episodes can be fitted on" (found on 2026-12-06, a killed run's log)
    shifted = [_episode(i, rng.random(30), variant="cartpole:length=2.0") for i in range(5)]
    with pytest.raises(ConfigError, match=r"no whole ID episode \(5 shifted, 2 interrupted\)"):
        fit_detectors_from_logs(agent, [_log(shifted, policy=policy_hash(agent), interrupted=2)])


def test_logs_that_cannot_make_one_threshold_are_refused_with_what_differs():
    rng = np.random.default_rng(2)
    ids = [_episode(i, rng.random(10)) for i in range(50)]
    two = r"two policies \(their weights' hashes\): a.mcap has 'sha256:a+', b.mcap 'sha256:b+'"
    with pytest.raises(ConfigError, match=two):
        calibrate_from_logs([_log(ids), _log(ids, path="b.mcap", policy="sha256:" + "b" * 64)])
    with pytest.raises(ConfigError, match="from two fits of the detectors"):
        calibrate_from_logs([_log(ids), _log(ids, path="b.mcap", fit="sha256:" + "2" * 64)])
    with pytest.raises(ConfigError, match="holds no features scores .its run scored spread, dynamics"):
        calibrate_from_logs([_log(ids)], detector="features")
    noisy = [_episode(i, rng.random(10), obs_noise=0.01) for i in range(50)]
    with pytest.raises(ConfigError, match="sensor noise 0 and 0.01"):
        calibrate_from_logs([_log(ids), _log(noisy, path="b.mcap")])
    with pytest.raises(ConfigError, match=r"hold 44 whole ID episodes \(0 shifted and 3 interrupted left out\): "
                                          r"far=0.05 needs at least 45"):
        calibrate_from_logs([_log(ids[:44], interrupted=3)])
    shifted = [_episode(i, rng.random(10), variant="cartpole:length=2.0") for i in range(5)]
    with pytest.raises(ConfigError, match=r"no whole ID episode \(5 shifted, 0 interrupted\)"):
        calibrate_from_logs([_log(shifted)])
    with pytest.raises(ConfigError, match="no logs given"):
        calibrate_from_logs([])


def test_recalibrate_on_a_noisier_worlds_logs_keeps_the_promise_there_where_the_simulators_threshold_always_alarms(
        tmp_path, capsys):
    """The deployment's world has sensor noise 0.01 the simulator lacks. The threshold calibrated
    in the simulator (22 episodes, far 0.1 at confidence 0.9) alarmed in all 22 logged episodes of
    the noisy world; `oodmon recalibrate` of that log alarmed 2 of 100 fresh noisy ones when
    written (2026-12-06), 100 of 100 with the simulator's. Its promise: with probability >= 0.9,
    a rate <= 0.1; at 0.1, 20 or more of 100 alarm with probability 0.002 (binomial), so the bound
    below fails by chance far less often than the promise itself may."""
    sim, real, log = tmp_path / "sim.json", tmp_path / "real.json", tmp_path / "real.mcap"
    steps = ["--max-steps", "200"]
    assert run_cli("calibrate", "--task", "cartpole", "--method", "ensemble", "--episodes", "22", "--far", "0.1",
                   *steps, "--out", str(sim)).returncode == 0
    done = run_cli("run", "--threshold", str(sim), "--obs-noise", "0.01", "--episodes", "22", *steps, "--mcap",
                   str(log))
    assert done.returncode == 0 and "22 of 22 episodes raised an alarm" in done.stdout
    detectors = ZOO / "cartpole-ensemble" / "detectors"
    refused = run_cli("recalibrate", str(log), "--out", str(real), "--plot", str(tmp_path / "plot.txt"))
    assert refused.returncode == 2 and "--plot" in refused.stderr and not real.exists()
    done = run_cli("recalibrate", str(log), "--far", "0.1", "--detectors", str(detectors), "--out", str(real),
                   "--plot", str(tmp_path / "statistics"))
    assert done.returncode == 0, done.stderr
    assert "22 ID episodes of 1 log file with sensor noise 0.01, 4400 steps (their runs' time limit: 200)" \
           in done.stdout and "copied to" in done.stdout
    assert "drew its episodes' statistics in" in done.stdout and "change over the logs" not in done.stderr
    assert (tmp_path / "statistics.png").read_bytes()[:4] == b"\x89PNG"
    threshold = Threshold.load(real)
    assert threshold.obs_noise == 0.01 and threshold.n_episodes == 22 and threshold.detector == "combined"
    assert threshold.episode_seeds == {"calibration": [0, 22]} and threshold.logs[0]["episodes"] == 22
    assert threshold.value > 100 * Threshold.load(sim).value and threshold.max_steps == 200  # (the logs' limit)
    assert (real.parent / "real.json.detectors" / "detectors.json").is_file()
    done = run_cli("validate", str(real), "--episodes", "100", "--json")  # as long as the logged runs
    validation = json.loads(done.stdout)
    assert validation["obs_noise"] == 0.01 and validation["max_steps"] == 200 and validation["steps"] == 100 * 200
    assert validation["stretches"] is None and validation["alarmed"] < 20, validation  # (2 when written)
    # the logged episodes are not fresh ones; another fit of the detectors is refused
    refused = run_cli("validate", str(real), "--episodes", "5", "--seed", "3")
    assert refused.returncode == 2 and "not fresh" in refused.stderr
    latest = run_cli("recalibrate", str(log), "--far", "0.2", "--last", "12", "--out", str(tmp_path / "latest.json"))
    assert latest.returncode == 0 and "12 ID episodes of 1 log file" in latest.stdout, latest.stderr
    assert "note: left out 10 earlier ID episodes" in latest.stderr
    assert Threshold.load(tmp_path / "latest.json").episode_seeds == {"calibration": [10, 22]}
    other = run_cli("recalibrate", str(log), "--far", "0.1", "--out", str(tmp_path / "other.json"), "--detectors",
                    str(ZOO / "cartpole-dropout" / "detectors"))
    assert other.returncode == 2 and "another fit than the one that scored the logs" in other.stderr
    assert not (tmp_path / "other.json").exists()


def test_detectors_fitted_on_the_noisier_worlds_logs_then_recalibrated_on_others_alarm_as_in_the_simulator(tmp_path):
    """The deployment's world (sensor noise 0.01) logged: the detectors fitted on 30 of its ID
    episodes (`fit-detectors --from-logs`), the alarm calibrated on 22 others scored by them
    (`recalibrate`), far 0.1 at confidence 0.9. When written (2026-12-06): combined > 4.37871
    (the simulator's fit recalibrated there: > 132,828), 0 of 60 fresh noisy ID episodes alarmed,
    and a pole twice as long from step 50 alarmed 5 of 5 at delay 1 (the simulator's fit: 18 of 20
    at delay median 65.5). At the promised rate 0.1, 13 or more of 60 alarm with probability 0.01."""
    world = ["--max-steps", "200", "--obs-noise", "0.01"]
    agent = ["--task", "cartpole", "--method", "ensemble"]
    fit_log, cal_log, folder = tmp_path / "fit.mcap", tmp_path / "cal.mcap", tmp_path / "det"
    assert run_cli("run", *agent, "--episodes", "30", *world, "--mcap", str(fit_log)).returncode == 0
    done = run_cli("fit-detectors", *agent, "--from-logs", str(fit_log), "--dynamics-updates", "300", "--out",
                   str(folder))
    assert done.returncode == 0, done.stderr
    assert "on 30 ID episodes of 1 log file with sensor noise 0.01" in done.stdout
    fitted = json.loads((folder / "detectors.json").read_text())["fitted_for"]
    assert fitted["obs_noise"] == 0.01 and fitted["seed"] is None and fitted["logs"] == [str(fit_log)]
    assert run_cli("run", *agent, "--detectors", str(folder), "--episodes", "22", *world, "--seed", "1000", "--mcap",
                   str(cal_log)).returncode == 0
    threshold = tmp_path / "real.json"
    assert run_cli("recalibrate", str(cal_log), "--far", "0.1", "--detectors", str(folder), "--out",
                   str(threshold)).returncode == 0
    assert Threshold.load(threshold).value < 50  # on the scale of a fit in its own world (the simulator's: 132,828)
    validation = json.loads(run_cli("validate", str(threshold), "--episodes", "60", "--max-steps", "200",
                                    "--json").stdout)
    assert validation["obs_noise"] == 0.01 and validation["alarmed"] < 13, validation  # (0 when written)
    shifted = tmp_path / "shifted.mcap"
    assert run_cli("run", "--threshold", str(threshold), "--variant", "cartpole:length=2.0", "--onset", "50",
                   "--episodes", "5", "--max-steps", "200", "--seed", "5000", "--mcap", str(shifted)).returncode == 0
    (row,) = [r for r in compute_monitor_metrics([read_log(shifted)]) if r.variant == "cartpole:length=2.0"]
    assert row.alarmed == 5 and row.early == 0 and row.delay_median <= 5  # (delay 1 when written)
    # the logs of another policy, and the options of played episodes, are refused
    other = run_cli("fit-detectors", "--task", "cartpole", "--method", "dropout", "--from-logs", str(fit_log), "--out",
                    str(tmp_path / "other"))
    assert other.returncode == 2 and "the logs are of another policy" in other.stderr
    played = run_cli("fit-detectors", *agent, "--from-logs", str(fit_log), "--episodes", "9", "--obs-noise", "0.01",
                     "--out", str(tmp_path / "other"))
    assert played.returncode == 2 and "--episodes and --obs-noise shape the episodes" in played.stderr
    played = run_cli("fit-detectors", *agent, "--last", "20", "--out", str(tmp_path / "other"))
    assert played.returncode == 2 and "--last N chooses the latest of the logs' episodes" in played.stderr


def test_the_steps_a_log_holds_are_read_in_order_and_episodes_that_cannot_be_fitted_on_are_said():
    log = Path(__file__).resolve().parents[1] / "data" / "cartpole-ensemble-id.mcap"
    steps = read_steps(log, [0, 2])
    assert set(steps) == {0, 2} and steps[0][0].shape == (500, 4) and steps[2][1].shape == (500,)
    assert set(np.unique(steps[0][1])) <= {0, 1} and np.isfinite(steps[0][0]).all()
    assert not np.array_equal(steps[0][0], steps[2][0])  # two episodes, not one read twice
    with pytest.raises(LogFormatError, match="the steps of episode 7 are not all there"):
        read_steps(log, [7])
    from oodmon.agents import load
    from oodmon.monitor.detectors.fitting import fit_recorded_detectors

    broken = steps[0][0].copy()
    broken[10, 2] = np.nan  # a reading that was not finite: the monitor feeds no detector that step
    with pytest.raises(ConfigError, match="2 of the 3 recorded episodes can be fitted on"):
        fit_recorded_detectors(load("cartpole", "ensemble"), [steps[0], steps[2], (broken, steps[0][1])])


def test_a_picture_policys_camera_detectors_are_fitted_on_the_frames_its_log_holds(tmp_path):
    """Pong, whose observations are stacks of frames: its log holds each step's newest frame, which
    is what the camera's detectors read; read back, they score each step exactly as they did in
    the run (the shipped fit's frames, stillness and vanishing, to the bit). Fitted on them:
    spread, features, frames, stillness, vanishing and their combined, for the agent's own
    (4, 84, 84) and masks; features reads the network at each stack, which the frames rebuild
    (oodmon's Pong fills its stack with an episode's first frame; an env that does not say so
    leaves features out, and refuses it by name). Monitored with that set, a corrupted camera
    (gaussian_noise@3 from step 30) lifts the frames score far above every ID step's, and the
    features score far above the last ID steps' (four short games: the fit speaks for little; the
    jump is large)."""
    from oodmon.agents import load
    from oodmon.monitor.detectors import DetectorSet, detectors_for
    from oodmon.monitor.detectors.base import Trajectory
    from oodmon.monitor.detectors.fitting import trajectory_scores
    from oodmon.replay import fit_detectors_from_logs

    log, folder, shifted = tmp_path / "id.mcap", tmp_path / "det", tmp_path / "shifted.mcap"
    agent_args = ["--task", "pong", "--method", "dropconnect"]
    assert run_cli("run", *agent_args, "--episodes", "4", "--max-steps", "60", "--seed", "300", "--mcap",
                   str(log)).returncode == 0
    steps = read_steps(log, [0, 1, 2, 3])
    assert steps[0][0].shape == (60, 84, 84) and steps[0][0].dtype == np.uint8 and steps[0][1].shape == (60,)
    agent = load("pong", "dropconnect")
    camera = detectors_for(agent).subset(["frames", "stillness", "vanishing"])
    logged = read_log(log).episodes[1]
    frames, actions = steps[1]
    again = trajectory_scores(camera, Trajectory(frames, actions[:-1]))
    for name in camera.names:
        assert np.array_equal(again[name], logged.detector_scores[name][:59]), name
    with pytest.MonkeyPatch.context() as patch:  # an env whose stack is not its first frame's at the reset
        patch.setattr("oodmon.envs.pong.CorruptedPong.STACK_FILLED_BY_FIRST_FRAME", False)
        with pytest.raises(ConfigError, match="the features detector reads the policy at each observation"):
            fit_detectors_from_logs(agent, [log], detectors=["features", "frames"])
        assert fit_detectors_from_logs(agent, [log]).names == ["spread", "frames", "stillness", "vanishing", "combined"]
    # a policy loaded from SB3 model files: the set records them, as one fitted on played episodes
    # does, so that a refusal names them (before 2026-12-07 a fit on frames recorded none)
    files = [{"path": "/models/pong.zip", "sha256": "ab" * 32, "algorithm": "DQN"}]
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(agent.metadata, "models", files)
        own = fit_detectors_from_logs(agent, [log], detectors=["stillness"])
    assert own.fitted_for["models"] == [{"path": "/models/pong.zip", "sha256": "ab" * 32}]
    assert "models" not in fit_detectors_from_logs(agent, [log], detectors=["stillness"]).fitted_for
    done = run_cli("fit-detectors", *agent_args, "--from-logs", str(log), "--out", str(folder))
    assert done.returncode == 0, done.stderr
    fitted_line = "fitted spread, features, frames, stillness, vanishing, combined on 4 ID episodes of 1 log file"
    assert fitted_line in done.stdout
    fitted = DetectorSet.load(folder)
    assert fitted.fitted_for["obs_shape"] == [4, 84, 84] and fitted.fitted_for["masks"] == "sampled"
    assert fitted.fitted_for["logs"] == [str(log)] and fitted.fitted_for["seed"] is None
    done = run_cli("run", *agent_args, "--detectors", str(folder), "--variant", "pong:gaussian_noise@3", "--onset",
                   "30", "--episodes", "1", "--max-steps", "60", "--seed", "900", "--mcap", str(shifted))
    assert done.returncode == 0, done.stderr
    episode = read_log(shifted).episodes[0]
    scores = episode.detector_scores["frames"]
    # a mean over the last 20 steps: from the 20th corrupted step on, all of them (14.2 against at
    # most 2.25 before the onset when written; each step's value is log(1 + d^2))
    assert scores[episode.shifted][20:].min() > 4 * scores[~episode.shifted].max()
    # features, fitted on 118 steps of 512 features, reads high for a game's first 22 steps (its
    # first two, the stack filled by one frame, seen at four starts only, held by the window's
    # mean); the 8 ID steps before the onset read 51-59 and each corrupted step past the window
    # 8,864 or more when written
    features = episode.detector_scores["features"]
    assert features[episode.shifted][20:].min() > 20 * features[~episode.shifted][-8:].max(), features.tolist()


def test_a_pong_stack_is_rebuilt_from_the_newest_frames_a_log_holds():
    """What fitting on a Pong log's frames asks the policy at: each step's stack of four frames,
    rebuilt from the newest frame of each step (the first frame filling the stack at the reset),
    equals the observation the env gave, over a game's first 40 steps, after a reset, and in an
    env with sticky actions."""
    import gymnasium

    from oodmon.monitor.detectors.fitting import stack_depth, stacks_from_frames

    for kwargs in ({}, {"repeat_action_probability": 0.25}):
        env = gymnasium.make("oodmon/Pong-v5", **kwargs)
        assert stack_depth(env) == 4
        actions = np.random.default_rng(5).integers(0, env.action_space.n, 40)
        for seed in (3, 4):  # the second game after a reset of the same env
            observations = [env.reset(seed=seed)[0]]
            observations += [env.step(int(action))[0] for action in actions]
            rebuilt = list(stacks_from_frames(np.stack([obs[-1] for obs in observations]), 4))
            assert len(rebuilt) == 41 and all(np.array_equal(a, b) for a, b in zip(rebuilt, observations))
        env.close()
    assert stack_depth(gymnasium.make("CartPole-v1")) is None

    class ChannelsLast(gymnasium.Env):  # says so, but stacks along its last axis: the log's frame is not its plane
        STACK_FILLED_BY_FIRST_FRAME = True
        observation_space = gymnasium.spaces.Box(0, 255, (84, 84, 4), np.uint8)
        action_space = gymnasium.spaces.Discrete(2)

    assert stack_depth(ChannelsLast()) is None
