"""Users' own models: an ensemble of their SB3 models, MC Dropout over their torch networks."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG, DQN
from torch import nn

from oodmon.agents import MCEstimator, estimator_from_sb3
from oodmon.agents.layers import add_dropout
from oodmon.errors import ConfigError

OBS = np.random.default_rng(1).normal(size=(5, 3)).astype(np.float32)
OBS4 = np.random.default_rng(1).normal(size=(5, 4)).astype(np.float32)


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
    with pytest.raises(ConfigError, match="DQN models, DDPG/TD3 models or SAC models, all of one kind"):
        estimator_from_sb3([DQN("MlpPolicy", env, seed=0), DDPG("MlpPolicy", gymnasium.make("Pendulum-v1"))])
    with pytest.raises(ConfigError, match="needs at least one SB3 model"):
        estimator_from_sb3([])


def _dqn_with_dropout(seed: int = 0) -> DQN:
    """A user's DQN whose Q-network has dropout after its hidden layers (acting with it off, as SB3's
    predict() does)."""
    model = DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=seed, policy_kwargs={"net_arch": [32, 32]})
    model.policy.q_net.q_net = add_dropout(model.policy.q_net.q_net, 0.2)
    return model


def test_one_users_model_with_dropout_can_fix_its_masks():
    # Fixed masks: sample k is one sub-network at every decision (the same obs, the same samples),
    # each of them one dropout mask of the model's (its Q-values are the plain network's with that
    # mask); the decision stays the mean of freshly sampled masks, the sampled estimator's own.
    from oodmon.agents.sb3 import sb3_agent

    model = _dqn_with_dropout()
    fixed = estimator_from_sb3([model], n_samples=10, seed=3, masks="fixed")
    sampled = estimator_from_sb3([model], n_samples=10, seed=3)
    first, again, other = fixed.estimate(OBS4), fixed.estimate(OBS4), sampled.estimate(OBS4)
    np.testing.assert_array_equal(first.samples, again.samples)
    assert len({s.tobytes() for s in first.samples}) == 10
    np.testing.assert_array_equal(first.action, other.action)  # the decision: sampled masks, the same seed
    # Sample k is the user's network with dropout mask k (the kept units scaled by 1/(1-p)) at every layer.
    net = model.policy.q_net.q_net  # Linear, ReLU, Dropout, Linear, ReLU, Dropout, Linear
    masks = [op.keep for op in fixed._fixed if hasattr(op, "keep")]  # (K, 1, 32) each, the scale folded in
    assert len(masks) == 2 and all(np.isin(m, [0.0, 1.25]).all() and (m == 0).any() for m in masks)
    with torch.no_grad():
        for k in range(10):
            h = torch.relu(net[0](torch.as_tensor(OBS4))) * torch.as_tensor(masks[0][k])
            q = net[6](torch.relu(net[3](h)) * torch.as_tensor(masks[1][k]))
            np.testing.assert_allclose(first.samples[k], q.numpy(), rtol=1e-5, atol=1e-6)
    agent = sb3_agent([model], "CartPole-v1", masks="fixed", seed=3)
    assert agent.estimator.masks == "fixed" and agent.method == "sb3"
    # Its threshold records the masks, and the monitor refuses it for the same model sampled anew.
    from oodmon.monitor import Monitor
    from oodmon.monitor.calibration import calibrate_agent

    threshold = calibrate_agent(agent, episodes=45)
    assert threshold.masks == "fixed" and threshold.detector == "spread"
    Monitor(agent, threshold)
    with pytest.raises(ConfigError, match="calibrated for masks 'fixed', not 'sampled'"):
        Monitor(sb3_agent([model], "CartPole-v1", seed=3), threshold)
    with pytest.raises(ConfigError, match="has no dropout or DropConnect layer"):
        sb3_agent([DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0)], "CartPole-v1", masks="fixed")
    with pytest.raises(ConfigError, match="for one DQN, DDPG/TD3 or SAC model with dropout"):
        sb3_agent([model, _dqn_with_dropout(1)], "CartPole-v1", masks="fixed")
    with pytest.raises(ConfigError, match="whose members are fixed already"):
        estimator_from_sb3([model, _dqn_with_dropout(1)], masks="fixed")
