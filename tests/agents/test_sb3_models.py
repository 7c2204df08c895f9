"""Your own SB3 policy: docs/your-policy.md's "Monitor your own SB3 policy" section run as written, the
deployed returns equal SB3's own, and a TD3 on Pendulum-v1 watched by the dynamics detector."""

from __future__ import annotations

import json
import re
import shlex
import sys
import zipfile
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import DQN, TD3
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv

from oodmon.agents.sb3 import load_sb3, sb3_agent, sb3_algorithm
from oodmon.cli import main
from oodmon.errors import ConfigError
from oodmon.monitor import MemorySink, Monitor, MonitoredEnv
from oodmon.monitor.detectors import DetectorSet
from oodmon.replay import read_log, read_logs
from tests.helpers import ActedOn, NoisePictures, saved_ensemble_acts_as_its_members

PAGE = Path(__file__).resolve().parents[2] / "docs" / "your-policy.md"


def _section_blocks() -> tuple[str, list[list[str]], str]:
    """The section's Python snippet, its oodmon commands (continuation lines joined) and the
    deployed process's Python block after them."""
    text = PAGE.read_text()
    section = text[text.index("## Monitor your own SB3 policy"):]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    python = re.search(r'\.venv/bin/python -c "\n(.*?)\n"\n', block, re.S).group(1)
    commands = block[block.index('\n"\n') + 3:].replace("\\\n", " ")
    deployed = re.search(r"```python\n(.*?)```", section[section.index(block):], re.S).group(1)
    return python, [shlex.split(line)[1:] for line in commands.splitlines() if line.startswith("oodmon ")], deployed


@pytest.fixture(scope="module", autouse=True)
def one_torch_thread():
    """Small networks: one thread is fastest (and 3x faster than two beside another job)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def readme_run(one_torch_thread, tmp_path_factory):
    """The section's snippet and commands, run in a fresh folder; the models and the outputs."""
    folder = tmp_path_factory.mktemp("sb3")
    (folder / "runs").mkdir()
    python, commands, _ = _section_blocks()
    outputs = []
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        exec(compile(python, "docs snippet", "exec"), {})
        for argv in commands:
            outputs.append((argv, main(argv)))
    return folder, commands, outputs


def test_the_docs_section_runs_as_written_and_replay_shows_the_detection(readme_run, capsys):
    folder, commands, outputs = readme_run
    assert [argv[0] for argv in commands] == ["calibrate", "validate", "run", "replay"]
    assert all(code == 0 for _, code in outputs), outputs
    threshold = json.loads((folder / "runs/dqn.json").read_text())
    assert threshold["task"] == "cartpole" and threshold["method"] == "sb3" and threshold["detector"] == "combined"
    assert main(["replay", str(folder / "runs/dqn.mcap"), "--json"]) == 0
    rows = {(r["variant"], r["detector"]): r for r in json.loads(capsys.readouterr().out)}
    assert set(rows) >= {("cartpole:length=2.0", "dynamics"), ("cartpole:length=2.0", "combined")}
    assert rows[("cartpole:length=2.0", "dynamics")]["auroc"] > 0.9  # 1.000 when written
    assert rows[("cartpole:length=2.0", "combined")]["detection_rate"] >= 0.8  # 5 of 5 when written


def test_a_threshold_names_its_model_files_where_other_models_or_none_are_given(readme_run, capsys):
    """Models given in another order, or some of them, were refused as "other weights" by hash
    alone, and a validate without --sb3 said "--sb3 ZIP" (2026-12-07): the threshold records its
    model files, in order, and the refusals name them."""
    from oodmon.hashing import file_sha256

    folder, _, _ = readme_run
    first, second = (str((folder / f"runs/dqn{seed}.zip").resolve()) for seed in (0, 1))
    threshold = str(folder / "runs/dqn.json")
    assert json.loads(Path(threshold).read_text())["models"] == [
        {"path": path, "sha256": file_sha256(path)} for path in (first, second)]
    run = ["run", "--env", "CartPole-v1", "--threshold", threshold, "--episodes", "1"]
    assert main([*run, "--sb3", second, first]) == 2
    assert (f"these are its model files in another order (the first acts): give them in its order, --sb3 {first} "
            f"{second}") in capsys.readouterr().err
    assert main([*run, "--sb3", first]) == 2
    assert f"it was calibrated on 2 model files: --sb3 {first} {second}" in capsys.readouterr().err
    # an old threshold, which records no models, asks for them again
    old = folder / "runs/old.json"
    old.write_text(json.dumps({k: v for k, v in json.loads(Path(threshold).read_text()).items()
                               if k not in ("models", "sb3")}))
    assert main(["validate", str(old)]) == 2
    assert f"{old} was calibrated on your own SB3 model(s) in CartPole-v1: give them again, --sb3 ZIP --env " \
           "CartPole-v1" in capsys.readouterr().err.replace("\n", " ")
    # so do the detectors calibrate fitted beside it (their refusal named no file before)
    assert DetectorSet.load(f"{threshold}.detectors").fitted_for["models"] == json.loads(
        Path(threshold).read_text())["models"]
    assert main(["calibrate", "--sb3", second, first, "--env", "CartPole-v1", "--detectors", f"{threshold}.detectors",
                 "--out", str(folder / "runs/other.json")]) == 2
    assert (f"the detectors were fitted on another policy's episodes (its weights, or a plain policy's name or code, "
            f"differ): on those of 2 model files, --sb3 {first} {second}") in capsys.readouterr().err


def test_a_threshold_alone_loads_the_models_it_was_calibrated_on_as_they_were_loaded(readme_run, tmp_path, capsys):
    """`oodmon run --threshold T` and `validate T` of a threshold calibrated on SB3 models asked
    for `--sb3 ... --env ...` again (2026-12-07): the threshold records the files and how they were
    loaded, and the two load them again and say so (the docs section's validate and run do: the
    first test), from beside the threshold where they moved with it. A file gone, a contradicting
    --env and a model trained again into its file are refused in words that say which."""
    import shutil

    from oodmon.monitor import Threshold
    from oodmon.replay import calibrate_from_logs

    folder, _, _ = readme_run
    first, second = (str((folder / f"runs/dqn{seed}.zip").resolve()) for seed in (0, 1))
    threshold = str(folder / "runs/dqn.json")
    assert Threshold.load(threshold).sb3 == {"env_id": "CartPole-v1", "vec_normalize": None, "frame_stack": None,
                                             "mean": False}
    log = tmp_path / "id.mcap"
    assert main(["run", "--threshold", threshold, "--episodes", "4", "--seed", "5000", "--max-steps", "60",
                 "--mcap", str(log)]) == 0
    out = capsys.readouterr()
    assert f"note: the policy {threshold} was calibrated on: --sb3 {first} {second} --env CartPole-v1" in \
           out.err.replace("\n", " ")
    assert "cartpole/sb3" in out.out
    # a threshold recalibrated on the logs of that run records the same (the log's about)
    assert calibrate_from_logs([log], far=0.5, confidence=None).sb3 == Threshold.load(threshold).sb3
    assert main(["run", "--threshold", threshold, "--env", "Pendulum-v1"]) == 2
    assert f"{threshold} was calibrated on SB3 models in CartPole-v1, not --env Pendulum-v1" in capsys.readouterr().err
    # in Python too: oodmon.watch(threshold=...) without the policy
    import gymnasium

    import oodmon

    env = oodmon.watch(threshold=threshold, env=gymnasium.make("CartPole-v1"))
    assert [model["path"] for model in env.monitor.agent.metadata["models"]] == [first, second]
    env.reset(seed=5000)
    assert env.step()[4]["oodmon"]["threshold"] == Threshold.load(threshold).value
    env.close()
    with pytest.raises(ConfigError, match="calibrated on SB3 models in CartPole-v1, not Pendulum-v1"):
        oodmon.watch(threshold=threshold, env_id="Pendulum-v1")
    with pytest.raises(ConfigError, match="give the policy to watch"):
        oodmon.watch()
    # moved with its models: they are found beside it (of the recorded bytes), and said
    moved = tmp_path / "moved"
    shutil.copytree(folder / "runs", moved, ignore=shutil.ignore_patterns("*.mcap", "deployed"))
    data = json.loads((moved / "dqn.json").read_text())
    data["models"] = [{**model, "path": str(tmp_path / "gone" / Path(model["path"]).name)} for model in data["models"]]
    (moved / "dqn.json").write_text(json.dumps(data))
    assert main(["validate", str(moved / "dqn.json"), "--episodes", "2"]) == 0
    said = capsys.readouterr()
    assert f"--sb3 {moved / 'dqn0.zip'} {moved / 'dqn1.zip'} --env CartPole-v1" in said.err.replace("\n", " ")
    assert re.search(r"cartpole/sb3, combined detector, .*: \d of 2 fresh ID episodes alarmed", said.out)
    shutil.copy(moved / "dqn1.zip", moved / "dqn0.zip")  # a file of that name beside it, of other bytes: not it
    assert main(["validate", str(moved / "dqn.json"), "--episodes", "1"]) == 2
    assert f"loaded from files that are neither there nor beside it: {tmp_path / 'gone' / 'dqn0.zip'}; give them " \
           "where they are now, --sb3 ZIP... --env CartPole-v1" in capsys.readouterr().err.replace("\n", " ")
    with pytest.raises(ConfigError, match=f"neither there nor beside it: {tmp_path / 'gone' / 'dqn0.zip'}; give them"):
        oodmon.watch(threshold=moved / "dqn.json")
    # another model saved into the first file since, where the threshold names it
    data["models"] = [{**model, "path": str(moved / Path(model["path"]).name)} for model in data["models"]]
    (moved / "dqn.json").write_text(json.dumps(data))
    assert main(["validate", str(moved / "dqn.json"), "--episodes", "1"]) == 2
    assert f"its model files ({moved / 'dqn0.zip'} {moved / 'dqn1.zip'}) changed since it was calibrated: other " \
           "bytes at the same path" in capsys.readouterr().err.replace("\n", " ")


def test_the_docs_deployed_process_reads_the_calibration_and_logs_split(readme_run, monkeypatch, capsys):
    """The page's deployed-process block, run as written after the section's commands: no
    episode of calibration, one monitored episode, a split log that replays."""
    import oodmon.monitor.calibration as calibration

    folder, _, _ = readme_run
    monkeypatch.chdir(folder)
    monkeypatch.setattr(calibration, "calibrate_agent", None)  # it must not calibrate: calling it would fail
    exec(compile(_section_blocks()[2], "docs deployed block", "exec"), {})
    parts = sorted((folder / "runs/deployed").glob("log-*.mcap"))
    assert len(parts) == 1 and re.fullmatch(r"log-\d{8}-\d{6}-00000\.mcap", parts[0].name)  # named by its start
    log = read_log(parts[0])
    (episode,) = log.episodes  # 139 steps when written (these 4,000-step DQNs do not solve the task)
    assert log.complete and episode.env_id == "CartPole-v1" and episode.total_return == episode.length > 20
    assert log.threshold == json.loads((folder / "runs/dqn.json").read_text())["value"]
    # the callback is told of each alarm the log records, at its step. Whether this one ID episode
    # alarms is chance (the threshold bounds the rate over episodes: validate's 100, above; this
    # seed-0 episode alarmed at step 135 of 139 on 2026-11-29, not before)
    printed = re.findall(r"OOD alarm: episode (\d+) step (\d+)", capsys.readouterr().out)
    assert len(printed) == episode.alarms and episode.alarm.any() == bool(printed)
    if printed:
        assert int(printed[0][1]) == episode.first_alarm_step and episode.alarm[episode.first_alarm_step]


