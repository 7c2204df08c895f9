"""An alarm names the readings whose change the dynamics model predicted worst (``AlarmEvent.readings``):
which sensor to look at. Measured on the shipped CartPole ensemble: scripts/alarm_readings.py."""

from __future__ import annotations

import re

import gymnasium
import numpy as np
import pytest

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import AlarmCommand, MemorySink, Monitor
from oodmon.monitor.detectors import DetectorSet, DriftDetector, detectors_for
from oodmon.monitor.monitor import READING_SD

#: The shipped ensemble's dynamics threshold (`oodmon calibrate --task cartpole --method ensemble
#: --detector dynamics`, the demo's): deterministic, the shipped detectors' scale.
THRESHOLD = -3.54762
EPISODES = 5


@pytest.fixture(scope="module")
def agent():
    return load("cartpole", "ensemble")


def monitor(agent, sinks, callbacks=()) -> Monitor:
    """The shipped ensemble under its dynamics threshold, with its shipped detectors."""
    return Monitor(agent, threshold=THRESHOLD, detectors=detectors_for(agent), detector="dynamics", sinks=sinks,
                   callbacks=callbacks)


def saved_threshold(path, value: float = THRESHOLD):
    """A threshold file of the shipped ensemble's dynamics alarm at ``value``, for `oodmon run`."""
    from oodmon.monitor import Threshold

    Threshold(value, "chosen_std", 1, "episode", 0.05, 45, 9_000, task="cartpole", method="ensemble",
              detector="dynamics").save(path)
    return path


def first_alarms(agent, spec: str) -> list:
    """The first alarm from the onset (step 50) of each of ``EPISODES`` episodes of ``spec``."""
    found = []
    for seed in range(EPISODES):
        sink = MemorySink()
        with monitor(agent, [sink]) as watching:
            watching.run_episode(parse_variant(spec).make(onset_step=50), seed=seed, max_steps=120)
        found.append(next(alarm for alarm in sink.alarms if alarm.step >= 50))
    return found


@pytest.mark.parametrize("spec, reading, name", [("cartpole:obs.stuck[0]=1", 0, "cart position"),
                                                 ("cartpole:obs.stuck[2]=1", 2, "pole angle"),
                                                 ("cartpole:length=2.0", 3, "pole angular velocity")])
def test_a_stuck_sensor_or_a_longer_pole_is_named_by_its_reading_far_above_any_other(agent, spec, reading, name):
    # a stuck sensor [k] named [k] at 16.9-1,180 sd in 10 of 10 episodes each, every other reading
    # within 0.75; a longer pole [3] (the pole's angular velocity) at 205-289 (scripts/alarm_readings.py)
    for alarm in first_alarms(agent, spec):
        assert len(alarm.readings) == 1 and alarm.readings[0][0] == reading, alarm.text()
        assert abs(alarm.readings[0][1]) > 10 and alarm.reading_names == (name,)
        assert f"reading [{reading}] ({name}) off the dynamics model's prediction by" in alarm.text()


def test_a_weaker_push_names_both_readings_it_moves(agent):
    for alarm in first_alarms(agent, "cartpole:force_mag=2.0"):  # 242-309 sd, the other 304 at most
        assert sorted(index for index, _ in alarm.readings) == [1, 3], alarm.text()
        assert "readings [" in alarm.text() and abs(alarm.readings[0][1]) >= abs(alarm.readings[1][1])


def test_id_transitions_keep_every_reading_well_within_the_line_so_a_false_alarm_seldom_names_one(agent):
    """The worst reading of any step of 10 ID episodes (4,990 transitions) read 1.43 sd at most,
    against the 3 an alarm needs to name a reading: a bound with room to spare, not a rate."""
    model = detectors_for(agent)["dynamics"]
    worst = []
    for seed in range(10):
        sink = MemorySink()
        with monitor(agent, [sink]) as watching:
            watching.run_episode(parse_variant("cartpole").make(), seed=800_000 + seed)
        obs = np.array([step.observation for step in sink.steps], dtype=np.float32)
        actions = np.array([step.action for step in sink.steps])
        worst.append(np.abs(model.standardized_residuals(obs[:-1], actions[:-1], obs[1:])).max())
    assert max(worst) < READING_SD / 1.5, worst


