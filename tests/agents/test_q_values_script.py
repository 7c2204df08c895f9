"""scripts/q_values.py: a DQN snapshot's Q-values at ID start states, beside the Bellman bound."""

from __future__ import annotations

import json

import numpy as np
from safetensors.numpy import save_file

from tests.helpers import load_script


def _snapshot(path, scale: float) -> dict[str, np.ndarray]:
    """A [4] -> 3 -> ReLU -> 2 Q-network, its keys as SB3's DQN policy saves them (a dropout layer
    between them, index 1, has no tensors)."""
    rng = np.random.default_rng(0)
    weights = {"q_net.q_net.0.weight": rng.standard_normal((3, 4)).astype(np.float32),
               "q_net.q_net.0.bias": np.ones(3, np.float32),
               "q_net.q_net.2.weight": rng.standard_normal((2, 3)).astype(np.float32),
               "q_net.q_net.2.bias": np.full(2, scale, np.float32)}
    save_file(weights, str(path))
    return weights


def test_q_values_reads_each_snapshot_as_the_target_network_would(tmp_path, capsys, monkeypatch):
    script = load_script("q_values")[1]
    snapshots = tmp_path / "runs" / "main" / "snapshots"
    snapshots.mkdir(parents=True)
    first = _snapshot(snapshots / "5000.safetensors", 1.0)
    _snapshot(snapshots / "10000.safetensors", 3000.0)  # an output bias of 3000: Q far above the bound
    (tmp_path / "train_log.jsonl").write_text(json.dumps({"run": "main", "steps": 5000, "eval_return_mean": 42.0}) + "\n")
    states = script.start_states()
    assert states.shape == (50, 4)
    hidden = np.maximum(states @ first["q_net.q_net.0.weight"].T + 1.0, 0.0)
    expected = (hidden @ first["q_net.q_net.2.weight"].T + 1.0).max(axis=1).mean()
    assert abs(script.mean_max_q(first, states) - expected) < 1e-4
    assert [label for label, _ in script.snapshots(tmp_path)] == ["main 5000", "main 10000"]  # by steps, not by name
    monkeypatch.setattr("sys.argv", ["q_values.py", str(tmp_path)])
    script.main()
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Bellman bound: 100")
    assert lines[2].split() == ["main", "5000", f"{expected:.1f}", "42.0"]
    assert float(lines[3].split()[2]) > 2000 and len(lines[3].split()) == 3  # no evaluation logged at 10000