def test_the_log_records_the_models_files_env_and_command(readme_run):
    folder, _, _ = readme_run
    log = read_log(folder / "runs/dqn.mcap")
    models = json.loads(log.metadata["about.models"])
    assert [Path(m["path"]).name for m in models] == ["dqn0.zip", "dqn1.zip"]
    assert all(len(m["sha256"]) == 64 and m["algorithm"] == "DQN" for m in models)
    assert log.metadata["about.env_id"] == "CartPole-v1"
    assert log.metadata["about.command"] == shlex.join(sys.argv)  # this process's command line (here pytest's)
    from oodmon.versions import machine

    assert log.metadata["about.machine"] == machine()  # the CPU kind, whose float kernels round the numbers
    assert log.task == "cartpole" and log.method == "sb3"


def test_the_deployed_returns_are_the_first_models_evaluate_policy_returns(readme_run):
    folder, _, _ = readme_run
    paths = [folder / "runs/dqn0.zip", folder / "runs/dqn1.zip"]
    agent = load_sb3(paths, "CartPole-v1")
    model = DQN.load(paths[0], device="cpu")
    env = gymnasium.make("CartPole-v1")
    with Monitor(agent) as monitor:  # the ensemble's spread scores; the first model acts
        ours = [monitor.run_episode(env, seed=seed).total_return for seed in range(3)]
    theirs = []
    for seed in range(3):
        vec = DummyVecEnv([lambda: gymnasium.make("CartPole-v1")])
        vec.seed(seed)
        theirs.append(evaluate_policy(model, vec, n_eval_episodes=1, deterministic=True, warn=False)[0])
    assert ours == theirs
    mean = load_sb3(paths, "CartPole-v1", mean=True)
    obs = np.zeros(4, np.float32)
    assert mean.act(obs) == int(mean.estimate(obs).action[0])  # --mean: the ensemble decides


def test_a_td3_on_pendulum_is_watched_by_the_dynamics_detector(tmp_path, capsys):
    model = TD3("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=0, learning_starts=200,
                policy_kwargs={"net_arch": [32, 32]})
    model.learn(400)
    model.save(tmp_path / "td3.zip")
    assert sb3_algorithm(tmp_path / "td3.zip") == ("TD3", "DDPG")
    common = ["--sb3", str(tmp_path / "td3.zip"), "--env", "Pendulum-v1"]
    assert main(["calibrate", *common, "--episodes", "10", "--far", "0.2", "--confidence", "none",
                 "--fit-episodes", "9", "--out", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["detector"] == "dynamics"  # a plain policy: no spread
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--variant", "pendulum:m=5.0", "--onset", "50",
                 "--episodes", "2", "--mcap", str(tmp_path / "x.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "x.mcap"), "--json"]) == 0
    rows = {r["detector"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(rows) == {"dynamics", "combined"} and rows["dynamics"]["auroc"] > 0.9


class _DictCartPole(gymnasium.ObservationWrapper):
    """CartPole whose observations are ``{"state": the usual vector, "mode": 1}`` (a Dict space with
    a discrete key counted from 1, which SB3 reads one-hot from 0 and gymnasium flattens from 1)."""

    def __init__(self) -> None:
        super().__init__(gymnasium.make("CartPole-v1"))
        self.observation_space = gymnasium.spaces.Dict({"state": self.env.observation_space,
                                                        "mode": gymnasium.spaces.Discrete(3, start=1)})

    def observation(self, obs):
        return {"state": obs, "mode": 1}


class _Halves(gymnasium.ObservationWrapper):
    """An env's vector observation as a dict of its two halves, named so that their keys sort the
    other way round ("b" the first numbers, "a" the rest): the policy's flattened dict is not the
    vector, and only the order SB3's CombinedExtractor concatenates in reads it right."""

    def __init__(self, env: gymnasium.Env | None = None, task_id: str = "CartPole-v1") -> None:
        super().__init__(env if env is not None else gymnasium.make(task_id))
        box, self.cut = self.env.observation_space, (self.env.observation_space.shape[0] + 1) // 2
        self.observation_space = gymnasium.spaces.Dict({
            "b": gymnasium.spaces.Box(box.low[:self.cut], box.high[:self.cut], dtype=box.dtype),
            "a": gymnasium.spaces.Box(box.low[self.cut:], box.high[self.cut:], dtype=box.dtype)})

    def observation(self, obs):
        return {"b": obs[:self.cut], "a": obs[self.cut:]}


class _Moded(_Halves):
    """_Halves with discrete keys as well: a mode (0-2: how many of the cart and the pole move right)
    and two flags (the cart left of centre, the pole leaning left), which SB3 reads one-hot and as 0/1."""

    def __init__(self) -> None:
        super().__init__()
        self.observation_space = gymnasium.spaces.Dict(
            {**self.observation_space.spaces, "mode": gymnasium.spaces.Discrete(3),
             "flags": gymnasium.spaces.MultiBinary(2)})

    def observation(self, obs):
        return super().observation(obs) | {"mode": int(obs[1] > 0) + int(obs[3] > 0),
                                           "flags": np.array([obs[0] < 0, obs[2] < 0], np.int8)}


for _task in ("CartPole-v1", "Pendulum-v1"):
    if f"Halves{_task}" not in gymnasium.registry:
        gymnasium.register(f"Halves{_task}", entry_point=_Halves, kwargs={"task_id": _task},
                           max_episode_steps=gymnasium.spec(_task).max_episode_steps)
if "ModedCartPole-v1" not in gymnasium.registry:
    gymnasium.register("ModedCartPole-v1", entry_point=_Moded, max_episode_steps=500)


@pytest.mark.parametrize("env_id, width", [("HalvesCartPole-v1", 4), ("ModedCartPole-v1", 9)])
def test_an_ensemble_of_multi_input_dqns_reads_dict_observations_as_their_networks_do(env_id, width):
    """Two MultiInputPolicy DQNs on dict observations: the ensemble's samples are each model's own
    Q-values at the dict, the deployed action is the first model's predict() of the dict (discrete
    keys too: flattened one-hot, as SB3 reads them)."""
    env = gymnasium.make(env_id)
    models = [DQN("MultiInputPolicy", env, seed=k, policy_kwargs={"net_arch": [16]}) for k in range(2)]
    agent = sb3_agent(models, env_id)
    assert agent.dict_space == env.observation_space and agent.estimator.obs_shape == (width,)
    obs, _ = env.reset(seed=0)
    for _ in range(12):
        assert isinstance(obs, dict)
        flat = agent.view(obs)
        ordered = [obs["a"], obs["b"]] if width == 4 else [obs["a"], obs["b"], obs["flags"], np.eye(3)[obs["mode"]]]
        np.testing.assert_array_equal(flat, np.concatenate(ordered))  # the keys' order, not the vector's
        samples = agent.estimate(flat).samples[:, 0]
        with torch.no_grad():
            theirs = [m.q_net(m.policy.obs_to_tensor(obs)[0])[0].numpy() for m in models]
        np.testing.assert_allclose(samples, theirs, rtol=1e-5, atol=1e-6)
        assert agent.act(flat) == int(models[0].predict(obs, deterministic=True)[0])
        obs, _, terminated, truncated, _ = env.step(agent.act(flat))
        if terminated or truncated:
            obs, _ = env.reset()


def test_a_multi_input_td3_on_dict_observations_is_watched_and_alarms_when_the_pendulum_gets_heavier():
    """oodmon.watch of a TD3 trained on dict observations, around the user's dict env: the user's
    loop gets dicts, the monitor reads them flattened, the log keeps them flattened, and a heavier
    pendulum (m=5 from step 50) alarms in each episode, never before step 50."""
    import oodmon
    from oodmon.monitor import MemorySink

    model = TD3("MultiInputPolicy", gymnasium.make("HalvesPendulum-v1"), seed=0, learning_starts=200,
                policy_kwargs={"net_arch": [32, 32]})
    model.learn(400)
    sink = MemorySink()
    shifted = _Halves(gymnasium.make("oodmon/Pendulum-v1", m=5.0, onset_step=50))
    env = oodmon.watch(model, "HalvesPendulum-v1", env=shifted, episodes=22, far=0.1, fit_episodes=20, sinks=[sink])
    assert env.monitor.detectors.names == ["dynamics", "drift", "combined"]  # a plain policy: no spread, no features
    first_alarms, starts = [], []
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        starts.append(obs)
        alarms = []
        for t in range(200):
            assert isinstance(obs, dict) and set(obs) == {"a", "b"}
            obs, _, terminated, truncated, info = env.step(model.predict(obs, deterministic=True)[0])
            if info["oodmon"]["alarm"]:
                alarms.append(t)
            if terminated or truncated:
                break
        first_alarms.append(alarms[0] if alarms else None)
    assert all(t is not None and 50 <= t <= 70 for t in first_alarms), first_alarms
    assert sink.steps[0].observation == pytest.approx([*starts[0]["a"], *starts[0]["b"]])  # flattened, keys in order


def test_a_policy_of_rgb_pictures_is_watched_by_the_frames_detector(tmp_path):
    """SB3 stores a model of channel-last pictures with its channels first ((3, 40, 40) for a
    (40, 40, 3) env), and its predict() takes the env's pictures as they come: the model was refused
    as "a model of another env?". Now it loads, the frames detector reads each picture, and the log
    holds the pictures in colour."""
    from stable_baselines3 import PPO

    import oodmon
    from oodmon.monitor import McapSink

    if "PicturesForTests-v0" not in gymnasium.registry:
        gymnasium.register("PicturesForTests-v0", entry_point=NoisePictures)
    model = PPO("CnnPolicy", gymnasium.make("PicturesForTests-v0"), seed=0, n_steps=32, batch_size=32)
    assert model.observation_space.shape == (3, 40, 40)
    model.save(tmp_path / "pictures.zip")
    agent = load_sb3([tmp_path / "pictures.zip"], "PicturesForTests-v0")
    sink = McapSink(tmp_path / "pictures.mcap")
    env = oodmon.watch(agent, env=gymnasium.make("PicturesForTests-v0"), episodes=20, confidence=None,
                       fit_episodes=6, sinks=[sink])
    assert env.monitor.detector == "combined" and "frames" in env.monitor.detectors.names
    env.reset(seed=0)
    for _ in range(5):
        info = env.step()[-1]
    assert np.isfinite(info["oodmon"]["scores"]["frames"])
    env.close()
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from mcap.reader import make_reader

    with open(tmp_path / "pictures.mcap", "rb") as file:
        frames = [RawImage.FromString(m.data) for _, _, m in make_reader(file).iter_messages(topics=["/oodmon/frame"])]
    assert frames and (frames[0].width, frames[0].height, frames[0].encoding) == (40, 40, "rgb8")


def test_bad_sb3_input_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ConfigError, match="does not exist"):
        load_sb3([tmp_path / "missing.zip"], "CartPole-v1")
    (tmp_path / "not.zip").write_text("hello")
    with pytest.raises(ConfigError, match="not a stable-baselines3 model"):
        load_sb3([tmp_path / "not.zip"], "CartPole-v1")
    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0).save(tmp_path / "dqn.zip")
    with pytest.raises(ConfigError, match="a model of another env"):
        load_sb3([tmp_path / "dqn.zip"], "Acrobot-v1")
    with pytest.raises(ConfigError, match="--mean deploys the ensemble's mean"):
        load_sb3([tmp_path / "dqn.zip"], "CartPole-v1", mean=True)
    # Models of two architectures: said (they became one plain policy, their ensemble dropped in silence).
    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=1, policy_kwargs={"net_arch": [32, 32]}).save(tmp_path / "wide.zip")
    with pytest.raises(ConfigError, match=r"the 2 models cannot form the ensemble .*member 1 has another architecture"):
        load_sb3([tmp_path / "dqn.zip", tmp_path / "wide.zip"], "CartPole-v1")
    from stable_baselines3 import PPO

    PPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, n_steps=32, batch_size=32).save(tmp_path / "ppo.zip")
    for pair in (["dqn.zip", "ppo.zip"], ["ppo.zip", "ppo.zip"]):  # the second was ignored
        with pytest.raises(ConfigError, match="several models form an ensemble.*give the deployed model alone"):
            load_sb3([tmp_path / name for name in pair], "CartPole-v1")
    assert main(["calibrate", "--sb3", str(tmp_path / "dqn.zip"), "--out", str(tmp_path / "t.json")]) == 2
    assert "--sb3 needs --env" in capsys.readouterr().err
    assert main(["run", "--sb3", str(tmp_path / "dqn.zip"), "--env", "CartPole-v1", "--variant", "pendulum:m=5.0"]) == 2
    assert "'pendulum:m=5.0' is not a cartpole variant" in capsys.readouterr().err
    # An env of Dict observations with a key that is no vector: said at once (it failed inside the
    # fitting: "a combined detector needs distinct member detectors other than itself; got []").
    if "DictCartPoleForTests-v0" not in gymnasium.registry:
        gymnasium.register("DictCartPoleForTests-v0", entry_point=_DictCartPole)
    dict_model = PPO("MultiInputPolicy", gymnasium.make("DictCartPoleForTests-v0"), seed=0, n_steps=32, batch_size=32)
    with pytest.raises(ConfigError, match=r"DictCartPoleForTests-v0's observations are Dict\(.*or a dict of vectors and "
                                          r"discrete values \(pictures beside them too\): wrap the env in "
                                          r"gymnasium.wrappers.FlattenObservation"):
        sb3_agent([dict_model], "DictCartPoleForTests-v0")
    DQN("MlpPolicy", gymnasium.make("Acrobot-v1"), seed=0).save(tmp_path / "acrobot.zip")  # an env without variants
    assert main(["run", "--sb3", str(tmp_path / "acrobot.zip"), "--env", "Acrobot-v1", "--variant", "cartpole:length=2.0"]) == 2
    assert ("'cartpole:length=2.0' is not a variant of Acrobot-v1: oodmon has variants of CartPole-v1, Pendulum-v1"
            in capsys.readouterr().err)
    assert main(["evaluate", "--sb3", str(tmp_path / "acrobot.zip"), "--env", "Acrobot-v1"]) == 2  # said: "unknown task"
    assert "evaluate plays oodmon's shifted variants of CartPole, Pendulum and Pong; --env Acrobot-v1" in capsys.readouterr().err
    assert main(["calibrate", "--method", "ensemble", "--out", str(tmp_path / "t.json")]) == 2
    assert "give --task" in capsys.readouterr().err


def test_a_model_named_without_its_zip_is_read_as_sb3s_load_reads_it(tmp_path, capsys):
    # model.save("runs/dqn") writes runs/dqn.zip and DQN.load("runs/dqn") reads it; oodmon said
    # "runs/dqn does not exist" until 2026-12-03.
    from oodmon.agents.sb3 import sb3_file

    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0).save(tmp_path / "dqn")
    assert sb3_file(tmp_path / "dqn") == tmp_path / "dqn.zip" and sb3_file(tmp_path / "dqn.zip") == tmp_path / "dqn.zip"
    agent = load_sb3([tmp_path / "dqn"], "CartPole-v1")
    assert [Path(m["path"]).name for m in agent.metadata["models"]] == ["dqn.zip"]  # what a log records
    (tmp_path / "both").write_text("not a model")  # a file of that very name is the one named, as for SB3
    assert sb3_file(tmp_path / "both") == tmp_path / "both"
    # the command line sees the file too: an output over it is refused before any work
    assert main(["calibrate", "--sb3", str(tmp_path / "dqn"), "--env", "CartPole-v1", "--out", str(tmp_path / "dqn.zip")]) == 2
    assert "is also --sb3; writing it would overwrite that file" in capsys.readouterr().err
    assert main(["calibrate", "--sb3", str(tmp_path / "nothing"), "--env", "CartPole-v1", "--out", str(tmp_path / "t.json")]) == 2
    assert "nothing does not exist (an SB3 model is the .zip that model.save() wrote; nothing.zip is not there either)" in (
        capsys.readouterr().err)
    # a name the system refuses (longer than a file name may be) is said as missing, in one line
    # (scripts/fuzz_cli.py --seed 171 found it a traceback on 2026-12-05)
    long = str(tmp_path / ("x" * 300))
    assert main(["calibrate", "--sb3", long, "--env", "CartPole-v1", "--out", str(tmp_path / "t.json")]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"oodmon: error: {long} does not exist (an SB3 model is the .zip that model.save() wrote; {'x' * 300}.zip is not "
        "there either)"]


