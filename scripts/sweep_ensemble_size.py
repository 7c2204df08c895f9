"""How the ensemble's spread separates the paper's ensemble variants as the ensemble grows.

Run (resumable; one thread; needs the bench's five CartPole / Pendulum ensemble trials, which
`oodmon bench --task T --trials 5 --workers 1 --out runs/bench5` trains and caches):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_ensemble_size.py [--tasks cartpole,pendulum]
    .venv/bin/python scripts/sweep_ensemble_size.py --table

The shipped ensemble (trial 0) and the bench's trials 1-4 are five independently trained K=5
ensembles of the same recipe, so pooling the members of n of them is a K=5n ensemble of
independent members, with no training: the sweep pools every run of n consecutive trials (mod 5)
for n = 1..5 (five groups at each K below 25, one at 25). Each group is measured as the sweep of
full-depth MC agents measures (scripts/sweep_full_depth.py): the pooled ensemble acts (the
members' mean decides), its per-step AUROC of the paper's score (and ``pre_squash_std`` on
Pendulum) from 10 ID episodes (seeds 200000+) against 5 episodes of each of the paper's ensemble
variants for the task (seeds 400000+), whether or not it fails there, and the mean returns.
Ensembles and episodes are deterministic: a row is the same on every run. One JSON line per group
goes to ``results/sweeps/ensemble_size.jsonl``; a group already there is not run again.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oodmon.agents import load
from oodmon.agents.estimators import EnsembleEstimator
from oodmon.agents.serialization import load_modules
from oodmon.threads import limit_threads
# scripts/: the MC sweeps' measurement
from sweep_full_depth import append_row, bench_trial, parse_or_print_table, read_rows, spread_aurocs

OUT = Path("results/sweeps/ensemble_size.jsonl")
VARIANTS = {"cartpole": ["cartpole:gravity=98.0", "cartpole:length=2.0"],
            "pendulum": ["pendulum:l=0.1", "pendulum:m=0.05"]}  # the paper's ensemble tables


def groups(trials: int = 5) -> list[list[int]]:
    """Every run of n consecutive trials (mod ``trials``), n = 1..trials; the whole set once.

    Example:
        >>> groups(3)
        [[0], [1], [2], [0, 1], [1, 2], [2, 0], [0, 1, 2]]
    """
    runs = [[(start + k) % trials for k in range(n)] for n in range(1, trials) for start in range(trials)]
    return runs + [list(range(trials))]


def pooled(task: str, trials: list[int]) -> EnsembleEstimator:
    """One ensemble of every member of the given trials' ensembles (trial 0: the shipped one)."""
    folders = [bench_trial(task, "ensemble", t) for t in trials]
    modules = [load_modules(folder, task=task)[0] for folder in folders]
    shipped = load(task, "ensemble")
    space = shipped.make_env().action_space
    bounds = dict(action_low=space.low, action_high=space.high) if shipped.estimator.kind == "actions" else {}
    return EnsembleEstimator([member for m in modules for member in m["members"]], shipped.estimator.kind,
                             torso=modules[0]["torso"], obs_shape=shipped.estimator.obs_shape, **bounds)


def measure(task: str, trials: list[int]) -> dict:
    start = time.monotonic()
    estimator = pooled(task, trials)
    row = {"task": task, "trials": trials, "K": estimator.n_samples}
    row["auroc"], row["variant_return_mean"], row["id_return_mean"] = spread_aurocs(estimator, task, VARIANTS[task])
    row["wall_time_s"] = round(time.monotonic() - start, 1)
    return row


def table() -> str:
    """Per task, score and K: the AUROC on each variant, mean +- std over the groups (which share
    trials at K = 10-20, so they are not independent), its range, and the mean returns' range."""
    rows = read_rows(OUT)
    lines = ["| task | score | K (groups) | ID return | variant: AUROC mean ± std (min to max), return (min to max) | "
             "the other variant: the same |", "|---|---|---|---|---|---|"]
    for task in dict.fromkeys(r["task"] for r in rows):
        mine = [r for r in rows if r["task"] == task]
        for score in mine[0]["auroc"]:
            for k in sorted({r["K"] for r in mine}):
                at = [r for r in mine if r["K"] == k]
                cells = []
                for spec in VARIANTS[task]:
                    values = np.array([r["auroc"][score][spec] for r in at])
                    returns = [r["variant_return_mean"][spec] for r in at]
                    spread = values.std(ddof=1) if len(values) > 1 else 0.0
                    cells.append(f"{spec.split(':')[1]}: {values.mean():.3f} ± {spread:.3f} ({values.min():.3f} to "
                                 f"{values.max():.3f}), {min(returns):.0f} to {max(returns):.0f}")
                id_returns = [r["id_return_mean"] for r in at]
                lines.append(f"| {task} | {score} | {k} ({len(at)}) | {min(id_returns):.1f} to {max(id_returns):.1f} | "
                             + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="cartpole,pendulum")
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    done = {(r["task"], tuple(r["trials"])) for r in read_rows(OUT)}
    for task in args.tasks.split(","):
        for trials in groups():
            if (task, tuple(trials)) in done:
                continue
            append_row(OUT, measure(task, trials))


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
