"""Does a long monitored run grow the process? Resident memory over a run, per choice of sinks.

Run (a few minutes; Linux, it reads /proc/self/status):
    .venv/bin/python scripts/monitor_memory.py --sinks none
    .venv/bin/python scripts/monitor_memory.py --sinks mcap
    .venv/bin/python scripts/monitor_memory.py --sinks mcap-split
    .venv/bin/python scripts/monitor_memory.py --sinks rerun
    .venv/bin/python scripts/monitor_memory.py --sinks rerun --rerun-alone
    .venv/bin/python scripts/monitor_memory.py --sinks rerun-no-footer
    .venv/bin/python scripts/monitor_memory.py --sinks rerun --hz 50
    .venv/bin/python scripts/monitor_memory.py --sinks rerun-serve --episodes 20000
    .venv/bin/python scripts/monitor_memory.py --sinks mcap --endless 200000

A monitor runs next to a deployed policy for days, so what it keeps per step must not pile up.
This plays the shipped CartPole ensemble's ID episodes (500 steps each) in a ``MonitoredEnv``
writing to the chosen sinks under ``--out``, prints the resident set size at a few episodes, and
last the growth in bytes per step from episode 50 (everything loaded and warm) to the end.
``--rerun-alone`` instead sends the same number of steps' series (six scalar series in batches of
200, as ``RerunSink`` sends them) through a bare ``rerun.RecordingStream`` to a file: whether a
growth is Rerun's own. It is: the file's footer, whose index of chunks Rerun keeps in memory until
the file ends; ``--sinks rerun-no-footer`` (``RerunSink(footer=False)``) writes none. On 2026-12-07
with ``--episodes 800``: ``rerun`` 35.7 bytes per step (34.8 once the sink sent its steps by the
clock, not at every episode's end), ``rerun-no-footer`` 0.5; later that day ``rerun`` 8.2, the
sink sending every 2,000 steps instead of 200 (it prints the chunks it sent: 4.0 per 1,000 steps,
against 30.0). ``--hz 50`` moves the Rerun sink's clock 1/50 s a step, so that it sends as for a
policy deciding 50 times a second (the text lines of the episodes, which Rerun batches by its own
clock, still come at full speed): with ``--episodes 800``, sending a file alone every 10 s, 0.60
chunks a second and 16.8 bytes a step, 72 MB a day; each second (as for most of 2026-12-07) 6.0
and 121.6, 525 MB a day. ``--sinks rerun-serve`` serves the stream (``RerunSink(serve=True)``), no
viewer connecting: Rerun's server keeps it up to its memory limit (512 MiB of data): with
``--episodes 20000`` the RSS grew 166 bytes a step to step 3.2 million (408 to 939 MB), then 27
to 6.4 million (1,026 MB) and 3 to 10 million (1,038 MB); with ``--serve-memory 32`` (``RerunSink(
serve_memory=32)``) it held at 445 MB after 250,000 steps, with 0 it stayed flat (406 MB).
``--endless STEPS`` plays one episode that never ends (Pendulum without its time limit, the shipped
Pendulum ensemble's four detectors). Until log format 6 the monitor kept such an episode's per-step
rewards, and ``McapSink`` its score arrays, to its end: 32 bytes per step with no sink and 110-121
with ``McapSink`` over 200,000 steps (2026-11-27). Since, they leave memory every
``Monitor(segment_steps=)`` steps (100,000): with ``--sinks mcap --endless 1200000`` the RSS stayed
between 298 and 304 MB from step 120,000 to 1,200,000 (the printed bytes per step, 5.2, is that
wobble over the steps, not a growth).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

STEPS_PER_EPISODE = 500  # CartPole's time limit; the shipped agent keeps the pole up to it
WARM = 50  # episodes before the growth is measured from


def rss_bytes() -> int:
    """The process's resident set size (``VmRSS`` of /proc/self/status)."""
    try:
        status = Path("/proc/self/status").read_text()
    except OSError:
        sys.exit("monitor_memory: needs Linux's /proc/self/status")
    kib = next(line.split()[1] for line in status.splitlines() if line.startswith("VmRSS:"))
    return int(kib) * 1024


