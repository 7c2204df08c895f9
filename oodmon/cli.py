"""The ``oodmon`` command: a thin layer over the library.

Errors a person can fix (:class:`oodmon.errors.OodmonError`, and files that cannot be written)
print as one line on stderr with exit code 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from rich.console import Console
from rich.table import Table

from oodmon.errors import ConfigError, InvalidParameterError, OodmonError
from oodmon.jsonfile import write_json
from oodmon.monitor.stopping import Terminated, stop_on_sigterm
from oodmon.names import MASKS, METHODS, TASKS
from oodmon.progress import unit_of
from oodmon.monitor.threshold import DETECTOR_NAMES
from oodmon.seeds import CALIBRATION, DETECTOR_FIT, VALIDATION

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI with ``argv`` (default: ``sys.argv[1:]``); return the exit code.

    Exit codes: 0 done, 1 a regression check found a fall, 2 input that cannot be used (one line
    on stderr), 130 interrupted (Ctrl-C; the logs keep every finished episode), 143 stopped by
    SIGTERM (a service manager's stop, ``kill``), which is taken as Ctrl-C is.
    """
    parser = _parser()
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        args, unknown = parser.parse_known_args(words)
        if unknown:  # said by the command's own parser, which knows the flags that were meant
            _unknown_arguments(_command_parser(parser, words), unknown)
    except SystemExit as exit:  # --help, --version, or a bad flag (one line, from _Parser.error)
        return exit.code if isinstance(exit.code, int) else 2
    if not hasattr(args, "handler"):
        parser.print_help()
        return 2
    args.argv = words  # what a result records as its command
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            _limit_torch_threads()
            with stop_on_sigterm():  # a service manager's stop ends a command as Ctrl-C does
                return args.handler(args) or 0
        except (OodmonError, OSError) as error:
            print(f"oodmon: error: {error}", file=sys.stderr)
            return 2
        except KeyboardInterrupt as interrupt:
            kept = getattr(args, "kept_on_interrupt", None)
            stopped = isinstance(interrupt, Terminated)
            print(("oodmon: stopped by SIGTERM" if stopped else "oodmon: interrupted") + (f"; {kept}" if kept else ""),
                  file=sys.stderr)
            return 143 if stopped else 130


#: What Ctrl-C leaves behind, said by the commands that write as they go or only at their end.
_LOGGED = "every finished episode is in the logs, the cut one is marked interrupted"
_KEPT = {
    "run": _LOGGED, "demo": _LOGGED,
    "train": "the last checkpoint is kept: the same command resumes from it",
    "bench": "trained models and finished cells are kept: the same command resumes from them",
    "calibrate": "no threshold file was written (it is written when the calibration ends): run the command again",
    "fit-detectors": "no detectors were written (they are written when the fitting ends): run the command again",
}


def _command_line(args: argparse.Namespace) -> str:
    """The command as typed (what a model or a bench result records of what made it)."""
    return "oodmon " + shlex.join(args.argv)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings in the terminal as one line each, without the source line Python would show."""
    print(f"oodmon: warning: {message}", file=sys.stderr)


class _Parser(argparse.ArgumentParser):
    """argparse, with a bad flag reported in one line (the usage is one ``--help`` away)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _command_parser(parser: argparse.ArgumentParser, words: Sequence[str]) -> argparse.ArgumentParser:
    """The parser of the (sub)command ``words`` name: ``oodmon run``'s for ``run --task ...``,
    ``oodmon envs show``'s for ``envs show ...``."""
    for word in words:
        commands = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        if commands is not None and word in commands.choices:
            parser = commands.choices[word]
        elif commands is None or not word.startswith("-"):
            break  # a command with no subcommands, or a word that names none: this parser read it
    return parser


def _unknown_arguments(parser: argparse.ArgumentParser, unknown: Sequence[str]) -> None:
    """Exit through ``parser.error``: the arguments it does not know, and for a mistyped flag the
    flag it has that is closest (``--rerun``: did you mean ``--rrd``?)."""
    import difflib

    flags = [flag for action in parser._actions for flag in action.option_strings if flag.startswith("--")]
    hints = []
    for word in unknown:
        name = word.split("=", 1)[0]
        close = difflib.get_close_matches(name, flags, n=1, cutoff=0.6) if name.startswith("--") else []
        hints += [(name, close[0])] if close else []
    message = f"unrecognized arguments: {' '.join(unknown)}"
    if len(hints) == 1 and sum(word.startswith("--") for word in unknown) == 1:  # no doubt which flag is meant
        message += f"; did you mean {hints[0][1]}?"
    elif hints:
        message += "; " + "; ".join(f"{name}: did you mean {close}?" for name, close in hints)
    parser.error(message)


def _widths(text: str) -> list[int]:
    """An argparse type: hidden widths, e.g. ``64,64`` (imported here: ``oodmon.agents`` loads torch,
    which ``oodmon --help`` need not wait for)."""
    from oodmon.agents.recipes import parse_widths

    return parse_widths(text)


