"""Your own stable-baselines3 models as an oodmon :class:`~oodmon.agents.Agent`.

``load_sb3(["a.zip", "b.zip"], "CartPole-v1")`` gives an agent the monitor, the calibration and
the detectors' fitting take like a shipped one:

- it **acts as deployed**: the first model's ``predict(obs, deterministic=True)``, never an
  average the user did not deploy (``mean=True`` deploys the ensemble's mean instead);
- one model has no samples to spread: the learned detectors (``dynamics``, and ``combined``)
  watch it, unless it has dropout or DropConnect layers (MC samples, ``masks="fixed"`` for K
  sub-networks drawn once; ``"fixed-decisions"`` reads the same K in one pass, the model's own
  ``predict()`` deciding either way); several DQN, several DDPG/TD3, or several SAC models (their
  deterministic actions) are also an ensemble whose spread and features are detectors
  (:func:`~oodmon.agents.networks.estimator_from_sb3`). One SAC model, and PPO and A2C, are watched
  by the learned detectors only. sb3-contrib's QR-DQN, TQC, TRPO, ARS, CrossQ, RecurrentPPO and
  MaskablePPO models load too (``pip install 'oodmon[contrib]'``), one model as a plain policy;
  several TQC models are an ensemble as SAC models are (their actor is SAC's), several QR-DQN
  models as DQN models are (of their quantiles' means); a RecurrentPPO decides with its LSTM's state carried
  through each episode, a MaskablePPO among the actions each step's action masks allow
  (:mod:`oodmon.agents.sb3_deployed`);
- its metadata record each model's path and sha256, the algorithm and the env id; its policy hash
  (what thresholds and fitted detectors are checked against) is the hash of the policies'
  parameters (and of the VecNormalize statistics' numbers), the same for a model loaded from its
  file, saved again, or trained in this process; ``files_hash``, the hash of the files, is what
  thresholds and detectors made before 2026-12-04 recorded, and still fits.

Loading goes through SB3's own ``load``, which would unpickle parts of the ``.zip`` (running any
code a crafted file holds): oodmon reads those parts first through a restricted unpickler and
hands them to it, so it unpickles nothing (:mod:`oodmon.agents.sb3_pickles`; ``imports`` names
the user's modules whose classes a file may name; ``unsafe_load_pickles=True`` is SB3's own
``load``). The algorithm is read from the zip's ``data`` JSON before that.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium

from oodmon.agents.agent import Agent
from oodmon.agents.dict_pictures import dict_pictures
from oodmon.agents.sb3_deployed import deployed_model
from oodmon.agents.sb3_pickles import data_objects, import_modules
from oodmon.agents.sb3_spaces import check_model_spaces, dict_space_of
from oodmon.agents.vec_normalize import (
    NO_NORMALIZATION,
    ObservationNormalizer,
    load_vec_normalize,
    normalizer_of,
    trained_in_vec_normalize,
)
from oodmon.errors import ConfigError
from oodmon.hashing import file_sha256, state_sha256

__all__ = ["SB3_ALGORITHMS", "SB3_CONTRIB_ALGORITHMS", "SB3_HYPERPARAMETERS", "dict_space_of", "load_sb3", "models_sha256",
           "sb3_agent", "sb3_algorithm", "sb3_file"]

#: SB3's policy modules and the algorithm classes that load them (first match that loads wins:
#: A2C and PPO share a policy class; DDPG's policy is TD3's and loads as TD3 for acting).
SB3_ALGORITHMS = {
    "stable_baselines3.dqn.policies": ("DQN",),
    "stable_baselines3.td3.policies": ("TD3", "DDPG"),
    "stable_baselines3.sac.policies": ("SAC",),
    "stable_baselines3.common.policies": ("PPO", "A2C"),
}


#: sb3-contrib's algorithms oodmon loads (``pip install 'oodmon[contrib]'``), by policy module: one
#: model is a plain policy, acting by its own ``predict(obs, deterministic=True)`` and watched by the
#: learned detectors; several TQC or QR-DQN models are an ensemble (see the module's docstring).
#: TRPO's policy is SB3's own actor-critic: told by the hyperparameters it saves
#: (:data:`SB3_HYPERPARAMETERS`).
SB3_CONTRIB_ALGORITHMS = {
    "sb3_contrib.common.recurrent.policies": ("RecurrentPPO",),  # its LSTM's state carried: RecurrentDeployedModel
    "sb3_contrib.common.maskable.policies": ("MaskablePPO",),  # the env's action masks given: MaskableDeployedModel
    "sb3_contrib.qrdqn.policies": ("QRDQN",),
    "sb3_contrib.tqc.policies": ("TQC",),
    "sb3_contrib.ars.policies": ("ARS",),
    "sb3_contrib.crossq.policies": ("CrossQ",),
}


#: A policy class of the user's own (a subclass of an SB3 policy, to add dropout, say) lives in the
#: user's module; the algorithm is then told by the hyperparameters only it saves in ``data``
#: (checked on SB3 2.9: each key below is saved by these algorithms and by no other of the six).
SB3_HYPERPARAMETERS = (
    ("cg_max_steps", ("TRPO",)),  # sb3-contrib's TRPO, whose policy module is SB3's own (before PPO's keys)
    ("exploration_fraction", ("DQN",)),
    ("target_entropy", ("SAC",)),
    ("policy_delay", ("TD3", "DDPG")),
    ("clip_range", ("PPO",)),
    ("vf_coef", ("A2C", "PPO")),  # after clip_range: PPO saves both
)


def sb3_file(path: str | Path) -> Path:
    """The model file ``path`` names, as SB3's own ``load`` finds it: ``model.save("runs/dqn")``
    writes ``runs/dqn.zip``, and ``DQN.load("runs/dqn")`` reads it; so does oodmon, where
    ``runs/dqn`` itself is no file. Anything else is left as given (a missing file is said where it is read).

    Example:
        >>> sb3_file("runs/no-such-model")
        PosixPath('runs/no-such-model')
    """
    path = Path(path)
    if not path.name:  # "", ".", "/": no file's name, and no name to add .zip to
        return path
    zipped = path.with_name(path.name + ".zip")
    # os.path's tests: a name the system refuses (too long, say) is no file, not an OSError
    return zipped if not os.path.exists(path) and path.suffix != ".zip" and os.path.isfile(zipped) else path


def sb3_algorithm(path: str | Path) -> tuple[str, ...]:
    """The SB3 algorithm classes that can load the model file ``path``, read from its ``data``
    JSON without loading (unpickling) anything: from the policy class's module, or, for a policy
    class of the user's own, from the hyperparameters the algorithm saved (:data:`SB3_HYPERPARAMETERS`).

    Raises:
        ConfigError: a missing file, or one that is not an SB3 model of a supported algorithm.
    """
    path = sb3_file(path)
    return _algorithms(_data(path), path)


def _algorithms(data: dict[str, Any], path: Path) -> tuple[str, ...]:
    """:func:`sb3_algorithm` of the model file's ``data``, read already."""
    module = data["policy_class"]["__module__"]
    if module == "stable_baselines3.common.policies" and "cg_max_steps" in data:
        return ("TRPO",)
    if module in SB3_ALGORITHMS or module in SB3_CONTRIB_ALGORITHMS:
        return (SB3_ALGORITHMS | SB3_CONTRIB_ALGORITHMS)[module]
    if module.split(".")[0] in ("stable_baselines3", "sb3_contrib"):  # their other algorithms
        raise ConfigError(f"{path} holds a policy of {module}; oodmon loads {ALGORITHMS_LOADED} models")
    algorithms = next((names for key, names in SB3_HYPERPARAMETERS if key in data), None)
    if algorithms is None:
        raise ConfigError(f"{path} holds a policy of {module}, and none of the hyperparameters DQN, DDPG, TD3, SAC, "
                          "PPO, A2C or TRPO save: a policy class of your own is loaded for those algorithms only")
    return algorithms


