"""Metrics as a terminal table, JSON, CSV or Markdown."""

from __future__ import annotations

import csv
import io
import json
import os
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence

from rich.table import Table
from rich.text import Text

from oodmon.envs.readings import reading_label
from oodmon.replay.failures import failure_step
from oodmon.replay.metrics import MonitorMetrics, VariantMetrics, env_of_variant, is_id_episode, monitor_row
from oodmon.replay.reader import RunLog

__all__ = ["COLUMNS", "EPISODE_COLUMNS", "episode_rows", "episodes_csv", "episodes_markdown", "episodes_table",
           "MONITOR_COLUMNS", "how_it_ended", "monitor_cells", "monitor_markdown", "monitor_summary", "monitor_table",
           "to_csv", "to_json", "to_markdown", "to_table"]

#: (field, heading) in the order the reports show them.
COLUMNS = [
    ("task", "task"), ("method", "method"), ("detector", "detector"), ("variant", "variant"), ("episodes", "episodes"),
    ("steps", "steps"),
    ("auroc", "AUROC"), ("aupr", "AUPR"), ("fpr_at_95_tpr", "FPR@95TPR"), ("false_alarm_rate", "false alarms (ID)"),
    ("early_alarm_rate", "early alarms"), ("detection_rate", "detected"), ("delay_mean", "delay mean"),
    ("delay_median", "delay median"),
]


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


#: Below this many columns the replay table switches to its narrow layout.
NARROW_WIDTH = 150
_SHORT_DETECTOR = {"spread": "spread", "dynamics": "dyn", "features": "feat", "combined": "comb"}


def _alarm_cell(m: VariantMetrics) -> str:
    """The alarm's figures in one narrow cell: ``FA 2%`` (ID), ``100% in 3`` (detected share, median delay)."""
    if m.false_alarm_rate is not None:
        return f"FA {m.false_alarm_rate:.0%}"
    if m.detection_rate is None:
        return ""
    delay = "" if m.delay_median is None else f" in {m.delay_median:g}"
    return f"{m.detection_rate:.0%}{delay}"


def _narrow_table(metrics: Sequence[VariantMetrics], title: str) -> Table:
    """The replay table for a terminal of about 80 columns: what every row shares goes into the
    title, the variant wraps instead of being cut, the alarm's figures share one column."""
    tasks, methods = sorted({m.task for m in metrics}), sorted({m.method for m in metrics})
    shared = [f"{'/'.join(tasks)}", f"{'/'.join(methods)}"] if len(methods) == 1 else ["/".join(tasks)]
    table = Table(title=f"{title}, {' '.join(shared)}", caption="alarm: FA = ID episodes with a false alarm; shifted: "
                        "share detected in median steps from the onset", pad_edge=False)
    table.add_column("variant" if len(methods) == 1 else "method variant", overflow="fold", ratio=1)
    for heading in ("det.", "AUROC", "AUPR", "FPR95", "alarm"):
        table.add_column(heading, justify="left" if heading == "det." else "right", no_wrap=True)
    for m in metrics:
        name = m.variant if len(methods) == 1 else f"{m.method} {m.variant}"
        table.add_row(name, _SHORT_DETECTOR.get(m.detector, m.detector), _cell(m.auroc), _cell(m.aupr),
                      _cell(m.fpr_at_95_tpr), _alarm_cell(m))
    return table


def to_table(metrics: Sequence[VariantMetrics], title: str = "replay", width: int | None = None) -> Table:
    """The replay table; a terminal ``width`` below :data:`NARROW_WIDTH` gets the narrow layout,
    readable at 80 columns."""
    if width is not None and width < NARROW_WIDTH:
        return _narrow_table(metrics, title)
    table = Table(title=title)
    for name, heading in COLUMNS:
        table.add_column(heading, justify="left" if name in ("task", "method", "detector", "variant") else "right")
    for m in metrics:
        table.add_row(*(_cell(getattr(m, name)) for name, _ in COLUMNS))
    return table


