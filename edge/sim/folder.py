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
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edge.errors import EdgeError


class SceneFolderError(EdgeError):
    """A scene folder or one of its files is missing or malformed."""

    def __init__(self, path: Path | str, reason: str) -> None:
        self.path = str(path)
        super().__init__(f"{path}: {reason}")


def write_pfm(path: Path | str, image: np.ndarray) -> None:
    """Write an (H, W) float32 map as a little-endian greyscale PFM (rows bottom to top)."""
    image = np.asarray(image, np.float32)
    if image.ndim != 2:
        raise ValueError(f"write_pfm: expected (H, W), got {image.shape}")
    h, w = image.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{w} {h}\n-1.0\n".encode("ascii"))
        f.write(np.ascontiguousarray(np.flipud(image)).astype("<f4").tobytes())


def read_pfm(path: Path | str) -> np.ndarray:
    """Read a greyscale or colour PFM; returns (H, W) float32 (first channel for colour)."""
    with open(path, "rb") as f:
        data = f.read()
    match = re.match(rb"(P[fF])\s+(\d+)\s+(\d+)\s+(-?[\d.eE+-]+)\s", data)
    if not match:
        raise SceneFolderError(path, "not a PFM file (bad header)")
    channels = 1 if match.group(1) == b"Pf" else 3
    w, h, scale = int(match.group(2)), int(match.group(3)), float(match.group(4))
    count = w * h * channels
    body = data[match.end():]
    if len(body) < 4 * count:
        raise SceneFolderError(path, f"truncated PFM: {len(body)} of {4 * count} bytes")
    image = np.frombuffer(body[: 4 * count], "<f4" if scale < 0 else ">f4")
    image = image.reshape(h, w, channels)[..., 0]
    return np.flipud(image).astype(np.float32)


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