@pytest.mark.filterwarnings("ignore::oodmon.monitor.monitor.OtherActionsWarning")  # (action 0 on purpose; tested below)
def test_watch_fits_calibrates_and_wraps_an_env_in_one_call():
    import oodmon
    from oodmon.monitor import MemorySink

    models = [DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=k, policy_kwargs={"net_arch": [16]}) for k in range(2)]
    sink = MemorySink()
    env = oodmon.watch(models, "CartPole-v1", env=gymnasium.make("CartPole-v1"), episodes=10, far=0.2,
                       confidence=None, fit_episodes=6, sinks=[sink])
    threshold = env.monitor.tracker.threshold
    assert np.isfinite(threshold) and env.monitor.detector == "combined"
    obs, _ = env.reset(seed=3)
    expected = models[0].predict(obs, deterministic=True)[0]
    obs, _, terminated, truncated, info = env.step()
    assert info["oodmon"]["threshold"] == threshold and set(info["oodmon"]["scores"]) >= {"dynamics", "combined"}
    assert sink.steps[0].action == int(expected)  # the first model acts, not the ensemble
    while not (terminated or truncated):
        obs, _, terminated, truncated, info = env.step(0)  # your action is the deployed one
    env.close()
    assert sink.episodes[0].variant == "cartpole"  # recorded from the env: replay needs no variant=
    assert [s.action for s in sink.steps[1:]] == [0] * (len(sink.steps) - 1)
    for model in models:  # (as models loaded from their files without an env: else the id of theirs is taken)
        model.env = None
    with pytest.raises(ConfigError, match="env id"):
        oodmon.watch(models)
    with pytest.raises(ConfigError, match=r"^the model in memory was trained with the observation_space Box"):
        oodmon.watch(models, "Pendulum-v1")  # (it read "(in memory) was trained ...")


def test_watch_saves_its_calibration_and_a_later_start_reads_it_running_no_episode(readme_run, tmp_path, capsys):
    """A deployed process cannot calibrate at every start: watch(save=) writes the threshold and the
    fitted detectors as `oodmon calibrate --out` does, and watch(threshold=) reads them (or the
    CLI's) without fitting or calibrating; a file of other weights is refused."""
    import oodmon
    from oodmon.monitor import MemorySink, Threshold

    folder, _, _ = readme_run
    paths = [folder / "runs/dqn0.zip", folder / "runs/dqn1.zip"]
    progress: list = []
    first = oodmon.watch(paths, "CartPole-v1", episodes=10, far=0.2, confidence=None, fit_episodes=6,
                         save=tmp_path / "w.json", on_progress=lambda *report: progress.append(report))
    assert progress and (tmp_path / "w.json.detectors" / "detectors.json").is_file()
    assert Threshold.load(tmp_path / "w.json").value == first.threshold
    progress.clear()
    later = oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json", sinks=[MemorySink()],
                         on_progress=lambda *report: progress.append(report))
    assert progress == []  # no episode ran
    assert (later.threshold, later.detector, later.detectors.names) == (first.threshold, first.detector,
                                                                       first.detectors.names)
    records = []
    for monitor in (first, later):
        sink = MemorySink()
        monitor.sinks.sinks.append(sink)
        with monitor:
            monitor.run_episode(gymnasium.make("CartPole-v1"), seed=7)
        records.append([step.scores for step in sink.steps])
    assert records[0] == records[1]  # the same detectors, score for score
    # The CLI's calibration reads the same way, and the CLI runs on watch's.
    cli = oodmon.watch(paths, "CartPole-v1", threshold=folder / "runs/dqn.json")
    assert cli.threshold == Threshold.load(folder / "runs/dqn.json").value and cli.detector == "combined"
    assert main(["run", "--sb3", *map(str, paths), "--env", "CartPole-v1", "--threshold", str(tmp_path / "w.json"),
                 "--episodes", "1"]) == 0
    capsys.readouterr()
    with pytest.raises(ConfigError, match="calibrated on other weights"):
        oodmon.watch(paths[::-1], "CartPole-v1", threshold=tmp_path / "w.json")  # the other model deploys: other hash
    with pytest.raises(ConfigError, match="not both"):
        oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json", save=tmp_path / "x.json")
    # save= at a model it reads, or at a log: refused before any episode, neither file changed
    kept = [path.read_bytes() for path in (paths[1], folder / "runs/dqn.mcap")]
    with pytest.raises(ConfigError, match="is also a file it reads"):
        oodmon.watch(paths, "CartPole-v1", save=paths[1])
    with pytest.raises(ConfigError, match="holds no threshold"):
        oodmon.watch(paths, "CartPole-v1", save=folder / "runs/dqn.mcap")
    assert [path.read_bytes() for path in (paths[1], folder / "runs/dqn.mcap")] == kept
    with pytest.raises(ConfigError, match="a threshold file's warm-up is the one it was calibrated for"):
        oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json", warmup=20)
    with pytest.raises(ConfigError, match="a threshold file's episodes are those it was calibrated on"):
        oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json", max_steps=5000)
    # options of a fit, which a threshold file's detectors (fitted beside it) never see: refused, not ignored
    with pytest.raises(ConfigError, match=r"^fit_episodes= shapes a fit of the detectors.*leave it out"):
        oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json", fit_episodes=30)
    with pytest.raises(ConfigError, match=r"^fit_episodes= and dynamics_updates= shape a fit.*leave them out"):
        oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json", fit_episodes=30, dynamics_updates=500)
    warm = oodmon.watch(paths, "CartPole-v1", episodes=10, far=0.2, confidence=None, fit_episodes=6, warmup=30,
                        save=tmp_path / "warm.json", max_steps=600)
    saved = Threshold.load(tmp_path / "warm.json")
    assert warm.tracker.warmup == 30 and saved.warmup == 30 and saved.max_steps == 600
    (tmp_path / "w.json.detectors").rename(tmp_path / "elsewhere")
    with pytest.raises(ConfigError, match="which is missing: copy that folder"):
        oodmon.watch(paths, "CartPole-v1", threshold=tmp_path / "w.json")


