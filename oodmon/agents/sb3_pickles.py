"""An SB3 model file's ``data`` read without running code from it.

SB3's ``load`` unpickles (with cloudpickle) every entry of the zip's ``data`` JSON that JSON
cannot hold: the spaces, the policy class and its keyword arguments, the schedules, the last
observation, ... A crafted file can hold any code there, which ``load`` runs. (The weights,
``policy.pth``, SB3 reads with ``torch.load(weights_only=True)``: tensors only.) :func:`data_objects`
decodes each such entry with an unpickler that reaches only what a model's data holds, and oodmon
gives them to SB3's ``load`` as its ``custom_objects``: SB3 then unpickles nothing of the file.

What an entry may name (Python's "Restricting Globals", docs.python.org/3/library/pickle.html):

- numpy's array, dtype, scalar and random-generator constructors, ``collections.deque`` and
  ``OrderedDict``, ``_codecs.encode`` (:data:`_CALLS`);
- classes of stable-baselines3, sb3-contrib, ``torch.nn.modules``, ``torch.optim``, numpy,
  gymnasium's spaces and ``oodmon.agents`` of the kinds a model's data holds (:func:`_kinds`): torch modules (policy
  classes, feature extractors, activation functions), optimizers, spaces, SB3's buffers,
  schedules and action noises, SB3's named tuples (``TrainFreq``) and enums; and torch's dtypes;
- a torch module class of a module the program has already imported (a policy class of your own,
  imported before the model is loaded, or named by ``imports=`` / ``--import``: its code has run
  already, on your word). A module not yet imported is not imported for a file.

Anything else is refused. And what an entry may call is narrower still (Python's own unpickler,
whose ``REDUCE``, ``INST`` and ``OBJ`` are checked): the functions of :data:`_CALLS` (numpy's
random-generator constructors given only a bit generator's name, class or instance), SB3's named
tuples and enums, numpy's dtypes. Every other class it finds is a value (a policy class, an
activation function), or is built empty (``NEWOBJ``: its ``__new__``) and given the state the
file holds, which is how spaces and schedules come back: no ``__init__`` of a file's choosing runs.

A refused entry that builds the policy (:data:`NEEDED`: the policy class, its keyword arguments,
the spaces) refuses the model, with a line saying what it names and how to load it anyway
(``--import`` its module, or ``unsafe_load_pickles=True``, ``--unsafe-load-pickles``: SB3's own
``load``, which runs what the file holds). Any other refused entry is training state a deployed
policy never reads (a schedule written as a function, say): it stands at the algorithm's default
for it (its ``__init__``'s), or ``None``.

Example (an entry whose pickle is ``os.system`` itself, protocol 0: ``cos\nsystem\n.``):
    >>> data_objects({"_last_obs": {":serialized:": "Y29zCnN5c3RlbQou"}}, object)  # not needed to act: its default, None
    {'_last_obs': None}
"""

from __future__ import annotations

import base64
import binascii
import enum
import importlib
import inspect
import io
import pickle  # restricted below: find_class reaches only what a model's data holds
import sys
import types
import warnings
from collections.abc import Mapping, Sequence
from functools import cache
from typing import Any

import numpy as np

from oodmon.agents.pickle_walk import one_line, walk_opcodes
from oodmon.errors import ConfigError

__all__ = ["NEEDED", "UNSAFE_HINT", "data_objects", "import_modules"]

#: The data entries the policy is built from: a model whose file holds one of them as something
#: refused is refused.
NEEDED = ("policy_class", "policy_kwargs", "observation_space", "action_space")

#: How to load a file oodmon refuses anyway, in the words of the command line and of Python.
UNSAFE_HINT = ("A file you trust (you made it): --unsafe-load-pickles (unsafe_load_pickles=True) loads it as "
               "stable-baselines3 does, running the code it holds")

#: The functions (and containers) an entry may call, by module and name: numpy's array, dtype and
#: scalar constructors (numpy 2 names them ``numpy._core``, numpy 1 ``numpy.core``), its random
#: generators' (a space's ``np_random``), and ``collections``' deque (the episode buffers) and
#: OrderedDict (a dict space's spaces), and ``_codecs.encode``, which a protocol-2 pickle writes bytes with.
_CALLS = {(module, name) for module in ("numpy._core.multiarray", "numpy.core.multiarray")
          for name in ("_reconstruct", "scalar")} \
    | {(module, "_frombuffer") for module in ("numpy._core.numeric", "numpy.core.numeric")} \
    | {("numpy", "dtype"), ("numpy", "ndarray")} \
    | {("numpy.random._pickle", name) for name in ("__generator_ctor", "__bit_generator_ctor", "__randomstate_ctor")} \
    | {("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"), ("collections", "deque"),
       ("collections", "OrderedDict"), ("_codecs", "encode")}  # the last: bytes in a protocol-2 pickle

