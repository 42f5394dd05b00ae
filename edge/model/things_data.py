"""Training stream from the things world (`edge.sim.things_store` files), with RAFT-Stereo's
augmentations: spatial scale and horizontal stretch, a left-right flip (views swapped),
asymmetric photometric changes per camera, the occlusion "eraser" on the right view, random
crops; and the LiDAR sampled from the GT per sample (`edge.sim.gt_lidar`, none to 64 rows).

A share of the stream (`rig_share`) comes from the original synthetic rig, so the network
keeps what it knows there. The folder is listed again every `relist_every` samples: a render
job can keep adding files while training runs.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from edge_depth.model.data import TRAIN_SEED_LIMIT, sample_to_arrays, to_tensors
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.gt_lidar import GtLidarPattern
from edge_depth.sim.things_store import list_things, read_things


def spatial(arrays: dict, rng: np.random.Generator, crop: tuple[int, int]) -> dict:
    """Scale by 2^U(-0.2, 0.4), stretch x by 2^U(-0.2, 0.2) (p 0.8), keep at least the crop;
    disparities scale with x; nearest-neighbour for GT so edges stay exact."""
    h, w = arrays["left"].shape
    if rng.random() < 0.8:
        scale = 2 ** rng.uniform(-0.2, 0.4)
        sx = scale * 2 ** rng.uniform(-0.2, 0.2)
        sy = scale
        sx, sy = max(sx, (crop[0] + 8) / w), max(sy, (crop[1] + 8) / h)
        size = (int(round(w * sx)), int(round(h * sy)))
        sx = size[0] / w
        for key in ("left", "right"):
            arrays[key] = cv2.resize(arrays[key], size, interpolation=cv2.INTER_LINEAR)
        for key in ("disp_left", "disp_right"):
            arrays[key] = cv2.resize(arrays[key], size, interpolation=cv2.INTER_NEAREST) * sx
    if rng.random() < 0.5:  # mirror the world: the right view becomes the left
        flip = lambda a: np.ascontiguousarray(a[:, ::-1])  # noqa: E731
        arrays["left"], arrays["right"] = flip(arrays["right"]), flip(arrays["left"])
        arrays["disp_left"], arrays["disp_right"] = (flip(arrays["disp_right"]),
                                                     flip(arrays["disp_left"]))
    return arrays


# RAFT-Stereo's asymmetric share: each camera draws its own photometric change this often, so
# 1 - 0.8^2 = 36 % of the pairs trained on differ far more than the world's two cameras do
ASYMMETRIC_SHARE = 0.2


def photometric(left: torch.Tensor, right: torch.Tensor, rng: np.random.Generator,
                own_share: float = ASYMMETRIC_SHARE) -> tuple[torch.Tensor, torch.Tensor]:
    """Brightness, contrast and gamma; `own_share` of the time each camera draws its own."""
    def params():
        return (float(rng.uniform(-25, 25)), float(rng.uniform(0.6, 1.4)),
                float(rng.uniform(0.8, 1.2)))

    shared = params()
    out = []
    for image in (left, right):
        brightness, contrast, gamma = params() if rng.random() < own_share else shared
        image = 255.0 * (image / 255.0).clamp(0, 1) ** gamma
        mean = image.mean()
        out.append(((image - mean) * contrast + mean + brightness).clamp(0, 255))
    return out[0], out[1]


def eraser(right: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """RAFT-Stereo's occlusion augmentation: 1-2 rectangles of the right view (50-100 px)
    filled with its mean grey, half of the time."""
    if rng.random() >= 0.5:
        return right
    right = right.clone()
    _, h, w = right.shape
    for _ in range(int(rng.integers(1, 3))):
        dx, dy = int(rng.integers(50, 101)), int(rng.integers(50, 101))
        x0, y0 = int(rng.integers(0, max(w - dx, 1))), int(rng.integers(0, max(h - dy, 1)))
        right[:, y0:y0 + dy, x0:x0 + dx] = right.mean()
    return right


def things_arrays(arrays: dict, rng: np.random.Generator, crop: tuple[int, int],
                  stereo_only_share: float | None = None) -> dict:
    """A stored things sample → the training dict of `edge.model.data.sample_to_arrays`;
    stereo_only_share: the probability of no LiDAR (default: `GtLidarPattern.random`'s)."""
    arrays = spatial(dict(arrays), rng, crop)
    h, _ = arrays["left"].shape
    pattern = GtLidarPattern.random(h, rng, stereo_only_share)
    sparse = {}
    for side in ("left", "right"):
        gt = arrays[f"disp_{side}"]
        sparse[side] = pattern.sample(gt, rng) if pattern is not None \
            else np.zeros(gt.shape, np.float32)
    return dict(left=arrays["left"], right=arrays["right"], gt=arrays["disp_left"],
                gt_right=arrays["disp_right"], sparse=sparse["left"],
                valid=sparse["left"] > 0, sparse_right=sparse["right"],
                valid_right=sparse["right"] > 0)


class ThingsTrainSet(IterableDataset):
    """Endless augmented stream from a folder of things samples (plus `rig_share` rig
    samples, seeds < 1 000 000). `rig_stereo_only_share`: how many of the rig samples come
    without their LiDAR (default none: the rig then trains with LiDAR only, and its
    stereo-only accuracy drifts as the trunk learns the things world; docs/experiments.md)."""

    def __init__(self, root, crop: tuple[int, int] = (320, 192), seed: int = 0,
                 rig_share: float = 0.15, relist_every: int = 200, shard: int = 0,
                 shards: int = 1, stereo_only_share: float | None = None,
                 asymmetric_share: float = ASYMMETRIC_SHARE,
                 rig_stereo_only_share: float = 0.0) -> None:
        self.root, self.crop, self.seed, self.rig_share = root, crop, seed, rig_share
        self.rig_stereo_only_share = rig_stereo_only_share
        self.stereo_only_share, self.asymmetric_share = stereo_only_share, asymmetric_share
        self.relist_every, self.shard, self.shards = relist_every, shard, shards
        if not list_things(root):
            raise ValueError(f"{root}: no things samples (NNNNNNN.npz) in this folder")

    def __iter__(self):
        info = get_worker_info()
        workers, worker = (info.num_workers, info.id) if info else (1, 0)
        part, parts = self.shard * workers + worker, self.shards * workers
        rng = np.random.default_rng([self.seed, part])
        files: list = []
        rig = RigConfig()
        for i in range(10 ** 12):
            if i % self.relist_every == 0:
                files = list_things(self.root)[part::parts] or list_things(self.root)
            if rng.random() < self.rig_share:
                sample = make_sample(int(rng.integers(0, TRAIN_SEED_LIMIT)), rig, "beams16")
                arrays = sample_to_arrays(sample)
                # drawn only when asked, so the streams of runs without it stay as they were
                if self.rig_stereo_only_share and rng.random() < self.rig_stereo_only_share:
                    for key in ("sparse", "valid", "sparse_right", "valid_right"):
                        arrays[key] = np.zeros_like(arrays[key])
            else:
                arrays = things_arrays(read_things(files[int(rng.integers(len(files)))]), rng,
                                       self.crop, self.stereo_only_share)
            # the rig's crop (same draws); the photometric changes below replace its own
            out = to_tensors(arrays, self.crop, rng, augment=False)
            out["left"], out["right"] = photometric(out["left"], out["right"], rng,
                                                    self.asymmetric_share)
            out["right"] = eraser(out["right"], rng)
            yield out