def test_a_calibration_binds_the_models_weights_not_their_files_bytes(readme_run, tmp_path, capsys):
    """SB3 writes other bytes each time it saves the same model (the zip's times): a threshold
    calibrated on the files fits the same models in memory and saved again (before 2026-12-04 both
    were refused as "other weights"), and one of another model does not. A threshold that recorded
    the files' hash, as they did before, still fits the models loaded from those files."""
    import oodmon
    from oodmon.hashing import file_sha256
    from oodmon.monitor import Threshold

    folder, _, _ = readme_run
    paths = [folder / "runs/dqn0.zip", folder / "runs/dqn1.zip"]
    threshold = folder / "runs/dqn.json"  # `oodmon calibrate --sb3 runs/dqn0.zip runs/dqn1.zip`'s
    models = [DQN.load(p) for p in paths]
    models[0].save(tmp_path / "dqn0.zip")
    assert file_sha256(tmp_path / "dqn0.zip") != file_sha256(paths[0])
    in_memory = oodmon.watch(models, "CartPole-v1", threshold=threshold)
    from_files = load_sb3(paths, "CartPole-v1")
    assert in_memory.policy_hash == from_files.metadata["policy_hash"] == Threshold.load(threshold).policy_hash
    logged = read_log(folder / "runs/dqn.mcap").metadata  # `oodmon run --sb3`'s: both hashes (replay pools by them)
    assert (logged["policy_hash"], logged["about.files_hash"]) == (from_files.metadata["policy_hash"],
                                                                   from_files.metadata["files_hash"])
    assert main(["run", "--sb3", str(tmp_path / "dqn0.zip"), str(paths[1]), "--env", "CartPole-v1",
                 "--threshold", str(threshold), "--episodes", "1"]) == 0
    capsys.readouterr()
    with pytest.raises(ConfigError, match="calibrated on other weights") as refused:
        oodmon.watch(models[::-1], "CartPole-v1", threshold=threshold)  # the other model deploys
    with pytest.raises(ConfigError) as refused_files:
        oodmon.watch(paths[::-1], "CartPole-v1", threshold=threshold)
    assert "give the files" in str(refused.value) and "give the files" not in str(refused_files.value)
    # a threshold of the files' hash (what calibrate recorded before 2026-12-04)
    old = json.loads(threshold.read_text()) | {"policy_hash": from_files.metadata["files_hash"]}
    (tmp_path / "old.json").write_text(json.dumps(old))
    (tmp_path / "old.json.detectors").symlink_to(folder / "runs/dqn.json.detectors")
    assert main(["run", "--sb3", *map(str, paths), "--env", "CartPole-v1", "--threshold", str(tmp_path / "old.json"),
                 "--episodes", "1"]) == 0
    with pytest.raises(ConfigError, match=r"calibrated on other weights .*before 2026-12-04, it recorded the files' "
                                          r"bytes, which models in memory do not have: give the files"):
        oodmon.watch(models, "CartPole-v1", threshold=tmp_path / "old.json")  # in memory the files are not known
    (tmp_path / "unknown.json").write_text(json.dumps(old | {"policy_hash": "unknown"}))  # no weights recorded
    (tmp_path / "unknown.json.detectors").symlink_to(folder / "runs/dqn.json.detectors")
    assert oodmon.watch(models, "CartPole-v1", threshold=tmp_path / "unknown.json").threshold == old["value"]
    detectors = DetectorSet.load(folder / "runs/dqn.json.detectors")
    detectors.fitted_for["policy_hash"] = from_files.metadata["files_hash"]
    fits = dict(task="cartpole", obs_shape=(4,), policy_hash=from_files.metadata["policy_hash"])
    assert detectors.check_fits(**fits, aliases=(from_files.metadata["files_hash"],)) == []
    assert "another policy's episodes" in detectors.check_fits(**fits)[0]


def test_watch_reads_one_dropout_models_fixed_sub_networks_when_asked(tmp_path):
    # watch(..., masks="fixed", detector="scaled_spread") fits that detector itself (as `oodmon
    # calibrate --detector scaled_spread` does) on the fixed sub-networks, and calibrates on it.
    import oodmon
    from oodmon.agents.layers import add_dropout
    from oodmon.agents.sb3 import sb3_agent

    model = DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16, 16]})
    model.policy.q_net.q_net = add_dropout(model.policy.q_net.q_net, 0.2)
    monitor = oodmon.watch(model, "CartPole-v1", masks="fixed", detector="scaled_spread", episodes=10, far=0.2,
                           confidence=None, fit_episodes=6, seed=0, save=tmp_path / "fixed.json")
    assert monitor.detector == "scaled_spread" and monitor.estimator.masks == "fixed"
    later = oodmon.watch(model, "CartPole-v1", threshold=tmp_path / "fixed.json", seed=0)  # loaded with the file's masks
    assert later.estimator.masks == "fixed" and later.detector == "scaled_spread" and later.threshold == monitor.threshold
    assert monitor.detectors.fitted_for["masks"] == "fixed" and "scaled_spread" in monitor.detectors.names
    assert np.isfinite(monitor.tracker.threshold)
    with pytest.raises(ConfigError, match="loaded with sampled masks, not 'fixed'"):
        oodmon.watch(sb3_agent([model], "CartPole-v1"), masks="fixed")


@pytest.mark.filterwarnings("ignore::oodmon.monitor.sb3_callback.ExplorationWarning")  # (its own test below)
def test_the_callback_scores_training_rollouts_and_writes_tensorboard(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from oodmon.monitor import MemorySink, MonitorCallback
    from oodmon.monitor import sb3_callback
    from oodmon.monitor.detectors import fit_detectors

    assert MonitorCallback is sb3_callback.MonitorCallback  # where a user looks first, beside Monitor
    env = gymnasium.make("CartPole-v1")
    space = env.action_space
    space.seed(0)
    detectors = fit_detectors(lambda obs: int(space.sample()), env, detectors=["dynamics"], episodes=6)
    sink = MemorySink()
    model = DQN("MlpPolicy", env, seed=0, learning_starts=100, policy_kwargs={"net_arch": [16]},
                tensorboard_log=str(tmp_path))
    with Monitor(None, 2.0, detectors=detectors, detector="dynamics", sinks=[sink]) as monitor:
        callback = MonitorCallback(monitor)
        model.learn(300, callback=callback, log_interval=1)
    assert len(sink.steps) == 300  # every training step of the env, scored
    assert {s.action for s in sink.steps} <= {0, 1} and sink.episodes[0].variant == "cartpole"
    assert sum(e.length for e in sink.episodes) == 300 and not any(e.interrupted for e in sink.episodes[:-1])
    assert all(e.terminated for e in sink.episodes[:-1])  # a random-ish CartPole policy drops the pole
    assert callback.alarms == monitor.alarms_raised == sum(e.alarms for e in sink.episodes)
    events = EventAccumulator(str(next(tmp_path.glob("DQN_*")))).Reload()
    tags = events.Tags()["scalars"]
    assert {"oodmon/score", "oodmon/score_dynamics", "oodmon/alarm_share", "oodmon/alarms", "oodmon/threshold"} <= set(tags)
    scores = [e.value for e in events.Scalars("oodmon/score")]
    assert len(scores) >= 5 and all(np.isfinite(scores))  # one dump per episode (log_interval=1)
    assert events.Scalars("oodmon/threshold")[-1].value == 2.0
    assert events.Scalars("oodmon/alarms")[-1].value <= monitor.alarms_raised


@pytest.mark.filterwarnings("ignore::oodmon.monitor.sb3_callback.ExplorationWarning")  # (its own test below)
@pytest.mark.parametrize("algorithm", ["DQN", "PPO"])
@pytest.mark.parametrize("normalized", [False, True], ids=["raw", "VecNormalize"])
def test_the_callback_scores_the_observation_each_action_was_taken_on(algorithm, normalized):
    # It read the model's _last_original_obs: for DQN (SAC, TD3) without VecNormalize that is the step
    # before's observation (299 of 300 steps were), for PPO (A2C) with it the one learn() began with.
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    acted: list = []
    venv = DummyVecEnv([lambda: ActedOn(gymnasium.make("CartPole-v1"), acted)])
    venv = VecNormalize(venv) if normalized else venv
    model = (DQN("MlpPolicy", venv, seed=0, learning_starts=50, policy_kwargs={"net_arch": [16]}) if algorithm == "DQN"
             else PPO("MlpPolicy", venv, seed=0, n_steps=100, batch_size=50, policy_kwargs={"net_arch": [16]}))
    steps = _learn_monitored(model, "CartPole-v1", 300)
    logged = np.array([step.observation for step in steps])
    assert len(logged) == len(acted) >= 300
    assert np.allclose(logged, np.array(acted), atol=1e-6)


@pytest.mark.filterwarnings("ignore::oodmon.monitor.sb3_callback.ExplorationWarning")  # (its own test below)
def test_the_callback_scores_a_dict_observation_flattened_in_its_keys_order():
    acted: list = []
    venv = DummyVecEnv([lambda: ActedOn(gymnasium.make("HalvesCartPole-v1"), acted)])
    model = DQN("MultiInputPolicy", venv, seed=0, learning_starts=50, policy_kwargs={"net_arch": [16]})
    steps = _learn_monitored(model, "HalvesCartPole-v1", 200)
    logged = np.array([step.observation for step in steps])
    assert len(logged) == len(acted) >= 200 and np.isfinite([s.score for s in steps]).all()
    assert np.allclose(logged, [np.r_[obs["a"], obs["b"]] for obs in acted], atol=1e-6)


def _learn_monitored(model, env_id: str, steps: int, explore: float = 0.0) -> list:
    """``model.learn(steps)`` with a MonitorCallback whose monitor's dynamics detector was fitted on
    3 random-policy episodes of ``env_id`` (flattened; ``explore``: as a fit that explores records
    it); the steps it logged."""
    from oodmon.monitor import MemorySink
    from oodmon.monitor.detectors import fit_detectors
    from oodmon.monitor.sb3_callback import MonitorCallback

    env = gymnasium.wrappers.FlattenObservation(gymnasium.make(env_id))
    space = env.action_space
    space.seed(0)
    discrete = isinstance(space, gymnasium.spaces.Discrete)
    act = (lambda obs: int(space.sample())) if discrete else lambda obs: space.sample()
    detectors = fit_detectors(act, env, detectors=["dynamics"], episodes=3, explore=explore)
    sink = MemorySink()
    with Monitor(None, 2.0, detectors=detectors, detector="dynamics", sinks=[sink]) as monitor:
        model.learn(steps, callback=MonitorCallback(monitor))
    return sink.steps


@pytest.mark.parametrize("algorithm, normalized, explored", [
    ("PPO", False, 100),  # samples every action while it learns
    ("TD3", False, 0),  # no action noise, past learning_starts: its actions are the deployed ones
    ("TD3", True, 0),  # so too read through VecNormalize (the observation compared is the one acted on)
], ids=["PPO", "TD3", "TD3-VecNormalize"])
def test_the_callback_says_how_many_training_steps_explored_and_leaves_learning_as_it_was(
        algorithm, normalized, explored, monkeypatch):
    """The detectors, fitted on the deployed policy's own actions, read exploration as a shift: a
    training run's alarms were mostly its exploration, unsaid (2026-12-07). The check asks the model
    for its deterministic action, which draws nothing: the model learns the same weights."""
    import warnings

    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from oodmon.monitor import ExplorationWarning, sb3_callback

    def learned(checked: int) -> tuple[list[str], list[torch.Tensor]]:
        monkeypatch.setattr(sb3_callback, "EXPLORATION_CHECKED", checked)
        venv = DummyVecEnv([lambda: gymnasium.make("Pendulum-v1")])
        venv = VecNormalize(venv) if normalized else venv
        kwargs = {"seed": 0, "policy_kwargs": {"net_arch": [16]}}
        model = (PPO("MlpPolicy", venv, n_steps=64, batch_size=32, n_epochs=1, **kwargs) if algorithm == "PPO"
                 else TD3("MlpPolicy", venv, learning_starts=0, train_freq=25, gradient_steps=1, **kwargs))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert len(_learn_monitored(model, "Pendulum-v1", 150)) >= 150  # (a PPO's rollouts of 64 steps: 192)
        return ([str(w.message) for w in caught if issubclass(w.category, ExplorationWarning)],
                [p.detach().clone() for p in model.policy.parameters()])

    said, weights = learned(checked=100)
    if explored:
        assert len(said) == 1 and said[0].startswith(f"{explored} of the first 100 training steps took another action "
                                                     "than the model's deterministic one (its exploration)")
    else:
        assert said == []
    unchecked, same = learned(checked=0)
    assert unchecked == [] and all(torch.equal(a, b) for a, b in zip(weights, same))


@pytest.mark.parametrize("explore", [0.05, 0.5])
def test_the_callback_warns_of_exploration_beyond_the_share_of_random_actions_the_detectors_were_fitted_on(explore):
    """Detectors fitted on episodes with random actions at a share P of their steps (``fit_explore``)
    have seen other actions' outcomes: the callback warns only where more of the first 100 training
    steps explored. A DQN taking a random action at 30% of its steps: half of those are its own on
    CartPole, so about 15 of 100 differ (binomial: 6-24 at four standard deviations; measured 10),
    more than 5%, fewer than 50%."""
    import warnings

    from oodmon.monitor import ExplorationWarning

    model = DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, learning_starts=0, exploration_initial_eps=0.3,
                exploration_final_eps=0.3, policy_kwargs={"net_arch": [16]})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _learn_monitored(model, "CartPole-v1", 150, explore=explore)
    said = [str(w.message) for w in caught if issubclass(w.category, ExplorationWarning)]
    if explore == 0.5:
        assert said == []
    else:
        explored = int(said[0].split()[0])
        assert len(said) == 1 and 6 <= explored <= 24 and said[0].startswith(
            f"{explored} of the first 100 training steps took another action than the model's deterministic one (its "
            "exploration), more than the 5% of random actions the detectors were fitted with: some alarms while it "
            "learns may be its exploration")


