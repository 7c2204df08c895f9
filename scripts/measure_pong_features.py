"""Per-step AUROC of the shipped Pong agents' detectors on the corruptions, without the full bench.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/measure_pong_features.py [METHOD ...]

A Pong bench (`oodmon bench --task pong --detectors spread,features,combined`) plays 10 whole ID
games and 5 per failing variant: hours on a CPU. This plays the first 1,000 steps of 2 ID games
(seeds of the bench's ID range) and the first 500 steps of one game per corruption at severity
3-5 (the bench's shifted seeds), scores every step with the agent's shipped detectors, off the
estimate its action was chosen from (as the monitor does; since 2026-11-28, before which a sampled
MC agent was asked again), and writes per-variant AUROC per detector as JSON to
results/detectors/pong-<method>.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from oodmon import seeds
from oodmon.agents import load
from oodmon.envs import Variant, parse_variant
from oodmon.monitor.detectors import collect, detectors_for, trajectory_scores
from oodmon.threads import limit_threads

WINDOWS = (1, 10, 30)  # the features detector's score averaged over its last N steps (computed from N = 1)
METHODS = ("ensemble", "dropout", "dropconnect")  # the order of docs/pong.md's tables (oodmon.names.METHODS: another)
VARIANTS = [f"pong:{c}@{s}" for c in ("gaussian_noise", "impulse_noise", "motion_blur") for s in (3, 4, 5)]


def _trailing(values: np.ndarray, window: int) -> np.ndarray:
    """The mean of each step's last ``window`` values (fewer at an episode's start), as the detector's
    ``window`` computes it."""
    sums = np.cumsum(np.r_[0.0, values])
    ends = np.arange(1, len(values) + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def measure(method: str) -> dict:
    agent = load("pong", method, seed=0)
    detectors = detectors_for(agent)
    start = time.time()
    id_runs = collect(agent, Variant("pong").make(), 2, seed=seeds.BENCH_ID, max_steps=1000, estimates_from=0)
    id_scores = [trajectory_scores(detectors, t) for t in id_runs]  # off the estimates the runs kept
    result = {"method": method, "id_steps": sum(len(t) for t in id_runs), "auroc": {}}
    for spec in VARIANTS:
        run = collect(agent, parse_variant(spec).make(), 1, seed=seeds.BENCH_SHIFTED, max_steps=500,
                      estimates_from=0)[0]
        scores = trajectory_scores(detectors, run)
        for name in detectors.names:
            negatives = np.concatenate([s[name] for s in id_scores])
            labels = np.r_[np.zeros(len(negatives)), np.ones(len(scores[name]))]
            auroc = float(roc_auc_score(labels, np.r_[negatives, scores[name]]))
            result["auroc"].setdefault(name, {})[spec] = round(auroc, 4)
        if detectors["features"].window == 1:
            for window in WINDOWS[1:]:
                negatives = np.concatenate([_trailing(s["features"], window) for s in id_scores])
                positives = _trailing(scores["features"], window)
                labels = np.r_[np.zeros(len(negatives)), np.ones(len(positives))]
                auroc = float(roc_auc_score(labels, np.r_[negatives, positives]))
                result["auroc"].setdefault(f"features-window{window}", {})[spec] = round(auroc, 4)
        print(method, spec, {n: values[spec] for n, values in result["auroc"].items()}, flush=True)
    result["wall_time_s"] = round(time.time() - start, 1)
    return result


def method_arguments(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> argparse.Namespace:
    """``parser`` with the shipped Pong agents to measure as its positional arguments, parsed:
    ``methods`` every one when none is named. (Not argparse's ``choices``: with ``nargs="*"``,
    Python 3.11's argparse refuses an empty list against them.)"""

    def method(name: str) -> str:
        if name not in METHODS:
            raise argparse.ArgumentTypeError(f"no shipped Pong agent {name!r}; choose from {', '.join(METHODS)}")
        return name

    parser.add_argument("methods", nargs="*", type=method, metavar="METHOD",
                        help=f"the shipped Pong agents to measure: {', '.join(METHODS)} (default: all three)")
    args = parser.parse_args(argv)
    args.methods = args.methods or list(METHODS)
    return args


def main(methods: list[str]) -> None:
    for method in methods:
        out = Path("results/detectors") / f"pong-{method}.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(measure(method), indent=1) + "\n")


if __name__ == "__main__":
    args = method_arguments(argparse.ArgumentParser(description=__doc__.split("\n\n")[0]))
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main(args.methods)
