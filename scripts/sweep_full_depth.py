"""Full-depth MC Dropout / DropConnect (a stochastic layer after every hidden layer): which drop
probability still solves the task, and how well its spread separates the paper's variants.

Run (resumable; one thread, so it can sit beside other work):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_full_depth.py [--tasks cartpole,pendulum]
        [--methods dropconnect] [--grid 0.01,0.02] [--learning-rate 1e-3] [--steps 100000] [--net-arch 64,64]

``--learning-rate``, ``--steps`` and ``--net-arch`` (hidden widths) change the recipe's, and
``--target-samples K`` trains a DQN with the TD target read from K MC samples of its target network
(``Recipe.target_samples``, recorded in the row), ``--buffer-size N`` and ``--final-eps E`` change a
DQN's replay buffer and final exploration rate (recorded as ``buffer_size`` and
``exploration_final_eps``); every row records
the learning rate and steps its agent was trained with (rows from before the recipe's defaults changed:
those of their time), and its hidden widths when they are not the recipe's.
``--shipped`` measures the shipped agents (at the depth they ship) on the same
episodes, the row to compare with. ``--table`` prints the rows as the zoo README's markdown table instead of running anything.

Each (task, method, p) trains with the shipped recipe but ``last_only=False`` and ``drop_p=p`` into
``runs/sweep/<task>-<method>-full-p<p>`` (resumed if interrupted), then measures, with the agent as
it ships (MC-mean decisions): ``id_return_mean`` over 20 ID episodes (from the export) and the
per-step AUROC of the paper's score (and ``pre_squash_std`` for Pendulum) on the variants the paper
reports for that method, from 10 ID episodes (seeds 200000+) against 5 episodes of each variant
(seeds 400000+). One JSON line per configuration goes to ``results/sweeps/full_depth.jsonl``; a
configuration already there is not run again.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from oodmon.agents import SOLVED_RETURN, load, load_agent, zoo_dir
from oodmon.agents.recipes import RECIPES, parse_widths, recipe_for
from oodmon.agents.training import train
from oodmon.envs import parse_variant
from oodmon.errors import ConfigError
from oodmon.monitor import MemorySink, Monitor
from oodmon.threads import limit_threads

OUT = Path("results/sweeps/full_depth.jsonl")
# The MC samples' seed (rows since 2026-11-24 record it as ``mc_seed``; the rows before were
# measured with unseeded samples, one draw of the same distribution: a second unseeded draw of the
# 12 Dropout rows moved their per-variant AUROC by 0.008 in the median, 0.062 at most, and their
# means by up to 0.024; see the zoo README).
MC_SEED = 0
GRID = (0.01, 0.05, 0.1, 0.2)
VARIANTS = {  # the variants of the paper's appendix tables, per task and method
    ("cartpole", "dropout"): ["cartpole:force_mag=2.5", "cartpole:gravity=49.0", "cartpole:masscart=3.0",
                              "cartpole:masspole=3.0"],
    ("cartpole", "dropconnect"): ["cartpole:force_mag=1.0", "cartpole:gravity=78.4", "cartpole:length=2.0",
                                  "cartpole:masscart=9.0", "cartpole:masspole=9.0"],
    ("pendulum", "dropout"): ["pendulum:g=50.0", "pendulum:l=5.0", "pendulum:m=5.0"],
    ("pendulum", "dropconnect"): ["pendulum:g=50.0", "pendulum:l=5.0", "pendulum:m=5.0"],
}


#: Where `oodmon bench --out runs/bench5` caches its trial models (trials 1-4; trial 0 is the zoo's).
BENCH_MODELS = Path("runs/bench5/models")


def bench_trial(task: str, method: str, trial: int, models: Path = BENCH_MODELS) -> Path:
    """The model folder of the bench's trial ``trial``: the shipped agent for trial 0, else the
    bench's cached training in ``models``.

    Raises:
        ConfigError: that trial has no trained model yet (the message names the command that trains it).
    """
    folder = zoo_dir() / f"{task}-{method}" if int(trial) == 0 else Path(models) / f"{task}-{method}-trial{trial}"
    if not (folder / "model.safetensors").exists():
        raise ConfigError(f"no trained model in {folder}: run `oodmon bench --task {task} --trials 5 --workers 2 "
                          f"--out {Path(models).parent}` first (it trains and caches the trials)")
    return folder


def episode_scores(agent, spec: str, episodes: int, seed: int, score: str,
                   obs_noise: float = 0.0) -> tuple[list[np.ndarray], list[float]]:
    """The agent playing ``spec`` under the monitor, episodes ``seed``, ``seed`` + 1, ...: each
    episode's per-step ``score`` and its return."""
    sink, variant = MemorySink(), parse_variant(spec)
    env = variant.make(obs_noise=obs_noise) if obs_noise else variant.make()
    with Monitor(agent, score=score, sinks=[sink], log_observations=False) as monitor:
        returns = [monitor.run_episode(env, seed=seed + k, variant=spec).total_return for k in range(episodes)]
    env.close()
    steps = np.array([(s.episode, s.score) for s in sink.steps])
    return [steps[steps[:, 0] == k, 1] for k in range(episodes)], returns


