"""LiDAR selection: per 2×2 cell of the full-resolution disparity, keep the network's values or
take the nearest LiDAR point's, chosen by a small learned scorer.

Why: the network estimates at 1/8 (refined at 1/4), so at depth edges its value is often the
other side's; the nearest LiDAR point's value is exact where it lies on the pixel's side of
the edge. Neither the image nor a matching cost alone says which (`docs/experiments.md`,
"Analysis" and session 17); this stage learns it from both: the photometric cost of each
candidate (3×3 and 5×5 windows at half resolution: 6 and 10 px), how far they disagree and in
which direction, the network's confidence, the distance to the LiDAR point, the image
gradient and the point's own residual; and, for spatial context (session 20), whether the cell
lies at an edge of the network's disparity or between two points' zones (their local ranges),
the grey step from the cell to its point's cell and the point's row offset. The scorer (a
2-layer perceptron, ~600 weights) is fitted on the bundle's own int8 outputs over training
frames by `tools/fit_select.py` and stored in the bundle's `model.json` under
`lidar_select`; bundles without that key run without the stage. The pixels it replaces get
a confidence of their own (the fitted share of such pixels within 1 px, from the scorer's
logit), not the network's, which was low there by construction.

Everything runs on 2×2 cells (half resolution) and only where the network's confidence is
below the fitted gate: at full resolution the stage cost 25–30 ms a frame on a 2-core robot,
over the engine's budget (docs/experiments.md, sessions 18–19). A chosen cell's four pixels
all take the LiDAR value. Without LiDAR points the disparity is returned unchanged.

Pure numpy + OpenCV (robot side, no torch).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from edge_depth.baselines import nearest_valid_index
from edge_depth.errors import ConfigError
from edge_depth.selfcheck import warp_right_to_left

FEATURES = ("cost5_net_minus_lidar", "cost9_net_minus_lidar", "log_cost5_net",
            "log_cost5_lidar", "log_disagreement", "lidar_minus_net", "confidence",
            "log_distance_to_lidar", "log_gradient", "log_point_residual",
            "log_grey_step_to_point", "log_net_range3", "log_net_range7",
            "log_lidar_range3", "log_lidar_range7", "log_grey_range5", "rows_to_point")
# with the network's own sides as candidates too (`side_cells` > 0; session 22)
SIDE_FEATURES = ("near_minus_net", "net_minus_far", "grey_side", "log_lidar_to_near",
                 "log_lidar_to_far")
CANDIDATES = ("network", "LiDAR point", "near side", "far side")
CELL_PX = 2  # the stage decides per CELL_PX × CELL_PX pixels
MIN_DISAGREEMENT_PX = 0.5  # below this the two candidates are the same value
# a cell the LiDAR point is no candidate for is scored for its sides only if one lies this far
# from the network's value: with 0.5 px, the cells whose sides lie nearer were 10 % of the
# stage's cells and held 6.5 % of the sides' oracle bad-3 gain at such cells (60 fitting
# frames; docs/experiments.md, session 23)
SIDE_ONLY_MIN_PX = 1.0
OUT_OF_VIEW_COST = 255.0  # a candidate that reads the right image left of its border
REMAP_ROW = 4096  # `warp_error_at`'s samples per remap row


def warp_error(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """|left(x, y) − right(x − d, y)| (grey levels), (H, W) float32. left/right (H, W) float32
    grey; disparity (H, W) px; bilinear in the right image; a pixel whose x − d falls left of
    the image costs OUT_OF_VIEW_COST."""
    error = cv2.absdiff(left, warp_right_to_left(right, disparity))
    out_of_view = np.arange(left.shape[1], dtype=np.float32)[None, :] < disparity
    np.copyto(error, np.float32(OUT_OF_VIEW_COST), where=out_of_view)  # 2× a boolean index
    return error


def warp_error_at(left: np.ndarray, right: np.ndarray, pixels: np.ndarray,
                  disparity: np.ndarray) -> np.ndarray:
    """`warp_error` at the given flat pixels only, for their own disparities (N,): the same
    values, for a map that differs from a warped one at those pixels alone."""
    w, n = left.shape[1], len(pixels)
    x = (pixels % w).astype(np.float32)
    disparity = np.asarray(disparity, np.float32)
    # the maps as rows of REMAP_ROW (remap takes images under 32 767 wide), the last padded
    rows = -(-n // REMAP_ROW)
    map_x, map_y = (np.zeros(rows * REMAP_ROW, np.float32) for _ in range(2))
    map_x[:n], map_y[:n] = x - disparity, pixels // w
    sample = cv2.remap(right, map_x.reshape(rows, REMAP_ROW), map_y.reshape(rows, REMAP_ROW),
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=0).reshape(-1)[:n]
    error = np.abs(left.ravel()[pixels] - sample)
    np.copyto(error, np.float32(OUT_OF_VIEW_COST), where=x < disparity)
    return error


def warped_cost(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                windows: tuple[int, ...]) -> list[np.ndarray]:
    """Mean `warp_error` over each window size; (H, W) each."""
    error = warp_error(left, right, disparity)
    return [cv2.blur(error, (k, k)) for k in windows]


def log1p32(x) -> np.ndarray:
    """log(1 + x) in float32, same shape: OpenCV's vectorised log. numpy's log1p ran as a
    scalar loop on an AVX2 host — 0.27 ms per 23 k values, 18× slower, and a dozen of them
    per frame (docs/experiments.md, session 21); the two agree to 1 ulp."""
    x = np.asarray(x, np.float32)
    return cv2.log(x.reshape(-1) + np.float32(1.0)).reshape(x.shape)


def tanh32(x) -> np.ndarray:
    """tanh in float32, same shape, from OpenCV's vectorised exp (numpy's tanh is a scalar
    loop on an AVX2 host, 4× slower; the two agree to 2e-7)."""
    x = np.asarray(x, np.float32)
    e = cv2.exp(x.reshape(-1) * np.float32(2.0)).reshape(x.shape)
    return np.float32(1.0) - np.float32(2.0) / (e + np.float32(1.0))


# MIN_DISAGREEMENT_PX in the space of the features that are log1p of a gap
LOG_MIN_DISAGREEMENT = log1p32(MIN_DISAGREEMENT_PX)


def local_range(image: np.ndarray, size: int) -> np.ndarray:
    """max − min over each size × size neighbourhood, per channel (float32 in, same out)."""
    kernel = np.ones((size, size), np.uint8)
    return cv2.dilate(image, kernel) - cv2.erode(image, kernel)


def cell_shape(shape: tuple[int, int]) -> tuple[int, int]:
    """(rows, columns) of cells covering an (H, W) image (the last ones may be cut)."""
    return -(-shape[0] // CELL_PX), -(-shape[1] // CELL_PX)


def _padded(image: np.ndarray) -> np.ndarray:
    """float32, edge-replicated to a multiple of CELL_PX in both directions."""
    h, w = image.shape
    hc, wc = cell_shape((h, w))
    image = np.asarray(image, np.float32)
    if (hc * CELL_PX, wc * CELL_PX) == (h, w):
        return image
    return cv2.copyMakeBorder(image, 0, hc * CELL_PX - h, 0, wc * CELL_PX - w,
                              cv2.BORDER_REPLICATE)


def cell_mean(image: np.ndarray) -> np.ndarray:
    """(H, W) → its cells' means, float32."""
    padded = _padded(image)
    hc, wc = cell_shape(image.shape)
    return cv2.resize(padded, (wc, hc), interpolation=cv2.INTER_AREA)


