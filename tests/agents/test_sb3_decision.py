"""Your own SB3 policy decides as its predict(obs, deterministic=True) does, float for float, without
the evaluation-mode walk and the distribution predict() builds at every call."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3
from torch import nn

from oodmon.agents.sb3 import load_sb3
from oodmon.agents.sb3_decision import decision


def _observations(space: gymnasium.Space, n: int) -> list:
    space.seed(0)
    return [space.sample() for _ in range(n)]


def _same(ours, theirs) -> bool:
    ours, theirs = np.asarray(ours), np.asarray(theirs)
    return ours.shape == theirs.shape and ours.dtype == theirs.dtype and np.array_equal(ours, theirs)


MODELS = [
    (PPO, "Acrobot-v1", "MlpPolicy"),       # Categorical: its probs' argmax
    (PPO, "Pendulum-v1", "MlpPolicy"),      # diagonal Gaussian: its mean, clipped to the space
    (A2C, "CartPole-v1", "MlpPolicy"),
    (DQN, "CartPole-v1", "MlpPolicy"),      # its own _predict (Q-values' argmax)
    (SAC, "Pendulum-v1", "MlpPolicy"),      # tanh of the Gaussian's mean, unscaled to the space
    (TD3, "MountainCarContinuous-v0", "MlpPolicy"),
    (DDPG, "Pendulum-v1", "MlpPolicy"),
]
try:  # sb3-contrib's (the dev extra installs it): TRPO's policy is PPO's, the others' their own
    from sb3_contrib import ARS, QRDQN, TQC, TRPO, CrossQ
    MODELS += [(TRPO, "Acrobot-v1", "MlpPolicy"), (QRDQN, "CartPole-v1", "MlpPolicy"),
               (TQC, "Pendulum-v1", "MlpPolicy"), (ARS, "Pendulum-v1", "LinearPolicy"),
               (CrossQ, "Pendulum-v1", "MlpPolicy")]  # CrossQ: batch renormalisation, another output in training mode
except ImportError:
    pass


@pytest.mark.parametrize(("algorithm", "env_id", "policy"), MODELS, ids=lambda x: getattr(x, "__name__", x))
def test_the_decision_is_predicts_float_for_float(algorithm, env_id, policy):
    env = gymnasium.make(env_id)
    model = algorithm(policy, env, seed=0, device="cpu")
    decide = decision(model)
    assert decide is not None
    for obs in _observations(env.observation_space, 300):  # far outside the ID states too: the space's whole box
        assert _same(decide(obs), model.predict(obs, deterministic=True)[0]), obs
    batch = np.stack(_observations(env.observation_space, 8))  # a vectorized observation keeps its batch axis
    assert _same(decide(batch), model.predict(batch, deterministic=True)[0])


def test_a_categorical_policy_of_near_ties_decides_as_its_probabilities_do():
    """Logits that differ in their last bits: the decision is the argmax of the probabilities torch's
    Categorical computes from them (as predict() takes it), not of the raw logits."""
    env = gymnasium.make("CartPole-v1")
    model = PPO("MlpPolicy", env, seed=0, device="cpu")
    with torch.no_grad():
        model.policy.action_net.weight.mul_(1e-6)  # logits within float rounding of each other
        model.policy.action_net.bias.zero_()
    decide, observations = decision(model), _observations(env.observation_space, 500)
    assert all(int(decide(obs)) == int(model.predict(obs, deterministic=True)[0]) for obs in observations)
    with torch.no_grad():  # the raw logits' argmax, which would decide otherwise somewhere: the ties are real
        logits = model.policy.action_net(model.policy.mlp_extractor.forward_actor(torch.as_tensor(np.stack(observations))))
    raw = logits.argmax(dim=1).numpy()
    assert any(r != int(model.predict(obs, deterministic=True)[0]) for r, obs in zip(raw, observations))


def test_a_policy_left_in_training_mode_decides_in_evaluation_mode_as_predict_does():
    """A model trained further in memory is left in training mode by SB3's learn(): its dropout is
    then on. predict() puts it in evaluation mode at every call; so does the decision, when needed."""
    env = gymnasium.make("Acrobot-v1")
    model = PPO("MlpPolicy", env, seed=0, device="cpu")
    model.policy.mlp_extractor.policy_net.append(nn.Dropout(0.5))
    decide = decision(model)
    obs = _observations(env.observation_space, 50)
    model.policy.set_training_mode(True)
    assert model.policy.mlp_extractor.policy_net[-1].training
    ours = [decide(o) for o in obs]
    assert not any(m.training for m in model.policy.modules())  # as predict() leaves it
    model.policy.set_training_mode(True)
    assert all(_same(a, model.predict(o, deterministic=True)[0]) for a, o in zip(ours, obs))
    model.policy.mlp_extractor.policy_net[-1].train()  # one module alone back in training mode
    assert all(_same(decide(o), model.predict(o, deterministic=True)[0]) for o in obs)


def test_policies_it_does_not_know_keep_predict():
    env = gymnasium.make("Pendulum-v1")
    sde = PPO("MlpPolicy", env, use_sde=True, seed=0, device="cpu")  # gSDE: its own distribution
    assert _same(decision(sde)(np.zeros(3, np.float32)), sde.predict(np.zeros(3, np.float32), deterministic=True)[0])

    class Shifted(PPO):  # an algorithm whose predict() does more than its policy's
        def predict(self, observation, state=None, episode_start=None, deterministic=False):
            action, state = super().predict(observation, state, episode_start, deterministic)
            return action + 0.5, state

    assert decision(Shifted("MlpPolicy", env, seed=0, device="cpu")) is None
    multi = gymnasium.make("CartPole-v1")
    multi.action_space = gymnasium.spaces.MultiDiscrete([2, 3])
    model = PPO("MlpPolicy", multi, seed=0, device="cpu")  # multi-discrete: read through its own _predict
    for obs in _observations(multi.observation_space, 50):
        assert _same(decision(model)(obs), model.predict(obs, deterministic=True)[0])


def test_a_loaded_policys_act_is_its_predict(tmp_path):
    """What the monitor calls: agent.act of a saved model, through load_sb3."""
    env = gymnasium.make("Acrobot-v1")
    PPO("MlpPolicy", env, seed=0, device="cpu").save(tmp_path / "ppo.zip")
    agent, model = load_sb3([tmp_path / "ppo.zip"], "Acrobot-v1"), PPO.load(tmp_path / "ppo.zip", device="cpu")
    for obs in _observations(env.observation_space, 100):
        action = agent.act(obs)
        assert isinstance(action, int) and action == int(model.predict(obs, deterministic=True)[0])


def test_an_observation_reaches_the_policy_as_sb3_makes_it_a_tensor():
    """The flat Box space's own path (np.array, the shape's check, torch.as_tensor) takes what
    predict() takes: a list, float64, a batch; an observation of another shape gets SB3's error."""
    env = gymnasium.make("Pendulum-v1")
    model = PPO("MlpPolicy", env, seed=0, device="cpu")
    decide = decision(model)
    for obs in ([0.5, -0.5, 1.0], np.array([0.5, -0.5, 1.0]), np.array([[0.5, -0.5, 1.0], [1.0, 0.0, -3.0]])):
        assert _same(decide(obs), model.predict(obs, deterministic=True)[0])
    with pytest.raises(ValueError, match=r"Unexpected observation shape \(4,\) for Box environment"):
        decide(np.zeros(4))
    with pytest.raises(ValueError, match=r"Unexpected observation shape \(4,\) for Box environment"):
        model.predict(np.zeros(4), deterministic=True)


