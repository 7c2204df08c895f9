"""Where an agent fails (the paper's step 3): mean return per variant beside the ID return.

A variant *fails* the agent when the agent keeps less than ``fail_fraction`` (default half) of
what it gains over a random policy in the ID env: ``return < random + fail_fraction * (id - random)``.
Measuring from the random policy's return makes the rule work for Pendulum's negative returns
and Pong's -21..21 as well as for CartPole's 0..500.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from oodmon import seeds
from oodmon.envs.grid import Variant
from oodmon.progress import Progress
from oodmon.side_by_side import finished_before, play_side_by_side, resolve_workers, stream_per_episode

__all__ = ["RANDOM_RETURN", "SOLVED_RETURN", "VariantResult", "episode_returns", "evaluate_variants", "failure_line"]

#: Mean return of a uniformly random policy in each task's ID env, measured with
#: ``episode_returns(lambda obs: space.sample(), Variant(task), 100)`` with ``space.seed(0)`` (Pong: 10 episodes).
RANDOM_RETURN: dict[str, float] = {"cartpole": 23.7, "pendulum": -1207.6, "pong": -20.6}


def failure_line(task: str, id_return: float, fail_fraction: float = 0.5) -> float:
    """The mean return below which a variant fails an agent whose ID return is ``id_return`` (see the
    module docstring): ``fail_fraction`` of its gain over a random policy.

    Example:
        >>> round(failure_line("cartpole", 500.0), 2)
        261.85
    """
    return RANDOM_RETURN[task] + fail_fraction * (id_return - RANDOM_RETURN[task])


#: The ID return (mean over a trained model's ``id_return_mean`` episodes) at which an agent counts as
#: solving its task: CartPole-v1's own ``reward_threshold``, and for Pendulum -200, the bar the zoo's
#: recipes were held to. Pong has no bar here.
SOLVED_RETURN: dict[str, float] = {"cartpole": 475.0, "pendulum": -200.0}


def episode_returns(
    policy: Callable[[np.ndarray], object],
    variant: Variant,
    episodes: int,
    *,
    seed: int = 0,
    onset_step: int = 0,
    on_progress: Progress | None = None,
    wrap: Callable[[gymnasium.Env], gymnasium.Env] | None = None,
) -> np.ndarray:
    """Returns of ``episodes`` episodes of ``policy`` in ``variant``, seeded ``seed``, ``seed+1``, ...
    ``on_progress(f"{variant.spec} episodes", done, episodes)`` after each. ``wrap``: the env as
    the policy observes it (``Agent.wrap``: a model trained inside VecFrameStack, say).

    Example:
        >>> from oodmon.envs.reference import cartpole_controller
        >>> episode_returns(cartpole_controller, Variant("cartpole"), 2).tolist()
        [500.0, 500.0]
    """
    env = variant.make(onset_step=onset_step)
    env = env if wrap is None else wrap(env)
    returns = []
    try:
        for episode in range(episodes):
            obs, _ = env.reset(seed=seed + episode)
            total, done = 0.0, False
            while not done:
                obs, reward, terminated, truncated, _ = env.step(policy(obs))
                total += float(reward)
                done = terminated or truncated
            returns.append(total)
            if on_progress is not None:
                on_progress(f"{variant.spec} episodes", episode + 1, episodes)
    finally:
        env.close()
    return np.asarray(returns)


@dataclass(frozen=True)
class VariantResult:
    """An agent's returns in one variant, judged against its ID return.

    Attributes:
        spec: the variant's spec string.
        returns: the episode returns.
        fails: whether the mean return is below the failure line (see the module docstring).
    """

    spec: str
    returns: np.ndarray
    fails: bool

    @property
    def mean(self) -> float:
        return float(np.mean(self.returns))


def evaluate_variants(
    policy: Callable[[np.ndarray], object],
    task: str,
    variants: Iterable[Variant],
    episodes: int,
    *,
    seed: int = seeds.VARIANT_EVALUATION,
    fail_fraction: float = 0.5,
    on_progress: Progress | None = None,
    wrap: Callable[[gymnasium.Env], gymnasium.Env] | None = None,
    workers: int = 1,
    sampler: Any = None,
) -> tuple[VariantResult, list[VariantResult]]:
    """Evaluate ``policy`` in the ID env and in each variant; mark the variants where it fails.
    ``on_progress("evaluation episodes", done, total)`` after each episode of all of them;
    ``wrap``: as :func:`episode_returns`'s.

    ``workers``: processes that play the variants side by side (0: one per core; see
    :mod:`oodmon.side_by_side`), a run of variants each. ``sampler``: the estimator whose draws
    ``policy`` decides by (``Agent.estimator``), if any: side by side, each variant draws from a
    stream of its own, so that the returns are the same for any ``workers`` >= 2 (one process's
    draws run on from variant to variant).

    Returns:
        The ID result and one result per variant, in order.

    Interrupted (Ctrl-C, SIGTERM), the ``KeyboardInterrupt`` carries in ``.evaluation`` the same of
    the ID env and the first variants evaluated whole (``None``: not even the ID env was); side by
    side, each worker takes one variant at a time.
    """
    variants = [Variant(task), *variants]
    workers = resolve_workers(workers, len(variants))
    start = stream_per_episode(sampler, workers)

    def play(first: int, count: int, done: Callable[[], None]) -> list[np.ndarray]:
        played = []
        try:
            for index in range(first, first + count):
                start(index)
                played.append(episode_returns(policy, variants[index], episodes, seed=seed,
                                              on_progress=lambda *_: done(), wrap=wrap))
        except KeyboardInterrupt as interrupt:  # (one process: those evaluated whole, from the ID env on)
            interrupt.finished = played
            raise
        return played

    def results(returns: list[np.ndarray]) -> tuple[VariantResult, list[VariantResult]]:
        line = failure_line(task, float(np.mean(returns[0])), fail_fraction)
        return VariantResult(task, returns[0], False), [VariantResult(v.spec, r, float(np.mean(r)) < line)
                                                        for v, r in zip(variants[1:], returns[1:])]

    try:
        returns = play_side_by_side(play, len(variants), workers, "evaluation episodes", on_progress,
                                    total=len(variants) * episodes, run_size=1)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # (Ctrl-C, SIGTERM, a worker's death)
        finished = finished_before(interrupt)
        interrupt.evaluation = results(finished) if finished else None
        raise
    return results(returns)
