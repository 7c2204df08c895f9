"""``transitions``: how surprising each step's transition is to the ID transitions counted, for
observations whose values repeat exactly: a gymnasium ``Discrete`` state (FrozenLake's cell,
Taxi's), ``MultiDiscrete``, ``MultiBinary``, a dict of them, read one-hot as SB3 reads them.

The ``dynamics`` detector models readings that change smoothly; every reading of a one-hot state
jumps, so it has nothing to predict there (and a Taxi's 500 readings took it over 12 minutes to
fit, 2026-11-30). Here the model is a table: fitting counts each (state, action, next state) of
the ID episodes, and a step's value is its transition's surprise, ``-log P(s' | s, a)``, with

    P(s' | s, a) = (n(s, a, s') + ALPHA * q(s')) / (n(s, a) + ALPHA)
    q(s') = (n(s') + 1) / (n + S + 1)

``n(s, a, s')`` the transition's count, ``n(s, a)`` the pair's, ``q`` the next states' ID
frequency with one count more each and one for every state never seen (``n`` transitions, ``S``
states). A transition seen often scores near ``-log`` of its frequency (0 in a deterministic
world); a pair never seen scores by how rare its next state was (``log(n + S + 1)`` for a state
never seen); a pair seen often that leads elsewhere than it ever did scores higher still. A
world that slips, or a state the policy never reached, shows at once. The score is the mean over
the episode's last ``window`` steps, whose window starts full of the ID steps' median value (as
``frames``'), so a first rare step is not a window's mean.

Its blind spot: a change that keeps every transition among those seen (the same moves, taken in
another order). Observations that rarely repeat (continuous readings) are refused at fit: each
would be a state of its own.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.monitor.detectors.base import Detector, RecentMean, StepContext, Trajectory

__all__ = ["TransitionsDetector"]

#: The prior's weight: how many transitions' worth of belief in the next states' ID frequency a pair
#: starts with.
ALPHA = 1.0

#: Fit refuses observations of which more than this share are distinct (of 50 or more): continuous
#: readings, every one a state of its own (CartPole's: all of them). Discrete ones repeat, if not in
#: a short fit of many starts: Blackjack's 60 hands of 1.4 steps, 59 distinct of 99.
MOST_DISTINCT = 0.9


def _key(values: Any) -> bytes:
    """One observation's (or action's) values as a key: float64 bytes, ``-0.0`` as ``0.0``."""
    return (np.asarray(values, dtype=np.float64).ravel() + 0.0).tobytes()


def _rows(values: Any) -> np.ndarray:
    """An episode's observations (or actions) as float64 rows, one per step, ``-0.0`` as ``0.0``."""
    values = np.asarray(values, dtype=np.float64)
    return values.reshape(len(values), -1) + 0.0


def _id_of(row: np.ndarray, ids: dict[bytes, int], rows: list[np.ndarray]) -> int:
    """``row``'s id in ``ids`` (by its bytes, as :func:`_key` makes them), a new one appended to ``rows``."""
    key = row.tobytes()
    found = ids.get(key)
    if found is None:
        found = ids[key] = len(rows)
        rows.append(row)
    return found


def _compact(rows: np.ndarray) -> np.ndarray:
    """``rows`` (floats) in the smallest dtype that holds them exactly: bytes for one-hot states."""
    if np.all(rows == np.round(rows)):
        for dtype in (np.uint8, np.int16, np.int32):
            info = np.iinfo(dtype)
            if rows.size == 0 or (rows.min() >= info.min and rows.max() <= info.max):
                return rows.astype(dtype)
    return rows