def _whole(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse type: a whole number in [minimum, maximum]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum or (maximum is not None and value > maximum):
            allowed = f">= {minimum}" if maximum is None else f"from {minimum} to {maximum}"
            raise argparse.ArgumentTypeError(f"{value} is not allowed; give a whole number {allowed}")
        return value

    return parse


def _number(test: Callable[[float], bool], allowed: str) -> Callable[[str], float]:
    """An argparse type: a number for which ``test`` holds (``allowed`` says which, for the message)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not test(value):
            raise argparse.ArgumentTypeError(f"{text} is not allowed; give {allowed}")
        return value

    return parse


_fraction = _number(lambda x: 0.0 < x < 1.0, "a number between 0 and 1 (exclusive)")
_non_negative = _number(lambda x: 0.0 <= x < float("inf"), "a finite number >= 0")
_positive = _number(lambda x: 0.0 < x < float("inf"), "a finite number > 0")
_SEED = _whole(0, 2**32 - 1)


def _add_rule(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rule", choices=["consecutive", "cusum", "martingale"], default="consecutive",
                        help="the alarm rule: consecutive (default: --consecutive steps above the threshold), cusum or "
                             "martingale (sequential, on p-values against ID reference episodes' scores; see the README)")


def _confidence(text: str) -> float | None:
    """An argparse type: ``--confidence`` in (0, 1), or ``none`` (the rate bounded on average only)."""
    if text.strip().lower() == "none":
        return None
    return _fraction(text)


def _add_confidence(parser: argparse.ArgumentParser, default: str | None = None) -> None:
    from oodmon.monitor.threshold import DEFAULT_CONFIDENCE

    parser.add_argument("--confidence", type=_confidence, default=DEFAULT_CONFIDENCE if default is None else _UNSET,
                        metavar="1-d",
                        help=f"with this probability over the calibration episodes, the threshold's false-alarm rate "
                             f"is <= --far (default {default or DEFAULT_CONFIDENCE}; 45 episodes for --far 0.05 at "
                             "0.9); 'none': only on average over calibrations (19 episodes for --far 0.05)")


#: oodmon.monitor.detectors.DEFAULT_FIT_EPISODES, written out: importing it here would load the
#: detectors (scipy, gymnasium) before every command; a test keeps the two equal.
_FIT_EPISODES = 90

#: An option left at its default where the default depends on another option (bench's --protocol).
_UNSET = -1.0


def _limit_torch_threads() -> None:
    """Honour ``OODMON_TORCH_THREADS`` in every command (the monitor, calibration and bench as much
    as training), so that a job run beside a training keeps to its share of the cores."""
    from oodmon.threads import torch_threads

    threads = torch_threads()
    if threads is None:
        return
    import torch

    torch.set_num_threads(threads)


def _table_console() -> Console:
    """A console for tables: the terminal's width, or a wide one when output goes to a file or pipe
    (rich would otherwise cut columns to 80 characters)."""
    console = Console()
    return console if console.is_terminal else Console(width=220)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="oodmon",
        description="Tells when a deployed RL policy has left the world it was trained in.",
    )
    from oodmon import __version__

    parser.add_argument("--version", action="version", version=f"oodmon {__version__}")
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")

    _add_envs(commands)
    _add_train(commands)
    _add_evaluate(commands)
    _add_calibrate(commands)
    _add_validate(commands)
    _add_fit_detectors(commands)
    _add_run(commands)
    _add_replay(commands)
    _add_check(commands)
    _add_bench(commands)
    _add_demo(commands)
    return parser


def _add_envs(commands: argparse._SubParsersAction) -> None:
    """`oodmon envs`, with `envs show` and `envs tour`."""
    envs = commands.add_parser("envs", help="list the paper's OOD variants; 'envs show SPEC' pictures one")
    envs.add_argument("--task", choices=TASKS, help="only this task's variants")
    envs.add_argument("--json", action="store_true", help="print JSON instead of a table")
    envs.set_defaults(handler=_envs_list)
    envs_commands = envs.add_subparsers(title="envs commands", metavar="COMMAND")
    show = envs_commands.add_parser(
        "show",
        help="what a variant changes",
        description="Pong: the clean and the corrupted frame side by side. CartPole, Pendulum: a "
        "hand-written reference controller's returns in the ID env and the variant, and its pole "
        "angle over an episode.",
    )
    show.add_argument("spec", help="a variant spec, e.g. pong:pixelate@3 or cartpole:length=2.0")
    show.add_argument("--out", help="write the picture to this file (.png or .jpg; a name without a suffix gets .png)")
    show.add_argument("--seed", type=_SEED, default=0, help="seed of the episode shown (default 0)")
    show.add_argument("--onset", type=_whole(0), default=0, help="step at which the shift begins (physics; default 0)")
    show.set_defaults(handler=_envs_show)
    tour = envs_commands.add_parser("tour", help="what the envs change, shown with a hand-written controller")
    tour.add_argument("--out", default="runs/tour", help="folder for the pictures (default runs/tour)")
    tour.set_defaults(handler=_envs_tour)


def _add_train(commands: argparse._SubParsersAction) -> None:
    """`oodmon train`."""
    train = commands.add_parser(
        "train", help="train an uncertainty-aware agent from its recipe (resumes an interrupted run)"
    )
    train.add_argument("--task", required=True, choices=TASKS, help="the task whose recipe to train")
    train.add_argument("--method", required=True, choices=METHODS,
                       help="the uncertainty method (its recipe: oodmon/zoo/README.md)")
    train.add_argument("--seed", type=_SEED, default=0, help="the trial's seed (default 0)")
    train.add_argument("--out", required=True, help="training directory; the same command resumes it")
    train.add_argument("--steps", type=_whole(1), help="override the recipe's training steps per run")
    train.add_argument("--export-only", action="store_true",
                       help="do not train: export the best checkpoint so far of an unfinished training")
    train.add_argument("--unsafe-load-pickles", action="store_true",
                       help="resume from an older training's checkpoint.zip and replay_buffer.pkl; these are "
                            "pickles, and loading one runs the code it holds: only for files you made yourself")
    train.set_defaults(handler=_train, kept_on_interrupt=_KEPT["train"])


def _add_evaluate(commands: argparse._SubParsersAction) -> None:
    """`oodmon evaluate`."""
    evaluate = commands.add_parser(
        "evaluate", help="where an agent fails: mean return per variant beside the ID return"
    )
    evaluate.add_argument("--task", choices=TASKS, help="required unless --sb3")
    evaluate.add_argument("--method", choices=METHODS,
                          help="a shipped agent (or give --model)")
    evaluate.add_argument("--model", help="a trained model directory instead of a shipped agent")
    _sb3_arguments(evaluate)
    evaluate.add_argument("--variants", default="paper",
                          help="'paper' (the paper's grid) or comma-separated specs (default paper)")
    evaluate.add_argument("--episodes", type=_whole(1), default=5, help="episodes per variant (default 5)")
    evaluate.add_argument("--fail-fraction", type=_fraction, default=0.5,
                          help="fails below this fraction of the ID gain over a random policy (default 0.5)")
    evaluate.add_argument("--json", action="store_true", help="print JSON instead of a table")
    evaluate.set_defaults(handler=_evaluate)


def _add_calibrate(commands: argparse._SubParsersAction) -> None:
    """`oodmon calibrate`."""
    calibrate = commands.add_parser(
        "calibrate", help="calibrate an agent's alarm threshold on held-out in-distribution episodes"
    )
    _agent_arguments(calibrate)
    calibrate.add_argument("--episodes", type=_whole(1), default=50, help="ID calibration episodes (default 50)")
    calibrate.add_argument("--far", type=_fraction, default=0.05, help="target false-alarm rate (default 0.05)")
    _add_confidence(calibrate)
    calibrate.add_argument("--consecutive", type=_whole(1),
                           help="m of the alarm rule (default 3 for the spread detector, 1 for a learned one)")
    calibrate.add_argument("--window", type=_whole(1),
                           help="compare the mean score of the last N steps (default 1: each step's; Pong 200 "
                                "unless the frames detector)")
    _add_rule(calibrate)
    calibrate.add_argument("--reference-episodes", type=_whole(1), default=20,
                           help="ID episodes a sequential rule's p-values are taken against (default 20; seeds apart)")
    calibrate.add_argument("--reference-by-age", action="store_true",
                           help="take a sequential rule's p-values against ID steps as long since reset, not all of them")
    calibrate.add_argument("--mode", choices=["episode", "step"], default="episode",
                           help="guarantee per episode (default) or per step")
    calibrate.add_argument("--score", default="chosen_std",
                           help="the spread's score: chosen_std (default), mean_std, max_std, margin_std (DQN) or pre_squash_std (DDPG)")
    calibrate.add_argument("--detector", choices=list(DETECTOR_NAMES),
                           help="the detector the alarm reads (default: the task's best measured one when the agent has "
                                "fitted detectors: cartpole combined, pendulum dynamics, pong frames; else spread); "
                                "a learned one without fitted detectors is fitted first, into <out>.detectors/")
    calibrate.add_argument("--fit-episodes", type=_whole(3), default=_FIT_EPISODES,
                           help=f"ID episodes the learned detectors are fitted on when calibrate fits them (default "
                                f"{_FIT_EPISODES})")
    calibrate.add_argument("--seed", type=_SEED, default=CALIBRATION,
                           help=f"seed of the first calibration episode and of MC sampling (default {CALIBRATION})")
    calibrate.add_argument("--out", required=True, help="the threshold file to write (JSON)")
    calibrate.set_defaults(handler=_calibrate, kept_on_interrupt=_KEPT["calibrate"])


def _add_validate(commands: argparse._SubParsersAction) -> None:
    """`oodmon validate`."""
    validate = commands.add_parser(
        "validate", help="run fresh ID episodes and print a threshold's realised false-alarm rate beside its target"
    )
    validate.add_argument("threshold", help="the threshold file (`oodmon calibrate`)")
    _agent_arguments(validate, defaults_from="the threshold's")
    validate.add_argument("--episodes", type=_whole(1), default=200, help="fresh ID episodes (default 200)")
    validate.add_argument("--seed", type=_SEED, default=VALIDATION,
                          help=f"seed of the first episode and of MC sampling (default {VALIDATION}, apart from "
                               "calibration's)")
    validate.add_argument("--obs-noise", type=_non_negative, default=0.0,
                          help="sensor noise, a fraction of each dimension's ID spread (default 0)")
    validate.add_argument("--force", action="store_true", help="validate even if the threshold was made for other weights")
    validate.add_argument("--json", action="store_true", help="print JSON instead of a sentence")
    validate.set_defaults(handler=_validate)


def _add_fit_detectors(commands: argparse._SubParsersAction) -> None:
    """`oodmon fit-detectors`."""
    fit = commands.add_parser(
        "fit-detectors", help="fit the learned detectors (dynamics, features, combined) on an agent's ID episodes"
    )
    _agent_arguments(fit)
    fit.add_argument("--only", help="comma-separated detectors (default: all the agent can have but scaled_spread, "
                                    "which is fitted only when named)")
    fit.add_argument("--episodes", type=_whole(3), default=_FIT_EPISODES,
                     help=f"ID episodes: two thirds fit, one third ranks for combined (default {_FIT_EPISODES})")
    fit.add_argument("--max-steps", type=_whole(1), help="cut each episode after this many steps (Pong: try 300)")
    fit.add_argument("--score", default="chosen_std", help="the spread score combined uses (default chosen_std)")
    fit.add_argument("--obs-noise", type=_non_negative, default=0.0,
                     help="sensor noise of the ID env, a fraction of each dimension's ID spread (default 0)")
    fit.add_argument("--out", required=True, help="folder for detectors.json and detectors.safetensors")
    fit.set_defaults(handler=_fit_detectors, kept_on_interrupt=_KEPT["fit-detectors"])


def _add_run(commands: argparse._SubParsersAction) -> None:
    """`oodmon run`."""
    run = commands.add_parser("run", help="run a monitored agent in an env (ID or shifted), logging to MCAP/Rerun")
    _agent_arguments(run)
    run.add_argument("--variant", help="a variant spec (default: the task's ID env)")
    run.add_argument("--onset", type=_whole(0), default=0, help="step at which the shift begins (default 0)")
    run.add_argument("--episodes", type=_whole(1), default=5, help="episodes (default 5)")
    run.add_argument("--seed", type=_SEED, default=0, help="seed of the first episode (default 0)")
    run.add_argument("--threshold", help="a threshold file from `oodmon calibrate` (default: no alarms)")
    run.add_argument("--mcap", help="write the run to this MCAP file")
    run.add_argument("--mcap-split-episodes", type=_whole(1), metavar="N",
                     help="split the MCAP log into files of N whole episodes: <name>-00000.mcap, <name>-00001.mcap, ... "
                          "(a long run; `oodmon replay` reads them from their folder)")
    run.add_argument("--mcap-split-mb", type=_positive, metavar="MB",
                     help="start the next MCAP file after the episode that takes one to MB megabytes (as above)")
    run.add_argument("--rrd", help="write the run to this Rerun file")
    live = run.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true", help="stream to a Rerun viewer started for it")
    live.add_argument("--serve", action="store_true", help="serve the stream for a remote Rerun viewer")
    live.add_argument("--connect", metavar="URL", help="stream to a running Rerun viewer at URL")
    run.add_argument("--bind", default="127.0.0.1",
                     help="address --serve listens on (default 127.0.0.1: this machine only; 0.0.0.0 opens it)")
    run.add_argument("--port", type=_whole(1, 65535), default=9876, help="port --serve listens on (default 9876)")
    run.add_argument("--force", action="store_true",
                     help="use a threshold calibrated for another task, method, score or weights (with a warning)")
    run.add_argument("--strict", action="store_true", help="a failing sink stops the run instead of warning")
    run.add_argument("--render", action="store_true",
                     help="log a picture of each CartPole or Pendulum state beside the scores (Rerun, Foxglove)")
    run.set_defaults(handler=_run, kept_on_interrupt=_KEPT["run"])


def _add_replay(commands: argparse._SubParsersAction) -> None:
    """`oodmon replay`."""
    replay = commands.add_parser("replay", help="metrics from recorded MCAP logs (files only; never modified)")
    replay.add_argument("logs", nargs="+", help="MCAP files, or folders holding them")
    formats = replay.add_mutually_exclusive_group()
    formats.add_argument("--json", action="store_true", help="print JSON (key auroc for the paper's metric)")
    formats.add_argument("--csv", action="store_true", help="print CSV")
    formats.add_argument("--markdown", action="store_true", help="print a Markdown table")
    replay.add_argument("--plots", metavar="DIR", help="also write PNG plots (ROC, traces, AUROC vs shift; with --monitor "
                                                      "each agent's alarm timeline) to DIR")
    replay.add_argument("--detector", help="the per-step metrics of this detector only (default: every detector "
                                           "the logs hold, one row each)")
    views = replay.add_mutually_exclusive_group()
    views.add_argument("--monitor", action="store_true",
                       help="the alarm's figures instead (the monitor's benchmark): false alarms with their interval, "
                            "alarms before failure, delays")
    views.add_argument("--episodes", action="store_true",
                       help="one row per episode instead: its steps, return, alarms, first alarm, delay, failure and "
                            "how it ended (interrupted ones too, which the metrics leave out)")
    replay.set_defaults(handler=_replay)


def _add_check(commands: argparse._SubParsersAction) -> None:
    """`oodmon check`."""
    check = commands.add_parser("check", help="regression check of recorded logs against a baseline")
    check.add_argument("logs", nargs="+", help="MCAP files, or folders holding them")
    check.add_argument("--baseline", required=True, help="the baseline JSON file")
    check.add_argument("--update", action="store_true", help="write the baseline from these logs instead")
    check.add_argument("--tolerance", type=_non_negative, help="allowed fall (default: the baseline's, else 0.02)")
    check.set_defaults(handler=_check)


def _add_bench(commands: argparse._SubParsersAction) -> None:
    """`oodmon bench`."""
    bench = commands.add_parser("bench", help="the paper's protocol: trials x methods x failing variants, scored by replay")
    bench.add_argument("--task", choices=TASKS, help="required unless --sb3")
    bench.add_argument("--methods", default="dropout,dropconnect,ensemble", help="comma-separated (default all three)")
    _sb3_arguments(bench)
    bench.add_argument("--trials", type=_whole(1),
                       help="trials per method (default 5; trial 0 is the zoo agent; --sb3: 1, nothing is trained)")
    bench.add_argument("--samples", type=_whole(2), metavar="K",
                       help="MC samples per decision of the Dropout and DropConnect agents (default: each recipe's, "
                            "20); the decisions are their mean, so episodes change too, and a decision costs more "
                            "(CartPole DropConnect: 0.3 ms at K=20, 9 ms at K=400)")
    bench.add_argument("--masks", choices=MASKS,
                       help="MC masks of the Dropout and DropConnect agents, and of one --sb3 model with dropout "
                            "(default: each model's, sampled): fixed draws K masks once, so that sample k is the same "
                            "sub-network at every decision (the decisions stay the mean of freshly sampled masks); "
                            "fixed-decisions: the same K fixed sub-networks decide too, by their mean (one pass)")
    bench.add_argument("--members", type=_whole(2), metavar="K",
                       help="members of each ensemble trial (default: the recipe's, 5); another size trains every "
                            "trial, trial 0 too (member k has the same seed at any size: members trained before are "
                            "kept), and a decision costs K members' forward passes")
    bench.add_argument("--net-arch", type=_widths, metavar="W,W",
                       help="hidden widths of every trial's network, e.g. 64,64 (default: each recipe's, CartPole "
                            "[256, 256], Pendulum [400, 300]); other widths train every trial, trial 0 too")
    bench.add_argument("--variants", default="paper", help="'paper' (the paper's grid) or comma-separated specs")
    bench.add_argument("--protocol", choices=["paper", "monitor"], default="paper",
                       help="paper (default): shifted from step 0, per-step AUROC; monitor: the monitor's own benchmark, "
                            "each shifted episode shifts at a random onset, alarms before failure and delays, "
                            "the false-alarm rate over many ID episodes, the task's best detector")
    bench.add_argument("--episodes", type=_whole(1), help="episodes per failing variant (default 5; monitor: 10)")
    bench.add_argument("--all-variants", action="store_true",
                       help="monitor every variant, not only those the agent fails on (Pong's corruptions: an alarm "
                            "is wanted whether or not the return drops)")
    bench.add_argument("--id-episodes", type=_whole(1), help="ID episodes per trial (default 10; monitor: 200)")
    bench.add_argument("--calibration-episodes", type=_whole(1),
                       help="ID episodes the threshold is calibrated on (default 45; monitor protocol: 90)")
    bench.add_argument("--far", type=_fraction, default=0.05, help="the alarm's target false-alarm rate (default 0.05)")
    _add_confidence(bench, default="0.9; monitor protocol: 0.99, so that the rate of 200 ID episodes shows the bound")
    bench.add_argument("--workers", type=_whole(0), default=0, help="worker processes for the cells (default: all cores)")
    bench.add_argument("--score", default="chosen_std",
                       help="chosen_std (the paper's, default), mean_std, max_std, margin_std (DQN) or pre_squash_std (DDPG)")
    bench.add_argument("--window", type=_whole(1),
                       help="alarm rule on the mean score of the last N steps (default 1; Pong 200 unless the frames "
                            "detector); AUROCs do not change")
    bench.add_argument("--detectors",
                       help="comma-separated detectors whose per-step AUROC is reported: spread (the paper's protocol's "
                            "default), dynamics, features, frames, combined, scaled_spread (ensembles, MC agents with --masks "
                            "fixed); the learned "
                            "ones are fitted per trial on ID episodes of their own (monitor protocol's default: spread "
                            "and the task's best)")
    bench.add_argument("--fit-episodes", type=_whole(3), default=0,
                       help=f"ID episodes the learned detectors are fitted on, per trial (default {_FIT_EPISODES}; "
                            "Pong 6 games)")
    bench.add_argument("--alarm-detector", choices=list(DETECTOR_NAMES),
                       help="the detector the monitor's alarm reads, one of --detectors (default spread; monitor "
                            "protocol: the task's best)")
    _add_rule(bench)
    bench.add_argument("--consecutive", type=_whole(1),
                       help="m of the alarm rule (default 3 for the spread detector, 1 for a learned one)")
    bench.add_argument("--obs-noise", type=_non_negative, default=0.0,
                       help="sensor noise in every monitored env, a fraction of each dimension's ID spread (default 0)")
    bench.add_argument("--executor", choices=["local", "ray"], default="local",
                       help="local worker processes (default) or Ray tasks (needs oodmon[ray])")
    bench.add_argument("--address", help="the Ray cluster to use (default: start a local one)")
    bench.add_argument("--bind", default="127.0.0.1",
                       help="address a local Ray cluster listens on (default 127.0.0.1: this machine only)")
    bench.add_argument("--out", default="runs/bench", help="models, logs and report (default runs/bench)")
    bench.add_argument("--json", action="store_true", help="print JSON instead of tables")
    bench.add_argument("--results", metavar="FILE",
                       help="also write the result as JSON to FILE (per trial AUROC, AUPR, FPR@95TPR, the alarms, the "
                            "settings and this command): results as data, what --baseline reads")
    bench.add_argument("--baseline", metavar="FILE",
                       help="a result --results wrote earlier: exit 1, naming each figure, where this run falls below it")
    bench.add_argument("--tolerance", type=_non_negative,
                       help="--baseline's allowed fall of AUROC, AUPR and rates, and relative rise of delays (default 0.02)")
    bench.set_defaults(handler=_bench, kept_on_interrupt=_KEPT["bench"])


def _add_demo(commands: argparse._SubParsersAction) -> None:
    """`oodmon demo`."""
    demo = commands.add_parser("demo", help="the main job of 'make demo': calibrate, monitor, log, summarise")
    demo.add_argument("--out", default="runs/demo", help="folder for the demo's files (default runs/demo)")
    demo.set_defaults(handler=_demo, kept_on_interrupt=_KEPT["demo"])


def _envs_list(args: argparse.Namespace) -> int:
    from oodmon.envs.grid import grid_rows

    rows = grid_rows([args.task] if args.task else TASKS)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    table = Table(title=f"The paper's OOD variants ({len(rows)})")
    for column in ("task", "spec", "parameter", "value", "default"):
        table.add_column(column)
    for row in rows:
        table.add_row(*(("" if row[k] is None else str(row[k])) for k in ("task", "spec", "parameter", "value", "default")))
    _table_console().print(table)
    return 0


def _envs_show(args: argparse.Namespace) -> int:
    from oodmon.envs import parse_variant
    from oodmon.envs.preview import compare_physics, pong_preview, save_physics_plot, save_rgb

    variant = parse_variant(args.spec)
    out = None
    if args.out:
        from oodmon.outputs import check_picture_file

        out = check_picture_file(args.out, parameter="--out")  # "shot" is written as shot.png
    console = Console(soft_wrap=True)
    if variant.task == "pong":
        image = pong_preview(variant, seed=args.seed)
        console.print(f"{variant.spec}: {variant.kwargs()}")
        if out:
            console.print(f"wrote {save_rgb(image, out)} (clean left, corrupted right)")
        return 0
    comparison = compare_physics(variant, seeds=range(args.seed, args.seed + 5), onset_step=args.onset)
    console.print(
        f"{variant.spec} (onset {args.onset}): reference controller's mean return over 5 seeds "
        f"{comparison.shifted_return:.1f}, against {comparison.id_return:.1f} in the ID env"
    )
    if out:
        console.print(f"wrote {save_physics_plot(comparison, out)}")
    return 0


@contextmanager
def _progress(*, transient: bool = True) -> Iterator[Callable[..., None]]:
    """An ``on_progress(stage, done, total, note=None)`` for long work (see :mod:`oodmon.progress`;
    ``note``: a latest figure to show beside the stage): rich bars on a terminal; where stderr is a
    file (a job under nohup), where a bar would only appear at the end, a dated line per stage at
    most once a minute, at its start and at its end, with a rate in the stage's unit."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    stderr = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    with Progress(*columns, console=stderr, transient=transient) as progress:
        bars: dict[str, int] = {}
        last_line: dict[str, tuple[float, int]] = {}  # name -> (time, done) of its last plain line

        notes: dict[str, str] = {}  # name -> its latest note (training: the last evaluation return)

        def report(name: str, done: int, total: int, note: str | None = None) -> None:
            total = total or None  # 0: not known in advance
            if name not in bars:
                bars[name] = progress.add_task(name, total=total)
            if note is not None:
                notes[name] = note
                progress.update(bars[name], description=f"{name} ({note})")
            progress.update(bars[name], completed=done, total=total)
            if stderr.is_terminal:
                return
            now = time.monotonic()
            then, before = last_line.get(name, (None, done))
            finished = total is not None and done >= total and before < total
            if then is None or now - then >= 60 or finished:
                rate = (done - before) / (now - then) if then is not None and now > then else 0.0
                counted = unit_of(name)
                speed = f"{rate:.1f} {counted}/s" if rate >= 1 or rate == 0 else f"{rate * 60:.1f} {counted}/min"
                left = (total - done) / rate if rate > 0 and total is not None and total > done else None
                eta = "" if left is None else f", about {left / 60:.0f} min left" if left >= 90 else f", about {left:.0f} s left"
                noted = f", {notes[name]}" if name in notes else ""
                of = "" if total is None else f"/{total}"
                print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {name}: {done}{of} {counted}, {speed}{eta}{noted}",
                      file=sys.stderr, flush=True)
                last_line[name] = (now, done)

        yield report


