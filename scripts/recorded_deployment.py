"""A deployment oodmon cannot play, watched from its recorded episodes (``oodmon.watch_recorded``).

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/recorded_deployment.py [--task cartpole|pendulum|pong]
         [--fit 90] [--calibration 50] [--fresh 300] [--shifted 20] [--onset 50] [--steps N] [--far 0.05]
         [--detectors dynamics,combined] [--variants 'cartpole:length=2.0;cartpole:masscart=3.0;...'] [--calibrations K]

The "robot" is a hand-written controller in oodmon's env of ``--task``, stepped by a loop of this
script's own, which records each episode as ``(observations, actions)``: oodmon is told neither the
env nor the policy. CartPole's (docs/your-policy.md's) pushes toward where the pole falls (two
discrete actions); Pendulum's brakes the swing and pushes toward the top (a torque, a ``Box``);
Pong's presses its six buttons at random, and its records are the (4, 84, 84) pictures it sees (a
camera: the camera's detectors read them; ``--detectors frames,stillness,vanishing,combined``
names the one that sees a part of the picture freeze, and the alarms' regions are printed).

The detectors are fitted on ``--fit`` recorded ID episodes (reset seeds 0 on) and the alarm
calibrated on ``--calibration`` others (seeds 10,000 on, ``--far`` at confidence 0.9); then
``--fresh`` fresh recorded ID episodes (seeds 50,000 on) are fed to the monitor step by step, as a
deployment feeds it, and ``--shifted`` episodes of each variant shifted from step ``--onset`` (seeds
90,000 on). It prints the threshold, the fresh episodes alarmed with their 95% interval, and per
variant the episodes alarmed, those alarmed before the onset, the delays, and the causes and
readings the first alarms named. About a minute on one core with the defaults.

``--calibrations K``: K thresholds, each calibrated on a set of ``--calibration`` episodes of its own,
and the share of the fresh episodes each alarms (from the fresh episodes' scores, once): how the
false-alarm rate of the threshold you get varies from one calibration to another, which the
promise bounds (with probability 0.9 it is at most ``--far``).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import gymnasium
import numpy as np

from oodmon.envs import parse_variant
from oodmon.monitor import MemorySink, Monitor, calibrate_on_episodes, episode_statistic, fit_on_episodes
from oodmon.monitor.threshold import clopper_pearson
from oodmon.threads import limit_threads

ACTIONS = gymnasium.spaces.Discrete(2)
NAMES = ["x", "v", "theta", "omega"]
#: Each task's action space, reading names and shifts measured by default.
TASKS = {"cartpole": (ACTIONS, NAMES, "cartpole:length=2.0;cartpole:masscart=3.0;cartpole:force_mag=5.0"),
         "pendulum": (gymnasium.spaces.Box(-2.0, 2.0, (1,), np.float32), ["cos theta", "sin theta", "omega"],
                      "pendulum:m=1.5;pendulum:g=14.0;pendulum:l=1.5"),
         "pong": (gymnasium.spaces.Discrete(6), None,
                  "pong:gaussian_noise@3;pong:frozen_region:top=80,left=50,height=70,width=60;pong:obs.stuck=1")}
#: Each task's episode limit by default.
STEPS = {"cartpole": 500, "pendulum": 200, "pong": 300}


def controller(obs: np.ndarray) -> int:
    """The robot's own policy, which oodmon never runs: push toward where the pole falls."""
    return int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)


def pendulum_controller(obs: np.ndarray) -> np.ndarray:
    """Pendulum's: brake the swing, and push toward the top (a torque in [-2, 2])."""
    cos, sin, omega = obs
    return np.clip([-2.0 * sin - 0.5 * omega], -2.0, 2.0).astype(np.float32)


class RandomButtons:
    """Pong's "robot": it presses the six buttons at random (seeded per episode); the camera's
    detectors read the picture, not the policy."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> int:
        return int(self.rng.integers(6))


def record(count: int, seed: int, steps: int, spec: str = "cartpole", onset: int = 0
           ) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` episodes of the task's controller in ``spec`` (shifted from step ``onset``), at
    most ``steps`` long, each as the robot's own records: (observations, actions), one row per step."""
    env = parse_variant(spec).make(onset_step=onset, max_episode_steps=steps)
    task = spec.split(":")[0]
    episodes = []
    for index in range(count):
        act = {"pendulum": pendulum_controller, "pong": RandomButtons(seed + index)}.get(task, controller)
        obs, _ = env.reset(seed=seed + index)
        observations, actions, done = [], [], False
        while not done:
            action = act(obs)
            observations.append(obs)
            actions.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        episodes.append((np.array(observations), np.array(actions)))
    env.close()
    return episodes


