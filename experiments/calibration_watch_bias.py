"""Where the calibration watch's pitch goes wrong on a scene (docs/experiments.md,
2026-12-07 "the calibration watch on scenes it was not tuned on").

    python experiments/calibration_watch_bias.py --seeds 6300000,6301000 [--cache DIR]
        [--reference engine|truth] [--per-sample] [--set NAME=VALUE ...]

Each seed's samples (frames seed + 0, every, 2·every, … < frames, as
`experiments/calibration_watch_sim.py` takes them) are rendered once, with the engine's
stereo-only reference, the true disparity and the LiDAR points, and kept in `--cache`; then
the watch runs on them for the five 0.3° cases (the right calibration, yaw ±0.3, pitch ±0.3)
with either reference. `--per-sample` prints each sample's own (pitch, yaw) minimum with the
right calibration: which scenes pull the estimate. `--set` overrides a module constant of
`edge.calibration_watch` (an ablation).
"""

from __future__ import annotations

import argparse
import functools
import os

import numpy as np

import edge_depth.calibration_watch as watch_module
from edge_depth.calibration.extrinsics import _perturb
from edge_depth.calibration_verdict import WatchEstimate
from edge_depth.calibration_watch import CalibrationWatch

CASES = (("right", (0, 0, 0)), ("yaw+", (0, 0.3, 0)), ("yaw-", (0, -0.3, 0)),
         ("pitch+", (0.3, 0, 0)), ("pitch-", (-0.3, 0, 0)))


def seed_samples(seed: int, frames: int, every: int, cache: str) -> dict:
    """The seed's samples: references (S, H, W), truths (S, H, W), points (list of (N, 3))."""
    path = os.path.join(cache, f"watch_{seed}_{frames}_{every}.npz")
    if os.path.exists(path):
        data = np.load(path, allow_pickle=True)
        return dict(reference=data["reference"], truth=data["truth"],
                    points=list(data["points"]), seeds=data["seeds"])
    from edge_depth.calibration.projection import project_to_disparity
    from edge_depth.calibration_watch import stereo_reference
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.sim.lidar import default_T_cam_lidar

    engine, rig = _engine(), RigConfig()
    reference, truth, points, seeds = [], [], [], []
    for i in range(0, frames, every):
        s = make_sample(seed + i, rig, "beams16")
        sparse, _ = project_to_disparity(s.scan.points, s.calibration(), default_T_cam_lidar())
        engine.infer(s.left, s.right, sparse)
        reference.append(stereo_reference(engine))
        truth.append(np.nan_to_num(s.disp_left).astype(np.float32))
        points.append(np.asarray(s.scan.points, np.float64))
        seeds.append(seed + i)
    os.makedirs(cache, exist_ok=True)
    holder = np.empty(len(points), object)
    holder[:] = points
    np.savez(path, reference=np.stack(reference), truth=np.stack(truth), points=holder,
             seeds=np.array(seeds))
    return dict(reference=np.stack(reference), truth=np.stack(truth), points=points,
                seeds=np.array(seeds))


@functools.cache
def _engine():
    """One engine for every seed this run renders (its start is the slow part)."""
    from edge_depth.runtime.engine import Engine

    return Engine()


def run_cases(data: dict, reference: str) -> list[tuple[str, WatchEstimate]]:
    """The watch's estimate after the seed's samples, for each of CASES, on `reference`
    ("reference": the engine's, "truth": the true disparity)."""
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.sim.lidar import default_T_cam_lidar

    calib = make_sample(int(data["seeds"][0]), RigConfig(), "beams16").calibration() \
        if "calib" not in data else data["calib"]
    data["calib"] = calib
    out = []
    for name, x in CASES:
        watch = CalibrationWatch(calib, _perturb(default_T_cam_lidar(), np.r_[x, 0, 0, 0]), 1)
        for disparity, points in zip(data[reference], data["points"], strict=True):
            watch.add(disparity, points)
        out.append((name, watch.estimate()))
    return out


def per_sample(data: dict, reference: str) -> None:
    """Each sample's own lowest (pitch, yaw) probe with the right calibration (the negative of
    the error it reads)."""
    from edge_depth.sim.lidar import default_T_cam_lidar

    watch = CalibrationWatch(data["calib"], default_T_cam_lidar(), 1)
    for seed, disparity, points in zip(data["seeds"], data[reference], data["points"],
                                       strict=True):
        cam = watch._seen_points(points)
        grid = watch._costs(watch._jacobian(cam), disparity, watch._grid)
        grid = grid.reshape(len(watch.pitch_axis), -1)
        (pitch, yaw), _ = watch._grid_minimum(grid)
        depth = np.median(cam[:, 2])
        print(f"    sample {seed}: pitch {pitch:+.2f} yaw {yaw:+.2f} ({len(cam)} points, "
              f"median depth {depth:.1f} m, cost at 0: {grid[len(grid) // 2].min():.3f})")


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--seeds", required=True, help="comma-separated")
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--every", type=int, default=13)
    p.add_argument("--cache", default="/tmp/watch_cache")
    p.add_argument("--reference", default="engine", choices=("engine", "truth"))
    p.add_argument("--per-sample", action="store_true")
    p.add_argument("--set", action="append", default=[], help="NAME=VALUE (a float)")
    args = p.parse_args(argv)
    for item in args.set:
        name, value = item.split("=")
        setattr(watch_module, name, type(getattr(watch_module, name))(float(value)))
    data_key = "reference" if args.reference == "engine" else "truth"
    flagged = within = false = seeds = 0
    for seed in (int(s) for s in args.seeds.split(",")):
        data = seed_samples(seed, args.frames, args.every, args.cache)
        results = run_cases(data, data_key)
        f, w, x = score(results)
        flagged, within, false, seeds = flagged + f, within + w, false + x, seeds + 1
        cells = [f"{name} p{e.error_deg[0]:+.2f}±{e.sigma_deg[0]:.2f} "
                 f"y{e.error_deg[1]:+.2f}±{e.sigma_deg[1]:.2f} {e.level}"
                 for name, e in results]
        print(f"{seed}: " + " | ".join(cells), flush=True)
        if args.per_sample:
            per_sample(data, data_key)
    print(f"{seeds} seeds: {flagged} of {4 * seeds} injected errors WARN or ERROR, {within} of "
          f"{4 * seeds} within ±30 %, {false} right calibrations WARN or ERROR")
    return 0


def score(results: list[tuple[str, WatchEstimate]]) -> tuple[int, int, int]:
    """(injected errors flagged, their estimates within ±30 %, right calibrations flagged)."""
    flagged = within = false = 0
    for (_, injected), (_, e) in zip(CASES, results, strict=True):
        alarm = e.level in ("WARN", "ERROR")
        if not any(injected):
            false += alarm
            continue
        axis = int(np.argmax(np.abs(injected)))
        flagged += alarm
        within += abs(e.error_deg[axis] - injected[axis]) <= 0.3 * abs(injected[axis])
    return flagged, within, false


if __name__ == "__main__":
    raise SystemExit(main())
