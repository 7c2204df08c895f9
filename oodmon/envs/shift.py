"""Shifts of your own env: other numbers in any gymnasium env, from a step of each episode on.

oodmon's variants cover CartPole, Pendulum and Pong. A policy of your own, in an env oodmon has
no variants of (``Acrobot-v1``, an env of yours), is shifted by changing numeric attributes of
its env, the numbers its ``step()`` reads: ``Acrobot-v1:LINK_MASS_2=3.0`` is Acrobot with a
second link three times as heavy. From the onset step on, :class:`ShiftAttributes` sets them
on ``env.unwrapped`` (a name it lacks, on the first wrapper around it that has it: a wrapper of
yours that adds a wind, a delay or a noise, and the number it reads); each ``reset`` puts the
env's own values back first, so the first steps of every episode are the env you trained in.
``info["shifted"]`` marks the steps of the shifted world, as in oodmon's envs, so that the
monitor's logs and ``oodmon replay`` count them as shifted (AUROC against your ID episodes,
alarms before the onset as false ones, delays).

Spec strings, as ``oodmon run --variant`` takes them and the logs write them::

    Acrobot-v1:LINK_MASS_2=3.0                   one attribute
    MountainCar-v0:force=0.0005,gravity=0.003    several
    my_envs:MyEnv-v0:friction=0.2                an env registered in a module of yours
    HalfCheetah-v5:model.body_mass[1]=12.0       an element of an array, through attributes
    Hopper-v5:model.opt.gravity[2]=-5.0          (MuJoCo's model: its arrays are set in place)
    Acrobot-v1:obs.bias[4]=0.5                   a sensor fault (oodmon.envs.SensorFaults): reading
                                                 4 of the observation off by 0.5 (also obs.scale,
                                                 obs.noise, obs.stuck)
    my_envs:MyBreakout-v0:obs.noise=30           every reading at once (a camera's every pixel)
    Taxi-v4:obs.noise=0.1                        a discrete reading misread one step in ten
    my_envs:MyRobot-v0:obs.joints.stuck[2]=1     reading 2 under a dict observation's key "joints"

An attribute that ``step()`` does not read (a quantity the env derives once in ``__init__`` from
another) changes nothing: pick the ones its code uses. CartPole and Pendulum have oodmon's own
variants (``cartpole:length=2.0``), which also update what those envs derive; their specs are
refused here with a pointer to them.
"""

from __future__ import annotations

import numbers
import re
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from oodmon.envs.checks import check_onset_step, episode_onset
from oodmon.envs.physics import PHYSICS_DEFAULTS
from oodmon.envs.registration import task_of_env, wrappers_of
from oodmon.envs.sensor_faults import SensorFaults
from oodmon.errors import InvalidParameterError, SpecError, UnknownParameterError
from oodmon.names import TASKS
from oodmon.validation import is_finite_real, is_real

__all__ = ["AnotherEnv", "EnvShift", "OtherEnv", "ShiftAttributes", "another_env_id", "own_variant",
           "parse_any_variant", "parse_env_shift", "same_env", "shifts_an_env"]

_SPEC_HELP = "expected ENV_ID:NAME=VALUE[,NAME=VALUE...], e.g. 'Acrobot-v1:LINK_MASS_2=3.0'"


#: A name a shift sets: an attribute, through attributes (``model.opt.gravity``), and an element of
#: an array there (``model.body_mass[1]``, ``model.geom_friction[0][0]``).
_NAME = re.compile(r"([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)((?:\[\d+\])*)")
#: A sensor fault of a part of a tuple observation, named by its place: ``obs.1.bias[0]``
#: (:class:`~oodmon.envs.sensor_faults.DictSensorFaults`).
_TUPLE_FAULT = re.compile(r"obs\.\d+\.[A-Za-z_]\w*(?:\[\d+\])?")


