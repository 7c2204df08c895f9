"""``oodmon bench``: the paper's protocol, or the monitor's, over trials, methods and variants."""

from __future__ import annotations

import argparse
import json
import os
import sys
from concurrent.futures.process import BrokenProcessPool

from oodmon.cli.display import _progress, _table_console
from oodmon.cli.loading import _load_agent
from oodmon.cli.parsing import (
    _FAILURES, _FIT_DEFAULT, _KEPT, _STEP_COUNT, _UNSET, _WARMUP, _add_confidence, _add_dynamics_updates, _add_explore,
    _add_rule, _command_line, _fraction, _non_negative, _sb3_arguments, _policy_argument, _whole, _widths,
)
from oodmon.errors import ConfigError
from oodmon.jsonfile import write_json
from oodmon.monitor.threshold import DETECTOR_NAMES
from oodmon.names import MASKS, METHODS, PLAIN_METHOD, TASKS


def _add_bench(commands: argparse._SubParsersAction) -> None:
    """`oodmon bench`."""
    bench = commands.add_parser("bench", help="the paper's protocol (trials x methods x failing variants, scored by "
                                              "replay) or the monitor's own (--protocol monitor: false alarms, alarms "
                                              "before failure, delays)")
    what = bench.add_argument_group("what is benched")
    world = bench.add_argument_group("the shifts and episodes")
    alarm = bench.add_argument_group("the detectors and the alarm")
    where = bench.add_argument_group("where it runs")
    out = bench.add_argument_group("results")
    what.add_argument("--task", choices=TASKS, help="required unless --sb3")
    what.add_argument("--methods", default="dropout,dropconnect,ensemble", help="comma-separated (default all three)")
    _sb3_arguments(what)
    _policy_argument(what)
    what.add_argument("--trials", type=_whole(1),
                      help="trials per method (default 5; trial 0 is the zoo agent; --sb3: 1, nothing is trained)")
    what.add_argument("--samples", type=_whole(2), metavar="K",
                      help="MC samples per decision of the Dropout and DropConnect agents (default: each recipe's, "
                           "20); the decisions are their mean, so episodes change too, and a decision costs more "
                           "(CartPole DropConnect: 0.3 ms at K=20, 9 ms at K=400)")
    what.add_argument("--masks", choices=MASKS,
                      help="MC masks of the Dropout and DropConnect agents, and of one --sb3 model with dropout "
                           "(default: each model's, sampled): fixed draws K masks once, so that sample k is the same "
                           "sub-network at every decision (the decisions stay the mean of freshly sampled masks); "
                           "fixed-decisions: the same K fixed sub-networks decide too, by their mean (one pass)")
    what.add_argument("--members", type=_whole(2), metavar="K",
                      help="members of each ensemble trial (default: the recipe's, 5); another size trains every "
                           "trial, trial 0 too (member k has the same seed at any size: members trained before are "
                           "kept), and a decision costs K members' forward passes")
    what.add_argument("--net-arch", type=_widths, metavar="W,W",
                      help="hidden widths of every trial's network, e.g. 64,64 (default: each recipe's, CartPole "
                           "[256, 256], Pendulum [400, 300]); other widths train every trial, trial 0 too")
    world.add_argument("--variants", default="paper",
                       help="'paper' (the paper's grid) or comma-separated specs (cartpole:gravity=20.0,length=2.0 "
                            "is one); your own --env: its shifts, e.g. Acrobot-v1:LINK_MASS_2=2.0,Acrobot-v1:LINK_MASS_2=3.0; "
                            "--sb3/--policy on a task's own id (--env CartPole-v1): its variants and shifts of that "
                            "env's other attributes, e.g. CartPole-v1:theta_threshold_radians=0.1")
    world.add_argument("--failure", choices=_FAILURES,
                       help="your own --env: what fails in it, for the alarms before the failure (blank without "
                            "it): terminated, the env ended the episode itself after the onset (a fall, a crash)")
    world.add_argument("--onsets", type=_onsets, metavar="LOW,HIGH",
                       help="monitor protocol: each shifted episode shifts at a step drawn from [LOW, HIGH) (default: "
                            "the task's, CartPole 20,200, Pendulum 100,150, Pong 100,1000; your own --env: required)")
    world.add_argument("--protocol", choices=["paper", "monitor"], default="paper",
                       help="paper (default): shifted from step 0, per-step AUROC; monitor: the monitor's own benchmark, "
                            "each shifted episode shifts at a random onset, alarms before failure and delays, "
                            "the false-alarm rate over many ID episodes, the task's best detector")
    world.add_argument("--episodes", type=_whole(1), help="episodes per failing variant (default 5; monitor: 10)")
    world.add_argument("--all-variants", action="store_true",
                       help="monitor (the paper's protocol: score) every variant in every trial, not only those the "
                            "trial's agent fails on; the tables say how many trials fail (the paper scored its five "
                            "trials on the variants its trained model failed on; Pong's corruptions: an alarm is "
                            "wanted whether or not the return drops)")
    world.add_argument("--id-episodes", type=_whole(1), help="ID episodes per trial (default 10; monitor: 200)")
    alarm.add_argument("--calibration-episodes", type=_whole(1),
                       help="ID episodes the threshold is calibrated on (default 45; monitor protocol: 90)")
    alarm.add_argument("--far", type=_fraction, default=0.05, help="the alarm's target false-alarm rate (default 0.05)")
    _add_confidence(alarm, default="0.9; monitor protocol: 0.99, so that the rate of 200 ID episodes shows the bound")
    where.add_argument("--workers", type=_whole(0), default=0,
                       help="worker processes for the trainings, the trials' preparations and the cells; one trial "
                            "(--trials 1, one method) of an agent that draws nothing (an ensemble; SB3 models without "
                            "dropout) plays its fitting, calibration and evaluation episodes in them (default 0: one per "
                            "core)")
    alarm.add_argument("--score", default="chosen_std",
                       help="chosen_std (the paper's, default), mean_std, max_std, margin_std (DQN) or pre_squash_std (DDPG)")
    alarm.add_argument("--window", type=_STEP_COUNT,
                       help="alarm rule on the mean score of the last N steps (default 1; Pong 200 for the spread and "
                            "features detectors); AUROCs do not change")
    alarm.add_argument("--detectors",
                       help="comma-separated detectors whose per-step AUROC is reported: spread (the paper's protocol's "
                            "default), dynamics, features, frames, combined, scaled_spread (ensembles, MC agents with --masks "
                            "fixed), drift (the dynamics model's residuals' bias), transitions (discrete states), stillness "
                            "(a sensor or camera unchanged longer than in ID episodes), motion and vanishing (parts of "
                            "a picture frozen); the learned "
                            "ones are fitted per trial on ID episodes of their own (monitor protocol's default: spread "
                            "and the task's best)")
    alarm.add_argument("--fit-episodes", type=_whole(3), default=0,
                       help=f"ID episodes the learned detectors are fitted on, per trial ({_FIT_DEFAULT})")
    _add_dynamics_updates(alarm, "fitted per trial")
    _add_explore(alarm, "--fit-explore", "per trial")
    alarm.add_argument("--alarm-detector", choices=list(DETECTOR_NAMES),
                       help="the detector the monitor's alarm reads, one of --detectors (default spread; monitor "
                            "protocol: the task's best)")
    _add_rule(alarm)
    alarm.add_argument("--consecutive", type=_STEP_COUNT,
                       help="m of the alarm rule (default 3 for the spread detector, 1 for a learned one)")
    alarm.add_argument("--warmup", type=_WARMUP, default=0,
                       help="the alarm looks at no score of an episode's first N steps (but a NaN reading's; default 0)")
    world.add_argument("--obs-noise", type=_non_negative, default=0.0,
                       help="sensor noise in every monitored env, a fraction of each dimension's ID spread (default 0)")
    where.add_argument("--executor", choices=["local", "ray"], default="local",
                       help="local worker processes (default) or Ray tasks on one cluster (needs oodmon[ray])")
    where.add_argument("--address", help="the Ray cluster to use, HOST:PORT as `ray start --head` prints it (default: "
                                          "RAY_ADDRESS if set, else a local cluster of the bench's own)")
    where.add_argument("--bind", default="127.0.0.1",
                       help="address a local Ray cluster listens on (default 127.0.0.1: this machine only)")
    out.add_argument("--out", default="runs/bench", help="models, logs and report (default runs/bench)")
    out.add_argument("--json", action="store_true", help="print JSON instead of tables")
    out.add_argument("--results", metavar="FILE",
                     help="also write the result as JSON to FILE (per trial AUROC, AUPR, FPR@95TPR, the alarms, the "
                          "settings and this command): results as data, what --baseline reads")
    out.add_argument("--baseline", metavar="FILE",
                     help="a result --results wrote earlier: exit 1, naming each figure, where this run falls below it "
                          "(a run of some of its methods is compared on their rows)")
    out.add_argument("--tolerance", type=_non_negative,
                     help="--baseline's allowed fall of AUROC, AUPR and rates, and relative rise of delays (default 0.02)")
    bench.set_defaults(handler=_bench, kept_on_interrupt=_KEPT["bench"])


