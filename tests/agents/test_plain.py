"""A policy of any kind, a function obs -> action: watched in Python (oodmon.watch) and from the
command line (--policy MODULE:NAME), its threshold bound to its weights where it has some."""

from __future__ import annotations

import copy
import json
import re
import shlex
import shutil
from dataclasses import replace
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

import oodmon
from oodmon.agents.plain import plain_agent, policy_by_name, weights_sha256
from oodmon.agents.sb3_spaces import dict_space_of
from oodmon.cli import main
from oodmon.envs import parse_env_shift
from oodmon.envs.probe import probe_shift
from oodmon.errors import ConfigError
from oodmon.monitor import MemorySink, Monitor, MonitoredEnv, Threshold, calibrate_agent
from oodmon.monitor.detectors import DynamicsDetector
from oodmon.monitor.detectors.fitting import cannot_have, collect
from oodmon.replay import read_log
from tests.helpers import run_as_written

PAGE = Path(__file__).resolve().parents[2] / "docs" / "your-policy.md"

def _readme_block() -> tuple[str, list[list[str]]]:
    """The page's controller module and its oodmon commands (continuation lines joined)."""
    text = PAGE.read_text()
    section = text[text.index("## Monitor a policy of any kind"):]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    module = re.search(r"<<'PY'\n(.*?\n)PY\n", block, re.S).group(1)
    commands = block[block.index("\nPY\n") + 4:].replace("\\\n", " ")
    return module, [shlex.split(line)[1:] for line in commands.splitlines() if line.startswith("oodmon ")]


def test_the_docs_controller_is_calibrated_run_and_replayed_as_written_then_watched_in_python(
        tmp_path, monkeypatch, capsys):
    module, commands = _readme_block()
    assert [argv[0] for argv in commands] == ["calibrate", "run", "replay"]
    assert "export PYTHONPATH=runs" in PAGE.read_text()
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs/my_controller.py").write_text(module)
    run_as_written(commands, tmp_path, monkeypatch, python_path=tmp_path / "runs", module="my_controller")
    capsys.readouterr()
    assert main(["replay", "--json", "runs/controller.mcap"]) == 0
    row = next(r for r in json.loads(capsys.readouterr().out) if r["detector"] == "combined")
    # the page's figures when written: 20 of 20 alarmed at step 31, delay 1 (the controller keeps
    # the long pole up). The dynamics model's fit follows the CPU's MKL kernels, so the threshold is
    # another on another machine (5.27629 where the page was measured, 3.87509 on an AVX-512 EPYC,
    # where seed 0's ID steps 17-30 cross it). An alarm in an episode's 30 ID steps is a false alarm,
    # at most 5% per whole episode: 2 or more of 5 has probability 0.023 at that rate.
    assert (row["method"], row["variant"], row["episodes"]) == ("plain", "cartpole:length=2.0", 5)
    assert row["early_alarm_rate"] <= 0.2
    assert row["detection_rate"] + row["early_alarm_rate"] == 1.0 and row["delay_median"] <= 5
    log = read_log("runs/controller.mcap")
    assert (log.metadata["about.policy"], log.metadata["about.env_id"]) == ("my_controller.act", "CartPole-v1")
    # its name and code, and its name alone (what its logs recorded before 2026-12-06: replay pools the two)
    assert log.metadata["policy_hash"].startswith("name:act code:") and log.metadata["about.name_hash"] == "name:act"
    assert main(["validate", "runs/controller.json", "--episodes", "5"]) == 2  # which policy: said, not guessed
    assert "--policy MODULE:NAME --env CartPole-v1" in capsys.readouterr().err
    # an attribute of CartPole-v1 that is not oodmon's physics, shifted for your own policy (refused
    # both as cartpole:... and as CartPole-v1:... before 2026-12-01): a pole that may lean 0.001 rad
    assert main(["run", "--policy", "my_controller:act", "--env", "CartPole-v1", "--threshold", "runs/controller.json",
                 "--variant", "CartPole-v1:theta_threshold_radians=0.001", "--onset", "30", "--episodes", "2",
                 "--mcap", "runs/strict.mcap"]) == 0
    strict = read_log("runs/strict.mcap").episodes
    assert [(e.variant, e.onset) for e in strict] == [("CartPole-v1:theta_threshold_radians=0.001", 30)] * 2
    assert all(e.terminated and 30 <= e.length < 40 for e in strict), [e.length for e in strict]  # ended at the onset

    # the deployed process in Python: the calibration read from the file, no episode of its own
    import my_controller

    monitor = oodmon.watch(my_controller.act, "CartPole-v1", threshold="runs/controller.json")
    assert (monitor.agent.method, monitor.agent.task, monitor.detector) == ("plain", "cartpole", "combined")
    # a function without weights: bound by its name and its code
    assert re.fullmatch(r"name:act code:[0-9a-f]{16}", monitor.agent.metadata["policy_hash"])

    def act_v2(obs):
        return my_controller.act(obs)

    with pytest.raises(ConfigError, match=r"calibrated for another policy \(name:act code:\w+, this is name:.*act_v2 "):
        oodmon.watch(act_v2, "CartPole-v1", threshold="runs/controller.json")
    # the same module with other gains (before 2026-12-06: the same name, so the same policy)
    (tmp_path / "runs/my_controller_tuned.py").write_text(module.replace("0.5 * obs[3]", "0.6 * obs[3]"))
    import my_controller_tuned

    with pytest.raises(ConfigError, match=r"calibrated for another version of act: its code, or a value it reads, has "
                                          r"changed since \(name:act code:\w+, this is name:act code:\w+\)"):
        oodmon.watch(my_controller_tuned.act, "CartPole-v1", threshold="runs/controller.json")
    capsys.readouterr()
    assert main(["run", "--policy", "my_controller_tuned:act", "--env", "CartPole-v1", "--threshold",
                 "runs/controller.json", "--episodes", "1"]) == 2
    assert "calibrated for another version of act" in capsys.readouterr().err
    # a threshold recorded by name alone (made before 2026-12-06) fits the policy of that name, as it did
    older = json.loads((tmp_path / "runs/controller.json").read_text()) | {"policy_hash": "name:act"}
    (tmp_path / "runs/older.json").write_text(json.dumps(older))
    shutil.copytree(tmp_path / "runs/controller.json.detectors", tmp_path / "runs/older.json.detectors")
    assert oodmon.watch(my_controller.act, "CartPole-v1", threshold="runs/older.json").threshold == older["value"]
    records = [monitor.run_episode(gymnasium.make("CartPole-v1"), seed=900_000 + i) for i in range(20)]
    assert all(r.length == 500 for r in records)  # it balances the pole
    # The threshold promises <= 5% false alarms per episode (confidence 0.9); 5 or more of 20 has
    # probability 0.016 at 5% and 0.043 at twice the target.
    assert sum(r.first_alarm_step is not None for r in records) <= 4


class TorchPolicy(torch.nn.Module):
    """A torch policy whose method acts on numpy observations."""

    def __init__(self) -> None:
        super().__init__()
        self.q = torch.nn.Linear(4, 2)

    def act(self, obs: np.ndarray) -> int:
        with torch.no_grad():
            return int(self.q(torch.as_tensor(obs)).argmax())


def test_a_torch_policys_threshold_is_bound_to_its_weights():
    torch.manual_seed(0)
    net = TorchPolicy()
    own = plain_agent(net.act, "CartPole-v1").metadata["policy_hash"]  # a method of a module: the module's weights
    assert own == "sha256:" + weights_sha256(net) == "sha256:" + weights_sha256(net.state_dict())
    same = copy.deepcopy(net)
    assert plain_agent(same.act, "CartPole-v1").metadata["policy_hash"] == own
    with torch.no_grad():
        same.q.bias[0] += 1e-3
    other = plain_agent(same.act, "CartPole-v1").metadata["policy_hash"]
    assert other != own
    # a function that closes over the module says which weights it decides by
    told = plain_agent(lambda obs: net.act(obs), "CartPole-v1", weights=net).metadata["policy_hash"]
    assert told == own
    threshold = Threshold(1.0, "chosen_std", 1, "episode", 0.05, 50, 500, task="cartpole", method="plain",
                          policy_hash=own, detector="dynamics")
    assert threshold.check_matches(task="cartpole", method="plain", score="chosen_std", policy_hash=own) == []
    assert "calibrated on other weights" in threshold.check_matches(task="cartpole", method="plain",
                                                                   score="chosen_std", policy_hash=other)[0]


