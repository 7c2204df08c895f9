"""The model format loads without unpickling and refuses damaged, foreign or mismatched files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from oodmon.agents import load, load_agent
from oodmon.agents.networks import build_modules
from oodmon.agents.serialization import load_modules, save_modules
from oodmon.errors import ModelFormatError, UnknownParameterError

ARCH = {"algorithm": "dqn", "obs_shape": [4], "n_outputs": 2, "cnn": False, "net_arch": [16, 16],
        "stochastic": "dropout", "drop_p": 0.1, "last_only": True, "n_members": 1, "shared_torso": False}
META = {"task": "cartpole", "method": "dropout", "algorithm": "dqn", "architecture": ARCH, "seed": 3, "n_samples": 20}


@pytest.fixture
def saved(tmp_path):
    torch.manual_seed(0)
    modules = build_modules(ARCH)
    save_modules(tmp_path, modules, META)
    return tmp_path, modules


def test_round_trip_gives_the_same_tensors_and_metadata(saved):
    path, modules = saved
    loaded, metadata = load_modules(path, task="cartpole")
    for name, tensor in modules.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[name], tensor, rtol=0, atol=0)
    assert metadata["seed"] == 3 and metadata["format_version"] == 1 and metadata["dtype"] == "float32"
    # The tensor file is safetensors: an 8-byte header length, then a JSON header; no pickle.
    raw = (path / "model.safetensors").read_bytes()
    header = json.loads(raw[8 : 8 + int.from_bytes(raw[:8], "little")])
    assert "network.1.weight" in header


def test_a_save_stopped_while_writing_leaves_the_agent_that_was_there(saved, monkeypatch):
    """A full disk or a kill while the tensors are written (an export over an agent, a session's end):
    the agent before still loads, and no part file is left."""
    path, _ = saved
    before = {p.name: p.read_bytes() for p in path.iterdir()}

    def stopped(tensors, filename):  # part of the file on disk, then the failure
        Path(filename).write_bytes(b"\0" * 100)
        raise failure

    monkeypatch.setattr("oodmon.agents.serialization.save_file", stopped)
    for failure in (OSError(28, "No space left on device"), KeyboardInterrupt()):
        with pytest.raises(type(failure)):
            save_modules(path, build_modules(ARCH), META | {"seed": 4})
        assert {p.name: p.read_bytes() for p in path.iterdir()} == before
        assert load_modules(path)[1]["seed"] == 3


def test_half_precision_loads_back_as_float32(tmp_path):
    arch = ARCH | {"stochastic": None, "n_members": 3}
    modules = build_modules(arch)
    save_modules(tmp_path, modules, META | {"architecture": arch, "method": "ensemble"}, half=True)
    loaded, metadata = load_modules(tmp_path)
    assert metadata["dtype"] == "float16"
    for name, tensor in loaded.state_dict().items():
        assert tensor.dtype == torch.float32
        torch.testing.assert_close(tensor, modules.state_dict()[name], atol=1e-3, rtol=1e-3)


def test_corrupted_tensor_file(saved):
    path, _ = saved
    raw = (path / "model.safetensors").read_bytes()
    (path / "model.safetensors").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ModelFormatError, match="has sha256 .* but model.json records .*damaged or was changed"):
        load_modules(path)
    # Without a recorded hash (a model saved before oodmon recorded one), safetensors still refuses it.
    metadata = json.loads((path / "model.json").read_text())
    del metadata["safetensors_sha256"]
    (path / "model.json").write_text(json.dumps(metadata))
    with pytest.warns(UserWarning, match="records no safetensors_sha256"), \
            pytest.raises(ModelFormatError, match="cannot be read as safetensors .* damaged"):
        load_modules(path)


def test_flipped_bytes_that_still_parse_are_refused(saved):
    # Flipped bytes inside the tensors (the last 256; the header is at the start): safetensors
    # would load them, the hash does not.
    path, _ = saved
    raw = bytearray((path / "model.safetensors").read_bytes())
    start = len(raw) - 256
    raw[start:] = bytes(b ^ 0xFF for b in raw[start:])
    (path / "model.safetensors").write_bytes(bytes(raw))
    from safetensors.torch import load_file

    assert load_file(str(path / "model.safetensors"))  # it parses
    with pytest.raises(ModelFormatError, match="damaged or was changed"):
        load_modules(path)


def test_every_shipped_model_records_the_hash_of_its_tensors():
    import hashlib

    from oodmon.agents import zoo_dir, zoo_names

    for name in zoo_names():
        metadata = json.loads((zoo_dir() / name / "model.json").read_text())
        data = (zoo_dir() / name / "model.safetensors").read_bytes()
        assert metadata["safetensors_sha256"] == hashlib.sha256(data).hexdigest(), name


def test_damaged_metadata(saved):
    path, _ = saved
    (path / "model.json").write_text("{not json")
    with pytest.raises(ModelFormatError, match="is not valid JSON"):
        load_agent(path)
    (path / "model.json").write_text(json.dumps({"task": "cartpole"}))
    with pytest.raises(ModelFormatError, match="lacks format_version, method, algorithm, architecture, seed"):
        load_agent(path)


def test_model_of_another_task(saved):
    path, _ = saved
    with pytest.raises(ModelFormatError, match="is a cartpole model, not a pendulum model"):
        load_agent(path, task="pendulum")


def test_architecture_mismatch(saved):
    path, _ = saved
    metadata = json.loads((path / "model.json").read_text())
    metadata["architecture"]["net_arch"] = [32, 16]
    (path / "model.json").write_text(json.dumps(metadata))
    with pytest.raises(ModelFormatError,
                       match=r"does not match the architecture in model.json \(wrong shape: network.1.bias, network.1.weight"):
        load_agent(path)


def test_an_architecture_record_with_unknown_or_missing_fields_is_refused(saved):
    path, _ = saved
    metadata = json.loads((path / "model.json").read_text())
    metadata["architecture"] = {k: v for k, v in metadata["architecture"].items() if k != "n_outputs"} | {"layers": 3}
    (path / "model.json").write_text(json.dumps(metadata))
    with pytest.raises(ModelFormatError, match=r"model.json: not an architecture record: unknown layers; missing n_outputs"):
        load_agent(path)


@pytest.mark.parametrize("field, value, words", [
    ("stochastic", "dropnut", "stochastic layer 'dropnut', not dropout or dropconnect"),  # a flipped bit, found by fuzzing
    ("algorithm", "dqm", "algorithm 'dqm', not dqn or ddpg"),  # was built as a DDPG head, silently
    ("net_arch", ["64a"], "invalid literal for int"),
])
def test_an_architecture_record_with_a_damaged_value_is_refused(saved, field, value, words):
    path, _ = saved
    metadata = json.loads((path / "model.json").read_text())
    metadata["architecture"][field] = value
    (path / "model.json").write_text(json.dumps(metadata))
    with pytest.raises(ModelFormatError, match=rf"model.json: not an architecture record.*{words}"):
        load_agent(path)


def test_missing_directory_and_unknown_shipped_name(tmp_path):
    with pytest.raises(ModelFormatError, match="does not exist: a model directory holds model.json"):
        load_agent(tmp_path / "nothing")
    with pytest.raises(UnknownParameterError, match="no shipped agent 'cartpole-bayes'; the zoo has"):
        load("cartpole", "bayes")


def test_loaded_agent_acts(saved):
    path, _ = saved
    agent = load_agent(path, seed=0)
    action = agent.act(np.zeros(4, np.float32))
    assert isinstance(action, int) and action in (0, 1)
    copy = path.parent / "copy"
    shutil.copytree(path, copy)
    np.testing.assert_array_equal(load_agent(copy, seed=0).estimate(np.ones(4)).samples,
                                  load_agent(path, seed=0).estimate(np.ones(4)).samples)