def test_the_alarm_command_gets_the_readings(agent, tmp_path):
    out = tmp_path / "readings.txt"
    command, sink = AlarmCommand(f'echo "$OODMON_READINGS $OODMON_READING_NAMES" >> {out}'), MemorySink()
    with monitor(agent, [sink], [command]) as watching:
        for seed in range(3):
            watching.run_episode(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=50), seed=seed, max_steps=80)
    assert command.close() == "ran 3 times (episodes 0, 1, 2), each exited 0"
    firsts = [next(alarm for alarm in sink.alarms if alarm.episode == episode) for episode in range(3)]
    assert all(alarm.step >= 50 for alarm in firsts)  # (each episode's first alarm: the command's)
    assert all(len(alarm.readings) == 1 for alarm in firsts)  # (a stuck angle: that reading alone)
    assert sorted(out.read_text().splitlines()) == sorted(f'2:{alarm.readings[0][1]!r} ["pole angle"]'
                                                          for alarm in firsts)


def test_an_env_whose_layout_is_not_known_names_its_readings_by_index_alone():
    from oodmon.monitor.alarms import AlarmEvent

    event = AlarmEvent(0, 51, 9.5, 5.9, "score > threshold", "dynamics", ((1, -311.3), (3, 310.8)),
                       reading_names=("cart velocity", ""))
    assert event.text().endswith("readings [1] (cart velocity) and [3] off the dynamics model's prediction by "
                                 "-311, +311 sd")
    assert AlarmEvent(0, 5, 9.5, 5.9, "score > threshold", "dynamics", ((2, 4.0),)).text().endswith(
        "; reading [2] off the dynamics model's prediction by +4 sd")


def test_no_reading_is_named_without_a_dynamics_model_or_a_step_before(agent):
    sink = MemorySink()
    with Monitor(agent, threshold=0.0, sinks=[sink]) as monitor:  # the spread alone: no model to ask
        monitor.run_episode(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=5), seed=0, max_steps=30)
    assert sink.alarms and all(alarm.readings == () for alarm in sink.alarms)
    sink = MemorySink()
    with Monitor(agent, threshold=-1e9, detectors=detectors_for(agent), detector="dynamics", sinks=[sink]) as monitor:
        monitor.run_episode(parse_variant("cartpole").make(), seed=0, max_steps=30)
    assert [(alarm.step, alarm.readings) for alarm in sink.alarms] == [(0, ())]  # its first step: no transition yet


def test_the_script_prints_what_each_variant_named_and_the_id_worst(monkeypatch, capsys):
    from tests.helpers import load_script

    script = load_script("alarm_readings")[1]
    monkeypatch.setattr("sys.argv", ["alarm_readings", "--episodes", "2", "cartpole:obs.stuck[2]=1",
                                     "cartpole:force_mag=2.0"])
    script.main()
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "cartpole/ensemble: dynamics > -3.54762; reading_sd 3.0"
    assert lines[1].startswith("cartpole:obs.stuck[2]=1      named first: [2] 2 of 2 (0 alarmed naming none, 0 not")
    assert lines[2].startswith("cartpole:force_mag=2.0       named first: [3] 1, [1] 1 of 2")  # the push moves both
    assert re.fullmatch(r"ID, 2 episodes, \d+ transitions: the worst reading's residual at a step: median \S+, 99.9th "
                        r"percentile \S+, largest (\S+) sd", lines[3])
    assert float(lines[3].split()[-2]) < READING_SD


def test_a_monitored_envs_info_holds_the_readings_at_the_step_each_alarm_is_raised(agent):
    from oodmon.monitor import MonitoredEnv

    sink = MemorySink()
    env = MonitoredEnv(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=50), monitor(agent, [sink]))
    env.reset(seed=0)
    said = {}
    for _ in range(80):
        *_, terminated, truncated, info = env.step()
        if "readings" in info["oodmon"]:
            said[info["oodmon"]["step"]] = info["oodmon"]["readings"], info["oodmon"]["reading_names"]
        if terminated or truncated:
            break
    env.close()
    raised = {alarm.step: ([list(pair) for pair in alarm.readings], list(alarm.reading_names))
              for alarm in sink.alarms if alarm.readings}
    assert said == raised and min(said) >= 50 and said[min(said)][0][0][0] == 2  # the stuck reading, where it began
    assert said[min(said)][1][0] == "pole angle"


