"""Plots from the recorded logs: every expected PNG is written and is an image."""

from __future__ import annotations

from pathlib import Path

import cv2

from oodmon.replay import compute_metrics, read_log
from oodmon.replay.plots import plot_roc, plot_trace, write_plots
from tests.helpers import run_cli

DATA = Path(__file__).parent.parent / "data"


def test_replay_plots_writes_roc_trace_and_auroc_vs_shift(tmp_path):
    result = run_cli("replay", str(DATA), "--plots", str(tmp_path))
    assert result.returncode == 0 and "wrote 4 plot(s)" in result.stderr
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["auroc_vs_shift_cartpole.png", "roc_cartpole_length_2.0.png",
                     "trace_ensemble_cartpole.png", "trace_ensemble_cartpole_length_2.0.png"]
    for name in names:
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.shape[0] > 300 and image.shape[1] > 350


def test_a_trace_panel_names_the_onset_of_a_shifted_episode_only():
    from oodmon.replay.plots import episode_name

    ids = read_log(DATA / "cartpole-ensemble-id.mcap").episodes
    assert episode_name(ids[0]) == f"cartpole\nseed {ids[0].seed}, return {ids[0].total_return:.0f}"  # no onset 0
    shifted = next(e for p in sorted(DATA.glob("*.mcap")) for e in read_log(p).episodes if e.variant != "cartpole")
    assert f"seed {shifted.seed}, onset {shifted.onset}, return" in episode_name(shifted)


def test_plots_that_the_logs_cannot_support_are_skipped(tmp_path):
    import dataclasses

    logs = [read_log(DATA / "cartpole-ensemble-id.mcap")]  # ID only: no shifted steps
    assert plot_roc(logs, "cartpole:length=2.0", tmp_path / "roc.png") is None
    assert plot_trace(logs, "ensemble", "cartpole:length=2.0", tmp_path / "trace.png") is None
    # what the alarm made of the ID episodes is all such logs give (until 2026-12-07: nothing)
    assert write_plots(logs, compute_metrics(logs), tmp_path) == [tmp_path / "trace_ensemble_cartpole.png"]
    unthresholded = [dataclasses.replace(logs[0], threshold=float("nan"))]  # a run without --threshold
    assert write_plots(unthresholded, compute_metrics(unthresholded), tmp_path / "none") == []


def test_roc_curves_without_detectors_named_rank_each_alarms_detector_over_the_runs_holding_its_scores(tmp_path):
    """Called from Python without ``detectors``, ``plot_roc`` ranked every run's alarm scores
    together: a ``spread`` ID run's beside a ``dynamics`` shifted run's, two scales on one axis. Now
    a curve per detector the alarms read, each over the scores of that detector (its own alarm's, or
    logged beside another's); a run holding none of them is left out of its curve."""
    import dataclasses

    import numpy as np

    from oodmon.replay.metrics import roc_points
    from oodmon.replay.plots import roc_curves

    id_log = read_log(DATA / "cartpole-ensemble-id.mcap")
    shifted_log = read_log(DATA / "cartpole-ensemble-length2.mcap")
    rng = np.random.default_rng(0)

    def dynamics_of(episode):  # a dynamics detector's scores on another scale: -5 ID, +50 shifted
        return np.where(episode.shifted, 50.0, -5.0) + rng.normal(0, 1, episode.length)

    id_run = dataclasses.replace(id_log, episodes=[  # its alarm read spread; dynamics logged beside
        dataclasses.replace(e, detector_scores={"spread": e.scores, "dynamics": dynamics_of(e)})
        for e in id_log.episodes])
    dynamics_run = dataclasses.replace(shifted_log, metadata=shifted_log.metadata | {"detector": "dynamics"}, episodes=[
        dataclasses.replace(e, scores=(d := dynamics_of(e)), detector_scores={"dynamics": d})
        for e in shifted_log.episodes])
    variant = "cartpole:length=2.0"
    curves = {name: (labels, scores) for _, name, labels, scores in roc_curves([id_run, dynamics_run], variant)}
    assert list(curves) == ["dynamics"]  # spread: no shifted run holds its scores
    labels, scores = curves["dynamics"]
    id_steps = sum(e.length for e in id_run.episodes) + sum(int((~e.shifted).sum()) for e in dynamics_run.episodes)
    assert (labels == 0).sum() == id_steps and np.all(scores[labels == 0] < 10)  # the ID run's dynamics scores
    fpr, tpr = roc_points(labels, scores)
    assert np.trapezoid(tpr, fpr) == 1.0
    # Named, as replay names them, each detector is read where logged (unchanged).
    named = roc_curves([id_run, dynamics_run], variant, {"ensemble": ["dynamics"]})
    assert [(name, len(labels)) for _, name, labels, _ in named] == [("dynamics", len(curves["dynamics"][0]))]
    assert plot_roc([id_run, dynamics_run], variant, tmp_path / "roc.png") == tmp_path / "roc.png"


