"""A candidate depth and drop probability over five seeds, beside the shipped recipe's five trials: does
it detect better and more evenly across trainings?

Run (resumable; one thread; minutes per seed on Pendulum):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_trials.py --task pendulum --method dropconnect \\
        --p 0.05 [--seeds 0,1,2,3,4]           # the candidate: full depth (a stochastic layer after every hidden layer)
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_trials.py --task pendulum --method dropconnect --shipped
    .venv/bin/python scripts/sweep_trials.py --table                       # mean ± std over seeds per variant

``--steps``, ``--select-top``, ``--target-samples``, ``--final-eps`` (a DQN's final exploration
rate) and ``--net-arch`` (hidden widths, e.g. ``64,64``: a smaller network decides faster) change the
candidate's training further; the rows record them.

The candidate is the shipped recipe with ``last_only=False`` and ``drop_p=p``, trained with seed k into
``runs/sweep/trials/<task>-<method>-full-p<p>-seed<k>``. ``--shipped`` measures the shipped recipe's
five trials as the bench has them: trial 0 is the zoo agent and trial k is
``runs/bench5/models/<task>-<method>-trial<k>`` (`oodmon bench --task T --trials 5 --workers 1 --out
runs/bench5` trains them). Each agent is measured as scripts/sweep_full_depth.py measures (10 ID
episodes against 5 of each of the paper's variants for the method, MC seed 0, whether or not the agent
fails). One JSON line per (recipe, seed) goes to ``results/sweeps/trials.jsonl``; a line already there
is not run again. The table marks the rows of today's shipped recipe "(shipped)"; the output-layer
Pendulum DropConnect rows were made with ``--shipped`` before the full-depth candidate was shipped.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from oodmon.agents import load_agent
from oodmon.agents.recipes import parse_widths, recipe_for
from oodmon.agents.training import train
from oodmon.threads import limit_threads
from sweep_full_depth import (MC_SEED, VARIANTS, append_row, bench_trial, check_dqn_options, dqn_changes, dqn_tag,
                              parse_or_print_table, read_rows, row_widths, spread_aurocs, variant_cells, widths_setting)

OUT = Path("results/sweeps/trials.jsonl")


def _label(row: dict) -> str:
    """The row's recipe: depth and p, and its steps and choice among snapshots where the row records
    them (rows before 2026-11-24 do not: they were trained for the recipe's steps of their time)."""
    label = f"{'output layer' if row['last_only'] else 'full depth'}, p={row['drop_p']:g}"
    if row.get("net_arch"):
        label += f", hidden {list(row['net_arch'])}"
    if "total_steps" in row:
        label += f", {row['total_steps']:,} steps"
    if row.get("select_top"):
        label += f", best of {row['select_top']} snapshots"
    if row.get("target_samples"):
        label += f", target of {row['target_samples']} samples"
    if row.get("exploration_final_eps") is not None:
        label += f", final epsilon {row['exploration_final_eps']:g}"
    return label


def _shown(row: dict) -> str:
    """The row's recipe, marked when it is today's shipped recipe (rows made with ``--shipped`` when
    another recipe was shipped keep their settings)."""
    shipped = recipe_for(row["task"], row["method"])
    made = (row["drop_p"], row["last_only"], row.get("total_steps", shipped.total_steps),
            row.get("select_top", shipped.select_top), row.get("target_samples", 0), row.get("exploration_final_eps"),
            row_widths(row))
    today = (shipped.drop_p, shipped.last_only, shipped.total_steps, shipped.select_top, shipped.target_samples, None,
             list(shipped.net_arch))
    return _label(row) + (" (shipped)" if made == today else " (shipped before)" if row.get("shipped") else "")


def table() -> str:
    """Per (task, method, recipe) and score, each variant's AUROC mean ± std over the seeds measured."""
    groups: dict[tuple, list[dict]] = {}
    for row in read_rows(OUT):
        groups.setdefault((row["task"], row["method"], _shown(row)), []).append(row)
    lines = ["| task | method | recipe | seeds | ID return (min to max) | score | " + "AUROC mean ± std per variant |",
             "|---|---|---|---|---|---|---|"]
    for (task, method, label), rows in groups.items():
        returns = [r["id_return_mean"] for r in rows]
        for score in rows[0]["auroc"]:
            lines.append(f"| {task} | {method} | {label} | {len(rows)} | {min(returns):.1f} to {max(returns):.1f} | "
                         f"`{score}` | {variant_cells(rows, score)[0]} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", choices=["cartpole", "pendulum"])
    parser.add_argument("--method", choices=["dropout", "dropconnect"])
    parser.add_argument("--p", type=float, help="the candidate's drop probability (full depth)")
    parser.add_argument("--steps", type=int, help="the candidate's training steps (default the recipe's)")
    parser.add_argument("--select-top", type=int, default=0, help="the candidate ships the best of this many "
                        "snapshots, each replayed on 20 ID episodes (Recipe.select_top; default 0: the best evaluation)")
    parser.add_argument("--target-samples", type=int, default=0, help="DQN: the candidate's TD target is the mean "
                        "of this many MC samples of its target network (Recipe.target_samples; default 0: SB3's)")
    parser.add_argument("--final-eps", type=float, help="DQN: the candidate's final exploration rate (default the "
                        "recipe's)")
    parser.add_argument("--net-arch", type=parse_widths, help="the candidate's hidden widths, e.g. 64,64 (default the "
                        "recipe's)")
    parser.add_argument("--shipped", action="store_true", help="measure the shipped recipe's five trials instead")
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--rows", type=Path, default=OUT, help=f"where the rows go (default {OUT}); another file "
                        "trains and measures again a recipe whose rows that one holds, e.g. to keep its agents")
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    if args.task is None or args.method is None or (args.p is None) == (not args.shipped):
        parser.error("give --task and --method, and either --p (a candidate) or --shipped")
    check_dqn_options(parser, args, [args.task])
    done = {(r["task"], r["method"], _label(r), r["seed"]) for r in read_rows(args.rows)}
    shipped = recipe_for(args.task, args.method)
    widths = list(args.net_arch or shipped.net_arch)  # a candidate's hidden widths
    for seed in (int(s) for s in args.seeds.split(",")):
        if args.shipped:
            settings = {"drop_p": shipped.drop_p, "last_only": shipped.last_only, "total_steps": shipped.total_steps,
                        "select_top": shipped.select_top, "shipped": True, **widths_setting(args.task, shipped.net_arch)}
        else:
            settings = {"drop_p": args.p, "last_only": False, "total_steps": args.steps or shipped.total_steps,
                        "select_top": args.select_top}
            if args.target_samples:
                settings["target_samples"] = args.target_samples
            settings |= widths_setting(args.task, widths)
            settings |= dqn_changes(args)
        if (args.task, args.method, _label(settings), seed) in done:
            continue
        if args.shipped:
            agent = load_agent(bench_trial(args.task, args.method, seed), task=args.task, seed=MC_SEED)
        else:
            out = (f"runs/sweep/trials/{args.task}-{args.method}-full-p{args.p:g}-steps{settings['total_steps']}"
                   f"-top{args.select_top}{f'-target{args.target_samples}' if args.target_samples else ''}"
                   f"{dqn_tag(dqn_changes(args))}{'-net' + 'x'.join(map(str, args.net_arch)) if args.net_arch else ''}"
                   f"-seed{seed}")
            recipe = replace(shipped, last_only=False, drop_p=args.p, total_steps=settings["total_steps"],
                             select_top=args.select_top, select_episodes=20, target_samples=args.target_samples,
                             hyperparams=shipped.hyperparams | dqn_changes(args),
                             net_arch=widths)
            train(args.task, args.method, out, seed=seed, recipe=recipe, command=f"scripts/sweep_trials.py ({out})")
            agent = load_agent(out, task=args.task, seed=MC_SEED)
        auroc, returns, _ = spread_aurocs(agent, args.task, VARIANTS[(args.task, args.method)])
        append_row(args.rows, {"task": args.task, "method": args.method, **settings, "seed": seed, "mc_seed": MC_SEED,
                         "id_return_mean": agent.metadata["id_return_mean"], "auroc": auroc,
                         "variant_return_mean": returns})


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
