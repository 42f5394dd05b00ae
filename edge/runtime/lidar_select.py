"""Full-resolution LiDAR selection: per pixel, keep the network's disparity or take the
nearest LiDAR point's, chosen by a small learned scorer.

Why: the network estimates at 1/8 (refined at 1/4), so at depth edges its value is often the
other side's; the nearest LiDAR point's value is exact where it lies on the pixel's side of
the edge. Neither the image nor a matching cost alone says which (`docs/experiments.md`,
"Analysis" and session 17); this stage learns it from both: the photometric cost of each
candidate at full resolution (5×5 and 9×9 windows), how far they disagree and in which
direction, the network's confidence, the distance to the LiDAR point, the image gradient and
the point's own residual. The scorer (a 2-layer perceptron, ~400 weights) is fitted on the
bundle's own int8 outputs over training frames by `tools/fit_select.py` and stored in the
bundle's `model.json` under `lidar_select`; bundles without that key run without the stage.
Without LiDAR points the disparity is returned unchanged.

Pure numpy + OpenCV (robot side, no torch).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.baselines import nearest_valid_index
from edge_depth.errors import ConfigError
from edge_depth.selfcheck import warp_right_to_left

FEATURES = ("cost5_net_minus_lidar", "cost9_net_minus_lidar", "log_cost5_net",
            "log_cost5_lidar", "log_disagreement", "lidar_minus_net", "confidence",
            "log_distance_to_lidar", "log_gradient", "log_point_residual")
MIN_DISAGREEMENT_PX = 0.5  # below this the two candidates are the same value
OUT_OF_VIEW_COST = 255.0  # a candidate that reads the right image left of its border


def warped_cost(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                windows: tuple[int, ...]) -> list[np.ndarray]:
    """Mean |left(x, y) − right(x − d, y)| (grey levels) over each window size; (H, W) each.
    left/right (H, W) float32 grey; disparity (H, W) px; bilinear in the right image; a pixel
    whose x − d falls left of the image costs OUT_OF_VIEW_COST."""
    error = np.abs(left - warp_right_to_left(right, disparity))
    out_of_view = np.arange(left.shape[1], dtype=np.float32)[None, :] < disparity
    error[out_of_view] = OUT_OF_VIEW_COST
    return [cv2.blur(error, (k, k)) for k in windows]


def selection_features(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                       confidence: np.ndarray, sparse: np.ndarray,
                       max_disagreement_px: float = np.inf
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scorer's inputs where the two candidates differ (by more than MIN_DISAGREEMENT_PX,
    at most max_disagreement_px).

    left/right (H, W) grey (any dtype), disparity and confidence (H, W) the network's
    outputs, sparse (H, W) LiDAR disparity in px (0 or non-finite = none). Returns
    (features (N, len(FEATURES)) float32, pixels (N,) their flat row-major indices,
    lidar (N,) float32 the nearest LiDAR point's disparity there). The point's residual is
    how far the network's own value at the LiDAR point's pixel is from the point: large
    where the point leaked through an occlusion or the network is wrong there too."""
    valid = np.isfinite(sparse) & (sparse > 0)
    empty = (np.zeros((0, len(FEATURES)), np.float32), np.zeros(0, np.int64),
             np.zeros(0, np.float32))
    if not valid.any():
        return empty
    index, distance = nearest_valid_index(valid)
    points = sparse[valid].astype(np.float32)
    residual = points - disparity[valid]
    index = index.ravel()
    net = disparity.ravel()
    signed = points[index] - net
    gap = np.abs(signed)
    pixels = np.flatnonzero((gap > MIN_DISAGREEMENT_PX) & (gap <= max_disagreement_px))
    if not len(pixels):
        return empty
    point = index[pixels]
    lidar = points[point]
    signed = signed[pixels]
    grey_l, grey_r = left.astype(np.float32), right.astype(np.float32)
    lidar_map = np.array(disparity, dtype=np.float32, order="C")  # a copy, ravel() a view
    lidar_map.ravel()[pixels] = lidar  # where they agree the cost is not used
    net5, net9 = (c.ravel()[pixels] for c in warped_cost(grey_l, grey_r, disparity, (5, 9)))
    lid5, lid9 = (c.ravel()[pixels] for c in warped_cost(grey_l, grey_r, lidar_map, (5, 9)))
    gradient = (np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 1, 0)) +
                np.abs(cv2.Sobel(grey_l, cv2.CV_32F, 0, 1))).ravel()[pixels]
    columns = (net5 - lid5, net9 - lid9, np.log1p(net5), np.log1p(lid5),
               np.log1p(np.abs(signed)), np.tanh(signed / 8.0), confidence.ravel()[pixels],
               np.log1p(distance.ravel()[pixels]), np.log1p(gradient),
               np.log1p(np.abs(residual[point])))
    return np.stack(columns, axis=1).astype(np.float32), pixels, lidar


