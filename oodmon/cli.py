"""The ``oodmon`` command: a thin layer over the library.

Errors a person can fix (:class:`oodmon.errors.OodmonError`, and files that cannot be written)
print as one line on stderr with exit code 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from rich.console import Console
from rich.table import Table

from oodmon.errors import OodmonError

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI with ``argv`` (default: ``sys.argv[1:]``); return the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "handler"):
        parser.print_help()
        return 2
    try:
        return args.handler(args) or 0
    except (OodmonError, OSError) as error:
        print(f"oodmon: error: {error}", file=sys.stderr)
        return 2


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="oodmon",
        description="Tells when a deployed RL policy has left the world it was trained in.",
    )
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")

    envs = commands.add_parser("envs", help="list the paper's OOD variants; 'envs show SPEC' pictures one")
    envs.add_argument("--task", choices=["cartpole", "pendulum", "pong"], help="only this task's variants")
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
    show.add_argument("--out", help="write the picture to this PNG file")
    show.add_argument("--seed", type=int, default=0, help="seed of the episode shown (default 0)")
    show.add_argument("--onset", type=int, default=0, help="step at which the shift begins (physics; default 0)")
    show.set_defaults(handler=_envs_show)

    train = commands.add_parser(
        "train", help="train an uncertainty-aware agent from its recipe (resumes an interrupted run)"
    )
    train.add_argument("--task", required=True, choices=["cartpole", "pendulum", "pong"])
    train.add_argument("--method", required=True, choices=["dropout", "dropconnect", "ensemble"])
    train.add_argument("--seed", type=int, default=0, help="the trial's seed (default 0)")
    train.add_argument("--out", required=True, help="training directory; the same command resumes it")
    train.add_argument("--steps", type=int, help="override the recipe's training steps per run")
    train.set_defaults(handler=_train)

    evaluate = commands.add_parser(
        "evaluate", help="where an agent fails: mean return per variant beside the ID return"
    )
    evaluate.add_argument("--task", required=True, choices=["cartpole", "pendulum", "pong"])
    evaluate.add_argument("--method", choices=["dropout", "dropconnect", "ensemble"],
                          help="a shipped agent (or give --model)")
    evaluate.add_argument("--model", help="a trained model directory instead of a shipped agent")
    evaluate.add_argument("--variants", default="paper",
                          help="'paper' (the paper's grid) or comma-separated specs (default paper)")
    evaluate.add_argument("--episodes", type=int, default=5, help="episodes per variant (default 5)")
    evaluate.add_argument("--fail-fraction", type=float, default=0.5,
                          help="fails below this fraction of the ID gain over a random policy (default 0.5)")
    evaluate.add_argument("--json", action="store_true", help="print JSON instead of a table")
    evaluate.set_defaults(handler=_evaluate)

    demo = commands.add_parser("demo", help="the main job of 'make demo'")
    demo.add_argument("--out", default="runs/demo", help="folder for the demo's files (default runs/demo)")
    demo.set_defaults(handler=_demo)
    return parser


def _envs_list(args: argparse.Namespace) -> int:
    from oodmon.envs import TASKS, paper_grid, severity_params
    from oodmon.paper import paper_grid_data

    tasks = [args.task] if args.task else list(TASKS)
    rows = []
    for task in tasks:
        defaults = paper_grid_data()[task].get("defaults", {})
        for variant in paper_grid(task):
            if task == "pong":
                params = severity_params(variant.corruption, variant.severity)
                value = ", ".join(f"{k}={v}" for k, v in params.items())
                rows.append({"task": task, "spec": variant.spec, "parameter": variant.corruption,
                             "value": value, "default": None})
            else:
                name, value = variant.params[0]
                rows.append({"task": task, "spec": variant.spec, "parameter": name,
                             "value": value, "default": defaults[name]})
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    table = Table(title=f"The paper's OOD variants ({len(rows)})")
    for column in ("task", "spec", "parameter", "value", "default"):
        table.add_column(column)
    for row in rows:
        table.add_row(*(("" if row[k] is None else str(row[k])) for k in ("task", "spec", "parameter", "value", "default")))
    Console().print(table)
    return 0


def _envs_show(args: argparse.Namespace) -> int:
    from oodmon.envs import parse_variant
    from oodmon.envs.preview import compare_physics, pong_preview, save_physics_plot, save_rgb

    variant = parse_variant(args.spec)
    console = Console(soft_wrap=True)
    if variant.task == "pong":
        image = pong_preview(variant, seed=args.seed)
        console.print(f"{variant.spec}: {variant.kwargs()}")
        if args.out:
            console.print(f"wrote {save_rgb(image, args.out)} (clean left, corrupted right)")
        return 0
    comparison = compare_physics(variant, seeds=range(args.seed, args.seed + 5), onset_step=args.onset)
    console.print(
        f"{variant.spec} (onset {args.onset}): reference controller's mean return over 5 seeds "
        f"{comparison.shifted_return:.1f}, against {comparison.id_return:.1f} in the ID env"
    )
    if args.out:
        console.print(f"wrote {save_physics_plot(comparison, args.out)}")
    return 0


def _train(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from oodmon.agents.training import train

    command = "oodmon " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("oodmon") else ""
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True)) as progress:
        bars: dict[str, int] = {}

        def report(run: str, done: int, total: int) -> None:
            if run not in bars:
                bars[run] = progress.add_task(f"{args.task}/{args.method} {run}", total=total)
            progress.update(bars[run], completed=done, total=total)

        agent = train(args.task, args.method, args.out, seed=args.seed, total_steps=args.steps, report=report,
                      command=command or f"oodmon train --task {args.task} --method {args.method} --seed {args.seed}")
    meta = agent.metadata
    Console(soft_wrap=True).print(
        f"{args.task}/{args.method}: id_return_mean {meta['id_return_mean']} over {meta['id_episodes']} episodes; "
        f"{sum(meta['training_steps'])} steps in {meta['wall_time_s']} s; saved to {args.out}"
    )
    return 0


def _load_agent(args: argparse.Namespace):
    from oodmon.agents import load, load_agent
    from oodmon.errors import ConfigError

    if args.model:
        return load_agent(args.model, task=args.task)
    if not args.method:
        raise ConfigError("give --method for a shipped agent, or --model DIR for a trained one")
    return load(args.task, args.method)


def _variants(task: str, text: str):
    from oodmon.envs import paper_grid, parse_variant
    from oodmon.errors import ConfigError

    if text == "paper":
        return paper_grid(task)
    variants = [parse_variant(spec) for spec in text.split(",")]
    for variant in variants:
        if variant.task != task:
            raise ConfigError(f"variant {variant.spec!r} is not a {task} variant")
    return variants


def _evaluate(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from oodmon.agents import evaluate_variants
    from oodmon.errors import InvalidParameterError

    if args.episodes < 1:
        raise InvalidParameterError(f"--episodes {args.episodes} is not allowed; give at least 1")
    agent = _load_agent(args)
    variants = _variants(args.task, args.variants)
    with Progress(console=Console(stderr=True), transient=True) as progress:
        bar = progress.add_task("evaluating", total=(len(variants) + 1) * args.episodes)
        id_result, results = evaluate_variants(
            agent.act, args.task, variants, args.episodes, fail_fraction=args.fail_fraction,
            on_episode=lambda spec, ret: progress.update(bar, advance=1, description=spec),
        )
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
    Console().print(table)
    failing = [r.spec for r in results if r.fails]
    Console(soft_wrap=True).print(f"{len(failing)} of {len(results)} variants fail the agent: {', '.join(failing)}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from oodmon.demo import run_demo

    run_demo(args.out)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
