"""A disk that fills never costs a readable file: the logger keeps room for its largest frame
and the summary, and a writer cut off all the same leaves a file the official reader takes."""

from __future__ import annotations

import re
import subprocess
import sys
from collections import namedtuple
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

import edge_depth.disk_reserve as disk_reserve
from edge_depth.capture.mcap_tolerant import end_cut_file
from edge_depth.mcap_log import TOPICS, McapLogger
from edge_depth.types import StereoFrame

ROOT = Path(__file__).resolve().parents[1]
Usage = namedtuple("Usage", "total used free")


def noise_frame(i: int, size=(400, 640)) -> StereoFrame:
    """A frame of incompressible images (each view 256 kB at 640x400)."""
    rng = np.random.default_rng(i)
    left, right = (rng.integers(0, 256, size, dtype=np.uint8) for _ in range(2))
    return StereoFrame(1_000_000_000 + i * 50_000_000, i, left, right, rectified=True)


def frames_per_file(path: Path) -> int:
    """The official reader's count of left images, summary or not."""
    with open(path, "rb") as f:
        return sum(1 for _, channel, _ in make_reader(f).iter_messages()
                   if channel.topic == TOPICS["left"])


def small_disk(monkeypatch, folder: Path, total: int) -> None:
    """The free space of a `total`-byte disk that holds only `folder`'s files."""
    def disk_usage(_path):
        used = sum(p.stat().st_size for p in folder.iterdir())
        return Usage(total, used, max(total - used, 0))

    monkeypatch.setattr(disk_reserve.shutil, "disk_usage", disk_usage)


def test_a_small_disk_keeps_room_for_its_largest_frame_and_closes_readable(tmp_path,
                                                                           monkeypatch):
    disk = tmp_path / "disk"
    disk.mkdir()
    total = 16 << 20  # an eighth of it (2 MiB) is smaller than a frame and the writer's chunk
    small_disk(monkeypatch, disk, total)
    logger = McapLogger(disk / "depth.mcap", compression="none", rotate_bytes=3 << 20)
    written = 0
    for i in range(80):
        logger.log_frame(noise_frame(i))
        written += logger.stopped is None
    logger.close()
    assert logger.stopped is not None and "is full" in logger.stopped
    assert 0 < written < 80
    assert sum(p.stat().st_size for p in disk.iterdir()) <= total  # the summaries fitted
    # every part: a summary, read back by the official reader, no part without a frame
    counts = [frames_per_file(p) for p in logger.files]
    for path in logger.files:
        with open(path, "rb") as f:
            assert make_reader(f).get_summary() is not None
    assert min(counts) >= 1 and sum(counts) == written
    said = re.search(r"with its summary \((\d+) frames\)", logger.stopped)
    assert said is not None and int(said.group(1)) == counts[-1]
    assert logger.reserve.largest_frame_bytes >= 2 * 640 * 400  # measured, not the bound


CUT_OFF = """
import resource, signal, sys
import numpy as np
from edge_depth.mcap_log import McapLogger
from tests.test_disk_full import noise_frame
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails as on a full disk
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), int(sys.argv[2])))
with McapLogger(sys.argv[1], compression="none", chunk_size=200_000) as logger:
    for i in range(12):
        logger.log_frame(noise_frame(i, (200, 320)))
"""


def test_a_writer_cut_off_mid_chunk_leaves_every_complete_chunk_readable(tmp_path):
    out = tmp_path / "cut.mcap"
    proc = subprocess.run([sys.executable, "-c", CUT_OFF, str(out), str(900_000)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    said = re.search(r"ended it after its last complete chunk, without a summary; (\d+) of its "
                     r"12 frames are readable", proc.stderr)
    assert said is not None, proc.stderr
    assert "with its summary" not in proc.stderr  # says only what happened
    kept = int(said.group(1))
    assert 3 <= kept < 12  # 900 kB hold a few 128 kB frames
    assert frames_per_file(out) == kept  # the official reader finds every frame it says


def test_ending_a_cut_file_keeps_its_complete_chunks_and_drops_the_partial_one(tmp_path):
    path = tmp_path / "depth.mcap"
    with McapLogger(path, compression="lz4", chunk_size=100_000) as logger:
        for i in range(6):
            logger.log_frame(noise_frame(i, (200, 320)))
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    third = sorted(c.chunk_start_offset for c in summary.chunk_indexes)[2]
    path.write_bytes(data[:third + 50])  # cut inside the third chunk
    assert end_cut_file(path) == third
    with open(path, "rb") as f:
        kept = [m.log_time for _, c, m in make_reader(f).iter_messages()
                if c.topic == TOPICS["left"]]
    assert kept == left_stamps_in_chunks(data, 2)


def left_stamps_in_chunks(data: bytes, count: int) -> list[int]:
    """The left images' stamps in the first `count` chunks of an intact file."""
    import io

    from mcap.records import Channel, Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    chunks = [r for r in StreamReader(io.BytesIO(data), emit_chunks=True).records
              if isinstance(r, Chunk)][:count]
    records = [r for chunk in chunks for r in breakup_chunk(chunk)]
    left = {r.id for r in records if isinstance(r, Channel) and r.topic == TOPICS["left"]}
    return [r.log_time for r in records if isinstance(r, Message) and r.channel_id in left]


def test_scans_while_no_frame_comes_stop_the_log_before_the_disk_fills(tmp_path, monkeypatch):
    import edge_depth.mcap_log as mcap_log
    from edge_depth.types import LidarScan

    disk = tmp_path / "disk"
    disk.mkdir()
    total = 16 << 20
    small_disk(monkeypatch, disk, total)
    clock = iter(range(10_000))  # each scan's check a second after the last
    monkeypatch.setattr(mcap_log.time, "monotonic", lambda: float(next(clock)))
    logger = McapLogger(disk / "depth.mcap", compression="none")
    logger.log_frame(noise_frame(0, (96, 160)))
    points = np.random.default_rng(1).random((40_000, 3)).astype(np.float32)  # 640 kB a scan
    for i in range(60):  # a camera away, a LiDAR still sending: 38 MB if all were written
        logger.log_scan(LidarScan(2_000_000_000 + i * 100_000_000, points))
    logger.close()
    assert logger.stopped is not None and "is full" in logger.stopped
    assert sum(p.stat().st_size for p in disk.iterdir()) <= total
    with open(logger.files[-1], "rb") as f:
        assert make_reader(f).get_summary() is not None


RAISING = """
import resource, signal, sys
from edge_depth.loggers import open_logger
from tests.test_disk_full import noise_frame
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), int(sys.argv[2])))
with open_logger(sys.argv[1], "ros2", compression="none", chunk_size=200_000) as logger:
    for i in range(12):
        logger.log_frame(noise_frame(i, (200, 320)))
print("stopped:", logger.stopped)
"""


def test_a_writer_that_raises_stops_the_log_and_leaves_its_complete_chunks(tmp_path):
    out = tmp_path / "ros2.mcap"
    proc = subprocess.run([sys.executable, "-c", RAISING, str(out), str(900_000)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert f"stopped: writing {out} failed" in proc.stdout  # said, and no later writes
    said = re.search(r"(\d+) of its \d+ frames are readable", proc.stdout)
    assert said is not None, proc.stdout
    with open(out, "rb") as f:
        stamps = {m.log_time for _, c, m in make_reader(f).iter_messages()
                  if c.topic.endswith("left/image_rect")}
    assert len(stamps) == int(said.group(1)) >= 2