def _train(args: argparse.Namespace) -> int:
    from oodmon.agents.recipes import recipe_for
    from oodmon.agents.training import train
    from oodmon.outputs import check_output_dir

    check_output_dir(args.out, parameter="--out")
    with _progress(transient=False) as report:
        label = f"{args.task}/{args.method}"
        total = args.steps or recipe_for(args.task, args.method).total_steps

        def evaluated(run: str, steps: int, mean: float) -> None:
            report(f"{label} {run} training steps", steps, total, f"last evaluation return {mean:.1f} at step {steps}")

        agent = train(args.task, args.method, args.out, seed=args.seed, total_steps=args.steps,
                      on_progress=lambda stage, done, of: report(f"{label} {stage}", done, of),
                      on_evaluation=evaluated,
                      export_only=args.export_only, load_pickles=args.unsafe_load_pickles,
                      command=_command_line(args))
    meta = agent.metadata
    Console(soft_wrap=True).print(
        f"{args.task}/{args.method}: id_return_mean {meta['id_return_mean']} over {meta['id_episodes']} episodes; "
        f"{sum(meta['training_steps'])} steps in {meta['wall_time_s']} s; saved to {args.out}"
    )
    return 0


def _agent_arguments(parser: argparse.ArgumentParser, *, defaults_from: str | None = None) -> None:
    """--task, --method, --model, --detectors; with ``defaults_from`` (a threshold file), the task and
    method default to what it was calibrated for, and the detectors to those fitted beside it."""
    if defaults_from is None:
        parser.add_argument("--task", choices=TASKS,
                            help="a shipped agent's task (required unless --sb3)")
    else:
        parser.add_argument("--task", choices=TASKS, help=f"default: {defaults_from} task")
    parser.add_argument("--method", choices=METHODS,
                        help="a shipped agent (or give --model)" if defaults_from is None
                        else f"a shipped agent (default: {defaults_from} method, unless --model)")
    parser.add_argument("--model", help="a trained model directory instead of a shipped agent")
    parser.add_argument("--masks", choices=MASKS,
                        help="the masks of an MC agent, or of one --sb3 model with dropout: sampled anew at every "
                             "decision, or fixed: K masks drawn once, so that the spread is that of K fixed "
                             "sub-networks (the decision is still the mean of sampled masks); fixed-decisions: the "
                             "fixed sub-networks decide too, by their mean, in the same pass. Default: the threshold "
                             "file's, if it records them, else the model's (sampled)")
    _sb3_arguments(parser)
    parser.add_argument("--detectors", metavar="DIR",
                        help="fitted detectors from `oodmon fit-detectors` (default: those `calibrate` fitted beside "
                             "the threshold file, else those shipped with the agent, if any)")


