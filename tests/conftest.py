"""Suite-wide settings. ``make test`` runs the test files in parallel (pytest-xdist, one file per
worker at a time, so a module's fixtures are built once): each worker then gets one thread for
torch and one for numpy's BLAS, and so do the commands the tests start, instead of every process
claiming every core (and keeping a second thread spinning: ``benchmarks/threads.py``)."""

from __future__ import annotations

import os


def pytest_configure(config) -> None:
    if os.environ.get("PYTEST_XDIST_WORKER"):
        from oodmon.threads import set_threads

        os.environ.setdefault("OODMON_TORCH_THREADS", "1")
        set_threads(1)
