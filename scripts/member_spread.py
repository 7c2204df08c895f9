"""Which members of a DDPG ensemble set its ``pre_squash_std``, on ID steps and shifted ones.

Run (seconds; any Pendulum ensemble's model folder: the zoo's, a bench trial's):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/member_spread.py \
        runs/bench5/models/pendulum-ensemble-members20-trial3 [--variant pendulum:l=0.1]

The ensemble acts (its members' mean decides) for 10 ID episodes (seeds 200000+) and 5 of the
variant (seeds 400000+), the sweeps' episodes, and at every step each member's actor output before
its tanh is taken. ``pre_squash_std`` is the std of those outputs over the members; the script
prints its per-step AUROC (shifted steps against ID ones) with every member, then per member the
median |output| on ID and on shifted steps and the AUROC without that member. A member whose ID
outputs sit far out on the tanh (a large ID median: it saturates the torque where the others do
not) widens the ID spread at every step, and leaving it out raises the AUROC. The last lines give
two spreads that no single member can set, the median absolute deviation and the interquartile
range of the same outputs, for comparison; and the std of the outputs after dividing each member's
by its own scale on ID steps, the median |output| over 10 other ID episodes (seeds 300000+), which
puts a saturating member on the others' footing (results/bench/README.md, "Why more members score worse").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from oodmon.agents import load_agent
from oodmon.envs import parse_variant
from oodmon.errors import ConfigError
from oodmon.monitor.detectors import collect
from oodmon.threads import limit_threads
from sweep_full_depth import step_auroc  # scripts/: the sweeps' AUROC

SPREADS = {
    "std": lambda outputs: outputs.std(axis=0),
    "median absolute deviation": lambda outputs: np.median(np.abs(outputs - np.median(outputs, axis=0)), axis=0),
    "interquartile range": lambda outputs: np.subtract(*np.percentile(outputs, [75, 25], axis=0)),
}


def member_outputs(folder: Path, spec: str | None, episodes: int, seed: int) -> np.ndarray:
    """(members, steps): each member's actor output before its tanh at every step of ``episodes``
    episodes of ``spec`` (None: the model's own task; seeds ``seed``, ``seed`` + 1, ...), the
    ensemble acting (the members' values ``collect`` keeps for ``scaled_spread``).

    Raises:
        ConfigError: the folder's model is not an ensemble of tanh actors with one action.
    """
    agent = load_agent(folder)
    trajectories = collect(agent, parse_variant(spec or agent.task).make(), episodes, seed=seed,
                           with_member_values=True)
    values = [t.member_values for t in trajectories]
    if any(v is None for v in values) or np.asarray(trajectories[0].actions).dtype.kind in "iu":
        raise ConfigError(f"{folder} is not an ensemble of independent DDPG actors (their outputs end in tanh)")
    outputs = np.concatenate(values)  # (steps, members, actions)
    if outputs.shape[2] != 1:
        raise ConfigError(f"{folder}'s actor has {outputs.shape[2]} actions; this script reads one")
    return outputs[:, :, 0].T


def report(id_outputs: np.ndarray, shifted: np.ndarray, scales: np.ndarray | None = None) -> list[str]:
    """The printed lines: the AUROC of ``pre_squash_std`` with every member; per member its
    median |output| on ID and shifted steps and the AUROC without it; the other spreads' AUROCs;
    with ``scales`` (members,), each member's scale on other ID steps, the AUROC of the std of the
    outputs divided by them."""
    every = range(len(id_outputs))

    def auroc(members, spread=SPREADS["std"]) -> float:
        return step_auroc(spread(id_outputs[members]), spread(shifted[members]))

    lines = [f"pre_squash_std AUROC with all {len(id_outputs)} members: {auroc(list(every)):.3f}",
             "member | median |output| ID | shifted | AUROC without it"]
    for k in every:
        lines.append(f"{k:6d} | {np.median(np.abs(id_outputs[k])):18.2f} | {np.median(np.abs(shifted[k])):7.2f} | "
                     f"{auroc([j for j in every if j != k]):.3f}")
    lines += [f"AUROC of the outputs' {name}, all members: {auroc(list(every), spread):.3f}"
              for name, spread in SPREADS.items() if name != "std"]
    if scales is not None:
        scaled = step_auroc(SPREADS["std"](id_outputs / scales[:, None]), SPREADS["std"](shifted / scales[:, None]))
        lines.append(f"AUROC of the std of each member's output over its median |output| on other ID episodes: {scaled:.3f}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="an ensemble's model folder (model.json + model.safetensors)")
    parser.add_argument("--variant", default="pendulum:l=0.1", help="the shifted variant (default pendulum:l=0.1)")
    args = parser.parse_args()
    id_outputs = member_outputs(args.folder, None, 10, 200_000)
    shifted = member_outputs(args.folder, args.variant, 5, 400_000)
    scales = np.median(np.abs(member_outputs(args.folder, None, 10, 300_000)), axis=1)
    print(f"{args.folder}, ID against {args.variant}")
    print("\n".join(report(id_outputs, shifted, scales)))


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
