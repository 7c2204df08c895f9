"""Timing shared by the benchmarks: microseconds per call, best of three rounds; and the
figures and per-task ratio lines the floor scripts print."""

from __future__ import annotations

import time
from collections.abc import Callable


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
