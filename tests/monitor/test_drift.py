"""The drift detector: a bias of the dynamics model's residuals, reading by reading."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from oodmon.envs import parse_variant
from oodmon.errors import ConfigError
from oodmon.monitor.detectors import DetectorSet, DriftDetector, DynamicsDetector, StepContext, fit_detectors
from oodmon.monitor.detectors.fitting import collect, trajectory_scores


def _policy(obs):
    return int(obs[2] + 0.5 * obs[3] > 0)  # balances CartPole for its 500 steps


@pytest.fixture(scope="module")
def fitted():
    episodes = collect(_policy, gymnasium.make("CartPole-v1"), 20, seed=0)
    dynamics = DynamicsDetector(2, seed=0).fit(episodes[:14])
    return dynamics, DriftDetector.of(dynamics), episodes[14:]


def _scores(detector, trajectories) -> list[np.ndarray]:
    out = []
    for trajectory in trajectories:
        detector.reset()
        prev = prev_action = None
        scores = []
        for obs, action in zip(trajectory.observations, trajectory.actions):
            scores.append(detector.score(StepContext(obs, action, prev_obs=prev, prev_action=prev_action)))
            prev, prev_action = obs, action
        out.append(np.array(scores))
    return out


def test_residuals_centre_on_zero_in_id_and_the_drift_sees_changed_physics_the_policy_copes_with(fitted):
    """On 6 held-out ID episodes the standardised residuals centre on 0 (means within 0.12 and
    spreads 0.12-0.20 when written; within 0.03 and 0.21-0.37 since the model trains 100 epochs
    here, its learning rate falling to 0, fitting version 8); a cart three times as heavy, a push half as
    strong and a shorter pole, which the policy balances through, score above every ID step at most
    steps (AUROC 0.99, 0.98, 0.99 when written; 0.998, 0.998, 0.996 since; 6 episodes each)."""
    dynamics, drift, held_out = fitted
    residuals = np.concatenate([dynamics.standardized_residuals(t.observations[:len(t.actions) - 1], t.actions[:-1],
                                                                t.observations[1:len(t.actions)]) for t in held_out])
    assert residuals.shape == (len(residuals), 4) and np.all(np.abs(residuals.mean(axis=0)) < 0.2)
    assert np.all(residuals.std(axis=0) < 1.0)
    in_id = np.concatenate(_scores(drift, held_out))
    assert in_id[0] == 0.0 and np.isfinite(in_id).all()
    for spec in ("cartpole:masscart=3.0", "cartpole:force_mag=5.0", "cartpole:length=0.8"):
        shifted = np.concatenate(_scores(drift, collect(_policy, parse_variant(spec).make(), 6, seed=100)))
        labels = np.r_[np.zeros(len(in_id)), np.ones(len(shifted))]
        assert roc_auc_score(labels, np.r_[in_id, shifted]) > 0.9, spec


def test_the_score_is_the_largest_windowed_bias_and_a_reset_or_a_gap_starts_it_again(fitted):
    dynamics, _, held_out = fitted
    drift = DriftDetector.of(dynamics, window=3)
    trajectory = held_out[0]
    obs, actions = trajectory.observations[:8], trajectory.actions[:8]
    residuals = dynamics.standardized_residuals(obs[:-1], actions[:-1], obs[1:]).astype(np.float64)
    scores = _scores(drift, [trajectory])[0][:8]
    for t in range(1, 8):  # step t's residual is of the transition t-1 -> t
        window = residuals[max(0, t - 3):t]
        expected = np.abs(window.sum(axis=0)).max() / np.sqrt(len(window))
        assert scores[t] == pytest.approx(expected, rel=2e-4)  # one row or a batch: float32 rounding apart
    assert drift.score(StepContext(obs[5], actions[5])) == 0.0  # no previous observation: nothing summed
    # far from ID (states 40 times those seen: the members' predicted changes large, the observed ones
    # other), where float32 sums would lose the mixture's variance: a window of one reads the batch's
    # largest residual magnitude
    one = DriftDetector.of(dynamics, window=1)
    rng = np.random.default_rng(0)
    far = obs[:6] * 40.0
    following = far + rng.normal(0.0, 1.0, far.shape).astype(np.float32)
    batch = np.abs(dynamics.standardized_residuals(far, actions[:6], following)).max(axis=1)
    for before, after, action, expected in zip(far, following, actions[:6], batch):
        one.reset()
        assert one.score(StepContext(after, 0, prev_obs=before, prev_action=action)) == pytest.approx(expected, rel=1e-4)
    assert batch.max() > 10  # far indeed
    # the sums behind a residual are taken in float64: members that agree on a large change (2e4
    # floor units, 1 apart) with their variances at the floor leave a mixture variance of 3 per
    # reading, which float32 sums of squares (some 1e10, rounding by hundreds) would lose
    fast = one._fast
    fast.mean[...] = 2e4 + np.arange(fast.members, dtype=np.float32)[:, None] - 2.0
    fast.w[...], fast.target[...] = 1.0, 0.0
    turned = one._residuals(fast, out=np.empty(2 * fast.d))  # each residual with its sign turned, then its negative
    assert turned[:fast.d] == pytest.approx(np.full(fast.d, 2e4 / np.sqrt(3.0)), rel=1e-9)
    with pytest.raises(ConfigError, match="window=0 is not allowed"):
        DriftDetector(dynamics, window=0)
    own = DriftDetector().fit(held_out[:3], n_actions=2, seed=0)  # a dynamics model of its own
    assert own.fitted and own.model.n_actions == 2 and np.isfinite(_scores(own, held_out[:1])[0]).all()
    # fitted again on another env's readings (Pendulum's 3, not 4) after it scored: its step's buffers
    # are made anew for them (they were CartPole's: "could not broadcast ... (48,) into shape (64,)")
    pendulum = collect(lambda _: np.zeros(1, np.float32), gymnasium.make("Pendulum-v1"), 3, seed=0)
    own.fit(pendulum, seed=0)
    assert own.model.obs_dim == 3 and np.isfinite(_scores(own, pendulum[:1])[0]).all()
    with pytest.raises(ConfigError, match="the drift detector is not fitted"):
        DriftDetector().score(StepContext(obs[1], 0, prev_obs=obs[0], prev_action=0))


def test_drift_is_fitted_only_when_named_brings_dynamics_joins_combined_and_round_trips(fitted, tmp_path):
    env = gymnasium.make("CartPole-v1")
    assert "drift" not in fit_detectors(_policy, env, episodes=3).names
    named = fit_detectors(_policy, env, detectors=["drift", "combined"], episodes=6)
    assert named.names == ["dynamics", "drift", "combined"] and named["combined"].members == ["dynamics", "drift"]
    assert fit_detectors(_policy, env, detectors=["drift"], episodes=3).names == ["dynamics", "drift"]
    named.save(tmp_path / "det")
    loaded = DetectorSet.load(tmp_path / "det")
    trajectory = fitted[2][0]
    assert _scores(loaded["drift"], [trajectory])[0].tolist() == _scores(named["drift"], [trajectory])[0].tolist()
    # the loaded set's drift reads its dynamics detector's model (a copy of the same weights in the files):
    # one forward pass of a step serves both, and scores as drift's own pass does
    assert loaded["drift"].model is loaded["dynamics"]
    through_set = trajectory_scores(loaded, trajectory)["drift"]
    assert through_set.tolist() == _scores(named["drift"], [trajectory])[0].tolist()
    for name in named.names:  # what a threshold records of them reads the same from the files
        assert loaded.fingerprint(name) == named.fingerprint(name)
    meta = json.loads((tmp_path / "det" / "detectors.json").read_text())
    for entry in meta["detectors"]:
        if entry["name"] == "drift":
            del entry["config"]["model"]  # a damaged file: the model's settings gone
    (tmp_path / "det" / "detectors.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match="the drift detector's settings are not valid"):
        DetectorSet.load(tmp_path / "det")


def test_a_drift_detector_copied_or_pickled_mid_episode_scores_on_as_the_original(fitted):
    """Its step's buffers are views of one another (rebuilt on first use after a copy), while the
    window's residuals go with it: a copy made mid-episode (a vector env's worker gets the monitor
    pickled) sums on from the same window, float for float."""
    import copy
    import pickle

    dynamics, _, held_out = fitted
    drift = DriftDetector.of(dynamics, window=5)
    trajectory = held_out[1]
    contexts = [StepContext(obs, action, prev_obs=prev, prev_action=prev_action)
                for prev, prev_action, obs, action in zip(trajectory.observations, trajectory.actions,
                                                          trajectory.observations[1:], trajectory.actions[1:])][:16]
    drift.reset()
    before = [drift.score(c) for c in contexts[:8]]
    copies = [copy.deepcopy(drift), pickle.loads(pickle.dumps(drift))]
    after = [drift.score(c) for c in contexts[8:]]
    for other in copies:
        assert [other.score(c) for c in contexts[8:]] == after
    assert all(value > 0 for value in before + after)


def test_a_long_observations_drift_sums_its_residuals_sparse_to_the_same_scores(monkeypatch):
    """The product that sums a step's outputs grows with the square of the readings: 348 readings'
    was a dense 151 MB array and 10.6 ms a step (benchmarks/drift_step.py's wide case: 101 times the
    dynamics step, 2.0 since). Past DENSE_PRODUCT entries it is sparse; the scores are the dense ones."""
    import oodmon.monitor.detectors.drift as drift

    from oodmon.monitor.detectors.base import Trajectory

    rng = np.random.default_rng(0)
    episodes = []
    for _ in range(4):
        observations, actions = [rng.normal(size=60)], rng.uniform(-1, 1, (100, 3)).astype(np.float32)
        for action in actions:
            observations.append(0.95 * observations[-1] + 0.05 * action.sum() + rng.normal(0, 0.05, 60))
        episodes.append(Trajectory(np.asarray(observations, np.float32), actions))
    model = DynamicsDetector(None, epochs=2, seed=0).fit(episodes[:3])
    sparse = DriftDetector.of(model)
    scores = _scores(sparse, episodes[3:])[0]
    assert not isinstance(sparse._product, np.ndarray) and sparse._product.shape[0] * sparse._product.shape[1] > 300_000
    monkeypatch.setattr(drift, "DENSE_PRODUCT", 10**9)
    dense = DriftDetector.of(model)
    np.testing.assert_allclose(scores, _scores(dense, episodes[3:])[0], rtol=1e-12)
    assert isinstance(dense._product, np.ndarray) and scores.max() > 0
