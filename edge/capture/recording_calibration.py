"""The calibration a recording carries (our /edge/calibration TOML, or a CameraInfo pair with
/tf_static), and why it could not be read where damage or an undecodable message hid it."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from edge_depth.capture.replay import McapSource, RecordingCalibration, ReplayError, TopicMap

log = logging.getLogger(__name__)


def recording_calibration(source: McapSource):
    """The calibration a recording carries, in precedence order: our /edge/calibration TOML,
    else the mapped CameraInfo pair with T_cam_lidar from /tf_static (the chain from the
    LiDAR's frame to the left camera's). (stereo, lidar or None, where it came from), or None
    when it carries neither. ReplayError when it carries neither that can be read because its
    data is damaged or its calibration message does not decode; where the CameraInfo pair
    stands in for such a calibration, a warning and the origin say so."""
    from edge_depth.calibration.io import loads_calibration

    found = source.scan_calibration()
    t = source.topics
    if found.toml is not None:
        stereo, lidar = loads_calibration(found.toml, f"{source.path} {t.calibration}")
        return stereo, lidar, f"the recording's {t.calibration}"
    unread = _unread_calibration(found, t)
    if len(found.infos) < 2:
        if unread:
            raise ReplayError(f"{source.path}: no calibration could be read: {unread}; give "
                              "a calibration file (--calib)")
        return None
    stereo, lidar, origin = _camera_info_calibration(source.path, found, t)
    if unread:
        log.warning("%s: %s; using the CameraInfo pair instead", source.path, unread)
        origin += f", used because {unread}"
    return stereo, lidar, origin


def _unread_calibration(found: RecordingCalibration, t: TopicMap) -> str:
    """Why the recording's own calibration may not have been seen: its message does not
    decode, or the data before a CameraInfo pair is damaged (it may have been there); ""
    when neither."""
    if found.unreadable is not None:
        return f"its {t.calibration} message is unreadable ({found.unreadable})"
    if found.lost:
        return (f"{'; '.join(found.lost[:3])}{' …' if len(found.lost) > 3 else ''} before "
                f"any {t.calibration} or CameraInfo pair was read (it may have held them)")
    return ""


def _camera_info_calibration(path: Path, found: RecordingCalibration, t: TopicMap):
    """(stereo, lidar or None, origin) from the CameraInfo pair and /tf_static."""
    from edge_depth.calibration.model import LidarExtrinsics
    from edge_depth.calibration.ros import chain_transform, stereo_from_camera_infos

    left, right = found.infos["left"], found.infos["right"]
    stereo = stereo_from_camera_infos(left, right, f"{path} {t.right_info}",
                                      rectified=t.rectified)
    origin = f"the recording's CameraInfo ({t.left_info}, {t.right_info})"
    lidar = None
    if found.lidar_frame and found.transforms:
        chain = chain_transform(found.transforms, left["frame_id"], found.lidar_frame)
        if chain is not None:
            T, chain_path = chain
            if t.rectified:  # the camera info's R turns the raw camera into the rectified one
                R = np.eye(4)
                R[:3, :3] = left["R"]
                T = R @ T
            lidar = LidarExtrinsics(T)
            origin += f" and {t.tf_static} ({' → '.join(chain_path)})"
        else:
            origin += (f"; {t.tf_static} has no chain from the LiDAR's frame "
                       f"{found.lidar_frame!r} to the camera's {left['frame_id']!r}")
    return stereo, lidar, origin