@pytest.mark.parametrize(("policy", "env_id", "kwargs", "said"), [
    (lambda obs: 3, "CartPole-v1", {}, "returned 3 for CartPole-v1's first observation, which the env refused"),
    (lambda obs: np.zeros(2), "Pendulum-v1", {}, "shape (2,)) for Pendulum-v1's first observation"),
    (lambda obs: torch.tensor(1), "CartPole-v1", {}, "Discrete(2) (a torch tensor: return a number, .item(), or an array"),
    (lambda obs: 0, "CartPole-v1", {"mean": True}, "are for SB3 models; a plain policy acts on the env's observations"),
    (lambda obs: 0, None, {}, "give the gymnasium env id your policy acts in"),
    # a tuple of vectors and discrete values is watched (below), tuples inside it too; one with a picture is not
    (lambda obs: 0, "plain_tests/TupleWithPicture-v0", {}, "plain_tests/TupleWithPicture-v0's observations are Tuple"),
    # a tuple of actions is watched (below); one with a tuple inside it is not
    (lambda obs: ((0, np.ones(1, np.float32)),), "plain_tests/NestedActions-v0", {},
     "plain_tests/NestedActions-v0's actions are Tuple(Tuple(Discrete(2), Box(0.0, 1.0, (1,), float32))); oodmon's "
     "detectors and logs read an action of a Box, Discrete, MultiDiscrete or MultiBinary space, or a tuple or dict "
     "of them"),
], ids=["action-refused", "box-shape", "torch-tensor", "sb3-option", "no-env", "tuple-observations-with-a-picture",
        "nested-tuple-actions"])
def test_a_policy_oodmon_cannot_run_is_said_before_any_episode(policy, env_id, kwargs, said):
    from oodmon.monitor.watch import as_agent

    if "plain_tests/TupleWithPicture-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/TupleWithPicture-v0", entry_point=_TupleWithPicture)
        gymnasium.register("plain_tests/NestedActions-v0", entry_point=_NestedActions)

    with pytest.raises(ConfigError) as error:
        as_agent(policy, env_id, **kwargs)
    assert said in str(error.value)


class _Walk(gymnasium.Env):
    """A random walk of two readings, pulled up or down by the action; 30 steps an episode."""

    metadata = {"render_modes": ["rgb_array"]}
    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self, render_mode=None) -> None:
        self.render_mode = render_mode

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = np.zeros(2, np.float32)
        return self.x.copy(), {}

    def step(self, action):
        self.x = (0.9 * self.x + self.np_random.normal(0, 0.1, 2) + (0.05 if action else -0.05)).astype(np.float32)
        return self.x.copy(), 1.0, False, False, {}


def test_watch_of_an_env_without_its_id_plays_the_id_gymnasium_made_it_by_and_says_when_it_cannot():
    if "plain_tests/Walk-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/Walk-v0", entry_point=_Walk, max_episode_steps=30)
    env = gymnasium.make("plain_tests/Walk-v0", render_mode="rgb_array")  # (rendering is not another world)
    watched = oodmon.watch(lambda obs: int(obs[0] < 0), env=env, fit_episodes=3, episodes=20, confidence=None)
    assert watched.monitor.agent.env_id == "plain_tests/Walk-v0"
    obs, _ = watched.reset(seed=0)
    for _ in range(30):
        obs, _, terminated, truncated, info = watched.step()
    assert truncated and "alarm" in info["oodmon"]
    for made, said in [(_Walk(), r"this env, a _Walk, was made without gymnasium's registry, .* gymnasium.register\("
                                 r"'my_envs/_Walk-v0', entry_point=_Walk, max_episode_steps=N\)"),
                       (gymnasium.make("plain_tests/Walk-v0", max_episode_steps=10),
                        r"made as gymnasium.make\('plain_tests/Walk-v0', max_episode_steps=10\), and fitting and "
                        r"calibration play the in-distribution world"),
                       (gymnasium.make("oodmon/CartPole-v1", length=2.0), r"gymnasium.make\('oodmon/CartPole-v1', "
                                                                         r"length=2.0\)")]:
        with pytest.raises(ConfigError, match=said):
            oodmon.watch(lambda obs: 0, env=made)
    # the id given where the env goes (before, an AttributeError of the str once the id was read off env=)
    for given in (None, "CartPole-v1"):
        with pytest.raises(ConfigError, match=r"got a str \('CartPole-v1' is an env id: give the env itself, "
                                              r"gymnasium.make\('CartPole-v1'\); oodmon.watch takes the id"):
            oodmon.watch(lambda obs: 0, given, env="CartPole-v1")
    with pytest.raises(ConfigError, match="the env to monitor is one gymnasium env, the one you step; got a int$"):
        oodmon.watch(lambda obs: 0, env=5)
    # given the id, the env made with other arguments is the deployed world (here the longer pole)
    assert oodmon.watch(lambda obs: 0, "oodmon/CartPole-v1", env=gymnasium.make("oodmon/CartPole-v1", length=2.0),
                        threshold=None, fit_episodes=3, episodes=20, confidence=None).monitor.agent.env_id == \
        "oodmon/CartPole-v1"
    # an SB3 model in memory: the env it learned in (through SB3's Monitor wrapper and DummyVecEnv)
    model = PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu")
    assert oodmon.watch(model, fit_episodes=3, episodes=20, confidence=None).agent.env_id == "CartPole-v1"
    shorter = PPO("MlpPolicy", gymnasium.make("CartPole-v1", max_episode_steps=50), seed=0, device="cpu")
    with pytest.raises(ConfigError, match=r"the env your model learned in was made as gymnasium.make\('CartPole-v1', "
                                          r"max_episode_steps=50\), .*: watch\(model, 'CartPole-v1'\) if that is"):
        oodmon.watch(shorter)
    model.env = None  # (as a model loaded from its file without an env: get_env() is None)
    with pytest.raises(ConfigError, match="give the gymnasium env id your models act in"):
        oodmon.watch(model)