def test_a_drift_alarm_with_no_step_far_off_names_the_drifting_reading_over_its_window(agent):
    """Gravity 13 (ID 9.8) moves no single step's reading 3 off the dynamics prediction: the drift
    detector's alarm named nothing. It now names the drift's own reading, its residuals summed over
    the window (over their root), as the detector scored it: the pole's angular velocity [3]."""
    shipped = detectors_for(agent)
    drift = DriftDetector.of(shipped["dynamics"])
    detectors = DetectorSet([shipped["spread"], shipped["dynamics"], drift])
    for seed in (0, 1):
        sink = MemorySink()
        with Monitor(agent, threshold=4.0, detectors=detectors, detector="drift", sinks=[sink]) as monitor:
            monitor.run_episode(parse_variant("cartpole:gravity=13.0").make(onset_step=50), seed=seed, max_steps=200)
        first = sink.alarms[0]
        assert first.step > 50 and first.readings_steps == 20 and [i for i, _ in first.readings] == [3], first.text()
        assert abs(first.readings[0][1]) == pytest.approx(first.score) and first.text().endswith(
            f"; cause: drift; reading [3] (pole angular velocity) drifting from the dynamics model's predictions: "
            f"{first.readings[0][1]:+.3g} sd summed over its last 20 steps")


def test_the_log_keeps_each_episodes_first_alarm_readings_and_replay_lists_them(agent, tmp_path):
    """Format 10: the episode message holds the first alarm's readings, which `replay --episodes`
    lists; a record whose readings are no such pairs is refused as a damaged log."""
    import json

    from oodmon.errors import LogFormatError
    from oodmon.monitor import McapSink
    from oodmon.replay import read_log
    from oodmon.replay.reader import _first_alarm_readings
    from tests.helpers import run_cli

    log, sink = tmp_path / "stuck.mcap", MemorySink()
    with monitor(agent, [sink, McapSink(log)]) as watching:
        for seed in range(2):
            watching.run_episode(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=50), seed=seed, max_steps=80)
        watching.run_episode(parse_variant("cartpole").make(), seed=5, max_steps=30)  # no alarm: none named
    firsts = [next(alarm for alarm in sink.alarms if alarm.episode == episode) for episode in range(2)]
    episodes = read_log(log).episodes
    assert [e.first_alarm_readings for e in episodes] == [alarm.readings for alarm in firsts] + [()]
    assert [e.first_alarm_readings_steps for e in episodes] == [1, 1, 1]
    listed = run_cli("replay", "--episodes", "--json", str(log))
    assert [row["first_alarm_readings"] for row in json.loads(listed.stdout)] == [
        f"[2] (pole angle) {alarm.readings[0][1]:+.3g} sd" for alarm in firsts] + [None]
    # `replay --monitor` counts, per variant, the reading each first alarm after the onset named first.
    (stuck,) = [row for row in json.loads(run_cli("replay", "--monitor", "--json", str(log)).stdout)
                if row["variant"] == "cartpole:obs.stuck[2]=1.0"]
    assert stuck["readings"] == {"[2] (pole angle)": 2} and stuck["causes"] == {"dynamics": 2}
    for damaged in ({"first_alarm_readings": "[2]"}, {"first_alarm_readings": [[2.5, 1.0]]},
                    {"first_alarm_readings": [[2, float("nan")]]}, {"first_alarm_readings_steps": 0}):
        with pytest.raises(LogFormatError, match="not a log oodmon wrote"):
            _first_alarm_readings(log, {"episode": 0, **damaged})
    assert _first_alarm_readings(log, {"episode": 0}) == ((), 1)  # a log older than format 10


