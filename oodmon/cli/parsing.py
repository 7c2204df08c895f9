"""The CLI's argument types, the options several commands share, and what Ctrl-C leaves behind."""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Callable, Sequence

from oodmon.names import MASKS, METHODS, TASKS
from oodmon.seeds import MOST_SEED
from oodmon.validation import MOST_STEPS
from oodmon_console import NOT_BEGUN  # (the program's entry point, beside the package: it imports nothing of it)

#: What Ctrl-C leaves behind, said by the commands that write as they go or only at their end.
_LOGGED = "every finished episode is in the logs, the cut one is marked interrupted"
_KEPT = {
    "run": _LOGGED, "demo": _LOGGED,
    "train": "the last checkpoint is kept: the same command resumes from it",
    "bench": "trained models and finished cells are kept: the same command resumes from them",
    "calibrate": "no threshold file or detectors were written (they are written when the calibration ends; those at "
                 "--out are as they were): run the command again",
    "fit-detectors": "no detectors were written (they are written when the fitting ends): run the command again",
    "recalibrate": "no threshold file was written (it is written when the calibration ends; a file at --out is as it "
                   "was): run the command again",
}
#: What a command stopped before its handler began says: Ctrl-C in torch's import (the first second)
#: said "the last checkpoint is kept" of a train that had written none, "every finished episode is
#: in the logs" of a run that had none (2026-12-06, scripts/fuzz_interrupts.py). The words the
#: program's entry point says of a stop in oodmon's own import, one step earlier.
_NOT_BEGUN = NOT_BEGUN


def _command_line(args: argparse.Namespace) -> str:
    """The command as typed (what a model or a bench result records of what made it)."""
    return "oodmon " + shlex.join(args.argv)


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


#: A fit's share of random actions (--explore, --fit-explore): 1 would fit on a random policy alone.
_explore_share = _number(lambda x: 0.0 <= x < 1.0, "a number >= 0 and < 1 (the share of the fitting steps)")


_positive = _number(lambda x: 0.0 < x < float("inf"), "a finite number > 0")


_SEED = _whole(0, MOST_SEED)

#: The alarm rule's --consecutive and --window, and its --warmup (oodmon.validation.MOST_STEPS).
_STEP_COUNT = _whole(1, MOST_STEPS)
_WARMUP = _whole(0, MOST_STEPS)


def _add_rule(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rule", choices=["consecutive", "cusum", "martingale"], default="consecutive",
                        help="the alarm rule: consecutive (default: --consecutive steps above the threshold), cusum or "
                             "martingale (sequential, on p-values against ID reference episodes' scores; see docs/monitor.md)")


def _confidence(text: str) -> float | None:
    """An argparse type: ``--confidence`` in (0, 1), or ``none`` (the rate bounded on average only)."""
    if text.strip().lower() == "none":
        return None
    return _fraction(text)


def _add_workers(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--workers", type=_whole(0), default=1,
                        help=f"processes that play {what} side by side (default 1; 0 or more than the cores: one "
                             "per core). An MC agent's episodes then draw from streams of their own: the same result "
                             "for any number from 2, not one process's")


def _dynamics_updates(text: str) -> int | None:
    """An argparse type: ``--dynamics-updates``, a whole number >= 1 or ``all`` (``None``: every epoch)."""
    if text.strip().lower() == "all":
        return None
    return _whole(1)(text)


def _add_dynamics_updates(parser: argparse.ArgumentParser, when: str) -> None:
    parser.add_argument("--dynamics-updates", type=_dynamics_updates, default=_MAX_UPDATES, metavar="N|all",
                        help=f"{when}, the dynamics model trains every one of its 100 epochs ('all', the default) "
                             "or the whole epochs that hold at most N Adam updates: a large fit's time bounded, and "
                             "the model blunter (3,000, fitting version 8's default: 50 epochs of 30,000 "
                             "transitions; a PPO's InvertedPendulum read a heavy pole as ID; see docs/detectors.md)")