def _data(path: Path) -> dict[str, Any]:
    """The model file's ``data`` JSON, parsed (nothing unpickled).

    Raises:
        ConfigError: a missing file, or one that is not an SB3 model (no ``data`` naming a policy class).
    """
    if os.path.isdir(path):
        raise ConfigError(f"{path} is a folder; an SB3 model is the .zip file that model.save() wrote")
    if not os.path.isfile(path):
        either = "" if path.suffix == ".zip" else f"; {path.name}.zip is not there either"
        raise ConfigError(f"{path} does not exist (an SB3 model is the .zip that model.save() wrote{either})")
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
        if not isinstance(data["policy_class"]["__module__"], str):
            raise TypeError("the policy class's module is no name")
    except (zipfile.BadZipFile, KeyError, TypeError, ValueError):
        raise ConfigError(f"{path} is not a stable-baselines3 model file (a .zip with a 'data' entry naming its "
                          "policy class)") from None
    return data


#: What :func:`sb3_algorithm` takes, in words.
ALGORITHMS_LOADED = ("stable-baselines3's DQN, DDPG, TD3, SAC, PPO and A2C, and sb3-contrib's QR-DQN, TQC, TRPO, ARS, "
                     "CrossQ, RecurrentPPO and MaskablePPO")


def _algorithm_class(name: str) -> type:
    """The class that loads algorithm ``name``'s files: stable-baselines3's, else sb3-contrib's.

    Raises:
        ConfigError: an sb3-contrib algorithm where sb3-contrib is not installed.
    """
    import stable_baselines3

    if hasattr(stable_baselines3, name):
        return getattr(stable_baselines3, name)
    try:
        import sb3_contrib
    except ImportError:
        raise ConfigError(f"a {name} model is loaded by sb3-contrib, which is not installed: pip install sb3-contrib "
                          "(or 'oodmon[contrib]')") from None
    return getattr(sb3_contrib, name)