def _settable(holder: object, name: str) -> bool:
    """Whether a shift can set ``holder.name``: a plain value of the object or its class, or a
    property with a setter; not one without (``np_random_seed``), nor a method."""
    if name.startswith("_"):
        return False
    if name in getattr(holder, "__dict__", {}):
        return True
    for cls in type(holder).__mro__:
        if name in vars(cls):
            found = vars(cls)[name]
            if isinstance(found, property):
                return found.fset is not None
            return not hasattr(found, "__get__") or hasattr(found, "__set__")
    return True


def _settable_names(holder: object) -> tuple[list[str], list[str]]:
    """The public attributes of ``holder`` a shift can set: its numbers, and its numeric arrays
    (whose elements it can set), each sorted. (An error's words: reads every attribute.)"""
    numbers_, arrays = [], []
    for name in dir(holder):
        if name.startswith("_") or not _settable(holder, name):
            continue
        try:
            value = getattr(holder, name)
        except Exception:  # noqa: BLE001, S112  (an attribute that cannot be read now is not one to list)
            continue
        if is_real(value):
            numbers_.append(name)
        elif isinstance(value, np.ndarray) and value.dtype.kind in "fiu" and value.size:
            arrays.append(f"{name}{list(value.shape)}")
    return numbers_, arrays


@dataclass(frozen=True)
class _Target:
    """One number a shift sets: ``holder.name`` or the element ``index`` of the array there."""

    holder: Any
    name: str
    index: tuple[int, ...]

    def get(self) -> numbers.Real:
        value = getattr(self.holder, self.name)
        return value[self.index].item() if self.index else value

    def set(self, value: numbers.Real) -> None:
        if not self.index:
            setattr(self.holder, self.name, value)
            return
        array = getattr(self.holder, self.name)
        array[self.index] = value  # in place: the env reads that array
        if getattr(self.holder, self.name)[self.index] != array.dtype.type(value):  # a copy was handed out
            raise InvalidParameterError(
                f"{self.name}{''.join(f'[{i}]' for i in self.index)}={value!r} changed nothing the env reads: its "
                f"{self.name} hands out a copy of the array, not the one it steps with")


def _target(owner: str, base: object, name: object) -> _Target:
    """Where ``name`` (an attribute, dotted, with element indices) points in ``base``.

    Raises:
        UnknownParameterError: no such number there; the message lists what there is.
    """
    match = _NAME.fullmatch(name) if isinstance(name, str) else None
    if match is None:
        hint = _index_hint(name) if isinstance(name, str) else ""
        raise UnknownParameterError(f"{owner}: {name!r} is not an attribute name; {_SPEC_HELP}{hint}")
    path, indices = match.group(1).split("."), tuple(int(i) for i in re.findall(r"\d+", match.group(2)))
    holder, walked = base, []
    for part in path[:-1]:
        if part.startswith("_") or not hasattr(holder, part):
            raise UnknownParameterError(f"{owner} has no attribute {'.'.join([*walked, part])!r} to shift through")
        holder, walked = getattr(holder, part), [*walked, part]
    last, where = path[-1], ".".join(walked) or owner
    value = getattr(holder, last, None) if not last.startswith("_") else None
    if indices:
        if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiu":
            raise UnknownParameterError(f"{owner}: {match.group(1)} is not a numeric array to index")
        array, shape = match.group(1), list(value.shape)
        if any(i >= n for i, n in zip(indices, value.shape)):
            raise UnknownParameterError(f"{owner}: {name} is outside {array}, an array of shape {shape}")
        if len(indices) > value.ndim:
            raise UnknownParameterError(f"{owner}: {name} has {len(indices)} indices; {array}, an array of shape "
                                        f"{shape}, takes {value.ndim}")
        if len(indices) < value.ndim:
            raise UnknownParameterError(
                f"{owner}: {name} is a part of shape {list(value.shape[len(indices):])} of {array}, an array of shape "
                f"{shape}: shift an element, an index for each axis, e.g. "
                f"{name}{''.join('[0]' for _ in value.shape[len(indices):])}")
        return _Target(holder, last, indices)
    if isinstance(value, np.ndarray) and value.dtype.kind in "fiu" and value.size:
        raise UnknownParameterError(f"{owner}: {name} is an array of shape {list(value.shape)}: shift an element, "
                                    f"e.g. {name}{''.join('[0]' for _ in value.shape)}")
    if not is_real(value) or not _settable(holder, last):
        numbers_, arrays = _settable_names(holder)
        listed = f"{', '.join(numbers_) or 'none'}" + (
            f"; arrays (shift an element, NAME[i]): {', '.join(arrays[:20])}{', ...' if len(arrays) > 20 else ''}"
            if arrays else "")
        raise UnknownParameterError(f"{owner} has no numeric attribute {name!r} to shift; the numeric attributes "
                                    f"of {where}: {listed}")
    return _Target(holder, last, ())


