"""SB3 models trained inside VecFrameStack: FrameStack stacks one env's observations exactly as
VecFrameStack does, and such a model is refused without --frame-stack (saying so), then fitted,
calibrated, run, evaluated and watched with it, its detectors reading the newest observation of each
stack."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import DQN, TD3
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

import oodmon
from oodmon.agents.frame_stack import FrameStack
from oodmon.agents.sb3 import load_sb3, sb3_agent
from oodmon.cli import main
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor import Monitor
from tests.helpers import NoisePictures


@pytest.mark.parametrize("make, shape", [(lambda: gymnasium.make("CartPole-v1"), (16,)),
                                         (lambda: NoisePictures((20, 24, 3), steps=15), (20, 24, 12))],
                         ids=["vector", "channels-last pictures"])
def test_frame_stack_gives_the_observations_vecframestack_gives(make, shape):
    theirs = VecFrameStack(DummyVecEnv([make]), 4)
    theirs.seed(5)
    ours = FrameStack(make(), 4)
    assert ours.observation_space.shape == theirs.observation_space.shape == shape
    a, (b, _) = theirs.reset()[0], ours.reset(seed=5)
    compared, ends = [np.array_equal(a, b)], 0
    rng = np.random.default_rng(0)
    for _ in range(80):  # several episodes: the stack starts again from zeros after each end
        action = int(rng.integers(2))
        a, _, done, info = theirs.step([action])
        b, _, terminated, truncated, _ = ours.step(action)
        if terminated or truncated:
            ends += 1
            compared.append(np.array_equal(info[0]["terminal_observation"], b))
            b, _ = ours.reset()
        compared.append(np.array_equal(a[0], b))
    assert ends >= 2 and all(compared) and len(compared) == 81 + ends
    b, _ = ours.reset(seed=1)
    own = shape[-1] // 4  # one observation's numbers (channels) along the stacked axis
    assert not b[..., :-own].any() and b[..., -own:].any()  # zeros before an episode's first observation
    with pytest.raises(InvalidParameterError, match="frame_stack=1 is not allowed"):
        FrameStack(make(), 1)


def test_a_td3_trained_inside_vecframestack_is_refused_without_it_then_watched_with_it(tmp_path, capsys):
    model = TD3("MlpPolicy", VecFrameStack(DummyVecEnv([lambda: gymnasium.make("Pendulum-v1")]), 3), seed=0,
                learning_starts=200, policy_kwargs={"net_arch": [32, 32]})
    model.learn(400)
    model.save(tmp_path / "td3.zip")
    common = ["--sb3", str(tmp_path / "td3.zip"), "--env", "Pendulum-v1"]
    out = ["--out", str(tmp_path / "t.json")]
    assert main(["calibrate", *common, *out]) == 2  # it failed inside SB3's predict, or acted on another shape
    assert "Or trained inside VecFrameStack(3)? Give --frame-stack 3" in capsys.readouterr().err
    common += ["--frame-stack", "3"]
    assert main(["calibrate", *common, "--episodes", "4", "--far", "0.2", "--confidence", "none",
                 "--fit-episodes", "9", *out]) == 0
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--variant", "pendulum:m=5.0", "--onset", "50",
                 "--episodes", "2", "--mcap", str(tmp_path / "x.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "x.mcap"), "--json"]) == 0
    rows = {r["detector"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["dynamics"]["auroc"] > 0.9  # 1.000 when written: the stacked observations are modelled
    log = oodmon.replay.read_log(tmp_path / "x.mcap")
    assert log.metadata["about.frame_stack"] == "3"  # the log says how the model saw the env
    assert main(["evaluate", *common, "--variants", "pendulum:m=5.0", "--episodes", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["variants"][0]["variant"] == "pendulum:m=5.0"
    # The monitor's benchmark stacks too: ID, fitting, calibration and the shifted cells (pendulum
    # episodes last 200 steps whatever the policy: the heavier pendulum is alarmed on).
    capsys.readouterr()
    assert main(["bench", *common, "--protocol", "monitor", "--variants", "pendulum:m=5.0", "--all-variants",
                 "--episodes", "2", "--id-episodes", "5", "--calibration-episodes", "4", "--far", "0.2",
                 "--confidence", "none", "--fit-episodes", "9", "--workers", "1", "--out", str(tmp_path / "b"),
                 "--json"]) == 0
    alarms = {r["variant"]: r for r in json.loads(capsys.readouterr().out)["alarms"] if r["method"] == "sb3"}
    assert alarms["pendulum:m=5.0"]["episodes"] == 2 and alarms["pendulum:m=5.0"]["alarmed"] >= 1  # 2 of 2 when written
    from oodmon.bench.cache import Sb3Models, _weights_sha256

    paths = (str(tmp_path / "td3.zip"),)  # the bench's cache tells the stacked model from the same file unstacked
    assert _weights_sha256(Sb3Models(paths, "Pendulum-v1", frame_stack=3)) != _weights_sha256(Sb3Models(paths, "Pendulum-v1"))
    assert main(["calibrate", "--task", "pendulum", "--method", "ensemble", "--frame-stack", "3", *out]) == 2
    assert "--frame-stack and --vec-normalize go with --sb3" in capsys.readouterr().err

    # Python: the env the user steps must give stacked observations; FrameStack makes them.
    agent = load_sb3([tmp_path / "td3.zip"], "Pendulum-v1", frame_stack=3)
    assert agent.make_env().observation_space.shape == (9,)
    assert sb3_agent([model], "Pendulum-v1").frame_stack == 3  # in memory: the VecFrameStack it was trained in
    with pytest.raises(ConfigError, match=r"stacked 3 deep: wrap the env you step in .*FrameStack\(env, 3\)"):
        oodmon.watch(agent, env=gymnasium.make("Pendulum-v1"), episodes=22, far=0.1, fit_episodes=5)
    env = oodmon.watch(agent, env=FrameStack(gymnasium.make("Pendulum-v1"), 3), episodes=3, far=0.5, confidence=None,
                       fit_episodes=5)
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        acted_on = obs
        obs, *_, info = env.step(model.predict(obs, deterministic=True)[0])
    assert obs.shape == (9,) and np.isfinite(info["oodmon"]["score"])
    # The detectors and the log read the env's own observation, the newest of the stack acted on.
    assert env.monitor.last_step.observation == pytest.approx(acted_on[-3:].tolist())
    assert env.monitor.detectors.fitted_for["obs_shape"] == [3]


def test_a_cnn_policy_on_stacked_rgb_pictures_logs_the_newest_picture(tmp_path):
    """VecFrameStack(2) of RGB pictures gives 6 channels, which SB3 moves first ((6, 36, 36)): it was
    refused as "a model of another env?" (only 1, 3 or 4 channels were recognised as moved). The
    frames detector and the log read the newest RGB picture, not the stack's last channel."""
    from stable_baselines3 import PPO

    from oodmon.monitor import MemorySink, Monitor
    from oodmon.monitor.detectors import fit_detectors

    if "StackedPicturesForTests-v0" not in gymnasium.registry:
        gymnasium.register("StackedPicturesForTests-v0", entry_point=lambda: NoisePictures((36, 36, 3), steps=6))
    venv = VecFrameStack(DummyVecEnv([lambda: gymnasium.make("StackedPicturesForTests-v0")]), 2)
    model = PPO("CnnPolicy", venv, seed=0, n_steps=16, batch_size=16)
    assert model.observation_space.shape == (6, 36, 36)
    agent = sb3_agent([model], "StackedPicturesForTests-v0", frame_stack=2)
    env = agent.make_env()
    detectors = fit_detectors(agent, env, detectors=["frames"], episodes=3)
    assert detectors.fitted_for["obs_shape"] == [36, 36, 3]
    sink = MemorySink()
    with Monitor(agent, 100.0, detectors=detectors, detector="frames", sinks=[sink]) as monitor:
        monitor.run_episode(env, seed=1)
    obs, _ = env.reset(seed=1)  # the same episode's first stack: zeros, then the first picture
    assert sink.steps[0].frame.shape == (36, 36, 3) and np.array_equal(sink.steps[0].frame, obs[..., 3:])
    # its log's pictures, the newest of each stack, fit its frames detector (refused before
    # 2026-12-07), for the shape the monitor checks, which then watches with it
    from oodmon.monitor import McapSink
    from oodmon.replay import fit_detectors_from_logs

    logging = McapSink(tmp_path / "x.mcap")
    with Monitor(agent, 100.0, detectors=detectors, detector="frames", sinks=[logging]) as monitor:
        for seed in range(4):
            monitor.run_episode(env, seed=seed)
    logged = fit_detectors_from_logs(agent, [tmp_path / "x.mcap"], detectors=["frames"])
    assert logged.names == ["frames"] and logged.fitted_for["obs_shape"] == [36, 36, 3]
    with Monitor(agent, 100.0, detectors=logged, detector="frames") as monitor:
        assert monitor.run_episode(env, seed=9).length == 6


