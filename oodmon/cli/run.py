"""``oodmon run`` (a monitored agent in an env, logged) and ``oodmon demo``."""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from collections import Counter, deque
from contextlib import nullcontext
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from oodmon.cli.display import _stretches_said
from oodmon.cli.loading import _agent_from_threshold, _check_agent_from_threshold, _detectors, _input_files, _load_agent
from oodmon.cli.parsing import (
    _KEPT, _LOGGED, _SEED, _add_reading_names, _agent_arguments, _non_negative, _positive, _whole,
)
from oodmon.errors import ConfigError
from oodmon.names import TASKS


def _add_run(commands: argparse._SubParsersAction) -> None:
    """`oodmon run`."""
    run = commands.add_parser("run", help="run a monitored agent in an env (ID or shifted), logging to MCAP/Rerun")
    _agent_arguments(run.add_argument_group("the policy it watches"), defaults_from="--threshold's")
    world = run.add_argument_group("the episodes")
    alarm = run.add_argument_group("the alarm")
    logs = run.add_argument_group("the logs")
    viewer = run.add_argument_group("live, in a Rerun viewer")
    world.add_argument("--variant", help="a variant spec (default: the task's ID env), e.g. cartpole:length=2.0; "
                                         "your own --env: ENV_ID:NAME=VALUE[,...], numeric attributes of its env "
                                         "set to other values from --onset on, e.g. Acrobot-v1:LINK_MASS_2=3.0, "
                                         "or sensor faults, e.g. 'Acrobot-v1:obs.bias[4]=0.5' (obs.bias, obs.scale, "
                                         "obs.noise, obs.stuck; of discrete values: a misread's probability "
                                         "'Taxi-v4:obs.noise=0.1'; of a dict, by key: 'ENV_ID:obs.KEY.stuck=1'); or "
                                         "another registered env's id, of the same spaces, deployed in from its "
                                         "reset, each step shifted, e.g. MiniGrid-DistShift2-v0 for --env "
                                         "MiniGrid-DistShift1-v0")
    world.add_argument("--onset", type=_whole(0), default=0, help="step at which the --variant's shift begins (default 0)")
    world.add_argument("--obs-noise", type=_non_negative,
                       help="sensor noise in every episode, ID or shifted, a fraction of each reading's ID spread "
                            "(CartPole, Pendulum; default: --threshold's, `calibrate --obs-noise`, else 0)")
    world.add_argument("--max-steps", type=_whole(1),
                       help="each episode's time limit instead of the env's own, as long as your deployment's runs "
                            "(default: --threshold's, `calibrate --max-steps`, else the env's own)")
    world.add_argument("--episodes", type=_whole(1), default=5, help="episodes (default 5)")
    world.add_argument("--seed", type=_SEED, default=0, help="seed of the first episode and of an MC agent's samples "
                                                             "(default 0): the same command plays the same episodes")
    alarm.add_argument("--threshold", help="a threshold file from `oodmon calibrate` (default: no alarms)")
    alarm.add_argument("--on-alarm", metavar="CMD",
                       help="a shell command run at each episode's first alarm, not waited for (the policy acts on; "
                            "at the end the run waits 10 s at most for those still running and says how they "
                            "ended): a page, a message, a hand-over. Its environment holds OODMON_EPISODE, "
                            "OODMON_STEP, OODMON_SCORE, OODMON_THRESHOLD, OODMON_RULE, OODMON_CAUSE, "
                            "OODMON_READINGS (the readings the dynamics model predicted worst), OODMON_ALARM "
                            "(the alarm's line), OODMON_VARIANT and OODMON_LOG (--mcap as given), e.g. "
                            "--on-alarm 'notify-send \"$OODMON_ALARM\"'")
    logs.add_argument("--mcap", help="write the run to this MCAP file; {start} in it is the run's start time "
                                     "(YYYYmmdd-HHMMSS): a log per start, e.g. runs/deployed/log-{start}.mcap")
    logs.add_argument("--mcap-split-episodes", type=_whole(1), metavar="N",
                      help="split the MCAP log into files of N whole episodes: <name>-00000.mcap, <name>-00001.mcap, ... "
                           "(a long run; `oodmon replay` reads them from their folder)")
    logs.add_argument("--mcap-split-mb", type=_positive, metavar="MB",
                      help="start the next MCAP file after the episode that takes one to MB megabytes (as above)")
    logs.add_argument("--rrd", help="write the run to this Rerun file ({start}: as in --mcap)")
    logs.add_argument("--rrd-no-footer", action="store_true",
                      help="write the --rrd file without Rerun's footer, whose index of chunks Rerun keeps in memory "
                           "until the run ends (8 bytes a step in CartPole's ID episodes played at full speed, some "
                           "72 MB a day at 50 decisions a second): a long run's memory stays flat; the file opens as "
                           "a killed run's does, and `rerun rrd optimize` adds a footer")
    logs.add_argument("--overwrite", action="store_true",
                      help="replace the logs of an earlier run at --mcap (all its parts, if split) and --rrd; "
                           "without it an existing log is refused, so that a run started again after a crash "
                           "cannot replace the log of the run that crashed (a command that a service manager "
                           "starts again: put {start} in the names)")
    live = viewer.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true", help="stream to a Rerun viewer started for it")
    live.add_argument("--serve", action="store_true", help="serve the stream for a remote Rerun viewer")
    live.add_argument("--connect", metavar="URL", help="stream to a running Rerun viewer at URL")
    viewer.add_argument("--bind", default="127.0.0.1",
                        help="address --serve, or --spawn's viewer, listens on (default 127.0.0.1: this machine only; "
                             "0.0.0.0 opens it)")
    viewer.add_argument("--port", type=_whole(1, 65535), default=9876,
                        help="port --serve, or --spawn's viewer, listens on (default 9876)")
    viewer.add_argument("--serve-memory", type=_whole(0), metavar="MIB", default=None,
                        help="MiB of the --serve stream kept for viewers that connect later, the earliest dropped "
                             "beyond (default 512: some 630 MB of the process after 3-5 million CartPole steps); "
                             "0 keeps none")
    alarm.add_argument("--force", action="store_true",
                       help="use a threshold calibrated for another task, method, score or weights (with a warning)")
    _add_reading_names(alarm, default="the threshold's, from `oodmon calibrate --reading-names`; the names of an "
                                      "env whose layout is known, a dict observation's keys")
    logs.add_argument("--strict", action="store_true", help="a failing sink stops the run instead of warning")
    logs.add_argument("--render", action="store_true",
                      help="log a picture of each CartPole or Pendulum state beside the scores (Rerun, Foxglove)")
    run.set_defaults(handler=_run, kept_on_interrupt=_KEPT["run"])


