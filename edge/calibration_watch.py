"""The calibration watched: the LiDAR–camera rotation error and, while the camera turns, the
LiDAR's clock offset, estimated from the frames the daemon already processes, with their
uncertainty and a level (docs/calibration.md has the measurements).

A sample's reference is the engine's network run without the LiDAR (`Engine.stereo_only`, two
steps on the frame's own encoding): a disparity that never saw the points, so it cannot follow
them where they are misplaced (the engine's own output does; a block matcher's fattened edges
moved the estimate by 0.1–0.6°). The points are those the left camera sees by the occlusion
filter grown by GROW_PX (the exact filter keeps LiDAR points the camera cannot see behind
edges, and they pull pitch by ~0.1°). For each probe rotation of the calibration — a (pitch,
yaw) grid and a roll line, about the rectified left camera's x (right), y (down) and z
(forward) axes — each point's disparity is compared with the reference's at the pixel it then
lands on: the mean of min(|d − D|, TRUNCATE_PX), HOLE_PX where it lands outside the image. Off
by a rotation, the points near depth edges land on the other surface. A point behind the
surface the camera sees (d < D) costs at most HOLE_PX (BEHIND_PX): the LiDAR, 8 cm above the
camera on the sim rig, sees background over the top of nearer surfaces that the camera cannot,
and with its rows far apart no filter of the points alone finds them all; counted in full they
pulled pitch on scenes with near objects, where a point in front of the seen surface is a
misplacement from any viewpoint (docs/experiments.md has the numbers and the ablation). Where
the evidence is weak: the cap was measured on the sim rig's scenes and its one LiDAR mount.

While the camera turns, points stamped at the wrong time land where the turn in the offset's
time moved them. Each sample keeps the camera's turn rate (`frame`: the images' shift between
the frames around it) and its points' stamp gap; the estimate moves each sample's costs along
yaw by rate × (gap + a candidate offset), and the lowest summed cost over the last WINDOW
samples gives the rotation and the offset together, each refined by a parabola; their
negatives are the errors. The uncertainty is a grouped jackknife's (the estimate without each
of JACKKNIFE_GROUPS interleaved groups of samples).

The uncertainty assumes the samples see different views, so a sample of the view the last
one saw (a robot standing still) replaces it. Samples come from a budget (`due`). The level
and the fixes are `edge.calibration_verdict`'s. Nothing here changes the calibration:
`edge-depth calibrate lidar --refine` writes a new file, the clock offset is the user's to set.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.projection import (
    OcclusionFilterConfig,
    rectified_lidar,
    transform_points,
    visible_points,
)
from edge_depth.calibration_verdict import (
    CLOCK_RESOLUTION_S,
    MIN_SAMPLES,
    RESOLUTION_DEG,
    SETTLING,
    WatchEstimate,
    beyond_px,
    verdict,
    warn_margin,
)
from edge_depth.camera_turn import TurnMeter

# the (pitch, yaw) grid, 9 x 17 probes: yaw reaches further, a turning robot's clock moves it
GRID_STEP_DEG, GRID_REACH_DEG, YAW_REACH_DEG = 0.15, 0.6, 1.2
ROLL_STEP_DEG, ROLL_REACH_DEG = 0.2, 1.2  # the roll line: 13 probes
TRUNCATE_PX, HOLE_PX = 3.0, 1.5
# a point behind the surface the camera sees may be hidden from the camera (the LiDAR sits
# elsewhere): it costs at most what a point without a reference (outside the image) costs
BEHIND_PX = HOLE_PX
GROW_PX = 6
MAX_POINTS = 6000  # per sample, evenly thinned beyond it: a fixed budget
PROBE_CHUNK = 16  # probes evaluated together
MIN_DEPTH_M = 0.2
BANK = 8  # samples the budget may hold back for a turn
TURN_SPACING = 4  # while turning, a sample in this many frames (each a moment of its own)
JACKKNIFE_GROUPS = 5  # the uncertainty's groups of samples
# a scan whose point directions are this flat (smallest / largest singular value) is one plane:
# a 2-D LiDAR (LD06, LD19, RPLIDAR) constrains yaw and the clock, not pitch or roll
PLANAR_RATIO = 0.05
WINDOW = 60  # the samples the estimate stands on: older ones are forgotten (a drift shows)
EVERY = 13  # one sample's budget in this many frames with LiDAR (the daemon's default: < 3 %)
REFERENCE_ITERS = 2
# the LiDAR-camera clock offset: observed while the camera turns (the points then land where
# the turn in the offset's time moved them); searched over ±CLOCK_REACH_S
CLOCK_STEP_S, CLOCK_REACH_S = 0.005, 0.15
MIN_TURN_DPS = 2.0  # the samples' RMS turn rate below which the offset is not observed
MIN_TURN_SAMPLES = 6  # ... and the samples with a turn rate measured


def stereo_reference(engine) -> np.ndarray:
    """The reference for the frame the engine has just inferred: its network without the LiDAR
    (`Engine.stereo_only`, REFERENCE_ITERS steps on the frame's own encoding), (H, W) float32
    px at the camera's size."""
    return engine.stereo_only(REFERENCE_ITERS)


@dataclass(frozen=True)
class _Sample:
    grid: np.ndarray  # the (pitch, yaw) probes' costs
    roll: np.ndarray  # the roll line's
    radius_px: float  # the points' median distance from the image centre
    turn_dps: float  # the camera's turn about its vertical axis, deg/s (NaN: not measured)
    gap_s: float  # the points' stamp minus the frame's, by the configured clock offset
    stamp_ns: int = -1  # the frame's
    planar: bool = False  # the scan is one plane (a 2-D LiDAR)
    view: np.ndarray | None = None  # the frame, small (`TurnMeter.view`)


def is_planar(points: np.ndarray) -> bool:
    """Whether a scan's points (LiDAR frame) lie in one plane through the LiDAR: a 2-D
    scanner's. From their directions' singular values (at most 2 000 of them)."""
    if len(points) < 3:
        return False
    points = points[:: max(1, len(points) // 2000)]
    norms = np.linalg.norm(points, axis=1, keepdims=True)
    directions = points[norms[:, 0] > 0] / norms[norms[:, 0] > 0]
    if len(directions) < 3:
        return False
    values = np.linalg.svd(directions, compute_uv=False)
    return bool(values[-1] < PLANAR_RATIO * values[0])


def _axis(step: float, reach: float) -> np.ndarray:
    n = int(round(reach / step))
    return np.arange(-n, n + 1) * step


def _rotations(angles_deg: np.ndarray) -> np.ndarray:
    """(P, 3) rotation vectors in degrees -> (P, 3, 3)."""
    return np.stack([cv2.Rodrigues(np.radians(a))[0] for a in angles_deg])


def parabola_minimum(xs: np.ndarray, costs: np.ndarray) -> tuple[float, bool]:
    """Where the costs are lowest, refined by a parabola through the lowest probe and its
    neighbours; and whether that is the probes' edge."""
    i = int(np.argmin(costs))
    if 0 < i < len(xs) - 1:
        a, b, c = costs[i - 1], costs[i], costs[i + 1]
        curve = a - 2 * b + c
        if curve > 0:
            return float(xs[i] + 0.5 * (a - c) / curve * (xs[1] - xs[0])), False
        return float(xs[i]), False
    return float(xs[i]), True


class CalibrationWatch:
    """`frame(stamp, left)` on every frame the engine runs; then, on a frame with LiDAR points,
    `due()`, and when True `add(reference, points, gap_s)` with the engine's stereo-only
    disparity, the frame's points (LiDAR frame, metres) and their stamp minus the frame's;
    read `estimate()` at any time (any thread)."""

    def __init__(self, calib: StereoCalibration, T_cam_lidar: np.ndarray,
                 every: int = EVERY) -> None:
        if every < 1:
            raise ValueError(f"every: >= 1, got {every}")
        self.calib, self.T = calib, np.asarray(T_cam_lidar, np.float64)
        self.every = every
        self._credit = BANK * every  # the budget (`due`), in frames: `every` a sample
        self._since = 0  # frames offered since the last sample
        base = OcclusionFilterConfig()
        self._filter = OcclusionFilterConfig(
            window=(base.window[0] + 2 * GROW_PX, base.window[1] + 2 * GROW_PX),
            slack_px=base.slack_px + GROW_PX, relative=0.08, margin_px=1.0)
        self.pitch_axis = _axis(GRID_STEP_DEG, GRID_REACH_DEG)
        self.yaw_axis = _axis(GRID_STEP_DEG, YAW_REACH_DEG)
        pitch, yaw = np.meshgrid(self.pitch_axis, self.yaw_axis, indexing="ij")
        self._grid = np.stack([pitch.ravel(), yaw.ravel(), np.zeros(pitch.size)], 1)
        self.roll_axis = _axis(ROLL_STEP_DEG, ROLL_REACH_DEG)
        # each sample's probe costs: (pitch, yaw) grid, roll line, the points' median
        # distance from the image centre (px)
        self._samples: deque[_Sample] = deque(maxlen=WINDOW)
        self.samples = 0  # all samples taken, the forgotten ones too
        self.turn = TurnMeter(calib.focal_px)  # the camera's turn between frames
        self.clock_axis = _axis(CLOCK_STEP_S, CLOCK_REACH_S)
        self._turned_cache: dict[int, tuple[_Sample, np.ndarray]] = {}
        self._estimate: tuple[tuple, WatchEstimate] | None = None  # (its samples, it)
        self._lock = threading.Lock()  # `add` on the engine's thread, `estimate` on others

    def due(self) -> bool:
        """Whether this frame (one with LiDAR points) becomes a sample. A budget of one sample
        in `every` frames, banked up to BANK samples: spent one in TURN_SPACING frames while
        the camera turns (the clock offset shows only then), else one in `every` frames. Over
        any stretch of frames the samples are at most its length / `every` + BANK."""
        self._since += 1
        self._credit = min(self._credit + 1, BANK * self.every)  # in frames
        if self._credit < self.every:
            return False
        take = self._credit >= BANK * self.every
        if not take and self._since >= TURN_SPACING:
            turn = self.turn.rate()
            take = bool(np.isfinite(turn) and abs(turn) >= MIN_TURN_DPS)
        if take:
            self._credit -= self.every
            self._since = 0
        return take

    def frame(self, stamp_ns: int, left: np.ndarray) -> None:
        """Every frame the engine runs, before `add`: for the camera's turn since the frame
        before (`TurnMeter`); the last sample's turn rate, centred, once the frame after it
        comes."""
        self.turn.frame(stamp_ns, left)
        with self._lock:
            last = self._samples[-1] if self._samples else None
            waiting = last is not None and last.stamp_ns == self.turn.frames[0][0]
        if waiting:  # the last sample's frame and this one: its turn rate, centred
            assert last is not None
            after = self.turn.rate()
            turn = float(np.nanmean([last.turn_dps, after])) \
                if np.isfinite([last.turn_dps, after]).any() else float("nan")
            with self._lock:
                if self._samples and self._samples[-1] is last:
                    self._samples[-1] = dataclasses.replace(last, turn_dps=turn)

    def add(self, reference: np.ndarray, points: np.ndarray, gap_s: float = 0.0) -> bool:
        """A sample: the stereo-only disparity (H, W), the frame's LiDAR points (N, 3) and their
        stamp minus the frame's (s, by the configured offset). False (nothing counted) when no
        point the camera sees lands in the image."""
        cam = self._seen_points(np.asarray(points, np.float64))
        if len(cam) == 0:
            return False
        moves = self._jacobian(cam)
        grid = self._costs(moves, reference, self._grid).reshape(len(self.pitch_axis), -1)
        with self._lock:
            total = sum((x.grid for x in self._samples), grid)
        pitch, yaw = self._grid_minimum(total)[0]
        roll = np.stack([np.full(len(self.roll_axis), pitch), np.full(len(self.roll_axis), yaw),
                         self.roll_axis], 1)
        roll_costs = self._costs(moves, reference, roll)
        f = self.calib.focal_px
        radius = float(np.median(np.hypot(f * cam[:, 0] / cam[:, 2],
                                          f * cam[:, 1] / cam[:, 2])))
        stamp = self.turn.frames[-1][0] if self.turn.frames else -1
        sample = _Sample(grid, roll_costs, radius, self.turn.rate(), float(gap_s), stamp,
                         is_planar(np.asarray(points, np.float64)), self.turn.view())
        with self._lock:
            last = self._samples[-1] if self._samples else None
        # a robot standing still: the same view again replaces the last sample rather than
        # counting twice (its bias would read as certain); the newest points still count
        again = last is not None and self.turn.same_view(last.view, sample.view)
        with self._lock:
            if again and self._samples and self._samples[-1] is last:
                self._samples.pop()
            self._samples.append(sample)
            self.samples += 1
        return True

    def _seen_points(self, points: np.ndarray) -> np.ndarray:
        """The points the left camera sees (grown filter), in the rectified left camera, at most
        MAX_POINTS."""
        if len(points) == 0:
            return np.zeros((0, 3))
        if len(points) > 2 * MAX_POINTS:  # the filter's cost: a point in two is enough
            points = points[::len(points) // (2 * MAX_POINTS)]
        seen = visible_points(points, self.calib, self.T, "left", self._filter)
        cam = transform_points(rectified_lidar(self.calib, self.T), points[seen])
        cam = cam[cam[:, 2] > MIN_DEPTH_M]
        if len(cam) > MAX_POINTS:
            cam = cam[np.linspace(0, len(cam) - 1, MAX_POINTS).astype(int)]
        return cam

    @staticmethod
    def _costs(moves: tuple[np.ndarray, np.ndarray], reference: np.ndarray,
               probes_deg: np.ndarray) -> np.ndarray:
        """Each probe rotation's (P, 3 degrees) mean truncated |d − D| over the points
        (truncated at BEHIND_PX where the point is behind the reference's surface). A
        probe moves each point's (u, v, d) by its first-order change (`_jacobian`): within
        the probes' reach (0.6°, roll 1.2°) the second-order terms stay below 0.1 px."""
        base, jacobian = moves
        probes = np.asarray(probes_deg, np.float32)
        h, w = reference.shape
        flat = reference.ravel()
        out = np.empty(len(probes))
        for start in range(0, len(probes), PROBE_CHUNK):  # a chunk's arrays stay in cache
            chunk = probes[start:start + PROBE_CHUNK]
            u, v, d = (base[c] + chunk @ jacobian[c] for c in range(3))  # (chunk, N) each
            inside = (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
            col = np.clip(u + 0.5, 0, w - 1).astype(np.int32)  # the nearest pixel
            row = np.clip(v + 0.5, 0, h - 1).astype(np.int32)
            row *= w
            row += col
            gap = d - flat[row]  # < 0: the point lies behind the surface the camera sees
            np.clip(gap, -BEHIND_PX, TRUNCATE_PX, out=gap)
            np.abs(gap, out=gap)
            gap[~(inside & np.isfinite(gap))] = HOLE_PX
            out[start:start + PROBE_CHUNK] = gap.mean(axis=1)
        return out

    def _jacobian(self, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points' (u, v, d) at the calibration, (3, N), and their change per degree of
        pitch, yaw and roll, (3 values, 3 axes, N)."""
        f, (cx, cy) = self.calib.focal_px, self.calib.principal_point
        fb = f * self.calib.baseline_m

        def project(points: np.ndarray) -> np.ndarray:
            z = np.maximum(points[:, 2], 1e-3)
            return np.stack([f * points[:, 0] / z + cx, f * points[:, 1] / z + cy, fb / z])

        base = project(cam)
        step = 0.1  # degrees
        columns = [(project(cam @ _rotations(np.eye(3)[k:k + 1] * step)[0].T) - base) / step
                   for k in range(3)]
        return base.astype(np.float32), np.stack(columns, axis=1).astype(np.float32)

    def _grid_minimum(self, costs: np.ndarray) -> tuple[tuple[float, float], bool]:
        """(pitch, yaw) of the lowest probe, refined; pitch 0 when `costs` is the
        calibration's row alone (a 2-D LiDAR)."""
        i, j = np.unravel_index(int(np.argmin(costs)), costs.shape)
        if costs.shape[0] == 1:
            yaw, edge_y = parabola_minimum(self.yaw_axis, costs[0])
            return (0.0, yaw), edge_y
        pitch, edge_p = parabola_minimum(self.pitch_axis, costs[:, j])
        yaw, edge_y = parabola_minimum(self.yaw_axis, costs[i, :])
        return (pitch, yaw), edge_p or edge_y

    def _minimum(self, grid: np.ndarray, roll: np.ndarray) -> tuple[np.ndarray, bool]:
        """(pitch, yaw, roll) of the lowest probes, and whether one is at the probes' edge;
        with the calibration's pitch row alone (a 2-D LiDAR) pitch and roll stay 0."""
        (pitch, yaw), edge = self._grid_minimum(grid)
        if grid.shape[0] == 1:
            return np.array([0.0, yaw, 0.0]), edge
        r, edge_r = parabola_minimum(self.roll_axis, roll)
        return np.array([pitch, yaw, r]), edge or edge_r

    def estimate(self) -> WatchEstimate:
        """The current estimate ("settling" before MIN_SAMPLES samples); computed again only
        after a new sample (or its turn rate) arrived."""
        with self._lock:
            window = list(self._samples)
            key = (self.samples, repr(window[-1].turn_dps) if window else "")
        if self._estimate is not None and self._estimate[0] == key:
            return self._estimate[1]
        estimate = self._estimate_from(window)
        self._estimate = (key, estimate)
        return estimate

    def _estimate_from(self, window: list[_Sample]) -> WatchEstimate:
        n = len(window)
        if n < MIN_SAMPLES:
            return WatchEstimate((0.0,) * 3, (0.0,) * 3, 0.0, SETTLING, n)
        turn = np.array([x.turn_dps for x in window])
        known = np.isfinite(turn)
        rms_turn = float(np.sqrt(np.mean(turn[known] ** 2))) if known.any() else 0.0
        observed = known.sum() >= MIN_TURN_SAMPLES and rms_turn >= MIN_TURN_DPS
        offsets = self.clock_axis
        # each sample's (pitch, yaw) costs moved along yaw by the turn during its points'
        # true age at each candidate offset: (samples, offsets, pitch, yaw); not observed,
        # only the offset 0 (the configured clock)
        grids = np.stack([self._turned_grid(x) for x in window])
        planar = 2 * sum(x.planar for x in window) > n
        if planar:  # pitch held at the calibration's: the (offset, yaw) costs of its row
            centre = len(self.pitch_axis) // 2
            grids = grids[:, :, centre:centre + 1]
        if not observed:
            zero = len(offsets) // 2
            grids, offsets = grids[:, zero:zero + 1], offsets[zero:zero + 1]
        roll = np.stack([x.roll for x in window])
        total, roll_total = grids.sum(axis=0), roll.sum(axis=0)
        best, clock, at_reach = self._joint_minimum(total, roll_total, offsets)
        # the grouped jackknife: the estimate without each of JACKKNIFE_GROUPS interleaved
        # groups in turn (leaving out one sample moves a lowest probe by a whole step or
        # none, which the single-sample jackknife blows up by n - 1)
        values = []
        for g in range(JACKKNIFE_GROUPS):
            b, c, _ = self._joint_minimum(total - grids[g::JACKKNIFE_GROUPS].sum(axis=0),
                                          roll_total - roll[g::JACKKNIFE_GROUPS].sum(axis=0),
                                          offsets)
            values.append(list(b) + [c])
        spread = np.asarray(values) - np.mean(values, axis=0)
        sigma = np.sqrt((JACKKNIFE_GROUPS - 1) / JACKKNIFE_GROUPS * (spread ** 2).sum(axis=0))
        radius = float(np.mean([x.radius_px for x in window]))
        if planar:  # not observed: reported as 0, no part of the level
            best[[0, 2]], sigma[[0, 2]] = 0.0, 0.0
        error = -best
        lever = np.radians([self.calib.focal_px, self.calib.focal_px, radius])  # px per °
        clock_lever = self.calib.focal_px * np.radians(rms_turn)  # px per second of offset
        errors = np.r_[error, clock if observed else 0.0]
        levers = np.r_[lever, clock_lever]
        resolution = np.r_[RESOLUTION_DEG, CLOCK_RESOLUTION_S]
        shift, level = verdict(errors, sigma, levers, resolution)
        parts = beyond_px(errors, warn_margin(sigma, resolution), levers)
        e, s = [float(x) for x in error], [float(x) for x in sigma[:3]]
        return WatchEstimate((e[0], e[1], e[2]), (s[0], s[1], s[2]), shift, level, n, at_reach,
                             float(clock) if observed else None,
                             float(sigma[3]) if observed else None, rms_turn, planar,
                             float(np.hypot.reduce(parts[:3])), float(parts[3]))

    def _turned_grid(self, sample: _Sample) -> np.ndarray:
        """The sample's (pitch, yaw) costs at each candidate clock offset, (offsets, pitch,
        yaw): kept while the sample is in the window."""
        cached = self._turned_cache.get(id(sample))
        if cached is None or cached[0] is not sample:
            turn = sample.turn_dps if np.isfinite(sample.turn_dps) else 0.0
            moved = turn * (sample.gap_s + self.clock_axis)
            cached = (sample, self._turned(sample.grid[None], moved[None])[0])
            self._turned_cache[id(sample)] = cached
            with self._lock:
                alive = {id(x) for x in self._samples}
            for gone in [k for k in self._turned_cache if k not in alive]:
                del self._turned_cache[gone]
        return cached[1]

    def _turned(self, grids: np.ndarray, turn_deg: np.ndarray) -> np.ndarray:
        """(samples, pitch, yaw) costs, each sample's evaluated at yaw − its turn per offset
        (samples, offsets; degrees), linearly between the probes and held beyond them."""
        axis = self.yaw_axis
        at = (axis[None, None, :] - turn_deg[:, :, None] - axis[0]) / (axis[1] - axis[0])
        at = np.clip(at, 0, len(axis) - 1)
        lo = np.minimum(at.astype(int), len(axis) - 2)
        frac = (at - lo)[:, :, None, :]
        idx = np.arange(len(grids))[:, None, None, None]
        rows = np.arange(grids.shape[1])[None, None, :, None]
        lo4 = lo[:, :, None, :]
        return grids[idx, rows, lo4] * (1 - frac) + grids[idx, rows, lo4 + 1] * frac

    def _joint_minimum(self, total: np.ndarray, roll: np.ndarray, offsets: np.ndarray
                       ) -> tuple[np.ndarray, float, bool]:
        """The (pitch, yaw, roll) probe and the clock offset whose summed costs are lowest
        (`total`: offsets, pitch, yaw)."""
        profile = total.reshape(len(offsets), -1).min(axis=1)
        k = int(np.argmin(profile))
        clock = parabola_minimum(offsets, profile)[0] if len(offsets) > 1 else 0.0
        best, at_reach = self._minimum(total[k], roll)
        return best, clock, at_reach
