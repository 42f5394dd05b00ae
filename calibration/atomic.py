"""Atomic file writes: a temporary file beside the target, then one rename.

Every file this project writes that a crash must not leave half-written (the calibration file,
rendered training pairs, checkpoints) goes through `atomic_write`; readers see the old file or
the new one, never a torn one. Folders (a scene folder, an adapted bundle) are staged and renamed
by their writers the same way.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_write(path: Path | str, suffix: str = ".tmp") -> Iterator[Path]:
    """Yields a temporary path in `path`'s folder to write to (its name ends in `suffix`, for
    writers that go by the extension, e.g. numpy's .npz). On a clean exit the file is flushed
    to disk and renamed over `path`; on an exception it is removed and `path` is untouched."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        # mkstemp's file is private (0600); the result gets the mode a plain open() would
        # give, or the replaced file's own (a daemon user must still read the calibration)
        os.chmod(tmp, stat.S_IMODE(path.stat().st_mode) if path.exists() else _new_file_mode())
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _new_file_mode() -> int:
    """0666 less the process's umask (read without changing it, unlike os.umask)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except OSError:
        pass
    return 0o644
