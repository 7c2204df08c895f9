"""Which readings an alarm names (``AlarmEvent.readings``), on shifted worlds and on ID ones.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/alarm_readings.py [--task cartpole] [--method ensemble]
         [--episodes 10] [--onset 50] [VARIANT ...]

The shipped agent with its shipped detectors, its alarm calibrated on the ``dynamics`` detector (as
``oodmon calibrate --detector dynamics``, the same threshold). For each variant (default: a stuck
sensor of each reading, a noisy one, and the paper's failing physics), ``--episodes`` episodes
shifted from ``--onset``:
how often each reading was named first at the first alarm from the onset on, the range of that
reading's residual (in the model's predicted standard deviations) and the largest of the other
readings' then. Then, on as many ID episodes, the worst residual of any reading at any step: what
``READING_SD`` must stay above, so that a false alarm seldom names a reading. About a minute.
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor import Monitor, calibrate_agent
from oodmon.monitor.detectors import detectors_for
from oodmon.monitor.monitor import READING_SD
from oodmon.monitor.sinks.base import MemorySink
from oodmon.seeds import CALIBRATION
from oodmon.threads import limit_threads

DEFAULT_VARIANTS = {
    "cartpole": ["cartpole:obs.stuck[0]=1", "cartpole:obs.stuck[1]=1", "cartpole:obs.stuck[2]=1",
                 "cartpole:obs.stuck[3]=1", "cartpole:obs.noise[1]=0.5", "cartpole:length=2.0",
                 "cartpole:force_mag=2.0", "cartpole:masscart=9.0", "cartpole:gravity=49.0"],
    "pendulum": ["pendulum:obs.stuck[0]=1", "pendulum:obs.stuck[2]=1", "pendulum:m=5.0", "pendulum:g=50.0",
                 "pendulum:l=0.1"],
}


def residuals(model, steps) -> np.ndarray:
    """The dynamics model's standardised residuals of an episode's transitions, (steps - 1, readings)."""
    obs = np.array([step.observation for step in steps], dtype=np.float32)
    actions = np.array([step.action for step in steps])
    return model.standardized_residuals(obs[:-1], actions[:-1], obs[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("variants", nargs="*")
    parser.add_argument("--task", default="cartpole", choices=sorted(DEFAULT_VARIANTS))
    parser.add_argument("--method", default="ensemble")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--onset", type=int, default=50)
    args = parser.parse_args()
    limit_threads()
    agent = load(args.task, args.method, seed=CALIBRATION)  # an MC agent's sampling seeded as `oodmon calibrate`'s
    detectors = detectors_for(agent)
    threshold = calibrate_agent(agent, detectors=detectors, detector="dynamics")
    print(f"{args.task}/{args.method}: dynamics > {threshold.value:.6g}; reading_sd {READING_SD}")
    model = detectors["dynamics"]
    for spec in args.variants or DEFAULT_VARIANTS[args.task]:
        env = parse_variant(spec).make(onset_step=args.onset)
        named, first, others, unnamed, missed = Counter(), [], [], 0, 0
        for episode in range(args.episodes):
            sink = MemorySink()
            with Monitor(agent, threshold=threshold, detectors=detectors, sinks=[sink]) as monitor:
                monitor.run_episode(env, seed=900_000 + episode)
            event = next((alarm for alarm in sink.alarms if alarm.step >= args.onset), None)
            if event is None or not event.readings:
                missed, unnamed = missed + (event is None), unnamed + (event is not None)
                continue
            named[event.readings[0][0]] += 1
            first.append(abs(event.readings[0][1]))
            at = residuals(model, sink.steps[event.step - 1:event.step + 1])[0]
            order = np.argsort(-np.abs(at))
            others.append(float(np.abs(at)[order[1:]].max()) if len(at) > 1 else 0.0)
        counts = ", ".join(f"[{index}] {count}" for index, count in named.most_common())
        spread = f"{min(first):.3g}-{max(first):.3g} sd" if first else "-"
        print(f"{spec:28s} named first: {counts or 'none'} of {args.episodes} ({unnamed} alarmed naming none, "
              f"{missed} not alarmed); its residual {spread}; the others' largest {max(others, default=0):.3g} sd")
    env = parse_variant(args.task).make()
    worst = []
    for episode in range(args.episodes):
        sink = MemorySink()
        with Monitor(agent, threshold=threshold, detectors=detectors, sinks=[sink]) as monitor:
            monitor.run_episode(env, seed=950_000 + episode)
        worst.append(np.abs(residuals(model, sink.steps)).max(axis=1))
    steps = np.concatenate(worst)
    print(f"ID, {args.episodes} episodes, {len(steps)} transitions: the worst reading's residual at a step: median "
          f"{np.median(steps):.3g}, 99.9th percentile {np.percentile(steps, 99.9):.3g}, largest {steps.max():.3g} sd")


if __name__ == "__main__":
    main()