def _run(args: argparse.Namespace) -> int:
    # (stopped as it loads, it said "every finished episode is in the logs" of none until 2026-12-06)
    args.kept_on_interrupt = "nothing was written: it was stopped before its first episode"
    from rich.progress import Progress

    from oodmon.envs.shift import same_env, shifts_an_env
    from oodmon.monitor import (
        AlarmCommand, McapSink, Monitor, OffCalibrationWarning, Stretches, Threshold,
    )
    from oodmon.monitor.sinks.base import refuse_earlier_logs
    from oodmon.monitor.sinks.mcap import existing_parts, part_path
    from oodmon.monitor.sinks.rerun import RerunSink
    from oodmon.outputs import check_output_file
    from oodmon.replay.metrics import is_id_variant

    inputs = _input_files(args)
    started = _start_time()  # {start} in the logs' names
    args.mcap, args.rrd = (name and name.replace("{start}", started) for name in (args.mcap, args.rrd))
    if (args.mcap_split_episodes or args.mcap_split_mb) and not args.mcap:
        raise ConfigError("--mcap-split-episodes and --mcap-split-mb split an MCAP log: give --mcap too")
    if args.rrd_no_footer and not args.rrd:
        raise ConfigError("--rrd-no-footer is for the Rerun file of --rrd (a live viewer's stream has no footer): "
                          "give --rrd too")
    if args.serve_memory is not None and not args.serve:
        raise ConfigError("--serve-memory is the memory of the stream --serve serves: give --serve too")
    if args.onset and not args.variant:  # the run played the ID world, its table headed "onset N"
        raise ConfigError(f"--onset {args.onset} is the step a shift begins at, and no --variant names one: give the "
                          "shifted world (--variant cartpole:length=2.0, or ENV_ID:NAME=VALUE of your own env), or "
                          "leave out --onset for an ID run")
    splits = bool(args.mcap_split_episodes or args.mcap_split_mb)
    if args.mcap:  # said in the CLI's words before the sinks are made
        check_output_file(part_path(args.mcap, 0, splits=splits), parameter="--mcap", inputs=inputs)
    if args.rrd:
        check_output_file(args.rrd, parameter="--rrd", inputs=[*inputs, ("--mcap", args.mcap)])
    if not args.overwrite:  # an earlier run's log, whole or split
        refuse_earlier_logs((existing_parts(args.mcap, splits=splits) if args.mcap else [])
                            + ([Path(args.rrd)] if args.rrd and Path(args.rrd).exists() else []), "--overwrite")
    # Without --overwrite the sinks check again when the run starts, once the inputs have loaded, and
    # claim their files then: a run started beside this one with the same names cannot share them.
    mcap = McapSink(args.mcap, split_episodes=args.mcap_split_episodes, split_mb=args.mcap_split_mb,
                    overwrite=args.overwrite) if args.mcap else None
    threshold = Threshold.load(args.threshold) if args.threshold else None
    from_threshold = threshold is not None and _agent_from_threshold(args, threshold, args.threshold)
    if threshold is not None:
        args.masks = args.masks or threshold.masks
    agent = _load_agent(args, seed=args.seed)  # seeded MC sampling: the same command, the same episodes
    if from_threshold:
        _check_agent_from_threshold(args, threshold, args.threshold, agent)
    if args.render and args.task not in ("cartpole", "pendulum"):  # it logged no picture, without a word
        raise ConfigError(f"--render draws CartPole and Pendulum states; {args.task} has no drawing in oodmon"
                          + (" (Pong's frames are logged without it)" if args.task == "pong" else "")
                          + ": leave out --render")
    if args.obs_noise is None:  # the world the threshold was calibrated in
        args.obs_noise = threshold.calibration_noise if threshold is not None else 0.0
    if args.max_steps is None and threshold is not None:  # and the length of its episodes
        args.max_steps = threshold.max_steps
    env, label = _run_env(args, agent)
    detectors = _detectors(args, agent, threshold)
    if threshold is not None and (not args.variant or args.onset or label == args.task):  # ID steps: false alarms
        _warn_if_reused(threshold, detectors, args.seed, args.episodes)
    if threshold is not None and threshold.step_mode_warning:
        warnings.warn(threshold.step_mode_warning, UserWarning, stacklevel=2)
    if args.on_alarm is not None and not args.on_alarm.strip():
        raise ConfigError(f"--on-alarm {args.on_alarm!r} is not allowed; give a shell command to run at each "
                          "episode's first alarm, e.g. --on-alarm 'notify-send \"$OODMON_ALARM\"'")
    if args.on_alarm is not None and threshold is None:
        raise ConfigError("--on-alarm runs its command at an alarm, and a run without --threshold raises none: give "
                          "--threshold (a file `oodmon calibrate` writes)")
    command = None if args.on_alarm is None else AlarmCommand(
        args.on_alarm, env={"OODMON_VARIANT": label} | ({"OODMON_LOG": args.mcap} if args.mcap else {}))
    sinks = [] if mcap is None else [mcap]
    if args.rrd or args.spawn or args.serve or args.connect:
        sinks.append(RerunSink(path=args.rrd, spawn=args.spawn, serve=args.serve, connect=args.connect,
                               bind=args.bind, port=args.port, overwrite=args.overwrite,
                               footer=not args.rrd_no_footer,
                               **({} if args.serve_memory is None else {"serve_memory": args.serve_memory})))
    console = Console(soft_wrap=True)
    onset = f", onset {args.onset}" if args.variant else ""  # (an ID run has none)
    rows = _EpisodeRows(calibrated=threshold.covered_steps if threshold is not None else None,
                        stretch=threshold.mean_episode if threshold is not None else None,
                        id_run=is_id_variant(label) and same_env(label, agent.task))

    def show(event) -> None:
        rows.alarm(event)
        progress.console.print(f"[bold red]ALARM[/bold red] {escape(event.text())}")

    interrupt = None
    args.kept_on_interrupt = _LOGGED if sinks else "no log was written (--mcap or --rrd keeps every step)"
    with warnings.catch_warnings(), command or nullcontext(), Progress(console=console, transient=True) as progress, \
            Monitor(agent, threshold, detectors=detectors, sinks=sinks, callbacks=[show, *filter(None, [command])],
                    strict=args.strict, force=args.force, render=args.render,
                    reading_names=args.reading_names) as monitor:
        warnings.simplefilter("ignore", OffCalibrationWarning)  # another noise, longer episodes: notes at the end
        if args.serve:
            progress.console.print(f"serving the Rerun stream at {sinks[-1].served_at}")
        elif args.spawn and sinks[-1].live_at:
            ours = f"started for this run, listening on {args.bind}:{args.port}"  # a viewer found there: its own
            progress.console.print(f"streaming to the Rerun viewer at {sinks[-1].live_at} ("
                                   + (ours if sinks[-1].viewer is not None else "one already running there") + ")")
        bar = progress.add_task(f"{label}{onset}", total=args.episodes)
        decisions = progress.add_task("decisions in this episode", total=None)  # a Pong game is thousands

        def count(stage: str, steps: int, total: int) -> None:
            if steps % 50 == 0:
                progress.update(decisions, completed=steps)
        try:
            for episode in range(args.episodes):
                progress.reset(decisions, total=None, description=f"episode {episode}: decisions")
                rows.add(monitor.run_episode(env, seed=args.seed + episode, on_progress=count))
                progress.update(bar, advance=1)
        except KeyboardInterrupt as stop:  # Ctrl-C, SIGTERM: the files are finished as at the end (the cut
            if not rows.episodes:  # episode marked), and the episodes played whole, if any, are said below
                raise
            interrupt = stop
    failures = dict(monitor.sinks.failures)  # after the sinks closed: a file that could not be finished counts
    env.close()
    files = {"McapSink": _files_written(mcap), "RerunSink": args.rrd}
    written = [str(p) for name, p in files.items() if p and name not in failures]
    console.print(rows.table(("interrupted: " if interrupt is not None else "")
                             + f"{args.task}/{agent.method} in {label}{onset}"
                             + (f", sensor noise {args.obs_noise:g}" if args.obs_noise else "")
                             + (f", episodes of up to {args.max_steps:,} steps" if args.max_steps else "")
                             + (f", {threshold.detector} detector: {threshold.rule_text}" if threshold
                                else ", no threshold")))
    if rows.left_out:
        console.print(f"{rows.left_out} episode{'s' if rows.left_out != 1 else ''} not shown"
                      + _listed_by(mcap, args.mcap, failed="McapSink" in failures))
    if threshold is not None:
        first_alarms = rows.first_alarms()
        said = f"{rows.alarmed} of {rows.episodes} episodes raised an alarm" + (
            f"; {first_alarms}" if first_alarms else "") + (f"; written to {', '.join(written)}" if written else "")
    else:  # "0 of 3 episodes raised an alarm" read as if the shift had gone unseen
        said = ("no threshold, so no alarm (for alarms give --threshold, a file `oodmon calibrate` writes for this "
                "agent)" + (f"; every step's scores written to {', '.join(written)}" if written else ""))
    console.print(said, markup=False)
    if args.rrd_no_footer and "RerunSink" not in failures:
        whole = Path(args.rrd).with_name(Path(args.rrd).stem + "-footer.rrd")
        console.print(f"note: {args.rrd} has no footer (--rrd-no-footer): Rerun reads it from its start; `rerun rrd "
                      f"optimize {args.rrd} -o {whole}` writes it again with one", markup=False)
    if threshold is not None and threshold.calibration_noise != args.obs_noise:  # the bound is for another world
        console.print(f"note: this run played sensor noise {args.obs_noise:g}, and {args.threshold} was calibrated "
                      f"with {threshold.calibration_noise:g}: its false-alarm bound is for that world (`oodmon validate "
                      f"{args.threshold} --obs-noise {args.obs_noise:g}` counts this one's)", markup=False)
    if rows.longer:  # the bound is for episodes like the calibration's: what it speaks of, counted
        stretches = Stretches.of_sums(rows.stretches, rows.stretch) if rows.stretches.clusters else None
        counted = (f"; counted by stretches of {rows.stretch:,} steps (a calibration episode's on average), this "
                   f"run's ID episodes: {_stretches_said(stretches, threshold.far)}" if stretches else "")
        console.print(f"note: {rows.longer} of {rows.episodes} episodes ran past {rows.calibrated:,} steps, the "
                      f"longest of {args.threshold}'s calibration episodes: its false-alarm bound is for episodes like "
                      f"those (`oodmon validate {args.threshold} --max-steps {rows.longest}` counts its false alarms "
                      f"in runs this long, `oodmon calibrate ... --max-steps {rows.longest}` calibrates on them){counted}",
                      markup=False)
    if rows.before_onset:
        # (replay's detection rates leave them out; their alarms count as early ones)
        console.print(f"note: {rows.before_onset} of {rows.episodes} episodes ended before step {args.onset}, the "
                      "onset: the shift never began in them (an --onset later than this env's episodes last?)",
                      markup=False)
    own_env = shifts_an_env(label) and "=" in label  # (not your env itself, nor another env: AnotherEnv)
    own_policy = bool(args.sb3 or args.policy) and args.task in ("cartpole", "pendulum")  # your policy, not an oodmon agent
    if args.variant and (own_env or own_policy) and threshold is not None and rows.episodes and not rows.alarmed:
        reset = " after the onset (at --onset 0 the env resets in the shifted world)" if args.onset else ""
        why = (f"an attribute the env reads only when it is made or reset changes nothing{reset}, nor does one "
               "where your policy never goes" if own_env else
               "a change of physics or of a sensor acts only in some states: gravity hardly acts on a pendulum your "
               "policy holds upright, and a stuck reading of a still one reads as before")
        console.print(f"does the shift change anything the env returns? `{_show_command(args, label)}` plays the env "
                      f"shifted and as it is from the same seed, your policy acting in both ({why})", markup=False)
    if command is not None:
        console.print(f"--on-alarm: {command.summary}", markup=False)
    if failures:
        console.print(f"[yellow]sink failures: {failures}[/yellow]")
    if interrupt is not None:
        one = rows.episodes == 1
        whole = f"the {rows.episodes:,} episode{'' if one else 's'} played whole {'is' if one else 'are'} in the table above"
        args.kept_on_interrupt = (f"{_LOGGED}; {whole}" if written else
                                  f"{whole}; no log was written (--mcap or --rrd keeps every step)")
        raise interrupt
    return 0


