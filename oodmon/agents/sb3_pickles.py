"""An SB3 model file's ``data`` read without running code from it.

SB3's ``load`` unpickles (with cloudpickle) every entry of the zip's ``data`` JSON that JSON
cannot hold: the spaces, the policy class and its keyword arguments, the schedules, the last
observation, ... A crafted file can hold any code there, which ``load`` runs. (The weights,
``policy.pth``, SB3 reads with ``torch.load(weights_only=True)``: tensors only.) :func:`data_objects`
decodes each such entry with an unpickler that reaches only what a model's data holds, and oodmon
gives them to SB3's ``load`` as its ``custom_objects``: SB3 then unpickles nothing of the file.

What an entry may name (Python's "Restricting Globals", docs.python.org/3/library/pickle.html):

- numpy's array, dtype, scalar and random-generator constructors, ``collections.deque`` and
  ``OrderedDict`` (:data:`_CALLS`);
- classes of stable-baselines3, sb3-contrib, torch, numpy and gymnasium's spaces of the kinds a
  model's data holds (:func:`_kinds`): torch modules (policy classes, feature extractors,
  activation functions), optimizers, spaces, SB3's buffers, schedules and action noises, named
  tuples (``TrainFreq``) and enums; and torch's dtypes;
- a torch module class of a module the program has already imported (a policy class of your own,
  imported before the model is loaded, or named by ``imports=`` / ``--import``: its code has run
  already, on your word). A module not yet imported is not imported for a file.

Anything else is refused. A refused entry that builds the policy (:data:`NEEDED`: the policy
class, its keyword arguments, the spaces) refuses the model, with a line saying what it names and
how to load it anyway: ``unsafe_load_pickles=True`` (``--unsafe-load-pickles``), SB3's own
``load``, which runs what the file holds. Any other refused entry is training state a deployed
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
import inspect
import io
import pickle  # restricted below: find_class reaches only what a model's data holds
import pickletools
import sys
import warnings
from collections.abc import Mapping, Sequence
from functools import cache
from typing import Any

import numpy as np

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
#: OrderedDict (a dict space's spaces).
_CALLS = {(module, name) for module in ("numpy._core.multiarray", "numpy.core.multiarray")
          for name in ("_reconstruct", "scalar")} \
    | {(module, "_frombuffer") for module in ("numpy._core.numeric", "numpy.core.numeric")} \
    | {("numpy", "dtype"), ("numpy", "ndarray")} \
    | {("numpy.random._pickle", name) for name in ("__generator_ctor", "__bit_generator_ctor", "__randomstate_ctor")} \
    | {("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"), ("collections", "deque"),
       ("collections", "OrderedDict")}

#: Packages whose classes of :func:`_kinds` an entry may name (each is installed beside oodmon).
_PACKAGES = ("stable_baselines3", "sb3_contrib", "torch", "numpy", "gymnasium.spaces")


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


def _in_packages(module: str) -> bool:
    return any(module == package or module.startswith(package + ".") for package in _PACKAGES)


class _Refused(pickle.UnpicklingError):
    """An entry names something oodmon does not load from a model file; ``module``: the module not
    imported that it names (``None``: it names something that is not of the kinds allowed)."""

    def __init__(self, what: str, module: str | None = None) -> None:
        super().__init__(what)
        self.module = module


class _DataUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _CALLS:
            return super().find_class(module, name)
        if _in_packages(module):
            found = super().find_class(module, name)  # a module of an installed package: importing it runs no file's code
        elif module in sys.modules:
            found = super().find_class(module, name)  # imported already: finding the name runs nothing
            if isinstance(found, type) and issubclass(found, _kinds()[0]):
                return found  # a torch module class of the program's own (a policy class of its own, say)
            raise _Refused(f"{module}.{name}, which a model's data does not hold")
        else:
            raise _Refused(f"{module}.{name}, of a module the program has not imported (oodmon imports none a file "
                           "names)", module)
        import torch

        if isinstance(found, torch.dtype):
            return found
        if isinstance(found, type) and (issubclass(found, _kinds()) or (issubclass(found, tuple)
                                                                         and hasattr(found, "_fields"))):
            return found
        raise _Refused(f"{module}.{name}, which a model's data does not hold")


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
    # Walked first without building anything: a damaged length is an error here, where the
    # unpickler would allocate the bytes it names before reading them (quietly: other bytes read
    # as opcodes can warn of string escapes).
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            for _ in pickletools.genops(raw):
                pass
        except Exception as error:  # noqa: BLE001  (pickletools fails in many ways on damaged bytes)
            raise pickle.UnpicklingError(str(error) or type(error).__name__) from None
    try:
        return _DataUnpickler(io.BytesIO(raw)).load()
    except _Refused:
        raise
    except Exception as error:  # noqa: BLE001  (a damaged entry fails in many ways; none runs code)
        raise pickle.UnpicklingError(" ".join(str(error).split()) or type(error).__name__) from None


def import_modules(names: Sequence[str]) -> None:
    """Import the modules ``names`` (the user's, which hold the classes their model files name).

    Raises:
        ConfigError: a name that is not a module Python finds.
    """
    import importlib

    for name in names:
        if not isinstance(name, str) or not name.strip():
            raise ConfigError(f"--import {name!r}: give a module name, e.g. --import my_policy")
        try:
            importlib.import_module(name)
        except ImportError as error:
            raise ConfigError(f"--import {name}: {error} (is its folder on PYTHONPATH?)") from None


def _default(algorithm: type, key: str) -> Any:
    """The algorithm's ``__init__`` default for ``key``, or ``None`` (it has none)."""
    try:
        parameter = inspect.signature(algorithm.__init__).parameters.get(key)
    except (TypeError, ValueError):
        return None
    return None if parameter is None or parameter.default is inspect.Parameter.empty else parameter.default


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
        except _Refused as refused:
            if key in NEEDED:
                own = "" if refused.module is None else (
                    f"A class of your own module: --import {refused.module} (imports=[{refused.module!r}], or import "
                    "it before loading). ")
                raise ConfigError(f"{path}: its {key} names {refused}; oodmon does not unpickle it (that could run "
                                  f"code from the file). {own}{UNSAFE_HINT}") from None
            objects[key] = _default(algorithm, key)
        except pickle.UnpicklingError as damaged:
            if key in NEEDED:
                raise ConfigError(f"{path}: its {key} is damaged ({damaged})") from None
            objects[key] = _default(algorithm, key)
    return objects
