"""Are a shifted world's states new to the agent? A nearest-neighbour check beside the spread's AUROC.

Run (a minute for CartPole DropConnect; one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/state_novelty.py --task cartpole --method dropconnect
        [--agent runs/bench5/models/cartpole-dropconnect-trial3]    # another trained folder than the zoo's

The agent (the zoo's, or ``--agent``'s folder) plays, deciding as it ships: ``--reference`` ID
episodes (seeds 300000+) whose observations are the reference; then the sweeps' episodes (10 ID,
seeds 200000+, against 5 of each of the paper's variants for the method, seeds 400000+; MC seed 0,
as ``scripts/sweep_full_depth.py``). Each step's novelty is the mean Euclidean distance of its
observation, standardised by the reference's mean and std, to its 5 nearest reference observations.
It prints, per variant, the per-step AUROC of that distance (shifted steps against ID ones) and of
the paper's score (``chosen_std``) on the same steps, then their means over the variants.

A high novelty AUROC where the spread's is low says the shifted states do differ from the ID ones
and the network's spread does not see it (measured on 2026-11-24: the zoo's CartPole DropConnect
agent, 0.86-0.97 against 0.55-0.65; the zoo README).
"""

from __future__ import annotations

import argparse

import numpy as np
from sklearn.neighbors import NearestNeighbors

from oodmon.agents import load, load_agent
from oodmon.envs import parse_variant
from oodmon.monitor import MemorySink, Monitor
from oodmon.threads import limit_threads
from sweep_full_depth import MC_SEED, VARIANTS, step_auroc

NEIGHBOURS = 5


def play(agent, spec: str, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Every step's observation and ``chosen_std``: the agent under the monitor, ``episodes`` of ``spec``
    (seeds ``seed``, ``seed`` + 1, ...), as the sweeps play theirs."""
    sink, env = MemorySink(), parse_variant(spec).make()
    with Monitor(agent, score="chosen_std", sinks=[sink]) as monitor:
        for k in range(episodes):
            monitor.run_episode(env, seed=seed + k, variant=spec)
    env.close()
    return np.array([step.observation for step in sink.steps]), np.array([step.score for step in sink.steps])


def novelty(reference: np.ndarray):
    """observations -> mean distance to the ``NEIGHBOURS`` nearest standardised reference observations."""
    mean, std = reference.mean(axis=0), np.maximum(reference.std(axis=0), 1e-9)
    index = NearestNeighbors(n_neighbors=NEIGHBOURS).fit((reference - mean) / std)
    return lambda observations: index.kneighbors((observations - mean) / std)[0].mean(axis=1)


def auroc(id_values: np.ndarray, shifted: np.ndarray) -> float:
    return round(step_auroc(id_values, shifted), 3)


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", choices=["cartpole", "pendulum"], required=True)
    parser.add_argument("--method", choices=["dropout", "dropconnect"], required=True)
    parser.add_argument("--agent", help="a trained agent's folder (default: the zoo's agent)")
    parser.add_argument("--reference", type=int, default=20, help="ID episodes whose observations are the reference")
    parser.add_argument("--id-episodes", type=int, default=10)
    parser.add_argument("--shifted-episodes", type=int, default=5)
    args = parser.parse_args(argv)
    if min(args.reference, args.id_episodes, args.shifted_episodes) < 1:
        parser.error("--reference, --id-episodes and --shifted-episodes must be at least 1")
    agent = (load_agent(args.agent, task=args.task, seed=MC_SEED) if args.agent
             else load(args.task, args.method, seed=MC_SEED))
    distance = novelty(play(agent, args.task, args.reference, 300_000)[0])
    id_obs, id_scores = play(agent, args.task, args.id_episodes, 200_000)
    id_distance = distance(id_obs)
    rows = {}
    print(f"{'variant':24s} {'novelty AUROC':>14s} {'chosen_std AUROC':>17s}")
    for spec in VARIANTS[(args.task, args.method)]:
        obs, scores = play(agent, spec, args.shifted_episodes, 400_000)
        rows[spec] = {"novelty": auroc(id_distance, distance(obs)), "chosen_std": auroc(id_scores, scores)}
        print(f"{spec:24s} {rows[spec]['novelty']:14.3f} {rows[spec]['chosen_std']:17.3f}", flush=True)
    means = {name: float(np.mean([row[name] for row in rows.values()])) for name in ("novelty", "chosen_std")}
    print(f"{'mean':24s} {means['novelty']:14.3f} {means['chosen_std']:17.3f}")
    return rows


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
