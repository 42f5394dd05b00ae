"""How much free space a log keeps so that its file can always be closed readable.

A frame is logged only while the disk has room for it, the chunk the writer holds in memory
and the file's summary on top of a floor. The frame's size is measured — the log file's
growth from one frame's start to the next, the largest seen (other writers on the disk do
not inflate it; the chunk held in memory is counted apart) — not fixed: a raw 640x400 frame
with every topic is ~5 MB, more than a fixed reserve on a small disk held (a 16 MiB disk kept
2 MiB and the writer failed mid-chunk). Before the first frame is measured, its size is
bounded from its pixel count (every topic uncompressed).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

# the most a frame can write a pixel, uncompressed: the mono pair (2 B), the sparse disparity,
# disparity, depth and confidence (4 x 4 B) and the depth's point (x y z intensity, 16 B)
FRAME_BYTES_PER_PIXEL = 34
SUMMARY_BASE_BYTES = 64 << 10  # schemas, channels, statistics, metadata
SUMMARY_BYTES_PER_CHUNK = 512  # a chunk index and its message index offsets


@dataclass
class DiskReserve:
    """`floor_bytes`: free space always kept (capped at an eighth of a small disk);
    `chunk_bytes`: the writer's chunk size (a chunk is held in memory until it is full)."""

    floor_bytes: int
    chunk_bytes: int
    largest_frame_bytes: int = 0  # measured; 0 until two frame starts have been seen
    _file_bytes_at_last_frame: int | None = None

    def needed(self, file_bytes: int, frame_pixels: int) -> int:
        """Bytes one more frame and the file's close take: the largest frame (or its bound
        before one is measured), the chunk in memory and the one it would start, and the
        summary of a file of `file_bytes`."""
        frame = self.largest_frame_bytes or frame_pixels * FRAME_BYTES_PER_PIXEL
        chunks = file_bytes // max(self.chunk_bytes, 1) + 2
        return frame + 2 * self.chunk_bytes + SUMMARY_BASE_BYTES + chunks * SUMMARY_BYTES_PER_CHUNK

    def below(self, folder: Path, file_bytes: int, frame_pixels: int,
              measure: bool = True) -> str | None:
        """At a frame's start: why the frame must not be logged (the free space below the
        reserve), or None. `file_bytes`: the log file's size now (`measure`: how much the
        last frame added to it is measured here; a new, smaller file starts the measure
        anew; off for a check between frames)."""
        if measure:
            last, self._file_bytes_at_last_frame = self._file_bytes_at_last_frame, file_bytes
            if last is not None and file_bytes > last:
                self.largest_frame_bytes = max(self.largest_frame_bytes, file_bytes - last)
        try:
            usage = shutil.disk_usage(folder)
        except OSError:
            return None  # nothing to go by: the writer's own errors still close the file
        reserve = max(min(self.floor_bytes, usage.total // 8),
                      self.needed(file_bytes, frame_pixels))
        if usage.free >= reserve:
            return None
        return (f"the disk holding {folder} is full ({usage.free / 2**20:.0f} MB free, below "
                f"{reserve / 2**20:.0f} MB)")
