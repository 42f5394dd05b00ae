"""A synthetic recording as a robot would write it (raw topics, the calibration, and the
ground truth on /sim/gt_disparity): `edge-depth synth --mcap`, the replay tests and the
benchmark use it. Here, not in `edge.capture.sim`, because the capture layer only reads."""

from __future__ import annotations

from edge_depth.capture.sim import SimSource
from edge_depth.sim import RigConfig
from edge_depth.types import GroundTruth


def write_sim_recording(path, count: int, seed: int = 0, rig: RigConfig | None = None,
                        lidar: str = "beams16", period_ms: float = 100.0) -> int:
    """Record rig scenes as a robot would (raw topics, calibration) plus /sim/gt_disparity,
    for replay tests and demos. Returns the number of messages."""
    from edge_depth.mcap_log import RAW_TOPICS, McapLogger

    source = SimSource(count, seed, rig, lidar, period_ms)
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
