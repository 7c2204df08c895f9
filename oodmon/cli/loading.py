"""The agent and the fitted detectors a command acts on, from its arguments."""

from __future__ import annotations

import argparse
from pathlib import Path

from oodmon.errors import ConfigError


def _load_agent(args: argparse.Namespace, *, seed: int | None = None):
    """The agent of --sb3/--env, --policy/--env, --model or --task/--method; ``seed`` seeds its MC
    sampling (None: fresh entropy). Sets ``args.task`` from --env for --sb3 models and a --policy."""
    from oodmon.agents import load, load_agent

    if getattr(args, "policy", None):  # commands without it (evaluate) have none
        return _plain_agent(args)
    if getattr(args, "sb3", None):  # commands without the --sb3 options (evaluate) have none
        from oodmon.agents.sb3 import load_sb3

        if not args.env:
            raise ConfigError("--sb3 needs --env: the gymnasium env id the models act in (e.g. CartPole-v1)")
        _check_frame_stack(args.frame_stack)
        if getattr(args, "model", None) or getattr(args, "method", None):
            raise ConfigError("--sb3 is instead of --model and --method: give one of them")
        agent = load_sb3(args.sb3, args.env, mean=args.mean, seed=seed, masks=getattr(args, "masks", None),
                         vec_normalize=args.vec_normalize, frame_stack=args.frame_stack,
                         imports=args.imports, unsafe_load_pickles=args.unsafe_load_pickles)
        return _task_of(args, agent)
    if getattr(args, "env", None) or getattr(args, "mean", False) or getattr(args, "vec_normalize", None) \
            or getattr(args, "frame_stack", None) is not None or getattr(args, "unsafe_load_pickles", False) \
            or getattr(args, "imports", None):
        raise ConfigError("--env, --mean, --import, --unsafe-load-pickles, --frame-stack and --vec-normalize go with "
                          "--sb3 (your own SB3 models); --env with --policy too")
    masks = getattr(args, "masks", None)
    if args.model:  # its model.json names its task (--task, where given, must be it)
        agent = load_agent(args.model, task=args.task, seed=seed, masks=masks)
        args.task = agent.task
        return agent
    if not args.task:
        raise ConfigError("give --task with --method, or --model (or --sb3 with --env for your own SB3 models, "
                          "--policy with --env for a policy of your own of any kind)")
    if not args.method:
        raise ConfigError("give --method for a shipped agent, or --model DIR for a trained one")
    return load(args.task, args.method, seed=seed, masks=masks)


def _agent_from_threshold(args: argparse.Namespace, threshold, name: str) -> bool:
    """Where no agent is given (--model, --sb3, --policy; --task and --method each default alone),
    the shipped agent ``threshold`` was calibrated for: ``args.task`` and ``args.method`` from it
    (`oodmon validate`, and `oodmon run --threshold`). ``name``: the threshold file, in the errors.
    True where it named the whole agent, neither --task nor --method given (see
    :func:`_check_agent_from_threshold`).

    Raises:
        ConfigError: the threshold records no task, or was calibrated on your own SB3 models or
            policy (no shipped agent has that name: they are given again, with their env).
    """
    from oodmon.envs.registration import TASK_OF_ENV
    from oodmon.names import PLAIN_METHOD

    if args.model or getattr(args, "sb3", None) or getattr(args, "policy", None):
        return False  # the agent given says its task (a threshold of another is refused by the monitor, or --force)
    whole = args.task is None and args.method is None
    args.task = args.task or threshold.task
    if args.task is None and threshold.episode_hashes is not None:  # (oodmon.watch_recorded's)
        raise ConfigError(f"{name} was calibrated on episodes you recorded, of a deployment no env plays "
                          "(oodmon.watch_recorded): there is no env to play here, nor the policy; check it on fresh "
                          f"records with `oodmon validate {name} --records FILE` (oodmon.monitor.validate_on_episodes), "
                          f"and watch with oodmon.watch_recorded(threshold={str(name)!r}) in your own loop (or give "
                          "--policy MODULE:NAME --env ID where an env does play it)")
    if args.task is None:
        raise ConfigError(f"{name} does not record its task; give --task")
    # a threshold records the task, which names the env oodmon has variants of (cartpole: CartPole-v1)
    env_id = next((env for env, task in TASK_OF_ENV.items() if task == threshold.task), threshold.task)
    if threshold.method == "sb3" and args.method is None and threshold.models and threshold.sb3 is not None:
        _sb3_from_threshold(args, threshold, name)  # the models it records, loaded as when calibrating
        return False
    if threshold.method == "sb3" and args.method is None:  # no shipped agent of that name
        files = threshold.sb3_files or "ZIP"
        raise ConfigError(f"{name} was calibrated on your own SB3 model(s) in {env_id}: give them again, --sb3 {files} "
                          f"--env {env_id} (with --vec-normalize and --frame-stack as when calibrating)")
    if threshold.method == PLAIN_METHOD and args.method is None:
        raise ConfigError(f"{name} was calibrated on your own policy in {env_id}: give it again, --policy "
                          f"MODULE:NAME --env {env_id}")
    args.method = args.method or threshold.method
    return whole


