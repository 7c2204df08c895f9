"""A partly frozen camera in Pong: part of the picture held from the onset, the rest live. Does the
shipped agent's alarm see it, how soon, and how many points go first?

Run (a few seconds per game on one thread; a threshold from ``oodmon calibrate --task pong --method
M [--detector motion] --out F``, read with the detectors fitted beside it as ``oodmon run`` reads them):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/frozen_region.py --method dropconnect \\
        --threshold runs/pong-dc.json [--regions agent_side,opponent_side] [--games 5]
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/frozen_region.py --tiles 7

A region of each raw 210x160 RGB frame the camera delivers (before the agent's preprocessing, as
``pong:`` corruptions are applied) holds what it showed at the onset: dead sensor rows, a frozen
part of the image, the variant ``pong:frozen_region:top=T,left=L,height=H,width=W`` (which ``oodmon
run --variant`` and ``oodmon bench --variants`` take as well). ``pong:obs.stuck=1`` is the whole
picture frozen (``stillness`` sees it some ten decisions on: docs/detectors.md); here the
rest of the picture goes on moving, so the whole picture never stands still. Regions (rows, columns
of the raw frame): ``agent_side`` the right third (the agent's paddle), ``opponent_side`` the left
third, ``centre`` rows 80-149 x columns 50-109, ``top_half``, ``bottom_half``, ``whole``, or
``R0:R1,C0:C1`` of your own.

For each region, ``--games`` games (seeds 800,000 on) monitored with the threshold from step
``--onset``, at most ``--max-steps`` decisions: the games alarmed, the delays (first alarm - onset),
alarms before the onset, and the points the agent lost from the onset to its alarm (to the game's
cut-off when none).

``--tiles N``: why ``stillness`` of tiles would not do (``motion`` weighs each tile's still runs by
how often it moves after the action taken instead). The agent plays ``--id-games`` ID games (seeds
700,000 on); each N x N-pixel tile of the newest 84x84 frame is a sensor whose longest unchanged
run is found over the first half, printed as a grid, and the most a game of the second half stood
still past it, per tile: the tiles that move most (the paddles' columns) stand still in ID games
for some 56-158 decisions, the others for hundreds, and fresh games pass those records (2026-11-30,
16 games: by up to 13 and 860). The agent's MC draws are seeded: a run plays the same games again.
Each region's games start from the agent as loaded (seed 0), so a region's figures are the same
whatever regions ``--regions`` lists before it. (Until 2026-12-01 the draws ran on from region to
region, and an MC agent's games of a region depended on the regions before it.)
Seen on 2026-12-01 (DropConnect, combined > 4.30125, the draws running on): ``--regions centre``
alone alarmed 1 of 5 games (delay 603, 4 points lost first; the others lost 0, 4, 0, 0), after
``agent_side`` 3 of 5 (delays 890, 125, 116; 12, 0 and 0 points lost first; 2 and 0 unalarmed). The same 5 seeds' ID
games lose 0-1 points from decision 200 to 1,200. The ``vanishing`` detector (``oodmon calibrate
--task pong --method dropconnect --detector vanishing``: vanishing > 0), ``--games 10`` and every
region but ``whole``: 10 of 10 games each, the centre at 4-33 decisions (Dropout's: 9 or 10 of 10,
the centre at 10-31; the ensemble's: 10 of 10, the centre at 6-34; docs/detectors.md).
Since 2026-12-01 ``vanishing`` is in Pong's default set (``DEFAULT_ADDS``), so a threshold of
``oodmon calibrate --task pong --method M`` reads it through ``combined``; the figures above by
the default alarm are of the set before. With it (DropConnect, combined > 4.54612, ``--regions
centre,agent_side --games 10``): the centre 10 of 10 at 5-34 decisions, no point lost; the agent's
third 10 of 10 at 2-39, one point lost in one game, the same games as ``--regions agent_side``
alone gives (2-47 when it ran on from the centre's draws).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from oodmon.agents import load
from oodmon.envs import Variant, parse_variant
from oodmon.envs.pong import SCREEN_SIZE
from oodmon.errors import OodmonError
from oodmon.monitor import Monitor, Threshold
from oodmon.monitor.detectors import collect, detectors_for
from oodmon.monitor.detectors.frames import newest_frame
from oodmon.monitor.detectors.motion import tile_changes
from oodmon.monitor.detectors.stillness import longest_runs
from oodmon.threads import limit_threads

#: Named regions of the raw 210x160 frame: (top, left, height, width).
REGIONS = {
    "agent_side": (0, 107, 210, 53),
    "opponent_side": (0, 0, 210, 53),
    "centre": (80, 50, 70, 60),
    "top_half": (0, 0, 105, 160),
    "bottom_half": (105, 0, 105, 160),
    "whole": (0, 0, 210, 160),
}


def region_variant(text: str) -> str:
    """The variant of a named region, or of ``R0:R1,C0:C1`` of the raw frame:
    ``pong:frozen_region:top=...,left=...,height=...,width=...``.

    Raises:
        argparse.ArgumentTypeError: neither, or a region outside the frame (said by the corruption).
    """
    if text in REGIONS:
        top, left, height, width = REGIONS[text]
    else:
        try:
            (r0, r1), (c0, c1) = (tuple(int(n) for n in part.split(":")) for part in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is no region: give one of {', '.join(REGIONS)} or "
                                             "R0:R1,C0:C1") from None
        top, left, height, width = r0, c0, r1 - r0, c1 - c0
    spec = f"pong:frozen_region:top={top},left={left},height={height},width={width}"
    try:
        return parse_variant(spec).spec
    except OodmonError as error:
        raise argparse.ArgumentTypeError(f"{text!r}: {error}") from None


def load_agent(method: str):
    """The shipped Pong agent, its MC draws seeded: the same games at every run."""
    return load("pong", method, seed=0)


def frozen_games(agent, threshold: Threshold, name: str, args: argparse.Namespace) -> dict[str, object]:
    """The region's games under the monitor (the detectors ``calibrate`` fitted beside the threshold
    file, as ``oodmon run`` reads them, else the agent's shipped ones): alarms, delays and the points
    lost before the alarm."""
    beside = Path(f"{args.threshold}.detectors")
    spec = region_variant(name)
    env = parse_variant(spec).make(onset_step=args.onset)
    delays, early, lost, missed_lost = [], 0, [], []
    with Monitor(agent, threshold, detectors=detectors_for(agent, beside if beside.is_dir() else None)) as monitor:
        for game in range(args.games):
            record = monitor.run_episode(env, seed=800_000 + game, max_steps=args.max_steps)
            alarm = record.first_alarm_step
            after = np.asarray(record.rewards[args.onset:alarm if alarm is not None and alarm >= args.onset else None])
            if alarm is not None and alarm < args.onset:
                early += 1
            elif alarm is not None:
                delays.append(alarm - args.onset)
                lost.append(int((after < 0).sum()))
            else:
                missed_lost.append(int((after < 0).sum()))
    env.close()
    return {"region": name, "variant": spec, "alarmed": f"{len(delays)}/{args.games}", "early": early, "delays": delays,
            "points lost before the alarm": lost, "points lost in the games not alarmed": missed_lost}


def tile_records(agent, tile: int, games: int) -> None:
    """Print each tile's longest unchanged run over the first half of ``games`` ID games (seeds
    700,000 on), and the most a game of the second half went past it."""
    n = SCREEN_SIZE // tile
    side = n * tile  # (tiles that would not fill the frame's last rows and columns are left out)
    runs = []
    for game in range(games):
        trajectory = collect(agent, Variant("pong").make(), 1, seed=700_000 + game)[0]
        frames = [newest_frame(obs)[:side, :side] for obs in trajectory.seen]
        changed = np.array([tile_changes(b, a, n) for a, b in zip(frames[:-1], frames[1:])])
        runs.append(longest_runs(~changed))
        print(f"ID game {game + 1}/{games}: {len(frames)} steps", flush=True)
    runs = np.array(runs)
    half = games // 2
    record, past = runs[:half].max(axis=0), (runs[half:] - runs[:half].max(axis=0)).max(axis=0)
    print(f"longest unchanged run of each {tile}x{tile} tile over ID games 1-{half} (the agent's paddle on the right):")
    print(np.array2string(record.reshape(n, n), max_line_width=200))
    print(f"the most games {half + 1}-{games} stood still past it (<= 0: none did):")
    print(np.array2string(past.reshape(n, n), max_line_width=200))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--method", choices=("dropout", "dropconnect", "ensemble"), default="dropconnect")
    parser.add_argument("--threshold", help="a threshold file of the shipped Pong agent (oodmon calibrate --out)")
    parser.add_argument("--regions", default="agent_side,opponent_side,centre,top_half",
                        help=f"comma-separated: {', '.join(REGIONS)}, or R0:R1,C0:C1 (give one of your own alone)")
    parser.add_argument("--games", type=int, default=5)
    parser.add_argument("--onset", type=int, default=200)
    parser.add_argument("--max-steps", type=int, default=1200, help="decisions per game at most")
    parser.add_argument("--tiles", type=int, help="instead: the ID records of N x N-pixel tiles (see above)")
    parser.add_argument("--id-games", type=int, default=16)
    args = parser.parse_args()
    limit_threads()
    agent = load_agent(args.method)
    if args.tiles is not None:
        tile_records(agent, args.tiles, args.id_games)
        return
    if args.threshold is None:
        parser.error("give --threshold (a file of oodmon calibrate --task pong --method M --out F), or --tiles N")
    threshold = Threshold.load(args.threshold)
    names = [args.regions] if args.regions.count(",") == 1 and ":" in args.regions else args.regions.split(",")
    for name in names:
        region_variant(name)  # refused before any game is played
    print(f"threshold: {threshold.detector} > {threshold.value:g}; onset {args.onset}, {args.games} games of at most "
          f"{args.max_steps} decisions", flush=True)
    for index, name in enumerate(names):  # each region with the agent as loaded: its games do not depend on the regions before
        print(frozen_games(agent if index == 0 else load_agent(args.method), threshold, name, args), flush=True)


if __name__ == "__main__":
    main()
