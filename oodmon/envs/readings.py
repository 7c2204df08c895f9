"""The names of the readings of envs whose observation layout gymnasium documents, by index.

An alarm names the readings whose change the dynamics model predicted worst by their index in the
observation (:attr:`~oodmon.monitor.alarms.AlarmEvent.readings`, ``[2]``, as a sensor fault's spec
names them, ``obs.stuck[2]``); where the env is one of these, its line adds the reading's name
(``[2] (pole angle)``). oodmon's CartPole and Pendulum read as gymnasium's do. A dict observation,
read flattened, names its readings by its keys (:func:`flat_names`: ``[4] (velocity[1])``).
"""

from __future__ import annotations

import itertools
import math

import gymnasium

__all__ = ["READING_NAMES", "flat_names", "reading_label", "reading_names"]

#: Each env's readings by index (gymnasium 1.x's classic-control docs), by id without a namespace.
READING_NAMES: dict[str, tuple[str, ...]] = {
    "CartPole-v1": ("cart position", "cart velocity", "pole angle", "pole angular velocity"),
    "Pendulum-v1": ("cos of the angle", "sin of the angle", "angular velocity"),
    "Acrobot-v1": ("cos of joint 1's angle", "sin of joint 1's angle", "cos of joint 2's angle",
                   "sin of joint 2's angle", "joint 1's angular velocity", "joint 2's angular velocity"),
    "MountainCar-v0": ("car position", "car velocity"),
    "MountainCarContinuous-v0": ("car position", "car velocity"),
}
READING_NAMES["CartPole-v0"] = READING_NAMES["CartPole-v1"]


def reading_names(env_id: str | None) -> tuple[str, ...]:
    """The names of ``env_id``'s readings by index (``oodmon/CartPole-v1`` reads as
    ``CartPole-v1``); empty for an env whose layout is not listed here.

    Example:
        >>> reading_names("oodmon/CartPole-v1")[2], reading_names("my_envs:MyEnv-v0"), reading_names(None)
        ('pole angle', (), ())
    """
    if not isinstance(env_id, str):
        return ()
    return READING_NAMES.get(env_id.rpartition("/")[2], ())


def flat_names(space: gymnasium.spaces.Space, name: str = "") -> tuple[str, ...]:
    """The name of each number of ``space``'s observations flattened (``gymnasium.spaces.flatten``, as
    an agent reads a dict observation), in that order: a dict's by its keys (``velocity[1]``; a
    nested one's ``arm.velocity[1]``), a ``Discrete`` one-hot by the value each number stands for
    (``mode=2``; ``value=2`` of a ``Discrete`` observation), a tuple's by position (``0[1]``,
    ``arm.0``); empty where the space does not flatten so.

    Example:
        >>> from gymnasium.spaces import Box, Dict, Discrete
        >>> flat_names(Dict({"velocity": Box(-1, 1, (2,)), "mode": Discrete(2, start=1), "speed": Box(0, 1, (1,))}))
        ('mode=1', 'mode=2', 'speed', 'velocity[0]', 'velocity[1]')
        >>> from gymnasium.spaces import Tuple
        >>> flat_names(Tuple((Box(-1, 1, (2,)), Discrete(2))))
        ('0[0]', '0[1]', '1=0', '1=1')
    """
    spaces = gymnasium.spaces
    if isinstance(space, spaces.Dict):
        parts = [flat_names(child, f"{name}.{key}" if name else str(key)) for key, child in space.spaces.items()]
    elif isinstance(space, spaces.Tuple):
        parts = [flat_names(child, f"{name}.{k}" if name else str(k)) for k, child in enumerate(space.spaces)]
    elif isinstance(space, spaces.Discrete):
        parts = [tuple(f"{name or 'value'}={int(space.start) + k}" for k in range(int(space.n)))]
    elif isinstance(space, spaces.MultiDiscrete) and space.nvec.ndim == 1:
        parts = [tuple(f"{name}[{i}]={int(start) + k}" for k in range(int(n)))
                 for i, (n, start) in enumerate(zip(space.nvec, space.start))]
    elif isinstance(space, (spaces.Box, spaces.MultiBinary)) and space.shape is not None:
        shape = tuple(space.shape)
        if math.prod(shape) == 1:
            parts = [(name,)]
        else:
            parts = [tuple(f"{name}[{','.join(map(str, index))}]" for index in itertools.product(*map(range, shape)))]
    else:
        return ()
    if any(not part for part in parts):
        return ()
    names = tuple(n for part in parts for n in part)
    try:
        return names if len(names) == spaces.flatdim(space) else ()
    except (NotImplementedError, ValueError):
        return ()


def reading_label(index: int, name: str = "") -> str:
    """A reading as an alarm names it: its index, and its name where one is known.

    Example:
        >>> reading_label(2, "pole angle"), reading_label(5)
        ('[2] (pole angle)', '[5]')
    """
    return f"[{index}]" + (f" ({name})" if name else "")