class _Parts(gymnasium.ObservationWrapper):
    """CartPole's observation as a dict of two vectors, named so that the keys sort the other way
    round ("pole": theta, theta'; "cart": x, x')."""

    def __init__(self) -> None:
        super().__init__(gymnasium.make("CartPole-v1"))
        box = self.env.observation_space
        self.observation_space = gymnasium.spaces.Dict({"pole": gymnasium.spaces.Box(box.low[2:], box.high[2:]),
                                                        "cart": gymnasium.spaces.Box(box.low[:2], box.high[:2])})

    def observation(self, obs):
        return {"cart": obs[:2].astype(np.float32), "pole": obs[2:].astype(np.float32)}


if "PartsCartPoleForFrameStack-v1" not in gymnasium.registry:
    gymnasium.register("PartsCartPoleForFrameStack-v1", entry_point=_Parts, max_episode_steps=500)


def test_dicts_are_stacked_key_by_key_as_vecframestack_stacks_them_and_read_flattened(tmp_path):
    env_id = "PartsCartPoleForFrameStack-v1"
    theirs = VecFrameStack(DummyVecEnv([lambda: gymnasium.make(env_id)]), 3)
    theirs.seed(5)
    ours = FrameStack(gymnasium.make(env_id), 3)
    assert ours.observation_space == theirs.observation_space
    a, (b, _) = theirs.reset(), ours.reset(seed=5)
    same = [all(np.array_equal(a[k][0], b[k]) for k in b)]
    rng, ends = np.random.default_rng(0), 0
    for _ in range(60):
        action = int(rng.integers(2))
        a, _, _, _ = theirs.step([action])
        b, _, terminated, truncated, _ = ours.step(action)
        if terminated or truncated:
            ends, (b, _) = ends + 1, ours.reset()
        same.append(all(np.array_equal(a[k][0], b[k]) for k in b))
    assert ends >= 2 and all(same)
    # Two MultiInput DQNs trained inside that VecFrameStack: their samples are their Q-values at the
    # stacked dict; the detectors and the log read the env's own newest dict, flattened.
    models = [DQN("MultiInputPolicy", theirs, seed=k, policy_kwargs={"net_arch": [16]}) for k in range(2)]
    agent = sb3_agent(models, env_id)  # in memory: the VecFrameStack they were trained in
    assert agent.frame_stack == 3 and agent.stacking.own_shape == (4,)
    env, own = agent.make_env(), gymnasium.make(env_id)
    flat, _ = env.reset(seed=3)
    own_obs, _ = own.reset(seed=3)
    for _ in range(12):
        stacked = gymnasium.spaces.unflatten(agent.dict_space, flat)
        with torch.no_grad():
            q = [m.q_net(m.policy.obs_to_tensor(stacked)[0])[0].numpy() for m in models]
        np.testing.assert_allclose(agent.estimate(flat).samples[:, 0], q, rtol=1e-5, atol=1e-6)
        assert agent.act(flat) == int(models[0].predict(stacked, deterministic=True)[0])
        np.testing.assert_array_equal(agent.own_observation(flat), gymnasium.spaces.flatten(own.observation_space, own_obs))
        action = agent.act(flat)
        flat, _, terminated, *_ = env.step(action)
        own_obs, *_ = own.step(action)
        if terminated:
            break
    # A file of such a model without --frame-stack: refused, the depth named (a dict's keys, each
    # another shape than the env's, were taken for the env's: SB3 failed inside predict()).
    models[0].save(tmp_path / "dqn.zip")
    with pytest.raises(ConfigError, match=r"Or trained inside VecFrameStack\(3\)\? Give --frame-stack 3"):
        load_sb3([tmp_path / "dqn.zip"], env_id)
    assert load_sb3([tmp_path / "dqn.zip"], env_id, frame_stack=3).stacking.own_shape == (4,)
    from oodmon.monitor import McapSink
    from oodmon.replay import fit_detectors_from_logs

    steps = 0
    with Monitor(agent, sinks=[McapSink(tmp_path / "x.mcap")]) as monitor:
        for seed in range(3):
            steps += monitor.run_episode(agent.make_env(), seed=seed).length
    assert steps >= 12 and len(monitor.last_step.observation) == 4  # the own dict, flattened
    # its log's newest dicts, flattened, rebuild the stacks of dicts the DQNs acted on (refused
    # before 2026-12-07): their spread there is the one the run logged, to the bit; fitted on them
    for _, logged, at in _spreads_at_rebuilt_stacks(agent, tmp_path / "x.mcap"):
        assert np.array_equal(at(None), logged[:-1])
    fitted = fit_detectors_from_logs(agent, [tmp_path / "x.mcap"], dynamics_updates=20)
    assert "features" in fitted.names and fitted.fitted_for["obs_shape"] == [4]


