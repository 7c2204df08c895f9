"""Variants: one OOD (or the ID) env of a task, named by a short spec string.

Spec strings, as the CLI and the logs write them, parse back to equal variants::

    cartpole                        the ID env of a task (also pendulum, pong)
    cartpole:length=2.0             physics changed (several: cartpole:gravity=20.0,length=2.0)
    pendulum:g=50.0
    pong:motion_blur@3              a corruption at one of the paper's severities 1..5
    pong:gaussian_noise:sigma=0.2   a corruption with its own parameters
    cartpole:obs.stuck[3]=1         a sensor fault (:class:`~oodmon.envs.sensor_faults.SensorFaults`): the
                                    pole's angular velocity frozen (also after physics:
                                    cartpole:length=2.0,obs.noise[0]=0.1; pong:obs.stuck=1, a frozen
                                    camera)

:func:`paper_grid` returns the variants of the paper's Table 1: 90 for CartPole, 40 for
Pendulum, 20 for Pong.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import gymnasium

from oodmon.envs.checks import check_physics
from oodmon.envs.corruptions import make_corruption
from oodmon.envs.physics import PHYSICS_DEFAULTS
from oodmon.errors import ConfigError, SpecError, UnknownParameterError, unknown
from oodmon.names import TASKS
from oodmon.paper import paper_grid_data

__all__ = ["ENV_IDS", "TASKS", "Variant", "grid_rows", "paper_grid", "parse_variant", "select_variants"]

#: The gymnasium id of each task's env.
ENV_IDS: dict[str, str] = {
    "cartpole": "oodmon/CartPole-v1",
    "pendulum": "oodmon/Pendulum-v1",
    "pong": "oodmon/Pong-v5",
}
assert tuple(ENV_IDS) == TASKS  # one env per task, in the same order

_SPEC_HELP = (
    "expected TASK, TASK:NAME=VALUE[,NAME=VALUE...], pong:CORRUPTION@SEVERITY or "
    "pong:CORRUPTION:NAME=VALUE[,...], e.g. 'cartpole:length=2.0' or 'pong:pixelate@3'; sensor faults as "
    "NAME=VALUE too, e.g. 'cartpole:obs.stuck[3]=1'"
)


@dataclass(frozen=True)
class Variant:
    """One env of a task: the ID env, a physics change, or a corruption.

    Build one with :func:`parse_variant` or take it from :func:`paper_grid`; constructing it
    directly validates the same way.

    Attributes:
        task: ``"cartpole"``, ``"pendulum"`` or ``"pong"``.
        params: physics parameters (CartPole, Pendulum) or a corruption's own parameters
            (Pong), as sorted ``(name, value)`` pairs.
        corruption: Pong's corruption name, or ``None``.
        severity: Pong's severity 1..5, or ``None`` when ``params`` give the corruption.
        faults: sensor faults (``obs.KIND[i]``, :class:`~oodmon.envs.sensor_faults.SensorFaults`) from the
            onset on, beside physics or alone (not beside a corruption), as sorted ``(name, value)`` pairs.

    Example:
        >>> v = parse_variant("cartpole:length=2.0")
        >>> v.spec, v.env_id, v.kwargs()
        ('cartpole:length=2.0', 'oodmon/CartPole-v1', {'length': 2.0})
        >>> env = v.make(onset_step=100)
        >>> parse_variant("cartpole:length=2.0,obs.stuck[3]=1").faults
        (('obs.stuck[3]', 1.0),)
    """

    task: str
    params: tuple[tuple[str, float], ...] = ()
    corruption: str | None = None
    severity: int | None = None
    faults: tuple[tuple[str, float], ...] = ()
    _kwargs: dict[str, Any] = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        if self.task not in ENV_IDS:
            raise UnknownParameterError(unknown("task", self.task, TASKS))
        if self.faults and self.corruption is not None:
            raise SpecError(f"{self.task}: a corruption and sensor faults at once; give one of them")
        params = dict(self.params)
        if self.task == "pong":
            if self.corruption is None and (params or self.severity is not None):
                raise SpecError(f"pong variant with parameters but no corruption; {_SPEC_HELP}")
            if self.corruption is not None:
                params = make_corruption(self.corruption, self.severity, **params).params()
                if self.severity is not None:
                    params = {}  # the severity names the parameters
        else:
            if self.corruption is not None or self.severity is not None:
                raise SpecError(
                    f"{self.task} variants change physics, not frames; corruptions are for pong"
                )
            checked = check_physics(ENV_IDS[self.task], PHYSICS_DEFAULTS[self.task], params)
            params = {name: checked[name] for name in params}
        object.__setattr__(self, "params", tuple(sorted(params.items())))
        if self.faults:
            from oodmon.envs.sensor_faults import SensorFaults

            checked = SensorFaults.of(self.task, _observation_space(self.task), dict(self.faults))
            object.__setattr__(self, "faults", tuple(sorted(checked.changes.items())))
        kwargs: dict[str, Any] = dict(self.params)
        if self.corruption is not None:
            kwargs["corruption"] = self.corruption
        if self.severity is not None:
            kwargs["severity"] = self.severity
        object.__setattr__(self, "_kwargs", kwargs)

    @property
    def env_id(self) -> str:
        """The gymnasium id to make this variant with."""
        return ENV_IDS[self.task]

    @property
    def is_id(self) -> bool:
        """Whether this is the task's default, in-distribution env."""
        return not self.params and self.corruption is None and not self.faults

    @property
    def spec(self) -> str:
        """The canonical spec string; :func:`parse_variant` turns it back into this variant."""
        text = self.task
        if self.corruption is not None:
            text += f":{self.corruption}"
            if self.severity is not None:
                return f"{text}@{self.severity}"
        if self.params or self.faults:
            text += ":" + ",".join(f"{name}={_format_number(value)}" for name, value in (*self.params, *self.faults))
        return text

    def kwargs(self) -> dict[str, Any]:
        """The keyword arguments of ``gymnasium.make(self.env_id, ...)`` for this variant."""
        return dict(self._kwargs)

    def make(self, *, onset_step: int = 0, **kwargs: Any) -> gymnasium.Env:
        """Make this variant's env, shifted from ``onset_step`` on (0: the whole episode); its sensor
        faults (if any) from then on too, by a :class:`~oodmon.envs.shift.ShiftAttributes` around it."""
        env = gymnasium.make(self.env_id, **self._kwargs, onset_step=onset_step, **kwargs)
        if not self.faults:
            return env
        from oodmon.envs.shift import ShiftAttributes

        return ShiftAttributes(env, dict(self.faults), onset_step=onset_step, env_id=self.env_id, forward_onset=True)

    def __str__(self) -> str:
        return self.spec