class TransitionsDetector(Detector):
    """The surprise of each transition to the ID transitions counted (see the module's text).

    Args:
        window: steps averaged into a step's score (1: each step's own; default 20).

    Example:
        >>> walk = Trajectory(np.eye(4)[[0, 1, 2, 3, 2, 1, 0]], np.array([1, 1, 1, 0, 0, 0]))
        >>> detector = TransitionsDetector(window=1).fit([walk] * 5)
        >>> seen = detector.step_surprise(np.eye(4)[1], 1, np.eye(4)[2])      # right, as always
        >>> slipped = detector.step_surprise(np.eye(4)[1], 1, np.eye(4)[0])   # right, and it went left
        >>> round(seen, 3), round(slipped, 3)
        (0.121, 3.555)
    """

    name = "transitions"
    learned = True

    def __init__(self, *, window: int = 20) -> None:
        self._recent = RecentMean(window)
        self.window = window
        self._states: np.ndarray | None = None  # (S, D): each distinct observation, flattened
        self._actions: np.ndarray | None = None  # (A, d): each distinct action, flattened
        self._transitions = np.zeros((0, 3), np.int64)  # (N, 3): state, action, next state ids
        self._counts = np.zeros(0, np.int64)  # (N,): each transition's count
        self._typical = 0.0  # the ID steps' median value: what a new episode's window starts with
        self._last: tuple[Any, int] | None = None  # the last step's observation and its state id

    @property
    def fitted(self) -> bool:
        return self._states is not None

    # -- fitting -----------------------------------------------------------------------------------
    def fit(self, trajectories: Sequence[Trajectory], *, seed: int = 0) -> TransitionsDetector:
        """Count the transitions of ID ``trajectories``.

        Raises:
            ConfigError: no transitions, or observations or actions that rarely repeat (continuous).
        """
        trajectories = [t for t in trajectories if len(t) > 0]
        if not trajectories:
            raise ConfigError("the transitions detector needs ID transitions to count; got none")
        state_ids: dict[bytes, int] = {}  # by first appearance; a dict of row bytes, not np.unique's sort
        action_ids: dict[bytes, int] = {}  # of rows (Taxi's 45,000 one-hot rows of 500: 4.5 s against 0.1)
        states, moves, rows = [], [], []
        for trajectory in trajectories:
            ids = [_id_of(row, state_ids, states) for row in _rows(trajectory.observations)]
            acted = [_id_of(row, action_ids, moves) for row in _rows(trajectory.actions)]
            rows.append(np.stack([ids[:-1], acted, ids[1:]], axis=1))
        seen = sum(len(t.observations) for t in trajectories)
        if seen >= 50 and len(states) > MOST_DISTINCT * seen:
            raise ConfigError(f"the transitions detector counts states that repeat; {len(states)} of the {seen} ID "
                              "observations are distinct (continuous readings?): for vector observations use the "
                              "dynamics detector")
        moves = np.array(moves)
        if not np.all(moves == np.round(moves)):
            raise ConfigError("the transitions detector counts (state, action) pairs, and these actions are "
                              "continuous: it watches policies of discrete actions")
        rows = np.concatenate(rows).astype(np.int64)
        self._states, self._actions = _compact(np.array(states)), _compact(moves)
        self._transitions, self._counts = np.unique(rows, axis=0, return_counts=True)
        self._index()
        self._typical = float(np.median([self._surprise(*row) for row in rows]))
        return self

    def _index(self) -> None:
        """The lookups that scoring reads, from the arrays (after a fit or a load)."""
        self._state_ids = {_key(row): i for i, row in enumerate(self._states)}
        self._action_ids = {_key(row): i for i, row in enumerate(self._actions)}
        self._triples = {tuple(int(v) for v in row): int(n) for row, n in zip(self._transitions, self._counts)}
        pairs: Counter[tuple[int, int]] = Counter()
        arrivals: Counter[int] = Counter()
        for (s, a, s_next), n in self._triples.items():
            pairs[s, a] += n
            arrivals[s_next] += n
        self._pairs, self._arrivals = pairs, arrivals
        self._denominator = float(self._counts.sum() + len(self._states) + 1)

    def _surprise(self, state: int, action: int, following: int) -> float:
        """``-log P(following | state, action)`` of ids (-1: never seen)."""
        q = (self._arrivals.get(following, 0) + 1) / self._denominator
        pair = self._pairs.get((state, action), 0)
        seen = self._triples.get((state, action, following), 0)
        return -math.log((seen + ALPHA * q) / (pair + ALPHA))

    def _state_id(self, obs: Any) -> int:
        """The id of the state ``obs`` is (-1: never seen)."""
        return self._state_ids.get(_key(obs), -1)

    def step_surprise(self, obs: Any, action: Any, next_obs: Any) -> float:
        """One transition's surprise, ``-log P(next_obs | obs, action)``."""
        self.check_fitted()
        return self._surprise(self._state_id(obs), self._action_ids.get(_key(action), -1), self._state_id(next_obs))

    # -- scoring -----------------------------------------------------------------------------------
    def reset(self) -> None:
        self._recent.fill(self._typical)
        self._last = None

    def score(self, context: StepContext) -> float:
        """The mean surprise over the episode's last ``window`` steps (the first step: the ID median)."""
        self.check_fitted()
        following = self._state_id(context.obs)
        last, self._last = self._last, (context.obs, following)
        if context.prev_obs is None:
            return self._recent.add(self._typical)
        # the previous step's observation was looked up then (the monitor hands the same array on)
        state = last[1] if last is not None and last[0] is context.prev_obs else self._state_id(context.prev_obs)
        action = self._action_ids.get(_key(context.prev_action), -1)
        return self._recent.add(self._surprise(state, action, following))

    # -- state -------------------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        return {"window": self.window}

    def tensors(self) -> dict[str, np.ndarray]:
        self.check_fitted()
        return {"states": self._states, "actions": self._actions, "transitions": self._transitions,
                "counts": self._counts, "typical": np.array([self._typical])}

    @classmethod
    def from_state(cls, config: Mapping[str, Any], tensors: Mapping[str, np.ndarray]) -> TransitionsDetector:
        detector = cls(**config)
        if any(name not in tensors for name in ("states", "actions", "transitions", "counts", "typical")):
            raise ConfigError("the transitions detector's tensors are incomplete")
        states, actions = np.asarray(tensors["states"]), np.asarray(tensors["actions"])
        transitions, counts = np.asarray(tensors["transitions"], np.int64), np.asarray(tensors["counts"], np.int64)
        if (states.ndim != 2 or actions.ndim != 2 or transitions.ndim != 2 or transitions.shape[1:] != (3,)
                or counts.shape != transitions.shape[:1]):
            raise ConfigError(f"the transitions detector's tensors have shapes states {states.shape}, actions "
                              f"{actions.shape}, transitions {transitions.shape}, counts {counts.shape}; expected "
                              "(S, D), (A, d), (N, 3) and (N,)")
        bounds = np.array([len(states), len(actions), len(states)])
        if len(transitions) and (transitions.min() < 0 or np.any(transitions.max(axis=0) >= bounds)):
            raise ConfigError("the transitions detector's transitions name states or actions it does not hold")
        if np.any(counts < 1) or not np.isfinite(np.asarray(tensors["typical"], np.float64)).all():
            raise ConfigError("the transitions detector's counts are not all positive, or its typical value is not a "
                              "number")
        detector._states, detector._actions = states, actions
        detector._transitions, detector._counts = transitions, counts
        detector._typical = float(np.asarray(tensors["typical"]).reshape(-1)[0])
        detector._index()
        return detector