def side_keys(net: np.ndarray, grey: np.ndarray, side_cells: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Per cell the largest and smallest key over side_cells × side_cells cells, a key
    packing the cell's disparity in quarter pixels × 256 and its grey level (whole numbers,
    exact in float32 below 2^24: up to 16 000 px)."""
    kernel = np.ones((side_cells, side_cells), np.uint8)
    level = np.clip(np.rint(grey), 0, 255)
    key = (np.rint(np.maximum(net, 0.0) * 4.0) * 256.0 + level).astype(np.float32)
    return cv2.dilate(key, kernel), cv2.erode(key, kernel)


def unpack_key(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A side key → (disparity px, grey level); floor and subtract, not np.divmod (3×
    slower): exact on these whole numbers."""
    quarters = np.floor(key * np.float32(1 / 256))
    return quarters / 4.0, key - quarters * 256.0


def key_disparity(key: np.ndarray) -> np.ndarray:
    """A side key's disparity alone (`unpack_key`'s first item, without the grey level's
    two passes)."""
    quarters = np.floor(key * np.float32(1 / 256))
    quarters *= np.float32(0.25)
    return quarters


def grey_side(grey: np.ndarray, near_grey: np.ndarray, far_grey: np.ndarray) -> np.ndarray:
    """Per cell, in [-1, 1]: > 0 where its grey level is closer to the near side's cell's
    than to the far side's — which side of an image edge the cell is on."""
    return tanh32((np.abs(grey - far_grey) - np.abs(grey - near_grey)) / 16.0)