#: numpy's random-generator constructors call what they are given: only what
#: :func:`_random_ctor_argument` admits may be.
_RANDOM_CTORS = {("numpy.random._pickle", name) for name in ("__generator_ctor", "__bit_generator_ctor",
                                                               "__randomstate_ctor")}


def _random_ctor_argument(value: Any) -> bool:
    """What numpy's pickles give its random-generator constructors: a bit generator's name, class
    (numpy 2) or instance, or the bit generators' own constructor (older pickles)."""
    return isinstance(value, (str, np.random.BitGenerator)) or (
        isinstance(value, type) and issubclass(value, np.random.BitGenerator)) or (
        _calls().get(id(value)) == ("numpy.random._pickle", "__bit_generator_ctor"))


#: Where an entry may find classes (of :func:`_kinds`), by module prefix; each is installed beside oodmon.
_PACKAGES = ("stable_baselines3.", "sb3_contrib.", "torch.nn.modules.", "torch.optim.", "numpy.", "gymnasium.spaces.",
             "oodmon.agents.")  # oodmon's own policy classes, should a user's model be built of them


#: Packages no class of the program's own lives in: their classes are found by :data:`_PACKAGES` only.
_NOT_OWN = {"torch", "numpy", "gymnasium", "stable_baselines3", "sb3_contrib", "oodmon"}


@cache
def _kinds() -> tuple[type, ...]:
    """The kinds of class a model's data holds (imported when first asked: torch and SB3 are heavy)."""
    import gymnasium
    import torch
    from stable_baselines3.common.buffers import BaseBuffer
    from stable_baselines3.common.noise import ActionNoise
    from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule, LinearSchedule

    return (torch.nn.Module, torch.optim.Optimizer, gymnasium.spaces.Space, BaseBuffer, ActionNoise, FloatSchedule,
            ConstantSchedule, LinearSchedule, enum.Enum, np.dtype, np.random.BitGenerator, np.random.Generator,
            np.random.RandomState, np.random.SeedSequence)


@cache
def _calls() -> dict[int, tuple[str, str]]:
    """The objects of :data:`_CALLS` (those this numpy has), by identity."""
    found = {}
    for module, name in _CALLS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numpy 2 warns of numpy.core's names
            try:
                found[id(getattr(importlib.import_module(module), name))] = (module, name)
            except (ImportError, AttributeError):
                continue  # the other numpy's name
    return found


def _named_tuple_or_enum(found: Any) -> bool:
    """SB3's (or sb3-contrib's) named tuples and enums (``TrainFreq``, ``TrainFrequencyUnit``): the
    classes an entry may call, besides :data:`_CALLS` and numpy's dtypes."""
    return isinstance(found, type) and (issubclass(found, enum.Enum) or (issubclass(found, tuple) and hasattr(
        found, "_fields"))) and found.__module__.split(".")[0] in ("stable_baselines3", "sb3_contrib")


class _Refused(pickle.UnpicklingError):
    """An entry names something oodmon does not load from a model file; ``module``: the module not
    imported that it names (``None``: it names something that is not of the kinds allowed)."""

    def __init__(self, what: str, module: str | None = None) -> None:
        super().__init__(what)
        self.module = module


class _DataUnpickler(pickle._Unpickler):  # noqa: SLF001  (Python's own unpickler, whose calls can be checked)
    """Finds only the classes of :func:`_kinds` (:meth:`find_class`) and calls only :data:`_CALLS`,
    SB3's named tuples and enums, and numpy's dtypes (:meth:`load_reduce`, :meth:`_instantiate`):
    every other class is only a value, or built empty (``NEWOBJ``) and given its state, which goes
    to objects only (:meth:`load_build`)."""

    dispatch = dict(pickle._Unpickler.dispatch)  # noqa: SLF001

    def find_class(self, module: str, name: str) -> Any:
        import torch

        if (module, name) in _CALLS:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)  # numpy 2 of numpy 1's names (older files)
                return super().find_class(module, name)
        if module == "torch" and isinstance(getattr(torch, name, None), torch.dtype):
            return getattr(torch, name)
        if module.startswith(_PACKAGES):
            found = super().find_class(module, name)  # a module of an installed package: importing it runs no file's code
            # where it lives, not only where it was found: a dotted name (protocol 4) walks attributes,
            # out of the module ("th.fx.GraphModule" from a module that imports torch as th)
            if isinstance(found, type) and found.__module__.startswith(_PACKAGES) \
                    and (issubclass(found, _kinds()) or _named_tuple_or_enum(found)):
                return found
        elif module.split(".")[0] in _NOT_OWN:
            pass  # torch's, numpy's, ... other classes and functions: refused below
        elif module in sys.modules:
            found = super().find_class(module, name)  # imported already: finding the name runs nothing
            if isinstance(found, type) and issubclass(found, torch.nn.Module) \
                    and found.__module__.split(".")[0] not in _NOT_OWN:
                return found  # a torch module class of the program's own (a policy class of its own, say)
        else:
            raise _Refused(f"{module}.{name}, of a module the program has not imported (oodmon imports none a file "
                           "names)", module)
        raise _Refused(f"{module}.{name}, which a model's data does not hold")

    def _check_call(self, called: Any, args: Any) -> None:
        name = _calls().get(id(called))
        if name is not None:
            if name in _RANDOM_CTORS and not all(_random_ctor_argument(a) for a in args):
                raise _Refused(f"{'.'.join(name)} given {', '.join(type(a).__name__ for a in args)}, which a model's "
                               "data does not hold")
            return
        if _named_tuple_or_enum(called) or (isinstance(called, type) and issubclass(called, np.dtype)):
            return
        raise _Refused(f"a call of {getattr(called, '__qualname__', type(called).__name__)}, which a model's data "
                       "does not hold")

    def load_reduce(self) -> None:
        self._check_call(self.stack[-2], self.stack[-1])
        super().load_reduce()

    dispatch[pickle.REDUCE[0]] = load_reduce

    def load_build(self) -> None:
        # state for an object the file built, never for a class or function it found: setting
        # attributes of a library's class would change it for the whole process
        target = self.stack[-2]
        if isinstance(target, (type, types.FunctionType, types.BuiltinFunctionType)):
            raise _Refused(f"state for {getattr(target, '__qualname__', target)} itself, which a model's data does not "
                           "hold")
        super().load_build()

    dispatch[pickle.BUILD[0]] = load_build

    def _instantiate(self, klass: Any, args: Any) -> None:  # INST and OBJ (protocols 0 and 1)
        if args or not isinstance(klass, type) or hasattr(klass, "__getinitargs__"):
            self._check_call(klass, args)  # a call, as load_reduce's; else only klass.__new__
        super()._instantiate(klass, args)


