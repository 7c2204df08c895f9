"""benchmarks/suite_time.py, which times the suite as `make test` runs it: its reading of pytest's
output and of what its plugins record (benchmarks/suite_fits.py: the fits; benchmarks/suite_workers.py:
when each test ran on which worker)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from oodmon.monitor.detectors.base import Trajectory
from oodmon.monitor.detectors.dynamics import DynamicsDetector

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

OUTPUT = """\
........................................................................ [ 98%]
..                                                                       [100%]
============================= slowest durations ==============================
41.30s call     tests/agents/test_own_env_readme.py::test_readme
3.50s setup    tests/monitor/test_kill.py::test_killed
2.00s call     tests/monitor/test_kill.py::test_killed
0.40s call     tests/monitor/test_kill.py::test_other
0.10s teardown tests/monitor/test_kill.py::test_other
0.00s call     oodmon/envs/checks.py::oodmon.envs.checks.positive_number
1640 passed in 258.79s (0:04:18)
"""


def _load(name: str):
    """benchmarks/<name>.py as a module (in sys.modules, as its dataclasses need, under a name of its own)."""
    spec = importlib.util.spec_from_file_location(f"benchmarks_{name}", BENCHMARKS / f"{name}.py")
    module = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_runs_output_gives_its_wall_time_and_each_tests_and_files_seconds(capsys):
    suite_time = _load("suite_time")
    run = suite_time.read_output(OUTPUT)
    assert (run.wall, run.counts) == (258.79, "1640 passed")
    assert run.tests["tests/monitor/test_kill.py::test_killed"] == pytest.approx(5.5)  # setup and call
    assert run.tests["tests/monitor/test_kill.py::test_other"] == pytest.approx(0.5)
    assert dict(run.phases) == pytest.approx({"call": 43.7, "setup": 3.5, "teardown": 0.1})
    assert run.files() == pytest.approx({"tests/agents/test_own_env_readme.py": 41.3, "tests/monitor/test_kill.py": 6.0,
                                         "oodmon/envs/checks.py": 0.0})
    suite_time.report(run, None, top=2)
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1] == "ratio=1.44"  # 258.79 s / 180 s
    assert any(line.startswith("tests of 3-10 s") and line.endswith("(1 tests)") for line in printed)
    assert any(line.startswith("tests of 10 s or more") and "41.3 s" in line for line in printed)
    files = printed.index("files that take the most:")
    assert printed[files + 1:files + 3] == ["     41.3 s  tests/agents/test_own_env_readme.py",
                                            "      6.0 s  tests/monitor/test_kill.py"]


def test_a_run_that_failed_is_read_and_one_that_never_ended_is_said():
    suite_time = _load("suite_time")
    failed = suite_time.read_output("1.00s call     tests/a.py::test_x\n"
                                    "=========== 1 failed, 1639 passed, 2 warnings in 300.50s (0:05:00) ===========\n")
    assert (failed.wall, failed.counts) == (300.5, "1 failed, 1639 passed, 2 warnings")
    with pytest.raises(ValueError, match="no closing line"):
        suite_time.read_output(OUTPUT.rsplit("\n", 2)[0])  # cut before pytest's last line
    assert suite_time.read_output(OUTPUT).only_slowest is None  # --durations=0: every test's


def test_the_output_of_make_test_is_read_as_the_slowest_tests_only(capsys):
    """`make test` lists the 10 slowest durations: their sums are not the suite's, and the report says so."""
    suite_time = _load("suite_time")
    run = suite_time.read_output(OUTPUT.replace("slowest durations", "slowest 10 durations"))
    assert run.only_slowest == 10 and run.summed == pytest.approx(47.3)
    suite_time.report(run, None)
    assert "pytest listed only the 10 slowest durations" in capsys.readouterr().out


