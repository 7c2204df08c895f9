"""``oodmon calibrate``, ``oodmon validate`` and ``oodmon fit-detectors``."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from oodmon.cli.display import _clustered, _progress
from oodmon.cli.loading import _agent_from_threshold, _check_agent_from_threshold, _detectors, _input_files, _load_agent
from oodmon.cli.parsing import (
    _FIT_DEFAULT, _KEPT, _MAX_UPDATES, _SEED, _STEP_COUNT, _WARMUP, _action_space, _add_confidence,
    _add_dynamics_updates, _add_explore, _add_reading_names, _add_rule, _add_workers, _agent_arguments, _fraction,
    _non_negative, _whole,
)
from oodmon.errors import ConfigError, unknown
from oodmon.monitor.stopping import stops_held
from oodmon.monitor.threshold import DETECTOR_NAMES, episodes_needed
from oodmon.seeds import CALIBRATION, DETECTOR_FIT, VALIDATION


def _add_calibrate(commands: argparse._SubParsersAction) -> None:
    """`oodmon calibrate`."""
    calibrate = commands.add_parser(
        "calibrate", help="calibrate an agent's alarm threshold on held-out in-distribution episodes"
    )
    policy = calibrate.add_argument_group("the policy it watches")
    detector = calibrate.add_argument_group("the detector the alarm reads")
    promise = calibrate.add_argument_group("the threshold and its promise")
    rule = calibrate.add_argument_group("the alarm rule")
    _agent_arguments(policy, detectors="fitted detectors to calibrate with, from `oodmon fit-detectors` or an "
                     "earlier calibrate (its <--out>.detectors): none is fitted again (default: those shipped with the "
                     "agent, if any; a learned detector asked for that they lack is fitted first, into "
                     "<--out>.detectors)")
    promise.add_argument("--episodes", type=_whole(1), default=50, help="ID calibration episodes (default 50)")
    promise.add_argument("--far", type=_fraction, default=0.05, help="target false-alarm rate (default 0.05)")
    _add_confidence(promise)
    _add_rule_counts(rule)
    _add_rule(rule)
    rule.add_argument("--reference-episodes", type=_whole(1), default=20,
                      help="ID episodes a sequential rule's p-values are taken against (default 20; seeds apart)")
    rule.add_argument("--reference-by-age", action="store_true",
                      help="take a sequential rule's p-values against ID steps as long since reset, not all of them")
    promise.add_argument("--mode", choices=["episode", "step"], default="episode",
                         help="guarantee per episode (default) or per step")
    detector.add_argument("--score", default="chosen_std",
                          help="the spread's score: chosen_std (default), mean_std, max_std, margin_std (DQN) or "
                               "pre_squash_std (DDPG)")
    detector.add_argument("--detector", choices=list(DETECTOR_NAMES),
                          help="the detector the alarm reads (default: the task's best measured one when the agent has "
                               "fitted detectors: cartpole combined, pendulum dynamics, pong combined (of frames, "
                               "stillness and vanishing); else spread); "
                               "a learned one without fitted detectors is fitted first, into <out>.detectors/")
    detector.add_argument("--fit-episodes", type=_whole(3),
                          help=f"ID episodes the learned detectors are fitted on when calibrate fits them ({_FIT_DEFAULT})")
    _add_dynamics_updates(detector, "when calibrate fits the detectors")
    _add_explore(detector, "--fit-explore", "when calibrate fits the detectors")
    promise.add_argument("--seed", type=_SEED, default=CALIBRATION,
                         help=f"seed of the first calibration episode and of MC sampling (default {CALIBRATION})")
    _add_workers(promise, "the calibration episodes (and those of a fit of detectors before it)")
    promise.add_argument("--obs-noise", type=_non_negative, default=0.0,
                         help="sensor noise of the ID world, a fraction of each reading's ID spread (CartPole, "
                              "Pendulum; default 0), recorded in the threshold for validate and run; where the alarm "
                              "reads a learned detector, the agent's shipped ones, fitted without noise, are fitted "
                              "again in that world first")
    promise.add_argument("--max-steps", type=_whole(1),
                         help="the calibration episodes' time limit instead of the env's own, for a deployment whose "
                              "runs are longer (the bound is for episodes like the calibration's); recorded in the "
                              "threshold for validate and run; detectors calibrate fits are fitted on such episodes too")
    promise.add_argument("--out", required=True, help="the threshold file to write (JSON)")
    records = calibrate.add_argument_group(
        "a deployment no env plays (oodmon.watch_recorded): its recorded episodes, none played")
    records.add_argument("--records", metavar="FILE",
                         help="the ID episodes to fit the detectors on (an .npz, oodmon.monitor.save_records)")
    records.add_argument("--calibration-records", metavar="FILE",
                         help="other ID episodes, to calibrate the alarm on (with --records)")
    records.add_argument("--action-space", type=_action_space, metavar="SPACE",
                         help="their actions: discrete:N (N actions, 0 to N - 1) or box:N (N numbers a step)")
    _add_reading_names(calibrate, default="none recorded: an env whose layout is known, a dict observation's keys, "
                                          "are named without", then="; the threshold keeps them, and `oodmon run` "
                                          "with it names its alarms' readings by them")
    calibrate.set_defaults(handler=_calibrate, kept_on_interrupt=_KEPT["calibrate"])


def _add_rule_counts(rule: argparse._ArgumentGroup) -> None:
    """The alarm rule's counts, which `calibrate` and `recalibrate` take alike."""
    rule.add_argument("--consecutive", type=_STEP_COUNT,
                      help="m of the alarm rule (default 3 for the spread detector, 1 for a learned one)")
    rule.add_argument("--window", type=_STEP_COUNT,
                      help="compare the mean score of the last N steps (default 1: each step's; Pong 200 "
                           "unless the frames detector)")
    rule.add_argument("--warmup", type=_WARMUP, default=0,
                      help="the alarm looks at no score of an episode's first N steps (but a NaN reading's): where "
                           "the learned detectors' means cover few transitions since the reset (default 0)")


