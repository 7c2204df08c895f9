"""The bench on a Ray cluster of its own address: the user's modules sent to it, what it says when
it cannot be reached, a local cluster started beside one that runs already."""

from __future__ import annotations

import functools
import json
import os
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from oodmon.bench import BenchConfig, cells, run_bench
from oodmon.bench.cells import _said_by_a_worker, _start_ray, check_ray_address, own_module_paths, sent_modules
from oodmon.errors import ConfigError

CONTROLLER = "def act(obs):\n    return int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)\n"


def test_the_modules_sent_to_a_cluster_are_the_users_own_not_installed_packages(tmp_path, monkeypatch):
    (tmp_path / "my_policy.py").write_text(CONTROLLER)
    (tmp_path / "my_envs").mkdir()
    (tmp_path / "my_envs" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    config = SimpleNamespace(policy="my_policy:act", env_id="my_envs.sub:Mine-v0", imports=("numpy", "json", "my_policy"))
    assert own_module_paths(config) == [str((tmp_path / "my_policy.py").resolve()), str((tmp_path / "my_envs").resolve())]
    none = SimpleNamespace(policy=None, env_id="CartPole-v1", imports=("no_such_module_here",))
    assert own_module_paths(none) == []  # an unknown module is said where it is imported, as without Ray
    # sent to a cluster at an address only: a local one's workers have this process's path
    assert sent_modules(SimpleNamespace(**vars(config), address="10.0.0.5:6379")) == own_module_paths(config)
    assert sent_modules(SimpleNamespace(**vars(config), address=None)) == []


def test_an_address_where_nothing_answers_is_said_before_any_work():
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]  # bound, not listening: refused
        config = BenchConfig(task="cartpole", executor="ray", address=f"127.0.0.1:{port}")
        with pytest.raises(ConfigError, match=rf"--address 127.0.0.1:{port}: nothing answers there"):
            check_ray_address(config)
        closed.listen()
        check_ray_address(config)  # something listens: left to Ray
    check_ray_address(BenchConfig(task="cartpole", executor="ray", address="auto"))  # Ray finds it
    check_ray_address(BenchConfig(task="cartpole", address=f"127.0.0.1:{port}"))  # not on Ray


def test_no_ray_is_said_before_any_work(tmp_path, monkeypatch):
    import importlib.util

    find = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else find(name, *a))
    config = BenchConfig(task="cartpole", methods=("dropout",), trials=1, executor="ray", out=str(tmp_path))
    with pytest.raises(ConfigError, match=r"--executor ray needs Ray: pip install 'oodmon\[ray\]'"):
        run_bench(config)
    assert not any(tmp_path.iterdir())  # nothing trained, fitted or calibrated first


def test_an_unknown_executor_is_said_before_any_work(tmp_path):
    """`BenchConfig` of the Python API takes any string as its executor: "dask" was refused only at
    the cells, after the trial's training, fitting and calibration."""
    config = BenchConfig(task="cartpole", methods=("dropout",), trials=1, executor="dask", out=str(tmp_path))
    with pytest.raises(ConfigError, match=r"executor='dask' is not allowed; use 'local' or 'ray'"):
        run_bench(config)
    assert not any(tmp_path.iterdir())


def test_a_refused_connection_says_how_to_give_the_clusters_token(monkeypatch):
    ray = pytest.importorskip("ray")

    def refused(**_):
        raise ConnectionError("Failed to connect to Ray cluster at 192.0.2.9:6379")

    monkeypatch.setattr(ray, "init", refused)
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    config = BenchConfig(task="cartpole", executor="ray", address="192.0.2.9:6379")
    with pytest.raises(ConfigError, match=r"--address 192.0.2.9:6379: Failed to connect .*set RAY_AUTH_MODE=token"):
        _start_ray(config, 1)
    monkeypatch.setenv("RAY_AUTH_MODE", "token")  # given already: Ray's own words alone
    with pytest.raises(ConfigError) as said:
        _start_ray(config, 1)
    assert "RAY_AUTH_MODE" not in str(said.value)


