"""SIGTERM to a bench on a local Ray cluster across the seconds Ray starts in: its exit codes.

Run (about 10 s a stop, one core; needs ray):
    .venv/bin/python scripts/ray_start_stops.py [--start 3.0 --end 7.0 --step 0.1 --rounds 1]

Starts ``scripts/fuzz_interrupts.py``'s Ray bench (``RAY``, in a temporary folder) once for each
delay from ``--start`` to ``--end`` seconds (``--rounds`` times), sends its process SIGTERM after
that delay, and prints for each stop: the exit code, whether Ray's core had caught the signal
first (its handler prints "SIGTERM received": the stop came as ``ray.init`` built Ray's core in the
process), the command's last line, and how many of Ray's processes are alive 3 s after the exit
(agents of a cluster whose start was cut end on their own a minute or so later, and are counted
again by the next stops). The last line counts the stops that met Ray's handler and ended 143.
Where Ray starts depends on the machine: 3.5-4.2 s after the command on session 88's Intel VM,
6.1-6.6 s on 2026-12-07's AMD EPYC one (start with a wide scan).

Found on 2026-12-07 (by hand, the script's loop in /tmp): every stop that met Ray's handler said
what was kept and then ended by Ray's abort in Python's exit (-6: 5 of 5, at 6.2-6.6 s). Since
``oodmon.cli.console`` leaves a stopped command with Ray loaded at once: 10 of 10 such stops ended
143 (4 of them by ``--start 6.0 --end 6.7 --step 0.05``), every other stop 143 as before.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from fuzz_interrupts import OODMON, RAY  # scripts/fuzz_interrupts.py, beside this script


def ray_processes() -> int:
    """Ray's processes alive on this machine (its workers and agents, its core's servers)."""
    names = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout.splitlines()
    return sum(name.startswith("ray::") or "/ray/core/src/" in name for name in names)


def stop_at(delay: float, folder: Path) -> tuple[int, bool, str]:
    """The bench SIGTERMed ``delay`` s after its start: its exit code, whether Ray's core caught
    the signal first, its last line of stderr."""
    command = subprocess.Popen([OODMON, *RAY], cwd=folder, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    time.sleep(delay)
    command.send_signal(signal.SIGTERM)
    try:
        _, stderr = command.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(command.pid, signal.SIGKILL)
        _, stderr = command.communicate()
    return command.returncode, "SIGTERM received" in stderr, (stderr.strip().splitlines() or [""])[-1][:90]


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
    met = met_143 = 0
    for _ in range(args.rounds):
        for delay in delays:
            with tempfile.TemporaryDirectory() as folder:
                code, caught, said = stop_at(delay, Path(folder))
            time.sleep(3.0)
            met += caught
            met_143 += caught and code == 143
            print(f"at {delay:5.2f} s: exit {code:4d}, Ray's handler {'met' if caught else '-  '}, "
                  f"Ray's processes left {ray_processes()}: {said!r}", flush=True)
    print(f"{met_143} of the {met} stops that met Ray's handler ended 143")
    return 0 if met_143 == met else 1


if __name__ == "__main__":
    sys.exit(main())
