"""The full-resolution matching's parts, each timed alone on rig test frames after the
engine's own inference: StereoBM at the frame's "auto" count (every 2nd row), the choice's
pair-only terms and, of them, the LiDAR's nearest-point map (and, for comparison, the same
distance transform on a half-resolution mask, which would pick other points at depth edges)
and one 5×5 warp cost, and the gate. Median ms of 20 calls.

    python experiments/matching_parts.py [--frames 2]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from edge_depth.baselines import lidar_nearest
from edge_depth.runtime.cells import local_range, warped_cost
from edge_depth.runtime.edge_match import disparities_for
from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample


def median_ms(fn, calls: int = 20) -> float:
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000)
    return float(np.median(times))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=2)
    args = p.parse_args()
    engine = Engine(threads=2)
    print(engine.describe())
    for seed in range(args.frames):
        parts = time_parts(engine, seed)
        print(f"frame {seed}: " + ", ".join(f"{k} {v:.1f}" for k, v in parts.items()))


def time_parts(engine: Engine, seed: int) -> dict[str, float]:
    match = engine.edge_match
    assert match is not None, "the shipped bundle's matching"
    sample = make_sample(1_000_000 + seed, RigConfig(), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    sparse = (sparse * valid).astype(np.float32)
    result = engine.infer(sample.left, sample.right, sparse)
    assert result.confidence is not None
    left, right, confidence = sample.left, sample.right, result.confidence
    count = disparities_for(result.disparity, result.disparity.shape[1])
    grey = [np.asarray(im, np.float32) for im in (left, right)]
    point = lidar_nearest(sparse, sparse > 0)
    half = cv2.resize((sparse > 0).astype(np.uint8), None, fx=0.5, fy=0.5,
                      interpolation=cv2.INTER_AREA) == 0
    parts = {
        f"StereoBM ({count})": lambda: match.matched(left, right, count),
        "pair-only terms": lambda: match.pair_terms(left, right, sparse),
        "of them the nearest point": lambda: lidar_nearest(sparse, sparse > 0),
        "its transform at half resolution": lambda: cv2.distanceTransformWithLabels(
            half.astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL),
        "a 5x5 warp cost": lambda: warped_cost(*grey, point, (5,)),
        "gate": lambda: (confidence < match.max_confidence)
        & (local_range(result.disparity, match.window_px) > match.min_range_px),
    }
    return {k: median_ms(fn) for k, fn in parts.items()}

if __name__ == "__main__":
    main()