PREPARING = "models, detectors, thresholds and failing variants of trials"  # the bench's second stage, as it reports it


def _bench_kept(reached: dict[str, tuple[int, int]]) -> str:
    """What an interrupted bench keeps, by the latest counts of its stages (``reached``): before, it
    said "trained models and finished cells are kept" of a bench stopped before either (2026-12-06).

    Example:
        >>> print(_bench_kept({"trained trial models": (2, 2), "monitored cells": (7, 30)}))
        the trial models, their thresholds and 7 of the 30 monitored cells are kept: the same command
        goes on from them
        >>> print(_bench_kept({"trained trial models": (1, 4)}))
        1 of the 4 trial models is trained and kept (a training under way goes on from its last
        checkpoint, if it wrote one): the same command goes on from them

    A bench that trains nothing (trial 0, the shipped agent, or trained before) and was stopped as it
    fitted its trials' detectors said "trained models and finished cells are kept" until 2026-12-06:
    it now counts its trials prepared, each kept as it is done::

        >>> print(_bench_kept({PREPARING: (1, 3)}))
        the trial models and 1 of the 3 trials' fitted detectors, thresholds and failing variants are
        kept: the same command goes on from them
    """
    resume = ": the same command goes on from them"
    if "monitored cells" in reached:
        done, total = reached["monitored cells"]
        return f"the trial models, their thresholds and {done:,} of the {total:,} monitored cells are kept{resume}"
    if PREPARING in reached:
        done, total = reached[PREPARING]
        return (f"the trial models and {done:,} of the {total:,} trials' fitted detectors, thresholds and failing "
                f"variants are kept{resume}")
    if "trained trial models" in reached:
        done, total = reached["trained trial models"]
        trained = ("no trial model was trained yet" if not done
                   else f"{done:,} of the {total:,} trial models {'is' if done == 1 else 'are'} trained and kept")
        return f"{trained} (a training under way goes on from its last checkpoint, if it wrote one){resume}"
    return _KEPT["bench"]


