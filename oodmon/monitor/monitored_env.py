"""An env whose steps a :class:`~oodmon.monitor.monitor.Monitor` scores and logs, and the check that
an env is one the monitored policy can act in.

``MonitoredEnv(env, monitor)`` is a gymnasium wrapper: ``step()`` without an action lets the
monitored policy act, ``step(action)`` takes yours, and every step's ``info["oodmon"]`` says what
the monitor made of it. Use it where a loop expects an env (SB3's ``evaluate_policy``, a vector env
of them, a Monitor each). Actions you give are the deployed ones, which the detectors learned: an
SB3 model's ``predict(obs, deterministic=True)`` (``evaluate_policy``'s default; ``predict``'s own
default samples, and a policy's sampled or random actions lead where the dynamics model never saw
its actions lead: a PPO on CartPole-v1 stepped with its sampled actions alarmed in 20 of 20 ID
episodes, ``scripts/exploration_alarms.py``).
"""

from __future__ import annotations

import warnings
import weakref
from typing import Any

import gymnasium

from oodmon.agents.agent import Agent
from oodmon.agents.sb3_spaces import words_of
from oodmon.envs.checks import space_mismatch, step_naming_refusal
from oodmon.envs.registration import env_id_of, obs_noise_of_env, onset_of_env, variant_of_env, wrappers_of
from oodmon.envs.shift import AnotherEnv, another_env_id
from oodmon.errors import ConfigError
from oodmon.monitor.alarms import compared_name
from oodmon.monitor.monitor import Monitor, NonFiniteObservationWarning, PolicyCannotAct, _frame

__all__ = ["MonitoredEnv", "check_env_of", "check_one_env"]


def check_one_env(env: Any) -> None:
    """Refuse what is not one gymnasium env (a vector env; an env id given where the env goes).

    Raises:
        ConfigError: saying what to give instead.
    """
    if not isinstance(env, gymnasium.Env):
        vector = hasattr(env, "num_envs")
        raise ConfigError(f"the env to monitor is one gymnasium env, the one you step; got a {type(env).__name__}"
                          + (" (a vector env): wrap each of its envs in a MonitoredEnv with a Monitor of its own "
                             "(monitor.twin() makes one like a monitor you have)" if vector else "")
                          + (f" ({env!r} is an env id: give the env itself, gymnasium.make({env!r}); oodmon.watch "
                             f"takes the id as its second argument, watch(policy, {env!r}))" if isinstance(env, str)
                             else ""))


def check_env_of(agent: Agent, env: gymnasium.Env) -> None:
    """Refuse an env whose observation or action space is not of the type and shape of the agent's
    own env's (``agent.make_env()``): an env of another task, which the policy cannot act in.

    Raises:
        ConfigError: something that is not one gymnasium env (a vector env), or naming the space,
            the env's and the agent's.
    """
    check_one_env(env)
    own = agent.make_env()
    if agent.dict_space is not None and not isinstance(env.observation_space, gymnasium.spaces.Box):
        env = _read_as(agent, env)
    try:
        what = space_mismatch(own, env)
    finally:
        own.close()
    if what is not None:
        stacked = "" if agent.frame_stack is None else (
            f" (the agent acts on observations stacked {agent.frame_stack} deep: wrap the env you step in "
            + (f"oodmon.agents.frame_stack.FrameStack(env, {agent.frame_stack}))" if agent.stacking.pad is None
               else f"agent.wrap(env), {_WRAP_FOR_WATCH})"))
        raise ConfigError(f"this env's {what} is {getattr(env, what)}, but {agent.task}/{agent.method} acts in "
                          f"{env_id_of(own)}, whose {what} is {getattr(own, what)}: an env of another task?{stacked}")
    if agent.stacking is not None and agent.stacking.pad is not None and _stacking_of(env) != agent.stacking:
        raise ConfigError(f"{agent.task}/{agent.method} was trained inside VecFrameStack(VecNormalize(env), "
                          f"{agent.frame_stack}): before an episode's first observation its stack holds the "
                          f"statistics' mean, not zeros; step the env agent.wrap(env) gives ({_WRAP_FOR_WATCH})")