def test_what_is_no_function_of_an_observation_is_said():
    with pytest.raises(ConfigError, match="policy is an SB3 ActorCriticPolicy: oodmon reads an SB3 model.s networks, "
                                          "given the model itself"):
        plain_agent(PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu").policy, "CartPole-v1")
    with pytest.raises(ConfigError, match="policy is a str, not a function obs -> action"):
        plain_agent("act", "CartPole-v1")


def test_evaluate_takes_a_policy_of_any_kind_and_says_where_it_has_no_variants(tmp_path, monkeypatch, capsys):
    """`oodmon evaluate --policy` (before: "unrecognized arguments"): where the docs controller fails
    among a task's variants; an env of no task's is refused naming --policy."""
    (tmp_path / "evaluated_controller.py").write_text(_readme_block()[0])
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["evaluate", "--policy", "evaluated_controller:act", "--env", "CartPole-v1", "--variants",
                 "cartpole:length=2.0,cartpole:length=4.0", "--episodes", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["task"] == "cartpole" and result["method"] == "plain" and result["id_return_mean"] == 500.0
    rows = {row["variant"]: row for row in result["variants"]}
    # the controller balances a pole twice as long, not one four times as long (when written: 500.0
    # and 72.0 over these two episodes)
    assert not rows["cartpole:length=2.0"]["fails"] and rows["cartpole:length=4.0"]["fails"]
    if "plain_tests/OwnCart-v0" not in gymnasium.registry:  # (CartPole under an id of no task's)
        gymnasium.register("plain_tests/OwnCart-v0", entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv",
                           max_episode_steps=500)
    assert main(["evaluate", "--policy", "evaluated_controller:act", "--env", "plain_tests/OwnCart-v0"]) == 2
    assert "monitor the policy in it with `oodmon run --policy ... --env plain_tests/OwnCart-v0`" in \
        capsys.readouterr().err


def test_policy_by_name_finds_the_function_and_says_what_is_wrong_with_a_name(tmp_path, monkeypatch):
    (tmp_path / "named_controller.py").write_text(_readme_block()[0] + "class Controller:\n    pass\n")
    monkeypatch.chdir(tmp_path)  # the module in the current folder, not on sys.path: as the oodmon command runs
    with pytest.raises(ConfigError, match="named_controller.py is in the current folder, .*PYTHONPATH=. oodmon"):
        policy_by_name("named_controller:act")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert policy_by_name("named_controller:act")(np.array([0.0, 0.0, 0.1, 0.0])) == 1
    for spec, said in [("named_controller", "give MODULE:NAME"), ("named_controller:nope", "named_controller has no 'nope'"),
                       ("named_controller:Controller", "is a class"), ("no_such_module_here:act", "on PYTHONPATH")]:
        with pytest.raises(ConfigError, match=said):
            policy_by_name(spec)


def test_bench_runs_the_monitors_protocol_on_a_plain_policy_cached_while_its_module_is_unchanged(
        tmp_path, monkeypatch, capsys):
    (tmp_path / "benched_controller.py").write_text(_readme_block()[0])
    monkeypatch.syspath_prepend(str(tmp_path))  # the cells' worker processes are forked with it
    out = tmp_path / "bench"
    argv = ["bench", "--policy", "benched_controller:act", "--env", "CartPole-v1", "--protocol", "monitor",
            "--variants", "cartpole:gravity=78.4", "--episodes", "5", "--id-episodes", "10",
            "--calibration-episodes", "19", "--confidence", "none", "--fit-episodes", "12", "--workers", "1",
            "--out", str(out), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    rows = {r["variant"]: r for r in result["alarms"] if r["method"] == "plain"}
    # when written: 5 of 5 shifted episodes alarmed, each before the pole fell (gravity 78.4 drops it)
    shifted = rows["cartpole:gravity=78.4"]
    assert rows["cartpole"]["episodes"] == 10 and shifted["episodes"] == 5
    assert shifted["alarmed"] >= 4 and shifted["failed"] == 5 and shifted["before_failure"] >= 4
    assert result["config"]["policy"] == "benched_controller:act"
    stamp = next(out.glob("logs/cartpole-*/plain/trial0/weights.sha256"))
    made_with = stamp.read_text()
    capsys.readouterr()
    assert main(argv) == 0 and stamp.read_text() == made_with  # from its cache: nothing set aside
    assert json.loads(capsys.readouterr().out)["alarms"] == result["alarms"]
    with (tmp_path / "benched_controller.py").open("a") as module:
        module.write("# changed\n")  # the policy's code: its results are set aside, the bench runs again
    assert main(argv) == 0
    assert "was made with other weights than benched_controller:act" in capsys.readouterr().err
    assert list((out / "set-aside").iterdir())
    assert main(argv[:-1] + ["--trials", "2"]) == 2
    assert "a policy: benched as one method ('plain') and one trial" in capsys.readouterr().err


class DictCartPole(gymnasium.ObservationWrapper):
    """oodmon's CartPole (a shift can begin mid-episode) with dict observations."""

    def __init__(self, **physics) -> None:
        super().__init__(gymnasium.make("oodmon/CartPole-v1", **physics))
        low, high = self.env.observation_space.low, self.env.observation_space.high
        self.observation_space = gymnasium.spaces.Dict({"cart": gymnasium.spaces.Box(low[:2], high[:2]),
                                                        "pole": gymnasium.spaces.Box(low[2:], high[2:])})

    def observation(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        return {"cart": obs[:2], "pole": obs[2:]}


def _register_dict_cartpole() -> None:
    if "plain_tests/DictCartPole-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/DictCartPole-v0", entry_point=DictCartPole, max_episode_steps=500)


def test_a_plain_policy_of_dict_observations_gets_dicts_and_its_detectors_read_them_flattened():
    _register_dict_cartpole()
    seen = set()

    def act(obs):
        seen.add(type(obs))
        return int(obs["pole"][0] + 0.5 * obs["pole"][1] + 0.01 * obs["cart"][0] + 0.1 * obs["cart"][1] > 0)

    monitor = oodmon.watch(act, "plain_tests/DictCartPole-v0", fit_episodes=12, episodes=20, confidence=None,
                           workers=2)
    assert seen == {dict}  # in fitting and calibration too, the policy got the env's dicts
    # the calibration episodes in two processes forked from this one (the env registered here, the
    # policy a closure): the threshold one process calibrates on the same detectors
    alone = calibrate_agent(monitor.agent, 20, detectors=monitor.detectors, detector="combined", confidence=None)
    assert monitor.threshold == alone.value
    assert monitor.agent.dict_space is not None and monitor.detector == "combined"
    ids = [monitor.run_episode(gymnasium.make("plain_tests/DictCartPole-v0"), seed=910_000 + i) for i in range(10)]
    # on average over calibrations <= 1/21 false alarms per episode (rank 20 of 20): 4 or more of 10
    # has probability 0.001 at 5% (0.013 at twice that)
    assert all(r.length == 500 for r in ids) and sum(r.first_alarm_step is not None for r in ids) <= 3
    longer = gymnasium.make("plain_tests/DictCartPole-v0", length=2.0, onset_step=30)
    shifted = [monitor.run_episode(longer, seed=920_000 + i) for i in range(5)]
    # when written: 5 of 5 alarmed at step 31 (as the array CartPole's controller above)
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 35 for r in shifted)
    # a sensor of one key frozen from step 30 (the world ID): the controller pushes on blind and the
    # pole falls some 10 steps later; when written, 10 of 10 alarmed at step 31-34, each before the fall
    frozen_pole = parse_env_shift("plain_tests/DictCartPole-v0:obs.pole.stuck=1").make(onset_step=30)
    frozen = [monitor.run_episode(frozen_pole, seed=930_000 + i) for i in range(5)]
    assert all(r.length < 60 for r in frozen)
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 35 < r.length for r in frozen)
    assert seen == {dict}


class MultiCart(gymnasium.Wrapper):
    """oodmon's CartPole with a MultiDiscrete([2, 3]) action: the side to push to, and how hard
    (half, the whole or one and a half times its force)."""

    def __init__(self, **physics) -> None:
        super().__init__(gymnasium.make("oodmon/CartPole-v1", **physics))
        self.action_space = gymnasium.spaces.MultiDiscrete([2, 3])
        self.force = self.env.unwrapped.force_mag

    def step(self, action):
        self.env.unwrapped.force_mag = self.force * (1 + int(action[1])) / 2
        return self.env.step(int(action[0]))


class MissionCartPole(DictCartPole):
    """DictCartPole with a mission beside the readings, as MiniGrid's observations have one (text,
    which gymnasium's FlattenObservation of MiniGrid cannot flatten): a new one each episode, drawn
    from the env's own random numbers, which says how hard to lean against the pole's swing."""

    MISSIONS = ("keep the pole up", "keep the pole up gently")

    def __init__(self, **physics) -> None:
        super().__init__(**physics)
        mission = gymnasium.spaces.Text(40, charset=" abcdefghijklmnopqrstuvwxyz")
        self.observation_space = gymnasium.spaces.Dict({**self.observation_space.spaces, "mission": mission})
        self.said: set[tuple[str, float]] = set()  # every mission given, with the pole's angle beside it

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.mission = self.MISSIONS[int(self.env.unwrapped.np_random.integers(2))]
        return self.observation(obs), info

    def observation(self, obs: np.ndarray) -> dict:
        self.said.add((self.mission, float(obs[2])))
        return {**super().observation(obs), "mission": self.mission}


def _leans_by_its_mission(heard: list):
    """The DictCartPole controller, leaning against the pole's swing less on a gentle mission."""
    def act(obs):
        heard.append((obs["mission"], float(obs["pole"][0])))
        swing = 0.3 if obs["mission"].endswith("gently") else 0.5
        return int(obs["pole"][0] + swing * obs["pole"][1] + 0.01 * obs["cart"][0] + 0.1 * obs["cart"][1] > 0)
    return act


def test_a_plain_policy_gets_the_text_of_its_dict_observations_and_the_detectors_read_the_rest():
    """MiniGrid's observations hold the mission as text beside the numbers: the policy reads it,
    the detectors cannot. The policy gets the env's whole dicts (in fitting, calibration, runs, and
    through a MonitoredEnv), the detectors read the other keys, and a changed world alarms."""
    if "plain_tests/MissionCartPole-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/MissionCartPole-v0", entry_point=MissionCartPole, max_episode_steps=200)
    heard: list[tuple[str, float]] = []
    monitor = oodmon.watch(_leans_by_its_mission(heard), "plain_tests/MissionCartPole-v0", fit_episodes=12,
                           episodes=20, confidence=None)
    assert {said for said, _ in heard} == set(MissionCartPole.MISSIONS) and len(heard) > 6000  # (32 episodes and more)
    assert list(monitor.agent.dict_space.spaces) == ["cart", "pole"] and monitor.agent.reads_words
    assert monitor.detectors["dynamics"].obs_dim == 4  # the readings alone
    env = gymnasium.make("plain_tests/MissionCartPole-v0")
    heard.clear()
    ids = [monitor.run_episode(env, seed=960_000 + i) for i in range(10)]
    # each step, the policy heard the mission the env gave with that step's angle (the env's own draw)
    assert set(heard) <= env.get_wrapper_attr("said") and len({said for said, _ in heard}) == 2 and len(heard) == 2000
    # on average over calibrations <= 1/21 false alarms per episode (rank 20 of 20): 4 or more of 10
    # has probability 0.001 at 5% (0.013 at twice that)
    assert all(r.length == 200 for r in ids) and sum(r.first_alarm_step is not None for r in ids) <= 3
    # a pole twice as long from step 30: when written, 5 of 5 alarmed at steps 33, 33, 31, 31, 32 (and
    # none of the 10 ID episodes above)
    longer = gymnasium.make("plain_tests/MissionCartPole-v0", length=2.0, onset_step=30)
    shifted = [monitor.run_episode(longer, seed=970_000 + i) for i in range(5)]
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 35 for r in shifted)
    # stepped by the user, the env's own dicts: the policy decides on the mission of each
    heard.clear()
    watched = MonitoredEnv(gymnasium.make("plain_tests/MissionCartPole-v0"), monitor.twin())
    obs, _ = watched.reset(seed=980_000)
    for _ in range(50):
        obs, *_ = watched.step()
    assert set(heard) <= watched.get_wrapper_attr("said") and len(heard) == 50
    # a sensor fault of the text is refused, naming the key; an SB3 model cannot read text at all
    with pytest.raises(ConfigError, match=r"\(key 'mission'\): sensor faults \(obs.noise\) read the readings of a Box"):
        parse_env_shift("plain_tests/MissionCartPole-v0:obs.mission.noise=0.1").make()
    with pytest.raises(ConfigError, match=r"its text \('mission'\) is no number SB3 or oodmon's detectors read: leave "
                                          r"it out, gymnasium.wrappers.FilterObservation\(env, \['cart', 'pole'\]\)"):
        dict_space_of(gymnasium.make("plain_tests/MissionCartPole-v0").observation_space, "x")


