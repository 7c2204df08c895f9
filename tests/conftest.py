"""Suite-wide settings. ``make test`` runs the tests in parallel (pytest-xdist, ``--dist worksteal``:
each worker starts on its share and an idle one takes tests from the other's, so a module whose
tests end up on both builds its module-scoped fixtures on each): each worker then gets one thread
for torch and one for numpy's BLAS, and so do the commands the tests start, instead of every
process claiming every core (and keeping a second thread spinning: ``benchmarks/threads.py``).

The tests that call SB3's ``model.learn()`` themselves, as a user does, share one logger folder,
removed at the end: SB3 makes an empty tempdir/SB3-<time> folder per ``learn()`` otherwise.

A module an earlier test imported from a temporary folder of its own (a user's policy or env module
written there: ``my_policy``, ``my_envs``) is forgotten before each test, so that a test of that
name imports its own instead of finding the last one's in ``sys.modules`` (on the same worker, in
an order that worksteal decides). Before the test, not after: the undo of a test's monkeypatch,
which runs after every fixture of this file, puts back what the test removed."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile

import pytest

_SB3_LOGDIR = None


def pytest_configure(config) -> None:
    global _SB3_LOGDIR
    if "SB3_LOGDIR" not in os.environ:
        _SB3_LOGDIR = os.environ["SB3_LOGDIR"] = tempfile.mkdtemp(prefix="oodmon-tests-sb3-")
    if os.environ.get("PYTEST_XDIST_WORKER"):
        from oodmon.threads import set_threads

        os.environ.setdefault("OODMON_TORCH_THREADS", "1")
        set_threads(1)


#: The modules of ``sys.modules`` found not to come from a temporary folder, by name: a module object
#: seen there already is not looked at again (asking each of a worker's 3,000-odd modules where it
#: lies took about 3 ms before every test, 1% of the suite; a namespace package's ``__path__``
#: searches sys.path again when read). A module imported again under that name is another object.
_NOT_TEMPORARY: dict[str, object] = {}


@pytest.fixture(autouse=True)
def forget_modules_imported_from_temporary_folders(tmp_path_factory):
    base = str(tmp_path_factory.getbasetemp())
    for name, module in list(sys.modules.items()):
        if _NOT_TEMPORARY.get(name) is module:
            continue
        where = getattr(module, "__file__", None) or next(iter(getattr(module, "__path__", None) or []), "")
        if isinstance(where, str) and where.startswith(base):
            del sys.modules[name]
        else:
            _NOT_TEMPORARY[name] = module


@pytest.fixture(autouse=True)
def close_figures_left_open():
    """The figures a test kept to read them (``save_figure`` patched to hand them over) stayed open
    in its worker: past 20 of them matplotlib warned at whichever test opened the next (a sweep
    script's, in a fresh clone's run, 2026-12-07). Closed after each test."""
    yield
    pyplot = sys.modules.get("matplotlib.pyplot")
    if pyplot is not None and pyplot.get_fignums():
        pyplot.close("all")


def pytest_unconfigure(config) -> None:
    if _SB3_LOGDIR is not None:
        shutil.rmtree(_SB3_LOGDIR, ignore_errors=True)
        del os.environ["SB3_LOGDIR"]
