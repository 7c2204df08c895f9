"""Act on an alarm: hand the episode to a fallback controller once the monitor alarms.

Run (about 20 seconds on one core):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/fallback.py [--episodes 20] [--fit-explore 0.1]

The deployed policy is the shipped CartPole ensemble, watched by its shipped detectors (combined,
the alarm calibrated here on 50 ID episodes at 5% false alarms, confidence 0.9). The fallback is a
hand-written linear controller (``balance``: push toward where the pole leans, its spin, the cart's
place and speed weighed in), which keeps the pole up in ID episodes as the agent does, and in
other worlds better or worse than it. Each world is played ``--episodes`` times from the same
seeds, shifted from step 50: by the agent alone, by the fallback alone, and by the agent handing
over to the fallback at the step after its first alarm (a ``MonitoredEnv`` stepped with the
action of whichever acts; the monitor goes on scoring the fallback's steps). Each line: the
episodes that failed (the pole fell or the cart left the track before step 500) each way, how
many of the agent's alarmed (up to its first alarm, a hand-over's episode is the agent's), and how
many of the fallback's alone (its actions are not the policy's, which the shipped detectors were
fitted on).

The lesson the numbers teach: the alarm says that the world changed, not that the fallback does
better in it. Where the fallback is the sturdier controller (a pole twice as long) the hand-over
saves the episodes the agent loses; where it is not (gravity ten times Earth's) it loses those
the agent would have kept. Measure a fallback in the shifted worlds it is meant for before trusting
it with an alarm, as here.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import Monitor, MonitoredEnv, OtherActionsWarning, calibrate_agent
from oodmon.monitor.detectors import detectors_for, fit_agent_detectors
from oodmon.threads import limit_threads

#: The worlds played: ID, and shifts where one controller or the other fails, from step ONSET.
WORLDS = ("cartpole", "cartpole:length=2.0", "cartpole:force_mag=100.0", "cartpole:gravity=98.0")
ONSET = 50


def balance(obs) -> int:
    """The fallback: push toward where the pole leans, its spin, the cart's place and speed weighed in."""
    x, velocity, angle, spin = obs
    return int(angle + 0.5 * spin + 0.05 * x + 0.1 * velocity > 0)


def play(monitor: Monitor, world: str, episodes: int, way: str) -> tuple[list[int], list[int]]:
    """The steps each of ``episodes`` episodes of ``world`` lasted played ``way`` (``agent``,
    ``fallback``, or ``hand-over``: the agent, then the fallback from the step after its first
    alarm), and the step of each episode's first alarm (-1: none)."""
    lengths, alarms = [], []
    for episode in range(episodes):
        env = MonitoredEnv(parse_variant(world).make(onset_step=ONSET), monitor)
        obs, _ = env.reset(seed=episode)
        done, first, steps = False, -1, 0
        while not done:
            fallback = way == "fallback" or (way == "hand-over" and first >= 0)
            action = balance(obs) if fallback else monitor.agent.act(obs)
            obs, _, terminated, truncated, info = env.step(action)
            if info["oodmon"]["alarm"] and first < 0:
                first = steps
            done, steps = terminated or truncated, steps + 1
        lengths.append(steps)
        alarms.append(first)
    return lengths, alarms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20, help="episodes per world and way (default 20)")
    parser.add_argument("--fit-explore", type=float, default=0.0, metavar="P",
                        help="fit the agent's detectors here with a random action at this share of the fitting steps "
                             "instead of reading its shipped ones (fit_agent_detectors' explore; 30 s more)")
    args = parser.parse_args()
    limit_threads()
    # The fallback alone acts otherwise than the agent from the first step: said once, known here.
    warnings.filterwarnings("ignore", category=OtherActionsWarning)
    agent = load("cartpole", "ensemble")
    detectors = fit_agent_detectors(agent, explore=args.fit_explore) if args.fit_explore else detectors_for(agent)
    threshold = calibrate_agent(agent, 50, 0.05, detectors=detectors)
    monitor = Monitor(agent, threshold, detectors=detectors)
    print(f"alarm when {threshold.rule_text} ({threshold.detector})")
    for world in WORLDS:
        failed, alarmed, firsts = {}, {}, []
        for way in ("agent", "fallback", "hand-over"):
            lengths, alarms = play(monitor, world, args.episodes, way)
            failed[way], alarmed[way] = sum(length < 500 for length in lengths), sum(step >= 0 for step in alarms)
            if way == "hand-over":
                firsts = [step for step in alarms if step >= 0]
                fell = [length - step for length, step in zip(lengths, alarms) if step >= 0 and length < 500]
        delays = f", its first alarm at median step {np.median(firsts):g}" if firsts else ""
        after = f"; handed over, {len(fell)} fell a median {np.median(fell):g} steps after the alarm" if fell else ""
        print(f"{world:26s} failed: agent {failed['agent']:2d}, fallback {failed['fallback']:2d}, hand-over "
              f"{failed['hand-over']:2d} of {args.episodes}; alarmed: agent {alarmed['hand-over']:2d}{delays}, "
              f"fallback alone {alarmed['fallback']:2d}{after}", flush=True)


if __name__ == "__main__":
    main()
