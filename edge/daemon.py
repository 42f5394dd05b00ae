"""The depth pipeline and the loop that runs it over a source: the on-robot daemon, replay and
the demo all use this.

frame ──► rectify ──► project the synced LiDAR ──► engine ──► MCAP (and live view)

Bad input is counted by kind and skipped, never raised out of the loop: a frame of the wrong
size, a frame that fails to rectify, a scan with no finite points. A live source runs in its
own thread into a bounded queue that drops the oldest frame when inference falls behind.
Frames wait, boundedly, for the LiDAR scans that cover them (`edge.capture.sync`): up to
`sync.max_wait_ms` of host time live, of stream time in replay.
SIGINT and SIGTERM stop the source, finish the frame in hand and close the MCAP file.
The commands that wire this up (`run`, `record`, `replay`) are in edge.commands.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from calibration.errors import CalibrationError
from calibration.model import LidarExtrinsics, StereoCalibration
from calibration.projection import project_to_disparity
from edge.capture.sync import LidarSync, SyncConfig
from edge.errors import EdgeError
from edge.mcap_log import McapLogger
from edge.metrics import disparity_metrics
from edge.runtime.engine import Engine
from edge.types import Calibration, DepthResult, GroundTruth, LidarScan, StereoFrame

log = logging.getLogger(__name__)


class FatalInputError(EdgeError):
    """Input that every later frame would share (the first frame's size differs from the
    calibration's): the run stops with this message instead of skipping frame after frame."""


@dataclass
class FrameOutput:
    result: DepthResult
    sparse: np.ndarray
    left: np.ndarray
    metrics: dict | None = None
    gt: np.ndarray | None = None


HISTORY = 10_000  # frames of timings kept for summaries: a daemon runs for days


@dataclass
class PipelineStats:
    """Counters since start; `timings` holds the last HISTORY frames, `window` the frames
    since the last /diagnostics report."""

    frames: int = 0
    scans: int = 0
    drops: int = 0
    errors: Counter = field(default_factory=Counter)
    timings: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    window: list[dict] = field(default_factory=list)
    metrics: list[dict] = field(default_factory=list)
    source_failed: bool = False
    fatal: str | None = None  # why the run stopped early (FatalInputError), if it did

    def count_error(self, kind: str, detail: object) -> None:
        if self.errors[kind] == 0:
            log.warning("%s: %s (counted, skipped; later ones are only counted)", kind, detail)
        self.errors[kind] += 1


class Pipeline:
    """One frame at a time: `on_scan(scan)`, `on_frame(frame, gt=None) -> FrameOutput`.

    With `engine=None` it is the recorder: frames are checked, rectified and logged with
    the raw scans, and nothing is inferred (`on_frame` returns None)."""

    def __init__(self, engine: Engine | None, stereo: StereoCalibration,
                 lidar: LidarExtrinsics | None, logger: McapLogger | None = None,
                 iters: int | None = None, deadline_ms: float | None = None,
                 sync: SyncConfig | None = None, log_raw: bool = True) -> None:
        plan = engine.plan_for(tuple(stereo.image_size)) if engine else None  # ConfigError
        if plan is not None and not plan.identity:                          # if it cannot run
            w, h = plan.scaled
            log.info("camera %dx%d runs on the %dx%d bundle at scale %.3f (%dx%d, padded)",
                     *stereo.image_size, *engine.size, plan.scale, w, h)
        self.engine, self.logger = engine, logger
        self.iters, self.deadline_ms, self.log_raw = iters, deadline_ms, log_raw
        self.set_calibration(stereo, lidar)
        sync = sync or SyncConfig()
        if lidar is not None and sync.time_offset_ns == 0:
            sync = SyncConfig(sync.mode, sync.window_ms, lidar.time_offset_ns, sync.keep_s,
                              sync.max_wait_ms)
        self.sync = LidarSync(sync)
        self.stats = PipelineStats()
        self._unpaired_since_ns: int | None = None  # first frame of a run without LiDAR
        self._warned_unpaired = False
        if lidar is None and engine is not None:
            log.warning("no LiDAR extrinsics in the calibration: running stereo only (add a "
                        "[lidar] section: edge-depth calibrate lidar)")
        self._lock = threading.Lock()
        if engine is not None:
            engine.warm_up()

    def set_calibration(self, stereo: StereoCalibration, lidar: LidarExtrinsics | None) -> None:
        self.stereo, self.lidar = stereo, lidar
        self.rectifier = stereo.rectifier()
        self.focal_px, self.baseline_m = stereo.focal_px, stereo.baseline_m
        self.principal_point = stereo.principal_point
        if self.logger is not None:
            self.logger.set_calibration(stereo, lidar)

    def on_scan(self, scan: LidarScan) -> None:
        with self._lock:
            self.stats.scans += 1
            finite = scan.finite()
            if len(finite) == 0:
                self.stats.count_error("lidar scan without finite points", scan.stamp_ns)
            else:
                self.sync.add(finite)
        if self.logger is not None and self.log_raw:
            self.logger.log_scan(scan)

    def frame_ready(self, stamp_ns: int) -> bool:
        """Whether a frame can go on: its scans are in, or there is no LiDAR to wait for."""
        with self._lock:
            return self.engine is None or self.lidar is None or self.sync.ready(stamp_ns)

    def lidar_delivering(self, stamp_ns: int) -> bool:
        with self._lock:
            return self.lidar is not None and self.sync.recent(stamp_ns)

    def _check_pairing(self, stamp_ns: int, paired: bool) -> None:
        """Warn once per episode when scans arrive but no frame has paired for 5 s."""
        if paired or self._unpaired_since_ns is None:
            self._unpaired_since_ns = None if paired else stamp_ns
            self._warned_unpaired = False
            return
        if self.stats.scans and not self._warned_unpaired \
                and stamp_ns - self._unpaired_since_ns > 5e9:
            gap = self.sync.median_gap_ms()
            log.warning("LiDAR scans arrive (%d so far) but no frame has paired with one for "
                        "5 s: median nearest-scan minus frame stamp %s; check the clocks "
                        "([lidar] time_offset_ns in the calibration) or [sync] window_ms",
                        self.stats.scans, "n/a" if gap is None else f"{gap:+.0f} ms")
            self._warned_unpaired = True

    def _size_fits(self, frame: StereoFrame) -> bool:
        """A first frame of another size stops the run (every frame would be skipped); one
        odd frame later on is counted and skipped."""
        if frame.size == tuple(self.stereo.image_size):
            return True
        (w, h), (cw, ch) = frame.size, self.stereo.image_size
        if self.stats.frames == 0:
            raise FatalInputError(f"the camera's frames are {w}x{h} but the calibration is "
                                  f"for {cw}x{ch}: calibrate at the camera's size (or set "
                                  "[camera] size to match)")
        self.stats.count_error("frame size", f"{frame.size}, the calibration's is {(cw, ch)}")
        return False

    def on_frame(self, frame: StereoFrame, gt: np.ndarray | None = None,
                 sync_wait_ms: float = 0.0) -> FrameOutput | None:
        t0 = time.perf_counter()
        if not self._size_fits(frame):
            return None
        try:
            left, right = self.rectifier.pair(frame)
        except Exception as exc:  # noqa: BLE001 - OpenCV errors are not one type
            self.stats.count_error("rectify", exc)
            return None
        if self.engine is None:  # recording: the rectified pair, nothing inferred
            if self.logger is not None:
                self.logger.log_frame(StereoFrame(frame.stamp_ns, frame.seq, left, right,
                                                  rectified=True))
            self.stats.frames += 1
            return None
        t1 = time.perf_counter()
        with self._lock:
            points = self.sync.points_for(frame.stamp_ns)
        if self.lidar is not None:
            self._check_pairing(frame.stamp_ns, len(points) > 0)
        if len(points) and self.lidar is not None:
            sparse, _ = project_to_disparity(points, self.stereo, self.lidar.T_cam_lidar)
        else:
            sparse = np.zeros(left.shape, np.float32)
        t2 = time.perf_counter()
        result = self.engine.infer(left, right, sparse, iters=self.iters,
                                   deadline_ms=self.deadline_ms, focal_px=self.focal_px,
                                   baseline_m=self.baseline_m, stamp_ns=frame.stamp_ns,
                                   started=t0)
        t3 = time.perf_counter()
        if self.logger is not None:
            if self.log_raw:
                self.logger.log_frame(StereoFrame(frame.stamp_ns, frame.seq, left, right,
                                                  rectified=True))
                if gt is not None:
                    self.logger.log_gt(frame.stamp_ns, gt)
            self.logger.log_result(result, sparse, self.focal_px, self.principal_point, left)
        t4 = time.perf_counter()
        timings = dict(result.timings_ms, rectify=(t1 - t0) * 1000, project=(t2 - t1) * 1000,
                       log=(t4 - t3) * 1000, frame=(t4 - t0) * 1000, sync_wait=sync_wait_ms,
                       iterations=result.iterations)
        self.stats.frames += 1
        self.stats.timings.append(timings)
        self.stats.window.append(timings)
        metrics = None
        if gt is not None and gt.shape == result.disparity.shape:
            metrics = disparity_metrics(result.disparity, gt)
            self.stats.metrics.append(metrics)
        return FrameOutput(result, sparse, left, metrics, gt)


def lidar_summary(pipeline: Pipeline) -> str:
    """The closing line about the LiDAR: how many frames had it, or why none did."""
    counters, stats = pipeline.sync.counters(), pipeline.stats
    paired, frames = counters["frames_with_lidar"], stats.frames
    if pipeline.lidar is None:
        return "no LiDAR extrinsics: stereo only (add a [lidar] section to the calibration)"
    if stats.scans == 0:
        return f"frames with LiDAR: 0 of {frames} (no scan arrived: stereo only)"
    line = f"frames with LiDAR: {paired} of {frames}"
    if paired < frames and pipeline.sync.median_gap_ms() is not None:
        line += (f" (unpaired frames: median nearest-scan minus frame stamp "
                 f"{pipeline.sync.median_gap_ms():+.0f} ms)")
    if counters["frames_gone_before_their_scans"]:
        line += f"; {counters['frames_gone_before_their_scans']} went on before their scans arrived"
    return line


def summarise(timings: list[dict]) -> dict[str, dict[str, float]]:
    keys = [k for k in timings[0] if k != "iterations"] if timings else []
    return {k: dict(median=float(np.median([t[k] for t in timings])),
                    p95=float(np.percentile([t[k] for t in timings], 95))) for k in keys}


def format_latency(summary: dict[str, dict[str, float]]) -> str:
    """'encoder 9.1/10.2, steps ...': median / p95 ms of each stage of a `summarise`."""
    return ", ".join(f"{k} {v['median']:.1f}/{v['p95']:.1f}" for k, v in summary.items()
                     if k != "step_mean")


class SystemdNotifier:
    """sd_notify without libsystemd: datagrams to $NOTIFY_SOCKET when it is set."""

    def __init__(self) -> None:
        address = os.environ.get("NOTIFY_SOCKET")
        self.address = None
        if address:
            self.address = "\0" + address[1:] if address.startswith("@") else address

    def notify(self, state: str) -> None:
        if self.address is None:
            return
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
                s.sendto(state.encode(), self.address)
        except OSError as exc:
            log.warning("systemd notify failed: %s", exc)


class StopFlag:
    """Set by SIGINT / SIGTERM (installed with `install`), or by hand."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.on_stop: list = []

    def set(self, *_args) -> None:
        self.event.set()
        for callback in self.on_stop:
            callback()

    def is_set(self) -> bool:
        return self.event.is_set()

    def install(self) -> None:
        self._previous = {sig: signal.signal(sig, self.set)
                          for sig in (signal.SIGINT, signal.SIGTERM)}

    def restore(self) -> None:
        for sig, handler in getattr(self, "_previous", {}).items():
            signal.signal(sig, handler)


class Runner:
    """Feeds a source's events through the pipeline until it ends or `stop` is set:
    source → (live: its own thread, then a queue of `queue_size` frames that drops the
    oldest when full) → frames held until their scans are in → pipeline → on_output.

    Replay (threaded=False) holds frames in stream time, live in host time. /diagnostics and
    the systemd watchdog tick once a period, also while no frame comes."""

    def __init__(self, source, pipeline: Pipeline, stop: StopFlag | None = None,
                 threaded: bool = False, queue_size: int = 2, on_output=None,
                 diagnostics_period_s: float = 1.0, max_frames: int | None = None) -> None:
        self.source, self.pipeline = source, pipeline
        self.stop = stop or StopFlag()
        self.stop.on_stop.append(source.close)
        self.threaded, self.queue_size = threaded, queue_size
        self.on_output, self.max_frames = on_output, max_frames
        self.period_s = diagnostics_period_s
        self.notifier = SystemdNotifier()
        self.stats = pipeline.stats
        self.frames: deque[StereoFrame] = deque()  # live: the capture thread's queue
        self.cond = threading.Condition()
        self.finished = threading.Event()
        self.waiting: deque[StereoFrame] = deque()  # replay: frames held in stream time
        self.gts: dict[int, np.ndarray] = {}
        self.last_diag = time.monotonic()
        self.last_stamp: int | None = None
        self.wait_ms = pipeline.sync.config.wait_ms

    # -- events ------------------------------------------------------------------------------
    def handle(self, event) -> None:
        """Errors an event raises are counted by kind; the loop goes on."""
        try:
            if isinstance(event, LidarScan):
                self.pipeline.on_scan(event)
            elif isinstance(event, StereoFrame):
                self._enqueue(event) if self.threaded else self.process(event)
            elif isinstance(event, GroundTruth):
                self._keep_gt(event)
            elif isinstance(event, Calibration) and event.toml is not None:
                from calibration.io import loads_calibration

                stereo, lidar = loads_calibration(event.toml, "recording /edge/calibration")
                self.pipeline.set_calibration(stereo, lidar or self.pipeline.lidar)
        except (EdgeError, CalibrationError, ValueError, ArithmeticError) as exc:
            self.stats.count_error(type(exc).__name__, exc)

    def _keep_gt(self, gt: GroundTruth) -> None:
        """Ground truth follows its frame: live, it is kept only while that frame is queued
        (a dropped frame's 1 MB of truth must not outlive it)."""
        if not self.threaded:
            self.gts[gt.stamp_ns] = gt.disparity
            return
        with self.cond:
            if any(f.stamp_ns == gt.stamp_ns for f in self.frames):
                self.gts[gt.stamp_ns] = gt.disparity

    def _enqueue(self, frame: StereoFrame) -> None:
        with self.cond:
            if len(self.frames) >= self.queue_size:
                dropped = self.frames.popleft()
                self.gts.pop(dropped.stamp_ns, None)
                self.stats.drops += 1
            self.frames.append(frame)
            self.cond.notify()

    def process(self, frame: StereoFrame, sync_wait_ms: float = 0.0) -> None:
        # ground truth follows its frame in our recordings: look for it once the frame is in
        with self.cond:
            gt = self.gts.pop(frame.stamp_ns, None)
            for stamp in [s for s in self.gts if s < frame.stamp_ns]:  # dropped, skipped
                del self.gts[stamp]
        try:
            out = self.pipeline.on_frame(frame, gt, sync_wait_ms)
        except FatalInputError as exc:  # every frame would fail: stop, say why
            self.stats.fatal = str(exc)
            log.error("%s", exc)
            self.stop.set()
            out = None
        except Exception as exc:  # noqa: BLE001 - one bad frame must not stop the daemon
            self.stats.count_error(f"frame: {type(exc).__name__}", exc)
            out = None
        logger = self.pipeline.logger
        if logger is not None and logger.stopped is not None and not self.stats.fatal:
            self.stats.fatal = logger.stopped  # the disk is full: stop, exit non-zero
            self.stop.set()
        if out is not None and self.on_output is not None:
            self.on_output(frame, out)
        if self.max_frames is not None and self.stats.frames >= self.max_frames:
            self.stop.set()
        self.last_stamp = frame.stamp_ns
        self.tick()

    # -- health ------------------------------------------------------------------------------
    def tick(self) -> None:
        """Once a period: /diagnostics and the systemd watchdog (also while no frame comes:
        a camera that is reconnecting must not get the daemon killed)."""
        if time.monotonic() - self.last_diag >= self.period_s:
            self.diagnostics()
            self.notifier.notify("WATCHDOG=1")

    def _source_counters(self) -> dict:
        try:
            return self.source.counters() if hasattr(self.source, "counters") else {}
        except Exception as exc:  # noqa: BLE001 - a counter must never stop the daemon
            return {"error": f"{type(exc).__name__}: {exc}"}

    def diagnostics(self) -> None:
        """Counters and the latency of the frames since the last report, on /diagnostics."""
        stats, pipeline = self.stats, self.pipeline
        window, stats.window = stats.window, []
        self.last_diag = time.monotonic()
        if pipeline.logger is not None and self.last_stamp is not None:
            pipeline.logger.log_diagnostics(self.last_stamp, dict(
                frames=stats.frames, scans=stats.scans, drops=stats.drops,
                errors=dict(stats.errors), lidar_sync=pipeline.sync.counters(),
                sources=self._source_counters(),
                latency_ms=summarise(window) if window else {},
                iterations=[t["iterations"] for t in window]))

    # -- waiting for the LiDAR -----------------------------------------------------------------
    def _wait_for_lidar(self, frame: StereoFrame) -> float:
        """Live: hold a frame (host time, at most wait_ms) while a delivering LiDAR has not
        yet sent the scans that cover it; returns the ms waited."""
        pipeline, start = self.pipeline, time.monotonic()
        while not pipeline.frame_ready(frame.stamp_ns) \
                and pipeline.lidar_delivering(frame.stamp_ns) and not self.stop.is_set():
            if time.monotonic() - start >= self.wait_ms / 1000:
                pipeline.sync.waited_out += 1
                break
            time.sleep(0.002)
        return (time.monotonic() - start) * 1000

    def _flush(self, latest_ns: int | None, everything: bool = False) -> None:
        """Replay: process held frames, oldest first, while each is ready, has waited
        wait_ms of stream time (up to the newest frame's stamp) or the stream has ended."""
        while self.waiting and not self.stop.is_set():
            head = self.waiting[0]
            ready = self.pipeline.frame_ready(head.stamp_ns)
            timed_out = latest_ns is not None and latest_ns - head.stamp_ns > self.wait_ms * 1e6
            if not (ready or timed_out or everything):
                return
            if not ready and self.pipeline.lidar is not None:
                self.pipeline.sync.waited_out += 1
            self.process(self.waiting.popleft())

    # -- the two loops -------------------------------------------------------------------------
    def _capture(self) -> None:
        try:
            for event in self.source:
                if self.stop.is_set():
                    break
                self.handle(event)
        except Exception as exc:  # noqa: BLE001 - reported, and the daemon exits non-zero
            self.stats.count_error("source", f"{type(exc).__name__}: {exc}")
            self.stats.source_failed = True
        finally:
            self.finished.set()
            with self.cond:
                self.cond.notify()

    def _next_frame(self) -> StereoFrame | None:
        with self.cond:
            while not self.frames and not self.finished.is_set() and not self.stop.is_set():
                self.cond.wait(0.1)
                self.tick()
            return self.frames.popleft() if self.frames else None

    def _run_live(self) -> None:
        thread = threading.Thread(target=self._capture, name="capture", daemon=True)
        thread.start()
        while not self.stop.is_set():
            frame = self._next_frame()
            if frame is None:
                if self.finished.is_set():
                    break
                continue
            self.process(frame, self._wait_for_lidar(frame))
        thread.join(timeout=5)

    def _run_replay(self) -> None:
        # a frame is held at least until the next event that is not its ground truth (so
        # the GT is in), then until its scans are in or it has waited out
        latest: int | None = None
        for event in self.source:
            if isinstance(event, StereoFrame):
                latest = event.stamp_ns if latest is None else max(latest, event.stamp_ns)
                self._flush(latest)
                self.waiting.append(event)
            else:
                self.handle(event)
                if not isinstance(event, GroundTruth):
                    self._flush(latest)
            if self.stop.is_set():
                break
        self._flush(latest, everything=True)

    def run(self) -> PipelineStats:
        self.notifier.notify("READY=1")
        self._run_live() if self.threaded else self._run_replay()
        if self.stats.window:
            self.diagnostics()  # the frames since the last report
        self.notifier.notify("STOPPING=1")
        return self.stats


def run(source, pipeline: Pipeline, stop: StopFlag | None = None, threaded: bool = False,
        queue_size: int = 2, on_output=None, diagnostics_period_s: float = 1.0,
        max_frames: int | None = None) -> PipelineStats:
    """`Runner(...).run()`: see Runner. on_output(frame, FrameOutput) is called for every
    processed frame."""
    return Runner(source, pipeline, stop, threaded, queue_size, on_output,
                  diagnostics_period_s, max_frames).run()
