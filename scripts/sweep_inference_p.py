"""Another drop probability when deciding than when training, or sampling the output layer only:
does MC DropConnect's spread then separate the paper's variants better?

Run (resumable; one thread; a minute or two per row; needs the bench's five DropConnect
trials of the task, which `oodmon bench --task <task> --trials 5 --workers 2 --out runs/bench5`
trains and caches):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_inference_p.py [--task cartpole]
        [--grid 0.02,0.05,0.1,0.2] [--sampled all|output] [--trials 0,1,2,3,4]
    .venv/bin/python scripts/sweep_inference_p.py --table          # the zoo README's table

The shipped agent (trial 0) and the bench's trials 1-4 are loaded with their DropConnect layers'
drop probability set to p (the kept weights scaled by 1 / (1 - p), as in training; the weights
are the trained ones). ``--sampled all`` (the default) samples every DropConnect layer, as the
full-depth agents are trained and shipped; ``--sampled output`` samples the output layer only and
computes the hidden layers once with their plain weights (the mean of their samples, since training
scales the kept weights), as the output-layer agents do. Each is measured as
scripts/sweep_full_depth.py measures: the agent acts by the mean of its 20 samples, per-step AUROC
from 10 ID episodes (seeds 200000+) against 5 episodes of each of the paper's DropConnect variants
(seeds 400000+), MC seed 0; the table shows the paper's score on CartPole and ``pre_squash_std`` on
Pendulum (where the paper's score stays near 0.2 at every depth: the zoo README). With every layer
sampled at the recipe's own p a CartPole row (p = 0.02) is the trial's row of
scripts/sweep_trials.py's shipped recipe, draw for draw; a Pendulum row (p = 0.05) differs from its
row there by other draws of the same distribution (those rows were sampled with dense masks). One
JSON line per (trial weights, p, sampled layers) goes to ``results/sweeps/inference_p.jsonl``; a
line already there is not run again.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from torch import nn

from oodmon.agents import Agent
from oodmon.agents.agent import agent_from_modules
from oodmon.agents.layers import DropConnectLinear
from oodmon.agents.serialization import load_modules
from oodmon.errors import ConfigError
from oodmon.threads import limit_threads
from sweep_full_depth import (MC_SEED, VARIANTS, append_row, bench_trial, parse_or_print_table, read_rows, spread_aurocs,
                              variant_cells)

OUT = Path("results/sweeps/inference_p.jsonl")
METHOD = "dropconnect"
#: The score each task's table shows (the paper's on CartPole; on Pendulum the paper's score stays
#: near 0.2 at every depth, so the pre-squash spread the bench also reports).
TABLE_SCORE = {"cartpole": "chosen_std", "pendulum": "pre_squash_std"}
#: Which DropConnect layers sample: every one (as trained and shipped), or the output layer only.
SAMPLED = ("all", "output")


def with_inference_p(folder: Path, p: float, *, sampled: str = "all", task: str = "cartpole") -> Agent:
    """The DropConnect agent of ``task`` in ``folder``, its sampled DropConnect layers dropping with
    probability ``p`` (MC seed 0, the recipe's samples per decision). ``sampled="output"``: only the
    output layer samples; the hidden layers compute once with their plain weights.

    Raises:
        ConfigError: ``p`` outside (0, 1), an unknown ``sampled``, or a model without DropConnect.
    """
    if not 0.0 < p < 1.0:
        raise ConfigError(f"inference p={p!r} is not allowed; it must lie strictly between 0 and 1")
    if sampled not in SAMPLED:
        raise ConfigError(f"sampled={sampled!r} is not one of {', '.join(SAMPLED)}")
    modules, metadata = load_modules(folder, task=task)
    layers = [(parent, name, m) for parent in modules.modules() for name, m in parent.named_children()
              if isinstance(m, DropConnectLinear)]  # in the order the forward pass meets them
    if not layers:
        raise ConfigError(f"the model in {folder} has no DropConnect layer")
    for k, (parent, name, layer) in enumerate(layers):
        if sampled == "output" and k < len(layers) - 1:
            setattr(parent, name, _plain(layer))
        else:
            layer.p = p
    return agent_from_modules(modules, metadata, folder, seed=MC_SEED)


def _plain(layer: DropConnectLinear) -> nn.Linear:
    """A plain linear layer with ``layer``'s weight and bias tensors (its samples' mean)."""
    linear = nn.Linear(layer.in_features, layer.out_features, bias=layer.bias is not None)
    linear.weight, linear.bias = layer.weight, layer.bias
    return linear


def table() -> str:
    """Per task, sampled layers and inference p: the AUROC of the task's table score on each variant,
    mean ± std over the trials, and the ID returns."""
    rows = read_rows(OUT)
    lines = ["| task | sampled layers | inference p | trials | ID return (min to max) | score: AUROC mean ± std per variant "
             "| mean over variants |", "|---|---|---:|---:|---|---|---:|"]
    groups = sorted({(r["task"], _sampled(r), r["p"]) for r in rows}, key=lambda g: (g[0] != "cartpole", g[1] != "all", g[2]))
    for task, sampled, p in groups:
        at = [r for r in rows if (r["task"], _sampled(r), r["p"]) == (task, sampled, p)]
        score = TABLE_SCORE[task]
        cells, overall = variant_cells(at, score)
        returns = [r["id_return_mean"] for r in at]
        lines.append(f"| {task} | {sampled} | {p:g} | {len(at)} | {min(returns):.1f} to {max(returns):.1f} | "
                     f"{score}: {cells} | {overall:.3f} |")
    return "\n".join(lines)


def _sampled(row: dict) -> str:
    """A row's sampled layers (the rows before ``--sampled`` sampled every layer and do not say so)."""
    return row.get("sampled", "all")


def _grid(text: str) -> list[float]:
    values = [float(x) for x in text.split(",")]
    if any(not 0.0 < p < 1.0 for p in values):
        raise argparse.ArgumentTypeError(f"--grid {text!r}: each p must lie strictly between 0 and 1")
    return values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=_grid, default=[0.02, 0.05, 0.1, 0.2], help="inference drop probabilities")
    parser.add_argument("--trials", default="0,1,2,3,4", help="trial numbers (0: the shipped agent)")
    parser.add_argument("--task", choices=sorted(TABLE_SCORE), default="cartpole")
    parser.add_argument("--sampled", choices=SAMPLED, default="all",
                        help="the DropConnect layers that sample: every one (as trained), or the output layer only")
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    done = {(r["safetensors_sha256"], r["p"], _sampled(r)) for r in read_rows(OUT)}
    for trial in (int(t) for t in args.trials.split(",")):
        for p in args.grid:
            start = time.monotonic()
            agent = with_inference_p(bench_trial(args.task, METHOD, trial), p, sampled=args.sampled, task=args.task)
            weights = agent.metadata["safetensors_sha256"]
            if (weights, p, args.sampled) in done:
                continue
            auroc, returns, id_return = spread_aurocs(agent, args.task, VARIANTS[(args.task, METHOD)])
            append_row(OUT, {"task": args.task, "method": METHOD, "trial": trial, "safetensors_sha256": weights,
                             "p": p, "sampled": args.sampled, "trained_p": agent.metadata.get("drop_p"),
                             "mc_seed": MC_SEED, "id_return_mean": id_return, "auroc": auroc,
                             "variant_return_mean": returns, "wall_time_s": round(time.monotonic() - start, 1)})


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
