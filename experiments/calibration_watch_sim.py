"""The shipped calibration watch (`edge.calibration_watch`) on the sim robot with known injected
rotation errors (docs/experiments.md, 2026-12-06 01:00).

    python experiments/calibration_watch_sim.py [--frames 100] [--seed 1000000] [--every 10]

Frames i = 0, every, 2·every, … of the sim robot (each a new scene, 16-beam LiDAR, 640×400)
are the watch's samples, as the daemon takes one in `every` frames with LiDAR; each case runs
the same frames with the calibration's rotation off by the injected angles, and prints the
estimate after the last frame, the level after each sample, and the watch's ms a sample.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import edge_depth.calibration_watch as watch_module
from edge_depth.calibration.extrinsics import _perturb
from edge_depth.calibration_watch import CalibrationWatch, stereo_reference

CASES = (("right calibration", (0, 0, 0)), ("yaw +0.3", (0, 0.3, 0)), ("yaw -0.3", (0, -0.3, 0)),
         ("pitch +0.3", (0.3, 0, 0)), ("pitch -0.3", (-0.3, 0, 0)), ("roll +0.5", (0, 0, 0.5)))


def main() -> None:
    from edge_depth.runtime.engine import Engine
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.sim.lidar import default_T_cam_lidar

    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--seed", type=int, default=1_000_000)
    p.add_argument("--every", type=int, default=10)
    p.add_argument("--points", type=int, default=watch_module.MAX_POINTS)
    p.add_argument("--step", type=float, default=watch_module.GRID_STEP_DEG)
    p.add_argument("--iters", type=int, default=watch_module.REFERENCE_ITERS)
    p.add_argument("--cases", default="all", help="comma-separated case names, or all")
    args = p.parse_args()
    watch_module.MAX_POINTS, watch_module.GRID_STEP_DEG = args.points, args.step
    watch_module.REFERENCE_ITERS = args.iters
    engine = Engine()
    rig = RigConfig()
    samples, references, reference_ms = [], [], []
    for i in range(0, args.frames, args.every):
        s = make_sample(args.seed + i, rig, "beams16")
        from edge_depth.calibration.projection import project_to_disparity

        sparse, _ = project_to_disparity(s.scan.points, s.calibration(), default_T_cam_lidar())
        engine.infer(s.left, s.right, sparse)  # the frame the daemon runs; then the watch's
        t = time.perf_counter()
        references.append(stereo_reference(engine))
        reference_ms.append((time.perf_counter() - t) * 1000)
        samples.append(s)
    calib, T = samples[0].calibration(), default_T_cam_lidar()
    print(f"{len(samples)} samples of {args.frames} frames from seed {args.seed}; the "
          f"stereo-only reference {np.median(reference_ms):.1f} ms a sample (median)")
    chosen = None if args.cases == "all" else set(args.cases.split(","))
    for name, x in CASES:
        if chosen is not None and name not in chosen:
            continue
        watch = CalibrationWatch(calib, _perturb(T, np.r_[x, 0.0, 0.0, 0.0]), every=1)
        levels, add_ms = [], []
        for s, reference in zip(samples, references, strict=True):
            t = time.perf_counter()
            watch.add(reference, s.scan.points)
            add_ms.append((time.perf_counter() - t) * 1000)
            levels.append(watch.estimate().level[0])
        print(f"{name}: {watch.estimate().describe()}; levels {''.join(levels)}; "
              f"{np.median(add_ms):.1f} ms a sample besides the reference", flush=True)


if __name__ == "__main__":
    main()
