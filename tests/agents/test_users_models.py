"""Users' own models: an ensemble of their SB3 models, MC Dropout over their torch networks."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG, DQN
from torch import nn

from oodmon.agents import MCEstimator, estimator_from_sb3
from oodmon.errors import ConfigError

OBS = np.random.default_rng(1).normal(size=(5, 3)).astype(np.float32)


def test_ensemble_of_users_ddpg_models_gives_their_actions():
    env = gymnasium.make("Pendulum-v1")
    models = [DDPG("MlpPolicy", env, seed=k, policy_kwargs={"net_arch": [32, 32]}) for k in range(3)]
    estimate = estimator_from_sb3(models).estimate(OBS)
    with torch.no_grad():
        expected = np.stack([m.policy.unscale_action(m.policy.actor(torch.as_tensor(OBS)).numpy()) for m in models])
    np.testing.assert_allclose(estimate.samples, expected, atol=1e-5)
    np.testing.assert_allclose(estimate.action, expected.mean(axis=0), atol=1e-5)
    assert (np.abs(estimate.samples) <= 2.0).all()


def test_ensemble_of_users_dqn_models_predicts_like_them():
    env = gymnasium.make("CartPole-v1")
    models = [DQN("MlpPolicy", env, seed=k) for k in range(4)]
    obs = np.random.default_rng(2).normal(size=(8, 4)).astype(np.float32)
    estimate = estimator_from_sb3(models).estimate(obs)
    for k, model in enumerate(models):
        np.testing.assert_array_equal(estimate.samples[k].argmax(axis=1), model.predict(obs, deterministic=True)[0])


class UsersActor(nn.Module):
    """Not a Sequential: a user's own network with dropout inside."""

    def __init__(self) -> None:
        super().__init__()
        self.body = nn.Linear(3, 64)
        self.drop = nn.Dropout(0.2)
        self.out = nn.Linear(64, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.out(self.drop(torch.relu(self.body(x)))))


def test_mc_dropout_over_a_users_torch_actor():
    torch.manual_seed(0)
    actor = UsersActor().eval()
    estimator = MCEstimator(actor, n_samples=30, kind="actions", action_low=[-2.0], action_high=[2.0], seed=4)
    estimate = estimator.estimate(OBS)
    assert estimate.samples.shape == (30, 5, 1)
    assert len({s.tobytes() for s in estimate.samples}) == 30 and (estimate.std > 0).all()
    assert not actor.training and not actor.drop.training
    with torch.no_grad():
        deterministic = 2.0 * actor(torch.as_tensor(OBS)).numpy()
    np.testing.assert_allclose(estimate.mean, deterministic, atol=0.3)


def test_users_models_errors():
    env = gymnasium.make("CartPole-v1")
    with pytest.raises(ConfigError, match="has no dropout or DropConnect layer"):
        estimator_from_sb3([DQN("MlpPolicy", env, seed=0)])
    with pytest.raises(ConfigError, match="DQN models or DDPG/TD3 models, all of one kind"):
        estimator_from_sb3([DQN("MlpPolicy", env, seed=0), DDPG("MlpPolicy", gymnasium.make("Pendulum-v1"))])
    with pytest.raises(ConfigError, match="needs at least one SB3 model"):
        estimator_from_sb3([])