def _policy_base(name: str) -> type | None:
    """The SB3 policy class every policy of algorithm ``name`` derives from (a user's own class too);
    ``None`` for sb3-contrib's, told by their own policy module."""
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.dqn.policies import DQNPolicy
    from stable_baselines3.sac.policies import SACPolicy
    from stable_baselines3.td3.policies import TD3Policy

    return {"DQN": DQNPolicy, "TD3": TD3Policy, "DDPG": TD3Policy, "SAC": SACPolicy, "PPO": ActorCriticPolicy,
            "A2C": ActorCriticPolicy}.get(name)


def _load_one(path: Path, unsafe_load_pickles: bool = False) -> tuple[Any, str]:
    errors, data = [], _data(path)
    for name in _algorithms(data, path):
        algorithm = _algorithm_class(name)
        try:
            # custom_objects: every entry SB3 would unpickle, read by oodmon without running code
            # (None: SB3 unpickles them itself, as its own load() does)
            objects = None if unsafe_load_pickles else data_objects(data, algorithm, path)
            with _optimizers_built_without_dynamo():
                model = algorithm.load(path, device="cpu", custom_objects=objects)
        except ConfigError:
            raise  # sb3-contrib not installed, or an entry refused: said as it is
        except Exception as error:  # noqa: BLE001  (the next class of the same policy may load it)
            errors.append(f"{name}: {error}")
            continue
        base = _policy_base(name)
        if base is not None and not isinstance(model.policy, base):  # another algorithm's, told by its hyperparameters
            errors.append(f"{name}: its policy {type(model.policy).__name__} is no {base.__name__}")
            continue
        return model, name
    raise ConfigError(f"stable-baselines3 could not load {path}: {'; '.join(errors)}")


@contextmanager
def _optimizers_built_without_dynamo() -> Iterator[None]:
    """For the time of an SB3 ``load``: torch's optimizers built and loaded without importing
    ``torch._dynamo``, which took 1.1 s of each ``--sb3`` command's start (2026-11-30; nearly the
    whole of loading a small model).

    Four methods of ``torch.optim.Optimizer`` (``add_param_group``, ``load_state_dict``,
    ``state_dict``, ``zero_grad``) are wrapped by ``torch._disable_dynamo``, whose first call
    imports ``torch._dynamo`` to build the method's dynamo-disabled function and keeps it on the
    method's own function as ``__dynamo_disable``. SB3's load builds every optimizer of the model
    and loads its state, optimizers oodmon never steps and nothing compiles; meanwhile each
    method's own function stands in as its disabled one. The stand-ins are taken away after, so a
    later call disables dynamo as torch does (a user's training in the same process). A torch
    whose optimizers are wrapped otherwise is left as it is (and imports dynamo as before)."""
    import torch
    from torch.optim import Optimizer

    disable = getattr(torch, "_disable_dynamo", None)
    wrapper = None if disable is None else disable(lambda: None).__code__  # the code of every method it wraps
    stood_in = []
    for member in vars(Optimizer).values():
        function = getattr(member, "__wrapped__", None)
        if wrapper is not None and getattr(member, "__code__", None) is wrapper and function is not None \
                and not hasattr(function, "__dynamo_disable"):
            setattr(function, "__dynamo_disable", function)
            stood_in.append(function)
    try:
        yield
    finally:
        for function in stood_in:
            delattr(function, "__dynamo_disable")


