"""``dynamics``: how badly a model of the ID world predicts what the sensors report next.

An ensemble of probabilistic MLPs (PEDM, Haider et al., AAMAS 2023) learns, from ID transitions
of the deployed policy, a Gaussian over the state change ``s' - s`` given ``(s, a)``. At each
step the monitor knows the previous observation and action and the new observation, so it can
ask how surprising that change is:

- ``nll`` (the default): the negative log-likelihood of the observed change under the members'
  mixture, per dimension.
- ``pedm`` (PEDM's ``pred_error_samples`` / ``min_mean``): draw ``n_draws`` predictions from
  each member's Gaussian; the score is the smallest mean squared error, per dimension normalised
  by the ID spread of the change, between a drawn change and the observed one.

Measured on the shipped ensembles (20 fit episodes; 10 ID against 5 shifted episodes per
variant, every transition), ``nll`` separates better: CartPole at 1% sensor noise, length=2.0,
gravity=98, force_mag=1, masscart=9, masspole=9, length=0.1: AUROC 0.998-1.000 against
``pedm``'s 0.967-1.000; Pendulum g=50, m=5, l=0.1, max_speed=1.6 and 4.0, max_torque=0.4:
0.954-1.000 against 0.943-1.000.

A step's score is the mean surprise over the episode's last ``window`` transitions (20 by
default): one transition of a shifted world often looks ordinary (Pendulum near rest, a CartPole
pole near upright, where gravity and mass hardly act), a run of them rarely does. Measured on the
shipped Pendulum ensemble (g=50, m=5, l=0.1, max_speed=1.6 and 4.0, max_torque=0.4; per-step
AUROC): window 1 gives 0.952-0.998 (mean 0.977), window 20 gives 0.986-0.997 (mean 0.991).

Until ``window`` transitions have come since the reset the mean covers fewer: a mean of few is
noisier, and the first transitions of an episode are its most surprising (the shipped CartPole
ensemble's: -2.3 at the first, -4.02 after step 100, sd 0.09). The highest scores of ID episodes
came in their first steps (50 of 50 of that agent's calibration episodes), and since an alarm's
threshold is the height the calibration episodes reach, those early peaks set it for whole
episodes. With ``early="standardised"`` (fits since
:data:`~oodmon.monitor.detectors.fitting.FIT_VERSION` 6) a mean of n < ``window`` transitions is
moved toward the ID median by ``sqrt(n / window)``
(:func:`~oodmon.monitor.detectors.base.standardise_early`), as much as a mean of independent
values needs to vary as a full window's does; the start-up's own excess is shrunk with it, not
removed (docs/detectors.md's "Early steps" measures both); ``early="mean"`` (every set fitted before)
keeps the plain mean.

It trains 100 epochs (since fitting version 9; version 8 stopped at 3,000 Adam updates, which left
CartPole's fit of 30,000 transitions 50 epochs, and ``max_updates`` still caps them so), the
learning rate falling linearly from ``lr`` to 0 over them (``schedule="linear"``; since fitting
version 8; before, 30 epochs at a constant ``lr``). After 30 epochs at a constant rate the model
was still moving, and where a fit happened to stop set the alarm: four seeds of the CartPole
DropConnect agent's fit, on 90 episodes, gave median delays of 6-16 steps on ``gravity=29.4`` and
1.5-7 on ``gravity=49.0`` (the dynamics alarm alone, at the largest peak of 90 held-out ID
episodes; ``scripts/dynamics_training.py``, which has the other fits measured: 100 epochs with the
decay 1-1.5 and 1, 30 with it 2.5-4 and 1). No fit alarmed any of 110 further held-out ID episodes.
The monitor's benchmark measures the same through the combined alarm
(``results/monitor/README.md``): 30 epochs with the decay slowed Pendulum's alarms, 100 kept or
shortened every one on both tasks. Version 8's cap of 3,000 updates bounded a large fit's time
(30,000 transitions on one core: 50 epochs some 6 s, 100 some 12, the zoo's refits) and blunted it:
a PPO's InvertedPendulum, 25-50 epochs, read a pole four times as heavy as ID where every epoch
spiked at its onset (``scripts/dynamics_cap.py``); the monitor's benchmark of the zoo's CartPole
agents and docs/your-policy.md's four benches of a user's own env alarmed as often or more, and as soon or
sooner, with every epoch (docs/detectors.md, ``--dynamics-updates``, which still takes a cap).

Two hidden layers of 64 units: 128 and 200 measured no better (Pendulum above: per-step AUROC
0.954-1.000 at 64 and at 128, window 1) and cost the monitor more per step.

Neither assumes a deterministic simulator: each member predicts a variance, so sensor noise in
the ID world (``obs_noise``) is part of what it learns. Vector observations only, stacked ones
(CartPole's state 4 deep, (4, 4)) modelled flattened; images go to the frames detector (see the
docs/pong.md). The first step of an episode has no transition yet: it scores the median ID score.

Training is torch (the members' weights stacked, one batched product per layer); scoring is
numpy, a few microseconds per step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.special import expit

from oodmon.agents.plan import repeat_rows
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.detectors.base import Detector, RecentMean, StepContext, Trajectory, standardise_early
from oodmon.monitor.detectors.frames import is_picture
from oodmon.progress import Progress
from oodmon.validation import is_whole

__all__ = ["JUMP_VALUES", "MAX_UPDATES", "MIN_LOGVAR", "DynamicsDetector", "check_max_updates", "min_logvar_for"]

_KINDS = ("pedm", "nll")
_EARLY = ("standardised", "mean")  # the score over fewer than window transitions (see DynamicsDetector)
_SCHEDULES = ("linear", "constant")  # Adam's learning rate over the fit (see DynamicsDetector)
#: The fit's default cap of Adam updates (``DynamicsDetector(max_updates=)``; ``--dynamics-updates``
#: and ``dynamics_updates=`` of the commands and functions that fit): none since fitting version 9,
#: every one of the fit's epochs (3,000 in version 8).
MAX_UPDATES: int | None = None
_CONSTANT_Z = 16.0  # the fast path's constant pre-activation (see _FastNll)
_ADAM_BETAS, _ADAM_EPS, _WEIGHT_DECAY = (0.9, 0.999), 1e-8, 1e-5  # the fit's Adam: torch's defaults, L2 decay
_MIN_LOGVAR, _MAX_LOGVAR = -12.0, 2.0  # soft bounds of the predicted log-variance (the lower one: min_logvar)

#: ``min_logvar`` per task where it is not the default -12 (chosen by measurement, see docs/detectors.md's
#: detector section); fitting an agent's detectors uses its task's.
MIN_LOGVAR: dict[str, float] = {"pendulum": -6.0}


#: A reading whose change takes at most this many distinct values over the ID transitions jumps
#: (a flag: -1, 0, +1) or never moves: the dynamics model takes it as an input and predicts the others.
JUMP_VALUES = 3


def check_max_updates(max_updates: Any, name: str = "max_updates") -> None:
    """Refuse a cap of the dynamics fit's updates that is neither a whole number >= 1 nor ``None``.

    Raises:
        InvalidParameterError: naming ``name`` (the parameter the caller took it as).
    """
    if max_updates is not None and not is_whole(max_updates):
        raise InvalidParameterError(f"{name}={max_updates!r} is not allowed; give an integer >= 1, or None "
                                    "(every epoch)")


def _numbers(value: Any) -> np.ndarray:
    """``value`` as float64 numbers, or an empty array where it is none (text, ``None``, ragged lists)."""
    try:
        array = np.asarray(value)
    except ValueError:  # (ragged lists)
        return np.empty(0)
    return array.astype(np.float64) if array.dtype.kind in "biuf" else np.empty(0)


def min_logvar_for(task: str | None) -> float:
    """The floor of the predicted log-variance for ``task``'s dynamics detector.

    Example:
        >>> min_logvar_for("pendulum"), min_logvar_for("cartpole"), min_logvar_for(None)
        (-6.0, -12.0, -12.0)
    """
    return MIN_LOGVAR.get(task or "", _MIN_LOGVAR)


class DynamicsDetector(Detector):
    """PEDM: a probabilistic ensemble dynamics model's surprise at each observed transition.

    Args:
        n_actions: the number of discrete actions (one-hot inputs), or ``None`` for continuous
            actions (normalised inputs).
        kind: ``"nll"`` or ``"pedm"`` (see the module docstring).
        members: ensemble members.
        hidden: units of each of the two hidden layers (SiLU).
        n_draws: predictions drawn per member per step (``pedm``).
        epochs: passes over the ID transitions when fitting, fewer where ``max_updates`` ends them.
        window: the step's score is the mean surprise over the episode's last ``window``
            transitions (1: each transition's own).
        batch_size, lr: Adam's minibatch and learning rate.
        neutral: the score of an episode's first step (set by :meth:`fit`).
        min_logvar: the soft floor of each predicted (normalised) log-variance. Without sensor
            noise a simulator's transitions are exact and the model learns variances near the
            floor, so the few ID steps it predicts slightly wrong look very surprising; a higher
            floor caps that surprise (see :data:`MIN_LOGVAR` for the tasks' values).
        seed: seeds fitting and the draws: the same seed gives the same scores.
        predicted: the readings (flattened indices) whose change is predicted and scored; ``None``:
            every one. Set by :meth:`fit`: a reading whose change takes at most
            :data:`JUMP_VALUES` values over the ID transitions (a contact flag's -1, 0, +1; a
            reading that never moved) is an input only. A Gaussian cannot model such a jump: one
            LunarLander leg touching down in an ID episode, never seen in fitting, scored 4e8 and
            set the threshold there (2026-11-29). Every reading is kept when none varies otherwise.
        early: ``"standardised"`` (the default): a mean over n < ``window`` transitions, just after
            a reset, is moved toward ``neutral`` by ``sqrt(n / window)``; ``"mean"``: the plain
            mean (what a file without the key was fitted with; see the module docstring).
        schedule: ``"linear"`` (the default): Adam's learning rate falls from ``lr`` to 0 along the
            fit's updates; ``"constant"``: ``lr`` throughout (what a file without the key was
            fitted with; see the module docstring).
        max_updates: the fit runs as many whole epochs (at least one, at most ``epochs``) as hold
            at most this many Adam updates, so that a large fit's time is bounded (``None``, the
            default since fitting version 9: every epoch; what a file without the key was fitted with).
    """

    name = "dynamics"
    learned = True

    def __init__(self, n_actions: int | None = None, *, kind: str = "nll", members: int = 5, hidden: int = 64,
                 n_draws: int = 4, epochs: int = 100, batch_size: int = 512, lr: float = 2e-3, window: int = 20,
                 seed: int = 0, neutral: float = 0.0, min_logvar: float = _MIN_LOGVAR, flatten: bool = False,
                 predicted: Sequence[int] | None = None, early: str = "standardised", schedule: str = "linear",
                 max_updates: int | None = MAX_UPDATES) -> None:
        if kind not in _KINDS:
            raise InvalidParameterError(f"kind={kind!r} is not allowed; use one of {', '.join(_KINDS)}")
        if early not in _EARLY:
            raise InvalidParameterError(f"early={early!r} is not allowed; use one of {', '.join(_EARLY)}")
        if schedule not in _SCHEDULES:
            raise InvalidParameterError(f"schedule={schedule!r} is not allowed; use one of {', '.join(_SCHEDULES)}")
        check_max_updates(max_updates)
        # (numpy's integers as Python's: the config is saved as JSON)
        self.early, self.schedule = early, schedule
        self.max_updates = None if max_updates is None else int(max_updates)
        for label, value in (("members", members), ("hidden", hidden), ("n_draws", n_draws), ("epochs", epochs),
                             ("batch_size", batch_size), ("window", window)):
            if not is_whole(value):
                raise InvalidParameterError(f"{label}={value!r} is not allowed; it must be an integer >= 1")
        if n_actions is not None and not is_whole(n_actions, 2):
            raise InvalidParameterError(f"n_actions={n_actions!r} is not allowed; give the number (>= 2) of "
                                        "discrete actions, or None for continuous actions")
        if not isinstance(min_logvar, (int, float)) or isinstance(min_logvar, bool) or not (
                -30.0 <= min_logvar < _MAX_LOGVAR):
            raise InvalidParameterError(f"min_logvar={min_logvar!r} is not allowed; give a number in [-30, {_MAX_LOGVAR:g})")
        self.min_logvar = float(min_logvar)
        self.n_actions, self.kind, self.members, self.hidden = n_actions, kind, members, hidden
        self.n_draws, self.epochs, self.seed = n_draws, epochs, seed
        self.batch_size, self.lr, self.window, self.neutral = batch_size, lr, window, float(neutral)
        self.flatten = bool(flatten)  # set by fit: the observations are stacked vectors, modelled flattened
        # set by fit: the readings whose change the model predicts (None: every one); the others,
        # which jump between a few values (contact flags, one-hot keys), are its inputs only
        if predicted is not None and (isinstance(predicted, (str, bytes, Mapping))
                                      or not all(is_whole(i, 0) for i in predicted)):
            raise InvalidParameterError(f"predicted={predicted!r} is not allowed; give the indices (whole numbers "
                                        ">= 0) of the readings the model predicts, or None for every one")
        self.predicted = None if predicted is None else np.asarray(predicted, dtype=np.int64)
        self._recent = RecentMean(window)
        self._weights: list[tuple[np.ndarray, np.ndarray]] | None = None
        self._norm: dict[str, np.ndarray] = {}
        self._fast: _FastNll | None = None  # built on first use from the fitted weights
        self.scored: StepContext | None = None  # the step whose transition the fast path's buffers hold
        self._rng = np.random.default_rng(seed)
        self.epochs_trained: int | None = None  # set by fit() (a loaded model does not know it)

    @property
    def fitted(self) -> bool:
        return self._weights is not None

    @property
    def obs_dim(self) -> int | None:
        return None if not self.fitted else len(self._norm["obs_mean"])

    # -- inputs ------------------------------------------------------------------------------------
    def action_refusal(self, action: Any) -> str | None:
        """Why the model cannot read ``action`` (the end of a sentence), or ``None``: of discrete
        actions, one whole number from 0 to n - 1; of continuous ones, as many finite numbers as it
        was fitted on.

        Example:
            >>> DynamicsDetector(2).action_refusal(2)
            'is not one of the 2 discrete actions (0 to 1) the dynamics model was fitted on'
        """
        if self.n_actions is not None:
            if isinstance(action, (int, np.integer)):  # (the common case, at every step: 5 us less than below)
                whole = 0 <= action < self.n_actions
            else:
                value = _numbers(action)
                number = value.reshape(-1)[0] if value.size == 1 else math.nan
                whole = math.isfinite(number) and number == round(number) and 0 <= number < self.n_actions
            return None if whole else (f"is not one of the {self.n_actions} discrete actions (0 to "
                                       f"{self.n_actions - 1}) the dynamics model was fitted on")
        value = _numbers(action)
        size = len(self._norm["act_mean"]) if self.fitted else value.size
        if value.size != size or not np.isfinite(value).all():
            return (f"is not {size} finite number{'s' if size > 1 else ''}, as the actions the dynamics model was "
                    "fitted on were")
        return None

    def _action_features(self, actions: np.ndarray) -> np.ndarray:
        if self.n_actions is not None:
            actions = np.asarray(actions).astype(np.int64).reshape(-1)
            if actions.min(initial=0) < 0 or actions.max(initial=0) >= self.n_actions:
                raise ConfigError(f"actions outside 0..{self.n_actions - 1} for a dynamics model of {self.n_actions} "
                                  "discrete actions")
            return np.eye(self.n_actions, dtype=np.float32)[actions]
        actions = np.asarray(actions, dtype=np.float32).reshape(len(actions), -1)
        return (actions - self._norm["act_mean"]) / self._norm["act_std"]

    def _inputs(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        obs = (np.asarray(obs, dtype=np.float32) - self._norm["obs_mean"]) / self._norm["obs_std"]
        return np.concatenate([obs, self._action_features(actions)], axis=1).astype(np.float32)

    # -- fitting -----------------------------------------------------------------------------------
    def fit(self, trajectories: Sequence[Trajectory], *, seed: int | None = None,
            on_progress: Progress | None = None) -> DynamicsDetector:
        """Fit the ensemble on the transitions of ID ``trajectories`` (each member on a bootstrap
        resample of them). A few seconds for 20 CartPole episodes on one core, longer for long
        observations (each epoch predicts every reading that changes smoothly).
        ``on_progress("dynamics model fitting epochs", done, epochs)`` after each epoch (the epochs
        ``max_updates`` leaves).

        Raises:
            ConfigError: no transitions, or observations that are not vectors.
        """
        import torch

        if seed is not None:
            self.seed, self._rng = seed, np.random.default_rng(seed)
        trajectories = [t for t in trajectories if len(t) > 0]
        if not trajectories:
            raise ConfigError("the dynamics detector needs ID transitions to fit on; got none")
        first = np.asarray(trajectories[0].observations)
        if is_picture(first.shape[1:], first.dtype):
            raise ConfigError(f"the dynamics detector models vector observations (stacked ones too); got images of shape "
                              f"{first.shape[1:]} (for images use the frames or the features detector)")
        self.flatten = first.ndim != 2  # stacked vectors, or one number a step (a Box of shape ())
        flat = [np.asarray(t.observations).reshape(len(t.observations), -1) for t in trajectories]
        _check_finite(flat, "observations", "reading",
                      "the monitor scores a step that holds one as the most shifted (a failed sensor: an alarm), "
                      "so give it finite ones in ID (a wrapper of the env that holds the last finite reading, say)")
        actions = np.concatenate([np.asarray(t.actions) for t in trajectories])
        if self.n_actions is None:  # continuous: the model's inputs as numbers, (steps, action dimensions)
            continuous = np.asarray(actions, dtype=np.float64).reshape(len(actions), -1)
            _check_finite([continuous], "actions", "dimension", "the policy's actions are inputs of the model")
        obs = np.concatenate([f[:-1] for f in flat]).astype(np.float64)
        nxt = np.concatenate([f[1:] for f in flat]).astype(np.float64)
        delta = nxt - obs
        smooth = np.array([len(np.unique(delta[:, i])) > JUMP_VALUES for i in range(delta.shape[1])])
        self.predicted = None if smooth.all() or not smooth.any() else np.flatnonzero(smooth)
        # A reading that never varied in fitting is an input in its own units (scale 1): divided by a
        # floor of 1e-6, its first change in deployment (a flag) fed the model inputs of a million.
        obs_std = obs.std(0)
        norm = {"obs_mean": obs.mean(0), "obs_std": np.where(obs_std < 1e-6, 1.0, obs_std),
                "delta_mean": delta.mean(0), "delta_std": np.maximum(delta.std(0), 1e-6)}
        if self.n_actions is None:
            norm |= {"act_mean": continuous.mean(0), "act_std": np.maximum(continuous.std(0), 1e-6)}
        self._norm = {k: v.astype(np.float32) for k, v in norm.items()}
        x = self._inputs(obs, actions)
        y = ((delta - norm["delta_mean"]) / norm["delta_std"]).astype(np.float32)
        if self.predicted is not None:
            y = y[:, self.predicted]

        # The caller's grad mode is not the fit's: oodmon.watch or calibrate_agent called inside the
        # user's own torch.no_grad() (or inference_mode()) stopped here with autograd's "element 0 of
        # tensors does not require grad" (2026-12-05).
        with torch.inference_mode(False), torch.enable_grad():
            self._weights = self._train(x, y, on_progress)
        self._fast = None
        # An episode's first step has no transition to score: it gets the median ID score, a
        # value that says "nothing seen yet" on this detector's own scale.
        self.neutral = 0.0
        self.neutral = float(np.median(self.score_transitions(obs, actions, nxt)))
        return self

    def _train(self, x: np.ndarray, y: np.ndarray, on_progress: Progress | None) -> list[tuple[np.ndarray, np.ndarray]]:
        """The members' weights and biases, layer by layer, trained on the normalised inputs ``x``
        and changes ``y`` (each member on its bootstrap resample; Adam, see :meth:`fit`)."""
        import torch

        generator = torch.Generator().manual_seed(self.seed)
        sizes = [x.shape[1], self.hidden, self.hidden, 2 * y.shape[1]]
        params = []
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
            bound = 1.0 / math.sqrt(fan_in)
            w = (torch.rand(self.members, fan_in, fan_out, generator=generator) * 2 - 1) * bound
            params += [w.requires_grad_(), torch.zeros(self.members, 1, fan_out, requires_grad=True)]
        moments = [(torch.zeros_like(param), torch.zeros_like(param)) for param in params]  # Adam's, per tensor
        n = len(x)
        xs, ys = torch.from_numpy(x), torch.from_numpy(y)
        boot = torch.randint(0, n, (self.members, n), generator=generator)  # each member's resample
        batch = min(self.batch_size, n)
        per_epoch = math.ceil(n / batch)
        epochs = self.epochs if self.max_updates is None else max(1, min(self.epochs, self.max_updates // per_epoch))
        updates, total = 0, epochs * per_epoch
        for epoch in range(epochs):
            order = boot[:, torch.randperm(n, generator=generator)]
            for start in range(0, n, batch):
                index = order[:, start:start + batch]
                # xs[index] as whole rows picked along dim 0: the same numbers in a third to a half of the
                # time (benchmarks/dynamics_fit.py)
                rows = index.reshape(-1)
                inputs = xs.index_select(0, rows).view(*index.shape, -1)
                targets = ys.index_select(0, rows).view(*index.shape, -1)
                mean, logvar = _forward_torch(params, inputs, self.min_logvar)
                loss = (((mean - targets) ** 2) * torch.exp(-logvar) + logvar).mean()
                grads = torch.autograd.grad(loss, params)
                # update k of the fit's total at lr * (1 - k / total) ("linear"), else at lr
                lr = self.lr * (1.0 - updates / total) if self.schedule == "linear" else self.lr
                updates += 1
                with torch.no_grad():
                    _adam_step(params, grads, moments, updates, lr)
            if on_progress is not None:
                on_progress("dynamics model fitting epochs", epoch + 1, epochs)
        self.epochs_trained = epochs  # (fitting_notes says so where max_updates ended the fit early)
        return [(params[i].detach().numpy().copy(), params[i + 1].detach().numpy().copy())
                for i in range(0, len(params), 2)]

    def __getstate__(self) -> dict[str, Any]:
        # A copy or a pickle (a vector env's worker process) leaves the fast path behind: its
        # buffers are views of one another, and copied they are separate arrays that score garbage
        # (a used detector deep-copied scored 274,488 where it scores -1.68). Rebuilt on first use.
        return self.__dict__ | {"_fast": None, "scored": None}

    def unscored(self) -> list[int]:
        """The readings the model takes as inputs only (they jump: see ``predicted``), flattened indices."""
        if self.predicted is None or not self.fitted:
            return []
        return sorted(set(range(self.obs_dim)) - set(self.predicted.tolist()))

    # -- scoring -----------------------------------------------------------------------------------
    def reset(self) -> None:
        self._recent.clear()
        self.scored = None

    def score(self, context: StepContext) -> float:
        """The mean surprise over the episode's last ``window`` transitions (the first step: ``neutral``)."""
        self.check_fitted()
        prev_obs, obs = context.prev_obs, context.obs
        if prev_obs is None:
            value = self.neutral
        else:
            if self.flatten:
                prev_obs, obs = np.ravel(prev_obs), np.ravel(obs)
            if self.kind == "nll":
                value = self._nll_one(prev_obs, context.prev_action, obs)
                self.scored = context  # the drift detector reads this step's pass from the buffers
            else:
                value = float(self.score_transitions(np.asarray(prev_obs)[None], np.asarray([context.prev_action]),
                                                     np.asarray(obs)[None])[0])
        recent = self._recent
        mean = recent.add(value)
        if self.early == "mean":
            return mean
        return standardise_early(mean, len(recent), self.window, self.neutral)

    def _nll_one(self, prev_obs: Any, prev_action: Any, obs: Any) -> float:
        """``score_transitions`` of one transition (``nll``), in a third of the numpy calls: the
        monitor pays this at every step. Equal to the batch path up to float32 rounding."""
        fast = self._fast
        if fast is None:
            fast = self._fast = _FastNll(self)
        return fast(prev_obs, prev_action, obs)

    def _predicted(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each member's predicted mean and log-variance of a batch's normalised changes, (E, B, d),
        and the observed ones, (B, d): the predicted readings' only."""
        self.check_fitted()
        obs = np.asarray(obs, dtype=np.float32)
        if self.flatten:
            obs, next_obs = obs.reshape(len(obs), -1), np.asarray(next_obs).reshape(len(obs), -1)
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise ConfigError(f"this dynamics detector was fitted on observations of {self.obs_dim} numbers; got "
                              f"shape {obs.shape[1:]}")
        mean, logvar = _forward_numpy(self._weights, self._inputs(obs, actions), self.min_logvar)
        target = ((np.asarray(next_obs, dtype=np.float32) - obs) - self._norm["delta_mean"]) / self._norm["delta_std"]
        if self.predicted is not None:
            target = target[:, self.predicted]
        return mean, logvar, target

    def score_transitions(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray) -> np.ndarray:
        """Scores of a batch of transitions ``(obs, actions) -> next_obs``, (batch,)."""
        mean, logvar, target = self._predicted(obs, actions, next_obs)
        if self.kind == "nll":
            per_member = -0.5 * (((target - mean) ** 2) * np.exp(-logvar) + logvar + math.log(2 * math.pi)).sum(-1)
            top = per_member.max(axis=0)
            log_mix = top + np.log(np.exp(per_member - top).mean(axis=0))
            return -log_mix / target.shape[-1]
        noise = self._rng.standard_normal((self.n_draws, *mean.shape), dtype=np.float32)
        draws = mean + np.exp(0.5 * logvar) * noise  # (D, E, B, d)
        errors = ((draws - target) ** 2).mean(axis=-1)  # (D, E, B)
        return errors.reshape(-1, errors.shape[-1]).min(axis=0)

    def standardized_residuals(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray) -> np.ndarray:
        """Each predicted reading's change minus the ensemble's mean prediction, over the mixture's
        standard deviation (its members' variances and their spread), (batch, predicted readings):
        centred on 0 with a spread of 1 at most per reading on ID transitions (less where the
        variance floor holds); what :class:`~oodmon.monitor.detectors.drift.DriftDetector` sums."""
        mean, logvar, target = self._predicted(obs, actions, next_obs)
        variance = np.exp(logvar).mean(axis=0) + mean.var(axis=0)
        return (target - mean.mean(axis=0)) / np.sqrt(variance)

    # -- state -------------------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        return {"n_actions": self.n_actions, "kind": self.kind, "members": self.members, "hidden": self.hidden,
                "n_draws": self.n_draws, "epochs": self.epochs, "batch_size": self.batch_size, "lr": self.lr,
                "window": self.window, "seed": self.seed, "neutral": self.neutral, "min_logvar": self.min_logvar} \
            | ({"flatten": True} if self.flatten else {}) \
            | ({} if self.predicted is None else {"predicted": self.predicted.tolist()}) \
            | ({} if self.early == "mean" else {"early": self.early}) \
            | ({} if self.schedule == "constant" else {"schedule": self.schedule}) \
            | ({} if self.max_updates is None else {"max_updates": self.max_updates})  # keys left out read as before

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        out = {f"norm.{k}": v for k, v in self._norm.items()}
        for i, (w, b) in enumerate(self._weights):
            out[f"layer{i}.weight"], out[f"layer{i}.bias"] = w, b
        return out

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> DynamicsDetector:
        # fitted before the keys: the plain mean, a constant learning rate, every epoch
        detector = cls(**({"early": "mean", "schedule": "constant", "max_updates": None} | dict(config)))
        detector._norm = {k[5:]: np.asarray(v, np.float32) for k, v in tensors.items() if k.startswith("norm.")}
        layers = sorted({int(k[5:].split(".")[0]) for k in tensors if k.startswith("layer")})
        if not layers or not {"obs_mean", "obs_std", "delta_mean", "delta_std"} <= set(detector._norm):
            raise ConfigError("the dynamics detector's tensors are incomplete")
        detector._weights = [(np.asarray(tensors[f"layer{i}.weight"], np.float32),
                              np.asarray(tensors[f"layer{i}.bias"], np.float32)) for i in layers]
        d, out = len(detector._norm["obs_mean"]), detector._weights[-1][0].shape[-1] // 2
        predicted = detector.predicted
        if (predicted is None and out != d) or (predicted is not None and (
                len(predicted) != out or len(set(predicted.tolist())) != out or predicted.min() < 0 or predicted.max() >= d)):
            raise ConfigError(f"the dynamics detector predicts {out} readings of {d}, but its predicted readings are "
                              f"{'all' if predicted is None else predicted.tolist()}")
        return detector


