"""Slamtec RPLIDAR A1/A2 standard scan: requests, response descriptors and scan nodes.

Requests are 0xA5 cmd [size payload checksum] (checksum: XOR of every byte before it).
Responses start with a 7-byte descriptor: 0xA5 0x5A, a 30-bit length and 2-bit send mode
(little endian u32), a data type byte. A scan (0x20) answers with descriptor length 5, mode 1
(multiple), type 0x81, then 5-byte nodes:
  byte 0: quality << 2 | !S << 1 | S    (S = first node of a new revolution)
  byte 1: angle_q6[6:0] << 1 | C        (C = check bit, always 1)
  byte 2: angle_q6[14:7]
  bytes 3-4: distance_q2 (u16, mm * 4)
angle = angle_q6 / 64 degrees (clockwise), distance = distance_q2 / 4 mm; 0 = no return.
A node whose S bits agree or whose C bit is 0 is not a node: the decoder moves on by one byte.
"""

from __future__ import annotations

from dataclasses import dataclass

SYNC, SYNC2 = 0xA5, 0x5A
CMD_STOP, CMD_RESET, CMD_SCAN, CMD_GET_INFO, CMD_GET_HEALTH = 0x25, 0x40, 0x20, 0x50, 0x52
CMD_SET_PWM = 0xF0
SCAN_DESCRIPTOR = bytes([0xA5, 0x5A, 0x05, 0x00, 0x00, 0x40, 0x81])
HEALTH_TYPE = 0x06
HEALTH_STATUS = {0: "good", 1: "warning", 2: "error"}
DEFAULT_PWM = 660
NODE_SIZE = 5  # bytes of one standard-scan node


def request(cmd: int, payload: bytes = b"") -> bytes:
    if not payload:
        return bytes([SYNC, cmd])
    body = bytes([SYNC, cmd, len(payload)]) + payload
    checksum = 0
    for b in body:
        checksum ^= b
    return body + bytes([checksum])


def set_pwm_request(pwm: int = DEFAULT_PWM) -> bytes:
    """A2 motor speed (0 stops it); A1 has no PWM command, its motor follows DTR."""
    return request(CMD_SET_PWM, int(pwm).to_bytes(2, "little"))


@dataclass(frozen=True)
class Descriptor:
    length: int
    mode: int
    data_type: int


def parse_descriptor(data: bytes) -> Descriptor:
    if len(data) != 7 or data[0] != SYNC or data[1] != SYNC2:
        raise ValueError(f"not a response descriptor: {data.hex()}")
    word = int.from_bytes(data[2:6], "little")
    return Descriptor(word & 0x3FFFFFFF, word >> 30, data[6])


def parse_health(data: bytes) -> tuple[str, int]:
    """3-byte health payload -> (status name, error code)."""
    if len(data) != 3:
        raise ValueError(f"health payload must be 3 bytes, got {len(data)}")
    return HEALTH_STATUS.get(data[0], f"unknown({data[0]})"), int.from_bytes(data[1:3], "little")


@dataclass(frozen=True)
class ScanNode:
    start: bool
    quality: int
    angle_deg: float
    distance_mm: float


def encode_node(start: bool, quality: int, angle_deg: float, distance_mm: float) -> bytes:
    """Build a node per the protocol (tests and simulators)."""
    angle_q6 = int(round(angle_deg * 64)) & 0x7FFF
    dist_q2 = int(round(distance_mm * 4)) & 0xFFFF
    s = 1 if start else 0
    return bytes([(quality & 0x3F) << 2 | (1 - s) << 1 | s, (angle_q6 & 0x7F) << 1 | 1,
                  angle_q6 >> 7]) + dist_q2.to_bytes(2, "little")


def valid_node(b: bytes | bytearray, i: int = 0) -> bool:
    s, not_s = b[i] & 1, (b[i] >> 1) & 1
    return s != not_s and b[i + 1] & 1 == 1


class RPLidarDecoder:
    """`feed(data) -> list[ScanNode]` after the scan descriptor; never raises.

    The descriptor is expected first (`expect_descriptor=True`): bytes before it are skipped.
    A bad node is resynchronised from the next byte and counted in `bad_nodes`."""

    def __init__(self, expect_descriptor: bool = True) -> None:
        self._buffer = bytearray()
        self._need_descriptor = expect_descriptor
        self.nodes = 0
        self.bad_nodes = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes) -> list[ScanNode]:
        buf = self._buffer
        buf += data
        i = 0
        if self._need_descriptor:
            at = buf.find(SCAN_DESCRIPTOR)
            if at < 0:
                keep = max(0, len(buf) - (len(SCAN_DESCRIPTOR) - 1))
                self.skipped_bytes += keep
                del buf[:keep]
                return []
            self.skipped_bytes += at
            i = at + len(SCAN_DESCRIPTOR)
            self._need_descriptor = False
        out = []
        while len(buf) - i >= NODE_SIZE:
            if not valid_node(buf, i):
                i += 1
                self.bad_nodes += 1
                self.skipped_bytes += 1
                continue
            b0, b1, b2 = buf[i], buf[i + 1], buf[i + 2]
            angle_q6 = (b1 >> 1) | (b2 << 7)
            dist_q2 = buf[i + 3] | (buf[i + 4] << 8)
            out.append(ScanNode(bool(b0 & 1), b0 >> 2, angle_q6 / 64.0, dist_q2 / 4.0))
            self.nodes += 1
            i += NODE_SIZE
        del buf[:i]
        return out