@pytest.mark.parametrize("way, differing, checked", [
    ("deterministic", (0, 0), 100),  # predict(obs, deterministic=True): the policy's own decision
    ("exploring", (6, 24), 100),  # predict(obs): a random action at 30% of the steps, half its own: about 15
    ("after an alarm", (0, 6), 12),  # every step alarms: only each episode's first is compared (a fallback's after)
])
def test_actions_given_to_a_monitor_that_are_not_the_policys_own_are_counted_and_said(way, differing, checked):
    """SB3's predict(obs) samples unless deterministic=True (a DQN's takes a random action at its
    exploration rate), and a loop of your own stepping a MonitoredEnv with it reads as a shift,
    unsaid before 2026-12-07. The monitor compares the first 100 actions given to it before an
    episode's first alarm with the policy's own decision, and warns once how many differed (at
    its close where fewer were given). Bounds: binomial, four standard deviations."""
    import warnings

    from oodmon.monitor import OtherActionsWarning
    from oodmon.monitor.detectors import fit_detectors

    model = DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16]})
    model.exploration_rate = 0.3
    agent = sb3_agent([model], "CartPole-v1")
    detectors = fit_detectors(agent, gymnasium.make("CartPole-v1"), detectors=["dynamics"], episodes=3,
                              dynamics_updates=5)
    threshold = -1e9 if way == "after an alarm" else None  # (every step alarms; None: none does)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with Monitor(agent, threshold, detectors=detectors, detector="dynamics") as monitor:
            env = MonitoredEnv(gymnasium.make("CartPole-v1"), monitor)
            for episode in range(12):  # (an untrained DQN's episodes last about 10 steps)
                obs, _ = env.reset(seed=episode)
                done = False
                while not done:
                    action, _ = model.predict(obs, deterministic=way == "deterministic")
                    obs, _, terminated, truncated, _ = env.step(action)
                    done = terminated or truncated
            compared = monitor._given.checked  # (before the close, which says what it counted)
    said = [str(w.message) for w in caught if issubclass(w.category, OtherActionsWarning)]
    count = int(said[0].split()[0]) if said else 0
    assert len(said) <= 1 and differing[0] <= count <= differing[1]
    assert not said or said[0].startswith(
        f"{count} of the first {checked} actions given to the monitor (before any alarm) were not the policy's own "
        "decision at their observation: SB3's predict(obs) samples unless deterministic=True")
    assert compared == checked


def test_a_warning_of_other_actions_made_an_error_leaves_the_log_whole(tmp_path):
    """Said at the close where fewer than 100 actions were given, after the log is finished, and at
    the 100th after that step is logged: under ``-W error`` the warning raises, and the log is whole
    all the same."""
    import warnings

    from oodmon.monitor import McapSink, OtherActionsWarning
    from oodmon.monitor.detectors import fit_detectors

    model = DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16]})
    model.exploration_rate = 1.0  # every action random: about half differ from its own
    agent = sb3_agent([model], "CartPole-v1")
    detectors = fit_detectors(agent, gymnasium.make("CartPole-v1"), detectors=["dynamics"], episodes=3,
                              dynamics_updates=5)
    monitor = Monitor(agent, None, detectors=detectors, detector="dynamics", sinks=[McapSink(tmp_path / "r.mcap")])
    env = MonitoredEnv(gymnasium.make("CartPole-v1"), monitor)
    obs, _ = env.reset(seed=0)
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(model.predict(obs)[0])
        done = terminated or truncated
    with warnings.catch_warnings():
        warnings.simplefilter("error", OtherActionsWarning)
        with pytest.raises(OtherActionsWarning, match=r"^\d+ of the first \d+ actions given to the monitor"):
            monitor.close()
    log = read_log(tmp_path / "r.mcap")
    assert log.complete and len(log.episodes) == 1
    sink = MemorySink()  # the 100th given step: logged before the warning raises
    monitor = Monitor(agent, None, detectors=detectors, detector="dynamics", sinks=[sink])
    env = MonitoredEnv(gymnasium.make("CartPole-v1"), monitor)
    with warnings.catch_warnings():
        warnings.simplefilter("error", OtherActionsWarning)
        with pytest.raises(OtherActionsWarning, match=r"^\d+ of the first 100 actions given to the monitor"):
            for episode in range(100):
                obs, _ = env.reset(seed=episode)
                done = False
                while not done:
                    obs, _, terminated, truncated, _ = env.step(model.predict(obs)[0])
                    done = terminated or truncated
    assert len(sink.steps) == 100
    monitor.close()  # (said once)


def test_an_env_of_the_users_own_module_is_made_by_module_and_id(tmp_path, monkeypatch, capsys):
    # The page's "module:EnvId": gymnasium imports the module (registering the env) before making it.
    (tmp_path / "users_envs_for_tests.py").write_text(
        "import gymnasium\n"
        "from gymnasium.wrappers import TransformObservation\n"
        "def make(**kwargs):\n"
        "    env = gymnasium.make('CartPole-v1', **kwargs)\n"
        "    return TransformObservation(env, lambda obs: obs * 2, env.observation_space)\n"
        "gymnasium.register('DoubledCartPoleForTests-v0', entry_point=make)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    env_id = "users_envs_for_tests:DoubledCartPoleForTests-v0"
    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16]}).save(tmp_path / "dqn.zip")
    threshold, log = str(tmp_path / "t.json"), str(tmp_path / "r.mcap")
    # far 0.05: the run below wants no false alarm of an untrained DQN's ID-like episodes (at 0.2, 1 of 2
    # alarmed once drift joined the default set of your own env's detectors)
    assert main(["calibrate", "--sb3", str(tmp_path / "dqn.zip"), "--env", env_id, "--episodes", "20", "--far", "0.05",
                 "--confidence", "none", "--fit-episodes", "6", "--out", threshold]) == 0
    assert main(["run", "--sb3", str(tmp_path / "dqn.zip"), "--env", env_id, "--threshold", threshold,
                 "--episodes", "2", "--mcap", log]) == 0
    capsys.readouterr()
    # the run's episodes are named by the id given, as calibration names its own (the env knows its id
    # without the module: the ID row of replay read DoubledCartPoleForTests-v0 beside the task's id)
    assert [e.variant for e in read_log(log).episodes] == [env_id] * 2
    agent = load_sb3([tmp_path / "dqn.zip"], env_id)
    doubled, _ = agent.make_env().reset(seed=0)
    assert np.allclose(doubled, 2 * gymnasium.make("CartPole-v1").reset(seed=0)[0])  # the user's wrapper acts
    # CartPole reads masscart only through what __init__ derived from it: the shift changes nothing, no
    # episode alarms, and the run says how to see whether a shift changes anything
    assert main(["run", "--sb3", str(tmp_path / "dqn.zip"), "--env", env_id, "--threshold", threshold,
                 "--episodes", "2", "--variant", f"{env_id}:masscart=5.0", "--onset", "3"]) == 0
    said = capsys.readouterr().out
    assert "0 of 2 episodes raised an alarm" in said
    command = re.search(r"`(oodmon envs show [^`]*)`", said.replace("\n", "")).group(1)
    assert shlex.split(command) == ["oodmon", "envs", "show", f"{env_id}:masscart=5.0", "--onset", "3",
                                    "--sb3", str(tmp_path / "dqn.zip")]
    assert main(shlex.split(command)[1:]) == 1  # the command as printed: the DQN acts in both
    shown = " ".join(capsys.readouterr().out.split())
    assert "changed nothing" in shown and "steps of the policy's actions" in shown
    sink = MemorySink()  # oodmon.watch's path names them so too
    detectors = DetectorSet.load(f"{threshold}.detectors")  # those calibrate fitted
    with MonitoredEnv(gymnasium.make(env_id), Monitor(agent, detectors=detectors, sinks=[sink])) as env:
        env.reset(seed=0)
        env.step()
    assert sink.episodes[0].variant == env_id


