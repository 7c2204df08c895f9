"""Log a monitored run to Rerun: an ``.rrd`` file, a spawned viewer, a served stream, or a URL.

Timeline ``step`` counts the run's steps. Entities: ``/score`` (the alarm's) and ``/threshold``;
under a rule that compares something else with the threshold (the mean over the last w steps, a
CUSUM or martingale statistic), ``/compared``, that value;
``/detectors/<name>`` (every detector's score);
``/uncertainty/<action>`` with the samples' mean and the band mean - std .. mean + std;
``/observation`` (vector tasks; a discrete observation as each reading's value, not the one-hot
vector the steps hold: Taxi's one series of its 500 states instead of 500) or ``/frame`` (Pong:
the 84x84 frame the agent saw), and over it ``/frame/alarm_region``, a box where an alarm said in
the picture its events fell (``AlarmEvent.region``: the vanishing detector's), from the alarm to
the episode's end;
``/shifted`` (1 while the shift is active); ``/alarms`` (warnings); ``/episode/return``.
A default blueprint lays these out, so opening the file shows a useful layout.

Per-step values are buffered and sent as columns every :data:`FLUSH_EVERY` steps, or sooner once
:data:`FLUSH_SECONDS` have passed since the last (:data:`FILE_FLUSH_SECONDS` to the file, which
has a buffer of its own beside a viewer's), and at an episode's end once :data:`END_FLUSH_SECONDS`
have: a ``log`` call per value costs 25-40 us, a column of thousands about 10 ms. (Until
2026-12-07 at every episode's end, and never by the clock: a live viewer of a policy deciding 10
times a second saw its steps up to 20 s late, and runs of short episodes sent a chunk per series
per episode, each an entry of the footer's index below: 10 series of a 20-step episode, a chunk
every 2 steps.)

The file's footer (Rerun's manifest of its chunks, which lets a reader reach any part of the file
without reading it all) is written when the run ends, and until then Rerun's file sink keeps an
entry per chunk in memory: 0.6-1.3 KB each (rerun-sdk 0.41), and the sink sends a chunk per series
at every send: 8 bytes a step in CartPole's ID episodes played at full speed (35 when it sent every
200 steps; ``scripts/monitor_memory.py``); a policy deciding 50 times a second, sending to the
file every :data:`FILE_FLUSH_SECONDS`, 72 MB a day (``--hz 50``). A long run writes the file
without it (``footer=False``): its memory stays flat, and the file reads as a killed run's does
(``rerun rrd optimize`` writes it again with a footer).
"""

from __future__ import annotations

import os
import sys
import time
import uuid
import warnings
from pathlib import Path

import numpy as np

from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.alarms import AlarmEvent, compared_name
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord
from oodmon.monitor.sinks.base import SinkWarning, check_existing, claim_file
from oodmon.validation import is_whole

__all__ = ["END_FLUSH_SECONDS", "FILE_CHECK_SECONDS", "FILE_FLUSH_SECONDS", "FLUSH_EVERY", "FLUSH_SECONDS",
           "FOOTER_WARN_CHUNKS", "SERVE_MEMORY_MIB", "FooterMemoryWarning", "RerunSink", "default_blueprint",
           "viewer_command"]

#: Steps buffered at most before the sink sends them, a column (a chunk) per series. Each chunk is an
#: entry of the footer's index in memory: at 200, the value until 2026-12-07, a run at full speed grew
#: 35 bytes a step, at 2,000 7-11 (``scripts/monitor_memory.py --sinks rerun``; a fast run's sends
#: then come by the clock below, at its episodes' ends), and it ran no slower.
FLUSH_EVERY = 2000

#: ... and at least this often (seconds), checked at each step, while a viewer takes them as they
#: come (``spawn``, ``connect``, ``serve``): what a live viewer lags at most behind a slow policy.
FLUSH_SECONDS = 1.0