def _bench(args: argparse.Namespace) -> int:
    from oodmon.bench import BenchConfig, run_bench
    from oodmon.monitor.alarms import default_window
    from oodmon.monitor.detectors import BEST_DETECTOR
    from oodmon.errors import UnknownParameterError, unknown

    methods = tuple(m.strip() for m in args.methods.split(","))
    for method in methods:
        if method not in METHODS:
            raise UnknownParameterError(unknown("method", method, METHODS, " in --methods"))
    samples = True  # the agents have samples of their own to spread
    if args.sb3 or args.policy:
        samples = _sb3_bench_task(args)
        methods = ("sb3",) if args.sb3 else (PLAIN_METHOD,)
    elif args.task is None:
        raise ConfigError("give --task (or --sb3 with --env for your own SB3 models, --policy with --env for a policy "
                          "of your own of any kind)")
    variants = "paper" if args.variants == "paper" else _split_specs(args.variants)
    monitor = args.protocol == "monitor"
    if args.onsets is not None and not monitor:
        raise ConfigError("--onsets draws each shifted episode's onset under the monitor's protocol (the paper's "
                          "shifts from step 0): add --protocol monitor")
    best = BEST_DETECTOR.get(args.task, "combined") if monitor or not samples else "spread"
    alarm_detector = args.alarm_detector or best
    detectors = (tuple(d.strip() for d in args.detectors.split(",")) if args.detectors
                 else tuple(dict.fromkeys(("spread", alarm_detector) if samples else (alarm_detector,))))
    # Ray's own variable, as ray.init() reads it; never a cluster Ray would find by its files (`ray start`'s)
    address = args.address or None
    if address is None and args.executor == "ray":
        address = os.environ.get("RAY_ADDRESS") or None
    config = BenchConfig(args.task, methods, args.trials or (1 if args.sb3 or args.policy else 5), variants,
                         args.episodes or (10 if monitor else 5), args.id_episodes or (200 if monitor else 10),
                         out=args.out, workers=args.workers,
                         executor=args.executor, address=address, bind=args.bind, score=args.score,
                         window=args.window or default_window(args.task, alarm_detector), detectors=detectors,
                         alarm_detector=alarm_detector, obs_noise=args.obs_noise,
                         calibration_episodes=args.calibration_episodes or (90 if monitor else 45), far=args.far,
                         confidence=(0.99 if monitor else 0.9) if args.confidence == _UNSET else args.confidence,
                         protocol=args.protocol, rule=args.rule, consecutive=args.consecutive,
                         all_variants=args.all_variants, sb3=tuple(args.sb3 or ()), env_id=args.env, mean=args.mean,
                         vec_normalize=args.vec_normalize, frame_stack=args.frame_stack,
                         imports=tuple(args.imports), unsafe_load_pickles=args.unsafe_load_pickles, policy=args.policy,
                         samples=args.samples, members=args.members,
                         net_arch=args.net_arch, fit_episodes=args.fit_episodes,
                         dynamics_updates=args.dynamics_updates, fit_explore=args.fit_explore,
                         masks=args.masks, onsets=args.onsets, failure=args.failure, warmup=args.warmup)
    config.variant_list()  # refuse bad specs before any work
    from oodmon.bench.baseline import (BASELINE_TOLERANCE, bench_falls, check_same_settings, load_bench_result,
                                       methods_left_out, provenance_notes)
    from oodmon.outputs import check_output_dir, check_output_file, replaced_file

    check_output_dir(args.out, parameter="--out")
    if args.tolerance is not None and not args.baseline:
        raise ConfigError("--tolerance is the allowed fall against --baseline FILE; give the baseline too")
    baseline = load_bench_result(args.baseline) if args.baseline else None  # a bad baseline fails before hours of work
    if baseline is not None:
        check_same_settings(config.what_made_the_numbers(), baseline, args.baseline)
    if args.results:
        check_output_file(args.results, parameter="--results", inputs=[("--baseline", args.baseline)])
        replaced_file(args.results, parameter="--results", holds="bench result", read=load_bench_result)
    with _progress() as report:
        reached: dict[str, tuple[int, int]] = {}  # what an interrupt keeps, by the stages' latest counts

        def reporting(stage: str, done: int, total: int, *note) -> None:
            if stage in ("trained trial models", PREPARING, "monitored cells"):
                reached[stage] = (done, total)
            report(stage, done, total, *note)

        try:
            result = run_bench(config, on_progress=reporting)
        except (KeyboardInterrupt, BrokenProcessPool):
            args.kept_on_interrupt = _bench_kept(reached)
            raise
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
    within: list[str] = []
    falls = bench_falls(data, baseline, tolerance, baseline_name=args.baseline, within=within)
    left_out = methods_left_out(data, baseline)
    if left_out:
        print(f"oodmon bench: {args.baseline}'s rows of {', '.join(left_out)} not compared (not run: --methods "
              f"{','.join(config.methods)})", file=sys.stderr)
    for line in within:
        print(f"within chance: {line}", file=sys.stderr)
    for line in falls:
        print(f"FELL {line}", file=sys.stderr)
    if falls:
        for note in provenance_notes(data, baseline, args.baseline):
            print(f"note: {note}", file=sys.stderr)
        print(f"oodmon bench: {len(falls)} figure(s) fell below {args.baseline}", file=sys.stderr)
        return 1
    chance = f"; {len(within)} move(s) beyond it were within chance" if within else ""
    print(f"oodmon bench: every figure of {args.baseline} held (tolerance {tolerance}{chance})", file=sys.stderr)
    return 0