class _DictCartPole(gymnasium.ObservationWrapper):
    """CartPole whose observation is a dict, {"cart": [position, velocity], "pole": [angle, angular
    velocity]} (flattened in that order: CartPole's own); with ``stuck_from``, the pole's angle reads
    what it read at that step on (a stuck sensor)."""

    def __init__(self, stuck_from: int | None = None) -> None:
        super().__init__(gymnasium.make("CartPole-v1"))
        half = gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float32)
        self.observation_space = gymnasium.spaces.Dict({"cart": half, "pole": half})
        self.stuck_from, self.steps, self.angle = stuck_from, 0, None

    def reset(self, **kwargs):
        self.steps, self.angle = 0, None
        return super().reset(**kwargs)

    def step(self, action):
        self.steps += 1
        return super().step(action)

    def observation(self, obs):
        if self.stuck_from is not None and self.steps >= self.stuck_from:
            self.angle = obs[2] if self.angle is None else self.angle
            obs = np.array([obs[0], obs[1], self.angle, obs[3]], np.float32)
        return {"cart": obs[:2].astype(np.float32), "pole": obs[2:].astype(np.float32)}


def test_a_dict_observations_readings_are_named_by_its_keys(tmp_path):
    """A dict observation is read flattened (gymnasium's order, its keys sorted): an alarm names
    the readings by key and position, ``[2] (pole[0])`` (it named them by index alone), and the log
    keeps the names for replay; names that match its flattening in every space gymnasium flattens,
    nested too."""
    from gymnasium.spaces import Box, Dict, Discrete, MultiBinary, MultiDiscrete, Tuple

    from oodmon.agents import plain_agent
    from oodmon.envs.readings import flat_names
    from oodmon.monitor import McapSink
    from oodmon.monitor.detectors import fit_detectors
    from oodmon.replay import read_log

    if "readings_tests/DictCartPole-v0" not in gymnasium.registry:
        gymnasium.register("readings_tests/DictCartPole-v0", entry_point=_DictCartPole, max_episode_steps=200)
    balance = plain_agent(lambda obs: int(obs["pole"][0] + 0.5 * obs["pole"][1] > 0), "readings_tests/DictCartPole-v0")
    detectors = fit_detectors(balance, balance.wrap(_DictCartPole()), detectors=["dynamics"], episodes=20)
    sink = MemorySink()
    # 100: this model's ID scores stay below -2.7, a stuck angle's steps score above 1,000 (by hand)
    with Monitor(balance, threshold=100.0, detectors=detectors, detector="dynamics",
                 sinks=[sink, McapSink(tmp_path / "dict.mcap")]) as watching:
        for seed in range(3):
            watching.run_episode(_DictCartPole(stuck_from=50), seed=100 + seed, max_steps=80)
    firsts = [next(alarm for alarm in sink.alarms if alarm.episode == episode) for episode in range(3)]
    assert all(51 <= alarm.step <= 53 for alarm in firsts), [alarm.step for alarm in firsts]
    assert [(alarm.readings[0][0], alarm.reading_names[0]) for alarm in firsts] == [(2, "pole[0]")] * 3
    assert "; reading [2] (pole[0]) off the dynamics model's prediction by" in firsts[0].text()
    logged = read_log(tmp_path / "dict.mcap")
    assert logged.reading_names == ("cart[0]", "cart[1]", "pole[0]", "pole[1]")
    assert [e.first_alarm_readings for e in logged.episodes] == [alarm.readings for alarm in firsts]
    with Monitor(load("cartpole", "ensemble"), threshold=THRESHOLD, sinks=[McapSink(tmp_path / "box.mcap")]) as box:
        box.run_episode(parse_variant("cartpole").make(), seed=0, max_steps=5)
    assert "about.reading_names" not in read_log(tmp_path / "box.mcap").metadata  # a Box's env names them

    space = Dict({"v": Box(-1, 1, (2, 2)), "m": Discrete(2, start=1), "md": MultiDiscrete([2, 3]), "s": Box(0, 1, ()),
                  "t": Tuple((MultiBinary(2), Box(0, 1, (1,)))), "n": Dict({"a": Box(0, 1, (1,))})})
    names = flat_names(space)
    assert names == ("m=1", "m=2", "md[0]=0", "md[0]=1", "md[1]=0", "md[1]=1", "md[1]=2", "n.a", "s", "t.0[0]",
                     "t.0[1]", "t.1", "v[0,0]", "v[0,1]", "v[1,0]", "v[1,1]")
    # Each name's number is where flatten puts it: a sample with one number changed moves that name's alone.
    sample = {"v": np.zeros((2, 2), np.float32), "m": 1, "md": np.array([0, 0]), "s": np.float32(0),
              "t": (np.zeros(2, np.int8), np.zeros(1, np.float32)), "n": {"a": np.zeros(1, np.float32)}}
    base = gymnasium.spaces.flatten(space, sample)
    moved = dict(sample, v=np.array([[0, 0], [0.5, 0]], np.float32), m=2)
    changed = np.flatnonzero(gymnasium.spaces.flatten(space, moved) != base)
    assert [names[k] for k in changed] == ["m=1", "m=2", "v[1,0]"]
    assert flat_names(gymnasium.spaces.Text(5)) == () and flat_names(Dict({"a": gymnasium.spaces.Text(5)})) == ()
    # What the detectors read of it: a dict with a picture, its vectors alone; a stack of dicts, no names.
    from oodmon.agents.agent import Agent
    from oodmon.agents.dict_pictures import dict_pictures
    from oodmon.agents.frame_stack import Stacking

    pictured = Dict({"camera": Box(0, 255, (4, 4, 1), np.uint8), "arm": Box(-1, 1, (2,)), "z": Discrete(2)})
    assert Agent(None, {}, dict_space=pictured, pictures=dict_pictures(pictured)).dict_reading_names() == (
        "arm[0]", "arm[1]", "z=0", "z=1")
    assert Agent(None, {}, dict_space=space).dict_reading_names() == names
    assert Agent(None, {}, dict_space=space, stacking=Stacking(2, (16,), False)).dict_reading_names() == ()


