"""A plain policy without weights is bound to its code (oodmon.agents.policy_code): an edit of what
it computes with is another policy, an edit of anything else in its file is not."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap

import pytest
import torch

from oodmon.agents.plain import plain_policy_hash
from oodmon.agents.policy_code import code_sha256

CONTROLLER = """\
import functools

import numpy as np

K = 0.5
W = np.array([0.01, 0.1, 1.0, 0.5])
UNREAD = 3


def leans(x):
    return x > 0


def act(obs):
    return int(leans(obs @ W) and obs[2] + K * obs[3] > -1)


def act_with(obs, k=0.5):
    return int(obs[2] + k * obs[3] > 0)


def gains(k):
    def act(obs):
        return int(obs[2] + k * obs[3] > 0)
    return act


class Controller:
    def __init__(self, k):
        self.k = k

    def __call__(self, obs):
        return int(obs[2] + self.k * obs[3] > 0)


def even(n):
    return n == 0 or odd(n - 1)


def odd(n):
    return n != 0 and even(n - 1)


def nudged(obs, by):
    return act(obs + by)


by_a_little = functools.partial(nudged, by=0.1)
"""


def _module(tmp_path, name: str, source: str):
    path = tmp_path / f"{name}.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # (inspect finds a class's source through its module)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def modules(tmp_path):
    made = []

    def make(source: str):
        made.append(f"policy_code_{len(made)}")
        return _module(tmp_path, made[-1], source)

    yield make
    for name in made:
        sys.modules.pop(name, None)


def _policies(module):
    return {"act": module.act, "act_with": module.act_with, "closure": module.gains(0.5),
            "object": module.Controller(0.5), "partial": module.by_a_little, "recursive": module.even}


def test_an_edit_of_what_the_policy_computes_with_is_another_policy(modules):
    base = {name: code_sha256(p) for name, p in _policies(modules(CONTROLLER)).items()}
    assert all(len(h) == 64 for h in base.values()) and len(set(base.values())) == len(base)

    def changed(old: str, new: str) -> set[str]:
        assert old in CONTROLLER
        edited = {name: code_sha256(p) for name, p in _policies(modules(CONTROLLER.replace(old, new))).items()}
        return {name for name in base if edited[name] != base[name]}

    # anything else in the file: a comment, a name none of them reads, a function none calls
    assert changed("UNREAD = 3", "UNREAD = 4  # a comment") == set()
    assert changed("class Controller:", "def unused():\n    return 1\n\n\nclass Controller:") == set()
    # what each reads: a module constant, an array, a helper it calls, its body, its default
    assert changed("K = 0.5", "K = 0.6") == {"act", "partial"}  # (the partial nudges act)
    assert changed("1.0, 0.5]", "1.0, 0.6]") == {"act", "partial"}
    assert changed("return x > 0", "return x >= 0") == {"act", "partial"}
    assert changed("k=0.5", "k=0.6") == {"act_with"}
    assert changed("return n == 0 or", "return n <= 0 or") == {"recursive"}  # (even and odd read each other)
    assert changed("self.k * obs[3]", "self.k * obs[3] * 1.0") == {"object"}
    # what a closure, an object and a partial hold
    module = modules(CONTROLLER)
    assert code_sha256(module.gains(0.6)) != base["closure"] and code_sha256(module.gains(0.5)) == base["closure"]
    assert code_sha256(module.Controller(0.6)) != base["object"]
    # a memory of the episode changes as it acts: its class counts, not what it holds
    module.Controller.begin_episode = lambda self: None
    assert code_sha256(module.Controller(0.6)) == code_sha256(module.Controller(0.5))
    assert code_sha256(module.functools.partial(module.nudged, by=0.2)) != base["partial"]


def test_what_the_policy_reads_of_other_files_of_yours_counts_and_installed_packages_do_not(tmp_path, monkeypatch):
    """``config.K`` and a helper imported from another file of yours are the policy's; numpy's code,
    the standard library's and oodmon's are not (an installed package's version is its own)."""
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "policy_code_config.py").write_text("K = 0.5\nUNREAD = 1\n")
    (tmp_path / "policy_code_helpers.py").write_text("def leans(x):\n    return x > 0\n")
    (tmp_path / "policy_code_policy.py").write_text(
        "import numpy as np\n\nimport policy_code_config as config\nfrom policy_code_helpers import leans\n\n\n"
        "def act(obs):\n    return int(leans(np.clip(obs[2] + config.K * obs[3], -1, 1)))\n")
    import policy_code_config
    import policy_code_helpers
    import policy_code_policy

    try:
        before = code_sha256(policy_code_policy.act)
        policy_code_config.UNREAD = 2  # a name the policy does not read
        assert code_sha256(policy_code_policy.act) == before
        policy_code_config.K = 0.6
        assert code_sha256(policy_code_policy.act) != before
        policy_code_config.K = 0.5
        assert code_sha256(policy_code_policy.act) == before
        (tmp_path / "policy_code_helpers.py").write_text("def leans(x):\n    return x >= 0\n")
        importlib.reload(policy_code_helpers)
        importlib.reload(policy_code_policy)  # (which imported the helper before its edit)
        assert code_sha256(policy_code_policy.act) != before
    finally:
        for name in ("policy_code_config", "policy_code_helpers", "policy_code_policy"):
            sys.modules.pop(name, None)
    from oodmon.agents.policy_code import _yours

    assert not any(_yours(name) for name in ("numpy", "json", "oodmon.agents.plain", "stable_baselines3"))