def _show_command(args: argparse.Namespace, label: str) -> str:
    """The `oodmon envs show` of the run's shift of your own env in which the run's own policy acts
    (its first SB3 model, read as the run read it, or its plain policy)."""
    import shlex

    words = ["oodmon", "envs", "show", label, "--onset", str(args.onset)]
    if args.policy:
        words += ["--policy", args.policy]
    elif args.sb3:
        words += ["--sb3", args.sb3[0]] + [word for module in args.imports for word in ("--import", module)]
        words += ["--unsafe-load-pickles"] * bool(args.unsafe_load_pickles)
        words += ["--vec-normalize", args.vec_normalize] if args.vec_normalize else []
        words += ["--frame-stack", str(args.frame_stack)] if args.frame_stack is not None else []
    return shlex.join(words)


def _start_time() -> str:
    """The run's start, local time, as ``{start}`` in ``--mcap`` and ``--rrd`` puts it: YYYYmmdd-HHMMSS."""
    return time.strftime("%Y%m%d-%H%M%S")


def _listed_by(mcap, path: str | None, *, failed: bool) -> str:
    """What lists the episodes `oodmon run`'s closing table leaves out: `oodmon replay` of its log
    (the file, or a split log's folder), which lacks some if its sink failed; or, with no log, --mcap."""
    if mcap is None:
        return " (--mcap logs every one)"
    log = (mcap.paths[0].parent if mcap.splits else mcap.paths[0]) if mcap.paths else path
    if failed:
        return f": the MCAP log lacks some (its sink failed), `oodmon replay {log} --episodes` lists those it holds"
    return f": `oodmon replay {log} --episodes` lists every one"