def test_a_model_trained_normalised_then_stacked_sees_what_vecframestack_of_vecnormalize_gave_it(tmp_path, capsys):
    """rl-baselines3-zoo's order, VecFrameStack(VecNormalize(venv)): each observation normalised,
    then stacked, normalised zeros before an episode's first. Its statistics are of one observation
    (the other order's are of the stack); such a model was refused as having "statistics of another
    env". Now FrameStack stands the statistics' mean before the first observation, and the agent
    normalises each observation of the stack with them. (SB3's DQN and TD3 cannot learn in this
    order, their buffers store VecNormalize's unstacked observations: a PPO learns here, and two
    DQNs built on the same env stand for an ensemble, untrained.)"""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from oodmon.agents.vec_normalize import ObservationNormalizer
    from oodmon.monitor import MonitoredEnv
    from oodmon.replay import read_log

    normalised = VecNormalize(DummyVecEnv([lambda: gymnasium.make("CartPole-v1")]), norm_reward=False)
    stacked = VecFrameStack(normalised, 3)
    ppo = PPO("MlpPolicy", stacked, n_steps=128, batch_size=64, n_epochs=2, seed=0, policy_kwargs={"net_arch": [32]})
    ppo.learn(256)  # the statistics move away from (0, 1) as it learns
    assert np.abs(normalised.obs_rms.mean).max() > 0.01
    normalised.save(tmp_path / "vecnormalize.pkl")
    models = [DQN("MlpPolicy", stacked, seed=k, policy_kwargs={"net_arch": [32]}) for k in range(2)]
    paths = [tmp_path / f"dqn{k}.zip" for k in range(2)]
    for model, path in zip([*models, ppo], [*paths, tmp_path / "ppo.zip"]):
        model.save(path)
    statistics = {"vec_normalize": tmp_path / "vecnormalize.pkl", "frame_stack": 3}
    agent, deployed = load_sb3(paths, "CartPole-v1", **statistics), load_sb3([tmp_path / "ppo.zip"], "CartPole-v1", **statistics)
    assert agent.metadata["vec_normalize"]["normalised_then_stacked"] == 3
    in_memory = sb3_agent([ppo], "CartPole-v1")  # the VecFrameStack and VecNormalize it learned in
    assert in_memory.frame_stack == 3 and in_memory.metadata["vec_normalize"]["normalised_then_stacked"] == 3
    venv = DummyVecEnv([lambda: gymnasium.make("CartPole-v1")])
    theirs = VecFrameStack(VecNormalize.load(tmp_path / "vecnormalize.pkl", venv), 3)
    theirs.venv.training = False
    theirs.seed(5)
    a, ours = theirs.reset()[0], agent.make_env()
    b, _ = ours.reset(seed=5)
    assert not a[:8].any()  # VecFrameStack's zeros before the first observation, which ours make of the mean
    ends = 0
    for _ in range(300):  # several episodes: the stack starts again after each end
        np.testing.assert_allclose(agent.estimator.observation_transform(b[None])[0], a, rtol=1e-6, atol=1e-7)
        with torch.no_grad():
            q = [m.q_net(m.policy.obs_to_tensor(a)[0])[0].numpy() for m in models]
        np.testing.assert_allclose(agent.estimate(b).samples[:, 0], q, rtol=1e-5, atol=1e-6)
        assert agent.act(b) == int(models[0].predict(a, deterministic=True)[0])
        action = deployed.act(b)
        assert action == int(ppo.predict(a, deterministic=True)[0])
        a, _, done, _ = theirs.step([action])
        a = a[0]
        b, _, terminated, truncated, _ = ours.step(action)
        if terminated or truncated:
            ends, (b, _) = ends + 1, ours.reset()
    assert ends >= 2
    # An env stacked without the mean in front would give the model other first observations: refused.
    with pytest.raises(ConfigError, match=r"VecFrameStack\(VecNormalize\(env\), 3\).*agent.wrap\(env\).*"
                                          r"MonitoredEnv\(monitor.agent.wrap\(env\), monitor\)"):
        MonitoredEnv(FrameStack(gymnasium.make("CartPole-v1"), 3), Monitor(agent))
    with pytest.raises(ConfigError, match=r"stacked 3 deep: wrap the env you step in agent.wrap\(env\)"):
        MonitoredEnv(gymnasium.make("CartPole-v1"), Monitor(agent))  # not stacked at all
    MonitoredEnv(agent.wrap(gymnasium.make("CartPole-v1")), Monitor(agent))
    # The command line: calibrated, run and logged.
    common = ["--sb3", str(tmp_path / "ppo.zip"), "--env", "CartPole-v1", "--vec-normalize",
              str(tmp_path / "vecnormalize.pkl"), "--frame-stack", "3"]
    assert main(["calibrate", *common, "--episodes", "10", "--far", "0.2", "--confidence", "none", "--fit-episodes", "9",
                 "--out", str(tmp_path / "t.json")]) == 0
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--episodes", "2", "--mcap",
                 str(tmp_path / "x.mcap")]) == 0
    log = read_log(tmp_path / "x.mcap")
    assert len(log.episodes) == 2 and json.loads(log.metadata["about.vec_normalize"])["normalised_then_stacked"] == 3
    # their log's observations rebuild the stacks the two DQNs acted on, the mean before the first:
    # their spread there is the one the run logged, to the bit
    ensemble = ["--sb3", *map(str, paths), *common[2:]]
    for observations, logged, at in _spreads_at_rebuilt_stacks(agent, _logged_run(ensemble, tmp_path / "e.mcap", 3)):
        assert len(logged) >= 8 and np.array_equal(at(None), logged[:-1])
    capsys.readouterr()
    with pytest.raises(ConfigError, match="stacks normalised observations .* of vector envs only"):
        ObservationNormalizer(None, None, keys={"state": (np.zeros(4), np.ones(4))}).stacked(3)


