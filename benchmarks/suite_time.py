"""The test suite's time as `make test` runs it, beside the 180 s goal, and where that time goes.

Run: .venv/bin/python benchmarks/suite_time.py [--fits] [--out runs/suite-time.txt]
     .venv/bin/python benchmarks/suite_time.py --read runs/suite-time.txt   (a saved run: seconds)

Runs the suite as ``make test`` does (pytest-xdist on every core, ``--dist worksteal``) with every
test's duration (``--durations=0``), keeps pytest's output in ``--out``, and prints: the wall time
and the number of tests; their setup, call and teardown seconds summed over the workers (the
wall time is about that sum over the cores, plus each worker's collection); how many tests take
how long; the files and the tests that take the most; and a last line ``ratio=<wall time / 180
s>`` (lower is better; goal <= 1.0, the code-health issue's). About five minutes on two cores. The
machine's speed moves the figure by half or more from one hour to the next, so it first prints a
gauge of that speed: the dynamics model's fit time per update (``benchmarks/dynamics_fit.py``'s
first figure, one thread, before the suite starts; on 2026-12-02 it read about 2,100 us in the
morning and 3,767 us in the afternoon, just after a run of the suite that took 335 s).

It also loads ``suite_workers.py`` (beside this script), a pytest plugin that records when each
test starts and ends on which worker, and prints each worker's busy seconds, how far apart the
workers' last tests end (a tail that ordering the tests could win back: 1.2 and 1.4 s in two runs
on 2026-12-04 and 05, so none) and the seconds before the first test and after the last (start-up,
collection, the summary).

``--fits`` loads ``suite_fits.py`` (beside this script), a pytest plugin that times every fit of
the dynamics model in the suite (about a fifth of its time on 2026-12-02), and prints their number,
CPU seconds, and the seconds of the fits whose model and transitions an earlier fit of the run had
already fitted (what a cache of fits would save), with the tests that repeat them.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GOAL_SECONDS = 180.0
DURATION = re.compile(r"^([\d.]+)s (setup|call|teardown)\s+(\S+)")
CLOSING = re.compile(r"^=*\s*(.*?) in ([\d.]+)s")
SLOWEST = re.compile(r"^=+ slowest (\d+ )?durations =+$")
BUCKETS = ((0.0, 0.3), (0.3, 1.0), (1.0, 3.0), (3.0, 10.0), (10.0, float("inf")))


@dataclass
class SuiteTime:
    """What one run's output says: the wall time, the closing counts ('1640 passed'), each
    test's seconds (setup + call + teardown) and each phase's sum, and how many durations pytest
    listed where it listed only the slowest (``make test``'s ``--durations=10``; None: every one)."""

    wall: float
    counts: str
    tests: dict[str, float] = field(default_factory=dict)
    phases: Counter = field(default_factory=Counter)
    only_slowest: int | None = None

    @property
    def summed(self) -> float:
        return sum(self.phases.values())

    def files(self) -> dict[str, float]:
        per_file: dict[str, float] = defaultdict(float)
        for test, seconds in self.tests.items():
            per_file[test.split("::")[0]] += seconds
        return dict(per_file)


def read_output(text: str) -> SuiteTime:
    """Parse pytest's output of a run with ``--durations=0`` (tests/test_suite_time.py shows one).

    Raises:
        ValueError: no closing line (the run did not end, or this is not pytest's output).
    """
    tests: dict[str, float] = defaultdict(float)
    phases: Counter = Counter()
    closing, only_slowest = None, None
    for line in text.splitlines():
        if (match := SLOWEST.match(line)) is not None and match.group(1):
            only_slowest = int(match.group(1))
        elif (match := DURATION.match(line)) is not None:
            seconds, phase, test = float(match.group(1)), match.group(2), match.group(3)
            tests[test] += seconds
            phases[phase] += seconds
        elif (match := CLOSING.match(line)) is not None and re.search(r"\d+ (passed|failed|error)", match.group(1)):
            closing = match
    if closing is None:
        raise ValueError("no closing line such as '1640 passed in 258.79s': the run did not end, or this is not "
                         "pytest's output")
    return SuiteTime(float(closing.group(2)), closing.group(1).strip(" ="), dict(tests), phases, only_slowest)


def read_fits(lines: list[str]) -> dict:
    """The fits ``suite_fits.py`` wrote: their number, CPU seconds, the number of distinct ones and
    the CPU seconds of those that fitted again what an earlier fit had, with the tests of each key
    that ran more than once (by the seconds they repeat)."""
    rows = [json.loads(line) for line in lines if line.strip()]
    by_key: dict[str, list[dict]] = defaultdict(list)
    for row in rows:
        by_key[row["key"]].append(row)
    repeated = sorted(((sum(r["cpu"] for r in same[1:]), sorted({r["test"] for r in same}))
                       for same in by_key.values() if len(same) > 1), key=lambda item: -item[0])
    return {"fits": len(rows), "cpu": sum(r["cpu"] for r in rows), "distinct": len(by_key),
            "repeated_cpu": sum(seconds for seconds, _ in repeated), "repeated": repeated}


@dataclass(frozen=True)
class Worker:
    """One xdist worker's share of a run: its tests, when its first started and its last ended
    (seconds since the epoch), and the seconds its tests took."""

    tests: int
    first: float
    last: float
    busy: float


def read_workers(lines: list[str]) -> dict[str, Worker]:
    """What ``suite_workers.py`` wrote, by worker (``gw0``, ...; ``main`` in a run without workers)."""
    rows: dict[str, list[dict]] = defaultdict(list)
    for line in lines:
        if line.strip():
            row = json.loads(line)
            rows[row["worker"]].append(row)
    return {name: Worker(len(own), min(r["start"] for r in own), max(r["end"] for r in own),
                         sum(r["end"] - r["start"] for r in own)) for name, own in sorted(rows.items())}


def gauge_us() -> float:
    """The machine's speed now: ``dynamics_fit.py``'s fit time per update (one thread, 600 updates, best of 3)."""
    from dynamics_fit import fit_us_per_update, synthetic_episodes  # benchmarks/, beside this script

    from oodmon.threads import set_threads

    set_threads(1)
    return fit_us_per_update(synthetic_episodes())


def run_suite(out: Path, fits: Path | None, environment: dict[str, str], workers: Path | None = None) -> str:
    """The suite as `make test` runs it, with every duration, in ``environment`` (this process's as
    it started: the gauge sets OPENBLAS_NUM_THREADS here); its output, also written to ``out``.
    ``fits``, ``workers``: the files the plugins ``suite_fits`` and ``suite_workers`` write (None:
    that plugin is not loaded)."""
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "auto", "--dist", "worksteal",
               "--durations=0", "--durations-min=0"]
    env = dict(environment)
    for plugin, variable, path in (("suite_workers", "OODMON_SUITE_WORKERS", workers),
                                   ("suite_fits", "OODMON_SUITE_FITS", fits)):
        if path is not None:
            command += ["-p", plugin]
            env[variable] = str(path)
    if workers is not None or fits is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).parent), env.get("PYTHONPATH")]))
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(done.stdout + done.stderr)
    return done.stdout


