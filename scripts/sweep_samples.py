"""More MC samples per decision: does a shipped MC agent's spread separate the paper's variants better?

Run (minutes; one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_samples.py --task cartpole --method dropconnect [--samples 20,100,400]
    .venv/bin/python scripts/sweep_samples.py --table          # the zoo README's table

The shipped agent is loaded with K samples per decision (``oodmon.agents.load(..., n_samples=K)``;
it still decides by the mean of its samples, so its episodes may differ a little from K=20's) and
measured as scripts/sweep_full_depth.py measures (10 ID episodes against 5 of each of the paper's
variants for the method, MC seed 0, whether or not the agent fails). A decision costs about K/20
times the shipped one. One JSON line per (task, method, K, agent) goes to
``results/sweeps/samples.jsonl`` (the agent: its weights' sha256); a line already there is not run
again, and the table marks the rows of the agent shipped today.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from oodmon.agents import load
from oodmon.threads import limit_threads
from sweep_full_depth import MC_SEED, VARIANTS, append_row, parse_or_print_table, read_rows, spread_aurocs

OUT = Path("results/sweeps/samples.jsonl")


def table() -> str:
    """Per (task, method, K) and score: the AUROC per variant and its mean over the variants."""
    lines = ["| task | method | agent (weights) | K | ID return | score | AUROC per variant | mean |",
             "|---|---|---|---:|---:|---|---|---:|"]
    shipped_weights: dict[tuple[str, str], str] = {}
    for row in read_rows(OUT):
        key = (row["task"], row["method"])
        if key not in shipped_weights:
            shipped_weights[key] = load(*key).metadata["safetensors_sha256"]
        shipped = shipped_weights[key] == row["safetensors_sha256"]
        agent = f"`{row['safetensors_sha256'][:8]}`" + (" (shipped)" if shipped else " (shipped before)")
        for score, aurocs in row["auroc"].items():
            cells = "; ".join(f"{spec.split(':')[1]} {value:.3f}" for spec, value in aurocs.items())
            lines.append(f"| {row['task']} | {row['method']} | {agent} | {row['n_samples']} | {row['id_return_mean']:.1f} | "
                         f"`{score}` | {cells} | {np.mean(list(aurocs.values())):.3f} |")
    return "\n".join(lines)


def _counts(text: str) -> list[int]:
    counts = [int(k) for k in text.split(",")]
    if any(k < 2 for k in counts):
        raise argparse.ArgumentTypeError(f"--samples {text!r}: each K must be an integer >= 2")
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", choices=["cartpole", "pendulum"])
    parser.add_argument("--method", choices=["dropout", "dropconnect"])
    parser.add_argument("--samples", type=_counts, default=[20, 100, 400], help="values of K, e.g. 20,100,400")
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    if args.task is None or args.method is None:
        parser.error("give --task and --method (or --table)")
    done = {(r["task"], r["method"], r["n_samples"], r["safetensors_sha256"]) for r in read_rows(OUT)}
    for k in args.samples:
        agent = load(args.task, args.method, n_samples=k, seed=MC_SEED)
        weights = agent.metadata["safetensors_sha256"]
        if (args.task, args.method, k, weights) in done:
            continue
        auroc, returns, id_return = spread_aurocs(agent, args.task, VARIANTS[(args.task, args.method)])
        append_row(OUT, {"task": args.task, "method": args.method, "safetensors_sha256": weights, "n_samples": k,
                         "mc_seed": MC_SEED, "id_return_mean": id_return, "auroc": auroc,
                         "variant_return_mean": returns})


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
