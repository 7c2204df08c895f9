"""Which member of a combined detector sets its alarm threshold, and what the others reach when shifted.

Run (seconds; needs the monitor benchmark's logs, `oodmon bench --protocol monitor --task cartpole
--trials 1 --out runs/bench-monitor3`, see results/monitor/README.md):
    .venv/bin/python scripts/member_excursions.py runs/bench-monitor3/logs/<task>-<key> ensemble gravity_98.0,gravity_68.6

For one method's trial 0 in a bench's log folder: the threshold the bench calibrated, then per member
of its combined detector (and per long member, its mean since the episode began) the largest rank
each episode reaches, as the combined detector ranks it (``CombinedDetector.rank``): over the 200 ID
episodes (median, 95th percentile, largest) and, for each named variant, after its onset in each
episode. The combined score is the largest of these ranks, and its threshold is about the largest
one of any ID calibration episode, so one member with wide ID excursions sets it for all.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from oodmon.monitor.detectors import DetectorSet
from oodmon.monitor.detectors.base import RunningMean
from oodmon.replay import read_log
from oodmon.threads import limit_threads


def episode_maxima(combined, path: Path, after_onset: bool) -> dict[str, np.ndarray]:
    """Per member (and ``<member> mean`` per long member): each episode's largest rank."""
    out: dict[str, list[float]] = {}
    for episode in read_log(path).episodes:
        scores, start = episode.detector_scores, episode.onset if after_onset else 0
        for name in combined.members:
            out.setdefault(name, []).append(max(combined.rank(name, float(v)) for v in scores[name][start:]))
        for name in combined.long_members:
            means = RunningMean(combined.horizon).along(scores[name])
            out.setdefault(f"{name} mean", []).append(max(combined.rank(name, float(v), long=True) for v in means[start:]))
    return {name: np.asarray(values) for name, values in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a bench log folder, runs/<out>/logs/<task>-<key>")
    parser.add_argument("method")
    parser.add_argument("variants", help="comma-separated log names of shifted variants, e.g. gravity_98.0")
    args = parser.parse_args()
    trial = args.folder / args.method / "trial0"
    combined = DetectorSet.load(next(trial.glob("detectors-*")))["combined"]
    threshold = json.loads(next(trial.glob("threshold-*.json")).read_text())["value"]
    task = args.folder.name.split("-", 1)[0]
    print(f"{args.method}: threshold {threshold:.2f} on the combined score")
    for name, values in episode_maxima(combined, trial / "monitor" / f"{task}.mcap", after_onset=False).items():
        print(f"  ID, {name}: largest rank per episode median {np.median(values):.1f}, "
              f"95th percentile {np.quantile(values, 0.95):.1f}, largest {values.max():.1f} ({len(values)} episodes)")
    for variant in args.variants.split(","):
        path = trial / "monitor" / f"{task}_{variant}.mcap"
        for name, values in episode_maxima(combined, path, after_onset=True).items():
            print(f"  {variant}, {name}: largest rank after the onset, per episode: "
                  + ", ".join(f"{v:.1f}" for v in np.sort(values)))


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