def _split_specs(text: str) -> tuple[str, ...]:
    """``--variants``' comma-separated specs, a spec's own further assignments kept with it.

    Example:
        >>> _split_specs("cartpole:gravity=20.0,length=2.0,cartpole:force_mag=1.0")
        ('cartpole:gravity=20.0,length=2.0', 'cartpole:force_mag=1.0')
    """
    specs: list[str] = []
    for piece in text.split(","):
        if specs and ":" not in piece and "=" in piece:  # NAME=VALUE of the spec before it
            specs[-1] += f",{piece}"
        else:
            specs.append(piece)
    return tuple(specs)


def _onsets(text: str) -> tuple[int, int]:
    """An argparse type: ``LOW,HIGH``, whole numbers 0 <= LOW < HIGH."""
    low, comma, high = text.partition(",")
    try:
        pair = (int(low), int(high))
    except ValueError:
        pair = None
    if not comma or pair is None or not 0 <= pair[0] < pair[1]:
        raise argparse.ArgumentTypeError(f"{text!r} is not LOW,HIGH: two whole numbers 0 <= LOW < HIGH, e.g. 20,100")
    return pair


def _sb3_bench_task(args: argparse.Namespace) -> bool:
    """For ``bench --sb3`` (or ``--policy``): set ``args.task`` from ``--env`` (the bench plays oodmon's variants of
    that task, or for your own env its shifts, under the monitor's protocol); True where the models
    have samples of their own (the spread detector applies)."""
    from oodmon.bench.config import check_own_env_bench
    from oodmon.envs.registration import task_of_env

    task = task_of_env(args.env) if args.env else None
    if args.env and task is None:  # said before the models load
        check_own_env_bench(args.env, args.protocol, args.onsets, args.variants, args.obs_noise, said="--env ")
    return _load_agent(args).estimator is not None
