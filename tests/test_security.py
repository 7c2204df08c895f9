"""Nothing oodmon reads by default runs code from a file: no pickle, no unrestricted torch.load,
no np.load with pickles, anywhere in the package; SB3's own (pickling) loaders only behind the
explicit flag."""

from __future__ import annotations

import re
from pathlib import Path

PACKAGE = Path(__file__).parent.parent / "oodmon"


def _lines():
    for path in sorted(PACKAGE.rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            yield path.relative_to(PACKAGE.parent), number, line


def test_no_pickle_and_no_unrestricted_loader_in_the_package():
    found = []
    for path, number, line in _lines():
        code = line.split("#")[0]
        if re.search(r"\b(import pickle|from pickle|cPickle|dill|joblib\.load|pd\.read_pickle)\b", code):
            found.append(f"{path}:{number}: {line.strip()}")
        if "torch.load(" in code and "weights_only=True" not in code:
            found.append(f"{path}:{number}: {line.strip()}")
        if "np.load(" in code and "allow_pickle=False" not in code:
            found.append(f"{path}:{number}: {line.strip()}")
    assert not found, "\n".join(found)


def test_sb3_pickle_loaders_sit_only_behind_the_explicit_flag():
    # SB3's .load() and load_replay_buffer() unpickle: one function holds them, and it is called
    # only where the user passed load_pickles=True (oodmon train --unsafe-load-pickles).
    calls = [(str(path), line.strip()) for path, _, line in _lines()
             if re.search(r"\)\.load\(|load_replay_buffer\(|\bDQN\.load\(|\bDDPG\.load\(", line.split("#")[0])]
    assert calls and {path for path, _ in calls} == {"oodmon/agents/training.py"}, calls
    source = (PACKAGE / "agents" / "training.py").read_text()
    body = source[source.index("def _load_pickled_checkpoint"):source.index("def architecture")]
    assert all(line in body for _, line in calls)
    uses = [m.start() for m in re.finditer(r"_load_pickled_checkpoint\(", source)]
    assert len(uses) == 2  # its definition and one call
    call = source[uses[1] - 200:uses[1]]
    assert "if load_pickles:" in call
