"""Pictures from recorded logs (PNG): ROC curves, uncertainty traces, AUROC against the shift.

- :func:`plot_roc`: per method and detector, the ROC curve of one variant's per-step scores.
- :func:`plot_trace`: the paper's Figures 4 and 5: one ID episode beside one shifted episode,
  the score over the steps with the threshold, the shifted steps shaded, alarms marked.
- :func:`plot_id_alarms`: per method and task, what the alarm made of the ID episodes (all a
  deployment's logs hold): the first alarmed one beside the calm one that came closest to the threshold.
- :func:`plot_auroc_vs_shift`: per method, AUROC against the parameter's value (or severity).
- :func:`plot_alarm_timeline` (``replay --monitor --plots``): per agent and shifted variant, each
  episode from its onset to its end, its first alarm and its failure: alarmed before the failure?
- :func:`plot_log_statistics` (``recalibrate --plot``): each calibration episode's statistic in the
  order they ended, the threshold, the logged runs' own, and the most likely change among them.
"""

from __future__ import annotations

import math
import textwrap
from collections import defaultdict
from dataclasses import replace
from itertools import cycle
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from oodmon.envs.physics import PHYSICS_DEFAULTS
from oodmon.envs.shift import parse_any_variant
from oodmon.errors import OodmonError
from oodmon.monitor.alarms import compared_name, rule_window, trailing_mean
from oodmon.outputs import safe_filename, save_figure
from oodmon.replay.failures import failure_known
from oodmon.replay.metrics import (EpisodeAlarms, VariantMetrics, alarm_events, env_of_variant, is_id_episode,
                                   is_id_variant, rankable, roc_points, shifted_alarms)
from oodmon.replay.reader import EpisodeLog, RunLog, read_compared, read_frames

if TYPE_CHECKING:
    from oodmon.monitor.threshold import Threshold
    from oodmon.replay.recalibrate import LogStatistics