#: ... and at least this often (seconds) to the file, as ``McapSink(flush_seconds=)``: about what
#: a killed run's file lacks of its last steps. Each send is a chunk per series, an entry each of the
#: footer's index in memory: sent each second (from 2026-12-07 until this period later that day), a
#: policy deciding 50 times a second grew the process 525 MB a day, at 10 s 72
#: (``scripts/monitor_memory.py --sinks rerun --episodes 800 --hz 50``: 6.0 chunks a second, 0.6).
FILE_FLUSH_SECONDS = 10.0

#: An episode's end sends the buffer when this many seconds have passed since the last send: a slow
#: policy's episode is whole in the viewer as it ends (whatever the pause before the next), while
#: short episodes played fast share their columns.
END_FLUSH_SECONDS = 0.1

#: How often (seconds) the sink looks whether the file grows as it sends steps: Rerun writes it from
#: a thread of its own, and a writer that failed (a full disk) showed only when the run ended.
FILE_CHECK_SECONDS = 10.0

#: MiB of a served stream (``serve``) that Rerun's server keeps for viewers that connect later, by
#: default (``RerunSink(serve_memory=)``, ``oodmon run --serve-memory``).
SERVE_MEMORY_MIB = 512

#: Chunks sent to a file with a footer after which the sink warns, once, of the memory its index
#: holds (60-130 MB at 0.6-1.3 KB a chunk): some 50,000 CartPole episodes of 500 steps played at
#: full speed (4 chunks per 1,000 steps); a slow policy's 7 series, sent to the file every 10 s,
#: some 40 hours.
FOOTER_WARN_CHUNKS = 100_000


class FooterMemoryWarning(UserWarning):
    """A Rerun file's footer index has grown large in memory: a long run should write none."""


#: The bytes a Rerun recording (.rrd) begins with (then the version of its encoding: RRF2 in rerun-sdk 0.41).
RRD_MAGIC = b"RRF"


def default_blueprint(task: str, n_outputs: int):
    """The layout a run opens with: score against threshold, per-action bands, what the agent
    saw beside the alarms, the episode returns."""
    import rerun.blueprint as rrb

    seen = rrb.Spatial2DView(origin="/frame", name="agent's view") if task == "pong" else rrb.TimeSeriesView(
        origin="/observation", name="observation")
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.TimeSeriesView(origin="/", contents=["/score", "/compared", "/threshold", "/shifted"],
                               name="alarm's score and threshold"),
            rrb.TimeSeriesView(origin="/uncertainty", name="samples: mean and mean ± std per action"),
            rrb.TimeSeriesView(origin="/detectors", name="every detector's score"),
            rrb.Horizontal(seen, rrb.TextLogView(origin="/alarms", name="alarms")),
            rrb.TimeSeriesView(origin="/episode", name="episode return"),
            row_shares=[3, 3, 2, 2, 1],
        ),
        collapse_panels=True,
    )


class _Outbox:
    """Steps not yet sent to some of the sink's recording streams: the file's (sent every
    :data:`FILE_FLUSH_SECONDS`), or those a viewer reads as they come (every :data:`FLUSH_SECONDS`).
    Until later on 2026-12-07 one buffer went to every stream, and a file beside a viewer was sent
    each second: at 50 decisions a second, 525 MB a day of the footer's index against 72."""

    __slots__ = ("streams", "file", "records", "steps", "sent_at")

    def __init__(self, streams: list, file: bool) -> None:
        self.streams, self.file = streams, file
        self.records: list[StepRecord] = []
        self.steps: list[int] = []  # the run's global step of each record
        self.sent_at = time.monotonic()

    def due(self, now: float) -> bool:
        return len(self.records) >= FLUSH_EVERY or now - self.sent_at >= (
            FILE_FLUSH_SECONDS if self.file else FLUSH_SECONDS)


