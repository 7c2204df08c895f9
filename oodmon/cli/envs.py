"""``oodmon envs``: the paper's OOD variants, listed, pictured and toured."""

from __future__ import annotations

import argparse
import json
import re

from rich.console import Console
from rich.table import Table

from oodmon.cli.display import _table_console
from oodmon.cli.parsing import _SEED, _whole
from oodmon.errors import ConfigError
from oodmon.names import TASKS


def _add_envs(commands: argparse._SubParsersAction) -> None:
    """`oodmon envs`, with `envs show` and `envs tour`."""
    envs = commands.add_parser("envs", help="list the paper's OOD variants; 'envs show SPEC' pictures one")
    envs.add_argument("--task", choices=TASKS, help="only this task's variants")
    envs.add_argument("--json", action="store_true", help="print JSON instead of a table")
    envs.set_defaults(handler=_envs_list, plays=False)  # no policy: torch not imported
    envs_commands = envs.add_subparsers(title="envs commands", metavar="COMMAND")
    show = envs_commands.add_parser(
        "show",
        help="what a variant changes",
        description="Pong: the clean and the corrupted frame side by side. CartPole, Pendulum: a "
        "hand-written reference controller's returns in the ID env and the variant, and its pole "
        "angle over an episode. A shift of your own env (ENV_ID:NAME=VALUE): the env as it is and "
        "shifted, from the same seed with the same random actions, and the step from which what it "
        "returned differs, if it does (an attribute the env reads only when made or reset changes nothing "
        "after the onset; at --onset 0 the env resets in the shifted world). "
        "With --sb3 or --policy your policy acts instead, in a CartPole or Pendulum variant too (beside the "
        "task's ID env): whether the shift changes anything in the states your policy visits.",
    )
    show.add_argument("spec", help="a variant spec, e.g. pong:pixelate@3 or cartpole:length=2.0, or a shift of "
                      "your own env, e.g. Acrobot-v1:LINK_MASS_2=3.0")
    show.add_argument("--out", help="write the picture to this file (.png or .jpg; a name without a suffix gets .png)")
    show.add_argument("--seed", type=_SEED, default=0, help="seed of the episode shown (default 0)")
    show.add_argument("--onset", type=_whole(0), default=0, help="step at which the shift begins (physics; default 0)")
    show.add_argument("--steps", type=_whole(1), default=500,
                      help="your own env's shift, or your policy acting: steps played at most (default 500; fewer "
                           "when the episode ends)")
    show.add_argument("--sb3", metavar="ZIP",
                      help="this stable-baselines3 model acts (deterministic) in the env as it is and shifted (your "
                           "own env's, a CartPole or Pendulum variant), in the states it visits (read without running "
                           "code from it, as `oodmon run --sb3`)")
    show.add_argument("--policy", metavar="MODULE:NAME",
                      help="this policy of yours, a function obs -> action, acts as --sb3 does (as "
                           "`oodmon run --policy`: the module is imported)")
    show.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE",
                      help="with --sb3: as `oodmon run --import`")
    show.add_argument("--unsafe-load-pickles", action="store_true",
                      help="with --sb3: as `oodmon run --unsafe-load-pickles` (runs code the file holds)")
    show.add_argument("--vec-normalize", metavar="PKL", help="with --sb3: as `oodmon run --vec-normalize`")
    show.add_argument("--frame-stack", type=int, metavar="N", help="with --sb3: as `oodmon run --frame-stack`")
    show.set_defaults(handler=_envs_show, plays=lambda args: bool(args.sb3 or args.policy))
    tour = envs_commands.add_parser("tour", help="what the envs change, shown with a hand-written controller")
    tour.add_argument("--out", default="runs/tour", help="folder for the pictures (default runs/tour)")
    tour.set_defaults(handler=_envs_tour, plays=False)


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
    from oodmon.envs import parse_any_variant
    from oodmon.envs.grid import Variant
    from oodmon.envs.preview import compare_physics, pong_preview, save_physics_plot, save_rgb

    spec = args.spec.strip()
    last = spec.rpartition(":")[2]  # (ENV_ID:NAME, a shift without its value, is said malformed below)
    if spec.partition(":")[0] not in TASKS and "=" not in spec and (last == spec or re.search(r"-v\d+$", last)):
        raise ConfigError(f"{spec} is an env's id alone: `envs show` plays an env beside a shift of it "
                          f"(ENV_ID:NAME=VALUE, e.g. {spec}:NAME=VALUE) or an oodmon variant; another env as your "
                          f"policy's deployed world is `oodmon run --variant {spec}`'s and the bench's, whose replay "
                          "ranks its steps against your ID runs'")
    variant = parse_any_variant(args.spec)  # oodmon's variant, else a shift of your own env
    out = None
    if args.out:
        from oodmon.outputs import check_picture_file

        out = check_picture_file(args.out, parameter="--out")  # "shot" is written as shot.png
    console = Console(soft_wrap=True)
    loading = args.vec_normalize is not None or args.frame_stack is not None or args.unsafe_load_pickles \
        or bool(args.imports)
    if isinstance(variant, Variant) and variant.task == "pong" and (args.sb3 or args.policy or loading):
        raise ConfigError(f"--sb3 and its options (--import, --unsafe-load-pickles, --frame-stack, --vec-normalize), and "
                          f"--policy, go with a shift of your own env or a CartPole or Pendulum variant; {variant.spec} "
                          "is shown as its clean and corrupted frames")
    if loading and not args.sb3:
        raise ConfigError("--import, --unsafe-load-pickles, --frame-stack and --vec-normalize go with --sb3")
    if args.sb3 and args.policy:
        raise ConfigError("--sb3 or --policy: the one policy that acts, give one of them")
    if not isinstance(variant, Variant) or args.sb3 or args.policy:  # your policy acting: the env's own and shifted
        return _show_probe(args, variant, out, console)
    if variant.task == "pong":
        image = pong_preview(variant, seed=args.seed)
        console.print(f"{variant.spec}: {variant.kwargs() or dict(variant.faults)}", markup=False)  # obs.KIND[i]
        if out:
            console.print(f"wrote {save_rgb(image, out)} (clean left, corrupted right)")
        return 0
    comparison = compare_physics(variant, seeds=range(args.seed, args.seed + 5), onset_step=args.onset)
    console.print(
        f"{variant.spec} (onset {args.onset}): reference controller's mean return over 5 seeds "
        f"{comparison.shifted_return:.1f}, against {comparison.id_return:.1f} in the ID env"
    )
    never = sum(not rollout.shifted.any() for rollout in comparison.shifted_rollouts)
    if never:  # the same returns, as if the shift changed nothing
        played = len(comparison.shifted_rollouts)
        console.print(f"note: {never} of {played} episodes ended before step {args.onset}, the onset: the shift never "
                      "began in them")
    if out:
        console.print(f"wrote {save_physics_plot(comparison, out)}")
    return 0