def test_the_saved_output_of_a_run_is_reported_and_a_missing_one_is_said(tmp_path, monkeypatch, capsys):
    suite_time = _load("suite_time")
    (tmp_path / "run.txt").write_text(OUTPUT)
    monkeypatch.setattr(sys, "argv", ["suite_time.py", "--read", str(tmp_path / "run.txt")])
    suite_time.main()
    assert capsys.readouterr().out.splitlines()[-1] == "ratio=1.44"
    monkeypatch.setattr(sys, "argv", ["suite_time.py", "--read", str(tmp_path / "none.txt")])
    with pytest.raises(SystemExit, match=r"suite_time.py: .*No such file.*none.txt'$"):
        suite_time.main()
    monkeypatch.setattr(sys, "argv", ["suite_time.py", "--read", str(tmp_path / "run.txt"), "--fits"])
    with pytest.raises(SystemExit) as refused:  # a saved output holds no fits: said, not ignored
        suite_time.main()
    assert refused.value.code == 2 and "--fits times the fits of a run of the suite" in capsys.readouterr().err
    (tmp_path / "cut.txt").write_text(OUTPUT[:200])
    monkeypatch.setattr(sys, "argv", ["suite_time.py", "--read", str(tmp_path / "cut.txt")])
    with pytest.raises(SystemExit, match=r"suite_time.py: no closing line .*\(.*cut.txt\)$"):
        suite_time.main()


def test_fits_of_the_same_model_on_the_same_transitions_count_as_repeated():
    suite_time = _load("suite_time")
    rows = [json.dumps({"key": key, "cpu": cpu, "wall": cpu, "test": test})
            for key, cpu, test in (("a", 2.0, "t1"), ("a", 1.5, "t2"), ("b", 1.0, "t3"), ("a", 0.5, "t2"))]
    fits = suite_time.read_fits(rows + [""])
    assert (fits["fits"], fits["cpu"], fits["distinct"], fits["repeated_cpu"]) == (4, 5.0, 2, 2.0)
    assert fits["repeated"] == [(2.0, ["t1", "t2"])]  # the first fit of a key is not a repeat
    assert suite_time.read_fits([]) == {"fits": 0, "cpu": 0, "distinct": 0, "repeated_cpu": 0, "repeated": []}


def _episodes(seed: int) -> list[Trajectory]:
    rng = np.random.default_rng(seed)
    return [Trajectory(observations=rng.standard_normal((31, 4)).astype(np.float32), actions=rng.integers(0, 2, 30))
            for _ in range(3)]


def test_the_plugin_writes_a_line_per_fit_keyed_by_what_decides_the_model(tmp_path, monkeypatch):
    suite_fits = _load("suite_fits")
    monkeypatch.setattr(DynamicsDetector, "fit", DynamicsDetector.fit)  # the plugin's wrapper is undone after
    monkeypatch.delenv("OODMON_SUITE_FITS", raising=False)
    original = DynamicsDetector.fit
    suite_fits.pytest_configure(None)
    assert DynamicsDetector.fit is original  # nothing asked: nothing wrapped
    monkeypatch.setenv("OODMON_SUITE_FITS", str(tmp_path / "fits.jsonl"))
    suite_fits.pytest_configure(None)
    plain = original(DynamicsDetector(2, epochs=2), _episodes(0))
    timed = DynamicsDetector(2, epochs=2).fit(_episodes(0))
    assert all(np.array_equal(a, b) for pair in zip(plain._weights, timed._weights) for a, b in zip(*pair))  # as ever
    DynamicsDetector(2, epochs=2).fit(_episodes(0), seed=1)  # another seed
    DynamicsDetector(2, epochs=2).fit(_episodes(1))  # other transitions
    DynamicsDetector(2, epochs=3).fit(_episodes(0))  # other settings
    DynamicsDetector(2, epochs=2).fit(_episodes(0))  # the first one's again
    rows = [json.loads(line) for line in (tmp_path / "fits.jsonl").read_text().splitlines()]
    keys = [row["key"] for row in rows]
    assert len(rows) == 5 and len(set(keys)) == 4 and keys[0] == keys[-1]
    assert all(row["cpu"] > 0 and row["wall"] > 0 for row in rows)
    assert rows[0]["test"].endswith("test_the_plugin_writes_a_line_per_fit_keyed_by_what_decides_the_model")


