"""A policy oodmon cannot sample and did not train: any function ``obs -> action``.

A hand-written controller, a policy of another library (CleanRL, RLlib, your own torch code), a
rule set: oodmon runs it as it is and watches it with the learned detectors (``dynamics``, ``drift``
and their ``combined`` score), which need the observations and the actions it takes, nothing of its
insides::

    import oodmon
    monitor = oodmon.watch(my_policy, "CartPole-v1")          # fits, calibrates, returns the monitor
    agent = plain_agent(my_policy, "CartPole-v1", weights=net)  # a threshold bound to net's weights

A threshold records the policy's weights (``policy_hash``), so that one calibrated for another policy
is refused. Of a function oodmon knows no weights unless told: ``weights=`` (a torch module or a
dict of tensors or arrays) names them; a torch module, or a method of one, is hashed by its own
``state_dict()``; any other policy is bound by its name (``name:act``, its ``__qualname__``: the
same whether it was imported as ``my_controller`` or run as ``__main__``) and its code
(``code:...``, the hash of its source and of the values it reads:
:mod:`oodmon.agents.policy_code`), which tells an edit of its gains from the policy calibrated.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.agent import Agent, flattened
from oodmon.agents.policy_code import code_sha256
from oodmon.agents.sb3_spaces import space_parts, words_of
from oodmon.envs.checks import tensor_hint
from oodmon.errors import ConfigError
from oodmon.hashing import state_sha256
from oodmon.names import PLAIN_METHOD

__all__ = ["plain_agent", "plain_policy_hash", "policy_by_name", "weights_sha256"]


def plain_agent(policy: Callable[[Any], Any], env_id: str, *, weights: Any = None) -> Agent:
    """An :class:`~oodmon.agents.Agent` that acts by ``policy(obs)`` in the gymnasium env ``env_id``
    (its observations as the env gives them, its action as the env takes it). Dict observations
    reach the policy as dicts; the detectors and the logs read them flattened, as of an SB3
    ``MultiInputPolicy`` (:meth:`Agent.view`), a picture among them by the frames detector; text
    among them (MiniGrid's mission) the policy alone reads.

    The policy acts once on the env's first observation (seed 0), and the env takes that action,
    before any episode of a calibration runs: an action the env refuses is said now. A policy with
    a memory of the episode (a recurrent network's state) that has a ``begin_episode()`` method is
    told of each episode's start, in fitting, calibration and monitoring alike
    (:meth:`Agent.begin_episode`).

    Args:
        policy: the deployed policy, a function of one observation.
        env_id: the env it acts in (any registered id, ``module:Id`` too).
        weights: what the policy's decisions are made of, for the thresholds' ``policy_hash``: a
            torch module, or a mapping of names to tensors or arrays (default: the policy's own
            ``state_dict()`` when it is a torch module or a method of one, else none: the policy is
            then bound by its name and its code, ``name:<qualname> code:<hash>``).

    Raises:
        ConfigError: ``policy`` not callable, or an SB3 model or policy (give the model:
            :func:`~oodmon.agents.sb3.sb3_agent`); an env whose observations are neither arrays
            nor a dict of vectors and discrete values (pictures beside them too), as SB3 models',
            nor a tuple of vectors and discrete values
            (:func:`~oodmon.agents.sb3_spaces.dict_space_of`); an action the env refuses, or of another
            shape than its Box actions.

    Example:
        >>> agent = plain_agent(lambda obs: int(obs[2] + 0.5 * obs[3] > 0), "CartPole-v1")
        >>> agent.method, agent.task, agent.estimator, agent.act(np.zeros(4, np.float32))
        ('plain', 'cartpole', None, 0)
    """
    from oodmon.agents.dict_pictures import dict_pictures
    from oodmon.agents.sb3_spaces import dict_space_of
    from oodmon.envs.registration import make_env, task_of_env

    _check_callable(policy)
    name = _name_of(policy)
    env = make_env(env_id)
    try:
        # None: a Box; discrete values counted from any start, and dicts in dicts (gymnasium's flatten
        # reads them; SB3's extractor does not)
        dict_space = dict_space_of(env.observation_space, env_id, retrain="as your policy then sees them",
                                   plain=True)
        action_parts = _action_parts(env.action_space, env_id)  # None: one number or vector an action
        obs, _ = env.reset(seed=0)
        _check_first_action(policy(obs), name, env, env_id)
    finally:
        env.close()
    metadata = {"task": task_of_env(env_id) or env_id, "method": PLAIN_METHOD, "env_id": env_id, "policy": name,
                "policy_hash": plain_policy_hash(policy, weights)}
    if " code:" in metadata["policy_hash"]:
        metadata["name_hash"] = _name_hash(policy)  # what a threshold of it recorded before its code was hashed
    if dict_space is None:
        return Agent(None, metadata, None, policy, action_parts=action_parts)
    reads = (_ReadsWords(policy, dict_space, list(env.observation_space.spaces), name)
             if words_of(env.observation_space) else _ReadsDicts(policy, dict_space))
    return Agent(None, metadata, None, reads, dict_space=dict_space, pictures=dict_pictures(dict_space),
                 action_parts=action_parts)


class _ReadsDicts:
    """A plain policy of dict (or discrete) observations: the monitor, the detectors' fitting and
    the envs :meth:`Agent.wrap` makes hand on each one flattened (:meth:`Agent.view`); the policy
    gets it back as the env gave it."""

    def __init__(self, policy: Callable[[Any], Any], space: gymnasium.spaces.Space) -> None:
        self.policy, self.space = policy, space
        if hasattr(policy, "begin_episode"):  # a memory of the episode, told of each one's start (Agent.remembers)
            self.begin_episode = policy.begin_episode

    def __call__(self, obs: Any) -> Any:
        return self.policy(self.unflatten(obs) if flattened(self.space, obs) else obs)

    def unflatten(self, obs: Any) -> Any:
        """A flattened observation as the env gave it."""
        return gymnasium.spaces.unflatten(self.space, np.asarray(obs))


class _ReadsWords(_ReadsDicts):
    """A plain policy of dict observations with text beside the numbers (MiniGrid's mission): the
    detectors read the numbers flattened (``space``, the dict of the other keys), and each
    observation :meth:`Agent.view` flattens tells the policy its text (:meth:`tell_words`), which
    it gets back in the dict, in the env's order of ``keys``."""

    def __init__(self, policy: Callable[[Any], Any], space: gymnasium.spaces.Dict, keys: list[str], name: str) -> None:
        super().__init__(policy, space)
        self.keys, self.name = keys, name
        self.words: dict[str, Any] | None = None  # the text of the observation last flattened

    def tell_words(self, obs: Mapping[str, Any]) -> None:
        """The text of the observation that is flattened now (the next the policy acts on)."""
        self.words = {key: obs[key] for key in self.keys if key not in self.space.spaces}

    def unflatten(self, obs: Any) -> Any:
        if self.words is None:
            raise ConfigError(f"{self.name} reads the text of its observations, and this one came flattened: step the "
                              "env agent.wrap(env) gives, or hand the monitor the env's own dicts")
        numbers = super().unflatten(obs)
        return {key: numbers[key] if key in numbers else self.words[key] for key in self.keys}


#: What a module :func:`policy_by_name` does not find may want (the bench on a Ray cluster says otherwise).
ON_PYTHONPATH = " (is its folder on PYTHONPATH?)"


def policy_by_name(spec: str) -> Callable[[Any], Any]:
    """The policy ``MODULE:NAME`` names (``NAME`` may be dotted, ``my_policy:controller.act``):
    the command line's ``--policy``. The module is imported, so this runs its code: the user's own.

    Raises:
        ConfigError: no ``:``, a module Python does not find (a file of that name in the current
            folder, which the ``oodmon`` command does not search, is named), no such attribute,
            or a class (name an instance, or a function).
    """
    module_name, _, attribute = spec.partition(":") if isinstance(spec, str) else ("", "", "")
    if not module_name.strip() or not attribute.strip() or module_name.startswith("."):
        raise ConfigError(f"--policy {spec!r}: give MODULE:NAME, a function (or a callable object) NAME of your module "
                          "MODULE, e.g. --policy my_policy:act")
    try:
        found: Any = importlib.import_module(module_name)
    except (ImportError, TypeError, ValueError) as error:
        here = Path(module_name.replace(".", "/") + ".py")
        hint = (f"; {here} is in the current folder, which the oodmon command does not search: PYTHONPATH=. oodmon ..."
                if here.is_file() else ON_PYTHONPATH)
        raise ConfigError(f"--policy {spec}: {error}{hint}") from None
    for part in attribute.split("."):
        if not hasattr(found, part):
            raise ConfigError(f"--policy {spec}: {found.__name__ if hasattr(found, '__name__') else module_name} has no "
                              f"{part!r}")
        found = getattr(found, part)
    if inspect.isclass(found):
        raise ConfigError(f"--policy {spec}: {attribute} is a class, which would make a new object of each observation; "
                          "name an instance of it, or a function obs -> action")
    _check_callable(found, f"--policy {spec}")
    return found


def weights_sha256(weights: Any) -> str | None:
    """The sha256 of a torch module's ``state_dict()`` or of a mapping of names to tensors or
    arrays (:func:`oodmon.hashing.state_sha256`, as of an SB3 model in memory); ``None`` for ``None``.

    Example:
        >>> weights_sha256({"w": np.ones(3)}) == weights_sha256({"w": np.ones(3)}), weights_sha256(None)
        (True, None)
    """
    if weights is None:
        return None
    state = weights.state_dict() if callable(getattr(weights, "state_dict", None)) else weights
    if not isinstance(state, Mapping):
        raise ConfigError(f"weights={type(weights).__name__}: give a torch module or a dict of tensors or arrays")
    return state_sha256(state)


def plain_policy_hash(policy: Callable[[Any], Any], weights: Any = None) -> str:
    """What a threshold records of a plain policy (``policy_hash``): ``sha256:`` of ``weights``
    (:func:`weights_sha256`), else of the torch module the policy is or whose method it is, else
    ``name:<qualname> code:<sha256>``, the hash of its source and of the values it reads
    (:func:`~oodmon.agents.policy_code.code_sha256`, first 16 hex digits), else (Python keeps
    no source of it) ``name:<qualname>``.

    Example:
        >>> def act(obs):
        ...     return 0
        >>> plain_policy_hash(act).split()[0], plain_policy_hash(act, {"w": np.ones(3)}).startswith("sha256:")
        ('name:act', True)
    """
    digest = weights_sha256(weights if weights is not None else _own_weights(policy))
    if digest is not None:
        return "sha256:" + digest
    code = code_sha256(policy)
    return _name_hash(policy) if code is None else f"{_name_hash(policy)} code:{code[:16]}"


def _name_hash(policy: Callable[[Any], Any]) -> str:
    """``name:<qualname>``: what thresholds recorded of a plain policy without weights until
    2026-12-06 (the name alone), which such a policy's agent still accepts
    (:func:`~oodmon.monitor.monitor.policy_hash_aliases`)."""
    return f"name:{_qualname(policy)}"


def _own_weights(policy: Any) -> Any:
    """The torch module a policy is, or whose method it is; else ``None``."""
    import torch

    owner = getattr(policy, "__self__", policy)
    return owner if isinstance(owner, torch.nn.Module) else None


def _check_callable(policy: Any, what: str = "policy") -> None:
    """A plain policy is a function of one observation, not an SB3 model or an SB3 policy network."""
    kind = type(policy).__module__.split(".")[0]
    if kind in ("stable_baselines3", "sb3_contrib"):
        raise ConfigError(f"{what} is an SB3 {type(policy).__name__}: oodmon reads an SB3 model's networks, given the "
                          "model itself (oodmon.watch(model, env_id), not its policy) or its files (--sb3)")
    if not callable(policy):
        raise ConfigError(f"{what} is a {type(policy).__name__}, not a function obs -> action")


def _named(policy: Any) -> Any:
    """What names a policy: the function itself, or a callable object's class."""
    return policy if hasattr(policy, "__qualname__") else type(policy)


def _qualname(policy: Any) -> str:
    """A function's ``__qualname__``, or its class's (a callable object)."""
    return _named(policy).__qualname__


def _name_of(policy: Any) -> str:
    """How a policy is named in its errors and its logs' ``about.policy``: ``module.qualname``."""
    return f"{getattr(_named(policy), '__module__', '?')}.{_qualname(policy)}"


#: The action spaces whose actions oodmon's detectors and logs read as they are: a number or a vector of them.
_ACTION_SPACES = (gymnasium.spaces.Box, gymnasium.spaces.Discrete, gymnasium.spaces.MultiDiscrete,
                  gymnasium.spaces.MultiBinary)


def _action_parts(space: gymnasium.spaces.Space, env_id: str) -> gymnasium.spaces.Space | None:
    """``space`` when its actions are a ``Tuple`` or ``Dict`` of such (a parameterised action:
    which push, and how hard), or a ``Discrete`` counted from another start than 0, which the
    detectors and the logs read flattened (:attr:`~oodmon.agents.Agent.action_parts`; one-hot);
    ``None`` for any other of ``_ACTION_SPACES``.

    Raises:
        ConfigError: any other (a tuple inside the tuple, text), before any episode, saying how to
            flatten it. Before 2026-12-06 a tuple of actions was played through the fitting
            episodes and stopped at the fit (numpy's "inhomogeneous shape").
    """
    if isinstance(space, gymnasium.spaces.Discrete) and space.start:
        return space  # read one-hot (-1 of Discrete(3, start=-1) the first), not as an index from 0
    if isinstance(space, _ACTION_SPACES):
        return None
    parts = space_parts(space)
    if parts and all(isinstance(part, _ACTION_SPACES) for part in parts):
        return space
    raise ConfigError(f"{env_id}'s actions are {space}; oodmon's detectors and logs read an action of a Box, "
                      "Discrete, MultiDiscrete or MultiBinary space, or a tuple or dict of them: give oodmon an env "
                      "whose actions are one vector (a gymnasium.ActionWrapper whose action_space is "
                      "gymnasium.spaces.flatten_space(space) and whose action(a) returns "
                      "gymnasium.spaces.unflatten(space, a)) and a policy that returns that vector")


def _check_first_action(action: Any, name: str, env: gymnasium.Env, env_id: str) -> None:
    """The env takes ``action``, the policy's of its first observation, else :class:`ConfigError`."""
    space = env.action_space
    if isinstance(space, gymnasium.spaces.Box) and np.shape(action) != space.shape:  # Pendulum would take a[0]
        raise ConfigError(f"{name} returned {action!r} (shape {np.shape(action)}) for {env_id}'s first observation, "
                          f"whose actions are {space} (shape {space.shape})")
    try:
        env.step(action)
    except Exception as error:  # noqa: BLE001 (the env's own words, whatever it raises)
        raise ConfigError(f"{name} returned {action!r} for {env_id}'s first observation, which the env refused "
                          f"({type(error).__name__}: {error}); its actions are {space}{tensor_hint(action)}") from error
