"""Per-step scores of many fresh ID episodes of a shipped agent, kept once, and step-mode calibrations re-drawn from them.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/step_scores.py play --episodes 1000 --out runs/step-scores
     .venv/bin/python scripts/step_scores.py redraw runs/step-scores [--n 50] [--draws 1000] [--far 0.05]

``play`` plays ``--episodes`` ID episodes of ``--task``/``--method`` (the shipped agent and its
fitted detectors), seeds ``--seed`` on (3,000,000: apart from calibration's, validation's and the
detectors' fitting), in ``--workers`` processes, and keeps each block of ``--block`` episodes'
per-step scores of ``--detector`` as ``OUT/<first seed>.npz`` (each episode's scores one after
another, and the episodes' lengths). A stopped run goes on from the blocks it has.

``redraw`` pools those episodes and, ``--draws`` times, calibrates a step-mode threshold on ``--n``
of them drawn without replacement (``oodmon.monitor.threshold.calibrate(mode="step")``) and reads
its realised rate, the share of the other episodes' steps above it. It prints, for
``--confidence`` (default 0.9) and for ``none``, the share of thresholds whose rate exceeds
``--far`` (a threshold with confidence 1 - d promises at most d of them; ``none`` promises the
rate on average only), with its 95% Clopper-Pearson interval, and the thresholds' mean rate.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from oodmon.monitor.threshold import calibrate, clopper_pearson


def play(args: argparse.Namespace) -> None:
    from oodmon.agents import load
    from oodmon.monitor.calibration import id_episode_scores
    from oodmon.monitor.detectors import detectors_for
    from oodmon.outputs import write_whole

    agent = load(args.task, args.method, seed=args.seed)
    detectors = detectors_for(agent)
    needed = detectors.subset([args.detector]) if args.detector != "spread" else None
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    for first in range(args.seed, args.seed + args.episodes, args.block):
        path = args.out / f"{first}.npz"
        if path.is_file():
            continue
        count = min(args.block, args.seed + args.episodes - first)
        scores = id_episode_scores(agent, count, seed=first, detectors=needed, detector=args.detector,
                                   workers=args.workers)
        write_whole(path, lambda part: _write_block(part, scores))
        print(f"{first + count - args.seed}/{args.episodes} episodes, {time.perf_counter() - started:.0f} s", flush=True)


def _write_block(part: Path, scores: list[np.ndarray]) -> None:
    with open(part, "wb") as out:  # (a file, not a name: np.savez_compressed would add .npz to the part's name)
        np.savez_compressed(out, scores=np.concatenate(scores), lengths=np.array([len(s) for s in scores]))


def episodes_of(folder: Path) -> list[np.ndarray]:
    """Every episode's per-step scores that ``play`` kept in ``folder``, in the order of their seeds."""
    episodes = []
    for path in sorted(folder.glob("*.npz"), key=lambda p: int(p.name.split(".")[0])):
        with np.load(path) as block:
            episodes += np.split(block["scores"], np.cumsum(block["lengths"])[:-1])
    return episodes


def redraw(args: argparse.Namespace) -> None:
    episodes = episodes_of(args.folder)
    rng = np.random.default_rng(args.seed)
    print(f"{len(episodes)} episodes, {sum(map(len, episodes)):,} steps; {args.draws} calibrations of {args.n} "
          f"episodes each, far={args.far}")
    for confidence in (args.confidence, None):
        rates = []
        for _ in range(args.draws):
            order = rng.permutation(len(episodes))
            chosen, rest = order[:args.n], order[args.n:]
            value = calibrate([episodes[i] for i in chosen], args.far, mode="step", confidence=confidence).value
            rates.append(sum(int((episodes[i] > value).sum()) for i in rest) / sum(len(episodes[i]) for i in rest))
        above = int(np.sum(np.array(rates) > args.far))
        low, high = clopper_pearson(above, args.draws)
        allowed = f"at most {1 - confidence:.0%} promised" if confidence is not None else "on average only"
        print(f"confidence {confidence}: {above} of {args.draws} thresholds above far ({above / args.draws:.1%}, "
              f"{low:.1%}-{high:.1%}; {allowed}); mean realised rate {np.mean(rates):.2%}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    played = commands.add_parser("play")
    played.add_argument("--task", default="cartpole")
    played.add_argument("--method", default="ensemble")
    played.add_argument("--detector", default="combined")
    played.add_argument("--episodes", type=int, default=1000)
    played.add_argument("--block", type=int, default=100)
    played.add_argument("--seed", type=int, default=3_000_000)
    played.add_argument("--workers", type=int, default=2)
    played.add_argument("--out", type=Path, required=True)
    drawn = commands.add_parser("redraw")
    drawn.add_argument("folder", type=Path)
    drawn.add_argument("--n", type=int, default=50)
    drawn.add_argument("--draws", type=int, default=1000)
    drawn.add_argument("--far", type=float, default=0.05)
    drawn.add_argument("--confidence", type=float, default=0.9)
    drawn.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    play(args) if args.command == "play" else redraw(args)


if __name__ == "__main__":
    from oodmon.threads import limit_threads

    limit_threads()
    main()
