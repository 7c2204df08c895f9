"""What a plain policy without weights computes with, hashed: an edit of it is another policy.

A threshold is bound to the policy it was calibrated for (``policy_hash``). A function with no
weights (a hand-written controller) was bound by its name alone until 2026-12-06, so an edit of
its gains kept the old threshold, whose false-alarm rate belongs to the controller before the edit.
:func:`code_sha256` hashes what the function's decisions are made of, read without running it:

- its source text (``inspect.getsource``: the same whether the module was imported or run as a
  script, and on any Python version, which bytecode is not);
- the values of the names it reads from its module and its closure, and its default arguments:
  numbers, strings, arrays and tensors (their bytes), containers of those, a torch module's
  weights, an SB3 model's (``model.predict`` in a function of yours); of a function or class it
  calls, of its file or another file of yours (not the standard library's, not an installed
  package's, not oodmon's), its source and what that reads in turn; of a module of yours, the
  values it holds of the names the code reads (``config.K``). Any other object (another package's
  function or module, an object of a class of yours held as a value) counts by its type's name
  only: its insides may change as the policy acts;
- of a callable object, its class's source and the attributes of the object itself (not of one
  with a memory of the episode, a ``begin_episode()`` method: its attributes change as it acts);
  of a bound method, the object's; of a ``functools.partial``, its function and its arguments.

An edit elsewhere in the file (a comment, another function, the script's monitoring code below
the policy) does not count: a threshold saved by ``oodmon.watch(act, ..., save=...)`` still fits
after the script is changed to read it back. An installed package's code (``pip install``) counts
by name only: its version is its own to say.

Example:
    >>> quoted = code_sha256(functools.partial(textwrap.indent, prefix="> "))
    >>> len(quoted), quoted == code_sha256(functools.partial(textwrap.indent, prefix="# "))
    (64, False)
    >>> code_sha256(len) is None  # a builtin: Python keeps no source of it
    True
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import sys
import sysconfig
import textwrap
import types
from collections.abc import Sequence
from typing import Any

__all__ = ["code_sha256"]

#: How deep containers of values are read (a list of dicts of arrays is three): deeper, by type only.
_DEPTH = 6
#: Containers of more items than this (a list the policy appends to, a replay buffer) count by type and length.
_ITEMS = 10_000


def code_sha256(policy: Any) -> str | None:
    """The hex sha256 of the source of ``policy`` and of the values it reads (see the module's
    docstring); ``None`` where Python keeps no source of it (defined in ``python -c``, a doctest, an
    interactive session, a builtin)."""
    digest = _Digest()
    try:
        digest.policy(policy)
    except Exception:  # noqa: BLE001 (_NoSource, or a value of yours whose repr fails): bound by its name, as before
        return None
    return digest.hexdigest()


class _NoSource(Exception):
    """The policy itself has no source Python can read."""


class _Digest:
    def __init__(self) -> None:
        self._hash = hashlib.sha256()
        self._seen: set[int] = set()  # functions and classes hashed already (recursion, shared helpers)
        self._read: set[tuple[int, str]] = set()  # (module, name) read already (modules that import each other)

    def hexdigest(self) -> str:
        return self._hash.hexdigest()

    def _add(self, tag: str, data: bytes | str = b"") -> None:
        raw = data.encode() if isinstance(data, str) else data
        self._hash.update(f"{tag}:{len(raw)}:".encode())
        self._hash.update(raw)

    def policy(self, policy: Any) -> None:
        if isinstance(policy, functools.partial):
            self.policy(policy.func)
            self.value(policy.args, 0)
            self.value(dict(policy.keywords), 0)
        elif isinstance(policy, types.MethodType):
            self._function(policy.__func__, required=True)
            self._attributes(policy.__self__)
        elif isinstance(policy, types.FunctionType):
            self._function(policy, required=True)
        elif isinstance(policy, type) or not callable(policy):
            raise _NoSource
        else:  # a callable object: its class, and what it holds
            self._class(type(policy), required=True)
            self._attributes(policy)

    def _source(self, thing: Any, required: bool) -> str | None:
        try:
            return textwrap.dedent(inspect.getsource(thing))
        except (OSError, TypeError):
            if required:
                raise _NoSource from None
            return None

    def _function(self, function: types.FunctionType, required: bool = False) -> None:
        if id(function) in self._seen:
            return
        self._seen.add(id(function))
        source = self._source(function, required)
        self._add("function", function.__qualname__)
        if source is None:
            return
        self._add("source", source)
        code = function.__code__
        self.value(function.__defaults__, 0)
        self.value(function.__kwdefaults__, 0)
        names = sorted(_names_read(code))
        for name, cell in zip(code.co_freevars, function.__closure__ or ()):
            self._add("closure", name)
            try:
                self._named_value(cell.cell_contents, function.__module__, names)
            except ValueError:  # a cell not yet filled
                self._add("empty")
        module_globals = function.__globals__
        for name in names:
            if name in module_globals:
                self._add("global", name)
                self._named_value(module_globals[name], function.__module__, names)

    def _class(self, cls: type, required: bool = False) -> None:
        if id(cls) in self._seen:
            return
        self._seen.add(id(cls))
        source = self._source(cls, required)
        self._add("class", cls.__qualname__)
        if source is not None:
            self._add("source", source)
            for function in vars(cls).values():  # what its methods read of their module
                if isinstance(function, (staticmethod, classmethod)):
                    function = function.__func__
                if isinstance(function, types.FunctionType):
                    self._function(function)

    def _attributes(self, owner: Any) -> None:
        state = getattr(owner, "__dict__", None)
        if hasattr(owner, "begin_episode"):  # a memory of the episode: its attributes change as it acts
            return
        if isinstance(state, dict):
            self._add("attributes")
            self.value({k: v for k, v in state.items() if not k.startswith("__")}, 0)

    def _named_value(self, value: Any, module: str, names: Sequence[str] = ()) -> None:
        """A value the code reads by ``name``: a function or class of its module or of another file
        of yours is followed, so is what it reads of a module of yours (``config.K``: the values of
        the ``names`` the code reads that the module holds); data is hashed."""
        if isinstance(value, types.FunctionType) and (value.__module__ == module or _yours(value.__module__)):
            self._function(value)
        elif isinstance(value, type) and (value.__module__ == module or _yours(value.__module__)):
            self._class(value)
        elif isinstance(value, types.ModuleType) and _yours(value.__name__):
            held = vars(value)
            for name in names:
                if name in held and (id(value), name) not in self._read:
                    self._read.add((id(value), name))
                    self._add("attribute", f"{value.__name__}.{name}")
                    self._named_value(held[name], value.__name__, names)
        elif isinstance(value, functools.partial):
            self._add("partial")
            self._named_value(value.func, module, names)
            self.value(value.args, 0)
            self.value(dict(value.keywords), 0)
        else:
            self.value(value, 0)

    def value(self, value: Any, depth: int) -> None:
        """Data's type and bytes; of anything else (a module, another package's function) the type's name."""
        self._add("type", type(value).__qualname__)  # (not its module: __main__ in a script, its name imported)
        if value is None or isinstance(value, (bool, int, float, complex, str, bytes)):
            self._add("repr", repr(value))
        elif depth >= _DEPTH:
            return
        elif isinstance(value, (tuple, list, set, frozenset, dict)) and len(value) > _ITEMS:
            self._add("items", str(len(value)))
        elif isinstance(value, (tuple, list)):
            self._add("items", str(len(value)))
            for item in value:
                self.value(item, depth + 1)
        elif isinstance(value, (set, frozenset)):
            self._add("items", str(len(value)))
            for item in sorted(value, key=repr):
                self.value(item, depth + 1)
        elif isinstance(value, dict):
            self._add("items", str(len(value)))
            for key in sorted(value, key=repr):
                self.value(key, depth + 1)
                self.value(value[key], depth + 1)
        elif _is_array(value):
            import numpy as np

            array = np.ascontiguousarray(value)
            self._add("array", f"{array.dtype.str}{array.shape}")
            if array.dtype != object:
                self._add("bytes", array.tobytes())
        elif _is_tensor(value):
            self.value(value.detach().cpu().numpy(), depth)
        elif _is_torch_module(value):
            from oodmon.hashing import state_sha256

            self._add("weights", state_sha256(value.state_dict()))
        elif type(value).__module__.startswith(("stable_baselines3.", "sb3_contrib.")) and \
                _is_torch_module(getattr(value, "policy", None)):  # an SB3 model the function asks for its action
            self.value(value.policy, depth)


