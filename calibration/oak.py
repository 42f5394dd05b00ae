"""Import an OAK's factory calibration (depthai `CalibrationHandler`) as a StereoCalibration.

depthai reports translations in centimetres; we ask for metres' worth by converting, and for
the calibrated translation (useSpecTranslation=False), not the board's design value. Intrinsics
are requested at the output size, so depthai scales them from the calibration resolution.
This module is the only one in `calibration/` that imports depthai.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.model import StereoCalibration


def stereo_from_handler(handler, size: tuple[int, int]) -> StereoCalibration:
    """Left/right stereo cameras of a CalibrationHandler (CAM_B/CAM_C unless the handler names
    others), intrinsics scaled to `size` (width, height)."""
    import depthai as dai

    sockets = dai.CameraBoardSocket
    try:
        left = handler.getStereoLeftCameraId()
        right = handler.getStereoRightCameraId()
    except RuntimeError:
        left, right = sockets.CAM_B, sockets.CAM_C
    if left == right or left not in (sockets.CAM_A, sockets.CAM_B, sockets.CAM_C, sockets.CAM_D):
        left, right = sockets.CAM_B, sockets.CAM_C
    w, h = size
    try:
        K = [np.array(handler.getCameraIntrinsics(cam, w, h), np.float64) for cam in (left, right)]
        dist = [np.array(handler.getDistortionCoefficients(cam), np.float64)
                for cam in (left, right)]
        models = [handler.getDistortionModel(cam) for cam in (left, right)]
        extr = np.array(handler.getCameraExtrinsics(left, right, False), np.float64)
    except RuntimeError as exc:
        raise CalibrationError(f"the OAK calibration lacks stereo data: {exc}") from None
    for cam, model in zip((left, right), models, strict=True):
        if model != dai.CameraModel.Perspective:
            raise CalibrationError(f"{cam}: distortion model {model} is not supported "
                                   f"(only Perspective)")
    dist = [d if d.size in (4, 5, 8, 12, 14) else np.resize(d, 14) for d in dist]
    R = extr[:3, :3]
    T = extr[:3, 3] / 100.0  # depthai: centimetres
    return StereoCalibration(K[0], dist[0], K[1], dist[1], R, T, (w, h))


def stereo_from_oak(eeprom_json: Path | None, size: tuple[int, int]) -> StereoCalibration:
    """From a CalibrationHandler JSON dump, or from the first connected device if None."""
    import depthai as dai

    if eeprom_json is not None:
        if not Path(eeprom_json).exists():
            raise CalibrationError("file not found", path=str(eeprom_json))
        try:
            handler = dai.CalibrationHandler(str(eeprom_json))  # type: ignore[call-overload]
        except RuntimeError as exc:
            raise CalibrationError(f"not a depthai calibration: {exc}",
                                   path=str(eeprom_json)) from None
        return stereo_from_handler(handler, size)
    try:
        with dai.Device() as device:
            return stereo_from_handler(device.readCalibration(), size)
    except RuntimeError as exc:
        raise CalibrationError(f"no OAK device could be opened: {exc}") from None
