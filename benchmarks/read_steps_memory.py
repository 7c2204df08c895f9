"""Memory of reading a picture policy's logged steps back (``read_steps``), beside the frames' own size.

Run: .venv/bin/python benchmarks/read_steps_memory.py [--games 10] [--log runs/bench-read-steps.mcap]

``fit-detectors --from-logs`` of a policy on pictures (Pong) reads every step's frame of the logs'
ID episodes into memory (:func:`oodmon.replay.reader.read_steps`) before it fits. This plays
``--games`` whole games of the shipped Pong DropConnect agent into an MCAP log (about 4.5 s a game
on one core; kept at ``--log`` and read again on the next run), then reads their steps back in a
fresh process and prints the process's peak resident memory (Linux's ``VmHWM``, reset first) above
what it held after reading the log's index (``read_log``), the frames' own bytes, the time, and last ``ratio=<peak above / the
frames' bytes>`` (lower is better; goal <= 1.5: the frames once, and the messages of the episode
being decoded; a small log reads higher, the reading's own imports weighing more). Until
2026-12-07 the messages of every frame were all kept while each episode's frames were decoded into
a list and stacked into one array (a third copy): 10 games (23,744 steps, 159.8 MB of frames) read
with a peak 344.3 MB above (ratio 2.16), 2 games (30.2 MB) 79.2 MB (2.62); since, each episode's
messages are decoded into one array filled in place and dropped as they go: 202.5 MB (1.27) and
63.6 MB (2.10), in the same 1.0 and 0.16 s (2026-12-07, the AMD EPYC VM).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

READ = """
import json, sys, time
from oodmon.replay import read_log
from oodmon.replay.reader import read_steps

def status_mb(key):  # VmRSS now, VmHWM the peak since the last reset
    line = next(line for line in open("/proc/self/status") if line.startswith(key + ":"))
    return int(line.split()[1]) / 1024

log = read_log(sys.argv[1])
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # (Linux: the peak starts again from what the process holds now)
before, start = status_mb("VmRSS"), time.perf_counter()
steps = read_steps(sys.argv[1], range(len(log.episodes)))
print(json.dumps({"above": status_mb("VmHWM") - before, "frames": sum(s[0].nbytes for s in steps.values()) / 2**20,
                  "seconds": time.perf_counter() - start, "steps": sum(len(s[0]) for s in steps.values())}))
"""


def write_log(path: Path, games: int) -> None:
    """``games`` whole ID games of the shipped Pong DropConnect agent, logged to ``path``."""
    from oodmon.cli import main

    path.parent.mkdir(parents=True, exist_ok=True)
    if main(["run", "--task", "pong", "--method", "dropconnect", "--episodes", str(games), "--seed", "300",
             "--mcap", str(path)]) != 0:
        sys.exit("the games could not be played and logged")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--games", type=int, default=10, help="whole Pong games to log (default 10)")
    parser.add_argument("--log", type=Path, default=ROOT / "runs" / "bench-read-steps.mcap",
                        help="the log to write, or to read again where it exists")
    args = parser.parse_args()
    if not args.log.exists():
        write_log(args.log, args.games)
    done = subprocess.run([sys.executable, "-c", READ, str(args.log)], capture_output=True, text=True, check=True)
    reading = json.loads(done.stdout)
    print(f"{reading['steps']} steps, frames {reading['frames']:.1f} MB, read in {reading['seconds']:.2f} s, "
          f"peak {reading['above']:.1f} MB above the log's index")
    print(f"ratio={reading['above'] / reading['frames']:.2f}")


if __name__ == "__main__":
    main()