def load_sb3(paths: Sequence[str | Path], env_id: str, *, mean: bool = False, n_samples: int = 20,
             seed: int | None = None, masks: str | None = None, vec_normalize: Any = None,
             frame_stack: int | None = None, imports: Sequence[str] = (), unsafe_load_pickles: bool = False) -> Agent:
    """An :class:`~oodmon.agents.Agent` of the SB3 model files in ``paths``, acting in ``env_id``.

    Args:
        paths: SB3 ``.zip`` files; the first is the deployed policy.
        env_id: any registered gymnasium env id (oodmon's or not) the models act in.
        mean: deploy the ensemble's mean decision instead of the first model's (several DQN or
            DDPG/TD3 models only).
        n_samples, seed: MC sampling of one model that has dropout layers.
        masks: that model's MC masks, ``sampled`` (None: the default) or ``fixed``.
        vec_normalize: models trained inside SB3's ``VecNormalize``: the statistics file it saved
            (``vec_normalize.save(path)``), read without running code from it
            (:func:`~oodmon.agents.vec_normalize.load_vec_normalize`); the models then see every
            observation normalised as in training (or a VecNormalize in memory, as
            :func:`sb3_agent` takes it). ``"none"``: they were, but it did not normalise
            observations (``norm_obs=False``).
        frame_stack: models trained inside SB3's ``VecFrameStack``: its ``n_stack``; the models then
            see the env's observations stacked as it stacks them
            (:class:`~oodmon.agents.frame_stack.FrameStack`); the detectors and the logs read the
            env's own, the newest of each stack (``Agent.own_observation``). With ``vec_normalize``
            statistics of one observation, not of the stack, the models were trained inside
            ``VecFrameStack(VecNormalize(venv))`` (rl-baselines3-zoo's order): each observation of
            the stack is normalised, and the statistics' mean stands before an episode's first,
            where VecFrameStack put normalised zeros (vector observations).
        imports: modules to import first (yours, e.g. ``["my_policy"]``): the classes of your own
            a file names (a policy class, a features extractor) are then found; oodmon imports no
            module a file names.
        unsafe_load_pickles: load the files as SB3's own ``load`` does, unpickling their data,
            which runs any code a file holds: only for files you trust. By default oodmon reads
            that data without running code (:mod:`oodmon.agents.sb3_pickles`) and refuses a file
            whose policy class, its keyword arguments or spaces name anything else.

    Raises:
        ConfigError: no paths, a file that is not an SB3 model, one whose data names what oodmon
            does not load (see ``unsafe_load_pickles``), spaces that do not match the env,
            ``mean`` without an ensemble, fixed masks without one model to sample, a PPO or A2C
            model trained inside VecNormalize without ``vec_normalize``, or statistics of another
            observation shape.
    """
    if isinstance(paths, (str, Path)) or not paths:
        raise ConfigError("give one or more SB3 model files (a list of paths)")
    paths = [sb3_file(p) for p in paths]
    for path in paths:
        sb3_algorithm(path)  # every file checked before any is unpickled
    if vec_normalize is None:
        normalized = [path for path in paths if trained_in_vec_normalize(path)]
        if normalized:
            raise ConfigError(f"{normalized[0]} was trained inside VecNormalize: it acts on normalised observations, and "
                              "on the env's own it acts as another policy. Give the statistics VecNormalize.save() "
                              "wrote (--vec-normalize vecnormalize.pkl; read without running code from it), or --vec-normalize "
                              "none if that VecNormalize did not normalise observations (norm_obs=False)")
    normalizer = None if vec_normalize is None else _normalizer_of(vec_normalize, [])  # said before any unpickling
    import_modules(imports)
    loaded = [_load_one(path, unsafe_load_pickles) for path in paths]
    files = [{"path": str(path.resolve()), "sha256": file_sha256(path), "algorithm": name}
             for path, (_, name) in zip(paths, loaded)]
    return sb3_agent([model for model, _ in loaded], env_id, mean=mean, n_samples=n_samples, seed=seed, files=files,
                     masks=masks, vec_normalize=normalizer or NO_NORMALIZATION, frame_stack=frame_stack)