@cache
def _observation_space(task: str) -> gymnasium.Space:
    """The observation space of ``task``'s env (made once)."""
    env = gymnasium.make(ENV_IDS[task])
    env.close()
    return env.observation_space


def _format_number(value: float | int) -> str:
    return repr(value) if isinstance(value, float) else str(value)


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf|nan"
_ASSIGNMENT = re.compile(rf"^([A-Za-z_]\w*|obs\.\w+(?:\[\d+\])?)=({_NUMBER})$")
_SEVERITY = re.compile(r"^([A-Za-z_]\w*)@(\S+)$")


def parse_variant(spec: str) -> Variant:
    """Parse a spec string (see the module docstring) into a :class:`Variant`.

    Raises:
        SpecError: the string does not have one of the accepted forms.
        UnknownParameterError: an unknown task, parameter or corruption.
        InvalidParameterError: a value outside what is allowed.

    Example:
        >>> parse_variant("pong:motion_blur@3").kwargs()
        {'corruption': 'motion_blur', 'severity': 3}
        >>> parse_variant("pendulum:g=50").spec
        'pendulum:g=50.0'
    """
    if not isinstance(spec, str) or not spec.strip():
        raise SpecError(f"malformed variant spec {spec!r}: {_SPEC_HELP}")
    task, _, rest = spec.strip().partition(":")
    if task not in ENV_IDS:
        from oodmon.envs.registration import task_of_env

        env_id, colon, assignments = spec.strip().rpartition(":")  # gymnasium's id of a task: CartPole-v1:length=2.0
        if not colon:
            env_id = assignments  # the id alone: its task's ID env
        its_task = task_of_env(env_id)
        if its_task is not None:
            named = its_task + (f":{assignments}" if colon else "")
            if colon:
                from oodmon.envs.shift import parse_env_shift

                try:
                    parse_env_shift(spec)
                except SpecError:  # (its task's physics or sensor faults: a variant of the task)
                    pass
                else:  # other attributes of gymnasium's env: not oodmon's variants
                    raise UnknownParameterError(
                        f"variant spec {spec!r} shifts attributes of gymnasium's {env_id} that are not oodmon's "
                        f"variants of {its_task} (its physics and sensor faults, `oodmon envs`): it runs with a policy "
                        f"of your own on {env_id} (`oodmon run` or `oodmon bench` with --sb3 or --policy and --env "
                        f"{env_id}), not with oodmon's {its_task} agents, which act in oodmon's own env")
            raise UnknownParameterError(f"variant spec {spec!r}: oodmon's variants of {env_id} are named by its task, "
                                        f"{named} (see `oodmon envs`)")
        raise UnknownParameterError(
            f"variant spec {spec!r}: {unknown('task', task, TASKS)}"
        )
    if not rest:
        return Variant(task)
    if task == "pong" and not rest.startswith("obs."):  # (Pong's sensor faults come alone: no corruption before them)
        corruption, _, assignments = rest.partition(":")
        severity_match = _SEVERITY.match(corruption)
        if severity_match and not assignments:
            name, severity = severity_match.groups()
            if not re.fullmatch(r"[-+]?\d+", severity):
                raise SpecError(
                    f"variant spec {spec!r}: severity {severity!r} is not an integer from 1 to 5"
                )
            return Variant(task, corruption=name, severity=int(severity))
        if not assignments or not re.fullmatch(r"[A-Za-z_]\w*", corruption):
            raise SpecError(f"malformed variant spec {spec!r}: {_SPEC_HELP}")
        params, faults = _split_faults(_parse_assignments(spec, assignments))
        return Variant(task, params, corruption=corruption, faults=faults)
    params, faults = _split_faults(_parse_assignments(spec, rest))
    return Variant(task, params, faults=faults)


