"""The observation statistics of an SB3 model trained inside ``VecNormalize``, read without running code.

A policy trained in ``VecNormalize(env, norm_obs=True)`` acts on normalised observations,
``clip((obs - mean) / sqrt(var + epsilon), -clip_obs, clip_obs)``, with the running statistics
SB3 saves beside the model (``vec_normalize.save("vecnormalize.pkl")``). Fed the env's raw
observations it acts as another policy: a PPO that keeps CartPole's pole up for 500 steps with
them, measured, lasts 78 without. oodmon's monitor must deploy it as it is deployed.

A dict observation (a ``MultiInputPolicy``'s) is normalised key by key, those VecNormalize
was told to (``norm_obs_keys``; by default every key), the others passed as they are; oodmon's
detectors read such a dict flattened, and :meth:`ObservationNormalizer.flattened` gives the same
normalisation of the flattened vector.

SB3's ``VecNormalize.load`` unpickles the file, which can run any code. :func:`load_vec_normalize`
reads it with an unpickler that calls nothing but numpy's array and dtype constructors (and
``OrderedDict``, a dict observation's container), and
builds every other object the file names (``VecNormalize``, ``RunningMeanStd``, the gymnasium
spaces, numpy's random generators) as an inert record of its state, never as the class itself;
a file that names anything else is refused, unread (Python's "Restricting Globals",
docs.python.org/3/library/pickle.html).

Example:
    >>> import numpy as np
    >>> normalizer = ObservationNormalizer(np.array([1.0, 0.0]), np.array([4.0, 1.0]), clip_obs=10.0)
    >>> normalizer(np.array([3.0, 20.0], np.float32)).tolist()
    [1.0, 10.0]
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle  # restricted below: find_class allows numpy's array constructors and OrderedDict only
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.agents.pickle_walk import one_line, walk_opcodes
from oodmon.errors import ConfigError
from oodmon.validation import not_a_file

__all__ = ["NO_NORMALIZATION", "ObservationNormalizer", "load_vec_normalize", "normalizer_of", "trained_in_vec_normalize"]

#: ``--vec-normalize none``: the model was trained inside VecNormalize, which did not normalise
#: its observations (``norm_obs=False``).
NO_NORMALIZATION = "none"

#: The only callables a statistics file may reach: numpy's array, dtype and scalar constructors
#: (numpy 2 names them ``numpy._core``, numpy 1 ``numpy.core``), and ``OrderedDict``, the container
#: of a dict observation's spaces (built empty, then filled with items: it runs nothing of the file's).
_CALLED = {(module, name) for module in ("numpy._core.multiarray", "numpy.core.multiarray")
           for name in ("_reconstruct", "scalar")} | {("numpy", "ndarray"), ("numpy", "dtype"),
                                                      ("collections", "OrderedDict")}

#: Modules whose names a statistics file holds and oodmon builds as inert records, not as themselves.
_RECORDED = ("stable_baselines3.common.vec_env.vec_normalize", "stable_baselines3.common.running_mean_std",
             "gymnasium.spaces.", "numpy.random.")


class _Record:
    """Stands for any class or function of :data:`_RECORDED` a statistics file names: called, it
    gives a record that keeps the state the file sets, and runs nothing."""

    state: Any = None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        self.state = state


class _StatisticsUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _CALLED:
            return super().find_class(module, name)
        if module.startswith(_RECORDED) or module in (m.rstrip(".") for m in _RECORDED):
            return _Record
        raise pickle.UnpicklingError(f"it names {module}.{name}, which a VecNormalize file does not hold")


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class ObservationNormalizer:
    """What ``VecNormalize`` does to an observation before its policy sees it.

    Attributes:
        mean, var: the running mean and variance of the observations seen in training, each of
            the observation's shape; ``None``: observations are not normalised (``norm_obs=False``).
            For dict observations, once :meth:`flattened`: those of the normalised keys' numbers, in
            the flattened vector's order.
        epsilon: added to ``var`` before its square root (SB3's default 1e-8).
        clip_obs: normalised observations are clipped to [-clip_obs, clip_obs].
        sha256: the hash of where the statistics came from: the file's, or of the numbers for
            statistics in memory.
        path: the file the statistics were read from (``None``: in memory).
        keys: dict observations: the normalised keys' ``(mean, var)`` (the other keys pass as they
            are); ``None`` for array observations.
        positions: once :meth:`flattened`, where the normalised keys' numbers sit in the flattened
            vector (``mean`` and ``var`` are theirs).
        frames: once :meth:`stacked`, how many observations side by side the statistics of one
            normalise (``mean`` and ``var`` repeated as many times); ``None``: not stacked.
        numbers_sha256: the hash of the numbers as read (before :meth:`flattened` or
            :meth:`stacked`), the same whether they came from a file or from memory: it binds
            thresholds and detectors to these statistics ("": ``sha256`` does).
    """

    mean: np.ndarray | None
    var: np.ndarray | None
    epsilon: float = 1e-8
    clip_obs: float = 10.0
    sha256: str = ""
    path: str | None = None
    keys: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    positions: np.ndarray | None = None
    frames: int | None = None
    numbers_sha256: str = ""

    def __call__(self, obs: np.ndarray | dict[str, np.ndarray]) -> np.ndarray | dict[str, np.ndarray]:
        """``obs`` (one observation or a batch; a dict one, or a dict flattened once :meth:`flattened`)
        as the policy saw observations in training (normalised numbers float32)."""
        if isinstance(obs, dict):
            if self.keys is None:
                raise ConfigError("these VecNormalize statistics are of array observations, not of dicts")
            return obs | {key: self._normalised(obs[key], mean, var) for key, (mean, var) in self.keys.items()}
        if self.keys is not None and self.positions is None:
            raise ConfigError("these VecNormalize statistics are of dict observations: flattened(dict_space) reads "
                              "the flattened vectors")
        if self.mean is None:
            return obs
        if self.positions is None:
            return self._normalised(obs, self.mean, self.var)
        out = np.array(obs, np.float32)  # a copy: the other keys' numbers as they are
        out[..., self.positions] = self._normalised(out[..., self.positions], self.mean, self.var)
        return out

    def _normalised(self, obs: np.ndarray, mean: np.ndarray, var: np.ndarray) -> np.ndarray:
        normalised = (np.asarray(obs, np.float64) - mean) / np.sqrt(var + self.epsilon)
        return np.clip(normalised, -self.clip_obs, self.clip_obs).astype(np.float32)

    def flattened(self, dict_space: Any) -> ObservationNormalizer:
        """These statistics of dict observations, for the vectors ``gymnasium.spaces.flatten`` makes of
        ``dict_space``'s dicts (what oodmon's detectors and estimators read; the dicts themselves
        are still normalised key by key).

        Raises:
            ConfigError: a normalised key the space lacks, is not a vector of, or holds another
                shape of (statistics of another env).
        """
        import gymnasium

        if self.keys is None:
            raise ConfigError("these VecNormalize statistics are of array observations, not of dicts")
        missing = sorted(set(self.keys) - set(dict_space.spaces))
        if missing:
            raise ConfigError(f"the VecNormalize statistics normalise the keys {missing}, which the observations "
                              f"{dict_space} lack: statistics of another env?")
        means, variances, positions, start = [], [], [], 0
        for key, space in dict_space.spaces.items():
            size = gymnasium.spaces.flatdim(space)
            if key in self.keys:
                mean, var = self.keys[key]
                if not isinstance(space, gymnasium.spaces.Box) or mean.shape != space.shape:
                    raise ConfigError(f"the VecNormalize statistics of key {key!r} are of shape {mean.shape}; the "
                                      f"observations' {key!r} is {space}: statistics of another env?")
                means.append(mean.ravel())
                variances.append(var.ravel())
                positions.append(np.arange(start, start + size))
            start += size
        if not positions:  # no key normalised
            return replace(self, mean=None, var=None, positions=np.zeros(0, np.int64))
        return replace(self, mean=np.concatenate(means), var=np.concatenate(variances),
                       positions=np.concatenate(positions))

    def stacked(self, n_stack: int) -> ObservationNormalizer:
        """These statistics of one vector observation, for ``n_stack`` of them side by side: a model
        trained inside ``VecFrameStack(VecNormalize(venv), n_stack)`` (rl-baselines3-zoo's order)
        saw each observation normalised, then stacked, with zeros before an episode's first
        observation, which :class:`~oodmon.agents.frame_stack.FrameStack` stands the mean in (its
        ``pad``; normalised: zero, up to the float32 rounding of the mean, ~1e-8).

        Raises:
            ConfigError: statistics of dict observations, or of other observations than vectors.

        Example:
            >>> one = ObservationNormalizer(np.array([1.0, 0.0]), np.array([4.0, 1.0]))
            >>> one.stacked(2)(np.array([1.0, 0.0, 3.0, 2.0], np.float32)).tolist()
            [0.0, 0.0, 1.0, 2.0]
        """
        if self.keys is not None or self.mean is None or self.mean.ndim != 1:
            raise ConfigError("oodmon stacks normalised observations (VecFrameStack(VecNormalize(env))) of vector envs "
                              f"only; these statistics are of {'dicts' if self.keys is not None else 'other observations'}")
        return replace(self, mean=np.tile(self.mean, n_stack), var=np.tile(self.var, n_stack), frames=n_stack)

    @property
    def shape(self) -> tuple[int, ...] | None:
        """The observations' shape the statistics are of (``None``: any, or dicts: see :meth:`flattened`)."""
        return None if self.mean is None or self.keys is not None else tuple(self.mean.shape)

    def describe(self) -> dict[str, Any]:
        """The JSON record of these statistics in an agent's metadata (and so in its logs)."""
        keys = {} if self.keys is None else {"norm_obs_keys": sorted(self.keys)}
        frames = {} if self.frames is None else {"normalised_then_stacked": self.frames}
        return {"path": self.path or "(in memory)", "sha256": self.sha256,
                "norm_obs": self.mean is not None or bool(self.keys),
                "clip_obs": self.clip_obs, "epsilon": self.epsilon} | keys | frames


def _numbers_sha256(arrays: list[np.ndarray | None], epsilon: float, clip_obs: float, keys: list[str] | None = None) -> str:
    digest = hashlib.sha256(json.dumps([epsilon, clip_obs] + ([] if keys is None else keys)).encode())
    for array in arrays:
        digest.update(b"none" if array is None else np.asarray(array, np.float64).tobytes())
    return digest.hexdigest()


def _statistics(rms: Any, what: str) -> tuple[np.ndarray, np.ndarray]:
    """The mean and var of one ``RunningMeanStd`` (in memory, or the file's record), checked."""
    rms = rms.state if isinstance(rms, _Record) else getattr(rms, "__dict__", None)
    if not isinstance(rms, dict) or not all(isinstance(rms.get(k), np.ndarray) for k in ("mean", "var")):
        raise ConfigError(f"it holds no observation statistics{what} (obs_rms with a mean and a var array)")
    mean, var = np.array(rms["mean"], np.float64), np.array(rms["var"], np.float64)  # copies
    if mean.shape != var.shape or not (np.isfinite(mean).all() and np.isfinite(var).all() and (var >= 0).all()):
        raise ConfigError(f"its observation statistics{what} are not usable (mean of shape {mean.shape}, var of shape "
                          f"{var.shape}, finite and var >= 0 required)")
    return mean, var


def _normalizer(state: dict[str, Any], *, sha256: str | None = None, path: str | None = None) -> ObservationNormalizer:
    """The normalizer of a ``VecNormalize``'s attributes (``state``: its ``__dict__`` or the file's record)."""
    epsilon, clip_obs = float(state.get("epsilon", 1e-8)), float(state.get("clip_obs", 10.0))
    mean = var = None
    if state.get("norm_obs", True) and isinstance(state.get("obs_rms"), dict):  # a dict observation's, key by key
        names = state.get("norm_obs_keys")
        if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) and n in state["obs_rms"] for n in names):
            raise ConfigError("its dict observations' statistics do not match its norm_obs_keys")
        keys = {name: _statistics(state["obs_rms"][name], f" of key {name!r}") for name in names}
        arrays = [array for pair in keys.values() for array in pair]
        numbers = _numbers_sha256(arrays, epsilon, clip_obs, list(keys))
        return ObservationNormalizer(None, None, epsilon, clip_obs, sha256 or numbers, path, keys, numbers_sha256=numbers)
    if state.get("norm_obs", True):
        mean, var = _statistics(state.get("obs_rms"), "")
    numbers = _numbers_sha256([mean, var], epsilon, clip_obs)
    return ObservationNormalizer(mean, var, epsilon, clip_obs, sha256 or numbers, path, numbers_sha256=numbers)


