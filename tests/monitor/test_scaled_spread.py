"""The scaled_spread detector: an ensemble's spread with each member on its own ID footing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from oodmon import seeds
from oodmon.agents import load
from oodmon.agents.estimators import Estimate
from oodmon.envs import parse_variant
from oodmon.errors import ConfigError
from oodmon.monitor.detectors import (
    DetectorSet, ScaledSpreadDetector, StepContext, Trajectory, collect, fit_agent_detectors, trajectory_scores,
)
from tests.helpers import run_cli


def _estimate(pre_squash: np.ndarray) -> Estimate:
    """An estimate of K members and one observation with these outputs before the tanh (K, n)."""
    k, n = pre_squash.shape
    return Estimate(np.zeros((1, n)), np.tanh(pre_squash)[:, None], np.zeros((1, n)), np.zeros((1, n)),
                    pre_squash=pre_squash[:, None].astype(np.float32))


def _step_auroc(id_scores, shifted) -> float:
    id_scores, shifted = np.concatenate(id_scores), np.concatenate(shifted)
    return float(roc_auc_score(np.r_[np.zeros(len(id_scores)), np.ones(len(shifted))], np.r_[id_scores, shifted]))


def test_a_member_saturating_at_id_steps_no_longer_hides_the_shift():
    # Four members near 0 at ID steps, member 3 far out (a saturating actor) and swinging; shifted,
    # all disagree by about 5. The plain std is set by member 3; scaled, the shifted steps stand out.
    rng = np.random.default_rng(0)
    id_outputs = rng.normal(0.0, 0.2, (600, 4, 1))
    id_outputs[:, 3] = rng.choice([-20.0, 20.0], (600, 1))
    fit, held_out = id_outputs[:400], id_outputs[400:]
    detector = ScaledSpreadDetector().fit([Trajectory(np.zeros((401, 3)), np.zeros((400, 1)), member_values=fit)])
    shifted = rng.normal(0.0, 5.0, (200, 4, 1))

    def scores(outputs):
        return [detector.score(StepContext(np.zeros(3), np.zeros(1), _estimate(o))) for o in outputs]

    plain = [float(o.std(axis=0).mean()) for o in held_out], [float(o.std(axis=0).mean()) for o in shifted]
    assert _step_auroc([plain[0]], [plain[1]]) < 0.2
    assert _step_auroc([scores(held_out)], [scores(shifted)]) > 0.95


def _shipped_aurocs(task: str, score: str, fit_episodes: int, variant: str) -> tuple[str, float, float]:
    """The shipped ensemble with scaled_spread fitted on ``fit_episodes`` ID episodes of the
    detectors' own seeds (two thirds fit), scored on the bench's 10 ID and 5 ``variant`` episodes
    (seeded: deterministic): its normalisation, the spread's per-step AUROC and scaled_spread's."""
    agent = load(task, "ensemble")
    detectors = fit_agent_detectors(agent, detectors=("scaled_spread",), episodes=fit_episodes, score=score)
    assert detectors.names == ["spread", "scaled_spread"]

    def scored(spec, episodes, seed):
        trajectories = collect(agent, parse_variant(spec).make(), episodes, seed=seed)
        return [trajectory_scores(detectors, t, agent.estimator) for t in trajectories]

    id_scores, shifted = scored(task, 10, seeds.BENCH_ID), scored(variant, 5, seeds.BENCH_SHIFTED)
    spread, scaled = (_step_auroc([s[name] for s in id_scores], [s[name] for s in shifted])
                      for name in ("spread", "scaled_spread"))
    return detectors["scaled_spread"].normalisation, spread, scaled


def test_it_separates_the_shipped_pendulum_ensembles_shift_that_pre_squash_std_misses():
    # m=0.05, fitted on 30 of 45 episodes: measured 0.915 per step against pre_squash_std's 0.777;
    # slack of about 0.04 either way.
    normalisation, spread, scaled = _shipped_aurocs("pendulum", "pre_squash_std", 45, "pendulum:m=0.05")
    assert normalisation == "scale"  # float actions: DDPG
    assert spread < 0.82
    assert scaled > 0.88 and scaled - spread > 0.08


def test_on_a_dqn_ensemble_it_reads_each_members_centred_q_values_as_id_z_scores():
    # gravity=98.0 on the shipped CartPole ensemble, fitted on 20 of 30 episodes: measured 0.981 per
    # step against margin_std's 0.769 (the paper's ensemble: 0.772 +- 0.040); slack 0.05.
    normalisation, margin, scaled = _shipped_aurocs("cartpole", "margin_std", 30, "cartpole:gravity=98.0")
    assert normalisation == "zscore"  # integer actions: DQN
    assert margin < 0.82
    assert scaled > 0.93


def test_it_is_saved_as_tensors_and_json_and_loads_to_the_same_scores(tmp_path):
    rng = np.random.default_rng(1)
    detector = ScaledSpreadDetector().fit([Trajectory(np.zeros((51, 3)), np.zeros((50, 1)),
                                                      member_values=rng.normal(0, [[1.0], [3.0], [0.5]], (50, 3, 1)))])
    DetectorSet([detector]).save(tmp_path / "set")
    loaded = DetectorSet.load(tmp_path / "set")["scaled_spread"]
    outputs = rng.normal(0, 2.0, (3, 1))
    context = StepContext(np.zeros(3), np.zeros(1), _estimate(outputs))
    assert loaded.score(context) == detector.score(context)
    meta = json.loads((tmp_path / "set" / "detectors.json").read_text())
    assert [d["name"] for d in meta["detectors"]] == ["scaled_spread"]
    assert meta["detectors"][0]["config"] == {"normalisation": "scale"}  # float actions: DDPG
    with pytest.raises(ConfigError, match="incomplete"):
        ScaledSpreadDetector.from_state({}, {})
    with pytest.raises(ConfigError, match="finite"):
        ScaledSpreadDetector.from_state({}, {"location": np.zeros((2, 1), np.float32),
                                             "scale": np.array([[1.0], [np.nan]], np.float32)})
    with pytest.raises(ConfigError, match="not one of scale, zscore"):
        ScaledSpreadDetector.from_state({"normalisation": "rank"}, {})


def test_a_member_whose_id_outputs_sit_at_zero_does_not_divide_by_zero():
    fit = np.zeros((10, 3, 1))
    fit[:, 0], fit[:, 1] = 2.0, -4.0  # member 2 always outputs 0
    detector = ScaledSpreadDetector().fit([Trajectory(np.zeros((11, 3)), np.zeros((10, 1)), member_values=fit)])
    score = detector.score(StepContext(np.zeros(3), np.zeros(1), _estimate(np.array([[2.0], [-4.0], [0.004]]))))
    assert np.isfinite(score) and score == pytest.approx(np.std([1.0, -1.0, 1.0]), rel=1e-5)  # 0.004 / (1e-3 * 4)


def test_it_refuses_what_it_cannot_score():
    with pytest.raises(ConfigError, match="MC samples are not members"):
        fit_agent_detectors(load("pendulum", "dropout"), detectors=("scaled_spread",), episodes=3)
    detector = ScaledSpreadDetector().fit([Trajectory(np.zeros((3, 3)), np.zeros((2, 1)),
                                                      member_values=np.ones((2, 5, 1)))])
    with pytest.raises(ConfigError, match="fitted on 5 members"):  # another ensemble
        detector.score(StepContext(np.zeros(3), np.zeros(1), _estimate(np.ones((3, 1)))))
    with pytest.raises(ConfigError, match="not fitted"):
        ScaledSpreadDetector().score(StepContext(np.zeros(3), np.zeros(1), _estimate(np.ones((3, 1)))))


def test_calibrate_fits_it_when_asked_and_run_alarms_on_it(tmp_path):
    # Its ID scores are high for a while after each reset (the swing-up, when every member pushes
    # hard), so the alarm takes p-values against ID steps of the same age: CUSUM by age (docs/monitor.md).
    out = tmp_path / "thr.json"
    result = run_cli("calibrate", "--task", "pendulum", "--method", "ensemble", "--detector", "scaled_spread",
                     "--score", "pre_squash_std", "--rule", "cusum", "--reference-by-age", "--episodes", "45",
                     "--fit-episodes", "30", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "scaled_spread detector" in result.stdout
    # its threshold is on the CUSUM's scale, which the line says beside the scores' (it said the scores' alone)
    statistic = json.loads(out.read_text())["quantiles"]
    assert f"; the CUSUM per episode median {statistic['statistic_q50']:.4g}, max {statistic['statistic_max']:.4g})" \
        in result.stdout.replace("\n", " ")
    assert DetectorSet.load(f"{out}.detectors").names == ["spread", "scaled_spread"]
    assert json.loads(out.read_text())["detector"] == "scaled_spread"
    # the episodes it was made from, recorded (validate refuses them): 45 calibration, 20 reference
    assert json.loads(out.read_text())["episode_seeds"] == {"calibration": [200_000, 200_045],
                                                           "reference": [800_000, 800_020]}
    run = run_cli("run", "--task", "pendulum", "--method", "ensemble", "--threshold", str(out), "--variant",
                  "pendulum:m=0.05", "--onset", "50", "--episodes", "3", "--mcap", str(tmp_path / "m.mcap"))
    assert run.returncode == 0, run.stderr
    assert "3 of 3 episodes raised an alarm" in run.stdout
    # and none before the shift (seeded episodes; a false alarm here is at most a 5% event per episode)
    quiet = run_cli("run", "--task", "pendulum", "--method", "ensemble", "--threshold", str(out), "--episodes", "3",
                    "--seed", "777000", "--mcap", str(tmp_path / "id.mcap"))
    assert quiet.returncode == 0 and "0 of 3 episodes raised an alarm" in quiet.stdout, quiet.stdout


def _trajectory(values: np.ndarray, discrete: bool = False) -> Trajectory:
    steps = len(values)
    actions = np.zeros(steps, np.int64) if discrete else np.zeros((steps, 1))
    return Trajectory(np.zeros((steps + 1, 3)), actions, member_values=values)


def test_whitened_it_sees_members_disagree_in_a_new_pattern_of_the_same_size():
    # Four sub-networks of one network: at ID steps they disagree along one fixed pattern (loadings
    # 1, -1, 1, -1 times a common factor) plus a little noise of their own. Shifted, they disagree
    # as much, each member as much as at ID steps, but in another pattern (1, -1, -1, 1). A
    # per-member z-score sees the same sizes (AUROC about 0.5); whitened by the ID covariance of the
    # deviations, the new pattern stands out.
    rng = np.random.default_rng(0)
    loadings = np.array([1.0, -1.0, 1.0, -1.0])[None, :, None]
    pattern = np.array([1.0, -1.0, -1.0, 1.0])[None, :, None]
    id_values = loadings * rng.normal(0, 1, (900, 1, 1)) + rng.normal(0, 0.05, (900, 4, 1))
    shifted = pattern * rng.normal(0, 1, (300, 1, 1)) + rng.normal(0, 0.05, (300, 4, 1))
    fit, held_out = id_values[:600], id_values[600:]
    whitened = ScaledSpreadDetector("whiten").fit([_trajectory(fit)])
    zscored = ScaledSpreadDetector("zscore").fit([_trajectory(fit)])
    assert abs(_step_auroc([zscored.spread(held_out)], [zscored.spread(shifted)]) - 0.5) < 0.15
    # measured 0.959: the shifted steps whose common factor is near 0 disagree too little to tell
    assert _step_auroc([whitened.spread(held_out)], [whitened.spread(shifted)]) > 0.92
    # fresh ID steps read about 1 (the root mean square of whitened deviations, shrinkage aside)
    assert 0.3 < np.median(whitened.spread(held_out)) < 1.5
    step = StepContext(np.zeros(3), np.zeros(1), _estimate(shifted[0]))
    assert whitened.score(step) == pytest.approx(float(whitened.spread(shifted[:1])[0]), rel=1e-5)


def test_whitened_it_reads_a_dqn_members_half_margin_once_and_saves_as_tensors(tmp_path):
    # Centred Q-values of two actions repeat each other (q1 = -q0): the last is left out, so the
    # covariance is of K half margins; saved and loaded, the same scores.
    rng = np.random.default_rng(2)
    half_margin = rng.normal(0, 1, (400, 4, 1)) * np.array([1.0, 2.0, 0.5, 1.0])[None, :, None]
    values = np.concatenate([half_margin, -half_margin], axis=2)
    detector = ScaledSpreadDetector("whiten").fit([_trajectory(values, discrete=True)])
    assert detector.config() == {"normalisation": "whiten", "drop_last": True}
    assert detector.tensors()["precision"].shape == (4, 4)
    DetectorSet([detector]).save(tmp_path / "set")
    loaded = DetectorSet.load(tmp_path / "set")["scaled_spread"]
    np.testing.assert_array_equal(loaded.spread(values[:50]), detector.spread(values[:50]))
    with pytest.raises(ConfigError, match="fitted on 4 members' deviations"):
        detector.score(StepContext(np.zeros(3), np.zeros(1), _estimate(np.ones((3, 1)))))
    with pytest.raises(ConfigError, match="incomplete"):
        ScaledSpreadDetector.from_state({"normalisation": "whiten"}, {"mean": np.zeros(4, np.float32)})
    with pytest.raises(ConfigError, match="no per-member values"):
        detector.normalised(values)
