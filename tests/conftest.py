"""Suite-wide settings. ``make test`` runs the test files in parallel (pytest-xdist, one file per
worker at a time, so a module's fixtures are built once): each worker then gets one torch thread,
and so do the commands the tests start, instead of every process claiming every core."""

from __future__ import annotations

import os


def pytest_configure(config) -> None:
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        os.environ.setdefault("OODMON_TORCH_THREADS", "1")
        torch.set_num_threads(1)
