"""LiDAR points deskewed by the camera's turn: each point moved by the turn between its own
time and the frame's, the turn measured from the frames themselves (`edge.camera_turn`)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.calibration.projection import project_to_disparity
from edge_depth.camera_turn import deskew, turned_points
from edge_depth.capture.replay import McapSource
from edge_depth.capture.sim import SimSource
from edge_depth.capture.sync import SyncConfig
from edge_depth.capture.synced import synced_frames
from edge_depth.daemon import Pipeline
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim_recording import write_turning_recording
from edge_depth.types import LidarScan, StereoFrame

T0 = 1_000_000_000


def test_deskew_turns_each_point_by_the_turn_since_its_own_time():
    rng = np.random.default_rng(0)
    T = SimSource(1, 0).calibration[1].T_cam_lidar
    scene = rng.uniform([-3, -1, 2], [3, 1, 9], (200, 3)).astype(np.float32)  # LiDAR frame
    omega = np.radians(30.0)  # the robot's yaw rate, rad/s
    times = T0 + rng.integers(-100_000_000, 0, 200)  # swept over the 100 ms before
    frame_ns = T0 + 20_000_000
    seen = turned_points(scene, T, omega * (times - T0) / 1e9)
    truth = turned_points(scene, T, omega * (frame_ns - T0) / 1e9)
    # the turn meter reads a turn that moves the image's content right as positive: -omega
    fixed = deskew(seen, times, frame_ns, -np.degrees(omega), T)
    assert np.abs(seen - truth).max() > 0.05  # metres: the skew is there
    np.testing.assert_allclose(fixed, truth, atol=1e-4)
    # one stamp for the whole scan: every point turned by the same angle
    one = deskew(seen[:1], np.int64(times[0]), frame_ns, -np.degrees(omega), T)
    np.testing.assert_allclose(one, truth[:1], atol=1e-4)


RIG = RigConfig(width=320, height=200, focal_px=225.0, max_disparity_px=30.0)


@pytest.fixture(scope="module")
def turning(tmp_path_factory):
    """A robot turning at up to ~30 deg/s whose LiDAR points are 40 ms older than their
    frames (8 frames at 30 Hz): (recording, stereo, extrinsics, the scene's points)."""
    path = tmp_path_factory.mktemp("turning") / "turning.mcap"
    write_turning_recording(path, 8, 1_000_000, RIG, period_ms=1000 / 30, lidar_lag_ms=40.0,
                            amplitude_deg=10.0, turn_period_s=2.0, hold=8)
    stereo, extrinsics = SimSource(1, 1_000_000, RIG).calibration
    return path, stereo, extrinsics, make_sample(1_000_000, RIG, "beams16").scan.points


def missed(sparse: np.ndarray, stamp_ns: int, turning) -> float:
    """The share of the true sparse map's points (the scene turned by the yaw at the frame's
    own time) with no point within 0.5 px of their disparity at their pixel."""
    _, stereo, extrinsics, scene = turning
    T = extrinsics.T_cam_lidar
    yaw = np.radians(10.0) * np.sin(2 * np.pi * (stamp_ns - T0) / 1e9 / 2.0)
    truth, valid = project_to_disparity(turned_points(scene, T, yaw), stereo, T)
    return 1.0 - float((np.abs(sparse - truth) < 0.5)[valid].mean())


def pipeline_misses(turning, engine, deskewed: bool) -> tuple[float, int]:
    """The pipeline's sparse maps' median `missed` from the 2nd frame on (the first has no
    turn yet) and the frames it deskewed."""
    path, stereo, extrinsics, _ = turning
    pipeline = Pipeline(engine, stereo, extrinsics, sync=SyncConfig(deskew=deskewed))
    misses = []
    for event in McapSource(path):
        if isinstance(event, LidarScan):
            pipeline.on_scan(event)
        if not isinstance(event, StereoFrame):
            continue
        prepared = pipeline.prepare(event)
        assert prepared is not None
        misses.append(missed(prepared.sparse, event.stamp_ns, turning))
    return float(np.median(misses[1:])), len(pipeline.stats.deskewed)


def test_the_pipeline_deskews_a_turning_robots_points(turning, engine):
    raw, none = pipeline_misses(turning, engine, deskewed=False)
    fixed, frames = pipeline_misses(turning, engine, deskewed=True)
    assert none == 0 and frames >= 6
    assert raw > 0.3 and fixed < 0.2, (raw, fixed)  # measured: 0.38 and 0.13


def test_the_offline_readers_deskew_as_the_daemon_does(turning):
    """adapt's and training's frames (`synced_frames` with the calibration's T_cam_lidar)."""
    path, stereo, extrinsics, _ = turning
    T = extrinsics.T_cam_lidar
    shares = {}
    for name, deskew_with in (("raw", None), ("deskewed", T)):
        misses = [missed(project_to_disparity(points, stereo, T)[0], frame.stamp_ns, turning)
                  for frame, _, _, points, _ in synced_frames(path, stereo,
                                                              deskew_with=deskew_with)]
        shares[name] = float(np.median(misses[1:]))
    # these wait for the scans as replay does, so each frame pairs with the next frame's
    # revolution, 7 ms after it (the pipeline above was handed the 40 ms older one)
    assert shares["raw"] > 0.1 and shares["deskewed"] < 0.5 * shares["raw"], shares  # 0.13, 0.04


def test_calibrate_lidar_fits_the_points_the_daemon_will_project(turning, capsys):
    """`calibrate lidar` reads a recording's points deskewed as the daemon will project them
    (`--no-deskew`: as recorded), and says how many frames it moved."""
    from edge_depth.calibrate import mcap_frames

    path, stereo, extrinsics, _ = turning
    T = extrinsics.T_cam_lidar
    stamps = [T0 + int(i * 1e9 / 30) for i in range(8)]  # the fixture's frames, 30 Hz
    shares = {}
    for name, deskew_with in (("raw", None), ("deskewed", T)):
        frames = mcap_frames(path, stereo, max_frames=8, deskew_with=deskew_with)
        shares[name] = float(np.median([
            missed(project_to_disparity(points, stereo, T)[0], stamp, turning)
            for (_, _, points), stamp in zip(frames[1:], stamps[1:], strict=True)]))
        said = capsys.readouterr().out
        assert ("deskewed by the camera's turn" in said) == (deskew_with is not None), said
    assert shares["deskewed"] < 0.5 * shares["raw"], shares  # measured: 0.13, 0.04
