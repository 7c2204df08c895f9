"""A dict observation holding a picture beside a vector (a camera and the state: an SB3
``MultiInputPolicy``, which reads the picture through a CNN): the policy gets the dict as the env
gives it, the dynamics detector reads the vector, the frames detector the picture, and the log
keeps the vector and the picture."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest
from stable_baselines3 import DQN

from oodmon.agents.sb3 import load_sb3, sb3_agent
from oodmon.cli import main
from oodmon.envs import parse_variant
from oodmon.errors import ConfigError
from oodmon.monitor import McapSink, MemorySink, Monitor
from oodmon.monitor.calibration import calibrate_agent
from oodmon.monitor.detectors import fit_agent_detectors, fit_detectors
from oodmon.replay import read_log
from tests.helpers import ActedOn

ENV_ID = "CameraCartPoleForTests-v0"


class _CameraCartPole(gymnasium.ObservationWrapper):
    """CartPole seen as ``{"camera": a 36 x 36 picture of the pole, "state": the usual vector}``
    (36 pixels: the least SB3's CNN takes)."""

    def __init__(self, env: gymnasium.Env | None = None, *, snow: bool = False) -> None:
        super().__init__(env if env is not None else gymnasium.make("CartPole-v1"))
        self.observation_space = gymnasium.spaces.Dict({
            "camera": gymnasium.spaces.Box(0, 255, (36, 36, 1), np.uint8), "state": self.env.observation_space})
        self.snow = np.random.default_rng(0) if snow else None  # a camera that snows: a shift in the picture alone

    def observation(self, obs):
        picture = np.zeros((36, 36, 1), np.uint8)
        foot = int(np.clip(18 + 6 * obs[0], 0, 35))  # the cart's position, then the pole up from it
        for height in range(12):
            picture[30 - height, int(np.clip(foot + height * np.sin(obs[2]), 0, 35)), 0] = 255
        if self.snow is not None:
            picture[self.snow.random(picture.shape) < 0.05] = 255
        return {"camera": picture, "state": obs}


class _ColourCamera(_CameraCartPole):
    """The camera in colour, (36, 36, 3): SB3 moves its channels first for the CNN."""

    def __init__(self) -> None:
        super().__init__()
        self.observation_space = gymnasium.spaces.Dict({
            "camera": gymnasium.spaces.Box(0, 255, (36, 36, 3), np.uint8), "state": self.env.observation_space})

    def observation(self, obs):
        grey = super().observation(obs)
        picture = np.repeat(grey["camera"], 3, axis=2)
        picture[..., 0] //= 2  # the pole in cyan: the channels differ
        return {"camera": picture, "state": grey["state"]}


class _TwoCameras(_CameraCartPole):
    """Pictures alone in the dict: nothing for the detectors to read."""

    def __init__(self) -> None:
        super().__init__()
        camera = self.observation_space["camera"]
        self.observation_space = gymnasium.spaces.Dict({"front": camera, "side": camera})

    def observation(self, obs):
        picture = super().observation(obs)["camera"]
        return {"front": picture, "side": picture}


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """A DQN on the camera and the state (400 steps: it keeps the pole up some 10 steps; the
    detectors watch the physics, whatever the policy)."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(ENV_ID, entry_point=_CameraCartPole)
    model = DQN("MultiInputPolicy", gymnasium.make(ENV_ID), seed=0, learning_starts=200,
                policy_kwargs={"net_arch": [32, 32]})
    assert model.observation_space["camera"].shape == (1, 36, 36)  # SB3 stores the picture channels first
    model.learn(400)
    path = tmp_path_factory.mktemp("camera") / "dqn.zip"
    model.save(path)
    return path


# (this small DQN drops the pole within a dozen steps: the doubled pole's episodes outlast its
# calibration episodes, which the monitor rightly warns of)
@pytest.mark.filterwarnings("ignore::oodmon.monitor.monitor.LongerThanCalibrationWarning")
def test_the_policy_gets_the_dict_the_detectors_its_vector_and_the_log_its_picture(model_path, tmp_path):
    agent = load_sb3([model_path], ENV_ID)
    assert agent.estimator is None and agent.own_shape == (4,)  # a plain policy; the detectors read the 4 numbers
    detectors = fit_agent_detectors(agent, episodes=40)
    assert detectors.names == ["dynamics", "drift", "frames", "stillness", "combined"]  # the vector, the picture
    threshold = calibrate_agent(agent, episodes=40, far=0.2, detectors=detectors, confidence=None)
    memory = MemorySink()
    with Monitor(agent, threshold=threshold, detectors=detectors, sinks=[memory, McapSink(tmp_path / "x.mcap")]) as monitor:
        for seed in range(10):  # fresh ID episodes, the pole twice as long from the start, and a snowing camera
            monitor.run_episode(_CameraCartPole(), seed=1000 + seed, variant="cartpole")
        for seed in range(10):
            shifted = _CameraCartPole(parse_variant("cartpole:length=2.0").make())
            monitor.run_episode(shifted, seed=2000 + seed, variant="cartpole:length=2.0")
        for seed in range(10):
            monitor.run_episode(_CameraCartPole(snow=True), seed=3000 + seed, variant="cartpole:snow")
    # The deployed policy acts on the dicts, exactly as SB3's predict() does on them.
    model, env = DQN.load(model_path, device="cpu"), _CameraCartPole()
    obs, _ = env.reset(seed=1000)
    first = [s for s in memory.steps if s.episode == 0]
    assert first[0].observation == pytest.approx(obs["state"].tolist())  # the vector, not the picture
    assert np.array_equal(first[0].frame, obs["camera"][..., 0])  # the picture, as the log's frame
    actions = []
    for _ in first:
        actions.append(int(model.predict(obs, deterministic=True)[0]))
        obs, _, terminated, truncated, _ = env.step(actions[-1])
    assert [s.action for s in first] == actions and (terminated or truncated)
    # The doubled pole is seen in the vector, the snow in the picture: each detector's shifted
    # steps score above the fresh ID steps (from each episode's second step: a transition).
    log = read_log(tmp_path / "x.mcap")

    def auroc(detector: str, variant: str) -> float:
        ours, id_ = ([e.scores_of(detector)[1:] for e in log.episodes if e.variant == v] for v in (variant, "cartpole"))
        return float(np.mean(np.concatenate(ours)[:, None] > np.concatenate(id_)[None, :]))

    # When written (80 ID transitions, 173 of the long pole, 86 of the snow): dynamics 1.000 and
    # 0.458, frames 0.712 and 1.000, combined 1.000 and 1.000.
    assert auroc("dynamics", "cartpole:length=2.0") > 0.9 and auroc("frames", "cartpole:snow") > 0.9
    assert auroc("dynamics", "cartpole:snow") < 0.7  # the physics are ID's: the picture is what shows the snow
    assert min(auroc("combined", v) for v in ("cartpole:length=2.0", "cartpole:snow")) > 0.9
    assert sum(e.alarms > 0 for e in log.episodes if e.variant != "cartpole") >= 16  # 20 of 20 when written


def test_the_cli_calibrates_and_runs_it(model_path, tmp_path, capsys):
    common = ["--sb3", str(model_path), "--env", ENV_ID]
    assert main(["calibrate", *common, "--episodes", "20", "--far", "0.2", "--confidence", "none",
                 "--fit-episodes", "20", "--out", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["detector"] == "combined"
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--episodes", "2",
                 "--mcap", str(tmp_path / "x.mcap")]) == 0
    log = read_log(tmp_path / "x.mcap")
    assert len(log.episodes) == 2 and set(log.detectors) == {"dynamics", "drift", "frames", "stillness", "combined"}


def test_pictures_alone_or_an_ensemble_of_cnns_are_refused_with_what_to_do(model_path):
    if "TwoCamerasForTests-v0" not in gymnasium.registry:
        gymnasium.register("TwoCamerasForTests-v0", entry_point=_TwoCameras)
    pictures_only = DQN("MultiInputPolicy", gymnasium.make("TwoCamerasForTests-v0"), seed=0, learning_starts=10)
    with pytest.raises(ConfigError, match="pictures alone, in a dict.*give the env's picture as its observation"):
        sb3_agent([pictures_only], "TwoCamerasForTests-v0")
    with pytest.raises(ConfigError, match="oodmon samples no CNN.*give the deployed model alone"):
        load_sb3([model_path, model_path], ENV_ID)
    with pytest.raises(ConfigError, match="oodmon samples no CNN"):
        load_sb3([model_path], ENV_ID, masks="fixed")


@pytest.mark.filterwarnings("ignore::oodmon.monitor.sb3_callback.ExplorationWarning")  # (test_sb3_models.py tests it)
def test_the_training_callback_logs_the_pictures_as_the_env_gave_them():
    """Inside ``model.learn``, SB3 hands the callback pictures with their channels first; the
    monitor's agent knows the env's dicts, and the log keeps each picture as the env gave it."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from oodmon.monitor.sb3_callback import MonitorCallback

    if "ColourCameraForTests-v0" not in gymnasium.registry:
        gymnasium.register("ColourCameraForTests-v0", entry_point=_ColourCamera)
    acted: list = []
    model = DQN("MultiInputPolicy", DummyVecEnv([lambda: ActedOn(_ColourCamera(), acted)]), seed=0, learning_starts=30,
                policy_kwargs={"net_arch": [16]})
    assert model.observation_space["camera"].shape == (3, 36, 36)
    agent = sb3_agent([model], "ColourCameraForTests-v0")
    memory = MemorySink()
    with Monitor(agent, threshold=1e9, detectors=fit_agent_detectors(agent, episodes=3), sinks=[memory]) as monitor:
        model.learn(60, callback=MonitorCallback(monitor))
    assert len(memory.steps) == len(acted) == 60
    for step, obs in zip(memory.steps, acted):
        assert np.array_equal(step.frame, obs["camera"]) and step.observation == pytest.approx(obs["state"].tolist())

    acted.clear()  # a monitor with no agent: the whole dict flattened in the env's own space, channels last
    memory = MemorySink()
    flat = gymnasium.wrappers.FlattenObservation(_ColourCamera())  # what a monitor with no agent reads
    flat.action_space.seed(0)
    dynamics = fit_detectors(lambda obs: int(flat.action_space.sample()), flat, detectors=["dynamics"], episodes=3)
    with Monitor(None, threshold=1e9, detectors=dynamics, detector="dynamics", sinks=[memory]) as monitor:
        model.learn(20, callback=MonitorCallback(monitor))
    space = _ColourCamera().observation_space
    assert len(memory.steps) == len(acted) == 20
    for step, obs in zip(memory.steps, acted):
        assert np.array_equal(step.observation, gymnasium.spaces.flatten(space, obs))


def test_its_detectors_are_fitted_on_its_logs_vectors_and_pictures(model_path, tmp_path):
    """Its log holds each step's vector and picture (the camera's frame), what its detectors read:
    they are fitted on it (refused before 2026-12-07), the vector's and the picture's, and the
    frames detector of the log's set tells a snowing camera from fresh ID episodes."""
    from oodmon.monitor.detectors.fitting import fit_recorded_detectors
    from oodmon.replay import fit_detectors_from_logs
    from oodmon.replay.reader import read_steps

    agent = load_sb3([model_path], ENV_ID)
    played = fit_agent_detectors(agent, episodes=15)
    with Monitor(agent, detectors=played, sinks=[McapSink(tmp_path / "id.mcap")]) as monitor:
        for seed in range(30):
            monitor.run_episode(_CameraCartPole(), seed=seed)
    vectors, actions, frames = read_steps(tmp_path / "id.mcap", [0], pictures=True)[0]
    assert vectors.shape[1:] == (4,) and frames.shape[1:] == (36, 36) and len(frames) == len(vectors) == len(actions)
    with pytest.raises(ConfigError, match="a recorded episode holds no frame at each step"):
        fit_recorded_detectors(agent, [(vectors, actions)] * 3)  # (episodes read without their pictures)
    with pytest.raises(ConfigError, match=r"the log's frames are \(9, 9\), the newest of this policy's pictures"):
        fit_recorded_detectors(agent, [(vectors, actions, frames[:, :9, :9])] * 3)
    fitted = fit_detectors_from_logs(agent, [tmp_path / "id.mcap"])
    assert fitted.names == played.names == ["dynamics", "drift", "frames", "stillness", "combined"]
    assert fitted.fitted_for["episodes"] == 30 and fitted.fitted_for["obs_shape"] == [4]
    memory = MemorySink()
    with Monitor(agent, detectors=fitted, sinks=[memory]) as monitor:
        for seed in range(5):
            monitor.run_episode(_CameraCartPole(), seed=500 + seed, variant="cartpole")
            monitor.run_episode(_CameraCartPole(snow=True), seed=600 + seed, variant="cartpole:snow")
    by_variant = {v: np.concatenate([[s.scores["frames"] for s in memory.steps if s.episode == k][1:]
                                     for k in range(10) if (k % 2 == 1) == (v == "snow")]) for v in ("id", "snow")}
    # the snowing steps (past each episode's first) against the fresh ID ones: AUROC 1.000 when
    # written (42 against 44 steps; the lowest snowing step 1.75, the highest ID one 0.65)
    assert np.mean(by_variant["snow"][:, None] > by_variant["id"][None, :]) > 0.9