def monitored(episodes: int, sinks: str, out: Path, hz: float | None = None,
              serve_memory: int | None = None) -> list[tuple[int, int]]:
    """(steps so far, RSS) at the checkpoints of a monitored run writing to ``sinks``; with ``hz``,
    the Rerun sink's clock (when it sends) moves ``1 / hz`` seconds a step, a policy deciding ``hz``
    times a second, while the run plays at full speed."""
    import types

    import gymnasium

    import oodmon  # noqa: F401  (registers the envs)
    import oodmon.monitor.sinks.rerun as rerun_sink
    from oodmon.agents import load
    from oodmon.monitor import McapSink, Monitor, MonitoredEnv, RerunSink

    clock = [0.0]  # the sink's seconds, with hz
    if hz is not None:
        rerun_sink.time = types.SimpleNamespace(monotonic=lambda: clock[0])

    mcap, rerun = out / "memory.mcap", out / "memory.rrd"  # the measurement's own files, made again each time
    chosen = {"none": lambda: [], "mcap": lambda: [McapSink(mcap, overwrite=True)],
              "rerun": lambda: [RerunSink(rerun, overwrite=True)],
              "rerun-no-footer": lambda: [RerunSink(rerun, overwrite=True, footer=False)],
              "rerun-serve": lambda: [RerunSink(serve=True, port=free_port(), **(
                  {} if serve_memory is None else {"serve_memory": serve_memory}))],
              "mcap-split": lambda: [McapSink(mcap, split_episodes=100, overwrite=True)],
              "all": lambda: [McapSink(mcap, overwrite=True), RerunSink(rerun, overwrite=True)]}[sinks]()
    monitor = Monitor(load("cartpole", "ensemble"), sinks=chosen)
    env = MonitoredEnv(gymnasium.make("oodmon/CartPole-v1"), monitor)
    points, steps = [], 0
    for episode in range(episodes):
        env.reset(seed=episode)
        while True:
            _, _, terminated, truncated, _ = env.step()
            steps += 1
            clock[0] = steps / hz if hz is not None else 0.0
            if terminated or truncated:
                break
        if episode + 1 in checkpoints(episodes):
            points.append((steps, rss_bytes()))
            print(f"episode {episode + 1}: {steps} steps, RSS {points[-1][1] / 1e6:.1f} MB", flush=True)
    monitor.close()
    for sink in chosen:
        if isinstance(sink, RerunSink):  # each chunk an entry of the footer's index, while the file is written
            print(f"RerunSink sent {sink.chunks:,} chunks of steps ({1000 * sink.chunks / steps:.1f} per 1,000 steps"
                  + (f", {sink.chunks / clock[0]:.2f} per second at {hz:g} decisions a second)" if hz else ")"))
    return points


