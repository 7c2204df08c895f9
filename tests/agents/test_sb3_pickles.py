"""A user's SB3 model file is read without running code from it (oodmon.agents.sb3_pickles): what
SB3 would unpickle reaches only a model's kinds of class; a crafted entry runs nothing; a class of
the user's own module loads once the user names the module; --unsafe-load-pickles is SB3's load."""

from __future__ import annotations

import base64
import json
import os
import pickle
import sys
import zipfile

import gymnasium
import numpy as np
import pytest
from stable_baselines3 import DQN, PPO

from oodmon.agents.sb3 import load_sb3
from oodmon.cli import main
from oodmon.errors import ConfigError


class _MakesFolder:
    """Pickled, a call of os.makedirs(folder): what a crafted file could run where SB3 unpickles it."""

    def __init__(self, folder) -> None:
        self.folder = str(folder)

    def __reduce__(self):
        return os.makedirs, (self.folder,)


def _with_entry(source, target, key, value) -> None:
    """A copy of the model file ``source`` at ``target`` whose ``data`` entry ``key`` is the pickle of ``value``."""
    with zipfile.ZipFile(source) as archive:
        parts = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(parts["data"])
    data[key] = {":type:": "<class 'object'>", ":serialized:": base64.b64encode(pickle.dumps(value)).decode()}
    parts["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(target, "w") as archive:
        for name, content in parts.items():
            archive.writestr(name, content)


def test_a_crafted_entry_runs_nothing_unless_the_user_says_load_it_as_sb3_does(tmp_path):
    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16]}).save(tmp_path / "dqn.zip")
    marker = tmp_path / "ran"
    # in what builds the policy: the model is refused, naming what the entry names
    _with_entry(tmp_path / "dqn.zip", tmp_path / "kwargs.zip", "policy_kwargs", {"net_arch": [16], "x": _MakesFolder(marker)})
    with pytest.raises(ConfigError, match=r"its policy_kwargs names os\.makedirs, which a model's data does not "
                                          r"hold; oodmon does not unpickle it .*--unsafe-load-pickles"):
        load_sb3([tmp_path / "kwargs.zip"], "CartPole-v1")
    assert not marker.exists()
    # in training state a deployed policy does not read: left at its default, the model loads
    _with_entry(tmp_path / "dqn.zip", tmp_path / "state.zip", "_last_obs", _MakesFolder(marker))
    agent = load_sb3([tmp_path / "state.zip"], "CartPole-v1")
    assert not marker.exists()
    plain = DQN.load(tmp_path / "dqn.zip", device="cpu")  # the file before it was crafted
    observations = np.random.default_rng(0).normal(size=(50, 4)).astype(np.float32)
    assert [agent.act(o) for o in observations] == [int(plain.predict(o, deterministic=True)[0]) for o in observations]
    # the flag is SB3's own load: the file's code runs (which is what it says)
    load_sb3([tmp_path / "state.zip"], "CartPole-v1", unsafe_load_pickles=True)
    assert marker.is_dir()


def test_schedules_written_as_functions_stand_at_the_algorithms_defaults_and_the_policy_acts_the_same(tmp_path):
    # A learning rate and clip range of one's own (a lambda: cloudpickle writes its code into the
    # file) are refused; PPO's defaults stand for them; acting never reads them.
    model = PPO("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=0, n_steps=64, batch_size=32,
                learning_rate=lambda remaining: 3e-4 * remaining, clip_range=lambda remaining: 0.1 * remaining)
    model.learn(64)
    model.save(tmp_path / "ppo.zip")
    from oodmon.agents.sb3 import _data
    from oodmon.agents.sb3_pickles import data_objects

    objects = data_objects(_data(tmp_path / "ppo.zip"), PPO)
    assert (objects["learning_rate"], objects["clip_range"], objects["lr_schedule"]) == (3e-4, 0.2, None)  # not the lambdas
    agent = load_sb3([tmp_path / "ppo.zip"], "Pendulum-v1")
    plain = PPO.load(tmp_path / "ppo.zip", device="cpu")
    observations = np.random.default_rng(1).uniform(-1, 1, size=(50, 3)).astype(np.float32)
    np.testing.assert_array_equal(np.stack([agent.act(o) for o in observations]),
                                  np.stack([plain.predict(o, deterministic=True)[0] for o in observations]))


