"""Which layer should the features detector read on a full-depth MC agent?

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/full_depth_features.py MODEL_DIR [--variants SPECS]

An MC agent's features (``Estimate.features``) are the activations its sampling starts from: the
last hidden layer when the stochastic layer sits at the output layer only, but the first hidden
layer (Dropout) or the observation itself (DropConnect) at full depth. This scores, on the same
episodes and with oodmon's own ``FeaturesDetector`` (fitted on the same ID episodes), those
features beside the last hidden layer of the network with its stochastic layers off (eval mode:
dropout is the identity, DropConnect the whole weights), and prints the per-step AUROC of each
per variant, shifted from step 0 against held-out ID steps, then the mean and lowest.

MODEL_DIR is a saved CartPole DQN agent (model.json and model.safetensors), e.g. a sweep's or the
zoo's ``oodmon/zoo/cartpole-dropout``. ``--variants``: comma-separated specs (default: the
paper's CartPole Dropout variants). Episodes: ``--fit-episodes`` ID ones to fit on (seeds from
1,000), ``--id-episodes`` held-out ID ones (seeds from 2,000), ``--episodes`` per variant (seeds
from 500,000, the bench's), the agent's MC samples seeded with 0.

Measured on 2026-12-04 (results/sweeps/README.md, "Shipping it was tried"): the full-depth
CartPole Dropout agent of p = 0.3, seed 0, on its 34 failing variants of the paper's grid, 60 / 10
/ 5 episodes: the first hidden layer 0.898 / 0.545 (mean / lowest), the last hidden layer 0.907 /
0.555: the layer is not why its features detector reads below the output-layer agent's. The
zoo's full-depth CartPole DropConnect agent (whose features are the observation itself), on its
44 failing variants of results/detectors/cartpole.json: the observation 0.920 / 0.469, the last
hidden layer 0.901 / 0.456: lower. Both kept reading what they read.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch
from sklearn.metrics import roc_auc_score

from oodmon.agents.agent import Agent, agent_from_modules
from oodmon.agents.serialization import load_modules
from oodmon.envs.grid import parse_variant
from oodmon.errors import OodmonError
from oodmon.monitor.detectors import collect
from oodmon.monitor.detectors.base import StepContext, Trajectory
from oodmon.monitor.detectors.features import FeaturesDetector
from oodmon.threads import limit_threads

#: The paper's CartPole Dropout variants (its appendix table), the default.
PAPER_DROPOUT = "cartpole:force_mag=2.5,cartpole:gravity=49.0,cartpole:masscart=3.0"
#: The two layers compared: today's features, and the last hidden layer with sampling off.
LAYERS = ("sampling input", "last hidden, eval")


class _Features:
    """What a StepContext reads of an estimate: its features, a batch of one."""

    def __init__(self, features: np.ndarray) -> None:
        self.features = features[None]


def play(agent: Agent, last_hidden: torch.nn.Module, spec: str, first_seed: int,
         episodes: int) -> list[list[Trajectory]]:
    """``episodes`` episodes of ``spec`` (seeds from ``first_seed``) as the detectors' fitting plays
    them, per layer of :data:`LAYERS`: the trajectories with the features the agent gave, and the
    same with its last hidden layer's (one pass over each episode's observations)."""
    played = collect(agent, parse_variant(spec).make(), episodes, seed=first_seed)
    with torch.no_grad():
        last = [last_hidden(torch.as_tensor(np.asarray(t.observations[:-1], np.float32))).numpy() for t in played]
    return [played, [replace(t, features=features) for t, features in zip(played, last)]]


def scores(detector: FeaturesDetector, trajectories: Sequence[Trajectory]) -> np.ndarray:
    """Every step's score of ``detector`` on ``trajectories``' features, episode by episode."""
    out = []
    for trajectory in trajectories:
        detector.reset()
        out += [detector.score(StepContext(np.zeros(1), int(action), estimate=_Features(features)))
                for action, features in zip(trajectory.actions, trajectory.features)]
    return np.asarray(out)


def compare(model_dir: str, variants: Sequence[str], *, fit_episodes: int = 60, id_episodes: int = 10,
            episodes: int = 5) -> dict[str, tuple[float, float]]:
    """Per variant, the per-step AUROC of the features detector on each layer of :data:`LAYERS`."""
    for spec in variants:  # a bad spec refused before any episode is played
        parse_variant(spec)
    modules, metadata = load_modules(model_dir, task="cartpole")
    agent = agent_from_modules(modules, metadata, model_dir, seed=0)
    last_hidden = modules["network"].eval()[:-1]
    fitting = play(agent, last_hidden, "cartpole", 1000, fit_episodes)
    held_out = play(agent, last_hidden, "cartpole", 2000, id_episodes)
    detectors = [FeaturesDetector(n_actions=2).fit(layer) for layer in fitting]
    id_scores = [scores(d, layer) for d, layer in zip(detectors, held_out)]
    result = {}
    for spec in variants:
        shifted = play(agent, last_hidden, spec, 500_000, episodes)
        aurocs = []
        for detector, ids, layer in zip(detectors, id_scores, shifted):
            s = scores(detector, layer)
            labels = np.r_[np.zeros(len(ids)), np.ones(len(s))]
            aurocs.append(float(roc_auc_score(labels, np.r_[ids, s])))
        result[spec] = tuple(aurocs)
    return result


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model_dir", help="a saved CartPole DQN agent's folder")
    parser.add_argument("--variants", default=PAPER_DROPOUT, help="comma-separated variant specs")
    parser.add_argument("--fit-episodes", type=int, default=60)
    parser.add_argument("--id-episodes", type=int, default=10)
    parser.add_argument("--episodes", type=int, default=5)
    args = parser.parse_args(argv)
    if min(args.fit_episodes, args.id_episodes, args.episodes) < 1:
        parser.error("--fit-episodes, --id-episodes and --episodes must be 1 or more")
    limit_threads()
    try:
        result = compare(args.model_dir, args.variants.split(","), fit_episodes=args.fit_episodes,
                         id_episodes=args.id_episodes, episodes=args.episodes)
    except OodmonError as error:  # a missing or other task's model, a bad variant spec: one line
        raise SystemExit(f"full_depth_features: {error}") from None
    print(f"{'variant':28s} {LAYERS[0]:>16s} {LAYERS[1]:>18s}")
    for spec, (today, last) in result.items():
        print(f"{spec:28s} {today:16.3f} {last:18.3f}")
    table = np.asarray(list(result.values()))
    print(f"mean / lowest: {LAYERS[0]} {table[:, 0].mean():.3f} / {table[:, 0].min():.3f}; "
          f"{LAYERS[1]} {table[:, 1].mean():.3f} / {table[:, 1].min():.3f}")


if __name__ == "__main__":
    main()
