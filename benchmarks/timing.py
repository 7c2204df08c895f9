"""Timing shared by the benchmarks: microseconds per call, best of three rounds; and the
figures and per-task ratio lines the floor scripts print."""

from __future__ import annotations

import time
from collections.abc import Callable
from statistics import median


def per_call_us(call: Callable[[], object], repeats: int, rounds: int = 3) -> float:
    """Microseconds per call of ``call``: warm up, then the best of ``rounds`` rounds of
    ``repeats`` calls (the round least disturbed by the rest of the machine)."""
    for _ in range(max(repeats // 10, 1)):
        call()
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(repeats):
            call()
        best = min(best, (time.perf_counter() - start) / repeats * 1e6)
    return best


def print_figures(figures: dict[str, float], width: int) -> None:
    """One line per figure: its label, then its microseconds."""
    for name, us in figures.items():
        print(f"{name:{width}s} {us:10.1f} us")


def print_ratios(name: str, ratios: dict[str, float]) -> None:
    """Lines ``<name>_<task>=<ratio>`` for each task, then ``<name>=`` the largest."""
    for task, ratio in ratios.items():
        print(f"{name}_{task}={ratio:.2f}")
    print(f"{name}={max(ratios.values()):.2f}")


def paired_us(call: Callable[[], object], baseline: Callable[[], object], repeats: int,
              pairs: int = 5) -> tuple[float, float, float]:
    """``call`` and ``baseline`` timed in alternation: ``pairs`` pairs of rounds, the first round
    of a pair ``call`` then ``baseline``, the second ``baseline`` then ``call``, each ``repeats``
    calls. Returns the median microseconds per call of each over its rounds, and the median over
    the pairs of a pair's ratio (``call``'s time in its two rounds / ``baseline``'s). On a shared
    VM the machine's speed drifts by 20-60% within a minute: a ratio of two figures taken minutes
    apart moves with it, one of a pair's back-to-back figures much less; and whichever goes
    second in a round has run slower here, by up to 2.3 times for a whole round (seen once, on
    2026-11-27): each order once per pair cancels that."""
    for function in (call, baseline):
        for _ in range(max(repeats // 10, 1)):
            function()

    def seconds(function) -> float:
        start = time.perf_counter()
        for _ in range(repeats):
            function()
        return time.perf_counter() - start

    ours, theirs, ratios = [], [], []
    for _ in range(pairs):
        a1 = seconds(call)
        b1 = seconds(baseline)
        b2 = seconds(baseline)
        a2 = seconds(call)
        ours += [a1, a2]
        theirs += [b1, b2]
        ratios.append((a1 + a2) / (b1 + b2))

    return median(ours) / repeats * 1e6, median(theirs) / repeats * 1e6, median(ratios)


def process_seconds(script: str, *args: str) -> float:
    """Seconds a new Python process running ``script`` (with ``args``) reports: the last number it
    prints, its own timing from its start (its imports included) to its end."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])
