"""Edge selection: on a frame without LiDAR points, per 2×2 cell keep the network's value or
take the near or the far side's, chosen by a small learned scorer.

Why: stereo only, the network loses to SGBM at depth edges and nowhere else (on Aloe 6.6
of its 14.2 bad-3 points lie within 4 px of an edge, SGBM's 2.4; docs/experiments.md): at
1/8 resolution its value there is often a blend, or the other side's. Both
sides' values are in its own output a few cells away — the largest and the smallest of its
cell means over SIDE_CELLS × SIDE_CELLS cells — and an oracle choosing among the three per
cell removes a sixth to a quarter of the bad-3 pixels (3 to 5 cells square). The scorer
(standardise, one ReLU layer, three logits) sees each candidate's photometric cost (3×3 and
5×5 cells at half resolution), how far the sides lie from the network's value, the
network's confidence and local range, the image gradient and grey range, and which side's
grey the cell resembles. It is fitted on the bundle's own int8 outputs, LiDAR zeroed, by
`tools/fit_edge_select.py` and stored in the bundle's model.json under `edge_select`;
bundles without it run without the stage.

With LiDAR points the engine runs the LiDAR selection (`edge.runtime.lidar_select`) instead:
the two never run on the same frame, so this stage adds nothing to the slowest frame's
time. It acts only where the network's confidence is below the fitted gate. Pure numpy +
OpenCV (robot side, no torch).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import (
    CELL_PX,
    LOG_MIN_DISAGREEMENT,
    Perceptron,
    Scratch,
    cell_mean,
    cell_pixels,
    cell_sides,
    feature_matrix,
    local_range,
    log1p32,
    side_columns,
    side_keys,
    sides_differ,
    unpack_key,
    warped_cost,
)

FEATURES = ("log_cost5_net", "log_cost9_net", "log_cost5_near", "log_cost5_far",
            "cost5_net_minus_near", "cost9_net_minus_near", "cost5_net_minus_far",
            "cost9_net_minus_far", "near_minus_net", "net_minus_far", "confidence",
            "log_net_range3", "log_gradient", "log_grey_range5", "grey_side")
CANDIDATES = ("network", "near side", "far side")
SIDE_CELLS = 3  # the sides' values: max / min of the cell means over this many cells square


def side_values(net: np.ndarray, grey: np.ndarray, side_cells: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(near, far, near_grey, far_grey): per cell the largest and the smallest cell-mean
    disparity over side_cells × side_cells cells around it (to 1/4 px), and the grey level
    (0–255, whole levels) of the cell each was taken from."""
    top, bottom = side_keys(net, grey, side_cells)
    (near, near_grey), (far, far_grey) = unpack_key(top), unpack_key(bottom)
    return near, far, near_grey, far_grey


