"""The transitions detector and discrete observations: a policy of FrozenLake's or Taxi's cells
gets its ints, the detectors read them one-hot, and a table of the ID transitions sees a world
that slips (docs/your-policy.md's block, run as written)."""

from __future__ import annotations

import json
import re
import shlex
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from stable_baselines3 import DQN

from oodmon.agents.plain import plain_agent
from oodmon.cli import main
from oodmon.errors import ConfigError
from oodmon.monitor import Monitor
from oodmon.monitor.detectors import DetectorSet, StepContext, Trajectory, TransitionsDetector, fit_detectors
from oodmon.monitor.detectors.fitting import collect
from oodmon.monitor.sinks.base import MemorySink
from tests.helpers import run_as_written

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "your-policy.md"


def _corridor_walks(n: int = 30, slip_every: int = 0) -> list[Trajectory]:
    """Walks right along cells 0..5 (one-hot), one step left every ``slip_every`` steps if given."""
    walks = []
    for start in range(n):
        cells, actions, cell = [start % 3], [], start % 3
        for step in range(12):
            cell = max(cell - 1, 0) if slip_every and step % slip_every == slip_every - 1 else min(cell + 1, 5)
            cells.append(cell)
            actions.append(1)
        walks.append(Trajectory(np.eye(6)[cells], np.array(actions)))
    return walks


def test_a_seen_transition_scores_low_a_slip_high_and_a_state_never_seen_by_how_rare_it_is():
    detector = TransitionsDetector(window=1).fit(_corridor_walks())
    right, slipped, stayed = (detector.step_surprise(np.eye(6)[2], 1, np.eye(6)[k]) for k in (3, 1, 2))
    assert right < 0.05  # 30 walks moved right from cell 2, every time
    assert slipped > 4.0 and stayed > 4.0  # (2, right) seen 30 times, never to 1 or 2: -log(q(s') / 31)
    never = detector.step_surprise(np.eye(6)[2], 1, np.full(6, 0.5))  # a state never seen at all
    # q(never) = 1 / (n + S + 1): the rarest next state there is
    assert never == pytest.approx(-np.log((1 / (360 + 6 + 1)) / (30 + 1)), rel=1e-9) and never > slipped
    unknown_action = detector.step_surprise(np.eye(6)[2], 0, np.eye(6)[3])  # a pair never seen: q(3) alone
    assert 0 < unknown_action < slipped


def test_an_episodes_window_starts_full_of_the_id_median_and_takes_each_step_in():
    detector = TransitionsDetector(window=4).fit(_corridor_walks())
    detector.reset()
    first = detector.score(StepContext(np.eye(6)[0], 1))
    assert first == pytest.approx(detector._typical)  # nothing seen yet: the ID median
    slip = detector.step_surprise(np.eye(6)[0], 1, np.eye(6)[0])
    second = detector.score(StepContext(np.eye(6)[0], 1, prev_obs=np.eye(6)[0], prev_action=1))
    assert second == pytest.approx((3 * detector._typical + slip) / 4)


def test_a_step_reads_the_previous_state_it_looked_up_and_scores_as_one_that_looks_it_up_again():
    detector = TransitionsDetector().fit(_corridor_walks())
    walk = _corridor_walks(1, slip_every=3)[0]
    runs = []
    for copied in (False, True):  # the monitor hands the last observation on; a copy is looked up again
        detector.reset()
        scores, prev = [], None
        for obs, action in zip(walk.observations, [None, *walk.actions]):
            handed = None if prev is None else prev.copy() if copied else prev
            scores.append(detector.score(StepContext(obs, 1, prev_obs=handed, prev_action=action)))
            prev = obs
        runs.append(scores)
    assert runs[0] == runs[1] and max(runs[0]) > detector._typical  # the slips seen either way


def test_a_fitted_table_saves_and_loads_as_arrays_and_scores_the_same(tmp_path):
    walks = _corridor_walks()
    fitted = DetectorSet([TransitionsDetector().fit(walks)])
    again = DetectorSet([TransitionsDetector().fit(walks)])
    assert fitted["transitions"].fingerprint() == again["transitions"].fingerprint()  # the same episodes, the same table
    loaded = DetectorSet.load(fitted.save(tmp_path / "det"))
    assert loaded["transitions"].fingerprint() == fitted["transitions"].fingerprint()
    assert loaded["transitions"].tensors()["states"].dtype == np.uint8  # one-hot rows kept as bytes
    for walk in _corridor_walks(5, slip_every=4):
        for step in range(1, len(walk)):
            args = (walk.observations[step - 1], walk.actions[step - 1], walk.observations[step])
            assert loaded["transitions"].step_surprise(*args) == fitted["transitions"].step_surprise(*args)


