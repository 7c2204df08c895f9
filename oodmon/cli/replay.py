"""``oodmon replay`` (metrics from recorded logs) and ``oodmon check`` (regression check)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console

from oodmon.cli.display import _stretches_said, _table_console
from oodmon.cli.parsing import _FAILURES, _non_negative
from oodmon.errors import ConfigError
from oodmon.jsonfile import write_json


def _add_replay(commands: argparse._SubParsersAction) -> None:
    """`oodmon replay`."""
    replay = commands.add_parser("replay", help="metrics from recorded MCAP logs (files only; never modified)")
    replay.add_argument("logs", nargs="+", help="MCAP files, or folders holding them")
    formats = replay.add_mutually_exclusive_group()
    formats.add_argument("--json", action="store_true", help="print JSON (key auroc for the paper's metric)")
    formats.add_argument("--csv", action="store_true", help="print CSV")
    formats.add_argument("--markdown", action="store_true", help="print a Markdown table")
    replay.add_argument("--plots", metavar="DIR", type=_plots_folder,
                        help="also write PNG plots (ROC, traces, AUROC vs shift; with --monitor each agent's alarm "
                             "timeline) to DIR")
    replay.add_argument("--detector", help="the per-step metrics of this detector only (default: every detector "
                                           "the logs hold, one row each)")
    views = replay.add_mutually_exclusive_group()
    views.add_argument("--monitor", action="store_true",
                       help="the alarm's figures instead (the monitor's benchmark): false alarms with their interval, "
                            "alarms before failure, delays")
    views.add_argument("--episodes", action="store_true",
                       help="one row per episode instead: its steps, return, alarms, first alarm, delay, failure and "
                            "how it ended (interrupted ones too, which the metrics leave out)")
    replay.add_argument("--failure", choices=_FAILURES,
                        help="--monitor, --episodes: what fails in an env oodmon has no variants of (its failure "
                             "columns are blank without it): terminated, the env ended the episode itself after the "
                             "onset (a fall, a crash: Hopper's; not Acrobot's, whose end is its goal)")
    replay.set_defaults(handler=_replay, plays=False)  # logs only: no policy, torch not imported


#: Endings of a picture's name, which --plots (a folder) refuses.
_PICTURES = {".png", ".jpg", ".jpeg", ".svg", ".pdf"}


def _plots_folder(text: str) -> str:
    """--plots DIR, refused where it names a log: ``oodmon replay --plots a.mcap`` took the log for the
    folder and said only that no log was given; or a picture (``--plots plot.png`` made a folder of
    that name), unless a folder of that name is there."""
    if text.endswith(".mcap"):
        raise argparse.ArgumentTypeError(f"{text} is a log, not the folder the plots go to: give the folder after "
                                         "--plots, the logs before it (oodmon replay LOGS --plots DIR)")
    if Path(text).suffix.lower() in _PICTURES and not Path(text).is_dir():  # it made a folder of that name
        raise argparse.ArgumentTypeError(f"{text} names a picture; --plots takes the folder the pictures go to (one "
                                         "per variant and method), e.g. --plots runs/plots")
    return text


def _replay(args: argparse.Namespace) -> int:
    from oodmon.replay import compute_all_metrics, compute_metrics, to_csv, to_json, to_markdown, to_table

    if args.plots:
        from oodmon.outputs import check_output_dir

        check_output_dir(args.plots, parameter="--plots")
    logs = _read_logs(args.logs)
    if args.failure and not (args.monitor or args.episodes):
        raise ConfigError("--failure says what fails in your own env for the alarms' figures: give --monitor or "
                          "--episodes too")
    if args.monitor:
        return _replay_monitor(args, logs)
    if args.episodes:
        return _replay_episodes(args, logs)
    metrics = compute_all_metrics(logs) if args.detector is None else compute_metrics(logs, args.detector)
    if args.plots:
        from oodmon.replay.plots import write_plots

        written = write_plots(logs, metrics, args.plots)  # AUROC against the shift: a line per detector replayed
        why = "" if written else (": nothing to draw, the logs hold no shifted steps to rank against ID ones, and "
                                  "their runs had no threshold whose alarms a trace of their ID episodes would show")
        print(f"wrote {len(written)} plot(s) to {args.plots}{why}", file=sys.stderr)
    if args.json:
        print(to_json(metrics))
    elif args.csv:
        print(to_csv(metrics), end="")
    elif args.markdown:
        print(to_markdown(metrics), end="")
    else:
        steps = sum(e.length for log in logs for e in log.episodes)
        console = _table_console()
        console.print(to_table(metrics, title=f"replay of {len(logs)} log(s), {steps} steps", width=console.width))
    return 0


def _replay_episodes(args: argparse.Namespace, logs) -> int:
    """``replay --episodes``: one row per episode."""
    from oodmon.replay.report import episode_rows, episodes_csv, episodes_markdown, episodes_table

    if args.plots or args.detector:
        raise ConfigError("--episodes lists the episodes; --plots and --detector go with the metrics")
    rows = episode_rows(logs, failure=args.failure)
    if args.json:
        print(json.dumps(rows, indent=1))
    elif args.csv:
        print(episodes_csv(rows), end="")
    elif args.markdown:
        print(episodes_markdown(rows), end="")
    else:
        alarmed = sum(row["alarms"] > 0 for row in rows)
        console = _table_console()
        console.print(episodes_table(rows, title=f"{len(rows)} episode(s) of {len(logs)} log(s), {alarmed} alarmed",
                                     width=console.width))
    return 0


def _replay_monitor(args: argparse.Namespace, logs) -> int:
    """``replay --monitor``: the alarm's figures per variant (the monitor's benchmark)."""
    from oodmon.replay import compute_monitor_metrics, monitor_markdown, monitor_summary, monitor_table
    from oodmon.replay.failures import failure_definition

    if args.csv:
        raise ConfigError("--monitor prints a table, --json or --markdown; not --csv")
    if logs and not any(log.has_threshold for log in logs):
        raise ConfigError("--monitor counts the alarms, and these logs ran without a threshold, so raised none: "
                          "run with `oodmon run --threshold FILE` (from `oodmon calibrate`)")
    metrics = compute_monitor_metrics(logs, failure=args.failure)
    if args.plots:
        from oodmon.replay.plots import write_monitor_plots

        written = write_monitor_plots(logs, args.plots, failure=args.failure)
        print(f"wrote {len(written)} plot(s) to {args.plots}", file=sys.stderr)
    if args.json:
        print(json.dumps([m.to_dict() for m in [*metrics, *monitor_summary(metrics)]], indent=1))
    elif args.markdown:
        print(monitor_markdown(metrics), end="")
    else:
        console = _table_console()
        console.print(monitor_table(metrics, title=f"the alarms of {len(logs)} log(s)", width=console.width))
        print(failure_definition({m.task for m in metrics}, args.failure), file=sys.stderr)
    return 0


def _read_logs(paths: Sequence[str]):
    from oodmon.replay import (made_from_episodes, pooled_fits, pooled_noise, pooled_thresholds, pooled_weights,
                               read_logs)
    from oodmon.replay.metrics import ended_before_onset, id_stretches, longer_than_calibration, off_calibration_noise
    from oodmon.seeds import use_words

    logs = read_logs(paths)
    interrupted = sum(len(log.interrupted) for log in logs)
    if interrupted:
        print(f"oodmon: note: {interrupted} interrupted episode(s) (runs stopped inside them) are left out of the "
              "metrics", file=sys.stderr)
    for (task, method), by_weights in pooled_weights(logs).items():
        print(f"oodmon: note: the {task}/{method} rows pool the logs of {len(by_weights)} policies' weights "
              f"({_logs_by(by_weights)}): their AUROC ranks one policy's steps against another's; replay each "
              "policy's logs apart for its own", file=sys.stderr)
    for (task, method, name), by_fit in pooled_fits(logs).items():
        print(f"oodmon: note: the {task}/{method} {name} rows pool the logs of {len(by_fit)} fits of the {name} "
              f"detector ({_logs_by(by_fit)}): two fits' scores are on two scales; replay each fit's logs apart",
              file=sys.stderr)
    for (task, method), by_threshold in pooled_thresholds(logs).items():
        print(f"oodmon: note: the {task}/{method} logs raised their alarms by {len(by_threshold)} thresholds "
              f"({_logs_by(by_threshold, 60)}): each detector's row counts the alarms of its own runs, but "
              "`--monitor` counts a variant's alarms together; replay each threshold's logs apart", file=sys.stderr)
    for (task, method), by_noise in pooled_noise(logs).items():
        print(f"oodmon: note: the {task}/{method} rows pool episodes played at {len(by_noise)} sensor noises "
              f"({_logs_by(by_noise)}): a noisy sensor moves every detector's ID scores, so their AUROC ranks one "
              "world's steps against another's; replay each noise's logs apart", file=sys.stderr)
    for (task, method), by_world in off_calibration_noise(logs).items():
        print(f"oodmon: note: the {task}/{method} logs played episodes at another sensor noise than their threshold "
              f"was calibrated in ({_logs_by(by_world, 40)}): its false-alarm bound is for that world, and their false "
              "alarms say nothing of it (calibrate in the world played: `oodmon calibrate --obs-noise X`)",
              file=sys.stderr)
    longer = longer_than_calibration(logs)
    counted = id_stretches(logs, longer)
    for (task, method), by_length in longer.items():
        if (task, method) in counted:  # what the bound speaks of, counted as `validate --max-steps` counts it
            stretches, far = counted[(task, method)]
            said = (f"; counted by stretches of {stretches.length:,} steps (a calibration episode's on average), as "
                    f"`oodmon validate --max-steps` counts them: {_stretches_said(stretches, far)}")
        else:
            said = (", and their false alarms say nothing of it (`oodmon validate --max-steps N` counts them in runs N "
                    "steps long, by stretches as long as the calibration's)")
        print(f"oodmon: note: the {task}/{method} logs hold ID episodes longer than their threshold's longest "
              f"calibration episode ({_logs_by(by_length, 40)}): its false-alarm bound is for episodes like those"
              f"{said}", file=sys.stderr)
    for (task, method), by_use in made_from_episodes(logs).items():
        counts: dict[str, int] = {}  # (a threshold calibrated on logs has runs of seeds: "calibration 2", ...)
        for use, count in by_use.items():
            counts[use_words(use)] = counts.get(use_words(use), 0) + count
        uses = " and ".join(f"{count} of {words} episodes" for words, count in counts.items())
        print(f"oodmon: note: the {task}/{method} logs played {uses} in the ID env (the same reset seeds): they "
              "alarm less often than fresh episodes, so their false alarms read low; run fresh ones (`oodmon run "
              "--seed` apart from them)", file=sys.stderr)
    never = [episode for log in logs for episode in log.episodes if ended_before_onset(episode)]
    if never:
        print(f"oodmon: note: {len(never)} episode(s) of shifted variants ended before their onset (the first of "
              f"{never[0].variant}, {never[0].length} steps against an onset of {never[0].onset}): the shift never "
              "began in them: the detection rates and \"alarmed\" leave them out (an alarm in them counts as early)",
              file=sys.stderr)
    unthresholded = [str(log.path) for log in logs if not log.has_threshold]
    if unthresholded:
        print(f"oodmon: note: {len(unthresholded)} log(s) ran without a threshold (`oodmon run --threshold`), so "
              f"raised no alarms: {', '.join(unthresholded[:3])}{', ...' if len(unthresholded) > 3 else ''}; "
              "their variants have no alarm figures", file=sys.stderr)
    return logs


def _logs_by(groups: dict[str, list], width: int = 15) -> str:
    """Logs grouped by what they were made with, in a few words: each group's first log and how many
    more; what they were made with cut to ``width`` characters."""
    shown = [(made_with if len(made_with) <= width else f"{made_with[:width]}...") + f": {paths[0]}"
             + (f" and {len(paths) - 1} more" if len(paths) > 1 else "")
             for made_with, paths in list(groups.items())[:3]]
    return "; ".join(shown) + ("; ..." if len(groups) > 3 else "")


def _add_check(commands: argparse._SubParsersAction) -> None:
    """`oodmon check`."""
    check = commands.add_parser("check", help="regression check of recorded logs against a baseline")
    check.add_argument("logs", nargs="+", help="MCAP files, or folders holding them")
    check.add_argument("--baseline", required=True, help="the baseline JSON file")
    check.add_argument("--update", action="store_true", help="write the baseline from these logs instead")
    check.add_argument("--tolerance", type=_non_negative, help="allowed fall (default: the baseline's, else 0.02)")
    check.set_defaults(handler=_check, plays=False)


def _check(args: argparse.Namespace) -> int:

    from oodmon.outputs import check_output_file, replaced_file
    from oodmon.replay import baseline_of, compute_all_metrics, find_falls, load_baseline
    from oodmon.replay.check import noise_differences, noise_of_logs

    if args.update:
        check_output_file(args.baseline, parameter="--baseline", inputs=[("a log", log) for log in args.logs])
        replaced = replaced_file(args.baseline, parameter="--baseline", holds="baseline", read=load_baseline)
        baseline = None
    else:
        baseline = load_baseline(args.baseline)  # before the logs: a bad baseline fails at once
    logs = _read_logs(args.logs)
    metrics = compute_all_metrics(logs)
    partial = _torn_note(logs)
    console = Console(soft_wrap=True)
    if args.update:
        tolerance = 0.02 if args.tolerance is None else args.tolerance
        write_json(args.baseline, baseline_of(metrics, tolerance, noise_of_logs(logs)))
        console.print(f"wrote {args.baseline}: {len(metrics)} rows, tolerance {tolerance}{partial}"
                      + (f" (replacing the baseline it held: {len(replaced['metrics'])} rows)" if replaced else ""))
        return 0
    for line in noise_differences(noise_of_logs(logs), baseline):
        print(f"oodmon: note: {line}: a noisy sensor moves every detector's scores, so a fall there may be the "
              "world's, not the policy's or the code's", file=sys.stderr)
    within: list[str] = []
    falls = find_falls(metrics, baseline, args.tolerance, within=within)
    if baseline["metrics"] and not {m.key for m in metrics} & set(baseline["metrics"]):
        print(f"oodmon: note: none of {args.baseline}'s {len(baseline['metrics'])} rows is in these logs: theirs are "
              f"of {_agents_of(m.key for m in metrics)}, the baseline's of {_agents_of(baseline['metrics'])} (a "
              "baseline of other logs? `oodmon check LOGS --baseline FILE --update` writes one of these)",
              file=sys.stderr)
    for line in within:
        print(f"within chance: {line}", file=sys.stderr)
    if falls:
        for line in falls:
            print(f"FELL {line}", file=sys.stderr)
        print(f"oodmon check: {len(falls)} metric(s) fell below {args.baseline}{partial}", file=sys.stderr)
        return 1
    chance = f"; {len(within)} move(s) beyond the tolerance were within chance" if within else ""
    new = sum(m.key not in baseline["metrics"] for m in metrics)  # (until 2026-12-07 counted as "at or above")
    unmatched = f"; {new} row(s) of the logs the baseline lacks, compared with nothing (--update writes them in)" \
        if new else ""
    console.print(f"ok: {len(metrics) - new} rows at or above {args.baseline}{chance}{unmatched}{partial}")
    return 0


def _agents_of(keys) -> str:
    """The task/method of metric row keys (``CartPole-v1/sb3/CartPole-v1:length=2.0@combined``), each once."""
    return ", ".join(sorted({"/".join(key.split("/")[:2]) for key in keys})) or "none"


def _torn_note(logs) -> str:
    """`oodmon check`'s words for logs that were torn and read in part (each with its recovery
    warning) and for split logs that lack a part (each with its warning): a fall may come from the
    episodes they lost. Empty when every log was whole and every split log's parts were read."""
    from oodmon.replay import missing_parts

    notes = []
    torn = sum(not log.complete for log in logs)
    if torn:
        one = torn == 1
        notes.append(f"{torn} of the {len(logs)} logs {'was' if one else 'were'} torn and read in part, as the warning "
                     f"above says: {'its' if one else 'their'} rows lack the episodes lost")
    gaps = len(missing_parts(logs))
    if gaps:
        notes.append(f"{gaps} split log{' lacks' if gaps == 1 else 's lack'} a part, as the warning above says: "
                     "the rows lack its episodes")
    return f" ({'; '.join(notes)})" if notes else ""