def _sb3_from_threshold(args: argparse.Namespace, threshold, name: str) -> None:
    """``args`` that load the SB3 models ``threshold`` was calibrated on (:attr:`~oodmon.monitor.
    Threshold.models`) as they were loaded then (:attr:`~oodmon.monitor.Threshold.sb3`): ``--sb3``,
    ``--env``, and ``--vec-normalize``, ``--frame-stack`` and ``--mean`` where not given; said on
    stderr. A file no longer where it was is looked for beside the threshold
    (:func:`~oodmon.monitor.threshold.recorded_sb3`). The policy's hash, which the monitor
    checks, still decides: a file changed since is refused there. ``--import`` and
    ``--unsafe-load-pickles`` are never read from a file (they run code): give them again where the
    models need them.

    Raises:
        ConfigError: an ``--env`` other than the threshold's, or a file it names that is gone.
    """
    from rich.console import Console

    from oodmon.monitor.threshold import recorded_sb3, sb3_arguments

    loaded = threshold.sb3
    env_id = loaded["env_id"]
    if args.env and args.env != env_id:
        raise ConfigError(f"{name} was calibrated on SB3 models in {env_id}, not --env {args.env}: leave out --env, or "
                          f"give the models and the threshold calibrated in {args.env}")
    loading, gone = recorded_sb3(threshold, name, vec_normalize=args.vec_normalize, frame_stack=args.frame_stack,
                                 mean=args.mean)
    if gone:
        raise ConfigError(f"{name} was calibrated on your own SB3 model(s) in {env_id}, loaded from files that are "
                          f"neither there nor beside it: {', '.join(gone)}; give them where they are now, --sb3 ZIP... "
                          f"--env {env_id}{' --vec-normalize PKL' if loaded['vec_normalize'] else ''}"
                          f"{' --frame-stack ' + str(loaded['frame_stack']) if loaded['frame_stack'] else ''}"
                          f"{' --mean' if loaded['mean'] else ''}")
    args.sb3, args.env, args.vec_normalize, args.frame_stack, args.mean = (
        loading[key] for key in ("models", "env_id", "vec_normalize", "frame_stack", "mean"))
    words = (f"--sb3 {sb3_arguments([{'path': path} for path in args.sb3])} --env {env_id}"
             + (f" --vec-normalize {args.vec_normalize}" if args.vec_normalize else "")
             + (f" --frame-stack {args.frame_stack}" if args.frame_stack else "") + (" --mean" if args.mean else ""))
    Console(stderr=True, soft_wrap=True).print(f"note: the policy {name} was calibrated on: {words}", markup=False)


def _check_agent_from_threshold(args: argparse.Namespace, threshold, name: str, agent) -> None:
    """The shipped agent :func:`_agent_from_threshold` chose, refused where ``threshold`` was
    calibrated on other weights of its task and method (a model trained with ``oodmon train``: the
    threshold does not record where it lies), naming what to give; ``--force`` uses it.

    Raises:
        ConfigError: the weights differ and ``--force`` was not given.
    """
    from oodmon.monitor.monitor import policy_hash

    if getattr(args, "force", False) or not threshold.policy_hash:
        return
    shipped = policy_hash(agent)  # (the sha256 of its weights' file: read once)
    if shipped == threshold.policy_hash:
        return
    raise ConfigError(f"{name} was calibrated on weights {threshold.policy_hash[:19]}..., not the shipped "
                      f"{args.task}/{args.method} agent's ({shipped[:19]}..., the agent of its task and "
                      "method): give the model it was calibrated with, --model DIR (or --force to use it with the "
                      "shipped agent)")


