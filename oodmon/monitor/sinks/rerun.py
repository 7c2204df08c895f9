"""Log a monitored run to Rerun: an ``.rrd`` file, a spawned viewer, a served stream, or a URL.

Timeline ``step`` counts the run's steps. Entities: ``/score`` and ``/threshold``;
``/uncertainty/<action>`` with the samples' mean and the band mean - std .. mean + std;
``/observation`` (vector tasks) or ``/frame`` (Pong: the 84x84 frame the agent saw);
``/shifted`` (1 while the shift is active); ``/alarms`` (warnings); ``/episode/return``.
A default blueprint lays these out, so opening the file shows a useful layout.

Per-step values are buffered and sent as columns every :data:`FLUSH_EVERY` steps and at every
episode end: a ``log`` call per value costs 25-40 us, a column of thousands about 10 ms.
"""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np

from oodmon.monitor.alarms import AlarmEvent
from oodmon.monitor.records import EpisodeRecord, RunInfo, StepRecord

__all__ = ["FLUSH_EVERY", "RerunSink", "default_blueprint"]

FLUSH_EVERY = 200


def default_blueprint(task: str, n_outputs: int):
    """The layout a run opens with: score against threshold, per-action bands, what the agent
    saw beside the alarms, the episode returns."""
    import rerun.blueprint as rrb

    seen = rrb.Spatial2DView(origin="/frame", name="agent's view") if task == "pong" else rrb.TimeSeriesView(
        origin="/observation", name="observation")
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.TimeSeriesView(origin="/", contents=["/score", "/threshold", "/shifted"], name="uncertainty score"),
            rrb.TimeSeriesView(origin="/uncertainty", name="samples: mean and mean ± std per action"),
            rrb.Horizontal(seen, rrb.TextLogView(origin="/alarms", name="alarms")),
            rrb.TimeSeriesView(origin="/episode", name="episode return"),
            row_shares=[3, 3, 2, 1],
        ),
        collapse_panels=True,
    )


