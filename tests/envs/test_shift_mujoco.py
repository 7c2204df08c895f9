"""Shifts of MuJoCo's own envs (gymnasium[mujoco], a dev dependency): elements of the model's
arrays set in place from the onset, put back at each reset; and a policy watched in one, end to end."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest

from oodmon.envs import parse_env_shift
from oodmon.errors import UnknownParameterError

@pytest.fixture(autouse=True)
def _in_a_folder_of_its_own(tmp_path, monkeypatch):
    """MuJoCo writes its warnings to MUJOCO_LOG.TXT in the working directory: not the repository's."""
    monkeypatch.chdir(tmp_path)


def _rollout(env: gymnasium.Env, steps: int):
    """Observations and ``info["shifted"]`` of ``steps`` steps of seeded random actions from ``reset(seed=0)``."""
    obs, info = env.reset(seed=0)
    observations, shifted = [obs], [info.get("shifted")]
    for action in np.random.default_rng(0).uniform(-1, 1, (steps, *env.action_space.shape)):
        obs, _, _, _, info = env.step(action.astype(np.float32))
        observations.append(obs)
        shifted.append(info.get("shifted"))
    return np.array(observations), shifted


@pytest.mark.parametrize("spec, array, index, own", [
    ("HalfCheetah-v5:model.body_mass[1]=12.0", "body_mass", 1, 6.2502),  # the torso twice as heavy
    ("Hopper-v5:model.opt.gravity[2]=-5.0", "opt.gravity", 2, -9.81),
    ("InvertedPendulum-v5:model.body_mass[2]=20.0", "body_mass", 2, 5.0186),  # the pole four times as heavy
], ids=["cheetah-mass", "hopper-gravity", "pendulum-mass"])
def test_a_shift_of_mujocos_model_arrays_changes_the_physics_from_the_onset_and_is_undone_at_each_reset(
        spec, array, index, own):
    shift = parse_env_shift(spec)
    plain, env = gymnasium.make(shift.env_id), shift.make(onset_step=4)
    model = env.unwrapped.model
    held = model.opt.gravity if array == "opt.gravity" else model.body_mass  # MuJoCo hands out views of its arrays
    for _ in range(2):  # every episode: the env's own values first, the shift from step 4 on
        expected, _ = _rollout(plain, steps=10)
        observed, flags = _rollout(env, steps=10)
        assert flags == [False] * 5 + [True] * 6
        np.testing.assert_array_equal(observed[:5], expected[:5])
        assert np.abs(observed[6:] - expected[6:]).max(axis=1).min() > 1e-3  # the shifted world moves otherwise
        assert held[index] == shift.params[0][1]
    env.reset(seed=1)
    assert held[index] == pytest.approx(own, abs=1e-4)


@pytest.mark.parametrize("name, words", [
    ("model.body_mass", r"model.body_mass is an array of shape \[8\]: shift an element"),
    ("model.body_mass[8]", r"outside model.body_mass, an array of shape \[8\]"),
    ("model.body_mas[1]", "model.body_mas is not a numeric array to index"),
    ("model.opt.gravty[2]", "model.opt.gravty is not a numeric array to index"),
], ids=["whole-array", "outside", "misspelt-array", "misspelt-option"])
def test_a_name_that_is_no_element_of_mujocos_model_is_refused_saying_what_is_there(name, words):
    with pytest.raises(UnknownParameterError, match=words):
        parse_env_shift(f"HalfCheetah-v5:{name}=1.0").make(onset_step=4)


def test_a_policy_watched_in_a_mujoco_env_alarms_on_a_heavier_pole_and_replay_tells_the_fall(tmp_path, capsys):
    """`oodmon calibrate`, `run --variant 'InvertedPendulum-v5:model.opt.gravity[2]=-60.0'` and `replay
    --monitor --failure terminated` on a PPO that has not learnt to balance (its episodes end in
    a few steps): MuJoCo's float64 observations through the detectors, the logs and replay."""
    from stable_baselines3 import PPO

    from oodmon.cli import main

    PPO("MlpPolicy", gymnasium.make("InvertedPendulum-v5"), seed=0, policy_kwargs={"net_arch": [8]}).save(
        tmp_path / "ip.zip")
    common = ["--sb3", str(tmp_path / "ip.zip"), "--env", "InvertedPendulum-v5"]
    assert main(["calibrate", *common, "--fit-episodes", "40", "--out", str(tmp_path / "t.json")]) == 0
    run = [*common, "--threshold", str(tmp_path / "t.json"), "--episodes", "10"]
    assert main(["run", *run, "--mcap", str(tmp_path / "id.mcap")]) == 0
    assert main(["run", *run, "--variant", "InvertedPendulum-v5:model.opt.gravity[2]=-60.0", "--onset", "2",
                 "--mcap", str(tmp_path / "heavy.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", "--monitor", str(tmp_path / "id.mcap"), str(tmp_path / "heavy.mcap"),
                 "--failure", "terminated", "--json"]) == 0
    rows = {row["variant"]: row for row in json.loads(capsys.readouterr().out)}
    heavy = rows["InvertedPendulum-v5:model.opt.gravity[2]=-60.0"]
    assert heavy["episodes"] == 10 and heavy["failed"] == 10  # an untrained policy drops it, six times as fast
    # 10 of 10 alarmed before the fall here (delay median 3.5): slack for another machine's rounding
    assert heavy["before_failure"] >= 8 and heavy["early"] == 0, heavy
