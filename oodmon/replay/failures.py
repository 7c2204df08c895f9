"""What counts as a failure of a shifted episode: the monitor's benchmark asks whether an alarm came
before it (and how long before), and its table's footnote says what it is for each task.

CartPole fails when its episode ends by itself (the pole fell, the cart left the track); Pendulum,
which never ends by itself, when its mean reward over the last steps falls below a bound after a
swing-up; Pong never (a lost point is part of an ID game); an env oodmon has no variants of only
when ``failure="terminated"`` says that its end is one (``--failure terminated``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from oodmon.errors import ConfigError
from oodmon.names import TASKS
from oodmon.replay.reader import EpisodeLog

__all__ = ["FAILURES", "PENDULUM_FAILURE_REWARD", "PENDULUM_FAILURE_WINDOW", "check_failure", "failure_definition",
           "failure_known", "failure_step", "id_failures"]


#: Pendulum never ends by itself: it has failed once the mean reward of the last
#: ``PENDULUM_FAILURE_WINDOW`` steps falls below ``PENDULUM_FAILURE_REWARD`` (the reward is
#: -(angle^2 + 0.1 speed^2 + 0.001 torque^2): a mean below -1 means the pole is on average about a
#: radian, ~57 degrees, from upright; a balanced pole scores near 0).
PENDULUM_FAILURE_WINDOW = 10
PENDULUM_FAILURE_REWARD = -1.0


def failure_definition(tasks: Iterable[str], failure: str | None = None) -> str:
    """The monitor's table's footnote: what "failed" is for each of ``tasks`` (:func:`failure_step`
    in a line each, only theirs; your own env's by ``failure``), and what the other columns count.

    Example:
        >>> failure_definition(["MountainCar-v0"]).split("; ")[0]
        "failed: MountainCar-v0's not told (blank) unless --failure terminated (the env ended the episode itself)"
        >>> failure_definition(["Hopper-v5"], "terminated").split("; ")[0]
        "failed: Hopper-v5's episode ended by itself after the onset (--failure terminated)"
    """
    said, tasks = [], set(tasks)
    for task in sorted(tasks, key=lambda t: (t not in TASKS, t)):
        if task == "cartpole":
            said.append("CartPole's episode ended by itself after the onset")
        elif task == "pendulum":
            said.append(f"Pendulum's mean reward over the last {PENDULUM_FAILURE_WINDOW} steps fell below "
                        f"{PENDULUM_FAILURE_REWARD:g} after the onset (oodmon.replay.failure_step)")
        elif task == "pong":
            said.append("Pong's not told (blank: a lost point is part of an ID game)")
        elif failure_known(task, failure):
            said.append(f"{task}'s episode ended by itself after the onset (--failure {failure})")
        else:
            said.append(f"{task}'s not told (blank) unless --failure terminated (the env ended the episode itself)")
    id_row = ("the ID row's failed: ID episodes the env ended where that is a failure"
              + (" (not Pendulum's)" if "pendulum" in tasks else ""))
    return "; ".join([f"failed: {'; '.join(said)}" if said else "failed: not told", id_row,
                      "delays in steps from the onset", "lead: steps from the first alarm to the failure, over the "
                      "episodes alarmed before it", "first alarms by: what raised each episode's first alarm after "
                      "the onset (logs since format 7), and the reading it named first, the one the dynamics model "
                      "predicted worst (format 10 on)"])


#: What may count as a failure of an env oodmon has no variants of (replay's and bench's
#: ``--failure``): ``terminated``, the env ended the episode itself after the onset (a fall, a
#: crash: Hopper's, LunarLander's), as CartPole's failure is told.
FAILURES = ("terminated",)


def check_failure(failure: str | None) -> str | None:
    """``failure`` if it is ``None`` or one of :data:`FAILURES`, else :class:`ConfigError`."""
    if failure is not None and failure not in FAILURES:
        raise ConfigError(f"failure={failure!r}: what counts as a failure of your own env, one of "
                          f"{', '.join(FAILURES)} (the env ended the episode itself), or none")
    return failure


def failure_known(task: str, failure: str | None = None) -> bool:
    """Whether a failed episode of ``task`` is told: CartPole's and Pendulum's (not Pong's: a lost
    point is part of an ID game), and an env oodmon has no variants of only when ``failure`` says
    what one is (its end may be a success: Acrobot's, MountainCar's).

    Example:
        >>> failure_known("cartpole"), failure_known("pong"), failure_known("Acrobot-v1")
        (True, False, False)
        >>> failure_known("Hopper-v5", "terminated"), failure_known("pong", "terminated")
        (True, False)
    """
    return task != "pong" and (task in TASKS or check_failure(failure) is not None)


def failure_step(episode: EpisodeLog, task: str, failure: str | None = None) -> int | None:
    """The step at which a shifted episode failed, or ``None`` (no failure after the onset, or unknown).

    - An episode the env ended itself (``terminated``: CartPole's pole fell or its cart left the
      track) fails at its last step, the one whose action ended it.
    - Pendulum fails at the first step from the onset on where the mean reward of the last
      :data:`PENDULUM_FAILURE_WINDOW` steps is below :data:`PENDULUM_FAILURE_REWARD`, provided it
      was above at the onset (a pole not yet swung up at the onset does not count as a failure).
    - Pong has no failure here (a lost point is part of an ID game), nor has a log without rewards
      and ``terminated`` (format < 4), nor an env oodmon has no variants of (:func:`failure_known`)
      unless ``failure="terminated"``: it then fails as CartPole does.

    Example:
        >>> from oodmon.replay.reader import EpisodeLog
        >>> e = EpisodeLog(episode=0, env_id="", variant="cartpole:length=2.0", onset=5, seed=0, total_return=9.0,
        ...                length=9, alarms=0, first_alarm_step=None, terminated=True, scores=np.zeros(9),
        ...                shifted=np.zeros(9, bool), alarm=np.zeros(9, bool))
        >>> failure_step(e, "cartpole")
        8
    """
    if task == "pendulum":
        if episode.rewards is None or episode.onset >= episode.length:
            return None
        sums = np.convolve(episode.rewards, np.ones(PENDULUM_FAILURE_WINDOW), "full")[:episode.length]
        means = sums / np.minimum(np.arange(1, episode.length + 1), PENDULUM_FAILURE_WINDOW)  # of the last <= w
        if means[episode.onset] < PENDULUM_FAILURE_REWARD:
            return None
        below = np.flatnonzero(means[episode.onset:] < PENDULUM_FAILURE_REWARD)
        return int(episode.onset + below[0]) if len(below) else None
    if not failure_known(task, failure) or not episode.terminated:
        return None
    last = episode.length - 1
    return last if last >= episode.onset else None


def id_failures(episodes: Sequence[EpisodeLog], task: str, failure: str | None = None) -> int | None:
    """How many ID episodes failed as a shifted one fails by the env ending it (CartPole's pole fell,
    your own env's end with ``failure="terminated"``): a policy that fails in its own world too (a
    hopper that falls after 300 steps) makes "failed" of a shifted variant the shift's doing only in
    part. ``None`` where no such failure is told: Pendulum's (its failure is a fall from a pole swung up
    at the onset, which an ID episode lacks), Pong's, your own env's without ``failure``, a log
    without ``terminated`` (format < 4).

    Example:
        >>> from oodmon.replay.reader import EpisodeLog
        >>> def e(terminated):
        ...     return EpisodeLog(episode=0, env_id="", variant="Hopper-v5", onset=0, seed=0, total_return=9.0,
        ...                       length=9, alarms=0, first_alarm_step=None, terminated=terminated,
        ...                       scores=np.zeros(9), shifted=np.zeros(9, bool), alarm=np.zeros(9, bool))
        >>> id_failures([e(True), e(False), e(True)], "Hopper-v5", "terminated")
        2
        >>> id_failures([e(True)], "Hopper-v5"), id_failures([e(True)], "pendulum")
        (None, None)
    """
    if task == "pendulum" or not failure_known(task, failure) or any(e.terminated is None for e in episodes):
        return None
    return sum(bool(e.terminated) for e in episodes)