def _split_faults(pairs: tuple[tuple[str, float], ...]) -> tuple[tuple[tuple[str, float], ...], tuple[tuple[str, float], ...]]:
    """``pairs`` as the env's own parameters and the sensor faults (``obs.`` names)."""
    return tuple(p for p in pairs if not p[0].startswith("obs.")), tuple(p for p in pairs if p[0].startswith("obs."))


def _parse_assignments(spec: str, text: str) -> tuple[tuple[str, float], ...]:
    pairs: dict[str, float] = {}
    for item in text.split(","):
        match = _ASSIGNMENT.match(item.strip())
        if not match:
            raise SpecError(f"malformed variant spec {spec!r} at {item!r}: {_SPEC_HELP}")
        name, value = match.groups()
        if name in pairs:
            raise SpecError(f"variant spec {spec!r} sets {name!r} twice")
        pairs[name] = float(value)
    return tuple(pairs.items())


def paper_grid(task: str) -> list[Variant]:
    """The OOD variants of the paper's Table 1 for ``task``, in the paper's order.

    Raises:
        UnknownParameterError: ``task`` is not ``cartpole``, ``pendulum`` or ``pong``.

    Example:
        >>> [len(paper_grid(t)) for t in ("cartpole", "pendulum", "pong")]
        [90, 40, 20]
        >>> paper_grid("pong")[0].spec
        'pong:gaussian_noise@1'
    """
    if task not in ENV_IDS:
        raise UnknownParameterError(unknown("task", task, TASKS))
    grid = paper_grid_data()[task]
    if task == "pong":
        return [
            Variant(task, corruption=name, severity=severity)
            for name, entry in grid["severities"].items()
            for severity in range(1, len(entry["values"]) + 1)
        ]
    return [
        Variant(task, ((name, float(value)),))
        for name, values in grid["values"].items()
        for value in values
    ]


def select_variants(task: str, specs: str | Sequence[str], *, shifted_only: bool = False) -> list[Variant]:
    """``"paper"`` (the paper's grid of ``task``) or spec strings, parsed and checked to be ``task``'s
    (and, with ``shifted_only``, not its ID env).

    Raises:
        SpecError, UnknownParameterError: a spec that does not parse.
        ConfigError: a variant of another task, or the ID env where only shifts are wanted.

    Example:
        >>> [v.spec for v in select_variants("cartpole", "cartpole:length=2.0,cartpole")]
        ['cartpole:length=2.0', 'cartpole']
        >>> len(select_variants("pendulum", "paper"))
        40
    """
    if isinstance(specs, str):
        if specs == "paper":
            return paper_grid(task)
        specs = specs.split(",")
    variants = [parse_variant(spec.strip()) for spec in specs]
    for variant in variants:
        if variant.task != task or (shifted_only and variant.is_id):
            raise ConfigError(f"variant {variant.spec!r} is not a {'shifted ' if shifted_only else ''}{task} variant")
    return variants


def grid_rows(tasks: Sequence[str] = TASKS) -> list[dict[str, Any]]:
    """The paper's variants of ``tasks`` as rows: task, spec, the parameter (Pong: the corruption),
    its value (Pong: the severity's parameters) and the ID default (Pong: none).

    Example:
        >>> grid_rows(["pendulum"])[0]
        {'task': 'pendulum', 'spec': 'pendulum:g=0.5', 'parameter': 'g', 'value': 0.5, 'default': 10.0}
    """
    from oodmon.envs.corruptions import severity_params

    rows = []
    for task in tasks:
        defaults = paper_grid_data()[task].get("defaults", {})
        for variant in paper_grid(task):
            if task == "pong":
                params = severity_params(variant.corruption, variant.severity)
                rows.append({"task": task, "spec": variant.spec, "parameter": variant.corruption,
                             "value": ", ".join(f"{k}={v}" for k, v in params.items()), "default": None})
            else:
                name, value = variant.params[0]
                rows.append({"task": task, "spec": variant.spec, "parameter": name, "value": value,
                             "default": defaults[name]})
    return rows
