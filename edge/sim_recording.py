"""A synthetic recording as a robot would write it (raw topics, the calibration, and the
ground truth on /sim/gt_disparity): `edge-depth synth --mcap`, the replay tests and the
benchmark use it. Here, not in `edge.capture.sim`, because the capture layer only reads."""

from __future__ import annotations

from edge.capture.sim import SimSource
from edge.sim import RigConfig
from edge.types import GroundTruth


def write_sim_recording(path, count: int, seed: int = 0, rig: RigConfig | None = None,
                        lidar: str = "beams16", period_ms: float = 100.0) -> int:
    """Record rig scenes as a robot would (raw topics, calibration) plus /sim/gt_disparity,
    for replay tests and demos. Returns the number of messages."""
    from edge.mcap_log import RAW_TOPICS, McapLogger

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