@pytest.mark.parametrize("segment_steps", [None, 7])
def test_a_killed_runs_running_episode_replays_what_raised_its_first_alarm_and_which_reading(agent, tmp_path,
                                                                                            segment_steps):
    """Format 11: the step that raised an alarm logs its cause and readings (``raised``), so the
    running episode of a log torn by a kill, whose episode message was never written, replays them
    (before: no cause, no reading, though its alarm's line was in the log), also where the alarm
    came before the episode's last segment (the reader drops those steps' messages but these); a
    damaged ``raised`` leaves the episode without them."""
    import json

    from oodmon.monitor import McapSink
    from oodmon.replay.reader import _raised
    from tests.helpers import run_cli, tear_inside_episode_one

    memory = MemorySink()
    segments = {} if segment_steps is None else {"segment_steps": segment_steps}
    watching = Monitor(agent, threshold=THRESHOLD, detectors=detectors_for(agent), detector="dynamics",
                       sinks=[McapSink(tmp_path / "run.mcap", flush_seconds=0), memory], **segments).open()
    env = parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=20)
    watching.run_episode(env, seed=0, variant="cartpole:obs.stuck[2]=1")
    log, _ = tear_inside_episode_one(watching, env, "cartpole:obs.stuck[2]=1", tmp_path, memory)
    (cut,) = log.interrupted
    (raised,) = [alarm for alarm in memory.alarms if alarm.episode == 1]
    assert (cut.first_alarm_step, cut.first_alarm_cause) == (raised.step, "dynamics") and 20 < raised.step < 35
    assert cut.first_alarm_readings == raised.readings and raised.readings[0][0] == 2
    if segment_steps is not None:
        return
    rows = json.loads(run_cli("replay", "--episodes", "--json", str(tmp_path / "torn.mcap")).stdout)
    assert rows[1]["ended"] == "interrupted" and rows[1]["first_alarm_cause"] == "dynamics"
    assert rows[1]["first_alarm_readings"] == f"[2] (pole angle) {raised.readings[0][1]:+.3g} sd"
    steps = [{"step": 21, "raised": {"cause": "dynamics", "readings": [[2, -9.5]], "readings_steps": 1}}]
    assert _raised(tmp_path, 1, steps, 21) == {"first_alarm_cause": "dynamics", "first_alarm_readings": [[2, -9.5]],
                                               "first_alarm_readings_steps": 1, "first_alarm_region": None}
    assert _raised(tmp_path, 1, steps, 22) == {}  # that step's message not on disk
    damaged = [{"step": 21, "raised": {"cause": 7, "readings": [[2.5, "x"]], "readings_steps": 0}}]
    assert _raised(tmp_path, 1, damaged, 21) == {} and _raised(tmp_path, 1, [{"step": 21, "raised": "x"}], 21) == {}


