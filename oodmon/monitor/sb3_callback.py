"""The monitor inside stable-baselines3: a callback that scores the rollouts of ``model.learn()``.

``MonitorCallback(monitor)`` watches the first env of the model's training env: at every step it
gives the monitor the observation the model acted on and the action the env got, so that every
detector scores the model's own behaviour, and writes through SB3's logger (TensorBoard, CSV,
stdout, whichever the model has):

- ``oodmon/score`` (the alarm detector's score) and ``oodmon/score_<detector>`` for each detector,
  as means over the steps since the last dump;
- ``oodmon/alarm_share``: the share of those steps where the alarm rule held;
- ``oodmon/alarms``: alarms raised so far; ``oodmon/threshold``.

**Exploration reads as a shift.** The detectors were fitted on the deployed policy's own actions
(its deterministic ones, as ``predict(obs, deterministic=True)`` gives them), and a model that
learns explores: a DQN's random actions, a PPO's or SAC's sampled ones. The dynamics model, which
never saw another action in those states, is surprised by their outcomes, so a training run's alarms
are mostly its exploration, not a shift of the world (``scripts/exploration_alarms.py``, 2026-12-07,
with the deployed policy's detectors and threshold: a DQN on CartPole-v1 taking a random action at
5% of its steps alarmed in 5 of 20 ID episodes, a PPO so in 20 of 20 and with its sampled actions in
20 of 20, a SAC's sampled actions on Reacher-v5 in 10 of 10; each deterministic in none). The
callback compares the first :data:`EXPLORATION_CHECKED` training steps' actions with the model's
deterministic one at the same observation and, where some differ, says how many
(:class:`ExplorationWarning`), once. Detectors fitted on episodes with some random actions
(``oodmon.watch(..., fit_explore=0.1)``, ``oodmon calibrate --fit-explore 0.1``) have seen other
actions' outcomes: the PPO's 5% random actions then alarmed 0 of 20, its sampled ones 8 of 20, the
DQN's 1 and 0 of 20, and the pole twice as long still 20 of 20 each at delay 1; the callback then
warns only where more steps explored than that share.

**So does learning.** A model that learns on changes what it does, and the states it comes to
visit move from those the detectors were fitted on, whatever their fit saw of other actions: after
4,096 more training steps, deciding deterministically, the DQN alarmed 17 of 20 ID episodes under
either monitor, the SAC 10 and 7 of 10, the PPO 4 and 0 of 20, and monitors fitted and calibrated
anew on each new policy none (the same script). A training run's alarms read its exploration and
its learning besides the world; the policy you deploy gets its own fit and calibration.

The monitor's sinks (MCAP, Rerun) log every step as in any run. For evaluation rollouts, wrap the
evaluation env instead: ``evaluate_policy(model, MonitoredEnv(env, monitor))`` or
``EvalCallback(MonitoredEnv(env, monitor))``; the wrapper takes SB3's actions as the deployed
ones and logs no phantom episode for a vector env's last auto-reset.

Example::

    from oodmon.monitor import Monitor
    from oodmon.monitor.sb3_callback import MonitorCallback
    model = DQN("MlpPolicy", "CartPole-v1", tensorboard_log="runs/tb")
    with Monitor(None, threshold, detectors=detectors) as monitor:   # None: it watches the model's actions
        model.learn(50_000, callback=MonitorCallback(monitor))
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from oodmon.envs.registration import env_id_of, obs_noise_of_env, task_of_env, variant_of_env
from oodmon.monitor.monitor import ActionTally, Monitor, _frame

__all__ = ["EXPLORATION_CHECKED", "ExplorationWarning", "MonitorCallback"]

#: The first training steps whose action the callback compares with the model's deterministic one.
EXPLORATION_CHECKED = 100


class ExplorationWarning(UserWarning):
    """:class:`MonitorCallback`: some of the first training steps took another action than the
    model's deterministic one (exploration), which the detectors, fitted on the deployed policy's
    own actions, read as a shift. Warned once per callback."""


class MonitorCallback(BaseCallback):
    """Scores every training step of the first env with ``monitor`` and logs it through SB3's
    logger (see the module docstring)."""

    def __init__(self, monitor: Monitor, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.monitor = monitor
        monitor.compares_given_actions = False  # (the training steps' actions are checked here, in the model's terms)
        self._obs: np.ndarray | None = None  # the first env's raw observation the model acts on next
        self._model_obs: Any = None  # that observation as the model reads it (normalised, channels first)
        self._tally = ActionTally(EXPLORATION_CHECKED)  # training steps compared with the deterministic action

    @property
    def alarms(self) -> int:
        """Alarms the monitor raised so far."""
        return self.monitor.alarms_raised

    def _variant(self) -> tuple[str, str, float]:
        """``(env_id, variant, obs_noise)`` of the first env, read from it where the vector env holds
        it here (else its id, and no sensor noise)."""
        envs = getattr(self.training_env, "envs", None)
        if envs:
            return env_id_of(envs[0]), variant_of_env(envs[0]), obs_noise_of_env(envs[0])
        spec = self.training_env.get_attr("spec", [0])[0]
        spec_id = spec.id if spec is not None else "unknown"
        return spec_id, task_of_env(spec_id) or spec_id, 0.0

    def _raw(self, observations: np.ndarray) -> np.ndarray:
        """The first env's observation as the env gave it: before the model's VecNormalize, if any
        (which holds the raw ones of the observations it last returned); a dict one flattened, as
        the monitor's agent reads it (``Agent.view``), its pictures as the env gave them (SB3's
        VecTransposeImage moved their channels first). The dict's space: the monitor's agent's,
        else the first env's own (a monitor with no agent)."""
        normalize = self.model.get_vec_normalize_env()
        raw = observations if normalize is None else normalize.get_original_obs()
        if not isinstance(raw, dict):
            return raw[0]
        space = getattr(self.monitor.agent, "dict_space", None)
        if space is None:
            space = self.training_env.get_attr("observation_space", [0])[0]
        first = {key: _as_the_env_gave_it(value[0], space[key].shape) for key, value in raw.items()}
        return gymnasium.spaces.flatten(space, first)

    def _on_training_start(self) -> None:
        self.monitor.open()
        # Not the model's _last_original_obs: DQN, SAC and TD3 hold there the observation of the step
        # before (without VecNormalize), PPO and A2C the one learn() began with (with it).
        self._obs = self._raw(self.model._last_obs)
        self._model_obs = _first(self.model._last_obs)

    def _on_step(self) -> bool:
        monitor = self.monitor
        if not monitor.in_episode:
            env_id, variant, obs_noise = self._variant()
            monitor.begin_episode(env_id=env_id, variant=variant, obs_noise=obs_noise)
        obs, model_obs = self._obs, self._model_obs
        self._obs = self._raw(self.locals["new_obs"])  # after an episode's end, the next one's first
        actions = self.locals.get("clipped_actions", self.locals["actions"])  # what the env got (PPO clips)
        action = actions[0]
        if self._tally.counting:
            self._check_exploration(model_obs, action)
            self._model_obs = _first(self.locals["new_obs"])  # (kept only while the check goes on)
        action = int(action) if np.ndim(action) == 0 else np.asarray(action)
        monitor.step(obs, action=action, frame=_frame(obs))
        record = monitor.last_step
        self.logger.record_mean("oodmon/score", record.score)
        for name, value in record.scores.items():
            self.logger.record_mean(f"oodmon/score_{name}", value)
        self.logger.record_mean("oodmon/alarm_share", float(record.alarm))
        self.logger.record("oodmon/alarms", monitor.alarms_raised)
        if np.isfinite(monitor.threshold):
            self.logger.record("oodmon/threshold", monitor.threshold)
        monitor.add_reward(float(self.locals["rewards"][0]))
        if self.locals["dones"][0]:
            info: dict[str, Any] = self.locals["infos"][0]
            monitor.end_episode(terminated=not info.get("TimeLimit.truncated", False))
        return True

    def _on_training_end(self) -> None:
        if self.monitor.in_episode and not self.monitor.abandon_empty_episode():
            self.monitor.end_episode(interrupted=True)  # cut by the end of learn(): not a whole episode
        if self._tally.partial:  # a learn() shorter than the steps checked
            self._warn_exploration()

    def _check_exploration(self, model_obs: Any, action: Any) -> None:
        """Compare a training step's action with the model's deterministic one at its observation;
        after :data:`EXPLORATION_CHECKED` steps, warn if some differed. A recurrent policy (whose
        action needs its memory of the episode) is not compared."""
        if "lstm_states" in self.locals:
            self._tally.cut()
            return
        masks = self.locals.get("action_masks")  # a MaskablePPO's: its deterministic action among the allowed
        masked = {} if masks is None else {"action_masks": masks[0]}
        deployed, _ = self.model.predict(model_obs, deterministic=True, **masked)
        if self._tally.add(deployed, action):
            self._warn_exploration()

    def _warn_exploration(self) -> None:
        """Say how many checked steps explored, unless the detectors were fitted on at least as
        large a share of random actions (``fitted_for["explore"]``)."""
        explore = float(self.monitor.detectors.fitted_for.get("explore") or 0.0)
        explored, checked = self._tally.differed, self._tally.checked
        if not explored or explored <= explore * checked:
            return
        said = f"{explored} of the first {checked} training steps took another action than the model's " \
               "deterministic one (its exploration)"
        if explore:
            warnings.warn(ExplorationWarning(
                f"{said}, more than the {100 * explore:.3g}% of random actions the detectors were fitted with: some "
                "alarms while it learns may be its exploration (a PPO's sampled actions on CartPole-v1 alarmed 8 of "
                "20 ID episodes with detectors fitted on 10% of random actions, its deterministic ones 1); a larger "
                "fit_explore (--fit-explore) reads more of them as ID"), stacklevel=2)
            return
        warnings.warn(ExplorationWarning(
            f"{said}: the detectors, fitted on the deployed policy's own actions, read such steps as a shift, so "
            "many alarms while it learns are its exploration (a PPO's sampled actions on CartPole-v1 alarmed 20 of 20 "
            "ID episodes, its deterministic ones none); detectors fitted with some random actions read them as ID "
            "(oodmon.watch(..., fit_explore=0.1), `oodmon calibrate --fit-explore 0.1`: the PPO's 5% random actions "
            "then alarmed 0 of 20, its sampled ones 8), though not the states a policy that learns on comes to "
            "visit; the deployed policy's alarms are those of oodmon run, or of evaluate_policy(model, "
            "MonitoredEnv(...)), with detectors fitted on it"), stacklevel=2)


def _first(observations: Any) -> Any:
    """The first env's observation of a vector env's batch (a dict's, key by key), as the model reads it."""
    if isinstance(observations, dict):
        return {key: value[0] for key, value in observations.items()}
    return observations[0]


def _as_the_env_gave_it(value: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` of the env's ``shape``: a picture whose channels SB3 moved first, moved back last.

    Example:
        >>> _as_the_env_gave_it(np.zeros((3, 4, 5)), (4, 5, 3)).shape
        (4, 5, 3)
    """
    value = np.asarray(value)
    if value.shape != tuple(shape) and len(shape) == 3 and value.shape == (shape[2], shape[0], shape[1]):
        return np.moveaxis(value, 0, -1)
    return value
