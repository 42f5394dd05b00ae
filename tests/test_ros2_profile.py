"""The ros2 output profile: every topic decodes with mcap-ros2-support's decoder
and agrees with the same run written in the foxglove profile; both replay to the same frames,
points and calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from edge_depth.calibration.io import loads_calibration
from edge_depth.calibration.ros import transform_matrix
from edge_depth.capture.replay import McapSource
from edge_depth.cli import main
from edge_depth.commands import replay_command
from edge_depth.runtime.options import EngineOptions
from edge_depth.types import Calibration, LidarScan, StereoFrame


@pytest.fixture(scope="module")
def both(recording, tmp_path_factory):
    out = tmp_path_factory.mktemp("profiles")
    paths = {p: out / f"{p}.mcap" for p in ("foxglove", "ros2")}
    for profile, path in paths.items():
        assert replay_command(recording, path, EngineOptions(iters=1), profile=profile) == 0
    return paths


def ros2_messages(path) -> dict[str, list]:
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, _, msg in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append(msg)
    return out


def foxglove_json(path, topic: str) -> list[dict]:
    with open(path, "rb") as f:
        return [json.loads(m.data) for _, c, m in make_reader(f).iter_messages()
                if c.topic == topic]


def test_every_ros2_topic_decodes_and_agrees_with_the_foxglove_file(both, recording):
    msgs = ros2_messages(both["ros2"])
    for topic in ("/stereo/left/image_rect", "/stereo/right/image_rect",
                  "/stereo/left/camera_info", "/stereo/right/camera_info", "/stereo/depth",
                  "/stereo/disparity", "/stereo/points", "/stereo/sparse_disparity",
                  "/lidar/points", "/tf_static", "/diagnostics", "/edge/calibration"):
        assert topic in msgs, topic
    stereo, lidar = loads_calibration(msgs["/edge/calibration"][0].data)
    # images: the same bytes as the foxglove file's frames
    fox = [e for e in McapSource(both["foxglove"]) if isinstance(e, StereoFrame)]
    for image, frame in zip(msgs["/stereo/left/image_rect"], fox, strict=True):
        assert image.encoding == "mono8"
        np.testing.assert_array_equal(np.frombuffer(image.data, np.uint8).reshape(
            image.height, image.width), frame.left)
    # depth: the same metres as the foxglove file's, NaN where invalid (REP 118)
    fox_depth = foxglove_images(both["foxglove"], "/depth/image")
    assert len(fox_depth) == len(msgs["/stereo/depth"]) == 3
    for image, reference in zip(msgs["/stereo/depth"], fox_depth, strict=True):
        depth = np.frombuffer(image.data, "<f4").reshape(image.height, image.width)
        np.testing.assert_array_equal(depth, reference)  # NaN where invalid in both
    # camera infos: the calibration's rectified intrinsics, the right P carrying -f·B
    left, right = msgs["/stereo/left/camera_info"][0], msgs["/stereo/right/camera_info"][0]
    f = stereo.focal_px
    assert left.k[0] == pytest.approx(f) and left.p[2] == pytest.approx(stereo.principal_point[0])
    assert right.p[3] == pytest.approx(-f * stereo.baseline_m)
    assert left.distortion_model == "plumb_bob"
    # the TF tree: camera_left → camera_right at +B, camera_left → lidar = T_cam_lidar
    tf = {(t.header.frame_id, t.child_frame_id): transform_matrix(
        (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z),
        (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
         t.transform.rotation.w)) for t in msgs["/tf_static"][0].transforms}
    assert tf[("camera_left", "camera_right")][0, 3] == pytest.approx(stereo.baseline_m)
    np.testing.assert_allclose(tf[("camera_left", "lidar")], lidar.T_cam_lidar, atol=1e-9)
    # diagnostics: the same counters as the foxglove profile's JSON
    status = msgs["/diagnostics"][-1].status[0]
    values = {kv.key: json.loads(kv.value) for kv in status.values}
    assert values["frames"] == foxglove_json(both["foxglove"], "/diagnostics")[-1]["frames"]
    # the depth cloud carries the left image's intensity at each back-projected pixel
    cloud = np.frombuffer(msgs["/stereo/points"][0].data, "<f4").reshape(-1, 4)
    u = np.rint(cloud[:, 0] * f / cloud[:, 2] + stereo.principal_point[0]).astype(int)
    v = np.rint(cloud[:, 1] * f / cloud[:, 2] + stereo.principal_point[1]).astype(int)
    np.testing.assert_array_equal(cloud[:, 3], fox[0].left[v, u])
    disparity = msgs["/stereo/disparity"][0]
    assert disparity.f == pytest.approx(f) and disparity.t == pytest.approx(stereo.baseline_m)


def foxglove_images(path, topic: str) -> list[np.ndarray]:
    from mcap_protobuf.decoder import DecoderFactory

    from edge_depth.capture.decode import decode_image

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [decode_image(msg) for _, c, _, msg in reader.iter_decoded_messages(
            topics=[topic])]


def test_both_profiles_replay_to_the_same_frames_points_and_calibration(both):
    events = {p: list(McapSource(path)) for p, path in both.items()}
    kinds = {p: [type(e).__name__ for e in ev if not isinstance(e, Calibration)]
             for p, ev in events.items()}
    assert kinds["foxglove"] == kinds["ros2"]
    for a, b in zip(*(([e for e in ev if not isinstance(e, Calibration)])
                      for ev in events.values()), strict=True):
        if isinstance(a, StereoFrame):
            assert a.stamp_ns == b.stamp_ns
            np.testing.assert_array_equal(a.left, b.left)
            np.testing.assert_array_equal(a.right, b.right)
        elif isinstance(a, LidarScan):
            np.testing.assert_array_equal(a.points, b.points)
    tomls = {p: [e.toml for e in ev if isinstance(e, Calibration) and e.toml]
             for p, ev in events.items()}
    assert tomls["foxglove"] == tomls["ros2"] and tomls["ros2"]


def test_demo_writes_the_ros2_profile(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--frames", "1", "--profile", "ros2"]) == 0
    msgs = ros2_messages(tmp_path / "demo.mcap")
    assert {"/stereo/depth", "/stereo/disparity", "/tf_static", "/stereo/left/camera_info"} \
        <= set(msgs)


@pytest.mark.parametrize("profile", ["ros2", "foxglove"])
def test_invalid_depth_is_nan_in_both_profiles(tmp_path, profile):
    from edge_depth.loggers import open_logger
    from edge_depth.types import DepthResult

    disparity = np.full((8, 16), 10.0, np.float32)
    disparity[0] = 0.1  # below the 0.5 px minimum: invalid
    depth = np.where(disparity >= 0.5, 4.5 / disparity, 0).astype(np.float32)
    with open_logger(tmp_path / "r.mcap", profile) as logger:
        logger.log_result(DepthResult(1, disparity, depth, disparity >= 0.5, 1))
    if profile == "ros2":
        image = ros2_messages(tmp_path / "r.mcap")["/stereo/depth"][0]
        got = np.frombuffer(image.data, "<f4").reshape(8, 16)
    else:
        (got,) = foxglove_images(tmp_path / "r.mcap", "/depth/image")
    assert np.isnan(got[0]).all() and np.allclose(got[1:], 0.45)


def test_the_live_view_with_the_ros2_profile_is_one_clear_line(tmp_path, capsys):
    from tests.test_daemon_config import SIM, write

    cfg = write(tmp_path, SIM.format(out=tmp_path / "d.mcap") + 'profile = "ros2"\n')
    assert main(["run", "--config", str(cfg), "--live", "0", "--max-frames", "1"]) == 1
    err = capsys.readouterr().err.strip()
    assert "--live: expected the foxglove profile" in err and len(err.splitlines()) == 1


def test_diagnostics_warn_on_errors_and_keep_every_value(tmp_path):
    from edge_depth.loggers import open_logger

    path = tmp_path / "diag.mcap"
    with open_logger(path, "ros2") as logger:
        logger.log_diagnostics(1_000, dict(frames=2, errors={}, band_refined_pct=[4.5]))
        logger.log_diagnostics(2_000, dict(frames=4, errors={"frame size": 1},
                                           band_refined_pct=[4.5, 6.25, 3.5]))
    first, second = (m.status[0] for m in ros2_messages(path)["/diagnostics"])
    assert (first.level, first.message) == (0, "2 frames, 0 errors")
    assert (second.level, second.message) == (1, "4 frames, 1 errors")   # WARN
    values = {kv.key: json.loads(kv.value) for kv in second.values}
    assert values["band_refined_pct"] == [4.5, 6.25, 3.5]