#: fit-detectors' flag of each of calibrate's options of a fit.
_FIT_DETECTORS_FLAG = {"--fit-episodes": "--episodes", "--fit-explore": "--explore"}


def _refuse_fit_options(args: argparse.Namespace) -> None:
    """Refuse calibrate's options of a fit where it fits no detectors (it reads fitted ones): said
    before the calibration's minutes, not ignored.

    Raises:
        ConfigError: naming the options given and how to fit with them.
    """
    given = [(flag, value) for flag, value, default in (
        ("--fit-episodes", args.fit_episodes, None), ("--dynamics-updates", args.dynamics_updates, _MAX_UPDATES),
        ("--fit-explore", args.fit_explore, 0.0)) if value != default]
    if not given:
        return
    flags = " and ".join(flag for flag, _ in given)
    settings = " ".join(f"{_FIT_DETECTORS_FLAG.get(flag, flag)} {value}" for flag, value in given)
    raise ConfigError(f"{flags} shape{'' if len(given) > 1 else 's'} a fit of the detectors, and calibrate fits none "
                      "here: it reads " + (f"those in {args.detectors}" if args.detectors else "the agent's shipped ones")
                      + f"; fit them with `oodmon fit-detectors ... {settings} --out DIR`, then calibrate with "
                      "--detectors DIR")