def test_a_local_cluster_is_the_benchs_own_even_where_ray_start_left_one_running(monkeypatch):
    """Ray's ``ray.init()`` joins a cluster ``ray start`` left on the machine and then refuses the
    bench's num_cpus (measured with Ray 2.60: "When connecting to an existing cluster, num_cpus and
    num_gpus must not be provided", a traceback): without an address the bench asks for a local one."""
    ray = pytest.importorskip("ray")
    asked = []
    monkeypatch.setattr(ray, "init", lambda **options: asked.append(options))
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    import ray._private.ray_constants as constants

    # (what a local start sets, restored after the test)
    monkeypatch.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", os.environ.get("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "1"))
    monkeypatch.setattr(constants, "ENABLE_RAY_CLUSTER", constants.ENABLE_RAY_CLUSTER)
    assert _start_ray(BenchConfig(task="cartpole", executor="ray"), 2, ["/home/me/ctl.py"])
    assert asked[0]["address"] == "local" and asked[0]["num_cpus"] == 2
    assert asked[0]["runtime_env"] == {"py_modules": ["/home/me/ctl.py"]}
    assert _start_ray(BenchConfig(task="cartpole", executor="ray", address="10.0.0.5:6379"), 2)
    assert asked[1]["address"] == "10.0.0.5:6379" and asked[1]["num_cpus"] is None and "runtime_env" not in asked[1]


def test_a_start_of_ray_cut_by_a_stop_ends_the_processes_it_began_and_no_other(monkeypatch):
    """Ctrl-C or SIGTERM inside ``ray.init``: its ``ray.shutdown()`` left Ray's dashboard and
    runtime-env agents (children of its raylet) alive for a minute or so after the bench ended
    (2026-12-07, Ray 2.60: a scan of SIGTERMs across Ray's start, ``scripts/ray_start_stops.py``).
    Here ``ray.init`` begins a process that ignores SIGTERM and a child of that one, then is
    stopped; the stand-in shutdown ends neither. A process begun before Ray's start stays."""
    ray = pytest.importorskip("ray")
    import psutil
    import ray._private.ray_constants as constants

    monkeypatch.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", os.environ.get("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "1"))
    monkeypatch.setattr(constants, "ENABLE_RAY_CLUSTER", constants.ENABLE_RAY_CLUSTER)
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "shutdown", lambda: None)
    sleep = [sys.executable, "-c", "import time; time.sleep(60)"]
    earlier = subprocess.Popen(sleep)
    begun = []

    def cut(**_):
        agent = ("import signal, subprocess, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
                 f"print(subprocess.Popen({sleep!r}).pid, flush=True); time.sleep(60)")
        begun.append(subprocess.Popen([sys.executable, "-c", agent], stdout=subprocess.PIPE, text=True))
        begun.append(psutil.Process(int(begun[0].stdout.readline())))  # its child, begun
        raise KeyboardInterrupt

    monkeypatch.setattr(ray, "init", cut)
    monkeypatch.setattr(cells, "_end", functools.partial(cells._end, seconds=0.5))  # (3 s in the bench)
    try:
        with pytest.raises(KeyboardInterrupt):
            _start_ray(BenchConfig(task="cartpole", executor="ray"), 2)
        assert begun[0].wait(timeout=10) == -9  # SIGTERM ignored: killed 0.5 s later
        # its child (SIGTERM ignored too, inherited) killed with it; gone once reaped, a moment later
        assert psutil.wait_procs([begun[1]], timeout=10)[1] == []
        assert earlier.poll() is None
    finally:
        for process in (earlier, *begun):
            try:
                process.kill()
            except psutil.Error:
                pass
        earlier.wait()


def test_a_workers_error_is_said_in_one_line_naming_the_cluster_where_a_module_was_missing():
    config = BenchConfig(task="cartpole", executor="ray", address="10.0.0.5:6379")
    missing = ConfigError("--policy ctl:act: No module named 'helpers' (is its folder on PYTHONPATH?)")
    said = _said_by_a_worker(SimpleNamespace(cause=missing), config, ["/home/me/ctl.py"])
    assert str(said) == ("on the Ray cluster at 10.0.0.5:6379: --policy ctl:act: No module named 'helpers' (oodmon sent "
                         "it ctl.py; a module of yours that those import must be installed on the cluster's machines or "
                         "found on the PYTHONPATH their `ray start` had)")
    local = _said_by_a_worker(SimpleNamespace(cause=missing), BenchConfig(task="cartpole", executor="ray"), [])
    assert str(local).startswith("on a Ray worker: --policy ctl:act: No module named 'helpers' (a module of yours must")
    full = OSError(28, "No space left on device")
    assert _said_by_a_worker(SimpleNamespace(cause=full), config, []) is full  # as local processes say it
    bug = SimpleNamespace(cause=ValueError("a bug"))
    assert _said_by_a_worker(bug, config, []) is bug  # not one a person can fix: Ray's traceback stays