def _yours(module_name: str) -> bool:
    """Whether a module is one of your own files: not the standard library's, not an installed
    package's (site-packages), not oodmon's, and a file (not ``__main__`` of a notebook)."""
    if module_name.split(".")[0] == "oodmon":
        return False
    file = getattr(sys.modules.get(module_name), "__file__", None)
    if not file:
        return False
    path = os.path.realpath(file)
    return not path.startswith(_LIBRARIES) and not any(part in path for part in _INSTALLED)


#: Where the standard library and installed packages live (sysconfig's paths of this interpreter).
_LIBRARIES = tuple({os.path.realpath(path) + os.sep for key in ("stdlib", "platstdlib", "purelib", "platlib")
                    if (path := sysconfig.get_paths().get(key))})
_INSTALLED = (f"{os.sep}site-packages{os.sep}", f"{os.sep}dist-packages{os.sep}")


def _names_read(code: types.CodeType) -> set[str]:
    """The global names a function's code and the code nested in it (lambdas, comprehensions) read."""
    names = set(code.co_names)
    for constant in code.co_consts:
        if isinstance(constant, types.CodeType):
            names |= _names_read(constant)
    return names


def _is_array(value: Any) -> bool:
    numpy = sys.modules.get("numpy")
    return numpy is not None and isinstance(value, (numpy.ndarray, numpy.generic))


def _is_tensor(value: Any) -> bool:
    torch = sys.modules.get("torch")  # (never imported here: a value of torch's exists only once it is)
    return torch is not None and isinstance(value, torch.Tensor)


def _is_torch_module(value: Any) -> bool:
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(value, torch.nn.Module)
