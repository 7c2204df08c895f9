"""A monitored decision's wall time with one thread / with the library's default (a thread per
core), alone and with a second such process beside it: torch's threads (a Pong decision) or
numpy's BLAS threads (a CartPole DropConnect decision with fixed masks).

Run: .venv/bin/python benchmarks/threads.py [--case torch|blas|blas-pong] [--episodes N]

Each configuration runs one or two processes side by side; each plays ``--episodes`` ID episodes
under the monitor (seeds 700,000 on, as ``oodmon validate``) and reports its decisions per second.
``--case torch`` (the default): the shipped Pong DropConnect agent with its frames detector (3
games by default), torch on one thread or on its default, numpy's BLAS on one thread in both.
``--case blas``: the shipped CartPole DropConnect agent loaded with ``masks="fixed"`` (its K fixed
sub-networks are one matrix product per layer, through numpy's OpenBLAS; 10 episodes by default),
numpy's BLAS on one thread or on its default, torch on one thread in both. ``--case blas-pong``:
the same threads, on the shipped Pong DropConnect agent with its features detector (a large
matrix-vector product through OpenBLAS at every step; 2 games by default). "one thread" is what
``OODMON_TORCH_THREADS=1`` gives (``oodmon.threads.limit_threads``, every command's default). Two
processes on a two-core machine, each with a library's default, is what two scripts that ignored
``OODMON_TORCH_THREADS`` did: each kept a second thread as busy as its main one (``top -H``; gdb
finds it in libgomp's barrier for torch, in OpenBLAS's ``blas_thread_server`` for numpy).

Prints seconds per 1,000 decisions for each configuration (the slower process where two run), then
``ratio_alone=`` (alone: default / one thread) and ``ratio=`` (two side by side: default / one
thread); lower than 1 would mean the library's default is faster. Readings (two cores, no other
load) are in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

SEED = 700_000
#: Per case: the agent (task, method, masks), the detectors the monitor reads, episodes by default.
CASES = {"torch": (("pong", "dropconnect", None), ["frames"], 3),
         "blas": (("cartpole", "dropconnect", "fixed"), None, 10),
         "blas-pong": (("pong", "dropconnect", None), ["features"], 2)}


def worker(case: str, threads: int, episodes: int) -> None:
    """Play ``episodes`` monitored episodes, the case's library on ``threads`` (0: its default) and
    the other on one; print {"decisions": n, "seconds": s, "threads": used} as JSON."""
    import numpy  # noqa: F401  (loads its BLAS for threadpoolctl)
    import torch
    from threadpoolctl import threadpool_info, threadpool_limits

    torch_threads, blas_threads = (threads, 1) if case == "torch" else (1, threads)  # 0: the library's default
    if torch_threads:
        torch.set_num_threads(torch_threads)
    if blas_threads:
        threadpool_limits(blas_threads, user_api="blas")
    from oodmon.agents import load
    from oodmon.monitor import Monitor
    from oodmon.monitor.detectors import detectors_for

    (task, method, masks), names, _ = CASES[case]
    agent = load(task, method, seed=SEED, masks=masks)
    detectors = detectors_for(agent).subset(names) if names else None
    env = agent.make_env()
    decisions, started = 0, time.perf_counter()
    with Monitor(agent, detectors=detectors, log_observations=False) as monitor:
        for episode in range(episodes):
            decisions += monitor.run_episode(env, seed=SEED + episode, variant=task).length
    used = torch.get_num_threads() if case == "torch" else next(  # numpy's own (opencv and scipy bring theirs)
        pool["num_threads"] for pool in threadpool_info() if f"{os.sep}numpy" in pool["filepath"])
    print(json.dumps({"decisions": decisions, "seconds": time.perf_counter() - started, "threads": used}))


def run(case: str, processes: int, threads: int, episodes: int) -> tuple[float, int]:
    """Seconds per 1,000 decisions of the slower of ``processes`` side by side, and the threads used."""
    env = {key: value for key, value in os.environ.items() if key != "OODMON_TORCH_THREADS"}
    children = [subprocess.Popen([sys.executable, __file__, "--worker", "--case", case, "--threads", str(threads),
                                  "--episodes", str(episodes)], stdout=subprocess.PIPE, text=True, env=env)
                for _ in range(processes)]
    reports = [json.loads(child.communicate()[0]) for child in children]
    if any(child.returncode for child in children):
        raise SystemExit("a worker failed")
    return max(1000 * r["seconds"] / r["decisions"] for r in reports), reports[0]["threads"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=sorted(CASES), default="torch")
    parser.add_argument("--episodes", type=int, help="per process (default: torch 3 games, blas 10 episodes, "
                        "blas-pong 2 games)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--threads", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    episodes = args.episodes or CASES[args.case][2]
    if args.worker:
        worker(args.case, args.threads, episodes)
        return
    library = "torch threads" if args.case == "torch" else "numpy BLAS threads"
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores; {episodes} episodes per process")
    times = {}
    for processes in (1, 2):
        for threads in (1, 0):
            seconds, used = run(args.case, processes, threads, episodes)
            times[processes, threads] = seconds
            print(f"{processes} process{'es' if processes > 1 else ''}, {library} {used} "
                  f"({'one' if threads else 'default'}): {seconds:.2f} s per 1,000 decisions", flush=True)
    print(f"ratio_alone={times[1, 0] / times[1, 1]:.2f}")
    print(f"ratio={times[2, 0] / times[2, 1]:.2f}")


if __name__ == "__main__":
    main()