def test_replay_says_why_it_drew_nothing(tmp_path, capsys):
    from oodmon.cli import main

    log = tmp_path / "plain.mcap"  # an ID run without a threshold: nothing to rank, no alarm to show
    assert main(["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "1", "--max-steps", "30",
                 "--mcap", str(log)]) == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--plots", str(tmp_path / "plots")]) == 0
    assert "wrote 0 plot(s) to " + str(tmp_path / "plots") + ": nothing to draw, the logs hold no shifted steps" in (
        capsys.readouterr().err)


def test_the_id_trace_shows_the_first_alarmed_episode_beside_the_calm_one_that_came_closest(tmp_path, monkeypatch):
    """A deployment's logs hold ID episodes only, and `replay --plots` of them wrote no picture. Now
    it draws the first episode that alarmed and, under the same threshold, the calm episode whose
    score came closest to the threshold: how far the alarm stood above what the world usually scores."""
    import numpy as np

    from oodmon.replay import EpisodeLog, RunLog
    from oodmon.replay import plots

    def episode(k, peak, alarm_at=None):
        scores = np.r_[np.zeros(10), peak, np.zeros(9)]
        return EpisodeLog(episode=k, env_id="", variant="cartpole", onset=0, seed=k, total_return=20.0, length=20,
                          alarms=int(alarm_at is not None), first_alarm_step=alarm_at, scores=scores,
                          shifted=np.zeros(20, bool), alarm=np.arange(20) == (alarm_at if alarm_at is not None else -1))

    other = RunLog(Path("older.mcap"), "cartpole", "sb3", 9.0, {"detector": "combined"}, [episode(0, 8.5)], True)
    logs = [other, RunLog(Path("deployed.mcap"), "cartpole", "sb3", 2.0, {"detector": "combined"},
                          [episode(0, 1.2), episode(1, 3.0, alarm_at=10), episode(2, 1.7), episode(3, 4.0, 10)], True)]
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    assert plots.plot_id_alarms(logs, "sb3", "cartpole", tmp_path / "id.png") is not None
    titles = [ax.get_title().replace("\n", " ") for ax in drawn[0].axes]
    # older.mcap's 8.5 came closer than 1.7 to its own threshold, not to this one: not drawn beside it
    assert titles[0].startswith("alarmed at step 10: episode 1 of deployed.mcap")
    assert titles[1].startswith("no alarm, the closest to the threshold: episode 2 of deployed.mcap")
    # the alarms of deployed.mcap's threshold counted, older.mcap's episode apart (it was "2 of 5")
    assert ("sb3, combined detector, cartpole: 2 of 4 ID episode(s) alarmed (1 more of runs by another alarm not "
            "counted; alarms as vertical lines)") == drawn[0].texts[0].get_text().replace("\n", " ")
    dashed = [line.get_ydata()[0] for ax in drawn[0].axes for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert dashed == [2.0, 2.0]
    quiet = [RunLog(Path("a.mcap"), "cartpole", "sb3", 2.0, {}, [episode(0, 1.2), episode(1, 1.5)], True)]
    assert plots.plot_id_alarms(quiet, "sb3", "cartpole", tmp_path / "q.png") is not None
    assert [ax.get_title().split(":")[0] for ax in drawn[1].axes] == ["no alarm, the closest to the threshold"]
    assert "episode 1 of a.mcap" in drawn[1].axes[0].get_title()
    # one panel's title wrapped to its width (it ran off both sides of the picture), and the
    # panel's own lines too ("no alarm, the closest to the threshold: episode 0 of idspread.mcap,
    # pendulum": 76 characters, cut at both edges)
    assert [len(line) <= 75 for line in drawn[1].texts[0].get_text().split("\n")] == [True, True]
    long = [RunLog(Path("a-log-of-a-deployment-whose-name-is-long.mcap"), "cartpole", "sb3", 2.0, {}, [episode(0, 1.2)],
                   True)]
    plots.plot_id_alarms(long, "sb3", "cartpole", tmp_path / "l.png")
    assert [len(line) <= 60 for line in drawn[2].axes[0].get_title().split("\n")] == [True, True, True]
    assert plots.plot_id_alarms(quiet, "dropout", "cartpole", tmp_path / "n.png") is None  # no such method


def test_a_windowed_rules_traces_draw_the_mean_the_alarm_compares(tmp_path, monkeypatch):
    """Pong's features alarm on their mean over 200 steps: the trace drew the score alone, which
    crossed the threshold in a calm game again and again where no alarm came, and the calm episode
    "closest" was that of the highest single score. Now the window's mean is drawn over the faint
    score, and the closest episode is the one whose mean came highest."""
    import numpy as np

    from oodmon.replay import EpisodeLog, RunLog
    from oodmon.replay import plots

    def episode(k, scores):
        n = len(scores)
        return EpisodeLog(episode=k, env_id="", variant="pong", onset=0, seed=k, total_return=0.0, length=n,
                          alarms=0, first_alarm_step=None, scores=np.asarray(scores, float), shifted=np.zeros(n, bool),
                          alarm=np.zeros(n, bool))

    # the spike crosses the threshold, 2.5, alone (its mean over 3 steps 1.33); the sustained stays below it (mean 2.0)
    spike, sustained = [0.0] * 10 + [4.0] + [0.0] * 9, [0.0] * 5 + [2.0] * 6 + [0.0] * 9
    logs = [RunLog(Path("w.mcap"), "pong", "dropconnect", 2.5, {"detector": "features",
                                                                 "rule": "mean score over 3 steps > threshold"},
                   [episode(0, spike), episode(1, sustained)], True)]
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    assert plots.plot_id_alarms(logs, "dropconnect", "pong", tmp_path / "w.png") is not None
    ax = drawn[0].axes[0]
    assert "episode 1 of w.mcap" in ax.get_title()  # its mean, 2.0, came closer than the spike's 1.33
    lines = {line.get_label(): line for line in ax.get_lines()}
    mean = lines["mean over 3 steps (the alarm's)"]
    assert mean.get_xdata().tolist() == list(range(2, 20)) and max(mean.get_ydata()) == 2.0
    assert lines["score"].get_alpha() < 1
    logs[0].metadata["rule"] = "mean score over 3 steps > threshold from step 4 of each episode"  # with a warm-up
    assert plots.plot_id_alarms(logs, "dropconnect", "pong", tmp_path / "u.png") is not None
    warm = {line.get_label(): line for line in drawn[-1].axes[0].get_lines()}["mean over 3 steps (the alarm's)"]
    assert warm.get_xdata().tolist() == list(range(6, 20))  # the window fills from the warm-up's end
    drawn.pop()
    logs[0].metadata["rule"] = "score > threshold"  # each step's own: as before, the score alone
    assert plots.plot_id_alarms(logs, "dropconnect", "pong", tmp_path / "s.png") is not None
    assert "episode 0 of w.mcap" in drawn[1].axes[0].get_title()  # the highest score, 4.0
    assert [line.get_label() for line in drawn[1].axes[0].get_lines()][:1] == ["score"]
    assert not any("mean over" in line.get_label() for line in drawn[1].axes[0].get_lines())
    # a CUSUM compares its statistic with a threshold on a scale of its own: the threshold was drawn on
    # the score's axis; now it is not, and the title says why
    from oodmon.monitor.alarms import rule_text

    logs[0].metadata["rule"] = rule_text("2.5", 1, rule="cusum")
    assert plots.plot_id_alarms(logs, "dropconnect", "pong", tmp_path / "c.png") is not None
    assert not [line for line in drawn[2].axes[0].get_lines() if line.get_linestyle() == "--"]
    assert "the alarm compares a CUSUM statistic of the scores with its threshold, 2.5, on a scale of its own: not " \
           "drawn here" in drawn[2].texts[0].get_text().replace("\n", " ")


def test_roc_and_trace_read_the_variants_own_task(tmp_path):
    """One method's runs of two tasks replayed together: a CartPole variant's ROC and trace take their
    ID steps from the CartPole runs alone (the Pendulum ID run's high scores would sink its AUROC)."""
    import numpy as np
    from sklearn.metrics import roc_auc_score

    from oodmon.replay import EpisodeLog, RunLog
    from oodmon.replay.plots import _labels_and_scores

    def log(task, variant, scores, shifted):
        n = len(scores)
        episode = EpisodeLog(episode=0, env_id="", variant=variant, onset=0, seed=0, total_return=0.0, length=n,
                             alarms=0, first_alarm_step=None, scores=np.asarray(scores, float),
                             shifted=np.full(n, shifted), alarm=np.zeros(n, bool))
        return RunLog(Path(f"{task}.mcap"), task, "dropconnect", 1.0, {}, [episode], True)

    logs = [log("pendulum", "pendulum", [9.0] * 4, False), log("cartpole", "cartpole", [0.1, 0.2, 0.3], False),
            log("cartpole", "cartpole:length=2.0", [0.5, 0.6], True)]
    labels, scores = _labels_and_scores(logs, "dropconnect", "cartpole:length=2.0")
    assert labels.tolist() == [0, 0, 0, 1, 1] and roc_auc_score(labels, scores) == 1.0
    both = plot_trace(logs, "dropconnect", "cartpole:length=2.0", tmp_path / "trace.png")
    # Without a CartPole ID run the shifted episode is drawn alone: one panel, not the Pendulum run beside it.
    alone = plot_trace(logs[:1] + logs[2:], "dropconnect", "cartpole:length=2.0", tmp_path / "t.png")
    width = {path.name: cv2.imread(str(path)).shape[1] for path in (both, alone)}
    assert width["t.png"] < 0.6 * width["trace.png"]


def test_a_run_shifted_mid_episode_alone_gets_its_trace_and_each_detector_its_auroc_line(tmp_path, monkeypatch):
    """A run with no ID log (its shift begins at step 20: the steps before are its ID ones) gets a
    trace of a shifted episode; the AUROC-vs-shift plot has one line per method and detector, which
    stops on either side of the parameter's ID value (a dashed line, in the title): the pole shorter
    than in ID and the pole longer are two shifts, not one curve through the ID world."""
    import numpy as np

    from oodmon.replay import EpisodeLog, RunLog
    from oodmon.replay import plots
    from oodmon.replay.plots import plot_auroc_vs_shift

    rng = np.random.default_rng(0)
    episodes = []
    # the last: the long pole and a stuck sensor, two changes, on no one parameter's line
    for k, variant in enumerate(("length=2.0", "length=3.0", "length=0.25", "length=2.0,obs.stuck[3]=1.0")):
        combined, dynamics = np.r_[rng.normal(0, 1, 20), rng.normal(3, 1, 40)], rng.normal(0, 1, 60)
        episodes.append(EpisodeLog(episode=k, env_id="", variant=f"cartpole:{variant}", onset=20, seed=k,
                                   total_return=60.0, length=60, alarms=1, first_alarm_step=21, scores=combined,
                                   shifted=np.arange(60) >= 20, alarm=np.arange(60) == 21,
                                   detector_scores={"combined": combined, "dynamics": dynamics}))
    logs = [RunLog(Path("sb3.mcap"), "cartpole", "sb3", 2.5, {"detector": "combined", "detectors": "dynamics,combined"},
                   episodes, True)]
    assert plot_trace(logs, "sb3", "cartpole:length=2.0", tmp_path / "trace.png") is not None
    metrics = compute_metrics(logs) + compute_metrics(logs, "dynamics")
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    assert plot_auroc_vs_shift(metrics, "cartpole", tmp_path / "shift.png") is not None
    ax = drawn[0].axes[0]
    segments: dict[str, list] = {}
    for line in ax.get_lines():
        if line.get_label().lstrip("_").startswith("sb3"):
            segments.setdefault(line.get_label().lstrip("_"), []).append(line)
    assert sorted(segments) == ["sb3, combined", "sb3, dynamics"]  # one line each, not one zigzag through both
    for lines in segments.values():
        assert [line.get_xdata().tolist() for line in lines] == [[0.25], [2.0, 3.0]]  # below the ID 0.5, above it
        assert len({line.get_color() for line in lines}) == 1
    assert [text.get_text() for text in ax.get_legend().get_texts()] == ["sb3, combined", "sb3, dynamics"]
    assert any(line.get_xdata()[0] == 0.5 and line.get_linestyle() == "--" for line in ax.get_lines())
    assert ax.get_title() == "length (ID 0.5, dashed)"
    drawn[0].canvas.draw()  # few values: each labelled (3 was left between the ticks at 2 and 5)
    assert [t.get_text() for t in ax.get_xticklabels() if t.get_text()] == ["0.25", "0.5", "2", "3"]
    auroc = {label: np.concatenate([line.get_ydata() for line in lines]) for label, lines in segments.items()}
    assert min(auroc["sb3, combined"]) > 0.9 > max(auroc["sb3, dynamics"])


def _episode(scores, onset):
    import numpy as np

    from oodmon.replay import EpisodeLog

    n = len(scores)
    return EpisodeLog(episode=0, env_id="", variant="cartpole" if onset is None else "cartpole:length=2.0",
                      onset=onset or 0, seed=0, total_return=float(n), length=n, alarms=0, first_alarm_step=None,
                      scores=np.asarray(scores, float), shifted=np.arange(n) >= (n if onset is None else onset),
                      alarm=np.zeros(n, bool))


def test_a_trace_whose_shifted_scores_dwarf_the_id_ones_draws_them_on_a_symlog_axis(tmp_path, monkeypatch):
    """The demo's dynamics scores: about -2 on ID steps, threshold -1.47, then up to 27,000 after the
    shift. On a linear axis the ID trace and the threshold were one line at zero; on the symlog axis
    they sit in its linear part (up to 10) and both lie inside the drawn range."""
    import numpy as np

    from oodmon.replay import RunLog
    from oodmon.replay import plots
    from oodmon.replay.plots import score_scale

    rng = np.random.default_rng(0)
    calm = -2.0 + 0.2 * rng.standard_normal(400)
    wide = [_episode(calm[:200], None), _episode(np.r_[calm[200:300], np.geomspace(100, 27_000, 150)], 100)]
    assert score_scale(wide, -1.47) == 10.0  # the ID scale, about 2.5, rounded up to a decade
    spread = [_episode(0.05 + 0.01 * rng.random(200), None),
              _episode(np.r_[0.05 + 0.01 * rng.random(100), np.full(50, 0.5)], 100)]
    assert score_scale(spread, 0.08) is None  # shifted scores 6 times the ID ones: a linear axis reads well
    assert score_scale(spread, float("nan")) is None
    inf = [_episode(np.r_[calm[:100], np.inf, 1.0], 100)]  # a failed sensor's +inf is not a size
    assert score_scale(inf, -1.47) is None

    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    for episodes, scale in ((wide, "symlog"), (spread, "linear")):
        logs = [RunLog(Path("x.mcap"), "cartpole", "ensemble", -1.47 if scale == "symlog" else 0.08,
                       {"detector": "dynamics"}, episodes, True)]
        assert plots.plot_trace(logs, "ensemble", "cartpole:length=2.0", tmp_path / "trace.png") is not None
        axes = drawn[-1].axes
        assert len(axes) == 2 and {ax.get_yscale() for ax in axes} == {scale}
    low, high = drawn[0].axes[0].get_ylim()
    assert low < min(calm[:300]) < -1.47 < 27_000 <= high  # the ID trace, the threshold and the peak all drawn


def test_the_id_panel_beside_a_shifted_run_draws_that_runs_detector_and_prefers_a_run_of_its_threshold(
        tmp_path, monkeypatch):
    """An ID run whose alarm read the spread (0-1.6, threshold 1.37) replayed beside a shifted run
    whose alarm read the dynamics score (threshold -1.19): the ID panel drew the spread against the
    dynamics threshold, as if the calm episode were above it at every step (2026-12-07, by hand with
    Pendulum's Dropout agent). It now draws the ID episode's dynamics scores, without the alarms its
    own threshold raised (the title says so), and takes an ID episode of a run of the shifted run's
    threshold where one is there; under a sequential rule, whose statistic each log holds of its own
    rule, only that one."""
    import dataclasses

    import numpy as np

    from oodmon.replay import RunLog
    from oodmon.replay import plots

    rng = np.random.default_rng(0)
    spread, dynamics = rng.uniform(0.0, 1.6, 200), -2.0 + 0.05 * rng.standard_normal(200)
    alarmed = dataclasses.replace(_episode(spread, None), alarms=1, first_alarm_step=9, alarm=np.arange(200) >= 9,
                                  detector_scores={"spread": spread, "dynamics": dynamics})
    shifted = dataclasses.replace(_episode(np.r_[dynamics[:50], np.full(150, 80.0)], 50), alarms=1,
                                  first_alarm_step=52, alarm=np.arange(200) >= 52)
    spread_run = RunLog(Path("id-spread.mcap"), "cartpole", "dropout", 1.37,
                        {"detector": "spread", "rule": "score > threshold for 3 consecutive steps"}, [alarmed], True)
    rule = {"detector": "dynamics", "rule": "score > threshold"}
    shifted_run = RunLog(Path("shifted.mcap"), "cartpole", "dropout", -1.19, rule, [shifted], True)
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))

    def id_panel(logs):
        assert plots.plot_trace(logs, "dropout", "cartpole:length=2.0", tmp_path / "trace.png") is not None
        figure = drawn[-1]
        if len(figure.axes) == 1:
            return None, figure._suptitle.get_text()
        line = next(line for line in figure.axes[0].get_lines() if line.get_label() == "score")
        alarms = [line for line in figure.axes[0].get_lines() if line.get_color() == "tab:purple"]
        return (line.get_ydata(), len(alarms)), figure._suptitle.get_text()

    (scores, alarms), title = id_panel([spread_run, shifted_run])
    assert np.array_equal(scores, dynamics) and alarms == 0
    assert "dropout, dynamics detector" in title and "the ID episode's alarms, by spread > 1.37, not drawn" in title
    calm = dataclasses.replace(_episode(dynamics - 0.5, None), detector_scores={"dynamics": dynamics - 0.5})
    same = RunLog(Path("id-dynamics.mcap"), "cartpole", "dropout", -1.19, rule, [calm], True)
    (scores, alarms), title = id_panel([spread_run, shifted_run, same])
    assert np.array_equal(scores, dynamics - 0.5) and "not drawn" not in title
    cusum = {"detector": "dynamics", "rule": "CUSUM of the scores' p-values > threshold"}
    assert plots._statistic_name(cusum["rule"]) is not None
    sequential = dataclasses.replace(shifted_run, threshold=103.0, metadata=cusum)
    assert id_panel([spread_run, same, sequential])[0] is None  # drawn alone, not beside another rule's episode


