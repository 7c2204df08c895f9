"""Doctests (``--doctest-modules`` over ``oodmon/``) write their examples' files where a user would,
``tempfile.mkdtemp()``: under pytest that folder is made in the test's own temporary folder, which
pytest removes with the rest of its old runs, instead of one empty folder per example left in /tmp
at every run of the suite. The suite's other settings: ``tests/conftest.py``."""

from __future__ import annotations

import tempfile

import pytest
from _pytest.doctest import DoctestItem


@pytest.fixture(autouse=True)
def _doctest_temp_folder(request, monkeypatch):
    if isinstance(request.node, DoctestItem):
        monkeypatch.setattr(tempfile, "tempdir", str(request.getfixturevalue("tmp_path")))