def _calibrate_records(args: argparse.Namespace) -> int:
    """`oodmon calibrate --records FIT --calibration-records CAL --action-space SPACE`: a deployment
    no env plays, its detectors fitted on recorded episodes and its alarm calibrated on others
    (:func:`oodmon.monitor.recorded.watch_recorded`'s parts), no episode played."""
    from oodmon.monitor import Threshold, calibrate_on_episodes, fit_on_episodes, load_records
    from oodmon.monitor.calibration import save_calibration
    from oodmon.monitor.threshold import conformal_rank
    from oodmon.outputs import check_output_dir, check_output_file, replaced_file

    played = [flag for flag, value, default in (
        ("--model", args.model, None), ("--sb3", args.sb3, None), ("--policy", args.policy, None),
        ("--task", args.task, None), ("--method", args.method, None), ("--detectors", args.detectors, None),
        ("--episodes", args.episodes, 50), ("--seed", args.seed, CALIBRATION), ("--workers", args.workers, 1),
        ("--obs-noise", args.obs_noise, 0.0), ("--max-steps", args.max_steps, None),
        ("--score", args.score, "chosen_std"), ("--rule", args.rule, "consecutive"),
        ("--fit-episodes", args.fit_episodes, None), ("--fit-explore", args.fit_explore, 0.0))
        if value != default]
    if played:
        raise ConfigError(f"--records fits and calibrates on recorded episodes of a deployment oodmon does not run: "
                          f"leave out {', '.join(played)} (they shape played episodes, or the policy)")
    if args.calibration_records is None or args.action_space is None:
        raise ConfigError("--records (the fitting episodes) goes with --calibration-records (other episodes, the "
                          "alarm's) and --action-space (discrete:N or box:N)")
    check_output_file(args.out, parameter="--out", inputs=[("a file it reads", args.records),
                                                          ("a file it reads", args.calibration_records)])
    replaced = replaced_file(args.out, parameter="--out", holds="threshold", read=Threshold.load)
    folder = Path(f"{args.out}.detectors")
    check_output_dir(folder, parameter="--out (its detectors folder)", create=False)
    fit, calibration = load_records(args.records), load_records(args.calibration_records)
    if args.mode == "episode":  # too few: said before the fit
        conformal_rank(len(calibration), args.far, args.confidence)
    with _progress() as report:
        detectors = fit_on_episodes(fit, args.action_space, dynamics_updates=args.dynamics_updates,
                                    on_progress=report)
        threshold = calibrate_on_episodes(detectors, calibration, args.far, detector=args.detector,
                                          confidence=args.confidence, consecutive=args.consecutive,
                                          window=args.window, warmup=args.warmup, mode=args.mode,
                                          reading_names=args.reading_names, on_progress=report)
    with stops_held():
        save_calibration(threshold, args.out, detectors)
    Console(soft_wrap=True).print(
        f"recorded episodes: alarm when {threshold.rule_text} ({threshold.detector} detector of "
        f"{', '.join(detectors.names)}, {threshold.mode} mode, fitted on the {len(fit)} episodes of {args.records} "
        f"and calibrated on the {threshold.n_episodes} of {args.calibration_records}, {threshold.n_steps} steps, rank "
        f"{threshold.rank} of {threshold.n_episodes if threshold.mode == 'episode' else threshold.n_steps}; ID score "
        f"median {threshold.quantiles['q50']:.4g}, max {threshold.quantiles['max']:.4g}); {threshold.promise}{escape(_names_said(threshold))}; wrote {args.out}"
        + (f" (replacing the threshold it held: alarm when {replaced.rule_text})" if replaced else "")
        + f" and the detectors into {folder}; `oodmon validate {args.out} --records FILE` counts fresh records, "
        f"and oodmon.watch_recorded(threshold={str(args.out)!r}) watches in your own loop")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from oodmon.monitor import Threshold, calibrate_agent
    from oodmon.monitor.calibration import save_calibration
    from oodmon.monitor.detectors import (
        BEST_DETECTOR, DEFAULT_FIT_EPISODES, detectors_for, fit_agent_detectors, fitting_notes,
    )
    from oodmon.kept import KeptFit
    from oodmon.monitor.detectors.fitting import check_can_have, fit_settings, fitted_when_named
    from oodmon.monitor.threshold import conformal_rank
    from oodmon.outputs import check_output_dir, check_output_file, replaced_file

    if args.records is not None:
        return _calibrate_records(args)
    if args.calibration_records is not None or args.action_space is not None:
        raise ConfigError("--calibration-records and --action-space go with --records (recorded episodes to fit on)")
    check_output_file(args.out, parameter="--out", inputs=_input_files(args))
    replaced = replaced_file(args.out, parameter="--out", holds="threshold", read=Threshold.load)  # before any episode
    if args.mode == "episode":
        conformal_rank(args.episodes, args.far, args.confidence)  # too few episodes: said before any runs
    agent = _load_agent(args, seed=args.seed)  # the same --seed, the same threshold, for MC agents too
    check_can_have(args.detector, agent)  # (a plain policy's spread: said before the fit, not after it)
    detectors = detectors_for(agent, args.detectors)
    fitted_to = None
    # A learned detector asked for, or a model from elsewhere (a plain policy has no spread; an SB3
    # ensemble's spread is weak): fit them first, on episodes of their own. So too for a combined
    # detector asked for with another spread score than the fitted one ranks.
    # scaled_spread is fitted only when asked for, alone (with the spread); drift, outside your own
    # env, only when asked for.
    left_out = detectors.for_score(args.score)[1] if detectors is not None else None
    named_only = fitted_when_named(args.detector) is not None
    # The shipped detectors learned a noiseless world: where the alarm reads one of them in a noisy
    # world, they are fitted again (at 1% noise, the CartPole ensemble's combined threshold was
    # 159,271 with them, 5.12 refitted; 2026-12-05). Those given by --detectors are the user's
    # choice: calibrate_agent warns of another noise.
    other_world = (detectors is not None and args.detectors is None and args.detector != "spread"
                   and float(detectors.fitted_for.get("obs_noise") or 0.0) != args.obs_noise)
    if (detectors is None and (args.detector not in (None, "spread") or agent.estimator is None or agent.env_id)
            or (args.detector == "combined" and left_out) or (named_only and args.detector not in (detectors or ()))
            or other_world):
        fitted_to = Path(f"{args.out}.detectors")
        check_output_dir(fitted_to, parameter="--out (its detectors folder)", create=False)
        kept_fit = KeptFit(fitted_to, fit_settings(agent, fitted_when_named(args.detector), score=args.score,
                                                   episodes=args.fit_episodes, dynamics_updates=args.dynamics_updates,
                                                   obs_noise=args.obs_noise, max_steps=args.max_steps,
                                                   workers=args.workers, explore=args.fit_explore))

        def fit(episodes_file: Path):
            unwritten = "no threshold file or detectors were written"
            with _progress() as report, _kept_fitting(args, episodes_file, unwritten):
                return fit_agent_detectors(agent, detectors=fitted_when_named(args.detector), score=args.score,
                                           episodes=args.fit_episodes, on_progress=report, workers=args.workers,
                                           dynamics_updates=args.dynamics_updates, obs_noise=args.obs_noise,
                                           max_steps=args.max_steps, kept=episodes_file, explore=args.fit_explore)

        detectors = kept_fit.fit(agent.estimator, fit)
        if kept_fit.reused:
            print(f"kept detectors: {', '.join(detectors.names)}, fitted before an interrupted calibration "
                  f"({kept_fit.detectors_folder})", file=sys.stderr)
    else:
        _refuse_fit_options(args)
    kept = Path(f"{args.out}.kept.npz")  # an interrupted calibration's episodes, which the same command goes on from
    try:
        with _progress() as report:
            threshold = calibrate_agent(agent, args.episodes, args.far, consecutive=args.consecutive, mode=args.mode,
                                        window=args.window, score=args.score, seed=args.seed, detectors=detectors,
                                        detector=args.detector, confidence=args.confidence, rule=args.rule,
                                        reference_episodes=args.reference_episodes,
                                        reference_by_age=args.reference_by_age, warmup=args.warmup,
                                        on_progress=report, workers=args.workers, obs_noise=args.obs_noise,
                                        max_steps=args.max_steps, kept=kept, reading_names=args.reading_names)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # (a worker's death too: killed for memory)
        played = getattr(interrupt, "kept_episodes", 0)
        what = [f"the {played:,} of the {args.episodes:,} calibration episodes played whole are kept in {kept}"
                ] if played else []
        if fitted_to is not None and kept_fit.keep():
            what.append(f"the detectors it fitted are kept in {kept_fit.detectors_folder}")
        if what:
            args.kept_on_interrupt = (f"no threshold file {'or detectors were' if fitted_to else 'was'} written (those "
                                      f"at --out are as they were); {', and '.join(what)}: the same command goes on "
                                      "from them")
        raise
    # Written together once the calibration ends, each file beside its place first: an interrupted
    # calibration or a full disk leaves the earlier threshold with the detectors it was calibrated with.
    # A stop here waits for the clean-up (the earlier calibration's detectors, which run would read)
    # and then says what was written: it said "no threshold file was written" of one written.
    with stops_held():
        save_calibration(threshold, args.out, detectors if fitted_to else None)
        kept.unlink(missing_ok=True)
        if fitted_to is not None:
            kept_fit.clear()
        cleared = None if fitted_to else _clear_earlier_detectors(args.out, args.detectors)
        args.kept_on_interrupt = _ended("calibration", f"its threshold is written to {args.out}"
                                        + (f", the detectors it fitted to {fitted_to}" if fitted_to else ""))
    Console(soft_wrap=True).print(
        f"{args.task}/{agent.method}: alarm when {threshold.rule_text} ({threshold.detector} detector, {threshold.mode} "
        f"mode, {threshold.n_episodes} ID episodes{_up_to(threshold.max_steps)}{_side_by_side(threshold.workers)}"
        f"{_noise(threshold.obs_noise)}, "
        f"{threshold.n_steps} steps, rank {threshold.rank} of "
        f"{threshold.n_episodes if threshold.mode == 'episode' else threshold.n_steps}; ID score median "
        f"{threshold.quantiles['q50']:.4g}, max {threshold.quantiles['max']:.4g}{_statistic_words(threshold)}); "
        f"{threshold.promise}{escape(_names_said(threshold))}; wrote {args.out}"
        + (f" (replacing the threshold it held: alarm when {replaced.rule_text}, {replaced.detector} detector, "
           f"{replaced.n_episodes} ID episodes)" if replaced else "")
        + (f"; fitted the detectors into {fitted_to}{_explored(detectors.fitted_for.get('explore'))} (`oodmon run` "
           "finds them there; to calibrate again without "
           f"fitting them, give --detectors {fitted_to})" if fitted_to else "")
        + (f"; removed the detectors an earlier calibration fitted into {cleared} (`oodmon run` would read them "
           "before those this threshold was calibrated with)" if cleared else "")
        + (f"; it reads the detectors in {args.detectors}: give `oodmon validate` and `oodmon run` --detectors "
           f"{args.detectors} too" if _read_elsewhere(args) else "")
    )
    if fitted_to:
        for note in fitting_notes(detectors):
            Console(soft_wrap=True).print(note, markup=False)
    best = BEST_DETECTOR.get(args.task)
    if best is not None and args.detector is None and threshold.detector != best:
        Console(stderr=True, soft_wrap=True).print(
            f"note: the {best} detector separates {args.task}'s shifts better than {threshold.detector}; "
            f"`--detector {best}` fits it first (about {DEFAULT_FIT_EPISODES} more ID episodes)"
            + (f"; the fitted one is left out: {left_out}" if left_out and best == "combined" else ""))
    return 0