__all__ = ["plot_alarm_timeline", "plot_auroc_vs_shift", "plot_id_alarms", "plot_log_statistics", "plot_roc",
           "plot_trace", "plot_where", "roc_curves", "write_monitor_plots", "write_plots"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _runs_of(logs: Sequence[RunLog], method: str, variant: str) -> list[RunLog]:
    """The logs of ``method`` on the task of the shifted ``variant``: its ID steps come from that
    task's runs alone, as in :func:`~oodmon.replay.compute_metrics`, not from the method's runs
    of another task replayed beside them."""
    tasks = {log.task for log in logs if any(episode.variant == variant for episode in log.episodes)}
    return [log for log in logs if log.method == method and log.task in tasks]


def _alarm_detectors(logs: Sequence[RunLog], method: str, variant: str) -> list[str]:
    """The detectors whose scores the alarms of ``method``'s runs read, each once."""
    return sorted({log.detector for log in _runs_of(logs, method, variant)})


def _labels_and_scores(logs: Sequence[RunLog], method: str, variant: str, detector: str | None = None, *,
                       held_only: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """``method``'s steps of ``variant``'s task as labels (1: shifted) and the scores of ``detector``
    (``None``: the alarm's), as replay's AUROC ranks them; ``None`` without both kinds of step.
    ``held_only``: the episodes whose log holds none of ``detector``'s scores are left out (every
    log holds its alarm's detector's), never one run's alarm scores ranked beside another's of
    another detector."""
    negatives, positives = [], []
    for log in _runs_of(logs, method, variant):
        for episode in log.episodes:
            if held_only and detector not in episode.detector_scores:
                continue
            scores = episode.scores_of(detector)
            if is_id_episode(episode, log.task):
                negatives.append(scores)
            elif episode.variant == variant:
                negatives.append(scores[~episode.shifted])
                positives.append(scores[episode.shifted])
    if not positives or not negatives:
        return None
    neg, pos = np.concatenate(negatives), np.concatenate(positives)
    if not len(neg) or not len(pos):
        return None
    return np.concatenate([np.zeros(len(neg)), np.ones(len(pos))]), np.concatenate([neg, pos])


def roc_curves(logs: Sequence[RunLog], variant: str, detectors: Mapping[str, Sequence[str]] | None = None
               ) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """What :func:`plot_roc` draws: per method (sorted) and detector, ``(method, detector, labels,
    scores)`` of ``variant``'s task's steps. ``detectors`` names each method's; ``None``: those its
    runs' alarms read, each ranked over the runs that hold its scores (a run whose alarm read
    ``spread`` ranks with the others' ``spread`` scores, not their ``dynamics`` alarm scores)."""
    curves = []
    for method in sorted({log.method for log in logs}):
        named = _alarm_detectors(logs, method, variant) if detectors is None else detectors.get(method, [])
        for name in named:
            data = _labels_and_scores(logs, method, variant, name, held_only=detectors is None)
            if data is not None:
                curves.append((method, name, *data))
    return curves


def plot_roc(logs: Sequence[RunLog], variant: str, path: str | Path,
             detectors: Mapping[str, Sequence[str]] | None = None) -> Path | None:
    """ROC curves of ``variant``, one per method and detector (:func:`roc_curves`): ``detectors``
    names each method's (``None``: the ones its alarms read); ``None`` when no method has both ID
    and OOD steps."""
    curves = roc_curves(logs, variant, detectors)
    if not curves:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(4.5, 4.5), dpi=110)
    colours: dict[str, str] = {}  # a detector's colour, the same for every method; a method's line style
    styles = dict(zip(sorted({method for method, *_ in curves}), cycle(["-", "--", ":", "-."])))
    for method, name, labels, scores in curves:
        fpr, tpr = roc_points(labels, rankable(scores))
        colour = colours.setdefault(name, f"C{len(colours) % 10}")
        ax.plot(fpr, tpr, color=colour, linestyle=styles[method],
                label=f"{method}, {name} (AUROC {np.trapezoid(tpr, fpr):.3f})")
    ax.plot([0, 1], [0, 1], color="grey", linestyle=":", linewidth=1)
    ax.set(xlabel="false-positive rate (ID steps)", ylabel="true-positive rate (OOD steps)", title=f"ROC: {variant}")
    ax.legend(loc="lower right", fontsize=8)
    return save_figure(fig, path)


def plot_trace(logs: Sequence[RunLog], method: str, variant: str, path: str | Path) -> Path | None:
    """The score over one ID episode beside one episode of ``variant`` (the paper's Figures 4, 5);
    the episode of ``variant`` alone when the logs hold no ID episode (a run whose shift begins
    mid-episode: its steps before the onset are the ID ones). The threshold and the rule drawn are
    those of the shifted episode's run, and the ID episode's scores the same detector's (see
    :func:`_id_beside`)."""
    runs = _runs_of(logs, method, variant)
    found = next(((episode, log) for log in runs for episode in log.episodes if episode.variant == variant), None)
    if found is None:
        return None
    shifted_episode, shifted_log = found
    text = shifted_log.metadata.get("rule", "")
    panels, sources, words = [], [], ""
    beside = _id_beside(runs, shifted_log)
    if beside is not None:
        id_episode, id_log, words = beside
        panels, sources = [(id_episode, f"ID: {episode_name(id_episode)}")], [id_log]
    panels.append((shifted_episode, f"shifted: {episode_name(shifted_episode)}"))
    sources.append(shifted_log)
    title = f"{method}, {shifted_log.detector} detector: alarms as vertical lines{words}"
    return _draw_with_rule(panels, sources, shifted_log.threshold, title, path, rule_window(text), text)


def _id_beside(runs: Sequence[RunLog], shifted: RunLog) -> tuple[EpisodeLog, RunLog, str] | None:
    """The ID episode :func:`plot_trace` draws beside an episode of the run ``shifted``, its log and
    the words the title then adds: the first ID episode of a run whose alarm compared the same
    detector's scores (of the same fit, where both logs name theirs) with the same threshold by the
    same rule, as it is; else, but under a sequential rule (whose statistic each log holds of its
    own rule), the first whose log holds that detector's scores of the same fit, drawn with those
    scores and without its own alarms, which another detector or threshold raised (the title's
    words say so where it had any). ``None`` where there is neither. Until 2026-12-07 the first ID
    episode of any run was drawn with its own run's alarm scores: a Pendulum spread of 0-1.6
    against the shifted run's dynamics threshold of -1.19, above it at every step."""
    detector, rule = shifted.detector, shifted.metadata.get("rule", "")
    fit = shifted.metadata.get(f"fitted.{detector}")
    ids = [(episode, log) for log in runs for episode in log.episodes if is_id_episode(episode, log.task)
           and fit in (None, log.metadata.get(f"fitted.{detector}", fit))]
    for episode, log in ids:
        if (log.detector, log.metadata.get("rule", "")) == (detector, rule) and (
                log.threshold == shifted.threshold or not (log.has_threshold or shifted.has_threshold)):
            return episode, log, ""
    if _statistic_name(rule) is not None:
        return None
    for episode, log in ids:
        if detector in episode.detector_scores:
            drawn = replace(episode, scores=episode.detector_scores[detector], alarm=np.zeros(episode.length, bool))
            dropped = f" (the ID episode's alarms, by {log.detector} > {log.threshold:.6g}, not drawn)"
            return drawn, log, dropped if episode.alarm.any() else ""
    return None


def plot_id_alarms(logs: Sequence[RunLog], method: str, task: str, path: str | Path) -> Path | None:
    """What the alarm made of ``method``'s ID episodes of ``task`` (a deployment's logs, where every
    episode is one): the first that alarmed beside the calm one that came closest to the same
    threshold (its score, or with a rule's window the mean the alarm compares, or a sequential
    rule's statistic as its log holds it), each drawn as
    :func:`plot_trace` draws one, or the calm one alone where none alarmed; ``None`` where the logs
    hold no ID episode of a run with a threshold. The title counts the ID episodes of the runs of
    that one alarm (detector, threshold and rule), and says how many others' it left out (until
    2026-12-07 it counted them among them, and named every detector of the logs)."""
    episodes = [(episode, log) for log in logs if log.method == method and log.task == task
                and np.isfinite(log.threshold) for episode in log.episodes if is_id_episode(episode, log.task)]
    if not episodes:
        return None

    def alarm_of(log: RunLog) -> tuple[str, float, str]:  # the detector, threshold and rule a run's alarm had
        return log.detector, log.threshold, log.metadata.get("rule", "")

    # the runs of one alarm: the first alarmed episode's, else the first episode's
    first = next((log for episode, log in episodes if episode.alarm.any()), episodes[0][1])
    detector, threshold, text = alarm_of(first)
    rule = rule_window(text)
    mine = [(episode, log) for episode, log in episodes if alarm_of(log) == (detector, threshold, text)]
    alarmed = [(episode, log) for episode, log in mine if episode.alarm.any()]
    calm = [(episode, log) for episode, log in mine if not episode.alarm.any()]
    logged = _logged_statistics(text, calm + alarmed[:1])  # a sequential rule's, as its logs hold it

    def margin(episode: EpisodeLog, log: RunLog) -> float:  # how close what the alarm compares came to the threshold
        compared = logged.get((log.path, episode.episode))
        if compared is None:
            compared = _compared(episode.scores, rule)[1]
        finite = compared[np.isfinite(compared)]
        return float(finite.max()) - threshold if len(finite) else -math.inf

    panels, sources = [], []
    if alarmed:
        first, log = alarmed[0]
        panels.append((first, f"alarmed at step {alarm_events(first.alarm)[0]}: episode {first.episode} of "
                              f"{log.path.name}, {episode_name(first)}"))
        sources.append(log)
    if calm:
        highest, log = max(calm, key=lambda pair: margin(*pair))
        panels.append((highest, f"no alarm, the closest to the threshold: episode {highest.episode} of "
                                f"{log.path.name}, {episode_name(highest)}"))
        sources.append(log)
    others = len(episodes) - len(mine)
    title = (f"{method}, {detector} detector, {task}: {len(alarmed)} of {len(mine)} ID episode(s) alarmed "
             + (f"({others} more of runs by another alarm not counted; " if others else "(")
             + "alarms as vertical lines)")
    return _draw_with_rule(panels, sources, threshold, title, path, rule, text, logged)


#: First alarms drawn by :func:`plot_where` (the first ones; its title says of how many).
WHERE_PANELS = 12


def plot_where(logs: Sequence[RunLog], task: str, method: str, path: str | Path) -> Path | None:
    """Where in the picture ``method``'s first alarms of ``task`` said their events fell
    (:attr:`EpisodeLog.first_alarm_region`, log format 12: a picture policy's alarm the
    ``vanishing`` detector raised): the frame the policy acted on at each first alarm, its region
    boxed, at most :data:`WHERE_PANELS` of them, the episodes in the logs' order; ``None`` where no
    episode's first alarm names one, or the logs hold none of those frames (a run that logged no
    pictures). The frames alone are read (:func:`~oodmon.replay.reader.read_frames`)."""
    named = [(log, episode) for log in logs if (log.task, log.method) == (task, method)
             for episode in sorted([*log.episodes, *log.interrupted], key=lambda e: e.episode)
             if episode.first_alarm_region is not None and episode.first_alarm_step is not None]
    shown, frames = named[:WHERE_PANELS], {}
    for source in dict.fromkeys(log.path for log, _ in shown):  # each log read once, for its frames alone
        steps = [(episode.episode, episode.first_alarm_step) for log, episode in shown if log.path == source]
        frames |= {(source, *step): frame for step, frame in read_frames(source, steps).items()}
    drawn = [(log, episode) for log, episode in shown
             if (log.path, episode.episode, episode.first_alarm_step) in frames]
    if not drawn:
        return None
    plt = _pyplot()
    from matplotlib.patches import Rectangle

    columns = min(4, len(drawn))
    rows = -(-len(drawn) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3 * columns, 3.3 * rows), squeeze=False)
    for ax in axes.flat[len(drawn):]:
        ax.axis("off")
    variants = {episode.variant for _, episode in drawn}
    for ax, (log, episode) in zip(axes.flat, drawn):
        frame, region = frames[(log.path, episode.episode, episode.first_alarm_step)], episode.first_alarm_region
        ax.imshow(frame, cmap="gray" if frame.ndim == 2 else None, vmin=0, vmax=255, interpolation="nearest")
        ax.add_patch(Rectangle((region.left - 0.5, region.top - 0.5), region.width, region.height, fill=False,
                               edgecolor="red", linewidth=2))
        onset = f" ({episode.first_alarm_step - episode.onset:+d})" if not is_id_episode(episode, log.task) else ""
        variant = "" if len(variants) == 1 else "\n" + episode.variant.removeprefix(f"{task}:")
        ax.set_title(f"episode {episode.episode}, step {episode.first_alarm_step}{onset}{variant}", fontsize=8,
                     wrap=True)
        ax.set_xticks([])
        ax.set_yticks([])
    shared = f" of {variants.pop()}" if len(variants) == 1 else ""
    fig.suptitle(f"{task}/{method}: where the first alarms{shared} said their events fell, boxed on the frame "
                 f"at each alarm (steps from the onset in brackets); {len(drawn)} of {len(named)} such first "
                 "alarm(s)", fontsize=9, wrap=True)
    return save_figure(fig, path)