def models_sha256(hashes: Sequence[str], *, mean: bool = False) -> str:
    """The one sha256 that stands for a set of SB3 models (each given by its own sha256): the
    model's own for one, else the hash of them all in order and of ``mean`` (the deployed policy).

    Example:
        >>> models_sha256(["ab"]), len(models_sha256(["ab", "cd"]))
        ('ab', 64)
    """
    if len(hashes) == 1:
        return hashes[0]
    return hashlib.sha256(("\n".join(hashes) + ("\nmean" if mean else "")).encode()).hexdigest()


def _normalizer_of(vec_normalize: Any, models: Sequence[Any]) -> ObservationNormalizer | None:
    """The observation statistics the models see (see :func:`sb3_agent`'s ``vec_normalize``)."""
    if vec_normalize is None:  # models in memory keep the VecNormalize they were trained in
        envs = [getattr(m, "get_vec_normalize_env", lambda: None)() for m in models]
        found = {n.sha256: n for n in (normalizer_of(e) for e in envs if e is not None)}
        if len(found) > 1 or (found and None in envs):
            raise ConfigError("the models were trained inside different VecNormalize envs (or some inside none): oodmon "
                              "gives every model the same observations; give vec_normalize= to choose their statistics")
        return next(iter(found.values()), None)
    if isinstance(vec_normalize, str) and vec_normalize == NO_NORMALIZATION:
        return None
    if isinstance(vec_normalize, ObservationNormalizer):
        return vec_normalize
    if isinstance(vec_normalize, (str, Path)):
        return load_vec_normalize(vec_normalize)
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(vec_normalize, VecNormalize):
        return normalizer_of(vec_normalize)
    raise ConfigError(f"vec_normalize={vec_normalize!r}: give a VecNormalize, its saved statistics file, or 'none'")


def _frame_stack_of(models: Sequence[Any]) -> int | None:
    """The ``n_stack`` of the ``VecFrameStack`` models in memory were trained inside (``None``: none).

    Raises:
        ConfigError: models trained inside different ones (or some inside none).
    """
    from stable_baselines3.common.vec_env import VecEnvWrapper, VecFrameStack

    depths = set()
    for model in models:
        env, depth = getattr(model, "get_env", lambda: None)(), None
        while isinstance(env, VecEnvWrapper):
            if isinstance(env, VecFrameStack):
                depth = env.stacked_obs.n_stack
                break
            env = env.venv
        depths.add(depth)
    if len(depths) > 1:
        raise ConfigError("the models were trained inside different VecFrameStack envs (or some inside none): oodmon "
                          "gives every model the same observations; give frame_stack= to choose their depth")
    return depths.pop()


def _parameters_sha256(model: Any) -> str:
    """The hash of a model's policy's parameters: what it decides by, whether it was loaded from a
    file (whose bytes change each time SB3 saves the same model) or trained in this process."""
    return state_sha256(model.policy.state_dict())


