"""The cells: monitored episodes of one variant into one MCAP log, run in worker processes or
as Ray tasks; the pool of worker processes every stage of a local bench runs in, which stops with
it (:func:`stopping_pool`); and the Ray cluster every stage of a bench on Ray runs on (its
trainings, its trials' preparations, its cells: :func:`ray_for`, :func:`on_ray`)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.agents.plain import ON_PYTHONPATH
from oodmon.bench.cache import PlainPolicy, Sb3Models, _bench_agent
from oodmon.bench.config import BenchConfig
from oodmon.envs.shift import own_variant, parse_any_variant
from oodmon.outputs import write_failure
from oodmon.names import TASKS
from oodmon.progress import Progress
from oodmon.errors import ConfigError, OodmonError

_NO_RAY = "--executor ray needs Ray: pip install 'oodmon[ray]'"
EXECUTORS = ("local", "ray")


def episode_onset(onsets: tuple[int, int], seed: int) -> int:
    """The onset of the shifted episode played with ``seed`` under the monitor's protocol: uniform
    in ``[low, high)``, drawn from the seed alone (the same episode, the same onset).

    Example:
        >>> episode_onset((20, 200), 500_000) == episode_onset((20, 200), 500_000)
        True
    """
    return int(np.random.default_rng([seed, 0x0175E7]).integers(*onsets))


def _run_cell(task: str, model: str | Sb3Models | PlainPolicy, threshold: str, spec: str, episodes: int, seed: int, log: str,
              detectors: str | None = None, obs_noise: float = 0.0, onsets: tuple[int, int] | None = None,
              n_samples: int | None = None, masks: str | None = None) -> str:
    """One cell, in a worker process: monitored episodes of one variant into one MCAP log.
    ``onsets``: each shifted episode shifts at a random step in this range (the monitor's protocol);
    ``n_samples``, ``masks``: an MC agent's samples per decision and masks (None: its model's)."""
    from oodmon.monitor import McapSink, Monitor, Threshold
    from oodmon.monitor.detectors import DetectorSet
    from oodmon.threads import set_threads

    set_threads(1)  # one of the workers side by side: torch and numpy's BLAS on one thread each
    agent = _bench_agent(model, task, seed, n_samples, masks)  # seeded MC sampling: the same cell, the same log
    # oodmon's variant, or a shift of your own env (of gymnasium's env of a task, where your own policy acts)
    variant = own_variant(spec, task) if task not in TASKS else parse_any_variant(spec)
    env = agent.wrap(variant.make(obs_noise=obs_noise) if obs_noise else variant.make())  # as the agent observes it
    temporary = Path(log).with_suffix(".part")
    temporary.parent.mkdir(parents=True, exist_ok=True)
    fitted = DetectorSet.load(detectors) if detectors else None
    try:
        with Monitor(agent, Threshold.load(threshold), detectors=fitted, sinks=[McapSink(temporary, overwrite=True)],
                     strict=True) as monitor:
            for episode in range(episodes):
                options = None if onsets is None or variant.is_id else {"onset_step": episode_onset(onsets, seed + episode)}
                monitor.run_episode(env, seed=seed + episode, variant=variant.spec, options=options)
    except OSError as error:  # strict: the log's sink failing ends the cell (a full disk): said naming its log
        temporary.unlink(missing_ok=True)
        raise write_failure(Path(log), error) from None
    env.close()
    os.replace(temporary, log)  # a complete log appears whole, or not at all
    return log


def _execute(jobs: list[tuple], config: BenchConfig, workers: int) -> Iterator[str]:
    """Run the cells; yield each finished cell's log path as it completes."""
    if not jobs:
        return
    if config.executor == "local":
        with stopping_pool(workers) as pool:
            for future in as_completed([pool.submit(_run_cell, *job) for job in jobs]):
                yield future.result()
        return
    yield from on_ray(_run_cell, jobs, config, workers)  # (an unknown executor: refused by run_bench, before any work)


