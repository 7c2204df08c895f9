"""Timing shared by the benchmarks: microseconds per call, best of three rounds."""

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