def test_what_a_table_cannot_count_is_refused_saying_why():
    rng = np.random.default_rng(0)
    continuous = [Trajectory(rng.normal(size=(21, 4)), rng.integers(0, 2, 20)) for _ in range(5)]
    with pytest.raises(ConfigError, match="states that repeat; 105 of the 105 .* use the dynamics detector"):
        TransitionsDetector().fit(continuous)
    torques = [Trajectory(np.eye(6)[[0, 1, 2, 3]], rng.normal(size=(3, 1))) for _ in range(5)]
    with pytest.raises(ConfigError, match="actions are continuous"):
        TransitionsDetector().fit(torques)
    tensors = TransitionsDetector().fit(_corridor_walks()).tensors()
    with pytest.raises(ConfigError, match="name states or actions it does not hold"):
        TransitionsDetector.from_state({"window": 20}, tensors | {"transitions": tensors["transitions"] + 100})
    # counts not positive: else a log of a negative P at a new step of a counted pair
    with pytest.raises(ConfigError, match="counts are not all positive"):
        TransitionsDetector.from_state({"window": 20}, tensors | {"counts": -tensors["counts"]})
    with pytest.raises(ConfigError, match="incomplete"):
        TransitionsDetector.from_state({"window": 20}, {k: v for k, v in tensors.items() if k != "counts"})


def test_a_plain_policy_of_discrete_cells_gets_ints_and_its_detectors_read_them_one_hot():
    seen = []

    def act(obs):  # FrozenLake's route down and right, told the cell as the env gives it
        seen.append(obs)
        return {0: 1, 4: 1, 8: 2, 9: 2, 10: 1, 14: 2}.get(int(obs), 0)

    agent = plain_agent(act, "FrozenLake-v1")  # before: "observations are Discrete(16) ... FlattenObservation"
    env = agent.make_env()
    detectors = fit_detectors(agent, env, episodes=30)
    assert detectors.names == ["transitions", "combined"]  # not the dynamics model of smooth readings
    assert all(np.ndim(obs) == 0 and float(obs) == int(obs) for obs in seen)
    trajectory = collect(agent, env, 1)[0]
    assert trajectory.observations.shape[1:] == (16,) and set(trajectory.observations.sum(axis=1)) == {1}
    sink = MemorySink()
    with Monitor(agent, detectors=detectors, sinks=[sink]) as monitor:
        episode = monitor.run_episode(env, seed=5)
    scores = [step.scores["transitions"] for step in sink.steps]
    assert episode.length == len(scores) >= 1 and np.all(np.isfinite(scores))
    assert len(sink.steps[0].observation) == 16 and sum(sink.steps[0].observation) == 1  # logged one-hot


def test_rerun_draws_a_discrete_observation_as_its_value_not_its_one_hot_vector(tmp_path):
    """A Taxi's 500 states were 500 series of 0 and 1 in Rerun; now one series of the state as the
    env gives it (the log's about.states tells the sink the one-hot blocks); the steps keep it one-hot."""
    import rerun.chunk as rc

    from oodmon.monitor.sinks.mcap import McapSink
    from oodmon.monitor.sinks.rerun import RerunSink
    from oodmon.replay import read_log

    cells = []

    def act(obs):
        cells.append(int(obs))
        return {0: 1, 4: 1, 8: 2, 9: 2, 10: 1, 14: 2}.get(int(obs), 0)

    agent = plain_agent(act, "FrozenLake-v1")
    env = agent.make_env()
    detectors = fit_detectors(agent, env, episodes=6)
    cells.clear()
    memory = MemorySink()
    sinks = [memory, RerunSink(tmp_path / "lake.rrd"), McapSink(tmp_path / "lake.mcap")]
    with Monitor(agent, detectors=detectors, sinks=sinks) as monitor:
        monitor.run_episode(env, seed=5)
    frame = rc.RrdReader(tmp_path / "lake.rrd").stream().collect().reader("step").to_pandas()
    drawn = frame["/observation:Scalars:scalars"].dropna()
    assert len(cells) >= 2 and [list(v) for v in drawn] == [[float(c)] for c in cells]
    assert [int(np.argmax(s.observation)) for s in memory.steps] == cells and len(memory.steps[0].observation) == 16
    assert read_log(tmp_path / "lake.mcap").metadata["about.states"] == "16"


