"""The depth pipeline, one frame at a time: the on-robot daemon, replay and the demo all use
this (the loop that feeds it from a source is `edge.runner`).

frame ──► rectify ──► project the synced LiDAR ──► engine ──► MCAP (and live view)

Bad input is counted by kind and skipped, never raised out of the loop: a frame of the wrong
size, a frame that fails to rectify, a scan with no finite points. `on_frame` is the three
stages `prepare` (rectify, sync, project), `infer` and `finish` (log, count, score) in a row;
the live runner overlaps them in threads. The commands that wire this up (`run`, `record`,
`replay`) are in edge.commands.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
from edge_depth.calibration.projection import project_to_disparity
from edge_depth.calibration_watch import CalibrationWatch, stereo_reference
from edge_depth.camera_turn import TurnMeter, deskewed
from edge_depth.capture.sync import LidarSync, SyncConfig
from edge_depth.errors import EdgeError
from edge_depth.health import OutputHealth, score_frame
from edge_depth.mcap_log import McapLogger
from edge_depth.metrics import disparity_metrics, error_map, temporal_instability
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.lidar_denoise import smooths
from edge_depth.runtime.propagate import Propagator
from edge_depth.types import DepthResult, LidarScan, StereoFrame

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


@dataclass
class Prepared:
    """A frame between the pipeline's stages: rectified, its LiDAR projected."""

    frame: StereoFrame
    left: np.ndarray
    right: np.ndarray
    sparse: np.ndarray
    gt: np.ndarray | None
    t0: float  # perf_counter at the start of `prepare`
    timings: dict
    queued_ms: float = 0.0  # from prepared to the engine's start (pipelined: the hand-off)
    points: np.ndarray | None = None  # the synced scans' points (LiDAR frame), if any
    points_stamp_ns: int | None = None  # ... their stamp in the camera's clock
    carried: bool = False  # [engine] rate = "camera": the key frame's depth carried here
    ahead: bool = False  # ... before the scan nearest it is due: carried, unpaired
    arrived: float | None = None  # live: perf_counter as the frame entered the capture queue


def _frame_period(stamps) -> float:
    """The camera's frame period from consecutive stamps (ns; 0 with fewer than two): the
    lower quartile of the positive gaps, which a dropped frame (a gap of two periods) moves
    only when most are drops."""
    gaps = np.diff(np.asarray(stamps, np.int64))
    gaps = gaps[gaps > 0]
    return float(np.percentile(gaps, 25)) if gaps.size else 0.0


# frames of timings kept for the summaries: a daemon runs for days, and a frame's dict of ~22
# timings holds ~1.4 kB (10 000 of them took half an hour of a 5 frames/s soak to fill)
HISTORY = 1_000


class MetricsMean:
    """The mean of every frame's metrics (EPE, bad-3, ...) over the whole run, kept as running
    sums: a list of each frame's grew by ~1 kB a frame, a leak in a daemon that runs for
    days on ground truth (the sim robot)."""

    def __init__(self) -> None:
        self.count = 0
        self.sums: dict[str, float] = {}

    def add(self, metrics: dict) -> None:
        self.count += 1
        for key, value in metrics.items():
            self.sums[key] = self.sums.get(key, 0.0) + float(value)

    def mean(self, key: str) -> float:
        return self.sums[key] / self.count

    def __len__(self) -> int:
        return self.count


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
    metrics: MetricsMean = field(default_factory=lambda: MetricsMean())
    # `edge.metrics.temporal_instability` over consecutive frames with ground truth
    instability: MetricsMean = field(default_factory=lambda: MetricsMean())
    done: deque = field(default_factory=lambda: deque(maxlen=HISTORY))  # monotonic s
    watch_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))  # each sample's
    # the frames whose points were deskewed: the most a point moved, px
    deskewed: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    source_failed: bool = False
    fatal: str | None = None  # why the run stopped early (FatalInputError), if it did

    def throughput(self) -> float | None:
        """Frames per second between the first and last of the recent finished frames."""
        if len(self.done) < 2 or self.done[-1] <= self.done[0]:
            return None
        return (len(self.done) - 1) / (self.done[-1] - self.done[0])

    def count_error(self, kind: str, detail: object) -> None:
        if self.errors[kind] == 0:
            log.warning("%s: %s (counted, skipped; later ones are only counted)", kind, detail)
        self.errors[kind] += 1


