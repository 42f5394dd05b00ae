"""Synthetic calibration views: a board seen by a stereo pair with known K, distortion, R, T.

The board is drawn as an image, mapped into each camera by the homography of its pose (at 2x
resolution, then area-downsampled for anti-aliased edges), and distorted with OpenCV's model by
remapping: every distorted pixel samples the ideal image at its undistorted position.
"""

from __future__ import annotations

import cv2
import numpy as np

from edge_depth.calibration.stereo import Board

PX_PER_M = 4000.0  # board texture resolution


def board_texture(board: Board) -> tuple[np.ndarray, float]:
    """(texture uint8, margin_m): the board pattern with a white margin around it."""
    if board.kind == "charuco":
        sq = int(board.square_m * PX_PER_M)
        size = (board.cols * sq, board.rows * sq)
        image = board.charuco().generateImage(size, marginSize=0, borderBits=1)
    else:
        sq = int(board.square_m * PX_PER_M)
        cols, rows = board.cols + 1, board.rows + 1  # squares
        yy, xx = np.mgrid[0:rows * sq, 0:cols * sq]
        image = (((yy // sq) + (xx // sq)) % 2 * 255).astype(np.uint8)
    margin = sq
    image = cv2.copyMakeBorder(image, margin, margin, margin, margin, cv2.BORDER_CONSTANT,
                               value=255)
    return image, margin / PX_PER_M


def render_view(board: Board, K: np.ndarray, dist: np.ndarray, rvec: np.ndarray,
                tvec: np.ndarray, size: tuple[int, int], background: int = 90) -> np.ndarray:
    """Grey (H, W) image of the board at pose (rvec, tvec) (board -> camera, metres)."""
    w, h = size
    texture, margin = board_texture(board)
    # Board coordinates of the texture: the first inner corner of a checkerboard is at (0, 0).
    offset = margin + (board.square_m if board.kind == "checkerboard" else 0.0)
    R, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    t = np.asarray(tvec, np.float64).reshape(3)
    scale = 2.0
    K2 = K.copy()
    K2[:2] *= scale
    # a pixel centre u of the output is the centre of its `scale` x `scale` block: scale u +
    # (scale - 1) / 2 in the supersampled image (without this, corners were 0.3 px off)
    K2[:2, 2] += (scale - 1) / 2
    # texture pixel (x, y) -> board point ((x / PX_PER_M) - offset, ...) -> camera -> pixel
    # (texture pixel x spans [x - 0.5, x + 0.5): its left edge is the pattern's x / PX_PER_M)
    shift = 0.5 / PX_PER_M - offset
    to_board = np.array([[1 / PX_PER_M, 0, shift], [0, 1 / PX_PER_M, shift], [0, 0, 1]])
    H = K2 @ np.column_stack([R[:, 0], R[:, 1], t]) @ to_board
    big = (int(w * scale), int(h * scale))
    ideal = cv2.warpPerspective(texture, H, big, flags=cv2.INTER_AREA,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    ideal = cv2.resize(ideal, (w, h), interpolation=cv2.INTER_AREA)
    # distortion: sample the ideal (undistorted) image at each pixel's undistorted position
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    pts = np.stack([u.ravel(), v.ravel()], 1)[:, None]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-6)
    und = cv2.undistortPoints(pts, K, dist, R=None, P=K, criteria=criteria)
    und = und.reshape(h, w, 2)
    return cv2.remap(ideal, und[..., 0], und[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=background)


def random_stereo_views(board: Board, K_l, D_l, K_r, D_r, R, T, size, count: int,
                        seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """`count` views of the board in random poses in front of the rig, fully in both images
    (poses that put a corner outside either image are redrawn)."""
    rng = np.random.default_rng(seed)
    obj = board.object_points().astype(np.float64)
    centre = obj.mean(axis=0)
    lefts: list[np.ndarray] = []
    rights: list[np.ndarray] = []
    w, h = size
    while len(lefts) < count:
        rvec = rng.uniform(-0.45, 0.45, 3)
        Rb, _ = cv2.Rodrigues(rvec)
        dist_m = rng.uniform(0.45, 0.9)
        target = np.array([rng.uniform(-0.12, 0.08), rng.uniform(-0.08, 0.08), dist_m])
        tvec = target - Rb @ centre
        r_rvec, _ = cv2.Rodrigues(R @ Rb)
        r_tvec = R @ tvec + np.asarray(T).ravel()
        ok = True
        for rv, tv, K, D in ((rvec, tvec, K_l, D_l), (r_rvec, r_tvec, K_r, D_r)):
            px, _ = cv2.projectPoints(obj, rv, tv, K, D)
            px = px.reshape(-1, 2)
            if not ((px[:, 0] > 15) & (px[:, 0] < w - 15) & (px[:, 1] > 15)
                    & (px[:, 1] < h - 15)).all():
                ok = False
        if not ok:
            continue
        lefts.append(render_view(board, K_l, D_l, rvec, tvec, size))
        rights.append(render_view(board, K_r, D_r, r_rvec, r_tvec, size))
    return lefts, rights
