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
    """The kind of CPU this process runs on: its architecture, its name with its family and model
    (Linux's ``/proc/cpuinfo``; elsewhere what ``platform`` says), the kernels numpy's OpenBLAS
    chose for it and the vector instructions torch's kernels use on it.

    The same command trains other weights, and fits other detectors, on another kind of CPU
    (2026-11-29: an Intel CPU with AVX-512 against an AMD EPYC one; on the Intel one alone, with
    torch held to AVX2 and MKL and OpenBLAS to theirs, a third set of weights): a model's, a log's
    and a bench result's metadata record it beside the library versions. A VM's name says little:
    two 2-core VMs that both read "x86_64; AMD EPYC; torch AVX512" fitted the shipped Pendulum
    ensemble's detectors otherwise (2026-12-03: each the same bytes run after run, the two apart),
    hence the family and model, and OpenBLAS's kernels, which numpy's products round by.

    Example:
        >>> machine().startswith(platform.machine())
        True
    """
    import torch

    name = platform.processor() or "unknown processor"
    first: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if not line.strip():
                break  # the first processor's block says it for all
            key, _, value = line.partition(":")
            first.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    name = first.get("model name", name)
    if "cpu family" in first and "model" in first:
        name += f" (family {first['cpu family']}, model {first['model']})"
    blas = _openblas_kernels()
    return (f"{platform.machine()}; {name}; " + (f"OpenBLAS {blas}; " if blas else "")
            + f"torch {torch.backends.cpu.get_cpu_capability()}")


def _openblas_kernels() -> str | None:
    """The CPU kernels numpy's OpenBLAS chose (``SkylakeX``, ``Zen``, ``Haswell``...), or ``None``
    where numpy uses another BLAS, or one outside its own folder (a system OpenBLAS), or
    threadpoolctl cannot tell."""
    import numpy  # noqa: F401  (its BLAS loaded, for threadpoolctl to find)
    from threadpoolctl import threadpool_info

    # numpy's own (its wheel's numpy.libs), not another package's copy: OpenCV brings one, which chose
    # other kernels (Zen) on the machine where numpy's chose SkylakeX
    kernels = [info["architecture"] for info in threadpool_info() if info.get("internal_api") == "openblas"
               and info.get("architecture") and "numpy" in str(info.get("filepath", ""))]
    return str(kernels[0]) if kernels else None
