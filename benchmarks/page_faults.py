"""A shipped agent's decisions in a process of their own, as `oodmon run` makes them, with glibc's
malloc as it is and with malloc told to keep its memory.

Run: .venv/bin/python benchmarks/page_faults.py [--task pendulum --method dropconnect]

Arrays above 128 KiB are mapped fresh by glibc's malloc and unmapped when freed (unless earlier
allocations have raised that threshold): a decision that makes such temporaries anew pays a page
fault per 4 KiB page, about 2 us each in this VM. ``benchmarks/uncertainty_step.py`` cannot see
this: it builds every agent in one process, whose earlier allocations leave malloc in another
state. Here each measurement is a new process that loads one agent and decides on one episode's
states, once with the environment as it is and once with ``MALLOC_MMAP_THRESHOLD_`` and
``MALLOC_TRIM_THRESHOLD_`` set (malloc keeps its memory: no faults from temporaries).

Lines: microseconds and minor page faults per decision for each; the last line is
ratio=<time as it is / time with malloc keeping its memory>; goal <= 1.1 (the agents' own arrays
leave malloc nothing to map). Pendulum DropConnect, 2026-11-27: 1.88 (2,149 us against 1,146; 570
faults per decision) before its sparse layers kept their arrays (``plan.Scratch``), 1.06 after
(1,154 us against 1,092; no faults).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

KEEP_MEMORY = {"MALLOC_MMAP_THRESHOLD_": str(1 << 28), "MALLOC_TRIM_THRESHOLD_": str(1 << 28)}
ROUNDS = 3


def child(task: str, method: str, decisions: int) -> dict[str, float]:
    """In this process: load the agent, collect an episode's states, then time the decisions on them."""
    from oodmon.agents import load
    from oodmon.envs import Variant
    from oodmon.threads import set_threads

    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    agent = load(task, method)
    env = Variant(task).make()
    obs, _ = env.reset(seed=0)
    states = []
    while len(states) < decisions:
        states.append(obs)
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, _ = env.reset(seed=len(states))
    estimator = agent.estimator
    for state in states[:20]:
        estimator.estimate(state)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    start = time.perf_counter()
    for state in states:
        estimator.estimate(state)
    seconds = time.perf_counter() - start
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    return {"us": seconds / decisions * 1e6, "faults": faults / decisions}


def measure(task: str, method: str, decisions: int, env: dict[str, str]) -> dict[str, float]:
    command = [sys.executable, __file__, "--task", task, "--method", method, "--decisions", str(decisions), "--child"]
    done = subprocess.run(command, env=os.environ | env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="pendulum")
    parser.add_argument("--method", default="dropconnect")
    parser.add_argument("--decisions", type=int, default=400)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.task, args.method, args.decisions)))
        return
    best = {}
    for _ in range(ROUNDS):  # alternating, the best round of each (the machine's speed drifts)
        for label, env in (("as it is", {}), ("keeping its memory", KEEP_MEMORY)):
            figures = measure(args.task, args.method, args.decisions, env | {"OODMON_TORCH_THREADS": "1"})
            if label not in best or figures["us"] < best[label]["us"]:
                best[label] = figures
    for label, figures in best.items():
        print(f"{args.task} {args.method}, malloc {label:18s} {figures['us']:8.1f} us  "
              f"{figures['faults']:7.1f} minor faults per decision")
    print(f"ratio={best['as it is']['us'] / best['keeping its memory']['us']:.2f}")


if __name__ == "__main__":
    main()
