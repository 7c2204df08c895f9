"""Every shipped agent loads, solves its task as its metadata says, and reproduces its ID episodes."""

from __future__ import annotations

import numpy as np
import pytest

from oodmon.agents import episode_returns, load, zoo_dir, zoo_names
from oodmon.envs import Variant

SOLVED = {"cartpole": 475.0, "pendulum": -200.0}
CLASSIC = [f"{task}-{method}" for task in SOLVED for method in ("dropout", "dropconnect", "ensemble")]
SIZE_BUDGET = 50 * 2**20


def test_the_zoo_ships_every_classic_agent():
    assert set(CLASSIC) <= set(zoo_names())


def test_the_zoo_is_small():
    size = sum(p.stat().st_size for p in zoo_dir().rglob("*") if p.is_file())
    assert size < SIZE_BUDGET / 5, f"zoo is {size / 2**20:.1f} MiB"


@pytest.mark.parametrize("name", CLASSIC)
def test_shipped_agent_solves_its_task_and_reproduces_its_id_episodes(name):
    task, method = name.split("-")
    agent = load(task, method, seed=None)
    meta = agent.metadata
    assert meta["task"] == task and meta["method"] == method
    assert meta["id_episodes"] == 20 and meta["id_return_mean"] >= SOLVED[task]
    assert meta["id_return_mean"] == pytest.approx(np.mean(meta["id_returns"]), abs=0.01)
    # The first episodes of the ID evaluation, replayed with the same seeds, give the same returns.
    replay = load(task, method, seed=meta["seed"])
    returns = episode_returns(replay.act, Variant(task), 3, seed=100_000)
    np.testing.assert_allclose(returns, meta["id_returns"][:3], atol=0.01)
    assert agent.estimator.n_samples == (5 if method == "ensemble" else 20)