def test_an_id_episode_that_never_ends_is_said_naming_the_missing_time_limit(monkeypatch):
    # Fitting, calibration and validation play whole episodes: in an env registered without
    # max_episode_steps a policy that never ends one ran for ever with no word beyond "1/90 episodes".
    import warnings

    from gymnasium.envs.classic_control.acrobot import AcrobotEnv

    import oodmon.envs.checks
    from oodmon.agents.sb3 import sb3_agent
    from oodmon.monitor import calibrate_agent
    from oodmon.monitor.detectors import fit_agent_detectors

    if "EndlessAcrobotForTests-v0" not in gymnasium.registry:
        gymnasium.register("EndlessAcrobotForTests-v0", entry_point=AcrobotEnv)  # no time limit
    monkeypatch.setattr(oodmon.envs.checks, "LONG_EPISODE", 300)  # an untrained DQN swings it up in none of them
    models = [DQN("MlpPolicy", gymnasium.make("Acrobot-v1"), seed=k, policy_kwargs={"net_arch": [8]}) for k in range(2)]
    endless = sb3_agent(models, "EndlessAcrobotForTests-v0")
    expected = r"an ID episode of EndlessAcrobotForTests-v0 has run 300 steps and not ended.*register it with max_episode_steps"
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # the warning stops the endless episode here
        with pytest.raises(UserWarning, match=expected):
            fit_agent_detectors(endless, detectors=["dynamics"], episodes=3)
        with pytest.raises(UserWarning, match=expected):
            calibrate_agent(endless, 10, 0.2, confidence=None, detector="spread")
        # Acrobot-v1 itself ends its episodes at 500 steps: it gets a word only past the limit
        monkeypatch.setattr(oodmon.envs.checks, "LONG_EPISODE", 501)
        detectors = fit_agent_detectors(sb3_agent(models, "Acrobot-v1"), detectors=["dynamics"], episodes=3)
    assert "dynamics" in detectors