def report(run: SuiteTime, fits: dict | None, top: int = 10, workers: dict[str, Worker] | None = None) -> None:
    print(f"{'wall time':48s} {run.wall:8.1f} s  ({run.counts})")
    if workers:
        for name, worker in workers.items():
            print(f"{'worker ' + name + ' busy':48s} {worker.busy:8.1f} s  ({worker.tests} tests, "
                  f"{worker.last - worker.first:.1f} s from its first test's start to its last's end)")
        first, last = min(w.first for w in workers.values()), max(w.last for w in workers.values())
        ends = [w.last for w in workers.values()]
        label = "the workers' last tests end apart by"
        print(f"{label:48s} {max(ends) - min(ends):8.1f} s  (a tail ordering could win)")
        print(f"{'before the first test and after the last':48s} {run.wall - (last - first):8.1f} s  "
              "(start-up, collection, the summary)")
    if run.only_slowest is not None:
        print(f"(pytest listed only the {run.only_slowest} slowest durations: the sums below are theirs; run with "
              "--durations=0, as this script does, for all)")
    print(f"{'tests summed over the workers':48s} {run.summed:8.1f} s  "
          + ", ".join(f"{phase} {run.phases[phase]:.1f}" for phase in ("setup", "call", "teardown")))
    for low, high in BUCKETS:
        inside = [s for s in run.tests.values() if low <= s < high]
        label = f"tests of {low:g}-{high:g} s" if high != float("inf") else f"tests of {low:g} s or more"
        print(f"{label:48s} {sum(inside):8.1f} s  ({len(inside)} tests)")
    print("files that take the most:")
    for name, seconds in sorted(run.files().items(), key=lambda item: -item[1])[:top]:
        print(f"  {seconds:7.1f} s  {name}")
    print("tests that take the most:")
    for name, seconds in sorted(run.tests.items(), key=lambda item: -item[1])[:top]:
        print(f"  {seconds:7.1f} s  {name}")
    if fits is not None:
        print(f"dynamics model fits: {fits['fits']} ({fits['distinct']} distinct), {fits['cpu']:.1f} s CPU, "
              f"{fits['repeated_cpu']:.1f} s of them fitting again what an earlier fit had")
        for seconds, tests in fits["repeated"][:top]:
            print(f"  {seconds:7.1f} s again  {', '.join(test.split('::')[-1] for test in tests)}")
    print(f"ratio={run.wall / GOAL_SECONDS:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "suite-time.txt",
                        help="where pytest's output is kept (default runs/suite-time.txt)")
    parser.add_argument("--fits", action="store_true", help="time every fit of the dynamics model too")
    parser.add_argument("--read", type=Path, metavar="FILE", help="report a saved run's output instead of running")
    args = parser.parse_args()
    if args.fits and args.read is not None:  # a saved output holds no fits
        parser.error("--fits times the fits of a run of the suite; --read reports a saved one: give one of them")
    try:
        if args.read is not None:
            print(f"(read from {args.read})")
            report(read_output(args.read.read_text()), None)
            return
        environment = dict(os.environ)
        print(f"{'gauge: dynamics fit per update, before the suite':48s} {gauge_us():8.1f} us")
        with tempfile.TemporaryDirectory(prefix="oodmon-suite-time-") as folder:
            fits_file = Path(folder) / "fits.jsonl" if args.fits else None
            workers_file = Path(folder) / "workers.jsonl"
            run = read_output(run_suite(args.out, fits_file, environment, workers_file))
            fits = None
            if fits_file is not None:  # (no file: the suite fitted no dynamics model)
                fits = read_fits(fits_file.read_text().splitlines() if fits_file.exists() else [])
            workers = read_workers(workers_file.read_text().splitlines() if workers_file.exists() else [])
    except OSError as error:
        sys.exit(f"suite_time.py: {error}")
    except ValueError as error:
        sys.exit(f"suite_time.py: {error} ({args.read if args.read is not None else args.out})")
    print(f"(pytest's output in {args.out})")
    report(run, fits, workers=workers)


if __name__ == "__main__":
    main()