def _target_in(owner: str, env: gymnasium.Env, name: object) -> _Target:
    """Where ``name`` points: in ``env.unwrapped``, or else in the first wrapper of it, from the
    outermost in, that has the attribute (a wrapper of yours that adds a wind or a delay, say).

    Raises:
        UnknownParameterError: neither has it; the message lists the numbers of both.
    """
    wrappers = wrappers_of(env)
    try:
        return _target(owner, env.unwrapped, name)
    except UnknownParameterError as error:
        first = name.split(".")[0].split("[")[0] if isinstance(name, str) else ""
        for wrapper in wrappers:
            if first and not first.startswith("_") and _wrappers_own(wrapper, first):
                return _target(f"{owner} (its wrapper {type(wrapper).__name__})", wrapper, name)
        listed = [f"of its wrapper {type(w).__name__}: {', '.join(found)}" for w in wrappers
                  if (found := [n for n in _settable_names(w)[0] if _wrappers_own(w, n)])]
        raise UnknownParameterError("; ".join([str(error), *listed])) from None


def _wrappers_own(wrapper: gymnasium.Wrapper, name: str) -> bool:
    """Whether ``name`` is the wrapper's own attribute (its instance's, or its class's below
    ``gymnasium.Wrapper``), not one every wrapper has (``spec``, ``render_mode``...)."""
    return name in vars(wrapper) and name != "env" or any(
        name in vars(cls) for cls in type(wrapper).__mro__ if cls not in gymnasium.Wrapper.__mro__)