def _decoded(encoded: Any) -> Any:
    """One ``:serialized:`` entry, unpickled by :class:`_DataUnpickler`.

    Raises:
        _Refused: it names something oodmon does not load.
        pickle.UnpicklingError: it is not a pickle (damaged).
    """
    try:
        raw = base64.b64decode(encoded, validate=True)
    except (binascii.Error, TypeError, ValueError):
        raise pickle.UnpicklingError("not base64") from None
    try:
        walk_opcodes(raw)  # a damaged length fails here, before the unpickler allocates it
        return _DataUnpickler(io.BytesIO(raw)).load()
    except _Refused:
        raise
    except Exception as error:  # noqa: BLE001  (a damaged entry fails in many ways; none runs code)
        raise pickle.UnpicklingError(one_line(error)) from None


def import_modules(names: Sequence[str]) -> None:
    """Import the modules ``names`` (the user's, which hold the classes their model files name).

    Raises:
        ConfigError: a name that is not a module Python finds.
    """
    for name in names:
        if not isinstance(name, str) or not name.strip() or name.startswith("."):
            raise ConfigError(f"--import {name!r}: give a module's full name, e.g. --import my_policy")
        try:
            importlib.import_module(name)
        except (ImportError, TypeError, ValueError) as error:
            raise ConfigError(f"--import {name}: {error} (is its folder on PYTHONPATH?)") from None


def _default(algorithm: type, key: str) -> Any:
    """The algorithm's ``__init__`` default for ``key``, or ``None`` (it has none)."""
    try:
        parameter = inspect.signature(algorithm.__init__).parameters.get(key)
    except (TypeError, ValueError):
        return None
    return None if parameter is None or parameter.default is inspect.Parameter.empty else parameter.default


def _unread(path: Any, key: str, error: pickle.UnpicklingError) -> str:
    """The line that refuses a model whose entry ``key`` (one of :data:`NEEDED`) could not be read."""
    if not isinstance(error, _Refused):
        return f"{path}: its {key} is damaged ({error})"
    own = "" if error.module is None else (
        f"A class of your own module: --import {error.module} (imports=[{error.module!r}], or import it before "
        "loading). ")
    return f"{path}: its {key} names {error}; oodmon does not unpickle it (that could run code from the file). " \
           f"{own}{UNSAFE_HINT}"


def data_objects(data: Mapping[str, Any], algorithm: type, path: Any = "the model file") -> dict[str, Any]:
    """Each entry of a model's ``data`` (its JSON, parsed) that SB3 would unpickle, as the objects
    SB3's ``load`` takes for them (``custom_objects``); ``algorithm``: the class loading it, whose
    defaults stand for refused entries not in :data:`NEEDED`.

    Raises:
        ConfigError: an entry of :data:`NEEDED` that names something refused, or is damaged.
    """
    objects = {}
    for key, item in data.items():
        if not (isinstance(item, dict) and ":serialized:" in item):
            continue  # plain JSON: SB3 reads it as it is
        try:
            objects[key] = _decoded(item[":serialized:"])
        except pickle.UnpicklingError as error:  # refused (_Refused), or damaged
            if key in NEEDED:
                raise ConfigError(_unread(path, key, error)) from None
            objects[key] = _default(algorithm, key)
    return objects
