"""Stereo calibration recovers a known rig from rendered board views."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge_depth.calibration.io import load_calibration
from edge_depth.calibration.stereo import Board, calibrate_stereo
from edge_depth.cli import main
from edge_depth.sim.board import random_stereo_views

K_L = np.array([[450.0, 0, 322.0], [0, 450.0, 198.0], [0, 0, 1]])
D_L = np.array([-0.08, 0.02, 0.0, 0.0, 0.0])
K_R = np.array([[448.0, 0, 318.0], [0, 448.5, 202.0], [0, 0, 1]])
D_R = np.array([-0.07, 0.015, 0.0, 0.0, 0.0])
R_TRUE, _ = cv2.Rodrigues(np.array([0.004, -0.01, 0.003]))
T_TRUE = np.array([-0.075, 0.0008, 0.0004])
BOARD = Board.parse("checkerboard:9x6", 0.025)


@pytest.fixture(scope="module")
def views():
    return random_stereo_views(BOARD, K_L, D_L, K_R, D_R, R_TRUE, T_TRUE, (640, 400), 12, seed=1)


def test_calibration_recovers_focal_baseline_and_rectifies_rows(views):
    calib, report = calibrate_stereo(*views, BOARD)
    assert abs(calib.K_left[0, 0] / 450.0 - 1) < 0.005
    assert abs(calib.K_right[1, 1] / 448.5 - 1) < 0.005
    assert abs(np.linalg.norm(calib.T) / np.linalg.norm(T_TRUE) - 1) < 0.01
    assert report.rms_stereo < 0.3 and report.rms_left < 0.3 and report.rms_right < 0.3
    assert report.rectified_row_error_px < 0.2
    assert len(report.per_view_error) == 12 and report.skipped_views == []
    # and the rectified images agree: a corner's row is the same in both rectified views
    rect_l, rect_r = calib.rectifier().rectify(views[0][0], views[1][0])
    found_l, cl = cv2.findChessboardCorners(rect_l, (9, 6))
    found_r, cr = cv2.findChessboardCorners(rect_r, (9, 6))
    assert found_l and found_r
    assert np.abs(cl.reshape(-1, 2)[:, 1] - cr.reshape(-1, 2)[:, 1]).mean() < 0.5


def test_views_without_a_board_are_listed_and_too_few_pairs_is_an_error(views):
    from edge_depth.calibration.errors import CalibrationFailedError

    blank = np.full((400, 640), 90, np.uint8)
    left = list(views[0][:7]) + [blank]
    right = list(views[1][:7]) + [views[1][7]]
    with pytest.raises(CalibrationFailedError, match="only 7 pairs"):
        calibrate_stereo(left, right, BOARD)
    _, report = calibrate_stereo(list(views[0]) + [blank], list(views[1]) + [blank], BOARD)
    assert report.skipped_views == ["view 12"]
    with pytest.raises(CalibrationFailedError, match="differ in size"):
        calibrate_stereo(list(views[0][:8]), [cv2.resize(v, (320, 200)) for v in views[1][:8]],
                         BOARD)
    with pytest.raises(CalibrationFailedError, match="12 left views but 11"):
        calibrate_stereo(list(views[0]), list(views[1][:11]), BOARD)


def test_calibrate_stereo_command_writes_a_loadable_file(views, tmp_path, capsys):
    for i, (l, r) in enumerate(zip(*views, strict=True)):
        cv2.imwrite(str(tmp_path / f"left{i:02d}.png"), l)
        cv2.imwrite(str(tmp_path / f"right{i:02d}.png"), r)
    out = tmp_path / "calib.toml"
    rc = main(["calibrate", "stereo", "--left", str(tmp_path / "left*.png"), "--right",
               str(tmp_path / "right*.png"), "--board", "checkerboard:9x6", "--square-m",
               "0.025", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "RMS reprojection error" in text and "baseline 74.9" in text
    stereo, _ = load_calibration(out)
    assert abs(stereo.baseline_m - 0.075) < 0.00075


def test_calibrate_stereo_command_fails_cleanly_and_writes_nothing(views, tmp_path, capsys):
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"left{i}.png"), views[0][i])
        cv2.imwrite(str(tmp_path / f"right{i}.png"), views[1][i])
    out = tmp_path / "calib.toml"
    rc = main(["calibrate", "stereo", "--left", str(tmp_path / "left*.png"), "--right",
               str(tmp_path / "right*.png"), "--board", "checkerboard:9x6", "--square-m",
               "0.025", "--out", str(out)])
    assert rc == 1 and not out.exists()
    assert "need at least 8" in capsys.readouterr().err
    rc = main(["calibrate", "stereo", "--left", str(tmp_path / "left*.png"), "--right",
               str(tmp_path / "right*.png"), "--board", "chess:9", "--square-m", "0.025",
               "--out", str(out)])
    assert rc == 1 and not out.exists()


def test_charuco_views_calibrate_to_the_right_baseline():
    board = Board.parse("charuco:8x6", 0.03)
    left, right = random_stereo_views(board, K_L, D_L, K_R, D_R, R_TRUE, T_TRUE, (640, 400), 10,
                                      seed=2)
    calib, report = calibrate_stereo(left, right, board)
    assert len(report.used_views) >= 8
    assert abs(np.linalg.norm(calib.T) / 0.075 - 1) < 0.01
    # fewer corners per view than a checkerboard: focal within 1.5 % (measured 0.9 / 0.7 %)
    assert abs(calib.K_left[0, 0] / 450.0 - 1) < 0.015
    assert abs(calib.K_right[1, 1] / 448.5 - 1) < 0.015
    assert report.rms_stereo < 0.3
