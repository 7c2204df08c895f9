"""How should the dynamics model train? Its alarm on gravity shifts, per fit seed, epochs and schedule.

Run (a few minutes per agent on one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/dynamics_training.py --method dropconnect \\
        --fits 30:constant,30:linear,60:linear,100:constant,100:linear,100:linear:5000,100:linear:3000

A shipped CartPole agent plays 90 ID episodes (the seeds ``fit_detectors`` fits on,
``DETECTOR_FIT`` on), 200 held-out ID episodes (seeds 1,110,000 on) and, per gravity variant, 20
episodes shifted from a random step in [20, 200) (seeds 1,111,000 + 100 x gravity + k). For each
fit (``epochs:schedule``, the learning rate constant or falling linearly to 0: ``DynamicsDetector``'s
``schedule``) and each seed of the model's initial weights and minibatches, the dynamics detector
alone is fitted on the 90 episodes (its other settings the defaults, CartPole's floor of the
log-variance), and its alarm is set as the monitor's is with 90 calibration episodes at
confidence 0.99 (``calibrate``: the largest per-episode peak of the first 90 held-out episodes). Printed per
fit: that threshold, how many of the other 110 held-out episodes pass it, and the median delay
(steps from the onset to the first step above it; inf where none) per variant.

What it showed (2026-12-01, AMD EPYC, DropConnect, seeds 0-3; why the dynamics model has trained
up to 100 epochs and 3,000 updates with a falling learning rate since fitting version 8), median
delays on ``gravity=29.4 / 49.0 / 68.6`` (the 90 episodes here hold 88 updates an epoch; the
monitor's fit takes the first 60 of its 90, 59 updates an epoch, so it gets 50 epochs):

| fit | delays | thresholds |
|---|---|---|
| 30 epochs, constant (before) | 6-16 / 1.5-7 / 1-4 | -2.65 to -2.38 |
| 30 epochs, linear | 2.5-4 / 1 / 1 | -2.58 to -0.62 |
| 60 epochs, linear | 1.5-3 / 1 / 1 | -3.13 to -1.85 |
| 100 epochs, constant | 1.5-3 / 1 / 1 | -3.68 to -3.17 |
| 100 epochs, linear | 1-1.5 / 1 / 1 | -3.83 to -3.25 |
| 100 epochs, at most 5,000 updates (56 epochs here), linear | 1.5-3 / 1 / 1 | -3.14 to -1.89 |
| version 8's default: 100 epochs, at most 3,000 updates (34 epochs here), linear | 2.5-4 / 1 / 1 | -2.65 to -0.80 |

No fit alarmed any of the 110 held-out ID episodes. At a constant rate the model was still moving
when the fit ended; a shift stands out sooner against a settled model. The monitor's benchmark of
all three agents on both tasks (``oodmon bench --protocol monitor``, ``results/monitor/README.md``)
chose among them: 30 epochs with the decay was as good on CartPole but slowed Pendulum's alarms
(the ensemble's ``m=5.0`` 4 to 6 steps at the median), 60 with it left Pendulum as before, 100
with it kept every alarm figure of both tasks and lowered Pendulum's false alarms (3, 4, 5 of 400
ID episodes to 0, 2, 2). Updates cost time (45,000 transitions took 7.3 s at 30 epochs and 18.3 s
at 100 on one core, and the test suite 30 s more), so a fit stops at 3,000 updates: Pendulum's
fit (60 episodes, 24 updates an epoch) still gets its 100 epochs, CartPole's 50; the monitor's
benchmark with that cap kept every CartPole alarm figure of version 6 too (DropConnect's gravity
variants at 1-3.5 steps at the median, 6 of 200 Dropout false alarms). Since fitting version 9
(2026-12-02) every epoch, no cap: the cap blunted larger fits of a user's own env
(``scripts/dynamics_cap.py``). ``--fits`` takes ``EPOCHS:SCHEDULE`` (every epoch) or
``EPOCHS:SCHEDULE:MAX_UPDATES``.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from oodmon.agents import load
from oodmon.envs import Variant, parse_variant
from oodmon.monitor.detectors import collect
from oodmon.monitor.detectors.dynamics import DynamicsDetector, min_logvar_for
from oodmon.monitor.detectors.fitting import trajectory_scores
from oodmon.monitor.detectors.store import DetectorSet
from oodmon.monitor.threshold import EarlyPeaksWarning, calibrate
from oodmon.names import METHODS
from oodmon.threads import limit_threads

GRAVITIES = ("29.4", "49.0", "68.6")
HELD_OUT, SHIFTED = 1_110_000, 1_111_000


def shifted_episodes(agent, gravity: str, episodes: int) -> list[tuple[int, object]]:
    """``episodes`` episodes of ``cartpole:gravity=<gravity>``, each shifted from a random step in
    [20, 200): (onset, trajectory) pairs."""
    rng = np.random.default_rng(int(float(gravity)))
    out = []
    for k in range(episodes):
        onset = int(rng.integers(20, 200))
        env = parse_variant(f"cartpole:gravity={gravity}").make(onset_step=onset)
        out.append((onset, collect(agent, env, 1, seed=SHIFTED + 100 * int(float(gravity)) + k)[0]))
    return out


def alarm_figures(detector: DynamicsDetector, held_out: list, shifted: dict[str, list]) -> tuple[float, int, dict]:
    """The threshold (``calibrate``'s on the first 90 held-out episodes at far 0.05, confidence
    0.99: their largest peak), the other held-out episodes above it, and the median delay per variant."""
    detectors = DetectorSet([detector])
    scores = [trajectory_scores(detectors, t)["dynamics"] for t in held_out]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EarlyPeaksWarning)  # the start-up sets it: measured as the monitor would
        threshold = calibrate(scores[:90], 0.05, consecutive=1, confidence=0.99, detector="dynamics").value
    peaks = np.array([s.max() for s in scores])
    delays = {}
    for gravity, episodes in shifted.items():
        found = []
        for onset, trajectory in episodes:
            over = np.flatnonzero(trajectory_scores(detectors, trajectory)["dynamics"][onset:] > threshold)
            found.append(float(over[0]) if len(over) else np.inf)
        delays[gravity] = float(np.median(found))
    return threshold, int((peaks[90:] > threshold).sum()), delays


def parse_fits(text: str) -> list[tuple[int, str, int | None]]:
    """``30:linear,100:linear:3000`` -> [(30, "linear", None), (100, "linear", 3000)]: epochs,
    schedule and the most updates (``None``: every epoch), each checked as the detector checks them
    (before any episode is played)."""
    fits = []
    for item in text.split(","):
        try:
            epochs, schedule, *cap = item.split(":")  # fewer than two parts: ValueError
            if len(cap) > 1:
                raise ValueError(item)
            fit = (int(epochs), schedule, int(cap[0]) if cap else None)
            DynamicsDetector(epochs=fit[0], schedule=schedule, max_updates=fit[2])  # its own checks
        except ValueError:  # (an InvalidParameterError is one)
            raise argparse.ArgumentTypeError(f"{item!r}: give EPOCHS:linear or EPOCHS:constant, then :MAX_UPDATES "
                                             "if any") from None
        fits.append(fit)
    return fits


def parse_seeds(text: str) -> list[int]:
    """``0,1,2,3`` -> [0, 1, 2, 3]: the seeds of the model's fit."""
    try:
        return [int(seed) for seed in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give comma-separated integers") from None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--method", choices=METHODS, default="dropconnect")
    parser.add_argument("--fits", type=parse_fits, default=parse_fits("30:constant,100:linear:3000"),
                        help="comma-separated EPOCHS:SCHEDULE[:MAX_UPDATES] (linear or constant; every epoch "
                             "without MAX_UPDATES)")
    parser.add_argument("--seeds", type=parse_seeds, default=[0, 1, 2, 3], help="comma-separated seeds of the model's fit")
    parser.add_argument("--shifted", type=int, default=20, help="episodes per gravity variant")
    args = parser.parse_args()
    limit_threads()
    agent = load("cartpole", args.method, seed=0)
    fit = collect(agent, Variant("cartpole").make(), 90)
    held_out = collect(agent, Variant("cartpole").make(), 200, seed=HELD_OUT)
    shifted = {gravity: shifted_episodes(agent, gravity, args.shifted) for gravity in GRAVITIES}
    for epochs, schedule, cap in args.fits:
        for seed in args.seeds:
            detector = DynamicsDetector(2, epochs=epochs, schedule=schedule, max_updates=cap, seed=seed,
                                        min_logvar=min_logvar_for("cartpole")).fit(fit)
            threshold, false_alarms, delays = alarm_figures(detector, held_out, shifted)
            at_most = "" if cap is None else f" (at most {cap} updates)"
            print(f"{args.method} {epochs} epochs{at_most}, {schedule}, seed {seed}: threshold {threshold:.2f}, held-out ID "
                  f"episodes above it {false_alarms}/110, median delays "
                  + ", ".join(f"gravity={g} {d:g}" for g, d in delays.items()), flush=True)


if __name__ == "__main__":
    main()
