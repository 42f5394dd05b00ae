"""tools/real_pairs.py builds the Aloe folder by the issue's recipe; tools/evaluate.py scores
the stereo-only net and the trivial SGBM + LiDAR fusion on it."""

from __future__ import annotations

import json

import cv2
import numpy as np

from edge.sim.folder import read_scene_folder
from tools import evaluate, real_pairs


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


def test_evaluate_scores_the_fusion_and_the_stereo_only_net(tmp_path):
    src = tmp_path / "doc"
    fake_opencv_doc(src, np.random.default_rng(1))
    real_pairs.main(["--from", str(src), "--out", str(tmp_path / "aloe"), "--textures",
                     str(tmp_path / "tex")])
    out = tmp_path / "eval.json"
    assert evaluate.main([str(tmp_path / "aloe"), "--methods",
                          "net,sgbm,sgbm-filled,sgbm+lidar,lidar-nearest", "--no-lidar",
                          "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert set(summary) == {"net", "net-nolidar", "sgbm", "sgbm-filled", "sgbm+lidar",
                            "lidar-nearest"}
    # a constant 20 px shift of a textured image: SGBM matches it; the fusion fills its holes
    assert summary["sgbm+lidar"]["density"] == 100.0
    assert summary["sgbm+lidar"]["epe"] <= summary["sgbm"]["epe"]
    assert summary["sgbm-filled"]["bad3"] < 5.0
    assert summary["lidar-nearest"]["epe"] < 0.2
    assert summary["net-nolidar"]["density"] == 100.0