class RerunSink:
    """Streams the run to Rerun.

    Args:
        path: write an ``.rrd`` file here.
        spawn: start a Rerun viewer and stream to it (needs a display and the ``rerun`` binary).
        serve: serve the stream over gRPC for a remote viewer (its URL is printed by Rerun).
        connect: stream to a viewer listening at this URL.
        recording_id: Rerun's recording id (default: a fresh one).
        flush_timeout: seconds to wait at an episode end for the data to reach its sinks. A
            viewer that is gone makes the flush fail (a warning from the monitor, which goes
            on); after that the sink stops waiting for it.
    """

    def __init__(self, path: str | Path | None = None, *, spawn: bool = False, serve: bool = False,
                 connect: str | None = None, recording_id: str | None = None, flush_timeout: float = 2.0) -> None:
        self.path = Path(path) if path is not None else None
        self.spawn, self.serve, self.connect = spawn, serve, connect
        self.recording_id = recording_id or str(uuid.uuid4())
        self.flush_timeout = flush_timeout
        self._unreachable = False
        self._rec = None
        self._global_step = 0
        self._buffer: list[StepRecord] = []
        self._steps: list[int] = []

    def open(self, run: RunInfo) -> None:
        import rerun as rr

        rec = rr.RecordingStream("oodmon", recording_id=self.recording_id)
        self._task = run.task
        self._names_sent = False
        sinks = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.path)))
        if self.spawn:
            rec.spawn(connect=False)
            sinks.append(rr.GrpcSink())
        if self.connect:
            sinks.append(rr.GrpcSink(self.connect))
        if self.serve:
            sinks.append(rr.GrpcServerSink())
        self._blueprint_outputs = None
        rec.set_sinks(*sinks)
        rec.send_recording_name(f"oodmon {run.task}/{run.method}")
        rec.log("/run", rr.TextDocument(
            f"task {run.task}, method {run.method}, score {run.score}, alarm rule: {run.rule}, "
            f"threshold {run.threshold}, policy {run.policy_hash}"), static=True)
        self._rr, self._rec = rr, rec

    def write_step(self, record: StepRecord) -> None:
        if not self._names_sent:
            self._send_layout(len(record.mean))
        self._buffer.append(record)
        self._steps.append(self._global_step)
        if record.frame is not None:
            self._rec.set_time("step", sequence=self._global_step)
            self._rec.log("/frame", self._rr.Image(record.frame))
        self._global_step += 1
        if len(self._buffer) >= FLUSH_EVERY:
            self._flush()

    def _send_layout(self, n_outputs: int) -> None:
        rr, rec = self._rr, self._rec
        label = "Q" if self._task in ("cartpole", "pong") else "action"
        for a in range(n_outputs):
            rec.log(f"/uncertainty/{label}{a}", rr.SeriesLines(names=["mean", "mean - std", "mean + std"],
                                                            colors=[[31, 119, 180], [160, 190, 230], [160, 190, 230]]),
                    static=True)
        rec.log("/score", rr.SeriesLines(names=["score"], colors=[[214, 39, 40]]), static=True)
        rec.log("/threshold", rr.SeriesLines(names=["threshold"], colors=[[60, 60, 60]]), static=True)
        rec.log("/shifted", rr.SeriesLines(names=["shift active"], colors=[[255, 160, 0]]), static=True)
        rec.send_blueprint(default_blueprint(self._task, n_outputs))
        self._label, self._names_sent = label, True

    def _flush(self) -> None:
        if not self._buffer:
            return
        rr, rec = self._rr, self._rec
        index = [rr.TimeColumn("step", sequence=self._steps)]
        mean = np.array([r.mean for r in self._buffer])
        std = np.array([r.std for r in self._buffer])
        for a in range(mean.shape[1]):
            band = np.stack([mean[:, a], mean[:, a] - std[:, a], mean[:, a] + std[:, a]], axis=1)
            rec.send_columns(f"/uncertainty/{self._label}{a}", indexes=index,
                             columns=rr.Scalars.columns(scalars=band))
        rec.send_columns("/score", indexes=index, columns=rr.Scalars.columns(scalars=[r.score for r in self._buffer]))
        rec.send_columns("/shifted", indexes=index,
                         columns=rr.Scalars.columns(scalars=[float(r.shifted) for r in self._buffer]))
        thresholds = np.array([r.threshold for r in self._buffer])
        if not np.isnan(thresholds).all():
            rec.send_columns("/threshold", indexes=index, columns=rr.Scalars.columns(scalars=thresholds))
        if self._buffer[0].observation is not None:
            rec.send_columns("/observation", indexes=index,
                             columns=rr.Scalars.columns(scalars=np.array([r.observation for r in self._buffer])))
        self._buffer.clear()
        self._steps.clear()

    def write_alarm(self, event: AlarmEvent) -> None:
        self._flush()
        self._rec.set_time("step", sequence=self._global_step - 1)
        self._rec.log("/alarms", self._rr.TextLog(
            f"episode {event.episode} step {event.step}: score {event.score:.4g} > {event.threshold:.4g} ({event.rule})",
            level=self._rr.TextLogLevel.WARN))

    def end_episode(self, record: EpisodeRecord) -> None:
        self._flush()
        self._rec.set_time("step", sequence=max(self._global_step - 1, 0))
        self._rec.log("/episode/return", self._rr.Scalars(record.total_return))
        self._rec.log("/episodes", self._rr.TextLog(
            f"episode {record.episode} ({record.variant}, onset {record.onset}, seed {record.seed}): return "
            f"{record.total_return:.1f}, {record.length} steps, {record.alarms} alarms", level=self._rr.TextLogLevel.INFO))
        self._flush_to_sinks()

    def _flush_to_sinks(self) -> None:
        if self._unreachable:
            return
        try:
            self._rec.flush(timeout_sec=self.flush_timeout)
        except RuntimeError as error:
            self._unreachable = True  # do not make every later episode wait for it
            raise RuntimeError(f"Rerun sink unreachable ({error}); logging goes on without waiting for it") from None

    def close(self) -> None:
        if self._rec is None:
            return
        try:
            self._flush()
            self._flush_to_sinks()
        finally:
            self._rec.disconnect()
            self._rec = None