def test_sensor_noise_in_every_episode_of_an_env_oodmon_has_no_variants_of_is_refused_pointing_to_the_fault():
    agent = plain_agent(lambda obs: 0, "Acrobot-v1")
    assert agent.check_noise(0.0) is None
    words = r"Acrobot-v1 has no such option: a noisy sensor of your own env is the sensor fault Acrobot-v1:obs.noise"
    with pytest.raises(ConfigError, match=words + r"=STD \(--variant, --onset 0\)"):
        agent.check_noise(0.01)


def test_another_env_of_the_same_spaces_is_the_policys_shifted_world_from_its_reset(tmp_path, monkeypatch, capsys):
    """Trained in one env, deployed in another registered one (MiniGrid's DistShift1 and DistShift2;
    here a CartPole and one whose pole is twice as long, each an id of its own): `run --variant
    OTHER_ID` and a MonitoredEnv of the other env log each of its steps as shifted (AnotherEnv), and
    replay counts its alarms as detections. Before 2026-12-06 run refused the id as a malformed
    shift, and a MonitoredEnv logged the other env's episodes as its ID ones (every alarm false)."""
    for name, physics in [("Cart", {}), ("LongCart", {"length": 2.0})]:
        if f"plain_tests/{name}-v0" not in gymnasium.registry:
            gymnasium.register(f"plain_tests/{name}-v0", entry_point="oodmon.envs.physics:ShiftedCartPole",
                               kwargs=physics, max_episode_steps=200)
    (tmp_path / "upright.py").write_text(_readme_block()[0])
    monkeypatch.syspath_prepend(str(tmp_path))
    threshold = str(tmp_path / "t.json")
    assert main(["calibrate", "--policy", "upright:act", "--env", "plain_tests/Cart-v0", "--episodes", "20",
                 "--confidence", "none", "--fit-episodes", "12", "--out", threshold]) == 0
    run = ["run", "--policy", "upright:act", "--env", "plain_tests/Cart-v0", "--threshold", threshold,
           "--episodes", "10"]
    assert main([*run, "--seed", "990000", "--mcap", str(tmp_path / "id.mcap")]) == 0
    assert main([*run, "--variant", "plain_tests/LongCart-v0", "--mcap", str(tmp_path / "long.mcap")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "does the shift change anything" not in said  # (a shift of attributes' hint: `envs show` takes none)
    # in Python: a MonitoredEnv of the other env, its id alone
    from oodmon.monitor import McapSink

    monitor = oodmon.watch(policy_by_name("upright:act"), "plain_tests/Cart-v0", fit_episodes=12, episodes=20,
                           confidence=None)
    with MonitoredEnv(gymnasium.make("plain_tests/LongCart-v0"),
                      monitor.twin(sinks=[McapSink(tmp_path / "watched.mcap")])) as watched:
        for episode in range(5):
            watched.reset(seed=995_000 + episode)
            while not any(watched.step()[2:4]):
                pass
    for logs, episodes in [(["id.mcap", "long.mcap"], 10), (["watched.mcap"], 5)]:
        plots = tmp_path / f"plots-{episodes}"
        assert main(["replay", "--plots", str(plots), *[str(tmp_path / log) for log in logs]]) == 0
        assert "roc_plain_tests_LongCart-v0.png" in {p.name for p in plots.iterdir()} or episodes == 5
        capsys.readouterr()
        assert main(["replay", "--json", *[str(tmp_path / log) for log in logs]]) == 0
        rows = {r["variant"]: r for r in json.loads(capsys.readouterr().out) if r["detector"] == "combined"}
        longer = rows["plain_tests/LongCart-v0"]
        # when written: every episode alarmed at its second step (delay 1: a pole twice as long, from
        # the reset), the CLI's run's steps ranked against its ID run's at AUROC 0.995
        assert longer["episodes"] == episodes and longer["detection_rate"] == 1.0 and longer["early_alarm_rate"] == 0
        assert longer["delay_median"] <= 5 and (longer["auroc"] > 0.9 if "id.mcap" in logs else longer["auroc"] is None)
    # on average over calibrations <= 1/21 false alarms per episode (rank 20 of 20): 4 or more of 10
    # has probability 0.001 at 5% (0.013 at twice that)
    assert main(["replay", "--json", str(tmp_path / "id.mcap")]) == 0
    ids = [r for r in json.loads(capsys.readouterr().out) if r["detector"] == "combined"]
    assert [r["variant"] for r in ids] == ["plain_tests/Cart-v0"] and ids[0]["false_alarm_rate"] <= 3 / 10
    # the monitor's benchmark of it (the onsets it draws are none of that env's: each episode shifted
    # from its reset); when written, 5 of 5 alarmed at delay 1
    capsys.readouterr()
    assert main(["bench", "--policy", "upright:act", "--env", "plain_tests/Cart-v0", "--protocol", "monitor",
                 "--variants", "plain_tests/LongCart-v0", "--onsets", "10,20", "--episodes", "5", "--id-episodes",
                 "10", "--calibration-episodes", "19", "--confidence", "none", "--fit-episodes", "12",
                 "--workers", "1", "--out", str(tmp_path / "bench"), "--json"]) == 0
    benched = {r["variant"]: r for r in json.loads(capsys.readouterr().out)["alarms"] if r["method"] == "plain"}
    assert benched["plain_tests/LongCart-v0"]["alarmed"] == 5 and benched["plain_tests/LongCart-v0"]["early"] == 0
    assert max(benched["plain_tests/LongCart-v0"]["delays"]) <= 5  # from the reset (onset 0), not from 10-19
    assert main(["bench", "--policy", "upright:act", "--env", "plain_tests/Cart-v0", "--protocol", "monitor",
                 "--variants", "Pendulum-v1", "--onsets", "10,20", "--out", str(tmp_path / "bench")]) == 2
    assert "--variants Pendulum-v1: its observation_space is Box" in capsys.readouterr().err
    # another env is the shifted world from its reset; one of other spaces is no world of the policy's
    assert main([*run, "--variant", "plain_tests/LongCart-v0", "--onset", "5"]) == 2
    assert "is another env than plain_tests/Cart-v0, deployed from its reset" in capsys.readouterr().err
    assert main([*run, "--variant", "Pendulum-v1"]) == 2
    assert "this env's observation_space is Box" in capsys.readouterr().err


class TupleCartPole(gymnasium.ObservationWrapper):
    """oodmon's CartPole (a shift can begin mid-episode) with tuple observations: the cart's two
    readings, the pole's two, and which side the pole leans to (a Discrete value)."""

    def __init__(self, **physics) -> None:
        super().__init__(gymnasium.make("oodmon/CartPole-v1", **physics))
        low, high = self.env.observation_space.low, self.env.observation_space.high
        self.observation_space = gymnasium.spaces.Tuple((gymnasium.spaces.Box(low[:2], high[:2]),
                                                         gymnasium.spaces.Box(low[2:], high[2:]),
                                                         gymnasium.spaces.Discrete(2)))

    def observation(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        return obs[:2], obs[2:], int(obs[2] > 0)


class TupleActionsCartPole(gymnasium.Wrapper):
    """oodmon's CartPole (a shift can begin mid-episode) pushed to a side with a strength: a
    parameterised action, Tuple(Discrete(2), Box(0, 1)), the force from half to one and a half
    times its own."""

    def __init__(self, **physics) -> None:
        super().__init__(gymnasium.make("oodmon/CartPole-v1", **physics))
        self.action_space = gymnasium.spaces.Tuple((gymnasium.spaces.Discrete(2),
                                                    gymnasium.spaces.Box(0.0, 1.0, (1,), np.float32)))
        self.force = self.env.unwrapped.force_mag

    def step(self, action):
        side, strength = action
        self.env.unwrapped.force_mag = self.force * (0.5 + float(strength[0]))
        return self.env.step(int(side))


class _NestedActions(TupleActionsCartPole):
    """A tuple inside the tuple of actions: what no detector reads as it is."""

    def __init__(self) -> None:
        super().__init__()
        self.action_space = gymnasium.spaces.Tuple((self.action_space,))

    def step(self, action):
        return super().step(action[0])


def test_a_plain_policy_of_a_tuple_of_actions_gives_the_env_tuples_and_the_detectors_read_them_flattened():
    """A parameterised action (which side, how hard): the env and the policy deal in tuples, the
    dynamics model and the log read each one flattened (the side one-hot, then the strength).
    Before, refused (2026-12-06 morning), and before that numpy's "inhomogeneous shape" after the
    fitting episodes."""
    if "plain_tests/TupleActionsCartPole-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/TupleActionsCartPole-v0", entry_point=TupleActionsCartPole,
                           max_episode_steps=200)

    def act(obs):
        lean = obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1]
        return int(lean > 0), np.array([min(1.0, 10 * abs(lean))], np.float32)

    sink = MemorySink()
    monitor = oodmon.watch(act, "plain_tests/TupleActionsCartPole-v0", fit_episodes=12, episodes=20, confidence=None,
                           sinks=[sink])
    assert monitor.agent.action_parts is not None and monitor.detectors["dynamics"].n_actions is None
    ids = [monitor.run_episode(gymnasium.make("plain_tests/TupleActionsCartPole-v0"), seed=960_000 + i)
           for i in range(10)]
    # on average over calibrations <= 1/21 false alarms per episode (rank 20 of 20): 4 or more of 10
    # has probability 0.001 at 5% (0.013 at twice that)
    assert all(r.length == 200 for r in ids) and sum(r.first_alarm_step is not None for r in ids) <= 3
    first, _ = gymnasium.make("plain_tests/TupleActionsCartPole-v0").reset(seed=960_000)
    side, strength = act(first)
    # the log holds the side one-hot, then the strength
    assert sink.steps[0].action == [float(side == 0), float(side == 1), pytest.approx(float(strength[0]))]
    assert all(len(step.action) == 3 and step.action[0] + step.action[1] == 1.0 for step in sink.steps)
    longer = gymnasium.make("plain_tests/TupleActionsCartPole-v0", length=2.0, onset_step=30)
    shifted = [monitor.run_episode(longer, seed=970_000 + i) for i in range(5)]
    # when written: 5 of 5 alarmed, at steps 31, 31, 35, 31, 34 (and 1 of the 10 ID episodes above)
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 40 for r in shifted)