class Pipeline:
    """One frame at a time: `on_scan(scan)`, `on_frame(frame, gt=None) -> FrameOutput`.

    With `engine=None` it is the recorder: frames are checked, rectified and logged with
    the raw scans, and nothing is inferred (`on_frame` returns None). `watch_every`: the
    calibration watched (`edge.calibration_watch`), one sample's budget in this many frames
    with LiDAR points; 0 off."""

    def __init__(self, engine: Engine | None, stereo: StereoCalibration,
                 lidar: LidarExtrinsics | None, logger: McapLogger | None = None,
                 iters: int | None = None, deadline_ms: float | None = None,
                 sync: SyncConfig | None = None, log_raw: bool = True,
                 watch_every: int = 0) -> None:
        plan = engine.plan_for(tuple(stereo.image_size)) if engine else None  # ConfigError
        if engine is not None and plan is not None and not plan.identity:  # if it cannot run
            w, h = plan.scaled
            if plan.bundle != engine.size:  # "budget" or "native": an input of its own
                log.info("camera %dx%d runs at scale %.3f (%dx%d, padded to %dx%d)",
                         *stereo.image_size, plan.scale, w, h, *plan.bundle)
            else:
                log.info("camera %dx%d runs on the %dx%d bundle at scale %.3f (%dx%d, padded)",
                         *stereo.image_size, *engine.size, plan.scale, w, h)
        self.engine, self.logger = engine, logger
        self.iters, self.deadline_ms, self.log_raw = iters, deadline_ms, log_raw
        self.watch_every = watch_every if engine is not None else 0
        # the camera's turn between the frames prepared, for deskewing the points
        self.turn: TurnMeter | None = None
        self.set_calibration(stereo, lidar)
        sync = sync or SyncConfig()
        if lidar is not None and sync.time_offset_ns == 0:
            sync = dataclasses.replace(sync, time_offset_ns=lidar.time_offset_ns)
        self.sync = LidarSync(sync)
        if sync.deskew and engine is not None:
            self.turn = TurnMeter(stereo.focal_px)
        self.stats = PipelineStats()
        self.health = OutputHealth()
        self._unpaired_since_ns: int | None = None  # first frame of a run without LiDAR
        self._warned_unpaired = False
        if lidar is None and engine is not None:
            log.warning("no LiDAR extrinsics in the calibration: running stereo only (add a "
                        "[lidar] section: edge-depth calibrate lidar)")
        self._lock = threading.Lock()
        # the last frame's (seq, error map), the map None without ground truth
        self._last_error: tuple[int, np.ndarray | None] | None = None
        # [engine] rate = "camera": the frames gone on before their scans (`goes_ahead`), and
        # the last frames' stamps (the camera's period)
        self.ahead_frames = 0
        self._frame_stamps: deque[int] = deque(maxlen=16)
        # [engine] rate = "camera": key frames and the frames between (edge.runtime.propagate)
        self.propagator = Propagator() if engine is not None and \
            engine.options.rate == "camera" else None
        if self.propagator is not None and sync.mode == "accumulate":
            log.warning("[engine] rate = \"camera\" carries depth between the scans of a "
                        "spinning LiDAR (sync \"nearest\"); with sync \"accumulate\" (a 2-D "
                        "scanner) every frame gets points of its own and is a key frame")
        if engine is not None:
            engine.warm_up(camera=tuple(stereo.image_size))

    def set_calibration(self, stereo: StereoCalibration, lidar: LidarExtrinsics | None) -> None:
        self.stereo, self.lidar = stereo, lidar
        self.rectifier = stereo.rectifier()
        self.focal_px, self.baseline_m = stereo.focal_px, stereo.baseline_m
        self.principal_point = stereo.principal_point
        self._projected: tuple[np.ndarray, np.ndarray] | None = None  # (points, their map)
        self.watch = None if lidar is None or self.watch_every < 1 else \
            CalibrationWatch(stereo, lidar.T_cam_lidar, self.watch_every)
        carry = getattr(self, "propagator", None)  # set after the first calibration
        if carry is not None:  # no key frame of the old calibration carried
            carry.last = None
        if self.turn is not None:  # a recording's own calibration, later
            self.turn = TurnMeter(stereo.focal_px)
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

    def goes_ahead(self, stamp_ns: int) -> bool:
        """At the camera's rate, whether a frame goes on without waiting for its scans, and
        is carried unpaired: a frame nearer the next scan than the key frame's own (by
        "nearest" it would pair with the next and wait for it) but before that scan is due,
        less half a frame period. So the frame nearest each scan is its key frame whether
        that scan has arrived when the frame is taken or not (a backlog, a replay's order),
        and the frames before it are carried from the key frame before. Only paired by
        "nearest", from a key frame with a scan that can be carried to it
        (`Propagator.can_carry`)."""
        with self._lock:
            return self._goes_ahead(stamp_ns)

    def _goes_ahead(self, stamp_ns: int) -> bool:
        """`goes_ahead`, the lock held."""
        carry = self.propagator
        if carry is None or self.sync.config.mode != "nearest" or carry.last is None or \
                carry.last.scan_ns is None or not carry.can_carry(stamp_ns):
            return False
        scan_period, frame_period = self.sync.period_ns(), _frame_period(self._frame_stamps)
        since = stamp_ns - carry.last.scan_ns
        return scan_period > 0 and frame_period > 0 and \
            scan_period / 2 < since < scan_period - frame_period / 2

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
        """The three stages in a row (replay, the demo, tests), then the watch's sample."""
        prepared = self.prepare(frame, gt, sync_wait_ms)
        if prepared is None:
            return None
        out = self.finish(prepared, self.infer(prepared))
        self.watch_sample(prepared)
        return out

    def prepare(self, frame: StereoFrame, gt: np.ndarray | None = None,
                sync_wait_ms: float = 0.0, arrived: float | None = None) -> Prepared | None:
        """Stage 1: size check, rectification, the synced scans projected. None when the
        frame is skipped (counted) or, recording, already logged. `arrived`: live, the
        perf_counter at which the frame entered the capture queue (its wait there and the
        frame's whole time in the daemon, `end_to_end`, are then in the timings)."""
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
        if self.turn is not None and self.lidar is not None:
            self.turn.frame(frame.stamp_ns, left)
        with self._lock:
            # at the camera's rate, a frame before the scan nearest it is due is carried: it
            # is not paired (nor counted unpaired) with the scans there are
            ahead = self.lidar is not None and self._goes_ahead(frame.stamp_ns)
            self.ahead_frames += ahead
            self._frame_stamps.append(frame.stamp_ns)
        points, points_stamp_ns, sparse = (None, None, np.zeros(left.shape, np.float32)) \
            if ahead else self._pair(frame.stamp_ns, left.shape)
        t2 = time.perf_counter()
        return Prepared(frame, left, right, sparse, gt, t0, dict(
            rectify=(t1 - t0) * 1000, project=(t2 - t1) * 1000, sync_wait=sync_wait_ms),
            points=points, points_stamp_ns=points_stamp_ns, arrived=arrived, ahead=ahead)

    def _pair(self, frame_ns: int, shape: tuple[int, ...]
              ) -> tuple[np.ndarray | None, int | None, np.ndarray]:
        """The synced scans of a frame: their points (None: none), their stamp (camera
        clock) and their sparse disparity (zeros without, or without LiDAR extrinsics)."""
        with self._lock:
            points = self.sync.points_for(frame_ns)
            points_stamp_ns = self.sync.last_points_stamp_ns if len(points) else None
            times = self.sync.last_points_times_ns
        if self.lidar is not None:
            self._check_pairing(frame_ns, len(points) > 0)
        if not len(points):
            return None, None, np.zeros(shape, np.float32)
        assert points_stamp_ns is not None
        return points, points_stamp_ns, np.zeros(shape, np.float32) if self.lidar is None \
            else self._project(points, frame_ns, points_stamp_ns if times is None else times)

    def _project(self, points: np.ndarray, frame_ns: int, times_ns) -> np.ndarray:
        """The points' sparse disparity. While the camera turns, each point is first moved by
        the turn between its own time (`times_ns`: (N,) or the scan's stamp, camera clock)
        and the frame's, where that moves one by `camera_turn.DESKEW_MIN_PX` or more;
        otherwise projected once per scan: frames paired with the same scan (a 10 Hz LiDAR
        beside a 30 Hz camera) reuse its map (read-only downstream)."""
        assert self.lidar is not None
        T = self.lidar.T_cam_lidar
        if self.turn is not None:
            moved, moved_px = deskewed(points, times_ns, frame_ns, self.turn.rate(),
                                       self.focal_px, T)
            if moved_px:
                self.stats.deskewed.append(moved_px)
                return project_to_disparity(moved, self.stereo, T)[0]
        last = self._projected
        if last is not None and last[0] is points:
            return last[1]
        sparse, _ = project_to_disparity(points, self.stereo, T)
        self._projected = (points, sparse)
        return sparse

    def infer(self, p: Prepared) -> DepthResult:
        """Stage 2: the engine (its deadline counts from the start of `prepare`)."""
        assert self.engine is not None, "the recorder infers nothing"
        p.queued_ms = (time.perf_counter() - p.t0) * 1000 - p.timings["rectify"] \
            - p.timings["project"]
        carry = self.propagator
        stamp = p.frame.stamp_ns  # ahead: unless a new calibration dropped the key frame
        if carry is not None and ((p.ahead and carry.can_carry(stamp)) or
                                  not carry.wants_engine(stamp, p.points_stamp_ns)):
            carried = carry.carry(stamp, p.left, self.focal_px, self.baseline_m,
                                  self.principal_point)
            if carried is not None:  # else the flow is lost: a key frame
                p.carried = True
                carry.ahead += p.ahead
                return carried
        if p.ahead:  # not carried after all (the flow lost, a new calibration): paired now
            with self._lock:
                self.ahead_frames -= 1
            p.ahead = False
            p.points, p.points_stamp_ns, p.sparse = self._pair(stamp, p.left.shape)
        result = self.engine.infer(p.left, p.right, p.sparse, iters=self.iters,
                                   deadline_ms=self.deadline_ms, focal_px=self.focal_px,
                                   baseline_m=self.baseline_m, stamp_ns=p.frame.stamp_ns,
                                   started=p.t0)
        if carry is not None:
            carry.key(p.frame.stamp_ns, p.points_stamp_ns, p.left, result)
        return result

    def watch_sample(self, p: Prepared) -> None:
        """The calibration watch's turn meter, and a sample when one is due: after the frame's
        inference on the engine's thread (its network is the reference), once the result is
        handed on, so no frame's latency carries it; a sample's ms go in `stats.watch_ms`."""
        watch = self.watch
        if watch is None or self.engine is None:
            return
        t = time.perf_counter()
        try:
            watch.frame(p.frame.stamp_ns, p.left)  # every frame: the turn between frames
            if p.points is None or p.carried or not watch.due():  # a carried frame: the
                return  # engine's last encoding is its key frame's
            gap_s = 0.0 if p.points_stamp_ns is None else \
                (p.points_stamp_ns - p.frame.stamp_ns) / 1e9
            watch.add(stereo_reference(self.engine), p.points, gap_s)
        except Exception as exc:  # noqa: BLE001 - the watch must never stop the daemon
            self.stats.count_error("calibration_watch", exc)
        self.stats.watch_ms.append((time.perf_counter() - t) * 1000)

    def finish(self, p: Prepared, result: DepthResult) -> FrameOutput:
        """Stage 3: log, count, score against ground truth. `frame` in the timings is the
        frame's latency from the start of `prepare` to logged."""
        t3 = time.perf_counter()
        frame = p.frame
        raw_ms = 0.0
        if self.logger is not None:
            if self.log_raw:
                self.logger.log_frame(StereoFrame(frame.stamp_ns, frame.seq, p.left, p.right,
                                                  rectified=True))
                if p.gt is not None:
                    self.logger.log_gt(frame.stamp_ns, p.gt)
                raw_ms = (time.perf_counter() - t3) * 1000
            self.logger.log_result(result, p.sparse, self.focal_px, self.principal_point,
                                   p.left)
        t4 = time.perf_counter()
        # engine_queue: from prepared to the engine's start (pipelined: the hand-off);
        # log: all of it, log_raw: of which the rectified pair and (sim) the GT
        timings = dict(result.timings_ms, **p.timings, engine_queue=p.queued_ms,
                       log=(t4 - t3) * 1000, log_raw=raw_ms, frame=(t4 - p.t0) * 1000,
                       iterations=result.iterations)
        # capture_queue: live, the frame's wait for this thread (the LiDAR's wait is
        # sync_wait); end_to_end: queued (or, without a queue, the LiDAR's wait) to logged
        if p.arrived is not None:
            timings["capture_queue"] = (p.t0 - p.arrived) * 1000 - p.timings["sync_wait"]
        timings["end_to_end"] = timings["frame"] + p.timings["sync_wait"] + \
            timings.get("capture_queue", 0.0)
        timings.update(_shares(result))
        if result.lidar_noise_px is not None:  # [engine] align_lidar, denoise_lidar
            timings["lidar_noise_px"] = result.lidar_noise_px
            timings["lidar_smoothed"] = float(self.engine is not None and
                                              self.engine.lidar_denoise is not None and
                                              smooths(result.lidar_noise_px))
        if (found := result.lidar_offset) is not None:  # [engine] align_lidar
            timings["lidar_put_back"] = float(found.moves)
            if found.moves:
                timings.update(lidar_dx_px=float(found.dx), lidar_dy_px=float(found.dy),
                               lidar_turn_deg=found.turn_deg)
        metrics, error = None, None
        if p.gt is not None and p.gt.shape == result.disparity.shape:
            metrics = disparity_metrics(result.disparity, p.gt)
            error = error_map(result.disparity, p.gt)
        health = score_frame(result.disparity, p.left, p.sparse)
        with self._lock:  # the instability between consecutive frames only (not over a drop)
            last, self._last_error = self._last_error, (frame.seq, error)
            if error is not None and last is not None and last[0] == frame.seq - 1 and \
                    last[1] is not None and last[1].shape == error.shape:
                change = temporal_instability(error, last[1])
                if np.isfinite(change):
                    self.stats.instability.add(dict(instability=change))
            self.health.add(health)
            self.stats.frames += 1
            self.stats.done.append(time.monotonic())
            self.stats.timings.append(timings)
            self.stats.window.append(timings)
            if metrics is not None:
                self.stats.metrics.add(metrics)
        return FrameOutput(result, p.sparse, p.left, metrics, p.gt)


# the stages' pixel counts (DepthResult) -> the share of the frame each is, % (frame_summary)
SHARES = {"selected_px": "replaced_pct", "refined_px": "refined_pct"}


def _shares(result: DepthResult) -> dict[str, float]:
    """Each stage's count as a % of the grid it was counted on (the engine's, scaled and
    padded, not the camera's: a 64x64 pad of a smaller image read over 100 %)."""
    grid = result.counted_px or result.disparity.size
    return {share: 100.0 * count / grid for name, share in SHARES.items()
            if (count := getattr(result, name)) is not None}

