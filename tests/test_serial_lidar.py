"""Serial LiDAR decoders (property tests) and sources over real pseudo-terminals."""

from __future__ import annotations

import os
import threading
import time
import tty

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_depth.capture import ld06, rplidar
from edge_depth.capture.serial_lidar import SerialLidarSource


def crc8_bitwise(data: bytes, poly: int = 0x4D) -> int:
    """Independent of the module's table: MSB-first, initial 0."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def packet(start: float, span: float = 9.6, speed: int = 3600, dist=None, stamp: int = 0):
    dist = dist if dist is not None else [1000 + 10 * k for k in range(12)]
    return ld06.encode_packet(speed, start, (start + span) % 360, stamp, dist, [200] * 12)


def test_crc_table_matches_a_bitwise_crc8_with_polynomial_0x4d():
    rng = np.random.default_rng(0)
    for _ in range(50):
        data = bytes(rng.integers(0, 256, 46, dtype=np.uint8))
        assert ld06.crc8(data) == crc8_bitwise(data)
    p = packet(10.0)
    assert len(p) == 47 and p[46] == crc8_bitwise(p[:46])


def test_ld06_packet_fields_and_angles_across_the_wrap():
    (got,) = ld06.LD06Decoder().feed(packet(355.0, span=9.6, stamp=1234))
    assert got.speed_deg_s == 3600 and got.timestamp_ms == 1234
    assert got.distances_mm[0] == 1000 and got.distances_mm[-1] == 1110
    angles = got.angles_deg()
    assert angles[0] == pytest.approx(355.0) and angles[-1] == pytest.approx(4.6, abs=1e-3)
    assert np.all(np.diff(np.unwrap(np.deg2rad(angles))) > 0)


def test_implausible_span_for_the_speed_is_dropped_and_counted():
    dec = ld06.LD06Decoder()
    assert dec.feed(packet(100.0, span=40.0)) == []
    assert dec.stats.bad_span == 1 and dec.stats.packets == 0


packets_st = st.lists(st.tuples(st.floats(0, 359.9), st.lists(st.integers(0, 12000),
                                                            min_size=12, max_size=12)),
                      min_size=1, max_size=6)
garbage_st = st.binary(max_size=80).map(lambda b: bytes(x for x in b if x != ld06.HEADER))


@settings(max_examples=150, deadline=None)
@given(packets_st, st.lists(garbage_st, min_size=7, max_size=7), st.integers(1, 64))
def test_valid_packets_spliced_into_garbage_come_out_exactly(items, garbage, chunk):
    stream = bytearray(garbage[0])
    sent = []
    for (start, dist), junk in zip(items, garbage[1:], strict=False):
        p = packet(round(start, 2), dist=dist)
        sent.append(p)
        stream += p + junk
    dec = ld06.LD06Decoder()
    got = []
    for i in range(0, len(stream), chunk):  # arbitrary read boundaries
        got += dec.feed(bytes(stream[i:i + chunk]))
    assert [ld06.encode_packet(g.speed_deg_s, g.start_deg, g.end_deg, g.timestamp_ms,
                               g.distances_mm, g.intensities) for g in got] == sent
    assert dec.stats.crc_errors == 0


@settings(max_examples=100, deadline=None)
@given(st.integers(2 * 8, 46 * 8 - 1), st.integers(0, 1000))
def test_a_bit_flip_is_a_crc_error_and_the_next_packet_survives(bit, dist0):
    # payload bytes avoid the header value so no packet can hide inside the corrupt one
    dist = [(dist0 + 7 * k) % 0x5300 for k in range(12)]
    bad = bytearray(packet(20.0, dist=dist))
    if ld06.HEADER in bad[2:] or ld06.HEADER in packet(40.0)[2:]:
        return
    bad[bit // 8] ^= 1 << (bit % 8)
    dec = ld06.LD06Decoder()
    got = dec.feed(bytes(bad) + packet(40.0))
    assert [g.start_deg for g in got] == [40.0]
    assert dec.stats.crc_errors == 1


def test_a_packet_starting_inside_a_truncated_one_is_found():
    good = packet(50.0)
    dec = ld06.LD06Decoder()
    got = dec.feed(packet(30.0)[:20] + good)
    assert [g.start_deg for g in got] == [50.0]


def test_revolutions_become_scans_in_the_lidar_frame():
    asm = ld06.RevolutionAssembler()
    scans = []
    for rev in range(2):
        for k in range(38):  # 38 packets of 9.6 deg: one revolution
            # every point of the packet at 90 deg clockwise -> -y (to the right)
            p = ld06.LD06Packet(3600, (k * 9.6) % 360, (k * 9.6 + 9.6) % 360, 0,
                                tuple([2000] * 12), tuple([100] * 12))
            s = asm.add(p, rev * 10**8 + k)
            if s is not None:
                scans.append(s)
    assert len(scans) == 1 and len(scans[0]) == 38 * 12
    pts = scans[0].points
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), 2.0, rtol=1e-5)
    angles = np.rad2deg(np.arctan2(-pts[:, 1], pts[:, 0])) % 360
    near90 = np.abs(angles - 90) < 0.5
    assert near90.any() and np.all(pts[near90, 1] < -1.99)
    assert scans[0].stamp_ns == 0 and scans[0].point_stamps_ns[-1] == 37


# -- RPLIDAR ------------------------------------------------------------------------------
def test_rplidar_requests_descriptors_and_nodes():
    assert rplidar.set_pwm_request(660) == bytes.fromhex("a5f0029402c1")  # the SDK's bytes
    assert rplidar.request(rplidar.CMD_SCAN) == b"\xa5\x20"
    d = rplidar.parse_descriptor(rplidar.SCAN_DESCRIPTOR)
    assert (d.length, d.mode, d.data_type) == (5, 1, 0x81)
    assert rplidar.parse_health(b"\x02\x05\x01") == ("error", 0x105)
    node = rplidar.encode_node(True, 47, 123.453125, 1234.25)
    dec = rplidar.RPLidarDecoder()
    (got,) = dec.feed(rplidar.SCAN_DESCRIPTOR + node)
    assert got == rplidar.ScanNode(True, 47, 123.453125, 1234.25)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.integers(0, 63), st.floats(0, 359.98),
                          st.floats(0, 16000)), min_size=1, max_size=20),
       st.lists(st.booleans(), min_size=20, max_size=20), st.integers(1, 16))
def test_rplidar_invalid_bytes_between_nodes_are_skipped(nodes, junk_after, chunk):
    stream = bytearray(b"\x01\x02" + rplidar.SCAN_DESCRIPTOR)
    expected = []
    for (start, q, angle, dist), junk in zip(nodes, junk_after, strict=False):
        raw = rplidar.encode_node(start, q, angle, dist)
        expected.append(rplidar.RPLidarDecoder(False).feed(raw)[0])
        stream += raw
        if junk:
            stream += b"\x00"  # S and !S both 0: never a node
    last = rplidar.encode_node(False, 1, 1.0, 1.0)  # so trailing junk is looked at too
    stream += last
    expected.append(rplidar.RPLidarDecoder(False).feed(last)[0])
    dec = rplidar.RPLidarDecoder()
    got = []
    for i in range(0, len(stream), chunk):
        got += dec.feed(bytes(stream[i:i + chunk]))
    assert got == expected
    assert dec.bad_nodes == sum(junk_after[:len(nodes)])


# -- over a pseudo-terminal ------------------------------------------------------------------
class FakeLD06:
    """Writes LD06 revolutions into the master side of a pty, from a thread."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        k = 0
        while not self.stop.is_set():
            try:
                os.write(self.master, packet((k * 9.6) % 360, stamp=k))
            except OSError:
                return
            k += 1
            time.sleep(0.0005)

    def unplug(self) -> None:
        self.stop.set()
        self.thread.join()
        os.close(self.master)
        os.close(self.slave)


