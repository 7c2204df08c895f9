"""A deployment whose ID world is not the simulator's: three ways to watch it, side by side.

Run (about 30 s a world on two cores):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/deployment_world.py \
        [--noises 0.005,0.01,0.02] [--out results/deployment/cartpole-ensemble.json]

The shipped CartPole ensemble, 200-step episodes. The simulator is the noiseless env; each
deployment world adds sensor noise (a fraction of each reading's ID spread) that the simulator
lacks. For each world, with the commands a user runs (in this process, ``oodmon.cli.main``):

- ``simulator``: the threshold calibrated in the simulator (``calibrate``, 50 episodes, its
  shipped detectors), used as it is;
- ``recalibrated``: that threshold calibrated again on 45 logged ID episodes of the deployment
  (``run --mcap``, then ``recalibrate``), the detectors still the simulator's fit;
- ``fitted on logs``: the detectors fitted on 50 logged ID episodes of the deployment
  (``fit-detectors --from-logs``), the alarm calibrated on 45 others scored by them
  (``recalibrate``).

Each threshold: far 0.05 at confidence 0.9; its false alarms on 100 fresh ID episodes of the
deployment (``validate --json``), and 20 episodes of each shift from step 50 in that world
(``run``, then ``replay --monitor --json``): how many alarmed, the median delay. Writes the rows as
JSON and prints them as a Markdown table (docs/monitor.md shows it).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

from oodmon.cli import main
from oodmon.jsonfile import write_json
from oodmon.threads import limit_threads

AGENT = ["--task", "cartpole", "--method", "ensemble"]
SHIFTS = ("cartpole:length=2.0", "cartpole:masscart=3.0", "cartpole:force_mag=5.0")
STEPS = ["--max-steps", "200"]


def oodmon(*argv: object, ok: tuple[int, ...] = (0,)) -> str:
    """``oodmon ARGV`` in this process; its standard output (its exit code must be one of ``ok``)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()) as err:
        code = main([str(a) for a in argv])
    if code not in ok:
        raise SystemExit(f"oodmon {' '.join(map(str, argv))} exited {code}: {err.getvalue()[-400:]}")
    return out.getvalue()


def judged(threshold: Path, noise: float, folder: Path, validate_episodes: int, shift_episodes: int) -> dict:
    """A threshold's fresh ID false alarms in the world of ``noise`` and its shifts' alarms."""
    validation = json.loads(oodmon("validate", threshold, "--episodes", validate_episodes, "--obs-noise", noise,
                                   *STEPS, "--workers", 2, "--json", ok=(0, 1)))  # (1: above its target)
    row = {"value": json.loads(threshold.read_text())["value"], "false_alarms": validation["alarmed"],
           "validated": validation["total"], "interval95": validation["interval95"], "shifts": {}}
    for shift in SHIFTS:
        log = folder / f"{threshold.stem}-{shift.split(':')[1]}.mcap"
        oodmon("run", "--threshold", threshold, "--variant", shift, "--onset", 50, "--episodes", shift_episodes,
               "--obs-noise", noise, *STEPS, "--seed", 9000, "--mcap", log)
        (metrics,) = [m for m in json.loads(oodmon("replay", "--monitor", "--json", log)) if m["variant"] == shift]
        row["shifts"][shift] = {"alarmed": metrics["alarmed"], "episodes": metrics["episodes"],
                                "early": metrics["early"], "delay_median": metrics["delay_median"]}
    return row


def world(noise: float, folder: Path, args: argparse.Namespace) -> dict:
    world_args = ["--obs-noise", noise, *STEPS]
    sim = folder / "simulator.json"
    oodmon("calibrate", *AGENT, "--episodes", 50, *STEPS, "--workers", 2, "--out", sim)
    rows = {"simulator": judged(sim, noise, folder, args.validate, args.shift_episodes)}
    oodmon("run", *AGENT, "--threshold", sim, "--episodes", 45, *world_args, "--seed", 3000, "--mcap",
           folder / "cal-sim.mcap")
    recalibrated = folder / "recalibrated.json"
    oodmon("recalibrate", folder / "cal-sim.mcap", "--out", recalibrated)
    rows["recalibrated"] = judged(recalibrated, noise, folder, args.validate, args.shift_episodes)
    oodmon("run", *AGENT, "--episodes", 50, *world_args, "--seed", 1000, "--mcap", folder / "fit.mcap")
    oodmon("fit-detectors", *AGENT, "--from-logs", folder / "fit.mcap", "--out", folder / "det")
    oodmon("run", *AGENT, "--detectors", folder / "det", "--episodes", 45, *world_args, "--seed", 3000, "--mcap",
           folder / "cal-det.mcap")
    fitted = folder / "fitted.json"
    oodmon("recalibrate", folder / "cal-det.mcap", "--detectors", folder / "det", "--out", fitted)
    rows["fitted on logs"] = judged(fitted, noise, folder, args.validate, args.shift_episodes)
    return rows


#: The rows' names in the table.
NAMES = {"simulator": "the simulator's", "recalibrated": "recalibrated", "fitted on logs": "fitted on logs"}


def markdown(results: dict) -> str:
    """The results as docs/monitor.md's table (tests/test_deployment_world_script.py keeps them equal)."""
    lines = ["| sensor noise | threshold | combined > | fresh ID alarmed | "
             + " | ".join(f"`{s.split(':')[1]}`" for s in SHIFTS) + " |", "|---" * (4 + len(SHIFTS)) + "|"]
    for noise, rows in results["worlds"].items():
        for name, row in rows.items():
            low, high = row["interval95"]
            shifts = " | ".join(_shift_cell(r) for r in row["shifts"].values())
            lines.append(f"| {noise} | {NAMES[name]} | {row['value']:,.6g} | {row['false_alarms']} of "
                         f"{row['validated']} ({100 * low:.1f}-{100 * high:.1f}%) | {shifts} |")
    return "\n".join(lines)


def _shift_cell(row: dict) -> str:
    """A shift's alarms in a table's words: alarmed at or after the onset, those alarmed before it
    (false alarms of the ID steps), the median delay ('-': none alarmed after the onset)."""
    early = f" ({row['early']} early)" if row["early"] else ""
    delay = "" if row["delay_median"] is None else f", {row['delay_median']:g}"
    return f"{row['alarmed']} of {row['episodes']}{early}{delay}"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noises", default="0.005,0.01,0.02", help="the deployment worlds' sensor noise")
    parser.add_argument("--validate", type=int, default=100, help="fresh ID episodes per threshold (default 100)")
    parser.add_argument("--shift-episodes", type=int, default=20, help="episodes per shift (default 20)")
    parser.add_argument("--out", default="results/deployment/cartpole-ensemble.json")
    return parser.parse_args(argv)


def run(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    limit_threads()  # OODMON_TORCH_THREADS, one thread where it is not set (each command sets it so too)
    command = ["OODMON_TORCH_THREADS=1", ".venv/bin/python", "scripts/deployment_world.py",
               *(sys.argv[1:] if argv is None else argv)]
    results = {"command": " ".join(command), "worlds": {}}
    for noise in (float(n) for n in args.noises.split(",")):
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as folder:
            results["worlds"][f"{noise:g}"] = world(noise, Path(folder), args)
        print(f"noise {noise:g}: {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_json(Path(args.out), results)
    print(markdown(results))
    return results


if __name__ == "__main__":
    run()
