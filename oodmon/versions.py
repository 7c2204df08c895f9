"""The versions of the libraries a model or a log was made with, and the machine's CPU kind, for
their metadata."""

from __future__ import annotations

import platform
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

__all__ = ["LIBRARIES", "library_versions", "machine"]

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


@cache
def machine() -> str:
    """The kind of CPU this process runs on: its architecture, its name (Linux's ``/proc/cpuinfo``;
    elsewhere what ``platform`` says) and the vector instructions torch's kernels use on it.

    The same command trains other weights, and fits other detectors, on another kind of CPU
    (2026-11-29: an Intel CPU with AVX-512 against an AMD EPYC one; on the Intel one alone, with
    torch held to AVX2 and MKL and OpenBLAS to theirs, a third set of weights): a model's, a log's
    and a bench result's metadata record it beside the library versions.

    Example:
        >>> machine().startswith(platform.machine())
        True
    """
    import torch

    name = platform.processor() or "unknown processor"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{platform.machine()}; {name}; torch {torch.backends.cpu.get_cpu_capability()}"
