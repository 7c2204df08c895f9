"""Pong watched through a deployment's camera that is not the simulator's: three ways to watch it.

Run (about a quarter of an hour on one core):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/camera_world.py [--gain 0.8] \
        [--out results/deployment/pong-camera.json]

The shipped Pong DropConnect agent and its shipped detectors. The simulator is oodmon's Pong; the
deployment's camera multiplies every pixel by ``--gain`` (a darker picture, as a real camera's
exposure may give), and nothing says so: its games are ID to the logs. The alarm is Pong's
default (``combined`` of the camera's detectors), far 0.1 at confidence 0.9, games of 400
decisions, with the Python calls the CLI's commands make:

- ``simulator``: calibrated on 22 games of the simulator (``calibrate_agent``);
- ``recalibrated``: on 22 logged games of the deployment (``calibrate_from_logs``), the detectors
  still the simulator's fit;
- ``fitted on logs``: the detectors fitted on 30 logged games of the deployment
  (``fit_detectors_from_logs``: the frames its logs hold), the alarm calibrated on 22 others they
  scored.

Each threshold: how many of 100 fresh deployment games alarm, and of 10 deployment games whose
camera also corrupts its frames from decision 150 (``gaussian_noise@3``, ``motion_blur@3``), how
many alarm after the onset (and how many before it), with the median delay. Writes the rows as
JSON and prints them as a Markdown table.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import warnings
from pathlib import Path

import gymnasium
import numpy as np

from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.jsonfile import write_json
from oodmon.monitor import LongerThanCalibrationWarning, McapSink, Monitor, calibrate_agent
from oodmon.monitor.detectors import detectors_for
from oodmon.monitor.threshold import clopper_pearson
from oodmon.replay import calibrate_from_logs, fit_detectors_from_logs
from oodmon.threads import limit_threads

STEPS, ONSET, FAR = 400, 150, 0.1
SHIFTS = ("pong:gaussian_noise@3", "pong:motion_blur@3")


class Camera(gymnasium.ObservationWrapper):
    """Every pixel of every frame times ``gain`` (each frame of a stack alike, as a camera gives
    them); the env's ``info`` is untouched: nothing says the picture differs."""

    def __init__(self, env: gymnasium.Env, gain: float) -> None:
        super().__init__(env)
        self.gain = gain

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(observation * self.gain), 0, 255).astype(np.uint8)


def games(agent, detectors, gain: float, seeds: range, *, spec: str = "pong", threshold=None,
          log: Path | None = None) -> list:
    """The records of games of ``spec`` seen through the camera of ``gain`` (a corruption from
    decision ONSET on), monitored with ``detectors`` (and ``threshold``), logged to ``log``."""
    env = Camera(parse_variant(spec).make(onset_step=ONSET if spec != "pong" else 0), gain)
    sinks = [McapSink(log)] if log is not None else []
    with Monitor(agent, threshold=threshold, detectors=detectors, sinks=sinks) as monitor:
        records = [monitor.run_episode(env, seed=seed, max_steps=STEPS) for seed in seeds]
    env.close()
    return records


def judged(agent, detectors, threshold, gain: float) -> dict:
    """``threshold``'s false alarms in 100 fresh deployment games (with their 95% interval) and its
    alarms on the shifts."""
    fresh = games(agent, detectors, gain, range(70_000, 70_100), threshold=threshold)
    alarmed = sum(r.alarms > 0 for r in fresh)
    row = {"value": threshold.value, "detector": threshold.detector, "false_alarms": alarmed, "games": len(fresh),
           "interval95": list(clopper_pearson(alarmed, len(fresh))), "shifts": {}}
    for spec in SHIFTS:
        shifted = games(agent, detectors, gain, range(80_000, 80_010), spec=spec, threshold=threshold)
        early = sum(r.first_alarm_step is not None and r.first_alarm_step < ONSET for r in shifted)
        delays = [r.first_alarm_step - ONSET for r in shifted
                  if r.first_alarm_step is not None and r.first_alarm_step >= ONSET]
        row["shifts"][spec] = {"alarmed": len(delays), "early": early, "games": len(shifted),
                               "delay_median": statistics.median(delays) if delays else None}
    return row


def markdown(result: dict) -> str:
    """The rows as docs/monitor.md shows them."""
    lines = ["| threshold | combined > | fresh deployment games alarmed | " + " | ".join(f"`{s.split(':')[1]}`"
                                                                                  for s in SHIFTS) + " |",
             "|---|---|---|" + "---|" * len(SHIFTS)]
    for name, row in result["thresholds"].items():
        cells = []
        for spec in SHIFTS:
            shift = row["shifts"][spec]
            cell = f"{shift['alarmed']} of {shift['games']}"
            cell += f", {shift['delay_median']:g}" if shift["delay_median"] is not None else ""
            cell += f" ({shift['early']} early)" if shift["early"] else ""
            cells.append(cell)
        low, high = row["interval95"]
        lines.append(f"| {name} | {row['value']:.6g} | {row['false_alarms']} of {row['games']} "
                     f"({100 * low:.1f}-{100 * high:.1f}%) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gain", type=float, default=0.8, help="the deployment camera's gain on every pixel")
    parser.add_argument("--out", default="results/deployment/pong-camera.json")
    args = parser.parse_args()
    limit_threads()
    warnings.filterwarnings("ignore", category=LongerThanCalibrationWarning)  # (every game is cut at STEPS)
    agent = load("pong", "dropconnect", seed=0)  # its MC masks drawn from one seeded stream: the same figures again
    shipped = detectors_for(agent)
    result = {"gain": args.gain, "steps": STEPS, "onset": ONSET, "far": FAR, "thresholds": {},
              "command": "OODMON_TORCH_THREADS=1 .venv/bin/python scripts/camera_world.py"
                         + (f" --gain {args.gain:g}" if args.gain != 0.8 else "")}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        simulator = calibrate_agent(agent, episodes=22, far=FAR, max_steps=STEPS, detectors=shipped)
        result["thresholds"]["the simulator's"] = judged(agent, shipped, simulator, args.gain)
        games(agent, shipped, args.gain, range(3000, 3022), log=folder / "cal.mcap")
        recalibrated = calibrate_from_logs([folder / "cal.mcap"], FAR)
        result["thresholds"]["recalibrated"] = judged(agent, shipped, recalibrated, args.gain)
        games(agent, shipped, args.gain, range(5000, 5030), log=folder / "fit.mcap")
        fitted = fit_detectors_from_logs(agent, [folder / "fit.mcap"])
        games(agent, fitted, args.gain, range(6000, 6022), log=folder / "cal-fitted.mcap")
        own = calibrate_from_logs([folder / "cal-fitted.mcap"], FAR)
        result["thresholds"]["fitted on logs"] = judged(agent, fitted, own, args.gain)
    write_json(args.out, result)
    print(f"Pong DropConnect, the deployment's camera at gain {args.gain:g}, games of {STEPS} decisions, far {FAR}")
    print(markdown(result))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