class ShiftAttributes(gymnasium.Wrapper):
    """Sets numeric attributes of ``env.unwrapped`` (or, for a name it lacks, of a wrapper of it
    that has it) to other values from ``onset_step`` on, and faults its sensors (names
    ``obs.KIND[i]``: :class:`~oodmon.envs.sensor_faults.SensorFaults`) from then on.

    Args:
        env: any gymnasium env.
        changes: attribute name -> its value in the shifted world; each must be a number the
            unwrapped env (or a wrapper of it) has (an int attribute takes whole values only), or an element of a
            numeric array there (``model.body_mass[1]``), or a sensor fault (``obs.bias[4]``).
        onset_step: index of the first ``step()`` of each episode in the shifted world (0: all);
            ``reset(options={"onset_step": n})`` sets it for that episode alone.
        env_id: the id the spec names (default ``env.spec.id``; ``module:Id`` as you made it).
        forward_onset: ``env`` shifts at onsets of its own (oodmon's task envs, made with the same
            ``onset_step``): an episode's ``onset_step`` option is handed on to it as well.

    Raises:
        UnknownParameterError: the env has no such numeric attribute (the message lists those it has).
        InvalidParameterError: a value that is not a finite number, a fraction for an int
            attribute, no change at all, or a negative onset.

    Example:
        >>> env = ShiftAttributes(gymnasium.make("Acrobot-v1"), {"LINK_MASS_2": 3.0}, onset_step=2)
        >>> _, info = env.reset(seed=0)
        >>> info["shifted"], env.unwrapped.LINK_MASS_2
        (False, 1.0)
        >>> [env.step(0)[4]["shifted"] for _ in range(3)], env.unwrapped.LINK_MASS_2
        ([False, False, True], 3.0)
        >>> env.spec.id, env.shift.spec
        ('Acrobot-v1', 'Acrobot-v1:LINK_MASS_2=3.0')
    """

    def __init__(self, env: gymnasium.Env, changes: dict[str, float], onset_step: int = 0, *,
                 env_id: str | None = None, forward_onset: bool = False) -> None:
        super().__init__(env)
        self._forward_onset = forward_onset
        owner = env_id or (env.spec.id if env.spec is not None else type(env.unwrapped).__name__)
        if not changes:
            raise InvalidParameterError(f"a shift of {owner} needs at least one attribute to change; {_SPEC_HELP}")
        sensed = {name: value for name, value in changes.items() if str(name).startswith("obs.")}
        self._sensors = SensorFaults.of(owner, env.observation_space, sensed)
        self._targets: dict[str, _Target] = {}
        self._own: dict[str, numbers.Real] = {}
        self._shifted: dict[str, numbers.Real] = {}
        for name, value in changes.items():
            if name in sensed:
                continue
            self._targets[name] = target = _target_in(owner, env, name)
            own = target.get()
            if not is_finite_real(value):
                raise InvalidParameterError(f"{owner}: {name}={value!r} is not a finite number")
            if isinstance(own, numbers.Integral) and value != int(value):
                raise InvalidParameterError(f"{owner}: {name} is a whole number ({own}); {name}={value!r} is not one")
            self._own[name] = own
            self._shifted[name] = type(own)(value) if isinstance(own, numbers.Integral) else float(value)
        if self._shifted == self._own and self._sensors is None:
            raise InvalidParameterError(f"{owner}: {changes} are its own values; a shift changes at least one")
        faults = {} if self._sensors is None else self._sensors.changes
        self.shift = EnvShift(owner, tuple(sorted((n, float(v)) for n, v in {**self._shifted, **faults}.items())))
        self.onset_step = self._configured_onset = check_onset_step(owner, onset_step)
        self._steps = 0
        self._set(shifted=True)  # an array handed out as a copy is refused now, not at the first onset
        self._set(shifted=False)

    def _set(self, shifted: bool) -> None:
        for name, value in (self._shifted if shifted else self._own).items():
            self._targets[name].set(value)
        self._active = shifted

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.onset_step, rest = episode_onset(self.shift.env_id, self._configured_onset, options)
        options = options if self._forward_onset else rest  # (the task env beneath reads it too)
        # the env's own world while it resets, its start states ID's; but at onset 0 the shifted one:
        # the whole episode is, and an attribute the env reads at reset (MiniGrid's layout) is seen
        self._set(shifted=self.onset_step == 0)
        obs, info = self.env.reset(seed=seed, options=options)
        self._steps = 0
        if self._sensors is not None:
            self._sensors.begin_episode(seed, obs)
        return self._sensed(obs), {**info, "shifted": self._active}

    def step(self, action: Any):
        if not self._active and self._steps >= self.onset_step:
            self._set(shifted=True)
        self._steps += 1
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._sensed(obs), reward, terminated, truncated, {**info, "shifted": self._active}

    def _sensed(self, obs):
        """What the sensors report: ``obs``, or from the onset on ``obs`` through the faults."""
        if self._sensors is None:
            return obs
        return self._sensors.read(obs, faulty=self._active)

    def close(self) -> None:
        self._set(shifted=False)  # an env made elsewhere and handed in is left as it came
        super().close()