HEAD = """
import sys
import ray
ray.init(address="local", num_cpus=1, include_dashboard=False, logging_level="ERROR")
print(ray.get_runtime_context().gcs_address, flush=True)
sys.stdin.read()
from ray._private.state import jobs
print(len(jobs()) - 1, flush=True)  # the drivers that joined it (this one's job is one)
ray.shutdown()
"""

BENCH = """
import sys
from oodmon.cli import main
argv = ["bench", "--policy", "far_controller:act", "--env", "CartPole-v1", "--protocol", "monitor",
        "--variants", "cartpole:obs.stuck[3]=1", "--all-variants", "--detectors", "stillness",
        "--alarm-detector", "stillness", "--episodes", "3", "--id-episodes", "4", "--calibration-episodes", "19",
        "--confidence", "none", "--fit-episodes", "12", "--workers", "1"]  # (stillness: no network to fit)
address, out = sys.argv[1:]
for name, flags in (("ray", ["--executor", "ray", "--address", address]), ("processes", [])):
    if main(argv + flags + ["--out", f"{out}/{name}", "--results", f"{out}/{name}.json"]) != 0:
        sys.exit(f"the bench on {name} failed")
"""


@pytest.mark.slow
def test_a_cluster_at_an_address_gets_the_policys_module_and_gives_the_local_processes_alarms(tmp_path):
    """A cluster of another process, as `ray start` leaves one (token authentication on, as Ray 2.59
    on turns it on there), whose workers cannot import the policy's module: the bench at its
    ``--address`` sends it the module and gets the local processes' alarms (before: "No module
    named 'far_controller'" in Ray's traceback). Ray runs in subprocesses only: this test
    process's Ray keeps its settings."""
    pytest.importorskip("ray")
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "far_controller.py").write_text(CONTROLLER)
    token = os.urandom(16).hex()
    base = {k: v for k, v in os.environ.items() if not k.startswith("RAY_") and k != "PYTHONPATH"}
    ray_env = dict(base, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token, OODMON_TORCH_THREADS="1")
    head = subprocess.Popen([sys.executable, "-c", HEAD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=ray_env, cwd=tmp_path)
    try:
        address = head.stdout.readline().strip()
        assert address, "the cluster did not start"
        repo = str(Path(__file__).resolve().parents[1])
        env = dict(ray_env, PYTHONPATH=os.pathsep.join([str(tmp_path / "mods"), repo]))
        done = subprocess.run([sys.executable, "-c", BENCH, address, str(tmp_path)], env=env, cwd=tmp_path,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
    finally:
        head.stdin.close()
        joined = head.stdout.read().strip()
        head.wait(timeout=60)
    assert joined == "1"  # the Ray bench ran there, not on a cluster of its own
    on_ray, local = (json.loads((tmp_path / f"{name}.json").read_text())["alarms"] for name in ("ray", "processes"))
    assert on_ray == local
    shifted = next(row for row in on_ray if row["variant"] == "cartpole:obs.stuck[3]=1.0")
    assert shifted["episodes"] == 3 and shifted["alarmed"] == 3  # the stuck reading stands still past its record


def test_the_command_reads_ray_address_where_no_address_is_given(tmp_path, monkeypatch):
    """Ray's own variable, as ``ray.init()`` reads it (but never a cluster found by `ray start`'s
    files): the bench's config gets it, for Ray only."""
    import oodmon.bench

    seen = []

    def stop(config, **_):
        seen.append(config.address)
        raise ConfigError("stopped here")

    monkeypatch.setattr(oodmon.bench, "run_bench", stop)  # (the command imports it when it runs)
    monkeypatch.setenv("RAY_ADDRESS", "10.0.0.5:6379")
    monkeypatch.chdir(tmp_path)  # the command makes its default --out, runs/bench, before the bench: not in the repository
    (tmp_path / "ray_address_policy.py").write_text(CONTROLLER)
    monkeypatch.syspath_prepend(str(tmp_path))
    argv = ["bench", "--policy", "ray_address_policy:act", "--env", "CartPole-v1", "--protocol", "monitor"]
    from oodmon.cli import main

    for flags in (["--executor", "ray"], ["--executor", "ray", "--address", "10.0.0.6:6379"], []):
        assert main(argv + flags) == 2
    assert seen == ["10.0.0.5:6379", "10.0.0.6:6379", None]

