"""Ensemble spreads after putting each member on its own ID footing, four ways, on the bench's trials.

Run (seconds; needs the bench's five CartPole and Pendulum ensemble trials, which
`oodmon bench --task T --trials 5 --workers 2 --out runs/bench5` trains and caches):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/member_normalisations.py

Per trial (trial 0 the shipped ensemble), each member's values at every step: a Pendulum actor's
output before its tanh, a CartPole DQN's Q-values centred on their mean over the actions (for two
actions, half the margin Q0 - Q1 and its negative). Each member's values are normalised by
statistics of that member on 10 ID episodes (seeds 300000+): divided by the median |value|
(``x/med|x|``, ``scaled_spread``'s for DDPG), or as robust or plain z-scores (the latter
``scaled_spread``'s for DQN); then the std
over the members, averaged over actions, is each step's score. Printed per variant of the paper's
ensemble tables and normalisation: the per-step AUROC of 10 ID episodes (seeds 200000+) against 5
shifted ones (seeds 400000+), the sweeps' episodes, whether or not the trial fails there; per trial,
then mean ± std (ddof 0, as the bench's tables) over the five.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from oodmon.agents import load_agent
from oodmon.envs import parse_variant
from oodmon.monitor.detectors import ScaledSpreadDetector, collect
from oodmon.threads import limit_threads
from sweep_full_depth import bench_trial, step_auroc  # scripts/

VARIANTS = {"cartpole": ["cartpole:gravity=98.0", "cartpole:length=2.0"],
            "pendulum": ["pendulum:l=0.1", "pendulum:m=0.05"]}


def trajectories(folder: Path, spec: str | None, episodes: int, seed: int) -> list:
    """``episodes`` episodes of ``spec`` (None: the model's task), the ensemble acting, with its
    members' values (a DDPG actor's outputs before the tanh, a DQN's centred Q-values)."""
    agent = load_agent(folder)
    return collect(agent, parse_variant(spec or agent.task).make(), episodes, seed=seed, with_member_values=True)


def normalisations(fit: list) -> dict:
    """Functions of (steps, members, n) values to the same values, each member's normalised by its
    statistics on the ``fit`` trajectories: ``scaled_spread``'s two normalisations as the detector
    computes them, and a robust z-score (its scale at least 1e-3 of the largest member's)."""
    values = np.concatenate([t.member_values for t in fit])
    median = np.median(values, axis=0)
    mad = np.median(np.abs(values - median), axis=0)
    mad = np.maximum(mad, 1e-3 * mad.max())
    return {
        "x/med|x|": ScaledSpreadDetector("scale").fit(fit).normalised,
        "(x-med)/MAD": lambda x: (x - median) / mad,
        "(x-mean)/std": ScaledSpreadDetector("zscore").fit(fit).normalised,
    }


def spread(values: np.ndarray) -> np.ndarray:
    """(steps,): the std over the members, averaged over the n values."""
    return values.std(axis=1).mean(axis=-1)


def main() -> None:
    results: dict[tuple[str, str], list[float]] = {}
    for task in ("cartpole", "pendulum"):
        for trial in range(5):
            folder = bench_trial(task, "ensemble", trial)
            normalise = normalisations(trajectories(folder, None, 10, 300_000))
            ids = np.concatenate([t.member_values for t in trajectories(folder, None, 10, 200_000)])
            for spec in VARIANTS[task]:
                shifted = np.concatenate([t.member_values for t in trajectories(folder, spec, 5, 400_000)])
                results.setdefault((spec, "raw std"), []).append(step_auroc(spread(ids), spread(shifted)))
                for name, normalised in normalise.items():
                    results.setdefault((spec, name), []).append(
                        step_auroc(spread(normalised(ids)), spread(normalised(shifted))))
    print("| variant | normalisation | per trial | mean ± std |\n|---|---|---|---|")
    for (spec, name), aurocs in results.items():
        print(f"| {spec} | {name} | {' '.join(f'{a:.3f}' for a in aurocs)} | {np.mean(aurocs):.3f} ± {np.std(aurocs):.3f} |")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
