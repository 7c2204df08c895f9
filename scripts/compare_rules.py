"""Compare alarm rules offline on the logs of the monitor's benchmark (how the defaults were chosen).

Run: .venv/bin/python scripts/compare_rules.py LOGS_FOLDER TASK DETECTOR

LOGS_FOLDER is a bench's ``logs/<task>-<key>`` folder from `oodmon bench --protocol monitor`
(every log holds every detector's per-step scores, so any rule can be replayed on them). Per agent:
the ID episodes are split by seed order into 20 reference episodes (for the sequential rules' p-values),
45 calibration episodes and the rest for the false-alarm count; every rule is calibrated at far
0.05 with confidence 0.9 on the same 45 and applied to every shifted episode. Printed per agent
and rule: the threshold, false alarms among the held-out ID episodes, failing episodes alarmed
before the failure, shifted episodes alarmed, and the median and 90th-percentile delay.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from oodmon.monitor import calibrate
from oodmon.monitor.alarms import AlarmTracker
from oodmon.monitor.sequential import Reference
from oodmon.replay import failure_step, read_logs

RULES = [("consecutive", 1, False), ("consecutive", 3, False), ("cusum", 1, False), ("cusum", 1, True),
         ("martingale", 1, False), ("martingale", 1, True)]


def first_alarm(scores: np.ndarray, rule: str, m: int, threshold: float, reference: Reference | None) -> int | None:
    """The step of the first alarm the monitor's own rule raises on ``scores``, or None."""
    tracker = AlarmTracker(threshold, m, rule=rule, reference=reference)
    return next((step for step, score in enumerate(scores) if tracker.update(0, step, score)[0]), None)


def main(folder: str, task: str, detector: str) -> None:
    warnings.simplefilter("ignore")
    for method_dir in sorted(Path(folder).iterdir()):
        logs = read_logs([method_dir / "trial0" / "monitor"])
        ids = [e.scores_of(detector) for log in logs for e in sorted(log.episodes, key=lambda e: e.seed)
               if e.variant == task]
        shifted = [e for log in logs for e in log.episodes if e.variant != task]
        for rule, m, by_age in RULES:
            reference = None
            if rule != "consecutive":  # as calibrate_agent builds it
                reference = Reference.from_episodes(ids[:20], by_age=by_age)
            threshold = calibrate(ids[20:65], 0.05, consecutive=m, rule=rule, reference=reference).value
            false_alarms = sum(first_alarm(s, rule, m, threshold, reference) is not None for s in ids[65:])
            delays, failed, before = [], 0, 0
            for e in shifted:
                alarm = first_alarm(e.scores_of(detector), rule, m, threshold, reference)
                if alarm is not None and alarm >= e.onset:
                    delays.append(alarm - e.onset)
                failure = failure_step(e, task)
                if failure is not None:
                    failed += 1
                    before += alarm is not None and e.onset <= alarm < failure
            name = f"{rule} m={m}" if rule == "consecutive" else f"{rule} ({'by age' if by_age else 'pooled'})"
            delay = f"{np.median(delays):g} / {np.quantile(delays, 0.9):.3g}" if delays else "-"
            print(f"{method_dir.name:11s} {name:22s} threshold {threshold:8.3f}  false alarms {false_alarms}/"
                  f"{len(ids) - 65}  before failure {before}/{failed}  alarmed {len(delays)}/{len(shifted)}  "
                  f"delay median / p90 {delay}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="a bench's logs/<task>-<key> folder (oodmon bench --protocol monitor)")
    parser.add_argument("task", help="the task whose ID episodes the logs hold (cartpole, pendulum, ...)")
    parser.add_argument("detector", help="the detector whose scores the rules read (dynamics, combined, ...)")
    args = parser.parse_args()
    main(args.folder, args.task, args.detector)
