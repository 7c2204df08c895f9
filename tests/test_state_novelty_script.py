"""scripts/state_novelty.py: how new a shifted world's observations are, beside the spread's AUROC."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers import load_script


@pytest.fixture
def script(monkeypatch):
    import oodmon

    monkeypatch.syspath_prepend(str(Path(oodmon.__file__).parent.parent / "scripts"))  # it imports sweep_full_depth
    return load_script("state_novelty")[1]


def test_novelty_is_the_standardised_distance_to_the_nearest_reference_observations(script):
    rng = np.random.default_rng(0)
    reference = rng.standard_normal((500, 2)) * np.array([1.0, 100.0])  # the second axis in other units
    distance = script.novelty(reference)
    # Standardised, one std along either axis is as far: 3 std away on the big axis reads like 3 on the small one.
    far_small, far_big = distance(np.array([[3.0, 0.0], [0.0, 300.0]]))
    assert abs(far_small - far_big) < 0.5
    inside, outside = distance(np.array([[0.0, 0.0], [6.0, 0.0]]))
    assert inside < 0.3 < 2.0 < outside  # 5 of 500 points lie close to the centre; none within 2 std of (6, 0)
    mean, std = reference.mean(axis=0), reference.std(axis=0)
    exact = np.sort(np.hypot(*((reference - mean) / std - (np.array([6.0, 0.0]) - mean) / std).T))[:5]
    assert abs(outside - exact.mean()) < 1e-9
    assert script.auroc(np.array([0.1, 0.2]), np.array([0.3, 0.4])) == 1.0


def test_state_novelty_runs_on_the_zoo_agent_and_scores_every_paper_variant(script, capsys):
    rows = script.main(["--task", "cartpole", "--method", "dropconnect", "--reference", "2", "--id-episodes", "1",
                        "--shifted-episodes", "1"])
    assert list(rows) == script.VARIANTS[("cartpole", "dropconnect")]
    assert all(0.0 <= value <= 1.0 for row in rows.values() for value in row.values())
    # length=2.0 is the paper's easiest DropConnect variant for the distance: a long pole falls through
    # angles and speeds no balanced ID episode reaches (0.967 with the full episode counts).
    assert rows["cartpole:length=2.0"]["novelty"] > 0.8
    assert capsys.readouterr().out.splitlines()[-1].startswith("mean")


def test_state_novelty_refuses_empty_episode_counts(script):
    with pytest.raises(SystemExit):
        script.main(["--task", "cartpole", "--method", "dropconnect", "--reference", "0"])
