"""Benchmark the stages that exist so far, at one input size, in one run.

    python tools/bench.py [--size 640x400] [--repeat 30] [--json OUT]

Stages: rectification (two remaps with maps computed once), LiDAR projection + occlusion
filter (64-beam scan, ~30k points before clipping to the image), and OpenCV SGBM (3-way, 64
disparities, grey) as the baseline the engine will be compared against. Methods alternate in
blocks with an untimed first call; medians and p95 in milliseconds. The engine (fp32/int8,
1/2/4/8 iterations) joins when the deployment issue lands.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibration.model import StereoCalibration  # noqa: E402
from calibration.projection import project_to_disparity  # noqa: E402
from edge.baselines import make_sgbm, sgbm_disparity  # noqa: E402
from edge.sim import RigConfig, make_sample  # noqa: E402


def _time(fn, repeat: int) -> list[float]:
    fn()  # untimed: thread pools and caches warm up
    out = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        out.append((time.perf_counter() - start) * 1000)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", default="640x400")
    p.add_argument("--repeat", type=int, default=30)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    rig = RigConfig(width=w, height=h, focal_px=450.0 * w / 640)
    sample = make_sample(1_000_000, rig, "beams64")
    K = np.array([[rig.focal_px, 0, rig.cx], [0, rig.focal_px, rig.cy], [0, 0, 1]])
    distorted = StereoCalibration(K, [-0.08, 0.02, 0, 0, 0], K, [-0.07, 0.015, 0, 0, 0],
                                  np.eye(3), [-rig.baseline_m, 0, 0], (w, h))
    rectifier = distorted.rectifier()
    ideal = sample.calibration()
    matcher = make_sgbm()
    stages = {
        "rectify": lambda: rectifier.rectify(sample.left, sample.right),
        "project_filter": lambda: project_to_disparity(sample.scan.points, ideal,
                                                       sample.T_cam_lidar),
        "sgbm": lambda: sgbm_disparity(sample.left, sample.right, matcher),
    }
    times: dict[str, list[float]] = {k: [] for k in stages}
    blocks = 3
    for _ in range(blocks):
        for name, fn in stages.items():
            times[name] += _time(fn, max(1, args.repeat // blocks))
    result = {name: dict(median_ms=float(np.median(t)), p95_ms=float(np.percentile(t, 95)),
                         runs=len(t)) for name, t in times.items()}
    result["points"] = len(sample.scan)
    result["sgbm_ms"] = result["sgbm"]["median_ms"]
    result["size"] = [w, h]
    print(f"| stage ({w}x{h}) | median ms | p95 ms |")
    print("|---|---|---|")
    for name in stages:
        print(f"| {name} | {result[name]['median_ms']:.2f} | {result[name]['p95_ms']:.2f} |")
    print(f"({result['points']} LiDAR points per scan)")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
