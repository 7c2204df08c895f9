"""Suite-wide settings. ``make test`` runs the test files in parallel (pytest-xdist, one file per
worker at a time, so a module's fixtures are built once): each worker then gets one thread for
torch and one for numpy's BLAS, and so do the commands the tests start, instead of every process
claiming every core (and keeping a second thread spinning: ``benchmarks/threads.py``).

The tests that call SB3's ``model.learn()`` themselves, as a user does, share one logger folder,
removed at the end: SB3 makes an empty tempdir/SB3-<time> folder per ``learn()`` otherwise."""

from __future__ import annotations

import os
import shutil
import tempfile

_SB3_LOGDIR = None


def pytest_configure(config) -> None:
    global _SB3_LOGDIR
    if "SB3_LOGDIR" not in os.environ:
        _SB3_LOGDIR = os.environ["SB3_LOGDIR"] = tempfile.mkdtemp(prefix="oodmon-tests-sb3-")
    if os.environ.get("PYTEST_XDIST_WORKER"):
        from oodmon.threads import set_threads

        os.environ.setdefault("OODMON_TORCH_THREADS", "1")
        set_threads(1)


def pytest_unconfigure(config) -> None:
    if _SB3_LOGDIR is not None:
        shutil.rmtree(_SB3_LOGDIR, ignore_errors=True)
        del os.environ["SB3_LOGDIR"]
