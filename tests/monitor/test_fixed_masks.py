"""MC agents with fixed masks: the spread of K fixed sub-networks, beside the paper's sampled masks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from oodmon import seeds
from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.errors import ConfigError
from oodmon.monitor import MemorySink, Monitor, Threshold
from oodmon.monitor.detectors import SpreadDetector, fit_agent_detectors
from oodmon.replay import read_log
from tests.helpers import run_cli


def _margin_scores(agent, spec: str, episodes: int, seed: int) -> tuple[np.ndarray, list[int]]:
    """Every step's margin_std of ``episodes`` seeded episodes of ``spec``, each read off the samples
    its decision was made from (as the bench reads it), and each episode's length."""
    sink = MemorySink()
    with Monitor(agent, detectors=[SpreadDetector("margin_std")], sinks=[sink]) as monitor:
        lengths = [monitor.run_episode(parse_variant(spec).make(), seed=seed + k).length for k in range(episodes)]
    return np.array([record.scores["spread"] for record in sink.steps]), lengths


@pytest.fixture(scope="module")
def id_runs() -> dict[str, tuple[np.ndarray, list[int], dict]]:
    """Per kind of masks: the shipped CartPole DropConnect agent's margin_std on the bench's 10 ID
    episode seeds (sampling seed 0), the episodes' lengths, and where its sampling stood after them
    (a variant's shifted episodes go on from there, as if played right after: each test's numbers
    are those of playing all 15 in a row, without playing the ID ones once per variant)."""
    runs = {}
    for masks in ("sampled", "fixed"):
        agent = load("cartpole", "dropconnect", seed=0, masks=masks)
        scores, lengths = _margin_scores(agent, "cartpole", 10, seeds.BENCH_ID)
        runs[masks] = (scores, lengths, agent.estimator.sampling_state)
    return runs


@pytest.mark.parametrize(("variant", "sampled_at_most", "fixed_at_least"),
                         [("cartpole:length=2.0", 0.77, 0.88), ("cartpole:force_mag=1.0", 0.78, 0.93)])
def test_fixed_masks_separate_the_shipped_cartpole_dropconnect_shifts(id_runs, variant, sampled_at_most, fixed_at_least):
    # The same decisions (the same sampling seed: the same episodes, step for step), two spreads: 20
    # sampled masks per decision against 20 fixed sub-networks, on the bench's 10 ID and 5 shifted
    # episode seeds. Measured: length=2.0 0.730 against 0.920, force_mag=1.0 0.739 against 0.973
    # (the paper's DropConnect: 0.880 and 0.791); slack about 0.04.
    aurocs, lengths = {}, {}
    for masks in ("sampled", "fixed"):
        id_scores, id_lengths, state = id_runs[masks]
        agent = load("cartpole", "dropconnect", seed=0, masks=masks)
        agent.estimator.sampling_state = state
        shifted, shifted_lengths = _margin_scores(agent, variant, 5, seeds.BENCH_SHIFTED)
        labels = np.r_[np.zeros(len(id_scores)), np.ones(len(shifted))]
        aurocs[masks] = roc_auc_score(labels, np.r_[id_scores, shifted])
        lengths[masks] = id_lengths + shifted_lengths
    assert lengths["sampled"] == lengths["fixed"]  # fixed masks do not change what the agent does
    assert min(lengths["sampled"][:10]) == 500 and max(lengths["sampled"][10:]) < 100  # solves ID, fails shifted
    assert aurocs["sampled"] < sampled_at_most
    assert aurocs["fixed"] > fixed_at_least


def test_a_threshold_records_its_masks_and_is_refused_for_the_other_kind(tmp_path):
    out = tmp_path / "thr.json"
    # A loose target (25%, the fewest episodes that bound it at confidence 0.9): the masks are what is tested here.
    result = run_cli("calibrate", "--task", "cartpole", "--method", "dropconnect", "--masks", "fixed", "--score",
                     "margin_std", "--far", "0.25", "--episodes", "9", "--out", str(out))
    assert result.returncode == 0, result.stderr
    threshold = Threshold.load(out)
    assert threshold.masks == "fixed"
    with pytest.raises(ConfigError, match="it was calibrated for masks 'fixed', not 'sampled'"):
        Monitor(load("cartpole", "dropconnect"), threshold)
    with pytest.raises(ConfigError, match="masks 'fixed', not 'fixed-decisions'"):  # the same sub-networks, another policy
        Monitor(load("cartpole", "dropconnect", masks="fixed-decisions"), threshold)
    Monitor(load("cartpole", "dropconnect", masks="fixed"), threshold)  # its own kind: accepted
    # `oodmon run` takes the masks from the threshold file: no --masks needed, and none refused.
    agent = ("--task", "cartpole", "--method", "dropconnect")
    run = run_cli("run", *agent, "--threshold", str(out), "--episodes", "1", "--mcap", str(tmp_path / "id.mcap"))
    assert run.returncode == 0, run.stderr
    assert read_log(tmp_path / "id.mcap").metadata["about.masks"] == "fixed"  # the log says how it was sampled
    refused = run_cli("run", *agent, "--threshold", str(out), "--masks", "sampled", "--episodes", "1")
    assert refused.returncode != 0 and "masks 'fixed', not 'sampled'" in refused.stderr
    out.write_text(json.dumps(json.loads(out.read_text()) | {"masks": "frozen"}))
    with pytest.raises(ConfigError, match="masks='frozen' is not allowed"):
        Threshold.load(out)


def test_scaled_spread_reads_the_fixed_sub_networks_and_is_left_out_for_sampled_masks():
    fixed = load("pendulum", "dropconnect", seed=0, masks="fixed")
    detectors = fit_agent_detectors(fixed, detectors=("scaled_spread", "combined"), episodes=6, max_steps=50)
    assert detectors.fitted_for["masks"] == "fixed"
    # 20 sub-networks sharing 95% of their weights move together: their deviations are whitened
    assert detectors["scaled_spread"].normalisation == "whiten"
    assert detectors["scaled_spread"].tensors()["precision"].shape == (20, 20)
    with Monitor(fixed, detectors=detectors) as monitor:
        assert {"scaled_spread", "combined"} <= set(monitor.detectors.names)
    with Monitor(load("pendulum", "dropconnect", seed=0), detectors=detectors) as monitor:  # sampled masks
        assert "scaled_spread" not in monitor.detectors.names and "combined" not in monitor.detectors.names
    with pytest.raises(ConfigError, match="read an MC policy's samples with fixed masks"):
        Monitor(load("pendulum", "dropconnect", seed=0), 1.0, detectors=detectors, detector="scaled_spread")
    with pytest.raises(ConfigError, match="sampled MC samples are not members"):
        fit_agent_detectors(load("pendulum", "dropconnect"), detectors=("scaled_spread",), episodes=3)
