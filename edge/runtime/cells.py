"""What both selections compute per 2×2 cell of the full-resolution disparity: the cell grid
(cell means, the LiDAR per cell, a cell's pixels), the photometric error of a candidate map
(whole or at given cells), the network's own two sides of an edge (packed max / min keys), the
scorer's feature matrix, buffers reused from frame to frame and the two-layer scorer itself.
`edge.runtime.lidar_select` is built from these.

Pure numpy + OpenCV (robot side, no torch).
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from edge_depth.selfcheck import warp_right_to_left

CELL_PX = 2  # the stage decides per CELL_PX × CELL_PX pixels
MIN_DISAGREEMENT_PX = 0.5  # below this the two candidates are the same value
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
    per frame (docs/experiments.md); the two agree to 1 ulp."""
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


def feature_matrix(columns, scratch: Scratch | None = None) -> np.ndarray:
    """N-long columns → (N, len(columns)) float32, interleaved by OpenCV's merge: writing each
    into a strided column of an empty array took 1.0 ms a frame at 17 k cells × 22, the merge
    0.2 (np.stack + astype 1.4; docs/experiments.md). With `scratch`, into its
    "features" buffer (valid until that buffer's next use)."""
    columns = [np.ascontiguousarray(c, np.float32).reshape(1, -1) for c in columns]
    n, f = columns[0].shape[1], len(columns)
    if scratch is None:
        return cv2.merge(columns).reshape(n, f)
    out = scratch.take("features", n, f)
    cv2.merge(columns, dst=out.reshape(1, n, f))
    return out


class Scratch(threading.local):
    """Buffers (float32 unless asked) a stage reuses from frame to frame, one set per thread,
    grown as frames need. A fresh array of a megabyte or more is fresh pages each frame: the
    feature matrix's merge took 0.75 ms into a new array and 0.2 into a reused one
    (docs/experiments.md)."""

    def __init__(self) -> None:
        self.buffers: dict[str, np.ndarray] = {}

    def take(self, name: str, rows: int, columns: int, dtype=np.float32) -> np.ndarray:
        """A contiguous (rows, columns) view of the named buffer (old contents)."""
        buffer = self.buffers.get(name)
        if buffer is None or len(buffer) < rows or buffer.shape[1] != columns or \
                buffer.dtype != dtype:
            buffer = np.empty((max(rows + rows // 4, 4096), columns), dtype)
            self.buffers[name] = buffer
        return buffer[:rows]


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
    threshold). OpenCV's gemm, not numpy's `@`: (N, F) · (F, K) in numpy, its feature-major
    transpose took 3 ms, not 0.7 (docs/experiments.md). Both run on an OpenBLAS whose threads
    spin after each call and take a core from what follows: the engine sets every OpenBLAS
    in its process to one thread (`edge.workers.one_openblas_thread`)."""

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