def _show_probe(args: argparse.Namespace, shift, out, console: Console) -> int:
    """`envs show` of a shift of your own env, or of a variant of oodmon's task where your policy acts:
    the env as it is and shifted, side by side (:func:`~oodmon.envs.probe.probe_shift`); exit code 1
    when nothing it returned differed."""
    from oodmon.envs.preview import save_probe_plot
    from oodmon.envs.probe import probe_shift

    policy = wrap = None
    if args.sb3:
        from oodmon.agents.sb3 import load_sb3
        from oodmon.cli.loading import _check_frame_stack

        _check_frame_stack(args.frame_stack)  # said as the option, before the model is read
        agent = load_sb3([args.sb3], shift.env_id, vec_normalize=args.vec_normalize, frame_stack=args.frame_stack,
                         imports=args.imports, unsafe_load_pickles=args.unsafe_load_pickles)
        policy, wrap = agent.act, agent.wrap
    elif args.policy:
        from oodmon.agents.plain import plain_agent, policy_by_name

        agent = plain_agent(policy_by_name(args.policy), shift.env_id)
        policy, wrap = agent.act, agent.wrap
    probe = probe_shift(shift, seed=args.seed, onset=args.onset, steps=args.steps, policy=policy, wrap=wrap)
    console.print(probe.summary(), markup=False)  # obs.KIND[i]: no markup
    if out:
        console.print(f"wrote {save_probe_plot(probe, out)}")
    return 0 if probe.changed else 1


def _envs_tour(args: argparse.Namespace) -> int:
    from oodmon.demo import run_env_tour
    from oodmon.outputs import check_output_dir

    check_output_dir(args.out, parameter="--out")
    run_env_tour(args.out)
    return 0