def _names_said(threshold) -> str:
    """The names a threshold gives its alarms' readings (``--reading-names``, or the logs'), after a
    ``"; "``; empty where it records none."""
    return f"; its alarms name the readings {', '.join(threshold.reading_names)}" if threshold.reading_names else ""


def _ended(work: str, written: str) -> str:
    """What a command stopped after its work says it kept: ``the calibration had ended: <written>``."""
    return f"the {work} had ended: {written}"


def _up_to(max_steps: int | None) -> str:
    """The words ' of up to N steps' of episodes with time limit ``max_steps`` (none: the env's own)."""
    return f" of up to {max_steps:,} steps" if max_steps else ""


def _noise(obs_noise: float | None) -> str:
    """The words ' with sensor noise X' where the episodes had some, else nothing."""
    return f" with sensor noise {obs_noise:g}" if obs_noise else ""


def _explored(explore: float | None, steps: str = "the fitting steps") -> str:
    """The words ', a random action at P% of <steps>' of a fit that explored, else nothing.

    Example:
        >>> _explored(0.1, "their steps"), _explored(None)
        (', a random action at 10% of their steps', '')
    """
    return f", a random action at {100 * explore:.3g}% of {steps}" if explore else ""


def _side_by_side(played_by: int | None) -> str:
    """The words ' played by N processes side by side' where more than one played the episodes (an
    MC agent's draws are then not one process's), else nothing."""
    return f" played by {played_by} processes side by side" if played_by and played_by > 1 else ""


def _read_elsewhere(args: argparse.Namespace) -> bool:
    """Whether calibrate read fitted detectors (``--detectors``) from another folder than the one
    beside its threshold (``<--out>.detectors``), where validate and run do not look."""
    return bool(args.detectors) and Path(args.detectors).resolve() != Path(f"{args.out}.detectors").resolve()


def _clear_earlier_detectors(out: str, given: str | None) -> Path | None:
    """Remove the detectors an earlier calibration fitted beside ``out`` (``<out>.detectors/``,
    the two files ``DetectorSet.save`` writes; the folder too once empty) when this one fitted none
    there, and return that folder (``None``: nothing removed). `oodmon run --threshold` and
    `validate` read that folder before the agent's own detectors: left there, they would be read
    with a threshold calibrated on others (and refused). Kept when ``--detectors`` named it."""
    folder = Path(f"{out}.detectors")
    if not (folder / "detectors.json").is_file() or (given is not None and Path(given).resolve() == folder.resolve()):
        return None
    for name in ("detectors.json", "detectors.safetensors"):
        (folder / name).unlink(missing_ok=True)
    with contextlib.suppress(OSError):  # it holds other files: kept
        folder.rmdir()
    return folder


def _add_recalibrate(commands: argparse._SubParsersAction) -> None:
    """`oodmon recalibrate`."""
    recalibrate = commands.add_parser(
        "recalibrate", help="calibrate a threshold on the ID episodes of logged runs: your deployment's own world, "
                            "where no simulator plays it"
    )
    recalibrate.add_argument("logs", nargs="+", help="MCAP logs of runs of the deployed policy in its own world, ID "
                                                     "(files, or folders holding them; `oodmon run --mcap`, a "
                                                     "MonitoredEnv with an McapSink)")
    promise = recalibrate.add_argument_group("the threshold and its promise")
    rule = recalibrate.add_argument_group("the alarm rule")
    promise.add_argument("--far", type=_fraction, default=0.05, help="target false-alarm rate (default 0.05)")
    _add_confidence(promise)
    promise.add_argument("--mode", choices=["episode", "step"], default="episode",
                         help="guarantee per episode (default) or per step")
    rule.add_argument("--detector", choices=list(DETECTOR_NAMES),
                      help="the detector whose logged scores the alarm reads (default: the one the logs' runs "
                           "alarmed on; of runs without a threshold, the one calibrate would choose among those they "
                           "scored)")
    _add_rule_counts(rule)
    recalibrate.add_argument("--detectors", help="the fitted detectors the logs' runs read (their threshold's "
                                                 "<threshold>.detectors, or --detectors): checked against the logs and "
                                                 "copied to <--out>.detectors, where `oodmon run` finds them")
    recalibrate.add_argument("--last", type=_whole(1), metavar="N",
                             help="calibrate on the latest N whole ID episodes only (by when they ended): a "
                                  "deployment logging on; after a change in its world, those since (default: all)")
    recalibrate.add_argument("--out", required=True, help="the threshold file to write (JSON)")
    recalibrate.add_argument("--plot", metavar="FILE", help="draw each calibration episode's statistic in the order "
                                                            "they ended, the threshold, and any change or burst among "
                                                            "them (of which it warns) to FILE (.png, .jpg)")
    recalibrate.set_defaults(handler=_recalibrate, plays=False, kept_on_interrupt=_KEPT["recalibrate"])


