"""A LiDAR map that sits off the image, moved back where the image's own edges say by how much.

A LiDAR–camera calibration that is off by a fraction of a degree moves the whole projected map
by a pixel or a few (an error in the LiDAR's pitch or yaw) or turns it about the image's
centre (one in its roll), and every point at a depth edge then lands on the wrong side of it.
Where two neighbouring points of one image row (`lidar_rows.row_runs`) differ by more than
JUMP_PX of disparity — or, on a noisy map, by more than JUMP_SIGMAS standard deviations of two
points' difference (`lidar_rows.noise_level`) — the scene has a depth edge between them, and
the left image an intensity edge there. Over the map's turns (TURNS_DEG) and shifts within
±REACH_PX, the mean edge strength (Sobel magnitude) of the left image at where the jumps would
be without them peaks at the map's misregistration. Noise and mixed returns (a point beside a
depth edge taking the other surface's range) put jumps off the image's edges too, and the
peak of hundreds of offsets then lands anywhere, 1.1-1.4x the identity's score on a map that
sits right. So the peak must be confirmed on jumps it was not chosen on (`held_out_z`): the
jumps of alternate LiDAR rows are two halves with their own noise, each half's peak is scored
against the identity on the other half, and the map is put back only where those paired
differences lie MIN_Z standard errors above zero, on at least MIN_JUMPS jumps. Where the
evidence is weak (few or ambiguous jumps, a noisy map moved by a pixel) the map is left as it
is: its offset is reported, `moves` false. A map whose occlusion filter left no such jumps
(the background hidden beside every near edge removed), or too noisy to show its edges, is
left as it is. The calibration watch
(`edge.calibration_watch`) is what finds the calibration's error over many frames and says how
to fix it; this keeps each frame's depth edges where the image has them meanwhile
(docs/experiments.md, 2026-12-06 19:32 and 21:45, 2026-12-07 the held-out test).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.runtime.lidar_rows import map_points, measured, row_noise, row_runs

REACH_PX = 4  # the largest offset searched, each way
JUMP_PX = 1.5  # disparity between neighbouring points that marks a depth edge ...
# ... or this many standard deviations of two noisy points' difference, if more: on a noisy
# map (σ 0.75 px) one neighbour pair in six differs by 1.5 px on no edge, and the search's
# peak fell on a random offset (docs/experiments.md, 2026-12-06 21:45)
JUMP_SIGMAS = 4.0
MIN_JUMPS = 40
# the held-out test's bar (`held_out_z`, one-sided): a map that sits right passes it by chance
# in about one frame of a thousand (p 0.0013 for a standard normal)
MIN_Z = 3.0
TURNS_DEG = tuple(np.arange(-4, 5) * 0.25)  # the turns searched, about the image centre
MAX_JUMPS = 200  # the most jumps the search reads (an even subset of a dense LiDAR's)
_STEPS = np.arange(-REACH_PX, REACH_PX + 1)
MOVES_DY, MOVES_DX = (a.ravel() for a in np.meshgrid(_STEPS, _STEPS, indexing="ij"))
# the identity's index among (turn, move), turn-major
IDENTITY = (len(TURNS_DEG) // 2) * len(MOVES_DX) + len(MOVES_DX) // 2


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


def as_grey8(image: np.ndarray) -> np.ndarray:
    """8-bit grey: float images (the engine's buffers) are rounded and clipped."""
    if image.dtype == np.uint8:
        return image
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


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
    the identity's, how many jumps it rests on, the map's noise level that told its jumps
    (`lidar_rows.noise_level`, px; None on a map too sparse to measure it), and the peak's
    support on jumps it was not chosen on (`held_out_z`, standard errors)."""

    dx: int
    dy: int
    turn_deg: float
    gain: float
    jumps: int
    noise_px: float | None = None
    held_out_z: float = 0.0

    @property
    def moves(self) -> bool:
        return (self.dx, self.dy, self.turn_deg) != (0, 0, 0.0) and \
            self.jumps >= MIN_JUMPS and self.held_out_z >= MIN_Z

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
    """How the map's depth edges sit against the left image's edges, and how sure the jumps
    are of it (`Offset.held_out_z`). `points`: `map_points(sparse)`,
    if at hand."""
    ys, xs, noise_px = _jumps_and_noise(sparse, points)
    if len(ys) < MIN_JUMPS:
        return Offset(0, 0, 0.0, 1.0, len(ys), noise_px)
    if len(ys) > MAX_JUMPS:  # a dense LiDAR: an even subset bounds the search's time
        keep = np.linspace(0, len(ys) - 1, MAX_JUMPS).astype(np.int64)
        ys, xs = ys[keep], xs[keep]
    scores = jump_scores(left, ys, xs)  # (turn × move, jump)
    total = scores.sum(axis=1, dtype=np.int64)
    peak, identity = int(np.argmax(total)), IDENTITY
    gain = float(total[peak]) / float(total[identity]) if total[identity] > 0 else 1.0
    t, i = divmod(peak, len(MOVES_DX))
    return Offset(int(MOVES_DX[i]), int(MOVES_DY[i]), float(TURNS_DEG[t]), gain, len(ys),
                  noise_px, held_out_z(scores, ys))


def held_out_z(scores: np.ndarray, rows: np.ndarray) -> float:
    """Whether the map is off by more than its noise and mixed returns explain: the jumps
    split by the parity of their LiDAR row (`rows`), each half's offset (its peak) tested on
    the other half's jumps against the identity — the mean of those paired differences of
    edge strength over its standard error, all jumps pooled. Each jump is judged at an
    offset chosen without it, so a peak that noise put anywhere scores ≈ 0 (standard normal)
    here. 0 with fewer than two jumps or no spread. `scores`: `jump_scores`' answer."""
    half = (np.unique(rows, return_inverse=True)[1] % 2).astype(bool)
    diff = np.empty(len(rows))
    for chosen in (half, ~half):
        peak = int(np.argmax(scores[:, chosen].sum(axis=1, dtype=np.int64)))
        diff[~chosen] = scores[peak, ~chosen].astype(np.float64) - scores[IDENTITY, ~chosen]
    spread = float(np.std(diff, ddof=1)) if len(diff) > 1 else 0.0
    return float(np.mean(diff) / (spread / np.sqrt(len(diff)))) if spread > 0 else 0.0


def jump_scores(left: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The left image's edge strength (`edge_strength`) at each jump (rows `ys`, columns
    `xs`) with each turn of TURNS_DEG and move of (MOVES_DX, MOVES_DY) undone: (turn × move,
    jump) int16, turn-major."""
    h, w = left.shape[:2]
    # padded so that no turn or shift searched reads outside (a border of no edges)
    pad = REACH_PX + int(np.ceil(np.hypot(h, w) / 2 * np.sin(np.deg2rad(max(TURNS_DEG))))) + 2
    strength = cv2.copyMakeBorder(edge_strength(left), pad, pad, pad, pad,
                                  cv2.BORDER_CONSTANT, value=0)
    flat, pw = strength.ravel(), w + 2 * pad
    # each jump's pixel with each turn undone (rounded), then every whole-pixel move: one
    # gather for every turn, move and jump
    places = []
    for turn in TURNS_DEG:
        x, y = undone(xs, ys, (h, w), turn, 0.0, 0.0)
        places.append(np.rint(y + pad).astype(np.int32) * pw + np.rint(x + pad).astype(np.int32))
    moves = (-(MOVES_DY * pw + MOVES_DX)).astype(np.int32)
    index = np.stack(places)[:, None, :] + moves[None, :, None]  # (turn, move, jump)
    return np.take(flat, index).reshape(len(TURNS_DEG) * len(moves), len(xs))


@dataclass(frozen=True)
class LidarAlign:
    """`apply(left, sparse)` -> (the map, put back where it sits off; its `Offset`)."""

    def apply(self, left: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, Offset]:
        points = map_points(sparse)
        found = offset(left, sparse, points)
        return (found.undo(sparse, points) if found.moves else sparse), found
