"""stable-baselines3 policies whose networks carry what an uncertainty method needs.

- :class:`UncertainDQNPolicy`: DQN (MLP or Nature CNN) with dropout or DropConnect in its
  Q-network, or with K bootstrapped heads on a shared torso (:class:`QHeads`).
- :class:`UncertainTD3Policy`: DDPG/TD3 whose actor has dropout or DropConnect.

They extend SB3 at its documented seams (``make_q_net``, ``make_actor``), so the optimizer is
built over the modified networks and SB3's training loop runs unchanged; only the bootstrapped
heads need their own loss (:class:`BootstrappedDQN`), and :class:`SampledTargetDQN` reads its
target network through MC samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import DQN
from stable_baselines3.dqn.policies import DQNPolicy
from stable_baselines3.td3.policies import TD3Policy
from torch import nn

from oodmon.agents.layers import add_dropout, mc_sampling, to_dropconnect
from oodmon.errors import InvalidParameterError

__all__ = ["STOCHASTIC_LAYERS", "BootstrappedDQN", "QHeads", "SampledTargetDQN", "UncertainDQNPolicy",
           "UncertainTD3Policy"]

#: The ways to make a network stochastic for MC sampling.
STOCHASTIC_LAYERS = {"dropout": add_dropout, "dropconnect": to_dropconnect}


def _make_stochastic(mlp: nn.Sequential, stochastic: str | None, drop_p: float, last_only: bool) -> nn.Sequential:
    if stochastic is None:
        return mlp
    if stochastic not in STOCHASTIC_LAYERS:
        raise InvalidParameterError(
            f"stochastic={stochastic!r} is not allowed; use None, {', '.join(map(repr, STOCHASTIC_LAYERS))}"
        )
    return STOCHASTIC_LAYERS[stochastic](mlp, drop_p, last_only=last_only)


class QHeads(nn.Module):
    """K Q-value heads on one feature vector; ``forward`` returns their mean (batch, actions).

    ``all_heads`` returns every head's Q-values, (K, batch, actions).
    """

    def __init__(self, template: nn.Sequential, n_heads: int) -> None:
        super().__init__()
        if n_heads < 2:
            raise InvalidParameterError(f"n_heads={n_heads!r} is not allowed; bootstrapped heads need at least 2")
        heads = [template]
        for _ in range(n_heads - 1):
            head = _fresh_copy(template)
            heads.append(head)
        self.heads = nn.ModuleList(heads)

    def all_heads(self, features: torch.Tensor) -> torch.Tensor:
        return torch.stack([head(features) for head in self.heads])

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.all_heads(features).mean(dim=0)


def _fresh_copy(template: nn.Sequential) -> nn.Sequential:
    """A copy of ``template``'s architecture with freshly initialised weights."""
    layers = []
    for module in template:
        if isinstance(module, nn.Linear):
            layers.append(nn.Linear(module.in_features, module.out_features, bias=module.bias is not None))
        else:
            layers.append(type(module)())
    return nn.Sequential(*layers)


class UncertainDQNPolicy(DQNPolicy):
    """A DQN policy with dropout or DropConnect in its Q-network, or K bootstrapped heads.

    Args (besides DQNPolicy's):
        stochastic: ``None``, ``"dropout"`` or ``"dropconnect"``.
        drop_p: the drop probability.
        last_only: the stochastic layer only at the output layer (see
            :func:`oodmon.agents.layers.add_dropout`).
        n_heads: 1 for one Q-head; K >= 2 for bootstrapped heads (train with
            :class:`BootstrappedDQN`).
    """

    def __init__(
        self,
        *args: Any,
        stochastic: str | None = None,
        drop_p: float = 0.1,
        last_only: bool = True,
        n_heads: int = 1,
        **kwargs: Any,
    ) -> None:
        self.stochastic, self.drop_p, self.last_only, self.n_heads = stochastic, drop_p, last_only, n_heads
        super().__init__(*args, **kwargs)

    def make_q_net(self):
        q_net = super().make_q_net()
        head = _make_stochastic(q_net.q_net, self.stochastic, self.drop_p, self.last_only)
        q_net.q_net = QHeads(head, self.n_heads) if self.n_heads > 1 else head
        return q_net.to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(stochastic=self.stochastic, drop_p=self.drop_p, last_only=self.last_only, n_heads=self.n_heads)
        return data


