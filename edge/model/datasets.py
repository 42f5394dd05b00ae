"""Training data besides the on-the-fly rig: scene folders, MCAP recordings (the real use
case: record on the robot, fine-tune self-supervised), the KITTI depth-completion layout and
the SceneFlow layout.

Every reader yields the dict of `edge.model.data.sample_to_arrays`: grey `left`, `right`
(uint8), `gt` / `gt_right` disparity (float32, 0 = unknown; zeros when the source has none),
`sparse` / `valid` and `sparse_right` / `valid_right` (the LiDAR in each view as disparity).
`open_training_data(spec)` picks the reader: a directory of scene folders, a `.mcap` file,
`kitti:DIR` or `sceneflow:DIR`.

KITTI depth completion, as laid out here (one folder per drive):
    DIR/<drive>/image_02/data/<id>.png, image_03/data/<id>.png          rectified colour pair
    DIR/<drive>/proj_depth/velodyne_raw/image_0{2,3}/<id>.png          sparse depth, uint16 / 256 m
    DIR/<drive>/proj_depth/groundtruth/image_0{2,3}/<id>.png           optional GT depth, same
    DIR/<drive>/calib_cam_to_cam.txt                                   P_rect_02, P_rect_03
Depth becomes disparity with f = P_rect_02[0, 0] and B = (P_rect_02[0, 3] − P_rect_03[0, 3]) / f.

SceneFlow (FlyingThings3D / Driving / Monkaa):
    DIR/frames_cleanpass/<...>/left/<id>.png, right/<id>.png
    DIR/disparity/<...>/left/<id>.pfm, right/<id>.pfm
SceneFlow has no LiDAR: the sparse input is the GT sampled on `lines` image rows (a 16-beam-like
pattern), which is how the paper's synthetic pre-training is usually set up.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from edge_depth.errors import ConfigError
from edge_depth.sim.folder import list_scene_folders, read_grey, read_pfm, read_scene_folder

log = logging.getLogger(__name__)


def _arrays(left, right, gt=None, gt_right=None, sparse=None, sparse_right=None) -> dict:
    zeros = np.zeros(left.shape, np.float32)

    def clean(d):
        if d is None:
            return zeros
        d = np.asarray(d, np.float32)
        return np.where(np.isfinite(d) & (d > 0), d, 0).astype(np.float32)

    sparse, sparse_right = clean(sparse), clean(sparse_right)
    return dict(left=left, right=right, gt=clean(gt), gt_right=clean(gt_right), sparse=sparse,
                valid=sparse > 0, sparse_right=sparse_right, valid_right=sparse_right > 0)


# -- scene folders ---------------------------------------------------------------------------
def scene_folder_arrays(folder: Path) -> dict:
    from edge_depth.calibration.model import StereoCalibration
    from edge_depth.calibration.projection import project_to_disparity

    scene = read_scene_folder(folder)
    sparse_right = None
    meta = scene.meta
    if scene.lidar is not None and {"focal_px", "baseline_m", "T_cam_lidar"} <= set(meta):
        h, w = scene.left.shape
        calib = StereoCalibration.ideal(meta["focal_px"], meta["baseline_m"], (w, h),
                                        meta.get("cx"), meta.get("cy"))
        sparse_right, _ = project_to_disparity(scene.lidar, calib,
                                               np.asarray(meta["T_cam_lidar"]), "right")
    return _arrays(scene.left, scene.right, scene.disp, None, scene.sparse, sparse_right)


# -- MCAP recordings -------------------------------------------------------------------------
def mcap_arrays(path: Path):
    """Frames of a recording with their LiDAR projected into both views (calibration from the
    recording); GT where the recording carries /sim/gt_disparity."""
    from edge_depth.calibration.projection import project_to_disparity
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource
    from edge_depth.capture.synced import synced_frames

    found = recording_calibration(McapSource(path))
    if found is None:
        raise ConfigError("data", "a recording with its calibration (/edge/calibration, or "
                          "a CameraInfo pair)", str(path))
    stereo, lidar, _ = found
    offset = lidar.time_offset_ns if lidar else 0
    T = None if lidar is None else lidar.T_cam_lidar
    for _, left, right, points, gt in synced_frames(path, stereo, offset, deskew_with=T):
        sparse = sparse_right = None
        if lidar is not None and len(points):
            sparse, _ = project_to_disparity(points, stereo, lidar.T_cam_lidar, "left")
            sparse_right, _ = project_to_disparity(points, stereo, lidar.T_cam_lidar, "right")
        yield _arrays(left, right, gt, None, sparse, sparse_right)


# -- KITTI depth completion ------------------------------------------------------------------
def read_kitti_calibration(path: Path) -> tuple[float, float]:
    """calib_cam_to_cam.txt -> (focal px, baseline m) of the rectified image_02/image_03."""
    rows = {}
    for line in path.read_text().splitlines():
        key, _, values = line.partition(":")
        if key in ("P_rect_02", "P_rect_03"):
            rows[key] = np.array(values.split(), np.float64).reshape(3, 4)
    if len(rows) != 2:
        raise ConfigError("P_rect_02/P_rect_03", "both rows", sorted(rows), str(path))
    f = rows["P_rect_02"][0, 0]
    return f, (rows["P_rect_02"][0, 3] - rows["P_rect_03"][0, 3]) / f


def read_kitti_depth(path: Path) -> np.ndarray:
    """16-bit PNG depth (value / 256 = metres, 0 = none) -> float32 metres."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16:
        raise ConfigError("data", "a 16-bit PNG depth map", str(path))
    return raw.astype(np.float32) / 256.0