@contextmanager
def stopping_pool(workers: int, progress: Any = None) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` processes whose jobs stop with the bench: on an exception or an
    interrupt here (or the loop over its results left early), the jobs not begun are cancelled and
    the workers killed (and where the bench is SIGKILLed, they die with it). A cell's log is moved
    in whole or not at all, a training's checkpoint is written whole: the same command resumes
    from them. Left to ``with ProcessPoolExecutor``, its shutdown waited for every queued job to
    run: Ctrl-C at the first of a CartPole bench's 102 cells ran 100 of them (11.1 s), and a
    five-trial bench's trainings would have trained on for hours.

    ``progress``: a ``multiprocessing`` queue the workers inherit, on which a job's
    :class:`Relay` ``()`` puts its reports (a queue cannot be sent with a job; a ``Manager``'s
    could, but its server is a process more, which outlived a SIGKILLed bench).

    The workers killed are every one the pool forked, read off its ``_processes`` (no public way
    says them). Until 2026-12-06 they were those that had said their pid as they started: a worker
    still starting (a loaded machine, or Ctrl-C in a bench's first moments) lived on, took the jobs
    already handed to the workers and ran them out, and the bench waited for them at its exit."""
    from oodmon.side_by_side import forking, worker_context

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=worker_context(), initializer=_start_worker,
                               initargs=(os.getpid(), progress))
    try:
        with forking():  # (the pool forks its workers at its first job, in the caller's loop)
            yield pool
    except BaseException:
        forked = list((getattr(pool, "_processes", None) or {}).values())  # (shutdown forgets them)
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in forked:
            worker.kill()
        for worker in forked:
            worker.join(timeout=5)  # gone (or reaped by the pool's own thread) before the bench goes on
        raise
    pool.shutdown(wait=True)


def _start_worker(bench: int, progress: Any = None) -> None:
    """A worker's start: its death bound to the bench's (a SIGKILLed bench, which has no time to
    kill its workers, left them to run their jobs out, orphaned); the bench's progress queue kept
    for its jobs' :class:`Relay` ``()``."""
    from oodmon.side_by_side import die_with

    global _PROGRESS
    die_with(bench)
    _PROGRESS = progress


_PROGRESS: Any = None  # in a worker of a stopping_pool: the queue its progress goes to


@contextmanager
def ray_for(config: BenchConfig, workers: int) -> Iterator[None]:
    """Where the bench runs on Ray (``executor="ray"``): its cluster for every stage inside, joined
    or started once (:func:`_start_ray`; a local one of ``workers`` CPUs) and shut down after if
    started here, the user's own modules sent to it (:func:`sent_modules`). Else nothing."""
    if config.executor != "ray":
        yield
        return
    started = _start_ray(config, workers, sent_modules(config))
    try:
        yield
    finally:
        if started:
            import ray

            ray.shutdown()


def on_ray(function: Callable[..., Any], jobs: list[tuple], config: BenchConfig, workers: int,
           report: Progress | None = None) -> Iterator[Any]:
    """``function(*job)`` for each job as a Ray task of one CPU, on the cluster Ray runs
    (:func:`ray_for`, which starts or joins one here where Ray runs none yet); yield each result as
    it comes. ``report``: each task gets one more argument, an ``on_progress`` whose reports reach
    ``report`` here (through a Ray queue), as a training's in a worker process of the bench's own."""
    with ray_for(config, workers):
        import ray

        queue = None
        if report is not None:
            from ray.util.queue import Queue

            queue = Queue()
            jobs = [(*job, Relay(queue)) for job in jobs]
        remote = ray.remote(num_cpus=1)(function)
        pending = [remote.remote(*job) for job in jobs]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=None if queue is None else 1.0)
            while queue is not None and not queue.empty():
                report(*queue.get())
            for finished in ready:
                try:
                    yield ray.get(finished)
                except ray.exceptions.RayTaskError as error:
                    raise _said_by_a_worker(error, config, sent_modules(config)) from None


class Relay:
    """A task's ``on_progress`` in a worker (a process, a Ray task): puts each report on the
    bench's queue (a Ray one; without one, the queue a :func:`stopping_pool`'s workers inherit),
    for the bench to report."""

    def __init__(self, queue: Any = None) -> None:
        self.queue = queue

    def __call__(self, stage: str, done: int, total: int) -> None:
        (_PROGRESS if self.queue is None else self.queue).put((stage, done, total))


def own_module_paths(config: BenchConfig) -> list[str]:
    """The files or package folders of the user's own modules that the bench's workers import by name (the
    policy's ``MODULE:NAME``, an env id's ``module:``, ``imports``), where they are not installed
    packages (site-packages, the standard library): what Ray sends its workers (``py_modules`` of
    the job, where the bench starts or joins the cluster), so that a cluster at an address, whose
    workers do not have this command's ``PYTHONPATH``, imports them as local processes do."""
    import importlib.util
    import sysconfig

    names = [*config.imports]
    if config.policy:
        names.append(config.policy.split(":")[0])
    if config.env_id and ":" in config.env_id:
        names.append(config.env_id.split(":")[0])
    installed = [Path(sysconfig.get_paths()[key]).resolve() for key in ("purelib", "platlib", "stdlib", "platstdlib")]
    paths: list[str] = []
    for name in dict.fromkeys(name.split(".")[0] for name in names if name):
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            continue  # said where it is imported, as without Ray
        if spec is None or spec.origin in (None, "built-in", "frozen"):
            continue
        where = Path(spec.submodule_search_locations[0] if spec.submodule_search_locations else spec.origin).resolve()
        if not any(where.is_relative_to(folder) for folder in installed) and str(where) not in paths:
            paths.append(str(where))
    return paths


def sent_modules(config: BenchConfig) -> list[str]:
    """What the bench sends a cluster at an address (:func:`own_module_paths`); nothing to a local
    cluster, whose workers have this command's path already (measured: a module on the driver's
    ``sys.path`` alone imports there) and which would only pack and upload the files again."""
    return own_module_paths(config) if config.address else []


def _said_by_a_worker(error: Exception, config: BenchConfig, shipped: list[str]) -> BaseException:
    """A task's error raised in a Ray worker, as the command says it for local processes: an
    error a person can fix by its own message (Ray's wraps it in the worker's traceback), naming
    the cluster where the modules sent to it were not enough."""
    cause = getattr(error, "cause", None)
    if not isinstance(cause, (OodmonError, OSError)):
        return error
    if isinstance(cause, ConfigError) and "No module named" in str(cause):
        where = f"the Ray cluster at {config.address}" if config.address else "a Ray worker"
        sent = (f"oodmon sent it {', '.join(Path(path).name for path in shipped)}; a module of yours that those import"
                if shipped else "a module of yours")
        said = str(cause).replace(ON_PYTHONPATH, "")  # it is, here: not there
        return ConfigError(f"on {where}: {said} ({sent} must be installed on the cluster's machines or found on the "
                           "PYTHONPATH their `ray start` had)")
    return cause


def check_ray_address(config: BenchConfig, timeout: float = 3.0) -> None:
    """Before any work: that the executor is one there is (a `BenchConfig` of the Python API takes
    any string; it was refused only at the cells, after the trainings and preparations), and for
    ``executor="ray"``: that Ray is installed, and that a cluster's
    ``HOST:PORT`` (or ``ray://HOST:PORT``) at ``config.address`` answers at all. Ray's own
    connection retries for as long as the command runs where nothing listens there (measured with
    Ray 2.60: still retrying after 5 minutes, saying only that the GCS was not found); other
    addresses (``auto``) are left to Ray.

    Raises:
        ConfigError: an unknown executor, no Ray, or nothing accepts a connection at that address within ``timeout`` seconds.
    """
    import importlib.util
    import socket

    if config.executor not in EXECUTORS:
        raise ConfigError(f"executor={config.executor!r} is not allowed; use " + " or ".join(map(repr, EXECUTORS)))
    if config.executor != "ray":
        return
    if importlib.util.find_spec("ray") is None:
        raise ConfigError(_NO_RAY)
    if not config.address:
        return
    host, colon, port = config.address.removeprefix("ray://").rpartition(":")
    if not colon or not port.isdigit() or not host:
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as error:
        raise ConfigError(f"--address {config.address}: nothing answers there ({error.strerror or error}); give the "
                          "address `ray start --head` printed on the cluster's head (HOST:PORT), or leave --address out "
                          "to start a local cluster") from None


def _start_ray(config: BenchConfig, workers: int, modules: Sequence[str] = ()) -> bool:
    """Connect to ``config.address``, or start a local Ray cluster whose servers listen on
    ``config.bind`` only (loopback by default; Ray would otherwise listen on every interface);
    ``modules``: files or package folders the job sends its workers (:func:`own_module_paths`).
    True where this call started Ray (and so must shut it down); where Ray runs already (started
    in your own Python), the bench uses it as it is."""
    loopback = config.address is None and config.bind in ("127.0.0.1", "localhost")
    if loopback:
        # Ray turns a loopback node address into the machine's external one unless it runs as a
        # single-machine cluster; this setting (read when ray is imported, and by its workers)
        # keeps every server of the local cluster on 127.0.0.1.
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    try:
        import ray
        import ray._private.ray_constants as ray_constants
    except ImportError:
        raise ConfigError(_NO_RAY) from None
    if ray.is_initialized():
        return False
    from oodmon.monitor.stopping import sigterm_handler_kept

    if loopback:
        ray_constants.ENABLE_RAY_CLUSTER = False  # where ray was imported before the setting
    options = {} if config.address or loopback else {"_node_ip_address": config.bind}
    if modules:
        options["runtime_env"] = {"py_modules": list(modules)}
    before = _children()
    try:
        # "local": a cluster of its own even where one runs already on this machine (`ray start`),
        # which Ray would join otherwise, refusing num_cpus (measured with Ray 2.60).
        with sigterm_handler_kept():  # (Ray's would end the bench without saying what it kept)
            ray.init(address=config.address or "local", num_cpus=None if config.address else workers,
                     include_dashboard=False, logging_level="ERROR", log_to_driver=False, **options)
    except ConnectionError as error:
        if not config.address:
            raise
        # Measured with Ray 2.60: `ray start --head` turns token authentication on, and a driver
        # without RAY_AUTH_MODE=token sends no token: Ray retries for some 20 s and says only this.
        hint = "" if os.environ.get("RAY_AUTH_MODE") else (
            "; a cluster started by `ray start` (Ray 2.59 on) asks for its token: set RAY_AUTH_MODE=token in this "
            "shell (Ray then reads the token from ~/.ray/auth_token, or from RAY_AUTH_TOKEN)")
        raise ConfigError(f"--address {config.address}: {error}{hint}") from None
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM as Ray started: what it started, ended here
        begun = [process for process in _children() if process not in before]
        ray.shutdown()
        _end(begun)
        raise
    return True


def _children() -> list[Any]:
    """This process's descendants (``psutil.Process``), every generation."""
    import psutil

    try:
        return psutil.Process().children(recursive=True)
    except psutil.Error:
        return []


def _end(processes: Sequence[Any], seconds: float = 3.0) -> None:
    """SIGTERM to each of ``processes`` still alive, SIGKILL to those alive ``seconds`` later.

    Where ``ray.init`` is stopped, its ``ray.shutdown()`` may leave Ray's dashboard and runtime-env
    agents, children of its raylet, alive for a minute or so (2026-12-07, Ray 2.60: 6 of 17
    SIGTERMs sent 4.6-6.6 s after a bench's start, as Ray started, left both; none after a stop once
    Ray ran; with this, none of 22): the processes that start began are ended here, none that ran
    before it."""
    import psutil

    for process in processes:
        try:
            process.terminate()
        except psutil.Error:  # gone already (ray.shutdown ended it), or not ours to end
            pass
    _, alive = psutil.wait_procs(processes, timeout=seconds)
    for process in alive:
        try:
            process.kill()
        except psutil.Error:
            pass
