"""Serial LiDAR sources: port handling around the pure decoders (ld06.py, rplidar.py).

Opened with `serial.serial_for_url`, so `/dev/ttyUSB0`, a pseudo-terminal and `loop://` all
work. A read timeout is not an error; a `SerialException` or `OSError` (unplugged cable)
closes the port, waits with exponential back-off and reopens, counting the reconnect.
`close()` from another thread stops the iteration promptly (`cancel_read`).

Stamps are the host's monotonic clock, as the camera's are. A read returns what has
arrived (never waiting for a full buffer), and each packet is stamped at its first point:
the read's return time, less the bytes that arrived after the packet (10 bits a byte at the
baud rate), less the packet's own transmission and, for the LD06, the time its 12 points
took to sweep (span / speed). The error left is the USB-serial adapter's latency — about
1 ms for a CP210x, up to 16 ms with an FTDI's default latency timer — plus the OS's wake-up
after the read, a few ms; revolutions are ~100 ms, the sync window 100 ms.
"""

from __future__ import annotations

import logging
import time
from collections import Counter

import numpy as np

from edge_depth.capture import Backoff, Source, ld06, rplidar
from edge_depth.errors import ConfigError, EdgeError
from edge_depth.types import LidarScan

log = logging.getLogger(__name__)

MODELS = {"ld06": 230400, "ld19": 230400, "rplidar-a1": 115200, "rplidar-a2": 115200}


class LidarDeviceError(EdgeError):
    """The device answered, but not as a working LiDAR (e.g. health status 'error')."""