def _sb3_arguments(parser: argparse.ArgumentParser) -> None:
    """--sb3, --env, --mean: your own stable-baselines3 models instead of an oodmon agent."""
    parser.add_argument("--sb3", nargs="+", metavar="ZIP",
                        help="your own stable-baselines3 model file(s) (DQN, DDPG, TD3, SAC, PPO, A2C), with --env; the "
                             "first is the deployed policy, several DQN or DDPG/TD3 models also form an ensemble detector. "
                             "SB3's loader unpickles: give only files you trust")
    parser.add_argument("--env", metavar="ID", help="the gymnasium env id the --sb3 models act in, e.g. CartPole-v1")
    parser.add_argument("--mean", action="store_true",
                        help="with several --sb3 models: deploy the ensemble's mean decision, not the first model's")
    parser.add_argument("--vec-normalize", metavar="PKL",
                        help="--sb3 models trained inside SB3's VecNormalize: the statistics file it saved "
                             "(vec_normalize.save(), e.g. vecnormalize.pkl; read without running code from it), so that they see "
                             "observations normalised as in training; 'none' if it did not normalise observations")
    parser.add_argument("--frame-stack", type=int, metavar="N",
                        help="--sb3 models trained inside SB3's VecFrameStack(N): their observations (and the detectors' "
                             "and the logs') are the env's stacked N deep as VecFrameStack stacks them")