class _NestedTuple(TupleCartPole):
    """The tuple and a dict of the pole's readings inside a tuple: what gymnasium flattens, and a
    plain policy gets back as it is (no sensor fault names a part inside a part)."""

    def __init__(self) -> None:
        super().__init__()
        self.observation_space = gymnasium.spaces.Tuple((self.observation_space, gymnasium.spaces.Dict(
            {"angle": gymnasium.spaces.Box(-1, 1, (1,)), "speed": gymnasium.spaces.Box(-np.inf, np.inf, (1,))})))

    def observation(self, obs: np.ndarray) -> tuple:
        return super().observation(obs), {"angle": obs[2:3], "speed": obs[3:4]}


class _TupleWithPicture(TupleCartPole):
    """A camera's picture beside the readings, in a tuple: a dict's picture is read (dict_pictures),
    a tuple's is not."""

    def __init__(self) -> None:
        super().__init__()
        self.observation_space = gymnasium.spaces.Tuple((gymnasium.spaces.Box(0, 255, (8, 8, 3), np.uint8),
                                                         self.observation_space))

    def observation(self, obs: np.ndarray) -> tuple:
        return np.zeros((8, 8, 3), np.uint8), super().observation(obs)


def test_a_plain_policy_of_nested_observations_gets_them_as_the_env_gives_them_and_its_detectors_flat():
    from oodmon.monitor.detectors import fit_agent_detectors

    if "plain_tests/NestedTuple-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/NestedTuple-v0", entry_point=_NestedTuple, max_episode_steps=200)
    seen = []

    def act(obs):
        (cart, pole, side), inner = obs
        seen.append(float(inner["angle"][0]) == float(pole[0]) and int(side) in (0, 1))
        return int(pole[0] + 0.5 * pole[1] + 0.01 * cart[0] + 0.1 * cart[1] > 0)

    agent = plain_agent(act, "plain_tests/NestedTuple-v0")
    assert agent.dict_space is not None and all(seen)
    # gymnasium's order: the tuple's parts, the side one-hot, then the dict's keys
    assert agent.view((((1.0, 2.0), (3.0, 4.0), 1), {"angle": [3.0], "speed": [4.0]})).tolist() == [
        1.0, 2.0, 3.0, 4.0, 0.0, 1.0, 3.0, 4.0]
    detectors = fit_agent_detectors(agent, episodes=3)
    with Monitor(agent, None, detectors=detectors) as monitor:
        record = monitor.run_episode(gymnasium.make("plain_tests/NestedTuple-v0"), seed=0)
    assert record.length == 200 and all(seen) and len(seen) > 800  # (the fit's three episodes, then this one)


