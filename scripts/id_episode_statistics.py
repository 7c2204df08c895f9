"""Per-episode alarm statistics of many fresh ID episodes of a shipped agent, computed once.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/id_episode_statistics.py [--episodes 1200]

Writes results/calibration/cartpole-ensemble-id.json: for each detector the shipped CartPole
ensemble has (spread, dynamics, features, combined), the statistic under the alarm rule m = 3
consecutive steps, window 1, of each of the episodes, seeds 700,000 + i (the validation range,
apart from calibration's).

``--resume`` goes on from a stopped run's file. Other agents and seeds: ``--task pong --method
dropconnect --only frames --monitor-rule --seed 200000 --out runs/x.json`` (``--monitor-rule``:
each detector's rule is the monitor's default, ``default_consecutive`` and ``default_window``, the
one ``oodmon calibrate`` uses; ``--seed`` is the first episode's and the MC sampling's, as ``oodmon
validate --seed`` takes it). An episode alarms under a threshold exactly when its statistic
exceeds it, so re-drawing calibration sets from these episodes and checking each threshold on the
rest measures what a threshold's false-alarm rate is, without playing the episodes again
(tests/monitor/test_rule_and_calibration.py does it 100 times in a fraction of a second).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from oodmon import seeds
from oodmon.agents import load
from oodmon.monitor import DEFAULT_CONSECUTIVE, Monitor, episode_statistic
from oodmon.monitor.alarms import default_consecutive, default_window
from oodmon.monitor.detectors import detectors_for
from oodmon.threads import limit_threads


class StatisticSink:
    """Keeps the steps of the running episode only; at its end, each detector's statistic."""

    def __init__(self, names: list[str], rules: dict[str, tuple[int, int]]) -> None:
        self.names, self.rules, self.steps = names, rules, []
        self.statistics: dict[str, list[float]] = {name: [] for name in names}
        self.lengths: list[int] = []

    def open(self, run) -> None: ...
    def write_alarm(self, event) -> None: ...
    def close(self) -> None: ...

    def write_step(self, record) -> None:
        self.steps.append(record.scores)

    def end_episode(self, record) -> None:
        for name in self.names:
            scores = np.array([step[name] for step in self.steps])
            self.statistics[name].append(float(episode_statistic(scores, *self.rules[name])))
        self.lengths.append(len(self.steps))
        self.steps = []

OUT = Path(__file__).resolve().parents[1] / "results" / "calibration" / "cartpole-ensemble-id.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1200)
    parser.add_argument("--task", default="cartpole")
    parser.add_argument("--method", default="ensemble")
    parser.add_argument("--only", help="comma-separated detectors (default: spread and every fitted one)")
    parser.add_argument("--monitor-rule", action="store_true",
                        help="each detector's default rule (else m = 3, window 1 for every detector)")
    parser.add_argument("--seed", type=int, default=seeds.VALIDATION)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--every", type=int, default=100, help="progress every this many episodes")
    parser.add_argument("--resume", action="store_true",
                        help="go on from the episodes --out holds (made by the same command); the MC sampling "
                             "starts again from the seed of the first new episode, so the episodes after the "
                             "stop differ from an unstopped run's but are as fresh")
    args = parser.parse_args()
    done = json.loads(args.out.read_text()) if args.resume and args.out.is_file() else None
    start = 0 if done is None else len(done["episode_lengths"])
    agent = load(args.task, args.method, seed=args.seed + start)
    detectors = detectors_for(agent)
    fitted = detectors.names if detectors else []
    names = args.only.split(",") if args.only else list(dict.fromkeys(["spread", *fitted]))
    learned = [name for name in names if name != "spread"]
    rules = {name: (default_consecutive(name), default_window(args.task, name)) if args.monitor_rule
             else (DEFAULT_CONSECUTIVE, 1) for name in names}
    command = "OODMON_TORCH_THREADS=1 .venv/bin/python scripts/id_episode_statistics.py --episodes " \
              f"{args.episodes}"
    if args.out != OUT:
        command += f" --task {args.task} --method {args.method}" + (f" --only {args.only}" if args.only else "") \
            + (" --monitor-rule" if args.monitor_rule else "") + f" --seed {args.seed} --out {args.out}"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rule = {name: {"consecutive": m, "window": w} for name, (m, w) in rules.items()}
    sink = StatisticSink(names, rules)
    resumed_at = []
    if done is not None:
        if done["agent"] != f"{args.task}-{args.method}" or done["seeds"][0] != args.seed \
                or sorted(done["statistics"]) != sorted(names):
            raise SystemExit(f"{args.out} was made by another command: {done['command']}")
        sink.lengths = list(done["episode_lengths"])
        sink.statistics = {name: list(values) for name, values in done["statistics"].items()}
        resumed_at = [*done.get("resumed_at", []), start]

    def write() -> None:
        """The episodes played so far (every --every episodes: a run stopped early keeps them)."""
        part = args.out.with_suffix(".part")  # whole or not at all, as the committed file's one line
        part.write_text(json.dumps({
            "agent": f"{args.task}-{args.method}",
            "rule": rule[names[0]] if len(set(rules.values())) == 1 else rule,
            "seeds": [args.seed, args.seed + len(sink.lengths)], "episode_lengths": sink.lengths,
            "statistics": {name: [round(v, 6) for v in values] for name, values in sink.statistics.items()},
            "command": command,
            **({"resumed_at": resumed_at} if resumed_at else {}),
        }) + "\n")
        part.replace(args.out)

    env = agent.make_env()
    started = time.perf_counter()
    with Monitor(agent, detectors=detectors.subset(learned) if learned else None, sinks=[sink],
                 log_observations=False) as monitor:
        for episode in range(start, args.episodes):
            monitor.run_episode(env, seed=args.seed + episode, variant=args.task)
            if (episode + 1) % args.every == 0 or episode + 1 == args.episodes:
                write()
                print(f"{episode + 1}/{args.episodes} episodes, {time.perf_counter() - started:.0f} s", flush=True)
    env.close()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