def _plain_agent(args: argparse.Namespace):
    """The agent of --policy MODULE:NAME in --env (:func:`oodmon.agents.plain.plain_agent`)."""
    from oodmon.agents.plain import plain_agent, policy_by_name

    if args.sb3 or getattr(args, "model", None) or getattr(args, "method", None):  # (bench has --methods)
        raise ConfigError("--policy is instead of --sb3, --model and --method: give one of them")
    if not args.env:
        raise ConfigError("--policy needs --env: the gymnasium env id the policy acts in (e.g. CartPole-v1)")
    others = [option for option, given in (("--mean", args.mean), ("--masks", getattr(args, "masks", None)),
                                           ("--vec-normalize", args.vec_normalize),
                                           ("--frame-stack", args.frame_stack is not None), ("--import", args.imports),
                                           ("--unsafe-load-pickles", args.unsafe_load_pickles)) if given]
    if others:
        verb = "go" if len(others) > 1 else "goes"
        raise ConfigError(f"{', '.join(others)} {verb} with --sb3; a --policy acts on the env's observations as they "
                          "are (import what it needs in its own module)")
    return _task_of(args, plain_agent(policy_by_name(args.policy), args.env))


def _task_of(args: argparse.Namespace, agent):
    """``agent``, with ``args.task`` set to its task (a --task that contradicts --env refused)."""
    if args.task and args.task != agent.task:
        raise ConfigError(f"--task {args.task} contradicts --env {args.env} (task {agent.task})")
    args.task = agent.task
    return agent


def _input_files(args: argparse.Namespace) -> list[tuple[str, str]]:
    """``(option, path)`` of every file a command's agent arguments read (--threshold, --model's
    files, --sb3, --vec-normalize, --detectors' files): an output given one of these paths would
    destroy it (``oodmon.outputs.check_output_file``'s ``inputs``)."""
    files = [("--threshold", getattr(args, "threshold", None))]
    for option, folder, names in (("--model", getattr(args, "model", None), ("model.json", "model.safetensors")),
                                  ("--detectors", getattr(args, "detectors", None),
                                   ("detectors.json", "detectors.safetensors"))):
        files += [(option, str(Path(folder) / name)) for name in names] if folder else []
    files += [("--sb3", path) for path in getattr(args, "sb3", None) or ()]
    normalizer = getattr(args, "vec_normalize", None)
    files.append(("--vec-normalize", normalizer if normalizer != "none" else None))
    return [(option, path) for option, path in files if path]


def _check_frame_stack(frame_stack: int | None) -> None:
    """``--frame-stack``, refused before any model is read unless 2 or more (or not given)."""
    if frame_stack is not None:
        from oodmon.agents.frame_stack import check_frame_stack

        check_frame_stack(frame_stack, parameter="--frame-stack ")


def _detectors(args: argparse.Namespace, agent, threshold=None):
    """The fitted detectors: ``--detectors``, else those `calibrate` fitted beside the threshold
    file (``<threshold>.detectors/``), else the agent's own, else ``None``; ``threshold``: that
    file's :class:`~oodmon.monitor.Threshold`, which says whether it was calibrated with fitted ones.

    Raises:
        ConfigError: none found where ``threshold`` was calibrated with fitted detectors."""
    from oodmon.monitor.detectors import detectors_for

    beside = Path(f"{args.threshold}.detectors") if getattr(args, "threshold", None) else None
    if args.detectors is None and beside is not None and (beside / "detectors.json").is_file():
        return detectors_for(agent, beside)
    chosen = detectors_for(agent, args.detectors)
    # a threshold moved without its folder (the monitor said only "nothing to score")
    if chosen is None and args.detectors is None and threshold is not None and threshold.detectors_hash:
        raise ConfigError(f"{args.threshold} was calibrated with fitted detectors ({threshold.detector}, "
                          f"{threshold.detectors_hash[:19]}...), and none are beside it ({beside}, where calibrate "
                          "writes them; moved without them?): give them with --detectors DIR, the folder they were "
                          "fitted into")
    return chosen


def _no_variants(command: str, env_id: str, flag: str = "--sb3") -> ConfigError:
    """The refusal of a command that plays oodmon's variants, for an --sb3 model (``flag``: or a
    --policy) of an env that has none."""
    what = "policy" if flag == "--policy" else "model"
    return ConfigError(f"{command} plays oodmon's shifted variants of CartPole, Pendulum and Pong; --env {env_id} is "
                       f"none of them: monitor the {what} in it with `oodmon run {flag} ... --env {env_id}` instead (a "
                       f"shift of your own: --variant {env_id}:NAME=VALUE, other numbers in its env's attributes)")
