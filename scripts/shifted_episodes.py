"""Which shifted episodes hold a five-trial CartPole row down? Per trial, the shifted episodes'
lengths and the AUROC without the episodes the agent survives.

Run (seconds; it reads the bench's logs and plays nothing):
    .venv/bin/python scripts/shifted_episodes.py results/bench/cartpole-dropconnect-fixed-masks.json \\
        --out runs/bench5 [--detector scaled_spread] [--variants cartpole:masscart=9.0,cartpole:force_mag=1.0] \\
        [--window 20]

The paper's protocol scores every step of every episode of a variant the agent fails on, the
episodes in which the agent keeps the pole up to the time limit too (CartPole: 500 steps, ended by
the limit, not by the env). A per-step detector that reads those steps as ID is right about the
states and wrong by the label. For each row of a ``bench --results`` file (a method, a variant and
a detector; CartPole only: its failures are the env's own), this finds the bench's logs under
``--out`` (where the bench ran), checks that each trial's AUROC recomputed from them is the file's,
and prints per trial the shifted episodes' lengths (``*``: survived to the time limit) and the
AUROC over the episodes that fail only, then both rows' mean ± std over the trials.

``--window W`` (W > 1) prints beside them the AUROC of each step's mean score over the episode's
last W steps (``RecentMean``, as the learned detectors' scores are 20-step means): whether a
detector that separates a trial's steps weakly would separate its stretches of steps.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np

from oodmon.bench.cache import _cell_log
from oodmon.bench.baseline import load_bench_result
from oodmon.bench.config import BenchConfig
from oodmon.replay import read_log
from oodmon.replay.failures import failure_step
from sweep_full_depth import step_auroc  # scripts/

TOLERANCE = 1e-9  # a recomputed AUROC must be the file's, to the float


def bench_config(results: dict, out: str) -> BenchConfig:
    """The ``BenchConfig`` a results file was made with, its logs under ``out``."""
    names = {f.name for f in fields(BenchConfig)}
    settings = {k: tuple(v) if isinstance(v, list) else v for k, v in results["config"].items() if k in names}
    return BenchConfig(**settings, out=out)


def episodes_of(path: Path, detector: str) -> list[tuple[np.ndarray, bool]]:
    """Each complete episode of a log: its per-step scores of ``detector`` and whether it failed."""
    if not path.exists():
        raise SystemExit(f"shifted_episodes: no log {path}: was the bench run with --out set to another folder?")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a torn log recovers its complete episodes; the AUROC check tells
        log = read_log(path)
    return [(episode.scores_of(detector), failure_step(episode, "cartpole") is not None) for episode in log.episodes]


def recent_means(scores: np.ndarray, window: int) -> np.ndarray:
    """Each step's mean score over the episode's last ``window`` steps (all of them before that).

    Example:
        >>> recent_means(np.array([1.0, 3.0, 5.0]), 2).tolist()
        [1.0, 2.0, 4.0]
    """
    sums = np.cumsum(np.r_[0.0, scores])
    ends = np.arange(1, len(scores) + 1)
    starts = np.maximum(ends - window, 0)
    return (sums[ends] - sums[starts]) / (ends - starts)


def trial_row(config: BenchConfig, row: dict, trial: int, window: int = 1) -> dict:
    """One trial of a results row: its episodes' lengths, the AUROC as the bench has it and without the
    episodes the agent survives (``None`` if every shifted episode survives); with ``window`` > 1 also
    the AUROC of the ``window``-step means."""
    method, detector = row["method"], row["detector"]
    id_episodes = episodes_of(_cell_log(config, method, trial, config.task), detector)
    ids = np.concatenate([s for s, _ in id_episodes])
    shifted = episodes_of(_cell_log(config, method, trial, row["variant"]), detector)
    auroc = step_auroc(ids, np.concatenate([s for s, _ in shifted]))
    expected = row["aurocs"][str(trial)]
    if abs(auroc - expected) > TOLERANCE:
        raise SystemExit(f"shifted_episodes: {method} {row['variant']} trial {trial}: the logs give AUROC {auroc:.6f}, "
                         f"the results file {expected:.6f}; these are not the logs that made it")
    failed = [s for s, fails in shifted if fails]
    windowed = None
    if window > 1:
        windowed = step_auroc(np.concatenate([recent_means(s, window) for s, _ in id_episodes]),
                              np.concatenate([recent_means(s, window) for s, _ in shifted]))
    return {"trial": trial, "lengths": [len(s) for s, _ in shifted], "survived": [not fails for _, fails in shifted],
            "auroc": auroc, "auroc_failing": step_auroc(ids, np.concatenate(failed)) if failed else None,
            "auroc_window": windowed}


def mean_std(values: list[float | None]) -> str:
    """``mean ± std`` over the trials of the values that exist (the std as the bench's tables take
    it, and the paper's: ``np.std``, over the trials themselves)."""
    values = [v for v in values if v is not None]
    return f"{np.mean(values):.3f} ± {np.std(values):.3f}" if values else "-"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, help="a `oodmon bench --results` file of a CartPole bench")
    parser.add_argument("--out", default="runs/bench5", help="the --out the bench ran with (its logs are there)")
    parser.add_argument("--detector", default=None, help="the rows of this detector only (default: every detector)")
    parser.add_argument("--variants", default=None,
                        help="comma-separated variant specs (default: the rows of the paper's variants)")
    parser.add_argument("--window", type=int, default=1,
                        help="also the AUROC of each step's mean score over the episode's last W steps (W > 1)")
    args = parser.parse_args(argv)
    if args.window < 1:
        parser.error(f"--window must be a whole number >= 1, not {args.window}")
    results = load_bench_result(args.results)
    config = bench_config(results, args.out)
    if config.task != "cartpole" or config.protocol != "paper":
        raise SystemExit("shifted_episodes: CartPole benches of the paper's protocol only (a CartPole episode fails "
                         f"when the env ends it); this file is {config.task}, protocol {config.protocol}")
    wanted = set(args.variants.split(",")) if args.variants else None
    rows = [r for r in results["rows"] if (args.detector is None or r["detector"] == args.detector)
            and (r["variant"] in wanted if wanted is not None else bool(r["paper"])) and r["aurocs"]]
    if not rows:
        raise SystemExit(f"shifted_episodes: no row of {args.results} matches --detector/--variants")
    for row in rows:
        print(f"{row['method']} {row['variant']} ({row['detector']}):")
        trials = [trial_row(config, row, int(t), args.window) for t in sorted(row["aurocs"], key=int)]
        windowed = f"; {args.window}-step means" if args.window > 1 else ""
        for t in trials:
            lengths = ", ".join(f"{n}{'*' if s else ''}" for n, s in zip(t["lengths"], t["survived"]))
            failing = "-" if t["auroc_failing"] is None else f"{t['auroc_failing']:.3f}"
            extra = f"{windowed} {t['auroc_window']:.3f}" if windowed else ""
            print(f"  trial {t['trial']}: lengths {lengths}; AUROC {t['auroc']:.3f}, over the failing episodes {failing}"
                  + extra)
        print(f"  mean ± std: {mean_std([t['auroc'] for t in trials])} (the bench's); over the failing episodes "
              f"{mean_std([t['auroc_failing'] for t in trials])}"
              + (f"{windowed} {mean_std([t['auroc_window'] for t in trials])}" if windowed else "") + "; "
              f"{sum(sum(t['survived']) for t in trials)} of {sum(len(t['survived']) for t in trials)} episodes survived")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