def step_auroc(id_values: np.ndarray, shifted: np.ndarray) -> float:
    """The per-step AUROC of ``shifted`` steps' values against ``id_values`` (higher: more shifted).

    Example:
        >>> step_auroc(np.array([0.1, 0.2]), np.array([0.3, 0.15]))
        0.75
    """
    labels = np.r_[np.zeros(len(id_values)), np.ones(len(shifted))]
    return float(roc_auc_score(labels, np.r_[id_values, shifted]))


def _scores(agent, spec: str, episodes: int, seed: int, score: str) -> tuple[np.ndarray, list[float]]:
    per_episode, returns = episode_scores(agent, spec, episodes, seed, score)
    return np.concatenate(per_episode), returns


def table() -> str:
    """The sweep's rows as markdown: solved or not, and the mean AUROC over the paper's variants."""
    lines = ["| task | method | depth | hidden | p | learning rate | steps | ID return (20 ep.) | solved | AUROC chosen_std | "
             "AUROC pre_squash_std |", "|---|---|---|---|---:|---:|---:|---:|---|---:|---:|"]
    for r in read_rows(OUT):
        means = {k: float(np.mean(list(v.values()))) for k, v in r["auroc"].items()}
        depth = "output only" if r["last_only"] else "full"
        if r.get("target_samples"):
            depth += f", target of {r['target_samples']} samples"
        if r.get("buffer_size") is not None:
            depth += f", buffer of {r['buffer_size']:,}"
        if r.get("exploration_final_eps") is not None:
            depth += f", final epsilon {r['exploration_final_eps']:g}"
        if r.get("shipped"):
            depth += " (shipped)" if _made_by_todays_recipe(r) else " (shipped before)"
        hidden = ", ".join(str(w) for w in row_widths(r))
        lines.append(f"| {r['task']} | {r['method']} | {depth} | [{hidden}] | {r['drop_p']:g} | {r['learning_rate']:g} | "
                     f"{r['steps']:,} | {r['id_return_mean']:.1f} | "
                     f"{'yes' if r['id_return_mean'] >= SOLVED_RETURN[r['task']] else 'no'} | {means['chosen_std']:.3f} | "
                     + (f"{means['pre_squash_std']:.3f} |" if "pre_squash_std" in means else "- |"))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="cartpole,pendulum")
    parser.add_argument("--methods", default="dropout,dropconnect")
    parser.add_argument("--grid", default=",".join(str(p) for p in GRID))
    parser.add_argument("--learning-rate", type=float, help="instead of the recipe's (recorded in the row)")
    parser.add_argument("--steps", type=int, help="training steps instead of the recipe's (recorded in the row)")
    parser.add_argument("--net-arch", type=parse_widths,
                        help="hidden widths instead of the recipe's, e.g. 64,64 (recorded in the row)")
    parser.add_argument("--target-samples", type=int, default=0,
                        help="DQN: the TD target is the mean of this many MC samples of the target network (recorded)")
    parser.add_argument("--buffer-size", type=int, help="DQN: replay buffer size instead of the recipe's (recorded)")
    parser.add_argument("--final-eps", type=float, help="DQN: final exploration rate instead of the recipe's (recorded)")
    parser.add_argument("--shipped", action="store_true",
                        help="measure the shipped (last-only) agents the same way instead of training")
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    check_dqn_options(parser, args, args.tasks.split(","))
    done = {_key(r) for r in read_rows(OUT)}
    for task in args.tasks.split(","):
        for method in args.methods.split(","):
            if args.shipped:
                recipe = recipe_for(task, method)
                settings = {"drop_p": recipe.drop_p, "last_only": recipe.last_only, "shipped": True, **_trained_by(recipe),
                            **widths_setting(task, recipe.net_arch)}
                if _key({"task": task, "method": method, **settings}) not in done:
                    _measure(load(task, method, seed=MC_SEED), task, method, settings)
                continue
            for p in (float(x) for x in args.grid.split(",")):
                recipe = replace(recipe_for(task, method), last_only=False, drop_p=p)
                name = f"{task}-{method}-full-p{p}"
                if args.learning_rate is not None:
                    recipe = replace(recipe, hyperparams=recipe.hyperparams | {"learning_rate": args.learning_rate})
                    name += f"-lr{args.learning_rate:g}"
                if args.steps is not None:
                    recipe = replace(recipe, total_steps=args.steps)
                    name += f"-steps{args.steps}"
                if args.net_arch is not None:
                    recipe = replace(recipe, net_arch=args.net_arch)
                    name += "-net" + "x".join(str(w) for w in recipe.net_arch)
                settings = {"drop_p": p, "last_only": False, **_trained_by(recipe), **widths_setting(task, recipe.net_arch)}
                if args.target_samples:
                    recipe = replace(recipe, target_samples=args.target_samples)
                    name += f"-target{args.target_samples}"
                    settings["target_samples"] = args.target_samples
                changes = dqn_changes(args)
                recipe = replace(recipe, hyperparams=recipe.hyperparams | changes)
                name += dqn_tag(changes)
                settings |= changes
                if _key({"task": task, "method": method, **settings}) in done:
                    continue
                start = time.monotonic()
                train(task, method, f"runs/sweep/{name}", seed=0, recipe=recipe, command=f"scripts/sweep_full_depth.py ({name})")
                _measure(load_agent(f"runs/sweep/{name}", task=task, seed=MC_SEED), task, method, settings, start)


