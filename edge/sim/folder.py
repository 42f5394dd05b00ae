"""The scene folder format: one folder per stereo pair, read by evaluation and training.

    left.png, right.png   rectified grey images (8-bit)
    disp.pfm              float32 left GT disparity in pixels, inf where unknown
    occ.png               255 where a left pixel is not visible in the right image
    lidar.npy             (N, 3) float32 LiDAR points in the LiDAR frame, metres
    sparse.pfm            LiDAR projected into the left image as disparity, 0 = no point
                          (occlusion-filtered, calibration.projection.project_to_disparity)
    meta.json             focal_px, baseline_m, cx, cy, T_cam_lidar (4x4), seed, lidar pattern

Only left.png and right.png are required when reading; the rest is optional.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edge_depth.errors import EdgeError


class SceneFolderError(EdgeError):
    """A scene folder or one of its files is missing or malformed."""

    def __init__(self, path: Path | str, reason: str) -> None:
        self.path = str(path)
        super().__init__(f"{path}: {reason}")


def write_pfm(path: Path | str, image: np.ndarray) -> None:
    """Write an (H, W) float32 map as a greyscale PFM (OpenCV's writer: little-endian, rows
    bottom to top; inf and NaN kept)."""
    image = np.asarray(image, np.float32)
    if image.ndim != 2:
        raise ValueError(f"write_pfm: expected (H, W), got {image.shape}")
    if Path(path).suffix.lower() != ".pfm":
        raise ValueError(f"write_pfm: the file name must end in .pfm, got {path}")
    if not cv2.imwrite(str(path), image):
        raise SceneFolderError(path, "could not write the PFM file")


def read_pfm(path: Path | str) -> np.ndarray:
    """Read a greyscale or colour PFM (OpenCV's reader: either byte order); returns (H, W)
    float32 (the first channel for colour)."""
    with open(path, "rb") as f:
        magic = f.read(2)
    if magic not in (b"Pf", b"PF"):
        raise SceneFolderError(path, "not a PFM file (bad header)")
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # our error says it
    try:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise SceneFolderError(path, "truncated or malformed PFM data")
    if image.ndim == 3:  # OpenCV's channel order is BGR: the file's first channel is last
        image = image[..., 2]
    return np.ascontiguousarray(image, np.float32)


@dataclass(frozen=True)
class SceneFolder:
    """The contents of one scene folder; optional parts are None when absent."""

    path: Path
    left: np.ndarray
    right: np.ndarray
    disp: np.ndarray | None
    occ: np.ndarray | None
    sparse: np.ndarray | None
    lidar: np.ndarray | None
    meta: dict


def read_grey(path: Path | str) -> np.ndarray:
    """An 8-bit grey (H, W) image (colour files converted); SceneFolderError if unreadable."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise SceneFolderError(path, "missing or unreadable image")
    return image


def read_scene_folder(path: Path | str) -> SceneFolder:
    """Load a scene folder (see the module docstring for the files)."""
    path = Path(path)
    if not path.is_dir():
        raise SceneFolderError(path, "not a directory")
    left, right = read_grey(path / "left.png"), read_grey(path / "right.png")
    if left.shape != right.shape:
        raise SceneFolderError(path, f"left {left.shape} and right {right.shape} differ in size")
    disp = read_pfm(path / "disp.pfm") if (path / "disp.pfm").exists() else None
    sparse = read_pfm(path / "sparse.pfm") if (path / "sparse.pfm").exists() else None
    occ = read_grey(path / "occ.png") > 127 if (path / "occ.png").exists() else None
    lidar = np.load(path / "lidar.npy") if (path / "lidar.npy").exists() else None
    meta = json.loads((path / "meta.json").read_text()) if (path / "meta.json").exists() else {}
    for name, arr in (("disp.pfm", disp), ("sparse.pfm", sparse), ("occ.png", occ)):
        if arr is not None and arr.shape != left.shape:
            raise SceneFolderError(path / name, f"shape {arr.shape}, expected {left.shape}")
    return SceneFolder(path, left, right, disp, occ, sparse, lidar, meta)


def list_scene_folders(root: Path | str) -> list[Path]:
    """Sorted sub-folders of `root` that hold a left.png (or root itself if it is one)."""
    root = Path(root)
    if (root / "left.png").exists():
        return [root]
    return sorted(p.parent for p in root.glob("*/left.png"))


def write_scene_folder(path: Path | str, sample, sparse: np.ndarray | None = None,
                       lidar_name: str = "") -> None:
    """Write a `SyntheticSample` as a scene folder, atomically (temp folder, then rename)."""
    path = Path(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        cv2.imwrite(str(tmp / "left.png"), sample.left)
        cv2.imwrite(str(tmp / "right.png"), sample.right)
        write_pfm(tmp / "disp.pfm", sample.disp_left)
        cv2.imwrite(str(tmp / "occ.png"), sample.occ_left.astype(np.uint8) * 255)
        np.save(tmp / "lidar.npy", sample.scan.points)
        if sparse is None:
            sparse, _ = sample.sparse_disparity("left")
        write_pfm(tmp / "sparse.pfm", sparse)
        rig = sample.rig
        meta = dict(focal_px=rig.focal_px, baseline_m=rig.baseline_m, cx=rig.cx, cy=rig.cy,
                    width=rig.width, height=rig.height, T_cam_lidar=sample.T_cam_lidar.tolist(),
                    seed=sample.seed, lidar=lidar_name, generator="edge.sim")
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