def _calibrate(args: argparse.Namespace) -> int:
    from oodmon.monitor import calibrate_agent
    from oodmon.monitor.detectors import BEST_DETECTOR, DEFAULT_FIT_EPISODES, detectors_for, fit_agent_detectors
    from oodmon.monitor.threshold import conformal_rank
    from oodmon.outputs import check_output_dir, check_output_file

    check_output_file(args.out, parameter="--out", inputs=[("--model", args.model and f"{args.model}/model.json")])
    if args.mode == "episode":
        conformal_rank(args.episodes, args.far, args.confidence)  # too few episodes: said before any runs
    agent = _load_agent(args, seed=args.seed)  # the same --seed, the same threshold, for MC agents too
    detectors = detectors_for(agent, args.detectors)
    fitted_to = None
    # A learned detector asked for, or a model from elsewhere (a plain policy has no spread; an SB3
    # ensemble's spread is weak): fit them first, on episodes of their own. So too for a combined
    # detector asked for with another spread score than the fitted one ranks.
    # scaled_spread is fitted only when asked for, alone (with the spread).
    left_out = detectors.for_score(args.score)[1] if detectors is not None else None
    scaled = args.detector == "scaled_spread"
    if (detectors is None and (args.detector not in (None, "spread") or agent.estimator is None or agent.env_id)
            or (args.detector == "combined" and left_out) or (scaled and "scaled_spread" not in (detectors or ()))):
        fitted_to = Path(f"{args.out}.detectors")
        check_output_dir(fitted_to, parameter="--out (its detectors folder)")
        with _progress() as report:
            detectors = fit_agent_detectors(agent, detectors=("scaled_spread",) if scaled else None, score=args.score,
                                            episodes=args.fit_episodes, on_progress=report)
        detectors.save(fitted_to)
    with _progress() as report:
        threshold = calibrate_agent(agent, args.episodes, args.far, consecutive=args.consecutive, mode=args.mode,
                                    window=args.window, score=args.score, seed=args.seed, detectors=detectors,
                                    detector=args.detector, confidence=args.confidence, rule=args.rule,
                                    reference_episodes=args.reference_episodes, reference_by_age=args.reference_by_age,
                                    on_progress=report)
    threshold.save(args.out)
    Console(soft_wrap=True).print(
        f"{args.task}/{agent.method}: alarm when {threshold.rule_text} ({threshold.detector} detector, {threshold.mode} "
        f"mode, {threshold.n_episodes} ID episodes, {threshold.n_steps} steps, rank {threshold.rank} of "
        f"{threshold.n_episodes if threshold.mode == 'episode' else threshold.n_steps}; ID score median "
        f"{threshold.quantiles['q50']:.4g}, max {threshold.quantiles['max']:.4g}); {threshold.promise}; wrote {args.out}"
        + (f"; fitted the detectors into {fitted_to} (`oodmon run` finds them there)"
           if fitted_to else "")
    )
    best = BEST_DETECTOR.get(args.task)
    if best is not None and args.detector is None and threshold.detector != best:
        Console(stderr=True, soft_wrap=True).print(
            f"note: the {best} detector separates {args.task}'s shifts better than {threshold.detector}; "
            f"`--detector {best}` fits it first (about {DEFAULT_FIT_EPISODES} more ID episodes)"
            + (f"; the fitted one is left out: {left_out}" if left_out and best == "combined" else ""))
    return 0


def _fit_detectors(args: argparse.Namespace) -> int:
    from oodmon.monitor.detectors import fit_agent_detectors
    from oodmon.outputs import check_output_dir

    check_output_dir(args.out, parameter="--out")
    agent = _load_agent(args, seed=DETECTOR_FIT)  # seeded MC sampling: the same command fits the same detectors
    only = args.only.split(",") if args.only else None
    with _progress() as report:
        detectors = fit_agent_detectors(agent, detectors=only, episodes=args.episodes, score=args.score,
                                        obs_noise=args.obs_noise, max_steps=args.max_steps, on_progress=report)
    detectors.save(args.out)
    Console(soft_wrap=True).print(f"{args.task}/{agent.method}: fitted {', '.join(detectors.names)} on "
                                  f"{args.episodes} ID episodes; wrote {args.out}")
    return 0