def test_a_plain_policy_of_a_tuple_of_discrete_values_gets_its_tuples():
    """Blackjack's hand (Tuple(Discrete(32), Discrete(11), Discrete(2))): before, refused as FrozenLake's cell was."""
    hands = []

    def stick_at_17(hand):
        hands.append(hand)
        total, _dealer, _usable_ace = hand
        return int(total < 17)

    agent = plain_agent(stick_at_17, "Blackjack-v1")
    env = agent.make_env()
    detectors = fit_detectors(agent, env, episodes=60)
    assert detectors.names == ["transitions", "combined"]
    assert all(isinstance(hand, tuple) and len(hand) == 3 for hand in hands)
    trajectory = collect(agent, env, 1)[0]
    assert trajectory.observations.shape[1:] == (32 + 11 + 2,) and set(trajectory.observations.sum(axis=1)) == {3}


def test_an_sb3_model_of_discrete_observations_is_calibrated_and_run(tmp_path, capsys):
    """An untrained DQN on FrozenLake (SB3 reads its cell one-hot): before, oodmon refused the env."""
    model = tmp_path / "lake.zip"
    DQN("MlpPolicy", gymnasium.make("FrozenLake-v1"), seed=0).save(model)
    out = tmp_path / "lake.json"
    assert main(["calibrate", "--sb3", str(model), "--env", "FrozenLake-v1", "--out", str(out), "--fit-episodes", "30"]) == 0
    fitted = json.loads((tmp_path / "lake.json.detectors/detectors.json").read_text())
    names = [d["name"] for d in fitted["detectors"]]
    assert "transitions" in names and "dynamics" not in names and names[-1] == "combined"
    assert json.loads(out.read_text())["detector"] == "combined"
    assert main(["run", "--sb3", str(model), "--env", "FrozenLake-v1", "--threshold", str(out), "--episodes", "5",
                 "--mcap", str(tmp_path / "lake.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", "--json", str(tmp_path / "lake.mcap")]) == 0
    row = next(r for r in json.loads(capsys.readouterr().out) if r["detector"] == "transitions")
    assert row["episodes"] == 5 and row["steps"] >= 5


def test_calibrating_the_transitions_detector_fits_it_and_says_why_where_states_do_not_repeat(
        tmp_path, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(ROOT / "scripts"))
    monkeypatch.delitem(sys.modules, "slippery_taxi", raising=False)
    taxi = ["--policy", "slippery_taxi:drive", "--env", "slippery_taxi:SlipperyTaxi-v0"]
    out = tmp_path / "taxi.json"
    assert main(["calibrate", *taxi, "--detector", "transitions", "--fit-episodes", "60", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["detector"] == "transitions"
    fitted = json.loads((tmp_path / "taxi.json.detectors/detectors.json").read_text())
    assert [d["name"] for d in fitted["detectors"]] == ["transitions", "combined"]
    capsys.readouterr()
    (tmp_path / "lean.py").write_text("def act(obs):\n    return int(obs[2] > 0)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    cartpole = ["--policy", "lean:act", "--env", "CartPole-v1"]
    # before: "calibrating the transitions detector needs it fitted", after fitting the dynamics model
    assert main(["calibrate", *cartpole, "--detector", "transitions", "--fit-episodes", "3",
                 "--out", str(tmp_path / "cartpole.json")]) == 2
    assert "counts states that repeat" in capsys.readouterr().err


def test_an_ensemble_of_dqns_on_discrete_cells_samples_each_models_q_values_of_the_one_hot_cell(tmp_path):
    """SB3 reads a Discrete cell one-hot; the estimator reads the one-hot view (before: a batch of 16 cells)."""
    from oodmon.agents.sb3 import load_sb3

    models = [DQN("MlpPolicy", gymnasium.make("FrozenLake-v1"), seed=k) for k in range(3)]
    for k, model in enumerate(models):
        model.save(tmp_path / f"q{k}.zip")
    agent = load_sb3([tmp_path / f"q{k}.zip" for k in range(3)], "FrozenLake-v1")
    for cell in range(16):
        estimate = agent.estimate(agent.view(cell))
        q_values = np.stack([m.q_net(m.policy.obs_to_tensor(cell)[0]).detach().numpy()[0] for m in models])
        np.testing.assert_allclose(estimate.samples[:, 0], q_values, atol=1e-6)
        assert agent.act(agent.view(cell)) == models[0].predict(cell, deterministic=True)[0]


def _taxi_block() -> list[list[str]]:
    text = PAGE.read_text()
    section = text[text.index("### Discrete observations"):]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1).replace("\\\n", " ")
    assert "export PYTHONPATH=scripts" in block
    return [shlex.split(line)[1:] for line in block.splitlines() if line.startswith("oodmon ")]


def test_the_docs_taxi_runs_as_written_and_every_taxi_that_slipped_or_misread_alarmed(
        tmp_path, monkeypatch, capsys):
    commands = _taxi_block()
    assert [argv[0] for argv in commands] == ["calibrate", "run", "run", "run", "replay"]
    (tmp_path / "runs").mkdir()
    run_as_written(commands, tmp_path, monkeypatch, python_path=ROOT / "scripts", module="slippery_taxi")
    capsys.readouterr()
    assert main(["replay", "--json", "runs/taxi-id.mcap", "runs/taxi-slip.mcap", "runs/taxi-misread.mcap"]) == 0
    rows = {(r["variant"], r["detector"]): r for r in json.loads(capsys.readouterr().out)}
    ids = rows[("slippery_taxi:SlipperyTaxi-v0", "combined")]
    slipped = rows[("slippery_taxi:SlipperyTaxi-v0:slip=0.2", "combined")]
    misread = rows[("slippery_taxi:SlipperyTaxi-v0:obs.noise=0.1", "combined")]
    # the page's figures when written: 1 of 100 ID episodes alarmed; 74 of 100 slipping ones, AUROC
    # 0.849; 51 of 100 misreading ones. The threshold promises <= 5% per episode (confidence 0.9): at
    # 5%, 11 or more of 100 has probability 0.011
    assert ids["episodes"] == 100 and ids["false_alarm_rate"] <= 10 / 100
    assert slipped["episodes"] == 100 and slipped["detection_rate"] >= 0.6 and slipped["auroc"] > 0.8
    assert misread["episodes"] == 100 and misread["detection_rate"] >= 0.35
    import slippery_taxi

    # when written: 74 slipped, every one alarmed 1 step after its first slip, none of the 26 others;
    # 52 misread a state, 50 alarmed 1 step after the first misread, 1 of the 48 others (before the
    # onset). Over 5,260 episodes: every one of 1,445 slipped taxis alarmed, 2,661 of 2,898 misreading
    # ones (92%): fewer than 80% of some 50 has probability 0.002 at 92% (binomial)
    for log, least, rate in (("runs/taxi-slip.mcap", 60, 0.95), ("runs/taxi-misread.mcap", 35, 0.8)):
        found = slippery_taxi.faults_and_alarms(log)
        assert found["faulted"] >= least and found["faulted_alarmed"] >= rate * found["faulted"]
        assert found["others_alarmed"] <= 0.1 * (found["episodes"] - found["faulted"]) + 1
        assert np.median(found["delays"]) <= 2
    detectors = json.loads(Path("runs/taxi.json.detectors/detectors.json").read_text())
    assert [d["name"] for d in detectors["detectors"]] == ["transitions", "combined"]
    assert main(["replay", "runs/taxi-id.mcap", "runs/taxi-slip.mcap", "--plots", "runs/plots"]) == 0
    # every picture in the folder, named without the env's module's colon (a file name on no Windows
    # disk): the AUROC-against-shift one was runs/plots/auroc_vs_shift_slippery_taxi:SlipperyTaxi-v0.png
    assert sorted(p.name for p in Path("runs/plots").iterdir()) == [
        "auroc_vs_shift_slippery_taxi_SlipperyTaxi-v0.png", "roc_slippery_taxi_SlipperyTaxi-v0_slip_0.2.png",
        "trace_plain_slippery_taxi_SlipperyTaxi-v0.png", "trace_plain_slippery_taxi_SlipperyTaxi-v0_slip_0.2.png"]
