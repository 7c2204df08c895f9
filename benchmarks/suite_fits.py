"""A pytest plugin of ``benchmarks/suite_time.py --fits``: every fit of the dynamics model in the
suite, timed, one JSON line each in the file ``OODMON_SUITE_FITS`` names (nothing without it).

Each line holds the fit's CPU and wall seconds, the test it ran in, and a key: a hash of the
detector's settings, the fit's seed and the transitions' bytes. Two fits of one key fit the same
model on the same transitions (the fit is seeded), so the later one's time is what a cache would
have saved. Loaded by ``-p suite_fits`` with this folder on PYTHONPATH (each xdist worker loads it
too); the fit itself runs as always.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from typing import Any

import numpy as np


def fit_key(detector: Any, trajectories: Any, seed: Any) -> str:
    """What decides a fit's model: the detector's public settings, the seed and each trajectory's
    observations and actions (their dtype, shape and bytes)."""
    digest = hashlib.sha256()
    settings = sorted((name, repr(value)) for name, value in vars(detector).items() if not name.startswith("_"))
    digest.update(repr((settings, seed)).encode())
    for trajectory in trajectories:
        for array in (trajectory.observations, trajectory.actions):
            array = np.ascontiguousarray(np.asarray(array))
            digest.update(f"{array.dtype}{array.shape}".encode())
            digest.update(array.tobytes())
    return digest.hexdigest()


def pytest_configure(config) -> None:
    path = os.environ.get("OODMON_SUITE_FITS")
    if not path:
        return
    from oodmon.monitor.detectors.dynamics import DynamicsDetector

    fit = DynamicsDetector.fit

    def timed_fit(self, trajectories, *, seed=None, on_progress=None):
        key = fit_key(self, trajectories, seed)
        cpu, wall = time.process_time(), time.perf_counter()
        fitted = fit(self, trajectories, seed=seed, on_progress=on_progress)
        row = {"key": key, "cpu": time.process_time() - cpu, "wall": time.perf_counter() - wall,
               "test": os.environ.get("PYTEST_CURRENT_TEST", "").rsplit(" ", 1)[0]}
        with open(path, "a") as out:  # one short line per write: the workers' lines do not interleave
            out.write(json.dumps(row) + "\n")
        return fitted

    DynamicsDetector.fit = timed_fit