def test_replay_monitor_plots_write_each_agents_alarm_timeline_and_its_id_alarms(tmp_path):
    # --plots was accepted with --monitor and wrote nothing; the ID episodes' trace since 2026-12-07
    result = run_cli("replay", str(DATA), "--monitor", "--plots", str(tmp_path))
    assert result.returncode == 0 and "wrote 2 plot(s)" in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alarms_cartpole_ensemble.png", "trace_ensemble_cartpole.png"]
    image = cv2.imread(str(tmp_path / "alarms_cartpole_ensemble.png"))
    assert image is not None and image.shape[0] > 150 and image.shape[1] > 800


def test_the_alarm_timeline_marks_each_episodes_first_alarm_early_alarm_and_failure(tmp_path, monkeypatch):
    from oodmon.replay import plots
    from oodmon.replay.metrics import EpisodeAlarms

    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    episodes = [EpisodeAlarms(early=-3, first=1, failure=5, end=5),  # a false alarm, then in time
                EpisodeAlarms(early=None, first=None, failure=4, end=4),  # never alarmed
                EpisodeAlarms(early=None, first=6, failure=4, end=9),  # alarmed after it failed (Pendulum goes on)
                EpisodeAlarms(early=None, first=2, failure=None, end=30)]  # alarmed, coped
    assert plots.plot_alarm_timeline({"cartpole:length=2.0": episodes}, "t", tmp_path / "a.png") is not None
    ax = drawn[0].axes[0]
    points = {c.get_label(): c.get_offsets().tolist() for c in ax.collections if c.get_label() in (
        "alarm before the failure", "alarm at or after the failure", "alarm before the onset", "failure")}
    assert points == {"alarm before the failure": [[1, 0], [2, 3]], "alarm at or after the failure": [[6, 2]],
                      "alarm before the onset": [[-3, 0]], "failure": [[5, 0], [4, 1], [4, 2]]}
    assert ax.get_title() == ("length=2.0: 3 of 4 episodes alarmed; 1 of 3 failures alarmed before them (lead median 4)"
                              "; delay median 2")  # the env (cartpole) is named once, in the figure's title
    assert drawn[0]._suptitle.get_text() == "cartpole: t"
    many = [EpisodeAlarms(None, 1, 9, 9)] * 70
    plots.plot_alarm_timeline({"cartpole:masscart=9.0": many}, "t", tmp_path / "b.png")
    ax = drawn[1].axes[0]
    assert "70 episodes alarmed (the first 60 drawn)" in ax.get_title()
    assert len(next(c for c in ax.collections if c.get_label() == "failure").get_offsets()) == 60
    assert plots.plot_alarm_timeline({"cartpole:length=2.0": []}, "t", tmp_path / "c.png") is None