class RerunSink:
    """Streams the run to Rerun.

    Args:
        path: write an ``.rrd`` file here.
        spawn: start a Rerun viewer listening on ``bind``:``port`` and stream to it (needs a display and
            the ``rerun`` binary; a viewer already listening there takes the stream instead).
        serve: serve the stream over gRPC for a viewer to connect to, on ``bind``:``port``; the
            server keeps up to ``serve_memory`` MiB of it for viewers that connect later (at the
            default 512, some 630 MB of the process, reached after 3-5 million CartPole steps;
            docs/monitor.md, "Memory over a long run"), the earliest dropped beyond.
        connect: stream to a viewer listening at this URL.
        bind: the address a served stream, or a spawned viewer, listens on; ``127.0.0.1`` (the
            default) keeps it on this machine, ``0.0.0.0`` opens it to the network on purpose.
        port: the port a served stream, or a spawned viewer, listens on (default 9876, Rerun's).
        recording_id: Rerun's recording id (default: a fresh one).
        flush_timeout: seconds to wait at an episode end for the data to reach its sinks.
        connect_timeout: seconds to wait for a viewer at ``connect`` to accept a connection.
        overwrite: replace a file already at ``path``; without it that file (the log of an earlier
            run) is refused with :class:`~oodmon.errors.ConfigError` when the sink is made. A file
            there that is no Rerun recording is refused either way.
        serve_memory: MiB of the served stream its server keeps for viewers that connect later
            (Rerun's ``server_memory_limit``; default :data:`SERVE_MEMORY_MIB`); 0 keeps none: a
            viewer then sees the steps from when it connects.
        footer: end the file with Rerun's footer (the default), whose index of chunks Rerun keeps
            in memory until the run ends (see above; a :class:`FooterMemoryWarning` once past
            :data:`FOOTER_WARN_CHUNKS` chunks); ``False`` for a long run: no footer, memory flat.

    A live viewer (``connect``, ``spawn``) has a recording stream of its own, apart from the file's:
    a viewer that cannot be reached at open, or stops taking data (a flush that times out, checked
    at each send of the buffer and each episode end), is dropped with one warning, and what would
    have gone to it is counted in :attr:`dropped` instead of queueing in memory; the file goes on.
    So a dead URL costs a run about ``connect_timeout`` and no memory.
    """

    def __init__(self, path: str | Path | None = None, *, spawn: bool = False, serve: bool = False,
                 connect: str | None = None, bind: str = "127.0.0.1", port: int = 9876,
                 recording_id: str | None = None, flush_timeout: float = 2.0, connect_timeout: float = 0.5,
                 overwrite: bool = False, footer: bool = True, serve_memory: int = SERVE_MEMORY_MIB) -> None:
        if not isinstance(footer, bool):
            raise InvalidParameterError(f"footer={footer!r} is not allowed; give True (Rerun's footer, the default) "
                                        "or False (none: a long run's memory stays flat)")
        if not is_whole(serve_memory, 0):
            raise InvalidParameterError(f"serve_memory={serve_memory!r} is not allowed; give the MiB a served stream "
                                        "keeps for viewers that connect later, a whole number >= 0 (0: none)")
        self.serve_memory = int(serve_memory)
        self.path = Path(path) if path is not None else None
        self.overwrite, self.footer = overwrite, footer
        self._check_existing()
        self.spawn, self.serve, self.connect = spawn, serve, connect
        self.bind, self.port = bind, port
        if serve and (taken := _cannot_listen(bind, port)) is not None:
            # Rerun's server fails on its own thread with a log line only, and the run went on serving
            # nothing (measured: the port of another listener; "serving the Rerun stream at ..." said).
            raise ConfigError(f"cannot serve the Rerun stream on {bind}:{port} ({taken}): another oodmon run or a "
                              "Rerun viewer listening there? Choose another port (--port, RerunSink(port=...))")
        self.recording_id = recording_id or str(uuid.uuid4())
        self.flush_timeout = flush_timeout
        self.connect_timeout = connect_timeout
        self.dropped = 0  # steps not sent to a live viewer that was gone
        self.served_at: str | None = None  # the URL a viewer connects to (``serve``)
        self.viewer = None  # the viewer process ``spawn`` started (subprocess.Popen), left running after the run
        self.live_at: str | None = None  # the URL of the viewer streamed to (``spawn``, ``connect``), once reached
        self._streams: list = []
        self._live = None
        self._global_step = 0
        self._outboxes: list[_Outbox] = []  # the file's, and the live streams' (a served one, a viewer's)
        self._last = (0, 0)  # (episode, step in it) of the last step written
        self._states: list[int] = []  # a discrete observation's values per reading (see open())
        self.chunks = 0  # columns sent, a chunk each (the footer's index holds these and the logs' few)
        self._file_chunks = 0  # of which to the file
        self._watch: tuple[float, int, int] | None = None  # the file: (looked at, its size, chunks sent then)
        self._stalled = False  # the last look found sends that had not reached the file
        self._boxed = False  # an alarm's region is drawn over the frame (cleared at the episode's end)

    def existing_paths(self) -> list[Path]:
        """The file an earlier run left at ``path``, if any (the live streams leave none)."""
        return [self.path] if self.path is not None and self.path.exists() else []

    def _check_existing(self) -> None:
        check_existing(self.existing_paths(), magic=RRD_MAGIC, kind="a Rerun recording (.rrd)",
                       overwrite=self.overwrite, remedy="RerunSink(..., overwrite=True)")

    def open(self, run: RunInfo) -> None:
        import rerun as rr

        self._check_existing()  # checked again: a file may have come since (this sink's own, opened again)

        self._rr = rr
        self._task = run.task
        # A rule with a window compares the mean of its last w scores, a sequential rule its
        # statistic (the tracker's, each record's compared), where the raw score alone crossed the
        # threshold again and again without an alarm (Pong's features, 2026-12-07)
        self._compared = compared_name(run.rule)
        # A discrete observation's values per reading (the monitor's about.states), whose one-hot
        # blocks /observation draws as each reading's value
        self._states = [int(n) for n in run.about.get("states", "").split(",") if n.strip().isdigit()]
        self._names_sent = False
        self._outboxes, live = [], []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.overwrite:
                self.path.unlink(missing_ok=True)
            claim_file(self.path).close()  # the name is this run's (Rerun's file sink writes it from the start)
            self._watch, self._stalled = (time.monotonic(), 0, self._file_chunks), False
            self._streams.append(self._stream(run, [rr.FileSink(str(self.path), write_footer=self.footer)]))
            self._outboxes.append(_Outbox([self._streams[-1]], file=True))
        if self.serve:
            server = rr.GrpcServerSink(bind_ip=self.bind, port=self.port,
                                       server_memory_limit=f"{self.serve_memory}MiB")
            self.served_at = server.uri
            self._streams.append(self._stream(run, [server]))
            live.append(self._streams[-1])
        if self.connect or self.spawn:
            url = self.connect or f"rerun+http://{_reach(self.bind)}:{self.port}/proxy"
            # a spawned viewer is waited for until it takes connections; a URL given is tried once
            unreachable = self._spawn_viewer(url) if self.spawn else _unreachable(url, self.connect_timeout)
            if unreachable is None:
                self._live = self._stream(run, [rr.GrpcSink(url)])
                self.live_at = url
                self._streams.append(self._live)
                live.append(self._live)
            else:
                _warn(f"no Rerun viewer at {url} ({unreachable}); the run goes on without it"
                      + (f", logging to {self.path}" if self.path else ""))
        if live:
            self._outboxes.append(_Outbox(live, file=False))

    def _spawn_viewer(self, url: str) -> str | None:
        """Start a Rerun viewer (``spawn``) listening on ``bind``:``port`` and wait until it takes
        connections at ``url``: ``None``, or why it did not (the run then goes on without it).

        The viewer is the one installed beside this Python (the ``rerun-sdk`` package's, in a
        virtual environment that is not activated and so not on ``PATH``), else the one on ``PATH``,
        started as ``rerun.spawn`` starts it (:func:`viewer_command`) but with ``--bind``: Rerun's
        viewer listens on every interface (0.0.0.0) unless told, so ``spawn`` served the run's stream
        to the network (measured with rerun-sdk 0.41: "Listening for gRPC connections on
        0.0.0.0:9876"). A viewer already listening at ``url`` takes the stream instead, as with
        ``rerun.spawn``."""
        import shutil
        import subprocess
        import tempfile

        if _unreachable(url, 0.2) is None:
            return None
        beside = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        executable = str(beside) if beside.is_file() else shutil.which("rerun")
        if executable is None:
            return "no viewer started: no `rerun` executable beside this Python or on PATH (the rerun-sdk package has one)"
        said = tempfile.TemporaryFile()  # what the viewer prints, read if it stops before it listens
        try:
            viewer = subprocess.Popen(viewer_command(executable, self.bind, self.port), stdin=subprocess.DEVNULL,
                                      stdout=said, stderr=subprocess.STDOUT, start_new_session=True,
                                      env={**os.environ, "RERUN_APP_ONLY": "true"})  # as rerun.spawn sets it
        except OSError as error:
            said.close()
            return f"no viewer started: {error.strerror or error}"
        self.viewer = viewer
        deadline = time.monotonic() + self.connect_timeout * 10
        while _unreachable(url, 0.2) is not None:
            if viewer.poll() is not None or time.monotonic() > deadline:
                said.seek(0)
                lines = [line for line in said.read().decode(errors="replace").splitlines() if line.strip()]
                said.close()
                last = _plain(lines[-1]) if lines else "it said nothing"
                if viewer.poll() is None:
                    return f"the viewer started did not listen within {self.connect_timeout * 10:g} s (its last line: {last})"
                return f"the viewer started stopped with exit code {viewer.returncode}: {last}"
            time.sleep(0.05)
        said.close()  # the viewer keeps its own handle; it is left running after the run, as rerun.spawn leaves it
        return None

    def _stream(self, run: RunInfo, sinks: list):
        rr = self._rr
        rec = rr.RecordingStream("oodmon", recording_id=self.recording_id)
        rec.set_sinks(*sinks)
        rec.send_recording_name(f"oodmon {run.task}/{run.method}")
        about = "".join(f"\n{key}: {value}" for key, value in run.about.items())
        versions = ", ".join(f"{name} {value}" for name, value in run.versions.items())
        rec.log("/run", rr.TextDocument(
            f"task {run.task}, method {run.method}, score {run.score}, alarm rule: {run.rule}, "
            f"threshold {run.threshold}, policy {run.policy_hash}\nversions: {versions}{about}"), static=True)
        return rec

    def _each(self, method: str, *args, **kwargs) -> None:
        for rec in self._streams:
            getattr(rec, method)(*args, **kwargs)

    def _send(self, box: _Outbox, entity: str, index: list, scalars) -> None:
        """One series' buffered values, a column (a chunk) to each of ``box``'s streams; counted in
        :attr:`chunks`, with one :class:`FooterMemoryWarning` at :data:`FOOTER_WARN_CHUNKS` to a file
        with a footer."""
        columns = self._rr.Scalars.columns(scalars=scalars)
        for rec in box.streams:
            rec.send_columns(entity, indexes=index, columns=columns)
        self.chunks += 1
        if not box.file:
            return
        self._file_chunks += 1
        if self._file_chunks == FOOTER_WARN_CHUNKS and self.footer:
            warnings.warn(f"{self.path}: Rerun keeps an index entry of each chunk of the file in memory to write its "
                          f"footer when the run ends: {self._file_chunks:,} chunks so far (0.6-1.3 KB each, measured "
                          "with rerun-sdk 0.41), and more as the run goes on. For a long run write the file without a "
                          "footer (oodmon run --rrd-no-footer; RerunSink(..., footer=False)): its memory stays flat",
                          FooterMemoryWarning, stacklevel=2)

    def _drop_live(self, why: str) -> None:
        self._streams.remove(self._live)
        for box in self._outboxes:
            if self._live in box.streams:
                box.streams.remove(self._live)
        self._outboxes = [box for box in self._outboxes if box.streams]  # (a served stream stays)
        try:
            self._live.disconnect()
        finally:
            self._live = None
            _warn(f"the Rerun viewer stopped taking data ({why}); it is dropped, the run goes on"
                  + (f", logging to {self.path}" if self.path else ""))

    def write_step(self, record: StepRecord) -> None:
        if (self.connect or self.spawn) and self._live is None:
            self.dropped += 1
        if not self._streams:
            self._global_step += 1
            return
        if not self._names_sent:
            self._send_layout(len(record.mean))
        for box in self._outboxes:
            box.records.append(record)
            box.steps.append(self._global_step)
        self._last = (record.episode, record.step)
        if record.frame is not None:
            self._set_time(self._global_step)
            self._each("log", "/frame", self._rr.Image(record.frame))
        self._global_step += 1
        now = time.monotonic()
        for box in self._outboxes:
            if not box.due(now):
                continue
            self._flush(box)
            if box.file:
                self._check_file()
            else:
                self._check_live()

    def _set_time(self, step: int, episode: int | None = None, in_episode: int | None = None) -> None:
        """Set the three timelines (episode and step in it default to the last step written's)."""
        last_episode, last_step = self._last
        self._each("set_time", "step", sequence=step)
        self._each("set_time", "episode", sequence=last_episode if episode is None else episode)
        self._each("set_time", "step_in_episode", sequence=last_step if in_episode is None else in_episode)

    def _check_live(self) -> None:
        """Drop a live viewer that does not take the data within ``flush_timeout``: its stream would
        otherwise queue everything in memory."""
        if self._live is None:
            return
        try:
            self._live.flush(timeout_sec=self.flush_timeout)
        except RuntimeError as error:
            self._drop_live(str(error).splitlines()[0][:120])

    def _send_layout(self, n_outputs: int) -> None:
        for rec in self._streams:
            self._send_layout_to(rec, n_outputs)
        self._names_sent = True

    def _send_layout_to(self, rec, n_outputs: int) -> None:
        rr = self._rr
        label = "Q" if self._task in ("cartpole", "pong") else "action"
        for a in range(n_outputs):
            rec.log(f"/uncertainty/{label}{a}", rr.SeriesLines(names=["mean", "mean - std", "mean + std"],
                                                            colors=[[31, 119, 180], [160, 190, 230], [160, 190, 230]]),
                    static=True)
        rec.log("/score", rr.SeriesLines(names=["score"], colors=[[214, 39, 40]]), static=True)
        if self._compared is not None:
            rec.log("/compared", rr.SeriesLines(names=[f"{self._compared} (what the alarm compares)"],
                                                colors=[[120, 0, 0]], widths=[2.0]), static=True)
        rec.log("/threshold", rr.SeriesLines(names=["threshold"], colors=[[60, 60, 60]]), static=True)
        rec.log("/shifted", rr.SeriesLines(names=["shift active"], colors=[[255, 160, 0]]), static=True)
        rec.send_blueprint(default_blueprint(self._task, n_outputs))
        self._label = label

    def _flush(self, box: _Outbox) -> None:
        """``box``'s buffered steps, a column per series to each of its streams."""
        records = box.records
        if not records:
            return
        rr = self._rr
        # Three timelines: the run's global step, the episode, the step within the episode (an alarm
        # at "step 103" of an episode is at step_in_episode 103 whatever the global step).
        index = [rr.TimeColumn("step", sequence=box.steps),
                 rr.TimeColumn("episode", sequence=[r.episode for r in records]),
                 rr.TimeColumn("step_in_episode", sequence=[r.step for r in records])]
        mean = np.array([r.mean for r in records])
        std = np.array([r.std for r in records])
        for a in range(mean.shape[1]):
            band = np.stack([mean[:, a], mean[:, a] - std[:, a], mean[:, a] + std[:, a]], axis=1)
            self._send(box, f"/uncertainty/{self._label}{a}", index, band)
        self._send(box, "/score", index, [r.score for r in records])
        if self._compared is not None:
            self._send(box, "/compared", index, [r.compared for r in records])
        self._send(box, "/shifted", index, [float(r.shifted) for r in records])
        for name in records[0].scores:  # every detector's score, on a series of its own
            self._send(box, f"/detectors/{name}", index, [r.scores.get(name, np.nan) for r in records])
        thresholds = np.array([r.threshold for r in records])
        if not np.isnan(thresholds).all():
            self._send(box, "/threshold", index, thresholds)
        if records[0].observation is not None:
            self._send(box, "/observation", index, _decoded([r.observation for r in records], self._states))
        box.records, box.steps, box.sent_at = [], [], time.monotonic()

    def write_alarm(self, event: AlarmEvent) -> None:
        if not self._streams:
            return
        self._set_time(self._global_step - 1, event.episode, event.step)
        self._each("log", "/alarms", self._rr.TextLog(
            event.text(),
            level=self._rr.TextLogLevel.WARN))
        if event.region is not None:  # where in the picture: a box over the agent's view
            region = event.region
            self._each("log", "/frame/alarm_region", self._rr.Boxes2D(
                mins=[[region.left, region.top]], sizes=[[region.width, region.height]],
                labels=[f"alarm: {event.cause}"], colors=[[255, 40, 40]]))
            self._boxed = True

    def end_episode(self, record: EpisodeRecord) -> None:
        if not self._streams:
            return
        now = time.monotonic()
        for box in self._outboxes:
            if now - box.sent_at >= END_FLUSH_SECONDS:
                self._flush(box)
        self._set_time(max(self._global_step - 1, 0), record.episode, max(record.length - 1, 0))
        self._each("log", "/episode/return", self._rr.Scalars(record.total_return))
        self._each("log", "/episodes", self._rr.TextLog(
            f"episode {record.episode} ({record.variant}, onset {record.onset}, seed {record.seed}"
            + (f", sensor noise {record.obs_noise:g}" if record.obs_noise else "") + "): return "
            f"{record.total_return:.1f}, {record.length} steps, {record.alarms} alarms", level=self._rr.TextLogLevel.INFO))
        if self._boxed:  # an alarm's box belongs to its episode's pictures
            self._set_time(self._global_step, record.episode, record.length)
            self._each("log", "/frame/alarm_region", self._rr.Clear(recursive=False))
            self._boxed = False
        self._check_live()
        self._check_file()

    def _check_file(self) -> None:
        """Whether Rerun still writes the file, looked at every :data:`FILE_CHECK_SECONDS` after a
        send: a file that did not grow though steps were sent since the last look, and still has
        not as long again later (a send of the last moment is on its way; a disk that stalls for
        seconds is not a failure), has lost its writer (a full disk: Rerun's thread stops at its
        first failed write, and logs why). Raised once, an ``OSError``: the monitor warns of it and
        counts it, and the run goes on without the file. Only the file's size is read: asking Rerun
        (a flush of the stream) made its close hang once the writer had failed (2026-12-07)."""
        if self._watch is None:
            return
        looked, size, chunks = self._watch
        now = time.monotonic()
        if now - looked < (max(1.0, FILE_CHECK_SECONDS) if self._stalled else FILE_CHECK_SECONDS):
            return
        try:
            grown = self.path.stat().st_size
        except OSError:  # moved or removed by someone else: Rerun writes on where it is; not ours to tell
            self._watch = None
            return
        if grown != size or self._file_chunks == chunks:  # written, or nothing sent since
            self._watch, self._stalled = (now, grown, self._file_chunks), False
        elif not self._stalled:  # sent, not yet written: look again as long after (a second at least)
            self._watch, self._stalled = (now, size, chunks), True
        else:
            self._watch = None
            raise OSError(f"Rerun has written nothing more to {self.path} though {self._file_chunks - chunks:,} "
                          "columns of steps were sent to it since it last grew: its writer stopped (a full disk? "
                          "Rerun's log says why); the file holds what was written before, and the run goes on "
                          "without it")

    def close(self) -> None:
        if not self._streams:
            return
        try:
            for box in self._outboxes:
                self._flush(box)
            self._check_live()
            for rec in self._streams:
                if rec is not self._live:
                    rec.flush(timeout_sec=self.flush_timeout)
        finally:
            for rec in self._streams:
                rec.disconnect()
            self._streams, self._live = [], None


