"""The ``oodmon`` command: a thin layer over the library.

Errors a person can fix (:class:`oodmon.errors.OodmonError`, and files that cannot be written)
print as one line on stderr with exit code 2, never as a traceback.

One module per group of commands, each with its arguments (``_add_<command>``) beside what it
does: :mod:`~oodmon.cli.envs`, :mod:`~oodmon.cli.training` (train, evaluate),
:mod:`~oodmon.cli.calibration` (calibrate, validate, fit-detectors), :mod:`~oodmon.cli.run` (run,
demo), :mod:`~oodmon.cli.replay` (replay, check), :mod:`~oodmon.cli.bench`; beside them the
argument types and the options several commands share (:mod:`~oodmon.cli.parsing`), the agent and
detectors a command acts on (:mod:`~oodmon.cli.loading`), and progress lines and tables
(:mod:`~oodmon.cli.display`).
"""

from __future__ import annotations

import argparse
import re
import sys
import traceback
import warnings
from collections.abc import Sequence
from concurrent.futures.process import BrokenProcessPool

from oodmon.cli.bench import _add_bench
from oodmon.cli.calibration import _add_calibrate, _add_fit_detectors, _add_recalibrate, _add_validate
from oodmon.cli.display import OutputClosed
from oodmon.cli.envs import _add_envs
from oodmon.cli.parsing import _NOT_BEGUN, _command_parser, _Parser, _unknown_arguments
from oodmon.cli.replay import _add_check, _add_replay
from oodmon.cli.run import _add_demo, _add_run
from oodmon.cli.training import _add_evaluate, _add_train
from oodmon.errors import OodmonError
from oodmon.monitor.stopping import Terminated, stop_on_sigterm
from oodmon.threads import limit_threads

__all__ = ["main"]

#: What a command whose output closed says (``{}``: after a command began, that its later output was lost).
_OUTPUT_CLOSED = "oodmon: stopped: its output was closed (the reader of its pipe ended{})"


def _sb3_files(args: argparse.Namespace) -> None:
    """``--sb3 runs/dqn`` names ``runs/dqn.zip`` where only that is there, as SB3's own ``load``
    reads it (:func:`oodmon.agents.sb3.sb3_file`): so the checks of inputs against outputs, and
    what a run records, see the file."""
    given = getattr(args, "sb3", None)
    if given:
        from oodmon.agents.sb3 import sb3_file

        args.sb3 = str(sb3_file(given)) if isinstance(given, str) else [str(sb3_file(path)) for path in given]


def _plays_a_policy(args: argparse.Namespace) -> bool:
    """Whether the command may run a policy, and so torch: every command but those whose parser
    says ``plays=False`` (they read logs or show envs), or a function of the arguments (``envs show``
    plays one with ``--sb3`` or ``--policy``)."""
    plays = getattr(args, "plays", True)
    return bool(plays(args) if callable(plays) else plays)


def console() -> int:
    """The ``oodmon`` program (and ``python -m oodmon``): :func:`main`, then Python's exit with
    Ctrl-C ignored and SIGTERM ending it at once with the command's exit code. By then the
    command's work is done and its files written; Python's exit, torch's and multiprocessing's
    clean-up, takes about half a second, and a Ctrl-C in it stopped the clean-up it came in and
    printed that one's traceback ("Exception ignored in atexit callback", 2026-12-06, an interrupt
    fuzzing of the commands), the exit code still 0; a SIGTERM there ended the process by the
    signal (-15, found by the same fuzzing: a calibrate that had written its threshold). After the
    last clean-up both are ignored (``oodmon_console.hold_stops_at_exit``): Python's teardown of the
    modules, most of the exit, gives a handler of Python's its default action back first.

    A command that was stopped (130, 141, 143) with Ray loaded (``bench --executor ray``) leaves at
    once, without Python's exit: a stop as ``ray.init`` built Ray's core in this process let Ray
    abort in that exit (SIGABRT, -6, after the line saying what was kept: 5 of 5 such stops on
    2026-12-07; ``scripts/ray_start_stops.py``), where the command had shut Ray down and closed
    its files already."""
    import signal

    from oodmon.cli.display import StopsWhenOutputCloses

    if sys.stdout is not None:  # (None: started with no standard output, `oodmon ... >&-`; print then writes nothing)
        sys.stdout = StopsWhenOutputCloses(sys.stdout)
    code = main()
    if code in _STOPPED and "ray" in sys.modules:
        _leave_now(code)
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def done(signum, frame) -> None:  # (a service manager's stop: the clean-up is all that is left)
        _leave_now(code if isinstance(code, int) else 1)

    signal.signal(signal.SIGTERM, done)
    try:  # (here, not in Python's exit, where a closed pipe's error would be printed)
        if sys.stdout is not None:
            sys.stdout.flush()
    except OutputClosed:  # the command's work was done: its code stands
        pass
    return code


_STOPPED = (130, 141, 143)  # main's exit codes of a stopped command: Ctrl-C, its output closed, SIGTERM