def cell_sides(net: np.ndarray, grey: np.ndarray, side_cells: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(near, far, their keys top, bottom): per cell the largest and smallest cell-mean
    disparity over side_cells × side_cells cells (`side_keys`, to 1/4 px)."""
    top, bottom = side_keys(net, grey, side_cells)
    return key_disparity(top), key_disparity(bottom), top, bottom


def side_columns(cells: np.ndarray, net: np.ndarray, grey: np.ndarray,
                 sides: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """At the given cells, from `cell_sides`: (near, far, and the features both selections
    read from them: how far each lies from the network's value, log1p — ≥ 0 but for the
    quarter-pixel rounding, or a negative network value, the sides being taken from
    max(disparity, 0) —, and `grey_side`)."""
    near, far, top, bottom = sides
    net_c, near_c, far_c = (m.ravel()[cells] for m in (net, near, far))
    return (near_c, far_c, log1p32(np.maximum(near_c - net_c, 0)),
            log1p32(np.maximum(net_c - far_c, 0)),
            grey_side(grey.ravel()[cells], unpack_key(top.ravel()[cells])[1],
                      unpack_key(bottom.ravel()[cells])[1]))


def sides_differ(near: np.ndarray, far: np.ndarray, net: np.ndarray,
                 min_px: float = MIN_DISAGREEMENT_PX) -> np.ndarray:
    """Cells whose near and far sides differ by more than MIN_DISAGREEMENT_PX and one of
    which lies more than min_px from the network's value (a 1e-3 px slack keeps every cell
    whose log-space test in `available` could pass): the others could never change, or
    (min_px larger) would change by too little to be worth scoring."""
    apart = min_px - 1e-3
    return ((near - far) > MIN_DISAGREEMENT_PX) & \
        (((near - net) > apart) | ((net - far) > apart))


def cell_lidar(sparse: np.ndarray) -> np.ndarray:
    """The sparse disparity (0 or non-finite = none) per cell: the largest (the nearest
    surface) of the cell's points, 0 where it has none."""
    h, w = sparse.shape
    hc, wc = cell_shape((h, w))
    if (hc * CELL_PX, wc * CELL_PX) != (h, w):
        padded = np.zeros((hc * CELL_PX, wc * CELL_PX), np.float32)
        padded[:h, :w] = sparse
        sparse = padded
    # fmax over the strided slices skips NaN and starts from 0 (so negatives count as none);
    # numpy's reduce over a reshaped (hc, 2, wc, 2) view took 11 ms at 640×400
    out = np.zeros((hc, wc), np.float32)
    for dy in range(CELL_PX):
        for dx in range(CELL_PX):
            np.fmax(out, sparse[dy::CELL_PX, dx::CELL_PX], out=out)
    out[~np.isfinite(out)] = 0
    return out


