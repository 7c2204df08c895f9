"""Whether a stable-baselines3 model fits the env it is deployed in, and how oodmon reads the env's
observation space.

- :func:`check_model_spaces`: the model's observation and action spaces against the env's (a
  model of another env is refused), allowing SB3's own moving of an image's channels first and
  naming the ``VecFrameStack`` depth a model trained inside one needs.
- :func:`dict_space_of`: the space oodmon unflattens observations into for the policy, for a dict
  of vectors and discrete values or discrete values alone (``None`` for an array), refusing the
  spaces oodmon's detectors cannot read.

Split from :mod:`oodmon.agents.sb3`, which uses both for the models it loads;
:mod:`oodmon.agents.plain` uses :func:`dict_space_of` for a policy of any kind.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.dict_pictures import is_picture_space
from oodmon.envs.checks import space_mismatch
from oodmon.errors import ConfigError

__all__ = ["check_model_spaces", "dict_space_of", "space_parts", "words_of"]


def check_model_spaces(model: Any, path: Path, env: gymnasium.Env, env_id: str, frame_stack: int | None = None) -> None:
    """Refuse ``model`` (loaded from ``path``) whose observation or action space is not the one of
    ``env`` (``env_id``'s, stacked ``frame_stack`` deep where the model was trained inside
    ``VecFrameStack``).

    Raises:
        ConfigError: naming the space, the model's and the env's, and the ``--frame-stack`` a
            stacked model needs.
    """
    what = space_mismatch(env, model)
    if what == "observation_space" and _transposed_image(env.observation_space, model.observation_space):
        what = space_mismatch(env, model, spaces=("action_space",))  # SB3's own (H, W, C) -> (C, H, W)
    if what is not None:
        ours = f"{env_id}'s, stacked {frame_stack} deep," if frame_stack else f"{env_id} has"
        hint = ""
        if what == "observation_space" and frame_stack is None:
            depth = _stack_depth(env.observation_space, model.observation_space)
            hint = (f" Or trained inside VecFrameStack({depth})? Give --frame-stack {depth} (frame_stack={depth})"
                    if depth else "")
        name = "the model in memory" if str(path) == "(in memory)" else str(path)  # (it read "(in memory) was ...")
        raise ConfigError(f"{name} was trained with the {what} {getattr(model, what)}; {ours} "
                          f"{getattr(env, what)}: a model of another env?{hint}")


def _stack_depth(env_space: Any, model_space: Any) -> int | None:
    """The n_stack of a VecFrameStack that makes ``env_space`` into ``model_space`` (along the last
    axis, or the first: channels-first images, and SB3's own transposition of channels-last ones),
    or ``None``."""
    if isinstance(env_space, gymnasium.spaces.Dict) and isinstance(model_space, gymnasium.spaces.Dict):
        if env_space.spaces.keys() != model_space.spaces.keys():
            return None  # a dict of vectors is stacked key by key: one depth for every key
        depths = {_stack_depth(env_space[key], model_space[key]) for key in env_space.spaces}
        return depths.pop() if len(depths) == 1 else None
    if not isinstance(env_space, gymnasium.spaces.Box) or not isinstance(model_space, gymnasium.spaces.Box):
        return None
    env_shape, shape = env_space.shape, model_space.shape
    if len(env_shape) != len(shape) or not env_shape:
        return None
    candidates = [(shape[-1], env_shape[-1], shape[:-1] == env_shape[:-1]),
                  (shape[0], env_shape[0], shape[1:] == env_shape[1:])]
    if len(env_shape) == 3:  # channels last, stacked on them, then moved first by SB3
        candidates.append((shape[0], env_shape[2], shape[1:] == env_shape[:2]))
    for stacked, own, rest in candidates:
        if rest and own and stacked % own == 0 and stacked // own >= 2:
            return stacked // own
    return None


def _transposed_image(env_space: Any, model_space: Any) -> bool:
    """Whether ``model_space`` is ``env_space``, an image with channels last, with its channels moved
    first, as SB3 stores a model trained on such an env (``VecTransposeImage``; its ``predict`` takes
    the env's images as they come); of a dict, each such image key so and the other keys the same."""
    from stable_baselines3.common.preprocessing import is_image_space

    if isinstance(env_space, gymnasium.spaces.Dict) and isinstance(model_space, gymnasium.spaces.Dict):
        return env_space.spaces.keys() == model_space.spaces.keys() and all(
            model_space[key] == sub or _transposed_image(sub, model_space[key]) for key, sub in env_space.spaces.items())
    if not isinstance(env_space, gymnasium.spaces.Box) or not isinstance(model_space, gymnasium.spaces.Box):
        return False
    shape = env_space.shape
    return (is_image_space(env_space) and len(shape) == 3
            and model_space.shape == (shape[2], shape[0], shape[1]))


def dict_space_of(space: Any, env_id: str, *, retrain: str = "and train the model on that",
                  plain: bool = False) -> gymnasium.spaces.Space | None:
    """``space`` when it is a dict of vectors and discrete values (an SB3 ``MultiInputPolicy``'s,
    which concatenates them flattened, discrete ones one-hot, as ``gymnasium.spaces.flatten``
    does), with pictures beside them or not (:mod:`oodmon.agents.dict_pictures`), or discrete
    values alone (``Discrete`` counted from 0, ``MultiDiscrete``, ``MultiBinary``: FrozenLake's
    cell, which SB3 reads one-hot too; a ``Tuple`` of them, Blackjack's hand, or of them and
    vectors, for a plain policy); ``None`` for an array space. ``plain`` (a plain policy's):
    discrete values counted from any start too, which gymnasium's one-hot reads and SB3's does not,
    dicts and tuples of vectors and discrete values inside the dict or tuple, and text beside them
    in a dict (:func:`words_of`: MiniGrid's mission), which the policy reads and the detectors do
    not: the dict of the other keys is returned.

    Raises:
        ConfigError: any other space (nested spaces inside a dict or a tuple, a dict of pictures
            alone, a tuple with a picture, text but for a plain policy's in a dict), saying to
            flatten the env's observations (to leave text out), ``retrain``.

    Example:
        >>> from gymnasium.spaces import Box, Discrete
        >>> dict_space_of(Box(-1.0, 1.0, (4,)), "CartPole-v1") is None, dict_space_of(Discrete(500), "Taxi-v3")
        (True, Discrete(500))
    """
    from stable_baselines3.common.preprocessing import is_image_space

    if isinstance(space, gymnasium.spaces.Box):
        return None
    if space_parts(space) is None and _flat_as_sb3(space, is_image_space, plain):  # discrete values, one-hot
        return space
    if isinstance(space, gymnasium.spaces.Tuple) and space.spaces and all(
            _flat_as_sb3(sub, is_image_space, plain) for sub in space.spaces):
        return space  # a tuple of them and vectors (Blackjack's hand): SB3 trains on none, a plain policy gets it back
    words = words_of(space)
    if isinstance(space, gymnasium.spaces.Dict):
        # a plain policy gets the text, the detectors read the rest (the dict dict_space_of returns)
        numbers = {key: sub for key, sub in space.spaces.items() if not (plain and key in words)}
        vectors = [sub for sub in numbers.values() if not is_picture_space(sub)]  # and discrete values
        if vectors and all(_flat_as_sb3(sub, is_image_space, plain) for sub in vectors):
            return gymnasium.spaces.Dict(numbers) if len(numbers) < len(space.spaces) else space
        if numbers and not vectors:
            raise ConfigError(f"{env_id}'s observations are {space}: pictures alone, in a dict. oodmon's detectors read "
                              "a dict's vectors (dynamics) and its first picture beside them (frames); for pictures "
                              "alone, give the env's picture as its observation (a Box), which the frames detector reads")
    kept = [key for key in space.spaces if key not in words] if words else None
    if kept == []:
        raise ConfigError(f"{env_id}'s observations are {space}: text alone, which oodmon's detectors do not read "
                          "(they read numbers: vectors, discrete values, pictures)")
    if kept and not plain:
        raise ConfigError(f"{env_id}'s observations are {space}; its text ({', '.join(map(repr, words))}) is no number "
                          "SB3 or oodmon's detectors read: leave it out, gymnasium.wrappers.FilterObservation(env, "
                          f"{kept!r}), {retrain}, to watch it (a policy of any kind, --policy or oodmon.watch(policy, "
                          "env_id), gets the text, and the detectors read the rest)")
    flatten = "FlattenObservation" if not kept else f"FlattenObservation(FilterObservation(env, {kept!r}))"
    raise ConfigError(f"{env_id}'s observations are {space}; oodmon's detectors read array observations (a gymnasium "
                      "Box: a vector, or stacked image frames), discrete values"
                      f"{'' if plain else ' (counted from 0)'}, or a dict of vectors "
                      f"and discrete values (pictures{' and text' if plain else ''} beside them too): wrap the env in "
                      f"gymnasium.wrappers.{flatten}, {retrain}, to watch it")


def words_of(space: Any) -> tuple[str, ...]:
    """The keys of a ``Dict`` space whose values are text (``gymnasium.spaces.Text``, MiniGrid's
    ``MissionSpace``: any space of strings), in the dict's order; ``()`` for any other space.

    Example:
        >>> from gymnasium.spaces import Box, Dict, Text
        >>> words_of(Dict(mission=Text(40), position=Box(0, 1))), words_of(Box(0, 1))
        (('mission',), ())
    """
    if not isinstance(space, gymnasium.spaces.Dict):
        return ()
    return tuple(key for key, sub in space.spaces.items()
                 if sub.dtype is not None and np.dtype(sub.dtype).kind == "U")


def space_parts(space: Any) -> list | None:
    """The spaces inside a ``Dict`` (in its keys' order) or a ``Tuple``; ``None`` for any other space.

    Example:
        >>> from gymnasium.spaces import Box, Dict, Discrete, Tuple
        >>> space_parts(Tuple((Discrete(2), Box(0, 1)))), space_parts(Dict(a=Discrete(3))), space_parts(Discrete(2))
        ([Discrete(2), Box(0.0, 1.0, (1,), float32)], [Discrete(3)], None)
    """
    if isinstance(space, gymnasium.spaces.Dict):
        return list(space.spaces.values())
    if isinstance(space, gymnasium.spaces.Tuple):
        return list(space.spaces)
    return None


def _flat_as_sb3(space: Any, is_image_space: Any, plain: bool = False) -> bool:
    """Whether gymnasium flattens a dict's ``space`` into the numbers SB3's ``CombinedExtractor``
    reads of it: a vector (not an image), a binary vector, or discrete values counted from 0
    (one-hot; SB3 ignores ``start``, gymnasium does not). ``plain``, for a policy of any kind,
    which gymnasium's flattening alone reads: counted from any start too, and dicts and tuples of
    such inside (SB3's extractor takes none)."""
    spaces = gymnasium.spaces
    parts = space_parts(space)
    if plain and parts is not None:
        return bool(parts) and all(_flat_as_sb3(part, is_image_space, plain) for part in parts)
    if isinstance(space, spaces.Box):
        return not is_image_space(space, check_channels=False)
    if isinstance(space, spaces.Discrete):
        return plain or int(space.start) == 0
    if isinstance(space, spaces.MultiDiscrete):
        return np.ndim(space.nvec) == 1 and (plain or not np.any(space.start))
    return isinstance(space, spaces.MultiBinary) and np.ndim(space.n) == 0
