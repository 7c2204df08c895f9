"""The Q-values a CartPole DQN training learned, snapshot by snapshot, beside the Bellman bound.

Run:
    .venv/bin/python scripts/q_values.py runs/bench5/models/cartpole-dropconnect-trial3 [more training folders]

A training folder (``oodmon train --out F``, or a bench trial model ``<out>/models/cartpole-<method>-trial<k>``)
keeps a snapshot of its weights at every periodic evaluation when its recipe chooses among snapshots
(``select_top``: CartPole DropConnect), else only its best and last weights. For each snapshot (or
those two) this prints the mean over 50 ID start states (reset seeds 0-49) of max_a Q(s, a), with
the weights as they are (no dropout or DropConnect sampled: what the DQN's target network reads),
beside the evaluation return logged at that step. CartPole pays 1 per step with gamma 0.99, so no
policy is worth more than 1 / (1 - 0.99) = 100 from any state; a Q-value far above it has been
learned from its own overestimates, not from returns.

Reads DQN MLP Q-networks (``q_net.q_net.<i>.weight``, ReLU between layers, SB3's default), one head.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium
import numpy as np
from safetensors.numpy import load_file

import oodmon  # noqa: F401  (registers the envs)
from oodmon.envs.grid import ENV_IDS

GAMMA = 0.99
BOUND = 1.0 / (1.0 - GAMMA)


def start_states(count: int = 50) -> np.ndarray:
    env = gymnasium.make(ENV_IDS["cartpole"])
    return np.array([env.reset(seed=seed)[0] for seed in range(count)], np.float32)


def mean_max_q(weights: dict[str, np.ndarray], states: np.ndarray) -> float:
    """Mean over ``states`` of max_a Q(s, a) of the MLP in ``weights`` (Linear layers in order, ReLU between)."""
    layers = sorted({int(key.split(".")[2]) for key in weights if key.startswith("q_net.q_net.") and key.endswith(".weight")})
    if not layers:
        raise SystemExit("no q_net.q_net.<i>.weight tensors: not a DQN MLP snapshot")
    x = states
    for position, index in enumerate(layers):
        x = x @ weights[f"q_net.q_net.{index}.weight"].T + weights[f"q_net.q_net.{index}.bias"]
        if position < len(layers) - 1:
            x = np.maximum(x, 0.0)
    return float(x.max(axis=1).mean())


def snapshots(folder: Path) -> list[tuple[str, Path]]:
    """(label, weights file) of a training folder's snapshots, by steps; else its best and last weights."""
    found = []
    for run in sorted((folder / "runs").glob("*")):
        kept = sorted((run / "snapshots").glob("*.safetensors"), key=lambda p: int(p.stem))
        found += [(f"{run.name} {p.stem}", p) for p in kept] or [
            (f"{run.name} {p.stem}", p) for p in (run / "best_policy.safetensors", run / "policy.safetensors") if p.exists()]
    return found


def evaluations(folder: Path) -> dict[str, float]:
    log = folder / "train_log.jsonl"
    rows = [json.loads(line) for line in log.read_text().splitlines() if line.strip()] if log.exists() else []
    return {f"{r['run']} {r['steps']}": r["eval_return_mean"] for r in rows if "eval_return_mean" in r}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="training folders (each with runs/<run>/...)")
    args = parser.parse_args()
    states = start_states()
    print(f"Bellman bound: {BOUND:.0f} (reward 1 per step, gamma {GAMMA})")
    for folder in args.folders:
        found = snapshots(folder)
        if not found:
            raise SystemExit(f"{folder}: no runs/<run>/snapshots, best_policy or policy weights")
        returns = evaluations(folder)
        print(f"{folder}: snapshot, mean max Q over 50 start states, evaluation return")
        for label, path in found:
            logged = returns.get(label)
            print(f"  {label:>12s} {mean_max_q(load_file(str(path)), states):9.1f} {'' if logged is None else f'{logged:7.1f}'}")


if __name__ == "__main__":
    main()