def endless(steps: int, sinks: str, out: Path) -> list[tuple[int, int]]:
    """(steps so far, RSS) at the checkpoints of ONE monitored episode of ``steps`` steps: a policy
    deployed in an env that never ends an episode (Pendulum without its time limit, the shipped
    Pendulum ensemble with its fitted detectors), writing to ``sinks``."""
    import gymnasium

    import oodmon  # noqa: F401  (registers the envs)
    from oodmon.agents import load
    from oodmon.monitor import McapSink, Monitor

    mcap = out / "memory.mcap"  # as above
    chosen = {"none": [], "mcap": [McapSink(mcap, overwrite=True)],
              "mcap-split": [McapSink(mcap, split_episodes=100, overwrite=True)]}[sinks]
    monitor = Monitor(load("pendulum", "ensemble"), sinks=chosen).open()
    env = gymnasium.make("Pendulum-v1", max_episode_steps=None)
    obs, _ = env.reset(seed=0)
    monitor.begin_episode(env_id="Pendulum-v1", variant="pendulum", seed=0)
    marks, points = {steps // 10 * n for n in (1, 2, 4, 8, 10)}, []
    for step in range(1, steps + 1):
        obs, reward, *_ = env.step(monitor.step(obs))
        monitor.add_reward(reward)
        if step in marks:
            points.append((step, rss_bytes()))
            print(f"step {step}: RSS {points[-1][1] / 1e6:.1f} MB", flush=True)
    monitor.end_episode(interrupted=True)
    monitor.close()
    return points


def rerun_alone(episodes: int, out: Path) -> list[tuple[int, int]]:
    """The same number of steps' series sent through a bare Rerun recording stream to a file."""
    import rerun as rr

    rec = rr.RecordingStream("memory")
    rec.set_sinks(rr.FileSink(str(out / "alone.rrd")))
    rng = np.random.default_rng(0)
    batch, points = 200, []
    marks = {n * STEPS_PER_EPISODE: n for n in checkpoints(episodes)}
    for start in range(0, episodes * STEPS_PER_EPISODE, batch):
        steps = np.arange(start, start + batch)
        index = [rr.TimeColumn("step", sequence=steps), rr.TimeColumn("episode", sequence=steps // STEPS_PER_EPISODE),
                 rr.TimeColumn("step_in_episode", sequence=steps % STEPS_PER_EPISODE)]
        for path in ("/a", "/b", "/c", "/d", "/e", "/f"):
            rec.send_columns(path, indexes=index, columns=rr.Scalars.columns(scalars=rng.random(batch)))
        done = start + batch
        if done in marks:
            points.append((done, rss_bytes()))
            print(f"episode {marks[done]}: {done} steps, RSS {points[-1][1] / 1e6:.1f} MB", flush=True)
    rec.flush()
    return points


def free_port() -> int:
    """A port of this machine no program listens on (for ``--sinks rerun-serve``)."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def checkpoints(episodes: int) -> list[int]:
    """Episodes after which the RSS is read: the warm-up's end, a few doublings, the last."""
    marks, n = [WARM], WARM * 2
    while n < episodes:
        marks.append(n)
        n *= 2
    return sorted({*marks, episodes})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sinks", choices=["none", "mcap", "mcap-split", "rerun", "rerun-no-footer", "rerun-serve",
                                            "all"],
                        default="all", help="mcap-split: an MCAP log in files of 100 episodes (McapSink("
                                            "split_episodes=100)); rerun-no-footer: RerunSink(footer=False); "
                                            "rerun-serve: RerunSink(serve=True), no viewer connecting")
    parser.add_argument("--episodes", type=int, default=400, help=f"episodes (more than {WARM}; default 400)")
    parser.add_argument("--rerun-alone", action="store_true", help="a bare Rerun stream instead of the monitor")
    parser.add_argument("--endless", type=int, metavar="STEPS",
                        help="one episode of STEPS steps instead (Pendulum without a time limit; sinks none, mcap or "
                             "mcap-split): what a policy whose env never ends an episode costs")
    parser.add_argument("--out", type=Path, default=None, help="folder for the files written (default: a temporary one)")
    parser.add_argument("--hz", type=float, default=None,
                        help="the Rerun sink's clock moves 1/HZ seconds a step (a policy deciding HZ times a "
                             "second; the run itself plays at full speed): it sends, and so makes chunks, as for "
                             "such a policy")
    parser.add_argument("--serve-memory", type=int, default=None, metavar="MIB",
                        help="with --sinks rerun-serve: RerunSink(serve_memory=MIB), the MiB the server keeps")
    args = parser.parse_args()
    if args.serve_memory is not None and (args.sinks != "rerun-serve" or args.serve_memory < 0):
        parser.error("--serve-memory takes a whole number >= 0 and --sinks rerun-serve")
    if args.hz is not None and not (args.hz > 0 and args.sinks in ("rerun", "rerun-no-footer", "rerun-serve", "all")
                                    and not args.rerun_alone and args.endless is None):
        parser.error("--hz takes a number > 0 and the monitor's Rerun sink (--sinks rerun, rerun-no-footer, "
                     "rerun-serve or all)")
    if args.episodes <= WARM:
        parser.error(f"--episodes must be more than {WARM}")
    if args.endless is not None and (args.endless < 100 or args.sinks not in ("none", "mcap", "mcap-split")):
        parser.error("--endless takes at least 100 steps and --sinks none, mcap or mcap-split")
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        if args.endless is not None:
            points = endless(args.endless, args.sinks, out)
        else:
            points = (rerun_alone(args.episodes, out) if args.rerun_alone
                      else monitored(args.episodes, args.sinks, out, args.hz, args.serve_memory))
    (first_steps, first_rss), (last_steps, last_rss) = points[0], points[-1]
    what = "a bare Rerun stream" if args.rerun_alone else f"sinks {args.sinks}" + (
        ", one endless episode" if args.endless is not None else "")
    per_step = (last_rss - first_rss) / (last_steps - first_steps)
    print(f"{what}: {per_step:.1f} bytes of RSS per step from step {first_steps} to {last_steps}"
          + (f"; at {args.hz:g} decisions a second {per_step * args.hz * 86400 / 1e6:.0f} MB a day" if args.hz else ""))


if __name__ == "__main__":
    main()
