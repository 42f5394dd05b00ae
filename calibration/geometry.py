"""Whether a stereo calibration can produce an image, not only whether each number is in range.

Every coefficient of a distortion model can sit inside its documented range and the model still
fold the image over itself (k1 = -450 sends every pixel outside the image and back), so the
rectification each camera will run is sampled on a grid and checked:

- **covers**: most rectified pixels look up a source pixel inside the camera's image, and
  together they span most of it (a lens model that folds near the centre leaves a
  rectification that magnifies a few pixels);
- **monotonic**: along a rectified row the source x increases, down a column the source y
  increases (no fold-over);
- **overlap**: the two rectified views see the same part of the scene.

A grid of 33 x 21 points per camera costs well under a millisecond.
"""

from __future__ import annotations

import cv2
import numpy as np

from edge_depth.calibration.errors import CalibrationError

GRID = (33, 21)  # samples across, down
MIN_COVERED = 0.5  # share of rectified samples whose source lies in the image
MIN_SPAN = 0.25  # share of the camera's image spanned by what the rectified view reads
MIN_OVERLAP = 0.5  # share of rectified samples valid in both views
MAX_FOLDED = 0.01  # share of neighbouring samples allowed to run backwards


def source_pixels(K: np.ndarray, dist: np.ndarray, R_rect: np.ndarray, P_rect: np.ndarray,
                  size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where the rectified view's grid samples read the raw image: (H', W', 2) source pixels
    and a (H', W') mask of those inside the image (the map cv2.initUndistortRectifyMap builds,
    at GRID's samples only)."""
    w, h = size
    u, v = np.meshgrid(np.linspace(0, w - 1, GRID[0]), np.linspace(0, h - 1, GRID[1]))
    f_x, f_y, c_x, c_y = P_rect[0, 0], P_rect[1, 1], P_rect[0, 2], P_rect[1, 2]
    rays = np.stack([(u - c_x) / f_x, (v - c_y) / f_y, np.ones_like(u)], -1).reshape(-1, 3)
    in_camera = rays @ R_rect  # R_rectᵀ · ray for each row vector
    ahead = in_camera[:, 2] > 1e-6
    src = np.full((in_camera.shape[0], 2), np.nan)
    if ahead.any():
        projected, _ = cv2.projectPoints(in_camera[ahead], np.zeros(3), np.zeros(3), K, dist)
        src[ahead] = projected.reshape(-1, 2)
    src = src.reshape(GRID[1], GRID[0], 2)
    with np.errstate(invalid="ignore"):
        inside = (np.isfinite(src).all(-1) & (src[..., 0] >= -0.5) & (src[..., 0] <= w - 0.5)
                  & (src[..., 1] >= -0.5) & (src[..., 1] <= h - 0.5))
    return src, inside


def _spanned_share(src: np.ndarray, inside: np.ndarray, size: tuple[int, int]) -> float:
    """Share of the image's area inside the bounding box of the samples read inside it."""
    if not inside.any():
        return 0.0
    x, y = src[inside][:, 0], src[inside][:, 1]
    return float((np.ptp(x) + 1) * (np.ptp(y) + 1) / (size[0] * size[1]))


def _folded_share(src: np.ndarray, inside: np.ndarray) -> float:
    """Share of neighbouring inside samples whose source runs backwards along x or y."""
    along_x = inside[:, 1:] & inside[:, :-1]
    along_y = inside[1:, :] & inside[:-1, :]
    backwards = ((np.diff(src[..., 0], axis=1) <= 0) & along_x).sum() \
        + ((np.diff(src[..., 1], axis=0) <= 0) & along_y).sum()
    pairs = along_x.sum() + along_y.sum()
    return float(backwards / pairs) if pairs else 1.0


def check_image_geometry(K_left: np.ndarray, dist_left: np.ndarray, K_right: np.ndarray,
                         dist_right: np.ndarray, rect: dict, size: tuple[int, int]) -> None:
    """Raise CalibrationError naming the property (covers, monotonic, overlap) that the
    rectification of this stereo calibration breaks."""
    for name, value in rect.items():
        if not np.isfinite(value).all():
            raise CalibrationError(f"the rectification ({name}) is not finite: the cameras' "
                                   "geometry cannot be rectified", key="extrinsics")
    views = []
    for side, K, dist, R_rect, P_rect in (("left", K_left, dist_left, rect["R1"], rect["P1"]),
                                          ("right", K_right, dist_right, rect["R2"], rect["P2"])):
        src, inside = source_pixels(K, dist, R_rect, P_rect, size)
        covered = float(inside.mean())
        if covered < MIN_COVERED:
            raise CalibrationError(
                f"the undistortion map does not cover the image: {covered:.0%} of the "
                f"rectified view reads pixels inside the camera's image (at least "
                f"{MIN_COVERED:.0%} expected); the distortion coefficients "
                f"{np.round(dist, 4).tolist()} do not describe a lens", key=f"{side}.dist")
        span = _spanned_share(src, inside, size)
        if span < MIN_SPAN:
            raise CalibrationError(
                f"the undistortion map does not cover the image: the rectified view reads "
                f"{span:.0%} of the camera's image (at least {MIN_SPAN:.0%} expected); the "
                f"distortion coefficients {np.round(dist, 4).tolist()} do not describe a lens",
                key=f"{side}.dist")
        folded = _folded_share(src, inside)
        if folded > MAX_FOLDED:
            raise CalibrationError(
                f"the undistortion map folds over ({folded:.0%} of neighbouring samples run "
                f"backwards; it must be monotonic); the distortion coefficients "
                f"{np.round(dist, 4).tolist()} do not describe a lens", key=f"{side}.dist")
        views.append(inside)
    overlap = float((views[0] & views[1]).mean())
    if overlap < MIN_OVERLAP:
        raise CalibrationError(f"the rectified views overlap on {overlap:.0%} of the image (at "
                               f"least {MIN_OVERLAP:.0%} expected): the cameras do not look at "
                               "the same scene", key="extrinsics")