def test_a_plain_policy_of_tuple_observations_gets_tuples_and_a_sensor_fault_of_one_part_alarms():
    """A Tuple of vectors and a discrete value, as a Dict's (above): the policy gets the env's tuples,
    the detectors read them flattened, and ``obs.N.KIND[i]`` names a sensor fault of part N."""
    if "plain_tests/TupleCartPole-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/TupleCartPole-v0", entry_point=TupleCartPole, max_episode_steps=200)
    seen = set()

    def act(obs):
        seen.add((type(obs), len(obs), type(obs[0]), str(obs[0].dtype), int(obs[2])))
        cart, pole, _ = obs
        return int(pole[0] + 0.5 * pole[1] + 0.01 * cart[0] + 0.1 * cart[1] > 0)

    # the discrete part is read one-hot (readings 4 and 5 flattened): inputs of the dynamics model
    with pytest.warns(UserWarning, match="readings 4, 5 of the observation .flattened. jump between a few values"):
        monitor = oodmon.watch(act, "plain_tests/TupleCartPole-v0", fit_episodes=12, episodes=20, confidence=None)
    assert {kind[:4] for kind in seen} == {(tuple, 3, np.ndarray, "float32")} and {kind[4] for kind in seen} == {0, 1}
    assert monitor.agent.view(((1.0, 2.0), (3.0, 4.0), 1)).tolist() == [1.0, 2.0, 3.0, 4.0, 0.0, 1.0]
    ids = [monitor.run_episode(gymnasium.make("plain_tests/TupleCartPole-v0"), seed=940_000 + i) for i in range(10)]
    # on average over calibrations <= 1/21 false alarms per episode (rank 20 of 20): 4 or more of 10
    # has probability 0.001 at 5% (0.013 at twice that)
    assert all(r.length == 200 for r in ids) and sum(r.first_alarm_step is not None for r in ids) <= 3
    # the pole's angular velocity (part 1, reading 1) off by 0.5 from step 30: when written, 5 of 5
    # alarmed at step 31 (and none of the 10 ID episodes above)
    biased = parse_env_shift("plain_tests/TupleCartPole-v0:obs.1.bias[1]=0.5")
    assert biased.params == (("obs.1.bias[1]", 0.5),)
    shifted = [monitor.run_episode(biased.make(onset_step=30), seed=950_000 + i) for i in range(5)]
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 35 for r in shifted)
    with pytest.raises(ConfigError, match=r"'obs.3.bias' names no part of its tuple observation; give "
                                          r"obs.N.KIND\[i\]=VALUE, N one of 0, 1, 2"):
        parse_env_shift("plain_tests/TupleCartPole-v0:obs.3.bias=1").make()
    with pytest.raises(ConfigError, match=r"\(part 2\): 'obs.scale' is no sensor fault of discrete values"):
        parse_env_shift("plain_tests/TupleCartPole-v0:obs.2.scale=2").make()


def test_a_plain_policy_of_multi_discrete_actions_is_watched_with_every_part_of_its_action_read():
    """A MultiDiscrete action reaches the dynamics model as its numbers (one-hot is for Discrete
    alone): a policy that pushes harder the harder it leans on the cart is fitted, calibrated and
    watched, and its model reads how hard it pushed."""
    if "plain_tests/MultiCart-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/MultiCart-v0", entry_point=MultiCart, max_episode_steps=500)

    def act(obs):  # the controller of the tests above, pushing harder the farther it would push
        push = obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1]
        return np.array([int(push > 0), 2 if abs(push) > 0.07 else int(abs(push) > 0.05)])

    monitor = oodmon.watch(act, "plain_tests/MultiCart-v0", fit_episodes=12, episodes=20, confidence=None)
    dynamics = monitor.detectors["dynamics"]
    assert dynamics.n_actions is None and dynamics._weights[0][0].shape[1] == 4 + 2  # the readings, then the action
    ids = [monitor.run_episode(gymnasium.make("plain_tests/MultiCart-v0"), seed=940_000 + i) for i in range(10)]
    # as the dict CartPole's test above: 4 or more of 10 has probability 0.001 at 5% per episode
    assert all(r.length == 500 for r in ids) and sum(r.first_alarm_step is not None for r in ids) <= 3
    # the strength is read: the same ID transitions scored with the whole and one and a half times
    # the force swapped (about half the steps each, when written) read worse
    trajectory = collect(monitor.agent, gymnasium.make("plain_tests/MultiCart-v0"), 1, seed=950_000)[0]
    obs, actions = np.asarray(trajectory.observations), np.asarray(trajectory.actions)
    assert min(np.mean(actions[:, 1] == 1), np.mean(actions[:, 1] == 2)) > 0.2
    other = actions.copy()
    other[actions[:, 1] > 0, 1] = 3 - actions[actions[:, 1] > 0, 1]
    as_pushed = dynamics.score_transitions(obs[:-1], actions, obs[1:])
    otherwise = dynamics.score_transitions(obs[:-1], other, obs[1:])
    assert np.median(otherwise) > np.median(as_pushed) + 1.0  # when written: 487.7 against -0.8
    longer = gymnasium.make("plain_tests/MultiCart-v0", length=2.0, onset_step=30)
    shifted = [monitor.run_episode(longer, seed=960_000 + i) for i in range(5)]
    # when written: alarmed at steps 38, 31, 38, 36 and 31 (each episode 500 steps: the pole held)
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 45 for r in shifted)


class CountedFromOne(gymnasium.Wrapper):
    """oodmon's CartPole whose two actions are 1 and 2 (``Discrete(2, start=1)``)."""

    steps = 0  # taken in any instance

    def __init__(self, **physics) -> None:
        super().__init__(gymnasium.make("oodmon/CartPole-v1", **physics))
        self.action_space = gymnasium.spaces.Discrete(2, start=1)

    def step(self, action):
        CountedFromOne.steps += 1
        return self.env.step(int(action) - 1)


class LakeFromOne(gymnasium.ObservationWrapper):
    """FrozenLake whose cells are numbered from 1 (``Discrete(16, start=1)``)."""

    def __init__(self) -> None:
        super().__init__(gymnasium.make("FrozenLake-v1"))
        self.observation_space = gymnasium.spaces.Discrete(16, start=1)

    def observation(self, obs):
        return int(obs) + 1


