"""Episodes played side by side: runs of consecutive episodes in worker processes.

Calibration and validation play tens to hundreds of ID episodes one after the other, each a chain
of batch-of-one decisions on one core (a Pong game: about a second; ``oodmon validate --episodes
300`` of Pong: 9.5 minutes); evaluation plays some episodes of each of tens of variants. They do
not depend on one another, so ``workers`` processes play a run of them each, forked from this one:
they have the agent, its detectors and the user's own policy as they are here, with nothing
pickled or loaded again (only the episodes' results come back, on a pipe of each worker's own).
Used by ``oodmon.monitor.calibration``, ``oodmon.monitor.detectors.fitting`` (the fitting's
episodes) and ``oodmon.agents.evaluation``.

What an episode draws:

- An agent that draws nothing when it decides (an ensemble, an SB3 model's or a plain policy's
  decision, fixed masks that decide) plays each episode as in one process: the same scores, the
  same threshold, whatever ``workers``.
- An MC agent (Dropout, DropConnect) draws its samples from one stream, which one process runs on
  from episode to episode: episode 7's draws depend on how many steps episodes 0-6 took, which a
  process playing episode 7 first cannot know. Side by side, each episode draws from a stream of
  its own instead, seeded by one number drawn from the agent's stream and the episode's seed
  (:func:`episode_streams`): the scores are the same for any ``workers`` >= 2, and another (as
  valid) sample of ID episodes than one process plays.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing.connection import Connection, wait
from typing import Any

import numpy as np

from oodmon.errors import InvalidParameterError
from oodmon.progress import Progress
from oodmon.validation import is_whole

__all__ = ["WorkerDied", "WorkerTraceback", "episode_streams", "finished_before", "forking", "play_side_by_side",
           "resolve_workers", "runs_of", "stream_per_episode", "usable_cores", "worker_context"]

#: ``play(first, count, done)``: play episodes ``first .. first + count - 1`` (indices from 0),
#: calling ``done()`` after each; return their results in a list, one per episode.
Play = Callable[[int, int, Callable[[], None]], list]


def resolve_workers(workers: int, episodes: int) -> int:
    """How many processes play ``episodes`` episodes: ``workers`` (0: one per core), at most one per
    core (more would only take turns on them, each with its copy of the agent) and one per episode;
    1 where this platform cannot fork (the workers need this process's memory).

    Example:
        >>> resolve_workers(1, 50), resolve_workers(10**9, 1)
        (1, 1)

    Raises:
        InvalidParameterError: ``workers`` is not a whole number >= 0.
    """
    if not is_whole(workers, 0):
        raise InvalidParameterError(f"workers={workers!r} is not allowed; give a whole number >= 1 of processes "
                                    "(0: one per core)")
    if "fork" not in multiprocessing.get_all_start_methods():
        return 1
    cores = usable_cores()
    return max(1, min(workers or cores, cores, episodes))


def finished_before(interrupt: BaseException) -> list:
    """The results of the first episodes played whole before ``interrupt`` (a Ctrl-C or SIGTERM
    out of :func:`play_side_by_side`, or a worker's death there, :class:`WorkerDied`), in the
    episodes' order: episodes 0 .. k - 1, the longest run
    of them from the first whose results had come back (an episode that ended early among later
    ones missing is left out with them, so that the shorter episodes are not the ones counted).
    Side by side, a worker's results come back when its run ends, so ``run_size`` sets what an
    interruption keeps; in one process a ``play`` that keeps its own sets them on the interrupt
    (``interrupt.finished``). ``[]`` where it kept none."""
    return list(getattr(interrupt, "finished", []))


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, which ``taskset`` and container CPU
    sets narrow), where the platform says; else all of the machine's."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0)) or 1
    return os.cpu_count() or 1


def runs_of(episodes: int, workers: int) -> list[tuple[int, int]]:
    """``episodes`` split into ``workers`` runs of consecutive episodes, as ``(first, count)``, the
    longer runs first.

    Example:
        >>> runs_of(7, 3)
        [(0, 3), (3, 2), (5, 2)]
    """
    size, extra = divmod(episodes, workers)
    runs, first = [], 0
    for worker in range(workers):
        count = size + (worker < extra)
        runs.append((first, count))
        first += count
    return [run for run in runs if run[1]]


def episode_streams(sampling_state: dict | None) -> tuple[dict | None, Callable[[int], dict] | None]:
    """An estimator's sampling state one draw on (``None`` where it has none), and the state of the
    stream an episode with seed ``s`` draws from side by side: seeded by that draw and ``s``, so
    that it does not depend on which process plays the episode, nor on the episodes before it.

    Example:
        >>> after, stream = episode_streams(np.random.default_rng(0).bit_generator.state)
        >>> stream(5) == stream(5), stream(5) == stream(6)
        (True, False)
    """
    if sampling_state is None:
        return None, None
    rng = np.random.default_rng()
    rng.bit_generator.state = sampling_state
    base = int(rng.integers(2**63))
    return rng.bit_generator.state, lambda seed: np.random.default_rng([base, seed]).bit_generator.state


def stream_per_episode(sampler: Any, workers: int) -> Callable[[int], None]:
    """``start(key)``, to call in a worker before each episode: sets ``sampler``'s stream (an
    estimator's ``sampling_state``) to the stream of the episode with that key (its seed; a
    variant's index), :func:`episode_streams`, once ``sampler``'s own stream has moved on by the
    one draw that seeds them. Where one process plays (``workers`` 1), or ``sampler`` draws nothing
    (``None``; an ensemble, fixed masks that decide: its ``draws``), a ``start`` that does nothing:
    the draws run on as in one process, and a generator never drawn from is left where it stands.

    Example:
        >>> stream_per_episode(None, 2)(7) is None
        True
    """
    state = getattr(sampler, "sampling_state", None) if workers > 1 and getattr(sampler, "draws", True) else None
    if state is None:
        return lambda key: None
    sampler.sampling_state, stream = episode_streams(state)

    def start(key: int) -> None:
        sampler.sampling_state = stream(key)

    return start


class WorkerDied(BrokenProcessPool):
    """A worker process that died while playing episodes; ``signal``: the name of the signal that
    killed it (``SIGKILL``: out of memory, or killed), ``None`` where it ended itself."""

    def __init__(self, message: str, signal: str | None) -> None:
        super().__init__(message)
        self.signal = signal


class WorkerTraceback(Exception):
    """The traceback of an exception raised in a worker, as its text: the ``__cause__`` of that
    exception where it is raised again in the command."""


def _worker(play: Play, connection: Connection, parent: int, inherited: list[Connection]) -> None:
    """A worker's life: runs of episodes as the command sends them, ``None`` to end. Each
    ``done()`` sends ``("episode",)``, each run's end ``("run", first, results)``, an exception
    ``("error", exception, traceback)``, all on this worker's own pipe."""
    import signal

    from oodmon.threads import set_threads

    die_with(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the group: the command stops its workers
    for other in inherited:  # the command's ends of the pipes of the workers forked before this one
        other.close()
    try:  # every error is the command's to raise (one here died with its traceback, read as a death)
        # One thread each, whatever OODMON_TORCH_THREADS says: the processes share the cores, and a
        # worker forked from a command whose torch ran on more (OODMON_TORCH_THREADS=2) hung in its
        # first parallel region (libgomp's threads are not forked; measured: Pong's DropConnect agent,
        # `validate --workers 2`, stopped after 300 s of 6 games), which one thread never enters.
        set_threads(1)
        while (run := connection.recv()) is not None:
            first, count = run
            results = play(first, count, lambda: connection.send(("episode",)))
            # (pickled before a byte is written: results pickle cannot carry are sent as an error)
            connection.send(("run", first, results))
    except BaseException as error:  # noqa: BLE001
        _send_error(connection, error)


def _send_error(connection: Connection, error: BaseException) -> None:
    """``("error", exception, traceback)`` to the command; an exception pickle cannot carry, as its words."""
    import traceback

    text = traceback.format_exc()
    try:
        connection.send(("error", error, text))
    except Exception:  # noqa: BLE001
        connection.send(("error", RuntimeError(f"{type(error).__name__}: {error}"), text))


def worker_context() -> Any:
    """The ``multiprocessing`` context of oodmon's workers: on Linux, processes forked from this one
    (they have the agent, the user's policy and the progress queues as they are here, and die with
    this process: :func:`die_with`); elsewhere the platform's default. Python 3.14 made Linux's
    default "forkserver", whose workers are the children of a server process: each of the bench's
    died at once, its parent not the bench (``oodmon bench --workers 2`` on 3.11 with that default
    set: "A process in the process pool was terminated abruptly", 2026-12-01)."""
    if sys.platform.startswith("linux"):
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context()


#: What Python 3.12 and newer warn at a fork of a process with threads besides the forking one
#: (``DeprecationWarning``: "This process (pid=N) is multi-threaded, use of fork() may lead to
#: deadlocks in the child."), the start of its message.
FORK_WARNING = r"This process \(pid=\d+\) is multi-threaded, use of fork\(\)"


@contextmanager
def forking() -> Iterator[None]:
    """Around this process's forks of its workers: Python 3.12's warning of a fork beside threads
    left out. The default filters hide it, but pytest and ``python -W default`` show it, and the
    commands print a warning as a line of their own: on 3.12 every ``--workers`` command said it
    (2026-12-01: the suite's one failure there, a worker's death said in more than one line). The
    threads it counts are the libraries' native ones (numpy's BLAS pool starts one at its import on
    two cores; a worker's torch and BLAS run on one thread, never entering a pool: :func:`_worker`)
    and the refresh thread of a command's progress display, which cannot be writing at a fork
    (``oodmon.cli.display`` holds its lock across forks). Other warnings are as they were."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=FORK_WARNING, category=DeprecationWarning)
        yield


def die_with(parent: int) -> None:
    """Linux: this worker is killed when the process that forked it dies, even by SIGKILL, which
    leaves it no time to stop its workers (they would play on for minutes, orphaned; the bench's
    would train on for hours)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # it died before that took hold
        os._exit(1)


def play_side_by_side(play: Play, episodes: int, workers: int, stage: str,
                      on_progress: Progress | None = None, *, total: int | None = None,
                      run_size: int | None = None) -> list:
    """``play`` over ``episodes`` episodes in ``workers`` processes forked from this one (a run of
    consecutive episodes each, :func:`runs_of`); every episode's result in the episodes' order.
    ``on_progress(stage, done, total)`` here at each ``done()`` in any process (``total``: the
    episodes; a play whose items are variants of several episodes each says ``done()`` after each
    of those and gives their number). With one worker, ``play(0, episodes, ...)`` runs here.

    ``run_size``: runs of at most this many episodes instead, each worker taking the next when its
    last ends. A run's results come back here (pickled) when it ends, so a play whose results are
    large sends them a few at a time: the detectors' fitting keeps every frame of every game
    (Pong: about 70 MB a game), which in runs of 45 games would be held here, in the worker and in
    the pipe between at once.

    A worker's exception is raised here (its traceback the ``__cause__``) and the other workers
    are killed at once; so is an interrupt here (Ctrl-C, which the workers ignore), and a worker's
    death (:class:`WorkerDied`, a ``BrokenProcessPool``: killed, out of memory, a crash in an
    env's C code).

    Each worker has a pipe of its own, read here between messages, never by a thread of its own:
    a worker killed while sending a large result (a Pong game's frames) ends its pipe, and the
    half message is read as its death. Through a process pool's one shared pipe, its reading
    thread waited for the rest for ever, and the command with it (seen: ``fit-detectors --workers
    2`` of Pong, SIGINT after 25 s; a play of 100 MB episodes interrupted at the second: 4 of 4
    tries hung)."""
    workers = resolve_workers(workers, episodes)
    done = 0

    def one_more() -> None:
        nonlocal done
        done += 1
        if on_progress is not None:
            on_progress(stage, done, episodes if total is None else total)

    if workers == 1:
        return play(0, episodes, one_more)
    runs = runs_of(episodes, workers) if run_size is None else [
        (first, min(run_size, episodes - first)) for first in range(0, episodes, run_size)]
    context = multiprocessing.get_context("fork")
    waiting, results = list(reversed(runs)), {}
    processes: dict[Connection, Any] = {}
    try:
        for _ in range(min(workers, len(runs))):
            ours, theirs = context.Pipe()
            # (not daemonic: a daemon may not start processes of its own, which a user's env may)
            process = context.Process(target=_worker, args=(play, theirs, os.getpid(), list(processes)))
            with forking():
                process.start()
            theirs.close()  # the worker's end, here no more: when the worker dies, reading ours ends
            processes[ours] = process
            ours.send(waiting.pop())
        playing = set(processes)
        while playing:
            for connection in wait(list(playing)):
                message = _receive(connection, processes[connection])
                if message[0] == "episode":
                    one_more()
                elif message[0] == "run":  # its next run, or its end
                    results[message[1]] = message[2]
                    if waiting:
                        connection.send(waiting.pop())
                    else:
                        connection.send(None)
                        playing.discard(connection)
                else:
                    _, error, text = message
                    raise error from WorkerTraceback(text)
        return [result for first, _ in runs for result in results[first]]
    except BaseException as error:
        _stop(processes.values())
        # Ctrl-C, SIGTERM, a worker's death: the runs that came back whole, from the first on
        if isinstance(error, (KeyboardInterrupt, BrokenProcessPool)):
            error.finished = []
            for first, _ in runs:
                if first not in results:
                    break
                error.finished += results[first]
        raise
    finally:
        for connection, process in processes.items():
            process.join(timeout=5)
            connection.close()


def _receive(connection: Connection, process: Any) -> tuple:
    """The next message of a worker, or :class:`WorkerDied` where it died (its pipe ended, a
    message cut short by its death too)."""
    try:
        return connection.recv()
    except (EOFError, OSError):
        import signal

        process.join(timeout=5)
        code = process.exitcode
        killed_by = signal.Signals(-code).name if code is not None and code < 0 else None
        if killed_by is not None:
            how = f"killed by {killed_by}): out of memory (SIGKILL), killed, or a crash in an env's C code (SIGSEGV)"
        else:  # a Python exception is sent here, not died of: something ended the process itself
            how = f"exit code {code}): an env or policy that ended its process (os._exit, a library's exit)"
        raise WorkerDied(f"a worker process (pid {process.pid}) died while playing episodes ({how}",
                         killed_by) from None


def _stop(workers) -> None:
    for process in workers:
        if process.is_alive():
            process.kill()