def _add_explore(parser: argparse._ActionsContainer, flag: str, when: str) -> None:
    """A fit's share of random actions: calibrate's and bench's --fit-explore, fit-detectors' --explore."""
    parser.add_argument(flag, type=_explore_share, default=0.0, metavar="P",
                        help=f"take a random action instead of the policy's at this share of the fitting steps, {when} "
                             "(default 0): for a policy whose actions will not all be its own deterministic ones (a "
                             "learning model's exploration, one deployed as it samples), whose other actions the "
                             "dynamics model would otherwise read as a shift; the threshold is calibrated on the "
                             "policy's own actions (docs/your-policy.md)")


def _action_space(text: str):
    """``--action-space``: ``discrete:N`` (N actions, 0 to N - 1) or ``box:N`` (N numbers a step), a
    gymnasium space.

    Example:
        >>> _action_space("discrete:2"), _action_space("box:1").shape
        (Discrete(2), (1,))
    """
    import gymnasium
    import numpy as np

    kind, _, size = text.partition(":")
    if kind in ("discrete", "box") and size.isdigit() and int(size) >= (2 if kind == "discrete" else 1):
        return gymnasium.spaces.Discrete(int(size)) if kind == "discrete" else \
            gymnasium.spaces.Box(-np.inf, np.inf, (int(size),), np.float32)
    raise argparse.ArgumentTypeError(f"{text!r} is no action space: give discrete:N (N >= 2 actions, 0 to N - 1) or "
                                     "box:N (N >= 1 numbers a step)")


def _reading_names(text: str) -> list[str]:
    """``--reading-names``: comma-separated names, each stripped (``'x, v'``: ``['x', 'v']``)."""
    return [name.strip() for name in text.split(",")]


def _add_reading_names(parser: argparse._ActionsContainer, *, default: str, then: str = "") -> None:
    """run's and calibrate's --reading-names."""
    parser.add_argument("--reading-names", type=_reading_names, metavar="NAMES",
                        help="the name of each number of the observations, comma-separated, by index (your own "
                             "env's: 'knee angle,knee velocity,...'): an alarm names its readings by them, and the "
                             f"log keeps them for replay{then} (default: {default})")


def _add_confidence(parser: argparse.ArgumentParser, default: str | None = None) -> None:
    from oodmon.monitor.threshold import DEFAULT_CONFIDENCE

    parser.add_argument("--confidence", type=_confidence, default=DEFAULT_CONFIDENCE if default is None else _UNSET,
                        metavar="1-d",
                        help=f"with this probability over the calibration episodes, the threshold's false-alarm rate "
                             f"is <= --far (default {default or DEFAULT_CONFIDENCE}; 45 episodes for --far 0.05 at "
                             "0.9); 'none': only on average over calibrations (19 episodes for --far 0.05)")


#: oodmon.monitor.detectors.DEFAULT_FIT_EPISODES and DEFAULT_FIT_STEPS, written out: importing them
#: here would load the detectors (scipy, gymnasium) before every command; a test keeps them equal.
_FIT_EPISODES = 90
_FIT_STEPS = 45_000
#: How many ID episodes a fit of the learned detectors plays by default, as the options' help says it.
_FIT_DEFAULT = f"default {_FIT_EPISODES}; your own --env: more, until they hold {_FIT_STEPS:,} steps"
#: oodmon.monitor.detectors.dynamics.MAX_UPDATES, written out for the same reason.
_MAX_UPDATES: int | None = None
#: oodmon.replay.failures.FAILURES, written out for the same reason: what ``--failure`` takes.
_FAILURES = ("terminated",)


#: An option left at its default where the default depends on another option (bench's --protocol).
_UNSET = -1.0