def test_discrete_actions_and_observations_not_counted_from_zero_are_read_one_hot_for_a_plain_policy():
    """The dynamics and drift detectors index a discrete action's one-hot row by the action: a plain
    policy's actions of ``Discrete(2, start=1)`` are read one-hot instead (``Agent.read_action``;
    refused before any play from 2026-12-02, after the fitting episodes before that, as "actions
    outside 0..1"). An agent that reads them as they are (an SB3 model, which ignores start) is
    still refused, saying which wrapper counts them from 0. Discrete observations not counted from
    0 are a plain policy's too (refused before 2026-12-06), and an SB3 model's are refused."""
    if "plain_tests/CountedFromOne-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/CountedFromOne-v0", entry_point=CountedFromOne, max_episode_steps=200)
        gymnasium.register("plain_tests/LakeFromOne-v0", entry_point=LakeFromOne, max_episode_steps=100)

    def act(obs):
        return 1 + int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)

    monitor = oodmon.watch(act, "plain_tests/CountedFromOne-v0", fit_episodes=12, episodes=20, confidence=None)
    assert monitor.agent.read_action(1).tolist() == [1.0, 0.0] and monitor.agent.read_action(2).tolist() == [0.0, 1.0]
    assert monitor.detectors["dynamics"].n_actions is None  # (the one-hot rows as numbers)
    ids = [monitor.run_episode(gymnasium.make("plain_tests/CountedFromOne-v0"), seed=980_000 + i) for i in range(10)]
    # <= 1/21 false alarms per episode on average over calibrations: 4 or more of 10 has probability 0.001
    assert all(r.length == 200 for r in ids) and sum(r.first_alarm_step is not None for r in ids) <= 3
    longer = gymnasium.make("plain_tests/CountedFromOne-v0", length=2.0, onset_step=30)
    shifted = [monitor.run_episode(longer, seed=990_000 + i) for i in range(5)]
    # when written: 5 of 5 alarmed, at steps 31, 31, 33, 33, 31 (and 1 of the 10 ID episodes above)
    assert all(r.first_alarm_step is not None and 30 < r.first_alarm_step <= 40 for r in shifted)
    as_they_are = replace(monitor.agent, action_parts=None)
    for detector in ("dynamics", "drift"):  # (and features, which a plain policy cannot have anyway)
        assert re.search(r"the \w+ detector reads a discrete action as one of its n actions counted from 0, and this "
                         r"env's are Discrete\(2, start=1\): .*returns a \+ 1",
                         cannot_have(detector, as_they_are, gymnasium.make("plain_tests/CountedFromOne-v0")))
    # discrete observations not counted from 0: a policy of any kind gets them as they are, the
    # detectors read them one-hot from their start (cell 1 the first); an SB3 model's are refused
    lake = plain_agent(lambda obs: 2 if int(obs) in (1, 2, 3) else 1, "plain_tests/LakeFromOne-v0")
    assert lake.view(1).tolist() == [1.0] + [0.0] * 15 and lake.view(16).tolist() == [0.0] * 15 + [1.0]
    with pytest.raises(ConfigError, match=r"observations are Discrete\(16, start=1\); .*discrete values \(counted from "
                                          r"0\).*FlattenObservation"):
        dict_space_of(gymnasium.spaces.Discrete(16, start=1), "plain_tests/LakeFromOne-v0")


class BreaksAtStep(gymnasium.Wrapper):
    """An env (CartPole) whose own step raises at its third step, whatever the action."""

    def __init__(self, env_id: str = "CartPole-v1") -> None:
        super().__init__(gymnasium.make(env_id))
        self.steps = 0

    def reset(self, **kwargs):
        self.steps = 0
        return self.env.reset(**kwargs)

    def step(self, action):
        self.steps += 1
        if self.steps == 3:
            raise RuntimeError("the simulator crashed")
        return self.env.step(action)


def test_an_action_the_env_refuses_mid_episode_is_named_with_its_step_and_the_envs_own_errors_are_not():
    """A policy that returns an action outside the env's space in some state (here None, once the
    cart has moved) failed with the env's traceback alone ("AssertionError: None (<class
    'NoneType'>) invalid", `oodmon calibrate` adding "run the command again"); now the sentence
    says what the policy returned, at which step of which episode: in the fitting episodes, the
    monitored ones (`MonitoredEnv` too, where the policy acts) and `envs show --policy`. An error
    of the env's own, on a good action, is raised as it is."""
    broken = [False]

    def act(obs):
        if broken[0] and abs(obs[0]) > 0.02:
            return None
        return int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)

    agent = plain_agent(act, "CartPole-v1")
    episodes = collect(agent, gymnasium.make("CartPole-v1"), 3, seed=970_000)  # (the fit below, small)
    broken[0] = True
    with pytest.raises(ConfigError, match=r"^the policy returned None at step \d+ of fitting episode 0 \(seed 970000\), "
                                          r"which the env refused \(AssertionError: .*\); its actions are Discrete\(2\)$"):
        collect(agent, gymnasium.make("CartPole-v1"), 3, seed=970_000)
    sink = MemorySink()
    dynamics = DynamicsDetector(2, epochs=2, seed=0).fit(episodes)
    monitor = Monitor(agent, threshold=1e9, detectors=[dynamics], sinks=[sink])
    with pytest.raises(ConfigError, match=r"^the policy returned None at step \d+ of an episode \(seed 5\), which"):
        monitor.run_episode(gymnasium.make("CartPole-v1"), seed=5)
    assert sink.episodes[-1].interrupted  # the episode is logged up to the step the env refused
    watched = MonitoredEnv(gymnasium.make("CartPole-v1"), monitor)  # the policy acts at env.step()
    watched.reset(seed=5)
    with pytest.raises(ConfigError, match=r"^the policy returned None at step \d+ of this episode, which the env"):
        while True:
            watched.step()
    watched.reset(seed=5)
    with pytest.raises(AssertionError, match=r"^5 \(<class 'int'>\) invalid"):
        watched.step(5)  # an action you give yourself: the env's own error
    with pytest.raises(ConfigError, match=r"^the policy returned None at step \d+ of an episode \(seed 0\), which"):
        probe_shift(parse_env_shift("CartPole-v1:theta_threshold_radians=0.3"), policy=act)  # `envs show --policy`
    broken[0] = False
    if "plain_tests/BreaksAtStep-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/BreaksAtStep-v0", entry_point=BreaksAtStep)
    with pytest.raises(RuntimeError, match="^the simulator crashed$"):
        collect(plain_agent(act, "CartPole-v1"), gymnasium.make("plain_tests/BreaksAtStep-v0"), 3)
    with pytest.raises(RuntimeError, match="^the simulator crashed$"):
        monitor.run_episode(gymnasium.make("plain_tests/BreaksAtStep-v0"), seed=5)
    # a float64 action of a float32 Box, which gymnasium's contains() refuses and the env takes, is
    # a good action: the env's own error is raised as it is
    if "plain_tests/PendulumBreaksAtStep-v0" not in gymnasium.registry:
        gymnasium.register("plain_tests/PendulumBreaksAtStep-v0", entry_point=BreaksAtStep,
                           kwargs={"env_id": "Pendulum-v1"})
    torque = plain_agent(lambda obs: np.array([-2.0 * obs[1] - 0.5 * obs[2]]), "Pendulum-v1")
    with pytest.raises(RuntimeError, match="^the simulator crashed$"):
        collect(torque, gymnasium.make("plain_tests/PendulumBreaksAtStep-v0"), 3)


def test_envs_show_plays_a_shift_of_your_own_env_with_your_policy(tmp_path, monkeypatch, capsys):
    (tmp_path / "pump.py").write_text("def act(obs):\n    return 2 if obs[4] > 0 else 0\n")  # Acrobot: torque with the velocity
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["envs", "show", "Acrobot-v1:LINK_MASS_2=3.0", "--onset", "20", "--policy", "pump:act"]) == 0
    # the policy's actions, not random ones: the heavier link moves otherwise from the first step after the onset
    assert "differs from the env's own from step 21 on, over 500 steps of the policy's actions" in capsys.readouterr().out
    assert main(["envs", "show", "pong:pixelate@3", "--policy", "pump:act"]) == 2
    assert "pong:pixelate@3 is shown as its clean and corrupted frames" in capsys.readouterr().err


