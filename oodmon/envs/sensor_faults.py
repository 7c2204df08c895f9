"""Sensor faults: the readings of an observation as a failing sensor reports them, from a step of
each episode on (a bias, a miscalibrated gain, noise, a frozen reading; for discrete readings, a
misread). :class:`~oodmon.envs.shift.ShiftAttributes` applies them for the ``obs.`` names of a
spec (``Acrobot-v1:obs.bias[4]=0.5``), and oodmon's own variants for theirs
(``cartpole:obs.stuck[3]=1``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, ClassVar

import gymnasium
import numpy as np

from oodmon.errors import InvalidParameterError, UnknownParameterError
from oodmon.validation import is_finite_real

__all__ = ["DictSensorFaults", "SensorFaults"]


class SensorFaults:
    """Faults of the readings of a ``Box`` observation, by reading (its flattened index ``i``):

    - ``obs.bias[i]=b``: the reading plus ``b``;
    - ``obs.scale[i]=k``: the reading times ``k`` (a miscalibrated gain; before the bias);
    - ``obs.noise[i]=s``: plus Gaussian noise of std ``s``, in the reading's own units, drawn from
      a generator seeded by each ``reset(seed=...)`` (the same episode, the same noise);
    - ``obs.stuck[i]=1``: the reading held at its last value before the fault (a frozen sensor).

    Without ``[i]`` (``obs.noise=30``) a fault is every reading's: a camera's every pixel, a whole
    sensor block's gain; a reading named with ``[i]`` as well takes that value instead. Readings of
    an integer observation (a picture's bytes) are rounded and clipped to their type's range (a
    pixel saturates at 255 rather than wrap around to 0).

    An observation of discrete values (``Discrete``: one reading; ``MultiDiscrete``,
    ``MultiBinary``: one per value, flattened; a ``Tuple`` of ``Discrete``: one per element, read
    back as a tuple) has no gain and no Gaussian noise; its faults are
    ``obs.bias[i]=b``, a whole ``b`` added (a miscount, clipped to the reading's values),
    ``obs.noise[i]=p``, the probability that a step's reading is misread as a value drawn
    uniformly from the reading's values (the same seeding), and ``obs.stuck[i]=1``.

    Made by :class:`ShiftAttributes` from the ``obs.`` names of its changes (``obs.`` is kept for
    them: an env attribute called ``obs`` cannot be shifted); a ``Dict`` observation's, one of these
    per key, and a ``Tuple``'s of other parts than ``Discrete`` ones, one per part, by
    :class:`DictSensorFaults`.

    Example:
        >>> faults = SensorFaults.of("X", gymnasium.spaces.Box(-1, 1, (3,)), {"obs.bias[0]": 0.5, "obs.stuck[2]": 1})
        >>> faults.begin_episode(0, np.zeros(3, np.float32))
        >>> faults.read(np.ones(3, np.float32), faulty=True).tolist()
        [1.5, 1.0, 0.0]
        >>> taxi = SensorFaults.of("Taxi-v4", gymnasium.spaces.Discrete(500), {"obs.bias": 3})
        >>> taxi.begin_episode(0, 17)
        >>> taxi.read(17, faulty=True), taxi.read(498, faulty=True)  # the same type as the env's, clipped to its values
        (20, 499)
    """

    KINDS: ClassVar[tuple[str, ...]] = ("bias", "scale", "noise", "stuck")
    _UNCHANGED: ClassVar[Mapping[str, float]] = MappingProxyType({"bias": 0.0, "scale": 1.0, "noise": 0.0, "stuck": 0.0})

    def __init__(self, changes: dict[str, float], faults: list[tuple[str, int | None, float]], size: int,
                 integers: np.iinfo | None = None, values: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """``changes`` as the spec names them; ``faults`` the same as (kind, reading or ``None`` for
        every reading, value), parsed and checked by :meth:`of`; ``size`` the readings of an
        observation; ``integers`` the range of an integer observation's type (its readings are rounded
        and clipped to it); ``values`` the lowest and highest value of each reading of a discrete
        observation (its noise is a misread's probability: :meth:`_discrete`)."""
        self.changes = changes
        self.bias, self.scale, self.noise = np.zeros(size), np.ones(size), np.zeros(size)
        self.stuck = np.zeros(size, bool)
        for kind, index, value in sorted(faults, key=lambda fault: fault[1] is not None):  # every reading's first
            where = slice(None) if index is None else index
            if kind == "stuck":
                self.stuck[where] = bool(value)
            else:
                getattr(self, kind)[where] = value
        self._noisy, self._holds = bool(self.noise.any()), bool(self.stuck.any())
        self._held: np.ndarray | None = None
        self._last: np.ndarray | None = None
        self._rng = np.random.default_rng(0)
        self._integers = integers
        self._values = values

    @classmethod
    def of(cls, owner: str, space: gymnasium.Space, changes: dict[str, float]) -> SensorFaults | None:
        """The faults of ``changes`` (names ``obs.KIND[i]``) for observations of ``space``; ``None``
        when there are none.

        Raises:
            UnknownParameterError: another kind (``scale`` of discrete values), an index the
                observation does not have, or an observation that is neither one ``Box`` nor
                discrete values.
            InvalidParameterError: a value that is not a finite number, a negative noise (above 1
                for discrete values), a fractional bias of discrete values, a stuck other than 1,
                or no fault at all.
        """
        if not changes:
            return None
        values = _discrete_values(space)
        if isinstance(space, gymnasium.spaces.Dict) or isinstance(space, gymnasium.spaces.Tuple) and values is None:
            return DictSensorFaults.of(owner, space, changes)
        if not isinstance(space, gymnasium.spaces.Box) and values is None:
            raise UnknownParameterError(f"{owner}: sensor faults ({', '.join(changes)}) read the readings of a Box "
                                        f"observation or of discrete values (Discrete, MultiDiscrete, MultiBinary, a "
                                        f"Tuple of Discrete), or of a dict or tuple of them; {owner}'s is {space}")
        kinds = cls.KINDS if values is None else tuple(kind for kind in cls.KINDS if kind != "scale")
        size, kept, faults = int(np.prod(space.shape)) if values is None else len(values[0]), {}, []
        for name, value in changes.items():
            match = re.fullmatch(r"obs\.(\w+)(?:\[(\d+)\])?", name)
            if match is None or match.group(1) not in kinds:
                of_what = "" if values is None else " of discrete values"
                raise UnknownParameterError(f"{owner}: {name!r} is no sensor fault{of_what}; give obs.KIND[i]=VALUE, "
                                            f"KIND one of {', '.join(kinds)}, i a reading of the observation "
                                            f"(0-{size - 1}), or obs.KIND=VALUE for every reading")
            kind, index = match.group(1), None if match.group(2) is None else int(match.group(2))
            if index is not None and index >= size:
                raise UnknownParameterError(f"{owner}: {name} is outside the observation, whose {size} readings are "
                                            f"0-{size - 1} (flattened)")
            problem = _fault_value_problem(kind, value, discrete=values is not None)
            if problem is not None:
                raise InvalidParameterError(f"{owner}: {name}={value!r} is not allowed; {problem}")
            if value != cls._UNCHANGED[kind] or (index is not None and f"obs.{kind}" in changes):
                kept[name] = float(value)  # (an unchanged reading kept where every reading's fault would change it)
                faults.append((kind, index, float(value)))
        if not kept:
            given = ", ".join(f"{name}={value:g}" for name, value in changes.items())
            unchanged = ", ".join(f"{kind} {value:g}" for kind, value in cls._UNCHANGED.items() if kind in kinds)
            raise InvalidParameterError(f"{owner}: {given} change{'s' if len(changes) == 1 else ''} no reading (each "
                                        f"kind's value that leaves a reading as it is: {unchanged}; obs.stuck[i]=1 "
                                        f"holds reading i from the onset); a shift changes at least one")
        integers = np.iinfo(space.dtype) if values is None and np.issubdtype(space.dtype, np.integer) else None
        return cls(kept, faults, size, integers, values)

    def begin_episode(self, seed: int | None, obs, stream: int | None = None) -> None:
        """A new episode: its noise seeded by ``seed`` (``None``: the generator goes on), its first
        reading kept; ``stream``: another generator of the same seed (a dict's key's own)."""
        if seed is not None:
            self._rng = np.random.default_rng([seed, 0x5E45] if stream is None else [seed, 0x5E45, stream])
        self._held = None
        if self._holds:  # the reading a stuck sensor would hold, were it to stick at once
            self._last = np.asarray(obs).reshape(-1).copy()

    def read(self, obs, *, faulty: bool):
        """``obs`` as the sensors report it: itself before the fault, through the faults after."""
        flat = np.asarray(obs).reshape(-1)
        if not faulty:
            if self._holds:  # the last reading before the fault, which a stuck sensor holds
                self._last = flat.copy()
            return obs
        if self._values is not None:
            reading = self._discrete(flat)
        else:
            reading = flat.astype(np.float64) * self.scale + self.bias
            if self._noisy:
                reading += self.noise * self._rng.normal(size=flat.shape)
        if self._holds:
            if self._held is None:  # the fault begins: a stuck sensor holds its last reading
                self._held = self._last if self._last is not None else flat.copy()
            reading[self.stuck] = self._held[self.stuck]
        if self._integers is not None:  # bytes saturate: 250 + 10 reads 255, not 4
            reading = np.clip(np.rint(reading), self._integers.min, self._integers.max)
        if np.ndim(obs) == 0 and not isinstance(obs, np.ndarray):  # a Discrete space's value: its type (Taxi's int)
            return type(obs)(reading[0])
        if isinstance(obs, tuple):  # a Tuple of Discrete values (Blackjack's hand): a tuple of their types
            return tuple(type(value)(read) for value, read in zip(obs, reading))
        return reading.astype(np.asarray(obs).dtype).reshape(np.shape(obs))

    def _discrete(self, flat: np.ndarray) -> np.ndarray:
        """Discrete readings through the bias (clipped to each reading's values) and the misreads:
        each reading drawn anew, uniformly from its values, with probability its noise (as many draws
        at every step, whichever readings are misread)."""
        low, high = self._values
        reading = np.clip(flat.astype(np.int64) + self.bias.astype(np.int64), low, high)
        if self._noisy:
            misread = self._rng.random(flat.shape) < self.noise
            drawn = self._rng.integers(low, high + 1)
            reading[misread] = drawn[misread]
        return reading


class DictSensorFaults:
    """Faults of the readings of a ``Dict`` observation, each key's its own: ``obs.KEY.KIND[i]=VALUE``
    is :class:`SensorFaults`' ``obs.KIND[i]=VALUE`` of the observation under ``KEY`` (a ``Box`` or
    discrete values), e.g. ``obs.joints.stuck[2]=1`` or ``obs.camera.noise=30``; the other keys are
    read as the env gives them. Each key's noise draws from a generator of its own, seeded by the
    episode's seed and the key's place in the dict. A ``Tuple`` observation's parts are named by
    their place, from 0 (``obs.1.bias[0]=0.5``: the second part's first reading), and read back as
    a tuple (a ``Tuple`` of ``Discrete`` values alone is :class:`SensorFaults`' own: one reading each).

    Example:
        >>> space = gymnasium.spaces.Dict({"pole": gymnasium.spaces.Box(-1, 1, (2,)), "cell": gymnasium.spaces.Discrete(4)})
        >>> faults = SensorFaults.of("X", space, {"obs.pole.bias[1]": 0.5, "obs.cell.stuck": 1})
        >>> faults.begin_episode(0, {"pole": np.zeros(2, np.float32), "cell": 2})
        >>> read = faults.read({"pole": np.ones(2, np.float32), "cell": 3}, faulty=True)
        >>> read["pole"].tolist(), read["cell"]
        ([1.0, 1.5], 2)
        >>> pair = gymnasium.spaces.Tuple((gymnasium.spaces.Box(-1, 1, (2,)), gymnasium.spaces.Discrete(4)))
        >>> faults = SensorFaults.of("X", pair, {"obs.0.bias[1]": 0.5})
        >>> faults.begin_episode(0, (np.zeros(2, np.float32), 2))
        >>> read = faults.read((np.ones(2, np.float32), 3), faulty=True)
        >>> read[0].tolist(), read[1]
        ([1.0, 1.5], 3)
    """

    def __init__(self, changes: dict[str, float], faults: dict[Any, SensorFaults], keys: list, *,
                 parts: bool = False) -> None:
        """``changes`` as the spec names them; ``faults`` each faulty key's, by where the observation
        holds it; ``keys`` the dict's, in its order (a tuple's places, 0, 1..., if ``parts``)."""
        self.changes, self._parts = changes, parts
        self._faults = {at: (key_faults, keys.index(at)) for at, key_faults in faults.items()}  # and its noise stream

    @classmethod
    def of(cls, owner: str, space: gymnasium.spaces.Dict | gymnasium.spaces.Tuple,
           changes: dict[str, float]) -> DictSensorFaults:
        """The faults of ``changes`` (names ``obs.KEY.KIND[i]``; a tuple's ``obs.N.KIND[i]``, N its
        part's place from 0) for observations of ``space``.

        Raises:
            UnknownParameterError: a name without a key of the dict (a place of the tuple), one of a
                dict or tuple inside it, or what :meth:`SensorFaults.of` refuses for that key's observation.
            InvalidParameterError: what :meth:`SensorFaults.of` refuses for that key's observation.
        """
        parts = isinstance(space, gymnasium.spaces.Tuple)
        keys = list(range(len(space.spaces))) if parts else list(space.spaces)
        named = [str(key) for key in keys]  # as a spec names them
        word, whose, key_word = ("part", "tuple", "N") if parts else ("key", "dict", "KEY")
        changed: dict[Any, dict[str, float]] = {}
        for name, value in changes.items():
            match = re.fullmatch(r"obs\.(\w+)\.(\w+(?:\[\d+\])?)", name)
            if match is None or match.group(1) not in named:
                raise UnknownParameterError(f"{owner}: {name!r} names no {word} of its {whose} observation; give "
                                            f"obs.{key_word}.KIND[i]=VALUE, {key_word} one of {', '.join(named)}")
            at = keys[named.index(match.group(1))]
            if isinstance(space[at], (gymnasium.spaces.Dict, gymnasium.spaces.Tuple)):
                raise UnknownParameterError(f"{owner}: {name!r} names a dict or a tuple in its {whose} observation; "
                                            f"sensor faults read the readings of a Box or of discrete values "
                                            f"{'in one of its parts' if parts else 'under one of its keys'}")
            changed.setdefault(at, {})[f"obs.{match.group(2)}"] = value
        faults = {at: SensorFaults.of(f"{owner} ({word} {at if parts else repr(at)})", space[at], key_changes)
                  for at, key_changes in changed.items()}
        kept = {f"obs.{at}.{name[len('obs.'):]}": value for at, key_faults in faults.items()
                for name, value in key_faults.changes.items()}
        return cls(kept, faults, keys, parts=parts)

    def begin_episode(self, seed: int | None, obs) -> None:
        """A new episode: each faulty key's (:meth:`SensorFaults.begin_episode`)."""
        for at, (faults, stream) in self._faults.items():
            faults.begin_episode(seed, obs[at], stream=stream)

    def read(self, obs, *, faulty: bool):
        """``obs`` as the sensors report it: itself before the fault (each faulty key's reading kept
        for a stuck sensor), each faulty key's readings through its faults after."""
        if not faulty:
            for at, (faults, _) in self._faults.items():
                faults.read(obs[at], faulty=False)
            return obs
        read = [(at, self._faults[at][0].read(value, faulty=True) if at in self._faults else value)
                for at, value in (enumerate(obs) if self._parts else obs.items())]
        return tuple(value for _, value in read) if self._parts else dict(read)


def _fault_value_problem(kind: str, value: Any, *, discrete: bool) -> str | None:
    """What is wrong with ``value`` for a sensor fault of ``kind`` (of discrete readings if
    ``discrete``), or ``None``."""
    if not is_finite_real(value):
        return "give a finite number"
    if kind == "stuck" and value not in (0, 1):
        return "stuck is 1 (held) or 0"
    if kind == "noise" and not discrete and value < 0:
        return "noise is a std, a finite number >= 0"
    if kind == "noise" and discrete and not 0 <= value <= 1:
        return "noise of discrete values is the probability of a misread, 0-1"
    if kind == "bias" and discrete and value != int(value):
        return "the bias of discrete values is a whole number"
    return None


def _discrete_values(space: gymnasium.Space) -> tuple[np.ndarray, np.ndarray] | None:
    """The lowest and highest value of each reading (flattened) of a ``Discrete``, ``MultiDiscrete``
    or ``MultiBinary`` space, or of a ``Tuple`` of ``Discrete`` spaces (one reading each); ``None``
    for any other."""
    if isinstance(space, gymnasium.spaces.Discrete):
        return np.array([space.start], np.int64), np.array([space.start + space.n - 1], np.int64)
    if isinstance(space, gymnasium.spaces.Tuple) and space.spaces and all(
            isinstance(part, gymnasium.spaces.Discrete) for part in space.spaces):
        low = np.array([part.start for part in space.spaces], np.int64)
        return low, low + np.array([part.n for part in space.spaces], np.int64) - 1
    if isinstance(space, gymnasium.spaces.MultiDiscrete):
        start = np.asarray(getattr(space, "start", 0), np.int64)
        low = np.broadcast_to(start, space.nvec.shape).reshape(-1)
        return low.copy(), low + space.nvec.reshape(-1).astype(np.int64) - 1
    if isinstance(space, gymnasium.spaces.MultiBinary):
        size = int(np.prod(space.shape))
        return np.zeros(size, np.int64), np.ones(size, np.int64)
    return None
