"""Mutation fuzz of the two files a robot owner writes: 300 mutated robot configs
and 300 mutated calibration files each load or fail with one error naming the file —
never another exception, never a hang. Seeded, a few seconds in all."""

from __future__ import annotations

import time

import numpy as np
import pytest

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.io import dumps_calibration, load_calibration
from edge_depth.capture.sim import SimSource
from edge_depth.config import load_robot_config
from edge_depth.errors import ConfigError

ROBOT = """[camera]
source = "sim"
size = [640, 400]
fps = 20.0
[lidar]
model = "sim"
[sync]
mode = "nearest"
window_ms = 100.0
max_wait_ms = 200.0
[engine]
precision = "int8"
threads = 2
iters = 4
deadline_ms = 80.0
[log]
out = "logs/depth.mcap"
rotate_mb = 1024.0
compression = "lz4"
"""
# what a hand edit or a bad disk turns values into
TOKENS = [b"nan", b"inf", b"-inf", b"1e308", b"-1", b"0", b"1e-300", b"99999999999999999999",
          b'"abc"', b"[]", b"[1, 2, 3]", b"true", b"{}", b"\xff\xfe", b"\x00", b"=", b"[", b'"',
          b"\n[engine]\n", b"2147483648", b"-0.0", b"1_000"]


def mutate(text: bytes, rng: np.random.Generator) -> bytes:
    raw = bytearray(text)
    for _ in range(int(rng.integers(1, 4))):
        at = int(rng.integers(0, len(raw)))
        kind = int(rng.integers(0, 4))
        if kind == 0:  # flip a bit
            raw[at] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:  # replace a value with a token
            line_end = raw.find(b"\n", at)
            eq = raw.rfind(b"=", 0, at)
            if eq != -1 and line_end != -1:
                raw[eq + 1:line_end] = b" " + TOKENS[int(rng.integers(0, len(TOKENS)))]
        elif kind == 2:  # delete a run of bytes
            del raw[at:at + int(rng.integers(1, 20))]
        else:  # insert a token
            raw[at:at] = TOKENS[int(rng.integers(0, len(TOKENS)))]
    return bytes(raw)


@pytest.mark.parametrize("kind", ["robot config", "calibration"])
def test_mutated_files_load_or_fail_with_one_named_error(tmp_path, kind):
    if kind == "robot config":
        clean, load, errors = ROBOT.encode(), load_robot_config, (ConfigError,)
    else:
        clean = dumps_calibration(*SimSource(1).calibration).encode()
        load, errors = load_calibration, (CalibrationError,)
    path = tmp_path / "file.toml"
    rng = np.random.default_rng(2026)
    outcomes = {"loaded": 0, "refused": 0}
    started = time.monotonic()
    for _ in range(300):
        path.write_bytes(mutate(clean, rng))
        try:
            load(path)
            outcomes["loaded"] += 1
        except errors as exc:
            assert str(path) in str(exc) and "\n" not in str(exc).strip()
            outcomes["refused"] += 1
    assert outcomes["loaded"] > 0 and outcomes["refused"] > 100  # both paths exercised
    assert time.monotonic() - started < 30
