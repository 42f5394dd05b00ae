"""OAK factory calibration and ROS camera_info imports."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.calibration.errors import CalibrationFileError
from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.ros import load_camera_info_pair, save_camera_info_pair
from edge_depth.cli import main


def _eeprom_json(path, translation_cm=(-7.42, 0.03, 0.01), spec_cm=(-7.5, 0.0, 0.0)):
    import depthai as dai

    S = dai.CameraBoardSocket
    h = dai.CalibrationHandler()
    h.setCameraIntrinsics(S.CAM_B, [[800.0, 0, 640], [0, 800, 400], [0, 0, 1]], 1280, 800)
    h.setCameraIntrinsics(S.CAM_C, [[802.0, 0, 636], [0, 801, 404], [0, 0, 1]], 1280, 800)
    h.setDistortionCoefficients(S.CAM_B, [-0.1, 0.02, 0, 0, 0] + [0.0] * 9)
    h.setDistortionCoefficients(S.CAM_C, [-0.09, 0.01, 0, 0, 0] + [0.0] * 9)
    h.setCameraExtrinsics(S.CAM_B, S.CAM_C, np.eye(3).tolist(), list(translation_cm),
                          list(spec_cm))
    h.setStereoLeft(S.CAM_B, np.eye(3).tolist())
    h.setStereoRight(S.CAM_C, np.eye(3).tolist())
    h.eepromToJsonFile(str(path))


def test_oak_import_scales_intrinsics_and_converts_centimetres(tmp_path):
    from edge_depth.calibration.oak import stereo_from_oak

    _eeprom_json(tmp_path / "eeprom.json")
    stereo = stereo_from_oak(tmp_path / "eeprom.json", (640, 400))
    np.testing.assert_allclose(stereo.K_left[0, 0], 400.0)  # 1280 -> 640 halves f
    np.testing.assert_allclose(stereo.K_right[1, 2], 202.0)
    # the calibrated translation (7.42 cm), not the board spec (7.5 cm), in metres
    np.testing.assert_allclose(stereo.T, [-0.0742, 0.0003, 0.0001], atol=1e-7)
    assert stereo.dist_left[0] == pytest.approx(-0.1)


def test_import_oak_command_writes_a_calibration(tmp_path, capsys):
    from edge_depth.calibration.io import load_calibration

    _eeprom_json(tmp_path / "eeprom.json")
    out = tmp_path / "calib.toml"
    assert main(["calibrate", "import-oak", "--eeprom-json", str(tmp_path / "eeprom.json"),
                 "--out", str(out)]) == 0
    stereo, _ = load_calibration(out)
    assert stereo.baseline_m == pytest.approx(0.0742, abs=2e-4)
    assert main(["calibrate", "import-oak", "--eeprom-json", str(tmp_path / "none.json"),
                 "--out", str(tmp_path / "x.toml")]) == 1
    assert "file not found" in capsys.readouterr().err


def test_ros_camera_info_round_trip(tmp_path):
    import cv2

    R, _ = cv2.Rodrigues(np.array([0.003, -0.008, 0.002]))
    K1 = np.array([[452.0, 0, 322.0], [0, 451.0, 198.0], [0, 0, 1]])
    K2 = np.array([[449.0, 0, 317.0], [0, 450.5, 203.0], [0, 0, 1]])
    stereo = StereoCalibration(K1, [-0.1, 0.02, 0.001, -0.001, 0.0], K2,
                               [-0.09, 0.015, 0, 0, 0], R, [-0.075, 0.001, 0.002], (640, 400))
    left, right = save_camera_info_pair(stereo, tmp_path)
    back = load_camera_info_pair(left, right)
    np.testing.assert_allclose(back.K_left, K1)
    np.testing.assert_allclose(back.R, R, atol=1e-9)
    np.testing.assert_allclose(back.T, stereo.T, atol=1e-9)
    assert back.focal_px == pytest.approx(stereo.focal_px)


def test_ros_yaml_defects_are_named(tmp_path):
    stereo = StereoCalibration.ideal(450, 0.075, (640, 400))
    left, right = save_camera_info_pair(stereo, tmp_path)
    right.write_text(right.read_text().replace("projection_matrix", "projection"))
    with pytest.raises(CalibrationFileError, match="projection_matrix.data"):
        load_camera_info_pair(left, right)
    right.write_text("[unclosed")
    with pytest.raises(CalibrationFileError, match="not valid YAML"):
        load_camera_info_pair(left, right)