def test_infinite_scores_are_marked_at_the_top_of_the_trace_not_left_out(tmp_path, monkeypatch):
    """A failed sensor's NaN observation scores +inf (the most shifted). The trace's line stopped at
    the last finite score, and the episode seemed to end there; the steps are now marked at the top."""
    import numpy as np

    from oodmon.replay import RunLog
    from oodmon.replay import plots

    scores = np.r_[np.full(30, 3.5), np.linspace(3.5, 18.0, 20), np.full(10, np.inf)]
    logs = [RunLog(Path("x.mcap"), "cartpole", "ensemble", 3.0, {}, [_episode(np.full(60, 3.5), None),
                                                                   _episode(scores, 10)], True)]
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    plots.plot_trace(logs, "ensemble", "cartpole:length=2.0", tmp_path / "trace.png")
    id_axis, shifted_axis = drawn[0].axes
    marked = [c for c in shifted_axis.collections if c.get_label() == "score +inf (at the top)"]
    assert len(marked) == 1 and marked[0].get_offsets()[:, 0].tolist() == list(range(50, 60))
    assert not [c for c in id_axis.collections if "inf" in str(c.get_label())]


def test_the_alarm_timeline_of_an_env_without_a_failure_names_no_failure(tmp_path, monkeypatch):
    # A shift of the user's own env (Acrobot's episode ends when it succeeds): its green dots were
    # labelled "alarm before the failure" and its title said "0 of 0 failures alarmed before them".
    from oodmon.replay import plots
    from oodmon.replay.metrics import EpisodeAlarms

    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    episodes = [EpisodeAlarms(early=-3, first=1, failure=None, end=5), EpisodeAlarms(early=None, first=2, failure=None, end=30)]
    assert plots.plot_alarm_timeline({"Acrobot-v1:LINK_MASS_2=3.0": episodes}, "t", tmp_path / "a.png",
                                     failures=False) is not None
    ax = drawn[0].axes[0]
    assert {c.get_label(): c.get_offsets().tolist() for c in ax.collections if not c.get_label().startswith("_")} == {
        "first alarm after the onset": [[1, 0], [2, 1]], "alarm before the onset": [[-3, 0]]}
    assert ax.get_title() == "LINK_MASS_2=3.0: 2 of 2 episodes alarmed; delay median 1.5"
    plots.plot_alarm_timeline({"Acrobot-v1:LINK_MASS_2=3.0": episodes}, "t", tmp_path / "b.png")  # told: none failed
    assert drawn[1].axes[0].get_title() == "LINK_MASS_2=3.0: 2 of 2 episodes alarmed; none failed; delay median 1.5"


