"""OAK adapter without a device: host-built depthai ImgFrames; the real-device test skips."""

from __future__ import annotations

import datetime

import numpy as np
import pytest

dai = pytest.importorskip("depthai")

from edge_depth.capture.oak import OakSource, StereoPairer, frame_to_array  # noqa: E402
from edge_depth.errors import InvalidDataError  # noqa: E402


def img_frame(seq: int, seconds: float, image: np.ndarray, kind=None,
              device_offset_s: float = 0.0):
    """A frame stamped `seconds` on the host's clock and `seconds + device_offset_s` on the
    device's own."""
    f = dai.ImgFrame()
    f.setType(kind or dai.ImgFrame.Type.GRAY8)
    f.setWidth(image.shape[1])
    f.setHeight(image.shape[0])
    f.setData(image.ravel())
    f.setSequenceNum(seq)
    f.setTimestamp(datetime.timedelta(seconds=seconds))
    f.setTimestampDevice(datetime.timedelta(seconds=seconds + device_offset_s))
    return f


def test_frames_pair_by_sequence_number_with_host_stamps_in_ns():
    rng = np.random.default_rng(0)
    images = {(side, s): rng.integers(0, 256, (40, 64), dtype=np.uint8)
              for side in ("left", "right") for s in range(4)}
    pairer = StereoPairer(max_pending=2)
    out = []
    # right frames arrive late and seq 1's right frame is lost
    order = [("left", 0), ("left", 1), ("right", 0), ("left", 2), ("right", 2), ("left", 3),
             ("right", 3)]
    for side, seq in order:
        # the device clock is 5 hours away from the host's: the stamps must not see it
        pair = pairer.add(side, img_frame(seq, 1.5 + seq / 30, images[(side, seq)],
                                          device_offset_s=5 * 3600.0))
        if pair is not None:
            out.append(pair)
    assert [p.seq for p in out] == [0, 2, 3]
    for p in out:
        np.testing.assert_array_equal(p.left, images[("left", p.seq)])
        np.testing.assert_array_equal(p.right, images[("right", p.seq)])
        assert not p.rectified
    assert out[0].stamp_ns == 1_500_000_000
    assert out[2].stamp_ns == 1_500_000_000 + 100_000_000
    # seq 1 waited more than max_pending sequence numbers: dropped and counted
    pairer.add("left", img_frame(9, 2.0, images[("left", 0)]))
    assert pairer.unpaired == 1


def test_a_frame_of_another_type_or_short_data_is_a_clear_error():
    bad = img_frame(0, 0.0, np.zeros((4, 6), np.uint8), dai.ImgFrame.Type.NV12)
    with pytest.raises(InvalidDataError, match="GRAY8"):
        frame_to_array(bad)
    short = img_frame(0, 0.0, np.zeros((4, 6), np.uint8))
    short.setHeight(8)
    with pytest.raises(InvalidDataError, match="48 bytes"):
        frame_to_array(short)


def _has_device() -> bool:
    try:
        return len(dai.Device.getAllAvailableDevices()) > 0
    except RuntimeError:
        return False


@pytest.mark.hardware
@pytest.mark.skipif(not _has_device(), reason="no OAK device connected")
def test_real_device_streams_paired_frames():  # pragma: no cover - needs hardware
    with OakSource() as source:
        for frame in source:
            assert frame.left.shape == (400, 640)
            assert source.calibration is not None
            break


def test_oak_counters_carry_unpaired_frames_for_diagnostics():
    source = OakSource((64, 40), 30.0)
    image = np.zeros((40, 64), np.uint8)
    source.pairer.add("left", img_frame(0, 1.0, image))
    source.pairer.add("left", img_frame(20, 1.5, image))  # seq 0 waited too long: lost
    assert source.counters() == dict(frames=0, unpaired=1, reconnects=0, errors={})
