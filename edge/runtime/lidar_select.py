"""LiDAR selection: per 2×2 cell of the full-resolution disparity, keep the network's values or
take the nearest LiDAR point's, chosen by a small learned scorer.

Why: the network estimates at 1/8 (refined at 1/4), so at depth edges its value is often the
other side's; the nearest LiDAR point's value is exact where it lies on the pixel's side of
the edge. Neither the image nor a matching cost alone says which (`docs/experiments.md`,
"Analysis"); this stage learns it from both: the photometric cost of each
candidate (3×3 and 5×5 windows at half resolution: 6 and 10 px), how far they disagree and in
which direction, the network's confidence, the distance to the LiDAR point, the image
gradient and the point's own residual; and, for spatial context, whether the cell
lies at an edge of the network's disparity or between two points' zones (their local ranges),
the grey step from the cell to its point's cell and the point's row offset. The scorer (a
2-layer perceptron, ~600 weights) is fitted on the bundle's own int8 outputs over training
frames by `tools/fit_select.py` and stored in the bundle's `model.json` under
`lidar_select`; bundles without that key run without the stage. The pixels it replaces get
a confidence of their own (the fitted share of such pixels within 1 px, from the scorer's
logit), not the network's, which was low there by construction.

Everything runs on 2×2 cells (half resolution) and only where the network's confidence is
below the fitted gate: at full resolution the stage cost 25–30 ms a frame on a 2-core robot,
over the engine's budget (docs/experiments.md). A chosen cell's four pixels
all take the LiDAR value. Without LiDAR points the disparity is returned unchanged.

Pure numpy + OpenCV (robot side, no torch).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from edge_depth.baselines import nearest_valid_index
from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import (
    CELL_PX,
    LOG_MIN_DISAGREEMENT,
    MIN_DISAGREEMENT_PX,
    Perceptron,
    Scratch,
    cell_lidar,
    cell_mean,
    cell_pixels,
    cell_sides,
    feature_matrix,
    local_range,
    log1p32,
    side_columns,
    sides_differ,
    tanh32,
    warp_error,
    warp_error_at,
)

FEATURES = ("cost5_net_minus_lidar", "cost9_net_minus_lidar", "log_cost5_net",
            "log_cost5_lidar", "log_disagreement", "lidar_minus_net", "confidence",
            "log_distance_to_lidar", "log_gradient", "log_point_residual",
            "log_grey_step_to_point", "log_net_range3", "log_net_range7",
            "log_lidar_range3", "log_lidar_range7", "log_grey_range5", "rows_to_point")
# with the network's own sides as candidates too (`side_cells` > 0; docs/experiments.md)
SIDE_FEATURES = ("near_minus_net", "net_minus_far", "grey_side", "log_lidar_to_near",
                 "log_lidar_to_far")
CANDIDATES = ("network", "LiDAR point", "near side", "far side")
# a cell the LiDAR point is no candidate for is scored for its sides only if one lies this far
# from the network's value: with 0.5 px, the cells whose sides lie nearer were 10 % of the
# stage's cells and held 6.5 % of the sides' oracle bad-3 gain at such cells (60 fitting
# frames; docs/experiments.md)
SIDE_ONLY_MIN_PX = 1.0


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
    lidar (N,) float32 the nearest LiDAR point's disparity there); what each feature says:
    `_point_columns`.

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
    index = index.ravel()
    nearest = points[index]  # each cell's nearest point's value
    signed = nearest - net.ravel()
    trust = cell_mean(confidence).ravel()
    grey_l = cell_mean(left)
    sides = cell_sides(net, grey_l, side_cells) if side_cells else None
    cells = _candidate_cells(signed, trust, net, sides, max_disagreement_px, max_confidence)
    if not len(cells):
        return empty
    point = index[cells]
    lidar = points[point]
    cell_maps = _CellMaps(grey_l, cell_mean(right), net, nearest.reshape(net.shape),
                          np.flatnonzero(valid.ravel())[point])
    columns = _point_columns(cell_maps, cells, lidar, signed[cells], trust[cells],
                             distance.ravel()[cells], (points - net[valid])[point])
    values = lidar
    if sides is not None:
        near_c, far_c, *side_features = side_columns(cells, net, grey_l, sides)
        columns += (*side_features, log1p32(np.abs(lidar - near_c)),
                    log1p32(np.abs(lidar - far_c)))
        values = np.empty((len(cells), 3), np.float32)
        values[:, 0], values[:, 1], values[:, 2] = lidar, near_c, far_c
    return feature_matrix(columns, scratch), cells, values


def _candidate_cells(signed: np.ndarray, trust: np.ndarray, net: np.ndarray,
                     sides: tuple | None, max_disagreement_px: float,
                     max_confidence: float) -> np.ndarray:
    """The flat cells scored: the nearest point differs from the network's cell value by
    more than MIN_DISAGREEMENT_PX and at most `max_disagreement_px` (or, with `sides`, the
    network's own sides differ), where the network's mean confidence is below
    `max_confidence`."""
    gap = np.abs(signed)
    candidate = (gap > MIN_DISAGREEMENT_PX) & (gap <= max_disagreement_px)
    if sides is not None:
        candidate |= sides_differ(*sides[:2], net, SIDE_ONLY_MIN_PX).ravel()
    return np.flatnonzero(candidate & (trust < max_confidence))


@dataclass(frozen=True)
class _CellMaps:
    """The cell-resolution maps the point's features read: both views' grey, the network's
    disparity, the nearest-point map, and each scored cell's point's own cell (flat)."""

    grey_l: np.ndarray
    grey_r: np.ndarray
    net: np.ndarray
    nearest: np.ndarray
    point_cell: np.ndarray


def _point_columns(maps: _CellMaps, cells: np.ndarray, lidar: np.ndarray, signed: np.ndarray,
                   trust: np.ndarray, distance: np.ndarray, residual: np.ndarray
                   ) -> tuple[np.ndarray, ...]:
    """FEATURES' columns at `cells`, in order. The point's residual is how far the
    network's own value at the LiDAR point's cell is from the point: large where the point
    leaked through an occlusion or the network is wrong there too. The local ranges (max −
    min over 3×3 / 7×7 cells) of the network's disparity and of the nearest-point map say
    whether the cell sits at an edge of either: without them the scorer could not tell a
    network that missed an edge from a LiDAR point across one, and a cap of 8 px on the
    disagreement had to keep the large ones out (docs/experiments.md)."""
    grey_l, net, point_cell = maps.grey_l, maps.net, maps.point_cell
    wc = net.shape[1]
    # the two disparity maps' local ranges in one pass each (2 channels)
    both = cv2.merge([net, maps.nearest])
    range3 = local_range(both, 3).reshape(-1, 2)[cells]
    range7 = local_range(both, 7).reshape(-1, 2)[cells]
    net5, net9, lid5, lid9 = _warp_costs(grey_l, maps.grey_r, net, cells, lidar)
    gradient = (np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 1, 0)) +
                np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 0, 1))).ravel()[cells]
    return (net5 - lid5, net9 - lid9, log1p32(net5), log1p32(lid5),
            log1p32(np.abs(signed)), tanh32(signed / 8.0),
            trust,
            log1p32(CELL_PX * distance), log1p32(gradient),
            log1p32(np.abs(residual)),
            log1p32(np.abs(grey_l.ravel()[cells] - grey_l.ravel()[point_cell])),
            log1p32(range3[:, 0]), log1p32(range7[:, 0]),
            log1p32(range3[:, 1]), log1p32(range7[:, 1]),
            log1p32(local_range(grey_l, 5).ravel()[cells]),
            tanh32((cells // wc - point_cell // wc) / 4.0))


def _warp_costs(grey_l: np.ndarray, grey_r: np.ndarray, net: np.ndarray, cells: np.ndarray,
                lidar: np.ndarray) -> tuple[np.ndarray, ...]:
    """The network's and the LiDAR candidate's warp errors at `cells`, averaged over 3 and
    5 cells (≈ 5 and 9 pixels): (net5, net9, lid5, lid9). The LiDAR candidate's map is the
    network's but at these cells (where they agree its cost is not used), so its error is
    the network's but there (a full second warp cost more)."""
    net_error = warp_error(grey_l, grey_r, net / CELL_PX)
    lidar_error = net_error.copy()
    lidar_error.ravel()[cells] = warp_error_at(grey_l, grey_r, cells, lidar / CELL_PX)
    net5, net9 = (cv2.blur(net_error, (k, k)).ravel()[cells] for k in (3, 5))
    lid5, lid9 = (cv2.blur(lidar_error, (k, k)).ravel()[cells] for k in (3, 5))
    return net5, net9, lid5, lid9


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
    (bundles fitted without it) keeps the network's confidence there."""

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
                    or (scale is not None and not (bias is not None and np.isfinite(scale)
                                                   and np.isfinite(bias))):
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
                             bias=float(self.confidence_bias or 0.0)))
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
        z = self.confidence_scale * np.asarray(logits, np.float32) + (self.confidence_bias or 0.0)
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
