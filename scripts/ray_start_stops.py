"""SIGTERM to a bench on a local Ray cluster across the seconds Ray starts in: its exit codes.

Run (about 10 s a stop, one core; needs ray):
    .venv/bin/python scripts/ray_start_stops.py [--start 3.0 --end 7.0 --step 0.1 --rounds 1]

Starts ``scripts/fuzz_interrupts.py``'s Ray bench (``RAY``, in a temporary folder, as the leader of
a session of its own) once for each delay from ``--start`` to ``--end`` seconds (``--rounds``
times), sends its process SIGTERM after that delay, and prints for each stop: the exit code,
whether Ray's core had caught the signal first (its handler prints "SIGTERM received": the stop
came as ``ray.init`` built Ray's core in the process), the processes of the command's session alive
3 s after its exit, and its last line. The last line counts the stops that met Ray's handler and
ended 143, and the stops that left processes; the exit code is 1 unless all of the first and none
of the second. Where Ray starts depends on the machine: 3.5-4.2 s after the command on session
88's Intel VM, 4.8-6.6 s on 2026-12-07's AMD EPYC one (start with a wide scan).

Found on 2026-12-07 (AMD EPYC): every stop that met Ray's handler said what was kept and then ended
by Ray's abort in Python's exit (-6: 5 of 5 by hand, at 6.2-6.6 s). Since ``oodmon.cli.console``
leaves a stopped command with Ray loaded at once: 23 of 23 such stops ended 143 (17 of them by this
script). And stops in Ray's start left Ray's two agents (``ray::DashboardAgent``,
``ray::RuntimeEnvAgent``) for a minute or so after ``ray.shutdown()``: ``--start 4.6 --end 6.6
--step 0.2`` (counted then by name over the machine) 5 of 11 stops, ``--start 4.8 --end 5.8 --step
0.2`` 1 of 6; since ``oodmon.bench.cells._start_ray`` ends what a cut start began, the first scan
twice: 0 of 11, 0 of 11.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from fuzz_interrupts import OODMON, RAY, session_left  # scripts/fuzz_interrupts.py, beside this script


def stop_at(delay: float, folder: Path) -> tuple[int, bool, str, int]:
    """The bench SIGTERMed ``delay`` s after its start: its exit code, whether Ray's core caught
    the signal first, its last line of stderr, and its session's processes alive 3 s after its exit."""
    command = subprocess.Popen([OODMON, *RAY], cwd=folder, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    time.sleep(delay)
    command.send_signal(signal.SIGTERM)
    try:
        _, stderr = command.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(command.pid, signal.SIGKILL)
        _, stderr = command.communicate()
    time.sleep(3.0)
    said = (stderr.strip().splitlines() or [""])[-1][:90]
    return command.returncode, "SIGTERM received" in stderr, said, len(session_left(command.pid))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--start", type=float, default=3.0, help="the first delay, s (default 3.0)")
    parser.add_argument("--end", type=float, default=7.0, help="the last delay, s (default 7.0)")
    parser.add_argument("--step", type=float, default=0.1, help="between delays, s (default 0.1)")
    parser.add_argument("--rounds", type=int, default=1, help="scans of the delays (default 1)")
    args = parser.parse_args()
    if not (args.step > 0 and 0 <= args.start <= args.end):
        parser.error("give 0 <= --start <= --end and --step > 0")
    delays = [args.start + i * args.step for i in range(int((args.end - args.start) / args.step + 1e-9) + 1)]
    met = met_143 = leaving = 0
    for _ in range(args.rounds):
        for delay in delays:
            with tempfile.TemporaryDirectory() as folder:
                code, caught, said, left = stop_at(delay, Path(folder))
            met += caught
            met_143 += caught and code == 143
            leaving += left > 0
            print(f"at {delay:5.2f} s: exit {code:4d}, Ray's handler {'met' if caught else '-  '}, "
                  f"processes left {left}: {said!r}", flush=True)
    print(f"{met_143} of the {met} stops that met Ray's handler ended 143; "
          f"{leaving} of the {len(delays) * args.rounds} stops left processes")
    return 0 if met_143 == met and not leaving else 1


if __name__ == "__main__":
    sys.exit(main())