class _FastNll:
    """One transition's mixture NLL in few numpy calls (the monitor pays this at every step).

    Folded into the weights once: the input normalisation (into the first layer; for discrete
    actions the one-hot column becomes a bias per action); a factor 1/2 of every hidden layer's
    pre-activation, so that SiLU is ``z' * (1 + tanh z')`` with ``z' = z / 2`` (numpy's tanh costs
    a third of scipy's expit); into the last layer, the normalised change's offset and a factor
    ``exp(-min_logvar / 2)`` (the means), and ``-max_logvar`` (the log-variances). The two soft
    bounds of the log-variance are then one expression: ``exp(logvar - min_logvar) = w`` with
    ``w = 1 + exp(max_logvar - min_logvar) * expit(raw - max_logvar)``, and a member's NLL sums
    ``error'^2 / w + log w`` (plus ``min_logvar`` per dimension) over the dimensions. Equal to
    :meth:`DynamicsDetector.score_transitions` up to float32 rounding.

    Every array of a call is allocated once, here, with its views (a view made per call costs
    as much as a small ufunc). A layer after the first reads a hidden vector that ends in a
    constant and a weight matrix that ends in the bias row divided by that constant, so its bias
    comes with the product. The constant is made by the layers themselves, so that every
    element-wise step writes whole contiguous buffers (writing into the hidden values beside the
    constant took 1.7 us per layer against 0.5): each member's units are followed by one more
    pre-activation, :data:`_CONSTANT_Z` (a zero weight column and that bias in the first layer; a
    zero column ending in ``_CONSTANT_Z / constant`` in the others), whose SiLU
    ``z' * (1 + tanh z')`` is exactly ``2 * _CONSTANT_Z`` (tanh(16) rounds to 1): the constant, a
    power of two, so dividing the bias by it and multiplying back are exact. The first layer's
    columns are padded with zeros to a multiple of 16: at a width 4-15 past a multiple of 16,
    OpenBLAS's sgemv kernel (Haswell) rounds its first 4-12 columns otherwise (measured with 4
    inputs). Checked: the same floats as the layout without the constant, on 120,000 random
    transitions of the six shipped CartPole and Pendulum detectors and on their monitored
    episodes. ``benchmarks/detector_step.py`` measures the step.
    """

    def __init__(self, detector: DynamicsDetector) -> None:
        norm = detector._norm
        (w0, b0), *middle, (wl, bl) = [(w.astype(np.float64), b.astype(np.float64)) for w, b in detector._weights]
        members, n_in, hidden = w0.shape
        d = len(norm["obs_mean"])
        z, constant = _f32(_CONSTANT_Z), _f32(2 * _CONSTANT_Z)
        probe = np.full(members * (hidden + 1), z)  # as the loop computes it, vectorised
        if not np.all(probe * (np.tanh(probe) + 1) == constant):  # what the layout rests on
            raise RuntimeError("numpy's float32 tanh(16) is not 1 here: the dynamics detector's fast path cannot run")
        width = -(-members * (hidden + 1) // 16) * 16  # the first layer's columns, padded (see above)

        def first_layer(matrix: np.ndarray, fill: float) -> np.ndarray:
            """(..., E*H) float64 -> (..., width) float32: each member's H columns, then ``fill``, then zeros."""
            matrix = matrix.astype(np.float32).reshape(*matrix.shape[:-1], members, hidden)
            spread = np.concatenate([matrix, np.full((*matrix.shape[:-1], 1), fill, np.float32)], axis=-1)
            flat = spread.reshape(*matrix.shape[:-2], members * (hidden + 1))
            return np.concatenate([flat, np.zeros((*flat.shape[:-1], width - flat.shape[-1]), np.float32)], axis=-1)

        w0 = 0.5 * w0.transpose(1, 0, 2).reshape(n_in, members * hidden)  # (in, E*H), halved
        obs_scale = 1.0 / norm["obs_std"].astype(np.float64)
        self.w_obs = first_layer(w0[:d] * obs_scale[:, None], 0.0)
        bias = 0.5 * b0.reshape(members * hidden) - (norm["obs_mean"] * obs_scale) @ w0[:d]
        self.n_actions = detector.n_actions
        if self.n_actions is None:
            act_scale = 1.0 / norm["act_std"].astype(np.float64)
            self.w_act = first_layer(w0[d:] * act_scale[:, None], 0.0)
            self.bias = first_layer(bias - (norm["act_mean"] * act_scale) @ w0[d:], _CONSTANT_Z)
            self.action_bias = np.empty(width, np.float32)  # the action's part of a step's first layer
        else:
            self.bias_per_action = list(first_layer(bias[None, :] + w0[d:], _CONSTANT_Z))  # row a: action a's one-hot
        floor = float(detector.min_logvar)
        root_precision = math.exp(-0.5 * floor)  # folded into the errors: error'^2 = error^2 * exp(-floor)
        delta_scale, delta_mean = 1.0 / norm["delta_std"].astype(np.float64), norm["delta_mean"]
        self.predicted = detector.predicted  # the readings scored (None: every one)
        if self.predicted is not None:
            delta_scale, delta_mean, d = delta_scale[self.predicted], delta_mean[self.predicted], len(self.predicted)
        bl = bl.copy()
        bl[:, 0, :d] += delta_mean * delta_scale  # the means, plus the offset of the normalised change
        bl[:, 0, :d] *= root_precision
        bl[:, 0, d:] -= _MAX_LOGVAR
        wl = np.concatenate([wl[:, :, :d] * root_precision, wl[:, :, d:]], axis=2)
        # Each later layer: weights (E, H + 1, out), the last row its bias over the constant, and
        # for a hidden layer one more column that makes the next constant.
        self.layers = []
        for w, b in middle:
            weights = np.concatenate([0.5 * w, 0.5 * b], axis=1).astype(np.float32)
            weights[:, -1] /= constant
            column = np.zeros((members, hidden + 1, 1), np.float32)
            column[:, -1] = z / constant
            self.layers.append(np.concatenate([weights, column], axis=2))
        weights = np.concatenate([wl, bl], axis=1).astype(np.float32)
        weights[:, -1] /= constant
        self.layers.append(weights)
        self.delta_scale = (delta_scale * root_precision).astype(np.float32)
        self.d = d
        self.const = 0.5 * (math.log(2 * math.pi) + floor) * d
        self.inv_members = 1.0 / members
        # Constants as 0-d float32 arrays: numpy takes a Python float scalar in twice the time of
        # an array (1.2 vs 0.6 us for 20 numbers here).
        self.one, self.span = _f32(1.0), _f32(math.exp(_MAX_LOGVAR - floor))
        # The buffers: pre-activations z and hidden vectors h, each member's ending in its
        # constant, and a scratch for tanh.
        self.z_first = np.empty(width, np.float32)
        shape = (members, 1, hidden + 1)
        self.z = [self.z_first[:members * (hidden + 1)].reshape(shape)] + [np.empty(shape, np.float32) for _ in middle]
        self.tanh = np.empty(shape, np.float32)
        self.h = [np.empty(shape, np.float32) for _ in self.z]
        # What a step leaves, in one buffer (the drift detector reads it in one product, see
        # outputs_layout): each member's output (its means, then its raw log-variances), w, and the
        # observed change.
        n_out = members * 2 * d
        self.outputs = np.empty(n_out + members * d + d, np.float32)
        self.out = self.outputs[:n_out].reshape(members, 1, 2 * d)
        self.w = self.outputs[n_out:n_out + members * d].reshape(members, d)
        self.target = self.outputs[n_out + members * d:]
        # What the loop over the layers reads, in one list: z -> h -> the next z (or the output)
        self.steps = list(zip(self.z, self.h, self.layers, self.z[1:] + [self.out]))
        self.mean, self.raw = self.out[:, 0, :d], self.out[:, 0, d:]
        self.log_w, self.error = (np.empty((members, d), np.float32) for _ in range(2))
        self.members = members

    def outputs_layout(self) -> dict[str, np.ndarray]:
        """Where ``outputs`` holds member k's mean and ``w`` of reading j, (members, d) each, and the
        change of reading j, (d,): flat indices (the outputs ``out`` are its first ``out.size``)."""
        members, d = self.members, self.d
        n_out = members * 2 * d
        return {"mean": np.arange(n_out).reshape(members, 2 * d)[:, :d],
                "w": n_out + np.arange(members * d).reshape(members, d), "change": n_out + members * d + np.arange(d)}

    def __call__(self, prev_obs: Any, prev_action: Any, obs: Any) -> float:
        prev = np.asarray(prev_obs, dtype=np.float32)
        one = self.one
        z = np.matmul(prev, self.w_obs, out=self.z_first)  # half the first pre-activation
        if self.n_actions is None:
            bias = np.matmul(np.asarray(prev_action, dtype=np.float32).reshape(-1), self.w_act, out=self.action_bias)
            bias += self.bias
            z += bias
        else:
            z += self.bias_per_action[int(prev_action)]
        t = self.tanh
        for z, h, weights, product in self.steps:
            np.tanh(z, out=t)
            t += one
            np.multiply(t, z, out=h)  # SiLU (each member's constant included)
            np.matmul(h, weights, out=product)  # the next pre-activation (or the output), bias included
        d = self.d
        w = expit(self.raw, out=self.w)
        w *= self.span
        w += one  # exp(logvar - min_logvar), in [1, exp(max - min)]
        if self.predicted is None:
            target = np.subtract(obs, prev, out=self.target, dtype=np.float32)
        else:
            target = np.take(np.subtract(obs, prev, dtype=np.float32), self.predicted, out=self.target)
        target *= self.delta_scale
        error = np.subtract(target, self.mean, out=self.error)  # (E, d)
        error *= error
        error /= w
        error += np.log(w, out=self.log_w)
        # np.add.reduce is what .sum(axis=1) calls, without its Python wrapper
        twice_nll = np.add.reduce(error, 1).tolist()  # per member, less constants
        low = min(twice_nll)
        mixture = 0.0  # a loop, not sum() over a generator: the same additions in the same order, no frames
        for value in twice_nll:
            mixture += math.exp(0.5 * (low - value))
        return (0.5 * low + self.const - math.log(mixture * self.inv_members)) / d


def _check_finite(arrays: Sequence[np.ndarray], what: str, part: str, hint: str) -> None:
    """Refuse the ID ``what`` (arrays of rows, parts; each episode's, read in place) where they hold
    a NaN or an infinity, naming the parts and how often, then ``hint``.

    Fitted on them, every weight of the model turned NaN, and the set's fitting stopped later at
    "the combined detector needs finite ID scores of 'dynamics'" (2026-12-01: CartPole whose cart
    position read NaN at 1% of its steps), which did not say why."""
    counts = sum((~np.isfinite(values)).sum(0) for values in arrays)
    if not np.any(counts):
        return
    parts = np.flatnonzero(counts)
    named = ", ".join(f"{part} {i} at {counts[i]:,}" for i in parts[:4]) + (
        f" and {len(parts) - 4} more" if len(parts) > 4 else "")
    raise ConfigError(f"the ID {what} hold values that are not finite (NaN or infinite): {named} of "
                      f"{sum(len(values) for values in arrays):,} {what}; the dynamics detector cannot fit on them: "
                      f"{hint}")


def _f32(value: float) -> np.ndarray:
    return np.array(value, dtype=np.float32)


def _split(out):
    d = out.shape[-1] // 2
    mean, raw = out[..., :d], out[..., d:]
    return mean, raw


def _adam_step(params, grads, moments, step: int, lr: float) -> None:
    """Adam's ``step``-th update (from 1) of ``params`` at learning rate ``lr``, given their
    ``grads`` and each one's moments (first, second), updated in place: ``torch.optim.Adam(params,
    lr, weight_decay=_WEIGHT_DECAY)``'s update, the same float operations in the same order as its
    one-tensor-at-a-time path (torch 2.13's ``_single_tensor_adam``: weight decay added to the
    gradient, no amsgrad), so the fit's weights are the bytes torch's Adam gives
    (``tests/monitor/test_detectors.py`` compares them). Written out because ``Adam.step`` imports
    ``torch._dynamo`` at its first call: 0.94 s of every process that fits (2026-12-04), beside
    the optimizer's own bookkeeping at every update (``benchmarks/dynamics_fit.py``)."""
    beta1, beta2 = _ADAM_BETAS
    step = float(step)  # (torch keeps the step count in a float32 tensor and reads it back as a float)
    bias_correction2_sqrt = (1 - beta2 ** step) ** 0.5
    step_size = lr / (1 - beta1 ** step)
    for param, grad, (exp_avg, exp_avg_sq) in zip(params, grads, moments):
        grad = grad.add(param, alpha=_WEIGHT_DECAY)
        exp_avg.lerp_(grad, 1 - beta1)
        exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        param.addcdiv_(exp_avg, (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(_ADAM_EPS), value=-step_size)


def _forward_torch(params, x, min_logvar: float = _MIN_LOGVAR):
    import torch
    import torch.nn.functional as F

    h = x
    for i in range(0, len(params) - 2, 2):
        h = torch.nn.functional.silu(torch.baddbmm(params[i + 1], h, params[i]))
    mean, raw = _split(torch.baddbmm(params[-1], h, params[-2]))
    logvar = _MAX_LOGVAR - F.softplus(_MAX_LOGVAR - raw)  # soft bounds, as PETS
    return mean, min_logvar + F.softplus(logvar - min_logvar)


def _softplus(x: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, x)


def _forward_numpy(weights, x: np.ndarray, min_logvar: float = _MIN_LOGVAR):
    h = repeat_rows(x, weights[0][0].shape[0])
    for w, b in weights[:-1]:
        z = np.matmul(h, w) + b
        with np.errstate(over="ignore"):  # exp(-z) = inf below z = -88 (float32): SiLU is then -0.0, as it should
            h = z / (1.0 + np.exp(-z))  # SiLU
    mean, raw = _split(np.matmul(h, weights[-1][0]) + weights[-1][1])
    logvar = _MAX_LOGVAR - _softplus(_MAX_LOGVAR - raw)
    return mean, min_logvar + _softplus(logvar - min_logvar)