def test_evaluate_takes_sb3_models_too(readme_run, capsys):
    folder, _, _ = readme_run
    assert main(["evaluate", "--sb3", str(folder / "runs/dqn0.zip"), "--env", "CartPole-v1", "--variants",
                 "cartpole:length=2.0", "--episodes", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["task"] == "cartpole" and result["method"] == "sb3"


def test_bench_runs_the_monitor_protocol_on_a_plain_sb3_policy(readme_run, capsys):
    """One DQN of docs/your-policy.md (no samples of its own): the monitor's benchmark with the learned
    detectors, cached per weights like the zoo's agents."""
    folder, _, _ = readme_run
    out = folder / "bench"
    argv = ["bench", "--sb3", str(folder / "runs/dqn0.zip"), "--env", "CartPole-v1", "--protocol", "monitor",
            "--variants", "cartpole:length=2.0", "--all-variants", "--episodes", "5", "--id-episodes", "20",
            "--calibration-episodes", "19", "--confidence", "none", "--fit-episodes", "30", "--workers", "1",
            "--out", str(out), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    rows = {r["variant"]: r for r in result["alarms"] if r["method"] == "sb3"}
    assert rows["cartpole"]["episodes"] == 20 and rows["cartpole:length=2.0"]["episodes"] == 5
    # 5 of 5 when written (the page's run: 5 of 5); this DQN drops the pole in ID episodes too, so an
    # episode may end before its onset (drawn in [20, 200)): 4 of the 4 that shifted on 2026-12-01
    began = 5 - rows["cartpole:length=2.0"]["never_shifted"]
    assert began >= 3 and rows["cartpole:length=2.0"]["alarmed"] >= began - 1
    folder_of_trial = next(out.glob("logs/cartpole-*-alarm-combined-fit*/sb3/trial0"))
    assert (folder_of_trial / "weights.sha256").read_text().strip() == file_sha256_of_models(folder / "runs/dqn0.zip")
    capsys.readouterr()
    assert main(argv[:-1]) == 0  # the same bench again, from its cache: the report as a person reads it
    printed = capsys.readouterr()
    ids, shifted = rows["cartpole"], rows["cartpole:length=2.0"]
    # a DQN of 4,000 steps drops the pole in some ID episodes too (CartPole's failure is told): said
    assert ids["failed"] is not None and 0 <= ids["failed"] <= 20
    fell = (f"; {ids['failed']}/20 ID episodes failed too (the env ended them): a shifted episode's failure is not the "
            "shift's doing alone") if ids["failed"] else ""
    assert (f"sb3: false alarms {ids['false_alarms']}/20 ID episodes (95% interval {ids['far_low']:.1%}-"
            f"{ids['far_high']:.1%}, target 0.05){fell}; {shifted['alarmed']}/{began} shifted episodes alarmed after the "
            f"onset ({shifted['early']} before it)"
            + (f"; {5 - began} more ended before their onset (never shifted)" if began < 5 else "")) \
        in " ".join(printed.out.split())
    assert "the monitor's benchmark (combined detector" in printed.out and "failed:" in printed.err
    assert main(argv[:-1] + ["--trials", "2"]) == 2
    assert "one trial" in capsys.readouterr().err
    assert main(["bench", "--sb3", str(folder / "runs/dqn0.zip"), "--env", "Acrobot-v1"]) == 2
    assert ("--env Acrobot-v1 is an env oodmon has no variants of: bench it with the monitor's protocol (--protocol monitor); "
            "the steps its shifts may begin at (e.g. --onsets 20,100); shifts of your own (--variants Acrobot-v1:NAME=VALUE"
            in " ".join(capsys.readouterr().err.split()))
    # only what is missing is said
    assert main(["bench", "--sb3", str(folder / "runs/dqn0.zip"), "--env", "Acrobot-v1", "--protocol", "monitor",
                 "--variants", "Acrobot-v1:LINK_MASS_2=3.0"]) == 2
    assert (" ".join(capsys.readouterr().err.split()).endswith(
        "--env Acrobot-v1 is an env oodmon has no variants of: bench it with the steps its shifts may begin at "
        "(e.g. --onsets 20,100)"))
    assert main(["bench", "--sb3", str(folder / "runs/dqn0.zip"), "--env", "CartPole-v1", "--detectors", "spread,combined",
                 "--protocol", "monitor", "--out", str(folder / "bench2")]) == 2
    assert "drop spread" in capsys.readouterr().err


def test_the_bench_counts_your_own_envs_fitting_in_the_steps_it_plays_on_for(tmp_path, monkeypatch):
    """Your own env's detectors are fitted on episodes played until they hold a number of steps: the
    bench's progress counts those in steps, as the library's does (it read "45000/45000 episodes")."""
    from oodmon.bench import BenchConfig
    from oodmon.bench.cache import _fit_trial_detectors
    from oodmon.monitor.detectors import fitting

    monkeypatch.setattr(fitting, "DEFAULT_FIT_STEPS", 18_300)  # 90 MountainCar episodes of 200 steps, then 2 more
    DQN("MlpPolicy", gymnasium.make("MountainCar-v0"), seed=0, policy_kwargs={"net_arch": [8]}).save(tmp_path / "mc.zip")
    agent = load_sb3([tmp_path / "mc.zip"], "MountainCar-v0")
    # the model's fit capped at 200 updates (its epochs' count is what is checked, not the model): two
    # thirds of the 92 episodes of 200 steps fit it, 12,200 transitions, 24 batches of 512 an epoch,
    # 8 epochs in 200 updates
    config = BenchConfig("MountainCar-v0", ("sb3",), 1, sb3=(str(tmp_path / "mc.zip"),), env_id="MountainCar-v0",
                         variants=("MountainCar-v0:gravity=0.005",), protocol="monitor", onsets=(50, 100),
                         detectors=("spread", "dynamics"), alarm_detector="dynamics", dynamics_updates=200)
    reports = []
    assert _fit_trial_detectors(config, agent, tmp_path, "sb3 trial 0",
                                lambda stage, done, total: reports.append((stage, done, total))) is not None
    assert ("sb3 trial 0: detector fitting episodes", 90, 90) in reports
    assert ("sb3 trial 0: detector fitting steps", 18_300, 18_300) in reports
    assert reports[-1] == ("sb3 trial 0: dynamics model fitting epochs", 8, 8)  # then the model's fit, in its epochs


def test_bench_runs_the_monitors_protocol_on_shifts_of_your_own_env(tmp_path, capsys):
    """`oodmon bench --sb3 ... --env MountainCar-v0 --protocol monitor --onsets 50,100 --variants
    MountainCar-v0:gravity=0.005`: ID episodes for the false alarms, each shifted episode shifted at
    its own onset in [50, 100), every shift monitored (no failure is told for such an env), cached."""
    DQN("MlpPolicy", gymnasium.make("MountainCar-v0"), seed=0, policy_kwargs={"net_arch": [8]}).save(tmp_path / "mc.zip")
    out = tmp_path / "bench"
    argv = ["bench", "--sb3", str(tmp_path / "mc.zip"), "--env", "MountainCar-v0", "--protocol", "monitor",
            "--onsets", "50,100", "--variants", "MountainCar-v0:gravity=0.005,force=0.0005,MountainCar-v0:gravity=0.01,"
            "MountainCar-v0:low[0]=-2.0",
            "--episodes", "4", "--id-episodes", "8", "--calibration-episodes", "10", "--far", "0.2",
            "--confidence", "none", "--fit-episodes", "10", "--workers", "1", "--out", str(out),
            "--results", str(tmp_path / "mc.json")]
    assert main(argv) == 0
    printed = capsys.readouterr()
    assert "no failure told for MountainCar-v0 (an env oodmon has no variants of)" in printed.out.replace("\n", " ")
    # its observation space's bound, read only when the env is made: the env does not feel it, and is said so
    assert ("MountainCar-v0:low[0]=-2.0: no episode alarmed, and nothing the env returned differed from its own over "
            "200 steps of your policy's actions, shifted from step 50") in " ".join(printed.out.split())
    assert "gravity=0.01: no episode alarmed" not in printed.out
    result = json.loads((tmp_path / "mc.json").read_text())
    assert result["config"]["onsets"] == [50, 100]
    rows = {r["variant"]: r for r in result["alarms"]}
    heavy, pair = rows["MountainCar-v0:gravity=0.01"], rows["MountainCar-v0:force=0.0005,gravity=0.005"]
    assert rows["MountainCar-v0"]["episodes"] == 8 and rows["MountainCar-v0"]["false_alarms"] is not None
    assert heavy["episodes"] == pair["episodes"] == 4 and heavy["failed"] is None
    # gravity x4 from a step in 50-99 of 200, an untrained policy: 3 of 4 alarmed when written
    # (delays 1-2 steps), and its shifted steps ranked at AUROC 0.979 against the ID cell's
    assert heavy["alarmed"] >= 2
    aurocs = {r["variant"]: r["mean"] for r in result["rows"]}
    assert aurocs["MountainCar-v0:gravity=0.01"] > 0.8
    logs = read_logs(sorted(out.glob("logs/MountainCar-v0-*/sb3/trial0/monitor-onsets50-100/*.mcap")))
    onsets = [e.onset for log in logs for e in log.episodes if e.variant != "MountainCar-v0"]
    assert len(onsets) == 12 and all(50 <= onset < 100 for onset in onsets) and len(set(onsets)) > 1
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*.mcap")}
    assert main([*argv[:-2], "--baseline", str(tmp_path / "mc.json")]) == 0  # from the cache, every figure held
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.mcap")} == stamps
    assert "every figure of" in capsys.readouterr().err
    assert main([*argv[:-2], "--failure", "terminated", "--json"]) == 0  # what fails, told: replayed from the cache
    told = {r["variant"]: r for r in json.loads(capsys.readouterr().out)["alarms"]}
    assert told["MountainCar-v0:gravity=0.01"]["failed"] == 0  # an untrained DQN never makes it end the episode
    assert told["MountainCar-v0"]["failed"] == 0 and rows["MountainCar-v0"]["failed"] is None  # nor in ID; untold: blank
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.mcap")} == stamps
    for change, words in [(["--protocol", "paper"], "bench it with the monitor's protocol"),
                          (["--onsets", None], "the steps its shifts may begin at"),
                          (["--variants", "paper"], "shifts of your own"),
                          (["--variants", "Acrobot-v1:LINK_MASS_2=3.0"], "shifts Acrobot-v1, not MountainCar-v0"),
                          (["--variants", "MountainCar-v0"], "the bench runs its ID episodes itself"),
                          (["--onsets", "100,50"], "is not LOW,HIGH"),
                          (["--failure", "fell"], "invalid choice: 'fell'")]:
        changed = list(argv) if change[0] in argv else [*argv, *change]
        at = changed.index(change[0])
        if change[1] is None:
            del changed[at:at + 2]
        else:
            changed[at + 1] = change[1]
        assert main(changed) == 2, change
        assert words in capsys.readouterr().err, change


def test_bench_of_your_own_model_on_a_tasks_gymnasium_env_takes_that_envs_other_attributes_beside_the_tasks_variants(
        tmp_path, capsys):
    """`oodmon bench --sb3 ... --env CartPole-v1` plays oodmon's variants of cartpole and, as `oodmon
    run` does, shifts of CartPole-v1's other attributes (a judge that ends the episode sooner); before
    2026-12-02 the bench refused the second kind. oodmon's physics named on CartPole-v1, or such a
    shift for oodmon's own agents, are refused as before."""
    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [8]}).save(tmp_path / "dqn.zip")
    judge = "CartPole-v1:theta_threshold_radians=0.001"  # the pole starts further over: every step ends the episode
    argv = ["bench", "--sb3", str(tmp_path / "dqn.zip"), "--env", "CartPole-v1", "--protocol", "monitor",
            "--onsets", "0,1", "--variants", f"{judge},cartpole:length=2.0", "--episodes", "4", "--id-episodes", "6",
            "--calibration-episodes", "10", "--far", "0.2", "--confidence", "none", "--fit-episodes", "6",
            "--workers", "1", "--out", str(tmp_path / "bench"), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    rows = {r["variant"]: r for r in result["alarms"]}
    failing = json.loads(next((tmp_path / "bench").glob("logs/*/sb3/trial0/failing.json")).read_text())
    assert failing["returns"][judge] == 1.0 and judge in failing["failing"]  # ended at its first step, from step 0
    assert rows[judge]["episodes"] == 4 and rows[judge]["failed"] == 4
    assert rows[judge]["alarmed"] == 0  # the world the policy reads is the same: no detector sees a judge
    assert rows["cartpole"]["episodes"] == 6
    for variants, words in [("CartPole-v1:length=2.0", "give cartpole:length=2.0"),
                            ("Acrobot-v1:LINK_MASS_2=3.0", "shifts Acrobot-v1, not CartPole-v1"),
                            ("CartPole-v1", "the bench runs its ID episodes itself")]:
        changed = [*argv[:argv.index("--variants") + 1], variants, *argv[argv.index("--variants") + 2:]]
        assert main(changed) == 2, variants
        assert words in capsys.readouterr().err, variants
    # a misspelt attribute: said before the detectors' fit and the calibration (before 2026-12-02,
    # when its cell came, after them), here and in an env oodmon has no variants of
    fresh = [*argv[:argv.index("--out") + 1], str(tmp_path / "fresh"), "--json"]
    fresh[fresh.index("--variants") + 1] = "CartPole-v1:theta_treshold_radians=0.1"
    assert main(fresh) == 2
    assert "CartPole-v1 has no numeric attribute 'theta_treshold_radians' to shift" in capsys.readouterr().err
    assert not list((tmp_path / "fresh").rglob("detectors-*")) and not list((tmp_path / "fresh").rglob("threshold-*"))
    assert main(["bench", "--task", "cartpole", "--methods", "ensemble", "--trials", "1", "--variants", judge,
                 "--out", str(tmp_path / "zoo")]) == 2  # oodmon's agents act in oodmon's envs: its variants only
    assert "(`oodmon run` or `oodmon bench` with --sb3 or --policy and --env CartPole-v1), not with oodmon's cartpole agents" in (
        " ".join(capsys.readouterr().err.split()))


def file_sha256_of_models(*paths: Path) -> str:
    """The bench's stamp of SB3 files: the first 16 hex of their sha256 (one file: its own)."""
    import hashlib

    from oodmon.hashing import file_sha256

    hashes = [file_sha256(p) for p in paths]
    return (hashes[0] if len(hashes) == 1 else hashlib.sha256("\n".join(hashes).encode()).hexdigest())[:16]


@pytest.mark.parametrize("algorithm, env_id", [("PPO", "CartPole-v1"), ("A2C", "CartPole-v1"), ("SAC", "Pendulum-v1")])
def test_ppo_a2c_and_sac_policies_act_as_sb3_does_and_have_no_samples(algorithm, env_id, tmp_path):
    import stable_baselines3

    model = getattr(stable_baselines3, algorithm)("MlpPolicy", gymnasium.make(env_id), seed=0,
                                                  policy_kwargs={"net_arch": [16]})
    model.save(tmp_path / "model.zip")
    agent = load_sb3([tmp_path / "model.zip"], env_id)
    assert agent.estimator is None and agent.method == "sb3"
    loaded = getattr(stable_baselines3, algorithm).load(tmp_path / "model.zip", device="cpu")
    env = gymnasium.make(env_id)
    for seed in range(3):
        obs = env.reset(seed=seed)[0]
        assert np.allclose(agent.act(obs), loaded.predict(obs, deterministic=True)[0])


def test_several_sac_models_are_an_ensemble_of_their_deterministic_actions(tmp_path, capsys):
    """SAC's deterministic action is tanh of its Gaussian's mean, scaled to the action bounds, as
    TD3's actor's: several SAC models form an ensemble whose samples are each model's own
    predict(deterministic=True) (they were refused as an ensemble before; one SAC still has none)."""
    from stable_baselines3 import SAC

    models = [SAC("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=k, learning_starts=100,
                  policy_kwargs={"net_arch": [32, 32]}) for k in range(3)]
    models[0].learn(300)  # a trained actor's means reach past the tanh's linear range
    paths = saved_ensemble_acts_as_its_members(models, tmp_path, "Pendulum-v1", steps=50)
    env = gymnasium.make("Pendulum-v1")
    obs, _ = env.reset(seed=1)
    mean = sb3_agent(models, "Pendulum-v1", mean=True)  # in memory: the same models, no files loaded again
    np.testing.assert_allclose(mean.act(obs), np.mean([m.predict(obs, deterministic=True)[0] for m in models], axis=0),
                               rtol=1e-5, atol=1e-5)
    assert sb3_agent(models[:1], "Pendulum-v1").estimator is None  # one SAC: no samples, the learned detectors watch it
    common = ["--sb3", *map(str, paths), "--env", "Pendulum-v1"]
    assert main(["calibrate", *common, "--episodes", "10", "--far", "0.2", "--confidence", "none",
                 "--fit-episodes", "9", "--out", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["detector"] == "dynamics"  # Pendulum's best
    assert main(["run", *common, "--threshold", str(tmp_path / "t.json"), "--variant", "pendulum:m=5.0",
                 "--onset", "50", "--episodes", "2", "--mcap", str(tmp_path / "x.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "x.mcap"), "--json"]) == 0
    rows = {r["detector"]: r for r in json.loads(capsys.readouterr().out)}
    assert {"spread", "features", "dynamics", "combined"} <= set(rows)  # the ensemble's detectors too
    gsde = SAC("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=0, use_sde=True, policy_kwargs={"net_arch": [16]})
    with pytest.raises(ConfigError, match="cannot form the ensemble"):
        sb3_agent([gsde, gsde], "Pendulum-v1")


def _rewrite_policy_module(path: Path, module: str) -> None:
    """``path``'s ``data`` JSON with its policy class's module renamed (the zip otherwise as SB3 wrote it)."""
    with zipfile.ZipFile(path) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(entries["data"])
    data["policy_class"]["__module__"] = module
    entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)


def test_a_policy_class_of_the_users_own_is_told_by_its_algorithms_hyperparameters(tmp_path):
    # Each of the six algorithms, its policy class renamed into a user's module: still told apart
    # from the hyperparameters it saved, without unpickling anything.
    from stable_baselines3 import A2C, DDPG, PPO, SAC

    for cls, env_id, expected in ((DQN, "CartPole-v1", ("DQN",)), (DDPG, "Pendulum-v1", ("TD3", "DDPG")),
                                  (TD3, "Pendulum-v1", ("TD3", "DDPG")), (SAC, "Pendulum-v1", ("SAC",)),
                                  (PPO, "CartPole-v1", ("PPO",)), (A2C, "CartPole-v1", ("A2C", "PPO"))):
        extra = {"buffer_size": 100} if cls in (DQN, DDPG, TD3, SAC) else {}
        path = tmp_path / f"{cls.__name__}.zip"
        cls("MlpPolicy", gymnasium.make(env_id), seed=0, **extra).save(path)
        _rewrite_policy_module(path, "my_policies")
        assert sb3_algorithm(path) == expected, cls.__name__
    data = json.loads(zipfile.ZipFile(path).read("data"))  # the A2C's, without the hyperparameters that tell it
    for key in ("vf_coef", "gae_lambda", "normalize_advantage", "n_steps", "ent_coef"):
        data.pop(key, None)
    with zipfile.ZipFile(tmp_path / "odd.zip", "w") as archive:
        archive.writestr("data", json.dumps(data))
    with pytest.raises(ConfigError, match="holds a policy of my_policies, and none of the hyperparameters"):
        sb3_algorithm(tmp_path / "odd.zip")
    # A file told as DQN by its hyperparameters must load as a DQN policy (a QR-DQN's subclass would not).
    import stable_baselines3

    from oodmon.agents import sb3

    ppo = PPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(stable_baselines3.DQN, "load", lambda *a, **k: ppo)
        with pytest.raises(ConfigError, match="its policy ActorCriticPolicy is no DQNPolicy"):
            sb3._load_one(tmp_path / "DQN.zip")
    # sb3-contrib's are told by their module (QR-DQN saves DQN's hyperparameters: its module says
    # QR-DQN); one oodmon does not know is refused, naming those it loads.
    _rewrite_policy_module(tmp_path / "DQN.zip", "sb3_contrib.qrdqn.policies")
    assert sb3_algorithm(tmp_path / "DQN.zip") == ("QRDQN",)
    _rewrite_policy_module(tmp_path / "DQN.zip", "sb3_contrib.newer.policies")
    with pytest.raises(ConfigError, match="holds a policy of sb3_contrib.newer.policies; oodmon loads stable-baselines3's "
                                          "DQN, .* and sb3-contrib's QR-DQN, TQC, TRPO, ARS, CrossQ, RecurrentPPO and "
                                          "MaskablePPO models"):
        sb3_algorithm(tmp_path / "DQN.zip")


def test_a_users_dqn_policy_with_dropout_loads_from_its_file_with_fixed_masks(tmp_path, monkeypatch):
    # The way to dropout in an SB3 DQN: a policy class of one's own. Its file loads (the user's module
    # importable, as in their project), and --masks fixed gives K fixed sub-networks of it.
    (tmp_path / "my_dropout_policy.py").write_text(
        "from stable_baselines3.dqn.policies import DQNPolicy\n"
        "from oodmon.agents.layers import add_dropout\n\n\n"
        "class DropoutDQNPolicy(DQNPolicy):\n"
        "    def make_q_net(self):\n"
        "        q_net = super().make_q_net()\n"
        "        q_net.q_net = add_dropout(q_net.q_net, 0.1)\n"
        "        return q_net\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    from my_dropout_policy import DropoutDQNPolicy

    DQN(DropoutDQNPolicy, gymnasium.make("CartPole-v1"), seed=0, buffer_size=100,
        policy_kwargs={"net_arch": [32, 32]}).save(tmp_path / "mine.zip")
    assert sb3_algorithm(tmp_path / "mine.zip") == ("DQN",)
    agent = load_sb3([tmp_path / "mine.zip"], "CartPole-v1", masks="fixed", seed=0)
    obs = np.zeros(4, np.float32)
    first, again = agent.estimator.estimate(obs), agent.estimator.estimate(obs)
    assert agent.estimator.masks == "fixed" and first.samples.shape == (20, 1, 2)
    np.testing.assert_array_equal(first.samples, again.samples)
    assert len({s.tobytes() for s in first.samples}) == 20
    # fixed-decisions: the same K sub-networks; the model's own predict() still decides
    deciding = load_sb3([tmp_path / "mine.zip"], "CartPole-v1", masks="fixed-decisions", seed=0)
    np.testing.assert_array_equal(deciding.estimator.estimate(obs).samples, first.samples)
    model = DQN.load(tmp_path / "mine.zip", device="cpu")
    for o in np.random.default_rng(0).normal(size=(10, 4)).astype(np.float32):
        assert deciding.act(o) == int(model.predict(o, deterministic=True)[0])


def test_the_docs_dropout_policy_example_runs_and_reads_fixed_sub_networks(tmp_path, monkeypatch, capsys):
    # The page's policy class of one's own, its snippet and commands as written, but for a shorter
    # training (600 steps instead of 8,000: what is tested is that the file loads and is read as fixed
    # sub-networks, not the example's numbers).
    from oodmon.monitor import Threshold

    text = PAGE.read_text()
    block = re.search(r"```sh\n(.*?)```", text[text.index("### A policy of your own class, with dropout"):], re.S).group(1)
    policy = re.search(r"<<'PY'\n(.*?)PY\n", block, re.S).group(1)
    python = re.search(r'\.venv/bin/python -c "\n(.*?)\n"\n', block, re.S).group(1)
    assert "model.learn(8000)" in python
    commands = block[block.index('\n"\n') + 3:].replace("\\\n", " ")
    argvs = [shlex.split(line)[1:] for line in commands.splitlines() if line.startswith("oodmon ")]
    assert [a[0] for a in argvs] == ["calibrate", "run", "replay"]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "my_policy.py").write_text(policy)
    monkeypatch.syspath_prepend(str(tmp_path / "runs"))  # the snippet's PYTHONPATH=runs
    monkeypatch.delitem(sys.modules, "my_policy", raising=False)
    exec(compile(python.replace("model.learn(8000)", "model.learn(600)"), "docs dropout snippet", "exec"), {})
    monkeypatch.delitem(sys.modules, "my_policy")  # the commands run in processes of their own: --import names it
    for argv in argvs:
        assert main(argv) == 0, argv
    threshold = Threshold.load("runs/dropout.json")
    assert (threshold.masks, threshold.detector, threshold.score) == ("fixed", "scaled_spread", "margin_std")
    log = read_log("runs/dropout.mcap")
    assert log.metadata["about.masks"] == "fixed" and len(log.episodes) == 5
    assert {"spread", "scaled_spread"} <= set(log.detectors)
    assert "scaled_spread" in capsys.readouterr().out


def test_a_shift_of_your_own_env_runs_from_its_onset_and_replay_counts_it_shifted(tmp_path, capsys):
    """`oodmon run --env MountainCar-v0 --variant MountainCar-v0:gravity=0.005 --onset 50`: the
    policy's own env until step 50, then gravity doubled and more (0.0025 -> 0.005); the log says so,
    and replay ranks its steps from the onset against the ID run's, counts alarms before the onset
    as early and times the others from it; it tells no failure (MountainCar's episode ends when it
    succeeds)."""
    from oodmon.replay import alarm_events, compute_metrics, compute_monitor_metrics, read_logs

    DQN("MlpPolicy", gymnasium.make("MountainCar-v0"), seed=0, policy_kwargs={"net_arch": [8]}).save(tmp_path / "mc.zip")
    own = ["--sb3", str(tmp_path / "mc.zip"), "--env", "MountainCar-v0"]
    assert main(["calibrate", *own, "--episodes", "10", "--fit-episodes", "10", "--far", "0.2", "--confidence", "none",
                 "--out", str(tmp_path / "mc.json")]) == 0
    run = ["run", *own, "--threshold", str(tmp_path / "mc.json"), "--episodes", "4"]
    assert main([*run, "--seed", "100", "--mcap", str(tmp_path / "id.mcap")]) == 0
    assert main([*run, "--seed", "200", "--variant", "MountainCar-v0:gravity=0.005", "--onset", "50",
                 "--mcap", str(tmp_path / "shift.mcap")]) == 0
    capsys.readouterr()
    logs = read_logs([tmp_path / "id.mcap", tmp_path / "shift.mcap"])
    shifted = logs[1].episodes
    assert {(e.variant, e.onset) for e in shifted} == {("MountainCar-v0:gravity=0.005", 50)}
    assert all(e.shifted.tolist() == [False] * 51 + [True] * 149 for e in shifted)  # what step 50 returns on
    # 600 shifted steps against 800 ID steps, every seed fixed: 0.881 measured on 2026-11-29; an
    # unshifted run reads ~0.5 (its steps are ID's), so 0.75 leaves room for other BLAS rounding
    rows = {m.variant: m for m in compute_metrics(logs) if m.detector == "combined"}
    assert rows["MountainCar-v0"].auroc is None and rows["MountainCar-v0:gravity=0.005"].auroc > 0.75
    alarms = {m.variant: m for m in compute_monitor_metrics(logs)}
    assert alarms["MountainCar-v0"].false_alarms is not None  # the ID run: its alarms are false ones
    heavy = alarms["MountainCar-v0:gravity=0.005"]
    assert heavy.alarmed >= 2 and heavy.failed is None and heavy.before_failure is None
    firsts = [min(after) for e in shifted if (after := [s for s in alarm_events(e.alarm) if s >= 50])]
    assert sorted(heavy.delays) == sorted(step - 50 for step in firsts)  # from the onset (after an early one too)
    assert heavy.early == sum(e.first_alarm_step is not None and e.first_alarm_step < 50 for e in shifted)
    logs_named = [str(tmp_path / "id.mcap"), str(tmp_path / "shift.mcap")]
    assert main(["replay", *logs_named, "--plots", str(tmp_path / "plots")]) == 0  # it parsed the spec as oodmon's
    assert main(["replay", "--monitor", *logs_named, "--plots", str(tmp_path / "plots")]) == 0
    footnote = capsys.readouterr().err.splitlines()[-1]  # what failed is, for this env only
    assert footnote.startswith("failed: MountainCar-v0's not told (blank) unless --failure terminated (the env ended the "
                               "episode itself); the ID row's failed: ") and "CartPole" not in footnote
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == [
        "alarms_MountainCar-v0_sb3.png", "auroc_vs_shift_MountainCar-v0.png", "roc_MountainCar-v0_gravity_0.005.png",
        "trace_sb3_MountainCar-v0.png", "trace_sb3_MountainCar-v0_gravity_0.005.png"]
    # told what fails (here, to see the plumbing: the env ending an episode, which this untrained
    # DQN never makes MountainCar do), the failure columns count it; --failure alone is refused
    assert main(["replay", "--monitor", "--json", "--failure", "terminated", *logs_named]) == 0
    told = {r["variant"]: r for r in json.loads(capsys.readouterr().out)}
    assert told["MountainCar-v0:gravity=0.005"]["failed"] == 0 and heavy.failed is None
    assert main(["replay", "--failure", "terminated", *logs_named]) == 2
    assert "give --monitor or --episodes too" in capsys.readouterr().err
    # what a person gets wrong is said in one line
    for variant, words in [("Acrobot-v1:LINK_MASS_2=3.0", "shifts Acrobot-v1, not MountainCar-v0"),
                           ("MountainCar-v0:gravty=0.005", "no numeric attribute 'gravty'.*gravity"),
                           ("MountainCar-v0:gravity", "expected ENV_ID:NAME=VALUE")]:
        assert main([*run, "--variant", variant]) == 2
        assert re.search(words, capsys.readouterr().err)


def test_calibrate_fits_the_drift_detector_when_the_alarm_reads_it_and_run_reads_it_back(readme_run, tmp_path, capsys):
    """`--detector drift` (fitted only when named) fits it beside the default set, whose combined
    then ranks it too; `run` reads the threshold and the detectors beside it."""
    folder, _, _ = readme_run
    model, out = str(folder / "runs/dqn0.zip"), tmp_path / "drift.json"
    assert main(["calibrate", "--sb3", model, "--env", "CartPole-v1", "--detector", "drift", "--episodes", "19",
                 "--confidence", "none", "--fit-episodes", "6", "--out", str(out)]) == 0
    assert "(drift detector" in capsys.readouterr().out
    detectors = json.loads((tmp_path / "drift.json.detectors" / "detectors.json").read_text())["detectors"]
    names = [d["name"] for d in detectors]
    assert names == ["dynamics", "drift", "combined"] and detectors[2]["config"]["members"] == ["dynamics", "drift"]
    assert json.loads(out.read_text())["detector"] == "drift"
    assert main(["run", "--sb3", model, "--env", "CartPole-v1", "--threshold", str(out), "--episodes", "1",
                 "--variant", "cartpole:masscart=3.0", "--onset", "10", "--mcap", str(tmp_path / "d.mcap")]) == 0
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "d.mcap"), "--json"]) == 0
    assert {r["detector"] for r in json.loads(capsys.readouterr().out)} >= {"dynamics", "drift", "combined"}



LOAD_IN_A_NEW_PROCESS = """
import sys
import numpy as np
from stable_baselines3 import SAC
from oodmon.agents.sb3 import load_sb3
agent = load_sb3([sys.argv[1]], "Pendulum-v1")
after_ours = "torch._dynamo" in sys.modules
theirs = SAC.load(sys.argv[1], device="cpu")  # SB3's own load
observations = np.random.default_rng(0).uniform(-1, 1, (5, 3)).astype(np.float32)
same = all(np.array_equal(agent.act(o), theirs.predict(o, deterministic=True)[0]) for o in observations)
print(after_ours, same, "torch._dynamo" in sys.modules)
"""


def test_loading_a_model_builds_its_optimizers_without_importing_dynamo_and_leaves_torch_as_it_was(tmp_path):
    """SB3's load builds each optimizer of the model (a SAC's three), whose first call of a method
    torch wraps to disable dynamo imported torch._dynamo: 1.1 s of every --sb3 command's start.
    In a new process: oodmon's load imports nothing of dynamo and acts as SB3's loaded model does; SB3's own
    load after it imports dynamo as before (torch's wrappers are as they were)."""
    import subprocess

    from stable_baselines3 import SAC

    SAC("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=0, policy_kwargs={"net_arch": [8]}).save(tmp_path / "sac.zip")
    out = subprocess.run([sys.executable, "-c", LOAD_IN_A_NEW_PROCESS, str(tmp_path / "sac.zip")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "True", "True"]