@dataclass(frozen=True)
class EnvShift:
    """A shift of an env oodmon has no variants of: its id and the attributes changed (none: the
    env itself, its ID runs, as :func:`own_variant` gives it).

    Attributes:
        env_id: the gymnasium id (``module:Id`` for an env registered in a module of yours).
        params: the attributes' shifted values, as sorted ``(name, value)`` pairs.

    Example:
        >>> shift = parse_env_shift("Acrobot-v1:LINK_MASS_2=3")
        >>> shift.spec, shift.is_id
        ('Acrobot-v1:LINK_MASS_2=3.0', False)
        >>> env = shift.make(onset_step=50)  # Acrobot-v1, its second link heavier from step 50
    """

    env_id: str
    params: tuple[tuple[str, float], ...]
    corruption = None  # as a Variant has them: a shift of your own env corrupts no frames
    severity = None

    @property
    def spec(self) -> str:
        """The spec string, as the logs record it; :func:`parse_env_shift` (:func:`own_variant`) reads it back."""
        if not self.params:
            return self.env_id
        return f"{self.env_id}:{','.join(f'{name}={value!r}' for name, value in self.params)}"

    @property
    def is_id(self) -> bool:
        """Whether this is the env itself (no attribute changed)."""
        return not self.params

    def make(self, *, onset_step: int = 0, **kwargs: Any) -> gymnasium.Env:
        """``gymnasium.make(env_id, **kwargs)``, shifted from ``onset_step`` on (0: the whole episode)
        by a :class:`ShiftAttributes`; the env itself when no attribute is changed.

        Raises:
            ConfigError: an id gymnasium cannot make (:func:`~oodmon.envs.registration.make_env`)."""
        from oodmon.envs.registration import make_env

        env = make_env(self.env_id, **kwargs)
        if self.is_id:
            return env
        return ShiftAttributes(env, dict(self.params), onset_step=onset_step, env_id=self.env_id)


def own_variant(spec: str, env_id: str) -> EnvShift | OtherEnv:
    """A variant of your own env ``env_id``: the env itself (``spec == env_id``), a shift of it
    (``ENV_ID:NAME=VALUE[,...]``, :func:`parse_env_shift`), or another env's id alone
    (:class:`OtherEnv`, deployed in from each reset).

    Raises:
        SpecError: a malformed spec, or a shift of another env.

    Example:
        >>> own_variant("Acrobot-v1", "Acrobot-v1").is_id, own_variant("Acrobot-v1:dt=0.1", "Acrobot-v1").is_id
        (True, False)
        >>> own_variant("MountainCar-v0", "Acrobot-v1")
        OtherEnv(env_id='MountainCar-v0')
    """
    if isinstance(spec, str) and spec.strip() == env_id:
        return EnvShift(env_id, ())
    other = another_env_id(spec, env_id)
    if other is not None:
        return OtherEnv(other)
    shift = parse_env_shift(spec)
    if shift.env_id != env_id:
        raise SpecError(f"{spec!r} shifts {shift.env_id}, not {env_id}: give {env_id}:NAME=VALUE, a numeric "
                        "attribute of its env and its shifted value")
    return shift


class AnotherEnv(gymnasium.Wrapper):
    """Another registered env than the policy's own, deployed as its shifted world (MiniGrid's
    DistShift2 for a policy of DistShift1; your cart registered heavier under an id of its own): each
    of its steps, from its reset on, is a shifted one (``info["shifted"]``, the onset 0), so that
    the log and replay count its alarms as detections, and its steps as the shifted ones AUROC ranks.
    ``oodmon run --variant OTHER_ID`` plays it, and a :class:`~oodmon.monitor.MonitoredEnv` of such
    an env wraps it so itself.

    Example:
        >>> env = AnotherEnv(gymnasium.make("CartPole-v1"))
        >>> env.reset(seed=0)[1]["shifted"], env.step(0)[-1]["shifted"]
        (True, True)
    """

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        # (an onset the bench draws is none of this env's: it is shifted from its reset)
        rest = None if options is None else {key: value for key, value in options.items() if key != "onset_step"}
        obs, info = self.env.reset(seed=seed, options=rest or None)
        return obs, {**info, "shifted": True}

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "shifted": True}