def edge_features(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                  confidence: np.ndarray, side_cells: int = SIDE_CELLS,
                  max_confidence: float = np.inf, scratch: Scratch | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scorer's inputs at the cells whose network confidence is below max_confidence,
    whose near and far sides differ by more than MIN_DISAGREEMENT_PX and one of which lies
    that far from the network's value.

    left/right (H, W) grey, disparity and confidence (H, W) the network's outputs. Returns
    (features (N, len(FEATURES)) float32, cells (N,) flat indices over the cell grid,
    values (N, 2) float32 the near and far sides' disparities there); with `scratch`, the
    features lie in its buffer until its next use (`feature_matrix`)."""
    net = cell_mean(disparity)
    grey_l = cell_mean(left)
    sides = cell_sides(net, grey_l, side_cells)
    near, far = sides[:2]
    trust = cell_mean(confidence)
    # a cell where neither side lies more than MIN_DISAGREEMENT_PX from the network's value
    # would never change (`EdgeSelect.choose`): left out here
    candidate = sides_differ(near, far, net) & (trust < max_confidence)
    cells = np.flatnonzero(candidate)
    if not len(cells):
        return (np.zeros((0, len(FEATURES)), np.float32), np.zeros(0, np.int64),
                np.zeros((0, 2), np.float32))
    grey_r = cell_mean(right)
    # disparities in cell units for the warp; windows 3 and 5 cells ≈ 5 and 9 pixels
    costs = [[c.ravel()[cells] for c in warped_cost(grey_l, grey_r, d / CELL_PX, (3, 5))]
             for d in (net, near, far)]
    (net5, net9), (near5, near9), (far5, far9) = costs
    near_c, far_c, near_gap, far_gap, grey_side_c = side_columns(cells, net, grey_l, sides)
    gradient = (np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 1, 0)) +
                np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 0, 1))).ravel()[cells]
    columns = (log1p32(net5), log1p32(net9), log1p32(near5), log1p32(far5),
               net5 - near5, net9 - near9, net5 - far5, net9 - far9,
               near_gap, far_gap, trust.ravel()[cells],
               log1p32(local_range(net, 3).ravel()[cells]), log1p32(gradient),
               log1p32(local_range(grey_l, 5).ravel()[cells]), grey_side_c)
    values = np.empty((len(cells), 2), np.float32)
    values[:, 0], values[:, 1] = near_c, far_c
    return feature_matrix(columns, scratch), cells, values


def sides_apart(features: np.ndarray) -> np.ndarray:
    """(N, 2) bool: whether the near / far side differs from the network's cell value by more
    than MIN_DISAGREEMENT_PX (read back from the features)."""
    # the features are log1p of the gaps: compared in that space (no expm1, no gather)
    out = np.empty((len(features), 2), bool)
    out[:, 0] = features[:, FEATURES.index("near_minus_net")] > LOG_MIN_DISAGREEMENT
    out[:, 1] = features[:, FEATURES.index("net_minus_far")] > LOG_MIN_DISAGREEMENT
    return out


@dataclass(frozen=True)
class EdgeSelect:
    """The fitted scorer: standardise, ReLU layer, three logits (CANDIDATES). mean/std (F,),
    w1 (F, K), b1 (K,), w2 (K, 3), b2 (3,); side_cells: the window the sides come from;
    max_confidence: cells at least this confident keep the network's values.
    confidence_scale/bias: a replaced cell's pixels get the confidence
    sigmoid(scale · margin + bias), margin = the chosen logit minus the network's."""

    mean: np.ndarray
    std: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    side_cells: int = SIDE_CELLS
    max_confidence: float = np.inf
    confidence_scale: float = 0.0
    confidence_bias: float = 0.0

    @classmethod
    def from_meta(cls, entry: dict) -> EdgeSelect:
        """From model.json's `edge_select` (ConfigError naming what is wrong)."""
        try:
            if list(entry["features"]) != list(FEATURES):
                raise ValueError(f"fitted on another feature set ({len(entry['features'])} "
                                 f"features; this engine computes {len(FEATURES)}): refit it "
                                 "with `python tools/fit_edge_select.py BUNDLE --data "
                                 "THINGS_DIR`, or run without it (`[engine] edge_select = "
                                 "false`)")
            if entry.get("cell_px") != CELL_PX:
                raise ValueError(f"fitted on {entry.get('cell_px')}-pixel cells, not {CELL_PX}")
            arrays = {k: np.asarray(entry[k], np.float32) for k in ("mean", "std", "w1", "b1",
                                                                     "w2", "b2")}
            gate = entry.get("max_confidence")
            out = cls(**arrays, side_cells=int(entry["side_cells"]),
                      max_confidence=np.inf if gate is None else float(gate),
                      confidence_scale=float(entry["confidence"]["scale"]),
                      confidence_bias=float(entry["confidence"]["bias"]))
            f, k, c = len(FEATURES), out.b1.shape[0], len(CANDIDATES)
            if out.mean.shape != (f,) or out.std.shape != (f,) or out.w1.shape != (f, k) \
                    or out.w2.shape != (k, c) or out.b2.shape != (c,) \
                    or not np.all(out.std > 0) or not out.side_cells >= 3 \
                    or not out.max_confidence > 0 \
                    or not np.isfinite([out.confidence_scale, out.confidence_bias]).all():
                raise ValueError("shapes or scales do not match")
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError("bundle", "model.json's edge_select as "
                              "tools/fit_edge_select.py writes it",
                              f"{type(exc).__name__}: {exc}") from None
        return out

    def to_meta(self) -> dict:
        return dict(features=list(FEATURES), candidates=list(CANDIDATES), cell_px=CELL_PX,
                    side_cells=int(self.side_cells), mean=self.mean.tolist(),
                    std=self.std.tolist(), w1=self.w1.tolist(), b1=self.b1.tolist(),
                    w2=self.w2.tolist(), b2=self.b2.tolist(),
                    max_confidence=None if np.isinf(self.max_confidence)
                    else float(self.max_confidence),
                    confidence=dict(scale=float(self.confidence_scale),
                                    bias=float(self.confidence_bias)))

    @cached_property
    def _scorer(self) -> Perceptron:
        return Perceptron(self.mean, self.std, self.w1, self.b1, self.w2, self.b2)

    @cached_property
    def _scratch(self) -> Scratch:
        return Scratch()

    def logits(self, features: np.ndarray) -> np.ndarray:
        """(N, F) → (N, 3) logits over CANDIDATES."""
        return self._scorer(features)

    def choose(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, F) → (the candidate chosen per cell, its logit's margin over the network's).
        A side within MIN_DISAGREEMENT_PX of the network's cell value is no other candidate
        and is never chosen."""
        logits = self.logits(features)
        apart = sides_apart(features)
        keep = logits[:, 0]
        near = np.where(apart[:, 0], logits[:, 1], -np.inf)
        far = np.where(apart[:, 1], logits[:, 2], -np.inf)
        # argmax over the three, written out (numpy's argmax along a 3-wide axis took ~2 ms
        # for 23 k cells); ties go to the earlier candidate, as argmax's
        side = np.where(near >= far, 1, 2)
        best = np.maximum(near, far)
        choice = np.where(best > keep, side, 0)
        return choice, np.where(choice > 0, best, keep) - keep

    def chosen_confidence(self, margin: np.ndarray) -> np.ndarray:
        """The confidence of replaced cells from their margins (chosen logit − network's)."""
        z = self.confidence_scale * np.asarray(margin, np.float32) + self.confidence_bias
        return (1.0 / (1.0 + np.exp(-z))).astype(np.float32)

    def apply(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """(disparity with the replaced cells' pixels set to their side's value, the
        confidence with theirs from `chosen_confidence`, how many pixels were replaced)."""
        features, cells, values = edge_features(left, right, disparity, confidence,
                                                self.side_cells, self.max_confidence,
                                                self._scratch)
        if not len(features):
            return disparity, confidence, 0
        choice, margin = self.choose(features)
        rows = np.flatnonzero(choice > 0)
        if not len(rows):
            return disparity, confidence, 0
        chosen = values[rows, choice[rows] - 1]
        margin = margin[rows]
        pixels, owner = cell_pixels(cells[rows], disparity.shape)
        disparity = disparity.astype(np.float32, copy=True)
        disparity.ravel()[pixels] = chosen[owner]
        confidence = confidence.astype(np.float32, copy=True)
        confidence.ravel()[pixels] = self.chosen_confidence(margin)[owner]
        return disparity, confidence, len(pixels)