def _cannot_listen(bind: str, port: int) -> str | None:
    """Why a server could not listen on ``bind``:``port`` now (the port taken, an address not of this
    machine), or None. Probed with SO_REUSEADDR, as Rerun's server (tokio) binds: a port left in
    TIME_WAIT by a run before is free to it."""
    import socket

    try:
        family = socket.getaddrinfo(bind, port, type=socket.SOCK_STREAM)[0][0]
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((bind, port))
    except (OSError, OverflowError) as error:
        return getattr(error, "strerror", None) or str(error)
    return None


def viewer_command(executable: str, bind: str, port: int) -> list[str]:
    """The command line ``RerunSink(spawn=True)`` starts a Rerun viewer with: ``rerun.spawn``'s
    (rerun-sdk 0.41: port, memory limits, ``--expect-data-soon``) and ``--bind``."""
    return [executable, f"--port={port}", f"--bind={bind}", "--memory-limit=75%", "--server-memory-limit=1GiB",
            "--expect-data-soon"]


def _reach(bind: str) -> str:
    """The host of a URL that reaches a server listening on ``bind`` from this machine."""
    if bind in ("", "0.0.0.0", "::"):
        return "127.0.0.1"
    return f"[{bind}]" if ":" in bind else bind


def _plain(line: str, keep: int = 200) -> str:
    """A line of a Rust program's log without its colour codes, its last ``keep`` characters (where
    the reason is: "Error: winit EventLoopError: os error at <source path>: neither WAYLAND_DISPLAY
    nor WAYLAND_SOCKET nor DISPLAY is set.")."""
    import re

    line = re.sub(r"\x1b\[[0-9;]*m", "", line).strip()
    return line if len(line) <= keep else "..." + line[-keep:]


