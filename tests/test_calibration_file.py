"""The calibration file: round trip, and every defect named by file and key."""

from __future__ import annotations

import re

import numpy as np
import pytest

from edge_depth.calibration.errors import CalibrationFileError
from edge_depth.calibration.io import dumps_calibration, load_calibration, save_calibration
from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
from edge_depth.sim.lidar import default_T_cam_lidar


def _calib() -> StereoCalibration:
    K1 = np.array([[452.0, 0, 322.0], [0, 451.0, 198.0], [0, 0, 1]])
    K2 = np.array([[449.0, 0, 317.0], [0, 450.5, 203.0], [0, 0, 1]])
    rvec = np.array([0.01, -0.02, 0.005])
    import cv2

    R, _ = cv2.Rodrigues(rvec)
    return StereoCalibration(K1, [-0.1, 0.02, 0.001, -0.001, 0.0], K2,
                             [-0.09, 0.015, 0.0, 0.0, 0.0], R, [-0.075, 0.001, 0.002],
                             (640, 400))


def test_round_trip_preserves_every_value(tmp_path):
    stereo, lidar = _calib(), LidarExtrinsics(default_T_cam_lidar(), time_offset_ns=-1500)
    save_calibration(tmp_path / "c.toml", stereo, lidar)
    s2, l2 = load_calibration(tmp_path / "c.toml")
    for name in ("K_left", "dist_left", "K_right", "dist_right", "R", "T"):
        np.testing.assert_array_equal(getattr(s2, name), getattr(stereo, name))
    np.testing.assert_array_equal(l2.T_cam_lidar, lidar.T_cam_lidar)
    assert l2.time_offset_ns == -1500 and s2.image_size == (640, 400)
    assert abs(s2.baseline_m - 0.0750) < 0.001 and s2.focal_px > 0


def test_lidar_section_is_optional(tmp_path):
    save_calibration(tmp_path / "c.toml", _calib())
    assert load_calibration(tmp_path / "c.toml")[1] is None


def _write(tmp_path, text):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


def _good_text():
    return dumps_calibration(_calib(), LidarExtrinsics(default_T_cam_lidar()))


@pytest.mark.parametrize("edit,key,expected", [
    (lambda t: t.replace("[stereo.right]\nK", "[stereo.right]\nKK"), "stereo.right.KK",
     "unexpected key"),
    (lambda t: re.sub(r"\[stereo.left\]\nK = .*\n", "[stereo.left]\n", t), "stereo.left.K",
     "missing key"),
    (lambda t: t.replace("image_size = [640, 400]", "image_size = [640]"), "stereo.image_size",
     "width, height"),
    (lambda t: re.sub(r"\[stereo.left\]\nK = \[\[452.0", "[stereo.left]\nK = [[-452.0", t),
     "stereo.left.K", "positive focal"),
    (lambda t: re.sub(r"T = \[-0.075, [^\]]*\]", "T = [-0.075, 0.0]", t),
     "stereo.extrinsics.T", "shape"),
    (lambda t: re.sub(r"R = \[\[[0-9.e-]+", "R = [[2.0", t), "stereo.extrinsics.R",
     "rotation"),
    (lambda t: t.replace("dist = [-0.1,", "dist = [nan,"), "stereo.left.dist", "finite"),
    (lambda t: t.replace("time_offset_ns = 0", "time_offset_ns = 0\nextra = 1"), "lidar.extra",
     "unexpected key"),
    # absurd but finite values: each refused, naming the key
    (lambda t: re.sub(r"\[stereo.left\]\nK = \[\[452.0", "[stereo.left]\nK = [[1e300", t),
     "stereo.left.K", "image widths"),
    (lambda t: re.sub(r"\[stereo.left\]\nK = \[\[452.0", "[stereo.left]\nK = [[1e-308", t),
     "stereo.left.K", "image widths"),
    (lambda t: re.sub(r"(\[stereo.left\]\nK = \[\[[^,]+, [^,]+, )[^\]]+\]", r"\g<1>1e308]", t),
     "stereo.left.K", "principal point"),
    (lambda t: t.replace("dist = [-0.1,", "dist = [1e300,"), "stereo.left.dist", "within"),
    (lambda t: t.replace("T = [-0.075,", "T = [0.075,"), "stereo.extrinsics.T",
     "left and right are swapped"),
    (lambda t: t.replace("image_size = [640, 400]", "image_size = [2147483648, 400]"),
     "stereo.image_size", "64-16384"),
    # below the engine's 64 px a side: refused for the size, before the rectification's
    # checks (a 1x1 image's would fail for a non-finite P1)
    (lambda t: t.replace("image_size = [640, 400]", "image_size = [1, 1]"),
     "stereo.image_size", "64-16384 px"),
    (lambda t: t.replace("image_size = [640, 400]", "image_size = [640, 16]"),
     "stereo.image_size", "got 640x16"),
    (lambda t: t.replace("time_offset_ns = 0", 'time_offset_ns = "abc"'),
     "lidar.time_offset_ns", "integer of nanoseconds"),
    (lambda t: t.replace("time_offset_ns = 0", "time_offset_ns = nan"),
     "lidar.time_offset_ns", "integer of nanoseconds"),
    (lambda t: t.replace("time_offset_ns = 0", "time_offset_ns = inf"),
     "lidar.time_offset_ns", "integer of nanoseconds"),
    (lambda t: t.replace("time_offset_ns = 0", "time_offset_ns = [1, 2]"),
     "lidar.time_offset_ns", "integer of nanoseconds"),
])
def test_defects_name_the_file_the_key_and_what_was_expected(tmp_path, edit, key, expected):
    text = edit(_good_text())
    assert text != _good_text(), "the edit must change the file"
    path = _write(tmp_path, text)
    with pytest.raises(CalibrationFileError) as exc:
        load_calibration(path)
    message = str(exc.value)
    assert str(path) in message and key in message and expected in message


def test_unparsable_and_missing_files(tmp_path):
    with pytest.raises(CalibrationFileError, match="not valid TOML"):
        load_calibration(_write(tmp_path, "[stereo\nimage_size = "))
    with pytest.raises(CalibrationFileError, match="file not found"):
        load_calibration(tmp_path / "nope.toml")


def test_save_is_atomic_and_leaves_no_temporary_files(tmp_path, monkeypatch):
    path = tmp_path / "c.toml"
    save_calibration(path, _calib())
    before = path.read_text()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr("os.fsync", boom)
    with pytest.raises(OSError):
        save_calibration(path, StereoCalibration.ideal(400, 0.05, (320, 200)))
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["c.toml"]


def test_atomic_write_replaces_whole_or_leaves_the_old_file(tmp_path):
    from edge_depth.calibration.atomic import atomic_write

    target = tmp_path / "calib.toml"
    target.write_text("old")
    with pytest.raises(OSError), atomic_write(target) as tmp:
        tmp.write_text("half")
        raise OSError("disk full")
    assert target.read_text() == "old" and sorted(tmp_path.iterdir()) == [target]
    with atomic_write(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and sorted(tmp_path.iterdir()) == [target]
    # permissions: a new file's are a plain open()'s, a replaced file keeps its own
    fresh = tmp_path / "fresh.toml"
    with atomic_write(fresh) as tmp:
        tmp.write_text("x")
    plain = tmp_path / "plain"
    plain.write_text("x")
    assert fresh.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777
    target.chmod(0o640)
    with atomic_write(target) as tmp:
        tmp.write_text("newer")
    assert target.stat().st_mode & 0o777 == 0o640
