"""What the variant scripts share: a scene folder copied under a new name with its LiDAR map
replaced (`experiments/lidar_noise.py`, `experiments/lidar_misregistration.py`)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from edge_depth.sim.folder import write_pfm


def write_lidar_variants(folder: Path, variants: dict[str, np.ndarray], out: Path) -> None:
    """OUT/<folder's name>_<key> for each map in `variants`: the folder, its sparse.pfm
    replaced by the map; says each folder written."""
    for key, sparse in variants.items():
        dst = out / f"{folder.name}_{key}"
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(folder, dst)
        write_pfm(dst / "sparse.pfm", sparse.astype(np.float32))
        print(dst)
