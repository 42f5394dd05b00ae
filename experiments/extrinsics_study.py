"""How well `calibrate lidar --refine` recovers a known LiDAR-camera error on the synthetic rig.

    python experiments/extrinsics_study.py [--sets 3] [--frames 6,12] [--errors 1:0.02,2:0.05]
        [--trials 3] [--lidar beams64] [--json out/extrinsics.json]

For each set of scenes (seeds 1 000 000 k + i, the rig at 640x400), each frame count, each
error (degrees:metres) and each trial, the true T_cam_lidar is moved by that rotation about a
random axis and that translation in a random direction, refined with `refine_extrinsics` on
the first N frames of the set, and the remaining rotation (degrees) and translation (mm) are
printed, then the worst and median per (frames, error).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    from edge_depth.calibration.extrinsics import (
        perturbed,
        pose_difference,
        refine_extrinsics,
    )
    from edge_depth.sim import make_sample

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", type=int, default=3)
    p.add_argument("--frames", default="6,12")
    p.add_argument("--errors", default="1:0.02,2:0.05", help="degrees:metres, comma separated")
    p.add_argument("--trials", type=int, default=3)
    p.add_argument("--lidar", default="beams64")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    counts = [int(n) for n in args.frames.split(",")]
    errors = [tuple(float(x) for x in e.split(":")) for e in args.errors.split(",")]

    rows = []
    for k in range(1, args.sets + 1):
        samples = [make_sample(1_000_000 * k + i, lidar=args.lidar) for i in range(max(counts))]
        frames = [(s.left, s.right, s.scan.points) for s in samples]
        calib, T = samples[0].calibration(), samples[0].T_cam_lidar
        for n in counts:
            for degrees, metres in errors:
                for trial in range(args.trials):
                    start = time.perf_counter()
                    refined, _ = refine_extrinsics(frames[:n], calib,
                                                   perturbed(T, degrees, metres, trial))
                    angle, shift = pose_difference(refined, T)
                    row = dict(set=k, frames=n, error_deg=degrees, error_m=metres, trial=trial,
                               rot_deg=angle, trans_mm=shift * 1000,
                               seconds=time.perf_counter() - start)
                    rows.append(row)
                    print(f"set {k} frames {n:2d} error {degrees:g} deg / {metres * 100:g} cm "
                          f"trial {trial}: {angle:.3f} deg, {shift * 1000:.2f} mm "
                          f"({row['seconds']:.1f} s)", flush=True)
    print("\n| frames | error | rotation left (deg) median / max | translation left (mm) "
          "median / max | time (s) median |\n|---|---|---|---|---|")
    for n in counts:
        for degrees, metres in errors:
            sel = [r for r in rows if r["frames"] == n and r["error_deg"] == degrees
                   and r["error_m"] == metres]
            rot = np.array([r["rot_deg"] for r in sel])
            mm = np.array([r["trans_mm"] for r in sel])
            sec = np.median([r["seconds"] for r in sel])
            print(f"| {n} | {degrees:g}° / {metres * 100:g} cm | {np.median(rot):.3f} / "
                  f"{rot.max():.3f} | {np.median(mm):.2f} / {mm.max():.2f} | {sec:.0f} |")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