def _hidden_ball_log(path: Path):
    """A log of two episodes of 20x40 pictures in which a ball vanishes mid-field from step 5 on,
    under the vanishing detector fitted on its rally: each first alarm names a region (format 12).
    Returns an episode's pictures."""
    from oodmon.monitor import McapSink, Monitor
    from oodmon.monitor.detectors import VanishingDetector
    from tests.helpers import RALLY, ball_pictures

    detector = VanishingDetector(grid=4, reach=4).fit([ball_pictures(RALLY)])
    pictures = ball_pictures(RALLY[:26], hidden=range(15, 25)).observations
    with Monitor(None, threshold=0.5, detectors=[detector], detector="vanishing", sinks=[McapSink(path)]) as monitor:
        for _ in range(2):
            monitor.begin_episode(env_id="Balls-v0", variant="Balls-v0:hidden", onset=3)
            for step, frame in enumerate(pictures):
                monitor.step(frame, action=0, frame=frame, shifted=step >= 3)
            monitor.end_episode(terminated=False)
    return pictures


def test_where_draws_the_frame_at_each_first_alarm_with_its_region_boxed(tmp_path, monkeypatch):
    """``replay --plots`` of a picture policy's logs: the frame the policy acted on at each first
    alarm that named a region (the vanishing detector's, format 12), the region boxed; the frames
    alone are read (``read_frames``)."""
    from matplotlib.patches import Rectangle

    from oodmon.replay import plots
    from oodmon.replay.reader import read_frames

    frames = _hidden_ball_log(tmp_path / "balls.mcap")
    log = read_log(tmp_path / "balls.mcap")
    regions = [(e.first_alarm_step, tuple(e.first_alarm_region)) for e in log.episodes]
    assert regions == [(5, (5, 10, 5, 10, 20, 40))] * 2  # rows 5-9, columns 10-19 of the 20x40 picture
    found = read_frames(tmp_path / "balls.mcap", [(0, 5), (1, 7), (1, 99), (5, 5)])
    assert sorted(found) == [(0, 5), (1, 7)]  # (no step 99, no episode 5)
    assert (found[(0, 5)] == frames[5]).all() and (found[(1, 7)] == frames[7]).all()
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    assert plots.plot_where([log], log.task, log.method, tmp_path / "where.png") is not None
    panels = [ax for ax in drawn[0].axes if ax.images]
    assert [ax.get_title() for ax in panels] == ["episode 0, step 5 (+2)", "episode 1, step 5 (+2)"]
    (box,) = [patch for patch in panels[0].patches if isinstance(patch, Rectangle)]
    assert (box.get_xy(), box.get_width(), box.get_height()) == ((9.5, 4.5), 10, 5)  # columns 10-19, rows 5-9
    assert (panels[0].images[0].get_array() == frames[5]).all()
    assert "where the first alarms of Balls-v0:hidden said their events fell" in drawn[0].texts[0].get_text()
    assert "2 of 2 such first alarm(s)" in drawn[0].texts[0].get_text().replace("\n", " ")
    assert plots.plot_where([log], log.task, "other", tmp_path / "none.png") is None  # no such method
    monkeypatch.undo()
    run_cli("replay", str(tmp_path / "balls.mcap"), "--monitor", "--plots", str(tmp_path / "plots"))
    assert [p.name for p in (tmp_path / "plots").glob("where_*.png")] == [
        f"where_{plots.safe_filename(log.task)}_{plots.safe_filename(log.method)}.png"]
