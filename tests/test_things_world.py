"""The things world: exact ray-cast geometry, consistent views, camera effects, storage, the
GT-sampled LiDAR and the training stream's augmentations."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.sim.gt_lidar import GtLidarPattern
from edge_depth.sim.photometry import CameraResponse, apply_camera
from edge_depth.sim.primitives import Cylinder, PlanePatch, Sphere, box_faces
from edge_depth.sim.textures import OPENCV_DOC_PHOTOS, texture_pyramids
from edge_depth.sim.things_store import DISPARITY_SCALE, generate, list_things, read_things
from edge_depth.sim.world import ThingsScene, WorldConfig, make_things_sample

SMALL = WorldConfig(width=160, height=100, focal_px=120.0, min_objects=3, max_objects=8,
                    max_disparity_range_px=(20.0, 35.0))
ORIGIN = np.zeros(3)


def test_sphere_hit_is_the_near_surface_on_the_axis_and_a_miss_beside_it():
    sphere = Sphere(np.array([0.0, 0.0, 5.0]), 1.0, 0, np.eye(3))
    hit = sphere.intersect(ORIGIN, np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0]]))
    assert hit.t[0] == pytest.approx(4.0)
    assert np.isinf(hit.t[1])
    np.testing.assert_allclose(hit.normal[0], [0, 0, -1], atol=1e-12)


def test_plane_patch_respects_its_outline_and_depth_is_the_ray_parameter():
    patch = PlanePatch(np.array([0.0, 0.0, 2.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                       (0.5, 0.25), "rect", 0)
    hit = patch.intersect(ORIGIN, np.array([[0.2, 0.1, 1.0], [0.3, 0.0, 1.0]]))
    assert hit.t[0] == pytest.approx(2.0)          # (0.4, 0.2) m on the plane: inside
    assert np.isinf(hit.t[1])                       # 0.6 m > 0.5 m half-width: outside
    np.testing.assert_allclose(hit.tex[0], [0.4, 0.2])


def test_cylinder_hits_its_side_and_stops_at_its_ends():
    pole = Cylinder(np.array([0.0, -1.0, 4.0]), np.array([0.0, 1.0, 0.0]), 2.0, 0.1, 0)
    hit = pole.intersect(ORIGIN, np.array([[0.0, 0.0, 1.0], [0.0, 0.3, 1.0]]))
    assert hit.t[0] == pytest.approx(3.9)
    assert np.isinf(hit.t[1])                       # y = 1.2 m at z 4: beyond the top end


def test_box_has_six_faces_around_its_centre():
    faces = box_faces(np.array([0.0, 0.0, 3.0]), np.eye(3), np.array([0.5, 0.4, 0.3]), 0)
    assert len(faces) == 6
    hit = min(f.intersect(ORIGIN, np.array([[0.0, 0.0, 1.0]])).t[0] for f in faces)
    assert hit == pytest.approx(2.7)


def test_right_view_sees_each_visible_left_point_at_the_same_depth_shifted_by_disparity():
    scene = ThingsScene(SMALL, np.random.default_rng(3))
    v, u = np.mgrid[0:SMALL.height, 0:SMALL.width].astype(np.float64)
    depth, *_ = scene.trace("left", u.ravel(), v.ravel())
    depth = depth.reshape(u.shape)
    occluded = scene.occlusion("left", depth)
    disparity = SMALL.focal_px * SMALL.baseline_m / depth
    seen = ~occluded
    assert 0.5 < seen.mean() < 1.0
    right_depth, *_ = scene.trace("right", (u - disparity)[seen], v[seen])
    np.testing.assert_allclose(right_depth, depth[seen], rtol=1e-6)
    # an occluded pixel inside the right image is hidden by something nearer there
    hidden = occluded & (u - disparity > 0) & np.isfinite(depth)
    if hidden.any():
        other, *_ = scene.trace("right", (u - disparity)[hidden], v[hidden])
        assert (other < depth[hidden]).all()


def test_rendered_sample_has_consistent_images_gt_and_range():
    sample = make_things_sample(5, SMALL)
    assert sample.left.shape == (100, 160) and sample.left.dtype == np.uint8
    assert 0.3 < sample.disp_left.min() and sample.disp_left.max() < 40
    seen = ~sample.occ_left
    v, u = np.nonzero(seen)
    u_r = np.rint(u - sample.disp_left[v, u]).astype(int)
    ok = (u_r >= 0) & (u_r < 160)
    # the right GT at the correspondent agrees with the left GT (up to the rounding of u_r
    # and slanted surfaces) for most visible pixels
    agree = np.abs(sample.disp_right[v[ok], u_r[ok]] - sample.disp_left[v[ok], u[ok]]) < 0.5
    assert agree.mean() > 0.9
    assert 20 < sample.left.mean() < 235 and sample.left.std() > 5
    again = make_things_sample(5, SMALL)
    np.testing.assert_array_equal(again.left, sample.left)


def test_texture_pool_mixes_sources_and_never_uses_the_evaluation_pair():
    assert not any(n.startswith(("aloe", "left", "right", "tsukuba")) for n in OPENCV_DOC_PHOTOS)
    pool = texture_pyramids(3)
    assert len(pool) >= 12 + 6 + 6 + 1                # photos, noise, repetitive, flat
    for pyramid in pool:
        assert len(pyramid) == 3 and pyramid[1].shape[0] == (pyramid[0].shape[0] + 1) // 2


def test_camera_response_changes_gain_between_views_but_keeps_structure():
    rng = np.random.default_rng(0)
    radiance = np.tile(np.linspace(0.2, 0.8, 64, dtype=np.float32), (48, 1))
    base = CameraResponse(100.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0)
    image = apply_camera(radiance, base, rng, float(radiance.mean()))
    assert abs(float(image.mean()) - 100.0) < 1.5    # auto-exposure lands on its target
    darker = apply_camera(radiance, CameraResponse(80.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0), rng,
                          float(radiance.mean()))
    assert float(darker.mean()) == pytest.approx(80.0, abs=1.5)
    assert np.corrcoef(image.ravel(), darker.ravel())[0, 1] > 0.99


def test_view_spread_scales_how_the_two_cameras_differ_and_keeps_the_scene():
    base = CameraResponse.random(np.random.default_rng(3))
    same = [base.for_view(v, np.random.default_rng(5), spread=0.0) for v in ("left", "right")]
    assert same[0] == same[1] == base  # one response for both cameras
    full = base.for_view("left", np.random.default_rng(5))  # spread 1: as rendered before
    rng = np.random.default_rng(5)
    assert full.exposure == base.exposure * float(rng.uniform(0.88, 1.12))
    assert full.gamma == base.gamma * float(rng.uniform(0.94, 1.06))
    quarter = base.for_view("left", np.random.default_rng(5), spread=0.25)
    assert quarter.exposure - base.exposure == pytest.approx((full.exposure - base.exposure) / 4)
    cfg = WorldConfig(width=96, height=64)
    a = make_things_sample(7, cfg)
    b = make_things_sample(7, WorldConfig(width=96, height=64, view_spread=0.0))
    np.testing.assert_array_equal(a.disp_left, b.disp_left)  # same scene, other cameras
    assert np.array_equal(a.left, make_things_sample(7, cfg).left)
    assert not np.array_equal(a.right, b.right)


def test_clean_cameras_keep_the_scene_and_make_the_views_agree():
    from edge_depth.selfcheck import warp_right_to_left

    clean = CameraResponse.random(np.random.default_rng(3)).clean()
    assert (clean.gamma, clean.vignetting, clean.blur_sigma_px, clean.jpeg_quality) == \
        (1.0, 0.0, 0.0, 0)
    errors = []
    for cfg in (WorldConfig(width=160, height=96),
                WorldConfig(width=160, height=96, clean_cameras=True)):
        sample = make_things_sample(11, cfg)
        seen = (sample.disp_left > 0) & ~sample.occ_left
        warped = warp_right_to_left(sample.right.astype(np.float32), sample.disp_left)
        errors.append((sample.disp_left, float(np.abs(sample.left - warped)[seen].mean())))
    np.testing.assert_array_equal(errors[0][0], errors[1][0])  # the same scene
    assert errors[1][1] < 0.7 * errors[0][1]                     # the views agree far better


def test_store_round_trips_disparity_to_a_sixty_fourth_of_a_pixel(tmp_path):
    assert generate(tmp_path, 2, 10, SMALL) == 2
    assert generate(tmp_path, 2, 10, SMALL) == 0       # already there: skipped
    files = list_things(tmp_path)
    assert [f.name for f in files] == ["0000010.npz", "0000011.npz"]
    stored = read_things(files[0])
    sample = make_things_sample(10, SMALL)
    assert np.abs(stored["disp_left"] - sample.disp_left).max() <= 0.5 / DISPARITY_SCALE
    np.testing.assert_array_equal(stored["occ_right"], sample.occ_right)


def test_gt_lidar_rows_read_the_gt_where_they_land():
    gt = np.tile(np.arange(1, 201, dtype=np.float32), (100, 1))  # d = column + 1
    pattern = GtLidarPattern.evenly(100, 4, column_step=2, noise_px=0.0)
    sparse = pattern.sample(gt, np.random.default_rng(0))
    rows = np.unique(np.nonzero(sparse)[0])
    np.testing.assert_array_equal(rows, [12, 38, 62, 88])  # (k + 0.5) * 100 / 4, rounded
    ys, xs = np.nonzero(sparse)
    np.testing.assert_array_equal(sparse[ys, xs], xs + 1)
    assert len(xs) == 4 * 100
    shifted = GtLidarPattern.evenly(100, 4, column_step=2, noise_px=0.0, shift_px=(2.0, 0.0))
    ys, xs = np.nonzero(shifted.sample(gt, np.random.default_rng(0)))
    assert np.all(shifted.sample(gt, np.random.default_rng(0))[ys, xs] == xs + 3)


def test_gt_lidar_random_patterns_include_stereo_only_and_skip_unknown_gt():
    rng = np.random.default_rng(1)
    patterns = [GtLidarPattern.random(400, rng) for _ in range(200)]
    assert 5 < sum(p is None for p in patterns) < 50
    gt = np.zeros((400, 640), np.float32)
    some = next(p for p in patterns if p is not None)
    assert not some.sample(gt, rng).any()


def test_gt_lidar_none_share_sets_the_stereo_only_probability():
    rng = np.random.default_rng(2)
    none = [GtLidarPattern.random(400, rng, none_share=0.5) is None for _ in range(400)]
    assert 160 < sum(none) < 240
    assert all(GtLidarPattern.random(400, rng, none_share=1.0) is None for _ in range(20))
    assert all(GtLidarPattern.random(400, rng, none_share=0.0) is not None for _ in range(50))
    with pytest.raises(ValueError, match="none_share"):
        GtLidarPattern.random(400, rng, none_share=1.5)


def test_training_stream_flips_swap_views_and_lidar_matches_the_gt(tmp_path):
    from edge_depth.model.things_data import ThingsTrainSet, spatial

    generate(tmp_path, 2, 0, WorldConfig(width=192, height=128, focal_px=140.0,
                                         max_disparity_range_px=(20.0, 30.0)))
    arrays = read_things(list_things(tmp_path)[0])
    rng = np.random.default_rng(0)
    for _ in range(20):
        out = spatial(dict(arrays), rng, (96, 64))
        if out["left"].shape == arrays["left"].shape and not np.array_equal(out["left"],
                                                                            arrays["left"]):
            np.testing.assert_array_equal(out["left"], arrays["right"][:, ::-1])
            np.testing.assert_array_equal(out["disp_left"], arrays["disp_right"][:, ::-1])
            break
    else:
        pytest.fail("no unscaled flip in 20 draws")
    stream = iter(ThingsTrainSet(tmp_path, (96, 64), rig_share=0.0))
    for _ in range(6):
        batch = next(stream)
        assert batch["left"].shape == (1, 64, 96)
        on = batch["valid"] > 0
        if on.any():  # the LiDAR reads the GT, noise ≤ 0.3 px std (and a 2 % scale at worst)
            err = (batch["sparse"][on] - batch["gt"][on]).abs()
            assert float(err.median()) < 1.0


def test_photometric_augmentation_draws_per_camera_as_often_as_asked():
    import torch

    from edge_depth.model.things_data import photometric

    image = torch.linspace(0, 255, 64 * 96).reshape(1, 64, 96)
    rng = np.random.default_rng(3)
    differ = {share: sum(not torch.equal(*photometric(image, image.clone(), rng, share))
                         for _ in range(200)) for share in (0.0, 0.2, 1.0)}
    assert differ[0.0] == 0                       # both views always share one change
    assert differ[1.0] == 200
    assert 50 < differ[0.2] < 95                  # 1 - 0.8^2 = 36 % of 200 = 72


def test_asymmetric_share_is_checked_and_applies_to_things_data_only(tmp_path, capsys):
    from edge_depth.tools import train

    for extra in (["--data", "things:x", "--asymmetric-share", "1.5"],
                  ["--asymmetric-share", "0.1"]):
        with pytest.raises(SystemExit):
            train.main(["--out", str(tmp_path / "r"), "--steps", "1"] + extra)
    err = capsys.readouterr().err
    assert "--asymmetric-share must be within 0-1, got 1.5" in err
    assert "--asymmetric-share applies to --data things:DIR only" in err


def test_rig_samples_come_without_lidar_as_often_as_asked(tmp_path, capsys):
    from edge_depth.model.things_data import ThingsTrainSet
    from edge_depth.tools import train

    generate(tmp_path, 1, 0, WorldConfig(width=192, height=128, focal_px=140.0,
                                         max_disparity_range_px=(20.0, 30.0)))

    def without_lidar(share: float) -> int:  # all rig samples: crops of a 640x400 frame
        stream = iter(ThingsTrainSet(tmp_path, (96, 64), rig_share=1.0,
                                     rig_stereo_only_share=share))
        samples = [next(stream) for _ in range(16)]
        if share == 1.0:  # neither view keeps its LiDAR
            assert not any(float(b[k].abs().sum()) for b in samples
                           for k in ("sparse", "valid", "sparse_right", "valid_right"))
        return sum(not bool(b["valid"].any()) for b in samples)

    assert without_lidar(1.0) == 16
    assert without_lidar(0.0) <= 2          # only crops that miss the 16 beams
    assert 3 <= without_lidar(0.5) <= 13
    for extra in (["--data", "things:x", "--rig-stereo-only-share", "2"],
                  ["--rig-stereo-only-share", "0.5"],
                  ["--data", "things:x", "--stereo-only-share", "-0.1"]):  # the same check
        with pytest.raises(SystemExit):
            train.main(["--out", str(tmp_path / "r"), "--steps", "1"] + extra)
    err = capsys.readouterr().err
    assert "--rig-stereo-only-share must be within 0-1, got 2.0" in err
    assert "--rig-stereo-only-share applies to --data things:DIR only" in err
    assert "--stereo-only-share must be within 0-1, got -0.1" in err


def test_things_stream_refuses_an_empty_folder(tmp_path):
    from edge_depth.model.things_data import ThingsTrainSet

    with pytest.raises(ValueError, match="no things samples"):
        ThingsTrainSet(tmp_path)


def test_gt_lidar_projected_from_the_right_view_keeps_what_the_left_camera_sees():
    # right view: a box at disparity 40 over columns 60-119 in front of a wall at 11; in the
    # left view the box covers columns 100-159 and the wall the rest. The wall the right
    # camera sees just right of the box (columns 120-148) lands inside the box in the left
    # view (131-159): hidden there, so the occlusion filter must drop it.
    right = np.full((60, 300), 11.0, np.float32)
    right[:, 60:120] = 40.0
    left = np.full((60, 300), 11.0, np.float32)
    left[:, 100:160] = 40.0
    pattern = GtLidarPattern.evenly(60, 3, column_step=2, noise_px=0.0)
    sparse = pattern.sample_projected(right, np.random.default_rng(0))
    ys, xs = np.nonzero(sparse)
    np.testing.assert_array_equal(sparse[ys, xs], left[ys, xs])  # no hidden wall point left
    assert ((xs >= 100) & (xs < 160)).sum() == 3 * 30  # the box, every 2nd column of each row
    assert ((xs >= 160) & (xs < 300)).sum() > 3 * 60  # the wall right of it
    scan = pattern.sample(right, np.random.default_rng(0))
    assert (scan[:, 120:149] == 11).sum() == 3 * 15  # the hidden wall was in the scan


def test_dims_set_the_widths_of_a_network_from_scratch_only(tmp_path, capsys):
    import argparse

    from edge_depth.model.config import ModelConfig
    from edge_depth.model.network import SparseStereoNet
    from edge_depth.tools import train
    from edge_depth.tools.train_args import parse_dims

    dims = parse_dims("feature=48,context=32,hidden=48,motion=48,head=32")  # stage 17's
    assert dims == dict(feature_dim=48, context_dim=32, hidden_dim=48, motion_dim=48,
                        head_dim=32)
    net = SparseStereoNet(ModelConfig(**dims))
    assert net.config.hidden_dim == 48 and net.config.context_dim == 32
    for bad in ("hidden=0", "width=48", "hidden=4.5"):
        with pytest.raises(argparse.ArgumentTypeError, match="NAME=N"):
            parse_dims(bad)
    with pytest.raises(SystemExit):
        train.main(["--out", str(tmp_path / "r"), "--steps", "1", "--dims", "hidden=48",
                    "--init", str(tmp_path / "x.pt")])
    assert "--dims is for a network from scratch" in capsys.readouterr().err