def load_vec_normalize(path: str | Path) -> ObservationNormalizer:
    """The observation statistics in the file ``VecNormalize.save(path)`` wrote, read without
    running code from it (see the module's docstring).

    Raises:
        ConfigError: a missing file, one that is not such a file, or one that names any class or
            function a VecNormalize file does not hold (it is not unpickled).
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--vec-normalize {path} {not_a_file(path)}: give the file "
                          "VecNormalize.save() wrote, e.g. vecnormalize.pkl")
    data = path.read_bytes()
    try:
        # A pickle (protocol 2 on; VecNormalize.save writes 4 or 5) is walked first without building
        # anything: a damaged length (a flipped bit) is then an error here (oodmon.agents.pickle_walk)
        if data.startswith(b"\x80"):
            walk_opcodes(data)
        unpickler = _StatisticsUnpickler(io.BytesIO(data))
        root = unpickler.load()
    except Exception as error:  # noqa: BLE001  (a damaged or foreign file fails in many ways; none runs code)
        raise ConfigError(f"--vec-normalize {path} is not a VecNormalize statistics file ({one_line(error)})") from None
    if not isinstance(root, _Record) or not isinstance(root.state, dict):
        raise ConfigError(f"--vec-normalize {path} is not a VecNormalize statistics file (VecNormalize.save() writes "
                          "one VecNormalize object)")
    try:
        return _normalizer(root.state, sha256=hashlib.sha256(data).hexdigest(), path=str(path.resolve()))
    except ConfigError as error:
        raise ConfigError(f"--vec-normalize {path}: {error}") from None


def normalizer_of(vec_normalize: Any) -> ObservationNormalizer:
    """The statistics of a ``VecNormalize`` in memory, as they are now (a copy: training on does
    not change them). ``model.get_vec_normalize_env()`` gives the one a model was trained in."""
    return _normalizer(dict(vec_normalize.__dict__))


def trained_in_vec_normalize(path: str | Path) -> bool:
    """Whether the PPO or A2C model in ``path`` was trained inside a ``VecNormalize``, read from
    its ``data`` JSON without loading it: SB3 keeps the raw observation beside the normalised one
    (``_last_original_obs``) only then. DQN, SAC and TD3 keep it always, so their files cannot
    tell (``False``)."""
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    return ("clip_range" in data or "vf_coef" in data) and data.get("_last_original_obs") is not None
