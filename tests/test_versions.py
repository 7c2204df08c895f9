"""oodmon.versions.machine: the CPU kind a model, a log or a bench result records."""

from __future__ import annotations

import platform

import pytest
import torch

from oodmon import versions

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC
flags\t\t: fpu avx512f

processor\t: 1
cpu family\t: 99
model\t\t: 99
model name\t: another
"""


@pytest.fixture
def fresh_machine():
    versions.machine.cache_clear()
    yield versions.machine
    versions.machine.cache_clear()


def test_machine_names_the_cpus_family_and_model_and_the_kernels_of_numpys_own_openblas(fresh_machine, tmp_path,
                                                                                     monkeypatch):
    """Two VMs that read "x86_64; AMD EPYC; torch AVX512" fitted the Pendulum ensemble's detectors
    otherwise (2026-12-03): the record now tells such CPUs apart. OpenCV brings an OpenBLAS of its
    own, which chose other kernels (Zen) than numpy's (SkylakeX) on the same machine."""
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(CPUINFO)
    monkeypatch.setattr(versions, "Path", lambda path: cpuinfo if path == "/proc/cpuinfo" else path)
    blas = [{"internal_api": "openblas", "architecture": "Zen", "filepath": "/v/opencv_python_headless.libs/libopenblas.so"},
            {"internal_api": "openmp", "filepath": "/v/torch/lib/libgomp.so.1"},
            {"internal_api": "openblas", "architecture": "SkylakeX", "filepath": "/v/numpy.libs/libscipy_openblas64_.so"}]
    monkeypatch.setattr("threadpoolctl.threadpool_info", lambda: blas)
    torch_kernels = torch.backends.cpu.get_cpu_capability()
    assert fresh_machine() == f"{platform.machine()}; AMD EPYC (family 25, model 17); OpenBLAS SkylakeX; torch {torch_kernels}"
    # no OpenBLAS of numpy's own (numpy on another BLAS; OpenCV's is not numpy's), no family (an ARM
    # CPU's cpuinfo): what is known
    cpuinfo.write_text("processor\t: 0\nmodel name\t: Neoverse\n")
    monkeypatch.setattr("threadpoolctl.threadpool_info", lambda: blas[:2])
    fresh_machine.cache_clear()
    assert fresh_machine() == f"{platform.machine()}; Neoverse; torch {torch_kernels}"


def test_this_machines_record_reads_its_own_cpuinfo_and_blas(fresh_machine):
    from threadpoolctl import threadpool_info

    here = fresh_machine()
    assert here.startswith(platform.machine()) and here.endswith(f"torch {torch.backends.cpu.get_cpu_capability()}")
    numpy_blas = [i for i in threadpool_info() if "numpy" in str(i.get("filepath", "")) and i.get("architecture")]
    assert all(f"OpenBLAS {i['architecture']};" in here for i in numpy_blas)
    try:
        has_family = "cpu family" in open("/proc/cpuinfo").read()
    except OSError:
        has_family = False
    assert ("(family " in here) == has_family
