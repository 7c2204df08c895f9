"""What thresholds calibrated on ID episodes alarm on others, from per-episode statistics computed once.

Run: .venv/bin/python scripts/redraw_calibration.py FILE [FILE ...] --detector frames [--threshold 3.12]

Each FILE is written by ``scripts/id_episode_statistics.py`` (one agent, one block of seeds). An
episode alarms under a threshold exactly when its statistic exceeds it, so:

- per block, and for the blocks pooled: the episodes, the empirical 90/95/99th percentiles, and
  with ``--threshold`` the share of the block's episodes above it (95% Clopper-Pearson interval);
- blocks against each other (two blocks: Mann-Whitney U and Kolmogorov-Smirnov p-values): whether
  the seed ranges give the same distribution, which the calibration's bound assumes (a fresh
  episode exchangeable with the calibration ones);
- re-drawn calibration sets of ``--n`` episodes (``--draws`` times, from the pooled episodes; each
  threshold checked on the rest): the share of thresholds whose realised rate exceeds ``--far``, at
  confidence 0.9 and 0.99 and on average (``none``), beside what the bound allows.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy import stats

from oodmon.monitor.threshold import calibrate, clopper_pearson, episodes_needed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--detector", required=True)
    parser.add_argument("--threshold", type=float, help="a threshold whose rate to read off the episodes")
    parser.add_argument("--far", type=float, default=0.05)
    parser.add_argument("--n", type=int, default=50, help="calibration episodes per re-draw (default 50)")
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    blocks = {}
    for path in args.files:
        data = json.loads(path.read_text())
        first, end = data["seeds"]
        blocks[f"seeds {first}-{end - 1}"] = np.asarray(data["statistics"][args.detector])
    pooled = np.concatenate(list(blocks.values()))
    for name, values in [*blocks.items(), ("pooled", pooled)]:
        q90, q95, q99 = np.quantile(values, [0.9, 0.95, 0.99])
        line = f"{name}: {len(values)} episodes, percentiles 90/95/99: {q90:.4f} / {q95:.4f} / {q99:.4f}"
        if args.threshold is not None:
            above = int(np.sum(values > args.threshold))
            low, high = clopper_pearson(above, len(values))
            line += f"; above {args.threshold:g}: {above} ({above / len(values):.1%}, {low:.1%}-{high:.1%})"
        print(line)
    if len(blocks) == 2:
        a, b = blocks.values()
        print(f"same distribution? Mann-Whitney p = {stats.mannwhitneyu(a, b).pvalue:.3f}, "
              f"Kolmogorov-Smirnov p = {stats.ks_2samp(a, b).pvalue:.3f}")
    exceeded: dict[float | None, list[float]] = {}
    for confidence in (0.9, 0.99, None):
        needed = episodes_needed(args.far, confidence)
        if args.n >= needed:
            exceeded[confidence] = []
        else:  # too few episodes for the bound
            print(f"confidence {confidence}: far={args.far:g} needs at least {needed} ID calibration episodes to bound "
                  f"its rate with confidence {confidence}; got {args.n}")
    rng = np.random.default_rng(args.seed)
    for _ in range(args.draws):
        order = rng.permutation(len(pooled))
        calibration, fresh = pooled[order[:args.n]], pooled[order[args.n:]]
        for confidence, rates in exceeded.items():
            threshold = calibrate([np.full(1, s) for s in calibration], args.far, consecutive=1, confidence=confidence)
            rates.append(np.mean(fresh > threshold.value))
    for confidence, rates in exceeded.items():
        rates = np.asarray(rates)
        allowed = f"at most {1 - confidence:.0%}" if confidence is not None else "no bound per threshold"
        print(f"n={args.n}, far={args.far}, confidence {confidence}: {np.mean(rates > args.far):.1%} of {len(rates)} "
              f"thresholds above far ({allowed}); mean rate {rates.mean():.2%}")


if __name__ == "__main__":
    main()