def _warn_if_reused(threshold, detectors, seed: int, episodes: int) -> None:
    """Warn where the run's episodes are ones ``threshold`` or the detectors its alarm reads were
    made from: their ID steps alarm less often than a fresh episode's would, so a count of false
    alarms in their logs reads low (``oodmon validate`` refuses such episodes)."""
    import warnings

    from oodmon.monitor.calibration import detectors_read, reused_episodes

    reused, free = reused_episodes(threshold, detectors_read(threshold, detectors), seed, episodes)
    if reused:
        warnings.warn(f"the run's episodes (seeds {seed:,}-{seed + episodes - 1:,}) include {reused}, which the "
                      "threshold was made from: they alarm less often in the ID env than fresh episodes would, so "
                      f"their false alarms read low (another --seed: e.g. {free})", UserWarning, stacklevel=2)


def _run_env(args: argparse.Namespace, agent) -> tuple[object, str]:
    """``oodmon run``'s env and its label: the ``--variant`` (a variant of the agent's task, a
    shift of your own model's env, shifting at ``--onset``, or another env of the same spaces,
    :class:`~oodmon.envs.AnotherEnv`), else your own model's env as you
    deploy it, else the task's ID env; with ``--obs-noise``'s sensor noise (oodmon's CartPole
    and Pendulum envs only) and ``--max-steps``' time limit."""
    from oodmon.envs import Variant, own_variant, parse_variant
    from oodmon.envs.registration import TASK_OF_ENV
    from oodmon.envs.shift import OtherEnv

    named_task = bool(args.variant) and args.variant.partition(":")[0] in TASKS
    if args.variant and args.task not in TASKS and named_task:
        raise ConfigError(f"variant {args.variant!r} is not a variant of {args.task}: oodmon has variants of "
                          f"{', '.join(sorted(TASK_OF_ENV))}; shift {args.task} itself with --variant "
                          f"{args.task}:NAME=VALUE (numeric attributes of its env), or leave out --variant")
    noise = args.obs_noise
    limit = {} if args.max_steps is None else {"max_episode_steps": args.max_steps}  # (--max-steps)
    agent.check_noise(noise)  # a noise the env refuses, or an env without it: said before the run, as calibrate says it
    # A shift of your own env's attributes; also of gymnasium's id of a task, where your own policy
    # acts (CartPole-v1:theta_threshold_radians=0.1: parse_env_shift refuses the task's physics there)
    if args.variant and not named_task and (args.task not in TASKS or agent.env_id is not None):
        if noise:
            raise ConfigError(f"--obs-noise is sensor noise of oodmon's envs, and {args.variant!r} shifts your own "
                              "env: give its sensor faults in --variant (e.g. ENV_ID:obs.noise=0.1), or leave out "
                              "--obs-noise" + (" (the threshold's is taken by default: give --obs-noise 0)"
                                               if args.threshold else ""))
        shift = own_variant(args.variant, agent.env_id)
        if isinstance(shift, OtherEnv):  # another registered env, every step of it the shifted world
            from oodmon.monitor.monitored_env import check_env_of

            if args.onset:
                raise ConfigError(f"--variant {shift.spec} is another env than {agent.env_id}, deployed from its "
                                  "reset: each of its steps is the shifted world; leave out --onset (a shift from a "
                                  f"step on is {agent.env_id}:NAME=VALUE, numeric attributes of its env)")
            env = shift.make(**limit)
            try:
                check_env_of(agent, env)  # spaces your policy acts in
            except ConfigError:
                env.close()
                raise
            return agent.wrap(env), shift.spec
        return agent.wrap(shift.make(onset_step=args.onset, **limit)), shift.spec
    noisy = {"obs_noise": noise} if noise else {}
    if args.variant:
        variant = parse_variant(args.variant)
        if variant.task != args.task:
            raise ConfigError(f"variant {variant.spec!r} is not a {args.task} variant")
        return agent.wrap(variant.make(onset_step=args.onset, **noisy, **limit)), variant.spec
    if agent.env_id is not None:  # your own model in its own env, as you deploy it
        return agent.make_env(noise, max_steps=args.max_steps), agent.env_id
    return Variant(args.task).make(onset_step=args.onset, **noisy, **limit), args.task