def _where_plots(logs: Sequence[RunLog], folder: Path) -> list[Path | None]:
    """:func:`plot_where` of each task and method the logs hold, as ``where_<task>_<method>.png``."""
    return [plot_where(logs, task, method, folder / f"where_{safe_filename(task)}_{safe_filename(method)}.png")
            for task, method in sorted({(log.task, log.method) for log in logs})]


def _statistic_name(text: str) -> str | None:
    """The name of the statistic a sequential rule (``text``, a log's ``rule`` in words) compares
    with its threshold (:func:`~oodmon.monitor.alarms.compared_name`); ``None`` under a rule that
    compares the scores or their mean over a window."""
    return compared_name(text) if rule_window(text)[0] == 1 else None


def _logged_statistics(text: str, episodes: Sequence[tuple[EpisodeLog, RunLog]]) -> dict[tuple[Path, int], np.ndarray]:
    """Under a sequential rule (``text``, a log's ``rule`` in words), the statistic each step
    message of ``episodes`` holds (format 9, :func:`~oodmon.replay.reader.read_compared`; one
    pass over each log), by (log path, episode), of the episodes whose every step holds it; ``{}``
    under any other rule."""
    if _statistic_name(text) is None:
        return {}
    wanted: dict[Path, dict[int, int]] = defaultdict(dict)
    for episode, log in episodes:
        wanted[log.path][episode.episode] = episode.length
    found = {}
    for path, lengths in wanted.items():
        try:
            read = read_compared(path, list(lengths))
        except OSError:  # (a log gone since it was read: drawn as an older one's)
            continue
        found.update({(path, k): values for k, values in read.items() if len(values) == lengths[k]})
    return found


