"""``scaled_spread``: an ensemble's spread with each member's values on that member's own ID footing.

The spread scores take the std over the members as they come, so one member whose values sit
elsewhere at ID steps sets the spread of every ID step and hides the shift: on Pendulum an actor
that saturates its torque (its output before the tanh far out, where the others sit near 0); on
CartPole a DQN member with an offset of its own between the two actions' Q-values. This detector
puts each member on its own ID footing before taking the std:

- DDPG ensembles (actors ending in tanh): each member's output before the tanh, divided by that
  member's median |output| over ID steps (0 stays the neutral action);
- DQN ensembles (discrete actions): each member's Q-values centred on their mean over the actions
  (with two actions, half the margin Q0 - Q1), as a z-score of that member's ID mean and std;
- MC agents with fixed masks (``whiten``): their K sub-networks share all but a few percent of
  their weights, so their values move together; each sub-network's deviation from the
  sub-networks' mean is read against the ID covariance of those deviations (a Mahalanobis distance,
  the covariance shrunk by Ledoit-Wolf): a spread whitened by how the sub-networks disagree at ID
  steps. Its score is the root mean square of the whitened deviations.

Measured under the bench's protocol over five trials (results/bench/README.md, "Why more members score worse";
``scripts/member_normalisations.py`` compares the normalisations on both tasks): Pendulum
ensembles read 0.953 ± 0.002 per step on ``l=0.1`` (``pre_squash_std``: 0.940 ± 0.015), CartPole's
0.984 ± 0.005 on ``gravity=98.0`` (``margin_std``: 0.793 ± 0.051). Dividing by a scale alone did
not help CartPole (0.869 on ``gravity=98.0`` on the sweeps' episodes, the z-score 0.969).

Sampled MC samples are not members (sample k is another network at every step), so
:func:`~oodmon.monitor.detectors.fit_detectors` refuses it for MC agents, unless their masks are
fixed (``load(..., masks="fixed")`` or ``"fixed-decisions"``): then sample k is one sub-network
throughout, a member.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory

if TYPE_CHECKING:
    from oodmon.agents.estimators import Estimate

__all__ = ["NORMALISATIONS", "ScaledSpreadDetector", "member_values"]

#: How the detector puts members on their ID footing (see the module docstring).
NORMALISATIONS = ("scale", "zscore", "whiten")

#: A member's scale is at least this fraction of the largest member's, so that a member whose ID
#: values never move does not divide by 0 (measured Pendulum scales span 0.07 to 17 in one ensemble).
SCALE_FLOOR = 1e-3


def member_values(estimate: Estimate) -> np.ndarray | None:
    """(K, n) at the estimate's first observation: a DDPG ensemble's (or fixed-mask MC actor's) outputs
    before the tanh, a DQN's Q-values centred on their mean over the actions; ``None`` for other policies."""
    if estimate.pre_squash is not None:
        return estimate.pre_squash[:, 0]
    if estimate.action.ndim == 1 and estimate.action.dtype.kind in "iu":
        q_values = estimate.samples[:, 0]
        return q_values - q_values.mean(axis=1, keepdims=True)
    return None


class ScaledSpreadDetector(Detector):
    """The std over an ensemble's members of their values, each member's on its own ID footing.

    Args:
        normalisation: ``scale`` (divide by the member's median |value| at ID steps: DDPG),
            ``zscore`` (subtract its ID mean, divide by its ID std: DQN) or ``whiten`` (the
            members' deviations from their mean against the ID covariance of those deviations:
            MC agents with fixed masks); ``None``: chosen by the ID trajectories' actions when
            fitted (integers: ``zscore``).

    Example:
        >>> import numpy as np
        >>> from oodmon.agents.estimators import Estimate
        >>> ids = [Trajectory(np.zeros((3, 3)), np.zeros((2, 1)), member_values=np.array([[[1.0], [10.0]]] * 2))]
        >>> detector = ScaledSpreadDetector().fit(ids)  # DDPG: member scales 1 and 10
        >>> est = Estimate(np.zeros((1, 1)), np.zeros((2, 1, 1)), np.zeros((1, 1)), np.zeros((1, 1)),
        ...                pre_squash=np.array([[[1.0]], [[-10.0]]]))
        >>> round(detector.score(StepContext(np.zeros(3), np.zeros(1), est)), 6)  # values 1 and -1: std 1
        1.0
    """

    name = "scaled_spread"
    needs_estimate = True
    learned = True

    def __init__(self, normalisation: str | None = None, drop_last: bool = False) -> None:
        if normalisation not in (None, *NORMALISATIONS):
            raise ConfigError(f"normalisation={normalisation!r} is not one of {', '.join(NORMALISATIONS)}")
        self.normalisation = normalisation
        self.drop_last = bool(drop_last)  # whiten: leave out each member's last value (see _deviations)
        self._location: np.ndarray | None = None  # (K, n): subtracted from each member's values
        self._scale: np.ndarray | None = None  # (K, n): what they are then divided by
        self._inverse: np.ndarray | None = None
        # whiten: the ID mean (D,) and precision (D, D) of the members' deviations, D = K x the values read
        self._mean: np.ndarray | None = None
        self._precision: np.ndarray | None = None

    @property
    def fitted(self) -> bool:
        return self._scale is not None or self._precision is not None

    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> ScaledSpreadDetector:
        """Each member's location and scale over the steps of ID ``trajectories``.

        Raises:
            ConfigError: the trajectories carry no members' values (the policy is no ensemble of oodmon).
        """
        if not trajectories or any(t.member_values is None for t in trajectories):
            raise ConfigError("the scaled_spread detector needs an ensemble's members' values at ID steps (an "
                              "oodmon DQN or DDPG ensemble); this policy gives none")
        values = np.concatenate([t.member_values for t in trajectories]).astype(np.float64)  # (T, K, n)
        discrete = np.asarray(trajectories[0].actions).dtype.kind in "iu"
        if self.normalisation is None:
            self.normalisation = "zscore" if discrete else "scale"
        if self.normalisation == "whiten":
            from sklearn.covariance import LedoitWolf

            self.drop_last = discrete and values.shape[2] > 1
            estimate = LedoitWolf().fit(_deviations(values, self.drop_last))
            self._set_whitening(estimate.location_.astype(np.float32), estimate.precision_.astype(np.float32))
            return self
        if self.normalisation == "zscore":
            location, scale = values.mean(axis=0), values.std(axis=0)
        else:
            location, scale = np.zeros(values.shape[1:]), np.median(np.abs(values), axis=0)
        self._set(location.astype(np.float32), scale.astype(np.float32))
        return self

    def _set_whitening(self, mean: np.ndarray, precision: np.ndarray) -> None:
        if (mean.ndim != 1 or precision.shape != (len(mean), len(mean)) or not np.all(np.isfinite(mean))
                or not np.all(np.isfinite(precision))):
            raise ConfigError(f"the scaled_spread detector's whitening needs a finite mean (D,) and precision (D, D); "
                              f"got shapes {mean.shape} and {precision.shape}")
        self._mean, self._precision = mean, precision

    def _set(self, location: np.ndarray, scale: np.ndarray) -> None:
        if (scale.ndim != 2 or location.shape != scale.shape or not np.all(np.isfinite(scale))
                or not np.all(np.isfinite(location)) or np.any(scale < 0)):
            raise ConfigError(f"the scaled_spread detector's location and scale must be finite, the scale >= 0, both "
                              f"of shape (members, values); got shapes {location.shape} and {scale.shape}")
        floor = max(SCALE_FLOOR * float(scale.max(initial=0.0)), np.finfo(np.float32).tiny)
        self._location, self._scale = location, scale
        self._inverse = (1.0 / np.maximum(scale, floor)).astype(np.float32)

    def score(self, context: StepContext) -> float:
        self.check_fitted()
        values = member_values(context.estimate) if context.estimate is not None else None
        if values is None:
            raise ConfigError("the scaled_spread detector needs an ensemble's members' values (an oodmon DQN or "
                              "DDPG ensemble); this policy gives none")
        if self.normalisation == "whiten":
            deviations = _deviations(values[None], self.drop_last)
            if deviations.shape[1] != len(self._mean):
                raise ConfigError(f"this scaled_spread detector was fitted on {len(self._mean)} members' deviations; "
                                  f"the policy gives values of shape {values.shape} (another policy?)")
            return float(self._whitened(deviations)[0])
        if values.shape != self._inverse.shape:
            raise ConfigError(f"this scaled_spread detector was fitted on {self._inverse.shape[0]} members of "
                              f"{self._inverse.shape[1]} value(s); the policy gives {values.shape} (another policy?)")
        return float(self.spread(values[None])[0])

    def spread(self, values: np.ndarray) -> np.ndarray:
        """(T,) scores of (T, K, n) members' values: the std over the members of each member's
        values on its ID footing, averaged over the n values; whitened: the root mean square of
        the members' whitened deviations, sqrt(d' P d / D)."""
        if self.normalisation == "whiten":
            self.check_fitted()
            return self._whitened(_deviations(values, self.drop_last))
        return self.normalised(values).std(axis=1).mean(axis=-1)

    def _whitened(self, deviations: np.ndarray) -> np.ndarray:
        """(T,) sqrt(d' P d / D) of (T, D) members' deviations, d their distance from the ID mean."""
        d = deviations - self._mean
        return np.sqrt(np.maximum(np.einsum("td,de,te->t", d, self._precision, d), 0.0) / len(self._mean))

    def normalised(self, values: np.ndarray) -> np.ndarray:
        """(..., K, n) members' values, each member's on its ID footing (its location subtracted,
        divided by its scale; not for ``whiten``, whose footing is the members' joint one)."""
        self.check_fitted()
        if self.normalisation == "whiten":
            raise ConfigError("the whitened scaled_spread reads the members jointly; it has no per-member values")
        return (values - self._location) * self._inverse

    def config(self) -> dict[str, Any]:
        return {"normalisation": self.normalisation} | ({"drop_last": self.drop_last} if self.drop_last else {})

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        if self.normalisation == "whiten":
            return {"mean": self._mean, "precision": self._precision}
        return {"location": self._location, "scale": self._scale}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> ScaledSpreadDetector:
        detector = cls(**config)
        if detector.normalisation == "whiten":
            if "mean" not in tensors or "precision" not in tensors:
                raise ConfigError("the whitened scaled_spread detector's tensors are incomplete (it needs mean and precision)")
            detector._set_whitening(np.asarray(tensors["mean"], np.float32), np.asarray(tensors["precision"], np.float32))
            return detector
        if "scale" not in tensors or "location" not in tensors:
            raise ConfigError("the scaled_spread detector's tensors are incomplete (it needs location and scale)")
        detector._set(np.asarray(tensors["location"], np.float32), np.asarray(tensors["scale"], np.float32))
        return detector


def _deviations(values: np.ndarray, drop_last: bool) -> np.ndarray:
    """(T, D): each member's values (T, K, n) minus the members' mean, flattened; ``drop_last``:
    without the last value, which a DQN member's centred Q-values (summing to 0) repeat: with two
    actions, the deviations of each member's half margin."""
    if drop_last:
        values = values[..., :-1]
    deviations = values - values.mean(axis=1, keepdims=True)
    return deviations.reshape(len(values), -1)
