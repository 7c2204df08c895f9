"""The sweep scripts' training options reach the recipe they train, and the rows record them apart."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from tests.helpers import load_script


@pytest.fixture
def scripts(monkeypatch, tmp_path):
    import oodmon

    monkeypatch.syspath_prepend(str(Path(oodmon.__file__).parent.parent / "scripts"))  # they import sweep_full_depth
    monkeypatch.chdir(tmp_path)  # nothing they write lands in the repository
    return load_script("sweep_full_depth")[1], load_script("sweep_trials")[1]


def _run(module, monkeypatch, *argv):
    """``module.main()`` with ``argv``, training and measuring replaced by recorders: the recipes it
    would train and the rows it would append."""
    trained, rows = [], []
    monkeypatch.setattr(sys, "argv", ["sweep", *argv])
    monkeypatch.setattr(module, "train", lambda task, method, out, seed, recipe, command: trained.append((out, recipe)))
    monkeypatch.setattr(module, "load_agent", lambda *a, **k: type("Agent", (), {"metadata": {"id_return_mean": 500.0}})())
    monkeypatch.setattr(module, "read_rows", lambda path: [])
    monkeypatch.setattr(module, "append_row", lambda path, row: rows.append(row))
    monkeypatch.setattr(module, "spread_aurocs", lambda *a: ({"chosen_std": {"cartpole:length=2.0": 0.5}}, {}, 500.0))
    module.main()
    return trained, rows


def test_sweep_trials_final_eps_trains_and_records_the_exploration_rate(scripts, monkeypatch):
    _, trials = scripts
    trained, rows = _run(trials, monkeypatch, "--task", "cartpole", "--method", "dropconnect", "--p", "0.02",
                         "--steps", "200000", "--select-top", "8", "--final-eps", "0.0", "--seeds", "3")
    (out, recipe), = trained
    assert out.endswith("-top8-eps0-seed3")
    assert recipe.hyperparams["exploration_final_eps"] == 0.0
    assert recipe.hyperparams["learning_rate"] == 1e-3  # the shipped recipe's other settings stay
    assert (recipe.total_steps, recipe.select_top, recipe.drop_p, recipe.last_only) == (200_000, 8, 0.02, False)
    row, = rows
    assert row["exploration_final_eps"] == 0.0 and row["seed"] == 3
    assert trials._label(row).endswith("best of 8 snapshots, final epsilon 0")
    # Without the option the recipe's rate stays and the row has no field: earlier rows keep their label.
    trained, rows = _run(trials, monkeypatch, "--task", "cartpole", "--method", "dropconnect", "--p", "0.02",
                         "--steps", "200000", "--select-top", "8", "--seeds", "3")
    assert trained[0][1].hyperparams["exploration_final_eps"] == 0.04 and "exploration_final_eps" not in rows[0]
    assert trials._shown(rows[0]).endswith("(shipped)") and not trials._shown(row).endswith("(shipped)")


def test_sweep_full_depth_buffer_and_final_eps_train_and_key_the_row(scripts, monkeypatch):
    full_depth, _ = scripts
    monkeypatch.setattr(full_depth, "_measure", lambda agent, task, method, settings, start=None: captured.append(settings))
    captured: list[dict] = []
    trained, _ = _run(full_depth, monkeypatch, "--tasks", "cartpole", "--methods", "dropconnect", "--grid", "0.02",
                      "--steps", "100000", "--buffer-size", "20000", "--final-eps", "0.1")
    (out, recipe), = trained
    assert out == "runs/sweep/cartpole-dropconnect-full-p0.02-steps100000-buffer20000-eps0.1"
    assert recipe.hyperparams["buffer_size"] == 20_000 and recipe.hyperparams["exploration_final_eps"] == 0.1
    settings, = captured
    row = {"task": "cartpole", "method": "dropconnect", **settings}
    plain = {key: value for key, value in row.items() if key not in ("buffer_size", "exploration_final_eps")}
    assert full_depth._key(row) != full_depth._key(plain) != full_depth._key({**plain, "buffer_size": 20_000})


@pytest.mark.parametrize("argv, message", [
    (("--task", "pendulum", "--final-eps", "0.0"), "pendulum trains DDPG"),
    (("--task", "cartpole", "--final-eps", "1.5"), "must be in \\[0, 1\\]"),
])
def test_sweep_trials_refuses_an_exploration_rate_it_cannot_train(scripts, monkeypatch, capsys, argv, message):
    _, trials = scripts
    with pytest.raises(SystemExit):
        _run(trials, monkeypatch, *argv, "--method", "dropconnect", "--p", "0.02", "--seeds", "0")
    assert re.search(message, capsys.readouterr().err)


def test_sweep_full_depth_refuses_a_buffer_below_one_and_ddpg_tasks(scripts, monkeypatch, capsys):
    full_depth, _ = scripts
    for argv, message in ((("--tasks", "cartpole", "--buffer-size", "0"), "at least 1"),
                          (("--tasks", "cartpole,pendulum", "--buffer-size", "20000"), "pendulum trains DDPG")):
        with pytest.raises(SystemExit):
            _run(full_depth, monkeypatch, *argv, "--methods", "dropconnect", "--grid", "0.02")
        assert message in capsys.readouterr().err
