"""A monitored Pong decision's wall time with torch on one thread / with torch's default (a thread
per core), alone and with a second such process beside it.

Run: .venv/bin/python benchmarks/torch_threads.py [--games 3]

Each configuration runs one or two processes side by side; each plays ``--games`` ID games of the
shipped Pong DropConnect agent under the monitor with its frames detector (seeds 700,000 on, as
``oodmon validate``) and reports its decisions per second. "one thread" is what
``OODMON_TORCH_THREADS=1`` gives (``oodmon.threads.limit_torch_threads``); "default" leaves torch
its own choice. Two processes on a two-core machine, each with torch's default, is what running two
scripts that ignored ``OODMON_TORCH_THREADS`` did: each kept a torch OpenMP thread as busy as its
main thread (``top -H``; gdb showed it in libgomp's barrier).

Prints seconds per 1,000 decisions for each configuration (the slower process where two run), then
``ratio_alone=`` (alone: default / one thread) and ``ratio=`` (two side by side: default / one
thread); lower than 1 would mean torch's default is faster. Readings on 2026-11-28 (two cores, no
other load) are in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

SEED = 700_000


def worker(threads: int, games: int) -> None:
    """Play ``games`` monitored games; print {"decisions": n, "seconds": s} as JSON."""
    import torch

    if threads:
        torch.set_num_threads(threads)
    from oodmon.agents import load
    from oodmon.monitor import Monitor
    from oodmon.monitor.detectors import detectors_for

    agent = load("pong", "dropconnect", seed=SEED)
    detectors = detectors_for(agent).subset(["frames"])
    env = agent.make_env()
    decisions, started = 0, time.perf_counter()
    with Monitor(agent, detectors=detectors, log_observations=False) as monitor:
        for game in range(games):
            decisions += monitor.run_episode(env, seed=SEED + game, variant="pong").length
    print(json.dumps({"decisions": decisions, "seconds": time.perf_counter() - started,
                      "threads": torch.get_num_threads()}))


def run(processes: int, threads: int, games: int) -> tuple[float, int]:
    """Seconds per 1,000 decisions of the slower of ``processes`` side by side, and torch's threads."""
    env = {key: value for key, value in os.environ.items() if key != "OODMON_TORCH_THREADS"}
    children = [subprocess.Popen([sys.executable, __file__, "--worker", "--threads", str(threads),
                                  "--games", str(games)], stdout=subprocess.PIPE, text=True, env=env)
                for _ in range(processes)]
    reports = [json.loads(child.communicate()[0]) for child in children]
    if any(child.returncode for child in children):
        raise SystemExit("a worker failed")
    return max(1000 * r["seconds"] / r["decisions"] for r in reports), reports[0]["threads"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--games", type=int, default=3)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--threads", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.threads, args.games)
        return
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores; {args.games} games per process")
    times = {}
    for processes in (1, 2):
        for threads in (1, 0):
            seconds, used = run(processes, threads, args.games)
            times[processes, threads] = seconds
            print(f"{processes} process{'es' if processes > 1 else ''}, torch threads {used} "
                  f"({'one' if threads else 'default'}): {seconds:.2f} s per 1,000 decisions", flush=True)
    print(f"ratio_alone={times[1, 0] / times[1, 1]:.2f}")
    print(f"ratio={times[2, 0] / times[2, 1]:.2f}")


if __name__ == "__main__":
    main()