@dataclass(frozen=True)
class OtherEnv:
    """Another registered env than the policy's, as a variant of it (:func:`own_variant`): what
    ``oodmon run --variant OTHER_ID`` and the bench's ``--variants`` play, each episode from its
    reset in :class:`AnotherEnv`. ``spec`` is its id; it has no onset of its own (one given is none
    of it: the whole episode is shifted).

    Example:
        >>> OtherEnv("CartPole-v1").make().reset(seed=0, options={"onset_step": 30})[1]["shifted"]
        True
    """

    env_id: str

    @property
    def spec(self) -> str:
        return self.env_id

    @property
    def params(self) -> tuple:
        """No attribute changed: the whole env is another."""
        return ()

    @property
    def is_id(self) -> bool:
        return False

    def make(self, *, onset_step: int = 0, **kwargs: Any) -> AnotherEnv:
        """The env, ``gymnasium.make(env_id, **kwargs)``, shifted from its reset (``onset_step`` is none of it)."""
        from oodmon.envs.registration import make_env

        return AnotherEnv(make_env(self.env_id, **kwargs))


def same_env(env_id: str, own: str) -> bool:
    """Whether the env ``env_id`` (an id, as a spec or the log names it) is the one ``own`` names (a
    policy's env id, ``module:Id`` too, or oodmon's task, which gymnasium's id of it is).

    Example:
        >>> same_env("MyEnv-v0", "my_envs:MyEnv-v0"), same_env("CartPole-v1", "cartpole")
        (True, True)
        >>> same_env("MiniGrid-DistShift2-v0", "MiniGrid-DistShift1-v0")
        False
    """
    ours, theirs = env_id.strip().rpartition(":")[2], own.strip().rpartition(":")[2]
    return ours == theirs or (task_of_env(ours) or ours) == (task_of_env(theirs) or theirs)


def another_env_id(spec: str, own: str | None) -> str | None:
    """``spec`` when it is an env's id alone (no ``NAME=VALUE``) and another env than ``own`` (the
    policy's env id or task: :func:`same_env`), the world :class:`AnotherEnv` deploys the policy
    in; else ``None`` (a shift of the policy's env, or the env itself).

    Example:
        >>> another_env_id("MiniGrid-DistShift2-v0", "MiniGrid-DistShift1-v0")
        'MiniGrid-DistShift2-v0'
        >>> another_env_id("Acrobot-v1", "Acrobot-v1") is None
        True
        >>> another_env_id("Acrobot-v1:LINK_MASS_2=3", "Acrobot-v1"), another_env_id("Acrobot-v1:dt", "Acrobot-v1")
        (None, None)
    """
    if not isinstance(spec, str) or not spec.strip() or "=" in spec or own is None or same_env(spec, own):
        return None
    head, colon, _ = spec.strip().rpartition(":")
    return None if colon and same_env(head, own) else spec.strip()  # (OWN_ID:NAME, a shift without its value)


def parse_any_variant(spec: str):
    """A spec read back: oodmon's :class:`~oodmon.envs.grid.Variant` (a spec of one of its tasks,
    whose errors are said as :func:`~oodmon.envs.grid.parse_variant` says them), else a shift of
    your own env (:func:`parse_env_shift`).

    Raises:
        OodmonError: neither (an env's id alone is neither: its runs are the env as it is).

    Example:
        >>> parse_any_variant("cartpole:length=2.0").params, parse_any_variant("Acrobot-v1:dt=0.1").params
        ((('length', 2.0),), (('dt', 0.1),))
    """
    from oodmon.envs.grid import parse_variant

    return parse_variant(spec) if isinstance(spec, str) and not shifts_an_env(spec) else parse_env_shift(spec)


def shifts_an_env(spec: str) -> bool:
    """Whether ``spec`` names a gymnasium id (a shift of an env's attributes, or the env itself)
    rather than one of oodmon's tasks (its variants).

    Example:
        >>> shifts_an_env("CartPole-v1:theta_threshold_radians=0.1"), shifts_an_env("cartpole:length=2.0")
        (True, False)
    """
    return spec.strip().partition(":")[0] not in TASKS


