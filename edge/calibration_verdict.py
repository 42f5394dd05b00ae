"""The calibration watch's verdict: its estimate (`WatchEstimate`), the level that estimate
earns, and what to do about it (`edge.calibration_watch` makes the estimate).

A rotation moves every projected point by about f · angle pixels whatever its depth (about the
optical axis: the points' distance from the image centre · angle), a clock error by the
image's speed × the error, so the level is in pixels: ERROR when the errors, less twice their
uncertainty, move the points by more than ERROR_PX; WARN beyond WARN_PX once the resolution
(what the estimate reads with the right calibration on the sim robot's scenes) is allowed too
— twice the uncertainty and the resolution are independent errors, added in quadrature
(`warn_margin`). The fixes are commands for the user: nothing here changes a calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AXES = ("pitch", "yaw", "roll")
MIN_SAMPLES = 8  # before these, the estimate is "settling"
WARN_PX, ERROR_PX = 0.1, 1.0
# what the estimate reads with the right calibration on the sim robot's scenes, per axis
# (pitch, yaw, roll): yaw and pitch up to 0.07°, roll up to 0.32° (its lever, the points'
# distance from the image centre, is short and the rig's edges seldom constrain it)
RESOLUTION_DEG = np.array([0.1, 0.1, 0.35])
CLOCK_RESOLUTION_S = 0.01
OK, WARN, ERROR, SETTLING = "OK", "WARN", "ERROR", "SETTLING"


@dataclass(frozen=True)
class WatchEstimate:
    """The calibration's rotation error (degrees: pitch, yaw, roll) and its standard error;
    the LiDAR–camera clock offset's error (seconds to add to the points' stamps; None while the
    camera has not turned enough to observe it) and its; the pixels they move the points by
    beyond twice their uncertainty, the level and the samples it stands on. `at_reach`: an
    axis at the probes' edge (the error is at least that)."""

    error_deg: tuple[float, float, float]
    sigma_deg: tuple[float, float, float]
    shift_px: float
    level: str
    samples: int
    at_reach: bool = False
    clock_s: float | None = None
    clock_sigma_s: float | None = None
    turn_dps: float = 0.0  # the samples' RMS turn rate
    planar: bool = False  # a 2-D LiDAR: pitch and roll not observed (reported as 0)
    # px the rotation and the clock each move the points by beyond the WARN margin
    rotation_px: float = 0.0
    clock_px: float = 0.0

    def describe(self) -> str:
        """'yaw +0.31° ± 0.02°, pitch −0.01° ± 0.02°, roll +0.05° ± 0.06°, clock −30 ms ± 4 ms
        (2.4 px): ERROR'."""
        if self.level == SETTLING:
            return f"settling ({self.samples} of {MIN_SAMPLES} samples, each of a view of its own)"
        parts = [f"{name} {self.error_deg[AXES.index(name)]:+.2f}° ± "
                 f"{self.sigma_deg[AXES.index(name)]:.2f}°" for name in ("yaw", "pitch", "roll")
                 if not (self.planar and name != "yaw")]
        if self.planar:
            parts.append("pitch and roll not observed (a 2-D LiDAR)")
        if self.clock_s is not None and self.clock_sigma_s is not None:
            parts.append(f"clock {self.clock_s * 1000:+.0f} ms ± "
                         f"{self.clock_sigma_s * 1000:.0f} ms")
        else:
            parts.append(f"clock not observed (turning {self.turn_dps:.1f}°/s)")
        reach = ", at least that: beyond the probes" if self.at_reach else ""
        return f"{', '.join(parts)} ({self.shift_px:.2f} px{reach}): {self.level}"

    def as_dict(self) -> dict:
        clock = None if self.clock_s is None else round(self.clock_s * 1000, 1)
        sigma = None if self.clock_sigma_s is None else round(self.clock_sigma_s * 1000, 1)
        return dict(level=self.level, samples=self.samples, shift_px=round(self.shift_px, 3),
                    at_reach=self.at_reach,
                    **{f"{axis}_deg": round(self.error_deg[i], 3) for i, axis in enumerate(AXES)},
                    **{f"{axis}_sigma_deg": round(self.sigma_deg[i], 3)
                       for i, axis in enumerate(AXES)},
                    clock_offset_ms=clock, clock_sigma_ms=sigma,
                    turn_dps=round(self.turn_dps, 2), planar=self.planar)


def warn_margin(sigma, resolution):
    """How far an estimate may read from zero before it says anything beyond 0.1 px: twice its
    uncertainty and its resolution (what it reads with the right calibration), independent
    errors, added in quadrature."""
    return np.hypot(2 * np.asarray(sigma), resolution)


def beyond_px(error: np.ndarray, margin: np.ndarray, lever_px: np.ndarray) -> np.ndarray:
    """Per term, the px the points move by beyond `margin` (the error's own units)."""
    return np.maximum(np.abs(error) - margin, 0.0) * lever_px


def verdict(error: np.ndarray, sigma: np.ndarray, lever_px: np.ndarray,
            resolution: np.ndarray = RESOLUTION_DEG) -> tuple[float, str]:
    """(px the points move by beyond twice the standard error, the level): ERROR beyond
    ERROR_PX, WARN beyond WARN_PX once `resolution` more is allowed (`warn_margin`), else OK.
    Per term (the rotation's axes in degrees, the clock offset in seconds): `lever_px`, px per
    unit (f·π/180 for pitch and yaw, the points' distance from the image centre·π/180 for
    roll, the image's speed in px/s for the clock)."""
    shift = float(np.hypot.reduce(beyond_px(error, 2 * sigma, lever_px)))
    if shift > ERROR_PX:
        return shift, ERROR
    warn = np.hypot.reduce(beyond_px(error, warn_margin(sigma, resolution), lever_px))
    return shift, WARN if warn > WARN_PX else OK


def fixes(estimate: WatchEstimate, recording: str | None, calibration: str | None,
          time_offset_ns: int = 0) -> str:
    """What to do about a WARN or ERROR (empty otherwise): the rotation's refine command, and
    the clock offset's value to set — each that alone moves the points beyond WARN_PX, or
    both where neither does alone."""
    if estimate.level not in (WARN, ERROR):
        return ""
    todo = []
    alone = [px > WARN_PX for px in (estimate.rotation_px, estimate.clock_px)]
    rotation, clock = alone if any(alone) else [px > 0 for px in (estimate.rotation_px,
                                                                   estimate.clock_px)]
    if rotation:
        todo.append(f"to refine the rotation: {refine_command(recording, calibration)}")
    if clock and estimate.clock_s is not None:
        value = int(round(time_offset_ns + estimate.clock_s * 1e9, -6))
        todo.append(f"the LiDAR's clock: set [lidar] time_offset_ns = {value} in "
                    f"{calibration or 'the calibration'}")
    return "; ".join(todo) or f"to refine it: {refine_command(recording, calibration)}"


def refine_command(recording: str | None, calibration: str | None) -> str:
    """The command that fixes it, pre-filled where the paths are known (without a calibration
    file, the recording's own is refined)."""
    command = f"edge-depth calibrate lidar --recording {recording or 'REC.mcap'} --refine"
    if calibration:
        stem = calibration[:-5] if calibration.endswith(".toml") else calibration
        return f"{command} --calib {calibration} --out {stem}_refined.toml"
    return f"{command} --out refined.toml"