def test_a_model_trained_stacked_then_normalised_has_statistics_of_the_stack_and_no_pad(tmp_path):
    """The other order, VecNormalize(VecFrameStack(venv)): statistics of the whole stack, which
    normalise it as one vector, zeros (raw) before an episode's first observation. Told apart from
    rl-baselines3-zoo's order by the statistics' shape."""
    from stable_baselines3.common.vec_env import VecNormalize

    theirs = VecNormalize(VecFrameStack(DummyVecEnv([lambda: gymnasium.make("CartPole-v1")]), 3), norm_reward=False)
    theirs.seed(0)
    theirs.reset()
    rng = np.random.default_rng(0)
    for _ in range(300):  # the statistics move away from (0, 1)
        theirs.step([int(rng.integers(2))])
    assert theirs.obs_rms.mean.shape == (12,) and np.abs(theirs.obs_rms.mean).max() > 0.01
    theirs.save(tmp_path / "vecnormalize.pkl")
    models = [DQN("MlpPolicy", theirs, seed=k, policy_kwargs={"net_arch": [32]}) for k in range(2)]
    agent = sb3_agent(models, "CartPole-v1", vec_normalize=tmp_path / "vecnormalize.pkl", frame_stack=3)
    assert agent.stacking.pad is None and "normalised_then_stacked" not in agent.metadata["vec_normalize"]
    theirs.training = False
    theirs.seed(5)
    a, ours = theirs.reset()[0], agent.make_env()
    b, _ = ours.reset(seed=5)
    for _ in range(60):
        np.testing.assert_allclose(agent.estimator.observation_transform(b[None])[0], a, rtol=1e-6, atol=1e-7)
        with torch.no_grad():
            q = [m.q_net(m.policy.obs_to_tensor(a)[0])[0].numpy() for m in models]
        np.testing.assert_allclose(agent.estimate(b).samples[:, 0], q, rtol=1e-5, atol=1e-6)
        action = agent.act(b)
        a = theirs.step([action])[0][0]
        b, _, terminated, truncated, _ = ours.step(action)
        if terminated or truncated:
            b, _ = ours.reset()