class SerialLidarSource(Source):
    def __init__(self, url: str, model: str = "ld06", baudrate: int | None = None,
                 read_size: int = 1024, timeout_s: float = 0.1,
                 backoff_s: tuple[float, float] = (0.2, 5.0), clock=time.monotonic_ns) -> None:
        if model not in MODELS:
            raise ConfigError("lidar.model", f"one of {sorted(MODELS)}", model)
        self.url, self.model = url, model
        self.baudrate = baudrate or MODELS[model]
        self.read_size, self.timeout_s = read_size, timeout_s
        self.backoff_s = backoff_s
        self.clock = clock
        super().__init__()
        self._port = None
        self.scans = 0
        self.reconnects = 0
        self.connects = 0
        self.errors: Counter = Counter()
        self.decoder = None
        self.assembler: ld06.RevolutionAssembler | None = None

    def counters(self) -> dict:
        errors = dict(self.errors)
        out: dict[str, object] = dict(model=self.model, scans=self.scans,
                                      reconnects=self.reconnects, errors=errors)
        if self.assembler is not None and self.assembler.cut:
            errors["revolution cut (the angle never wrapped)"] = self.assembler.cut
        decoder = self.decoder
        if decoder is not None and hasattr(decoder, "stats"):  # LD06 / LD19
            s = decoder.stats
            out.update(packets=s.packets, crc_errors=s.crc_errors, bad_span=s.bad_span,
                       skipped_bytes=s.skipped_bytes)
        elif decoder is not None:  # RPLIDAR
            out.update(nodes=decoder.nodes, bad_nodes=decoder.bad_nodes,
                       skipped_bytes=decoder.skipped_bytes)
        return out

    # -- lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        super().close()
        port = self._port
        if port is not None:
            try:
                port.cancel_read()
            except Exception:  # noqa: BLE001 - not every port type can cancel
                pass

    def _open(self):
        import serial

        port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.timeout_s)
        if self.model.startswith("rplidar"):
            self._start_rplidar(port)
            self.decoder = rplidar.RPLidarDecoder()
        else:
            self.decoder = ld06.LD06Decoder()
        self.connects += 1
        return port

    def _start_rplidar(self, port) -> None:
        port.write(rplidar.request(rplidar.CMD_STOP))
        time.sleep(0.01)
        port.reset_input_buffer()
        port.write(rplidar.request(rplidar.CMD_GET_HEALTH))
        reply = port.read(10)
        if len(reply) == 10:
            status, code = rplidar.parse_health(reply[7:])
            if status == "error":
                raise LidarDeviceError(f"{self.url}: RPLIDAR health 'error' (code {code}); "
                                       "power-cycle or send a reset")
        else:
            self.errors["no health reply"] += 1
        if self.model == "rplidar-a1":
            try:
                port.dtr = False  # the A1's USB adapter runs the motor while DTR is low
            except OSError:
                self.errors["dtr"] += 1
        else:
            port.write(rplidar.set_pwm_request())
        port.write(rplidar.request(rplidar.CMD_SCAN))

    def _close_port(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                if self.model.startswith("rplidar"):
                    port.write(rplidar.request(rplidar.CMD_STOP))
                    if self.model == "rplidar-a2":
                        port.write(rplidar.set_pwm_request(0))  # motor off
                    else:
                        port.dtr = True  # A1: motor off while DTR is high
                port.close()
            except Exception:  # noqa: BLE001 - the device may already be gone
                pass

    # -- iteration -----------------------------------------------------------------------------
    def _opened(self, backoff: Backoff) -> bool:
        """The port open (opened now if it was closed; a reopen counts as a reconnect), or
        False after a failed attempt, counted and backed off."""
        import serial

        if self._port is not None:
            return True
        try:
            self._port = self._open()
        except (serial.SerialException, OSError, LidarDeviceError) as exc:
            self.errors[f"open: {type(exc).__name__}"] += 1
            backoff.wait()
            return False
        if self.connects > 1:
            self.reconnects += 1
            log.warning("%s: reconnected", self.url)
        backoff.reset()
        return True

    def __iter__(self):
        import serial

        backoff = Backoff(self._stop, *self.backoff_s)
        self.assembler = assembler = ld06.RevolutionAssembler()
        revolution: list[rplidar.ScanNode] = []
        rev_stamp = 0
        try:
            while not self._stop.is_set():
                if not self._opened(backoff):
                    continue
                try:
                    waiting = getattr(self._port, "in_waiting", 0) or 1
                    data = self._port.read(min(self.read_size, waiting))
                except (serial.SerialException, OSError) as exc:
                    if self._stop.is_set():
                        break
                    self.errors[f"read: {type(exc).__name__}"] += 1
                    log.warning("%s: %s; reconnecting", self.url, exc)
                    self._close_port()
                    cut = assembler.cut  # a fresh revolution; the count goes on
                    self.assembler = assembler = ld06.RevolutionAssembler()
                    assembler.cut = cut
                    revolution = []
                    continue
                if not data:
                    continue
                now = int(self.clock())
                byte_ns = 10e9 / self.baudrate  # start + 8 data + stop bits
                if isinstance(self.decoder, ld06.LD06Decoder):
                    packets = self.decoder.feed(data)
                    for k, packet in enumerate(packets):
                        after = (len(packets) - k) * ld06.PACKET_SIZE  # its own bytes too
                        sweep = packet.span_deg() / max(packet.speed_deg_s, 1) * 1e9
                        scan = assembler.add(packet, int(now - after * byte_ns - sweep))
                        if scan is not None:
                            self.scans += 1
                            yield scan
                else:
                    nodes = self.decoder.feed(data)
                    for k, node in enumerate(nodes):
                        node_ns = int(now - (len(nodes) - k) * rplidar.NODE_SIZE * byte_ns)
                        too_long = len(revolution) >= ld06.MAX_REVOLUTION_POINTS
                        if too_long:  # the start flag never came: cut, bounded memory
                            self.errors["revolution cut (no start flag)"] += 1
                        if (node.start or too_long) and revolution:
                            self.scans += 1
                            yield nodes_to_scan(revolution, rev_stamp)
                            revolution = []
                        if not revolution:
                            rev_stamp = node_ns
                        revolution.append(node)
        finally:
            self._close_port()


def nodes_to_scan(nodes: list[rplidar.ScanNode], stamp_ns: int) -> LidarScan:
    """One revolution of RPLIDAR nodes -> LidarScan in the LiDAR frame (clockwise angles)."""
    a = np.deg2rad(np.array([n.angle_deg for n in nodes], np.float32))
    r = np.array([n.distance_mm for n in nodes], np.float32) / 1000.0
    q = np.array([n.quality for n in nodes], np.float32)
    keep = r > 0
    a, r, q = a[keep], r[keep], q[keep]
    pts = np.stack([r * np.cos(a), -r * np.sin(a), np.zeros_like(r)], 1).astype(np.float32)
    return LidarScan(int(stamp_ns), pts, q, np.full(len(r), int(stamp_ns), np.int64))