SB3_OWN = [(PPO, "Acrobot-v1"), (PPO, "Pendulum-v1"), (A2C, "CartPole-v1"), (DQN, "CartPole-v1"),
           (SAC, "Pendulum-v1"), (TD3, "Pendulum-v1"), (DDPG, "Pendulum-v1")]


@pytest.mark.parametrize(("algorithm", "env_id"), SB3_OWN, ids=lambda x: getattr(x, "__name__", x))
def test_sb3s_own_policies_decide_without_a_module_call_and_predict_makes_them(algorithm, env_id, monkeypatch):
    """The networks of SB3's own policies run layer by layer (each layer's forward, what __call__ runs
    when no hook is set): no Module.__call__ in a decision, where predict() makes several."""
    env = gymnasium.make(env_id)
    model = algorithm("MlpPolicy", env, seed=0, device="cpu")
    decide, observations = decision(model), _observations(env.observation_space, 20)
    calls = []
    original = nn.Module._call_impl

    def counted(self, *args, **kwargs):
        calls.append(type(self).__name__)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(nn.Module, "_call_impl", counted)
    ours = [decide(obs) for obs in observations]
    assert calls == []
    theirs = [model.predict(obs, deterministic=True)[0] for obs in observations]
    assert len(calls) >= 3 * len(observations) and "Linear" in calls
    assert all(_same(a, b) for a, b in zip(ours, theirs))


