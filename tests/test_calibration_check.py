"""`edge-depth calibrate check`: a verdict from every frame of a recording, and an exit status
of its own (CHECK_NO_VERDICT) when it could not reach one, never a pass."""

from __future__ import annotations

import numpy as np

from edge_depth.calibrate import CHECK_ERROR, CHECK_NO_VERDICT
from edge_depth.calibration.extrinsics import _perturb
from edge_depth.calibration.io import save_calibration
from edge_depth.calibration.model import LidarExtrinsics
from edge_depth.cli import main


def _recording_with_its_calibration_yawed(folder, frames: int, yaw_deg: float):
    """A sim recording (192x128) and its own calibration with the LiDAR turned by `yaw_deg`
    about the camera's vertical axis, written beside it."""
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource

    rec = folder / "rec.mcap"
    assert main(["synth", "--mcap", str(rec), "--frames", str(frames), "--seed", "1000000",
                 "--size", "192x128"]) == 0
    stereo, lidar = recording_calibration(McapSource(rec))[:2]
    yawed = folder / "yawed.toml"
    save_calibration(yawed, stereo,
                     LidarExtrinsics(_perturb(lidar.T_cam_lidar, np.r_[0, yaw_deg, 0, 0, 0, 0])))
    return rec, yawed


def test_a_one_degree_yaw_on_sixty_frames_is_an_error_at_the_defaults(tmp_path, capsys):
    rec, yawed = _recording_with_its_calibration_yawed(tmp_path, 60, 1.0)
    capsys.readouterr()
    assert main(["calibrate", "check", str(rec), "--calib", str(yawed)]) == CHECK_ERROR
    out = capsys.readouterr().out
    assert "60 samples from 60 frames (60 with LiDAR)" in out  # every frame sampled offline
    line = next(x for x in out.splitlines() if x.startswith("LiDAR-camera rotation error"))
    assert 0.8 < float(line.split("yaw ")[1].split("°")[0]) < 1.2 and line.endswith("ERROR")
    assert "--refine" in out
    # the daemon's budget over the same frames: 5 samples, no verdict, and it says so
    assert main(["calibrate", "check", str(rec), "--calib", str(yawed),
                 "--every", "13"]) == CHECK_NO_VERDICT
    out = capsys.readouterr().out
    assert "no verdict: too few samples (5 of the 8 needed)" in out
    assert "a smaller --every" in out


def test_a_recording_without_lidar_says_which_topic_it_looked_on(tmp_path, capsys):
    from edge_depth.capture.replay import TopicMap
    from edge_depth.loggers import open_logger
    from edge_depth.mcap_log import RAW_TOPICS
    from edge_depth.sim import RigConfig, make_sample

    rec = tmp_path / "no_lidar.mcap"
    with open_logger(rec, topics=RAW_TOPICS) as logger:
        for i in range(3):
            sample = make_sample(1_000_000 + i, RigConfig(width=96, height=64))
            if i == 0:
                logger.set_calibration(sample.calibration(), LidarExtrinsics(sample.T_cam_lidar))
            logger.log_frame(sample.frame(1_000_000_000 + i * 100_000_000, i))
    assert main(["calibrate", "check", str(rec)]) == CHECK_NO_VERDICT
    out = capsys.readouterr().out
    assert f"no verdict: no LiDAR scan found on {TopicMap().lidar} (3 frames read)" in out
    assert "rotation error" not in out


def test_a_calibration_below_the_engines_size_is_refused_for_its_size(tmp_path, capsys):
    from edge_depth.calibration.io import dumps_calibration
    from edge_depth.calibration.model import StereoCalibration
    from edge_depth.sim.lidar import default_T_cam_lidar

    text = dumps_calibration(StereoCalibration.ideal(450.0, 0.075, (640, 400)),
                             LidarExtrinsics(default_T_cam_lidar()))
    for side in (1, 16):
        calib = tmp_path / f"c{side}.toml"
        calib.write_text(text.replace("image_size = [640, 400]",
                                      f"image_size = [{side}, {side}]"))
        # the calibration is read before the recording, which need not exist
        assert main(["calibrate", "check", str(tmp_path / "rec.mcap"),
                     "--calib", str(calib)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1
        assert f"{calib}: stereo.image_size: expected (width, height) each in 64-16384" \
            in err[0] and err[0].endswith(f"got {side}x{side}")
