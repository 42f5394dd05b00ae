"""A study: on a turning sim robot (`edge.sim_recording.write_turning_recording`), how the
calibration watch's per-sample yaw reading moves with the camera's turn rate, with the LiDAR's
clock right and 30 ms off (docs/experiments.md, 2026-12-06 00:40).

    python experiments/clock_offset_probe.py [--frames 200] [--every 2]

Writes the recordings to a temporary folder, runs the watch's samples as `calibrate check`
does, and prints per recording the least-squares slope of the samples' own yaw readings
against their turn rate (degrees per degree/s: seconds), next to the clock error injected.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from edge_depth.calibration.projection import project_to_disparity
from edge_depth.calibration_watch import CalibrationWatch, parabola_minimum, stereo_reference
from edge_depth.capture.recording_calibration import recording_calibration
from edge_depth.capture.replay import McapSource
from edge_depth.capture.synced import stamped_frames
from edge_depth.runtime.engine import Engine
from edge_depth.sim_recording import write_turning_recording


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--every", type=int, default=2)
    p.add_argument("--seed", type=int, default=1_000_000)
    args = p.parse_args()
    engine = Engine()
    with tempfile.TemporaryDirectory() as tmp:
        for late_ms in (0.0, 30.0, -30.0):
            rec = Path(tmp) / f"turn{late_ms:+.0f}.mcap"
            write_turning_recording(rec, args.frames, args.seed, lidar_clock_ms=late_ms)
            stereo, lidar = recording_calibration(McapSource(rec))[:2]
            watch = CalibrationWatch(stereo, lidar.T_cam_lidar, args.every)
            for frame, left, right, points, stamp, _ in stamped_frames(rec, stereo):
                watch.frame(frame.stamp_ns, left)
                if not len(points) or not watch.due():
                    continue
                sparse, _ = project_to_disparity(points, stereo, lidar.T_cam_lidar)
                engine.infer(left, right, sparse)
                watch.add(stereo_reference(engine), points, (stamp - frame.stamp_ns) / 1e9)
            rows = []
            for s in watch._samples:
                yaw, _ = parabola_minimum(watch.yaw_axis, s.grid.min(axis=0))  # its own
                rows.append((s.turn_dps, s.gap_s, -yaw))
            turn, gap, yaw = (np.array(c) for c in zip(*rows, strict=True))
            ok = np.isfinite(turn)
            slope, icept = np.polyfit(turn[ok], yaw[ok], 1)
            print(f"LiDAR clock {late_ms:+.0f} ms late: {ok.sum()} of {len(turn)} samples with a "
                  f"turn rate (|rate| median {np.median(np.abs(turn[ok])):.1f} deg/s), gap "
                  f"{np.median(gap) * 1000:+.0f} ms; yaw reading = {icept:+.3f} deg + "
                  f"{slope * 1000:+.1f} ms x rate", flush=True)


if __name__ == "__main__":
    main()