class _EpisodeRows:
    """``oodmon run``'s closing table, in constant memory: the first and the last ``shown`` // 2
    episodes (their records without the per-step rewards), and how many ran and alarmed. A run of
    weeks keeps no per-step data here (the records with their rewards took about 20 bytes a step)
    and prints a table of at most ``shown`` rows; ``oodmon replay LOG --episodes`` lists them all."""

    def __init__(self, shown: int = 20, *, calibrated: int | None = None, stretch: int | None = None,
                 id_run: bool | None = None) -> None:
        self.first: list = []
        # the run's episodes are of the policy's own world as it is (not a shift, nor another env:
        # their alarms false ones); None: by each episode's variant
        self.id_run = id_run
        self.last = deque(maxlen=shown - shown // 2)
        self.shown, self.episodes, self.alarmed = shown, 0, 0
        self.before_onset = 0  # episodes of a shifted variant that ended before their onset: never shifted
        # episodes longer than ``calibrated`` (the threshold's longest calibration episode), the longest
        self.calibrated, self.longer, self.longest = calibrated, 0, 0
        # the ID episodes' stretches of ``stretch`` steps, alarmed and in all, summed per episode
        from oodmon.monitor.threshold import ClusterSums

        self.stretch, self.stretches, self._alarm_steps = stretch, ClusterSums(), []
        # what raised each episode's first alarm (none before its onset) and the reading it named first
        self.causes: Counter[str] = Counter()
        self.readings: Counter[str] = Counter()
        self._first_event = None

    def alarm(self, event) -> None:
        """An alarm raised in the running episode (a Monitor callback): its step, where stretches are
        counted; the episode's first, whose cause and first reading :meth:`add` counts."""
        if self.stretch is not None:
            self._alarm_steps.append(event.step)
        if self._first_event is None:
            self._first_event = event

    def first_alarms(self) -> str:
        """``first alarms by dynamics 3; reading [2] (pole angle) 3``: what raised the episodes'
        first alarms (those before an onset left out) and the reading each named first; ``""`` for none."""
        from oodmon.replay.report import causes_cell

        return f"first alarms by {causes_cell(self.causes, self.readings)}" if self.causes else ""

    def add(self, record) -> None:
        from oodmon.envs.readings import reading_label
        from oodmon.monitor.threshold import Stretches
        from oodmon.replay.metrics import ended_before_onset

        self.episodes += 1
        self.alarmed += record.alarms > 0
        self.before_onset += ended_before_onset(record)
        self.longer += self.calibrated is not None and record.length > self.calibrated
        self.longest = max(self.longest, record.length)
        if self.stretch is not None and self._is_id(record):
            self.stretches.add(*Stretches.count(record.length, self._alarm_steps, self.stretch))
        self._alarm_steps = []
        first, self._first_event = self._first_event, None
        if first is not None and record.first_alarm_step == first.step and not record.alarmed_early:
            self.causes[first.cause or "unknown"] += 1
            if first.readings:
                self.readings[reading_label(first.readings[0][0], (first.reading_names or ("",))[0])] += 1
        slim = dataclasses.replace(record, rewards=None)
        (self.first if len(self.first) < self.shown // 2 else self.last).append(slim)

    def _is_id(self, record) -> bool:
        from oodmon.replay.metrics import is_id_variant

        return is_id_variant(record.variant) if self.id_run is None else self.id_run

    @property
    def left_out(self) -> int:
        """Episodes the table does not show."""
        return self.episodes - len(self.first) - len(self.last)

    def table(self, title: str) -> Table:
        """A row per episode kept, with its alarms and their delay, and a row "..." for those left out."""
        from oodmon.replay.report import how_it_ended

        left_out = self.left_out
        table = Table(title=title)
        for column in ("episode", "seed", "return", "length", "alarms", "first alarm", "delay", "ended"):
            table.add_column(column, justify="left" if column == "ended" else "right")
        for index, record in enumerate([*self.first, *self.last]):
            if index == len(self.first) and left_out:
                table.add_row("...", *[""] * 7)
            if record.first_alarm_step is None or self._is_id(record):
                delay = ""
            else:
                delay = "before onset" if record.alarmed_early else str(record.delay)
            table.add_row(str(record.episode), str(record.seed), f"{record.total_return:.1f}", str(record.length),
                          str(record.alarms), "" if record.first_alarm_step is None else str(record.first_alarm_step),
                          delay, how_it_ended(record.interrupted, record.terminated))
        return table


def _files_written(mcap) -> str | None:
    """The closing line's words for what ``mcap`` (an McapSink, or ``None``) wrote: its file, the first
    and last of a split run's, or ``None`` where it wrote none (it could not open one)."""
    if mcap is None or not mcap.paths:
        return None
    paths = mcap.paths
    return str(paths[0]) if len(paths) == 1 else f"{paths[0]} ... {paths[-1].name} ({len(paths)} files)"


def _add_demo(commands: argparse._SubParsersAction) -> None:
    """`oodmon demo`."""
    demo = commands.add_parser("demo", help="the main job of 'make demo': calibrate, monitor, log, summarise")
    demo.add_argument("--out", default="runs/demo", help="folder for the demo's files (default runs/demo)")
    demo.set_defaults(handler=_demo, kept_on_interrupt=_KEPT["demo"])


def _demo(args: argparse.Namespace) -> int:
    nothing = (f"nothing was written: the demo calibrates first, then writes its threshold and logs into "
               f"{args.out}: run the command again")
    args.kept_on_interrupt = nothing  # (until its logs begin: "every finished episode is in" them)
    from oodmon.demo import run_demo

    from oodmon.outputs import check_output_dir

    check_output_dir(args.out, parameter="--out")
    try:
        run_demo(args.out)
    except KeyboardInterrupt as interrupt:
        args.kept_on_interrupt = nothing if getattr(interrupt, "nothing_written", False) else _KEPT["demo"]
        raise
    return 0
