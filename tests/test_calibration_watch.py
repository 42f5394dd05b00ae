"""The calibration watch: the LiDAR–camera rotation error from the frames the daemon runs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_depth.calibration.extrinsics import _perturb
from edge_depth.calibration_verdict import (
    ERROR,
    OK,
    SETTLING,
    WARN,
    WatchEstimate,
    fixes,
    refine_command,
    verdict,
)
from edge_depth.calibration_watch import CalibrationWatch
from edge_depth.cli import main
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.lidar import default_T_cam_lidar

RIG = RigConfig(width=320, height=200, focal_px=225.0, max_disparity_px=30.0)


@pytest.fixture(scope="module")
def frames():
    """Sim frames at 320x200 with their true disparity as the reference: what the watch
    measures, without the engine's own error."""
    return [make_sample(3_000_000 + i, RIG, "beams16") for i in range(12)]


def watched(frames, rotation_deg) -> CalibrationWatch:
    watch = CalibrationWatch(frames[0].calibration(),
                             _perturb(default_T_cam_lidar(), np.r_[rotation_deg, 0, 0, 0]), 1)
    for s in frames:
        assert watch.due()
        assert watch.add(np.nan_to_num(s.disp_left).astype(np.float32), s.scan.points)
    return watch


@pytest.mark.parametrize("rotation, axis", [((0, 0.4, 0), 1), ((0, -0.4, 0), 1),
                                            ((0.4, 0, 0), 0), ((-0.4, 0, 0), 0)])
def test_an_injected_rotation_is_estimated_with_its_sign(frames, rotation, axis):
    estimate = watched(frames, rotation).estimate()
    assert estimate.error_deg[axis] == pytest.approx(rotation[axis], abs=0.08)
    assert abs(estimate.error_deg[1 - axis]) < 0.08  # the other axis stays put
    # 0.4 deg at f = 225 px moves the points by 1.6 px: ERROR (beyond 1 px)
    assert estimate.level == ERROR and estimate.shift_px > 1.0


def test_points_hidden_from_the_camera_do_not_pull_pitch(monkeypatch):
    """A LiDAR 25 cm above the camera sees background over the top of nearer surfaces; kept
    (the occlusion filter off), those points land inside the nearer surface, below its top
    edges. Behind the surface the camera sees, they cost no more than a point without a
    reference, so the right calibration reads pitch 0; counted in full they pulled it."""
    import edge_depth.calibration_watch as watch_module

    T = default_T_cam_lidar(0.25)
    scenes = [make_sample(3_000_000 + i, RIG, "beams16", T_cam_lidar=T) for i in range(12)]
    monkeypatch.setattr(watch_module, "visible_points", lambda p, *a, **k: np.ones(len(p), bool))

    def pitch() -> float:
        watch = CalibrationWatch(scenes[0].calibration(), T, 1)
        for s in scenes:
            watch.add(np.nan_to_num(s.disp_left).astype(np.float32), s.scan.points)
        return watch.estimate().error_deg[0]

    assert abs(pitch()) < 0.02
    monkeypatch.setattr(watch_module, "BEHIND_PX", watch_module.TRUNCATE_PX)
    assert pitch() < -0.04  # the hidden points, counted in full, read as the camera pitched


def test_the_right_calibration_is_ok_and_settles_first(frames):
    watch = watched(frames[:7], (0, 0, 0))
    assert watch.estimate().level == SETTLING and "settling" in watch.estimate().describe()
    watch.add(np.nan_to_num(frames[7].disp_left).astype(np.float32), frames[7].scan.points)
    estimate = watch.estimate()
    assert estimate.level == OK and max(abs(e) for e in estimate.error_deg[:2]) < 0.05
    assert estimate.as_dict()["level"] == OK and estimate.as_dict()["samples"] == 8