def _read_as(agent: Agent, env: gymnasium.Env) -> gymnasium.Env:
    """``env`` with its spaces as ``agent`` reads them (nothing stepped): its dicts or discrete
    values flattened, the text of its dicts left out for a policy that reads it (the agent's
    :attr:`~oodmon.agents.Agent.reads_words`); ``env`` itself where they do not flatten (text
    another agent does not read: MiniGrid's mission, which gymnasium cannot flatten)."""
    space = env.observation_space
    words = words_of(space) if agent.reads_words else ()
    if words:
        space = gymnasium.spaces.Dict({key: sub for key, sub in space.spaces.items() if key not in words})
    try:
        return gymnasium.wrappers.TransformObservation(env, lambda obs: obs, gymnasium.spaces.flatten_space(space))
    except NotImplementedError:
        return env


def _another_env(agent: Agent, env: gymnasium.Env) -> bool:
    """Whether ``env`` is another registered env than the one ``agent``'s policy acts in (its
    ``env_id``), with no shift of its own: MiniGrid's DistShift2 for a policy of DistShift1."""
    if env.spec is None or agent.env_id is None or variant_of_env(env) != env_id_of(env):
        return False
    return another_env_id(env_id_of(env), agent.env_id) is not None


#: Where a user of :func:`oodmon.watch` finds the agent whose ``wrap`` stacks their env.
_WRAP_FOR_WATCH = "with oodmon.watch, call it without env= and step MonitoredEnv(monitor.agent.wrap(env), monitor)"


def _stacking_of(env: gymnasium.Env) -> Any:
    """The :class:`~oodmon.agents.frame_stack.Stacking` of the first ``FrameStack`` wrapping ``env``, or ``None``."""
    from oodmon.agents.frame_stack import FrameStack

    return next((wrapper.stacking for wrapper in wrappers_of(env) if isinstance(wrapper, FrameStack)), None)


