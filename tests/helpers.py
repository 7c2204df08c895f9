"""Helpers shared by the tests."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import warnings


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """``oodmon ARGS`` run in this process, its output captured as a subprocess's would be.

    In-process saves the 3-4 s a new interpreter spends importing torch, per call; ``python -m
    oodmon`` itself is run as a subprocess by tests/test_cli.py. Warnings are printed to the
    captured stderr every time, as a fresh process would print them.
    """
    from oodmon.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.filterwarnings("error", category=DeprecationWarning, module="oodmon.*")
        warnings.showwarning = lambda message, category, filename, lineno, file=None, line=None: sys.stderr.write(
            warnings.formatwarning(message, category, filename, lineno, line))
        code = main(list(args))
    return subprocess.CompletedProcess(["oodmon", *args], code, out.getvalue(), err.getvalue())


def load_script(name: str):
    """The repository's root and scripts/<name>.py loaded as a module (the scripts' own imports of
    each other need scripts/ on sys.path: pytest's ``monkeypatch.syspath_prepend``)."""
    import importlib.util
    from pathlib import Path

    import oodmon

    root = Path(oodmon.__file__).parent.parent
    spec = importlib.util.spec_from_file_location(name, root / "scripts" / f"{name}.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return root, script