def _recalibrate(args: argparse.Namespace) -> int:
    from oodmon.monitor import Threshold
    from oodmon.monitor.calibration import save_calibration
    from oodmon.monitor.detectors import DetectorSet
    from oodmon.outputs import check_output_file, check_picture_file, replaced_file
    from oodmon.replay.plots import plot_log_statistics
    from oodmon.replay.recalibrate import calibrate_from_logs, change_in_logs, log_episodes

    inputs = [("--detectors", args.detectors), *(("a log", log) for log in args.logs)]
    check_output_file(args.out, parameter="--out", inputs=inputs)
    plot = None if args.plot is None else check_picture_file(args.plot, parameter="--plot",
                                                             inputs=[*inputs, ("--out", args.out)])
    replaced = replaced_file(args.out, parameter="--out", holds="threshold", read=Threshold.load)
    detectors = DetectorSet.load(args.detectors) if args.detectors else None
    found = log_episodes(args.logs, last=args.last)
    threshold = calibrate_from_logs(found, args.far, confidence=args.confidence, detector=args.detector,
                                    consecutive=args.consecutive, window=args.window, warmup=args.warmup,
                                    mode=args.mode)
    if detectors is not None and threshold.detector != "spread":
        if threshold.detector not in detectors:
            raise ConfigError(f"--detectors {args.detectors} holds no fitted {threshold.detector} detector (it has "
                              f"{', '.join(detectors.names)}), whose scores the logs hold")
        if detectors.fingerprint(threshold.detector) != threshold.detectors_hash:
            raise ConfigError(f"--detectors {args.detectors} is another fit than the one that scored the logs "
                              f"({detectors.fingerprint(threshold.detector)}, the logs' {threshold.detectors_hash}): "
                              "give the detectors the logs' runs read")
    with stops_held():  # (as calibrate's)
        save_calibration(threshold, args.out, detectors)
        cleared = None if detectors is not None else _clear_earlier_detectors(args.out, None)
        args.kept_on_interrupt = _ended("calibration", f"its threshold is written to {args.out}")
    if plot is not None:
        plot_log_statistics(change_in_logs(found, threshold), threshold, plot)
    Console(soft_wrap=True).print(
        f"{threshold.task}/{threshold.method}: alarm when {threshold.rule_text} ({threshold.detector} detector, "
        f"{threshold.mode} mode, {threshold.n_episodes} ID episodes of {len(found.logs)} log file"
        f"{'s' if len(found.logs) > 1 else ''}{_noise(threshold.obs_noise)}, {threshold.n_steps} steps"
        + (f" (their runs' time limit: {threshold.max_steps:,})" if threshold.max_steps else "")
        + f", rank "
        f"{threshold.rank} of {threshold.n_episodes if threshold.mode == 'episode' else threshold.n_steps}; ID score "
        f"median {threshold.quantiles['q50']:.4g}, max {threshold.quantiles['max']:.4g}); {threshold.promise}"
        f"{_names_said(threshold)}; wrote {args.out}"
        + (f" (replacing the threshold it held: alarm when {replaced.rule_text})" if replaced else "")
        + (f"; the detectors it reads copied to {args.out}.detectors (`oodmon run` finds them there)"
           if detectors is not None else "")
        + (f"; removed the detectors an earlier calibration fitted into {cleared}" if cleared else "")
        + (f"; drew its episodes' statistics in {plot}" if plot is not None else ""),
        markup=False)
    notes = [said] if (said := _left_out_said(found.left_out())) else []
    if found.cut:
        notes.append(f"{found.cut} episodes ended at the step an alarm began, their env not ending them: an alarm may "
                     "have cut them short, so they count as above any threshold")
    if threshold.detector != "spread" and detectors is None:
        notes.append(f"`oodmon run --threshold {args.out}` must read the fitted {threshold.detector} detector the "
                     "logs' runs read (it refuses another fit): a shipped agent's own, or give run --detectors DIR "
                     "(their threshold's <threshold>.detectors), or give --detectors DIR here to copy it beside")
    for note in notes:
        Console(stderr=True, soft_wrap=True).print(f"note: {note}", markup=False)
    return 0


def _left_out_said(left_out: dict[str, int]) -> str | None:
    """What a calibration or fit on logs left out (``LogEpisodes.left_out``), in words; ``None``: nothing."""
    words = {"earlier": "earlier ID", "shifted": "shifted", "interrupted": "the run was stopped inside"}
    said = [f"{count:,} {words[why]}" for why, count in left_out.items() if count]
    return f"left out {' and '.join(said)} episodes" if said else None


def _add_validate(commands: argparse._SubParsersAction) -> None:
    """`oodmon validate`."""
    validate = commands.add_parser(
        "validate", help="run fresh ID episodes and print a threshold's realised false-alarm rate beside its target"
    )
    validate.add_argument("threshold", help="the threshold file (`oodmon calibrate`)")
    _agent_arguments(validate.add_argument_group("the policy it watches"), defaults_from="the threshold's")
    validate.add_argument("--episodes", type=_whole(1), default=200, help="fresh ID episodes (default 200)")
    validate.add_argument("--seed", type=_SEED, default=VALIDATION,
                          help=f"seed of the first episode and of MC sampling (default {VALIDATION}, apart from "
                               "calibration's)")
    validate.add_argument("--obs-noise", type=_non_negative,
                          help="sensor noise, a fraction of each dimension's ID spread (default: the threshold's, "
                               "`calibrate --obs-noise`; 0 where it records none)")
    validate.add_argument("--max-steps", type=_whole(1),
                          help="each episode's time limit instead of the env's own: check the threshold on runs as "
                               "long as your deployment's (default: the threshold's, `calibrate --max-steps`, else the "
                               "env's own; episode mode: also counted by stretches as long as the calibration "
                               "episodes, which the bound is for)")
    validate.add_argument("--force", action="store_true", help="validate even if the threshold was made for other weights")
    _add_workers(validate, "the validation episodes")
    validate.add_argument("--records", metavar="FILE",
                          help="count these recorded ID episodes (an .npz, oodmon.monitor.save_records) instead of "
                               "playing any: a threshold made from recorded episodes (oodmon.watch_recorded), of a "
                               "deployment no env plays")
    validate.add_argument("--json", action="store_true", help="print JSON instead of a sentence")
    validate.set_defaults(handler=_validate)