def sb3_agent(models: Sequence[Any], env_id: str, *, mean: bool = False, n_samples: int = 20,
              seed: int | None = None, files: Sequence[dict[str, str]] | None = None,
              masks: str | None = None, vec_normalize: Any = None, frame_stack: int | None = None) -> Agent:
    """An :class:`~oodmon.agents.Agent` of SB3 models already loaded (or trained) in this process;
    the first is the deployed policy. ``files``: each model's path, sha256 and algorithm, when they
    came from files (:func:`load_sb3`); else they are described by the hash of their parameters.
    ``masks``: the MC masks of one model with dropout or DropConnect layers (see :func:`load_sb3`).
    ``vec_normalize``: the observation statistics of models trained inside SB3's ``VecNormalize``:
    that VecNormalize, its saved file, an
    :class:`~oodmon.agents.vec_normalize.ObservationNormalizer`, or ``"none"``; ``None`` (the
    default): the VecNormalize the models in memory were trained in, if any
    (``model.get_vec_normalize_env()``, its statistics as they are now). The deployed policy and
    the samples see normalised observations; the learned detectors and the logs the env's own.
    ``frame_stack``: the ``n_stack`` of the ``VecFrameStack`` the models were trained inside (see
    :func:`load_sb3`); ``None`` (the default): for models in memory, that of the VecFrameStack they
    were trained in, if any.

    Raises:
        ConfigError: no models, spaces that do not match the env, observations that are neither
            an array nor a dict of vectors (the agent reads those flattened: ``Agent.view``; the
            policy gets them as dicts; pictures beside the vectors go to the frames detector and
            the log: :mod:`oodmon.agents.dict_pictures`), several models or fixed masks of a dict
            with pictures, ``mean`` without an ensemble, fixed masks without one DQN or DDPG/TD3
            model with dropout or DropConnect layers, or statistics of another shape than the
            observations (or different ones for different models).
    """
    from oodmon.envs.registration import make_env, task_of_env

    if not models or not all(hasattr(m, "policy") and hasattr(m, "predict") for m in models):
        raise ConfigError(f"give one or more stable-baselines3 models ({ALGORITHMS_LOADED})")
    if frame_stack is None and files is None:  # models in memory: the VecFrameStack they were trained in, if any
        frame_stack = _frame_stack_of(models)
    weights = [_parameters_sha256(m) for m in models]
    if files is None:
        files = [{"path": "(in memory)", "sha256": w, "algorithm": type(m).__name__} for m, w in zip(models, weights)]
    env = make_env(env_id)
    normalizer = _normalizer_of(vec_normalize, models)
    stacking = None
    if frame_stack is not None:  # the observations the models act on
        from oodmon.agents.frame_stack import FrameStack, check_frame_stack

        frame_stack, pad = check_frame_stack(frame_stack), None
        if normalizer is not None and normalizer.shape is not None and normalizer.shape == env.observation_space.shape:
            # statistics of one observation: normalised, then stacked (VecFrameStack(VecNormalize(venv)))
            pad = normalizer.mean.astype(env.observation_space.dtype)  # normalised: VecFrameStack's zeros
            normalizer = normalizer.stacked(frame_stack)
        env = FrameStack(env, frame_stack, pad=pad)
        stacking = env.stacking
    for model, file in zip(models, files):
        check_model_spaces(model, Path(file["path"]), env, env_id, frame_stack)
    env.close()
    dict_space = dict_space_of(env.observation_space, env_id)
    if normalizer is not None:
        normalizer = _normalizer_for_env(normalizer, env, env_id, dict_space, models[0])
    names = {file["algorithm"] for file in files}
    masks = masks or "sampled"
    # TQC's actor is SAC's; QR-DQN's Q-values are its quantiles' means
    sampled = names in ({"DQN"}, {"TD3"}, {"DDPG"}, {"TD3", "DDPG"}, {"SAC"}, {"TQC"}, {"QRDQN"})
    if len(models) > 1 and not sampled:  # the others were ignored in silence
        got = ", ".join(file["algorithm"] for file in files)
        raise ConfigError(f"several models form an ensemble, whose spread oodmon reads from DQN, DDPG/TD3, SAC, TQC or "
                          f"QR-DQN models, all of one algorithm; got {got}: give the deployed model alone (the learned "
                          "detectors watch it)")
    if masks != "sampled" and (len(models) > 1 or not sampled):
        raise ConfigError(f"masks={masks!r} is for one DQN, DDPG/TD3 or SAC model with dropout or DropConnect layers (MC "
                          f"samples); got {len(models)} {'/'.join(sorted(names))} model(s)")
    pictures = None if dict_space is None else dict_pictures(dict_space)
    if pictures is not None and (len(models) > 1 or masks != "sampled"):
        raise ConfigError(f"{env_id}'s observations hold pictures ({pictures.picture_key!r}), which the models read "
                          "through a CNN, and oodmon samples no CNN (no ensemble spread, no masks): give the deployed "
                          "model alone (the learned detectors watch it: dynamics the dict's vectors, frames its picture)")
    # PPO, A2C, sb3-contrib's: networks oodmon does not sample; the learned detectors watch them
    estimator = _estimator_of(models, n_samples, seed, masks) if sampled and pictures is None else None
    if mean and estimator is None:
        raise ConfigError("--mean deploys the ensemble's mean: give several DQN, DDPG/TD3, SAC, TQC or QR-DQN models "
                          "(of one algorithm)")
    if estimator is not None:
        estimator.observation_transform = normalizer
    metadata = {
        "task": task_of_env(env_id) or env_id,
        "method": "sb3",
        "algorithm": files[0]["algorithm"].lower(),
        "env_id": env_id,
        "deployed": "ensemble mean" if mean else f"{files[0]['path']} (the first model)",
        "models": list(files),
    } | _hashes(weights, files, normalizer, mean) \
        | ({} if normalizer is None else {"vec_normalize": normalizer.describe()}) \
        | ({} if frame_stack is None else {"frame_stack": frame_stack})
    discrete = isinstance(models[0].action_space, gymnasium.spaces.Discrete)
    deployed = deployed_model(models[0], files[0]["algorithm"], discrete, normalizer, dict_space)
    return Agent(estimator, metadata, None, None if mean else deployed,
                 dict_space=dict_space, stacking=stacking, pictures=pictures)


