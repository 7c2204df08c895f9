"""``features``: the Mahalanobis distance of the policy's features from the ID ones.

Lee et al. (NeurIPS 2018): class-conditional Gaussians with one shared covariance, fitted on the
network's features at ID steps. Here the class is the chosen action (DQN; one class for continuous
actions), the features are the policy's deterministic ones (``Estimate.features``: Pong's 512
CNN features, the last hidden layer of an MLP), and the covariance is Ledoit-Wolf shrunk, which
stays well-conditioned from a few hundred frames. The score is the squared distance from the
chosen action's mean; an action never chosen at ID steps uses the pooled mean.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, StepContext, Trajectory

__all__ = ["FeaturesDetector"]


class FeaturesDetector(Detector):
    """Squared Mahalanobis distance of the policy's features, class-conditional on the action.

    Args:
        n_actions: discrete actions (one class each), or ``None`` (one class).
    """

    name = "features"
    needs_estimate = True
    learned = True

    def __init__(self, n_actions: int | None = None) -> None:
        self.n_actions = n_actions
        self._means: np.ndarray | None = None  # (classes + 1, F): per class, then pooled
        self._factor: np.ndarray | None = None  # (F, F) with factor @ factor.T = precision

    @property
    def fitted(self) -> bool:
        return self._means is not None

    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> FeaturesDetector:
        """Fit the class means and the shared covariance on the features of ID ``trajectories``.

        Raises:
            ConfigError: the trajectories carry no features (the policy has none).
        """
        from sklearn.covariance import LedoitWolf

        if not trajectories or any(t.features is None for t in trajectories):
            raise ConfigError("the features detector needs the policy's features at ID steps; this policy gives "
                              "none (an ensemble or MC agent of oodmon does)")
        features = np.concatenate([t.features for t in trajectories]).astype(np.float64)
        classes = self._classes(np.concatenate([np.asarray(t.actions) for t in trajectories]))
        n_classes = 1 if self.n_actions is None else self.n_actions
        pooled = features.mean(axis=0)
        means = np.stack([features[classes == c].mean(axis=0) if np.any(classes == c) else pooled
                          for c in range(n_classes)] + [pooled])
        centred = features - means[classes]
        covariance = LedoitWolf(assume_centered=True).fit(centred).covariance_
        precision = np.linalg.inv(covariance)
        self._means = means.astype(np.float32)
        self._factor = np.linalg.cholesky((precision + precision.T) / 2).astype(np.float32)
        return self

    def _classes(self, actions: np.ndarray) -> np.ndarray:
        if self.n_actions is None:
            return np.zeros(len(actions), dtype=np.int64)
        return np.asarray(actions).astype(np.int64).reshape(-1)

    def score(self, context: StepContext) -> float:
        self.check_fitted()
        features = context.features
        if features is None:
            raise ConfigError("the features detector needs the policy's features; this policy gives none")
        if features.shape[-1] != self._means.shape[1]:
            raise ConfigError(f"this features detector was fitted on {self._means.shape[1]} features; the policy "
                              f"gives {features.shape[-1]} (another policy?)")
        klass = 0 if self.n_actions is None else int(np.asarray(context.action).reshape(-1)[0])
        mean = self._means[klass] if 0 <= klass < len(self._means) - 1 else self._means[-1]
        projected = (features.astype(np.float32) - mean) @ self._factor
        return float(projected @ projected)

    def config(self) -> dict[str, Any]:
        return {"n_actions": self.n_actions}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"means": self._means, "factor": self._factor}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> FeaturesDetector:
        detector = cls(**config)
        if "means" not in tensors or "factor" not in tensors:
            raise ConfigError("the features detector's tensors are incomplete")
        detector._means = np.asarray(tensors["means"], np.float32)
        detector._factor = np.asarray(tensors["factor"], np.float32)
        return detector