def _validate(args: argparse.Namespace) -> int:
    from oodmon.monitor import Threshold, validate_threshold

    if args.records is not None:
        return _validate_records(args)
    threshold = Threshold.load(args.threshold)
    from_threshold = _agent_from_threshold(args, threshold, args.threshold)
    args.masks = args.masks or threshold.masks
    agent = _load_agent(args, seed=args.seed)  # the same --seed, the same count, for MC agents too
    if from_threshold:
        _check_agent_from_threshold(args, threshold, args.threshold, agent)
    detectors = _detectors(args, agent, threshold)
    try:
        with _progress() as report:
            result = validate_threshold(agent, threshold, args.episodes, seed=args.seed, detectors=detectors,
                                        obs_noise=args.obs_noise, force=args.force, on_progress=report,
                                        workers=args.workers, max_steps=args.max_steps)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # Ctrl-C, SIGTERM, a worker's death: the episodes
        # played whole are still a count
        played = getattr(interrupt, "validation", None)
        if played is not None:
            _print_validation(args, agent, threshold, played, interrupted=True)
            args.kept_on_interrupt = (f"the {played.episodes:,} of the {args.episodes:,} episodes played whole before "
                                      "it are counted above")
        raise
    _print_validation(args, agent, threshold, result)
    return 1 if result.verdict == "above" else 0


def _validate_records(args: argparse.Namespace) -> int:
    """`oodmon validate THRESHOLD --records FILE`: the recorded episodes counted, none played."""
    from oodmon.monitor import Threshold, load_records, validate_on_episodes

    given = [option for option, value in (("--model", args.model), ("--sb3", args.sb3), ("--policy", args.policy),
                                          ("--task", args.task), ("--method", args.method)) if value]
    if given:
        raise ConfigError(f"--records counts recorded episodes of the threshold's deployment, which oodmon does not "
                          f"run: leave out {', '.join(given)}")
    threshold = Threshold.load(args.threshold)
    with _progress() as report:
        result = validate_on_episodes(args.threshold, load_records(args.records), on_progress=report)
    _print_validation(args, None, threshold, result)
    return 1 if result.verdict == "above" else 0


def _print_validation(args: argparse.Namespace, agent, threshold, result, *, interrupted: bool = False) -> None:
    """``validate``'s answer: its JSON (``--json``) or its line(s), of ``result``; ``interrupted``: a
    count of the episodes played whole before Ctrl-C or SIGTERM, said so first."""
    from oodmon.side_by_side import resolve_workers

    unit = "episodes" if threshold.mode == "episode" else "steps"
    # (agent None: the recorded episodes of a deployment oodmon does not run, `--records`)
    task, method = (agent.task, agent.method) if agent is not None else (None, None)
    label = f"{task}/{method}" if agent is not None else f"the recorded episodes of {args.records}"
    seed = args.seed if agent is not None else None
    noise = result.obs_noise  # (the threshold's, unless --obs-noise)
    stretches = result.stretches
    if args.json:
        print(json.dumps({"threshold": str(args.threshold), "task": task, "method": method,
                          "detector": threshold.detector, "rule": threshold.rule_text, "unit": unit,
                          "alarmed": result.alarmed, "total": result.total, "rate": result.rate,
                          "interval95": [result.low, result.high], "design_effect": result.design_effect,
                          "far": result.far,
                          "confidence": result.confidence, "seed": seed, "obs_noise": noise,
                          "calibrated_obs_noise": threshold.calibration_noise,  # the world the bound is for
                          "workers": resolve_workers(args.workers, args.episodes) if agent is not None else None,
                          "steps": result.steps, "alarms": result.alarms, "max_steps": result.max_steps,
                          "stretches": None if stretches is None else {
                              "length": stretches.length, "alarmed": stretches.alarmed, "total": stretches.total,
                              "rate": stretches.rate, "interval95": [stretches.low, stretches.high],
                              "design_effect": stretches.design_effect},
                          "verdict": result.verdict, "interrupted": interrupted, "episodes": result.episodes},
                         indent=1))
    else:
        verdict = {"above": "ABOVE the target: this threshold alarms too often"
                            + _above_hint(threshold, noise, result.max_steps),
                   "below": "below the target",
                   "consistent": "consistent with the target (the interval holds it)"}[result.verdict]
        said = (f"interrupted: of the {args.episodes:,} episodes asked for, the first {result.episodes:,} were played "
                "whole, and are counted here\n" if interrupted else "")
        said += (f"{label}, {threshold.detector} detector, alarm when {threshold.rule_text}: "
                f"{result.alarmed} of {result.total} fresh ID {unit}{_up_to(result.max_steps)}{_noise(noise)}"
                f"{_other_noise(threshold, noise)} "
                f"alarmed, {result.rate:.1%} (95% interval {result.low:.1%}-{result.high:.1%}"
                f"{_clustered('steps', result.design_effect)})")
        if stretches is not None:  # the figure the bound speaks of, on a line of its own
            said += (f"; {result.alarms:,} alarm{'s' if result.alarms != 1 else ''} in {result.steps:,} steps\n"
                     f"the bound is for episodes like the calibration's ({stretches.length:,} steps on average): of "
                     f"the {stretches.total:,} stretches of {stretches.length:,} steps, {stretches.alarmed:,} alarmed, "
                     f"{stretches.rate:.1%} (95% interval {stretches.low:.1%}-{stretches.high:.1%}"
                     f"{_clustered('stretches', stretches.design_effect)})")
        Console(soft_wrap=True).print(
            said + f"; target {result.far:g}"
            + (f" with confidence {result.confidence:g}" if result.confidence is not None else " on average")
            + f": {verdict}", markup=False)