def _leave_now(code: int) -> None:
    """End the process with ``code`` at once, what it printed flushed, no clean-up of Python's exit run."""
    import os

    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError, OutputClosed):  # a closed pipe: nothing more can reach it
            pass
    os._exit(code)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI with ``argv`` (default: ``sys.argv[1:]``); return the exit code.

    Exit codes: 0 done, 1 a regression check found a fall (or validate's interval above its target,
    or ``envs show`` of a shift that changed nothing), 2 input that cannot be used (one line
    on stderr), 3 an error oodmon cannot explain (its traceback, then what the command kept, as
    for Ctrl-C: an env's, a policy's or a callback's own error, or a bug; a worker process that
    died, out of memory or in an env's C code, is said in one line, the command's traceback would
    not find it), 130 interrupted
    (Ctrl-C; the logs keep every finished episode), 143 stopped by SIGTERM (a service manager's
    stop, ``kill``), which is taken as Ctrl-C is, 141 its output closed (``oodmon run | head``: the
    reader ended; taken as Ctrl-C is, in the ``oodmon`` program).
    """
    parser = _parser()
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        args, unknown = parser.parse_known_args(words)
        if unknown:  # said by the command's own parser, which knows the flags that were meant
            _unknown_arguments(_command_parser(parser, words), unknown)
    except SystemExit as exit:  # --help, --version, or a bad flag (one line, from _Parser.error)
        return exit.code if isinstance(exit.code, int) else 2
    except OutputClosed:  # (`oodmon run --help | true`: the help met a closed pipe; nothing began)
        print(_OUTPUT_CLOSED.format(""), file=sys.stderr)
        return 141
    if not hasattr(args, "handler"):
        try:
            parser.print_help()
        except OutputClosed:  # (as above)
            pass
        return 2
    args.argv = words  # what a result records as its command
    kept = getattr(args, "kept_on_interrupt", None)  # what the command says it keeps, once it has begun
    args.kept_on_interrupt = _NOT_BEGUN  # until then (torch's import as the threads are set)
    with warnings.catch_warnings():
        warnings.showwarning = _warning_shower()
        try:
            # a service manager's stop ends a command as Ctrl-C does, from torch's import on (before
            # 2026-12-06 from the handler's start: a SIGTERM in the second of torch's import ended the
            # process by signal, saying nothing)
            with stop_on_sigterm():
                _sb3_files(args)
                # OODMON_TORCH_THREADS in every command, one thread where it is not set (limit_threads);
                # a command that plays no policy (replay, check, envs) leaves torch unimported
                limit_threads(torch=_plays_a_policy(args))
                args.kept_on_interrupt = kept  # (what the command keeps, once it has begun)
                return args.handler(args) or 0
        except (OodmonError, OSError) as error:
            print(f"oodmon: error: {error}", file=sys.stderr)
            return 2
        except OutputClosed:  # (`oodmon run | head`: the reader is gone; stderr says it)
            print(_OUTPUT_CLOSED.format("; what it printed since went nowhere") + _kept(args), file=sys.stderr)
            return 141
        except KeyboardInterrupt as interrupt:
            stopped = isinstance(interrupt, Terminated)
            print(("oodmon: stopped by SIGTERM" if stopped else "oodmon: interrupted") + _kept(args), file=sys.stderr)
            return 143 if stopped else 130
        except BrokenProcessPool as error:  # a worker died: the traceback here is not where, nor why
            print(f"oodmon: stopped: {_worker_death(error)}" + _kept(args), file=sys.stderr)
            return 3
        except Exception as error:  # noqa: BLE001  (not one oodmon can explain: an env's or a policy's own, or a bug)
            # Its traceback is what finds the cause; then, as for Ctrl-C, what the command kept, and
            # an exit code of its own (Python's 1 would read as a regression check's fall).
            traceback.print_exc()
            print(f"oodmon: stopped by {type(error).__name__}: {error} (the traceback above)" + _kept(args),
                  file=sys.stderr)
            return 3


def _worker_death(error: BrokenProcessPool) -> str:
    """What a worker's death says (side by side's names its pid and its signal or exit code; a
    process pool's, the bench's, only that one was "terminated abruptly"), and where it may have
    been killed for memory, what to try."""
    from oodmon.side_by_side import WorkerDied

    ended_itself = isinstance(error, WorkerDied) and error.signal is None
    return (str(error).rstrip(".") or "a worker process died") + ("" if ended_itself else
                                                                  "; fewer --workers need less memory")


def _kept(args: argparse.Namespace) -> str:
    """``"; "`` and what a stopped command leaves behind (its ``kept_on_interrupt``), or nothing."""
    kept = getattr(args, "kept_on_interrupt", None)
    return f"; {kept}" if kept else ""


_COLOUR = re.compile(r"\x1b\[[0-9;]*m")  # a terminal's colour codes (SGR), as gymnasium.utils.colorize writes them


def _warning_shower():
    """A ``warnings.showwarning`` for one command: warnings in the terminal as one line each,
    without the source line Python would show, nor the colour codes and ``WARN:`` of gymnasium's
    own (``gymnasium.logger.warn``: a user's env whose ``step()`` returns a list said "oodmon:
    warning: \\x1b[33mWARN: The obs returned ..."), and each text once (a bench of your own
    policy on ``CartPole-v0`` said "The environment CartPole-v0 is out of date" 11 times, once per
    env made; each worker process says it once too)."""
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = _COLOUR.sub("", str(message)).removeprefix("WARN: ")
        if text not in shown:
            shown.add(text)
            print(f"oodmon: warning: {text}", file=sys.stderr)

    return show


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="oodmon",
        description="Tells when a deployed RL policy has left the world it was trained in.",
        epilog="Start with `oodmon demo`; `oodmon COMMAND --help` says what each command takes. The repository's "
               "README has a quick start, and its docs/ folder a page per part (the monitor, your own policy, the "
               "detectors, replay, the benchmarks).",
    )
    from oodmon import __version__

    parser.add_argument("--version", action="version", version=f"oodmon {__version__}")
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")

    _add_envs(commands)
    _add_train(commands)
    _add_evaluate(commands)
    _add_calibrate(commands)
    _add_validate(commands)
    _add_recalibrate(commands)
    _add_fit_detectors(commands)
    _add_run(commands)
    _add_replay(commands)
    _add_check(commands)
    _add_bench(commands)
    _add_demo(commands)
    return parser