@pytest.mark.parametrize(("algorithm", "env_id", "layer"), [
    (PPO, "Acrobot-v1", lambda model: model.policy.action_net),
    (DQN, "CartPole-v1", lambda model: model.policy.q_net.q_net[-1]),
    (SAC, "Pendulum-v1", lambda model: model.policy.actor.mu),
    (TD3, "Pendulum-v1", lambda model: model.policy.actor.mu[0]),
], ids=["PPO", "DQN", "SAC", "TD3"])
def test_a_hook_set_after_the_decision_was_made_runs_as_predict_runs_it(algorithm, env_id, layer):
    """A forward hook that changes a layer's output, a pre-hook, a global hook: the decision then calls
    the modules as predict() does, and acts on what the hook made of them."""
    env = gymnasium.make(env_id)
    model = algorithm("MlpPolicy", env, seed=0, device="cpu")
    decide, observations = decision(model), _observations(env.observation_space, 100)
    plain = [decide(obs) for obs in observations]
    handle = layer(model).register_forward_hook(lambda module, args, out: out * -3.0 + 0.7)
    hooked = [decide(obs) for obs in observations]
    assert all(_same(a, model.predict(obs, deterministic=True)[0]) for a, obs in zip(hooked, observations))
    assert any(not _same(a, b) for a, b in zip(hooked, plain))  # the hook did change decisions
    handle.remove()
    assert all(_same(decide(obs), b) for obs, b in zip(observations, plain))
    seen = []
    handle = layer(model).register_forward_pre_hook(lambda module, args: seen.append(module) or None)
    decide(observations[0])
    assert seen == [layer(model)]
    handle.remove()
    handle = torch.nn.modules.module.register_module_forward_hook(lambda module, args, out: seen.append(module))
    try:
        decide(observations[0])
    finally:
        handle.remove()
    assert layer(model) in seen[1:]


def test_a_users_own_extractor_method_is_called_as_predict_calls_it():
    """An MlpExtractor whose forward_actor is the user's own: called as a whole, not replaced by its
    policy_net's layers."""
    from stable_baselines3.common.torch_layers import MlpExtractor

    class Mirrored(MlpExtractor):
        def forward_actor(self, features):
            return -self.policy_net(features)

    env = gymnasium.make("Acrobot-v1")
    model = PPO("MlpPolicy", env, seed=0, device="cpu")
    model.policy.mlp_extractor.__class__ = Mirrored
    decide, observations = decision(model), _observations(env.observation_space, 300)
    ours = [decide(obs) for obs in observations]
    assert all(_same(a, model.predict(obs, deterministic=True)[0]) for a, obs in zip(ours, observations))
    model.policy.mlp_extractor.__class__ = MlpExtractor  # the layers alone would have decided otherwise
    assert any(not _same(a, model.predict(obs, deterministic=True)[0]) for a, obs in zip(ours, observations))
