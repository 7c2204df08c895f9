"""Ensemble spreads after putting each member on its own ID footing, four ways, on the bench's trials.

Run (seconds; needs the bench's five CartPole and Pendulum ensemble trials, which
`oodmon bench --task T --trials 5 --workers 2 --out runs/bench5` trains and caches):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/member_normalisations.py

Per trial (trial 0 the shipped ensemble), each member's values at every step: a Pendulum actor's
output before its tanh, a CartPole DQN's Q-values centred on their mean over the actions (for two
actions, half the margin Q0 - Q1 and its negative). Each member's values are normalised by
statistics of that member on 10 ID episodes (seeds 300000+): divided by the median |value|
(``x/med|x|``, the ``scaled_spread`` detector's), or as robust or plain z-scores; then the std
over the members, averaged over actions, is each step's score. Printed per variant of the paper's
ensemble tables and normalisation: the per-step AUROC of 10 ID episodes (seeds 200000+) against 5
shifted ones (seeds 400000+), the sweeps' episodes, whether or not the trial fails there; per trial,
then mean ± std (ddof 0, as the bench's tables) over the five.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from member_spread import member_outputs  # scripts/
from oodmon.agents import load_agent
from oodmon.envs import parse_variant
from sweep_full_depth import bench_trial, step_auroc  # scripts/

VARIANTS = {"cartpole": ["cartpole:gravity=98.0", "cartpole:length=2.0"],
            "pendulum": ["pendulum:l=0.1", "pendulum:m=0.05"]}


def centred_q_values(folder: Path, spec: str | None, episodes: int, seed: int) -> np.ndarray:
    """(members, steps, actions): each DQN member's Q-values minus their mean over the actions, the
    ensemble acting on ``episodes`` episodes of ``spec`` (None: the model's task)."""
    agent = load_agent(folder)
    env, out = parse_variant(spec or agent.task).make(), []
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        done = False
        while not done:
            estimate = agent.estimate(obs)
            q = estimate.samples[:, 0]
            out.append(q - q.mean(axis=1, keepdims=True))
            obs, _, terminated, truncated, _ = env.step(int(estimate.action[0]))
            done = terminated or truncated
    env.close()
    return np.stack(out, axis=1)


def normalisations(fit: np.ndarray) -> dict:
    """Functions of (members, steps, n) values, each member's by its statistics on ``fit``
    (a scale at least 1e-3 of the largest member's, so that none divides by 0)."""
    def floor(scale):
        return np.maximum(scale, 1e-3 * scale.max())

    median = np.median(fit, axis=1, keepdims=True)
    return {
        "x/med|x|": lambda x: x / floor(np.median(np.abs(fit), axis=1, keepdims=True)),
        "(x-med)/MAD": lambda x: (x - median) / floor(np.median(np.abs(fit - median), axis=1, keepdims=True)),
        "(x-mean)/std": lambda x: (x - fit.mean(axis=1, keepdims=True)) / floor(fit.std(axis=1, keepdims=True)),
    }


def main() -> None:
    results: dict[tuple[str, str], list[float]] = {}
    for task, values in (("cartpole", centred_q_values),
                         ("pendulum", lambda *a: member_outputs(*a)[..., None])):
        for trial in range(5):
            folder = bench_trial(task, "ensemble", trial)
            fit, ids = values(folder, None, 10, 300_000), values(folder, None, 10, 200_000)
            for spec in VARIANTS[task]:
                shifted = values(folder, spec, 5, 400_000)
                results.setdefault((spec, "raw std"), []).append(
                    step_auroc(ids.std(axis=0).mean(axis=1), shifted.std(axis=0).mean(axis=1)))
                for name, normalise in normalisations(fit).items():
                    results.setdefault((spec, name), []).append(
                        step_auroc(normalise(ids).std(axis=0).mean(axis=1), normalise(shifted).std(axis=0).mean(axis=1)))
    print("| variant | normalisation | per trial | mean ± std |\n|---|---|---|---|")
    for (spec, name), aurocs in results.items():
        print(f"| {spec} | {name} | {' '.join(f'{a:.3f}' for a in aurocs)} | {np.mean(aurocs):.3f} ± {np.std(aurocs):.3f} |")


if __name__ == "__main__":
    main()
