"""A loaded agent: its estimator, its metadata, and the policy it deploys.

``oodmon.agents.load("cartpole", "ensemble")`` loads a shipped agent from the zoo inside the
package; :func:`load_agent` loads one from any directory written by training.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.dict_pictures import DictPictures
from oodmon.agents.estimators import Estimate, UncertaintyEstimator
from oodmon.agents.frame_stack import Stacking
from oodmon.agents.networks import estimator_for
from oodmon.agents.serialization import load_modules
from oodmon.errors import ConfigError, InvalidParameterError, ModelFormatError, UnknownParameterError
from oodmon.validation import is_real

__all__ = ["Agent", "agent_from_modules", "flattened", "load", "load_agent", "zoo_dir", "zoo_names"]


@dataclass
class Agent:
    """An uncertainty-aware policy, or a policy someone else trained (:mod:`oodmon.agents.sb3`).

    Attributes:
        estimator: computes the deployed action and the K samples behind it; ``None`` for a plain
            policy with nothing to sample (one SB3 model), which only learned detectors can watch.
        metadata: the model's JSON metadata (task, method, training, ID return, versions; for
            models from elsewhere, their files, hashes and env id).
        path: where the model was loaded from (``None`` for an agent built in memory).
        deploy: the deployed policy ``obs -> action`` when it is not the estimator's decision
            (the first of several SB3 models, as deployed, while the ensemble only scores).
        dict_space: the env's observation space when its observations are dicts (an SB3
            ``MultiInputPolicy``) or discrete values (``Discrete``, ``MultiDiscrete``,
            ``MultiBinary``): the agent, the detectors and the logs see each one flattened (one-hot),
            as :meth:`view` makes it (the policy gets the env's back, see :mod:`oodmon.agents.sb3`);
            of a dict with text that a plain policy reads (:attr:`reads_words`), the other keys.
        stacking: the model was trained inside SB3's ``VecFrameStack``: it acts on observations
            stacked as that stacks them (:class:`~oodmon.agents.frame_stack.Stacking`), in the envs
            :meth:`wrap` makes so; the detectors and the logs read the env's own, the newest of
            each stack (:meth:`own_observation`).
        pictures: the dict observations hold pictures beside vectors
            (:class:`~oodmon.agents.dict_pictures.DictPictures`): the policy gets the whole dict,
            the detectors and the logs read the vector keys (:meth:`own_observation`), and the
            frames detector and the logs the first picture.
        action_parts: the env's action space when its actions are a ``Tuple`` or ``Dict`` of
            vectors and discrete values (a plain policy's parameterised action: which push, and
            how hard), or a ``Discrete`` counted from another start than 0: the env and the policy
            deal in those, the detectors and the logs read each one flattened (:meth:`read_action`;
            a ``Discrete`` one-hot).
    """

    estimator: UncertaintyEstimator | None
    metadata: dict[str, Any]
    path: Path | None = None
    deploy: Callable[[np.ndarray], Any] | None = None
    dict_space: gymnasium.spaces.Space | None = None
    stacking: Stacking | None = None
    pictures: DictPictures | None = None
    action_parts: gymnasium.spaces.Space | None = None

    @property
    def task(self) -> str:
        """oodmon's task name, or for a model of another env, that env's id."""
        return self.metadata["task"]

    @property
    def method(self) -> str:
        return self.metadata["method"]

    @property
    def env_id(self) -> str | None:
        """The gymnasium env id the model was loaded for (``None``: the task's own oodmon env)."""
        return self.metadata.get("env_id")

    def estimate(self, obs: np.ndarray) -> Estimate:
        """The deployed action and the K samples for one observation or a batch."""
        if self.estimator is None:
            raise ConfigError(f"{self!r} has no samples to estimate from (a plain policy); it acts with act()")
        return self.estimator.estimate(obs)

    def act(self, obs: np.ndarray) -> int | np.ndarray:
        """The deployed action for one observation: an int (DQN) or an action array (DDPG)."""
        if self.deploy is not None:
            return self.deploy(obs)
        action = self.estimator.estimate(obs).action[0]
        return int(action) if self.estimator.kind == "q_values" else action

    def begin_episode(self) -> None:
        """An episode begins: a policy with a memory of the episode (a RecurrentPPO's LSTM state)
        forgets the last one. The envs :meth:`wrap` makes call it at each reset, the monitor and the
        detectors' fitting at each episode's start; nothing for any other policy."""
        begin = getattr(self.deploy, "begin_episode", None)
        if begin is not None:
            begin()

    @property
    def remembers(self) -> bool:
        """Whether the deployed policy carries a memory from step to step (:meth:`begin_episode`)."""
        return hasattr(self.deploy, "begin_episode")

    @property
    def reads_masks(self) -> bool:
        """Whether the deployed policy decides among the actions the env's action masks allow
        (sb3-contrib's MaskablePPO): the envs :meth:`wrap` makes, the monitor and the detectors'
        fitting tell it each step's (:meth:`tell_masks`)."""
        return hasattr(self.deploy, "tell_masks")

    def twin(self) -> Agent:
        """This agent for another env stepped beside its own (a vector env's): the same networks and
        metadata, and for a policy that reads its env beside the observation (:attr:`remembers`,
        :attr:`reads_masks`, :attr:`reads_words`) a memory, masks and text of its own; the agent
        itself for any other."""
        if not (self.remembers or self.reads_masks or self.reads_words):
            return self
        return dataclasses.replace(self, deploy=copy.copy(self.deploy))

    def tell_masks(self, env: gymnasium.Env) -> None:
        """Give a policy that reads action masks (:attr:`reads_masks`) those ``env`` allows now, by its
        ``action_masks()`` (sb3-contrib's ``ActionMasker`` wrapper, or the env's own method).

        Raises:
            ConfigError: the env has no ``action_masks()``.
        """
        if not self.reads_masks:
            return
        try:
            action_masks = env.get_wrapper_attr("action_masks")
        except AttributeError:
            raise ConfigError(f"{self.task}/{self.method} decides among the actions the env's action masks allow, and "
                              f"this env has no action_masks(): wrap it as in training "
                              "(sb3_contrib.common.wrappers.ActionMasker(env, mask_fn))") from None
        self.deploy.tell_masks(np.asarray(action_masks(), dtype=bool))

    def view(self, obs: Any) -> Any:
        """The observation as the agent, the detectors and the logs read it: a dict observation
        flattened (``gymnasium.spaces.flatten`` over :attr:`dict_space`, the order the policy's
        ``CombinedExtractor`` concatenates its keys in), a discrete one one-hot; any other as it is."""
        if self.dict_space is not None and not flattened(self.dict_space, obs):
            if self.reads_words:
                self.deploy.tell_words(obs)
            return gymnasium.spaces.flatten(self.dict_space, obs)
        return obs

    @property
    def reads_words(self) -> bool:
        """Whether the deployed policy reads text of its dict observations that the detectors do not
        (a plain policy's, MiniGrid's mission: :func:`~oodmon.agents.sb3_spaces.words_of`): each
        observation :meth:`view` flattens tells it the text, which it reads beside the numbers."""
        return hasattr(self.deploy, "tell_words")

    def read_action(self, action: Any) -> Any:
        """The action as the detectors and the logs read it: one of :attr:`action_parts` flattened
        (``gymnasium.spaces.flatten``: a ``Discrete`` part one-hot, a ``Box`` part's numbers), any
        other as it is.

        Example:
            >>> space = gymnasium.spaces.Tuple((gymnasium.spaces.Discrete(2), gymnasium.spaces.Box(0, 1, (1,))))
            >>> Agent(None, {}, action_parts=space).read_action((1, np.array([0.5], np.float32))).tolist()
            [0.0, 1.0, 0.5]
        """
        if self.action_parts is None:
            return action
        return gymnasium.spaces.flatten(self.action_parts, action).astype(np.float32)

    @property
    def frame_stack(self) -> int | None:
        """The depth of the VecFrameStack the model was trained inside, or ``None``."""
        return None if self.stacking is None else self.stacking.n

    @property
    def reads_own(self) -> bool:
        """Whether the detectors read less than the agent acts on (:meth:`own_observation`)."""
        return self.stacking is not None or self.pictures is not None

    @property
    def own_shape(self) -> tuple[int, ...] | None:
        """The shape of what the detectors read, where they read less than the agent acts on."""
        if self.pictures is not None:
            return self.pictures.own_shape
        return None if self.stacking is None else self.stacking.own_shape

    def own_observation(self, obs: Any) -> Any:
        """What the detectors read and the logs keep of ``obs``, the observation the agent acts on:
        the env's own, the newest of a stack (:attr:`stacking`); of a dict with pictures, its
        vectors (:attr:`pictures`); any other as it is."""
        if self.stacking is not None:
            obs = self.stacking.newest(obs)
        return obs if self.pictures is None else self.pictures.vectors(obs)

    def dict_reading_names(self) -> tuple[str, ...]:
        """The name of each number the detectors read of a dict observation, by its index there
        (an alarm's readings name them): the dict's keys and positions as it flattens
        (:func:`~oodmon.envs.readings.flat_names`), of its vector keys alone where it holds pictures
        (:meth:`own_observation`); none of a stack of dicts, nor of an observation not a dict.

        Example:
            >>> space = gymnasium.spaces.Dict({"camera": gymnasium.spaces.Box(0, 255, (2, 2, 1), np.uint8),
            ...                                "speed": gymnasium.spaces.Box(-1, 1, (2,))})
            >>> from oodmon.agents.dict_pictures import dict_pictures
            >>> Agent(None, {}, dict_space=space, pictures=dict_pictures(space)).dict_reading_names()
            ('speed[0]', 'speed[1]')
        """
        from oodmon.envs.readings import flat_names

        if self.dict_space is None or self.stacking is not None:
            return ()
        names = flat_names(self.dict_space)
        if self.pictures is None or not names:
            return names
        return tuple(names[k] for k in self.pictures.positions)

    def wrap(self, env: gymnasium.Env) -> gymnasium.Env:
        """``env`` (the gymnasium env of the agent's env id, or an oodmon variant of it) giving the
        observations the agent acts on: stacked :attr:`frame_stack` deep as SB3's VecFrameStack
        stacks them (:class:`~oodmon.agents.frame_stack.FrameStack`; a dict key by key), and dict
        and discrete ones flattened (``FlattenObservation``, as :meth:`view`; their text told to a
        policy that reads it, :attr:`reads_words`), and for a policy with a memory
        (:attr:`remembers`) or one that reads action masks (:attr:`reads_masks`) telling it of each
        reset (:meth:`begin_episode`) and each step's masks (:meth:`tell_masks`); ``env`` itself for
        any other agent."""
        if self.remembers or self.reads_masks:
            env = _TellsPolicy(env, self)
        if self.stacking is not None:
            from oodmon.agents.frame_stack import FrameStack

            env = FrameStack(env, self.stacking.n, "first" if self.stacking.channels_first else "last", self.stacking.pad)
        if self.reads_words:  # the numbers flattened, the text told to the policy (view)
            flat = gymnasium.spaces.flatten_space(self.dict_space)
            env = gymnasium.wrappers.TransformObservation(env, self.view, flat)
        elif self.dict_space is not None:
            env = gymnasium.wrappers.FlattenObservation(env)
        return env

    def check_noise(self, obs_noise: float) -> str | None:
        """The oodmon task whose env plays sensor noise ``obs_noise`` for this agent (``None``: no
        noise), checked without making an env: what :meth:`make_env` would refuse, said before the
        first episode of a calibration, a validation or a run.

        Raises:
            ConfigError: noise for an env oodmon has no variants of, or for Pong (whose env read
                it as a corruption's parameter before 2026-12-05).
            InvalidParameterError: noise outside [0, 10].
        """
        from oodmon.envs.grid import ENV_IDS
        from oodmon.envs.physics import PHYSICS_DEFAULTS, check_obs_noise
        from oodmon.envs.registration import task_of_env

        if not is_real(obs_noise):  # ('' is no noise to an `if not`, and failed later as a float)
            raise InvalidParameterError(f"obs_noise={obs_noise!r} is not allowed; it is the sensor noise's std as a "
                                        "fraction of each observation dimension's ID spread, a number in [0, 10] "
                                        "(0: none)")
        if obs_noise == 0:
            return None
        task = self.task if self.env_id is None else task_of_env(self.env_id)  # oodmon's env of that task
        if task is None:
            raise ConfigError(f"obs_noise (--obs-noise) is an option of oodmon's envs; {self.env_id} has no such "
                              f"option: a noisy sensor of your own env is the sensor fault {self.env_id}:obs.noise=STD "
                              "(--variant, --onset 0), whose episodes count as shifted ones")
        if task not in PHYSICS_DEFAULTS:
            raise ConfigError(f"obs_noise (--obs-noise) is sensor noise of oodmon's {' and '.join(PHYSICS_DEFAULTS)} "
                              f"envs; {task} has none: its variants corrupt the frames instead "
                              f"(`oodmon envs --task {task}`), and its ID world is noiseless")
        check_obs_noise(ENV_IDS[task], obs_noise)
        return task

    def make_env(self, obs_noise: float = 0.0, *, max_steps: int | None = None) -> gymnasium.Env:
        """The ID env this agent acts in: its task's oodmon env, or the gymnasium env id it was
        loaded for (``gymnasium.make(env_id)``; sensor noise is oodmon's envs' option only, see
        :meth:`check_noise`), with the agent's observations (:meth:`wrap`). ``max_steps``: its
        episodes' time limit instead of the env's own (gymnasium's ``max_episode_steps``)."""
        from oodmon.envs.grid import Variant
        from oodmon.envs.registration import make_env

        limit = {} if max_steps is None else {"max_episode_steps": max_steps}
        noisy = self.check_noise(obs_noise)
        if noisy is not None:
            return Variant(noisy).make(obs_noise=obs_noise, **limit)
        if self.env_id is not None:
            return self.wrap(make_env(self.env_id, **limit))  # the user's own env, exactly as they deploy in it
        return Variant(self.task).make(**limit)

    def __repr__(self) -> str:
        ret = self.metadata.get("id_return_mean")
        k = "none (plain policy)" if self.estimator is None else self.estimator.n_samples
        masks = getattr(self.estimator, "masks", None)
        masks = {"fixed": ", fixed masks", "fixed-decisions": ", fixed masks deciding"}.get(masks, "")
        return f"Agent({self.task}, {self.method}, K={k}{masks}, id_return_mean={ret}, path={self.path})"


def flattened(space: gymnasium.spaces.Space, obs: Any) -> bool:
    """Whether ``obs``, an observation of ``space`` (an Agent's :attr:`~Agent.dict_space`), is
    flattened already (:meth:`Agent.view`): not a dict (a tuple), or not of the space's own shape.

    Example:
        >>> lake = gymnasium.spaces.Discrete(16)
        >>> flattened(lake, 3), flattened(lake, gymnasium.spaces.flatten(lake, 3))
        (False, True)
    """
    if isinstance(space, gymnasium.spaces.Dict):
        return not isinstance(obs, Mapping)
    if isinstance(space, gymnasium.spaces.Tuple):
        return not isinstance(obs, tuple)
    return np.shape(obs) != space.shape


def load_agent(directory: str | Path, *, task: str | None = None, n_samples: int | None = None,
               seed: int | None = None, masks: str | None = None) -> Agent:
    """Load an agent saved by training (``model.json`` + ``model.safetensors``).

    Args:
        directory: the model's directory.
        task: if given, refuse another task's model.
        n_samples: MC samples per decision (default: the recipe's); ignored by ensembles.
        seed: seeds MC sampling (see :class:`~oodmon.agents.estimators.MCEstimator`).
        masks: ``"sampled"``, ``"fixed"`` or ``"fixed-decisions"`` MC masks (default: the model's ``masks``, else
            sampled; see :class:`~oodmon.agents.estimators.MCEstimator`); ignored by ensembles.

    Raises:
        ModelFormatError: a missing, damaged or mismatched model (see ``serialization``).
    """
    modules, metadata = load_modules(directory, task=task)
    return agent_from_modules(modules, metadata, directory, n_samples=n_samples, seed=seed, masks=masks)


def agent_from_modules(modules: Any, metadata: dict[str, Any], directory: str | Path, *, n_samples: int | None = None,
                       seed: int | None = None, masks: str | None = None) -> Agent:
    """The agent of modules and metadata as :func:`~oodmon.agents.serialization.load_modules` gives
    them (its architecture, MC samples and action bounds read from the metadata), loaded from
    ``directory``. :func:`load_agent` is this after ``load_modules``; call it yourself to change
    the modules first (an experiment's other drop probability, say: the estimator compiles them).
    """
    estimator = estimator_for(
        modules, metadata["architecture"], seed=seed,
        n_samples=metadata.get("n_samples", 20) if n_samples is None else n_samples,
        action_low=metadata.get("action_low"), action_high=metadata.get("action_high"),
        masks=masks or metadata.get("masks", "sampled"),
    )
    return Agent(estimator, metadata, Path(directory))


def zoo_dir() -> Path:
    """The folder of the shipped zoo inside the installed package."""
    return Path(str(resources.files("oodmon") / "zoo"))


def zoo_names() -> list[str]:
    """The shipped agents as ``task-method`` names, e.g. ``cartpole-ensemble``."""
    root = zoo_dir()
    return sorted(p.name for p in root.iterdir() if (p / "model.json").is_file()) if root.is_dir() else []


class _TellsPolicy(gymnasium.Wrapper):
    """Tells the agent's policy what it needs of the env it acts in beside the observation: each
    reset (:meth:`Agent.begin_episode`, a memory forgotten) and the action masks after each reset and
    step (:meth:`Agent.tell_masks`)."""

    def __init__(self, env: gymnasium.Env, agent: Agent) -> None:
        super().__init__(env)
        self._agent = agent

    def reset(self, **kwargs: Any):
        self._agent.begin_episode()
        result = self.env.reset(**kwargs)
        self._agent.tell_masks(self.env)
        return result

    def step(self, action: Any):
        result = self.env.step(action)
        self._agent.tell_masks(self.env)
        return result


def load(task: str, method: str, *, n_samples: int | None = None, seed: int | None = None,
         masks: str | None = None) -> Agent:
    """Load a shipped agent by task and method.

    Raises:
        UnknownParameterError: no shipped agent of that name; the message lists those there are.

    Example:
        >>> agent = load("cartpole", "ensemble")
        >>> agent.act(np.zeros(4, np.float32))
        0
    """
    name = f"{task}-{method}"
    directory = zoo_dir() / name
    if not (directory / "model.json").is_file():
        shipped = ", ".join(zoo_names()) or "none yet"
        raise UnknownParameterError(f"no shipped agent {name!r}; the zoo has: {shipped}")
    try:
        return load_agent(directory, task=task, n_samples=n_samples, seed=seed, masks=masks)
    except ModelFormatError as error:
        raise ModelFormatError(f"the shipped agent {name!r} is damaged: {error}") from None