def test_a_stacked_ensembles_detectors_are_fitted_on_its_logs_asking_it_at_the_stacks_rebuilt(tmp_path):
    """Two DQNs made inside VecFrameStack(4), watched as an ensemble: their log holds each step's
    newest observation, what the detectors read, so their detectors are fitted on it (before
    2026-12-07 refused), and the stacks the models acted on are rebuilt from it, zeros before an
    episode's first observation, as VecFrameStack stacks them: the models' spread at each rebuilt
    stack is the one the run logged, to the bit; at the logged observations repeated (a stack
    filled by its first, as oodmon's Pong fills its own) it is not."""
    from oodmon.monitor.detectors.fitting import stacks_from_frames
    from oodmon.replay import fit_detectors_from_logs

    files = [str(tmp_path / f"dqn{seed}.zip") for seed in (0, 1)]
    for seed, path in enumerate(files):  # (untrained: the stacks are what this is about)
        DQN("MlpPolicy", VecFrameStack(DummyVecEnv([lambda: gymnasium.make("CartPole-v1")]), 4), seed=seed,
            policy_kwargs={"net_arch": [16]}).save(path)
    args = ["--sb3", *files, "--env", "CartPole-v1", "--frame-stack", "4"]
    agent, log = load_sb3(files, "CartPole-v1", frame_stack=4), tmp_path / "id.mcap"
    reports = []
    fitted = fit_detectors_from_logs(agent, [_logged_run(args, log, 9)], on_progress=lambda *r: reports.append(r))
    assert fitted.names == ["spread", "dynamics", "features", "combined"] and fitted.fitted_for["obs_shape"] == [4]
    asked = [r for r in reports if r[0] == "the policy asked at each step: logged episodes"]  # (unit: episodes)
    assert asked == [(asked[0][0], k, 9) for k in range(1, 10)]
    filled = 0
    for observations, logged, at in _spreads_at_rebuilt_stacks(agent, log):
        assert len(observations) == len(logged) >= 8 and np.array_equal(at(None), logged[:-1])
        first_filled = np.stack([s.reshape(-1) for s in stacks_from_frames(observations[:, None], 4)])
        filled += not np.array_equal(at(first_filled)[:3], logged[:3])
    assert filled == 9