def _index_hint(item: str) -> str:
    """What a malformed item that indexes an array did wrong, if that is it: numpy's ``[0,0]``
    (whose comma splits the spec) or an index from the end."""
    name = item.partition("=")[0]
    if "[" not in name and "]" not in name:
        return ""
    array = name.partition("[")[0].strip() or "NAME"
    if array.startswith("obs."):  # a sensor fault's reading: one index, in the flattened observation
        return f"; a reading is counted from 0 in the flattened observation ({array}[0], not {array}[-1])"
    return (f"; an element of an array takes an index for each axis, each in brackets of its own and counted from 0 "
            f"({array}[0][0] for an array of two axes, not {array}[0,0] nor {array}[-1])")


def parse_env_shift(spec: str) -> EnvShift:
    """Parse ``ENV_ID:NAME=VALUE[,NAME=VALUE...]`` into an :class:`EnvShift` (the env is not made:
    its attributes are checked by :meth:`EnvShift.make`).

    Raises:
        SpecError: not of that form, an attribute set twice, or the physics or sensor faults alone
            of an env oodmon has variants of (their specs are ``cartpole:...`` and ``pendulum:...``;
            its other attributes are a shift of its id: ``CartPole-v1:theta_threshold_radians=0.1``).

    Example:
        >>> parse_env_shift("my_envs:MyEnv-v0:friction=0.2,mass=2").params
        (('friction', 0.2), ('mass', 2.0))
    """
    from oodmon.envs.registration import task_of_env

    env_id, colon, assignments = spec.strip().rpartition(":") if isinstance(spec, str) else ("", "", "")
    if not colon or not env_id or env_id.endswith(":") or "=" not in assignments:
        raise SpecError(f"malformed shift {spec!r}: {_SPEC_HELP}")
    if env_id in TASKS:
        raise SpecError(f"{spec!r} is a variant of oodmon's {env_id} (oodmon.envs.parse_variant), not a shift of "
                        f"your own env: {_SPEC_HELP}")
    params: dict[str, float] = {}
    for item in assignments.split(","):
        name, equals, value = (part.strip() for part in item.partition("="))
        try:
            number = float(value)
        except ValueError:
            number = None
        named = bool(_NAME.fullmatch(name) or _TUPLE_FAULT.fullmatch(name))
        if not equals or not named or number is None:
            hint = "" if named else _index_hint(item)  # (a name of the form, its value not a number: no hint)
            raise SpecError(f"malformed shift {spec!r} at {item!r}: {_SPEC_HELP}{hint}")
        if name in params:
            raise SpecError(f"shift {spec!r} sets {name!r} twice")
        params[name] = number
    task = task_of_env(env_id)
    if task is not None:
        # oodmon's variants of the task set its physics (updating what the env derives from them) and
        # sensor faults; a shift of the env's id sets its other attributes (and faults beside them)
        own = PHYSICS_DEFAULTS.get(task)  # (None: Pong, whose variants are all there is)
        physics = [name for name in params if own is None or name in own]
        others = [name for name in params if name not in physics and not name.startswith("obs.")]
        if physics and others:
            raise SpecError(f"{spec!r} mixes {task}'s physics ({', '.join(physics)}), which oodmon's variants of {env_id} "
                            f"set ({task}:NAME=VALUE, updating what the env derives from them), with other attributes "
                            f"({', '.join(others)}), which a shift of {env_id} sets: one spec cannot hold both")
        if not others:
            raise SpecError(f"{env_id} has oodmon's own variants, which also update what the env derives from its "
                            f"physics: give {task}:{assignments} (in Python to oodmon.envs.parse_variant, whose "
                            f".make(onset_step=N) makes the env; `oodmon envs` lists them)")
    return EnvShift(env_id, tuple(sorted(params.items())))
