"""Errors of the calibration package: each names the file, the key and what was expected."""

from __future__ import annotations


class CalibrationError(Exception):
    """Base of the calibration package's errors."""

    def __init__(self, message: str, path: str | None = None, key: str | None = None) -> None:
        self.path = path
        self.key = key
        where = ": ".join(p for p in (path, key) if p)
        super().__init__(f"{where}: {message}" if where else message)


class CalibrationFileError(CalibrationError):
    """A calibration file is missing, unparsable or has a bad value."""


class CalibrationFailedError(CalibrationError):
    """A calibration could not be computed from the given views (too few, mismatched...)."""
