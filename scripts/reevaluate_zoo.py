"""Redo the ID evaluation in the metadata of shipped agents, with the weights as they are.

Run: .venv/bin/python scripts/reevaluate_zoo.py cartpole-dropconnect pendulum-dropconnect

For when the sampling code changes the random stream an MC agent draws from (not the weights,
not the distribution of its samples): the agent's ``id_returns`` are recomputed with the seeds and
episode count that training used (``oodmon.agents.training.train``: seed 100_000 onwards, the
agent's own sampling seed), so that ``tests/agents/test_zoo.py`` can replay them exactly. The
weights are not touched; ``id_reevaluated`` records when and with which oodmon version.
"""

from __future__ import annotations

import argparse
import datetime
import json

import numpy as np

from oodmon import __version__
from oodmon.agents import episode_returns, load, zoo_dir
from oodmon.envs import Variant
from oodmon.threads import limit_threads


def reevaluate(name: str) -> None:
    task, method = name.split("-")
    path = zoo_dir() / name / "model.json"
    metadata = json.loads(path.read_text())
    agent = load(task, method, seed=metadata["seed"])
    returns = episode_returns(agent.act, Variant(task), metadata["id_episodes"], seed=100_000)
    before = metadata["id_return_mean"]
    metadata.update(
        id_returns=[round(float(r), 2) for r in returns], id_return_mean=round(float(np.mean(returns)), 2),
        id_reevaluated={"date": datetime.date.today().isoformat(), "oodmon": __version__,
                        "command": "python scripts/reevaluate_zoo.py " + name},
    )
    path.write_text(json.dumps(metadata, indent=1, sort_keys=True) + "\n")
    print(f"{name}: id_return_mean {before} -> {metadata['id_return_mean']} over {len(returns)} episodes")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="+", metavar="NAME", choices=sorted(p.parent.name for p in zoo_dir().glob("*/model.json")),
                        help="shipped agents, e.g. cartpole-dropconnect")
    args = parser.parse_args()  # every name checked before any file is written
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    for zoo_name in args.names:
        reevaluate(zoo_name)