def wait_for(predicate, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def test_ld06_over_a_pty_survives_an_unplug_and_stops_on_close(tmp_path):
    link = tmp_path / "ttyLIDAR"
    first = FakeLD06()
    link.symlink_to(first.path)
    source = SerialLidarSource(str(link), "ld06", backoff_s=(0.05, 0.2))
    scans = []
    reader = threading.Thread(target=lambda: scans.extend(source), daemon=True)
    reader.start()
    assert wait_for(lambda: source.connects == 1)
    first.thread.start()
    assert wait_for(lambda: len(scans) >= 2)
    first.unplug()
    second = FakeLD06()
    link.unlink()
    link.symlink_to(second.path)
    assert wait_for(lambda: source.reconnects == 1)
    before = len(scans)
    second.thread.start()
    assert wait_for(lambda: len(scans) >= before + 2)
    source.close()
    reader.join(timeout=5)
    assert not reader.is_alive()
    second.unplug()
    assert any(k.startswith("read") or k.startswith("open") for k in source.errors)
    counters = source.counters()  # what reaches /diagnostics
    assert counters["reconnects"] == 1 and counters["scans"] == len(scans)
    assert counters["packets"] >= 2 * 37 and counters["crc_errors"] == 0
    assert counters["errors"] == dict(source.errors)
    # the first connection's first revolutions are whole: 37 or 38 packets of 9.6 degrees
    assert {len(scans[0]), len(scans[1])} <= {37 * 12, 38 * 12}
    np.testing.assert_allclose(np.hypot(*scans[0].points[:12, :2].T),
                               np.arange(1000, 1120, 10) / 1000, atol=1e-6)


class FakeRPLidar:
    """An RPLIDAR on a pseudo-terminal (a context manager): answers the health query and,
    once asked to scan, streams the nodes `node(i)` returns (None: nothing more)."""

    def __init__(self, node) -> None:
        self.node = node
        self.requests = bytearray()
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        import select

        streaming, i = False, 0
        while not self.stop.is_set():
            if select.select([self.master], [], [], 0.0005)[0]:
                self.requests.extend(os.read(self.master, 64))
                if self.requests.endswith(rplidar.request(rplidar.CMD_GET_HEALTH)):
                    os.write(self.master, bytes([0xA5, 0x5A, 3, 0, 0, 0, 6, 0, 0, 0]))
                if self.requests.endswith(rplidar.request(rplidar.CMD_SCAN)) and not streaming:
                    os.write(self.master, rplidar.SCAN_DESCRIPTOR)
                    streaming = True
            node = self.node(i) if streaming else None
            if node is not None:
                os.write(self.master, node)
                i += 1

    def __enter__(self) -> FakeRPLidar:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        time.sleep(0.1)  # let the device thread read the stop requests
        self.stop.set()
        self.thread.join()
        os.close(self.master)
        os.close(self.slave)


def scans_from(port: str, count: int) -> tuple[SerialLidarSource, list]:
    source = SerialLidarSource(port, "rplidar-a2")
    scans = []
    for scan in source:
        scans.append(scan)
        if len(scans) == count:
            source.close()
    return source, scans


def test_rplidar_over_a_pty_answers_health_and_streams_nodes():
    def node(i: int) -> bytes:
        angle = i % 360
        return rplidar.encode_node(angle == 0, 15, float(angle), 500.0 + angle)

    with FakeRPLidar(node) as device:
        _, scans = scans_from(device.port, 2)
    requests = device.requests
    assert b"\xa5\x52" in requests and rplidar.set_pwm_request() in requests
    assert requests.rfind(rplidar.request(rplidar.CMD_STOP)) > requests.find(b"\xa5\x20")
    assert requests.endswith(rplidar.set_pwm_request(0))
    assert len(scans[1]) >= 300
    r = np.hypot(scans[1].points[:, 0], scans[1].points[:, 1])
    assert r.min() >= 0.5 and r.max() <= 0.86


def test_a_revolution_that_never_wraps_is_cut_at_the_point_limit():
    asm = ld06.RevolutionAssembler(max_points=120)
    scans = []
    for k in range(100):  # the start angle never wraps (a failing encoder)
        p = ld06.LD06Packet(3600, 10.0, 19.6, 0, tuple([2000] * 12), tuple([100] * 12))
        s = asm.add(p, k)
        assert asm._count <= 120  # bounded
        if s is not None:
            scans.append(s)
    assert asm.cut == len(scans) == 9 and all(len(s) == 120 for s in scans)


def test_rplidar_without_start_flags_is_cut_and_counted(monkeypatch):
    monkeypatch.setattr(ld06, "MAX_REVOLUTION_POINTS", 50)

    def node(i: int) -> bytes | None:  # never a start flag
        return rplidar.encode_node(False, 15, float(i % 360), 800.0) if i < 400 else None

    with FakeRPLidar(node) as device:
        source, scans = scans_from(device.port, 3)
    assert len(scans) >= 3 and all(len(s) == 50 for s in scans)  # closing ends the batch
    assert source.counters()["errors"]["revolution cut (no start flag)"] >= len(scans)


class FakePort:
    """A serial port whose reads return prepared chunks (and say how much is waiting)."""

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = list(chunks)

    @property
    def in_waiting(self) -> int:
        return len(self.chunks[0]) if self.chunks else 0

    def read(self, n: int) -> bytes:
        if not self.chunks:
            time.sleep(0.01)
            return b""
        chunk = self.chunks.pop(0)
        assert n >= len(chunk)  # reads take what has arrived, not a fixed size
        return chunk

    def write(self, data: bytes) -> None:
        pass

    def cancel_read(self) -> None:
        pass

    def close(self) -> None:
        pass


def test_serial_stamps_are_each_packets_first_point_not_the_reads_return(monkeypatch):
    import serial

    revolution = b"".join(ld06.encode_packet(3600, 10.0 * k, 10.0 * k + 9.0, 0, [1000] * 12,
                                             [100] * 12) for k in range(36))
    wrap = ld06.encode_packet(3600, 0.0, 9.0, 0, [1000] * 12, [100] * 12)
    monkeypatch.setattr(serial, "serial_for_url",
                        lambda *a, **k: FakePort([revolution, wrap]))
    reads = iter([5_000_000_000, 5_100_000_000])  # host time when each read returned
    source = SerialLidarSource("fake", "ld06", read_size=4096,
                               clock=lambda: next(reads, 6_000_000_000))
    scan = next(iter(source))
    source.close()
    byte_ns = 10e9 / 230400
    sweep_ns = 9.0 / 3600 * 1e9  # 12 points over 9 degrees at 3600 deg/s
    expected = [int(5_000_000_000 - (36 - k) * 47 * byte_ns - sweep_ns) for k in range(36)]
    stamps = sorted(set(scan.point_stamps_ns.tolist()))
    assert stamps == expected
    assert scan.stamp_ns == expected[0]  # ~73 ms before the read returned
    assert 5_000_000_000 - scan.stamp_ns == pytest.approx(36 * 47 * byte_ns + sweep_ns, abs=1)