def _other_noise(threshold, obs_noise: float) -> str:
    """The words ' (calibrated with sensor noise Y)' where validation's noise is not the threshold's."""
    calibrated = threshold.calibration_noise
    return "" if calibrated == obs_noise else f" (calibrated with sensor noise {calibrated:g})"


def _above_hint(threshold, obs_noise: float, max_steps: int | None = None) -> str:
    """What to do about a threshold whose fresh rate lies above its target: calibrate in the world it
    watches, where validation played another sensor noise (0.1% noise put the demo's noiseless
    threshold above 100 of 100 fresh episodes, 2026-12-05: a draw of calibration episodes is not the
    reason then) or longer episodes (the docs' own CartPole controller, calibrated on its 500-step
    episodes: 29 of 314 stretches of 500 steps alarmed in episodes of up to 5,000, where its cart
    wanders further than in 500 steps; 2026-12-05); else how often calibration gives one, and how to
    get another."""
    calibrated = threshold.calibration_noise
    if calibrated != obs_noise:
        return (f" in a world of sensor noise {obs_noise:g}; its bound is for the world it was calibrated in, noise "
                f"{calibrated:g}: calibrate in this one (`oodmon calibrate --obs-noise {obs_noise:g}`)")
    if max_steps is not None and max_steps != threshold.max_steps:
        return (f" in episodes of up to {max_steps:,} steps; its bound is for episodes like its calibration's: calibrate "
                f"on episodes as long as these (`oodmon calibrate --max-steps {max_steps}`)")
    if threshold.confidence is None:
        return " (a threshold calibrated for the average rate often is: calibrate with --confidence 0.9)"
    about = "" if threshold.mode == "episode" else "about "  # (a large-sample limit of the steps: step_threshold)
    hint = (f" (calibration gives one this high with probability up to {about}{1 - threshold.confidence:.2g}: calibrate "
            "again on other episodes, --seed")
    if threshold.confidence < 0.99:
        hint += f", or for a surer bound, --confidence 0.99 --episodes {episodes_needed(threshold.far, 0.99)}"
    return hint + ")"


def _add_fit_detectors(commands: argparse._SubParsersAction) -> None:
    """`oodmon fit-detectors`."""
    fit = commands.add_parser(
        "fit-detectors", help="fit the learned detectors (dynamics or transitions, features, combined) on an agent's "
                              "ID episodes"
    )
    _agent_arguments(fit.add_argument_group("the policy it watches"), detectors=None)
    fit.add_argument("--only", type=_detector_names,
                     help="comma-separated detectors (default: all the agent can have but scaled_spread, fitted only "
                          "when named, and drift, named or in your own env; transitions instead of dynamics and drift "
                          "for discrete observations; stillness for pictures, for vectors when named; motion and "
                          "vanishing, for pictures, when named)")
    fit.add_argument("--episodes", type=_whole(3),
                     help=f"ID episodes: two thirds fit, one third ranks for combined ({_FIT_DEFAULT})")
    fit.add_argument("--max-steps", type=_whole(1),
                     help="each episode's time limit instead of the env's own: shorter cuts it (Pong: try 300), longer "
                          "lifts it (a deployment's long runs, as `calibrate --max-steps` plays them)")
    fit.add_argument("--score", default="chosen_std", help="the spread score combined uses (default chosen_std)")
    fit.add_argument("--obs-noise", type=_non_negative, default=0.0,
                     help="sensor noise of the ID env, a fraction of each dimension's ID spread (default 0)")
    _add_dynamics_updates(fit, "fitted on the episodes' two thirds")
    _add_explore(fit, "--explore", "in the episodes it plays")
    _add_workers(fit, "the fitting episodes")
    fit.add_argument("--from-logs", nargs="+", metavar="LOG",
                     help="fit on the whole ID episodes of these logs of the policy (MCAP files or folders: its "
                          "deployment's own world, `oodmon run --mcap`) instead of playing episodes; then calibrate "
                          "with `oodmon recalibrate` on other logs scored by these detectors")
    fit.add_argument("--last", type=_whole(1), metavar="N",
                     help="with --from-logs: fit on the latest N whole ID episodes only, by when they ended (after a "
                          "change in the deployment's world, those since; default: all)")
    fit.add_argument("--out", required=True, help="folder for detectors.json and detectors.safetensors")
    fit.add_argument("--overwrite", action="store_true",
                     help="replace the fitted detectors --out holds already; without it they are refused, since a "
                          "threshold calibrated with them is refused by `oodmon run` once they are replaced")
    fit.set_defaults(handler=_fit_detectors, kept_on_interrupt=_KEPT["fit-detectors"])


def _refuse_playing_options(args: argparse.Namespace) -> None:
    """Refuse fit-detectors' options of the episodes it plays where it fits on logs (--from-logs),
    which hold episodes played already: said, not ignored.

    Raises:
        ConfigError: naming the options given.
    """
    given = [flag for flag, value, default in (
        ("--episodes", args.episodes, None), ("--max-steps", args.max_steps, None),
        ("--obs-noise", args.obs_noise, 0.0), ("--workers", args.workers, 1), ("--score", args.score, "chosen_std"),
        ("--explore", args.explore, 0.0)) if value != default]
    if given:
        raise ConfigError(f"{' and '.join(given)} shape{'' if len(given) > 1 else 's'} the episodes fit-detectors "
                          "plays, and --from-logs fits on the logs' episodes as they were played (their number, "
                          "length, sensor noise and spread score): leave them out, or fit on played episodes without "
                          "--from-logs")