def to_json(metrics: Sequence[VariantMetrics]) -> str:
    """Replay's rows (one per task, method, detector and variant) as a JSON list of objects."""
    return json.dumps([m.to_dict() for m in metrics], indent=1)


def _csv(names: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    """CSV of a header of ``names`` and ``rows`` of values, ``None`` written empty."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(names)
    for row in rows:
        writer.writerow(["" if value is None else value for value in row])
    return buffer.getvalue()


def _markdown(headings: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table of ``headings`` and ``rows`` of cells."""
    lines = ["| " + " | ".join(headings) + " |", "|" + "---|" * len(headings)]
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return "\n".join(lines) + "\n"


def to_csv(metrics: Sequence[VariantMetrics]) -> str:
    """Replay's rows as CSV, a header of the column names first."""
    return _csv([name for name, _ in COLUMNS], ([getattr(m, name) for name, _ in COLUMNS] for m in metrics))


def to_markdown(metrics: Sequence[VariantMetrics]) -> str:
    """Replay's rows as a markdown table, headed as the terminal's."""
    return _markdown([h for _, h in COLUMNS], ([_cell(getattr(m, name)) for name, _ in COLUMNS] for m in metrics))


# -- the monitor's own benchmark ----------------------------------------------------------------

#: The heading of each column of the monitor's table.
MONITOR_COLUMNS = ["method", "variant", "episodes", "false alarms (ID) / early", "alarmed", "failed",
                   "alarmed before failure", "lead median", "delay median", "delay p90", "first alarms by"]


#: Below this many columns the monitor's table switches to its narrow layout (the wide one's ten
#: columns leave a variant's name a few characters there).
MONITOR_NARROW_WIDTH = 170

#: The variant of :func:`monitor_summary`'s rows: a (task, method)'s shifted variants pooled.
POOLED = "all shifted"


def _share(part: int | None, whole: int | None) -> str:
    if part is None or not whole:
        return ""
    return f"{part}/{whole} ({part / whole:.0%})"


def shared_starts(m: MonitorMetrics) -> int | None:
    """How many ID starts a pooled row's early alarms came from, where fewer than the alarms (None
    otherwise): the variants play the same seeds, so one start's false alarm before the onset is in
    every variant, and "16/160 early" may be one episode's alarm sixteen times.

    Example:
        >>> from oodmon.replay.metrics import monitor_row
        >>> row = lambda starts: monitor_row("pendulum", "dropout", POOLED, 160, 16, 0, 0, [1], early_starts=starts)
        >>> shared_starts(row(["500004@51"] * 16)), shared_starts(row([f"{k}@3" for k in range(16)]))
        (1, None)
    """
    starts = len(m.early_starts)
    return starts if 0 < starts < (m.early or 0) else None


def shared_starts_words(m: MonitorMetrics) -> str | None:
    """:func:`shared_starts` in words (``1 ID start``, ``2 ID starts``), or None."""
    starts = shared_starts(m)
    return None if starts is None else f"{starts} ID start{'s' if starts != 1 else ''}"


def _early_cell(m: MonitorMetrics, share: str) -> str:
    """The early alarms' cell (``share``: its count), a pooled row's ID starts after it where the
    variants repeat them: ``16/160 (10%), 1 ID start``."""
    words = shared_starts_words(m)
    return share if words is None else f"{share}, {words}"


def monitor_summary(metrics: Sequence[MonitorMetrics]) -> list[MonitorMetrics]:
    """Per (task, method), the shifted variants pooled into one row (variant ``all shifted``)."""
    pooled: dict[tuple[str, str], list[MonitorMetrics]] = {}
    for m in metrics:
        if not m.is_id:
            pooled.setdefault((m.task, m.method), []).append(m)
    def total(counts: list[int | None]) -> int | None:  # None: no failure defined for the task
        return None if None in counts else sum(counts)

    return [monitor_row(task, method, POOLED, sum(m.episodes for m in group), sum(m.early for m in group),
                        total([m.failed for m in group]), total([m.before_failure for m in group]),
                        [d for m in group for d in m.delays], [lead for m in group for lead in m.leads],
                        sum((Counter(m.causes) for m in group), Counter()), sum(m.never_shifted for m in group),
                        [start for m in group for start in m.early_starts],
                        sum((Counter(m.readings) for m in group), Counter()))
            for (task, method), group in sorted(pooled.items())]


def monitor_cells(m: MonitorMetrics, *, name_task: bool = False) -> list[str]:
    """One row of the monitor's table (:data:`MONITOR_COLUMNS`); ``name_task``: a pooled row says
    its task (``all shifted (pendulum)``), for a table of several tasks' runs."""
    delay = (lambda v: "" if v is None else f"{v:g}")
    if m.is_id:
        first = f"{_share(m.false_alarms, m.episodes)} [{m.far_low:.1%}, {m.far_high:.1%}]"
        return [m.method, m.variant, str(m.episodes), first, "", _share(m.failed, m.episodes), "", "", "", "", ""]
    variant = f"{m.variant} ({m.task})" if name_task and m.variant == POOLED else m.variant
    return [m.method, variant, str(m.episodes), _early_cell(m, _share(m.early, m.episodes)),
            _share(m.alarmed, m.shifted_episodes), _share(m.failed, m.episodes), _share(m.before_failure, m.failed),
            delay(m.lead_median), delay(m.delay_median), delay(m.delay_p90), causes_cell(m.causes, m.readings)]


def causes_cell(causes: Mapping[str, int], readings: Mapping[str, int] | None = None) -> str:
    """``stillness 9, frames 1``: how many first alarms each cause raised, the most frequent first;
    then, where some named one, how many named each reading first (:attr:`MonitorMetrics.readings`).

    Example:
        >>> causes_cell({"dynamics": 8, "features": 2}), causes_cell({})
        ('dynamics 8, features 2', '')
        >>> causes_cell({"dynamics": 9}, {"[2] (pole angle)": 8, "[3] (pole angular velocity)": 1})
        'dynamics 9; reading [2] (pole angle) 8, [3] (pole angular velocity) 1'
    """
    said = ", ".join(f"{cause} {count}" for cause, count in causes.items())
    if readings:
        said += "; reading " + ", ".join(f"{reading} {count}" for reading, count in readings.items())
    return said


def _monitor_rows(metrics: Sequence[MonitorMetrics]) -> list[tuple[bool, list[str]]]:
    """Each row of the monitor's table, the pooled ones last: whether it is pooled, and its cells
    (a pooled row names its task when the table holds several tasks' runs)."""
    several = len({m.task for m in metrics}) > 1
    return [(m.variant == POOLED, monitor_cells(m, name_task=several)) for m in [*metrics, *monitor_summary(metrics)]]


def _narrow_monitor_table(metrics: Sequence[MonitorMetrics], title: str) -> Table:
    """The monitor's table for a terminal of about 80 columns: the task (one) and method (one) go
    into the title and out of the variants' names, the variant wraps instead of being cut, counts
    without their percentages, the false-alarm rate's interval in the caption, and what raised the
    first alarms (the wide table's last column) on a line under the variant."""
    rows = [*metrics, *monitor_summary(metrics)]
    tasks, methods = sorted({m.task for m in rows}), sorted({m.method for m in rows})
    shared = [*tasks[:len(tasks) == 1], *methods[:len(methods) == 1]]
    intervals = [f"{m.method + ' ' if len(methods) > 1 else ''}{m.far_low:.1%}-{m.far_high:.1%}" for m in rows if m.is_id]
    table = Table(title=", ".join([title, *shared]), pad_edge=False, caption=(
        "FA: ID episodes alarmed" + (f" (95% interval {', '.join(intervals)})" if intervals else "")
        + "; early: alarmed before the onset"
        + (", (n): from n ID starts the variants share" if any(map(shared_starts, rows)) else "")
        + "; before: failing episodes alarmed before the failure (-: none "
        "failed); lead: median steps from that alarm to the failure; delay: median/p90 steps from the onset; "
        "by: what raised the first alarms after the onset (and the reading each named first)"))
    table.add_column("variant" if len(methods) == 1 else "method variant", overflow="fold", ratio=1)
    for heading in ("FA/early", "alarmed", "before", "lead", "delay"):
        table.add_column(heading, justify="right", no_wrap=True)

    def count(part: int | None, whole: int | None) -> str:
        return "" if part is None or whole is None else "-" if not whole else f"{part}/{whole}"

    for m in rows:
        name = m.variant.removeprefix(f"{m.task}:") if len(tasks) == 1 else m.variant
        name = name if len(methods) == 1 else f"{m.method} {name}"
        if m.is_id:
            table.add_row(name, count(m.false_alarms, m.episodes), "", "", "", "")
            continue
        if m.causes:  # what raised the first alarms, on a line of its own under the variant
            name = Text(name).append(f"\nby {causes_cell(m.causes, m.readings)}", style="dim")
        starts = shared_starts(m)
        early = count(m.early, m.episodes) + ("" if starts is None else f" ({starts})")
        table.add_row(name, early, count(m.alarmed, m.shifted_episodes), count(m.before_failure, m.failed),
                      "" if m.lead_median is None else f"{m.lead_median:g}",
                      "" if m.delay_median is None else f"{m.delay_median:g}/{m.delay_p90:g}",
                      style="bold" if m.variant == POOLED else None)
    return table


def monitor_table(metrics: Sequence[MonitorMetrics], title: str = "the monitor's benchmark",
                  width: int | None = None) -> Table:
    """The monitor's figures per variant, then each method's shifted variants pooled; a terminal
    ``width`` below :data:`MONITOR_NARROW_WIDTH` gets the narrow layout, readable at 80 columns."""
    if width is not None and width < MONITOR_NARROW_WIDTH:
        return _narrow_monitor_table(metrics, title)
    table = Table(title=title)
    for heading in MONITOR_COLUMNS:  # a long variant or list of causes wraps rather than being cut
        table.add_column(heading, justify="left" if heading in ("method", "variant") else "right",
                         overflow="fold" if heading in ("variant", "first alarms by") else "ellipsis")
    for pooled, cells in _monitor_rows(metrics):
        table.add_row(*cells, style="bold" if pooled else None)
    return table


def monitor_markdown(metrics: Sequence[MonitorMetrics]) -> str:
    """The monitor's benchmark rows (``replay --monitor``) as a markdown table."""
    return _markdown(MONITOR_COLUMNS, (cells for _, cells in _monitor_rows(metrics)))


# -- one row per episode ----------------------------------------------------------------------

#: (field, heading) of the per-episode listing (``oodmon replay --episodes``).
EPISODE_COLUMNS = [
    ("log", "log"), ("episode", "episode"), ("variant", "variant"), ("seed", "seed"), ("onset", "onset"),
    ("length", "steps"), ("return", "return"), ("alarms", "alarms"), ("first_alarm_step", "first alarm"),
    ("delay", "delay"), ("first_alarm_cause", "cause"), ("failure_step", "failed at"), ("ended", "ended"),
    ("obs_noise", "noise"),  # after the others: the CSV's columns before format 8 keep their places
    ("first_alarm_readings", "readings"),  # (format 10) after those of format 8
    ("first_alarm_region", "where"),  # (format 12) after those of format 10
]


def readings_cell(readings: Sequence[tuple[int, float]], steps: int = 1, names: Sequence[str] = ()) -> str | None:
    """The readings an alarm named (:attr:`~oodmon.monitor.alarms.AlarmEvent.readings`) in a
    table's cell, each with its name in ``names`` (by index) where there is one; ``None`` for none.

    Example:
        >>> readings_cell([(1, -263.2), (3, 209.4)]), readings_cell([(4, -4.75)], 20), readings_cell([])
        ('[1] -263, [3] +209 sd', '[4] -4.75 sd over 20 steps', None)
        >>> readings_cell([(2, -269.0)], names=["cart position", "cart velocity", "pole angle"])
        '[2] (pole angle) -269 sd'
    """
    if not readings:
        return None
    return ", ".join(f"{reading_label(index, names[index] if index < len(names) else '')} {residual:+.3g}"
                     for index, residual in readings) + " sd" + (f" over {steps} steps" if steps > 1 else "")


def how_it_ended(interrupted: bool, terminated: bool | None) -> str:
    """An episode's ending in a word: ``interrupted`` (the run stopped inside it), ``terminated``
    (the env ended it: a fall), ``time limit`` (or an alarm callback), ``""`` (not recorded)."""
    return ("interrupted" if interrupted else "terminated" if terminated
            else "time limit" if terminated is False else "")


def episode_rows(logs: Sequence[RunLog], failure: str | None = None) -> list[dict]:
    """One row per logged episode, in each log's order, the interrupted ones (a run stopped or torn
    inside them, left out of the metrics) among them: what each episode did and when it alarmed.

    ``onset``, ``delay`` (steps from the onset to the first alarm; negative: before the onset) and
    ``failure_step`` (:func:`~oodmon.replay.failures.failure_step`, ``failure`` what fails in an env
    oodmon has no variants of) are ``None`` for ID episodes;
    ``obs_noise`` is the env's sensor noise (0: none, or a log older than format 8);
    ``first_alarm_cause`` is what raised the first alarm's score (``None``: no alarm, or a log
    older than format 7); ``first_alarm_readings`` the readings it named (:func:`readings_cell`;
    ``None``: none named, or a log older than format 10) and ``first_alarm_region`` where in the
    picture (``rows 28-34, columns 21-34 of the 84x84 picture``, :class:`~oodmon.monitor.alarms.Region`;
    ``None``: none, or a log older than format 12); ``return`` is ``None`` where the log does
    not have it (an episode cut at a tear); ``ended``
    is ``terminated`` (the env ended it), ``time limit`` (or an alarm callback), ``interrupted``, or
    ``""`` (logs older than format 4).
    """
    rows = []
    for log in logs:
        for e in sorted([*log.episodes, *log.interrupted], key=lambda e: e.episode):
            shifted = not is_id_episode(e, log.task)
            ended = how_it_ended(e.interrupted, e.terminated)
            rows.append({
                "log": str(log.path), "episode": e.episode, "variant": e.variant, "obs_noise": e.obs_noise,
                "seed": e.seed,
                "onset": e.onset if shifted else None, "length": e.length,
                "return": None if e.total_return != e.total_return else e.total_return,  # NaN: not logged
                "alarms": e.alarms, "first_alarm_step": e.first_alarm_step,
                "delay": e.first_alarm_step - e.onset if shifted and e.first_alarm_step is not None else None,
                "first_alarm_cause": e.first_alarm_cause,
                "first_alarm_readings": readings_cell(e.first_alarm_readings, e.first_alarm_readings_steps,
                                                      log.reading_names_of(e)),
                "first_alarm_region": None if e.first_alarm_region is None else e.first_alarm_region.text(),
                "failure_step": failure_step(e, log.task, failure) if shifted and not e.interrupted else None,
                "ended": ended,
            })
    return rows


def _episode_cell(name: str, value: object) -> str:
    if value is None:
        return ""
    if name == "return":
        return f"{value:.1f}"
    if name == "obs_noise":
        return f"{value:g}"
    if name == "delay" and value < 0:
        return "before onset"  # as `oodmon run` says it; the JSON and CSV keep the number
    return str(value)


def _common_folder(paths: Sequence[str]) -> str:
    """The folder ``paths`` share (``""``: none, as for absolute and relative paths together)."""
    try:
        return os.path.commonpath([os.path.dirname(path) or "." for path in paths])
    except ValueError:
        return ""


#: Below this many columns the per-episode table switches to its narrow layout.
EPISODES_NARROW_WIDTH = 150
_ENDED_SHORT = {"terminated": "env", "time limit": "limit", "interrupted": "cut"}


def episodes_table(rows: Sequence[dict], title: str, width: int | None = None) -> Table:
    """:func:`episode_rows` as a terminal table. What every row shares goes into the title, so that
    each row shows the episode's own figures: the log (one log: its path; several: their folder,
    each row its path within it), the env (each variant without it, ``ID`` for the env itself) and
    the sensor noise (where the episodes were played at several: a column, or in the narrow layout
    each variant's cell).
    A terminal ``width`` below :data:`EPISODES_NARROW_WIDTH` gets the narrow layout, readable at 80
    columns: logs numbered (the numbers in the caption), the first alarm and its delay in one
    column, short headings and endings."""
    logs = list(dict.fromkeys(row["log"] for row in rows))
    folder = _common_folder(logs) if len(logs) > 1 else ""
    relative = {log: os.path.relpath(log, folder) if folder else log for log in logs}
    envs = {env_of_variant(row["variant"]) for row in rows}
    env = envs.pop() if len(envs) == 1 else None
    shared = logs[:1] if len(logs) == 1 else [f"in {folder}"] if folder not in ("", ".") else []
    noises = {row["obs_noise"] for row in rows}
    noise = [f"sensor noise {min(noises):g}"] if len(noises) == 1 and noises != {0.0} else []
    narrow = width is not None and width < EPISODES_NARROW_WIDTH
    named = {log: str(number) for number, log in enumerate(logs, 1)} if narrow and len(logs) > 1 else relative
    caption = None
    if narrow:
        caption = ("logs: " + "; ".join(f"{named[log]} {relative[log]}" for log in logs) + ". " if len(logs) > 1 else "")
        caption += "alarm: the first alarm's step (its delay from the onset); ended: env (terminated), limit, cut"
    table = Table(title=", ".join([title, *shared, *([env] if env else []), *noise]), caption=caption,
                  pad_edge=not narrow)
    if narrow:
        columns = [("log", "log"), ("episode", "ep"), ("variant", "variant"), ("seed", "seed"), ("onset", "onset"),
                   ("length", "steps"), ("return", "return"), ("alarm", "alarm"), ("failure_step", "failed"),
                   ("ended", "ended")]  # (several noises: each in its variant's cell, as no column fits)
    else:
        columns = list(EPISODE_COLUMNS)
    said = ("first_alarm_readings", "first_alarm_region")  # what the first alarm named: a column where any row has it
    filled = {name for name in said if any(row[name] for row in rows)}
    columns = [(name, heading) for name, heading in columns
               if (name != "log" or len(logs) > 1) and (name != "obs_noise" or len(noises) > 1)
               and (name not in said or name in filled)]
    for name, heading in columns:
        left = name in ("log", "variant", "ended", *said)
        table.add_column(heading, justify="left" if left else "right",
                         overflow="fold" if name in ("log", "variant", *said) else "ellipsis",
                         ratio=1 if narrow and name == "variant" else None, no_wrap=narrow and name != "variant")
    for row in rows:
        shown = dict(row, log=named[row["log"]])
        if env:
            shown["variant"] = "ID" if row["variant"] == env else row["variant"].removeprefix(f"{env}:")
        if narrow:
            if len(noises) > 1:
                shown["variant"] = f"{shown['variant']}, noise {row['obs_noise']:g}"
            delay = row["delay"]
            shown["alarm"] = (None if row["first_alarm_step"] is None else f"{row['first_alarm_step']}"
                              + ("" if delay is None else f" ({delay:+d})"))
            shown["ended"] = _ENDED_SHORT.get(row["ended"], row["ended"])
        table.add_row(*(_episode_cell(name, shown[name]) for name, _ in columns),
                      style="bold red" if row["alarms"] else None)
    return table


def episodes_csv(rows: Sequence[dict]) -> str:
    """One row per episode (``replay --episodes``) as CSV."""
    return _csv([name for name, _ in EPISODE_COLUMNS], ([row[name] for name, _ in EPISODE_COLUMNS] for row in rows))


def episodes_markdown(rows: Sequence[dict]) -> str:
    """One row per episode (``replay --episodes``) as a markdown table."""
    return _markdown([h for _, h in EPISODE_COLUMNS],
                     ([_episode_cell(name, row[name]) for name, _ in EPISODE_COLUMNS] for row in rows))
