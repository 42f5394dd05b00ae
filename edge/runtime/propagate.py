"""Depth at the camera's rate (`[engine] rate = "camera"`): the engine on key frames — a frame
with a scan its key frame did not have — and, on the frames between, the last key frame's
disparity and confidence carried along the optical flow from the frame's left image to the
key frame's (OpenCV's DIS, its ultrafast preset: ~2.5 ms a 640×400 frame on two cores, and
~1 ms more for the check that the flow is not lost: `LOST_RESIDUAL`).

Any motion is carried (the camera's turn and drive, an object's own), the disparity itself is
not changed: driving at 0.3 m/s it grows by ~3 % between scans at 1 m (docs/experiments.md,
2026-12-07: 1.13–1.22× the key frames' EPE between scans on the moving sim worlds, steadier
than the engine on every frame). A key frame older than MAX_KEY_AGE_S is not carried. Keyed
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
        self._grid: tuple[np.ndarray, np.ndarray] | None = None  # pixel coordinates (x, y)

    def counters(self) -> dict[str, int]:
        """Since the start, for /diagnostics: key frames (the engine; `lost`: of them, those
        whose flow was lost) and frames carried."""
        return dict(key_frames=self.keys, carried=self.carried, lost=self.lost)

    def wants_engine(self, stamp_ns: int, scan_ns: int | None) -> bool:
        """Whether a frame is a key frame: no key frame yet, no LiDAR, a scan the key frame
        did not have, or a key frame too old to carry."""
        last = self.last
        return last is None or scan_ns is None or scan_ns != last.scan_ns or \
            stamp_ns - last.stamp_ns > MAX_KEY_AGE_S * 1e9 or stamp_ns < last.stamp_ns

    def key(self, stamp_ns: int, scan_ns: int | None, left: np.ndarray,
            result: DepthResult) -> None:
        self.last = KeyFrame(stamp_ns, scan_ns, np.ascontiguousarray(left, np.uint8), result)
        self.keys += 1

    def carry(self, stamp_ns: int, left: np.ndarray, focal_px: float | None,
              baseline_m: float | None) -> DepthResult | None:
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

        def carried(image: np.ndarray) -> np.ndarray:
            return cv2.remap(image, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

        residual = cv2.absdiff(carried(last.left), grey)
        if float(np.mean(residual)) > LOST_RESIDUAL:
            self.lost += 1
            return None
        disparity = carried(last.result.disparity)
        confidence = None if last.result.confidence is None else \
            carried(last.result.confidence)
        depth, valid = disparity_to_depth(disparity, focal_px, baseline_m)
        self.carried += 1
        return DepthResult(stamp_ns=int(stamp_ns), disparity=disparity, depth=depth,
                           valid=valid, iterations=0,
                           timings_ms={"propagate": (time.perf_counter() - t) * 1000},
                           confidence=confidence)
