"""The detectors: each separates a shift it should see, fits and scores deterministically, survives
a save/load round trip exactly, and refuses what it was not made for; the monitor runs them all and
logs every score, also for a plain policy that has no samples of its own."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from oodmon.agents import load, zoo_names
from oodmon.envs import Variant, parse_variant
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor import McapSink, MemorySink, Monitor, Threshold, calibrate_agent
from oodmon.monitor.detectors.base import RunningMean
from oodmon.monitor.detectors import (
    FIT_VERSION, CombinedDetector, DetectorSet, DynamicsDetector, FeaturesDetector, SpreadDetector, StepContext, collect,
    Trajectory, best_detector, detectors_for, fit_detectors, trajectory_scores,
)
from oodmon.monitor.scores import score_function
from oodmon.replay import compute_all_metrics, read_log
from oodmon.versions import machine


def _auroc(id_scores, ood_scores) -> float:
    id_scores, ood_scores = np.concatenate(id_scores), np.concatenate(ood_scores)
    labels = np.r_[np.zeros(len(id_scores)), np.ones(len(ood_scores))]
    return float(roc_auc_score(labels, np.r_[id_scores, ood_scores]))


def _transition_scores(detector, trajectories):
    return [detector.score_transitions(t.observations[:-1], t.actions, t.observations[1:]) for t in trajectories]


@pytest.fixture(scope="module")
def agent():
    return load("cartpole", "ensemble")


@pytest.fixture(scope="module")
def id_trajectories(agent):
    return collect(agent, Variant("cartpole").make(), 7, seed=600_000)


@pytest.fixture(scope="module")
def fitted(agent):
    """spread, dynamics, features and combined for the CartPole ensemble, on 6 ID episodes."""
    return fit_detectors(agent, Variant("cartpole").make(), episodes=6, task="cartpole")


# -- what each detector sees ----------------------------------------------------------------------
@pytest.mark.parametrize("spec", ["cartpole:length=2.0", "cartpole:gravity=98.0"])
def test_dynamics_separates_changed_physics_from_id(agent, id_trajectories, spec):
    """Fitted on 4 ID episodes (2,000 transitions; a few seconds), scored on 3 fresh ID and 3 shifted
    episodes, every transition: far above chance (0.5). Measured 0.99-1.00 with the defaults."""
    detector = DynamicsDetector(2, epochs=15, seed=0).fit(id_trajectories[:4])
    shifted = collect(agent, parse_variant(spec).make(), 3, seed=500_000)
    assert _auroc(_transition_scores(detector, id_trajectories[4:]), _transition_scores(detector, shifted)) > 0.9


def test_the_shipped_detectors_see_a_stuck_sensor_of_the_shipped_cartpole_ensemble_before_the_pole_falls():
    """The pole's angular velocity frozen from step 50 (``cartpole:obs.stuck[3]=1``; the world is
    ID's): the ensemble pushes on blind and the pole falls some 10 steps later. Measured with `oodmon
    run` (onset 100, 10 episodes, the calibrated threshold): every episode alarmed 1 step after the
    onset, 8 steps before the fall; per-step AUROC 1.000 for dynamics and combined."""
    from oodmon import seeds

    agent = load("cartpole", "ensemble")
    sink = MemorySink()
    with Monitor(agent, detectors=detectors_for(agent), sinks=[sink]) as monitor:
        lengths = [monitor.run_episode(parse_variant("cartpole:obs.stuck[3]=1").make(onset_step=50),
                                       seed=seeds.BENCH_SHIFTED + k).length for k in range(3)]
    assert all(50 < length < 80 for length in lengths)  # it falls, soon after the fault
    episodes = [[r for r in sink.steps if r.episode == k] for k in range(3)]
    for detector in ("dynamics", "combined"):
        id_steps = [[r.scores[detector] for r in episode if not r.shifted] for episode in episodes]
        faulted = [[r.scores[detector] for r in episode if r.shifted] for episode in episodes]
        assert _auroc(id_steps, faulted) > 0.99
        # every faulted step (the first too, whose angular velocity is the last one read) but the
        # first scores above every ID step of its episode
        assert all(min(f[1:]) > max(i) for i, f in zip(id_steps, faulted))


def test_the_shipped_combined_detector_sees_doubled_gravity_that_the_agent_survives():
    """CartPole DropConnect mostly keeps the pole up under gravity=19.6, and each transition is only a
    little surprising. On the bench's episodes (10 ID, 5 shifted, four kept up for 500 steps here;
    seeded, so deterministic; each step scored off the samples its decision was made from, as the
    monitor scores it) the shipped combined detector separates its steps from ID ones: with a
    dynamics model fitted 30 epochs at a constant learning rate (fitting versions up to 6) the
    members ranked alone reached 0.917 (0.810 fitted on 30 episodes), and the dynamics detector's
    mean since the episode began lifted the combined detector to 0.999; fitted longer, the rate
    falling to 0 (version 8), the members alone reach 0.9993, the combined detector 0.9994."""
    from oodmon import seeds

    agent = load("cartpole", "dropconnect", seed=seeds.CALIBRATION)
    detectors = detectors_for(agent)
    combined = detectors["combined"]
    assert combined.long_members == ["dynamics"]

    def scored(spec, episodes, seed):
        sink = MemorySink()  # every detector's score of each step, off the samples its decision was made from
        with Monitor(agent, detectors=detectors, sinks=[sink]) as monitor:
            lengths = [monitor.run_episode(parse_variant(spec).make(), seed=seed + k).length for k in range(episodes)]
        steps = [[r for r in sink.steps if r.episode == k] for k in range(episodes)]
        members_only = [[max(combined.rank(m, r.scores[m]) for m in combined.members) for r in episode]
                        for episode in steps]
        return [[r.scores["combined"] for r in episode] for episode in steps], members_only, lengths

    id_combined, id_members, _ = scored("cartpole", 10, seeds.BENCH_ID)
    shifted_combined, shifted_members, lengths = scored("cartpole:gravity=19.6", 5, seeds.BENCH_SHIFTED)
    assert sum(length == 500 for length in lengths) >= 3  # the agent survives most of them
    members, both = _auroc(id_members, shifted_members), _auroc(id_combined, shifted_combined)
    assert both > 0.99 and both >= members - 0.002, (members, both)


def test_dynamics_copes_with_sensor_noise(agent):
    """With 1% sensor noise in ID and shifted worlds alike the model learns the noise as variance
    and still separates length=2.0 (measured 0.998 with the defaults)."""
    train = collect(agent, Variant("cartpole").make(obs_noise=0.01), 6, seed=600_000)
    detector = DynamicsDetector(2, epochs=15, seed=0).fit(train[:4])
    shifted = collect(agent, parse_variant("cartpole:length=2.0").make(obs_noise=0.01), 3, seed=500_000)
    assert _auroc(_transition_scores(detector, train[4:]), _transition_scores(detector, shifted)) > 0.9


def test_features_separate_gaussian_noise_frames_in_pong():
    """Mahalanobis distance of the Pong ensemble's 512 CNN features, fitted on 300 ID frames,
    against 150 fresh ID frames and 150 frames under gaussian_noise@5 (each step's own distance,
    and the default mean over 20 steps)."""
    pong = load("pong", "ensemble")
    env = Variant("pong").make()
    train = collect(pong, env, 3, seed=600_000, max_steps=100)
    fresh = collect(pong, env, 1, seed=600_010, max_steps=150)
    noisy = collect(pong, parse_variant("pong:gaussian_noise@5").make(), 1, seed=500_000, max_steps=150)
    detectors = [FeaturesDetector(6, window=1).fit(train), FeaturesDetector(6).fit(train)]

    def scores(detector, trajectories):
        out = []
        for t in trajectories:
            detector.reset()
            out.append(np.array([detector.score(StepContext(o, a, pong.estimate(o)))
                                 for o, a in zip(t.observations[:-1], t.actions)]))
        return out
    for detector in detectors:
        assert _auroc(scores(detector, fresh), scores(detector, noisy)) > 0.9


def test_spread_detector_gives_the_scores_of_before(agent, id_trajectories):
    obs = id_trajectories[0].observations[:50]
    for name in ("chosen_std", "mean_std", "max_std", "margin_std"):
        detector = SpreadDetector(name)
        for o in obs:
            estimate = agent.estimate(o)
            assert detector.score(StepContext(o, int(estimate.action[0]), estimate)) == float(
                score_function(name)(estimate)[0])


def test_collect_keeps_the_estimates_from_the_episode_asked_and_trajectory_scores_reads_them():
    """collect(estimates_from=1): the first episode keeps none, the second one per action, the
    estimate its action was chosen from; trajectory_scores then scores those, asking no estimator."""
    dropout = load("cartpole", "dropout", seed=3)
    first, second = collect(dropout, Variant("cartpole").make(), 2, seed=610_000, max_steps=30, estimates_from=1)
    assert first.estimates is None and len(second.estimates) == len(second) == 30
    assert [int(e.action[0]) for e in second.estimates] == [int(a) for a in second.actions]
    kept = trajectory_scores(DetectorSet([SpreadDetector()]), second)["spread"]  # no estimator given
    np.testing.assert_array_equal(kept, [score_function("chosen_std")(e)[0] for e in second.estimates])
    with pytest.raises(ConfigError, match="one estimate per action"):
        Trajectory(second.observations, second.actions, estimates=second.estimates[:-1])


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
def test_combined_ranks_the_spread_the_monitor_reads_off_the_samples_each_action_was_chosen_from(method):
    """fit_detectors plays its ID episodes once: the held-out third's spread, which combined ranks,
    is that of the samples each action was chosen from, the spread a Monitor logs playing the same
    episodes from the same point of the sampling. (Before FIT_VERSION 5 an MC policy was asked
    again at each held-out step: other samples, and its sampling left elsewhere.) DropConnect's
    layers keep scratch arrays from call to call: each kept estimate must still be its own."""
    agent = load("cartpole", method, seed=1)
    start = agent.estimator.sampling_state
    fitted = fit_detectors(agent, Variant("cartpole").make(), detectors=["features", "combined"], episodes=6,
                           seed=600_000)
    after = agent.estimator.sampling_state
    agent.estimator.sampling_state = start
    collect(agent, Variant("cartpole").make(), 4, seed=600_000)  # the two thirds fitted on: the same draws
    sink = MemorySink()
    with Monitor(agent, detectors=fitted.subset(["spread"]), sinks=[sink]) as monitor:
        for episode in (4, 5):
            monitor.run_episode(Variant("cartpole").make(), seed=600_000 + episode)
    assert agent.estimator.sampling_state == after  # fitting drew once a step, as the monitor draws
    monitored = np.sort(np.array([step.scores["spread"] for step in sink.steps], np.float32))
    assert len(monitored) >= 100 and len(np.unique(monitored)) > len(monitored) // 2  # sampled: no two steps alike
    np.testing.assert_array_equal(fitted["combined"].tensors()["reference.spread"], monitored)


def test_combined_is_the_largest_id_rank_of_its_members():
    combined = CombinedDetector(["a", "b"]).fit_reference({"a": np.arange(100.0), "b": np.arange(100.0) * 10})
    context = StepContext(np.zeros(1), 0, scores={"a": 89.5, "b": 500.0})  # p = 11/101 and 50/101
    assert combined.score(context) == pytest.approx(-np.log10(11 / 101))
    beyond = combined.score(StepContext(np.zeros(1), 0, scores={"a": 99.0 + 2 * np.std(np.arange(100.0)), "b": 0}))
    assert beyond == pytest.approx(-np.log10(1 / 101) + 2.0)  # past the ID maximum it keeps growing
    assert combined.rank("a", 89.5) == pytest.approx(-np.log10(11 / 101)) and combined.rank("a", -3.0) == 0.0
    for scores in ({"a": 89.5, "b": 500.0}, {"a": -3.0, "b": 1e6}, {"a": 50.0, "b": 990.0}, {"a": 99.0, "b": 0.0}):
        ranks = [combined.rank(name, value) for name, value in scores.items()]
        assert combined.score(StepContext(np.zeros(1), 0, scores=scores)) == max(ranks)  # the same floats
    with pytest.raises(ConfigError, match="needs the scores of b"):
        combined.score(StepContext(np.zeros(1), 0, scores={"a": 1.0}))


def test_combined_names_the_member_that_gave_its_score():
    """``leader``: the statistic ranked highest at the last step (what an alarm's ``cause`` says);
    a long member's mean by its own name; the first member that could not score (NaN)."""
    rng = np.random.default_rng(2)
    reference = {"dynamics": _long_member_scores(rng, 20, 0.0), "b": _long_member_scores(rng, 20, 0.0)}
    steps_only = CombinedDetector(["dynamics", "b"], long_members=[]).fit_reference(reference)
    assert steps_only.leader is None

    def leader(combined: CombinedDetector, dynamics: float, b: float) -> str:
        combined.score(StepContext(np.zeros(1), 0, scores={"dynamics": dynamics, "b": b}))
        return combined.leader

    assert leader(steps_only, 0.0, 9.0) == "b" and leader(steps_only, 9.0, 0.0) == "dynamics"
    assert leader(steps_only, 0.0, float("nan")) == "b"
    assert leader(steps_only, float("nan"), float("nan")) == "dynamics"  # the first that could not score
    with_mean = CombinedDetector(["dynamics", "b"]).fit_reference(reference)
    for _ in range(300):  # each step a little high, none far from its ID peers: the mean stands out
        step = leader(with_mean, 1.0, 0.0)
    assert step == "dynamics (mean since the episode began)"
    assert with_mean.rank("dynamics", 1.0) < with_mean.rank("dynamics", 1.0, long=True)
    with_mean.reset()
    assert leader(with_mean, 0.0, 9.0) == "b"


def test_running_mean_is_the_mean_of_the_last_window_values_since_the_clear():
    rng = np.random.default_rng(0)
    values = rng.normal(size=700)
    mean = RunningMean(500)
    online = [mean.add(float(v)) for v in values]
    expected = [values[max(0, t - 499):t + 1].mean() for t in range(len(values))]
    np.testing.assert_allclose(online, expected, rtol=0, atol=1e-12)  # a running sum: rounding only
    np.testing.assert_array_equal(mean.along(values), online)  # the same floats as the steps gave
    mean.clear()
    assert mean.add(3.0) == 3.0


def _long_member_scores(rng, episodes, shift, steps=400):
    """Per episode, a member's per-step scores: N(shift, 1) i.i.d. (a persistent small shift when shift > 0)."""
    return [rng.normal(shift, 1.0, steps) for _ in range(episodes)]


def test_combined_ranks_a_long_members_mean_since_the_episode_began():
    """A shift that raises every step's score by half an ID standard deviation: each step alone is
    ranked near its ID peers, the mean since the start leaves the ID means behind."""
    rng = np.random.default_rng(1)
    reference = {"dynamics": _long_member_scores(rng, 20, 0.0), "b": _long_member_scores(rng, 20, 0.0)}
    with_mean = CombinedDetector(["dynamics", "b"]).fit_reference(reference)
    without = CombinedDetector(["dynamics", "b"], long_members=[]).fit_reference(reference)
    assert with_mean.long_members == ["dynamics"] and without.long_members == []

    def scores(combined, episodes_of_dynamics, episodes_of_b):
        out = []
        for dynamics, b in zip(episodes_of_dynamics, episodes_of_b):
            combined.reset()
            out.append([combined.score(StepContext(np.zeros(1), 0, scores={"dynamics": float(x), "b": float(y)}))
                        for x, y in zip(dynamics, b)])
        return out

    id_episodes = (_long_member_scores(rng, 10, 0.0), _long_member_scores(rng, 10, 0.0))
    shifted = (_long_member_scores(rng, 5, 0.5), _long_member_scores(rng, 5, 0.0))
    # Each step alone: AUROC of N(0.5, 1) against N(0, 1) is Phi(0.5 / sqrt 2) = 0.64, diluted by b's ranks.
    assert _auroc(scores(without, *id_episodes), scores(without, *shifted)) < 0.66
    # With the mean: after t steps it is N(0.5, 1/t) against ID means N(0, 1/t); from t ~ 40 on, beyond
    # nearly all of them (measured 0.90 with these seeds; the first steps of an episode stay near chance).
    assert _auroc(scores(with_mean, *id_episodes), scores(with_mean, *shifted)) > 0.85
    # The score is the largest of the members' ranks and the mean's rank, the same floats as rank() gives
    with_mean.reset()
    means = RunningMean(with_mean.horizon)
    for x, y in zip(shifted[0][0][:50], shifted[1][0][:50]):
        step = with_mean.score(StepContext(np.zeros(1), 0, scores={"dynamics": float(x), "b": float(y)}))
        assert step == max(with_mean.rank("dynamics", float(x)), with_mean.rank("b", float(y)),
                           with_mean.rank("dynamics", means.add(float(x)), long=True))


def test_a_log_member_with_a_heavy_id_tail_no_longer_sets_the_threshold_for_all():
    """A member with a heavy ID tail (Pareto scores, as the features detector's squared distances
    have) reaches, in some ID episodes, far beyond its reference maximum; ranked on its raw score
    it then puts the threshold (the largest combined score over 90 ID episodes) where a clear
    shift of another member cannot reach. Ranked by its logarithm it does not. Seeded; measured
    0 and 20 of 20 shifted episodes alarmed, 1 of 100 ID episodes each time (the threshold's
    false-alarm rate is about 1/91 either way)."""
    rng = np.random.default_rng(3)

    def episodes(n, steps=200):
        return [{"features": 1.0 + rng.pareto(1.5, steps), "dynamics": rng.normal(0.0, 1.0, steps)} for _ in range(n)]

    held_out = episodes(10)
    reference = {m: [e[m] for e in held_out] for m in ("features", "dynamics")}
    calibration, fresh_id, shifted = episodes(90), episodes(100), episodes(20)
    for episode in shifted:
        episode["dynamics"][100:120] += 6.0  # 20 steps six ID standard deviations off
    alarmed = {}
    for log in ([], ["features"]):
        combined = CombinedDetector(["features", "dynamics"], long_members=[], log_members=log).fit_reference(reference)

        def largest(episode):
            return max(combined.score(StepContext(np.zeros(1), 0, scores={"features": float(f), "dynamics": float(d)}))
                       for f, d in zip(episode["features"], episode["dynamics"]))

        threshold = max(largest(e) for e in calibration)
        alarmed[tuple(log)] = sum(largest(e) > threshold for e in shifted)
        assert sum(largest(e) > threshold for e in fresh_id) <= 5  # (binomial(100, 1/91): P(> 5) < 0.01)
    assert alarmed[()] <= 5 and alarmed[("features",)] >= 18
    # in range a log member's rank is its raw score's (a monotone map), beyond the top it grows with the log
    raw = CombinedDetector(["features"], long_members=[], log_members=[]).fit_reference({"features": reference["features"]})
    logged = CombinedDetector(["features"], long_members=[]).fit_reference({"features": reference["features"]})
    assert logged.log_members == ["features"]  # LOG_MEMBERS' default
    for value in np.quantile(np.concatenate(reference["features"]), [0.1, 0.5, 0.9, 0.999]):
        assert logged.rank("features", float(value)) == pytest.approx(raw.rank("features", float(value)))
    steps = np.concatenate(reference["features"])
    beyond = -np.log10(1 / (len(steps) + 1))  # the rank of any value past the largest ID one, before the excess
    log_std = np.log(steps).astype(np.float32).astype(np.float64).std()
    assert logged.rank("features", float(steps.max() * np.e)) == pytest.approx(beyond + 1.0 / log_std, rel=1e-5)
    with pytest.raises(ConfigError, match="must not be negative"):
        CombinedDetector(["features"], long_members=[]).fit_reference({"features": np.r_[-1.0, np.ones(9)]})


def test_combined_long_members_are_checked_and_need_per_episode_scores():
    with pytest.raises(ConfigError, match="long_members must be distinct members"):
        CombinedDetector(["a", "b"], long_members=["c"])
    with pytest.raises(ConfigError, match="log_members must be distinct members"):
        CombinedDetector(["a", "b"], log_members=["a", "a"])
    with pytest.raises(InvalidParameterError, match="horizon=0 is not allowed"):
        CombinedDetector(["dynamics"], horizon=0)
    with pytest.raises(ConfigError, match="give the ID scores of 'dynamics' per episode"):
        CombinedDetector(["dynamics", "b"]).fit_reference({"dynamics": np.arange(100.0), "b": np.arange(100.0)})


def test_a_combined_detector_saved_without_long_members_loads_as_before(fitted, agent, id_trajectories, tmp_path):
    """A detectors file from before the long members (no ``long_members`` in its config) ranks its
    members only; the fitted set ranks dynamics' mean too and survives a round trip with it."""
    assert fitted["combined"].long_members == ["dynamics"] and fitted["combined"].horizon == 500
    fitted.save(tmp_path / "det")
    meta_path = tmp_path / "det" / "detectors.json"
    meta = json.loads(meta_path.read_text())
    combined_config = next(d["config"] for d in meta["detectors"] if d["name"] == "combined")
    assert combined_config["long_members"] == ["dynamics"] and set(combined_config["long_scale"]) == {"dynamics"}
    for key in ("long_members", "horizon", "long_scale"):
        del combined_config[key]
    meta_path.write_text(json.dumps(meta))
    old = DetectorSet.load(tmp_path / "det")["combined"]
    assert old.long_members == []
    scores = trajectory_scores(fitted.subset(["spread", "dynamics", "features"]), id_trajectories[6], agent.estimator)
    for step in range(len(scores["dynamics"])):
        context = {name: float(values[step]) for name, values in scores.items()}
        assert old.score(StepContext(np.zeros(1), 0, scores=context)) == max(
            fitted["combined"].rank(name, value) for name, value in context.items())


@pytest.mark.parametrize("name", zoo_names())
def test_every_shipped_detector_set_loads_fitted_for_its_agent_by_todays_fitting(name):
    """scripts/fit_zoo_detectors.sh's output: each set loads (its tensors match their sha256), was
    fitted on the shipped agent's weights by today's fitting (FIT_VERSION), and its combined
    detector ranks dynamics' mean wherever it has dynamics (vector observations) and features by
    the logarithm of its score; Pong's combines frames, stillness and vanishing alone (COMBINED_LEAVES_OUT,
    DEFAULT_ADDS), fitted on 90 whole games."""
    from oodmon.agents import zoo_dir
    from oodmon.hashing import file_sha256

    folder = zoo_dir() / name
    detectors = DetectorSet.load(folder / "detectors")
    assert detectors.fitted_for["policy_hash"] == "sha256:" + file_sha256(folder / "model.safetensors")
    assert detectors.fitted_for["version"] == FIT_VERSION and detectors.fitted_for["task"] == name.split("-")[0]
    combined = detectors["combined"]
    assert combined.long_members == (["dynamics"] if "dynamics" in detectors else [])
    assert combined.log_members == (["features"] if "features" in combined.members else [])
    others = [d for d in detectors.names if d != "combined"]
    assert combined.members == (["frames", "stillness", "vanishing"] if name.startswith("pong") else others)
    if name.startswith("pong"):
        assert detectors.fitted_for["episodes"] == 90 and detectors["vanishing"].events.shape == (2, 144)


# -- determinism and files ----------------------------------------------------------------------------
def test_fit_and_score_are_deterministic_under_a_seed(id_trajectories):
    first = DynamicsDetector(2, epochs=3, seed=7).fit(id_trajectories[:2])
    second = DynamicsDetector(2, epochs=3, seed=7).fit(id_trajectories[:2])
    for key, value in first.tensors().items():
        np.testing.assert_array_equal(value, second.tensors()[key])
    other = DynamicsDetector(2, epochs=3, seed=8).fit(id_trajectories[:2])
    assert not np.array_equal(first.tensors()["layer0.weight"], other.tensors()["layer0.weight"])
    pedm = [DynamicsDetector(2, kind="pedm", epochs=3, seed=7).fit(id_trajectories[:2]) for _ in range(2)]
    a, b = (_transition_scores(d, id_trajectories[2:3])[0] for d in pedm)  # pedm draws: seeded too
    np.testing.assert_array_equal(a, b)


def test_the_dynamics_fit_trains_the_same_model_inside_the_callers_no_grad_or_inference_mode(id_trajectories):
    """oodmon.watch or calibrate_agent called inside the user's own torch.no_grad() stopped in the fit
    with autograd's "element 0 of tensors does not require grad" (found 2026-12-05); the caller's
    mode is left as it was."""
    import torch

    free = DynamicsDetector(2, epochs=3, seed=7).fit(id_trajectories[:2]).tensors()
    for mode in (torch.no_grad, torch.inference_mode):
        with mode():
            inside = DynamicsDetector(2, epochs=3, seed=7).fit(id_trajectories[:2]).tensors()
            assert not torch.is_grad_enabled()
        for key, value in free.items():
            np.testing.assert_array_equal(value, inside[key])
    assert torch.is_grad_enabled() and not torch.is_inference_mode_enabled()


def test_the_dynamics_fit_reports_each_epoch_and_fits_the_same_model(id_trajectories):
    """A fit of long observations took minutes after the last episode's progress line, said nothing."""
    reports = []
    reported = DynamicsDetector(2, epochs=3, seed=7).fit(id_trajectories[:2], on_progress=lambda *r: reports.append(r))
    assert reports == [("dynamics model fitting epochs", k, 3) for k in (1, 2, 3)]
    silent = DynamicsDetector(2, epochs=3, seed=7).fit(id_trajectories[:2])
    for key, value in reported.tensors().items():
        np.testing.assert_array_equal(value, silent.tensors()[key])


def test_save_and_load_give_identical_scores(fitted, agent, id_trajectories, tmp_path):
    fitted.save(tmp_path / "det")
    loaded = DetectorSet.load(tmp_path / "det")
    assert loaded.names == fitted.names == ["spread", "dynamics", "features", "combined"]
    assert loaded.fitted_for["task"] == "cartpole" and loaded.fitted_for["obs_shape"] == [4]
    assert loaded.fitted_for["version"] == FIT_VERSION  # what the bench keys its cache on
    shifted = collect(agent, parse_variant("cartpole:length=2.0").make(), 1, seed=500_000)[0]
    for trajectory in (id_trajectories[6], shifted):
        before = trajectory_scores(fitted, trajectory, agent.estimator)
        after = trajectory_scores(loaded, trajectory, agent.estimator)
        for name in fitted.names:
            np.testing.assert_array_equal(before[name], after[name])
    meta = json.loads((tmp_path / "det" / "detectors.json").read_text())
    assert meta["format"] == "oodmon.detectors" and "safetensors_sha256" in meta
    # the CPU kind that fitted them (another kind's kernels fit other numbers), kept through save and load
    assert meta["fitted_for"]["machine"] == loaded.fitted_for["machine"] == machine()


def test_a_damaged_or_foreign_detectors_file_is_refused(fitted, tmp_path):
    folder = fitted.save(tmp_path / "det")
    data = bytearray((folder / "detectors.safetensors").read_bytes())
    data[-10] ^= 0xFF
    (folder / "detectors.safetensors").write_bytes(bytes(data))
    with pytest.raises(ConfigError, match="sha256"):
        DetectorSet.load(folder)
    with pytest.raises(ConfigError, match="does not exist"):
        DetectorSet.load(tmp_path / "nowhere")
    (tmp_path / "device").mkdir()  # (a device was said not to exist until 2026-12-05)
    (tmp_path / "device" / "detectors.json").symlink_to("/dev/zero")
    with pytest.raises(ConfigError, match=r"detectors.json is not a regular file \(a device or a pipe\): fitted"):
        DetectorSet.load(tmp_path / "device")
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "detectors.json").write_text('{"format": "something else"}')
    (tmp_path / "foreign" / "detectors.safetensors").write_bytes(b"")
    with pytest.raises(ConfigError, match="not a detectors file"):
        DetectorSet.load(tmp_path / "foreign")
    # A setting's name damaged in detectors.json (a flipped bit, found by fuzzing; was a KeyError).
    folder = fitted.save(tmp_path / "det2")
    meta = json.loads((folder / "detectors.json").read_text())
    entry = next(e for e in meta["detectors"] if e["name"] == "combined")
    entry["config"]["memberz"] = entry["config"].pop("members")
    (folder / "detectors.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"the combined detector's settings are not valid \(KeyError: 'members'\)"):
        DetectorSet.load(folder)


def test_a_save_stopped_while_writing_leaves_the_set_that_was_there(fitted, tmp_path, monkeypatch):
    """A disk that fills or a Ctrl-C while the tensors are written (an --overwrite refit of the set a
    threshold was calibrated with): the earlier set still loads, and no part file is left."""
    import safetensors
    import safetensors.numpy

    folder = fitted.subset(["spread", "dynamics"]).save(tmp_path / "det")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}

    def stopped(tensors, filename):  # half the file on disk, then the failure
        Path(filename).write_bytes(b"\0" * 100)
        raise failure

    monkeypatch.setattr(safetensors.numpy, "save_file", stopped)
    full = safetensors.SafetensorError("Error while serializing: I/O error: No space left on device (os error 28)")
    for failure in (OSError(28, "No space left on device"), full, KeyboardInterrupt()):
        # a full disk: one OSError naming the file (safetensors' own error reached the CLI as a traceback)
        expected = (KeyboardInterrupt, None) if isinstance(failure, KeyboardInterrupt) else (
            OSError, r"detectors\.safetensors could not be written \(.*No space left on device.* MB free on its disk\)$")
        with pytest.raises(expected[0], match=expected[1]):
            fitted.save(folder)
        assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
        assert DetectorSet.load(folder).names == ["spread", "dynamics"]


# -- clear errors -----------------------------------------------------------------------------------
def test_an_unfitted_detector_is_an_error(agent):
    with pytest.raises(ConfigError, match="dynamics detector is not fitted"):
        Monitor(agent, detectors=[DynamicsDetector(2)])
    with pytest.raises(ConfigError, match="features detector is not fitted"):
        FeaturesDetector(2).score(StepContext(np.zeros(4), 0, agent.estimate(np.zeros(4, np.float32))))


def test_detectors_fitted_for_another_task_or_shape_are_refused(fitted, agent):
    pendulum = load("pendulum", "ensemble")
    with pytest.raises(ConfigError, match="fitted for task 'cartpole', not 'pendulum'"):
        Monitor(pendulum, detectors=DetectorSet([fitted["dynamics"]], fitted_for=fitted.fitted_for))
    with pytest.warns(UserWarning, match="using the fitted detectors, which do not fit this policy"):
        Monitor(pendulum, detectors=DetectorSet([fitted["dynamics"]], fitted_for=fitted.fitted_for), force=True)
    with pytest.raises(ConfigError, match="fitted on observations of 4 numbers"):
        fitted["dynamics"].score_transitions(np.zeros((1, 3)), np.zeros(1, int), np.zeros((1, 3)))
    with pytest.raises(ConfigError, match="fitted on 256 features"):
        fitted["features"].score(StepContext(np.zeros(3), np.zeros(1), pendulum.estimate(np.zeros(3, np.float32))))


def test_a_threshold_naming_a_detector_the_monitor_lacks_is_refused(agent, fitted):
    threshold = Threshold(1.0, "chosen_std", 3, "episode", 0.05, 20, 100, task="cartpole", detector="dynamics")
    with pytest.raises(ConfigError, match=r"reads the 'dynamics' detector, which this monitor does not have .*"
                                          r"an oodmon agent's shipped ones are detectors_for\(agent\)"):
        Monitor(agent, threshold)
    Monitor(agent, threshold, detectors=fitted)  # with it: fine
    # a threshold that records its detectors' fit names it: which folder to give
    recorded = Threshold(1.0, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", detector="dynamics",
                         detectors_hash=fitted.fingerprint("dynamics"))
    with pytest.raises(ConfigError, match=r"does not have .*; the threshold was calibrated with fitted dynamics "
                                          rf"detectors {fitted.fingerprint('dynamics')[:19]}\.\.\.$"):
        Monitor(agent, recorded)
    with pytest.raises(ConfigError, match=r"nothing to score: .*; the threshold was calibrated with fitted dynamics "
                                          rf"detectors {fitted.fingerprint('dynamics')[:19]}\.\.\.$"):
        Monitor(lambda obs: 0, recorded)
    with pytest.raises(ConfigError, match=r"nothing to score: .*Monitor\(detectors=fit_detectors\(\.\.\.\)\)\)$"):
        Monitor(lambda obs: 0, threshold)  # it records none: nothing more to say
    with pytest.raises(InvalidParameterError, match="detector='sonar'"):
        Threshold(1.0, "chosen_std", 3, "episode", 0.05, 20, 100, detector="sonar")
    with pytest.raises(ConfigError, match="needs it fitted"):
        calibrate_agent(agent, 20, detector="features")


@pytest.mark.parametrize("name", [n for n in zoo_names()])
def test_a_fitted_detectors_fingerprint_reads_the_same_from_its_files(name, tmp_path):
    """Every shipped set (dynamics, features, frames, combined, scaled_spread among them), written
    and read again: each learned detector's fingerprint unchanged; spread learns nothing (None)."""
    task, method = name.split("-")
    shipped = detectors_for(load(task, method))
    shipped.save(tmp_path / "copy")
    copy = DetectorSet.load(tmp_path / "copy")
    learned = [n for n in shipped.names if n != "spread"]
    assert learned and all(copy.fingerprint(n) == shipped.fingerprint(n) for n in learned)
    assert len({shipped.fingerprint(n) for n in learned}) == len(learned)  # each its own
    assert "spread" not in shipped or shipped.fingerprint("spread") is None


def test_a_threshold_records_its_fitted_detectors_and_refuses_others(agent, fitted):
    """The scale of a learned detector's score is its fit's: a threshold calibrated with one fit
    records its fingerprint, and a monitor given another fit of the same detector (or a combined
    detector over another fit of a member) refuses it, or with force warns."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its early-peaks note: a fit on 6 episodes
        threshold = calibrate_agent(agent, 19, detectors=fitted, detector="dynamics", confidence=None)
    assert threshold.detectors_hash == fitted.fingerprint("dynamics")
    Monitor(agent, threshold, detectors=fitted)  # the same fit: fine
    refit = DynamicsDetector(2, seed=1).fit(collect(agent, Variant("cartpole").make(), 2, seed=600_100))
    assert refit.fingerprint() != fitted["dynamics"].fingerprint()
    other = fitted.with_detector(refit)
    with pytest.raises(ConfigError, match="calibrated with other fitted dynamics detectors"):
        Monitor(agent, threshold, detectors=other)
    with pytest.warns(UserWarning, match="calibrated with other fitted dynamics detectors"):
        Monitor(agent, threshold, detectors=other, force=True)
    # combined: its own fit and its learned members' (spread learns nothing: the score says it)
    assert other.fingerprint("combined") != fitted.fingerprint("combined")
    assert other.fingerprint("features") == fitted.fingerprint("features")
    combined = Threshold(1.0, "chosen_std", 1, "episode", 0.05, 20, 100, detector="combined",
                         detectors_hash=fitted.fingerprint("combined"))
    Monitor(agent, combined, detectors=fitted)
    with pytest.raises(ConfigError, match="other fitted combined detectors"):
        Monitor(agent, combined, detectors=other)
    with pytest.raises(InvalidParameterError, match="detectors_hash=3"):
        Threshold(1.0, "chosen_std", 3, "episode", 0.05, 20, 100, detectors_hash=3)


def test_an_old_threshold_file_reads_as_spread(tmp_path):
    path = tmp_path / "old.json"
    path.write_text(json.dumps({"value": 1.0, "score": "chosen_std", "consecutive": 3, "mode": "episode",
                                "far": 0.05, "n_episodes": 20, "n_steps": 100}))
    assert Threshold.load(path).detector == "spread"


# -- the monitor with detectors -----------------------------------------------------------------------
def test_the_monitor_logs_every_detector_and_alarms_on_the_named_one(agent, fitted, tmp_path):
    sink = MemorySink()
    env = parse_variant("cartpole:length=2.0").make(onset_step=30)
    with Monitor(agent, threshold=1.0, detector="combined", detectors=fitted,
                 sinks=[sink, McapSink(tmp_path / "run.mcap")]) as monitor:
        monitor.run_episode(env, seed=3, variant="cartpole:length=2.0")
        monitor.run_episode(Variant("cartpole").make(), seed=4, variant="cartpole")
    assert all(set(s.scores) == {"spread", "dynamics", "features", "combined"} for s in sink.steps)
    assert all(s.score == s.scores["combined"] for s in sink.steps)
    assert sink.run.detector == "combined" and sink.run.detectors == ("spread", "dynamics", "features", "combined")
    log = read_log(tmp_path / "run.mcap")
    assert log.detector == "combined" and log.detectors == ["spread", "dynamics", "features", "combined"]
    first = [s for s in sink.steps if s.episode == 0]
    np.testing.assert_array_equal(log.episodes[0].detector_scores["dynamics"], [s.scores["dynamics"] for s in first])
    rows = compute_all_metrics([log])
    assert [(m.detector, m.variant) for m in rows if m.auroc is not None] == [
        (name, "cartpole:length=2.0") for name in ("spread", "dynamics", "features", "combined")]
    by_detector = {m.detector: m.auroc for m in rows if m.auroc is not None}
    assert by_detector["dynamics"] > 0.9 and by_detector["combined"] > 0.9
    # The alarm figures belong to the detector the alarm read; the others raised none.
    assert {m.detector: m.detection_rate is not None for m in rows if m.auroc is not None} == {
        "spread": False, "dynamics": False, "features": False, "combined": True}
    assert {m.detector: m.false_alarm_rate is not None for m in rows if m.variant == "cartpole"} == {
        "spread": False, "dynamics": False, "features": False, "combined": True}


def test_replay_plots_draw_the_auroc_of_every_detector_the_log_holds(agent, fitted, tmp_path, monkeypatch):
    """`replay --plots`: AUROC against the shift and the ROC get a line per detector logged (they drew
    the alarm's detector alone), each ROC's AUROC the table's; `--detector` draws that one."""
    from oodmon.cli import main
    from oodmon.replay import compute_all_metrics, plots, read_log

    with Monitor(agent, threshold=1.0, detector="combined", detectors=fitted,
                 sinks=[McapSink(tmp_path / "run.mcap")]) as monitor:
        monitor.run_episode(parse_variant("cartpole:length=2.0").make(onset_step=30), seed=3, variant="cartpole:length=2.0")
    table = {m.detector: m.auroc for m in compute_all_metrics([read_log(tmp_path / "run.mcap")]) if m.auroc is not None}
    assert sorted(table) == ["combined", "dynamics", "features", "spread"] and len(set(table.values())) > 1
    drawn = {}
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.update({Path(path).name: fig}) or Path(path))
    for argv, names in (([], ["combined", "dynamics", "features", "spread"]), (["--detector", "dynamics"], ["dynamics"])):
        assert main(["replay", str(tmp_path / "run.mcap"), "--plots", str(tmp_path / "plots"), *argv]) == 0
        lines = drawn["auroc_vs_shift_cartpole.png"].axes[0].get_lines()
        assert sorted(line.get_label() for line in lines if line.get_label().startswith("ensemble")) == [
            f"ensemble, {name}" for name in names]
        curves = [line.get_label() for line in drawn["roc_cartpole_length_2.0.png"].axes[0].get_lines()
                  if line.get_label().startswith("ensemble")]
        assert curves == [f"ensemble, {name} (AUROC {table[name]:.3f})" for name in names]


def test_a_plain_policy_is_watched_with_the_actions_it_takes(agent, fitted):
    """A policy without samples (here: always push right) is watched, not replaced: the monitor
    scores the transitions its actions cause with the dynamics detector."""
    dynamics = DetectorSet([fitted["dynamics"]], fitted_for=fitted.fitted_for)
    sink = MemorySink()
    env = gymnasium.make("oodmon/CartPole-v1", length=2.0)
    with Monitor(None, threshold=0.0, detectors=dynamics, sinks=[sink]) as monitor:
        monitor.begin_episode(variant="cartpole:length=2.0")
        obs, _ = env.reset(seed=0)
        for _ in range(5):
            assert monitor.step(obs, action=1) == 1
            obs, *_ = env.step(1)
        monitor.end_episode()
    assert [s.action for s in sink.steps] == [1] * 5 and sink.steps[0].mean == []
    assert set(sink.steps[0].scores) == {"dynamics"}
    with pytest.raises(ConfigError, match="need the policy's samples or features"):
        Monitor(None, detectors=fitted)
    with Monitor(lambda obs: 0, detectors=dynamics) as monitor:  # a callable policy acts itself
        record = monitor.run_episode(Variant("cartpole").make(), seed=1)
    assert record.length > 0
    with pytest.raises(ConfigError, match="pass the deployed action"):
        with Monitor(None, detectors=dynamics) as monitor:
            monitor.begin_episode()
            monitor.step(np.zeros(4, np.float32))


def test_dynamics_scores_the_mean_of_its_last_window_transitions(fitted, id_trajectories):
    """The monitor's per-step dynamics score: the first step is the neutral (median ID) value, then
    the mean surprise of the last 20 transitions, starting afresh each episode, a mean of n < 20
    moved toward the neutral value by sqrt(n / 20) (``early="mean"``: not moved); equal to the
    batch path's numbers up to float32 rounding."""
    dynamics = fitted["dynamics"]
    assert dynamics.early == "standardised"  # a fit's default
    trajectory = id_trajectories[6]
    raw = np.r_[dynamics.neutral, dynamics.score_transitions(trajectory.observations[:-2], trajectory.actions[:-1],
                                                             trajectory.observations[1:-1])]
    means = np.array([raw[max(0, t - 19):t + 1].mean() for t in range(len(raw))])
    count = np.minimum(np.arange(1, len(raw) + 1), 20)
    expected = dynamics.neutral + (means - dynamics.neutral) * np.sqrt(count / 20)
    # from 20 transitions on not moved (sqrt(20 / 20) = 1: the same but for rounding, as fits on another
    # CPU kind showed, 2026-12-03), before them moved by far more than rounding
    np.testing.assert_allclose(expected[20:], means[20:], rtol=1e-6)
    assert np.abs(expected[1:19] - means[1:19]).max() > 0.1
    for _ in range(2):  # a second episode starts afresh
        got = trajectory_scores(DetectorSet([dynamics]), trajectory)["dynamics"]
        np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)
    plain = DynamicsDetector.from_state(dynamics.config() | {"early": "mean"}, dynamics.tensors())
    np.testing.assert_allclose(trajectory_scores(DetectorSet([plain]), trajectory)["dynamics"], means,
                               rtol=1e-4, atol=1e-4)
    with pytest.raises(InvalidParameterError, match="early='median' is not allowed; use one of standardised, mean"):
        DynamicsDetector(2, early="median")


def test_a_dynamics_detector_fitted_before_early_means_were_standardised_scores_as_it_did(fitted, tmp_path):
    """A set saved without the ``early`` key (every set fitted before FIT_VERSION 6) keeps the plain
    mean, so that a threshold calibrated on its scores keeps its meaning; a new fit saves the key."""
    fitted.save(tmp_path / "new")
    saved = json.loads((tmp_path / "new/detectors.json").read_text())
    (config,) = [d["config"] for d in saved["detectors"] if d["name"] == "dynamics"]
    assert config["early"] == "standardised"
    del config["early"]
    (tmp_path / "new/detectors.json").write_text(json.dumps(saved))
    # the JSON's own hash does not cover the key: the set loads, as an older file would
    assert DetectorSet.load(tmp_path / "new")["dynamics"].early == "mean"


def test_the_fit_stops_at_its_updates_its_rate_falling_and_older_files_read_as_fitted(tmp_path):
    """Fitting version 8: at most ``max_updates`` Adam updates in whole epochs (at least one), the
    learning rate falling linearly to 0 (``schedule="linear"``); a file without the keys was fitted
    every epoch at a constant rate and says so when loaded; bad values are refused."""
    rng = np.random.default_rng(0)
    episodes = [Trajectory(rng.standard_normal((101, 4)).astype(np.float32), rng.integers(0, 2, 100))
                for _ in range(6)]  # 600 transitions: 3 updates an epoch at a batch of 256
    reports = []
    capped = DynamicsDetector(2, epochs=8, batch_size=256, max_updates=10, seed=0).fit(
        episodes, on_progress=lambda stage, done, total: reports.append((done, total)))
    assert reports == [(k, 3) for k in (1, 2, 3)]  # 10 updates hold 3 whole epochs of 3
    one = DynamicsDetector(2, epochs=8, batch_size=256, max_updates=1, seed=0)
    one.fit(episodes, on_progress=lambda stage, done, total: reports.append(("one", done, total)))
    assert reports[-1] == ("one", 1, 1)  # never fewer than one epoch
    # the decay changes the fit; the same seed and schedule give the same one
    again = DynamicsDetector(2, epochs=8, batch_size=256, max_updates=10, seed=0).fit(episodes)
    flat = DynamicsDetector(2, epochs=8, batch_size=256, max_updates=10, seed=0, schedule="constant").fit(episodes)
    assert all(np.array_equal(a, b) for a, b in zip(capped.tensors().values(), again.tensors().values()))
    assert not np.array_equal(capped.tensors()["layer0.weight"], flat.tensors()["layer0.weight"])
    config = capped.config()
    assert config["schedule"] == "linear" and config["max_updates"] == 10
    older = {k: v for k, v in config.items() if k not in ("schedule", "max_updates")}
    loaded = DynamicsDetector.from_state(older, capped.tensors())
    assert (loaded.schedule, loaded.max_updates) == ("constant", None)
    for bad in ({"schedule": "cosine"}, {"max_updates": 0}, {"max_updates": 2.5}, {"max_updates": True}):
        with pytest.raises(InvalidParameterError, match=f"{next(iter(bad))}=.* is not allowed"):
            DynamicsDetector(2, **bad)


def test_fit_detectors_passes_its_cap_of_updates_to_the_dynamics_model_and_refuses_a_bad_one_before_playing(
        agent, monkeypatch, tmp_path):
    """``fit_detectors(dynamics_updates=)``: the cap the dynamics model is fitted with (None: every
    epoch), a fit it ended early said in the fitting's notes, and a bad cap named as the caller
    gave it and refused before the fitting's episodes are played."""
    from oodmon.monitor.detectors import fit_agent_detectors, fitting, fitting_notes

    env = Variant("cartpole").make()
    fitted = fit_detectors(agent, env, detectors=["dynamics"], episodes=3, dynamics_updates=None)
    assert fitted["dynamics"].max_updates is None and fit_detectors.__kwdefaults__["dynamics_updates"] is None
    assert fitted["dynamics"].epochs_trained == 100 and fitting_notes(fitted) == []
    # two episodes of 500 steps fit: 2 updates an epoch, so a cap of 3 ends the fit after one; said
    capped = fit_detectors(agent, env, detectors=["dynamics"], episodes=3, dynamics_updates=3)
    assert capped["dynamics"].epochs_trained == 1 and fitting_notes(capped) == [
        "dynamics: the model trained 1 of its 100 epochs, as many as hold the 3 Adam updates its fit is capped at; "
        "--dynamics-updates all (dynamics_updates=None, the default) trains every one: slower, and on the benches "
        "measured it alarmed more often or sooner, with a few more false alarms on some (docs/detectors.md, --dynamics-updates)"]
    assert not np.array_equal(capped["dynamics"].tensors()["layer0.weight"], fitted["dynamics"].tensors()["layer0.weight"])
    capped.save(tmp_path / "capped")  # a loaded model does not know how far it trained: no note
    assert fitting_notes(DetectorSet.load(tmp_path / "capped")) == []
    monkeypatch.setattr(fitting, "collect", lambda *a, **k: pytest.fail("played the fitting's episodes"))
    with pytest.raises(InvalidParameterError, match=r"^dynamics_updates=0 is not allowed"):
        fit_detectors(agent, env, detectors=["dynamics"], episodes=3, dynamics_updates=0)
    # a time limit of no steps (or False) too, by either door: it reached gymnasium's TimeLimit from
    # fit_agent_detectors, a ValueError (scripts/fuzz_api.py, 2026-12-05)
    for max_steps in (0, False, 2.5):
        with pytest.raises(InvalidParameterError, match=rf"^max_steps={max_steps!r} is not allowed"):
            fit_detectors(agent, env, detectors=["dynamics"], episodes=3, max_steps=max_steps)
        with pytest.raises(InvalidParameterError, match=rf"^max_steps={max_steps!r} is not allowed"):
            fit_agent_detectors(agent, detectors=["dynamics"], episodes=3, max_steps=max_steps)


def test_standardised_early_means_lower_the_threshold_the_id_episodes_first_steps_set(agent):
    """The shipped CartPole ensemble's dynamics detector on 40 fresh ID episodes (500 steps each),
    its means standardised (the zoo's, since fitting version 6) and plain (as before): with plain
    means 50 of 50 calibration episodes peaked within their first 20 steps, which set the threshold
    for whole episodes. With a constant learning rate (version 6) part of that was the start-up
    itself (the first transition's mean surprise -2.3, the 20th's -3.7, after step 100 -4.02 with an
    sd of 0.09), and standardised episodes still peaked early 17 of 40 times (plain 40), the median
    episode's peak above the ID steps' median 0.69 against 1.10, the threshold -2.80 against -2.34.
    Trained longer, its learning rate falling to 0 (version 8: 50 epochs here), the model is
    sharper after the start-up than during it (the plain mean -3.97 after the first transition,
    -4.04 after the 20th, -5.00 after step 100 with an sd of 0.035), so standardised episodes
    still peak early more often (30 of 40, plain 40) but lower: the median peak 1.00 above the
    median against 1.60, the threshold -3.32 against -2.26 (the median -5.00). Deterministic (the
    ensemble)."""
    import warnings

    from oodmon.monitor.threshold import EarlyPeaksWarning, calibrate

    standardised = detectors_for(agent)["dynamics"]
    assert standardised.early == "standardised"  # the zoo's sets are fitted since FIT_VERSION 6
    plain = DynamicsDetector.from_state(standardised.config() | {"early": "mean"}, standardised.tensors())
    episodes = collect(agent, Variant("cartpole").make(), 40, seed=650_000)
    assert min(len(t) for t in episodes) == 500
    scores = {name: [trajectory_scores(DetectorSet([detector]), t)["dynamics"] for t in episodes]
              for name, detector in (("plain", plain), ("moved", standardised))}
    # after step 20 the scores are the same: only the first steps moved, toward the ID median
    assert all(np.array_equal(a[20:], b[20:]) for a, b in zip(scores["plain"], scores["moved"]))
    early = {name: sum(int(np.argmax(s)) < 20 for s in values) for name, values in scores.items()}
    assert early["plain"] >= 36 and early["moved"] <= early["plain"], early
    median = float(np.median(np.concatenate(scores["plain"])))
    peak = {name: float(np.median([s.max() for s in values])) - median for name, values in scores.items()}
    assert peak["moved"] < 0.8 * peak["plain"], peak
    # far 0.1: 40 episodes are too few for 0.05 at confidence 0.9
    with pytest.warns(EarlyPeaksWarning, match="40 of the 40 calibration episodes"):  # says so for the plain means
        high = {"plain": calibrate(scores["plain"], 0.1, consecutive=1, detector="dynamics").value}
    with warnings.catch_warnings():
        warnings.simplefilter("error", EarlyPeaksWarning)  # the standardised: none (30 of 40 peak early, lower)
        high["moved"] = calibrate(scores["moved"], 0.1, consecutive=1, detector="dynamics").value
    assert high["moved"] < high["plain"] - 0.2, high


def test_the_one_step_dynamics_path_equals_the_batch_path_for_continuous_actions_and_saturated_variances():
    """The monitor's one-transition NLL (weights folded, SiLU by tanh, both soft bounds in one
    expression) against the plain batch expressions: continuous actions, every allowed floor, and
    log-variance outputs pushed far past both bounds, where no exp may overflow."""
    rng = np.random.default_rng(0)
    trajectories = []
    for _ in range(4):
        obs = [rng.standard_normal(3)]
        actions = rng.uniform(-2, 2, (60, 1))
        for a in actions:
            obs.append(0.9 * obs[-1] + 0.1 * a[0] + 0.01 * rng.standard_normal(3))
        trajectories.append(Trajectory(np.array(obs, np.float32), actions.astype(np.float32)))
    t = trajectories[0]
    for floor in (-30.0, -12.0, -6.0, -2.0):
        detector = DynamicsDetector(None, epochs=3, seed=0, min_logvar=floor).fit(trajectories[1:])
        for scale in (1.0, 1e4):  # 1e4: raw log-variances of +-thousands, far past both bounds
            w, b = detector._weights[-1]
            detector._weights[-1] = (np.concatenate([w[..., :3], w[..., 3:] * scale], -1), b * scale)
            detector._fast = None
            batch = detector.score_transitions(t.observations[:-1], t.actions, t.observations[1:])
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                one_by_one = [detector._nll_one(t.observations[k], t.actions[k], t.observations[k + 1])
                              for k in range(len(t.actions))]
            assert np.all(np.isfinite(one_by_one))
            np.testing.assert_allclose(one_by_one, batch, rtol=1e-4, atol=1e-4 * max(1.0, np.abs(batch).max()))


@pytest.mark.parametrize("members, hidden", [(1, 7), (3, 16), (5, 64)])
def test_the_one_step_dynamics_path_equals_the_batch_path_at_other_sizes(id_trajectories, members, hidden):
    """The one-transition path lays each member's units out with a constant unit and pads the first
    layer to a multiple of 16 columns (8, 51 and 325 units here): the same scores as the batch path
    for any ensemble size and width, one member included."""
    detector = DynamicsDetector(2, members=members, hidden=hidden, epochs=2, seed=0).fit(id_trajectories[:1])
    t = id_trajectories[5]
    batch = detector.score_transitions(t.observations[:-1], t.actions, t.observations[1:])
    one_by_one = [detector._nll_one(t.observations[k], t.actions[k], t.observations[k + 1]) for k in range(len(t.actions))]
    np.testing.assert_allclose(one_by_one, batch, rtol=1e-4, atol=1e-4 * max(1.0, np.abs(batch).max()))


def test_the_dynamics_floor_of_the_log_variance_is_kept_and_used_by_both_paths(id_trajectories, tmp_path):
    """min_logvar: saved and loaded with the detector (files without it read as the old -12), used by
    the monitor's one-step path as by the batch path, refused outside [-30, 2); a higher floor caps
    the surprise a near-exact transition can cause."""
    from oodmon.monitor.detectors import MIN_LOGVAR

    assert MIN_LOGVAR["pendulum"] == -6.0 and "cartpole" not in MIN_LOGVAR
    low = DynamicsDetector(2, epochs=5, seed=0).fit(id_trajectories[:3])
    high = DynamicsDetector(2, epochs=5, seed=0, min_logvar=-2.0).fit(id_trajectories[:3])
    t = id_trajectories[4]
    batch = high.score_transitions(t.observations[:-1], t.actions, t.observations[1:])
    one_by_one = [high._nll_one(t.observations[k], t.actions[k], t.observations[k + 1]) for k in range(len(t.actions))]
    np.testing.assert_allclose(one_by_one, batch, rtol=1e-4, atol=1e-4)
    assert batch.max() < low.score_transitions(t.observations[:-1], t.actions, t.observations[1:]).max()
    DetectorSet([high]).save(tmp_path / "d")
    loaded = DetectorSet.load(tmp_path / "d")["dynamics"]
    assert loaded.min_logvar == -2.0
    np.testing.assert_array_equal(loaded.score_transitions(t.observations[:-1], t.actions, t.observations[1:]), batch)
    config = {k: v for k, v in low.config().items() if k != "min_logvar"}  # as files before the setting
    assert DynamicsDetector.from_state(config, low.tensors()).min_logvar == -12.0
    for bad in (2.0, -31.0, float("nan"), "low", True):
        with pytest.raises(InvalidParameterError, match="min_logvar"):
            DynamicsDetector(2, min_logvar=bad)


def test_a_combined_detector_fitted_on_one_spread_score_is_not_used_with_another(agent):
    # The shipped CartPole detectors rank the spread by chosen_std. With margin_std the combined
    # detector's ranks would compare margin spreads with chosen_std ones: it is left out, and an
    # alarm on it is refused with what to do instead.
    fitted = detectors_for(agent)
    assert fitted["spread"].score_name == "chosen_std" and "combined" in fitted
    sink = MemorySink()
    with Monitor(agent, score="margin_std", detectors=fitted, sinks=[sink]) as monitor:
        assert sorted(monitor.detectors.names) == ["dynamics", "features", "spread"]
        assert monitor.detectors["spread"].score_name == "margin_std"
        record = monitor.run_episode(Variant("cartpole").make(), seed=3)
    assert record.length == len(sink.steps) > 0 and sorted(sink.steps[0].scores) == ["dynamics", "features", "spread"]
    estimate = agent.estimate(sink.steps[0].observation)
    assert sink.steps[0].scores["spread"] == pytest.approx(float(score_function("margin_std")(estimate)[0]))
    with Monitor(agent, score="chosen_std", detectors=fitted) as monitor:
        assert "combined" in monitor.detectors and monitor.detectors["spread"] is fitted["spread"]
    with pytest.raises(ConfigError, match=r"ranks the spread by 'chosen_std', not by 'margin_std'; refit .*"
                                          r"oodmon fit-detectors --score margin_std"):
        Monitor(agent, score="margin_std", detectors=fitted, detector="combined")
    assert best_detector("cartpole", fitted, "margin_std") == "spread"
    assert best_detector("cartpole", fitted, "chosen_std") == best_detector("cartpole", fitted) == "combined"


def test_a_used_dynamics_detector_copied_or_pickled_scores_as_the_original():
    # Its fast path's buffers are views of one another; copied with it they became separate
    # arrays, and the copy scored 274,488 where the original scores -1.68 (oodmon.watch's monitor
    # sent to a vector env's worker process is pickled after its calibration used it).
    import copy
    import pickle

    from oodmon.monitor.detectors import detectors_for

    detector = detectors_for(load("cartpole", "ensemble"), None)["dynamics"]
    rng = np.random.default_rng(0)
    transitions = [(rng.normal(size=4).astype(np.float32) * 0.1, int(rng.integers(2)),
                    rng.normal(size=4).astype(np.float32) * 0.1) for _ in range(20)]

    def scores(d) -> list[float]:
        d.reset()
        return [d.score(StepContext(obs, 0, prev_obs=prev, prev_action=action)) for prev, action, obs in transitions]

    original = scores(detector)  # builds the fast path
    assert scores(copy.deepcopy(detector)) == original
    assert scores(pickle.loads(pickle.dumps(detector))) == original


def _stacked_cartpole(flat: bool, **physics) -> gymnasium.Env:
    from gymnasium.wrappers import FlattenObservation, FrameStackObservation

    env = FrameStackObservation(Variant("cartpole", physics).make(onset_step=20), 4)
    return FlattenObservation(env) if flat else env


def test_stacked_vector_observations_are_watched_by_a_dynamics_model_of_them_flattened(tmp_path):
    # CartPole's state stacked 4 deep, a float Box (4, 4), was read as a 4 x 4 picture by the frames
    # detector: gravity=49.0 at AUROC 0.381, where a dynamics model of the 16 numbers reads 0.846
    # (10 ID against 5 shifted episodes, a hand-written controller; length=2.0: 0.915 against 0.989).
    from oodmon.monitor import MemorySink, Monitor
    from oodmon.monitor.detectors import DetectorSet, DynamicsDetector, Trajectory, default_detectors, fit_detectors
    from oodmon.monitor.detectors.frames import is_picture

    weights = np.array([0.1, 0.5, 3.0, 1.0])

    def policy(obs):
        return int(weights @ np.asarray(obs).reshape(-1, 4)[-1] > 0)  # the newest state

    assert default_detectors(policy, _stacked_cartpole(False)) == ("dynamics", "combined")
    # drift joins the default set in an env oodmon has no variants of, not in oodmon's tasks
    assert default_detectors(policy, _stacked_cartpole(False), "cartpole") == ("dynamics", "combined")
    assert default_detectors(policy, _stacked_cartpole(False), "CartPole-v0") == ("dynamics", "drift", "combined")
    assert not is_picture((4, 4), np.float32) and is_picture((4, 84, 84), np.uint8) and is_picture((40, 40, 3), np.uint8)
    # (200 updates: the two fits are compared with each other, not with the shift)
    fitted = {flat: fit_detectors(policy, _stacked_cartpole(flat), detectors=["dynamics"], episodes=9, dynamics_updates=200)
              for flat in (False, True)}
    assert fitted[False]["dynamics"].flatten and not fitted[True]["dynamics"].flatten
    fitted[False].save(tmp_path / "stacked")
    scores = {}
    for name, detectors in (("stacked", fitted[False]), ("flat", fitted[True]),
                            ("loaded", DetectorSet.load(tmp_path / "stacked"))):
        sink = MemorySink()
        with Monitor(policy, None, detectors=detectors, detector="dynamics", sinks=[sink]) as monitor:
            for seed in range(2):
                monitor.run_episode(_stacked_cartpole(name == "flat", gravity=49.0), seed=seed, max_steps=100)
        scores[name] = [step.scores["dynamics"] for step in sink.steps]
    assert scores["stacked"] == scores["flat"] == scores["loaded"]  # the same model of the same numbers
    assert len(sink.steps[0].observation) == 16  # logged flattened (it was not logged at all)
    with pytest.raises(ConfigError, match=r"got images of shape \(4, 84, 84\)"):
        DynamicsDetector(6).fit([Trajectory(np.zeros((3, 4, 84, 84), np.uint8), np.zeros(2, int))])


class _Walk(gymnasium.Env):
    """A walk on a line that ends past +-5, observed as one number: a Box of shape () (``vector``:
    the same number as a Box of shape (1,)); ``drift`` pushes it each step."""

    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self, vector: bool = False, drift: float = 0.0) -> None:
        self.observation_space = gymnasium.spaces.Box(-10, 10, shape=(1,) if vector else (), dtype=np.float32)
        self.vector, self.drift = vector, drift

    def _obs(self) -> np.ndarray:
        return np.array([self.x] if self.vector else self.x, np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return self._obs(), {}

    def step(self, action):
        self.t += 1
        self.x += (0.1 if action else -0.1) + self.drift + self.np_random.normal(0, 0.05)
        return self._obs(), 1.0, abs(self.x) > 5, self.t >= 200, {}


def test_one_number_observations_are_watched_as_a_vector_of_one(tmp_path):
    # A Box of shape () fitted, then its first scored step stopped the calibration with numpy's
    # "matmul: Input operand 0 does not have enough dimensions" (2026-12-01)
    from oodmon.monitor import MemorySink, Monitor
    from oodmon.monitor.detectors import DetectorSet, default_detectors, fit_detectors

    def policy(obs):
        return int(np.asarray(obs).reshape(-1)[0] < 0)  # back toward 0

    assert default_detectors(policy, _Walk(), "Walk-v0") == ("dynamics", "drift", "combined")
    fitted = {vector: fit_detectors(policy, _Walk(vector), detectors=["dynamics", "drift", "combined"], episodes=9)
              for vector in (False, True)}
    assert fitted[False]["dynamics"].flatten and not fitted[True]["dynamics"].flatten
    fitted[False].save(tmp_path / "walk")
    scores = {}
    for name, detectors in (("number", fitted[False]), ("vector", fitted[True]), ("loaded", DetectorSet.load(tmp_path / "walk"))):
        sink = MemorySink()
        with Monitor(policy, None, detectors=detectors, detector="combined", sinks=[sink]) as monitor:
            for seed, drift in ((0, 0.0), (1, 0.0), (2, 0.2)):
                monitor.run_episode(_Walk(name == "vector", drift), seed=seed, max_steps=200)
        scores[name] = [(step.episode, step.scores["dynamics"], step.scores["drift"], step.scores["combined"])
                        for step in sink.steps]
    assert scores["number"] == scores["vector"] == scores["loaded"]  # the same model of the same number
    walks = scores["number"]
    pushed = [dynamics for episode, dynamics, *_ in walks if episode == 2]
    assert len(pushed) < 100  # the push ends the walk (the policy's own walks last 200 steps)
    assert min(pushed[5:]) > max(dynamics for episode, dynamics, *_ in walks if episode < 2)

def test_your_own_envs_default_fitting_plays_on_until_its_episodes_hold_enough_steps(monkeypatch):
    # Acrobot's swung-up episodes are ~110 steps: 90 of them held a fifth of CartPole's steps and
    # left the dynamics model unsure of the swing-up's end, where every ID episode's score peaked.
    from stable_baselines3 import DQN

    import oodmon.monitor.detectors.fitting as fitting
    from oodmon.agents.sb3 import sb3_agent
    from oodmon.monitor.detectors import collect, fit_agent_detectors

    reports = []
    played = collect(lambda obs: 0, gymnasium.make("MountainCar-v0"), 3, min_steps=1000,
                     on_progress=lambda *report: reports.append(report))
    assert [len(t) for t in played] == [200] * 5  # 600 steps after the 3 asked, on to 1,000
    assert reports == [("detector fitting episodes", k, 3) for k in (1, 2, 3)] + [
        ("detector fitting steps", 800, 1000), ("detector fitting steps", 1000, 1000)]
    monkeypatch.setattr(fitting, "DEFAULT_FIT_EPISODES", 3)
    monkeypatch.setattr(fitting, "DEFAULT_FIT_STEPS", 1000)
    for env_id, default, asked in (("MountainCar-v0", 5, 3), ("CartPole-v1", 3, 4)):
        model = DQN("MlpPolicy", gymnasium.make(env_id), seed=0, policy_kwargs={"net_arch": [8]})
        agent = sb3_agent([model], env_id)
        assert fit_agent_detectors(agent, detectors=["dynamics"]).fitted_for["episodes"] == default
        assert fit_agent_detectors(agent, detectors=["dynamics"], episodes=asked).fitted_for["episodes"] == asked
    mountain_car = DQN("MlpPolicy", gymnasium.make("MountainCar-v0"), seed=1, policy_kwargs={"net_arch": [8]})
    fitted = fit_agent_detectors(sb3_agent([mountain_car], "MountainCar-v0"))  # combined too: its last third ranks
    assert fitted.names == ["dynamics", "drift", "combined"] and fitted.fitted_for["episodes"] == 5  # your own env: drift


def test_a_dynamics_model_fitted_on_a_still_policy_scores_a_far_transition_without_an_overflow_warning():
    """A policy that holds its env nearly still (a balanced MuJoCo InvertedPendulum: observations'
    std ~1e-3) gives normalised inputs of hundreds at an episode's first steps; the batch path's
    SiLU, z / (1 + exp(-z)), overflowed there and `oodmon calibrate` printed "overflow encountered
    in exp" (the score itself was right: SiLU of a large negative z is -0.0)."""
    rng = np.random.default_rng(0)
    trajectories = []
    for _ in range(3):
        obs = [1e-3 * rng.standard_normal(3)]
        actions = 1e-3 * rng.standard_normal((50, 1))
        for a in actions:
            obs.append(0.99 * obs[-1] + a[0] + 1e-4 * rng.standard_normal(3))
        trajectories.append(Trajectory(np.array(obs, np.float32), actions.astype(np.float32)))
    far = np.full((1, 3), 5.0, np.float32)  # thousands of the fitted stds away
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        detector = DynamicsDetector(None, epochs=3, seed=0).fit(trajectories)
        batch = detector.score_transitions(far, np.array([[1.0]], np.float32), far * 0.5)
        one = detector._nll_one(far[0], np.array([1.0], np.float32), far[0] * 0.5)
    own = trajectories[0]
    id_highest = detector.score_transitions(own.observations[:-1], own.actions, own.observations[1:]).max()
    assert np.isfinite(batch[0]) and batch[0] > 1e3 * id_highest > 0  # far out, and scored so
    np.testing.assert_allclose(one, batch[0], rtol=1e-3)


def _landings(rng, episodes: int, touch: float) -> list:
    """Episodes of a lander falling: height and speed (smooth), and a contact flag that jumps from
    0 to 1 when it lands, which it does in a ``touch`` share of the episodes (rare: LunarLander's legs)."""
    trajectories = []
    for _ in range(episodes):
        height, speed, lands = rng.uniform(5, 10), 0.0, rng.random() < touch
        obs, actions = [], []
        for _ in range(60):
            flag = float(lands and height <= 0.5)
            obs.append([height, speed, flag])
            action = rng.uniform(-1, 1)
            actions.append([action])
            speed = speed - 0.05 + 0.02 * action
            height = max(0.5 if lands else -1e9, height + speed)
        obs.append([height, speed, float(lands and height <= 0.5)])
        trajectories.append(Trajectory(np.array(obs, np.float32), np.array(actions, np.float32)))
    return trajectories


def test_a_reading_that_jumps_is_an_input_of_the_dynamics_model_not_a_prediction(tmp_path):
    """A contact flag's change is -1, 0 or +1: a Gaussian cannot model it, and one ID touch-down
    never seen in fitting scored 4e8 on a LunarLander PPO (2026-11-29), which set the threshold
    there and hid every shift. Such a reading (its change takes <= 3 values over the ID
    transitions, or it never moves) is now an input only: the fit says which readings it predicts,
    both paths score those, and the file keeps them. Continuous readings only: unchanged (None)."""
    from oodmon.monitor.detectors.dynamics import JUMP_VALUES

    rng = np.random.default_rng(0)
    never = _landings(rng, 20, touch=0.0)  # the flag never moves in fitting
    detector = DynamicsDetector(None, epochs=10, seed=0).fit(never)
    assert JUMP_VALUES == 3 and detector.predicted.tolist() == [0, 1]
    landing = _landings(np.random.default_rng(1), 40, touch=1.0)[0]
    scores = detector.score_transitions(landing.observations[:-1], landing.actions, landing.observations[1:])
    own = detector.score_transitions(never[0].observations[:-1], never[0].actions, never[0].observations[1:])
    # the touch-down and the ground after it: 3.3 (2.8e14 before the flag was an input); 2.5, the
    # fitting episodes 1.1 at most, since the fit's learning rate falls to 0 (fitting version 8)
    assert scores.max() < 10 and own.max() < 2
    one = [detector._nll_one(landing.observations[k], landing.actions[k], landing.observations[k + 1])
           for k in range(len(landing.actions))]
    np.testing.assert_allclose(one, scores, rtol=1e-4, atol=1e-4 * max(1.0, np.abs(scores).max()))
    with pytest.raises(ConfigError, match="predicts 2 readings of 3"):  # a file whose predicted readings were lost
        DynamicsDetector.from_state({k: v for k, v in detector.config().items() if k != "predicted"}, detector.tensors())
    saved = DetectorSet([detector])
    from oodmon.monitor.detectors import fitting_notes as _fitting_notes  # calibrate, fit-detectors print them

    assert detector.unscored() == [2] and _fitting_notes(saved) == [
        "dynamics: reading 2 of the observation (flattened) jumps between a few values over the ID transitions (a "
        "contact flag) or never moved: inputs of the model, not scored by it (a Gaussian cannot model a jump), so a "
        "fault of theirs alone goes unseen by this detector"]
    saved.save(tmp_path / "d")
    loaded = DetectorSet.load(tmp_path / "d")["dynamics"]
    assert loaded.predicted.tolist() == [0, 1]
    np.testing.assert_array_equal(loaded.score_transitions(landing.observations[:-1], landing.actions,
                                                           landing.observations[1:]), scores)
    for bad in ([0.0, 1.0], [True, False], "01", {"0": 1}):  # a damaged file: not truncated to whole numbers
        with pytest.raises(InvalidParameterError, match="predicted=.* is not allowed"):
            DynamicsDetector(None, predicted=bad)
    smooth = [Trajectory(t.observations[:, :2], t.actions) for t in never]
    assert DynamicsDetector(None, epochs=2, seed=0).fit(smooth).predicted is None
    every = DynamicsDetector(None, epochs=2, seed=0).fit(smooth)
    assert "predicted" not in every.config() and every.unscored() == [] and _fitting_notes(DetectorSet([every])) == []


class _PointWithLamp(gymnasium.Env):
    """A point pushed left or right, and a lamp reading that stays 0 (it would light on a fault)."""

    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = gymnasium.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state = self.np_random.normal(size=2)
        return np.array([*self.state, 0.0], np.float32), {}

    def step(self, action):
        self.state = np.array([self.state[0] + 0.1 * self.state[1], 0.9 * self.state[1] + (0.1 if action else -0.1)])
        return np.array([*self.state, 0.0], np.float32), 1.0, False, False, {}


def test_fit_detectors_says_which_readings_the_dynamics_model_does_not_score(tmp_path, capsys):
    from stable_baselines3 import DQN

    from oodmon.cli import main

    if "PointWithLampForTests-v0" not in gymnasium.registry:
        gymnasium.register("PointWithLampForTests-v0", entry_point=_PointWithLamp, max_episode_steps=40)
    DQN("MlpPolicy", gymnasium.make("PointWithLampForTests-v0"), policy_kwargs={"net_arch": [8]}, seed=0).save(
        tmp_path / "m.zip")
    assert main(["fit-detectors", "--sb3", str(tmp_path / "m.zip"), "--env", "PointWithLampForTests-v0",
                 "--episodes", "6", "--out", str(tmp_path / "d")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "dynamics: reading 2 of the observation (flattened) jumps between a few values" in said
    assert DetectorSet.load(tmp_path / "d")["dynamics"].unscored() == [2]


def test_the_dynamics_fit_refuses_id_observations_or_actions_that_are_not_finite():
    # Fitted on a CartPole whose cart position read NaN at 1% of its steps, every weight turned NaN and
    # the fitting stopped later at "the combined detector needs finite ID scores of 'dynamics'"
    from oodmon.monitor.detectors import DynamicsDetector, Trajectory

    rng = np.random.default_rng(0)
    obs = rng.normal(size=(11, 3))
    obs[[2, 7], 1], obs[4, 2] = np.nan, np.inf
    with pytest.raises(ConfigError, match=r"ID observations hold values that are not finite \(NaN or infinite\): "
                                          r"reading 1 at 2, reading 2 at 1 of 11 observations; .*a failed sensor"):
        DynamicsDetector(2).fit([Trajectory(obs, rng.integers(0, 2, 10))])
    actions = rng.normal(size=(10, 2))
    actions[3, 0] = np.nan
    with pytest.raises(ConfigError, match=r"ID actions .*: dimension 0 at 1 of 10 actions; .*the policy's actions are "
                                          r"inputs of the model"):
        DynamicsDetector().fit([Trajectory(rng.normal(size=(11, 3)), actions)])
    assert DynamicsDetector(epochs=1).fit([Trajectory(np.where(np.isfinite(obs), obs, 0.0), rng.integers(0, 2, 10))]).fitted


def test_the_dynamics_fits_adam_is_torchs_to_the_bit_and_a_fit_leaves_dynamo_unimported():
    """The fit's Adam update, written out (torch.optim.Adam.step imported torch._dynamo at its first
    call: 0.94 s of every process that fits), gives the bytes torch's Adam gives: the same random
    gradients over 60 steps of three stacked tensors, the learning rate falling as the fit's
    linear schedule lowers it; and a fit in a new process imports no torch._dynamo."""
    import subprocess
    import sys

    import torch

    from oodmon.monitor.detectors.dynamics import _adam_step

    generator = torch.Generator().manual_seed(0)
    shapes = [(5, 6, 64), (5, 1, 64), (5, 64, 8)]
    ours = [torch.randn(shape, generator=generator) for shape in shapes]
    theirs = [p.clone().requires_grad_() for p in ours]
    moments = [(torch.zeros_like(p), torch.zeros_like(p)) for p in ours]
    optimiser = torch.optim.Adam(theirs, lr=2e-3, weight_decay=1e-5)
    for step in range(60):
        grads = [torch.randn(shape, generator=generator) * 10 ** float(step % 3 - 1) for shape in shapes]
        lr = 2e-3 * (1.0 - step / 60)
        for p, g in zip(theirs, grads):
            p.grad = g.clone()
        optimiser.param_groups[0]["lr"] = lr
        optimiser.step()
        with torch.no_grad():
            _adam_step(ours, grads, moments, step + 1, lr)
        assert all(torch.equal(a, b.detach()) for a, b in zip(ours, theirs)), step
    code = ("import sys; import numpy as np; from oodmon.monitor.detectors.base import Trajectory; "
            "from oodmon.monitor.detectors.dynamics import DynamicsDetector; "
            "walk = np.cumsum(np.random.default_rng(0).standard_normal((201, 4)), 0).astype(np.float32); "
            "DynamicsDetector(2, seed=0, epochs=2).fit([Trajectory(walk, np.arange(200) % 2)]); "
            "print('torch._dynamo' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "False\n"