def test_a_robot_standing_still_counts_its_one_view_once(frames):
    """The same view sampled again replaces the last sample (its bias would read as certain);
    a different view adds one."""
    watch = CalibrationWatch(frames[0].calibration(), default_T_cam_lidar(), 1)
    still = frames[0]
    reference = np.nan_to_num(still.disp_left).astype(np.float32)
    for i in range(9):
        watch.frame(i * 100_000_000, still.left)
        assert watch.due() and watch.add(reference, still.scan.points)
    assert watch.samples == 9 and watch.estimate().samples == 1
    assert watch.estimate().level == SETTLING
    for i, s in enumerate(frames[1:8], start=9):
        watch.frame(i * 100_000_000, s.left)
        watch.due()
        watch.add(np.nan_to_num(s.disp_left).astype(np.float32), s.scan.points)
    assert watch.estimate().samples == 8 and watch.estimate().level == OK


def test_every_nth_frame_is_a_sample_and_a_frame_without_seen_points_is_none():
    watch = CalibrationWatch(make_sample(1, RIG).calibration(), default_T_cam_lidar(), every=3)
    assert [watch.due() for _ in range(7)] == [True, False, False, True, False, False, True]
    assert not watch.add(np.ones((200, 320), np.float32), np.zeros((0, 3)))
    behind = np.array([[0.0, 0.0, -5.0]] * 10)  # behind the LiDAR: nothing in view
    assert not watch.add(np.ones((200, 320), np.float32), behind) and watch.samples == 0


def test_levels_are_pixels_beyond_twice_the_uncertainty_and_the_resolution():
    lever = np.radians([450.0, 450.0, 200.0])  # px per degree
    assert verdict(np.array([0.0, 0.3, 0.0]), np.zeros(3), lever)[1] == ERROR  # 2.4 px
    # 0.12 deg is 0.94 px: under ERROR, and beyond the 0.1 deg resolution + 0.1 px: WARN
    assert verdict(np.array([0.0, 0.12, 0.0]), np.zeros(3), lever)[1] == WARN
    assert verdict(np.array([0.0, 0.08, 0.0]), np.zeros(3), lever)[1] == OK  # within it
    # the same 0.3 deg with an uncertainty of 0.15 deg is not yet certain: 0 px beyond 2 sigma
    shift, level = verdict(np.array([0.0, 0.3, 0.0]), np.array([0.0, 0.15, 0.0]), lever)
    assert shift == 0.0 and level == OK
    # a clock 30 ms off while the image moves 50 px/s: 1.5 px, beside a right rotation
    clock = verdict(np.zeros(4), np.zeros(4), np.r_[lever, 50.0], np.r_[0.1, 0.1, 0.35, 0.01])
    off = verdict(np.r_[0.0, 0.0, 0.0, 0.03], np.zeros(4), np.r_[lever, 50.0],
                  np.r_[0.1, 0.1, 0.35, 0.01])
    assert clock == (0.0, OK) and off[1] == ERROR and off[0] == pytest.approx(1.5)
    # 30 +- 10 ms: twice the uncertainty and the 10 ms resolution in quadrature leave 7.6 ms
    # (0.38 px at 50 px/s): WARN, where adding them (30 ms) would have said nothing
    unsure = verdict(np.r_[0.0, 0.0, 0.0, 0.03], np.r_[0.0, 0.0, 0.0, 0.01],
                     np.r_[lever, 50.0], np.r_[0.1, 0.1, 0.35, 0.01])
    assert unsure[1] == WARN and unsure[0] == pytest.approx(0.5)


def test_the_refine_command_is_pre_filled():
    assert refine_command("rec.mcap", "robot.toml") == (
        "edge-depth calibrate lidar --recording rec.mcap --refine --calib robot.toml "
        "--out robot_refined.toml")
    assert refine_command("rec.mcap", None).endswith("--refine --out refined.toml")


def test_the_fix_names_what_alone_moves_the_points_beyond_warn():
    def estimate(rotation_px, clock_px, level=WARN):
        return WatchEstimate((0.0, -0.11, 0.0), (0.02,) * 3, 0.7, level, 15, clock_s=-0.03,
                             clock_sigma_s=0.01, rotation_px=rotation_px, clock_px=clock_px)

    # a right rotation a hair beyond its margin beside a clock 30 ms off: the clock alone
    clock_only = fixes(estimate(0.02, 0.4), "rec.mcap", "robot.toml", 5_000_000)
    assert clock_only == "the LiDAR's clock: set [lidar] time_offset_ns = -25000000 in robot.toml"
    both = fixes(estimate(0.5, 0.4), "rec.mcap", "robot.toml")
    assert both.startswith("to refine the rotation: edge-depth calibrate lidar") and "clock" in both
    # neither alone beyond 0.1 px, together WARN: both named
    assert "rotation" in fixes(estimate(0.08, 0.08), None, None) and \
        "clock" in fixes(estimate(0.08, 0.08), None, None)
    assert fixes(estimate(0.02, 0.4, OK), "rec.mcap", None) == ""


