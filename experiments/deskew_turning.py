"""A study: on a turning sim robot whose LiDAR points are older than the frame they pair with,
how far each point lands from where the camera sees it at the frame's time, as recorded and
after `edge.camera_turn.deskew` (the camera's turn measured from the frames).

    python experiments/deskew_turning.py [--lag-ms 40] [--amplitude-deg 10] [--frames 90]

The recording is `edge.sim_recording.write_turning_recording`'s; the truth is each scan's
scene points turned by the robot's yaw at the frame's own time. Prints the median and p90 of
the points' horizontal misplacement in pixels, raw, deskewed, and deskewed with the turn's
sign flipped (which must be worse than raw: the sign is the measured one).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from edge_depth.camera_turn import TurnMeter, deskew, turned_points
from edge_depth.capture.replay import McapSource
from edge_depth.capture.sim import SimSource
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim_recording import write_turning_recording
from edge_depth.types import LidarScan, StereoFrame


def columns(points: np.ndarray, T: np.ndarray, rig: RigConfig) -> np.ndarray:
    """Each LiDAR point's image column in the (ideal, rectified) left camera; NaN behind it."""
    cam = points @ T[:3, :3].T + T[:3, 3]
    z = np.where(cam[:, 2] > 0.3, cam[:, 2], np.nan)
    return rig.focal_px * cam[:, 0] / z + rig.cx


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--period-ms", type=float, default=1000 / 30)
    p.add_argument("--lag-ms", type=float, default=40.0)
    p.add_argument("--amplitude-deg", type=float, default=10.0)
    p.add_argument("--turn-period-s", type=float, default=2.0)
    p.add_argument("--hold", type=int, default=30)
    p.add_argument("--seed", type=int, default=1_000_000)
    args = p.parse_args()
    rig = RigConfig()
    T = SimSource(1, args.seed, rig).calibration[1].T_cam_lidar
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "turning.mcap"
        write_turning_recording(path, args.frames, args.seed, rig, period_ms=args.period_ms,
                                lidar_lag_ms=args.lag_ms, amplitude_deg=args.amplitude_deg,
                                turn_period_s=args.turn_period_s, hold=args.hold)
        events = list(McapSource(path))
    frames = [e for e in events if isinstance(e, StereoFrame)]
    scans = [e for e in events if isinstance(e, LidarScan)]
    meter = TurnMeter(rig.focal_px)
    errors: dict[str, list[np.ndarray]] = {"raw": [], "deskewed": [], "sign flipped": []}
    rates = []
    for i, (frame, scan) in enumerate(zip(frames, scans, strict=True)):
        meter.frame(frame.stamp_ns, frame.left)
        rate = meter.rate()
        sample = make_sample(args.seed + i // args.hold, rig, "beams16")
        if not np.isfinite(rate) or len(sample.scan) != len(scan):
            continue
        rates.append(rate)
        yaw = np.radians(args.amplitude_deg) * np.sin(
            2 * np.pi * (frame.stamp_ns - 1_000_000_000) / 1e9 / args.turn_period_s)
        truth = columns(turned_points(sample.scan.points, T, yaw), T, rig)
        assert scan.point_stamps_ns is not None
        for name, points in (
                ("raw", scan.points),
                ("deskewed", deskew(scan.points, scan.point_stamps_ns, frame.stamp_ns, rate, T)),
                ("sign flipped", deskew(scan.points, scan.point_stamps_ns, frame.stamp_ns,
                                        -rate, T))):
            u = columns(points, T, rig)
            seen = np.isfinite(u) & np.isfinite(truth) & (truth >= 0) & (truth < rig.width)
            errors[name].append(np.abs(u - truth)[seen])
    print(f"{len(rates)} of {len(frames)} frames with a measured turn (|rate| median "
          f"{np.median(np.abs(rates)):.1f} deg/s, max {np.max(np.abs(rates)):.1f}); LiDAR "
          f"{args.lag_ms:g} ms older than its frame")
    for name, parts in errors.items():
        e = np.concatenate(parts)
        print(f"{name:>13}: |column error| median {np.median(e):.2f} px, p90 "
              f"{np.percentile(e, 90):.2f} px ({len(e)} points)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