def test_runs_closing_line_counts_what_raised_the_first_alarms_and_the_reading_each_named(tmp_path, capsys):
    """`oodmon run` ends with each episode's first alarm tallied by cause and first reading (its
    table shows at most 20 episodes); an alarm before the onset, a false one, is not counted."""
    from oodmon.cli import main

    def closing(threshold: float) -> str:
        path = saved_threshold(tmp_path / f"{threshold}.json", threshold)
        assert main(["run", "--threshold", str(path), "--variant", "cartpole:obs.stuck[2]=1", "--onset", "50",
                     "--episodes", "3", "--max-steps", "80"]) == 0
        return capsys.readouterr().out.strip().splitlines()[-1]

    assert closing(THRESHOLD) == ("3 of 3 episodes raised an alarm; first alarms by dynamics 3; reading [2] (pole "
                                  "angle) 3")
    assert closing(-1e9) == "3 of 3 episodes raised an alarm"  # at step 0: before the onset


def test_names_you_give_name_an_alarms_readings_in_its_line_the_log_and_replay(agent, tmp_path, capsys):
    """``Monitor(reading_names=...)`` (``run --reading-names``): an env of yours whose layout oodmon
    does not know names its readings as you say, ahead of any it knows; a twin keeps them; a count
    other than the observation's is refused at the first step, a text alone at once."""
    import json

    from oodmon.cli import main
    from oodmon.errors import ConfigError, InvalidParameterError
    from oodmon.monitor import McapSink
    from oodmon.replay import read_log
    from tests.helpers import run_cli

    names = ["x", "v", "theta", "omega"]
    sink = MemorySink()
    with Monitor(agent, threshold=THRESHOLD, detectors=detectors_for(agent), detector="dynamics",
                 sinks=[sink, McapSink(tmp_path / "named.mcap")], reading_names=names) as watching:
        watching.run_episode(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=50), seed=0, max_steps=80)
        twin_sink = MemorySink()
        twin = watching.twin(sinks=[twin_sink])
    (alarm,) = sink.alarms
    assert alarm.reading_names[0] == "theta" and "; reading [2] (theta) off the dynamics model's" in alarm.text()
    assert read_log(tmp_path / "named.mcap").reading_names == tuple(names)
    (row,) = [r for r in json.loads(run_cli("replay", "--monitor", "--json", str(tmp_path / "named.mcap")).stdout)
              if r["variant"] == "cartpole:obs.stuck[2]=1.0"]
    assert row["readings"] == {"[2] (theta)": 1}
    with twin:
        twin.run_episode(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=50), seed=0, max_steps=80)
    assert [a.reading_names[0] for a in twin_sink.alarms] == ["theta"]

    with pytest.raises(ConfigError, match=r"reading_names \(--reading-names\) has 3 name\(s\); the observations the "
                                          r"detectors read have 4 number\(s\)"):
        with Monitor(agent, threshold=THRESHOLD, reading_names=names[:3]) as short:
            short.run_episode(parse_variant("cartpole").make(), seed=0, max_steps=5)
    for bad in ("x,v,theta,omega", [1, 2, 3, 4], 4):
        with pytest.raises(InvalidParameterError, match="give a list of texts"):
            Monitor(agent, threshold=THRESHOLD, reading_names=bad)
    capsys.readouterr()
    assert main(["run", "--threshold", str(saved_threshold(tmp_path / "t.json")), "--variant",
                 "cartpole:obs.stuck[2]=1", "--onset", "50", "--episodes", "2", "--max-steps", "80",
                 "--reading-names", "x, v, theta, omega"]) == 0
    closing = capsys.readouterr().out.strip().splitlines()[-1]
    assert closing.endswith("first alarms by dynamics 2; reading [2] (theta) 2")