def test_a_policy_class_of_ones_own_loads_once_its_module_is_named(tmp_path, monkeypatch, capsys):
    (tmp_path / "own_policy_module.py").write_text(
        "from stable_baselines3.dqn.policies import DQNPolicy\n\n\n"
        "class OwnDQNPolicy(DQNPolicy):\n"
        "    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    from own_policy_module import OwnDQNPolicy

    DQN(OwnDQNPolicy, gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16]}).save(tmp_path / "own.zip")
    monkeypatch.delitem(sys.modules, "own_policy_module")  # as in another process: not imported
    model = ["--sb3", str(tmp_path / "own.zip"), "--env", "CartPole-v1"]
    calibrate = ["calibrate", *model, "--episodes", "4", "--far", "0.3", "--confidence", "none", "--out",
                 str(tmp_path / "t.json")]
    validate = ["validate", str(tmp_path / "t.json"), *model, "--episodes", "2"]
    assert main(calibrate) == 2
    error = capsys.readouterr().err
    assert "its policy_class names own_policy_module.OwnDQNPolicy, of a module the program has not imported" in error
    assert "--import own_policy_module" in error and "own_policy_module" not in sys.modules  # not imported for the file
    assert main([*calibrate, "--import", "own_policy_module"]) == 0
    assert main([*validate, "--import", "no_such_module_here"]) == 2
    assert "--import no_such_module_here: No module named 'no_such_module_here'" in capsys.readouterr().err
    for name in ("..", ".own_policy_module", " "):
        assert main([*validate, "--import", name]) == 2
        assert "give a module's full name, e.g. --import my_policy" in capsys.readouterr().err
    assert main(["calibrate", "--task", "cartpole", "--method", "ensemble", "--import", "own_policy_module",
                 "--out", str(tmp_path / "u.json")]) == 2
    assert "--import, --unsafe-load-pickles" in capsys.readouterr().err


@pytest.mark.parametrize("entry, refused", [
    (b"ctorch.nn.modules.linear\nLinear\n(I10\nI10\ntR.", "a call of Linear"),  # a class it finds, but called
    (b"cnumpy.random._pickle\n__bit_generator_ctor\n(ctorch.nn.modules.linear\nLinear\ntR.",  # called through numpy
     "__bit_generator_ctor given type"),
    (b"(ctorch.nn.modules.linear\nLinear\nI10\nI10\no.", "a call of Linear"),  # the same by OBJ (protocol 1)
    (b"cbuiltins\ngetattr\n(cos\nsystem\nS'x'\ntR.", "builtins.getattr, which a model's data does not hold"),
    # state given to a class it finds: setattr(FloatSchedule, "oodmon_test", 1) for the whole process
    (b"cstable_baselines3.common.utils\nFloatSchedule\n(}(S'oodmon_test'\nI1\ndtb.", "state for FloatSchedule itself"),
])
def test_the_unpickler_calls_nothing_but_what_a_models_data_calls(entry, refused):
    from oodmon.agents.sb3_pickles import data_objects

    serialized = {":serialized:": base64.b64encode(entry).decode()}
    with pytest.raises(ConfigError, match=refused):
        data_objects({"policy_kwargs": serialized}, DQN)
    assert data_objects({"_last_obs": serialized}, DQN) == {"_last_obs": None}  # training state: its default
    assert data_objects({"learning_rate": serialized}, DQN) == {"learning_rate": 1e-4}  # DQN's default
    from stable_baselines3.common.utils import FloatSchedule

    assert not hasattr(FloatSchedule, "oodmon_test")


def test_a_model_of_oodmons_own_policy_class_loads_without_an_import(tmp_path):
    # oodmon's installed classes are found as SB3's are (not as the program's own: oodmon's
    # namespace is not searched that way): a DQN built of its MC Dropout policy
    from oodmon.agents.policies import UncertainDQNPolicy

    DQN(UncertainDQNPolicy, gymnasium.make("CartPole-v1"), seed=0,
        policy_kwargs={"stochastic": "dropout", "drop_p": 0.1, "net_arch": [16]}).save(tmp_path / "mc.zip")
    agent = load_sb3([tmp_path / "mc.zip"], "CartPole-v1")
    assert type(agent.estimator).__name__ == "MCEstimator" and agent.estimator.n_samples == 20


@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_arrays_of_older_files_decode_too(protocol):
    # numpy 1 named its constructors numpy.core (numpy 2 warns of the name); a protocol-2 pickle
    # writes them as text lines (renamed here as numpy 1 wrote them) and bytes through _codecs.encode
    from oodmon.agents.sb3_pickles import data_objects

    raw = pickle.dumps(np.arange(3.0), protocol=protocol)
    if protocol == 2:
        raw = raw.replace(b"cnumpy._core.multiarray\n", b"cnumpy.core.multiarray\n")
        assert b"cnumpy.core.multiarray\n" in raw and b"_codecs" in raw
    decoded = data_objects({"_last_obs": {":serialized:": base64.b64encode(raw).decode()}}, DQN)["_last_obs"]
    np.testing.assert_array_equal(decoded, [0.0, 1.0, 2.0])
