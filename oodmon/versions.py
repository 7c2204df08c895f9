"""The versions of the libraries a model or a log was made with, for their metadata."""

from __future__ import annotations

import platform
from importlib.metadata import PackageNotFoundError, version

__all__ = ["LIBRARIES", "library_versions"]

#: The libraries whose versions decide what a model or a log holds.
LIBRARIES = ("oodmon", "torch", "stable_baselines3", "gymnasium", "numpy", "ale_py", "safetensors", "mcap")


def library_versions(names: tuple[str, ...] = LIBRARIES) -> dict[str, str]:
    """``{name: version}`` for each library (``"not installed"`` when missing), and Python's.

    Example:
        >>> "python" in library_versions(("numpy",))
        True
    """
    found = {}
    for name in names:
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = "not installed"
    found["python"] = platform.python_version()
    return found
