"""``oodmon train`` and ``oodmon evaluate``: train an agent from its recipe; where it fails."""

from __future__ import annotations

import argparse
import json
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from rich.console import Console
from rich.table import Table

from oodmon.cli.display import _progress, _table_console
from oodmon.cli.loading import _load_agent, _no_variants
from oodmon.cli.parsing import (_KEPT, _SEED, _add_workers, _command_line, _fraction, _policy_argument, _sb3_arguments,
                                _whole)
from oodmon.errors import InvalidParameterError
from oodmon.names import METHODS, TASKS


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

        try:
            agent = train(args.task, args.method, args.out, seed=args.seed, total_steps=args.steps,
                          on_progress=lambda stage, done, of: report(f"{label} {stage}", done, of),
                          on_evaluation=evaluated,
                          export_only=args.export_only, load_pickles=args.unsafe_load_pickles,
                          command=_command_line(args))
        except KeyboardInterrupt as interrupt:
            # train notes each run's steps at its last checkpoint (none noted: stopped before its runs,
            # and the usual words stand)
            steps = getattr(interrupt, "checkpoint_steps", None)
            if steps is not None and not any(steps):
                args.kept_on_interrupt = (f"no checkpoint was written yet (the first after "
                                          f"{interrupt.checkpoint_every:,} steps): the same command starts the "
                                          "training again")
            elif steps is None and not any(Path(args.out).glob("runs/*/checkpoint.*")):
                # stopped before its runs began (importing SB3, checking --out), and no earlier
                # training's checkpoint there: "the last checkpoint is kept" said so of none (2026-12-06).
                # The runs' layout (oodmon.agents.checkpoints.Run) is read here without importing it:
                # the stop may have come in that very import
                args.kept_on_interrupt = "nothing was trained yet: the same command starts the training"
            raise
    meta = agent.metadata
    Console(soft_wrap=True).print(
        f"{args.task}/{args.method}: id_return_mean {meta['id_return_mean']} over {meta['id_episodes']} episodes; "
        f"{sum(meta['training_steps'])} steps in {meta['wall_time_s']} s; saved to {args.out}"
    )
    return 0


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
    _policy_argument(evaluate)
    evaluate.add_argument("--variants", default="paper",
                          help="'paper' (the paper's grid) or comma-separated specs (default paper)")
    evaluate.add_argument("--episodes", type=_whole(1), default=5, help="episodes per variant (default 5)")
    evaluate.add_argument("--fail-fraction", type=_fraction, default=0.5,
                          help="fails below this fraction of the ID gain over a random policy (default 0.5)")
    _add_workers(evaluate, "the variants (a run of them each)")
    evaluate.add_argument("--json", action="store_true", help="print JSON instead of a table")
    evaluate.set_defaults(handler=_evaluate)


def _evaluate(args: argparse.Namespace) -> int:
    from oodmon.agents import evaluate_variants

    if args.episodes < 1:
        raise InvalidParameterError(f"--episodes {args.episodes} is not allowed; give at least 1")
    agent = _load_agent(args, seed=0)  # seeded MC sampling: the same command, the same table
    from oodmon.envs.grid import select_variants

    if args.task not in TASKS:  # --sb3 or --policy in an env oodmon has no variants of
        raise _no_variants("evaluate", args.env, "--policy" if args.policy else "--sb3")
    variants = select_variants(args.task, args.variants)
    try:
        with _progress() as report:
            id_result, results = evaluate_variants(agent.act, args.task, variants, args.episodes,
                                                   fail_fraction=args.fail_fraction, on_progress=report,
                                                   wrap=agent.wrap, workers=args.workers, sampler=agent.estimator)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # Ctrl-C, SIGTERM, a worker's death: the
        # variants evaluated whole are still said
        evaluated = getattr(interrupt, "evaluation", None)
        if evaluated is not None:
            _print_evaluation(args, agent, *evaluated, len(variants), interrupted=True)
            args.kept_on_interrupt = (f"the ID env and the first {len(evaluated[1]):,} of the {len(variants):,} "
                                      "variants, evaluated whole, are in the table above")
        raise
    _print_evaluation(args, agent, id_result, results, len(variants))
    return 0


def _print_evaluation(args: argparse.Namespace, agent, id_result, results, asked: int, *,
                      interrupted: bool = False) -> None:
    """``evaluate``'s answer, its JSON (``--json``) or its table, of the ID env and ``results`` of
    the ``asked`` variants; ``interrupted``: those evaluated whole before Ctrl-C or SIGTERM."""
    from oodmon.side_by_side import resolve_workers

    rows = [{"variant": r.spec, "return_mean": round(r.mean, 2), "return_std": round(float(r.returns.std()), 2),
             "fails": r.fails} for r in [id_result, *results]]
    if args.json:
        print(json.dumps({"task": args.task, "method": agent.method, "episodes": args.episodes,
                          "workers": resolve_workers(args.workers, asked + 1),  # those that played them
                          "id_return_mean": rows[0]["return_mean"], "variants": rows[1:],
                          "interrupted": interrupted, "variants_asked": asked}, indent=1))
        return
    table = Table(title=("interrupted: " if interrupted else "")
                  + f"{args.task}/{agent.method}: mean return over {args.episodes} episodes "
                    f"(ID {id_result.mean:.1f}; fails below {args.fail_fraction:.0%} of the gain over random)")
    for column in ("variant", "return", "std", "fails"):
        table.add_column(column, justify="left" if column == "variant" else "right")
    for row in rows:
        style = "bold red" if row["fails"] else None
        table.add_row(row["variant"], f"{row['return_mean']:.1f}", f"{row['return_std']:.1f}",
                      "FAILS" if row["fails"] else "", style=style)
    _table_console().print(table)
    failing = [r.spec for r in results if r.fails]
    Console(soft_wrap=True).print(f"{len(failing)} of {len(results)} variants fail the agent"
                                  + (f": {', '.join(failing)}" if failing else ""))  # (none: no colon left hanging)
