"""Fit the learned detectors of a deployed policy on ID episodes of its own.

:func:`collect` plays ID episodes with the policy and keeps what the detectors learn from
(observations, deployed actions, features). :func:`fit_detectors` splits them: the first two
thirds fit ``dynamics`` and ``features``, the last third gives the ``combined`` detector its
members' ID scores (scores of steps the members were not fitted on, or the in-sample fit would
make every fresh ID step look rare; each step's off the estimate its action was chosen from, as
the monitor scores it: ``collect(..., estimates_from=...)``). The episodes use seeds of their own
(:data:`oodmon.seeds.DETECTOR_FIT` on), apart from calibration's: the threshold is calibrated
afterwards on other episodes, so its guarantee holds for the fitted detectors as they are.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from oodmon.agents.sb3_spaces import space_parts
from oodmon.envs.checks import step_naming_refusal, warn_if_endless
from oodmon.errors import ConfigError, InvalidParameterError, unknown
from oodmon.kept import SamplingTrail
from oodmon.monitor.detectors.base import StepContext, Trajectory
from oodmon.monitor.detectors.combined import CombinedDetector
from oodmon.monitor.detectors.drift import DriftDetector
from oodmon.monitor.detectors.dynamics import MAX_UPDATES, DynamicsDetector, check_max_updates, min_logvar_for
from oodmon.monitor.detectors.features import FeaturesDetector
from oodmon.monitor.detectors.frames import is_picture, newest_frame
from oodmon.monitor.detectors.scaled_spread import ScaledSpreadDetector, member_values
from oodmon.monitor.detectors.spread import SpreadDetector
from oodmon.monitor.detectors.store import DETECTORS, DetectorSet
from oodmon.monitor.detectors.transitions import TransitionsDetector
from oodmon.monitor.scores import DEFAULT_SCORE
from oodmon.names import BEST_DETECTOR, fixed_masks
from oodmon.progress import Progress
from oodmon.seeds import DETECTOR_FIT, check_seed
from oodmon.side_by_side import finished_before, play_side_by_side, resolve_workers, stream_per_episode
from oodmon.validation import check_max_steps, is_whole
from oodmon.versions import machine

__all__ = ["AS_LOGGED", "BEST_DETECTOR", "DEFAULT_ADDS", "DEFAULT_FIT_EPISODES", "DEFAULT_FIT_STEPS", "FIT_VERSION",
           "KEEP_AT_MOST", "Explorer", "acted_on_rebuilt", "best_detector", "check_explore", "collect",
           "default_detectors", "default_fit_steps", "detectors_for", "discrete_states", "fit_agent_detectors",
           "fit_recorded_detectors", "fit_settings", "fitting_notes", "fitting_share", "fit_detectors", "policy_parts",
           "read_kept_trajectories", "stack_depth", "stacks_from_frames", "trajectory_scores"]

#: ID episodes the learned detectors are fitted on by default: two thirds fit, one third ranks.
#: 90 since 2026-11-24 (30 before): on the monitor's own benchmark (same agents and episodes) the
#: CartPole ensemble then alarmed 270 of 270 shifted episodes (253 with 30) and Pendulum's
#: DropConnect and ensemble 110 and 120 of 150 and 160 (100 and 110), with delays as short or
#: shorter except CartPole DropConnect's at gravity x8-x10 and length (1-3 steps later); the
#: docs/bench.md's monitor benchmark has the figures.
DEFAULT_FIT_EPISODES = 90

#: For an env oodmon has no variants of, whose episodes may be short, the default fitting plays on
#: past :data:`DEFAULT_FIT_EPISODES` until its episodes hold this many steps: as many as 90
#: CartPole episodes of 500 (oodmon's own tasks keep their 90 episodes, on which every figure of
#: the READMEs was measured). Measured on 2026-11-29 on a PPO that swings Acrobot-v1 up in about
#: 110 steps (docs/your-policy.md, "Shift your own env"): fitted on 90 episodes (about 10,000 steps) its ID
#: scores peaked at each swing-up's end, the threshold rose to 7.39, and the monitor's benchmark
#: alarmed 17 of 70 shifted episodes (three physics shifts, four sensor faults); fitted until
#: 45,000 steps (409 episodes), 49 of 70, delay medians 1-7.5, with 0 of 200 ID episodes alarmed.
DEFAULT_FIT_STEPS = 45_000


def default_fit_steps(task: str | None) -> int:
    """The steps the default fitting's episodes must hold for ``task``: none beyond
    :data:`DEFAULT_FIT_EPISODES` for oodmon's tasks, :data:`DEFAULT_FIT_STEPS` for an env oodmon
    has no variants of (a gymnasium id).

    Example:
        >>> default_fit_steps("cartpole"), default_fit_steps("Acrobot-v1")
        (0, 45000)
    """
    from oodmon.names import TASKS

    return 0 if task is None or task in TASKS else DEFAULT_FIT_STEPS

#: Recorded in a fitted set's ``fitted_for["version"]`` and in the bench's cache key; raised when
#: fitting the same episodes gives other detectors, so that nothing fitted or scored by an older
#: oodmon is reused. 2: ``combined`` ranks dynamics' mean since the episode began; 3: and
#: ``features`` by the logarithm of its score; 4: 90 episodes by default, not 30 (a set without
#: the key is of version 1); 5: ``combined`` ranks the held-out episodes' spread off the samples
#: each action was chosen from (before, an MC policy with sampled masks was asked again, drawing
#: other samples and leaving its sampling elsewhere for what came after the fitting); 6: ``dynamics``
#: standardises its means over fewer than 20 transitions after a reset (``early="standardised"``);
#: 8: ``dynamics`` trains up to 100 epochs and 3,000 updates, not 30 epochs, its learning rate
#: falling linearly to 0 over the fit (``schedule``, ``max_updates``; 7 was a version taken back
#: the day it came: a cache of it is not of this fitting); 9: ``dynamics`` trains every one of its
#: 100 epochs, no longer stopping at 3,000 updates (``max_updates=None``; a set of version 8 keeps
#: its cap in its file): on every bench measured it alarmed more often or sooner (docs/detectors.md,
#: ``--dynamics-updates``).
FIT_VERSION = 9

# The detector with the highest mean per-step AUROC over the paper's failing variants, per task, on
# the shipped agents (results/detectors/, `scripts/detector_table.py`; docs/detectors.md's detector table);
# Pong: frames, which alarmed every shifted game of the monitor's benchmark within a few decisions
# where features needed 200-decision means and still missed DropConnect's mild blur
# (results/monitor/pong-frames-*.json), and since 2026-11-30 combined, of frames and stillness
# (COMBINED_LEAVES_OUT): the same benchmark and a frozen camera (`pong:obs.stuck=1`), which frames
# never sees, alarmed 10 of 10 games of each agent 11-14 decisions after it froze; the nine
# corruptions 90 of 90 as before, 25 of 27 delay medians the same and 2 longer by 0.5; 0, 2 and 0
# of 200 ID games alarmed against 3, 1 and 0 (results/monitor/pong-combined-*.json); since
# 2026-12-01 with vanishing among its members (DEFAULT_ADDS).
# Pendulum: dynamics was the best when chosen; since the detectors are fitted on 90 episodes
# `combined` reads 0.001-0.003 higher per step on all three Pendulum agents, but as the alarm
# (the monitor's benchmark with `--detectors spread,combined --alarm-detector combined`,
# 2026-11-24) it alarmed the same episodes, 0-1 step later on 5 variants, with 9 false alarms of
# 400 for Dropout against dynamics' 4: dynamics stays.
# (the dict itself in oodmon.names, which replay reads without loading the detectors)

#: What a task's ``combined`` leaves out of the detectors it has, measured as adding nothing there
#: but false alarms. Pong's spread and features: frames separates every corruption (per-step AUROC
#: 0.999-1.000 on the shipped agents; the spread 0.35-0.66, the features' step scores noisy enough
#: to need 200-decision means), and with them in the combined of frames and stillness its
#: threshold rose. The monitor's benchmark of the shipped DropConnect and Dropout agents
#: (2026-11-30; ``--detectors spread,features,frames,stillness,combined --alarm-detector
#: combined --window 1``): 6 of 200 ID games alarmed for each, and Dropout alarmed 8 of 100 shifted
#: games before the onset; their logged scores ranked again by a combined of frames and stillness
#: alone (its threshold the largest of the first 90 ID games, against the other 110): thresholds
#: 6.30 and 3.79 against 7.73 and 5.94, 0 and 3 of those 110 alarmed against 2 and 0, every delay
#: shorter or the same (1-2 steps shorter for Dropout).
COMBINED_LEAVES_OUT = {"pong": ("spread", "features")}

#: What a task's default set holds beside the detectors its observations give, measured as worth it
#: there. Pong's ``vanishing`` (2026-12-01): in its ``combined`` beside ``frames`` and ``stillness``,
#: the set fitted on 90 whole games (6 games of 1,000 decisions before), the monitor's benchmark
#: (results/monitor/pong-combined-90games-<method>.json) alarmed a frozen part of the picture in 10
#: of 10 games of each of the three agents, the centre 13.5-36.5 decisions after it froze (DropConnect
#: 0 of 10 and the ensemble 4 of 10 at 2,489.5 without), motion blur at 1 (4-6), the nine corruptions
#: and a frozen camera as before or up to 2.5 decisions later (DropConnect's noises 5-7 against
#: 4-4.5), and 0 of 200 ID games for each (Dropout 2 before).
DEFAULT_ADDS = {"pong": ("vanishing",)}


def best_detector(task: str | None, detectors: DetectorSet | None, score: str | None = None) -> str:
    """The detector an alarm reads by default: the task's best (:data:`BEST_DETECTOR`; for an env
    oodmon has not measured, ``combined``) when ``detectors`` has it fitted (and, given the
    spread's ``score``, fitted for it: see :meth:`DetectorSet.for_score`), else ``spread``, or for
    a plain policy (no ``spread``) the set's last detector."""
    best = BEST_DETECTOR.get(task or "", "combined")
    if detectors is not None and score is not None:
        detectors = detectors.for_score(score)[0]
    if detectors is not None and best in detectors:
        return best
    if detectors is not None and len(detectors) and "spread" not in detectors:
        return detectors.names[-1]
    return "spread"


def policy_parts(policy: Any) -> tuple[Any, Callable[[np.ndarray], Any], dict]:
    """``(estimator or None, act, metadata)`` of an Agent, an estimator or a plain callable policy."""
    from oodmon.agents.agent import Agent
    from oodmon.agents.estimators import UncertaintyEstimator

    if isinstance(policy, Agent):
        return policy.estimator, policy.act, policy.metadata
    if isinstance(policy, UncertaintyEstimator):
        def act(obs):
            raw = policy.estimate(obs).action[0]
            return int(raw) if policy.kind == "q_values" else np.asarray(raw)
        return policy, act, {}
    if callable(policy):
        return None, policy, {}
    raise ConfigError(f"a policy is an oodmon Agent, an uncertainty estimator or a callable obs -> action; got "
                      f"{type(policy).__name__}")


def _policy_identity(policy: Any, estimator: Any) -> str | None:
    """What tells the fitting episodes kept for ``policy`` from another's where the caller gave no
    ``policy_hash``: an agent's own (:func:`~oodmon.monitor.monitor.policy_hash`), else the sha256
    of its estimator's weights and of the VecNormalize statistics it reads its observations through
    (``observation_transform``), else a plain policy's (:func:`~oodmon.agents.plain.plain_policy_hash`:
    its torch module's weights, or its name and code)."""
    from oodmon.agents.agent import Agent
    from oodmon.agents.plain import plain_policy_hash
    from oodmon.hashing import state_sha256
    from oodmon.monitor.monitor import policy_hash

    if isinstance(policy, Agent) and (own := policy_hash(policy)) != "unknown":  # (a hash of its model's file)
        return own
    if estimator is not None:
        weights = estimator.weights()
        if not weights:
            return None
        # an SB3 model's VecNormalize statistics count as its weights (oodmon.agents.sb3's policy_hash)
        transform = getattr(estimator, "observation_transform", None)
        statistics = getattr(transform, "numbers_sha256", "") or getattr(transform, "sha256", "")
        if statistics:
            weights = weights | {"observation_transform": np.frombuffer(statistics.encode(), np.uint8)}
        return "sha256:" + state_sha256(weights)
    return plain_policy_hash(policy)


def _draws(estimator: Any) -> dict[str, Any]:
    """How a policy's estimator draws its samples, as the keys of what kept fitting episodes and
    kept detectors were made by: its masks' kind and its samples per decision (``None`` for none)."""
    return {"masks": getattr(estimator, "masks", None), "samples": None if estimator is None else estimator.n_samples}


def collect(policy: Any, env: gymnasium.Env, episodes: int, *, seed: int = DETECTOR_FIT,
            on_progress: Progress | None = None, max_steps: int | None = None,
            with_member_values: bool = False, estimates_from: int | None = None,
            min_steps: int = 0, workers: int = 1, done: Sequence[Trajectory] = (),
            explore: float = 0.0) -> list[Trajectory]:
    """Play ``episodes`` episodes of ``env`` (seeds ``seed``, ``seed + 1``, ...) with ``policy``
    (each cut after ``max_steps`` steps if given), and more until they hold ``min_steps`` steps;
    ``with_member_values``: keep an ensemble's members' values too (what ``scaled_spread`` is
    fitted on); ``estimates_from``: keep each step's estimate (``Trajectory.estimates``) in the
    episodes from this index on. ``done``: the first episodes, played already (kept by an
    interrupted collection): the episodes after them are played.

    ``explore``: at this share of the steps (each drawn on its own) the env gets a random action of
    its action space (among those its action masks allow, for a policy that reads them) instead of
    the policy's, and the episode keeps the action taken (:class:`Explorer`: seeded per episode,
    the same in any process). The policy is asked at every step all the same (its estimate is kept,
    and an MC policy draws as it would).

    Interrupted (Ctrl-C, SIGTERM, a worker's death), the exception carries every episode played
    whole from the first on, ``done`` among them (:func:`~oodmon.side_by_side.finished_before`).

    ``workers``: processes that play them side by side (0: one per core), each with its copy of
    ``policy`` and ``env`` (:mod:`oodmon.side_by_side`, which says what an MC policy draws there),
    sending each episode back as it ends. The episodes are those one process plays: those asked
    for, then, for ``min_steps``, batches of as many more as the steps still missing need at the
    mean length so far, cut back to the first that hold them.
    """
    seed = check_seed(seed)
    workers = resolve_workers(workers, episodes)
    estimator, act, _ = policy_parts(policy)
    ensemble = with_member_values and has_members(estimator)
    deploy = getattr(policy, "deploy", None)  # an Agent whose deployed policy is not its estimator's decision
    # An Agent acting on stacks, or on dicts with pictures: the detectors read the newest of each
    # stack, the dict's vectors (Agent.own_observation).
    own = policy.own_observation if getattr(policy, "reads_own", False) else None
    pictures_of = getattr(policy, "pictures", None)  # a dict's picture, which the frames detector reads
    # an Agent of a tuple or dict of actions: the env gets them, the detectors read them flattened
    read_action = policy.read_action if getattr(policy, "action_parts", None) is not None else None
    # An Agent whose policy needs the env beside the observation (a memory forgotten at each reset,
    # the action masks of each step), told as the monitor tells it, in an env of yours too.
    begin = policy.begin_episode if getattr(policy, "remembers", False) else None
    tell = policy.tell_masks if getattr(policy, "reads_masks", False) else None
    explorer = Explorer(env, explore, masked=tell is not None) if explore else None

    def play_episode(episode: int) -> Trajectory:
        obs, _ = env.reset(seed=seed + episode)
        if explorer is not None:
            explorer.begin(seed + episode)
        if begin is not None:
            begin()
        if tell is not None:
            tell(env)
        observations, actions, features, values, estimates = [obs], [], [], [], []
        keep = estimator is not None and estimates_from is not None and episode >= estimates_from
        label = f"fitting episode {episode}"  # (what a refused action's error names)
        while True:
            if estimator is not None:
                estimate = estimator.estimate(obs)
                if keep:
                    estimates.append(estimate)
                raw = estimate.action[0]
                action = deploy(obs) if deploy is not None else int(raw) if estimator.kind == "q_values" else np.asarray(raw)
                if estimate.features is not None:
                    features.append(estimate.features[0])
                if ensemble:
                    values.append(member_values(estimate))
            else:
                action = act(obs)
            if explorer is not None:
                action = explorer.action(action)
            obs, _, terminated, truncated, _ = step_naming_refusal(env, action, step=len(actions) + 1, episode=label,
                                                                   seed=seed + episode)
            if tell is not None:
                tell(env)
            observations.append(obs)
            actions.append(action if read_action is None else read_action(action))
            warn_if_endless(env, len(actions))
            if terminated or truncated or (max_steps is not None and len(actions) >= max_steps):
                break
        acted_on = pictures = None
        if pictures_of is not None:
            pictures = np.asarray([pictures_of.picture(o) for o in observations])
        if own is not None:  # what the policy acted on is kept where an estimator reads it again
            acted_on = np.asarray(observations) if estimator is not None else None
            observations = [own(o) for o in observations]
        return Trajectory(np.asarray(observations), np.asarray(actions),
                          np.asarray(features) if len(features) == len(actions) else None,
                          np.asarray(values) if ensemble and values[0] is not None else None,
                          acted_on, pictures, tuple(estimates) if keep else None)

    if workers > 1:
        return _collect_side_by_side(play_episode, estimator, episodes, seed, workers, min_steps, on_progress, done)
    trajectories = list(done)
    steps, episode = sum(len(t) for t in trajectories), len(trajectories)
    try:
        while episode < episodes or steps < min_steps:
            trajectories.append(play_episode(episode))
            steps += len(trajectories[-1])
            episode += 1
            if on_progress is not None and episode <= episodes:
                on_progress("detector fitting episodes", episode, episodes)
            elif on_progress is not None:  # on past the episodes asked, for the steps asked
                on_progress("detector fitting steps", min(steps, min_steps), min_steps)
    except KeyboardInterrupt as interrupt:
        interrupt.finished = trajectories
        raise
    return trajectories


#: Seeds the random actions of a fit that explores (:class:`Explorer`), apart from the env's resets.
EXPLORE_STREAM = 4_771


class Explorer:
    """A fit's random actions (``fit_detectors(..., explore=P)``): at each step, with probability
    ``explore``, an action drawn from ``env``'s action space instead of the policy's (among those
    its ``action_masks()`` allow now where ``masked``). The draws of episode ``i`` come from a
    stream of its own, ``begin(seed + i)``: the same whichever process plays it, and in an
    episode played again after an interruption.

    Example:
        >>> explorer = Explorer(gymnasium.make("CartPole-v1"), 0.5)
        >>> explorer.begin(0)
        >>> [int(explorer.action(7)) for _ in range(6)]
        [7, 0, 1, 7, 0, 1]
    """

    def __init__(self, env: gymnasium.Env, explore: float, *, masked: bool = False) -> None:
        if masked and not isinstance(env.action_space, gymnasium.spaces.Discrete):
            raise ConfigError(f"a fit that explores draws a masked policy's random actions among those its action "
                              f"masks allow, for a Discrete action space; this env's is {env.action_space}: fit "
                              "without exploring")
        self.env, self.explore, self.masked = env, explore, masked
        self.space = copy.deepcopy(env.action_space)  # (seeded here: the env's own draws stay the env's)
        self._rng = np.random.default_rng()

    def begin(self, episode_seed: int) -> None:
        """Draw episode ``episode_seed``'s actions from its own stream."""
        self._rng = np.random.default_rng([EXPLORE_STREAM, episode_seed])
        self.space.seed(int(self._rng.integers(2**31)))

    def action(self, chosen: Any) -> Any:
        """The action the env gets: ``chosen`` (the policy's), or at a share ``explore`` of the steps a random one."""
        if self._rng.random() >= self.explore:
            return chosen
        if self.masked:
            allowed = np.asarray(self.env.get_wrapper_attr("action_masks")(), dtype=np.int8)
            return self.space.sample(mask=allowed)
        return self.space.sample()


def check_explore(explore: Any, parameter: str = "explore") -> float:
    """``explore`` as a float, a share of the steps in [0, 1).

    Example:
        >>> check_explore(np.float32(0.25)), check_explore(0)
        (0.25, 0.0)

    Raises:
        InvalidParameterError: anything else (1 would fit on a random policy's episodes alone).
    """
    if isinstance(explore, (bool, np.bool_)) or not isinstance(explore, (int, float, np.integer, np.floating)) \
            or not 0 <= explore < 1:
        raise InvalidParameterError(f"{parameter}={explore!r} is not allowed; it is the share of the fitting steps "
                                    "that take a random action instead of the policy's, a number >= 0 and < 1 "
                                    "(e.g. 0.1)")
    return float(explore)


def _collect_side_by_side(play_episode: Callable[[int], Trajectory], estimator: Any, episodes: int, seed: int,
                          workers: int, min_steps: int, on_progress: Progress | None,
                          done: Sequence[Trajectory] = ()) -> list[Trajectory]:
    """:func:`collect`'s episodes played by ``workers`` processes (``play_episode(i)``: episode
    ``i``), after those ``done`` already. Each episode draws from a stream of its own, so that those
    after ``done`` are those an uninterrupted collection plays."""
    start = stream_per_episode(estimator, workers)

    def play(first: int, count: int, finished: Callable[[], None]) -> list[Trajectory]:
        played = []
        for episode in range(first, first + count):
            start(seed + episode)
            played.append(play_episode(episode))
            finished()
        return played

    def play_more(count: int, stage: str) -> list[Trajectory]:
        offset = len(trajectories)
        # One episode a run: each comes back as it ends (a Pong game's frames: about 70 MB).
        return play_side_by_side(lambda first, n, finished: play(offset + first, n, finished), count, workers, stage,
                                 on_progress, run_size=1)

    trajectories = list(done)
    try:
        if len(trajectories) < episodes:
            trajectories += play_more(episodes - len(trajectories), "detector fitting episodes")
        steps = sum(len(t) for t in trajectories)
        while steps < min_steps:
            more = max(workers, math.ceil((min_steps - steps) * len(trajectories) / max(steps, 1)))
            trajectories += play_more(more, "detector fitting episodes, more for the steps")
            steps = sum(len(t) for t in trajectories)
            if on_progress is not None:
                on_progress("detector fitting steps", min(steps, min_steps), min_steps)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # those of the runs before, then this one's
        interrupt.finished = trajectories + finished_before(interrupt)
        raise
    if min_steps:  # as one process: on past the episodes asked only until they hold the steps
        held = np.cumsum([len(t) for t in trajectories])
        trajectories = trajectories[:max(episodes, int(np.searchsorted(held, min_steps)) + 1)]
    return trajectories


#: The most bytes of episodes an interrupted fit keeps (:func:`fit_detectors`' ``kept``): an Acrobot
#: PPO's 409 episodes hold under 2 MB, the CartPole ensemble's 90 with its features 48 MB (written
#: in a fraction of a second); a Pong game's frames about 70 MB, whose 90 games (6 GB) would take a
#: while to write when Ctrl-C asks to stop.
KEEP_AT_MOST = 1 << 30

_FIELDS = ("observations", "actions", "features", "member_values", "acted_on", "pictures")


def _keep_trajectories(path: str | Path, made_by: dict[str, Any], trajectories: Sequence[Trajectory],
                       state: dict | None = None) -> int:
    """Write the episodes ``trajectories`` to ``path`` (see :func:`fit_detectors`' ``kept``), each
    field of each as an array of its own (``"3.observations"``, ``"3.estimates.samples"``: episode 3's),
    and ``state``, where an MC policy's draws stood after them in one process, whole or not at all;
    how many were kept: 0 where there were none, or they hold Python objects or more than
    :data:`KEEP_AT_MOST` bytes, or the disk is full (said in a warning)."""
    import warnings

    from oodmon.agents.estimators import Estimate
    from oodmon.kept import state_array, write_kept

    if not trajectories:
        return 0
    arrays: dict[str, np.ndarray] = {"episodes": np.array(len(trajectories)), **state_array(state)}
    for i, trajectory in enumerate(trajectories):
        arrays |= {f"{i}.{name}": np.asarray(getattr(trajectory, name)) for name in _FIELDS
                   if getattr(trajectory, name) is not None}
        if trajectory.estimates is not None:
            arrays[f"{i}.estimates"] = np.array(len(trajectory.estimates))
            for name in Estimate.__dataclass_fields__:
                values = [getattr(e, name) for e in trajectory.estimates]
                if name == "features" and trajectory.features is not None:
                    continue  # the trajectory's own, step for step (read back from them)
                if values and values[0] is not None:
                    arrays[f"{i}.estimates.{name}"] = np.stack(values)
    size = sum(array.nbytes for array in arrays.values())
    try:
        if size > KEEP_AT_MOST:
            raise ValueError(f"{size / 1e9:.1f} GB, more than oodmon keeps on an interrupt")
        write_kept(path, made_by, arrays)
    except (ValueError, OSError) as error:  # (a full disk: said, and the interrupt goes on as one)
        warnings.warn(f"the {len(trajectories):,} detector fitting episodes played whole are not kept: {error}",
                      stacklevel=4)
        return 0
    return len(trajectories)


def read_kept_trajectories(path: str | Path, made_by: dict[str, Any]) -> list[Trajectory]:
    """The episodes an interrupted :func:`fit_detectors` kept in ``path`` (see its ``kept``), where a
    fit ``made_by`` the same settings kept them; ``[]`` where there is no such file, and with a
    :class:`~oodmon.kept.KeptEpisodesWarning` where it is another fit's or unreadable. Nothing in
    it is unpickled."""
    return _read_kept_trajectories(path, made_by)[0]


def _read_kept_trajectories(path: str | Path, made_by: dict[str, Any]) -> tuple[list[Trajectory], dict | None]:
    """:func:`read_kept_trajectories`' episodes, and where an MC policy's draws stood after them in
    one process (:class:`~oodmon.kept.SamplingTrail`), or ``None``."""
    from oodmon.agents.estimators import Estimate
    from oodmon.kept import read_kept, state_of, unreadable

    arrays = read_kept(path, made_by, "fitting", stacklevel=4)  # (the caller of fit_detectors, or of ours)
    if not arrays:
        return [], None
    trajectories = []
    try:
        state = state_of(arrays)
        for i in range(int(arrays["episodes"])):
            estimates = None
            if f"{i}.estimates" in arrays:
                fields = {name: arrays.get(f"{i}.estimates.{name}") for name in Estimate.__dataclass_fields__}
                if fields["features"] is None and f"{i}.features" in arrays:  # (kept once: see _keep_trajectories)
                    fields["features"] = arrays[f"{i}.features"][:, None]
                estimates = tuple(Estimate(**{name: None if values is None else values[t]
                                              for name, values in fields.items()})
                                  for t in range(int(arrays[f"{i}.estimates"])))
            required = {name: arrays[f"{i}.{name}"] for name in ("observations", "actions")}
            trajectories.append(Trajectory(**{name: arrays.get(f"{i}.{name}") for name in _FIELDS} | required,
                                           estimates=estimates))
    except (KeyError, ValueError, TypeError, IndexError, ConfigError) as error:
        unreadable(path, "fitting", f"{type(error).__name__}: {error}", stacklevel=4)
        return [], None
    return trajectories, state


def trajectory_scores(detectors: DetectorSet, trajectory: Trajectory, estimator: Any = None) -> dict[str, np.ndarray]:
    """Every detector's per-step scores along a recorded trajectory, as the monitor would give them:
    off the estimates the trajectory kept (``Trajectory.estimates``, those its actions were chosen
    from), else off ``estimator``'s estimate at each step, asked for now."""
    detectors.reset()
    out: dict[str, list[float]] = {name: [] for name in detectors.names}
    prev_obs = prev_action = None
    for step in range(len(trajectory)):
        obs, action = trajectory.observations[step], trajectory.actions[step]
        acted_on = obs if trajectory.acted_on is None else trajectory.acted_on[step]
        picture = None if trajectory.pictures is None else trajectory.pictures[step]
        if trajectory.estimates is not None:
            estimate = trajectory.estimates[step]
        else:
            estimate = estimator.estimate(acted_on) if estimator is not None else None
        scores = detectors.score(StepContext(obs, action, estimate, prev_obs, prev_action, {}, picture))
        for name, value in scores.items():
            out[name].append(value)
        prev_obs, prev_action = obs, action
    return {name: np.asarray(values) for name, values in out.items()}


def default_detectors(policy: Any, env: gymnasium.Env, task: str | None = None) -> tuple[str, ...]:
    """The learned detectors ``policy`` in ``env`` can have: ``dynamics`` for vector observations
    (stacked ones too, flattened), with ``drift`` where ``task`` is an env oodmon has no variants of
    (:mod:`~oodmon.monitor.detectors.drift`), ``transitions`` instead of both for discrete states
    (:func:`discrete_states`), ``features`` for an oodmon agent or estimator, ``frames`` and
    ``stillness`` (a frozen camera) for image observations
    (:func:`~oodmon.monitor.detectors.frames.is_picture`) and beside ``dynamics`` for an agent's
    dicts with pictures beside vectors (``Agent.pictures``), what :data:`DEFAULT_ADDS` adds for
    ``task`` (Pong: ``vanishing``), and ``combined``."""
    from oodmon.names import TASKS

    estimator, _, _ = policy_parts(policy)
    space = env.observation_space
    picture = is_picture(tuple(space.shape or ()), space.dtype)
    names = [] if picture else ["transitions"] if discrete_states(policy, env) else ["dynamics"]
    if names == ["dynamics"] and task is not None and task not in TASKS:
        names.append("drift")
    if estimator is not None:
        names.append("features")
    if picture or getattr(policy, "pictures", None) is not None:
        names += ["frames", "stillness"]
    names += [name for name in DEFAULT_ADDS.get(task or "", ()) if cannot_have(name, policy, env) is None]
    return (*names, "combined")


def brings_default_set(detectors: Sequence[str]) -> bool:
    """Whether fitting ``detectors`` fits the policy's default set too: ``combined`` named without
    a learned member to combine (:func:`fit_detectors`).

    Example:
        >>> brings_default_set(["spread", "combined"]), brings_default_set(["frames", "combined"])
        (True, False)
    """
    return "combined" in detectors and not {"dynamics", "features", "frames", "transitions"} & set(detectors)


def discrete_states(policy: Any, env: gymnasium.Env) -> bool:
    """Whether the observations of ``policy`` (an Agent's ``dict_space``, which its detectors read
    one-hot) or else of ``env`` are discrete values: ``Discrete``, ``MultiDiscrete``, ``MultiBinary``,
    or a dict or tuple of nothing else; the ``transitions`` detector's, not the ``dynamics`` model's.

    Example:
        >>> discrete_states(None, gymnasium.make("FrozenLake-v1")), discrete_states(None, gymnasium.make("CartPole-v1"))
        (True, False)
    """
    spaces = gymnasium.spaces
    space = getattr(policy, "dict_space", None)
    space = env.observation_space if space is None else space
    parts = space_parts(space)
    return all(isinstance(part, (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary))
               for part in ([space] if parts is None else parts))


def fit_detectors(policy: Any, env: gymnasium.Env, *, detectors: Sequence[str] | None = None,
                  episodes: int = DEFAULT_FIT_EPISODES, seed: int = DETECTOR_FIT, score: str = DEFAULT_SCORE,
                  task: str | None = None, policy_hash: str | None = None, obs_noise: float = 0.0,
                  on_progress: Progress | None = None, max_steps: int | None = None,
                  min_steps: int = 0, workers: int = 1, dynamics_updates: int | None = MAX_UPDATES,
                  kept: str | Path | None = None, explore: float = 0.0) -> DetectorSet:
    """Fit the named detectors (default: :func:`default_detectors`) for ``policy`` on
    ``episodes`` ID episodes of ``env`` (each cut after ``max_steps`` steps if given), and more
    until they hold ``min_steps`` steps (two thirds of them fit, one third ranks).

    ``explore``: the share of the fitting steps that take a random action instead of the policy's
    (:func:`collect`; recorded in ``fitted_for["explore"]``). Fitted on its actions alone (0, the
    default), the dynamics model has seen one action in each state, and reads another action there
    (a learning model's exploration, a policy deployed as it samples, a fallback) as a shift:
    fitted with 0.1, a DQN on CartPole-v1 taking a random action at 5% of its steps alarmed 1 of 20
    ID episodes, not 5, a PPO 0, not 20, and a pole twice as long 20 of 20 either way, at delay 1
    (``scripts/exploration_alarms.py``, docs/your-policy.md). The threshold is calibrated on the
    policy's own actions as before.

    ``spread`` (with ``score``) joins the set whenever the policy has samples; ``combined``
    combines every other detector of the set (but what :data:`COMBINED_LEAVES_OUT` leaves out for
    ``task``, where others remain), and named alone it brings the learned members the
    policy can have (``["combined"]`` fits dynamics and features too). ``features`` needs an oodmon agent or estimator
    (a plain callable has no features); ``dynamics`` needs vector observations; ``scaled_spread``, fitted
    only when named, an oodmon ensemble (DQN or DDPG); ``drift`` reads the dynamics model's residuals
    (it brings ``dynamics``), fitted by default in an env oodmon has no variants of, else only when
    named; ``transitions`` needs observations whose values repeat (discrete states, where it is
    fitted by default instead of ``dynamics`` and ``drift``).

    ``dynamics_updates``: the dynamics model's fit stops after the whole epochs that hold at most
    this many Adam updates (``None``: all of its 100 epochs; :class:`DynamicsDetector`'s
    ``max_updates``; the default since fitting version 9). A cap bounds a large fit's time and
    blunts it: 30,000 transitions of a PPO's InvertedPendulum got 50 epochs at version 8's 3,000,
    and the model read a pole four times as heavy as ID where all 100 spiked at its onset
    (``scripts/dynamics_cap.py``; docs/detectors.md weighs both).

    ``workers``: processes that play the episodes side by side (0: one per core; :func:`collect`);
    the fitting itself runs here. A policy that draws nothing when it decides gets the same
    detectors from any number; an MC policy's episodes draw from streams of their own there
    (:mod:`oodmon.side_by_side`), and ``fitted_for["workers"]`` records how many played them.

    ``kept``: a file (``.npz``) where an interrupted fit (Ctrl-C, SIGTERM, or a worker's death)
    keeps the episodes it played whole, and from which a fit of the same policy, detectors, seed,
    episodes and world goes on: it plays only the episodes after them (none where the fit itself
    was interrupted). The ``KeyboardInterrupt`` (``BrokenProcessPool``) then carries their number
    in ``.kept_episodes`` (0 where none could be kept: episodes of Python objects, more than
    :data:`KEEP_AT_MOST` bytes, a dozen Pong games, or a full disk; a warning says why). A file
    made otherwise is not read (:class:`~oodmon.kept.KeptEpisodesWarning`; the policy is told by
    ``policy_hash``, else by its own: an agent's, its estimator's weights, a plain policy's weights
    or name, :func:`~oodmon.agents.plain.plain_policy_hash`). The caller removes it once the
    detectors are saved. The detectors are the uninterrupted fit's: side by side each episode
    draws from a stream of its own, and in one process the file keeps where an MC policy's draws
    stood after the episodes kept (:class:`~oodmon.kept.SamplingTrail`), which the fit that goes
    on draws on from.

    Raises:
        InvalidParameterError: an unknown detector name or fewer than 3 episodes.
        ConfigError: a detector this policy or env cannot have.
    """
    estimator, _, metadata = policy_parts(policy)
    task = task or metadata.get("task")
    detectors = _named(policy, env, task, detectors)
    if not is_whole(episodes, 3):
        raise InvalidParameterError(f"episodes={episodes!r} is not allowed; fitting needs a whole number >= 3 of "
                                    "ID episodes (two thirds fit, one third ranks)")
    check_max_updates(dynamics_updates, "dynamics_updates")  # before the episodes are played
    check_max_steps(max_steps)
    seed = check_seed(seed)
    explore = check_explore(explore)
    workers = resolve_workers(workers, episodes)
    n_actions = _checked_actions(detectors, policy, env)
    # The held-out third keeps its estimates: combined ranks the spread of the samples each action
    # was chosen from, as the monitor reads it (asked again, a sampled MC policy would draw others).
    # Played on for min_steps, the episodes are not known beforehand: all keep theirs, the fit
    # part's dropped after.
    keep_from = max(1, (2 * episodes) // 3) if not min_steps else 0
    made_by = None if kept is None else {
        "policy": policy_hash or _policy_identity(policy, estimator), "task": task,
        "env": getattr(env.spec, "id", None), "detectors": list(detectors),
        "episodes": episodes, "min_steps": min_steps, "seed": seed, "obs_noise": float(obs_noise),
        "max_steps": max_steps, **_draws(estimator), **({"explore": explore} if explore else {})}
    done, state = ([], None) if kept is None else _read_kept_trajectories(kept, made_by)
    if done and on_progress is not None:
        on_progress("kept detector fitting episodes", len(done), len(done))  # (an interrupted fit's)
    trail = SamplingTrail(estimator, workers)  # an MC policy in one process draws on from where they left it
    trail.resume(state)
    trajectories = done
    try:
        trajectories = collect(policy, env, episodes, seed=seed, on_progress=trail.progress(on_progress),
                               max_steps=max_steps, with_member_values="scaled_spread" in detectors,
                               estimates_from=keep_from if "combined" in detectors else None, min_steps=min_steps,
                               workers=workers, done=done, explore=explore)
        return _fitted(trajectories, detectors, estimator, task, score, n_actions, seed, dynamics_updates, on_progress,
                       policy_hash=policy_hash, obs_noise=obs_noise, workers=workers, max_steps=max_steps,
                       recorded={**({"explore": explore} if explore else {}), **_models_of(metadata)} or None)
    except (KeyboardInterrupt, BrokenProcessPool) as interrupt:  # (Ctrl-C, SIGTERM, a worker's death)
        if kept is not None:
            # in the episodes: those played whole; in the fit itself: every one
            played = finished_before(interrupt) if hasattr(interrupt, "finished") else trajectories
            interrupt.kept_episodes = _keep_trajectories(kept, made_by, played,
                                                         trail.state_after(len(played) - len(done), state))
        raise


def _named(policy: Any, env: gymnasium.Env, task: str | None, detectors: Sequence[str] | None) -> tuple[str, ...]:
    """The detectors a fit of ``policy`` in ``env`` fits: ``detectors`` (default: :func:`default_detectors`),
    with the default set where one of them brings it and ``dynamics`` where ``drift`` reads its residuals.

    Raises:
        InvalidParameterError: an unknown detector name.
    """
    detectors = default_detectors(policy, env, task) if detectors is None else tuple(detectors)
    strangers = [name for name in detectors if name not in DETECTORS]
    if strangers:
        raise InvalidParameterError(unknown("detector", strangers[0], DETECTORS))
    if brings_default_set(detectors):
        detectors = tuple(dict.fromkeys((*default_detectors(policy, env, task), *detectors)))
    if "drift" in detectors and "dynamics" not in detectors:  # it reads the dynamics model's residuals
        detectors = ("dynamics", *detectors)
    return detectors


def _checked_actions(detectors: Sequence[str], policy: Any, env: gymnasium.Env) -> int | None:
    """The discrete actions the dynamics model reads one-hot (``None``: the actions are numbers),
    once ``policy`` in ``env`` is checked to have each of ``detectors``.

    Raises:
        ConfigError: a detector it cannot have (:func:`cannot_have`).
    """
    # (spread is not asked: it joins where the policy has samples)
    reason = cannot_have_any([name for name in detectors if name != "spread"], policy, env)
    if reason is not None:
        raise ConfigError(reason)
    # (an Agent whose actions are read flattened, Agent.read_action, hands the model numbers: one-hot
    # rows of a Discrete counted from another start than 0 among them)
    read_flat = getattr(policy, "action_parts", None) is not None
    return int(env.action_space.n) if isinstance(env.action_space, gymnasium.spaces.Discrete) and not read_flat \
        else None


def _models_of(metadata: dict[str, Any]) -> dict[str, Any]:
    """``{"models": [...]}``: the SB3 model files a policy's metadata names, which a fitted set
    records as a threshold does (:func:`~oodmon.monitor.threshold.model_files`), so that a refusal
    can name them; nothing for a policy of no such files."""
    from oodmon.monitor.threshold import model_files

    models = model_files(metadata.get("models"))
    return {} if models is None else {"models": models}


def fitting_share(episodes: int) -> int:
    """How many of a fit's ``episodes`` fit the detectors, the first ones: two thirds, at least
    one; the rest rank them for ``combined``.

    Example:
        >>> fitting_share(90), fitting_share(4), fitting_share(1)
        (60, 2, 1)
    """
    return max(1, (2 * episodes) // 3)


def _fitted(trajectories: list[Trajectory], detectors: Sequence[str], estimator: Any, task: str | None, score: str,
            n_actions: int | None, seed: int, dynamics_updates: int | None, on_progress: Progress | None, *,
            policy_hash: str | None, obs_noise: float, workers: int, max_steps: int | None,
            recorded: dict[str, Any] | None = None) -> DetectorSet:
    """:func:`fit_detectors`' set, fitted on the episodes ``trajectories`` it played (``estimator``:
    the policy's, or ``None``); ``recorded``: what ``fitted_for`` says instead of how they were
    played (episodes from logs: no reset seeds of this fit's)."""
    n_fit = fitting_share(len(trajectories))
    fit, held_out = [replace(t, estimates=None) for t in trajectories[:n_fit]], trajectories[n_fit:]
    parts = [SpreadDetector(score)] if estimator is not None else []
    if "dynamics" in detectors:
        parts.append(DynamicsDetector(n_actions, seed=seed, min_logvar=min_logvar_for(task), max_updates=dynamics_updates
                                      ).fit(fit, on_progress=on_progress))
        if "drift" in detectors:
            parts.append(DriftDetector.of(parts[-1]))
    if "transitions" in detectors:
        parts.append(TransitionsDetector().fit(fit))
    if "features" in detectors:
        parts.append(FeaturesDetector(n_actions).fit(fit))
    for name in ("frames", "stillness", "motion", "vanishing"):  # the camera's, fitted on the episodes alone
        if name in detectors:
            parts.append(DETECTORS[name]().fit(fit))
    if "scaled_spread" in detectors:
        # An MC agent's fixed sub-networks share most of their weights and move together: whitened.
        whiten = fixed_masks(getattr(estimator, "masks", None))
        parts.append(ScaledSpreadDetector("whiten" if whiten else None).fit(fit))
    obs_shape = list(np.shape(trajectories[0].observations)[1:])
    # machine: the CPU kind that fitted them, whose float kernels another kind's do not round alike
    fitted_for = {"task": task, "obs_shape": obs_shape, "policy_hash": policy_hash, "version": FIT_VERSION,
                  "episodes": len(trajectories), "seed": seed, "obs_noise": obs_noise,
                  "masks": getattr(estimator, "masks", None), "machine": machine()}
    if workers > 1:  # (recorded only then: the sets fitted in one process before 2026-12-01 read the same)
        fitted_for["workers"] = workers
    if max_steps is not None:  # each episode's limit (since 2026-12-05: it may lift the env's own)
        fitted_for["max_steps"] = max_steps
    result = DetectorSet(parts, fitted_for=fitted_for | (recorded or {}))
    if "combined" in detectors:
        left_out = COMBINED_LEAVES_OUT.get(task or "", ())
        members = [d.name for d in parts if d.name not in left_out] or [d.name for d in parts]
        reference: dict[str, list[np.ndarray]] = {name: [] for name in members}
        for trajectory in held_out:
            for name, values in trajectory_scores(result, trajectory, estimator).items():
                if name in reference:
                    reference[name].append(values)
        combined = CombinedDetector(members).fit_reference(reference)  # per episode: see its long members
        result = result.with_detector(combined)
    return result


def cannot_have(detector: str, policy: Any, env: gymnasium.Env) -> str | None:
    """Why ``policy`` acting in ``env`` cannot have ``detector`` (a sentence), or ``None``."""
    estimator = policy_parts(policy)[0]
    if detector in ("spread", "features") and estimator is None:
        return (f"the {detector} detector reads the policy's {'samples' if detector == 'spread' else 'features'}, and "
                "this one has none (a plain policy, or one SB3 model of a kind oodmon does not sample): the learned "
                "detectors watch it (dynamics, combined)")
    if detector == "scaled_spread" and not has_members(estimator):
        return ("the scaled_spread detector puts each ensemble member's values on its own ID footing: it needs an "
                "oodmon ensemble, or an MC agent with fixed masks (load it with masks='fixed', --masks fixed): sampled "
                "MC samples are not members")
    if detector == "transitions" and is_picture(tuple(env.observation_space.shape or ()), env.observation_space.dtype):
        return ("the transitions detector counts states that repeat (discrete observations); this env's are pictures "
                "(the frames detector reads those)")
    actions = env.action_space
    if detector in ("dynamics", "drift", "features") and isinstance(actions, gymnasium.spaces.Discrete) \
            and actions.start and getattr(policy, "action_parts", None) is None:
        # (one-hot rows, or one class each, indexed by the action itself: 1 of Discrete(2, start=1)
        # read as the second, 2 past the end, an error after the fitting episodes were played)
        return (f"the {detector} detector reads a discrete action as one of its n actions counted from 0, and this "
                f"env's are {actions}: give oodmon an env whose actions count from 0 (a gymnasium.ActionWrapper "
                f"whose action(a) returns a + {int(actions.start)}) and a policy that acts in it, as SB3's models "
                "need too (they ignore start)")
    pictures = getattr(policy, "pictures", None)  # an Agent's dicts with pictures: the frames detector reads those
    if detector in ("frames", "motion", "vanishing") and len(env.observation_space.shape or ()) < 2 and pictures is None:
        return f"the {detector} detector needs image observations; this env's are of shape {env.observation_space.shape}"
    return None


def cannot_have_any(detectors: Sequence[str], policy: Any, env: gymnasium.Env) -> str | None:
    """Why ``policy`` acting in ``env`` cannot have the first of ``detectors`` it cannot have
    (:func:`cannot_have`), or ``None``."""
    return next((reason for name in detectors if (reason := cannot_have(name, policy, env)) is not None), None)


def check_can_have(detector: str | None, agent: Any, fitted: Any = None) -> None:
    """Refuse, saying why, an alarm on ``detector`` that ``agent`` cannot have (:func:`cannot_have`):
    said before minutes of fitting or calibration. ``fitted``: the detectors fitted so far, named.

    Raises:
        ConfigError: the sentence of :func:`cannot_have`.
    """
    if detector is None:
        return
    env = agent.make_env()
    try:
        reason = cannot_have(detector, agent, env)
    finally:
        env.close()
    if reason is not None:
        raise ConfigError(f"{reason}; calibrate another detector" + (f" (fitted: {', '.join(fitted.names)})" if fitted
                                                                     else ""))


def fitted_when_named(detector: str | None) -> tuple[str, ...] | None:
    """What to fit for an alarm that reads ``detector`` when nothing is fitted yet: ``None`` (the
    policy's default set) but for the detectors fitted only when named: ``scaled_spread`` alone,
    ``drift`` with the default set, whose ``combined`` then ranks it too, and ``transitions`` (the
    default for discrete observations; named for others, whose fit says whether they repeat) and
    ``stillness`` (the default for pictures; for vectors named), ``motion`` and ``vanishing``
    (pictures, named) with the default set and a ``combined`` that ranks them.

    Example:
        >>> fitted_when_named("drift"), fitted_when_named("scaled_spread"), fitted_when_named("combined")
        (('drift', 'combined'), ('scaled_spread',), None)
    """
    return {"scaled_spread": ("scaled_spread",), "drift": ("drift", "combined"),
            "transitions": ("transitions", "combined"), "stillness": ("stillness", "combined"),
            "motion": ("motion", "combined"), "vanishing": ("vanishing", "combined")}.get(detector or "")


def has_members(estimator: Any) -> bool:
    """Whether sample k of ``estimator`` is the same network at every decision: an ensemble's
    member, or an MC estimator's fixed sub-network (``masks="fixed"`` or ``"fixed-decisions"``)."""
    from oodmon.agents.estimators import EnsembleEstimator

    return isinstance(estimator, EnsembleEstimator) or fixed_masks(getattr(estimator, "masks", None))


def fit_agent_detectors(agent: Any, *, detectors: Sequence[str] | None = None, episodes: int | None = None,
                        seed: int = DETECTOR_FIT, score: str = DEFAULT_SCORE, obs_noise: float = 0.0,
                        max_steps: int | None = None, on_progress: Progress | None = None,
                        workers: int = 1, dynamics_updates: int | None = MAX_UPDATES,
                        kept: str | Path | None = None, explore: float = 0.0) -> DetectorSet:
    """:func:`fit_detectors` for an oodmon agent in its task's ID env (with ``obs_noise``), on
    ``episodes`` episodes; ``None``: :data:`DEFAULT_FIT_EPISODES`, and for an env oodmon has no
    variants of as many more as hold :data:`DEFAULT_FIT_STEPS` steps (:func:`default_fit_steps`);
    ``workers`` processes play them side by side; ``dynamics_updates``, ``kept`` (the episodes
    an interrupted fit keeps) and ``explore`` (random actions) as :func:`fit_detectors` takes them.
    ``max_steps``: each episode's time limit instead of the env's own, shorter (Pong's games) or
    longer (a deployment's runs, as ``calibrate --max-steps`` plays them)."""
    from oodmon.monitor.monitor import policy_hash

    check_max_steps(max_steps)
    env = agent.make_env(obs_noise, max_steps=max_steps)
    try:
        return fit_detectors(agent, env, detectors=detectors, episodes=episodes or DEFAULT_FIT_EPISODES, seed=seed,
                             score=score, task=agent.task, policy_hash=policy_hash(agent), obs_noise=obs_noise,
                             on_progress=on_progress, max_steps=max_steps,
                             min_steps=default_fit_steps(agent.task) if episodes is None else 0, workers=workers,
                             dynamics_updates=dynamics_updates, kept=kept, explore=explore)
    finally:
        env.close()


#: What fitting on a log's frames leaves out: what reads the policy at each observation, which a
#: log of pictures holds only the newest frame of (a stack's other frames are not logged), unless
#: the observations the policy acted on are rebuilt from those (:func:`acted_on_rebuilt`).
NOT_FROM_FRAMES = ("features", "scaled_spread")


def fit_recorded_detectors(agent: Any, episodes: Sequence[tuple[np.ndarray, ...]], *,
                           detectors: Sequence[str] | None = None, score: str = DEFAULT_SCORE, obs_noise: float = 0.0,
                           seed: int = DETECTOR_FIT, dynamics_updates: int | None = MAX_UPDATES,
                           on_progress: Progress | None = None, recorded: dict[str, Any] | None = None) -> DetectorSet:
    """:func:`fit_agent_detectors`' set, fitted on recorded ID episodes of ``agent`` instead of
    episodes it plays: each ``(observations, actions)``, ``(T, ...)`` each, as a monitor's log holds
    them (the observations the detectors read, the actions read flattened; :func:`oodmon.replay.
    fit_detectors_from_logs` reads them). The first two thirds fit, the last third ranks, as in a
    played fit; the features and an ensemble's member values are the agent's at each observation.
    ``seed`` seeds the models' fits; ``recorded`` is what ``fitted_for`` says of the episodes (no
    reset seeds: validate then refuses none of them). Episodes with a reading that is not finite
    are left out, as the monitor feeds no detector such a step.

    A policy that acts on pictures is fitted on the frames its log holds (the newest of each
    observation: ``observations`` of ``(T, H, W)`` or ``(T, H, W, 3)`` bytes), which is what the
    camera's detectors (``frames``, ``stillness``, ``motion``, ``vanishing``, and a ``combined`` of
    them) read of each step; the spread, which needs no fit, is kept. The detectors that read the
    policy at each observation (:data:`NOT_FROM_FRAMES`) are fitted on the policy's estimates at
    its observations rebuilt from the frames where they can be (:func:`acted_on_rebuilt`: oodmon's
    Pong, a VecFrameStack's, since 2026-12-07), else left out.

    A policy trained inside SB3's ``VecFrameStack`` acts on a stack of the observations its log
    holds (the newest of each, what its detectors read): each step's stack is rebuilt from them
    (:func:`~oodmon.agents.frame_stack.restacked`, since 2026-12-07) where the policy is asked.

    A policy with a memory of the episode, or one that reads a dict's text beside its numbers, is
    fitted where it has no samples (a plain policy, one SB3 model; since 2026-12-07): its
    detectors read what the log holds, and it is not asked. So is one whose dicts hold a picture
    beside their vectors (an SB3 ``MultiInputPolicy``'s camera): each episode then comes with its
    frames third, ``(observations, actions, frames)`` (:func:`~oodmon.replay.reader.read_steps`
    with ``pictures``), which the camera's detectors read beside the vectors.

    Raises:
        ConfigError: an agent whose detectors read less than it acts on in a way its log cannot
            rebuild (the picture, memory or text of the episode where it is asked for its samples),
            a dict's pictures the episodes lack, fewer than 3 usable episodes, or
            a detector it cannot have (as :func:`fit_detectors`), or one a log's frames cannot fit.
    """
    from oodmon.monitor.monitor import policy_hash

    stacking, in_dict = getattr(agent, "stacking", None), getattr(agent, "pictures", None)
    # a memory of the episode, a dict's text or its picture matter only where the policy is asked
    # (its samples); the detectors read what the log holds: the numbers, a dict's picture as the frame
    asked = agent.estimator is not None and (agent.remembers or agent.reads_words or in_dict is not None)
    if asked:
        raise ConfigError("its log holds what the detectors read of each step, not all that this policy acts on (the "
                          "picture, text or memory of the episode that its samples read): fit its detectors on played "
                          "episodes (`oodmon fit-detectors` without --from-logs)")
    pictures = any(np.asarray(e[0]).dtype == np.uint8 and np.ndim(e[0]) >= 3 for e in episodes)
    usable = []  # (observations, actions, a dict's pictures or None) of each episode that can be fitted on
    for episode in episodes:
        observations = np.asarray(episode[0]) if pictures else np.asarray(episode[0], np.float64)
        if len(observations) >= 2 and (pictures or np.isfinite(observations).all()):
            usable.append((observations, np.asarray(episode[1]), _dict_pictures(in_dict, episode)))
    if len(usable) < 3:
        raise ConfigError(f"{len(usable)} of the {len(episodes)} recorded episodes can be fitted on (two steps or "
                          "more, every reading finite); fitting needs at least 3 (two thirds fit, one third ranks)")
    check_max_updates(dynamics_updates, "dynamics_updates")
    seed = check_seed(seed)
    env = agent.make_env(obs_noise)  # its spaces: which detectors the agent can have
    try:
        names = _named(agent, env, agent.task, detectors)
        n_actions = _checked_actions(names, agent, env)
        # what a set fitted on frames records as the shape the detectors read (of a stack: the newest
        # observation's), which the monitor checks
        obs_shape = list(agent.own_shape if stacking is not None else env.observation_space.shape or ())
        acted_on = acted_on_rebuilt(agent, env)
    finally:
        env.close()
    estimator = agent.estimator
    if pictures:
        return _fitted_on_frames([e[:2] for e in usable], names, detectors, estimator, score, seed, on_progress,
                                 obs_shape,
                                 None if estimator is None else acted_on, n_actions, policy_hash=policy_hash(agent),
                                 task=agent.task, obs_noise=obs_noise,
                                 recorded={**_models_of(agent.metadata), **(recorded or {})})
    ensemble = "scaled_spread" in names and has_members(estimator)
    trajectories = []
    for episode, (observations, actions, camera) in enumerate(usable):
        steps = len(observations) - 1
        # a stack the policy acted on, rebuilt (a played fit's Trajectory.acted_on), else the logged ones
        stacks = None if acted_on is AS_LOGGED or estimator is None else np.stack(list(acted_on(observations)))
        estimates = [] if estimator is None else [
            estimator.estimate(obs) for obs in (observations if stacks is None else stacks)[:-1]]
        features, values = _policy_reads(estimates, steps, ensemble)
        trajectories.append(Trajectory(observations, actions[:steps], features, values, acted_on=stacks,
                                       pictures=camera))
        _said_asked(on_progress, estimator, episode + 1, len(usable))
    return _fitted(trajectories, names, estimator, agent.task, score, n_actions, seed, dynamics_updates, on_progress,
                   policy_hash=policy_hash(agent), obs_noise=obs_noise, workers=1, max_steps=None,
                   recorded={"seed": None, **_models_of(agent.metadata), **(recorded or {})})


def _dict_pictures(in_dict: Any, episode: tuple) -> np.ndarray | None:
    """An episode's pictures where the policy's observations are dicts with a picture beside their
    vectors (:class:`~oodmon.agents.dict_pictures.DictPictures`): its log's frames (a recorded
    episode's third part), in the picture's own shape (a frame of one channel is logged without its
    axis); ``None`` for other policies.

    Raises:
        ConfigError: an episode without a frame at each step (logged without pictures).
    """
    if in_dict is None:
        return None
    if len(episode) < 3 or episode[2] is None:
        raise ConfigError("this policy reads a picture beside the numbers of its dict observations, and a recorded "
                          "episode holds no frame at each step to fit the camera's detectors on: log its runs with "
                          "their frames, or fit on played episodes (`oodmon fit-detectors` without --from-logs)")
    frames = np.asarray(episode[2])
    if frames[0].size != math.prod(in_dict.picture_shape):  # (a stack's newest frame: not the picture)
        raise ConfigError(f"the log's frames are {frames.shape[1:]}, the newest of this policy's pictures of "
                          f"{in_dict.picture_shape}: fit on played episodes (`oodmon fit-detectors` without "
                          "--from-logs)")
    return frames.reshape(len(frames), *in_dict.picture_shape)


def _policy_reads(estimates: Sequence[Any], steps: int, members: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The policy's features at each of the ``steps`` observations it acted on, from its
    ``estimates`` there, and an ensemble's member values (``members``), as a played fit keeps them
    (:class:`Trajectory`); ``None`` for what it has not (no estimates: a plain policy)."""
    features = [estimate.features[0] for estimate in estimates if estimate.features is not None]
    return (np.asarray(features) if len(features) == steps else None,
            np.asarray([member_values(estimate) for estimate in estimates]) if members else None)


def _said_asked(on_progress: Progress | None, estimator: Any, done: int, episodes: int) -> None:
    """The progress of asking the policy at each logged step (a game of Pong's, a thousand of them,
    some seconds), where it is asked."""
    if on_progress is not None and estimator is not None:
        on_progress("the policy asked at each step: logged episodes", done, episodes)


#: Each step's observation the policy acted on, rebuilt from an episode's logged ones (from its reset).
Rebuild = Callable[[np.ndarray], Iterator[np.ndarray]]

#: The :data:`Rebuild` of a policy that acted on the observations its log holds: they, as they are.
AS_LOGGED: Rebuild = iter


def acted_on_rebuilt(agent: Any, env: gymnasium.Env) -> Rebuild | None:
    """How the observations ``agent`` acted on in ``env`` (its :meth:`~oodmon.agents.Agent.make_env`)
    are rebuilt from those its log holds, each step's newest: a stack its env builds from them
    (:func:`stack_depth`: oodmon's Pong), or one SB3's ``VecFrameStack`` built (the agent's
    ``stacking``, :func:`~oodmon.agents.frame_stack.restacked`); the logged ones as they are where the
    policy acts on those; ``None`` where they cannot be (the newest frames of another env's stack)."""
    from oodmon.agents.frame_stack import FrameStack, restacked

    depth = stack_depth(env)
    if depth is not None:
        return lambda frames: stacks_from_frames(frames, depth)
    stacking = getattr(agent, "stacking", None)
    if stacking is not None:
        while not isinstance(env, FrameStack):  # (Agent.wrap puts it around the env's own)
            env = env.env
        space, stacked = env.env.observation_space, env.observation_space
        if stacking.positions is not None:  # dicts of vectors: logged flattened, stacked key by key, read flattened
            return lambda own: (gymnasium.spaces.flatten(stacked, stack) for stack in restacked(
                [gymnasium.spaces.unflatten(space, np.asarray(v, np.float32)) for v in own], space, stacking))
        shape = tuple(space.shape)
        # a log's picture of one channel is kept without its axis: (84, 84) of an Atari (84, 84, 1)
        return lambda own: restacked(np.reshape(own, (len(own), *shape)).astype(space.dtype), space, stacking)
    space = env.observation_space
    shape = tuple(space.shape or ())
    if is_picture(shape, space.dtype) and newest_frame(np.zeros(shape, space.dtype)).shape != shape:
        return None  # a stack of pictures of the env's own making: the log holds its newest only
    return AS_LOGGED


def stack_depth(env: gymnasium.Env) -> int | None:
    """How many of a log's newest frames make one of ``env``'s observations, where the stack is
    rebuilt from them (:func:`stacks_from_frames`): for an env whose observation is a stack of its
    last frames along its first axis, ``(N, H, W)``, that an episode's first frame fills at the
    reset (``STACK_FILLED_BY_FIRST_FRAME``: oodmon's Pong; an env of yours may say so too);
    ``None`` for any other (SB3's ``VecFrameStack`` fills it with zeros, a wrapper may change what
    the env stacks)."""
    unwrapped, space = env.unwrapped, env.observation_space
    shape = tuple(space.shape or ())
    if not getattr(unwrapped, "STACK_FILLED_BY_FIRST_FRAME", False) or shape != unwrapped.observation_space.shape:
        return None
    # a stack along the first axis, (N, H, W), whose last plane the monitor logs (not channels last)
    if len(shape) != 3 or newest_frame(np.zeros(shape, space.dtype)).shape != shape[1:]:
        return None
    return int(shape[0])


def stacks_from_frames(frames: np.ndarray, depth: int) -> Iterator[np.ndarray]:
    """Each step's observation, a stack of ``depth`` frames (oldest first) that the episode's first
    frame fills at its start, rebuilt from ``frames``, each step's newest as a monitor logs them.

    Example:
        >>> frames = np.arange(3).reshape(3, 1, 1)
        >>> [stack.ravel().tolist() for stack in stacks_from_frames(frames, 2)]
        [[0, 0], [0, 1], [1, 2]]
    """
    for step in range(len(frames)):
        yield frames[np.maximum(np.arange(step - depth + 1, step + 1), 0)]


def _fitted_on_frames(episodes: list[tuple[np.ndarray, np.ndarray]], names: Sequence[str],
                      asked: Sequence[str] | None, estimator: Any, score: str, seed: int,
                      on_progress: Progress | None, obs_shape: list[int], acted_on: Rebuild | None,
                      n_actions: int | None, *, policy_hash: str | None, task: str | None, obs_noise: float,
                      recorded: dict[str, Any] | None) -> DetectorSet:
    """:func:`fit_recorded_detectors`' set of a policy acting on pictures, fitted on the frames of
    ``episodes``: the camera's detectors of ``names``, their ``combined``, and the spread where the
    policy has samples. The detectors that read the policy at each observation
    (:data:`NOT_FROM_FRAMES`) are fitted too where the observations it acted on are rebuilt from
    the log's frames (``acted_on``, :func:`acted_on_rebuilt`; the policy asked at each); else left
    out, and refused where ``asked`` names them. The set records the policy's own
    observation shape and MC masks, which the monitor checks, and ``recorded`` (the episodes'
    logs, the policy's SB3 model files, which a refusal names)."""
    cannot = [] if acted_on is not None else [name for name in NOT_FROM_FRAMES if name in (asked or ())]
    if cannot:
        raise ConfigError(f"the {cannot[0]} detector reads the policy at each observation, of which a log of pictures "
                          "holds the newest frame only (and this policy's stack cannot be rebuilt from them): fit it "
                          "on played episodes (`oodmon fit-detectors` without --from-logs), or leave it out")
    kept = [name for name in names if (acted_on is not None or name not in NOT_FROM_FRAMES) and name != "spread"]
    if not [name for name in kept if name != "combined"]:
        raise ConfigError(f"of {', '.join(names)}, a log's frames fit none (the camera's detectors, frames, "
                          "stillness, motion and vanishing, read them)")
    reads = acted_on is not None and any(name in kept for name in NOT_FROM_FRAMES)
    members = "scaled_spread" in kept and has_members(estimator)
    trajectories = []
    for episode, (frames, actions) in enumerate(episodes):
        steps = len(frames) - 1
        estimates = [estimator.estimate(obs) for obs in acted_on(frames[:-1])] if reads else None
        features, values = _policy_reads(estimates, steps, members) if reads else (None, None)
        # the held-out episodes' estimates kept: the combined's reference scores them off those
        held_out = episode >= fitting_share(len(episodes))
        trajectories.append(Trajectory(frames, actions[:steps], features, values,
                                       estimates=estimates if held_out else None))
        _said_asked(on_progress, estimator if reads else None, episode + 1, len(episodes))
    fitted = _fitted(trajectories, kept, None, task, score, n_actions, seed, None, on_progress, policy_hash=policy_hash,
                     obs_noise=obs_noise, workers=1, max_steps=None,
                     recorded={"seed": None, "obs_shape": obs_shape, "masks": getattr(estimator, "masks", None),
                               **(recorded or {})})
    if estimator is None:  # (as a played fit: the spread where the policy has samples)
        return fitted
    return DetectorSet([SpreadDetector(score), *fitted], fitted_for=fitted.fitted_for)


def fit_settings(agent: Any, detectors: Sequence[str] | None, *, score: str, episodes: int | None,
                 dynamics_updates: int | None, obs_noise: float, max_steps: int | None, workers: int,
                 explore: float = 0.0) -> dict[str, Any]:
    """What :func:`fit_agent_detectors` of these arguments fits of and with, as JSON-able data: the
    policy's hash, the detectors asked for, the fitting's version and settings. A set kept by an
    interrupted calibration (:class:`oodmon.kept.KeptFit`) is read again only where they agree."""
    from oodmon.monitor.monitor import policy_hash

    return {"policy": policy_hash(agent), "task": agent.task,
            "detectors": None if detectors is None else list(detectors), "score": score, "episodes": episodes,
            "dynamics_updates": dynamics_updates, "obs_noise": float(obs_noise), "max_steps": max_steps,
            "workers": workers, "version": FIT_VERSION, **_draws(agent.estimator),
            **({"explore": explore} if explore else {})}


def detectors_for(agent: Any, directory: str | Path | None = None) -> DetectorSet | None:
    """The fitted detectors in ``directory``, else those shipped beside ``agent``'s model (its
    ``detectors/`` folder), else ``None``."""
    if directory is not None:
        return DetectorSet.load(directory)
    own = Path(agent.path) / "detectors" if getattr(agent, "path", None) is not None else None
    return DetectorSet.load(own) if own is not None and (own / "detectors.json").is_file() else None


def _runs(indices: Sequence[int]) -> str:
    """Sorted indices in words, three or more in a row as a range (the note for a policy on Pong's
    RAM listed 118 of its 128 bytes one by one).

    Example:
        >>> _runs([0, 1, 2, 3, 7, 8, 10, 11, 12])
        '0-3, 7, 8, 10-12'
    """
    runs: list[list[int]] = []
    for index in indices:
        if runs and index == runs[-1][-1] + 1:
            runs[-1].append(index)
        else:
            runs.append([index])
    return ", ".join(f"{run[0]}-{run[-1]}" if len(run) > 2 else ", ".join(map(str, run)) for run in runs)


def fitting_notes(detectors: DetectorSet | None) -> list[str]:
    """What a fit leaves unwatched or blunt, in words (``oodmon calibrate`` and ``fit-detectors``
    print them, :func:`oodmon.watch` warns them): the readings the dynamics model takes as inputs
    only, and a dynamics fit its cap of updates ended before its last epoch (a model just fitted:
    a loaded one does not know how far it trained)."""
    dynamics = detectors["dynamics"] if detectors is not None and "dynamics" in detectors.names else None
    if dynamics is None:
        return []
    notes = []
    unscored = dynamics.unscored()
    if unscored:
        notes.append(f"dynamics: reading{'s' if len(unscored) > 1 else ''} {_runs(unscored)} of the observation "
                     f"(flattened) jump{'' if len(unscored) > 1 else 's'} between a few values over the ID transitions (a "
                     "contact flag) or never moved: inputs of the model, not scored by it (a Gaussian cannot model a "
                     "jump), so a fault of theirs alone goes unseen by this detector")
    trained = dynamics.epochs_trained
    if trained is not None and trained < dynamics.epochs:
        notes.append(f"dynamics: the model trained {trained} of its {dynamics.epochs} epochs, as many as hold the "
                     f"{dynamics.max_updates:,} Adam updates its fit is capped at; --dynamics-updates all "
                     "(dynamics_updates=None, the default) trains every one: slower, and on the benches measured it "
                     "alarmed more often or sooner, with a few more false alarms on some (docs/detectors.md, --dynamics-updates)")
    return notes
