"""Another drop probability when deciding than when training: does MC DropConnect's spread then
separate the paper's variants better?

Run (resumable; one torch thread; a minute or two per row; needs the bench's five CartPole
DropConnect trials, which `oodmon bench --task cartpole --trials 5 --workers 2 --out runs/bench5`
trains and caches):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_inference_p.py [--grid 0.02,0.05,0.1,0.2]
    .venv/bin/python scripts/sweep_inference_p.py --table          # the zoo README's table

The shipped agent (trial 0) and the bench's trials 1-4 are loaded with every DropConnect layer's
drop probability set to p (the kept weights scaled by 1 / (1 - p), as in training; the weights
are the trained ones) and measured as scripts/sweep_full_depth.py measures: the agent acts by the
mean of its 20 samples, per-step AUROC of the paper's score from 10 ID episodes (seeds 200000+)
against 5 episodes of each of the paper's DropConnect variants (seeds 400000+), MC seed 0. At the
recipe's own p (0.02) a row is the trial's row of scripts/sweep_trials.py's shipped recipe. One
JSON line per (trial weights, p) goes to ``results/sweeps/inference_p.jsonl``; a line already there
is not run again.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oodmon.agents import Agent
from oodmon.agents.networks import estimator_for
from oodmon.agents.layers import DropConnectLinear
from oodmon.agents.serialization import load_modules
from oodmon.errors import ConfigError
from sweep_full_depth import MC_SEED, VARIANTS, append_row, bench_trial, parse_or_print_table, read_rows, spread_aurocs

OUT = Path("results/sweeps/inference_p.jsonl")
TASK, METHOD = "cartpole", "dropconnect"


def with_inference_p(folder: Path, p: float) -> Agent:
    """The DropConnect agent in ``folder``, every DropConnect layer dropping with probability ``p``
    (MC seed 0, the recipe's samples per decision).

    Raises:
        ConfigError: ``p`` outside (0, 1), or a model without DropConnect.
    """
    if not 0.0 < p < 1.0:
        raise ConfigError(f"inference p={p!r} is not allowed; it must lie strictly between 0 and 1")
    modules, metadata = load_modules(folder, task=TASK)
    layers = [m for m in modules.modules() if isinstance(m, DropConnectLinear)]
    if not layers:
        raise ConfigError(f"the model in {folder} has no DropConnect layer")
    for layer in layers:
        layer.p = p
    estimator = estimator_for(modules, metadata["architecture"], n_samples=metadata.get("n_samples", 20), seed=MC_SEED)
    return Agent(estimator, metadata, folder)


def table() -> str:
    """Per inference p: the AUROC on each variant, mean ± std over the trials, and the ID returns."""
    rows = read_rows(OUT)
    lines = ["| inference p | trials | ID return (min to max) | AUROC mean ± std per variant | mean over variants |",
             "|---:|---:|---|---|---:|"]
    for p in sorted({r["p"] for r in rows}):
        at = [r for r in rows if r["p"] == p]
        specs = list(at[0]["auroc"]["chosen_std"])
        per_variant = {spec: np.array([r["auroc"]["chosen_std"][spec] for r in at]) for spec in specs}
        cells = "; ".join(f"{spec.split(':')[1]} {v.mean():.3f} ± {v.std():.3f}" for spec, v in per_variant.items())
        returns = [r["id_return_mean"] for r in at]
        overall = np.mean([v.mean() for v in per_variant.values()])
        lines.append(f"| {p:g} | {len(at)} | {min(returns):.1f} to {max(returns):.1f} | {cells} | {overall:.3f} |")
    return "\n".join(lines)


def _grid(text: str) -> list[float]:
    values = [float(x) for x in text.split(",")]
    if any(not 0.0 < p < 1.0 for p in values):
        raise argparse.ArgumentTypeError(f"--grid {text!r}: each p must lie strictly between 0 and 1")
    return values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=_grid, default=[0.02, 0.05, 0.1, 0.2], help="inference drop probabilities")
    parser.add_argument("--trials", default="0,1,2,3,4", help="trial numbers (0: the shipped agent)")
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    done = {(r["safetensors_sha256"], r["p"]) for r in read_rows(OUT)}
    for trial in (int(t) for t in args.trials.split(",")):
        for p in args.grid:
            start = time.monotonic()
            agent = with_inference_p(bench_trial(TASK, METHOD, trial), p)
            weights = agent.metadata["safetensors_sha256"]
            if (weights, p) in done:
                continue
            auroc, returns, id_return = spread_aurocs(agent, TASK, VARIANTS[(TASK, METHOD)])
            append_row(OUT, {"task": TASK, "method": METHOD, "trial": trial, "safetensors_sha256": weights, "p": p,
                             "trained_p": agent.metadata.get("drop_p"), "mc_seed": MC_SEED,
                             "id_return_mean": id_return, "auroc": auroc, "variant_return_mean": returns,
                             "wall_time_s": round(time.monotonic() - start, 1)})


if __name__ == "__main__":
    main()
