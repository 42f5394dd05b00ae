"""The loop that runs the pipeline (`edge.daemon.Pipeline`) over a source.

A live source runs in its own thread into a bounded queue that drops the oldest frame when
inference falls behind. Frames wait, boundedly, for the LiDAR scans that cover them
(`edge.capture.sync`): up to `sync.max_wait_ms` of host time live, of stream time in replay.
Live, the pipeline's stages overlap: this loop prepares frame n + 1 (rectify, project) while
an engine thread infers frame n and a logging thread writes frame n − 1 (OpenCV, NumPy, ONNX
Runtime, OpenVINO and the MCAP writer release the GIL), each hand-off a one-frame slot, so the
frame rate is the slowest stage's, not the sum, and latency stays bounded.
SIGINT and SIGTERM stop the source, finish the frames in hand and close the MCAP file.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import socket
import threading
import time
from collections import deque

import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.daemon import FatalInputError, Pipeline, PipelineStats
from edge_depth.errors import EdgeError
from edge_depth.frame_summary import replaced_shares, summarise
from edge_depth.types import Calibration, GroundTruth, LidarScan, StereoFrame

log = logging.getLogger(__name__)
STARTUP_S = 3.0  # a LiDAR that has sent nothing yet: waited for this long after the first frame


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
                 diagnostics_period_s: float = 1.0, max_frames: int | None = None,
                 pipelined: bool = False) -> None:
        self.source, self.pipeline = source, pipeline
        self.pipelined = pipelined  # live only: overlap prepare / infer / log
        self._tick_lock = threading.Lock()
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
        self.arrived: dict[int, float] = {}  # live: perf_counter as each frame was queued
        self.last_diag = time.monotonic()
        self.last_stamp: int | None = None
        self.wait_ms = pipeline.sync.config.wait_ms
        self.first_frame_at: float | None = None  # monotonic s: the first frame held

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
                from edge_depth.calibration.io import loads_calibration

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
                self.arrived.pop(dropped.stamp_ns, None)
                self.stats.drops += 1
            self.frames.append(frame)
            self.arrived[frame.stamp_ns] = time.perf_counter()
            self.cond.notify()

    def process(self, frame: StereoFrame, sync_wait_ms: float = 0.0) -> None:
        """One frame through the three stages in this thread (replay; live unpipelined)."""
        prepared = self._prepare(frame, sync_wait_ms)
        out = None
        if prepared is not None:
            result = self._infer(prepared)
            out = None if result is None else self._finish(prepared, result)
            if result is not None:
                self._guarded(self.pipeline.watch_sample, prepared)
        self._after(frame, out)

    def _prepare(self, frame: StereoFrame, sync_wait_ms: float = 0.0):
        # ground truth follows its frame in our recordings: look for it once the frame is in
        with self.cond:
            gt = self.gts.pop(frame.stamp_ns, None)
            for stamp in [s for s in self.gts if s < frame.stamp_ns]:  # dropped, skipped
                del self.gts[stamp]
            arrived = self.arrived.pop(frame.stamp_ns, None)
        return self._guarded(self.pipeline.prepare, frame, gt, sync_wait_ms, arrived)

    def _infer(self, prepared):
        return self._guarded(self.pipeline.infer, prepared)

    def _finish(self, prepared, result):
        return self._guarded(self.pipeline.finish, prepared, result)

    def _guarded(self, stage, *args):
        """A stage's errors: a fatal one stops the run with its reason, any other is counted
        for its frame (one bad frame must not stop the daemon); both return None."""
        try:
            return stage(*args)
        except FatalInputError as exc:  # every frame would fail: stop, say why
            self.stats.fatal = str(exc)
            log.error("%s", exc)
            self.stop.set()
        except Exception as exc:  # noqa: BLE001 - one bad frame must not stop the daemon
            self.stats.count_error(f"frame: {type(exc).__name__}", exc)
        return None

    def _after(self, frame: StereoFrame, out) -> None:
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
        if time.monotonic() - self.last_diag < self.period_s:
            return
        if not self._tick_lock.acquire(blocking=False):
            return  # another of the pipeline's threads is reporting right now
        try:
            if time.monotonic() - self.last_diag >= self.period_s:
                self.diagnostics()
                self.notifier.notify("WATCHDOG=1")
        finally:
            self._tick_lock.release()

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
                iterations=[t["iterations"] for t in window],
                lidar_select_replaced_pct=[round(s, 2) for s in replaced_shares(window)],
                band_refined_pct=[round(s, 2) for s in
                                  replaced_shares(window, "refined_pct")],
                band_skipped=int(sum(replaced_shares(window, "band_skipped"))),
                lidar_put_back=[int(s) for s in replaced_shares(window, "lidar_put_back")],
                lidar_noise_px=[round(s, 2) for s in replaced_shares(window, "lidar_noise_px")],
                output_health=pipeline.health.diagnostics(),
                **({} if pipeline.propagator is None else
                   dict(camera_rate=pipeline.propagator.counters())),
                **({} if pipeline.watch is None else
                   dict(calibration_watch=pipeline.watch.estimate().as_dict()))))

    # -- waiting for the LiDAR -----------------------------------------------------------------
    def _wait_for_lidar(self, frame: StereoFrame) -> float:
        """Live: hold a frame (host time, at most wait_ms) while a delivering LiDAR has not
        yet sent the scans that cover it — or, within STARTUP_S of the first frame, while no
        scan has come yet (the first frames' scans may come after them) — unless, at the
        camera's rate, it is a frame before its scan is due (`Pipeline.goes_ahead`: it is
        carried, and the engine never idles waiting for a scan); returns the ms waited."""
        pipeline, start = self.pipeline, time.monotonic()
        if self.first_frame_at is None:
            self.first_frame_at = start
        starting = (pipeline.lidar is not None and not pipeline.stats.scans
                    and start - self.first_frame_at < STARTUP_S)
        while not pipeline.frame_ready(frame.stamp_ns) and not self.stop.is_set() \
                and (starting or pipeline.lidar_delivering(frame.stamp_ns)) \
                and not pipeline.goes_ahead(frame.stamp_ns):
            if time.monotonic() - start >= self.wait_ms / 1000:
                pipeline.sync.waited_out += 1
                break
            time.sleep(0.002)
        return (time.monotonic() - start) * 1000

    def _flush(self, latest_ns: int | None, everything: bool = False) -> None:
        """Replay: process held frames, oldest first, while each is ready, has waited
        wait_ms of stream time (up to the newest frame's stamp), may go on without its scans
        (`Pipeline.goes_ahead`: the camera's rate, as live) or the stream has ended."""
        while self.waiting and not self.stop.is_set():
            head = self.waiting[0]
            ready = self.pipeline.frame_ready(head.stamp_ns)
            ahead = self.pipeline.goes_ahead(head.stamp_ns)
            timed_out = latest_ns is not None and latest_ns - head.stamp_ns > self.wait_ms * 1e6
            if not (ready or ahead or timed_out or everything):
                return
            if not (ready or ahead) and self.pipeline.lidar is not None:
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
        if self.pipelined and self.pipeline.engine is not None:
            self._run_pipelined()
        else:
            while not self.stop.is_set():
                frame = self._next_frame()
                if frame is None:
                    if self.finished.is_set():
                        break
                    continue
                self.process(frame, self._wait_for_lidar(frame))
        thread.join(timeout=5)

    def _run_pipelined(self) -> None:
        """This thread prepares, an engine thread infers, a logging thread finishes. The
        hand-off to the engine holds one frame and a newer one replaces it (counted as a
        drop), so the engine always takes the freshest; the one to the logging thread holds
        one result (logging is faster than the engine)."""
        to_engine: queue.Queue = queue.Queue(maxsize=1)
        to_log: queue.Queue = queue.Queue(maxsize=1)
        workers = [threading.Thread(target=self._engine_loop, args=(to_engine, to_log),
                                    name="engine", daemon=True),
                   threading.Thread(target=self._log_loop, args=(to_log,), name="log",
                                    daemon=True)]
        for worker in workers:
            worker.start()
        submitted = 0
        while not self.stop.is_set():
            if self.max_frames is not None and submitted >= self.max_frames:
                break  # the last ones are in hand: no more than asked for
            frame = self._next_frame()
            if frame is None:
                if self.finished.is_set():
                    break
                continue
            prepared = self._prepare(frame, self._wait_for_lidar(frame))
            if prepared is None:
                self._after(frame, None)
                continue
            # the freshest frame wins: one still waiting for the engine is dropped (latency
            # stays ~one engine time instead of growing by a frame per slot)
            try:
                stale = to_engine.get_nowait()
            except queue.Empty:
                stale = None
            if stale is not None:
                self.stats.drops += 1
                submitted -= 1
            to_engine.put(prepared)
            submitted += 1
        to_engine.put(None)  # the frames in hand are finished and logged, then the threads end
        for worker in workers:
            while worker.is_alive():
                worker.join(timeout=0.1)
                self.tick()

    def _engine_loop(self, to_engine: queue.Queue, to_log: queue.Queue) -> None:
        """The pipelined run's engine thread: infers each prepared frame handed to it and
        hands the result on (None: skipped), then the calibration watch's sample."""
        while (item := to_engine.get()) is not None:
            result = self._infer(item)
            to_log.put(None if result is None else (item, result))
            if result is None:
                self._after(item.frame, None)  # skipped: still counts for the stops
            else:  # the frame is on its way: the watch's sample delays none
                self._guarded(self.pipeline.watch_sample, item)
        to_log.put(StopIteration)

    def _log_loop(self, to_log: queue.Queue) -> None:
        """The pipelined run's logging thread: finishes each result handed to it."""
        while (item := to_log.get()) is not StopIteration:
            if item is None:
                continue
            try:
                self._after(item[0].frame, self._finish(*item))
            except Exception as exc:  # noqa: BLE001 - e.g. on_output: stop, and keep
                # draining, or the engine thread would block on a full hand-off forever
                self.stats.count_error(f"output: {type(exc).__name__}", exc)
                self.stop.set()

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
        max_frames: int | None = None, pipelined: bool = False) -> PipelineStats:
    """`Runner(...).run()`: see Runner. on_output(frame, FrameOutput) is called for every
    processed frame (live and pipelined: from the logging thread)."""
    return Runner(source, pipeline, stop, threaded, queue_size, on_output,
                  diagnostics_period_s, max_frames, pipelined).run()