def test_the_suite_runs_as_make_test_runs_it_in_the_environment_the_script_started_with(tmp_path, monkeypatch):
    """(The suite itself is not run here: the command, its environment and the kept output.)"""
    suite_time = _load("suite_time")
    ran = []

    def run(command, **options):
        ran.append((command, options))
        return subprocess.CompletedProcess(command, 0, OUTPUT, "a warning\n")

    monkeypatch.setattr(subprocess, "run", run)
    out = tmp_path / "runs" / "suite.txt"
    started = {"PATH": "/usr/bin", "PYTHONPATH": "/mine"}
    assert suite_time.read_output(suite_time.run_suite(out, None, started)).wall == 258.79
    command, options = ran[0]
    assert command[1:] == ["-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "auto", "--dist", "worksteal",
                           "--durations=0", "--durations-min=0"]  # make test's, every duration listed
    assert options["env"] == started and options["cwd"] == suite_time.ROOT
    assert out.read_text() == OUTPUT + "a warning\n"
    suite_time.run_suite(out, tmp_path / "fits.jsonl", started)
    command, options = ran[1]
    assert command[-2:] == ["-p", "suite_fits"] and options["env"]["OODMON_SUITE_FITS"] == str(tmp_path / "fits.jsonl")
    assert options["env"]["PYTHONPATH"] == os.pathsep.join([str(BENCHMARKS), "/mine"])  # the plugin found, the user's path kept
    suite_time.run_suite(out, None, started, tmp_path / "workers.jsonl")
    command, options = ran[2]
    assert command[-2:] == ["-p", "suite_workers"] and "OODMON_SUITE_FITS" not in options["env"]
    assert options["env"]["OODMON_SUITE_WORKERS"] == str(tmp_path / "workers.jsonl")
    assert options["env"]["PYTHONPATH"] == os.pathsep.join([str(BENCHMARKS), "/mine"])
    assert started == {"PATH": "/usr/bin", "PYTHONPATH": "/mine"}  # not changed in place


def test_the_workers_spans_say_how_far_apart_their_last_tests_end_and_what_came_before_the_first(capsys):
    suite_time = _load("suite_time")
    rows = [json.dumps({"worker": worker, "test": f"t{i}", "start": start, "end": end})
            for i, (worker, start, end) in enumerate((("gw0", 1000.0, 1010.0), ("gw1", 1000.5, 1100.0),
                                                      ("gw0", 1010.0, 1090.0), ("gw1", 1100.0, 1101.0)))]
    workers = suite_time.read_workers(rows + [""])
    assert list(workers) == ["gw0", "gw1"]
    assert workers["gw0"] == suite_time.Worker(tests=2, first=1000.0, last=1090.0, busy=90.0)
    assert workers["gw1"] == suite_time.Worker(tests=2, first=1000.5, last=1101.0, busy=100.5)
    suite_time.report(suite_time.read_output(OUTPUT), None, workers=workers)
    printed = capsys.readouterr().out.splitlines()
    assert printed[1].startswith("worker gw0 busy") and "90.0 s  (2 tests, 90.0 s from" in printed[1]
    assert printed[3].startswith("the workers' last tests end apart by") and "11.0 s" in printed[3]
    assert printed[4].startswith("before the first test and after the last") and "157.8 s" in printed[4]  # 258.79 - 101
    assert suite_time.read_workers([]) == {}


def test_the_workers_plugin_records_in_each_worker_and_not_in_the_controller(tmp_path, monkeypatch):
    suite_workers = _load("suite_workers")
    path = tmp_path / "workers.jsonl"
    monkeypatch.setenv("OODMON_SUITE_WORKERS", str(path))

    def configure(dist: str, worker: bool):
        config = SimpleNamespace(option=SimpleNamespace(dist=dist), **({"workerinput": {}} if worker else {}))
        suite_workers.pytest_configure(config)

    cases = (("worksteal", False, "controller"), ("worksteal", True, "worker"), ("no", False, "plain"))
    for dist, worker, test in cases:
        configure(dist, worker)
        if worker:
            monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw3")
        else:
            monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
        suite_workers.pytest_runtest_logstart(test, None)
        suite_workers.pytest_runtest_logfinish(test, None)
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [(row["worker"], row["test"]) for row in rows] == [("gw3", "worker"), ("main", "plain")]
    assert all(row["end"] >= row["start"] > 0 for row in rows)
    monkeypatch.delenv("OODMON_SUITE_WORKERS")
    configure("no", False)
    suite_workers.pytest_runtest_logstart("unasked", None)
    suite_workers.pytest_runtest_logfinish("unasked", None)
    assert len(path.read_text().splitlines()) == 2  # nothing asked: nothing written
