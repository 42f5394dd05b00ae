"""Training data: the synthetic rig generated on the fly, and scene folders.

Splits of the rig, by seed: training seeds are below 1 000 000; the fixed test split is seeds
1 000 000 + i, the validation split 2 000 000 + i. Nothing trains on the test or validation
seeds (`SyntheticTrainSet` refuses them).
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from edge_depth.sim import RigConfig, make_sample

TEST_SEED0 = 1_000_000
VAL_SEED0 = 2_000_000
TRAIN_SEED_LIMIT = 1_000_000


def sample_to_arrays(sample) -> dict[str, np.ndarray]:
    """Left/right images, GT disparities and filtered sparse LiDAR of both views, as arrays."""
    sparse_l, valid_l = sample.sparse_disparity("left")
    sparse_r, valid_r = sample.sparse_disparity("right")
    return dict(left=sample.left, right=sample.right, gt=sample.disp_left,
                gt_right=sample.disp_right, sparse=sparse_l, valid=valid_l,
                sparse_right=sparse_r, valid_right=valid_r)


def to_tensors(arrays: dict[str, np.ndarray], crop: tuple[int, int] | None,
               rng: np.random.Generator, augment: bool) -> dict[str, torch.Tensor]:
    """Random crop (width, height), contrast/brightness augmentation, (1, H, W) float32."""
    h, w = arrays["left"].shape
    y0 = x0 = 0
    ch, cw = h, w
    if crop is not None:
        cw, ch = crop
        y0 = int(rng.integers(0, h - ch + 1))
        x0 = int(rng.integers(0, w - cw + 1))
    out = {}
    for key, value in arrays.items():
        out[key] = torch.from_numpy(
            np.ascontiguousarray(value[y0:y0 + ch, x0:x0 + cw]).astype(np.float32))[None]
    if augment:
        # grey images: the paper's saturation augmentation (0-1.4) becomes a contrast
        # scaling about the mean in the same range, independently per camera
        for key in ("left", "right"):
            image = out[key]
            factor = float(rng.uniform(0.6, 1.4))
            mean = image.mean()
            out[key] = ((image - mean) * factor + mean + float(rng.uniform(-10, 10))).clamp(0, 255)
    return out


class SyntheticTrainSet(IterableDataset):
    """Endless stream of rendered training samples (seeds < 1 000 000, per-worker streams)."""

    def __init__(self, seed: int = 0, crop: tuple[int, int] = (320, 192),
                 rig: RigConfig | None = None, patterns: tuple[str, ...] = ("beams16",),
                 augment: bool = True) -> None:
        self.seed, self.crop, self.rig = seed, crop, rig or RigConfig()
        self.patterns, self.augment = patterns, augment

    def __iter__(self):
        info = get_worker_info()
        worker = info.id if info else 0
        rng = np.random.default_rng([self.seed, worker])
        while True:
            scene_seed = int(rng.integers(0, TRAIN_SEED_LIMIT))
            pattern = self.patterns[int(rng.integers(len(self.patterns)))]
            sample = make_sample(scene_seed, self.rig, pattern)
            yield to_tensors(sample_to_arrays(sample), self.crop, rng, self.augment)


class FixedSplit(Dataset):
    """A fixed, seeded split (test or validation) rendered on demand, uncropped."""

    def __init__(self, first_seed: int, count: int, pattern: str = "beams16",
                 rig: RigConfig | None = None) -> None:
        self.first_seed, self.count, self.pattern = first_seed, count, pattern
        self.rig = rig or RigConfig()

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        sample = make_sample(self.first_seed + i, self.rig, self.pattern)
        return to_tensors(sample_to_arrays(sample), None, np.random.default_rng(0), False)


class RecordedTrainSet(IterableDataset):
    """Endless stream from recorded data (`edge.model.datasets.open_training_data` spec):
    passes over the data again and again, shuffled through a buffer, cropped and augmented
    like the rig. `shard` / `shards` split it between workers and DDP ranks."""

    def __init__(self, spec: str, crop: tuple[int, int] | None = (320, 192), seed: int = 0,
                 augment: bool = True, buffer: int = 16, shard: int = 0, shards: int = 1
                 ) -> None:
        from edge_depth.model.datasets import open_training_data

        self.spec, self.crop, self.seed, self.augment = spec, crop, seed, augment
        self.buffer, self.shard, self.shards = buffer, shard, shards
        self.passes = open_training_data(spec)

    def __iter__(self):
        info = get_worker_info()
        workers, worker = (info.num_workers, info.id) if info else (1, 0)
        parts, part = self.shards * workers, self.shard * workers + worker
        rng = np.random.default_rng([self.seed, part])
        pool: list[dict] = []
        while True:
            seen = 0
            for i, arrays in enumerate(self.passes()):
                if i % parts != part:
                    continue
                seen += 1
                h, w = arrays["left"].shape
                if self.crop is not None and (w < self.crop[0] or h < self.crop[1]):
                    raise ValueError(f"{self.spec}: a {w}x{h} frame is smaller than the crop "
                                     f"{self.crop[0]}x{self.crop[1]}")
                pool.append(arrays)
                if len(pool) >= self.buffer:
                    yield to_tensors(pool.pop(int(rng.integers(len(pool)))), self.crop, rng,
                                     self.augment)
            if seen == 0:
                raise ValueError(f"{self.spec}: no frames for shard {part} of {parts}")
            while pool:
                yield to_tensors(pool.pop(int(rng.integers(len(pool)))), self.crop, rng,
                                 self.augment)
