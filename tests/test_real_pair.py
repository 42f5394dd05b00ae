"""tools/real_pairs.py builds the Aloe folder by the issue's recipe; tools/evaluate.py scores
the stereo-only net and the trivial SGBM + LiDAR fusion on it."""

from __future__ import annotations

import json

import cv2
import numpy as np

from edge_depth.sim.folder import read_scene_folder
from edge_depth.tools import evaluate, real_pairs


def fake_opencv_doc(folder, rng):
    """Stand-ins for aloeL/R.jpg and aloeGT.png at Aloe's full size (1282x1110): a textured
    left image, the right one shifted by a constant 40 px disparity."""
    folder.mkdir()
    left = cv2.GaussianBlur(rng.uniform(0, 255, (1110, 1282)).astype(np.float32), (0, 0), 2)
    left = cv2.normalize(left, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    right = np.roll(left, -40, axis=1)
    gt = np.full((1110, 1282), 40, np.uint8)
    gt[:, :40] = 0                                     # unknown where the right view ends
    cv2.imwrite(str(folder / "aloeL.jpg"), left)
    cv2.imwrite(str(folder / "aloeR.jpg"), right)
    cv2.imwrite(str(folder / "aloeGT.png"), gt)
    cv2.imwrite(str(folder / "baboon.jpg"), left[:64, :64])


def test_aloe_folder_follows_the_recipe(tmp_path):
    src = tmp_path / "doc"
    fake_opencv_doc(src, np.random.default_rng(0))
    out = tmp_path / "aloe"
    assert real_pairs.main(["--from", str(src), "--out", str(out), "--textures",
                            str(tmp_path / "tex")]) == 0
    scene = read_scene_folder(out)
    assert scene.left.shape == (400, 640)
    known = np.isfinite(scene.disp)
    np.testing.assert_array_equal(scene.disp[known], 20.0)   # 40 px at full size, halved
    ys, xs = np.nonzero(scene.sparse)
    np.testing.assert_array_equal(np.unique(ys), np.rint((np.arange(16) + 0.5) * 25))
    assert set(np.unique(xs % 2)) == {0}                      # every 2nd column
    assert abs(float(np.std(scene.sparse[ys, xs] - 20.0)) - 0.1) < 0.02
    assert json.loads((out / "meta.json").read_text())["evaluation_only"] is True
    assert (tmp_path / "tex" / "baboon.jpg").exists()
    assert not (tmp_path / "tex" / "aloeL.jpg").exists()


def test_motorcycle_folder_is_the_real_pair_from_scikit_image(tmp_path):
    out = tmp_path / "moto"
    assert real_pairs.main(["--motorcycle", "--out", str(out)]) == 0
    scene = read_scene_folder(out)
    assert scene.left.shape == scene.right.shape == (400, 640)
    known = np.isfinite(scene.disp)
    assert 0.85 < known.mean() < 0.95
    assert 7.0 < scene.disp[known].min() and scene.disp[known].max() < 61.0
    ys, xs = np.nonzero(scene.sparse)
    np.testing.assert_array_equal(np.unique(ys), np.rint((np.arange(16) + 0.5) * 25))
    # the GT is this pair's: the right view warped by it lands on the left view
    grid_x = (np.arange(640)[None, :] - np.where(known, scene.disp, 0)).astype(np.float32)
    grid_y = np.repeat(np.arange(400, dtype=np.float32)[:, None], 640, 1)
    warped = cv2.remap(scene.right.astype(np.float32), grid_x, grid_y, cv2.INTER_LINEAR)
    left = scene.left.astype(np.float32)
    inside = known & (grid_x > 0)
    assert np.median(np.abs(warped - left)[inside]) < 5.0
    assert np.median(np.abs(scene.right.astype(np.float32) - left)[inside]) > 10.0
    assert json.loads((out / "meta.json").read_text())["evaluation_only"] is False


def test_evaluate_scores_the_fusion_and_the_stereo_only_net(tmp_path):
    src = tmp_path / "doc"
    fake_opencv_doc(src, np.random.default_rng(1))
    real_pairs.main(["--from", str(src), "--out", str(tmp_path / "aloe"), "--textures",
                     str(tmp_path / "tex")])
    out, pic = tmp_path / "eval.json", tmp_path / "errors.png"
    assert evaluate.main([str(tmp_path / "aloe"), "--methods",
                          "net,sgbm,sgbm-filled,sgbm+lidar,lidar-nearest", "--no-lidar",
                          "--json", str(out), "--picture", str(pic)]) == 0
    summary = json.loads(out.read_text())
    assert set(summary) == {"net", "net-nolidar", "sgbm", "sgbm-filled", "sgbm+lidar",
                            "lidar-nearest"}
    # a constant 20 px shift of a textured image: SGBM matches it; the fusion fills its holes
    assert summary["sgbm+lidar"]["density"] == 100.0
    assert summary["sgbm+lidar"]["epe"] <= summary["sgbm"]["epe"]
    assert summary["sgbm-filled"]["bad3"] < 5.0
    assert summary["lidar-nearest"]["epe"] < 0.2
    assert summary["net-nolidar"]["density"] == 100.0
    # the picture: left, GT and six error tiles at half size, three to a row
    tiles = cv2.imread(str(pic))
    assert tiles.shape == (3 * 200, 3 * 320, 3)
    nearest = tiles[2 * 200 + 30:3 * 200 - 10, 10:320 - 10]             # lidar-nearest: exact
    sgbm = tiles[200 + 30:2 * 200 - 10, 10:320 - 10]                     # sgbm: holes in red
    holes = lambda tile: ((tile[..., 2] > 200) & (tile[..., :2] < 60).all(-1)).mean()  # noqa: E731
    assert nearest.mean() < 40 and holes(nearest) < 0.01 < holes(sgbm)
