"""Where the replay's calibration comes from: --calib, the recording's /edge/calibration, or
a ROS 2 bag's CameraInfo pair with T_cam_lidar from the /tf_static chain."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from edge_depth.calibration.io import save_calibration
from edge_depth.calibration.ros import chain_transform
from edge_depth.capture.recording_calibration import recording_calibration
from edge_depth.capture.replay import McapSource, ReplayError, TopicMap
from edge_depth.commands import replay_command
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim import RigConfig, make_sample
from tests.ros2_bag import transform, write_bag

TOPICS = dict(left="/left/image_rect", right="/right/image_rect", lidar="/points",
              left_info="/left/camera_info", right_info="/right/camera_info",
              calibration="", gt="")


def pose(yaw_deg: float, t) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [yaw_deg, 0.3 * yaw_deg, -0.5 * yaw_deg],
                                    degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def test_the_chain_walks_edges_either_way_and_says_when_frames_do_not_join():
    A, B = pose(30, [0.1, 0.2, 0.3]), pose(-50, [1.0, 0.0, -0.4])
    # base → cam and base → lidar: cam ← lidar goes up one edge and down the other
    edges = [("base", "cam", A), ("base", "lidar", B), ("world", "other", np.eye(4))]
    T, path = chain_transform(edges, "cam", "lidar")
    np.testing.assert_allclose(T, np.linalg.inv(A) @ B, atol=1e-12)
    assert path == ["lidar", "base", "cam"]
    T_back, _ = chain_transform(edges, "lidar", "cam")
    np.testing.assert_allclose(T_back @ T, np.eye(4), atol=1e-12)
    assert chain_transform(edges, "cam", "other") is None


@pytest.fixture(scope="module")
def samples():
    return [make_sample(1_000_000 + i, RigConfig(width=160, height=96)) for i in range(2)]


def tf_tree(T_cam_lidar) -> list[dict]:
    """base_link → camera and base_link → lidar, composing to T_cam_lidar."""
    A = pose(20, [0.05, -0.02, 0.3])  # T_base_camera
    return [transform("base_link", "camera", A),
            transform("base_link", "lidar", A @ T_cam_lidar)]


def test_a_bag_with_camera_info_and_tf_static_replays_with_its_lidar(samples, tmp_path,
                                                                    caplog, capsys):
    bag = tmp_path / "bag.mcap"
    write_bag(bag, samples, tf=tf_tree(samples[0].T_cam_lidar))
    stereo, lidar, origin = recording_calibration(McapSource(bag, TopicMap(**TOPICS)))
    np.testing.assert_allclose(lidar.T_cam_lidar, samples[0].T_cam_lidar, atol=1e-6)
    assert stereo.focal_px == pytest.approx(samples[0].rig.focal_px)
    assert stereo.baseline_m == pytest.approx(samples[0].rig.baseline_m)
    assert "lidar → base_link → camera" in origin
    caplog.set_level(logging.INFO)
    assert replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=2), topics=TOPICS) == 0
    assert "calibration: the recording's CameraInfo" in caplog.text
    out = capsys.readouterr().out
    assert "frames with LiDAR: 2 of 2" in out
    # the closing summary's frame rate: the two frames' own, a number
    assert float(out.split("throughput ")[1].split(" frames/s")[0]) > 0


def test_without_a_transform_a_mapped_lidar_is_an_error_and_unmapped_runs_stereo_only(
        samples, tmp_path, caplog):
    bag = tmp_path / "bag.mcap"
    write_bag(bag, samples)
    with pytest.raises(ReplayError, match="no LiDAR extrinsics.*calibrate lidar"):
        replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=2), topics=TOPICS)
    stereo_only = dict(TOPICS, lidar="")
    assert replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=2),
                          topics=stereo_only) == 0


def test_calib_comes_first_and_a_recording_with_nothing_names_the_options(samples, tmp_path,
                                                                         caplog):
    bag = tmp_path / "bag.mcap"
    write_bag(bag, samples)  # CameraInfo but no transforms: --calib supplies the LiDAR
    calib = tmp_path / "calib.toml"
    save_calibration(calib, samples[0].calibration(), _lidar(samples[0]))
    caplog.set_level(logging.INFO)
    assert replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=2), calib=calib,
                          topics=TOPICS) == 0
    assert f"calibration: --calib {calib}" in caplog.text
    nothing = dict(TOPICS, left_info="", right_info="")
    with pytest.raises(ValueError, match="neither.*CameraInfo pair"):
        replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=2), topics=nothing)


def _lidar(sample):
    from edge_depth.calibration.model import LidarExtrinsics

    return LidarExtrinsics(sample.T_cam_lidar)


def test_calibrate_lidar_reads_a_ros2_bag_with_its_topics_and_own_calibration(samples,
                                                                             tmp_path,
                                                                             capsys):
    from edge_depth.cli import main

    bag = tmp_path / "bag.mcap"
    write_bag(bag, samples, tf=tf_tree(samples[0].T_cam_lidar))
    topics = tmp_path / "topics.toml"
    topics.write_text("[topics]\n" + "".join(f'{k} = "{v}"\n' for k, v in TOPICS.items()))
    assert main(["calibrate", "lidar", "--recording", str(bag), "--topics", str(topics),
                 "--max-frames", "2"]) == 0
    out = capsys.readouterr().out
    assert "calibration: the recording's CameraInfo" in out and "/tf_static" in out
    # without the transform there is nothing to check: one line says so
    bare = tmp_path / "bare.mcap"
    write_bag(bare, samples)
    assert main(["calibrate", "lidar", "--recording", str(bare), "--topics",
                 str(topics)]) == 1
    assert "no LiDAR extrinsics" in capsys.readouterr().err


def test_an_unmapped_or_missing_lidar_topic_is_said_and_left_equal_right_refused(
        samples, tmp_path, caplog):
    bag = tmp_path / "bag.mcap"
    write_bag(bag, samples)
    stereo_only = dict(TOPICS, lidar="")
    assert replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=1),
                          topics=stereo_only) == 0
    assert "no LiDAR topic is mapped; LiDAR-like topics there: /points, /scan" in caplog.text
    caplog.clear()
    calib = tmp_path / "calib.toml"
    save_calibration(calib, samples[0].calibration(), _lidar(samples[0]))
    assert replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=1), calib=calib,
                          topics=dict(TOPICS, lidar="/velodyne_points")) == 0
    assert "the mapped LiDAR topic /velodyne_points is not in the recording" in caplog.text
    with pytest.raises(ReplayError, match="left and right are the same topic"):
        TopicMap.from_dict(dict(TOPICS, right=TOPICS["left"]))


def test_a_ros2_bag_directory_replays_its_files_in_the_metadata_order(samples, tmp_path):
    from edge_depth.types import StereoFrame

    bag = tmp_path / "robot_bag"
    bag.mkdir()
    write_bag(bag / "robot_bag_1.mcap", samples[1:], tf=tf_tree(samples[0].T_cam_lidar))
    write_bag(bag / "robot_bag_0.mcap", samples[:1], tf=tf_tree(samples[0].T_cam_lidar))
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n"
        "  relative_file_paths:\n    - robot_bag_0.mcap\n    - robot_bag_1.mcap\n")
    frames = [e for e in McapSource(bag, TopicMap(**TOPICS)) if isinstance(e, StereoFrame)]
    assert len(frames) == 2
    np.testing.assert_array_equal(frames[0].left, samples[0].left)  # file 0 first
    np.testing.assert_array_equal(frames[1].left, samples[1].left)
    empty = tmp_path / "empty_dir"
    empty.mkdir()
    with pytest.raises(ReplayError, match="without .mcap files"):
        McapSource(empty)


def test_header_stamps_that_are_all_zero_fall_back_to_arrival_order(samples, tmp_path,
                                                                    caplog, capsys):
    bag = tmp_path / "zero.mcap"
    write_bag(bag, samples, tf=tf_tree(samples[0].T_cam_lidar), zero_stamps=True)
    assert replay_command(bag, tmp_path / "out.mcap", EngineOptions(iters=1), topics=TOPICS) == 0
    assert "pairing by the messages' arrival order (a recording's log times)" in caplog.text
    # the second frame on is stamped by its log time and finds its scan
    assert "frames with LiDAR: 1 of 2" in capsys.readouterr().out
