"""The calibration file (TOML): load with validation, save atomically.

    [stereo]
    image_size = [640, 400]            # width, height in pixels, each 64-16384
    [stereo.left]
    K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    dist = [k1, k2, p1, p2, k3]        # OpenCV order
    [stereo.right]
    K = ...
    dist = ...
    [stereo.extrinsics]
    R = [[...], [...], [...]]          # right camera from left camera
    T = [tx, ty, tz]                   # metres, right camera from left camera
    [lidar]                            # optional
    T_cam_lidar = [[...] x 4]          # left camera from LiDAR, metres
    time_offset_ns = 0                 # added to LiDAR stamps
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edge_depth.calibration.atomic import atomic_write
from edge_depth.calibration.errors import CalibrationError, CalibrationFileError
from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
from edge_depth.calibration.tomlfile import TomlReadError, parse_toml, read_toml

_SCHEMA: dict[str, set[str]] = {
    "": {"stereo", "lidar"},
    "stereo": {"image_size", "left", "right", "extrinsics"},
    "stereo.left": {"K", "dist"},
    "stereo.right": {"K", "dist"},
    "stereo.extrinsics": {"R", "T"},
    "lidar": {"T_cam_lidar", "time_offset_ns"},
}
_OPTIONAL = {"lidar", "lidar.time_offset_ns"}


def _check_keys(path: str, table: dict, prefix: str) -> None:
    expected = _SCHEMA[prefix]
    for key in sorted(set(table) - expected):
        full = f"{prefix}.{key}" if prefix else key
        raise CalibrationFileError(f"unexpected key (allowed: {', '.join(sorted(expected))})",
                                   path, full)
    for key in sorted(expected - set(table)):
        full = f"{prefix}.{key}" if prefix else key
        if full not in _OPTIONAL:
            raise CalibrationFileError("missing key", path, full)
    for key, value in table.items():
        full = f"{prefix}.{key}" if prefix else key
        if full in _SCHEMA:
            if not isinstance(value, dict):
                raise CalibrationFileError("expected a table", path, full)
            _check_keys(path, value, full)


def _numeric(path: str, key: str, value):
    try:
        return np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise CalibrationFileError("expected numbers in a (nested) list", path, key) from None


def load_calibration(path: str | Path) -> tuple[StereoCalibration, LidarExtrinsics | None]:
    """Read and validate a calibration file. Every problem is a CalibrationFileError that names
    the file, the key and what was expected."""
    path = str(path)
    try:
        data = read_toml(path)
    except FileNotFoundError:
        raise CalibrationFileError("file not found", path) from None
    except IsADirectoryError:
        raise CalibrationFileError("a directory, not a calibration file", path) from None
    except TomlReadError as exc:
        raise CalibrationFileError(str(exc), path) from None
    return calibration_from_toml(data, path)


MAX_TIME_OFFSET_NS = 3600 * 10**9  # an hour: beyond it the clocks are not the same kind


def _time_offset(path: str, value) -> int:
    """An integer of nanoseconds within ±1 h (TOML gives int, float, str, list …)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or value != value or abs(value) > MAX_TIME_OFFSET_NS or int(value) != value:
        raise CalibrationFileError(f"expected an integer of nanoseconds within "
                                   f"±{MAX_TIME_OFFSET_NS}, got {value!r}", path,
                                   "lidar.time_offset_ns")
    return int(value)


def loads_calibration(text: str, path: str = "<string>"
                      ) -> tuple[StereoCalibration, LidarExtrinsics | None]:
    """`load_calibration` from TOML text; `path` names where it came from in errors."""
    try:
        data = parse_toml(text)
    except TomlReadError as exc:
        raise CalibrationFileError(str(exc), path) from None
    return calibration_from_toml(data, path)


def calibration_from_toml(data: dict, path: str
                          ) -> tuple[StereoCalibration, LidarExtrinsics | None]:
    """The validated calibration from a parsed file's tables."""
    _check_keys(path, data, "")
    s = data["stereo"]
    size = s["image_size"]
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) for v in size)):
        raise CalibrationFileError(f"expected [width, height] integers, got {size!r}", path,
                                   "stereo.image_size")
    try:
        stereo = StereoCalibration(
            K_left=_numeric(path, "stereo.left.K", s["left"]["K"]),
            dist_left=_numeric(path, "stereo.left.dist", s["left"]["dist"]).ravel(),
            K_right=_numeric(path, "stereo.right.K", s["right"]["K"]),
            dist_right=_numeric(path, "stereo.right.dist", s["right"]["dist"]).ravel(),
            R=_numeric(path, "stereo.extrinsics.R", s["extrinsics"]["R"]),
            T=_numeric(path, "stereo.extrinsics.T", s["extrinsics"]["T"]),
            image_size=(size[0], size[1]))
        lidar = None
        if "lidar" in data:
            lid = data["lidar"]
            lidar = LidarExtrinsics(_numeric(path, "lidar.T_cam_lidar", lid["T_cam_lidar"]),
                                    _time_offset(path, lid.get("time_offset_ns", 0)))
    except CalibrationFileError:
        raise
    except CalibrationError as exc:
        key = exc.key if exc.key and exc.key.startswith("lidar") else f"stereo.{exc.key}"
        message = str(exc).split(": ", 1)[-1]
        raise CalibrationFileError(message, path, key) from None
    return stereo, lidar


def _fmt(value) -> str:
    arr = np.asarray(value)
    if arr.ndim == 0:
        return repr(float(arr))
    return "[" + ", ".join(_fmt(v) for v in arr) + "]"


def dumps_calibration(stereo: StereoCalibration, lidar: LidarExtrinsics | None = None) -> str:
    lines = ["# edge-depth calibration (see calibration/io.py for the format)", "[stereo]",
             f"image_size = [{stereo.image_size[0]}, {stereo.image_size[1]}]", "",
             "[stereo.left]", f"K = {_fmt(stereo.K_left)}", f"dist = {_fmt(stereo.dist_left)}",
             "", "[stereo.right]", f"K = {_fmt(stereo.K_right)}",
             f"dist = {_fmt(stereo.dist_right)}", "", "[stereo.extrinsics]",
             f"R = {_fmt(stereo.R)}", f"T = {_fmt(stereo.T)}", ""]
    if lidar is not None:
        lines += ["[lidar]", f"T_cam_lidar = {_fmt(lidar.T_cam_lidar)}",
                  f"time_offset_ns = {lidar.time_offset_ns}", ""]
    return "\n".join(lines)


def save_calibration(path: str | Path, stereo: StereoCalibration,
                     lidar: LidarExtrinsics | None = None) -> None:
    """Write atomically: a temporary file in the same folder, then rename over `path`."""
    text = dumps_calibration(stereo, lidar)
    with atomic_write(path) as tmp:
        tmp.write_text(text)