def _hashes(weights: Sequence[str], files: Sequence[dict[str, str]], normalizer: Any, mean: bool) -> dict[str, str]:
    """The agent's ``policy_hash``: of its models' parameters (``weights``) and its statistics'
    numbers, whether they came from files or from memory (a threshold of the raw-observation policy
    refuses one with statistics: they count as weights); and, of models from files, ``files_hash``,
    of the files, which thresholds, detectors and logs recorded as ``policy_hash`` before 2026-12-04."""
    statistics = [] if normalizer is None else [normalizer.numbers_sha256 or normalizer.sha256]
    combined = models_sha256([*weights, *statistics], mean=mean)
    of_files = models_sha256([file["sha256"] for file in files] + ([] if normalizer is None else [normalizer.sha256]),
                             mean=mean)
    return {"policy_hash": "sha256:" + combined} | ({} if of_files == combined else {"files_hash": "sha256:" + of_files})


def _normalizer_for_env(normalizer: Any, env: gymnasium.Env, env_id: str, dict_space: Any, model: Any) -> Any:
    """``normalizer``'s statistics as the agent applies them to ``env_id``'s observations (a dict's
    flattened like its vectors), checked against the env's and the deployed ``model``'s observations.

    Raises:
        ConfigError: statistics of dict observations for an env of arrays or the other way, or of
            another shape than the observations.
    """
    where = f" in {normalizer.path}" if normalizer.path else ""
    if (dict_space is not None) != (normalizer.keys is not None):
        raise ConfigError(f"the VecNormalize statistics{where} are of "
                          f"{'dict' if normalizer.keys is not None else 'array'} observations; {env_id}'s are "
                          f"{env.observation_space}: statistics of another env?")
    if dict_space is not None:
        try:
            normalizer = normalizer.flattened(dict_space)
        except ConfigError as error:
            raise ConfigError(f"{env_id}: {error}") from None
    if normalizer.shape is not None and normalizer.shape not in (env.observation_space.shape, model.observation_space.shape):
        raise ConfigError(f"the VecNormalize statistics{where} are of observations of shape {normalizer.shape}; "
                          f"{env_id}'s are {env.observation_space.shape}: statistics of another env?")
    return normalizer


def _estimator_of(models: Sequence[Any], n_samples: int, seed: int | None, masks: str) -> Any:
    """The estimator of the models' samples (an ensemble's, or one model's MC samples), or ``None``
    for one model without dropout or DropConnect (nothing to sample).

    Raises:
        ConfigError: several models that cannot form an ensemble, or fixed masks of a model with no
            dropout or DropConnect layer.
    """
    from oodmon.agents.networks import estimator_from_sb3

    try:
        return estimator_from_sb3(list(models), n_samples=n_samples, seed=seed, masks=masks)
    except ConfigError as error:
        if len(models) > 1:  # an ensemble asked for (it was dropped in silence: no spread, no features)
            raise ConfigError(f"the {len(models)} models cannot form the ensemble whose spread would watch the first: "
                              f"{error}; give the deployed model alone (the learned detectors watch it)") from None
        if masks != "sampled":
            raise ConfigError(f"masks={masks!r} fixes the masks of MC samples, and this model has none: {error}") \
                from None
        return None