@dataclass(frozen=True)
class LidarSelect:
    """The fitted scorer: standardise, ReLU layer, one logit; p(LiDAR is nearer the truth).
    mean/std (F,), w1 (F, K), b1 (K,), w2 (K,), b2 scalar; max_disagreement_px: pixels where
    the candidates differ by more keep the network's value."""

    mean: np.ndarray
    std: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float
    max_disagreement_px: float = np.inf

    @classmethod
    def from_meta(cls, entry: dict) -> LidarSelect:
        """From model.json's `lidar_select` (ConfigError naming what is wrong)."""
        try:
            if list(entry["features"]) != list(FEATURES):
                raise ValueError(f"features {entry['features']} are not {list(FEATURES)}")
            arrays = {k: np.asarray(entry[k], np.float32) for k in ("mean", "std", "w1",
                                                                     "b1", "w2")}
            cap = entry.get("max_disagreement_px")
            out = cls(b2=float(entry["b2"]), **arrays,
                      max_disagreement_px=np.inf if cap is None else float(cap))
            f, k = len(FEATURES), out.b1.shape[0]
            if out.mean.shape != (f,) or out.std.shape != (f,) or out.w1.shape != (f, k) \
                    or out.w2.shape != (k,) or not np.all(out.std > 0) \
                    or not out.max_disagreement_px > MIN_DISAGREEMENT_PX:
                raise ValueError("shapes or scales do not match")
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError("bundle", "model.json's lidar_select as tools/fit_select.py "
                              "writes it", f"{type(exc).__name__}: {exc}") from None
        return out

    def to_meta(self) -> dict:
        return dict(features=list(FEATURES), mean=self.mean.tolist(), std=self.std.tolist(),
                    w1=self.w1.tolist(), b1=self.b1.tolist(), w2=self.w2.tolist(),
                    b2=float(self.b2),
                    max_disagreement_px=None if np.isinf(self.max_disagreement_px)
                    else float(self.max_disagreement_px))

    def logit(self, features: np.ndarray) -> np.ndarray:
        """(N, F) → (N,) logit that the LiDAR candidate is nearer the truth (the
        standardisation folded into the first layer: one matmul)."""
        if not len(features):
            return np.zeros(0, np.float32)
        w1 = self.w1 / self.std[:, None]
        b1 = self.b1 - (self.mean / self.std) @ self.w1
        # OpenCV's gemm, not numpy's `@`: OpenBLAS's threads spin after each call and, on a
        # 2-core robot, took the CPU from the inference runtime's next graphs (encoder 13 → 23
        # ms in tools/bench.py while the stage ran; docs/experiments.md, session 18)
        features = np.ascontiguousarray(features, np.float32)
        hidden = cv2.gemm(features, np.ascontiguousarray(w1, np.float32), 1.0, None, 0.0)
        hidden += b1
        np.maximum(hidden, 0.0, out=hidden)
        return cv2.gemm(hidden, self.w2.reshape(-1, 1).astype(np.float32), 1.0, None,
                        0.0)[:, 0] + np.float32(self.b2)

    def probability(self, features: np.ndarray) -> np.ndarray:
        """(N, F) → (N,) probability that the LiDAR candidate is nearer the truth."""
        return 1.0 / (1.0 + np.exp(-self.logit(features)))

    def apply(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, int]:
        """(disparity (H, W) with the chosen pixels replaced, how many were replaced)."""
        features, pixels, lidar = selection_features(left, right, disparity, confidence,
                                                     sparse, self.max_disagreement_px)
        if not len(features):
            return disparity, 0
        take = self.logit(features) > 0  # p > 0.5
        out = np.array(disparity, dtype=np.float32, order="C")  # a copy, ravel() a view
        out.ravel()[pixels[take]] = lidar[take]
        return out, int(take.sum())
