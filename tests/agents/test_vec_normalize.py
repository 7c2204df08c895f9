"""SB3 models trained inside VecNormalize: they act on normalised observations, so oodmon deploys
and samples them so, with statistics read from SB3's file without running code from it."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from oodmon.agents.evaluation import episode_returns
from oodmon.agents.sb3 import load_sb3, sb3_agent
from oodmon.agents.vec_normalize import ObservationNormalizer, load_vec_normalize, trained_in_vec_normalize
from oodmon.cli import main
from oodmon.envs.grid import Variant
from oodmon.errors import ConfigError
from oodmon.monitor import MemorySink, Monitor

#: A linear controller that keeps CartPole's pole up for 500 steps from every start tried (push right
#: when 0.1 x + 0.5 x' + 3 theta + theta' > 0), and statistics that move and scale every input.
CONTROLLER = np.array([0.1, 0.5, 3.0, 1.0])
MEAN, VAR = np.array([0.5, -0.2, 0.05, 0.1]), np.array([4.0, 1.0, 0.01, 0.25])


@pytest.fixture(scope="module")
def normalised_ppo(tmp_path_factory):
    """A PPO "trained" inside VecNormalize (a few steps, so that SB3 records it) whose action layer
    is then set to the controller above as it reads normalised observations; its files."""
    folder = tmp_path_factory.mktemp("vecnorm")
    venv = VecNormalize(make_vec_env("CartPole-v1", n_envs=1, seed=0))
    model = PPO("MlpPolicy", venv, seed=0, n_steps=16, batch_size=16, n_epochs=1, policy_kwargs={"net_arch": []})
    model.learn(16)
    venv.obs_rms.mean, venv.obs_rms.var = MEAN.copy(), VAR.copy()
    std = np.sqrt(VAR + venv.epsilon)
    with torch.no_grad():  # logits (0, w . z + b) on normalised z: action 1 where the controller pushes right
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.zero_()
        model.policy.action_net.weight[1] = torch.as_tensor(CONTROLLER * std, dtype=torch.float32)
        model.policy.action_net.bias[1] = float(CONTROLLER @ MEAN)
    model.save(folder / "ppo.zip")
    venv.save(folder / "vecnormalize.pkl")
    return folder, model, venv


def _returns(agent) -> list[float]:
    return episode_returns(agent.act, Variant("cartpole"), 5).tolist()


def test_the_statistics_are_read_as_sb3_reads_them_and_the_policy_acts_as_deployed(normalised_ppo):
    folder, model, venv = normalised_ppo
    normalizer = load_vec_normalize(folder / "vecnormalize.pkl")
    obs = np.random.default_rng(0).normal(size=(50, 4)).astype(np.float32) * [1, 1, 0.2, 1]
    saved = pickle.loads((folder / "vecnormalize.pkl").read_bytes())  # SB3's own reading, here in the test only
    assert np.allclose(normalizer(obs), saved.normalize_obs(obs), atol=1e-6)
    agent = load_sb3([folder / "ppo.zip"], "CartPole-v1", vec_normalize=folder / "vecnormalize.pkl")
    actions = [agent.act(o) for o in obs]
    assert actions == [int(model.predict(venv.normalize_obs(o), deterministic=True)[0]) for o in obs]
    raw = load_sb3([folder / "ppo.zip"], "CartPole-v1", vec_normalize="none")
    assert sum(a != raw.act(o) for a, o in zip(actions, obs)) >= 5  # the raw policy is another policy (9 of 50)
    # Deployed with its statistics it keeps the pole up; fed the env's own observations it does not.
    assert _returns(agent) == [500.0] * 5
    assert max(_returns(raw)) < 100
    assert agent.metadata["vec_normalize"]["sha256"] == normalizer.sha256
    assert agent.metadata["policy_hash"] != raw.metadata["policy_hash"]  # a threshold of one refuses the other
    # the same weights and statistics in memory (the VecNormalize it was trained in): the same policy
    assert sb3_agent([model], "CartPole-v1").metadata["policy_hash"] == agent.metadata["policy_hash"]
    moved = VecNormalize.load(str(folder / "vecnormalize.pkl"), make_vec_env("CartPole-v1", n_envs=1))
    moved.obs_rms.mean = MEAN + 0.01  # other statistics: another policy
    assert sb3_agent([model], "CartPole-v1", vec_normalize=moved).metadata["policy_hash"] != agent.metadata["policy_hash"]


def test_a_ppo_trained_inside_vecnormalize_is_refused_without_its_statistics(normalised_ppo, tmp_path, capsys):
    folder, _, _ = normalised_ppo
    assert trained_in_vec_normalize(folder / "ppo.zip")
    with pytest.raises(ConfigError, match=r"trained inside VecNormalize.*--vec-normalize vecnormalize.pkl"):
        load_sb3([folder / "ppo.zip"], "CartPole-v1")
    PPO("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, n_steps=16, batch_size=16).learn(16).save(tmp_path / "plain.zip")
    assert not trained_in_vec_normalize(tmp_path / "plain.zip")
    load_sb3([tmp_path / "plain.zip"], "CartPole-v1")  # a PPO trained on raw observations loads as before
    out = str(tmp_path / "t.json")
    assert main(["calibrate", "--sb3", str(folder / "ppo.zip"), "--env", "CartPole-v1", "--out", out]) == 2
    assert "--vec-normalize" in capsys.readouterr().err
    assert main(["calibrate", "--task", "cartpole", "--method", "ensemble", "--vec-normalize", "x.pkl", "--out", out]) == 2
    assert "--vec-normalize go with --sb3" in capsys.readouterr().err
    assert main(["calibrate", "--sb3", str(folder / "ppo.zip"), "--env", "CartPole-v1", "--vec-normalize",
                 str(tmp_path / "missing.pkl"), "--out", out]) == 2
    assert "missing.pkl does not exist" in capsys.readouterr().err
    # (a device was said not to exist until 2026-12-05)
    for wrong, said in ((tmp_path, "is a folder"), (folder / "ppo.zip", "is not a VecNormalize statistics file ("),
                        ("/dev/zero", "/dev/zero is not a regular file (a device or a pipe)")):
        assert main(["calibrate", "--sb3", str(folder / "ppo.zip"), "--env", "CartPole-v1", "--vec-normalize", str(wrong),
                     "--out", out]) == 2
        err = capsys.readouterr().err
        assert said in err and err.count("\n") == 1  # one line
    pendulum = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    pendulum.save(tmp_path / "pendulum.pkl")
    with pytest.raises(ConfigError, match=r"observations of shape \(3,\); CartPole-v1's are \(4,\)"):
        load_sb3([folder / "ppo.zip"], "CartPole-v1", vec_normalize=tmp_path / "pendulum.pkl")


class _Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


@pytest.mark.parametrize("payload", ["system", "eval", "nested", "not a pickle"])
def test_a_statistics_file_that_would_run_code_is_refused_unrun(payload, normalised_ppo, tmp_path):
    marker = tmp_path / "ran"
    folder, _, venv = normalised_ppo
    if payload == "system":
        data = pickle.dumps(_Payload(marker))
    elif payload == "eval":
        data = pickle.dumps(eval)  # a builtin named by the file
    elif payload == "nested":  # a genuine file with the payload inside one of its attributes
        venv.old_reward = _Payload(marker)
        try:
            data = pickle.dumps(venv)
        finally:
            venv.old_reward = np.zeros(1)
    else:
        data = b"hello"
    (tmp_path / "evil.pkl").write_bytes(data)
    with pytest.raises(ConfigError, match="is not a VecNormalize statistics file"):
        load_vec_normalize(tmp_path / "evil.pkl")
    assert not marker.exists()


def test_a_damaged_statistics_file_is_refused_in_one_line_wherever_it_is_damaged(normalised_ppo, tmp_path):
    """Cut at every 7th byte or with one of 300 bits flipped (seeded), the file either still reads
    (a flipped digit of a number: its sha256 then binds thresholds to the damaged one) or is refused
    with a ConfigError naming it; nothing else is raised. Before 2026-11-27 a flipped length made the
    unpickler allocate what it named first: MemoryError, and a message of its empty text "()"."""
    import random

    raw = (normalised_ppo[0] / "vecnormalize.pkl").read_bytes()
    damaged = tmp_path / "damaged.pkl"
    rng = random.Random(0)
    cases = [raw[:cut] for cut in range(0, len(raw), 7)]
    for _ in range(300):
        data = bytearray(raw)
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        cases.append(bytes(data))
    refused = 0
    for data in cases:
        damaged.write_bytes(data)
        try:
            load_vec_normalize(damaged)
        except ConfigError as error:
            assert str(error).startswith(f"--vec-normalize {damaged}") and not str(error).endswith("()"), error
            refused += 1
    assert refused >= len(cases) // 2  # every cut but the whole file's, and most flips (measured: 2,328 of 2,912)
    # An opcode damaged into BYTEARRAY8 reads the next 8 bytes as a length: named, not allocated.
    import pickletools

    position = next(pos for op, _, pos in pickletools.genops(raw) if op.name == "SHORT_BINBYTES")
    data = bytearray(raw)
    data[position] = 0x96  # BYTEARRAY8
    damaged.write_bytes(bytes(data))
    with pytest.raises(ConfigError, match=r"expected \d+ bytes in a bytearray8, but only \d+ remain"):
        load_vec_normalize(damaged)


def test_models_in_memory_use_the_vecnormalize_they_were_trained_in(normalised_ppo):
    _, model, venv = normalised_ppo
    obs = np.random.default_rng(1).normal(size=(20, 4)).astype(np.float32)
    agent = sb3_agent([model], "CartPole-v1")  # model.get_vec_normalize_env() is venv
    assert [agent.act(o) for o in obs] == [int(model.predict(venv.normalize_obs(o), deterministic=True)[0]) for o in obs]
    assert agent.metadata["vec_normalize"]["path"] == "(in memory)"
    plain = sb3_agent([model], "CartPole-v1", vec_normalize="none")
    assert "vec_normalize" not in plain.metadata
    with pytest.raises(ConfigError, match="vec_normalize=3"):
        sb3_agent([model], "CartPole-v1", vec_normalize=3)


def test_an_ensembles_samples_and_the_monitor_read_normalised_observations(normalised_ppo, tmp_path):
    # DQN files cannot tell whether VecNormalize trained them (SB3 keeps the raw observation either
    # way): given the statistics, the ensemble's samples are those of the normalised observations.
    folder, _, venv = normalised_ppo
    for k in range(2):
        DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=k, policy_kwargs={"net_arch": [16]}).save(tmp_path / f"{k}.zip")
    paths = [tmp_path / "0.zip", tmp_path / "1.zip"]
    agent = load_sb3(paths, "CartPole-v1", vec_normalize=folder / "vecnormalize.pkl")
    raw = load_sb3(paths, "CartPole-v1")
    obs = np.array([0.3, -0.5, 0.04, 0.2], np.float32)
    assert np.allclose(agent.estimate(obs).samples, raw.estimate(venv.normalize_obs(obs)).samples, atol=1e-6)
    assert not np.allclose(agent.estimate(obs).samples, raw.estimate(obs).samples)
    sink = MemorySink()
    monitor = Monitor(agent, 1e9, sinks=[sink])
    monitor.begin_episode()
    assert monitor.step(obs) == agent.act(obs)
    record = sink.steps[0]
    assert np.allclose(record.observation, obs)  # the log keeps the env's own observation
    assert np.allclose(record.mean, agent.estimate(obs).mean[0])  # and the samples of the normalised one


def test_bench_keys_its_cache_by_the_statistics_too(normalised_ppo, tmp_path):
    from oodmon.bench import BenchConfig
    from oodmon.bench.cache import Sb3Models, _weights_sha256

    folder, _, _ = normalised_ppo
    paths = (str(folder / "ppo.zip"),)
    stats = str(folder / "vecnormalize.pkl")
    with_stats = _weights_sha256(Sb3Models(paths, "CartPole-v1", vec_normalize=stats))
    assert with_stats != _weights_sha256(Sb3Models(paths, "CartPole-v1", vec_normalize="none"))
    agent = load_sb3(list(paths), "CartPole-v1", vec_normalize=stats)
    assert agent.metadata["files_hash"] == "sha256:" + with_stats  # the cache's key is of the files
    with pytest.raises(ConfigError, match="vec_normalize, frame_stack, imports and unsafe_load_pickles are how sb3"):
        BenchConfig("cartpole", ("ensemble",), 1, "paper", vec_normalize=stats)


def test_statistics_that_do_not_normalise_observations_leave_them_as_they_are(normalised_ppo, tmp_path):
    folder, model, _ = normalised_ppo
    rewards_only = VecNormalize(make_vec_env("CartPole-v1", n_envs=1, seed=0), norm_obs=False, norm_reward=True)
    rewards_only.save(tmp_path / "rewards.pkl")
    agent = load_sb3([folder / "ppo.zip"], "CartPole-v1", vec_normalize=tmp_path / "rewards.pkl")
    obs = np.array([0.3, -0.5, 0.04, 0.2], np.float32)
    assert agent.act(obs) == int(model.predict(obs, deterministic=True)[0])
    assert agent.metadata["vec_normalize"]["norm_obs"] is False
    in_memory = load_sb3([folder / "ppo.zip"], "CartPole-v1", vec_normalize=rewards_only)  # files and a VecNormalize
    assert in_memory.act(obs) == agent.act(obs)


def test_the_normalizer_clips_as_vecnormalize_does():
    normalizer = ObservationNormalizer(np.zeros(2), np.ones(2), epsilon=0.0, clip_obs=5.0)
    assert normalizer(np.array([100.0, -2.0])).tolist() == [5.0, -2.0]
    assert ObservationNormalizer(None, None)(np.array([100.0])).tolist() == [100.0]  # norm_obs=False


class _Split(gymnasium.ObservationWrapper):
    """CartPole's observation as a dict: the cart ("cart": x, x'), the pole ("pole": theta, theta')
    and a discrete key ("side": whether the pole leans right), named so that the dict's flattened
    order (cart, pole, side... sorted: cart, pole, side) differs from the keys VecNormalize normalises."""

    def __init__(self) -> None:
        super().__init__(gymnasium.make("CartPole-v1"))
        box = self.env.observation_space
        self.observation_space = gymnasium.spaces.Dict({
            "pole": gymnasium.spaces.Box(box.low[2:], box.high[2:], dtype=box.dtype),
            "cart": gymnasium.spaces.Box(box.low[:2], box.high[:2], dtype=box.dtype),
            "side": gymnasium.spaces.Discrete(2)})

    def observation(self, obs):
        return {"cart": obs[:2], "pole": obs[2:], "side": int(obs[2] > 0)}


if "SplitCartPoleForVecNormalize-v1" not in gymnasium.registry:
    gymnasium.register("SplitCartPoleForVecNormalize-v1", entry_point=_Split, max_episode_steps=500)


@pytest.mark.parametrize("keys", [["pole", "cart"], ["pole"]])
def test_dict_observations_are_normalised_key_by_key_as_vecnormalize_does(keys, tmp_path):
    # MultiInputPolicy DQNs inside VecNormalize(norm_obs_keys=keys), statistics that move and scale
    # every number: the ensemble's samples are each model's Q-values at VecNormalize's own
    # normalisation of the dict, the deployed action its predict() there; the keys not listed, and
    # the discrete one, pass as they are.
    env_id = "SplitCartPoleForVecNormalize-v1"
    venv = VecNormalize(make_vec_env(env_id, n_envs=1, seed=0), norm_obs_keys=keys)
    models = [DQN("MultiInputPolicy", venv, seed=k, learning_starts=1000, policy_kwargs={"net_arch": [16]}) for k in range(2)]
    models[0].learn(20)  # VecNormalize's statistics move; then set to numbers far from 0 and 1
    venv.obs_rms["pole"].mean, venv.obs_rms["pole"].var = np.array([0.05, 0.1]), np.array([0.01, 0.25])
    if "cart" in keys:
        venv.obs_rms["cart"].mean, venv.obs_rms["cart"].var = np.array([0.5, -0.2]), np.array([4.0, 1.0])
    for k, model in enumerate(models):
        model.save(tmp_path / f"{k}.zip")
    venv.save(tmp_path / "vecnormalize.pkl")
    agent = load_sb3([tmp_path / "0.zip", tmp_path / "1.zip"], env_id, vec_normalize=tmp_path / "vecnormalize.pkl")
    assert agent.metadata["vec_normalize"]["norm_obs_keys"] == sorted(keys)
    raw = load_sb3([tmp_path / "0.zip", tmp_path / "1.zip"], env_id, vec_normalize="none")
    env = gymnasium.make(env_id)
    obs, _ = env.reset(seed=0)
    moved = 0
    for _ in range(15):
        normalised = venv.normalize_obs({key: value[None] if key != "side" else np.array([value])
                                         for key, value in obs.items()})
        with torch.no_grad():
            theirs = [m.q_net(m.policy.obs_to_tensor(normalised)[0])[0].numpy() for m in models]
        flat = agent.view(obs)
        np.testing.assert_allclose(agent.estimate(flat).samples[:, 0], theirs, rtol=1e-5, atol=1e-5)
        assert agent.act(flat) == int(models[0].predict(normalised, deterministic=True)[0][0])
        moved += not np.allclose(agent.estimate(flat).samples, raw.estimate(flat).samples)
        obs, _, terminated, truncated, _ = env.step(agent.act(flat))
        if terminated or truncated:
            obs, _ = env.reset()
    assert moved == 15  # the statistics change what the networks see at every step


def test_statistics_of_dicts_and_of_arrays_are_not_mixed_up(normalised_ppo, tmp_path):
    folder, _, _ = normalised_ppo
    env_id = "SplitCartPoleForVecNormalize-v1"
    venv = VecNormalize(make_vec_env(env_id, n_envs=1, seed=0), norm_obs_keys=["pole"])
    DQN("MultiInputPolicy", venv, seed=0, policy_kwargs={"net_arch": [16]}).save(tmp_path / "dict.zip")
    venv.save(tmp_path / "dict.pkl")
    with pytest.raises(ConfigError, match=r"are of array observations; SplitCartPoleForVecNormalize-v1's are Dict"):
        load_sb3([tmp_path / "dict.zip"], env_id, vec_normalize=folder / "vecnormalize.pkl")
    with pytest.raises(ConfigError, match=r"are of dict observations; CartPole-v1's are Box"):
        load_sb3([folder / "ppo.zip"], "CartPole-v1", vec_normalize=tmp_path / "dict.pkl")
    normalizer = load_vec_normalize(tmp_path / "dict.pkl")
    other = gymnasium.spaces.Dict({"pole": gymnasium.spaces.Box(-1, 1, (3,)), "cart": gymnasium.spaces.Box(-1, 1, (2,))})
    with pytest.raises(ConfigError, match=r"statistics of key 'pole' are of shape \(2,\)"):
        normalizer.flattened(other)
    with pytest.raises(ConfigError, match=r"normalise the keys \['pole'\], which the observations"):
        normalizer.flattened(gymnasium.spaces.Dict({"cart": gymnasium.spaces.Box(-1, 1, (2,))}))
    with pytest.raises(ConfigError, match=r"flattened\(dict_space\) reads the flattened vectors"):
        normalizer(np.zeros(5, np.float32))