def test_a_network_the_policy_reads_counts_by_its_weights(modules):
    module = modules("import torch\n\nNET = torch.nn.Linear(4, 2)\n\n\n"
                     "def act(obs):\n    return int(NET(torch.as_tensor(obs)).argmax())\n")
    before = code_sha256(module.act)
    with torch.no_grad():
        module.NET.weight[0, 0] += 1.0
    assert code_sha256(module.act) != before


def test_an_sb3_model_the_policy_asks_counts_by_its_weights(modules):
    module = modules("from stable_baselines3 import PPO\n\nMODEL = PPO('MlpPolicy', 'CartPole-v1', seed=0)\n\n\n"
                     "def act(obs):\n    return int(MODEL.predict(obs, deterministic=True)[0])\n")
    before = code_sha256(module.act)
    assert code_sha256(module.act) == before
    with torch.no_grad():
        next(module.MODEL.policy.parameters()).add_(0.01)  # trained on, or another model.zip loaded
    assert code_sha256(module.act) != before


def test_the_hash_is_the_same_in_another_process_imported_or_run_as_a_script(tmp_path, modules):
    module = modules(CONTROLLER + "\n\nclass Gain(float):\n    pass\n")
    here = [code_sha256(module.act), code_sha256(module.Controller(module.Gain(0.5)))]
    (tmp_path / "controller.py").write_text(CONTROLLER + "\n\nclass Gain(float):\n    pass\n" + textwrap.dedent("""
        if __name__ == "__main__":
            from oodmon.agents.policy_code import code_sha256
            print(code_sha256(act), code_sha256(Controller(Gain(0.5))))
        """))
    script = subprocess.run([sys.executable, "controller.py"], cwd=tmp_path, capture_output=True, text=True,
                            timeout=120)
    assert script.returncode == 0, script.stderr[-2000:]
    assert script.stdout.split() == here


def test_what_hashing_cannot_read_is_left_to_the_name(modules):
    """A value of the user's whose repr fails leaves the policy bound by its name, never an error;
    a long list the policy appends to counts by its length, read in a moment."""
    module = modules("class Odd:\n    def __repr__(self):\n        raise RuntimeError('no')\n\n\n"
                     "TABLE = {Odd(): 1, Odd(): 2}\nSEEN = []\n\n\n"
                     "def act(obs):\n    return TABLE.get(obs, 0)\n\n\n"
                     "def remembers(obs):\n    SEEN.append(obs)\n    return 0\n")
    assert code_sha256(module.act) is None and plain_policy_hash(module.act) == "name:act"
    module.SEEN.extend([0.5] * 2_000_000)
    long = code_sha256(module.remembers)
    module.SEEN[0] = 0.7
    assert code_sha256(module.remembers) == long  # (its items unread)
    module.SEEN.append(0.5)
    assert code_sha256(module.remembers) != long


def test_a_policy_python_keeps_no_source_of_is_bound_by_its_name_as_before():
    namespace: dict = {}
    exec(compile("def act(obs):\n    return 0\n", "<python -c>", "exec"), namespace)
    assert code_sha256(namespace["act"]) is None and plain_policy_hash(namespace["act"]) == "name:act"
    assert code_sha256(len) is None and code_sha256(dict) is None  # a builtin; a class is no policy
