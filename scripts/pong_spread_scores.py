"""The shipped Pong agents' spread under each DQN score (chosen_std, mean_std, max_std, margin_std), on
the steps of scripts/measure_pong_features.py.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/pong_spread_scores.py [METHOD ...]   (a few minutes each)
     .venv/bin/python scripts/pong_spread_scores.py --table                            (docs/pong.md's table)

The same steps as measure_pong_features.py (the first 1,000 steps of 2 ID games, the first 500 of one
game per corruption at severity 3-5, the same seeds), so its ``chosen_std`` column is the ``spread``
of results/detectors/pong-<method>.json. Each step's estimate is drawn once, the one its action was
chosen from (as the monitor reads it; since 2026-11-28, before which the agent was asked again at
each step), and every score is read from it. Writes per method, score and variant the per-step AUROC to
results/detectors/spread-scores-pong.json (a method measured again replaces its entry).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from oodmon import seeds
from oodmon.agents import load
from oodmon.envs import Variant, parse_variant
from oodmon.monitor.detectors import collect
from oodmon.monitor.scores import score_function
from oodmon.threads import limit_threads

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure_pong_features import METHODS, VARIANTS, method_arguments  # noqa: E402  (the script beside this one)

OUT = Path("results/detectors/spread-scores-pong.json")
SCORES = ("chosen_std", "mean_std", "max_std", "margin_std")


def _scores(trajectory) -> dict[str, np.ndarray]:
    functions = {name: score_function(name) for name in SCORES}
    values: dict[str, list[float]] = {name: [] for name in SCORES}
    for estimate in trajectory.estimates:
        for name, function in functions.items():
            values[name].append(float(function(estimate)[0]))
    return {name: np.asarray(v) for name, v in values.items()}


def measure(method: str) -> dict:
    agent = load("pong", method, seed=0)
    start = time.time()
    ids = [_scores(t) for t in collect(agent, Variant("pong").make(), 2, seed=seeds.BENCH_ID, max_steps=1000,
                                       estimates_from=0)]
    result: dict = {"id_steps": sum(len(s["chosen_std"]) for s in ids), "auroc": {name: {} for name in SCORES}}
    for spec in VARIANTS:
        shifted = _scores(collect(agent, parse_variant(spec).make(), 1, seed=seeds.BENCH_SHIFTED, max_steps=500,
                                  estimates_from=0)[0])
        for name in SCORES:
            negatives = np.concatenate([s[name] for s in ids])
            labels = np.r_[np.zeros(len(negatives)), np.ones(len(shifted[name]))]
            result["auroc"][name][spec] = round(float(roc_auc_score(labels, np.r_[negatives, shifted[name]])), 4)
        print(method, spec, {name: result["auroc"][name][spec] for name in SCORES}, flush=True)
    result["wall_time_s"] = round(time.time() - start, 1)
    return result


def table(results: dict) -> str:
    """Per method and score, the mean AUROC over the noises (gaussian, impulse) and over motion blur."""
    lines = ["| method | score | noises @3-5: mean (lowest) | motion blur @3-5: mean (lowest) |", "|---|---|---|---|"]
    for method in (m for m in METHODS if m in results):
        for name in SCORES:
            row = results[method]["auroc"][name]
            cells = []
            for kind in (("gaussian_noise", "impulse_noise"), ("motion_blur",)):
                values = [v for spec, v in row.items() if spec.split(":")[1].split("@")[0] in kind]
                cells.append(f"{np.mean(values):.3f} ({min(values):.3f})")
            lines.append(f"| {method} | `{name}` | {cells[0]} | {cells[1]} |")
    return "\n".join(lines)


def _read() -> dict:
    return json.loads(OUT.read_text()) if OUT.exists() else {}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", action="store_true", help="print docs/pong.md's table from the committed results")
    args = method_arguments(parser, argv)
    if args.table:
        print(table(_read()))
        return
    for method in args.methods:
        measured = measure(method)
        results = _read()  # read after measuring: another run may have written meanwhile
        results[method] = measured
        OUT.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
