"""The SB3 side of a recipe: its training env, its SB3 model (DQN, bootstrapped DQN or DDPG with
oodmon's policies) and the architecture record the model format keeps."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from stable_baselines3 import DDPG, DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.torch_layers import NatureCNN

from oodmon.agents.networks import Architecture
from oodmon.agents.policies import BootstrappedDQN, SampledTargetDQN, UncertainDQNPolicy, UncertainTD3Policy
from oodmon.agents.recipes import Recipe, recipe_architecture
from oodmon.errors import ConfigError
from oodmon.envs.grid import ENV_IDS

__all__ = ["EpisodeSoFar", "algorithm_class", "architecture", "new_model", "recipe_architecture", "training_env"]


def architecture(recipe: Recipe, env: gymnasium.Env) -> Architecture:
    """The architecture record (see ``networks``) of a recipe's agent in ``env``."""
    discrete = isinstance(env.action_space, gymnasium.spaces.Discrete)
    return Architecture(
        obs_shape=env.observation_space.shape,
        n_outputs=int(env.action_space.n) if discrete else int(np.prod(env.action_space.shape)),
        **recipe_architecture(recipe),
    )


class EpisodeSoFar(gymnasium.Wrapper):
    """Keeps what it takes to put the env back where it stands: the seed of the episode's reset,
    the state of the env's generator just before it, and every action since. A training resumed
    from a checkpoint plays that episode again (:meth:`replay`) and goes on from the same step of
    it, as the interrupted training did (the envs' steps draw no random numbers: CartPole's and
    Pendulum's physics, and Pong's emulator with sticky actions off, as oodmon's Pong has them)."""

    def __init__(self, env: gymnasium.Env) -> None:
        super().__init__(env)
        self.started = False  # reset at least once
        self.reset_seed: int | None = None
        self.generator_state: dict | None = None  # None where the reset was seeded (it seeds the generator)
        self.actions: list = []

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.started, self.reset_seed, self.actions = True, seed, []
        self.generator_state = None if seed is not None else self.unwrapped.np_random.bit_generator.state
        return super().reset(seed=seed, options=options)

    def step(self, action):
        self.actions.append(np.array(action))
        return super().step(action)

    @staticmethod
    def replay(env: gymnasium.Env, reset_seed: int | None, generator_state: dict | None, actions) -> np.ndarray:
        """Reset ``env`` (this wrapper, or wrappers around it) as the episode was reset and take its
        actions again; the observation it stands at."""
        if generator_state is not None:
            env.unwrapped.np_random.bit_generator.state = generator_state
        obs, _ = env.reset(seed=reset_seed)
        for action in actions:
            obs, *_ = env.step(action)
        return obs


def training_env(recipe: Recipe) -> gymnasium.Env:
    """The env a recipe trains in: its task's ID env, keeping the episode so far (:class:`EpisodeSoFar`:
    a resumed training plays it again), its rewards reduced to their signs where the recipe clips them."""
    env = EpisodeSoFar(gymnasium.make(ENV_IDS[recipe.task]))
    if recipe.reward_clip:
        env = gymnasium.wrappers.TransformReward(env, lambda r: float(np.sign(r)))
    return env


def new_model(recipe: Recipe, env: gymnasium.Env, seed: int) -> BaseAlgorithm:
    """An untrained SB3 model of the recipe (its algorithm, network and hyperparameters) in ``env``."""
    arch = architecture(recipe, env)
    policy_kwargs: dict[str, Any] = {
        "net_arch": list(recipe.net_arch),
        "stochastic": arch.stochastic,
        "drop_p": recipe.drop_p,
        "last_only": recipe.last_only,
    }
    if recipe.cnn:
        policy_kwargs["features_extractor_class"] = NatureCNN
    common: dict[str, Any] = dict(seed=seed, device="cpu", verbose=0, **recipe.hyperparams)
    if recipe.algorithm == "ddpg":
        n = env.action_space.shape[0]
        scale = recipe.action_noise * (env.action_space.high - env.action_space.low) / 2
        common["action_noise"] = NormalActionNoise(np.zeros(n), scale * np.ones(n))
    elif arch.shared_torso:
        policy_kwargs["n_heads"] = recipe.n_members
    if recipe.target_samples:
        if recipe.algorithm != "dqn" or arch.stochastic is None:
            raise ConfigError(f"target_samples={recipe.target_samples} samples a DQN's dropout or DropConnect target "
                              f"network; the {recipe.task} {recipe.method} recipe has none")
        common["target_samples"] = recipe.target_samples
    policy = UncertainTD3Policy if recipe.algorithm == "ddpg" else UncertainDQNPolicy
    return algorithm_class(recipe)(policy, env, policy_kwargs=policy_kwargs, **common)


def algorithm_class(recipe: Recipe) -> type[BaseAlgorithm]:
    """The SB3 algorithm a recipe trains with: DDPG, DQN, or oodmon's DQNs of a shared torso
    (:class:`BootstrappedDQN`) or of a sampled target (:class:`SampledTargetDQN`)."""
    if recipe.algorithm == "ddpg":
        return DDPG
    if recipe.method == "ensemble" and recipe.shared_torso:
        return BootstrappedDQN
    return SampledTargetDQN if recipe.target_samples else DQN