def watched(monitor, episodes: list[tuple[np.ndarray, np.ndarray]], sink: MemorySink) -> list[int | None]:
    """Each episode's first alarmed step, ``monitor`` fed step by step (``sink`` among its sinks)."""
    firsts = []
    with monitor:
        for observations, actions in episodes:
            monitor.begin_episode()
            for obs, action in zip(observations, actions):
                monitor.step(obs, action=action)
            record = monitor.end_episode()
            firsts.append(record.first_alarm_step)
    return firsts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=sorted(TASKS), default="cartpole")
    parser.add_argument("--fit", type=int, default=90)
    parser.add_argument("--calibration", type=int, default=50)
    parser.add_argument("--fresh", type=int, default=300)
    parser.add_argument("--shifted", type=int, default=20)
    parser.add_argument("--onset", type=int, default=50)
    parser.add_argument("--steps", type=int, help="each episode's limit (default: STEPS, the task's)")
    parser.add_argument("--far", type=float, default=0.05)
    parser.add_argument("--detectors", help="the detectors to fit (default: fit_on_episodes's)")
    parser.add_argument("--variants", help="the shifts, separated by ';' (default: the task's in TASKS)")
    parser.add_argument("--calibrations", type=int, default=1,
                        help="calibrate this many thresholds on sets of their own and count each one's false alarms "
                             "on the fresh episodes (default 1: the one)")
    args = parser.parse_args()
    actions, names, variants = TASKS[args.task]
    args.steps = args.steps or STEPS[args.task]
    limit_threads()
    start = time.perf_counter()
    # (what watch_recorded does, in its two parts: the threshold and the detectors are kept here)
    detectors = fit_on_episodes(record(args.fit, 0, args.steps, args.task), actions,
                                detectors=None if args.detectors is None else args.detectors.split(","))
    threshold = calibrate_on_episodes(detectors, record(args.calibration, 10_000, args.steps, args.task), args.far,
                                      reading_names=names)
    print(f"fitted {', '.join(detectors.names)} on {args.fit} and calibrated on {args.calibration} recorded episodes "
          f"in {time.perf_counter() - start:.0f} s: {threshold.detector} > {threshold.value:.6g}")
    sink = MemorySink()
    fresh = watched(monitor_of(threshold, detectors, sink), record(args.fresh, 50_000, args.steps, args.task), sink)
    alarmed = sum(first is not None for first in fresh)
    low, high = clopper_pearson(alarmed, len(fresh))
    print(f"fresh ID: {alarmed} of {len(fresh)} alarmed ({alarmed / len(fresh):.1%}, 95% interval "
          f"{low:.1%}-{high:.1%}; target {args.far:.0%} at confidence 0.9)")
    if args.calibrations > 1:
        other_calibrations(args, detectors, threshold, statistics(sink, threshold))
    for spec in (args.variants or variants).split(";"):
        sink = MemorySink()
        firsts = watched(monitor_of(threshold, detectors, sink),
                         record(args.shifted, 90_000, args.steps, spec, args.onset), sink)
        early = sum(first is not None and first < args.onset for first in firsts)
        delays = sorted(first - args.onset for first in firsts if first is not None and first >= args.onset)
        events = [event for event in sink.alarms if event.step >= args.onset]
        firsts_named = {event.episode: event for event in reversed(events)}.values()  # each episode's first
        causes = Counter(event.cause for event in firsts_named)
        readings = Counter(f"[{event.readings[0][0]}]" + (f" ({names[event.readings[0][0]]})" if names else "")
                           for event in firsts_named if event.readings)
        regions = Counter(event.region.text() for event in firsts_named if event.region is not None)
        print(f"{spec} from step {args.onset}: {len(delays)} of {len(firsts)} alarmed after the onset, {early} before; "
              f"delays {delays}; causes {dict(causes)}" + (f"; first readings {dict(readings)}" if readings else "")
              + (f"; regions {dict(regions)}" if regions else ""))


def statistics(sink: MemorySink, threshold) -> np.ndarray:
    """Each episode's statistic under ``threshold``'s rule (:func:`~oodmon.monitor.alarms.episode_statistic`),
    from the scores of the alarm's detector ``sink`` kept: an episode alarms exactly where it
    exceeds a threshold's value."""
    scores: dict[int, list[float]] = {}
    for step in sink.steps:
        scores.setdefault(step.episode, []).append(step.score)
    return np.array([episode_statistic(np.asarray(values), threshold.consecutive, threshold.window,
                                       warmup=threshold.warmup) for _, values in sorted(scores.items())])


def other_calibrations(args: argparse.Namespace, detectors, first, fresh: np.ndarray) -> None:
    """``--calibrations``: as many thresholds, each calibrated on ``--calibration`` episodes of its
    own (seeds 10,000 on, one set after the other; the first is the threshold above), and the share
    of the fresh episodes (their statistics ``fresh``) each would have alarmed: the promise is that
    at most about 1 - confidence of such thresholds exceed the target."""
    values = [first.value]
    for index in range(1, args.calibrations):
        episodes = record(args.calibration, 10_000 + index * args.calibration, args.steps, args.task)
        values.append(calibrate_on_episodes(detectors, episodes, args.far).value)
    rates = np.array([np.mean(fresh > value) for value in values])
    above = int(np.sum(rates > args.far))
    print(f"{args.calibrations} calibrations of {args.calibration} episodes each: thresholds "
          f"{min(values):.4g}-{max(values):.4g}; their false-alarm rates on the {len(fresh)} fresh episodes "
          f"{rates.min():.1%}-{rates.max():.1%} (median {np.median(rates):.1%}); {above} of {args.calibrations} above "
          f"the target {args.far:g} (the promise: with probability 0.9 each is not)")


def monitor_of(threshold, detectors, sink: MemorySink) -> Monitor:
    """The monitor of the calibration made, logging to ``sink``: what a deployed process's
    ``watch_recorded(threshold=...)`` reads back."""
    return Monitor(None, threshold, detectors=detectors, sinks=[sink])


if __name__ == "__main__":
    main()