def _depth_to_disparity(depth: np.ndarray, f: float, b: float) -> np.ndarray:
    out = np.zeros_like(depth)
    np.divide(f * b, depth, out=out, where=depth > 0)
    return out


def kitti_arrays(root: Path):
    drives = sorted(p for p in root.iterdir() if (p / "image_02" / "data").is_dir())
    if not drives:
        raise ConfigError("data", "kitti:DIR with DIR/<drive>/image_02/data", str(root))
    for drive in drives:
        f, b = read_kitti_calibration(drive / "calib_cam_to_cam.txt")
        proj = drive / "proj_depth"
        for left_path in sorted((drive / "image_02" / "data").glob("*.png")):
            name = left_path.name
            sparse = {}
            gt = {}
            for cam in ("02", "03"):
                lidar_path = proj / "velodyne_raw" / f"image_{cam}" / name
                gt_path = proj / "groundtruth" / f"image_{cam}" / name
                sparse[cam] = (_depth_to_disparity(read_kitti_depth(lidar_path), f, b)
                               if lidar_path.exists() else None)
                gt[cam] = (_depth_to_disparity(read_kitti_depth(gt_path), f, b)
                           if gt_path.exists() else None)
            yield _arrays(read_grey(left_path), read_grey(drive / "image_03" / "data" / name),
                          gt["02"], gt["03"], sparse["02"], sparse["03"])


# -- SceneFlow -------------------------------------------------------------------------------
def lidar_like_sample(gt: np.ndarray, lines: int = 16, seed: int = 0) -> np.ndarray:
    """GT disparity kept on `lines` evenly spaced rows (jittered), every other pixel."""
    h, w = gt.shape
    rng = np.random.default_rng(seed)
    spacing = h * 0.75 / max(lines - 1, 1)
    jitter = rng.uniform(-0.3, 0.3, lines) * spacing  # small enough that rows stay distinct
    rows = np.clip(np.linspace(h * 0.15, h * 0.9, lines) + jitter, 0, h - 1)
    out = np.zeros_like(gt)
    for r in rows.astype(int):
        out[r, ::2] = gt[r, ::2]
    return out


def sceneflow_arrays(root: Path, lines: int = 16):
    lefts = sorted((root / "frames_cleanpass").rglob("left/*.png"))
    if not lefts:
        raise ConfigError("data", "sceneflow:DIR with DIR/frames_cleanpass/.../left/*.png",
                          str(root))
    for i, left_path in enumerate(lefts):
        rel = left_path.relative_to(root / "frames_cleanpass")
        right_path = left_path.parent.parent / "right" / left_path.name
        disp_l = root / "disparity" / rel.with_suffix(".pfm")
        disp_r = root / "disparity" / rel.parent.parent / "right" / rel.with_suffix(
            ".pfm").name
        gt = read_pfm(disp_l) if disp_l.exists() else None
        gt_r = read_pfm(disp_r) if disp_r.exists() else None
        sparse = lidar_like_sample(gt, lines, i) if gt is not None else None
        sparse_r = lidar_like_sample(gt_r, lines, i) if gt_r is not None else None
        yield _arrays(read_grey(left_path), read_grey(right_path), gt, gt_r, sparse, sparse_r)


# -- choosing ------------------------------------------------------------------------------
def open_training_data(spec: str):
    """A function returning a fresh iterator of arrays dicts (one pass over the data)."""
    if spec.startswith("kitti:"):
        root = Path(spec[6:])
        return lambda: kitti_arrays(root)
    if spec.startswith("sceneflow:"):
        root = Path(spec[10:])
        return lambda: sceneflow_arrays(root)
    path = Path(spec)
    if path.suffix == ".mcap":
        if not path.is_file():
            raise ConfigError("data", "an existing .mcap recording", spec)
        return lambda: mcap_arrays(path)
    folders = list_scene_folders(path)
    if not folders:
        raise ConfigError("data", "scene folders, a .mcap file, kitti:DIR or sceneflow:DIR",
                          spec)
    return lambda: (scene_folder_arrays(f) for f in folders)