def test_the_stereo_only_reference_never_sees_the_lidar(engine, noiseless_samples):
    from edge_depth.calibration.projection import project_to_disparity

    s = noiseless_samples[0]
    with pytest.raises(RuntimeError, match="follows an infer"):
        type(engine)(precision="int8", threads=1).stereo_only()
    sparse, _ = project_to_disparity(s.scan.points, s.calibration(), s.T_cam_lidar)
    with_lidar = engine.infer(s.left, s.right, sparse)
    reference = engine.stereo_only(2)
    engine.infer(s.left, s.right, np.zeros_like(sparse))
    assert reference.shape == s.left.shape
    np.testing.assert_array_equal(reference, engine.stereo_only(2))
    # and it is not the frame's result, which the LiDAR anchors
    assert np.abs(reference - with_lidar.disparity).max() > 0.5


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory):
    from edge_depth.calibration.io import save_calibration
    from edge_depth.calibration.model import LidarExtrinsics
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource

    folder = tmp_path_factory.mktemp("watch")
    rec = folder / "rec.mcap"
    assert main(["synth", "--mcap", str(rec), "--frames", "10", "--seed", "1000000",
                 "--size", "320x200"]) == 0
    stereo, lidar = recording_calibration(McapSource(rec))[:2]
    calibs = {}
    for name, yaw in (("right", 0.0), ("yawed", 0.5)):
        calibs[name] = folder / f"{name}.toml"
        save_calibration(calibs[name], stereo,
                         LidarExtrinsics(_perturb(lidar.T_cam_lidar, np.r_[0, yaw, 0, 0, 0, 0])))
    return rec, calibs


def test_calibrate_check_exits_1_on_error_with_the_command_that_fixes_it(small_recording,
                                                                         capsys):
    rec, calibs = small_recording
    # offline every frame is a sample: 10 of its 10 frames
    assert main(["calibrate", "check", str(rec), "--calib", str(calibs["yawed"])]) == 1
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("LiDAR-camera rotation error"))
    yaw = float(line.split("yaw ")[1].split("°")[0])
    assert 0.35 < yaw < 0.65 and line.endswith("ERROR")
    assert f"--recording {rec} --refine --calib {calibs['yawed']}" in out
    assert "not observed" in line  # a still robot: no clock offset to see
    assert main(["calibrate", "check", str(rec), "--calib", str(calibs["right"])]) == 0
    assert capsys.readouterr().out.count(": OK") == 1