def _draw_with_rule(panels: Sequence[tuple[EpisodeLog, str]], sources: Sequence[RunLog], threshold: float, title: str,
                    path: str | Path, rule: tuple[int, int], text: str,
                    logged: Mapping[tuple[Path, int], np.ndarray] | None = None) -> Path:
    """:func:`_draw_traces` of ``panels`` (each episode's log in ``sources``) under the rule ``text``
    (a log's ``rule``, in words). A sequential rule compares a statistic of the scores with its
    threshold, on a scale of its own: the statistic each step message holds (format 9,
    :func:`~oodmon.replay.reader.read_compared`) is drawn on a right axis with the threshold, and
    where the logs are older neither is drawn, which the title says. ``logged``: the statistics
    :func:`_logged_statistics` read already."""
    name = _statistic_name(text)
    if name is None:
        return _draw_traces(panels, threshold, title, path, rule)
    if logged is None:
        logged = _logged_statistics(text, [(episode, log) for (episode, _), log in zip(panels, sources)])
    statistics = [logged.get((log.path, episode.episode)) for (episode, _), log in zip(panels, sources)]
    if all(statistic is not None for statistic in statistics):
        words = f"; the alarm compares the {name} statistic (right axis, as logged) with its threshold"
        return _draw_traces(panels, threshold, title + words, path, rule, statistics=(name, statistics))
    words = (f"; the alarm compares a {name} statistic of the scores with its threshold, {threshold:.4g}, on a scale "
             "of its own: not drawn here (the logs are older than format 9, whose steps hold it)")
    return _draw_traces(panels, float("nan"), title + words, path, rule)


