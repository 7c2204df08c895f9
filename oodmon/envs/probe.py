"""Does a shift of your own env change anything? The env's own world and the shifted one, side by side.

A shift sets numbers in the env (``ENV_ID:NAME=VALUE``, :mod:`oodmon.envs.shift`); an attribute
the env reads only when it is made or reset (LunarLander builds its Box2D world from ``gravity``
at reset; MuJoCo derives a body's inertia from its geometry when it compiles) changes nothing
after the onset, and the monitor can only stay silent (at onset 0 the env resets in the shifted
world, so one read at reset takes effect). :func:`probe_shift` plays the env as it
is and the shifted env from the same seed with the same actions (drawn at random from the action
space, seeded) and says from which step what the env returned (observation, reward, the episode's
end) first differed, if it did. ``oodmon envs show ENV_ID:NAME=VALUE`` prints it (and plots the
readings with ``--out``).

It takes a variant of oodmon's CartPole and Pendulum as well (``pendulum:g=14.0``), beside the task's
ID env, for your own policy on gymnasium's id of the task: a change of physics is felt only in the
states where it acts (gravity hardly acts on a pendulum held upright), which your policy's
episodes may never leave (``oodmon envs show pendulum:g=14.0 --onset 50 --sb3 ZIP``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import numpy as np

from oodmon.envs.checks import check_onset_step, step_naming_refusal
from oodmon.envs.grid import Variant
from oodmon.envs.shift import EnvShift

__all__ = ["ShiftProbe", "probe_shift"]

#: Readings of an observation kept for the plot (a picture's thousands are only compared).
_PLOTTED_READINGS = 16


@dataclass(frozen=True)
class ShiftProbe:
    """The env's own episode and the shifted one, from the same seed with the same actions.

    Attributes:
        shift: what was shifted: a shift of your own env, or a variant of one of oodmon's tasks.
        onset: the step the shift began at.
        seed: the seed of both resets and of the actions.
        steps: the steps played in both (fewer than asked when either episode ended).
        first_difference: the first step whose observation, reward or end differed (0: the
            observation ``reset`` returned), ``None`` if none did.
        largest: per reading (flattened), the largest absolute difference over the steps played.
        per_step: per step (``reset``'s observation first), the largest absolute difference of its readings.
        own, shifted: the observations of each episode (flattened, at most 16 readings kept; an
            observation of more readings is compared, not kept), ``reset``'s first.
        own_return, shifted_return: the rewards' sums over the steps played.
        ended: ``(own, shifted)``: whether each episode ended (terminated or truncated) there.
        actions: ``random`` (the same in both) or ``policy`` (a policy acted in each).
    """

    shift: EnvShift | Variant
    onset: int
    seed: int
    steps: int
    first_difference: int | None
    largest: np.ndarray = field(repr=False)
    per_step: np.ndarray = field(repr=False)
    own: np.ndarray | None = field(repr=False)
    shifted: np.ndarray | None = field(repr=False)
    own_return: float = 0.0
    shifted_return: float = 0.0
    ended: tuple[bool, bool] = (False, False)
    actions: str = "random"

    @property
    def changed(self) -> bool:
        """Whether anything the env returned differed."""
        return self.first_difference is not None

    def largest_share(self) -> tuple[int, float] | None:
        """The reading that moved most for its range, and by what share of that range: its largest
        difference over the range of its values in the env's own episode (``None`` where the readings
        were not kept, or none varied there).

        Example:
            >>> from oodmon.envs import parse_variant
            >>> from oodmon.envs.reference import pendulum_controller
            >>> probe = probe_shift(parse_variant("pendulum:g=14.0"), onset=50, steps=200, policy=pendulum_controller)
            >>> reading, share = probe.largest_share()  # sin(angle), 0.0007 of its range of about 2
            >>> reading, round(share, 5)
            (1, 0.00035)
        """
        if self.own is None:
            return None
        ranges = np.ptp(self.own, axis=0)
        varied = np.flatnonzero(ranges > 0)
        if not len(varied):
            return None
        shares = self.largest[varied] / ranges[varied]
        return int(varied[np.argmax(shares)]), float(shares.max())

    @property
    def reached_onset(self) -> bool:
        """Whether the shifted episode played its step ``onset`` (counted from 0), the first one shifted."""
        return self.steps > self.onset

    def summary(self) -> str:
        """What the probe saw, in words."""
        played = (f"{self.steps} steps of " + ("random actions" if self.actions == "random" else "the policy's actions")
                  + f" (seed {self.seed}) from the same reset, onset {self.onset}")
        if not self.changed and not self.reached_onset:  # (nothing was shifted: nothing to say of the shift)
            return (f"{self.shift.spec}: not seen: the episode ended after {played}, before the shift began; "
                    "try an earlier --onset, --sb3 or --policy (a policy that keeps the episode going), or --seed")
        if not self.changed:
            return (f"{self.shift.spec}: nothing the env returned differed from its own over {played} "
                    "(observations, rewards, the episode's end): the shift changed nothing there. An attribute "
                    "the env reads only when it is made or reset, or one a switch turns off, changes nothing after "
                    "the onset (LunarLander builds its world from gravity at reset, and blows wind_power only when "
                    "made with enable_wind=True); pick one its step() reads, or a sensor fault (obs.KIND[i]=VALUE), "
                    "or shift it from onset 0 (the env then resets in the shifted world); "
                    "or the states where it matters were not reached (try --steps, --seed)")
        readings = np.flatnonzero(self.largest > 0)
        shown = ", ".join(f"{i}: {self.largest[i]:.3g}" for i in readings[np.argsort(-self.largest[readings])][:6])
        more = f" and {len(readings) - 6} more" if len(readings) > 6 else ""
        return (f"{self.shift.spec}: differs from the env's own from step {self.first_difference} on, over {played}; "
                f"largest difference by reading: {shown or 'none (the rewards or the end differ)'}{more}; return "
                f"{self.shifted_return:.1f} against {self.own_return:.1f}"
                + (f" (episodes ended: own {self.ended[0]}, shifted {self.ended[1]})" if any(self.ended) else ""))


def probe_shift(shift: EnvShift | Variant, *, seed: int = 0, onset: int = 0, steps: int = 500,
                policy: Callable[[Any], Any] | None = None,
                wrap: Callable[[gymnasium.Env], gymnasium.Env] | None = None) -> ShiftProbe:
    """Play ``shift``'s env as it is (a variant's: its task's ID env) and shifted from ``onset`` on,
    from ``reset(seed=seed)`` with the same random actions (``action_space.seed(seed)``), for
    ``steps`` steps or until either episode ends, and compare what they returned.

    ``policy``: ``obs -> action`` acts in each env instead (the states your policy visits, where a
    shift may matter that random actions never reach; its actions differ once the observations
    do); ``wrap``: what the policy's env is made of the env (``Agent.wrap``: a frame stack), whose
    observations are then compared.

    Raises:
        ConfigError, UnknownParameterError, InvalidParameterError: as :meth:`EnvShift.make`; a
            negative onset; ``steps`` not a whole number >= 1.

    Example:
        >>> from oodmon.envs import parse_env_shift
        >>> probe_shift(parse_env_shift("Acrobot-v1:LINK_MASS_2=3.0"), onset=10, steps=50).first_difference
        11
    """
    from oodmon.errors import InvalidParameterError
    from oodmon.validation import is_whole

    if not is_whole(steps, 1):
        raise InvalidParameterError(f"steps={steps!r} is not allowed; give a whole number >= 1")
    check_onset_step(shift.env_id, onset)
    wrap = wrap or (lambda env: env)
    as_it_is = Variant(shift.task) if isinstance(shift, Variant) else EnvShift(shift.env_id, ())
    own_env, shifted_env = wrap(as_it_is.make()), wrap(shift.make(onset_step=onset))
    try:
        if policy is None:
            own_env.action_space.seed(seed)
            actions = [own_env.action_space.sample() for _ in range(steps)]
            act = lambda step, obs: actions[step]  # noqa: E731
        else:
            act = lambda step, obs: policy(obs)  # noqa: E731
        # One episode after the other, never interleaved: a policy with a memory of its episode, or
        # one that reads each step's action masks from the env, acts in one env at a time.
        own, shifted = _play(own_env, seed, steps, act), _play(shifted_env, seed, steps, act)
    finally:
        own_env.close()
        shifted_env.close()
    played = min(len(own[1]), len(shifted[1]))  # the steps played in both: until either episode ended
    kept: tuple[list, list] = ([], [])
    largest, per_step, first = None, [], None
    for step in range(played + 1):
        flat = [_readings(own_env.observation_space, episode[0][step]) for episode in (own, shifted)]
        difference = np.abs(flat[1] - flat[0])
        difference[np.isnan(flat[0]) & np.isnan(flat[1])] = 0.0  # NaN in both: the same reading
        difference[np.isnan(difference)] = np.inf  # NaN in one
        largest = difference if largest is None else np.maximum(largest, difference)
        per_step.append(float(difference.max(initial=0.0)))
        for keep, values in zip(kept, flat):
            if values.size <= _PLOTTED_READINGS:
                keep.append(values)
        if first is None and difference.any():
            first = step
        if step == played:
            break
        if first is None and (own[1][step] != shifted[1][step] or own[2][step] != shifted[2][step]):
            first = step + 1
    ended = (own[2][played - 1], shifted[2][played - 1]) if played else (False, False)
    return ShiftProbe(shift, onset, seed, played, first, largest, np.array(per_step),
                      np.array(kept[0]) if kept[0] else None, np.array(kept[1]) if kept[1] else None,
                      sum(own[1][:played]), sum(shifted[1][:played]), ended, "random" if policy is None else "policy")


def _play(env: gymnasium.Env, seed: int, steps: int,
          act: Callable[[int, Any], Any]) -> tuple[list[Any], list[float], list[bool]]:
    """One episode of ``env`` from ``reset(seed=seed)``, ``act(step, obs)`` acting, for ``steps``
    steps or until it ends: its observations (``reset``'s first), rewards and whether each step ended it."""
    observations, rewards, ends = [env.reset(seed=seed)[0]], [], []
    for step in range(steps):
        action = act(step, observations[-1])
        obs, reward, terminated, truncated, _ = step_naming_refusal(env, action, step=step + 1, seed=seed)
        observations.append(obs)
        rewards.append(float(reward))
        ends.append(bool(terminated or truncated))
        if ends[-1]:
            break
    return observations, rewards, ends


def _readings(space: gymnasium.Space, obs: Any) -> np.ndarray:
    """An observation's numbers, flattened (a dict's as ``gymnasium.spaces.flatten`` orders them)."""
    if isinstance(space, (gymnasium.spaces.Dict, gymnasium.spaces.Tuple)):
        obs = gymnasium.spaces.flatten(space, obs)
    return np.asarray(obs, dtype=np.float64).reshape(-1)
