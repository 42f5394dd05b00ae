"""A LiDAR map that sits off the image, moved back where the image's own edges say by how much.

A LiDAR–camera calibration that is off by a fraction of a degree moves the whole projected map
by a pixel or a few (an error in the LiDAR's pitch or yaw) or turns it about the image's
centre (one in its roll), and every point at a depth edge then lands on the wrong side of it.
Where two neighbouring points of one image row (`lidar_rows.row_runs`) differ by more than
JUMP_PX of disparity — or, on a noisy map, by more than JUMP_SIGMAS standard deviations of two
points' difference (`lidar_rows.noise_level`) — the scene has a depth edge between them, and
the left image an intensity edge there. Over the map's turns (TURNS_DEG) and shifts within
±REACH_PX, the mean edge strength (Sobel magnitude) of the left image at where the jumps would
be without them peaks at the map's misregistration; where that peak is not the identity, rests
on at least MIN_JUMPS jumps and beats the identity's score by MIN_GAIN, the map is put back by
it. A map whose occlusion filter left no such jumps (the background hidden beside every near
edge removed), or too noisy to show its edges, is left as it is. The calibration watch
(`edge.calibration_watch`) is what finds the calibration's error over many frames and says how
to fix it; this keeps each frame's depth edges where the image has them meanwhile
(docs/experiments.md, 2026-12-06 19:32 and 21:45).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.runtime.edge_match import as_grey8
from edge_depth.runtime.lidar_rows import map_points, measured, row_noise, row_runs

REACH_PX = 4  # the largest offset searched, each way
JUMP_PX = 1.5  # disparity between neighbouring points that marks a depth edge ...
# ... or this many standard deviations of two noisy points' difference, if more: on a noisy
# map (σ 0.75 px) one neighbour pair in six differs by 1.5 px on no edge, and the search's
# peak fell on a random offset (docs/experiments.md, 2026-12-06 21:45)
JUMP_SIGMAS = 4.0
MIN_JUMPS = 40
MIN_GAIN = 1.15  # the peak's score over the score at (0, 0)
TURNS_DEG = tuple(np.arange(-4, 5) * 0.25)  # the turns searched, about the image centre
MAX_JUMPS = 200  # the most jumps the search reads (an even subset of a dense LiDAR's)


def depth_jumps(sparse: np.ndarray, points: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the depth edges between neighbouring points of one row: where two
    row neighbours differ by more than `jump_px` at the map's noise level, the pixel between
    them. `points`: `map_points(sparse)`, if at hand."""
    return _jumps_and_noise(sparse, points)[:2]


def _jumps_and_noise(sparse: np.ndarray, points: tuple[np.ndarray, np.ndarray] | None
                     ) -> tuple[np.ndarray, np.ndarray, float | None]:
    """`depth_jumps`' rows and columns, and the map's noise level they were told by
    (`lidar_rows.measured`: None on a map too sparse to measure it)."""
    ys, xs = map_points(sparse) if points is None else points
    d = sparse[ys, xs]
    run = row_runs(ys, xs)
    level = measured(row_noise(d, xs, run))
    jump = (run[1:] == run[:-1]) & (np.abs(d[1:] - d[:-1]) > jump_px(level))
    return ys[:-1][jump], (xs[:-1][jump] + xs[1:][jump]) // 2, level


def jump_px(level: float | None) -> float:
    """The difference between row neighbours that marks a depth edge on a map of this noise
    level (`lidar_rows.measured`): JUMP_PX, or JUMP_SIGMAS standard deviations of two points'
    difference if more; JUMP_PX where the level is unknown (None)."""
    if level is None:
        return JUMP_PX
    return max(JUMP_PX, JUMP_SIGMAS * float(np.sqrt(2.0)) * level)


def edge_strength(left: np.ndarray) -> np.ndarray:
    """|∂I/∂x| + |∂I/∂y| of the left image (3×3 Sobel), in whole grey levels (int16: at most
    2 × 1020)."""
    grey = as_grey8(left)
    zero = np.zeros(grey.shape, np.int16)
    gx = cv2.absdiff(cv2.Sobel(grey, cv2.CV_16S, 1, 0, ksize=3), zero)
    gy = cv2.absdiff(cv2.Sobel(grey, cv2.CV_16S, 0, 1, ksize=3), zero)
    return cv2.add(gx, gy)


def shifted(sparse: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """The map moved by (dx, dy) px (x right, y down); what leaves the image is dropped, what
    enters it is empty (0)."""
    h, w = sparse.shape
    out = np.zeros_like(sparse)
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        sparse[max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)]
    return out