def test_replay_says_it_in_one_line_and_on_diagnostics(small_recording, tmp_path, capsys):
    from mcap.reader import make_reader

    rec, calibs = small_recording
    out = tmp_path / "out.mcap"
    assert main(["replay", str(rec), "--calib", str(calibs["yawed"]), "--out", str(out)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines()
                if x.startswith("LiDAR-camera calibration watch"))
    # one sample in 13 frames with LiDAR: 1 of the 8 a verdict needs
    assert "settling (1 of 8 samples, each of a view of its own)" in line and "refine" not in line
    with open(out, "rb") as f:
        diagnostics = [json.loads(m.data) for _, _, m in
                       make_reader(f).iter_messages(topics=["/diagnostics"])]
    assert diagnostics[-1]["calibration_watch"]["level"] == SETTLING
    # the engine's check of the LiDAR map, per frame: whether it was put back (0: the sim's
    # never is) and its range noise (the sim's points are exact: below the 0.3 px the summary
    # speaks at); and the band refinement's share of each frame
    frames = sum(len(d["iterations"]) for d in diagnostics)
    assert sum(len(d["band_refined_pct"]) for d in diagnostics) == frames > 0
    assert all(0 < v < 100 for d in diagnostics for v in d["band_refined_pct"])
    assert "photometry_change" not in diagnostics[-1]
    assert all(v == 0 for d in diagnostics for v in d["lidar_put_back"])
    noise = [v for d in diagnostics for v in d["lidar_noise_px"]]
    assert len(noise) == frames and all(0 <= v < 0.3 for v in noise), noise


def test_the_ros2_profile_gives_it_a_diagnostic_status_of_its_own():
    from edge_depth.ros2_log import watch_status

    status = watch_status(dict(level=ERROR, samples=12, shift_px=2.4, at_reach=False,
                               pitch_deg=0.01, yaw_deg=0.31, roll_deg=0.0))
    assert status["level"] == 2 and status["name"] == "edge-depth/lidar_calibration"
    assert "yaw +0.31" in status["message"]
    assert {"key": "yaw_deg", "value": "0.31"} in status["values"]
    assert watch_status(dict(level=SETTLING, samples=3))["level"] == 0


def test_a_turning_robot_shows_the_lidar_clock_offset_and_its_fix(tmp_path, capsys):
    from edge_depth.calibration.io import save_calibration
    from edge_depth.calibration.model import LidarExtrinsics
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource

    rec = tmp_path / "turning.mcap"
    assert main(["synth", "--mcap", str(rec), "--frames", "100", "--seed", "1000000",
                 "--size", "320x200", "--turn-deg", "3", "--lidar-late-ms", "30"]) == 0
    capsys.readouterr()
    daemons = ["--every", "13"]  # the daemon's sampling over 100 frames: its banked samples
    code = main(["calibrate", "check", str(rec)] + daemons)
    out = capsys.readouterr().out
    # the clock alone, 24-30 ms at this size's turn rate: WARN (exit 0) or ERROR (exit 1)
    line = next(x for x in out.splitlines() if x.startswith("LiDAR-camera rotation error"))
    assert line.endswith(("WARN", "ERROR")) and code == int(line.endswith("ERROR"))
    clock_ms = float(out.split("clock ")[1].split(" ms")[0])
    assert -39 < clock_ms < -21  # the stamps run 30 ms late: the offset to set is -30 ms
    value = int(out.split("time_offset_ns = ")[1].split()[0])
    assert value == round(clock_ms) * 1_000_000
    # with that offset in the calibration the same recording checks OK
    stereo, lidar = recording_calibration(McapSource(rec))[:2]
    fixed = tmp_path / "fixed.toml"
    save_calibration(fixed, stereo, LidarExtrinsics(lidar.T_cam_lidar, value))
    assert main(["calibrate", "check", str(rec), "--calib", str(fixed)] + daemons) == 0
    after = capsys.readouterr().out
    assert abs(float(after.split("clock ")[1].split(" ms")[0])) < 8 and after.count("OK") == 1


def test_a_failing_watch_is_counted_and_the_replay_goes_on(small_recording, tmp_path, capsys,
                                                           monkeypatch):
    from edge_depth.runtime.engine import Engine

    def broken(self, iters=2):
        raise RuntimeError("the reference failed")

    monkeypatch.setattr(Engine, "stereo_only", broken)
    rec, _ = small_recording
    assert main(["replay", str(rec), "--out", str(tmp_path / "out.mcap")]) == 0
    out = capsys.readouterr().out
    assert "10 frames" in out and "'calibration_watch': 1" in out  # one sample due: counted


def test_a_2d_lidar_observes_yaw_not_pitch_or_roll():
    from edge_depth.calibration_watch import is_planar

    planar = [make_sample(3_000_000 + i, RIG, "planar") for i in range(8)]
    assert is_planar(np.asarray(planar[0].scan.points, np.float64))
    assert not is_planar(np.asarray(make_sample(3_000_000, RIG).scan.points, np.float64))
    right = watched(planar, (0, 0, 0)).estimate()
    assert right.planar and right.level == OK  # no false alarm from the unobserved axes
    assert right.error_deg[0] == right.error_deg[2] == 0.0
    assert "pitch and roll not observed (a 2-D LiDAR)" in right.describe()
    assert right.as_dict()["planar"] is True
    yawed = watched(planar, (0, 0.4, 0)).estimate()
    assert yawed.error_deg[1] == pytest.approx(0.4, abs=0.1)
