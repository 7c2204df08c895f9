"""How often the clustered interval `validate` prints in step mode misses the true rate, simulated.

Run (seconds):
    .venv/bin/python scripts/interval_coverage.py [--draws 1000] [--steps 500] [--seed 0]

`oodmon validate` of a step-mode threshold counts the steps above it over fresh ID episodes and
prints a 95% interval of their share (:func:`oodmon.monitor.threshold.clustered_interval`: Korn
and Graubard's, each episode a cluster). Its limits come from a large-sample approximation, and
the thresholds' own limit is widened where the episodes' shares are skewed to the right (a few
episodes far above the rest: Hall's correction, ``_skew_factor``); until 2026-12-06 the interval
`validate` prints had no such correction. Since 2026-12-06 it has: its upper limit is widened by
the skew beyond what its Clopper-Pearson form carries (``_excess_skew_factor``). This draws
episodes whose share of steps above a threshold is known, and counts how often each limit misses
that share (each should miss it in at most 2.5% of the draws):

- ``beta``: each episode's share from a Beta of mean 0.08 and intra-episode correlation 0.3 (the
  simulation of ``tests/monitor/test_rule_and_calibration.py``);
- ``skewed``: 4% of the episodes at a share about 0.5 (Beta(4, 4)), the rest near 0.005 (Beta(0.3,
  60)): a few episodes far above the rest.

Read on 2026-12-06 (the defaults: 1,000 draws of episodes of 500 steps, seed 0), the upper limit
below the true share: beta 6.5% of the draws over 20 episodes, 3.5% over 50, 2.7% over 200
(validate's default); skewed 45.0%, 15.0% and 2.3%; the lower limit above it at most 1.4%. Before
the correction (the same draws): beta 8.1%, 4.6% and 3.4%; skewed 45.4%, 16.2% and 4.4%. The
skewed misses over 20 and 50 episodes are the draws in which none of the rare episodes came up
(0.96^20 = 44%, 0.96^50 = 13%): the episodes seen then show no skew, so no limit read off them
can reach the share. What helps is more episodes: `validate --episodes`, 200 by default.
"""

import argparse

import numpy as np

from oodmon.monitor.threshold import clustered_interval

KINDS = ("beta", "skewed")


def episodes(kind: str, count: int, steps: int, rng: np.random.Generator) -> tuple[list[tuple[int, int]], float]:
    """``count`` episodes of ``steps`` steps each, as ``(steps above, steps)``, and the true share."""
    if kind == "beta":
        a, b = 0.08 * (1 / 0.3 - 1), 0.92 * (1 / 0.3 - 1)
        share, true = rng.beta(a, b, count), 0.08
    elif kind == "skewed":
        rare = rng.random(count) < 0.04
        share = np.where(rare, rng.beta(4, 4, count), rng.beta(0.3, 60, count))
        true = 0.04 * 0.5 + 0.96 * 0.3 / 60.3
    else:
        raise ValueError(f"kind={kind!r}: use one of {', '.join(KINDS)}")
    return [(int(s), steps) for s in rng.binomial(steps, share)], true


def misses(kind: str, count: int, draws: int, steps: int = 500, seed: int = 0) -> tuple[float, float]:
    """The shares of ``draws`` draws in which the 95% interval's upper limit fell below the true
    share, and in which its lower limit rose above it."""
    rng = np.random.default_rng(seed)
    below = above = 0
    for _ in range(draws):
        counts, true = episodes(kind, count, steps, rng)
        interval = clustered_interval(counts)
        below += interval.high < true
        above += interval.low > true
    return below / draws, above / draws


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=500, help="steps per episode")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for kind in KINDS:
        for count in (20, 50, 200):
            below, above = misses(kind, count, args.draws, args.steps, args.seed)
            print(f"{kind:7s} {count:4d} episodes: upper limit below the true share in {below:.1%} of the draws, "
                  f"lower limit above it in {above:.1%} (each at most 2.5%)")


if __name__ == "__main__":
    main()
