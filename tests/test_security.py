"""Nothing oodmon reads by default runs code from a file: no pickle, no unrestricted torch.load,
no np.load with pickles, anywhere in the package; SB3's own (pickling) loaders only behind the
explicit flags; a user's SB3 model files read through a restricted unpickler."""

from __future__ import annotations

import re
from pathlib import Path

PACKAGE = Path(__file__).parent.parent / "oodmon"


def _lines():
    for path in sorted(PACKAGE.rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            yield path.relative_to(PACKAGE.parent), number, line


#: The modules that import pickle, each for a restricted unpickler (tests below): SB3's VecNormalize
#: statistics (numpy's array constructors only) and the data of a user's SB3 model files.
RESTRICTED_UNPICKLERS = {"oodmon/agents/vec_normalize.py", "oodmon/agents/sb3_pickles.py"}


def test_no_pickle_and_no_unrestricted_loader_in_the_package():
    found = []
    for path, number, line in _lines():
        code = line.split("#")[0]
        if str(path) in RESTRICTED_UNPICKLERS and code.strip() == "import pickle":
            continue
        if re.search(r"\b(import pickle|from pickle|cPickle|dill|joblib\.load|pd\.read_pickle)\b", code):
            found.append(f"{path}:{number}: {line.strip()}")
        if "torch.load(" in code and "weights_only=True" not in code:
            found.append(f"{path}:{number}: {line.strip()}")
        if "np.load(" in code and "allow_pickle=False" not in code:
            found.append(f"{path}:{number}: {line.strip()}")
    assert not found, "\n".join(found)


def test_sb3_pickle_loaders_sit_only_behind_the_explicit_flag():
    # SB3's .load() and load_replay_buffer() unpickle: one function holds them, and it is called
    # only where the user passed load_pickles=True (oodmon train --unsafe-load-pickles); and a
    # user's model file (sb3._load_one, the next test).
    calls = [(str(path), line.strip()) for path, _, line in _lines() if str(path) not in RESTRICTED_UNPICKLERS
             and re.search(r"\)\.load\(|\balgorithm\.load\(|load_replay_buffer\(|\bDQN\.load\(|\bDDPG\.load\(",
                          line.split("#")[0])]
    assert calls and {path for path, _ in calls} == {"oodmon/agents/checkpoints.py", "oodmon/agents/sb3.py"}, calls
    calls = [(path, line) for path, line in calls if path == "oodmon/agents/checkpoints.py"]
    source = (PACKAGE / "agents" / "checkpoints.py").read_text()
    body = source[source.index("def _load_pickled_checkpoint"):source.index("class _RunCallback")]
    assert all(line in body for _, line in calls)
    uses = [m.start() for m in re.finditer(r"_load_pickled_checkpoint\(", source)]
    assert len(uses) == 2  # its definition and one call
    call = source[uses[1] - 200:uses[1]]
    assert "if load_pickles:" in call


def test_users_sb3_files_are_read_only_when_the_user_names_them_and_unpickled_only_on_the_flag():
    # A user's own SB3 .zip goes through SB3's loader only in sb3._load_one, reached only from
    # load_sb3, which only an explicit --sb3 (or a call naming the files) reaches; the file's kind is
    # read from its JSON first; SB3 gets every entry it would unpickle, read by the restricted
    # unpickler (custom_objects), unless the user passed unsafe_load_pickles (--unsafe-load-pickles).
    source = (PACKAGE / "agents" / "sb3.py").read_text()
    loader = source[source.index("def _load_one"):source.index("def _optimizers_built_without_dynamo")]
    assert 'algorithm.load(path, device="cpu", custom_objects=objects)' in loader and "_algorithms(data, path)" in loader
    assert "objects = None if unsafe_load_pickles else data_objects(data, algorithm, path)" in loader
    calls = [m.start() for m in re.finditer(r"_load_one\(", source)][1:]
    assert calls == [source.index("_load_one(path, unsafe_load_pickles) for path")]
    assert calls[0] > source.index("def load_sb3")
    callers = [str(path) for path, _, line in _lines()
               if "load_sb3(" in line.split("#")[0] and str(path) != "oodmon/agents/sb3.py"]
    assert set(callers) == {"oodmon/cli/loading.py", "oodmon/cli/envs.py", "oodmon/monitor/watch.py",
                            "oodmon/bench/cache.py"}, callers
    cli = (PACKAGE / "cli" / "loading.py").read_text()
    assert cli[cli.index("load_sb3(") - 700:cli.index("load_sb3(")].count('getattr(args, "sb3", None)') == 1
    # envs show: only for the model its --sb3 names
    envs = (PACKAGE / "cli" / "envs.py").read_text()
    assert envs.count("load_sb3(") == 1 and "if args.sb3:" in envs[envs.index("load_sb3(") - 400:envs.index("load_sb3(")]
    # bench: only for a config naming the files (BenchConfig.sb3, from `bench --sb3`)
    bench = (PACKAGE / "bench" / "cache.py").read_text()
    assert bench.count("load_sb3(") == 1
    assert "if isinstance(source, Sb3Models):" in bench[bench.index("load_sb3(") - 300:bench.index("load_sb3(")]
    assert bench.count("Sb3Models(") == 1 and "if config.sb3:" in bench[bench.index("Sb3Models(") - 200:bench.index("Sb3Models(")]


def test_the_vecnormalize_unpickler_reaches_numpys_array_constructors_only():
    import pickle

    from oodmon.agents import vec_normalize

    source = (PACKAGE / "agents" / "vec_normalize.py").read_text()
    assert source.count("pickle.Unpickler") == 1 and source.count("super().find_class(") == 1
    assert source.count(".load()") == 1 and "unpickler = _StatisticsUnpickler(io.BytesIO(data))" in source
    assert not re.search(r"pickle\.(loads?|Unpickler\(|load\()", source.replace("pickle.Unpickler):", ""))
    assert vec_normalize._CALLED == {(m, n) for m in ("numpy._core.multiarray", "numpy.core.multiarray")
                                     for n in ("_reconstruct", "scalar")} | {("numpy", "ndarray"), ("numpy", "dtype"),
                                                                             ("collections", "OrderedDict")}
    unpickler = vec_normalize._StatisticsUnpickler(__import__("io").BytesIO(b""))
    assert unpickler.find_class("collections", "OrderedDict") is __import__("collections").OrderedDict  # a container
    for module, name in [("os", "system"), ("builtins", "eval"), ("numpy", "load"), ("numpy.lib.npyio", "load"),
                         ("subprocess", "Popen"), ("torch", "load"), ("collections", "namedtuple"),
                         ("collections", "defaultdict")]:
        with __import__("pytest").raises(pickle.UnpicklingError):
            unpickler.find_class(module, name)
    for module, name in [("stable_baselines3.common.vec_env.vec_normalize", "VecNormalize"),
                         ("gymnasium.spaces.box", "Box"), ("numpy.random._pickle", "__generator_ctor")]:
        assert unpickler.find_class(module, name) is vec_normalize._Record  # built inert, never the real thing


def test_the_sb3_data_unpickler_reaches_a_models_kinds_of_class_only():
    import pickle

    import pytest
    import torch
    from stable_baselines3.common.type_aliases import TrainFreq
    from stable_baselines3.common.utils import FloatSchedule

    from oodmon.agents import sb3_pickles

    source = (PACKAGE / "agents" / "sb3_pickles.py").read_text()
    assert "class _DataUnpickler(pickle._Unpickler):" in source and source.count(".load()") == 1
    assert "_DataUnpickler(io.BytesIO(raw)).load()" in source
    assert not re.search(r"pickle\.(loads?\(|_?Unpickler\(|load\()", source.replace("pickle._Unpickler):", ""))
    # the calls an entry makes go through the checked REDUCE (and INST/OBJ) of that unpickler
    assert sb3_pickles._DataUnpickler.dispatch[pickle.REDUCE[0]] is sb3_pickles._DataUnpickler.load_reduce
    unpickler = sb3_pickles._DataUnpickler(__import__("io").BytesIO(b""))
    for module, name in [("os", "system"), ("posix", "system"), ("builtins", "eval"), ("builtins", "getattr"),
                         ("numpy", "load"), ("subprocess", "Popen"), ("torch", "load"), ("torch.storage", "_load_from_bytes"),
                         ("cloudpickle.cloudpickle", "_make_function"), ("types", "CodeType"), ("functools", "partial"),
                         ("collections", "namedtuple"), ("stable_baselines3.common.logger", "HumanOutputFormat"),
                         ("stable_baselines3.common.utils", "configure_logger"), ("shutil", "rmtree"),
                         ("torch.fx.graph_module", "GraphModule"), ("torch.jit._script", "RecursiveScriptModule"),
                         ("a_module_nobody_imported", "Policy")]:
        with pytest.raises(pickle.UnpicklingError):
            unpickler.find_class(module, name)
    assert "a_module_nobody_imported" not in __import__("sys").modules  # refused without importing it
    unpickler.proto = 5  # protocol 4 on: a dotted name walks attributes, which must not lead out of the namespaces
    own = __import__("types").ModuleType("own_module_that_imports_torch")
    own.torch = torch
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(__import__("sys").modules, own.__name__, own)
        for module, name in [("stable_baselines3.common.policies", "th.fx.GraphModule"),
                             ("stable_baselines3.common.policies", "th.jit.ScriptModule"),
                             (own.__name__, "torch.fx.GraphModule")]:
            with pytest.raises(pickle.UnpicklingError):
                unpickler.find_class(module, name)
    for module, name, found in [("torch.nn.modules.activation", "ReLU", torch.nn.ReLU), ("torch", "float32", torch.float32),
                                ("stable_baselines3.common.type_aliases", "TrainFreq", TrainFreq),
                                ("stable_baselines3.common.utils", "FloatSchedule", FloatSchedule),
                                ("collections", "deque", __import__("collections").deque)]:
        assert unpickler.find_class(module, name) is found


def test_a_shell_command_runs_only_where_a_caller_names_it_never_from_a_file():
    # `run --on-alarm CMD` (AlarmCommand) is the package's one shell: no threshold, baseline or log
    # oodmon reads can carry a command into it (2026-12-05)
    shells = [f"{path}:{number}" for path, number, line in _lines()
              if re.search(r"shell\s*=\s*True|os\.system\(|os\.popen\(", line.split("#")[0])]
    assert len(shells) == 1 and shells[0].startswith("oodmon/monitor/alarm_command.py:"), shells
    made = [(str(path), line.strip()) for path, _, line in _lines()
            if re.search(r"\bAlarmCommand\(", line.split("#")[0]) and not line.strip().startswith((">>>", "class "))]
    assert [path for path, _ in made] == ["oodmon/cli/run.py"], made
    assert "args.on_alarm" in (PACKAGE / "cli" / "run.py").read_text().split("AlarmCommand(\n", 1)[1][:60]
