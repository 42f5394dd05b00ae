"""Training from recorded data (scene folders, MCAP, KITTI and SceneFlow layouts) and with
DistributedDataParallel."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from edge_depth.cli import main as cli  # noqa: E402
from edge_depth.model.data import RecordedTrainSet  # noqa: E402
from edge_depth.model.datasets import (  # noqa: E402
    kitti_arrays,
    open_training_data,
    read_kitti_calibration,
    sceneflow_arrays,
)
from edge_depth.sim.folder import write_pfm  # noqa: E402
from edge_depth.tools import train  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINT = ROOT / "edge" / "models" / "sparse_stereo.pt"


def make_kitti(root: Path, f=721.5377, b=0.5327) -> dict:
    drive = root / "2011_09_26_drive_0001_sync"
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (48, 96, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (48, 96, 3), dtype=np.uint8)
    depth = np.zeros((48, 96), np.uint16)
    depth[10, 20], depth[30, 50] = 10 * 256, 25 * 256  # 10 m and 25 m
    gt = np.full((48, 96), 20 * 256, np.uint16)
    for sub, image in (("image_02/data", left), ("image_03/data", right)):
        (drive / sub).mkdir(parents=True)
        cv2.imwrite(str(drive / sub / "0000000005.png"), image)
    for kind, image in (("velodyne_raw", depth), ("groundtruth", gt)):
        for cam in ("image_02", "image_03"):
            (drive / "proj_depth" / kind / cam).mkdir(parents=True)
            cv2.imwrite(str(drive / "proj_depth" / kind / cam / "0000000005.png"), image)
    (drive / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\n"
        f"P_rect_02: {f} 0 609.5593 44.85728 0 {f} 172.854 0.2163791 0 0 1 0.002745884\n"
        f"P_rect_03: {f} 0 609.5593 {44.85728 - f * b} 0 {f} 172.854 2.395 0 0 1 0.0037\n")
    return dict(left=left, right=right)


def test_kitti_depth_completion_layout_reads_as_disparity(tmp_path):
    images = make_kitti(tmp_path)
    f, b = read_kitti_calibration(tmp_path / "2011_09_26_drive_0001_sync" /
                                  "calib_cam_to_cam.txt")
    assert f == pytest.approx(721.5377) and b == pytest.approx(0.5327)
    (arrays,) = list(kitti_arrays(tmp_path))
    grey = cv2.cvtColor(images["left"], cv2.COLOR_BGR2GRAY).astype(int)
    assert np.abs(arrays["left"].astype(int) - grey).max() <= 1  # decoder's own rounding
    assert arrays["valid"].sum() == 2
    assert arrays["sparse"][10, 20] == pytest.approx(f * b / 10, rel=1e-5)
    assert arrays["sparse"][30, 50] == pytest.approx(f * b / 25, rel=1e-5)
    assert arrays["sparse_right"][10, 20] == pytest.approx(f * b / 10, rel=1e-5)
    np.testing.assert_allclose(arrays["gt"], f * b / 20, rtol=1e-5)


def test_sceneflow_layout_reads_gt_and_a_lidar_like_sample(tmp_path):
    rng = np.random.default_rng(1)
    base = Path("TRAIN/A/0000")
    disp = {side: rng.uniform(1, 80, (64, 96)).astype(np.float32) for side in ("left", "right")}
    for side in ("left", "right"):
        (tmp_path / "frames_cleanpass" / base / side).mkdir(parents=True)
        (tmp_path / "disparity" / base / side).mkdir(parents=True)
        cv2.imwrite(str(tmp_path / "frames_cleanpass" / base / side / "0006.png"),
                    rng.integers(0, 256, (64, 96, 3), dtype=np.uint8))
        write_pfm(tmp_path / "disparity" / base / side / "0006.pfm", disp[side])
    (arrays,) = list(sceneflow_arrays(tmp_path))
    np.testing.assert_array_equal(arrays["gt"], disp["left"])
    np.testing.assert_array_equal(arrays["gt_right"], disp["right"])
    rows = np.nonzero(arrays["valid"].any(1))[0]
    assert len(rows) == 16
    v = arrays["valid"]
    np.testing.assert_array_equal(arrays["sparse"][v], disp["left"][v])


def test_bad_data_specs_are_clear_errors(tmp_path):
    from edge_depth.errors import ConfigError

    with pytest.raises(ConfigError, match="scene folders, a .mcap file"):
        open_training_data(str(tmp_path))
    with pytest.raises(ConfigError, match="existing .mcap"):
        open_training_data(str(tmp_path / "missing.mcap"))
    with pytest.raises(ConfigError, match="kitti:DIR"):
        list(open_training_data(f"kitti:{tmp_path}")())


def test_self_supervised_fine_tuning_from_a_recording(tmp_path):
    rec = tmp_path / "rec.mcap"
    assert cli(["synth", "--mcap", str(rec), "--frames", "2", "--size", "160x96"]) == 0
    data = RecordedTrainSet(str(rec), (64, 64), buffer=2)
    batch = next(iter(data))
    assert batch["left"].shape == (1, 64, 64)
    assert float(batch["valid"].sum()) > 0 and float(batch["valid_right"].sum()) > 0
    out = tmp_path / "ft"
    assert train.main(["--out", str(out), "--data", str(rec), "--init", str(CHECKPOINT),
                       "--mode", "self", "--steps", "2", "--batch", "1", "--crop", "64x64",
                       "--iters", "2", "--workers", "0"]) == 0
    ckpt = torch.load(out / "final.pt", weights_only=False)
    assert ckpt["step"] == 2 and ckpt["args"]["data"] == str(rec)
    init = torch.load(CHECKPOINT, weights_only=False)
    assert list(ckpt["config"]["widths"]) == list(init["config"]["widths"])
    changed = [k for k in init["model"] if not torch.equal(init["model"][k], ckpt["model"][k])]
    assert changed  # it trained from the shipped weights
    rows = (out / "metrics.csv").read_text().splitlines()
    assert len(rows) == 3 and "nan" not in rows[-1].split(",")[1]


def test_supervised_training_from_scene_folders(tmp_path):
    scenes = tmp_path / "scenes"
    assert cli(["synth", "--out", str(scenes), "--count", "2", "--size", "160x96"]) == 0
    out = tmp_path / "sup"
    assert train.main(["--out", str(out), "--data", str(scenes), "--steps", "2", "--batch",
                       "1", "--crop", "64x64", "--iters", "2", "--workers", "0"]) == 0
    assert (out / "final.pt").exists()


@pytest.mark.slow
def test_torchrun_two_cpu_processes_keep_identical_replicas(tmp_path):
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2",
           "--master_port=29577", str(ROOT / "tools" / "train.py"), "--out", str(out),
           "--steps", "2", "--batch", "1", "--crop", "64x64", "--iters", "2", "--workers", "0",
           "--threads", "1"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT,
                            env=dict(os.environ, OMP_NUM_THREADS="1"))
    # the ranks' own errors come first in stderr, torchrun's summary of them last (a
    # failure in CI, rank 1 aborted with SIGABRT, showed only the summary)
    assert result.returncode == 0, result.stderr[:3000] + "\n...\n" + result.stderr[-1500:]
    sums = json.loads((out / "replicas.json").read_text())
    assert len(sums) == 2 and sums[0] == sums[1]
    ckpt = torch.load(out / "final.pt", weights_only=False)
    assert ckpt["step"] == 2 and not any(k.startswith("module.") for k in ckpt["model"])
