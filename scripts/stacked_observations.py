"""Stacked vector observations: the frames detector against a dynamics model of them flattened.

Run (about 10 seconds on one core):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/stacked_observations.py

CartPole's state stacked 4 deep (``FrameStackObservation``, a float Box of shape (4, 4)), acted on
by a hand-written controller of the newest state. Each detector is fitted on 30 ID episodes, then
scored on 10 ID episodes against the shifted steps of 5 episodes of each variant (shift at step
20, episodes cut at 300 steps); per-step ROC AUC. Until 2026-11-26 oodmon read such observations as
a 4 x 4 picture (``frames``); ``default_detectors`` now gives them ``dynamics``, which models the
16 numbers flattened.
"""

from __future__ import annotations

import argparse

import numpy as np
from gymnasium.wrappers import FrameStackObservation
from sklearn.metrics import roc_auc_score

from oodmon.envs.grid import Variant
from oodmon.monitor import MemorySink, Monitor
from oodmon.monitor.detectors import fit_detectors
from oodmon.threads import limit_threads

CONTROLLER = np.array([0.1, 0.5, 3.0, 1.0])  # push right when 0.1 x + 0.5 x' + 3 theta + theta' > 0
VARIANTS = ({"length": 2.0}, {"masscart": 9.0}, {"gravity": 49.0}, {"force_mag": 2.5})


def policy(obs: np.ndarray) -> int:
    return int(CONTROLLER @ np.asarray(obs).reshape(-1, 4)[-1] > 0)


def make(**physics):
    return FrameStackObservation(Variant("cartpole", physics).make(onset_step=20), 4)


def step_scores(detectors, name: str, seeds: range, shifted_only: bool, **physics) -> list[float]:
    scores = []
    for seed in seeds:
        sink = MemorySink()
        with Monitor(policy, None, detectors=detectors, detector=name, sinks=[sink]) as monitor:
            monitor.run_episode(make(**physics), seed=seed, max_steps=300)
        scores += [step.scores[name] for step in sink.steps if step.shifted or not shifted_only]
    return scores


def main() -> None:
    limit_threads()
    for name in ("frames", "dynamics"):
        detectors = fit_detectors(policy, make(), detectors=[name], episodes=30)
        ids = step_scores(detectors, name, range(100, 110), False)
        row = []
        for physics in VARIANTS:
            ood = step_scores(detectors, name, range(200, 205), True, **physics)
            auroc = roc_auc_score([0] * len(ids) + [1] * len(ood), ids + ood)
            row.append(f"{','.join(f'{k}={v}' for k, v in physics.items())} {auroc:.3f}")
        print(f"{name:8s} " + "; ".join(row))


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