class UncertainTD3Policy(TD3Policy):
    """A DDPG/TD3 policy whose actor has dropout or DropConnect (the critic stays plain).

    Args (besides TD3Policy's): ``stochastic``, ``drop_p``, ``last_only`` as
    :class:`UncertainDQNPolicy`.
    """

    def __init__(
        self, *args: Any, stochastic: str | None = None, drop_p: float = 0.1, last_only: bool = True, **kwargs: Any
    ) -> None:
        self.stochastic, self.drop_p, self.last_only = stochastic, drop_p, last_only
        super().__init__(*args, **kwargs)

    def make_actor(self, features_extractor=None):
        actor = super().make_actor(features_extractor)
        actor.mu = _make_stochastic(actor.mu, self.stochastic, self.drop_p, self.last_only)
        return actor.to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(stochastic=self.stochastic, drop_p=self.drop_p, last_only=self.last_only)
        return data


class BootstrappedDQN(DQN):
    """DQN with K bootstrapped heads on a shared torso (Osband et al., 2016).

    Each head has its own TD target from the same head of the target network, and each
    transition of a minibatch trains each head with probability ``bootstrap_p`` (an online
    bootstrap: masks are drawn per minibatch, not stored with the transitions). The agent acts
    greedily on the mean of the heads (epsilon-greedy while training).
    """

    def __init__(self, *args: Any, bootstrap_p: float = 0.5, **kwargs: Any) -> None:
        self.bootstrap_p = bootstrap_p
        super().__init__(*args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        q_net, target_net = self.policy.q_net, self.policy.q_net_target
        losses = []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = data.discounts if data.discounts is not None else self.gamma
            with torch.no_grad():
                features = target_net.extract_features(data.next_observations, target_net.features_extractor)
                next_q = target_net.q_net.all_heads(features)
                targets = data.rewards.T + (1 - data.dones.T) * discounts * next_q.max(dim=2).values  # (K, B)
            current = q_net.q_net.all_heads(q_net.extract_features(data.observations, q_net.features_extractor))
            index = data.actions.long().T.unsqueeze(-1).expand(current.shape[0], -1, 1)
            chosen = current.gather(2, index).squeeze(-1)  # (K, B)
            masks = torch.bernoulli(torch.full_like(chosen, self.bootstrap_p))
            per_sample = F.smooth_l1_loss(chosen, targets, reduction="none")
            loss = (per_sample * masks).sum() / masks.sum().clamp(min=1.0)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))


class _SampledTarget(nn.Module):
    """A DQN target network read as the mean of K MC samples of its dropout or DropConnect layers
    (K masks, each shared by the batch), instead of with its plain weights. Its parameters are the
    target network's own, in the same order, so SB3's target updates (``polyak_update``) reach them."""

    def __init__(self, target: nn.Module, samples: int) -> None:
        super().__init__()
        self.target, self.samples = target, samples

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        features = self.target.extract_features(obs, self.target.features_extractor)
        with mc_sampling(self.target):
            return self.target.q_net(features.expand(self.samples, *features.shape)).mean(dim=0)


class SampledTargetDQN(DQN):
    """DQN whose TD target reads the target network as the online one is trained: the mean of
    ``target_samples`` MC samples of its dropout or DropConnect layers, not its plain weights.

    Why: the CartPole DropConnect trainings with SB3's plain target learn Q-values up to 35 times the
    largest return (``scripts/q_values.py``; the zoo README), and at p >= 0.05 their policies do not
    learn. With the target sampled the Q-values stayed at 120-180, five seeds at p = 0.02 solved the
    task, and p = 0.05 and 0.1 learned (the zoo README). Everything else is SB3's DQN: the sampled target is the algorithm's
    ``q_net_target``, SB3's ``train()`` calls it, and the policy (what is saved) is unchanged.
    """

    def __init__(self, *args: Any, target_samples: int = 8, **kwargs: Any) -> None:
        if not (isinstance(target_samples, int) and target_samples >= 1):
            raise InvalidParameterError(f"target_samples={target_samples!r} is not allowed; use a whole number >= 1")
        self.target_samples = target_samples
        super().__init__(*args, **kwargs)

    def _create_aliases(self) -> None:
        super()._create_aliases()
        self.q_net_target = _SampledTarget(self.policy.q_net_target, self.target_samples)