def _logged_run(args: list[str], log, episodes: int):
    """``log``, written by ``oodmon run ARGS`` of ``episodes`` ID episodes."""
    from tests.helpers import run_cli

    done = run_cli("run", *args, "--episodes", str(episodes), "--seed", "3", "--mcap", str(log))
    assert done.returncode == 0, done.stderr
    return log


def _spreads_at_rebuilt_stacks(agent, log):
    """Each episode of ``log``: its logged observations, its logged spread, and the spread of
    ``agent`` at each step's stack (those given, else those rebuilt from the observations), but the
    last (the log holds the observations acted on, not the one after the last action)."""
    from oodmon.monitor.detectors import DetectorSet
    from oodmon.monitor.detectors.base import Trajectory
    from oodmon.monitor.detectors.fitting import acted_on_rebuilt, trajectory_scores
    from oodmon.monitor.detectors.spread import SpreadDetector
    from oodmon.replay import read_log
    from oodmon.replay.reader import read_steps

    read = read_log(log)
    steps = read_steps(log, range(len(read.episodes)))
    env = agent.make_env(0.0)
    rebuild = acted_on_rebuilt(agent, env)
    env.close()
    spread = DetectorSet([SpreadDetector(read.metadata["score"])])
    for k, episode in enumerate(read.episodes):
        observations, actions = steps[k]

        def at(stacks, observations=observations, actions=actions):
            stacks = np.stack(list(rebuild(observations))) if stacks is None else stacks
            trajectory = Trajectory(observations, actions[:-1], acted_on=stacks)
            return trajectory_scores(spread, trajectory, agent.estimator)["spread"]
        yield observations, episode.detector_scores["spread"], at
