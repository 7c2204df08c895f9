"""A pytest plugin of ``benchmarks/suite_time.py``: when each test of the suite started and ended,
on which xdist worker, one JSON line each in the file ``OODMON_SUITE_WORKERS`` names (nothing
without it).

From these lines the script tells whether the workers stay busy to the end or one waits for the
other's last long test (a tail that ordering the tests could win back), and how much of the wall
time passes before the first test starts (start-up and collection). Loaded by ``-p suite_workers``
with this folder on PYTHONPATH (each xdist worker loads it too).
"""

from __future__ import annotations

import json
import os
import time

_started: dict[str, float] = {}
_recording = False


def pytest_configure(config) -> None:
    """Record in the process that runs the tests: a worker, or a run without workers; not in the
    xdist controller, which hears of every worker's tests too."""
    global _recording
    controller = getattr(config.option, "dist", "no") != "no" and not hasattr(config, "workerinput")
    _recording = bool(os.environ.get("OODMON_SUITE_WORKERS")) and not controller


def pytest_runtest_logstart(nodeid: str, location) -> None:
    if _recording:
        _started[nodeid] = time.time()


def pytest_runtest_logfinish(nodeid: str, location) -> None:
    path = os.environ.get("OODMON_SUITE_WORKERS")
    if not _recording or not path or nodeid not in _started:
        return
    row = {"worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), "test": nodeid,
           "start": _started.pop(nodeid), "end": time.time()}
    with open(path, "a") as out:  # one short line per write: the workers' lines do not interleave
        out.write(json.dumps(row) + "\n")
