"""Where a picture policy's alarms say in the picture (``AlarmEvent.region``), on Pong with a part of the camera frozen.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/alarm_regions.py [--method ensemble] [--threshold 3.95619]
         [--games 5] [--onset 200] [--max-steps 700] [--parts centre,agent_side,...]

The shipped Pong agent with its shipped detectors under its default alarm (``combined``; the
threshold ``oodmon calibrate --task pong --method M`` gives, docs/detectors.md: DropConnect
4.54612, Dropout 4.74657, the ensemble 3.95619). For each frozen part of the raw 210x160 frame
(``pong:frozen_region``: the centre block, the agent's and the opponent's thirds, the top and the
bottom halves), ``--games`` games (seeds 800,000 on) frozen from decision ``--onset``: each game's
first alarm after the onset, its cause, and the box it named (the ``vanishing`` detector's), and
whether that box lies within :data:`REACH` pixels (a ball's reach) of the frozen part in the
84x84 picture the agent reads. A few minutes for the ensemble on one core.
"""

from __future__ import annotations

import argparse
from collections import Counter

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import MemorySink, Monitor
from oodmon.monitor.alarms import Region
from oodmon.monitor.detectors import detectors_for
from oodmon.monitor.detectors.vanishing import REACH
from oodmon.seeds import CALIBRATION
from oodmon.threads import limit_threads

#: The default alarm's threshold of each shipped Pong agent (docs/detectors.md, "The default thresholds").
DEFAULT_THRESHOLDS = {"dropconnect": 4.54612, "dropout": 4.74657, "ensemble": 3.95619}
#: The frozen parts, (top, left, height, width) of the raw 210x160 frame (scripts/frozen_region.py's).
PARTS = {"centre": (80, 50, 70, 60), "agent_side": (0, 107, 210, 53), "opponent_side": (0, 0, 210, 53),
         "top_half": (0, 0, 105, 160), "bottom_half": (105, 0, 105, 160)}
#: Pong's raw frame, which the agent's picture (``region.rows`` x ``region.columns``) is scaled from.
RAW = (210, 160)


def near_part(region: Region, part: tuple[int, int, int, int], reach: float = REACH) -> bool:
    """Whether ``region`` (in the agent's picture) lies within ``reach`` pixels of ``part`` (in the
    raw frame, scaled to the picture).

    Example:
        >>> centre = PARTS["centre"]                  # rows 32-59, columns 26-57 of an 84x84 picture
        >>> near_part(Region(28, 21, 7, 14, 84, 84), centre), near_part(Region(0, 0, 7, 7, 84, 84), centre)
        (True, False)
    """
    top, left, height, width = part
    down, across = region.rows / RAW[0], region.columns / RAW[1]
    return (top * down - reach <= region.top and region.top + region.height <= (top + height) * down + reach
            and left * across - reach <= region.left and region.left + region.width <= (left + width) * across + reach)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--method", default="ensemble", choices=sorted(DEFAULT_THRESHOLDS))
    parser.add_argument("--threshold", type=float, help="the combined detector's threshold (default: the method's)")
    parser.add_argument("--games", type=int, default=5)
    parser.add_argument("--onset", type=int, default=200)
    parser.add_argument("--max-steps", type=int, default=700)
    parser.add_argument("--parts", default=",".join(PARTS))
    args = parser.parse_args()
    limit_threads()
    agent = load("pong", args.method, seed=CALIBRATION)  # an MC agent's sampling seeded as `oodmon calibrate`'s
    detectors = detectors_for(agent)
    threshold = DEFAULT_THRESHOLDS[args.method] if args.threshold is None else args.threshold
    print(f"pong/{args.method}: combined > {threshold:g}, frozen from decision {args.onset}, at most {args.max_steps}")
    causes, named, near = Counter(), 0, 0
    for name in args.parts.split(","):
        top, left, height, width = PARTS[name]
        for game in range(args.games):
            sink = MemorySink()
            with Monitor(agent, threshold, detectors=detectors, detector="combined", sinks=[sink]) as monitor:
                env = parse_variant(f"pong:frozen_region:top={top},left={left},height={height},width={width}").make(
                    onset_step=args.onset)
                monitor.run_episode(env, seed=800_000 + game, max_steps=args.max_steps)
            first = next((alarm for alarm in sink.alarms if alarm.step >= args.onset), None)
            if first is None:
                print(f"{name:14s} game {game}: no alarm by decision {args.max_steps}")
                continue
            causes[first.cause] += 1
            region = first.region
            close = region is not None and near_part(region, PARTS[name])
            named, near = named + (region is not None), near + close
            print(f"{name:14s} game {game}: +{first.step - args.onset} decisions, {first.cause}"
                  + (f", {region.text()}" + (f", within {REACH} pixels of the part" if close else ", away from it")
                     if region is not None else ""))
    print(f"first alarms by {', '.join(f'{cause} {count}' for cause, count in causes.most_common())}; {named} named a "
          f"region, {near} of them within {REACH} pixels of the frozen part")


if __name__ == "__main__":
    main()