def selection_features(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                       confidence: np.ndarray, sparse: np.ndarray,
                       max_disagreement_px: float = np.inf, max_confidence: float = np.inf,
                       side_cells: int = 0, scratch: Scratch | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scorer's inputs at the cells where the two candidates differ (by more than
    MIN_DISAGREEMENT_PX, at most max_disagreement_px) and the network's confidence is below
    max_confidence.

    left/right (H, W) grey (any dtype), disparity and confidence (H, W) the network's
    outputs, sparse (H, W) LiDAR disparity in px (0 or non-finite = none). Returns
    (features (N, len(FEATURES)) float32, cells (N,) their flat indices over `cell_shape`,
    lidar (N,) float32 the nearest LiDAR point's disparity there). The point's residual is
    how far the network's own value at the LiDAR point's cell is from the point: large where
    the point leaked through an occlusion or the network is wrong there too. The local ranges
    (max − min over 3×3 / 7×7 cells) of the network's disparity and of the nearest-point map
    say whether the cell sits at an edge of either: without them the scorer could not tell a
    network that missed an edge from a LiDAR point across one, and a cap of 8 px on the
    disagreement had to keep the large ones out (docs/experiments.md, session 20).

    side_cells > 0: the network's own near and far sides (the largest and smallest of its
    cell means over side_cells × side_cells cells) are candidates too. The cells are then
    also those where the sides differ (`sides_differ`), below the same confidence gate;
    SIDE_FEATURES are appended (how far each side lies from the network's value, which
    side's grey the cell resembles, how far the LiDAR point lies from each side); and the
    third item is (N, 3): the LiDAR point's, the near side's and the far side's values
    (`available` says which of them are candidates at each cell).

    scratch: the feature matrix goes into its buffer (`feature_matrix`), valid until the
    next call with the same scratch."""
    n_features = len(FEATURES) + (len(SIDE_FEATURES) if side_cells else 0)
    empty = (np.zeros((0, n_features), np.float32), np.zeros(0, np.int64),
             np.zeros((0, 3) if side_cells else 0, np.float32))
    lidar_cells = cell_lidar(sparse)
    valid = lidar_cells > 0
    if not valid.any():
        return empty
    index, distance = nearest_valid_index(valid)
    net = cell_mean(disparity)
    points = lidar_cells[valid]
    residual = points - net[valid]
    index = index.ravel()
    nearest = points[index]  # each cell's nearest point's value
    signed = nearest - net.ravel()
    gap = np.abs(signed)
    trust = cell_mean(confidence).ravel()
    candidate = (gap > MIN_DISAGREEMENT_PX) & (gap <= max_disagreement_px)
    grey_l = cell_mean(left)
    if side_cells:
        sides = cell_sides(net, grey_l, side_cells)
        candidate |= sides_differ(*sides[:2], net, SIDE_ONLY_MIN_PX).ravel()
    cells = np.flatnonzero(candidate & (trust < max_confidence))
    if not len(cells):
        return empty
    point = index[cells]
    lidar = points[point]
    signed = signed[cells]
    grey_r = cell_mean(right)
    wc = net.shape[1]
    point_cell = np.flatnonzero(valid.ravel())[point]
    # the two disparity maps' local ranges in one pass each (2 channels)
    both = cv2.merge([net, nearest.reshape(net.shape)])
    range3 = local_range(both, 3).reshape(-1, 2)[cells]
    range7 = local_range(both, 7).reshape(-1, 2)[cells]
    # disparities in cell units for the warp; windows 3 and 5 cells ≈ 5 and 9 pixels. The
    # LiDAR candidate's map is the network's but at these cells (where they agree its cost is
    # not used), so its error is the network's but there (a full second warp cost more)
    net_error = warp_error(grey_l, grey_r, net / CELL_PX)
    lidar_error = net_error.copy()
    lidar_error.ravel()[cells] = warp_error_at(grey_l, grey_r, cells, lidar / CELL_PX)
    net5, net9 = (cv2.blur(net_error, (k, k)).ravel()[cells] for k in (3, 5))
    lid5, lid9 = (cv2.blur(lidar_error, (k, k)).ravel()[cells] for k in (3, 5))
    gradient = (np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 1, 0)) +
                np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 0, 1))).ravel()[cells]
    columns = (net5 - lid5, net9 - lid9, log1p32(net5), log1p32(lid5),
               log1p32(np.abs(signed)), tanh32(signed / 8.0),
               trust[cells],
               log1p32(CELL_PX * distance.ravel()[cells]), log1p32(gradient),
               log1p32(np.abs(residual[point])),
               log1p32(np.abs(grey_l.ravel()[cells] - grey_l.ravel()[point_cell])),
               log1p32(range3[:, 0]), log1p32(range7[:, 0]),
               log1p32(range3[:, 1]), log1p32(range7[:, 1]),
               log1p32(local_range(grey_l, 5).ravel()[cells]),
               tanh32((cells // wc - point_cell // wc) / 4.0))
    values = lidar
    if side_cells:
        near_c, far_c, *side_features = side_columns(cells, net, grey_l, sides)
        columns += (*side_features, log1p32(np.abs(lidar - near_c)),
                    log1p32(np.abs(lidar - far_c)))
        values = np.empty((len(cells), 3), np.float32)
        values[:, 0], values[:, 1], values[:, 2] = lidar, near_c, far_c
    return feature_matrix(columns, scratch), cells, values


def feature_matrix(columns, scratch: Scratch | None = None) -> np.ndarray:
    """N-long columns → (N, len(columns)) float32, interleaved by OpenCV's merge: writing each
    into a strided column of an empty array took 1.0 ms a frame at 17 k cells × 22, the merge
    0.2 (np.stack + astype 1.4; docs/experiments.md, session 23). With `scratch`, into its
    "features" buffer (valid until that buffer's next use)."""
    columns = [np.ascontiguousarray(c, np.float32).reshape(1, -1) for c in columns]
    n, f = columns[0].shape[1], len(columns)
    if scratch is None:
        return cv2.merge(columns).reshape(n, f)
    out = scratch.take("features", n, f)
    cv2.merge(columns, dst=out.reshape(1, n, f))
    return out


class Scratch(threading.local):
    """Float32 buffers a stage reuses from frame to frame, one set per thread, grown as frames
    need. A fresh array of a megabyte or more is fresh pages each frame: the feature matrix's
    merge took 0.75 ms into a new array and 0.2 into a reused one (session 23)."""

    def __init__(self) -> None:
        self.buffers: dict[str, np.ndarray] = {}

    def take(self, name: str, rows: int, columns: int) -> np.ndarray:
        """A contiguous (rows, columns) float32 view of the named buffer (old contents)."""
        buffer = self.buffers.get(name)
        if buffer is None or len(buffer) < rows or buffer.shape[1] != columns:
            buffer = np.empty((max(rows + rows // 4, 4096), columns), np.float32)
            self.buffers[name] = buffer
        return buffer[:rows]


def available(features: np.ndarray, max_disagreement_px: float = np.inf) -> np.ndarray:
    """(N, 3) bool, for features with SIDE_FEATURES: whether the LiDAR point, the near side
    and the far side are candidates at each cell — each differs from the network's cell value
    by more than MIN_DISAGREEMENT_PX, the point by at most max_disagreement_px (read back
    from the features: they are log1p of the gaps, compared in that space)."""
    gap = features[:, FEATURES.index("log_disagreement")]
    sides = len(FEATURES)
    out = np.empty((len(features), 3), bool)
    out[:, 0] = (gap > LOG_MIN_DISAGREEMENT) & (gap <= log1p32(max_disagreement_px))
    out[:, 1] = features[:, sides + SIDE_FEATURES.index("near_minus_net")] > LOG_MIN_DISAGREEMENT
    out[:, 2] = features[:, sides + SIDE_FEATURES.index("net_minus_far")] > LOG_MIN_DISAGREEMENT
    return out


def cell_pixels(cells: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The full-resolution pixels of the given cells: (flat pixel indices, which entry of
    `cells` each belongs to); cells cut by the image's border give fewer."""
    h, w = shape
    wc = cell_shape(shape)[1]
    if h % CELL_PX == 0 and w % CELL_PX == 0:  # no cut cells (the usual case): one add
        first = (cells // wc) * (CELL_PX * w) + (cells % wc) * CELL_PX
        offsets = (np.arange(CELL_PX)[:, None] * w + np.arange(CELL_PX)[None, :]).ravel()
        return ((first[:, None] + offsets[None, :]).ravel(),
                np.repeat(np.arange(len(cells)), CELL_PX * CELL_PX))
    y0, x0 = (cells // wc) * CELL_PX, (cells % wc) * CELL_PX
    dy, dx = np.divmod(np.arange(CELL_PX * CELL_PX), CELL_PX)
    ys, xs = y0[:, None] + dy[None, :], x0[:, None] + dx[None, :]
    owner = np.broadcast_to(np.arange(len(cells))[:, None], ys.shape)
    inside = (ys < h) & (xs < w)
    return ys[inside] * w + xs[inside], owner[inside]


class Perceptron:
    """A fitted scorer, standardise → ReLU layer → linear outputs, with the standardisation
    folded into the first layer: logits for (N, F) features in two OpenCV gemms, each adding
    its bias tiled to N rows (kept and grown as frames need: one broadcast add and a ReLU
    pass over the hidden layer cost ~0.7 ms a frame more than gemm's add and OpenCV's
    threshold). OpenCV's gemm, not numpy's `@`: OpenBLAS's threads spin after each call and,
    on a 2-core robot, took the CPU from the inference runtime's next graphs (encoder 13 →
    23 ms in tools/bench.py while the stage ran; docs/experiments.md, session 18); and
    (N, F) · (F, K): its feature-major transpose took 3 ms, not 0.7 (session 20)."""

    def __init__(self, mean: np.ndarray, std: np.ndarray, w1: np.ndarray, b1: np.ndarray,
                 w2: np.ndarray, b2) -> None:
        self.w1 = np.ascontiguousarray(w1 / std[:, None], np.float32)
        self.b1 = (b1 - (mean / std) @ w1).astype(np.float32)
        self.w2 = np.ascontiguousarray(np.reshape(w2, (len(b1), -1)), np.float32)
        self.b2 = np.asarray(b2, np.float32).reshape(-1)
        self._tiles = (np.zeros((0, len(self.b1)), np.float32),
                       np.zeros((0, len(self.b2)), np.float32))
        self._scratch = Scratch()  # the hidden layer's

    def __call__(self, features: np.ndarray) -> np.ndarray:
        """(N, F) → (N, outputs) float32."""
        n = len(features)
        if not n:
            return np.zeros((0, len(self.b2)), np.float32)
        if len(self._tiles[0]) < n:
            rows = max(n, 4096)
            self._tiles = (np.tile(self.b1, (rows, 1)), np.tile(self.b2, (rows, 1)))
        b1, b2 = self._tiles[0][:n], self._tiles[1][:n]
        hidden = cv2.gemm(np.ascontiguousarray(features, np.float32), self.w1, 1.0, b1, 1.0,
                          dst=self._scratch.take("hidden", n, len(self.b1)))
        cv2.threshold(hidden, 0.0, 0.0, cv2.THRESH_TOZERO, dst=hidden)  # ReLU
        return cv2.gemm(hidden, self.w2, 1.0, b2, 1.0)


@dataclass(frozen=True)
class LidarSelect:
    """The fitted scorer: standardise, ReLU layer, logits. Without sides (side_cells 0): one
    logit, p(LiDAR is nearer the truth); with them, three (CANDIDATES after the network's,
    whose logit is fixed at 0): a cell takes the available candidate of the largest positive
    logit. mean/std (F,), w1 (F, K), b1 (K,), w2 (K,) or (K, 3), b2 scalar or (3,);
    max_disagreement_px: a LiDAR point differing from the network's cell value by more is no
    candidate; max_confidence: cells where the network's mean confidence is at least this
    keep its values. confidence_scale/bias: a replaced cell's pixels get the confidence
    sigmoid(scale · logit + bias) (the chosen candidate's logit), fitted as the share of such
    pixels within 1 px of the truth (the network's confidence means the same); None
    (bundles fitted before session 20) keeps the network's confidence there."""

    mean: np.ndarray
    std: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float | np.ndarray
    max_disagreement_px: float = np.inf
    max_confidence: float = np.inf
    confidence_scale: float | None = None
    confidence_bias: float | None = None
    side_cells: int = 0

    @property
    def features(self) -> tuple[str, ...]:
        return FEATURES + SIDE_FEATURES if self.side_cells else FEATURES

    @classmethod
    def from_meta(cls, entry: dict) -> LidarSelect:
        """From model.json's `lidar_select` (ConfigError naming what is wrong)."""
        try:
            side_cells = int(entry.get("side_cells") or 0)
            expected = FEATURES + SIDE_FEATURES if side_cells else FEATURES
            if list(entry["features"]) != list(expected):
                fitted = list(entry["features"])
                which = "an older" if fitted == list(expected[:len(fitted)]) else "another"
                raise ValueError(f"fitted on {which} feature set ({len(fitted)} features; "
                                 f"this engine computes {len(expected)}): refit it with "
                                 "`python tools/fit_select.py BUNDLE --data THINGS_DIR`, or "
                                 "run without it (`[engine] lidar_select = false`)")
            if entry.get("cell_px") != CELL_PX:
                raise ValueError(f"fitted on {entry.get('cell_px', 1)}-pixel cells, not "
                                 f"{CELL_PX} (refit with tools/fit_select.py)")
            arrays = {k: np.asarray(entry[k], np.float32) for k in ("mean", "std", "w1",
                                                                     "b1", "w2")}
            b2 = np.asarray(entry["b2"], np.float32) if side_cells else float(entry["b2"])
            cap, gate = entry.get("max_disagreement_px"), entry.get("max_confidence")
            calibration = entry.get("confidence")
            scale, bias = (None, None) if calibration is None else \
                (float(calibration["scale"]), float(calibration["bias"]))
            out = cls(b2=b2, **arrays,
                      max_disagreement_px=np.inf if cap is None else float(cap),
                      max_confidence=np.inf if gate is None else float(gate),
                      confidence_scale=scale, confidence_bias=bias, side_cells=side_cells)
            f, k = len(expected), out.b1.shape[0]
            outputs = (k, len(CANDIDATES) - 1) if side_cells else (k,)
            if out.mean.shape != (f,) or out.std.shape != (f,) or out.w1.shape != (f, k) \
                    or out.w2.shape != outputs or np.shape(b2) != outputs[1:] \
                    or not np.all(out.std > 0) \
                    or not out.max_disagreement_px > MIN_DISAGREEMENT_PX \
                    or not out.max_confidence > 0 or not (side_cells == 0 or side_cells >= 3) \
                    or (scale is not None and not (np.isfinite(scale) and np.isfinite(bias))):
                raise ValueError("shapes or scales do not match")
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError("bundle", "model.json's lidar_select as tools/fit_select.py "
                              "writes it", f"{type(exc).__name__}: {exc}") from None
        return out

    def to_meta(self) -> dict:
        out = dict(features=list(self.features), cell_px=CELL_PX, mean=self.mean.tolist(),
                   std=self.std.tolist(), w1=self.w1.tolist(), b1=self.b1.tolist(),
                   w2=self.w2.tolist(),
                   b2=np.asarray(self.b2).tolist() if self.side_cells else float(self.b2),
                   max_disagreement_px=None if np.isinf(self.max_disagreement_px)
                   else float(self.max_disagreement_px),
                   max_confidence=None if np.isinf(self.max_confidence)
                   else float(self.max_confidence),
                   confidence=None if self.confidence_scale is None
                   else dict(scale=float(self.confidence_scale),
                             bias=float(self.confidence_bias)))
        if self.side_cells:
            out.update(side_cells=int(self.side_cells), candidates=list(CANDIDATES))
        return out

    @cached_property
    def _scorer(self) -> Perceptron:
        return Perceptron(self.mean, self.std, self.w1, self.b1, self.w2, self.b2)

    @cached_property
    def _scratch(self) -> Scratch:
        return Scratch()

    def logit(self, features: np.ndarray) -> np.ndarray:
        """(N, F) → (N,) logit that the LiDAR candidate is nearer the truth, or with sides
        (N, 3) one per candidate after the network."""
        out = self._scorer(features)
        return out if self.side_cells else out[:, 0]

    def probability(self, features: np.ndarray) -> np.ndarray:
        """(N, F) → (N,) probability that the LiDAR candidate is nearer the truth."""
        return 1.0 / (1.0 + np.exp(-self.logit(features)))

    def choose(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, F) → (the candidate chosen per cell: 0 keeps the network's value, else
        CANDIDATES' index; the chosen logit, 0 where the network's is kept). A candidate
        that is not `available` is never chosen; ties go to the earlier candidate."""
        logits = self.logit(features)
        if not self.side_cells:
            take = logits > 0  # p > 0.5
            return take.astype(np.int64), np.where(take, logits, 0)
        logits = np.where(available(features, self.max_disagreement_px), logits, -np.inf)
        best = logits[:, 0].copy()
        choice = np.where(best > 0, 1, 0)
        for i in (1, 2):  # a 3-wide argmax written out (numpy's took ~2 ms for 23 k cells)
            better = logits[:, i] > np.maximum(best, 0)
            choice[better] = i + 1
            np.maximum(best, logits[:, i], out=best)
        return choice, np.where(choice > 0, best, 0).astype(np.float32)

    def chosen_confidence(self, logits: np.ndarray) -> np.ndarray | None:
        """The confidence of cells whose value was replaced, from their chosen logits (None
        without a fitted calibration)."""
        if self.confidence_scale is None:
            return None
        z = self.confidence_scale * np.asarray(logits, np.float32) + self.confidence_bias
        return (1.0 / (1.0 + np.exp(-z))).astype(np.float32)

    def apply(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray, sparse: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, int]:
        """(disparity (H, W) with the chosen cells' pixels replaced, the confidence with
        theirs replaced by `chosen_confidence` (when fitted), how many pixels were)."""
        features, cells, values = selection_features(left, right, disparity, confidence,
                                                     sparse, self.max_disagreement_px,
                                                     self.max_confidence, self.side_cells,
                                                     self._scratch)
        if not len(features):
            return disparity, confidence, 0
        choice, margin = self.choose(features)
        rows = np.flatnonzero(choice)
        if not len(rows):
            return disparity, confidence, 0
        chosen = values[rows] if values.ndim == 1 else values[rows, choice[rows] - 1]
        # only the chosen cells' pixels are written (a copy, then a scatter): a full-frame
        # resize and np.where per output cost ~1.5 ms
        pixels, owner = cell_pixels(cells[rows], disparity.shape)
        disparity = disparity.astype(np.float32, copy=True)
        disparity.ravel()[pixels] = chosen[owner]
        trust = self.chosen_confidence(margin[rows])
        if trust is not None:
            confidence = confidence.astype(np.float32, copy=True)
            confidence.ravel()[pixels] = trust[owner]
        return disparity, confidence, len(pixels)
