"""A synthetic recording as a robot would write it (raw topics, the calibration, and the
ground truth on /sim/gt_disparity): `edge-depth synth --mcap`, the replay tests and the
benchmark use it. Here, not in `edge.capture.sim`, because the capture layer only reads."""

from __future__ import annotations

from edge_depth.capture.sim import SimSource
from edge_depth.sim import RigConfig
from edge_depth.sim.motion import Motion
from edge_depth.types import GroundTruth


def write_sim_recording(path, count: int, seed: int = 0, rig: RigConfig | None = None,
                        lidar: str = "beams16", period_ms: float = 100.0,
                        motion: Motion | None = None, scan_every: int = 1) -> int:
    """Record rig scenes as a robot would (raw topics, calibration) plus /sim/gt_disparity,
    for replay tests and demos; with `motion`, one world moving (`edge.sim.motion`), the
    ground truth on every frame and a scan with every `scan_every` frames. Returns the number
    of messages."""
    from edge_depth.mcap_log import RAW_TOPICS, McapLogger

    source = SimSource(count, seed, rig, lidar, period_ms, motion=motion,
                       scan_every=scan_every)
    with McapLogger(path, topics=RAW_TOPICS) as logger:
        logger.set_calibration(*source.calibration)
        for event in source:
            if isinstance(event, GroundTruth):
                logger.log_gt(event.stamp_ns, event.disparity)
            elif hasattr(event, "points"):
                logger.log_scan(event)
            else:
                logger.log_frame(event)
        return logger.messages


def write_street_recording(path, count: int, seed: int = 0, period_ms: float = 100.0,
                           lidar_lag_ms: float = 5.0) -> int:
    """Record street scenes (`edge.sim.street`: 1242×375, 64-beam LiDAR) as a robot would,
    plus /sim/gt_disparity: a world the shipped model never trained on. Each frame is its own
    scene; the scan is stamped `lidar_lag_ms` before its frame. Returns the message count."""
    import numpy as np

    from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
    from edge_depth.mcap_log import RAW_TOPICS, McapLogger
    from edge_depth.sim.street import (
        STREET_CAMERA,
        T_CAM_LIDAR,
        StreetScene,
        lidar_points,
        street_lidar,
    )
    from edge_depth.sim.world import make_things_sample
    from edge_depth.types import LidarScan, StereoFrame

    cfg = STREET_CAMERA
    stereo = StereoCalibration.ideal(cfg.focal_px, cfg.baseline_m, (cfg.width, cfg.height),
                                     cfg.cx, cfg.cy)
    with McapLogger(path, topics=RAW_TOPICS) as logger:
        logger.set_calibration(stereo, LidarExtrinsics(T_CAM_LIDAR))
        for i in range(count):
            stamp = 1_000_000_000 + int(i * period_ms * 1e6)
            sample = make_things_sample(seed + i, cfg, StreetScene)
            sparse = street_lidar(sample.disp_left, np.random.default_rng([seed + i, 64]))
            logger.log_scan(LidarScan(stamp - int(lidar_lag_ms * 1e6),
                                      lidar_points(sparse, cfg)))
            logger.log_frame(StereoFrame(stamp, i, sample.left, sample.right, rectified=True))
            logger.log_gt(stamp, sample.disp_left)
        return logger.messages


def write_turning_recording(path, count: int, seed: int = 0, rig: RigConfig | None = None,
                            lidar: str = "beams16", period_ms: float = 100.0,
                            lidar_lag_ms: float = 5.0, amplitude_deg: float = 3.0,
                            turn_period_s: float = 2.0, hold: int = 20,
                            lidar_clock_ms: float = 0.0) -> int:
    """A robot turning back and forth in front of rig scenes, for the calibration watch's
    clock offset: its yaw θ(t) = amplitude · sin(2π t / turn_period) about the left camera's
    vertical axis, a new scene every `hold` frames. Each frame is the scene's pair rotated by
    θ at the frame's time (a rotation about a camera's centre is a homography of its image;
    both views get the same one, which leaves the pair rectified to within 0.7 px at 3°); each
    scan holds the scene's points as the LiDAR saw each at its own time (with each point's
    stamp), is stamped by its forward middle (what the camera sees) `lidar_lag_ms` before its
    frame, and swept that middle `lidar_clock_ms` before its stamps say: stamps that run late
    (a USB adapter's latency) by an offset the calibration's `time_offset_ns` does not know
    of, whose right value is then −lidar_clock_ms. No ground truth. Returns the number of
    messages."""
    import cv2
    import numpy as np

    from edge_depth.mcap_log import RAW_TOPICS, McapLogger
    from edge_depth.sim import make_sample
    from edge_depth.types import StereoFrame

    rig = rig or RigConfig()
    if hold < 1 or turn_period_s <= 0:
        raise ValueError(f"hold >= 1 and turn_period_s > 0, got {hold}, {turn_period_s}")
    source = SimSource(count, seed, rig, lidar, period_ms)
    stereo, extrinsics = source.calibration
    K = np.array([[rig.focal_px, 0, rig.cx], [0, rig.focal_px, rig.cy], [0, 0, 1.0]])
    T = extrinsics.T_cam_lidar

    def rotation(t_s: float) -> np.ndarray:  # the robot's turn at t_s into the recording
        yaw = np.radians(amplitude_deg) * np.sin(2 * np.pi * t_s / turn_period_s)
        return cv2.Rodrigues(np.array([0.0, yaw, 0.0]))[0]

    with McapLogger(path, topics=RAW_TOPICS) as logger:
        logger.set_calibration(stereo, extrinsics)
        sample = None
        for i in range(count):
            if i % hold == 0:
                sample = make_sample(seed + i // hold, rig, lidar)
            assert sample is not None
            stamp = 1_000_000_000 + int(i * period_ms * 1e6)
            # the revolution stamped `lidar_lag_ms` before its frame
            forward_ns = stamp - int(lidar_lag_ms * 1e6)
            logger.log_scan(_turning_scan(sample.scan, forward_ns, T, amplitude_deg,
                                          turn_period_s, lidar_clock_ms))
            H = K @ rotation(i * period_ms / 1000).T @ np.linalg.inv(K)
            size = (rig.width, rig.height)
            left, right = (cv2.warpPerspective(im, H, size, flags=cv2.INTER_LINEAR,
                                               borderMode=cv2.BORDER_REPLICATE)
                           for im in (sample.left, sample.right))
            logger.log_frame(StereoFrame(stamp, i, left, right, rectified=True))
        return logger.messages


def _turning_scan(scan, forward_ns: int, T_cam_lidar, amplitude_deg: float,
                  turn_period_s: float, lidar_clock_ms: float):
    """`write_turning_recording`'s scan: the scene's points as the LiDAR saw each at its own
    time on the turning robot (X_cam -> R(t)^T X_cam, back to the LiDAR), stamped by its
    forward middle (what the camera sees), `forward_ns`, with each point's stamp; every point
    was swept `lidar_clock_ms` before its stamp."""
    import numpy as np

    from edge_depth.camera_turn import turned_points
    from edge_depth.types import LidarScan

    offsets = scan.point_stamps_ns - scan.stamp_ns
    stamps = (forward_ns + offsets - int(np.median(offsets))).astype(np.int64)
    yaw = np.radians(amplitude_deg) * np.sin(
        2 * np.pi * (stamps - int(lidar_clock_ms * 1e6) - 1_000_000_000) / 1e9 / turn_period_s)
    return LidarScan(forward_ns, turned_points(scan.points, T_cam_lidar, yaw), None, stamps)