def _compared(scores: np.ndarray, rule: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The steps at which a rule of (window, warm-up) compares a mean with the threshold, and those
    means (:func:`~oodmon.monitor.alarms.trailing_mean` of the scores after the warm-up); each step's
    own score where the window is 1 and there is no warm-up."""
    window, warmup = rule
    means = trailing_mean(scores[warmup:], window)
    return np.arange(warmup + window - 1, warmup + window - 1 + len(means)), means


def _draw_traces(panels: Sequence[tuple[EpisodeLog, str]], threshold: float, title: str, path: str | Path,
                 rule: tuple[int, int] = (1, 0), *,
                 statistics: tuple[str, Sequence[np.ndarray]] | None = None) -> Path:
    """Each episode's score over its steps in a panel of its own (titled), sharing the score axis:
    the threshold dashed, the shifted steps shaded, each alarm's start a vertical line, a NaN or
    infinite score marked at the panel's edge; a symlog axis where :func:`score_scale` says. With a
    ``rule``'s window (:func:`~oodmon.monitor.alarms.rule_window`) over 1 the score is drawn faint,
    and the mean over the window (after the rule's warm-up), which the alarm compares with the
    threshold, over it (the score alone crossed the threshold where no alarm came:
    Pong's features, 2026-12-07). ``statistics``: a sequential rule's name and its statistic at
    each step of each panel's episode, drawn on a right axis with the threshold, which is on its
    scale (not the score's)."""
    plt = _pyplot()
    on_score_axis = threshold if statistics is None else float("nan")
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.4), dpi=110, sharey=True, squeeze=False)
    axes = axes[0]
    for ax, (episode, name) in zip(axes, panels):
        steps = np.arange(episode.length)
        window = rule[0]
        ax.plot(steps, episode.scores, color="tab:red", linewidth=1, label="score", alpha=0.35 if window > 1 else 1.0)
        if window > 1:
            ax.plot(*_compared(episode.scores, rule), color="tab:red", linewidth=1.5,
                    label=f"mean over {window} steps (the alarm's)")
        for infinite, height, side in ((episode.scores == np.inf, 0.97, "top"),
                                       (episode.scores == -np.inf, 0.03, "bottom")):
            if infinite.any():  # (a NaN or infinite input: no line reaches them; replay keeps +inf, the most shifted)
                ax.scatter(steps[infinite], np.full(int(infinite.sum()), height), transform=ax.get_xaxis_transform(),
                           marker="^" if side == "top" else "v", s=12, color="tab:red", clip_on=False,
                           label=f"score {'+' if side == 'top' else '-'}inf (at the {side})")
        if np.isfinite(on_score_axis):
            ax.axhline(on_score_axis, color="black", linewidth=1, linestyle="--", label="threshold")
        if episode.shifted.any():
            ax.fill_between(steps, 0, 1, where=episode.shifted, transform=ax.get_xaxis_transform(),
                            color="tab:orange", alpha=0.15, label="shift active")
        for event in alarm_events(episode.alarm):
            ax.axvline(event, color="tab:purple", linewidth=1)
        # (a panel's axes are narrower than its share of the figure: 69 characters ran past their edges)
        ax.set_title("\n".join(textwrap.fill(line, 60) for line in name.split("\n")), fontsize=9)
        ax.set_xlabel("step")
    twins = []
    for ax, statistic in zip(axes, [] if statistics is None else statistics[1]):
        twin = ax.twinx()  # the statistic's own scale, the threshold's too
        twin.plot(np.arange(len(statistic)), statistic, color="tab:blue", linewidth=1.5,
                  label=f"{statistics[0]} (the alarm's; right axis)")
        if np.isfinite(threshold):
            twin.axhline(threshold, color="black", linewidth=1, linestyle="--", label="threshold (right axis)")
        twins.append(twin)
    if twins:  # one scale for every panel's statistic, as the scores share theirs
        top = max([threshold] + [float(np.nanmax(statistic, initial=0.0)) for statistic in statistics[1]])
        for twin in twins:
            twin.set_ylim(0 if statistics[0] == "CUSUM" else None, top * 1.05 if top > 0 else None)
        twins[-1].set_ylabel(f"{statistics[0]} statistic")
        twins[-1].legend(loc="lower right", fontsize=8)
    scale = score_scale([episode for episode, _ in panels], on_score_axis)
    if scale is not None:  # the axes share y: these calls set every panel's
        drawn = np.concatenate([episode.scores for episode, _ in panels] + [[on_score_axis]])
        drawn = drawn[np.isfinite(drawn)]
        low, high = float(drawn.min()), float(drawn.max())
        axes[0].set_yscale("symlog", linthresh=scale)
        axes[0].set_ylim(low * 2 if low < -scale else low - scale / 4, high * 2 if high > scale else high + scale / 4)
    # the score the alarm reads: the spread, an uncertainty, or a learned detector's (a surprise, a distance)
    axes[0].set_ylabel("alarm's score" if scale is None else "alarm's score (symlog)")
    axes[-1].legend(loc="upper left", fontsize=8)
    # (one panel's width holds about 70 characters: 75 ran past its edges by a letter, 2026-12-07)
    fig.suptitle(textwrap.fill(title, 70 * len(panels)), fontsize=9)
    return save_figure(fig, path)


# Shifted scores this many times the ID ones' size draw on a symlog axis (see score_scale).
WIDE_RANGE = 30.0


def score_scale(episodes: Sequence[EpisodeLog], threshold: float) -> float | None:
    """The linear range of a symlog score axis for these episodes, or ``None`` for a linear one.

    A learned detector's shifted scores can be thousands of times its ID ones (the demo's dynamics
    score: about -2 on ID steps and at the threshold, up to 27,000 after the pole's length doubles);
    on a linear axis the ID trace and the threshold are one flat line at zero. When the largest
    finite score exceeds ``WIDE_RANGE`` times the ID scale (the larger of the threshold's size and
    the 99th percentile of the unshifted steps' sizes), the axis is symlog, linear up to that scale
    rounded up to a power of ten.
    """
    unshifted = [episode.scores[~episode.shifted] for episode in episodes]
    every = np.concatenate([episode.scores for episode in episodes])
    every = np.abs(every[np.isfinite(every)])
    calm = np.concatenate(unshifted) if unshifted else np.empty(0)
    calm = np.abs(calm[np.isfinite(calm)])
    scale = max(abs(threshold) if np.isfinite(threshold) else 0.0, float(np.percentile(calm, 99)) if len(calm) else 0.0)
    if scale <= 0.0 or not len(every) or every.max() <= WIDE_RANGE * scale:
        return None
    return _decade(scale)


def _decade(scale: float) -> float:
    """``scale`` rounded up to a power of ten: a symlog axis' linear range, whose ticks then stay
    0 and powers of ten."""
    return float(10.0 ** np.ceil(np.log10(scale)))


def episode_name(episode) -> str:
    """A panel's title: the episode's variant, seed, onset (an ID episode has none) and return."""
    onset = "" if is_id_variant(episode.variant) else f", onset {episode.onset}"
    return f"{episode.variant}\nseed {episode.seed}{onset}, return {episode.total_return:.0f}"


def plot_auroc_vs_shift(metrics: Sequence[VariantMetrics], task: str, path: str | Path) -> Path | None:
    """AUROC against each parameter's value (log scale) or the severity, one line per method and
    detector (that of the metrics' rows). A physics parameter of oodmon's tasks gets its ID value
    as a dashed line in its title, and each line stops on either side of it: the values below it
    and those above are two shifts, not one curve through the ID world."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter

    series: dict[tuple[str, str], list[tuple[float, float]]] = defaultdict(list)
    id_values: dict[str, float] = {}
    for m in metrics:
        if m.task != task or m.auroc is None:
            continue
        try:
            variant = parse_any_variant(m.variant)  # oodmon's, or a shift of your own env
        except OodmonError:  # another env than the policy's (AnotherEnv): no value to draw it at
            continue
        if variant.corruption is not None and variant.severity is not None:
            series[(variant.corruption, f"{m.method}, {m.detector}")].append((variant.severity, m.auroc))
        elif len(changes := (*variant.params, *getattr(variant, "faults", ()))) == 1:  # a task's sensor fault too
            name, value = changes[0]
            series[(name, f"{m.method}, {m.detector}")].append((value, m.auroc))
            if name in PHYSICS_DEFAULTS.get(getattr(variant, "task", None), {}):
                id_values[name] = PHYSICS_DEFAULTS[variant.task][name]
    if not series:
        return None
    names = sorted({name for name, _ in series})
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 3.4), dpi=110, sharey=True, squeeze=False)
    for ax, name in zip(axes[0], names):
        id_value = id_values.get(name)
        values = [] if id_value is None else [id_value]  # what the axis spans
        for (parameter, label), points in sorted(series.items()):
            if parameter != name:
                continue
            points.sort()
            values += [value for value, _ in points]
            sides = [points] if id_value is None else [[p for p in points if p[0] <= id_value],
                                                       [p for p in points if p[0] > id_value]]
            color = None
            for side in (side for side in sides if side):  # an AUROC of 1 shows whole (clip_on)
                line, = ax.plot(*zip(*side), marker="o", markersize=3, clip_on=False, color=color,
                                label=label if color is None else "_" + label)
                color = line.get_color()
        if id_value is not None:
            ax.axvline(id_value, color="grey", linestyle="--", linewidth=1)
        if task != "pong" and all(value > 0 for value in values):  # a shift of your own env may set 0 or less
            ax.set_xscale("log")  # labelled at 1, 2 and 5 times a power of ten, as 50, not 5 x 10^1
            ticks = value_ticks(values)  # or at the values themselves, where they are few
            ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)) if ticks is None else FixedLocator(ticks))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
            ax.xaxis.set_minor_formatter(NullFormatter())
        title = name if id_value is None else f"{name} (ID {id_value:g}, dashed)"
        ax.set(title=title, xlabel="severity" if task == "pong" else "value", ylim=(0, 1))
        ax.axhline(0.5, color="grey", linestyle=":", linewidth=1)
    axes[0][0].set_ylabel("AUROC")
    axes[0][-1].legend(fontsize=8)
    return save_figure(fig, path)


def value_ticks(values: Sequence[float]) -> list[float] | None:
    """The values of a log axis to label, where they are few (2 to 6) and far enough apart on it
    to be read (an eighth of the axis' span at least): a shift to 3.0 from the ID 1.0 is labelled
    3, not left between the ticks at 2 and 5; ``None``: the axis' own ticks.

    Example:
        >>> value_ticks([1.0, 3.0]), value_ticks([0.05, 0.0556, 0.0625, 2.0]), value_ticks([4.0])
        ([1.0, 3.0], None, None)
    """
    distinct = sorted(set(values))
    if not 2 <= len(distinct) <= 6:
        return None
    logs = np.log10(distinct)
    return distinct if np.diff(logs).min() >= (logs[-1] - logs[0]) / 8 else None


def write_plots(logs: Sequence[RunLog], metrics: Sequence[VariantMetrics], folder: str | Path) -> list[Path]:
    """Every plot the logs allow, into ``folder``; returns the files written."""
    folder = Path(folder)
    written: list[Path | None] = []
    # each shifted variant's ROC: a curve per detector of the table's rows (every one the logs hold, or
    # replay's --detector), by method
    detectors: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for m in sorted(metrics, key=lambda m: m.detector):
        if m.auroc is not None and m.detector not in detectors[m.variant][m.method]:
            detectors[m.variant][m.method].append(m.detector)
    for variant in sorted(detectors):
        written.append(plot_roc(logs, variant, folder / f"roc_{safe_filename(variant)}.png", detectors[variant]))
        for method in sorted({log.method for log in logs}):
            name = f"trace_{safe_filename(method)}_{safe_filename(variant)}.png"
            written.append(plot_trace(logs, method, variant, folder / name))
    for task in sorted({m.task for m in metrics}):
        written.append(plot_auroc_vs_shift(metrics, task, folder / f"auroc_vs_shift_{safe_filename(task)}.png"))
    written += _id_alarm_plots(logs, folder)  # what the alarm made of the ID episodes: all a deployment's logs hold
    written += _where_plots(logs, folder)  # a camera's first alarms: where in the picture
    return [p for p in written if p is not None]


def _id_alarm_plots(logs: Sequence[RunLog], folder: Path) -> list[Path | None]:
    """:func:`plot_id_alarms` of each method and task the logs hold, as ``trace_<method>_<task>.png``."""
    return [plot_id_alarms(logs, method, task, folder / f"trace_{safe_filename(method)}_{safe_filename(task)}.png")
            for method, task in sorted({(log.method, log.task) for log in logs})]


#: Episodes drawn per variant by :func:`plot_alarm_timeline` (the first ones; its title says of how many).
TIMELINE_EPISODES = 60


def plot_alarm_timeline(variants: dict[str, Sequence[EpisodeAlarms]], title: str, path: str | Path, *,
                        failures: bool = True) -> Path | None:
    """The monitor's benchmark as a picture: a panel per shifted variant, a line per episode from
    its onset (x = 0) to its end, its first alarm at or after the onset (a dot: green before the
    failure or in an episode that did not fail, red at or after it), an alarm before the onset (an
    orange triangle, a false alarm) and the failure (a black cross). ``variants``: each variant's
    :class:`~oodmon.replay.metrics.EpisodeAlarms` (:func:`~oodmon.replay.metrics.shifted_alarms`);
    at most :data:`TIMELINE_EPISODES` of each are drawn. ``failures=False``: no failure is defined
    for the env (:func:`~oodmon.replay.failures.failure_known`), so the dots and the titles say nothing
    of one. ``None`` when there is no episode."""
    variants = {variant: list(episodes) for variant, episodes in variants.items() if episodes}
    if not variants:
        return None
    plt = _pyplot()
    heights = [1.0 + 0.05 * min(len(e), TIMELINE_EPISODES) for e in variants.values()]
    fig, axes = plt.subplots(len(variants), 1, figsize=(9, 0.6 + sum(heights)), dpi=110, squeeze=False,
                             sharex=True, gridspec_kw={"height_ratios": heights})
    styles = {"alarm before the failure": dict(marker="o", color="tab:green", s=14),
              "first alarm after the onset": dict(marker="o", color="tab:green", s=14),
              "alarm at or after the failure": dict(marker="o", color="tab:red", s=14),
              "alarm before the onset": dict(marker="<", color="tab:orange", s=16),
              "failure": dict(marker="x", color="black", s=16)}
    envs = {env_of_variant(variant) for variant in variants}
    env = envs.pop() if len(envs) == 1 else None  # named once, in the figure's title
    for ax, (variant, episodes) in zip(axes[:, 0], variants.items()):
        shown = episodes[:TIMELINE_EPISODES]
        rows = np.arange(len(shown))
        starts = [min(0, e.early or 0) for e in shown]
        ax.hlines(rows, starts, [e.end for e in shown], color="lightgrey", linewidth=1)
        points = {name: [] for name in styles}
        for row, e in zip(rows, shown):
            if e.first is not None:
                late = e.failure is not None and e.first >= e.failure
                points["alarm at or after the failure" if late else "alarm before the failure"].append((e.first, row))
            if e.early is not None:
                points["alarm before the onset"].append((e.early, row))
            if e.failure is not None:
                points["failure"].append((e.failure, row))
        if not failures:  # the same green dots, named for what they are
            points["first alarm after the onset"] = points.pop("alarm before the failure")
        for name, style in styles.items():
            if points.get(name):
                ax.scatter(*zip(*points[name]), label=name, zorder=3, **style)
        ax.axvline(0, color="black", linewidth=0.8, linestyle="--")
        failed = sum(e.failure is not None for e in episodes)
        alarmed = sum(e.first is not None for e in episodes)
        delays = [e.first for e in episodes if e.first is not None]
        leads = [e.lead for e in episodes if e.lead is not None]
        more = f" (the first {len(shown)} drawn)" if len(shown) < len(episodes) else ""
        told = ("" if not failures else "; none failed" if not failed else
                f"; {sum(e.before_failure for e in episodes)} of {failed} failures alarmed before them"
                + (f" (lead median {np.median(leads):g})" if leads else ""))
        ax.set_title(f"{variant.removeprefix(f'{env}:') if env else variant}: {alarmed} of {len(episodes)} episodes "
                     f"alarmed{more}{told}" + (f"; delay median {np.median(delays):g}" if delays else ""), fontsize=8)
        ax.set_yticks([])
        ax.set_ylim(-1, len(shown))
        ax.invert_yaxis()
    handles = {label: handle for ax in axes[:, 0] for handle, label in zip(*ax.get_legend_handles_labels())}
    axes[0, 0].legend(handles.values(), handles.keys(), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    axes[-1, 0].set_xlabel("steps since the shift's onset")
    fig.suptitle(title if env is None or title.startswith(env) else f"{env}: {title}", fontsize=9)
    return save_figure(fig, path)


def write_monitor_plots(logs: Sequence[RunLog], folder: str | Path, failure: str | None = None) -> list[Path]:
    """``replay --monitor --plots``: an alarm timeline per agent (task and method), and what the
    alarm made of its ID episodes (:func:`plot_id_alarms`, the false alarms), into ``folder``
    (``failure``: what fails in an env oodmon has no variants of)."""
    by_agent: dict[tuple[str, str], dict[str, list[EpisodeAlarms]]] = defaultdict(dict)
    for (task, method, variant), episodes in shifted_alarms(logs, failure).items():
        by_agent[(task, method)][variant] = episodes
    written = [plot_alarm_timeline(variants, f"{task}/{method}: the first alarm of each shifted episode",
                                   Path(folder) / f"alarms_{safe_filename(task)}_{safe_filename(method)}.png",
                                   failures=failure_known(task, failure))
               for (task, method), variants in sorted(by_agent.items())]
    written += _id_alarm_plots(logs, Path(folder))
    written += _where_plots(logs, Path(folder))
    return [p for p in written if p is not None]


def plot_log_statistics(statistics: LogStatistics, threshold: Threshold, path: str | Path) -> Path:
    """``oodmon recalibrate --plot``: each calibration episode's statistic under ``threshold``'s
    rule in the order they ended (:func:`~oodmon.replay.recalibrate.change_in_logs`), a line where
    another log's episodes follow, the threshold, the logged runs' own where they alarmed on the
    same detector, Pettitt's most likely change with each side's median (dashed where the test does not find it)
    and, shaded, a stretch where the highest crowd (:func:`~oodmon.replay.recalibrate.burst`).
    The bound asks for one world: points that rise or fall over the logs are two."""
    from oodmon.replay.recalibrate import CHANGE_LEVEL

    values, n = statistics.values, len(statistics.values)
    x = np.arange(n)
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.6), dpi=110)
    finite = np.isfinite(values)
    ax.scatter(x[finite], values[finite], s=10, color="tab:blue", label="an episode's statistic")
    if (~finite).any():  # an episode an alarm may have cut short (+inf), or one too short for the rule (-inf)
        ax.scatter(x[~finite], np.where(values[~finite] > 0, 0.97, 0.03), transform=ax.get_xaxis_transform(),
                   marker="^", s=14, color="tab:red", clip_on=False, label="+inf or -inf (cut short, or too short)")
    ax.axhline(threshold.value, color="black", linewidth=1, label=f"threshold {threshold.value:.4g}")
    earlier = {log.threshold for log, _ in statistics.episodes
               if log.has_threshold and log.detector == threshold.detector}
    for value in sorted(earlier):
        ax.axhline(value, color="grey", linewidth=1, linestyle=":", label=f"the runs' threshold {value:.4g}")
    starts = [i for i in range(1, n) if statistics.episodes[i][0] is not statistics.episodes[i - 1][0]]
    for i in starts:
        ax.axvline(i - 0.5, color="grey", linewidth=0.5, alpha=0.5)
    crowd = statistics.burst
    if crowd is not None and crowd.p_value < CHANGE_LEVEL / 2:
        ax.axvspan(crowd.first - 0.5, crowd.last + 0.5, color="tab:red", alpha=0.12, label=(
            f"{crowd.count} of the {crowd.size} highest crowd here (p = {crowd.p_value:.2g})"))
    change = statistics.change
    if change is not None:
        found = change.p_value < CHANGE_LEVEL / 2
        style = {"color": "tab:orange" if found else "tab:grey", "linewidth": 1.5 if found else 1,
                 "linestyle": "-" if found else "--"}
        for low, high, median in ((0, change.at, change.before), (change.at, n, change.after)):
            if math.isfinite(median):
                ax.hlines(median, low - 0.5, high - 0.5, **style)
        ax.axvline(change.at - 0.5, **style, label=(
            f"{'a change' if found else 'no change found'} (Pettitt p = {change.p_value:.2g}): each side's median"))
    ax.set_xlabel(f"calibration episode, in the order they ended ({len({id(log) for log, _ in statistics.episodes})} "
                  "log(s); grey lines: another log's episodes follow)")
    scale = _statistic_scale(values[finite])
    if scale is not None:
        ax.set_yscale("symlog", linthresh=scale)
        # (its own limits clipped the highest points at the top edge and reached down to -100 for
        # statistics all above 0: half a decade of room above, and 0 below where none is negative)
        shown = np.append(values[finite], threshold.value)
        high, low = float(shown.max()), float(shown.min())
        ax.set_ylim(min(0.0, 3 * low), 3 * high if high > 0 else high / 3 if high < 0 else scale)
    ax.set_ylabel(f"{threshold.detector} statistic" + (" (symlog)" if scale is not None else ""))
    ax.legend(loc="best", fontsize=7)
    ax.set_title(f"{threshold.task}/{threshold.method}: {n} ID episodes of the logs, alarm when {threshold.rule_text}",
                 fontsize=9)
    return save_figure(fig, path)


def _statistic_scale(values: np.ndarray) -> float | None:
    """A symlog axis' linear range for episode statistics of which some are far larger than a
    quarter of them (``WIDE_RANGE`` times their lower quartile's size: a world that changed among
    the logs, whose threshold is thousands of times the other world's statistics), ``None`` for a
    linear axis."""
    if not len(values):
        return None
    sizes = np.abs(values)
    scale = float(np.percentile(sizes, 25))
    if scale <= 0.0 or float(sizes.max()) <= WIDE_RANGE * scale:
        return None
    return _decade(scale)