#: The sweeps' DQN options: argparse name -> (the recipe's hyperparameter, its tag in a folder name).
DQN_OPTIONS = {"buffer_size": ("buffer_size", "buffer"), "final_eps": ("exploration_final_eps", "eps")}


def dqn_changes(args: argparse.Namespace) -> dict:
    """The recipe's hyperparameters the sweep's DQN options given change (none given: empty); the
    rows record them under these names."""
    return {hyperparam: value for option, (hyperparam, _) in DQN_OPTIONS.items()
            if (value := getattr(args, option, None)) is not None}


def dqn_tag(changes: dict) -> str:
    """The training folder's suffix for :func:`dqn_changes`, e.g. ``-buffer20000-eps0``."""
    tags = {hyperparam: tag for hyperparam, tag in DQN_OPTIONS.values()}
    return "".join(f"-{tags[hyperparam]}{value:g}" for hyperparam, value in changes.items())


def check_dqn_options(parser: argparse.ArgumentParser, args: argparse.Namespace, tasks: list[str]) -> None:
    """Refuse ``--final-eps`` outside [0, 1], ``--buffer-size`` below 1, and either for a task whose
    recipe is not a DQN's (DDPG has no epsilon; SB3 would fail deep in the training)."""
    final_eps, buffer_size = getattr(args, "final_eps", None), getattr(args, "buffer_size", None)
    if final_eps is not None and not 0.0 <= final_eps <= 1.0:
        parser.error(f"--final-eps must be in [0, 1]; got {final_eps:g}")
    if buffer_size is not None and buffer_size < 1:
        parser.error(f"--buffer-size must be at least 1; got {buffer_size}")
    if dqn_changes(args):
        for task in tasks:
            if task in RECIPES and RECIPES[task].algorithm != "dqn":
                parser.error(f"--final-eps and --buffer-size change a DQN's training; {task} trains "
                             f"{RECIPES[task].algorithm.upper()}")


def _trained_by(recipe) -> dict:
    """The learning rate and steps a row's agent was trained with (every row records them: the
    recipe's defaults change)."""
    return {"learning_rate": recipe.hyperparams["learning_rate"], "steps": recipe.total_steps}