def _unreachable(url: str, timeout: float) -> str | None:
    """Why nothing accepts a connection at a Rerun gRPC ``url`` within ``timeout`` s, or None."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(url.replace("rerun+", "", 1).replace("rerun://", "http://", 1))
    try:
        host, port = parts.hostname, parts.port or (443 if parts.scheme == "https" else 9876)
    except ValueError as error:
        return str(error)
    if not host:
        return "no host in the URL"
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return None
    except OSError as error:
        return error.strerror or type(error).__name__


def _warn(message: str) -> None:
    warnings.warn(message, SinkWarning, stacklevel=4)


def _decoded(observations: list, states: list[int]) -> np.ndarray:
    """Steps' observations, (steps, readings): each one-hot block of ``states`` values as the index
    of its 1 (a discrete observation, as the env gave it), or as they are when they are not such.

    Example:
        >>> _decoded([[0, 0, 1, 0, 1, 0, 0, 0], [1, 0, 0, 0, 0, 0, 0, 1]], [3, 5]).tolist()
        [[2.0, 1.0], [0.0, 4.0]]
    """
    values = np.asarray(observations, dtype=np.float64)
    if not states or values.ndim != 2 or values.shape[1] != sum(states):
        return values
    bounds = np.cumsum([0, *states])
    return np.stack([values[:, a:b].argmax(axis=1) for a, b in zip(bounds[:-1], bounds[1:])], axis=1).astype(np.float64)
