"""Per-step AUROC of each detector with and without every episode's first steps, from bench logs.

Run: .venv/bin/python scripts/first_steps.py LOG_FOLDER [--skip 1,2,5]

LOG_FOLDER is one agent's logs of an ``oodmon bench`` run with the learned detectors (the paper's
protocol: shifted from step 0), e.g. ``runs/bench-det9/logs/<key>/dropout/trial0``: its ID log
``<task>.mcap`` and a log per failing variant. For each variant it prints how many shifted steps
there are and how many of them are an episode's first, then each detector's per-step AUROC as
``oodmon replay`` and the bench compute it (ID steps against shifted ones, a score that could not
be computed ranked as the most shifted), over all steps and with each episode's first N steps left
out of both sides, for each N of ``--skip``; last, each detector's mean and lowest over the variants.

Why: under a physics shift an episode's first observation is drawn from the ID reset distribution,
and at the first step no transition has been seen, so no detector can tell that step from an ID
one. An agent that fails within a few steps (CartPole's tiny poles) gives shifted episodes whose
first steps are a large share of their steps, which caps the per-step AUROC of any detector; the
columns without the first steps say what the detectors make of the rest. Measured on 2026-12-04:
results/sweeps/README.md, "Shipping it was tried".
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from oodmon.errors import OodmonError
from oodmon.replay import compute_metrics
from oodmon.replay.metrics import is_id_variant
from oodmon.replay.reader import EpisodeLog, RunLog, read_logs


def from_step(log: RunLog, skip: int) -> RunLog:
    """``log`` with each episode's first ``skip`` steps cut off (an episode no longer than that
    dropped), its onset moved with them."""
    def cut(episode: EpisodeLog) -> EpisodeLog:
        rest = slice(skip, None)
        return replace(episode, length=episode.length - skip, onset=max(episode.onset - skip, 0),
                       scores=episode.scores[rest], shifted=episode.shifted[rest], alarm=episode.alarm[rest],
                       detector_scores={name: values[rest] for name, values in episode.detector_scores.items()},
                       rewards=None if episode.rewards is None else episode.rewards[rest])
    return replace(log, episodes=[cut(e) for e in log.episodes if e.length > skip])


def aurocs(folder: str | Path, skips: Sequence[int] = (1,)) -> tuple[list[str], dict[str, dict]]:
    """:func:`aurocs_of` the logs in ``folder``.

    Raises:
        OodmonError: a folder without logs, or without an ID log.
    """
    paths = sorted(Path(folder).glob("*.mcap"))
    if not paths:
        raise OodmonError(f"{folder} holds no .mcap logs (an agent's folder of the bench's logs: "
                          f"runs/<out>/logs/<key>/<method>/trial<t>)")
    return aurocs_of(read_logs(paths), skips, str(folder))


def aurocs_of(logs: Sequence[RunLog], skips: Sequence[int] = (1,), where: str = "the logs"
              ) -> tuple[list[str], dict[str, dict]]:
    """The detectors of one agent's ``logs`` and per variant: ``steps`` (shifted ones), ``starts``
    (shifted steps that are an episode's first) and per detector the per-step AUROC, as
    :func:`~oodmon.replay.compute_metrics` gives it, for each number of first steps left out (0 and
    ``skips``).

    Raises:
        OodmonError: no ID episodes among them.
    """
    episodes = [e for log in logs for e in log.episodes]
    if not any(is_id_variant(e.variant) for e in episodes):
        raise OodmonError(f"{where} hold no ID episodes (the bench writes <task>.mcap beside the variants')")
    detectors = logs[0].detectors
    result: dict[str, dict] = {}
    for e in episodes:
        if not is_id_variant(e.variant):
            row = result.setdefault(e.variant, {"steps": 0, "starts": 0, **{d: {} for d in detectors}})
            row["steps"] += int(np.sum(e.shifted))
            row["starts"] += int(e.length > 0 and bool(e.shifted[0]))
    for skip in (0, *skips):
        cut = logs if skip == 0 else [from_step(log, skip) for log in logs]
        for detector in detectors:
            for metrics in compute_metrics(cut, detector=detector):
                if metrics.variant in result and metrics.auroc is not None:
                    result[metrics.variant][detector][skip] = metrics.auroc
    return detectors, dict(sorted(result.items()))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="one agent's bench logs, e.g. runs/bench-det9/logs/<key>/dropout/trial0")
    parser.add_argument("--skip", default="1", help="comma-separated numbers of first steps to leave out (default 1)")
    args = parser.parse_args(argv)
    try:
        skips = [int(x) for x in args.skip.split(",")]
    except ValueError:
        parser.error(f"--skip takes whole numbers, comma-separated; got {args.skip!r}")
    if any(s < 1 for s in skips):
        parser.error("--skip numbers must be 1 or more")
    try:
        detectors, result = aurocs(args.folder, skips)
    except OodmonError as error:
        raise SystemExit(f"first_steps: {error}") from None
    columns = [(d, s) for d in detectors for s in (0, *skips)]
    labels = [d[:9] if s == 0 else f"{d[:8]} >={s}" for d, s in columns]  # >=N: from step N on
    print(f"{'variant':28s} {'steps':>6s} {'starts':>6s} " + " ".join(label.rjust(13) for label in labels))
    for variant, row in result.items():
        cells = " ".join(f"{row[d][s]:13.3f}" if s in row[d] else " " * 13 for d, s in columns)
        print(f"{variant:28s} {row['steps']:6d} {row['starts']:6d} {cells}")
    for label, reduce in (("mean", np.mean), ("lowest", np.min)):
        cells = " ".join(f"{reduce([r[d][s] for r in result.values() if s in r[d]]):13.3f}" for d, s in columns)
        print(f"{label:28s} {'':6s} {'':6s} {cells}")


if __name__ == "__main__":
    main()
