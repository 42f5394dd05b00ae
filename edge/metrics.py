"""Disparity and depth accuracy metrics over GT-valid pixels (pure numpy).

A method's holes (non-finite or <= 0 predictions) count as errors: their error is taken as the
full GT disparity, and they count against density.
"""

from __future__ import annotations

import numpy as np


def disparity_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None
                      ) -> dict[str, float]:
    """EPE (px), bad-1/2/3 (% of pixels off by more than 1/2/3 px) and density (% predicted).

    pred, gt: (H, W) disparity in pixels; gt non-finite or <= 0 is unknown. mask: optional
    (H, W) bool restricting the evaluated pixels (e.g. non-occluded).
    """
    valid = np.isfinite(gt) & (gt > 0)
    if mask is not None:
        valid &= mask
    g = gt[valid].astype(np.float64)
    p = pred[valid].astype(np.float64)
    if g.size == 0:
        return dict(epe=float("nan"), bad1=float("nan"), bad2=float("nan"),
                    bad3=float("nan"), density=0.0)
    has = np.isfinite(p) & (p > 0)
    err = np.where(has, np.abs(p - g), g)
    return dict(epe=float(err.mean()), bad1=float((err > 1).mean() * 100),
                bad2=float((err > 2).mean() * 100), bad3=float((err > 3).mean() * 100),
                density=float(has.mean() * 100))


def depth_metrics(pred_disp: np.ndarray, gt_disp: np.ndarray, focal_px: float,
                  baseline_m: float) -> dict[str, float]:
    """KITTI depth metrics from disparities: RMSE and MAE in mm, iRMSE and iMAE in 1/km,
    over pixels where both GT and prediction are positive and finite."""
    ok = np.isfinite(gt_disp) & (gt_disp > 0) & np.isfinite(pred_disp) & (pred_disp > 0)
    if not ok.any():
        return dict(rmse_mm=float("nan"), mae_mm=float("nan"), irmse=float("nan"),
                    imae=float("nan"))
    fb = focal_px * baseline_m
    z_gt = fb / gt_disp[ok].astype(np.float64)
    z_p = fb / pred_disp[ok].astype(np.float64)
    dz = (z_p - z_gt) * 1000.0
    dinv = (1.0 / z_p - 1.0 / z_gt) * 1000.0  # 1/km
    return dict(rmse_mm=float(np.sqrt(np.mean(dz**2))), mae_mm=float(np.mean(np.abs(dz))),
                irmse=float(np.sqrt(np.mean(dinv**2))), imae=float(np.mean(np.abs(dinv))))


CONFIDENCE_THRESHOLDS = (0.5, 0.7, 0.9)


def confidence_calibration(pred: np.ndarray, gt: np.ndarray, confidence: np.ndarray,
                           thresholds: tuple[float, ...] = CONFIDENCE_THRESHOLDS
                           ) -> dict[str, float]:
    """For each threshold t: the share of GT-valid pixels kept (confidence ≥ t, %) and the
    bad-1 (%) among them; keys kept@t and bad1@t (bad1@t is NaN when nothing is kept)."""
    valid = np.isfinite(gt) & (gt > 0)
    err = np.abs(np.where(np.isfinite(pred), pred, 0.0) - gt)[valid]
    conf = confidence[valid]
    out = {}
    for t in thresholds:
        kept = conf >= t
        out[f"kept@{t:g}"] = float(kept.mean() * 100) if kept.size else float("nan")
        out[f"bad1@{t:g}"] = float((err[kept] > 1).mean() * 100) if kept.any() else float("nan")
    return out