def _run(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from oodmon.monitor import McapSink, Monitor, Threshold
    from oodmon.monitor.sinks.rerun import RerunSink
    from oodmon.outputs import check_output_file

    inputs = [("--threshold", args.threshold), ("--model", args.model and f"{args.model}/model.safetensors"),
              ("--model", args.model and f"{args.model}/model.json"), *[("--sb3", path) for path in args.sb3 or ()]]
    if (args.mcap_split_episodes or args.mcap_split_mb) and not args.mcap:
        raise ConfigError("--mcap-split-episodes and --mcap-split-mb split an MCAP log: give --mcap too")
    mcap = McapSink(args.mcap, split_episodes=args.mcap_split_episodes, split_mb=args.mcap_split_mb) if args.mcap else None
    if mcap is not None:
        check_output_file(mcap.part_path(0), parameter="--mcap", inputs=inputs)
    if args.rrd:
        check_output_file(args.rrd, parameter="--rrd", inputs=[*inputs, ("--mcap", args.mcap)])
    threshold = Threshold.load(args.threshold) if args.threshold else None
    args.masks = args.masks or (threshold.masks if threshold is not None else None)
    agent = _load_agent(args)
    if args.render and args.task not in ("cartpole", "pendulum"):  # it logged no picture, without a word
        raise ConfigError(f"--render draws CartPole and Pendulum states; {args.task} has no drawing in oodmon"
                          + (" (Pong's frames are logged without it)" if args.task == "pong" else "")
                          + ": leave out --render")
    env, label = _run_env(args, agent)
    detectors = _detectors(args, agent)
    sinks = [] if mcap is None else [mcap]
    if args.rrd or args.spawn or args.serve or args.connect:
        sinks.append(RerunSink(path=args.rrd, spawn=args.spawn, serve=args.serve, connect=args.connect,
                               bind=args.bind, port=args.port))
    console = Console(soft_wrap=True)
    alarm_lines = []

    def show(event) -> None:
        alarm_lines.append(event)
        progress.console.print(f"[bold red]ALARM[/bold red] episode {event.episode} step {event.step}: "
                               f"score {event.score:.4g} > {event.threshold:.4g} ({event.rule})")

    rows = _EpisodeRows()
    with Progress(console=console, transient=True) as progress, \
            Monitor(agent, threshold, detectors=detectors, sinks=sinks, callbacks=[show], strict=args.strict,
                    force=args.force, render=args.render) as monitor:
        if args.serve:
            progress.console.print(f"serving the Rerun stream at {sinks[-1].served_at}")
        bar = progress.add_task(f"{label} (onset {args.onset})", total=args.episodes)
        decisions = progress.add_task("decisions in this episode", total=None)  # a Pong game is thousands

        def count(stage: str, steps: int, total: int) -> None:
            if steps % 50 == 0:
                progress.update(decisions, completed=steps)
        for episode in range(args.episodes):
            progress.reset(decisions, total=None, description=f"episode {episode}: decisions")
            rows.add(monitor.run_episode(env, seed=args.seed + episode, on_progress=count))
            progress.update(bar, advance=1)
    failures = dict(monitor.sinks.failures)  # after the sinks closed: a file that could not be finished counts
    env.close()
    files = {"McapSink": _files_written(mcap), "RerunSink": args.rrd}
    written = [str(p) for name, p in files.items() if p and name not in failures]
    console.print(rows.table(f"{args.task}/{agent.method} in {label}, onset {args.onset}"
                             + (f", {threshold.rule_text}" if threshold else ", no threshold")))
    if rows.left_out:
        console.print(f"{rows.left_out} episode{'s' if rows.left_out != 1 else ''} not shown"
                      + _listed_by(mcap, args.mcap, failed="McapSink" in failures))
    console.print(f"{rows.alarmed} of {rows.episodes} episodes raised an alarm"
                  + (f"; written to {', '.join(written)}" if written else ""))
    if failures:
        console.print(f"[yellow]sink failures: {failures}[/yellow]")
    return 0


def _listed_by(mcap, path: str | None, *, failed: bool) -> str:
    """What lists the episodes `oodmon run`'s closing table leaves out: `oodmon replay` of its log
    (the file, or a split log's folder), which lacks some if its sink failed; or, with no log, --mcap."""
    if mcap is None:
        return " (--mcap logs every one)"
    log = (mcap.paths[0].parent if mcap.splits else mcap.paths[0]) if mcap.paths else path
    if failed:
        return f": the MCAP log lacks some (its sink failed), `oodmon replay {log} --episodes` lists those it holds"
    return f": `oodmon replay {log} --episodes` lists every one"


def _run_env(args: argparse.Namespace, agent) -> tuple[object, str]:
    """``oodmon run``'s env and its label: the ``--variant`` (a variant of the agent's task, shifting
    at ``--onset``), else your own model's env as you deploy it, else the task's ID env."""
    from oodmon.envs import Variant, parse_variant
    from oodmon.envs.registration import TASK_OF_ENV

    if args.variant:
        variant = parse_variant(args.variant)
        if variant.task != args.task:
            raise ConfigError(f"variant {variant.spec!r} is not a {args.task} variant" if args.task in TASKS else
                              f"variant {variant.spec!r} is not a variant of {args.task}: oodmon has variants of "
                              f"{', '.join(sorted(TASK_OF_ENV))} only; leave out --variant to run {args.task} itself")
        return agent.wrap(variant.make(onset_step=args.onset)), variant.spec
    if agent.env_id is not None:  # your own model in its own env, as you deploy it
        return agent.make_env(), agent.env_id
    return Variant(args.task).make(onset_step=args.onset), args.task


class _EpisodeRows:
    """``oodmon run``'s closing table, in constant memory: the first and the last ``shown`` // 2
    episodes (their records without the per-step rewards), and how many ran and alarmed. A run of
    weeks keeps no per-step data here (the records with their rewards took about 20 bytes a step)
    and prints a table of at most ``shown`` rows; ``oodmon replay LOG --episodes`` lists them all."""

    def __init__(self, shown: int = 20) -> None:
        self.first: list = []
        self.last = deque(maxlen=shown - shown // 2)
        self.shown, self.episodes, self.alarmed = shown, 0, 0

    def add(self, record) -> None:
        self.episodes += 1
        self.alarmed += record.alarms > 0
        slim = dataclasses.replace(record, rewards=None)
        (self.first if len(self.first) < self.shown // 2 else self.last).append(slim)

    @property
    def left_out(self) -> int:
        """Episodes the table does not show."""
        return self.episodes - len(self.first) - len(self.last)

    def table(self, title: str) -> Table:
        """A row per episode kept, with its alarms and their delay, and a row "..." for those left out."""
        from oodmon.replay.metrics import is_id_variant

        left_out = self.left_out
        table = Table(title=title)
        for column in ("episode", "seed", "return", "length", "alarms", "first alarm", "delay"):
            table.add_column(column, justify="right")
        for index, record in enumerate([*self.first, *self.last]):
            if index == len(self.first) and left_out:
                table.add_row("...", *[""] * 6)
            if record.first_alarm_step is None or is_id_variant(record.variant):
                delay = ""
            else:
                delay = "before onset" if record.alarmed_early else str(record.delay)
            table.add_row(str(record.episode), str(record.seed), f"{record.total_return:.1f}", str(record.length),
                          str(record.alarms), "" if record.first_alarm_step is None else str(record.first_alarm_step),
                          delay)
        return table


def _files_written(mcap) -> str | None:
    """The closing line's words for what ``mcap`` (an McapSink, or ``None``) wrote: its file, the first
    and last of a split run's, or ``None`` where it wrote none (it could not open one)."""
    if mcap is None or not mcap.paths:
        return None
    paths = mcap.paths
    return str(paths[0]) if len(paths) == 1 else f"{paths[0]} ... {paths[-1].name} ({len(paths)} files)"


def _read_logs(paths: Sequence[str]):
    from oodmon.replay import read_logs

    logs = read_logs(paths)
    interrupted = sum(len(log.interrupted) for log in logs)
    if interrupted:
        print(f"oodmon: note: {interrupted} interrupted episode(s) (runs stopped inside them) are left out of the "
              "metrics", file=sys.stderr)
    unthresholded = [str(log.path) for log in logs if not log.has_threshold]
    if unthresholded:
        print(f"oodmon: note: {len(unthresholded)} log(s) ran without a threshold (`oodmon run --threshold`), so "
              f"raised no alarms: {', '.join(unthresholded[:3])}{', ...' if len(unthresholded) > 3 else ''}; "
              "their variants have no alarm figures", file=sys.stderr)
    return logs


def _replay(args: argparse.Namespace) -> int:
    from oodmon.replay import compute_all_metrics, compute_metrics, to_csv, to_json, to_markdown, to_table

    if args.plots:
        from oodmon.outputs import check_output_dir

        check_output_dir(args.plots, parameter="--plots")
    logs = _read_logs(args.logs)
    if args.monitor:
        return _replay_monitor(args, logs)
    if args.episodes:
        return _replay_episodes(args, logs)
    metrics = compute_all_metrics(logs) if args.detector is None else compute_metrics(logs, args.detector)
    if args.plots:
        from oodmon.replay.plots import write_plots

        written = write_plots(logs, metrics, args.plots)  # AUROC against the shift: a line per detector replayed
        print(f"wrote {len(written)} plot(s) to {args.plots}", file=sys.stderr)
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
    rows = episode_rows(logs)
    if args.json:
        print(json.dumps(rows, indent=1))
    elif args.csv:
        print(episodes_csv(rows), end="")
    elif args.markdown:
        print(episodes_markdown(rows), end="")
    else:
        alarmed = sum(row["alarms"] > 0 for row in rows)
        _table_console().print(episodes_table(rows, title=f"{len(rows)} episode(s) of {len(logs)} log(s), "
                                                          f"{alarmed} alarmed"))
    return 0


def _replay_monitor(args: argparse.Namespace, logs) -> int:
    """``replay --monitor``: the alarm's figures per variant (the monitor's benchmark)."""
    from oodmon.replay import compute_monitor_metrics, monitor_markdown, monitor_summary, monitor_table
    from oodmon.replay.metrics import FAILURE_DEFINITION

    if args.csv:
        raise ConfigError("--monitor prints a table, --json or --markdown; not --csv")
    if logs and not any(log.has_threshold for log in logs):
        raise ConfigError("--monitor counts the alarms, and these logs ran without a threshold, so raised none: "
                          "run with `oodmon run --threshold FILE` (from `oodmon calibrate`)")
    metrics = compute_monitor_metrics(logs)
    if args.plots:
        from oodmon.replay.plots import write_monitor_plots

        written = write_monitor_plots(logs, args.plots)
        print(f"wrote {len(written)} plot(s) to {args.plots}", file=sys.stderr)
    if args.json:
        print(json.dumps([m.to_dict() for m in [*metrics, *monitor_summary(metrics)]], indent=1))
    elif args.markdown:
        print(monitor_markdown(metrics), end="")
    else:
        _table_console().print(monitor_table(metrics, title=f"the alarms of {len(logs)} log(s)"))
        print(FAILURE_DEFINITION, file=sys.stderr)
    return 0


def _check(args: argparse.Namespace) -> int:

    from oodmon.outputs import check_output_file
    from oodmon.replay import baseline_of, compute_all_metrics, find_falls, load_baseline

    if args.update:
        check_output_file(args.baseline, parameter="--baseline", inputs=[("a log", log) for log in args.logs])
        baseline = None
    else:
        baseline = load_baseline(args.baseline)  # before the logs: a bad baseline fails at once
    logs = _read_logs(args.logs)
    metrics = compute_all_metrics(logs)
    partial = _torn_note(logs)
    console = Console(soft_wrap=True)
    if args.update:
        tolerance = 0.02 if args.tolerance is None else args.tolerance
        write_json(args.baseline, baseline_of(metrics, tolerance))
        console.print(f"wrote {args.baseline}: {len(metrics)} rows, tolerance {tolerance}{partial}")
        return 0
    falls = find_falls(metrics, baseline, args.tolerance)
    if falls:
        for line in falls:
            print(f"FELL {line}", file=sys.stderr)
        print(f"oodmon check: {len(falls)} metric(s) fell below {args.baseline}{partial}", file=sys.stderr)
        return 1
    console.print(f"ok: {len(metrics)} rows at or above {args.baseline}{partial}")
    return 0


def _torn_note(logs) -> str:
    """`oodmon check`'s words for logs that were torn and read in part (each with its recovery
    warning): a fall may come from the episodes they lost. Empty when every log was whole."""
    torn = sum(not log.complete for log in logs)
    if not torn:
        return ""
    one = torn == 1
    return (f" ({torn} of the {len(logs)} logs {'was' if one else 'were'} torn and read in part, as the warning above "
            f"says: {'its' if one else 'their'} rows lack the episodes lost)")


def _bench(args: argparse.Namespace) -> int:
    from oodmon.bench import BenchConfig, run_bench
    from oodmon.monitor.alarms import default_window
    from oodmon.monitor.detectors import BEST_DETECTOR
    from oodmon.errors import UnknownParameterError

    methods = tuple(m.strip() for m in args.methods.split(","))
    for method in methods:
        if method not in METHODS:
            raise UnknownParameterError(f"unknown method {method!r} in --methods; choose from {', '.join(METHODS)}")
    samples = True  # the agents have samples of their own to spread
    if args.sb3:
        samples = _sb3_bench_task(args)
        methods = ("sb3",)
    elif args.task is None:
        raise ConfigError("give --task (or --sb3 with --env for your own SB3 models)")
    variants = "paper" if args.variants == "paper" else tuple(args.variants.split(","))
    monitor = args.protocol == "monitor"
    best = BEST_DETECTOR[args.task] if monitor or not samples else "spread"
    alarm_detector = args.alarm_detector or best
    detectors = (tuple(d.strip() for d in args.detectors.split(",")) if args.detectors
                 else tuple(dict.fromkeys(("spread", alarm_detector) if samples else (alarm_detector,))))
    config = BenchConfig(args.task, methods, args.trials or (1 if args.sb3 else 5), variants,
                         args.episodes or (10 if monitor else 5), args.id_episodes or (200 if monitor else 10),
                         out=args.out, workers=args.workers,
                         executor=args.executor, address=args.address, bind=args.bind, score=args.score,
                         window=args.window or default_window(args.task, alarm_detector), detectors=detectors,
                         alarm_detector=alarm_detector, obs_noise=args.obs_noise,
                         calibration_episodes=args.calibration_episodes or (90 if monitor else 45), far=args.far,
                         confidence=(0.99 if monitor else 0.9) if args.confidence == _UNSET else args.confidence,
                         protocol=args.protocol, rule=args.rule, consecutive=args.consecutive,
                         all_variants=args.all_variants, sb3=tuple(args.sb3 or ()), env_id=args.env, mean=args.mean,
                         vec_normalize=args.vec_normalize, frame_stack=args.frame_stack,
                         samples=args.samples, members=args.members,
                         net_arch=args.net_arch, fit_episodes=args.fit_episodes,
                         masks=args.masks)
    config.variant_list()  # refuse bad specs before any work
    from oodmon.bench.baseline import BASELINE_TOLERANCE, bench_falls, check_same_settings, load_bench_result
    from oodmon.outputs import check_output_dir, check_output_file

    check_output_dir(args.out, parameter="--out")
    if args.tolerance is not None and not args.baseline:
        raise ConfigError("--tolerance is the allowed fall against --baseline FILE; give the baseline too")
    baseline = load_bench_result(args.baseline) if args.baseline else None  # a bad baseline fails before hours of work
    if baseline is not None:
        check_same_settings(config.what_made_the_numbers(), baseline, args.baseline)
    if args.results:
        check_output_file(args.results, parameter="--results", inputs=[("--baseline", args.baseline)])
    with _progress() as report:
        result = run_bench(config, on_progress=report)
    data = result.to_json(config, command=_command_line(args))
    if args.results:
        write_json(args.results, data)
        print(f"wrote {args.results}", file=sys.stderr)
    if args.json:
        print(json.dumps(data, indent=1))
    else:
        from oodmon.bench.report import print_monitor_report, print_paper_report

        (print_monitor_report if monitor else print_paper_report)(config, result, _table_console())
    if baseline is None:
        return 0
    tolerance = BASELINE_TOLERANCE if args.tolerance is None else args.tolerance
    falls = bench_falls(data, baseline, tolerance, baseline_name=args.baseline)
    for line in falls:
        print(f"FELL {line}", file=sys.stderr)
    if falls:
        print(f"oodmon bench: {len(falls)} figure(s) fell below {args.baseline}", file=sys.stderr)
        return 1
    print(f"oodmon bench: every figure of {args.baseline} held (tolerance {tolerance})", file=sys.stderr)
    return 0


def _no_variants(command: str, env_id: str) -> ConfigError:
    """The refusal of a command that plays oodmon's variants, for an --sb3 model of an env that has none."""
    return ConfigError(f"{command} plays oodmon's shifted variants of CartPole, Pendulum and Pong; --env {env_id} is "
                       f"none of them: monitor the model in it with `oodmon run --sb3 ... --env {env_id}` instead")


def _sb3_bench_task(args: argparse.Namespace) -> bool:
    """For ``bench --sb3``: set ``args.task`` from ``--env`` (the bench plays oodmon's variants of
    that task); True where the models have samples of their own (the spread detector applies)."""
    from oodmon.envs.registration import task_of_env

    task = task_of_env(args.env) if args.env else None
    if args.env and task is None:
        raise _no_variants("bench", args.env)
    return _load_agent(args).estimator is not None


def _detectors(args: argparse.Namespace, agent):
    """The fitted detectors: ``--detectors``, else those `calibrate` fitted beside the threshold
    file (``<threshold>.detectors/``), else the agent's own, else ``None``."""
    from oodmon.monitor.detectors import detectors_for

    beside = Path(f"{args.threshold}.detectors") if getattr(args, "threshold", None) else None
    if args.detectors is None and beside is not None and (beside / "detectors.json").is_file():
        return detectors_for(agent, beside)
    return detectors_for(agent, args.detectors)


def _validate(args: argparse.Namespace) -> int:
    from oodmon.monitor import Threshold, validate_threshold

    threshold = Threshold.load(args.threshold)
    args.task = args.task or threshold.task
    if args.task is None:
        raise ConfigError(f"{args.threshold} does not record its task; give --task")
    if args.model is None and not args.sb3:
        if threshold.method == "sb3" and args.method is None:  # no shipped agent of that name
            raise ConfigError(f"{args.threshold} was calibrated on your own SB3 model(s) in {threshold.task}: give them "
                              f"again, --sb3 ZIP --env {threshold.task} (with --vec-normalize and --frame-stack as "
                              "when calibrating)")
        args.method = args.method or threshold.method
    args.masks = args.masks or threshold.masks
    agent = _load_agent(args, seed=args.seed)  # the same --seed, the same count, for MC agents too
    detectors = _detectors(args, agent)
    with _progress() as report:
        result = validate_threshold(agent, threshold, args.episodes, seed=args.seed, detectors=detectors,
                                    obs_noise=args.obs_noise, force=args.force, on_progress=report)
    unit = "episodes" if threshold.mode == "episode" else "steps"
    if args.json:
        print(json.dumps({"threshold": str(args.threshold), "task": agent.task, "method": agent.method,
                          "detector": threshold.detector, "rule": threshold.rule_text, "unit": unit,
                          "alarmed": result.alarmed, "total": result.total, "rate": result.rate,
                          "interval95": [result.low, result.high], "far": result.far,
                          "confidence": result.confidence, "seed": args.seed, "verdict": result.verdict}, indent=1))
    else:
        verdict = {"above": "ABOVE the target: this threshold alarms too often",
                   "below": "below the target",
                   "consistent": "consistent with the target (the interval holds it)"}[result.verdict]
        Console(soft_wrap=True).print(
            f"{agent.task}/{agent.method}, {threshold.detector} detector, alarm when {threshold.rule_text}: "
            f"{result.alarmed} of {result.total} fresh ID {unit} alarmed, {result.rate:.1%} (95% interval "
            f"{result.low:.1%}-{result.high:.1%}); target {result.far:g}"
            + (f" with confidence {result.confidence:g}" if result.confidence is not None else " on average")
            + f": {verdict}")
    return 1 if result.verdict == "above" else 0


def _check_frame_stack(frame_stack: int | None) -> None:
    """``--frame-stack``, refused before any model is read unless 2 or more (or not given)."""
    if frame_stack is not None:
        from oodmon.agents.frame_stack import check_frame_stack

        check_frame_stack(frame_stack, parameter="--frame-stack ")


def _load_agent(args: argparse.Namespace, *, seed: int | None = None):
    """The agent of --sb3/--env, --model or --task/--method; ``seed`` seeds its MC sampling (None:
    fresh entropy). Sets ``args.task`` from --env for --sb3 models."""
    from oodmon.agents import load, load_agent

    if getattr(args, "sb3", None):  # commands without the --sb3 options (evaluate) have none
        from oodmon.agents.sb3 import load_sb3

        if not args.env:
            raise ConfigError("--sb3 needs --env: the gymnasium env id the models act in (e.g. CartPole-v1)")
        _check_frame_stack(args.frame_stack)
        if getattr(args, "model", None) or getattr(args, "method", None):
            raise ConfigError("--sb3 is instead of --model and --method: give one of them")
        agent = load_sb3(args.sb3, args.env, mean=args.mean, seed=seed, masks=getattr(args, "masks", None),
                         vec_normalize=args.vec_normalize, frame_stack=args.frame_stack)
        if args.task and args.task != agent.task:
            raise ConfigError(f"--task {args.task} contradicts --env {args.env} (task {agent.task})")
        args.task = agent.task
        return agent
    if getattr(args, "env", None) or getattr(args, "mean", False) or getattr(args, "vec_normalize", None) \
            or getattr(args, "frame_stack", None) is not None:
        raise ConfigError("--env, --mean, --frame-stack and --vec-normalize go with --sb3 (your own SB3 models)")
    if not args.task:
        raise ConfigError("give --task with --method or --model (or --sb3 with --env for your own SB3 models)")
    masks = getattr(args, "masks", None)
    if args.model:
        return load_agent(args.model, task=args.task, seed=seed, masks=masks)
    if not args.method:
        raise ConfigError("give --method for a shipped agent, or --model DIR for a trained one")
    return load(args.task, args.method, seed=seed, masks=masks)


def _evaluate(args: argparse.Namespace) -> int:
    from oodmon.agents import evaluate_variants

    if args.episodes < 1:
        raise InvalidParameterError(f"--episodes {args.episodes} is not allowed; give at least 1")
    agent = _load_agent(args)
    from oodmon.envs.grid import select_variants

    if args.task not in TASKS:  # --sb3 in an env oodmon has no variants of
        raise _no_variants("evaluate", args.env)
    variants = select_variants(args.task, args.variants)
    with _progress() as report:
        id_result, results = evaluate_variants(agent.act, args.task, variants, args.episodes,
                                               fail_fraction=args.fail_fraction, on_progress=report, wrap=agent.wrap)
    rows = [{"variant": r.spec, "return_mean": round(r.mean, 2), "return_std": round(float(r.returns.std()), 2),
             "fails": r.fails} for r in [id_result, *results]]
    if args.json:
        print(json.dumps({"task": args.task, "method": agent.method, "episodes": args.episodes,
                          "id_return_mean": rows[0]["return_mean"], "variants": rows[1:]}, indent=1))
        return 0
    table = Table(title=f"{args.task}/{agent.method}: mean return over {args.episodes} episodes "
                        f"(ID {id_result.mean:.1f}; fails below {args.fail_fraction:.0%} of the gain over random)")
    for column in ("variant", "return", "std", "fails"):
        table.add_column(column, justify="left" if column == "variant" else "right")
    for row in rows:
        style = "bold red" if row["fails"] else None
        table.add_row(row["variant"], f"{row['return_mean']:.1f}", f"{row['return_std']:.1f}",
                      "FAILS" if row["fails"] else "", style=style)
    _table_console().print(table)
    failing = [r.spec for r in results if r.fails]
    Console(soft_wrap=True).print(f"{len(failing)} of {len(results)} variants fail the agent: {', '.join(failing)}")
    return 0


def _envs_tour(args: argparse.Namespace) -> int:
    from oodmon.demo import run_env_tour

    from oodmon.outputs import check_output_dir

    check_output_dir(args.out, parameter="--out")
    run_env_tour(args.out)
    return 0


def _demo(args: argparse.Namespace) -> int:
    from oodmon.demo import run_demo

    from oodmon.outputs import check_output_dir

    check_output_dir(args.out, parameter="--out")
    run_demo(args.out)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
