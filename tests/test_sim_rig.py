"""The synthetic rig's ground truth must be exactly right: everything downstream trusts it."""

from __future__ import annotations

import cv2
import numpy as np

from edge_depth.calibration.projection import transform_points
from edge_depth.sim import PATTERNS, RigConfig, make_sample
from edge_depth.sim.lidar import R_CAM_LIDAR, default_T_cam_lidar


def _warp_right_to_left(right: np.ndarray, disp_left: np.ndarray) -> np.ndarray:
    h, w = disp_left.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(right.astype(np.float32), u - disp_left, v, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def test_right_image_warped_by_gt_disparity_reproduces_left(noiseless_samples):
    for s in noiseless_samples:
        warped = _warp_right_to_left(s.right, s.disp_left)
        visible = ~s.occ_left
        mae = np.abs(warped - s.left.astype(np.float32))[visible].mean()
        assert mae < 1.0, f"seed {s.seed}: warp MAE {mae:.3f} grey levels"
        # and the check has teeth: a 1 px disparity error is visibly worse
        wrong = _warp_right_to_left(s.right, s.disp_left + 1.0)
        assert np.abs(wrong - s.left)[visible].mean() > 2 * mae


def test_left_view_warped_to_right_by_right_gt(noiseless_samples):
    for s in noiseless_samples:
        h, w = s.disp_right.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        warped = cv2.remap(s.left.astype(np.float32), u + s.disp_right, v, cv2.INTER_LINEAR)
        mae = np.abs(warped - s.right)[~s.occ_right].mean()
        assert mae < 1.0, f"seed {s.seed}: right-view warp MAE {mae:.3f}"


def test_occluded_pixels_are_those_covered_by_a_nearer_surface(noiseless_samples):
    for s in noiseless_samples:
        h, w = s.disp_left.shape
        u = np.arange(w)[None, :].repeat(h, 0)
        v = np.arange(h)[:, None].repeat(w, 1)
        u_right = np.rint(u - s.disp_left).astype(int)
        inside = (u_right >= 0) & (u_right < w)
        right_d = np.where(inside, s.disp_right[v, np.clip(u_right, 0, w - 1)], np.inf)
        covered = right_d > s.disp_left + 0.5  # a nearer surface in the right view
        agree = (covered == s.occ_left) | ~inside
        # exact at continuous positions; rounding to pixel centres may flip edge pixels only
        assert agree.mean() > 0.99
        assert s.occ_left[~inside].all(), "correspondents outside the right image are occluded"
        assert 0.005 < s.occ_left.mean() < 0.4


def test_disparity_is_affine_on_each_layer(noiseless_samples):
    s = noiseless_samples[0]
    _, owner = s.scene.render_depth_order("left")
    for k in np.unique(owner):
        ys, xs = np.nonzero(owner == k)
        if len(ys) < 50:
            continue
        A = np.stack([np.ones_like(xs), xs, ys], 1).astype(np.float64)
        coef, *_ = np.linalg.lstsq(A, s.disp_left[ys, xs].astype(np.float64), rcond=None)
        assert np.abs(A @ coef - s.disp_left[ys, xs]).max() < 1e-3


def test_lidar_points_land_on_pixels_with_their_depth(noiseless_samples):
    unseen_total = 0
    for s in noiseless_samples:
        rig = s.rig
        cam = transform_points(s.T_cam_lidar, s.scan.points)
        cam = cam[cam[:, 2] > 0.1]
        u = rig.focal_px * cam[:, 0] / cam[:, 2] + rig.cx
        v = rig.focal_px * cam[:, 1] / cam[:, 2] + rig.cy
        inside = (u > -0.5) & (u < rig.width - 0.5) & (v > -0.5) & (v < rig.height - 0.5)
        u, v, z = u[inside], v[inside], cam[inside, 2]
        assert len(z) > 500
        d_point = rig.focal_px * rig.baseline_m / z
        seen = np.abs(s.scene.nearest_disparity_at("left", u, v) - d_point) < 1e-3
        # where the camera sees the point's surface, the GT at the rounded pixel agrees
        # to within the plane's slope over half a pixel
        gt = s.disp_left[np.rint(v).astype(int), np.rint(u).astype(int)]
        assert np.median(np.abs(gt[seen] - d_point[seen])) < 0.05
        assert np.mean(np.abs(gt[seen] - d_point[seen]) < 0.5) > 0.99
        unseen_total += int((~seen).sum())
        # points the camera cannot see are hidden behind a nearer surface, never in front
        hidden = s.scene.nearest_disparity_at("left", u[~seen], v[~seen])
        assert (hidden > d_point[~seen]).all()
    # the LiDAR's parallax must produce some such points, but few
    assert unseen_total > 0


def test_lidar_range_noise_and_dropout_are_applied(small_rig):
    clean = make_sample(7, small_rig, PATTERNS["beams16"].noiseless())
    noisy = make_sample(7, small_rig, "beams16")
    assert len(noisy.scan) < len(clean.scan)  # dropouts
    assert noisy.scan.points.dtype == np.float32
    assert noisy.scan.point_stamps_ns is not None


def test_lidar_frame_is_x_forward_z_up_mounted_above_camera():
    T = default_T_cam_lidar(0.08)
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 0, 1])  # LiDAR forward = camera z
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1], [0, -1, 0])  # LiDAR up = camera -y
    np.testing.assert_allclose(T[:3, 3], [0, -0.08, 0])
    assert np.isclose(np.linalg.det(R_CAM_LIDAR), 1.0)


def test_planar_pattern_is_one_tilted_line(small_rig):
    s = make_sample(3, small_rig, "planar")
    assert 0 < len(s.scan) <= 450
    tilt = np.radians(PATTERNS["planar"].tilt_deg)
    normal = np.array([-np.sin(tilt), 0.0, np.cos(tilt)])  # the scan plane, pitched
    pts = s.scan.points.astype(np.float64)
    assert np.abs(pts @ normal).max() < 1e-4 * np.linalg.norm(pts, axis=1).max()
    forward = pts[:, 0] > 0.5
    assert (pts[forward, 2] < 0).all()  # tilted down: forward points lie below the LiDAR


def test_same_seed_same_bytes_different_seed_different_scene(small_rig):
    a, b, c = make_sample(11, small_rig), make_sample(11, small_rig), make_sample(12, small_rig)
    assert a.left.tobytes() == b.left.tobytes() and a.right.tobytes() == b.right.tobytes()
    assert a.disp_left.tobytes() == b.disp_left.tobytes()
    assert a.scan.points.tobytes() == b.scan.points.tobytes()
    assert a.left.tobytes() != c.left.tobytes()
    assert not np.array_equal(a.disp_left, c.disp_left)


def test_scene_statistics_match_the_spec():
    rig = RigConfig()
    counts = []
    for seed in range(6):
        s = make_sample(seed, rig)
        assert s.left.shape == (400, 640) and s.left.dtype == np.uint8
        assert rig.min_disparity_px <= s.disp_left.min()
        assert s.disp_left.max() <= rig.max_disparity_px + 1e-3
        counts.append(len(s.scene.layers) - 1)
    assert all(3 <= n <= 15 for n in counts)
    assert len(set(counts)) > 1