def _fitting_kept(folder: Path) -> Path:
    """Where a fit of detectors into ``folder``, interrupted, keeps its episodes: beside it (inside
    the file system's root, which has nothing beside it).

    Example:
        >>> _fitting_kept(Path("runs/det")).name, _fitting_kept(Path(".")).name == Path.cwd().name + ".kept.npz"
        ('det.kept.npz', True)
    """
    folder = folder.resolve()  # (``--out .`` has no name of its own)
    return folder / "kept.npz" if not folder.name else folder.with_name(folder.name + ".kept.npz")


@contextlib.contextmanager
def _kept_fitting(args: argparse.Namespace, kept: Path, written: str):
    """Says, where the fit inside is interrupted (Ctrl-C, SIGTERM, a worker's death), the fitting
    episodes it kept in ``kept`` (``args.kept_on_interrupt``), after ``written``: what it did not write."""
    try:
        yield
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:
        count = getattr(interrupt, "kept_episodes", 0)
        if count:
            args.kept_on_interrupt = (f"{written} (those at --out are as they were); the {count:,} detector fitting "
                                      f"episodes played whole are kept in {kept}: the same command goes on from them")
        raise


def _detector_names(text: str) -> tuple[str, ...]:
    """An argparse type: comma-separated detector names, each one oodmon has (said before the agent
    loads, and with the name meant where one is misspelt).

    Example:
        >>> _detector_names("dynamics, drift")
        ('dynamics', 'drift')
    """
    names = tuple(name.strip() for name in text.split(","))
    for name in names:
        if name not in DETECTOR_NAMES:
            raise argparse.ArgumentTypeError(unknown("detector", name, DETECTOR_NAMES))
    return names


def _calibrated_beside(folder: Path) -> str:
    """Words naming the threshold ``calibrate`` fitted ``folder`` for (``T.detectors`` beside ``T``), or ``""``."""
    folder = folder.resolve()  # (``--out .`` has no name of its own: a ValueError after the fit, 2026-12-05)
    if not folder.name.endswith(".detectors"):
        return ""
    threshold = folder.with_name(folder.name.removesuffix(".detectors"))
    if threshold.is_file():
        return f", those `oodmon calibrate` fitted for {threshold}"
    return ""


def _statistic_words(threshold) -> str:
    """What calibrate's line adds under a sequential rule, whose threshold is on its statistic's
    scale, not the score's: that statistic per calibration episode, its median and largest."""
    from oodmon.monitor.alarms import compared_name

    quantiles = threshold.quantiles
    if "statistic_max" not in quantiles:
        return ""
    return (f"; the {compared_name(threshold.rule_text)} per episode median {quantiles['statistic_q50']:.4g}, max "
            f"{quantiles['statistic_max']:.4g}")


def _fit_detectors(args: argparse.Namespace) -> int:
    from oodmon.monitor.detectors import fit_agent_detectors, fitting_notes
    from oodmon.outputs import check_output_dir

    out = check_output_dir(args.out, parameter="--out", create=False)  # (made by the save: none where stopped before)
    replacing = (out / "detectors.json").exists()
    if replacing and not args.overwrite:  # before minutes of fitting
        raise ConfigError(f"--out {out} holds fitted detectors already{_calibrated_beside(out)}: a threshold "
                          "calibrated with them would be refused by `oodmon run` once they are replaced; give another "
                          "folder, or --overwrite to replace them")
    if args.from_logs:
        _refuse_playing_options(args)
    elif args.last is not None:
        raise ConfigError("--last N chooses the latest of the logs' episodes (--from-logs LOG...); the episodes "
                          "fit-detectors plays are --episodes")
    agent = _load_agent(args, seed=DETECTOR_FIT)  # seeded MC sampling: the same command fits the same detectors
    only = list(args.only) if args.only else None
    kept = _fitting_kept(out)
    if args.from_logs:
        from oodmon.replay import fit_detectors_from_logs

        with _progress() as report:
            detectors = fit_detectors_from_logs(agent, args.from_logs, detectors=only, last=args.last,
                                                dynamics_updates=args.dynamics_updates, on_progress=report)
    else:
        with _progress() as report, _kept_fitting(args, kept, "no detectors were written"):
            detectors = fit_agent_detectors(agent, detectors=only, episodes=args.episodes, score=args.score,
                                            obs_noise=args.obs_noise, max_steps=args.max_steps, on_progress=report,
                                            workers=args.workers, dynamics_updates=args.dynamics_updates, kept=kept,
                                            explore=args.explore)
    with stops_held():  # (as calibrate's)
        detectors.save(args.out)
        kept.unlink(missing_ok=True)
        args.kept_on_interrupt = _ended("fitting", f"the detectors are written to {args.out}")
    console = Console(soft_wrap=True)
    beside = _calibrated_beside(out)  # after the fitting: the threshold beside as it is now
    replaced = "" if not replacing else f" (replacing the set it held{beside}: calibrate that threshold again)" if beside \
        else " (replacing the set it held)"
    logs = detectors.fitted_for.get("logs")
    of_logs = f" of {len(logs)} log file{'s' if len(logs) > 1 else ''}" if logs else ""
    console.print(f"{args.task}/{agent.method}: fitted {', '.join(detectors.names)} on "
                  f"{detectors.fitted_for['episodes']} ID episodes{_up_to(args.max_steps)}{of_logs}"
                  f"{_noise(detectors.fitted_for['obs_noise']) if logs else ''}"
                  f"{_side_by_side(detectors.fitted_for.get('workers'))}"
                  f"{_explored(detectors.fitted_for.get('explore'), 'their steps')}; wrote {args.out}{replaced}")
    if logs and (said := _left_out_said(detectors.fitted_for.get("left_out", {}))):
        Console(stderr=True, soft_wrap=True).print(f"note: {said}", markup=False)
    for note in fitting_notes(detectors):
        console.print(note, markup=False)
    return 0