class MonitoredEnv(gymnasium.Wrapper):
    """An env whose steps are scored and logged by a :class:`Monitor`.

    ``step()`` with no action lets the monitored policy act; ``step(action)`` takes your action
    (the monitor still scores and logs the policy's estimate at that observation). Every step's
    ``info["oodmon"]`` holds every detector's score (``scores``), the alarm's (``score``,
    ``detector``), the ``threshold`` and whether the ``alarm`` rule holds; when an alarm callback
    ended the episode (it returned True: the step is ``truncated``), ``ended_by_alarm`` says which
    alarm. A reset that no step follows logs no episode. A policy that cannot act on a NaN or
    infinite observation (SB3's raise) does not step the env: that step is logged and alarmed, the
    episode ends there (``truncated``, reward 0, ``info["oodmon"]["policy_could_not_act"]`` says
    why) with a :class:`NonFiniteObservationWarning`, as ``oodmon run`` ends it. An env of another
    registered id than the policy's (MiniGrid's DistShift2 for a policy of DistShift1) is its
    shifted world, each step from its reset on (:class:`~oodmon.envs.AnotherEnv`), in the log and
    in replay.

    Example:
        >>> from oodmon.agents import load
        >>> env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), Monitor(load("cartpole", "dropout")))
        >>> obs, info = env.reset(seed=0)
        >>> obs, reward, terminated, truncated, info = env.step()
        >>> env.monitor.episode, reward
        (0, 1.0)
    """

    def __init__(self, env: gymnasium.Env, monitor: Monitor, *, variant: str | None = None) -> None:
        if monitor.agent is not None:
            check_env_of(monitor.agent, env)  # its kind, then its spaces
        else:
            check_one_env(env)
        if variant is None and monitor.agent is not None and _another_env(monitor.agent, env):
            env = AnotherEnv(env)  # each of its steps shifted, in the log and in replay
        super().__init__(env)
        self.monitor = monitor
        self.variant = variant
        self._compares = compared_name(monitor.tracker.rule) is not None  # info["oodmon"]["compared"]
        self._obs: Any = None
        self._info: dict = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)  # (an episode still running ends at begin_episode)
        self.monitor.begin_episode(env_id=env_id_of(self.env), variant=self.variant or variant_of_env(self.env),
                                   onset=onset_of_env(self.env), seed=seed, obs_noise=obs_noise_of_env(self.env))
        self.monitor._episode_owner = weakref.ref(self)  # weak: a monitor does not keep an old env alive
        self.monitor._tell_masks(self.env)
        self._obs, self._info = obs, info
        return obs, info

    def step(self, action: Any = None):
        owner = self.monitor._episode_owner
        if not self.monitor.in_episode:  # (the monitor's own words name its begin_episode, which an env's user never calls)
            raise ConfigError("step() with no episode running: reset() the env first, before its first step and "
                              "after an episode ended (terminated or truncated) or the env was closed")
        if owner is None or owner() is not self:
            raise ConfigError("this env's Monitor follows an episode that another MonitoredEnv began (one Monitor "
                              "shared by several envs, as in a vector env of MonitoredEnvs? their steps would mix "
                              "into one episode's log): give each env its own Monitor (monitor.twin()), or reset this env first")
        # Your action, when you give one, is the deployed one: the detectors that model transitions see it.
        try:
            chosen = self.monitor.step(self._obs, action=action, shifted=bool(self._info.get("shifted", False)),
                                       frame=_frame(self._obs))
        except PolicyCannotAct as error:  # logged and alarmed; the env is not stepped, the episode ends (truncated)
            warnings.warn(NonFiniteObservationWarning(f"{error}; the episode ends there"), stacklevel=2)
            info = {**self._info, "oodmon": {**self._telemetry(), "policy_could_not_act": str(error)}}
            self.monitor.end_episode(terminated=False)
            self._info = info
            return self._obs, 0.0, False, True, info
        if action is None:  # the policy's action: one the env refuses is named (yours keeps the env's own error)
            obs, reward, terminated, truncated, info = step_naming_refusal(self.env, chosen, step=self.monitor._length,
                                                                           episode="this episode")
        else:
            obs, reward, terminated, truncated, info = self.env.step(chosen)
        self.monitor._tell_masks(self.env)
        self.monitor.add_reward(reward)
        info = {**info, "oodmon": self._telemetry()}
        truncated = truncated or self.monitor.stop_requested
        if terminated or truncated:
            self.monitor.end_episode(terminated=bool(terminated))
        self._obs, self._info = obs, info
        return obs, reward, terminated, truncated, info

    def _telemetry(self) -> dict[str, Any]:
        """``info["oodmon"]``: what the monitor made of the step just taken (its observation is the
        one the action was chosen at)."""
        record, monitor = self.monitor.last_step, self.monitor
        telemetry = {"step": record.step, "scores": dict(record.scores), "score": record.score,
                     "detector": monitor.detector, "threshold": record.threshold, "alarm": record.alarm}
        if self._compares:  # a window's mean, a sequential statistic: what the threshold is compared with
            telemetry["compared"] = record.compared
        if record.alarm:  # what raised the score at this step (AlarmEvent.cause), while the alarm holds
            telemetry["cause"] = monitor.last_cause
        if monitor.last_alarm is not None and monitor.last_alarm.readings:  # at the step an alarm is raised
            telemetry["readings"] = [list(pair) for pair in monitor.last_alarm.readings]
            telemetry["readings_steps"] = monitor.last_alarm.readings_steps
            if any(monitor.last_alarm.reading_names):  # ("" where a reading has none)
                telemetry["reading_names"] = list(monitor.last_alarm.reading_names)
        if monitor.last_alarm is not None and monitor.last_alarm.region is not None:  # a picture's part (vanishing)
            telemetry["region"] = monitor.last_alarm.region._asdict()
        if monitor.stop_event is not None:
            event = monitor.stop_event
            telemetry["ended_by_alarm"] = f"an alarm callback ended the episode: {event.text()}"  # the alarm log's line
        return telemetry

    def close(self) -> None:
        self.monitor.close()  # an episode still running is logged as interrupted
        super().close()