def test_a_run_whose_shift_of_the_env_alarmed_nowhere_prints_the_envs_show_of_its_own_policy(tmp_path, monkeypatch,
                                                                                              capsys):
    """A judge set tighter, `CartPole-v1:theta_threshold_radians=0.1` from step 150: the controller
    keeps well within it, no episode alarms, and the run prints the probe to try with the controller
    acting (before 2026-12-02 it gave random actions, which drop the pole long before step 150, and
    said nothing of gymnasium's id of one of oodmon's tasks). Likewise for oodmon's own variant of
    the task, gravity 12% stronger from step 30, which the controller copes with (said since
    2026-12-04): `envs show` plays it beside the task's ID env, the controller acting."""
    (tmp_path / "upright.py").write_text(_readme_block()[0])
    monkeypatch.syspath_prepend(str(tmp_path))
    threshold = str(tmp_path / "t.json")
    # the alarm on stillness (a CartPole never repeats a state: it alarms nowhere), the set fitted small
    assert main(["calibrate", "--policy", "upright:act", "--env", "CartPole-v1", "--detector", "stillness",
                 "--episodes", "20", "--far", "0.2", "--confidence", "none", "--fit-episodes", "4",
                 "--dynamics-updates", "100", "--out", threshold]) == 0
    capsys.readouterr()
    assert main(["run", "--policy", "upright:act", "--env", "CartPole-v1", "--threshold", threshold, "--episodes", "2",
                 "--variant", "CartPole-v1:theta_threshold_radians=0.1", "--onset", "150"]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "0 of 2 episodes raised an alarm" in said
    command = re.search(r"`(oodmon envs show [^`]*)`", said).group(1)
    assert shlex.split(command) == ["oodmon", "envs", "show", "CartPole-v1:theta_threshold_radians=0.1", "--onset",
                                    "150", "--policy", "upright:act"]
    assert main(shlex.split(command)[1:]) == 1  # as printed: nothing differs where the controller goes
    assert "over 500 steps of the policy's actions" in " ".join(capsys.readouterr().out.split())
    assert main(["run", "--policy", "upright:act", "--env", "CartPole-v1", "--threshold", threshold, "--episodes", "2",
                 "--variant", "cartpole:gravity=11.0", "--onset", "30"]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "0 of 2 episodes raised an alarm" in said and "a change of physics or of a sensor acts only in some states" in said
    command = re.search(r"`(oodmon envs show [^`]*)`", said).group(1)
    assert shlex.split(command) == ["oodmon", "envs", "show", "cartpole:gravity=11.0", "--onset", "30", "--policy",
                                    "upright:act"]
    assert main(shlex.split(command)[1:]) == 0  # the pole's readings move apart from step 31, both held 500 steps
    assert "from step 31 on, over 500 steps of the policy's actions" in " ".join(capsys.readouterr().out.split())


def test_a_detector_a_plain_policy_cannot_have_is_refused_before_any_episode(tmp_path, monkeypatch, capsys):
    (tmp_path / "refused_controller.py").write_text(_readme_block()[0])
    monkeypatch.syspath_prepend(str(tmp_path))
    import refused_controller

    calls = []
    monkeypatch.setattr("oodmon.monitor.detectors.fitting.collect", lambda *a, **k: calls.append(1))  # no fit begins
    for detector, said in [("spread", "the spread detector reads the policy's samples, and this one has none"),
                           ("features", "the features detector reads the policy's features, and this one has none"),
                           ("frames", "the frames detector needs image observations; this env's are of shape (4,)")]:
        assert main(["calibrate", "--policy", "refused_controller:act", "--env", "CartPole-v1", "--detector", detector,
                     "--out", str(tmp_path / "t.json")]) == 2
        assert said in capsys.readouterr().err
        with pytest.raises(ConfigError, match=said.replace("(", r"\(").replace(")", r"\)")):
            oodmon.watch(refused_controller.act, "CartPole-v1", detector=detector)
    assert calls == [] and not (tmp_path / "t.json").exists()


class Remembering:
    """A policy with a memory of the episode: the steps it has acted in it, forgotten at its start."""

    def __init__(self) -> None:
        self.steps, self.begun = 0, 0

    def begin_episode(self) -> None:
        self.steps, self.begun = 0, self.begun + 1

    def __call__(self, obs):
        self.steps += 1
        pole = obs["pole"] if isinstance(obs, dict) else obs[2:]
        return int(pole[0] + 0.5 * pole[1] > 0)


@pytest.mark.parametrize("env_id", ["CartPole-v1", "plain_tests/DictCartPole-v0"])
def test_a_plain_policy_with_a_memory_is_told_of_each_episodes_start(env_id, tmp_path):
    import dataclasses

    from oodmon.agents import load
    from oodmon.monitor import Monitor
    from oodmon.monitor.detectors import fit_agent_detectors
    from oodmon.monitor.detectors.fitting import fit_recorded_detectors
    from oodmon.monitor.sinks import McapSink
    from oodmon.replay import fit_detectors_from_logs

    _register_dict_cartpole()
    policy = Remembering()
    agent = plain_agent(policy, env_id)
    assert agent.remembers
    detectors = fit_agent_detectors(agent, episodes=3)
    assert policy.begun >= 3  # the fit's episodes each began anew
    with Monitor(agent, None, detectors=detectors, sinks=[McapSink(tmp_path / "id.mcap")]) as monitor:
        lengths = [monitor.run_episode(gymnasium.make(env_id), seed=seed).length for seed in (1, 2, 3)]
        assert policy.steps == lengths[2]  # its memory is of the last episode alone
    # its detectors fitted on that log (refused before 2026-12-07): they read the numbers the log
    # holds, and the policy, which has no samples, is not asked (its memory stays as it was)
    begun = policy.begun
    fitted = fit_detectors_from_logs(agent, [tmp_path / "id.mcap"], dynamics_updates=50)
    assert fitted.names == detectors.names and "dynamics" in fitted.names and fitted.fitted_for["episodes"] == 3
    assert (policy.steps, policy.begun) == (lengths[2], begun)
    # where its samples would read the memory (an ensemble's, deciding with one), the log cannot serve
    sampled = dataclasses.replace(load("cartpole", "ensemble"), deploy=policy)
    with pytest.raises(ConfigError, match="the picture, text or memory of the episode that its samples read"):
        fit_recorded_detectors(sampled, [])


class _OneDecision(gymnasium.Env):
    """A contextual bandit: a context, one decision, the episode ends (its last observation the
    context's echo)."""

    observation_space = gymnasium.spaces.Box(-1, 1, shape=(2,), dtype=np.float32)
    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self, decisions: int = 1) -> None:
        self.decisions = decisions  # (2: two contexts an episode)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.context, self.made = self.np_random.uniform(-1, 1, 2).astype(np.float32), 0
        return self.context, {}

    def step(self, action):
        self.made += 1
        reward = float(action == (self.context[0] > 0))
        self.context = (0.5 * self.context + self.np_random.normal(0, 0.01, 2)).astype(np.float32)
        return self.context, reward, self.made == self.decisions, False, {}


def test_an_alarm_that_reads_changes_is_refused_where_every_episode_lasts_one_step():
    # The monitor scores the observations the policy acts on; an episode of one step has only its
    # first, which no change led to: calibrated, the combined alarm read "score > -0" from 50 equal
    # ID scores and alarmed at nothing (2026-12-01)
    from oodmon.monitor.detectors import fit_detectors

    for decisions in (1, 2):
        if f"plain_tests/Decisions{decisions}-v0" not in gymnasium.registry:
            gymnasium.register(f"plain_tests/Decisions{decisions}-v0", entry_point=_OneDecision,
                               kwargs={"decisions": decisions})
    agents = {n: plain_agent(lambda obs: int(obs[0] > 0), f"plain_tests/Decisions{n}-v0") for n in (1, 2)}
    fitted = {n: fit_detectors(agents[n], gymnasium.make(f"plain_tests/Decisions{n}-v0"), episodes=30) for n in (1, 2)}
    assert fitted[1].names == fitted[2].names == ["dynamics", "drift", "combined"]
    for detector in ("combined", "dynamics", "drift"):
        with pytest.raises(ConfigError, match=f"every ID episode lasted one step: the {detector} detector scores the "
                                              "change into each observation .* an ensemble"):
            calibrate_agent(agents[1], 50, detectors=fitted[1], detector=detector)
        # two steps: the second's change is scored
        assert calibrate_agent(agents[2], 50, detectors=fitted[2], detector=detector).n_steps == 100

