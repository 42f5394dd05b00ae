"""The live view: the logger serves the Foxglove WebSocket protocol, and a client that joins
late still gets the calibration and the transforms."""

from __future__ import annotations

import socket

from edge_depth.mcap_log import McapLogger
from edge_depth.types import StereoFrame


def test_live_view_serves_a_foxglove_websocket(tmp_path):
    request = ("GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
               "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
               "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1, "
               "foxglove.websocket.v1\r\n\r\n")
    with McapLogger(tmp_path / "live.mcap", live=True, live_port=0) as logger:
        port = logger.server.port
        with socket.create_connection(("127.0.0.1", port), timeout=5) as conn:
            conn.sendall(request.encode())
            reply = conn.recv(4096).decode(errors="replace")
    assert reply.startswith("HTTP/1.1 101") and "foxglove" in reply
    assert logger.server is None


def _ws_connect(port: int):
    conn = socket.create_connection(("127.0.0.1", port), timeout=5)
    conn.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                  b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                  b"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1, "
                  b"foxglove.websocket.v1\r\n\r\n")
    stream = conn.makefile("rb")
    while stream.readline() not in (b"\r\n", b""):  # the 101 reply's headers
        pass
    return conn, stream


def _ws_send_text(conn, text: str) -> None:
    import os

    data = text.encode()
    mask = os.urandom(4)
    head = bytes([0x81, 0x80 | 126]) + len(data).to_bytes(2, "big") if len(data) >= 126 \
        else bytes([0x81, 0x80 | len(data)])
    conn.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


def _ws_read(stream) -> tuple[int, bytes]:
    b0, b1 = stream.read(2)
    n = b1 & 0x7F
    if n == 126:
        n = int.from_bytes(stream.read(2), "big")
    elif n == 127:
        n = int.from_bytes(stream.read(8), "big")
    return b0 & 0x0F, stream.read(n)


def test_a_live_client_joining_after_the_third_frame_gets_calibration_and_transforms(
        tmp_path):
    import json

    from edge_depth.capture.sim import SimSource

    stereo, lidar = SimSource(1).calibration
    frames = [e for e in SimSource(3, 1_000_000) if isinstance(e, StereoFrame)]
    with McapLogger(tmp_path / "live.mcap", live=True, live_port=0) as logger:
        logger.set_calibration(stereo, lidar)
        for frame in frames:
            logger.log_frame(frame)
        conn, stream = _ws_connect(logger.server.port)
        channels = {}
        while not {"/edge/calibration", "/tf"} <= set(channels):
            opcode, payload = _ws_read(stream)
            if opcode == 1 and json.loads(payload).get("op") == "advertise":
                channels.update({c["topic"]: c["id"] for c in json.loads(payload)["channels"]})
        subs = {1: "/edge/calibration", 2: "/tf"}
        _ws_send_text(conn, json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": channels[topic]} for i, topic in subs.items()]}))
        got = {}
        while set(got) != set(subs.values()):
            opcode, payload = _ws_read(stream)
            if opcode == 2 and payload[0] == 1:  # MessageData: op, subscription id, time, data
                got[subs[int.from_bytes(payload[1:5], "little")]] = payload[13:]
        conn.close()
    assert json.loads(got["/edge/calibration"])["toml"] == logger.calibration_toml
    assert b"camera_right" in got["/tf"] and b"lidar" in got["/tf"]  # the two transforms
