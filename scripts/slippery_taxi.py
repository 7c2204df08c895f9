"""A taxi whose wheels may slip, and a policy that drives it: docs/your-policy.md's example of a policy of
discrete observations (gymnasium's ``Taxi-v4``: 500 states, one integer each) watched by oodmon.

``SlipperyTaxi-v0`` is ``Taxi-v4`` (its 200-step limit) inside :class:`Slip`, whose attribute
``slip`` (0.0: the plain taxi) is the probability that a step's action is replaced by one drawn
at random (the env's own generator, so seeded); ``--variant SlipperyTaxi-v0:slip=0.2 --onset 5``
makes the road icy from step 5. ``drive`` is the optimal policy of the plain taxi, from value
iteration over the env's own transition table (computed once, at import; a plain function
``obs -> action``, as ``oodmon ... --policy slippery_taxi:drive`` takes it).

Used as ``PYTHONPATH=scripts oodmon calibrate --policy slippery_taxi:drive --env
slippery_taxi:SlipperyTaxi-v0 ...`` (docs/your-policy.md, "Discrete observations"). Run as a script on a
log of a slip's run or of a sensor fault's (``SlipperyTaxi-v0:obs.noise=0.1``), it plays each
episode again from its seed and tells in which episodes something went wrong from the onset on
(an action replaced by another, a state read as another than the taxi's), and the alarms of those
and of the others:
    .venv/bin/python scripts/slippery_taxi.py runs/taxi-slip.mcap
"""

from __future__ import annotations

import gymnasium
import numpy as np

ENV_ID = "SlipperyTaxi-v0"


class Slip(gymnasium.Wrapper):
    """With probability :attr:`slip`, the env gets a random action instead of the policy's
    (``info["slipped"]``: it was another than the policy's)."""

    def __init__(self, env: gymnasium.Env, slip: float = 0.0) -> None:
        super().__init__(env)
        self.slip = slip

    def step(self, action):
        random, taken = self.env.unwrapped.np_random, action
        if self.slip > 0 and random.random() < self.slip:
            taken = int(random.integers(self.action_space.n))
        obs, reward, terminated, truncated, info = self.env.step(taken)
        return obs, reward, terminated, truncated, {**info, "slipped": taken != action}


def make_slippery_taxi(slip: float = 0.0) -> gymnasium.Env:
    return Slip(gymnasium.make("Taxi-v4"), slip)


def optimal_actions(env: gymnasium.Env, gamma: float = 0.99, sweeps: int = 300) -> np.ndarray:
    """The greedy action of each state after value iteration over ``env.unwrapped.P`` (toy-text envs' table)."""
    table = env.unwrapped.P
    n_states, n_actions = len(table), len(table[0])
    rows = np.array([(s, a, p, s2, r, done) for s in range(n_states) for a in range(n_actions)
                     for p, s2, r, done in table[s][a]], dtype=np.float64)
    pair = (rows[:, 0] * n_actions + rows[:, 1]).astype(int)
    following, prob, reward, going_on = rows[:, 3].astype(int), rows[:, 2], rows[:, 4], 1.0 - rows[:, 5]
    value = np.zeros(n_states)
    for _ in range(sweeps):
        q = np.bincount(pair, prob * (reward + gamma * going_on * value[following]), n_states * n_actions)
        value = q.reshape(n_states, n_actions).max(axis=1)
    return q.reshape(n_states, n_actions).argmax(axis=1)


if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point=make_slippery_taxi)
_ROUTE = optimal_actions(gymnasium.make("Taxi-v4"))


def drive(obs: int) -> int:
    """The plain taxi's optimal action in state ``obs``."""
    return int(_ROUTE[int(obs)])


def faults_and_alarms(log_path: str) -> dict[str, object]:
    """Each episode of a slip's or a sensor fault's run (an ``oodmon run`` log) played again from
    its seed: in how many something went wrong (a slip: an action replaced by another; a misread:
    the policy read another state than the taxi's), how many of those and of the others alarmed,
    and the steps from the first slip or misread to the first alarm."""
    from oodmon.envs import parse_env_shift
    from oodmon.replay import read_log

    counts = {"episodes": 0, "faulted": 0, "faulted_alarmed": 0, "others_alarmed": 0, "delays": []}
    for episode in read_log(log_path).episodes:
        env = parse_env_shift(episode.variant).make(onset_step=int(episode.onset))
        obs, _ = env.reset(seed=int(episode.seed))
        first = None
        for step in range(episode.length):
            obs, _, terminated, truncated, info = env.step(drive(obs))
            if (info["slipped"] or obs != env.unwrapped.s) and first is None:
                first = step
            if terminated or truncated:
                break
        alarm = episode.first_alarm_step
        counts["episodes"] += 1
        if first is None:
            counts["others_alarmed"] += alarm is not None
            continue
        counts["faulted"] += 1
        counts["faulted_alarmed"] += alarm is not None
        if alarm is not None:
            counts["delays"].append(int(alarm - first))
    return counts


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", help="an oodmon run's MCAP log of the taxi (oodmon run --policy slippery_taxi:drive ...)")
    found = faults_and_alarms(parser.parse_args().log)
    delays = found.pop("delays")
    print(found, "steps from the first slip or misread to the first alarm: median", float(np.median(delays)) if delays else None,
          "p90", float(np.percentile(delays, 90)) if delays else None)
