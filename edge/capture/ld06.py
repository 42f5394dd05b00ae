"""LDROBOT LD06 / LD19 (230400 baud): a pure packet decoder and revolution assembly.

Packet (47 bytes, little endian): 0x54 header, 0x2C ver_len (12 points), u16 speed (deg/s),
u16 start angle (0.01 deg), 12 x (u16 distance mm, u8 intensity), u16 end angle (0.01 deg),
u16 timestamp (ms, wraps at 30000), u8 CRC-8 (polynomial 0x4D, initial 0, no reflection) over
the first 46 bytes. Angles of the 12 points are interpolated from start to end, across 360.

On a bad CRC the decoder resumes at the byte after the header it tried, not after the whole
47 bytes, so a real packet that starts inside a corrupt one is still found.

The sensor turns clockwise seen from above, angle 0 at its front: in the LiDAR frame (x
forward, y left, z up) a return at angle a and range r is (r cos a, -r sin a, 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from edge_depth.types import LidarScan

HEADER, VER_LEN = 0x54, 0x2C
PACKET_SIZE = 47
POINTS_PER_PACKET = 12
SAMPLE_RATE_HZ = 4500  # LD06 ranging frequency; 12 points span 11 sample intervals


def _crc_table(poly: int = 0x4D) -> np.ndarray:
    table = np.zeros(256, np.uint8)
    for i in range(256):
        crc = i
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[i] = crc
    return table


CRC_TABLE = _crc_table()


def crc8(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc = int(CRC_TABLE[crc ^ byte])
    return crc


@dataclass(frozen=True)
class LD06Packet:
    speed_deg_s: int
    start_deg: float
    end_deg: float
    timestamp_ms: int
    distances_mm: tuple[int, ...]
    intensities: tuple[int, ...]

    def angles_deg(self) -> np.ndarray:
        end = self.end_deg if self.end_deg >= self.start_deg else self.end_deg + 360.0
        return (np.linspace(self.start_deg, end, POINTS_PER_PACKET) % 360.0).astype(np.float32)

    def span_deg(self) -> float:
        return (self.end_deg - self.start_deg) % 360.0


def encode_packet(speed_deg_s: int, start_deg: float, end_deg: float, timestamp_ms: int,
                  distances_mm, intensities) -> bytes:
    """Build a packet per the protocol (tests and simulators)."""
    body = bytearray([HEADER, VER_LEN])
    body += int(speed_deg_s).to_bytes(2, "little")
    body += int(round(start_deg * 100) % 36000).to_bytes(2, "little")
    for d, i in zip(distances_mm, intensities, strict=True):
        body += int(d).to_bytes(2, "little") + bytes([int(i)])
    body += int(round(end_deg * 100) % 36000).to_bytes(2, "little")
    body += int(timestamp_ms % 30000).to_bytes(2, "little")
    return bytes(body + bytes([crc8(bytes(body))]))


@dataclass
class DecoderStats:
    packets: int = 0
    crc_errors: int = 0
    bad_span: int = 0
    skipped_bytes: int = 0
    scans: int = 0
    counts: dict = field(default_factory=dict)


class LD06Decoder:
    """`feed(data) -> list[LD06Packet]`: bytes in, whole valid packets out; never raises."""

    def __init__(self, max_span_factor: float = 3.0, max_span_deg: float = 30.0) -> None:
        self._buffer = bytearray()
        self.stats = DecoderStats()
        self.max_span_factor, self.max_span_deg = max_span_factor, max_span_deg

    def plausible(self, packet: LD06Packet) -> bool:
        """Angular span consistent with the spin speed (12 points over 11 sample intervals)."""
        expected = packet.speed_deg_s * (POINTS_PER_PACKET - 1) / SAMPLE_RATE_HZ
        span = packet.span_deg()
        return span <= self.max_span_deg and span <= self.max_span_factor * expected + 0.5

    def feed(self, data: bytes) -> list[LD06Packet]:
        buf = self._buffer
        buf += data
        out: list[LD06Packet] = []
        i = 0
        n = len(buf)
        while n - i >= 2:
            if buf[i] != HEADER or buf[i + 1] != VER_LEN:
                i += 1
                self.stats.skipped_bytes += 1
                continue
            if n - i < PACKET_SIZE:
                break
            frame = bytes(buf[i:i + PACKET_SIZE])
            if crc8(frame[:46]) != frame[46]:
                self.stats.crc_errors += 1
                i += 1  # resynchronise from the next byte
                self.stats.skipped_bytes += 1
                continue
            packet = _parse(frame)
            if self.plausible(packet):
                out.append(packet)
                self.stats.packets += 1
            else:
                self.stats.bad_span += 1
            i += PACKET_SIZE
        if i == n - 1 and buf[i] != HEADER:  # a lone byte that cannot start a packet
            i += 1
            self.stats.skipped_bytes += 1
        del buf[:i]
        return out


def _parse(frame: bytes) -> LD06Packet:
    speed = int.from_bytes(frame[2:4], "little")
    start = int.from_bytes(frame[4:6], "little") / 100.0
    dist, inten = [], []
    for k in range(POINTS_PER_PACKET):
        off = 6 + 3 * k
        dist.append(int.from_bytes(frame[off:off + 2], "little"))
        inten.append(frame[off + 2])
    end = int.from_bytes(frame[42:44], "little") / 100.0
    stamp = int.from_bytes(frame[44:46], "little")
    return LD06Packet(speed, start % 360.0, end % 360.0, stamp, tuple(dist), tuple(inten))


# ~10x the most points a revolution of the supported LiDARs holds (LD06: ~450 at 10 Hz,
# RPLIDAR A2: ~800): past it a revolution is cut, so memory stays bounded when the angle
# never wraps (a failing encoder) or the start flag never comes
MAX_REVOLUTION_POINTS = 20_000


class RevolutionAssembler:
    """Packets -> one `LidarScan` per revolution (emitted when the start angle wraps, or cut
    at `max_points`, counted in `cut`).

    `add(packet, stamp_ns)`: stamp_ns is the host time the packet arrived; the scan's stamp is
    its first packet's, each point carries its packet's stamp. Zero distances are no return.
    """

    def __init__(self, min_range_m: float = 0.02,
                 max_points: int = MAX_REVOLUTION_POINTS) -> None:
        self.min_range_m = min_range_m
        self.max_points = max_points
        self.cut = 0  # revolutions emitted at max_points because the angle never wrapped
        self._count = 0
        self._points: list[np.ndarray] = []
        self._intensity: list[np.ndarray] = []
        self._stamps: list[np.ndarray] = []
        self._last_start: float | None = None
        self._scan_stamp: int | None = None

    def add(self, packet: LD06Packet | tuple, stamp_ns: int) -> LidarScan | None:
        """`packet` is an LD06Packet or (angles_deg, distances_m, intensities)."""
        if isinstance(packet, LD06Packet):
            angles = np.deg2rad(packet.angles_deg())
            ranges = np.asarray(packet.distances_mm, np.float32) / 1000.0
            inten = np.asarray(packet.intensities, np.float32)
            start = packet.start_deg
        else:
            angles_deg, ranges, inten = (np.asarray(a, np.float32) for a in packet)
            angles = np.deg2rad(angles_deg)
            start = float(angles_deg[0]) if len(angles_deg) else 0.0
        scan = None
        if self._last_start is not None and start < self._last_start - 180.0:
            scan = self.flush()
        elif self._count + len(ranges) > self.max_points:  # bounded memory: a revolution
            scan = self.flush()                             # that never closes is cut
            self.cut += 1
        self._last_start = start
        if self._scan_stamp is None:
            self._scan_stamp = int(stamp_ns)
        keep = ranges >= self.min_range_m
        r, a = ranges[keep], angles[keep]
        self._points.append(np.stack([r * np.cos(a), -r * np.sin(a), np.zeros_like(r)], 1))
        self._intensity.append(inten[keep])
        self._stamps.append(np.full(int(keep.sum()), int(stamp_ns), np.int64))
        self._count += len(ranges)
        return scan

    def flush(self) -> LidarScan | None:
        if self._scan_stamp is None:
            return None
        pts = (np.concatenate(self._points).astype(np.float32) if self._points
               else np.zeros((0, 3), np.float32))
        scan = LidarScan(self._scan_stamp, pts, np.concatenate(self._intensity),
                         np.concatenate(self._stamps))
        self._points, self._intensity, self._stamps = [], [], []
        self._scan_stamp, self._count = None, 0
        return scan