def undone(xs: np.ndarray, ys: np.ndarray, shape: tuple[int, ...], turn_deg: float, dx: float,
           dy: float) -> tuple[np.ndarray, np.ndarray]:
    """Where pixels (xs, ys) of a map that sits turned by `turn_deg` about the image centre and
    moved by (dx, dy) — the move as seen once the turn is undone — were before: float (x, y)."""
    h, w = shape
    cx, cy = (w - 1) / 2, (h - 1) / 2
    a = np.deg2rad(-turn_deg)
    x, y = xs - cx, ys - cy
    return cx + np.cos(a) * x - np.sin(a) * y - dx, cy + np.sin(a) * x + np.cos(a) * y - dy


@dataclass(frozen=True)
class Offset:
    """The map's misregistration as the jumps see it: turned by `turn_deg` about the image
    centre and moved by (dx, dy) px (the move once the turn is undone); the peak's score over
    the identity's, how many jumps it rests on, and the map's noise level that told its jumps
    (`lidar_rows.noise_level`, px; None on a map too sparse to measure it)."""

    dx: int
    dy: int
    turn_deg: float
    gain: float
    jumps: int
    noise_px: float | None = None

    @property
    def moves(self) -> bool:
        return (self.dx, self.dy, self.turn_deg) != (0, 0, 0.0) and \
            self.jumps >= MIN_JUMPS and self.gain >= MIN_GAIN

    def undo(self, sparse: np.ndarray, points: tuple[np.ndarray, np.ndarray] | None = None
             ) -> np.ndarray:
        """The map as it was before: each point back where it came from (the nearer wins where
        two land on one pixel; what leaves the image is dropped). `points`:
        `map_points(sparse)`, if at hand."""
        if self.turn_deg == 0:
            return shifted(sparse, -self.dx, -self.dy)
        ys, xs = map_points(sparse) if points is None else points
        x, y = undone(xs, ys, sparse.shape, self.turn_deg, self.dx, self.dy)
        u, v = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
        h, w = sparse.shape
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        out = np.zeros_like(sparse)
        np.maximum.at(out, (v[inside], u[inside]), sparse[ys[inside], xs[inside]])
        return out


def offset(left: np.ndarray, sparse: np.ndarray,
           points: tuple[np.ndarray, np.ndarray] | None = None) -> Offset:
    """How the map's depth edges sit against the left image's edges. `points`:
    `map_points(sparse)`, if at hand."""
    ys, xs, noise_px = _jumps_and_noise(sparse, points)
    if len(ys) < MIN_JUMPS:
        return Offset(0, 0, 0.0, 1.0, len(ys), noise_px)
    if len(ys) > MAX_JUMPS:  # a dense LiDAR: an even subset bounds the search's time
        keep = np.linspace(0, len(ys) - 1, MAX_JUMPS).astype(np.int64)
        ys, xs = ys[keep], xs[keep]
    h, w = left.shape
    # padded so that no turn or shift searched reads outside (a border of no edges)
    pad = REACH_PX + int(np.ceil(np.hypot(h, w) / 2 * np.sin(np.deg2rad(max(TURNS_DEG))))) + 2
    strength = cv2.copyMakeBorder(edge_strength(left), pad, pad, pad, pad,
                                  cv2.BORDER_CONSTANT, value=0)
    flat, pw = strength.ravel(), w + 2 * pad
    steps = np.arange(-REACH_PX, REACH_PX + 1)
    dy, dx = (a.ravel() for a in np.meshgrid(steps, steps, indexing="ij"))
    # each jump's pixel with each turn undone (rounded), then every whole-pixel move: one
    # integer sum and one gather for every turn, move and jump
    places = []
    for turn in TURNS_DEG:
        x, y = undone(xs, ys, (h, w), turn, 0.0, 0.0)
        places.append(np.rint(y + pad).astype(np.int32) * pw + np.rint(x + pad).astype(np.int32))
    moves = (-(dy * pw + dx)).astype(np.int32)
    index = np.stack(places)[:, None, :] + moves[None, :, None]  # (turn, move, jump)
    scores = np.take(flat, index).sum(axis=2, dtype=np.int32)  # (turn, move), × len(ys)
    t, i = np.unravel_index(int(np.argmax(scores)), scores.shape)
    at_identity = float(scores[len(TURNS_DEG) // 2, len(dx) // 2])
    gain = float(scores[t, i]) / at_identity if at_identity > 0 else 1.0
    return Offset(int(dx[i]), int(dy[i]), float(TURNS_DEG[t]), gain, len(ys), noise_px)


@dataclass(frozen=True)
class LidarAlign:
    """`apply(left, sparse)` -> (the map, put back where it sits off; its `Offset`)."""

    def apply(self, left: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, Offset]:
        points = map_points(sparse)
        found = offset(left, sparse, points)
        return (found.undo(sparse, points) if found.moves else sparse), found
