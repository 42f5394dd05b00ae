"""Depth at the camera's rate (`[engine] rate = "camera"`): the engine on key frames — a frame
with a scan its key frame did not have — and, on the frames between, the last key frame's
disparity and confidence carried along the optical flow from the frame's left image to the
key frame's (OpenCV's DIS, its ultrafast preset: ~2.5 ms a 640×400 frame on two cores,
~1 ms more for the check that the flow is not lost, `LOST_RESIDUAL`, and ~1.6 ms for the
depth change below).

Any motion is carried (the camera's turn and drive, an object's own). The disparity itself
changes as the camera moves (driving at 0.3 m/s it grows by ~3 % between scans at 1 m): the
camera's motion since the key frame is fitted to the flow and the carried disparity
(`ego_motion`: the motion field of a rigid scene, six unknowns, a robust least squares on a
grid of pixels) and each pixel's disparity scaled by its depth's change; where the fit is
unsure (few pixels, a large residual, an implausible change) it stays as it was. A key
frame older than MAX_KEY_AGE_S is not carried. Keyed
on the scan's stamp, so it carries between the scans of a spinning LiDAR paired by "nearest";
with "accumulate" (a 2-D scanner) every frame has points of its own and is a key frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.runtime.engine import disparity_to_depth
from edge_depth.types import DepthResult

MAX_KEY_AGE_S = 0.25  # a key frame carried no further than this (a stalled LiDAR)
# the flow is lost (a scene cut, a blur, a flash) where the key frame's left image carried
# along it differs from the frame's by more than this mean |Δ| (grey levels): on the moving sim
# worlds a carry reads 2-6 over one or two frames and 11 over three, a scene cut 65; at 20 the
# live sim robot (frames dropped, carries longer) lost 4-5 carries a run that were not cuts
LOST_RESIDUAL = 32.0
INTERPOLATION = cv2.INTER_NEAREST
FIT_PIXELS = 4000  # the motion fit reads a grid of about this many pixels (every 8th at 640x400)
# the fewest grid pixels it fits (200 equations for 6 unknowns): a noisier camera leaves few
# within FIT_MAX_GREY (on the moving sim worlds 51-465 of ~4000 on a third of the frames)
FIT_MIN_PIXELS = 100
# after the Huber passes, a last one without the pixels whose residual is over this many
# robust σ (1.4826 × the median absolute deviation) above the median: what moves on its own
OUTLIER_SIGMAS = 3.0
FIT_MAX_GREY = 8  # a grid pixel is fitted where the carried image is within this of the frame's
# the fit is unsure where the median pixel's flow misses the rigid motion's by more than
# this (px: DIS's own error on the sim worlds is a few tenths) or where it would change a
# disparity by more than MAX_SCALE_CHANGE (on over 1 % of the pixels) between a key frame and
# a frame 0.25 s later
FIT_MAX_RESIDUAL_PX = 1.5
MAX_SCALE_CHANGE = 0.15


@dataclass
class KeyFrame:
    stamp_ns: int
    scan_ns: int | None  # the stamp of the scan it ran with (None: no LiDAR)
    left: np.ndarray  # grey uint8, contiguous (DIS's input)
    result: DepthResult


class Propagator:
    """`key(...)` after each engine run; `carry(...)` on a frame between scans."""

    def __init__(self) -> None:
        self.flow = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
        self.last: KeyFrame | None = None
        self.keys = self.carried = self.lost = 0
        self.scaled = 0  # carried frames whose disparity the fitted motion scaled
        self.ahead = 0  # carried frames that went on before the scan nearest them was due
        self.scans = 0  # scans a key frame ran with (each once)
        self._grid: tuple[np.ndarray, np.ndarray] | None = None  # pixel coordinates (x, y)

    def counters(self) -> dict[str, int]:
        """Since the start, for /diagnostics: key frames (the engine; `lost`: of them, those
        whose flow was lost; `scans`: the scans they ran with, each counted once) and frames
        carried (`scaled`: of them, those whose disparity the fitted motion changed; `ahead`:
        those that went on before the scan nearest them was due)."""
        return dict(key_frames=self.keys, carried=self.carried, lost=self.lost,
                    scaled=self.scaled, scans=self.scans, ahead=self.ahead)

    def can_carry(self, stamp_ns: int) -> bool:
        """Whether the last key frame may be carried to a frame at `stamp_ns` (it is not
        older than MAX_KEY_AGE_S and not after the frame)."""
        last = self.last
        return last is not None and 0 <= stamp_ns - last.stamp_ns <= MAX_KEY_AGE_S * 1e9

    def wants_engine(self, stamp_ns: int, scan_ns: int | None) -> bool:
        """Whether a frame is a key frame: no key frame yet, no LiDAR, a scan the key frame
        did not have, or a key frame too old to carry."""
        last = self.last
        return last is None or not self.can_carry(stamp_ns) or scan_ns is None or \
            scan_ns != last.scan_ns

    def key(self, stamp_ns: int, scan_ns: int | None, left: np.ndarray,
            result: DepthResult) -> None:
        if scan_ns is not None and (self.last is None or self.last.scan_ns != scan_ns):
            self.scans += 1
        self.last = KeyFrame(stamp_ns, scan_ns, np.ascontiguousarray(left, np.uint8), result)
        self.keys += 1

    def carry(self, stamp_ns: int, left: np.ndarray, focal_px: float | None,
              baseline_m: float | None,
              principal_point: tuple[float, float] | None = None) -> DepthResult | None:
        """The last key frame's disparity (and confidence) seen from this frame; None when
        the flow is lost (LOST_RESIDUAL): the frame must be a key frame."""
        last = self.last
        assert last is not None, "carry follows a key frame"
        t = time.perf_counter()
        grey = np.ascontiguousarray(left, np.uint8)
        flow = self.flow.calc(grey, last.left, None)
        if self._grid is None or self._grid[0].shape != grey.shape:  # kept while the size stays
            h, w = grey.shape
            self._grid = np.meshgrid(np.arange(w, dtype=np.float32),
                                     np.arange(h, dtype=np.float32))
        xs, ys = self._grid[0] + flow[..., 0], self._grid[1] + flow[..., 1]

        def carried(image: np.ndarray, how: int = cv2.INTER_LINEAR) -> np.ndarray:
            return cv2.remap(image, xs, ys, how, borderMode=cv2.BORDER_REPLICATE)

        residual = cv2.absdiff(carried(last.left), grey)
        if float(np.mean(residual)) > LOST_RESIDUAL:
            self.lost += 1
            return None
        disparity = carried(last.result.disparity, INTERPOLATION)
        if focal_px and baseline_m:
            scale = depth_change(flow, disparity, residual, focal_px, baseline_m,
                                 principal_point)
            if scale is not None:
                disparity *= scale
                self.scaled += 1
        confidence = None if last.result.confidence is None else \
            carried(last.result.confidence)
        depth, valid = disparity_to_depth(disparity, focal_px, baseline_m)
        self.carried += 1
        return DepthResult(stamp_ns=int(stamp_ns), disparity=disparity, depth=depth,
                           valid=valid, iterations=0,
                           timings_ms={"propagate": (time.perf_counter() - t) * 1000},
                           confidence=confidence)


def ego_motion(flow: np.ndarray, disparity: np.ndarray, usable: np.ndarray, focal_px: float,
               baseline_m: float, principal_point: tuple[float, float]
               ) -> tuple[np.ndarray, float, int] | None:
    """The camera's motion from a frame to its key frame, fitted to the optical flow (frame
    → key frame, (H, W, 2)) and the key frame's disparity carried to the frame, on a grid of
    `usable` pixels whose flow stays in the image: a point p of the frame is R p + T in the
    key frame's, R ≈ I + [ω]×, and its image moves by ((f Tx − x Tz) d / (f B) + …, …) plus
    the rotation's terms (x, y from the principal point), linear in (ω, T). Huber-weighted
    least squares (three passes, 1 px), then once more without the pixels over OUTLIER_SIGMAS
    robust σ above the median residual (an object moving on its own weighs nothing, not
    merely less). Returns ((ωx, ωy, ωz, Tx, Ty, Tz): rad, m), the
    median residual (px) and the pixels used; None with fewer than FIT_MIN_PIXELS or a
    singular system."""
    f, b = float(focal_px), float(baseline_m)
    cx, cy = principal_point
    h, w = disparity.shape
    step = max(1, int(np.sqrt(disparity.size / FIT_PIXELS)))
    grid = (slice(step // 2, None, step), slice(step // 2, None, step))
    d, moved = disparity[grid], flow[grid]
    gy, gx = np.mgrid[step // 2:h:step, step // 2:w:step]
    lands = (gx + moved[..., 0] >= 0) & (gx + moved[..., 0] <= w - 1) & \
        (gy + moved[..., 1] >= 0) & (gy + moved[..., 1] <= h - 1)
    keep = usable[grid] & lands & np.isfinite(d) & (d > 0)
    if np.count_nonzero(keep) < FIT_MIN_PIXELS:
        return None
    x, y = gx[keep] - cx, gy[keep] - cy
    d = d[keep].astype(np.float64)
    u, v = (moved[..., k][keep].astype(np.float64) for k in (0, 1))
    zero = np.zeros_like(x)
    rows_u = np.stack([-x * y / f, f + x * x / f, -y, d / b, zero, -x * d / (f * b)], axis=1)
    rows_v = np.stack([-(f + y * y / f), x * y / f, x, zero, d / b, -y * d / (f * b)], axis=1)
    A, rhs = np.concatenate([rows_u, rows_v]), np.concatenate([u, v])
    weight = np.ones(len(A))
    try:
        for _ in range(3):
            motion, residual = _solve(A, rhs, weight, len(x))
            weight = np.tile(1.0 / np.maximum(residual, 1.0), 2)  # Huber at 1 px
        centre = np.median(residual)
        spread = 1.4826 * np.median(np.abs(residual - centre))
        inlier = residual <= centre + OUTLIER_SIGMAS * max(spread, 1e-3)
        motion, residual = _solve(A, rhs, np.tile(inlier, 2) * weight, len(x))
    except np.linalg.LinAlgError:  # e.g. every usable pixel on one line
        return None
    return motion, float(np.median(residual)), len(x)


def _solve(A: np.ndarray, rhs: np.ndarray, weight: np.ndarray, pixels: int
           ) -> tuple[np.ndarray, np.ndarray]:
    """The weighted least squares of A m = rhs by its normal equations (6 × 6), the columns
    scaled to one size: (m, each pixel's residual, px — its u and v rows the first and second
    `pixels` of A)."""
    Aw = A * weight[:, None]
    norm = np.sqrt(np.einsum("ij,ij->j", Aw, A)) + 1e-12
    motion = np.linalg.solve((Aw.T @ A) / np.outer(norm, norm), (Aw.T @ rhs) / norm) / norm
    miss = A @ motion - rhs
    return motion, np.hypot(miss[:pixels], miss[pixels:])


def depth_change(flow: np.ndarray, disparity: np.ndarray, residual: np.ndarray,
                 focal_px: float, baseline_m: float,
                 principal_point: tuple[float, float] | None = None) -> np.ndarray | None:
    """Each pixel's disparity now over the key frame's (H, W) from `ego_motion`: its depth in
    the key frame is z (1 + ωx y / f − ωy x / f) + Tz, so to first order the ratio is
    1 + ωx y / f − ωy x / f + Tz d / (f B). Fitted on the pixels whose flow matches the
    images (`residual`, the key frame's image carried along the flow against the frame's,
    under FIT_MAX_GREY). None where the fit is unsure: too few pixels, a median residual
    over FIT_MAX_RESIDUAL_PX, or a change over MAX_SCALE_CHANGE on more than 1 % of the
    known pixels; elsewhere each pixel's change is clipped to MAX_SCALE_CHANGE."""
    h, w = disparity.shape
    cx, cy = principal_point if principal_point is not None else ((w - 1) / 2, (h - 1) / 2)
    fitted = ego_motion(flow, disparity, residual < FIT_MAX_GREY, focal_px, baseline_m,
                        (cx, cy))
    if fitted is None or fitted[1] > FIT_MAX_RESIDUAL_PX:
        return None
    (wx, wy, _, _, _, tz), f = fitted[0], float(focal_px)
    x = np.arange(w, dtype=np.float32) - np.float32(cx)
    y = np.arange(h, dtype=np.float32) - np.float32(cy)
    turn = (np.float32(wx / f) * y)[:, None] - (np.float32(wy / f) * x)[None, :]
    known = np.isfinite(disparity) & (disparity > 0)
    change = turn + np.float32(tz / (f * baseline_m)) * np.where(known, disparity, 0.0)
    beyond = int(np.count_nonzero(np.abs(change[known]) > MAX_SCALE_CHANGE))
    if beyond > 0.01 * int(np.count_nonzero(known)):
        return None
    np.clip(change, -MAX_SCALE_CHANGE, MAX_SCALE_CHANGE, out=change)
    return (1.0 + change).astype(np.float32, copy=False)