def _made_by_todays_recipe(row: dict) -> bool:
    """Whether a ``--shipped`` row measured the agent today's recipe trains (its depth, p, learning
    rate, steps and hidden widths), not one shipped before."""
    recipe = recipe_for(row["task"], row["method"])
    return (row["last_only"], row["drop_p"], row["learning_rate"], row["steps"], row_widths(row)) == (
        recipe.last_only, recipe.drop_p, recipe.hyperparams["learning_rate"], recipe.total_steps, list(recipe.net_arch))


def _key(row: dict) -> tuple:
    net_arch = tuple(row_widths(row))
    if row.get("shipped"):
        return row["task"], row["method"], "shipped", row["last_only"], row["drop_p"], row["steps"], net_arch
    return (row["task"], row["method"], row["drop_p"], row["learning_rate"], row["steps"], net_arch,
            row.get("target_samples", 0), row.get("buffer_size"), row.get("exploration_final_eps"))


def _measure(agent, task: str, method: str, settings: dict, start: float | None = None) -> None:
    """Append the agent's row: ID return, per-step AUROC per score and variant, variant returns."""
    start = time.monotonic() if start is None else start
    row = {"task": task, "method": method, **settings, "mc_seed": MC_SEED,
           "id_return_mean": agent.metadata["id_return_mean"]}
    row["auroc"], row["variant_return_mean"], _ = spread_aurocs(agent, task, VARIANTS[(task, method)])
    row["wall_time_s"] = round(time.monotonic() - start, 1)
    append_row(OUT, row)


def spread_aurocs(policy, task: str, variants: list[str]) -> tuple[dict, dict, float]:
    """The sweeps' measurement of a policy (an agent or an estimator, acting under the monitor):
    per score (the paper's, and ``pre_squash_std`` on Pendulum) and variant the per-step AUROC of
    10 ID episodes (seeds 200000+) against 5 of the variant (seeds 400000+); the variants' mean
    returns; the ID episodes' mean return."""
    auroc, returns = {}, {}
    for score in (["chosen_std"] + (["pre_squash_std"] if task == "pendulum" else [])):
        id_scores, id_returns = _scores(policy, task, 10, 200_000, score)
        auroc[score] = {}
        for spec in variants:
            ood, shifted_returns = _scores(policy, spec, 5, 400_000, score)
            auroc[score][spec] = round(step_auroc(id_scores, ood), 3)
            returns[spec] = round(float(np.mean(shifted_returns)), 1)
    return auroc, returns, round(float(np.mean(id_returns)), 1)


def variant_cells(rows: list[dict], score: str) -> tuple[str, float]:
    """The rows' AUROC of ``score`` per variant as one table cell, ``"length=2.0 0.601 ± 0.084; ..."``
    (mean ± std over the rows, in the first row's order of variants), and the mean over the variants."""
    per_variant = {spec: np.array([r["auroc"][score][spec] for r in rows]) for spec in rows[0]["auroc"][score]}
    cells = "; ".join(f"{spec.split(':')[1]} {v.mean():.3f} ± {v.std():.3f}" for spec, v in per_variant.items())
    return cells, float(np.mean([v.mean() for v in per_variant.values()]))


def parse_or_print_table(parser: argparse.ArgumentParser, table) -> argparse.Namespace | None:
    """The sweeps' command line with ``--table`` added: print ``table()`` and give None when it is
    given (run nothing), else the parsed arguments."""
    parser.add_argument("--table", action="store_true", help="print the rows as a markdown table, run nothing")
    args = parser.parse_args()
    if args.table:
        print(table())
        return None
    return args


def row_widths(row: dict) -> list[int]:
    """The hidden widths a row's agent was trained at: its ``net_arch``, or else its task's (the rows
    record widths only where they are not the task's, so an older row still reads right if a
    method's recipe takes widths of its own)."""
    return list(row.get("net_arch") or RECIPES[row["task"]].net_arch)


def widths_setting(task: str, widths) -> dict:
    """What a row records of hidden widths ``widths``: nothing where they are ``task``'s."""
    return {} if list(widths) == list(RECIPES[task].net_arch) else {"net_arch": list(widths)}


def read_rows(path: Path) -> list[dict]:
    """The JSON lines of a sweep's file (none before its first row)."""
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def append_row(path: Path, row: dict) -> None:
    """One JSON line more in ``path`` (and on the screen)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(row) + "\n")
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
