"""The cells: monitored episodes of one variant into one MCAP log, run in worker processes or
as Ray tasks."""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from oodmon.bench.cache import PlainPolicy, Sb3Models, _bench_agent
from oodmon.bench.config import BenchConfig
from oodmon.envs.grid import parse_variant
from oodmon.envs.shift import own_variant
from oodmon.outputs import write_failure
from oodmon.names import TASKS
from oodmon.errors import ConfigError

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
    variant = parse_variant(spec) if task in TASKS else own_variant(spec, task)  # oodmon's, or your own env's
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
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for future in as_completed([pool.submit(_run_cell, *job) for job in jobs]):
                yield future.result()
        return
    if config.executor != "ray":
        raise ConfigError(f"executor={config.executor!r} is not allowed; use 'local' or 'ray'")
    started = _start_ray(config, workers)
    import ray

    try:
        remote = ray.remote(num_cpus=1)(_run_cell)
        pending = [remote.remote(*job) for job in jobs]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        if started:
            ray.shutdown()


def _start_ray(config: BenchConfig, workers: int) -> bool:
    """Connect to ``config.address``, or start a local Ray cluster whose servers listen on
    ``config.bind`` only (loopback by default; Ray would otherwise listen on every interface).
    True where this call started Ray (and so must shut it down)."""
    import os

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
        raise ConfigError("--executor ray needs Ray: pip install 'oodmon[ray]'") from None
    if ray.is_initialized():
        return False
    if loopback:
        ray_constants.ENABLE_RAY_CLUSTER = False  # where ray was imported before the setting
    options = {} if config.address or loopback else {"_node_ip_address": config.bind}
    ray.init(address=config.address, num_cpus=None if config.address else workers, include_dashboard=False,
             logging_level="ERROR", log_to_driver=False, **options)
    return True