#: --detectors' help where the detectors default to those `calibrate` fitted beside the threshold (run, validate).
DETECTORS_BESIDE = ("fitted detectors from `oodmon fit-detectors` (default: those `calibrate` fitted beside the threshold "
                    "file, else those shipped with the agent, if any)")


def _agent_arguments(parser: argparse.ArgumentParser, *, defaults_from: str | None = None,
                     detectors: str | None = DETECTORS_BESIDE) -> None:
    """--task, --method, --model, --masks, the --sb3 options, --policy and --detectors (``detectors``:
    its help; None: no --detectors, for a command that reads no fitted detectors); with
    ``defaults_from`` (a threshold file, in words), the task and method default to what it was
    calibrated for."""
    parser.add_argument("--task", choices=TASKS, help="a shipped agent's task (" + (
        "required unless --sb3 or --policy)" if defaults_from is None else f"default: {defaults_from})"))
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
    _sb3_arguments(parser, from_threshold=defaults_from is not None)
    _policy_argument(parser)
    if detectors is not None:
        parser.add_argument("--detectors", metavar="DIR", help=detectors)


def _policy_argument(parser: argparse.ArgumentParser) -> None:
    """--policy MODULE:NAME: your own policy of any kind instead of an oodmon agent or SB3 models."""
    parser.add_argument("--policy", metavar="MODULE:NAME",
                        help="your own policy of any kind, with --env: a function obs -> action (or a callable object) "
                             "NAME of your module MODULE, which is imported (its code runs); the learned detectors watch "
                             "it (e.g. --policy my_controller:act, with its folder on PYTHONPATH)")


def _sb3_arguments(parser: argparse.ArgumentParser, *, from_threshold: bool = False) -> None:
    """--sb3, --env, --mean: your own stable-baselines3 models instead of an oodmon agent
    (``from_threshold``: a command whose threshold file names them by default)."""
    parser.add_argument("--sb3", nargs="+", metavar="ZIP",
                        help="your own stable-baselines3 model file(s) (DQN, DDPG, TD3, SAC, PPO, A2C; sb3-contrib's "
                             "QR-DQN, TQC, TRPO, ARS, CrossQ, RecurrentPPO, MaskablePPO), with --env; the first is the "
                             "deployed policy, several DQN, DDPG/TD3, SAC, TQC or QR-DQN models (of one algorithm) also "
                             "form an ensemble detector (runs/dqn reads runs/dqn.zip, as SB3's load does). Read without "
                             "running code from them: a file whose policy class, "
                             "its arguments or spaces name anything else is refused (see --unsafe-load-pickles)"
                             + ("; default: the models a threshold calibrated on them records, with its --env, "
                                "--vec-normalize, --frame-stack and --mean" if from_threshold else ""))
    parser.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE",
                        help="import this module of yours first (repeatable), whose classes the --sb3 files name (a "
                             "policy class of your own, say; oodmon imports no module a file names)")
    parser.add_argument("--unsafe-load-pickles", action="store_true",
                        help="load the --sb3 files as stable-baselines3 does, unpickling their data: it runs any code "
                             "a file holds, so only for files you trust")
    parser.add_argument("--env", metavar="ID",
                        help="the gymnasium env id the --sb3 models (or the --policy) act in, e.g. CartPole-v1")
    parser.add_argument("--mean", action="store_true",
                        help="with several --sb3 models: deploy the ensemble's mean decision, not the first model's")
    parser.add_argument("--vec-normalize", metavar="PKL",
                        help="--sb3 models trained inside SB3's VecNormalize: the statistics file it saved "
                             "(vec_normalize.save(), e.g. vecnormalize.pkl; read without running code from it), so that they see "
                             "observations normalised as in training; 'none' if it did not normalise observations")
    parser.add_argument("--frame-stack", type=int, metavar="N",
                        help="--sb3 models trained inside SB3's VecFrameStack(N): their observations (and the detectors' "
                             "and the logs') are the env's stacked N deep as VecFrameStack stacks them")