def test_names_given_at_calibration_go_with_the_threshold_to_every_monitor_of_it(agent, tmp_path, capsys):
    """``calibrate_agent(reading_names=...)`` (``calibrate --reading-names``) records the names in
    the threshold: a monitor of it (``oodmon run`` without ``--reading-names``) names its alarms'
    readings by them, unless given others; a threshold calibrated on logs of a run given names
    records them too; a count other than the observation's is refused at the first step, as the
    threshold's."""
    import json
    from dataclasses import replace

    import oodmon
    from oodmon.cli import main
    from oodmon.errors import ConfigError
    from oodmon.monitor import McapSink, Threshold, calibrate_agent
    from oodmon.replay import calibrate_from_logs

    names = ["x", "v", "theta", "omega"]
    detectors = detectors_for(agent)
    # (far 0.2 on average over calibrations: 5 episodes are enough; 80 steps each, fast)
    threshold = calibrate_agent(agent, 5, 0.2, confidence=None, detectors=detectors, detector="dynamics",
                                max_steps=80, reading_names=names)
    assert threshold.reading_names == names
    loaded = Threshold.load(threshold.save(tmp_path / "named.json"))
    assert loaded.reading_names == names

    def first_names(threshold, watch=False, **given) -> list[str]:
        sink = MemorySink()
        with (oodmon.watch(agent, threshold=threshold, sinks=[sink], **given) if watch else
              Monitor(agent, threshold=threshold, detectors=detectors, sinks=[sink], **given)) as watching:
            watching.run_episode(parse_variant("cartpole:obs.stuck[2]=1").make(onset_step=50), seed=0, max_steps=80)
        return [alarm.reading_names[0] for alarm in sink.alarms if alarm.step >= 50][:1]

    assert first_names(loaded) == ["theta"]
    assert first_names(loaded, reading_names=["a", "b", "c", "d"]) == ["c"]  # given ones come first
    assert first_names(tmp_path / "named.json", watch=True) == ["theta"]  # oodmon.watch(threshold=FILE)
    assert first_names(tmp_path / "named.json", watch=True, reading_names=["a", "b", "c", "d"]) == ["c"]
    assert first_names(replace(loaded, reading_names=None)) == ["pole angle"]  # the env's known layout
    with pytest.raises(ConfigError, match=r"the threshold's reading_names \(calibrate --reading-names\) has 3 "
                                          r"name\(s\); the observations the detectors read have 4"):
        first_names(replace(loaded, reading_names=names[:3]))
    for bad in ("x, v", [], ["x", 2]):
        (tmp_path / "bad.json").write_text(json.dumps(loaded.to_dict() | {"reading_names": bad}))
        with pytest.raises(ConfigError, match=r"reading_names=.* is not allowed; it must be a list of texts"):
            Threshold.load(tmp_path / "bad.json")

    # calibrated on the logs of ID runs given names: the threshold records them
    with Monitor(agent, threshold=loaded, detectors=detectors, sinks=[McapSink(tmp_path / "id.mcap")]) as watching:
        for seed in range(5):
            watching.run_episode(parse_variant("cartpole").make(), seed=900_000 + seed, max_steps=30)
    assert calibrate_from_logs([tmp_path / "id.mcap"], 0.2, confidence=None).reading_names == names
    capsys.readouterr()
    assert main(["recalibrate", str(tmp_path / "id.mcap"), "--far", "0.2", "--confidence", "none", "--out",
                 str(tmp_path / "re.json")]) == 0
    assert "; its alarms name the readings x, v, theta, omega; wrote" in capsys.readouterr().out
    assert Threshold.load(tmp_path / "re.json").reading_names == names

    # the command line: calibrate --reading-names, then run with the threshold alone
    capsys.readouterr()
    assert main(["calibrate", "--task", "cartpole", "--method", "ensemble", "--detector", "dynamics", "--episodes",
                 "5", "--far", "0.2", "--confidence", "none", "--max-steps", "80", "--reading-names",
                 "x, v, theta, omega", "--out", str(tmp_path / "cli.json")]) == 0
    assert "; its alarms name the readings x, v, theta, omega;" in capsys.readouterr().out
    written = Threshold.load(tmp_path / "cli.json")
    assert written.reading_names == names
    # at the shipped calibration's value (5 episodes of 80 steps give -4.25, which alarms before the onset)
    replace(written, value=THRESHOLD).save(tmp_path / "cli.json")
    assert main(["run", "--threshold", str(tmp_path / "cli.json"), "--variant", "cartpole:obs.stuck[2]=1",
                 "--onset", "50", "--episodes", "2", "--max-steps", "80"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].endswith(
        "first alarms by dynamics 2; reading [2] (theta) 2")
