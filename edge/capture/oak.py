"""Luxonis OAK stereo through depthai v3: CAM_B (left) and CAM_C (right) as GRAY8.

`OakSource` builds the pipeline (two `Camera` nodes, `requestOutput((w, h), GRAY8, fps)`,
non-blocking output queues that drop the oldest frame), pairs the two streams by sequence
number (`StereoPairer`, pure and tested with host-built `ImgFrame`s), stamps frames with the
host-synchronised stamp (`getTimestamp()`: the host's monotonic clock, the one the serial
LiDARs stamp with; never the device's own clock, which no host sensor shares), in ns, reads
the device's factory calibration, and reconnects with back-off after an X_LINK error.
Frames are raw (not rectified): the pipeline rectifies them with the calibration.
"""

from __future__ import annotations

import logging
import time
from collections import Counter

import numpy as np

from edge_depth.capture import Backoff, Source
from edge_depth.errors import InvalidDataError
from edge_depth.types import StereoFrame

log = logging.getLogger(__name__)


def timedelta_ns(td) -> int:
    return (td.days * 86_400 + td.seconds) * 1_000_000_000 + td.microseconds * 1_000


def frame_to_array(frame) -> np.ndarray:
    """A GRAY8 (or RAW8) `dai.ImgFrame` -> (H, W) uint8 copy."""
    import depthai as dai

    kind = frame.getType()
    if kind not in (dai.ImgFrame.Type.GRAY8, dai.ImgFrame.Type.RAW8):
        raise InvalidDataError("OAK frame type", "GRAY8 or RAW8", kind)
    w, h = frame.getWidth(), frame.getHeight()
    data = np.asarray(frame.getData(), np.uint8)
    if data.size < w * h:
        raise InvalidDataError("OAK frame data", f"{w * h} bytes for {w}x{h}", data.size)
    return data[: w * h].reshape(h, w).copy()


class StereoPairer:
    """Pairs left and right frames with the same sequence number into `StereoFrame`s.

    A frame waiting more than `max_pending` sequence numbers for its partner is dropped and
    counted (the other camera lost it)."""

    def __init__(self, max_pending: int = 8) -> None:
        self.max_pending = max_pending
        self._pending: dict[str, dict[int, tuple[int, np.ndarray]]] = {"left": {}, "right": {}}
        self.pairs = 0
        self.unpaired = 0

    def add(self, side: str, frame) -> StereoFrame | None:
        seq = int(frame.getSequenceNum())
        stamp = timedelta_ns(frame.getTimestamp())
        image = frame_to_array(frame)
        other = "right" if side == "left" else "left"
        match = self._pending[other].pop(seq, None)
        if match is None:
            self._pending[side][seq] = (stamp, image)
            for s in [s for s in self._pending[side] if s < seq - self.max_pending]:
                del self._pending[side][s]
                self.unpaired += 1
            return None
        images = {side: image, other: match[1]}
        self.pairs += 1
        return StereoFrame(min(stamp, match[0]), seq, images["left"], images["right"])


class OakSource(Source):
    """Frames from an OAK device (a context manager; `close()` from any thread)."""

    def __init__(self, size: tuple[int, int] = (640, 400), fps: float = 30.0,
                 device_id: str | None = None, queue_size: int = 4,
                 backoff_s: tuple[float, float] = (0.5, 10.0)) -> None:
        self.size, self.fps, self.device_id = size, fps, device_id
        self.queue_size, self.backoff_s = queue_size, backoff_s
        super().__init__()
        self.pairer = StereoPairer()
        self.frames = 0
        self.reconnects = 0
        self.errors: Counter = Counter()
        self.calibration = None

    def counters(self) -> dict:
        return dict(frames=self.frames, unpaired=self.pairer.unpaired,
                    reconnects=self.reconnects, errors=dict(self.errors))

    def _build(self):
        import depthai as dai

        from edge_depth.calibration.oak import stereo_from_handler

        device = dai.Device(dai.DeviceInfo(self.device_id)) if self.device_id else dai.Device()
        pipeline = dai.Pipeline(device)
        queues = {}
        for side, socket in (("left", dai.CameraBoardSocket.CAM_B),
                             ("right", dai.CameraBoardSocket.CAM_C)):
            cam = pipeline.create(dai.node.Camera).build(socket)
            out = cam.requestOutput(self.size, dai.ImgFrame.Type.GRAY8, fps=self.fps)
            queues[side] = out.createOutputQueue(maxSize=self.queue_size, blocking=False)
        self.calibration = stereo_from_handler(device.readCalibration(), self.size)
        pipeline.start()
        return pipeline, queues

    def __iter__(self):
        backoff = Backoff(self._stop, *self.backoff_s)
        connected_once = False
        while not self._stop.is_set():
            try:
                pipeline, queues = self._build()
            except RuntimeError as exc:  # no device, or X_LINK trouble while opening
                self.errors[f"open: {exc}"[:80]] += 1
                log.warning("OAK: %s; retrying in %.1f s", exc, backoff.delay)
                backoff.wait()
                continue
            if connected_once:
                self.reconnects += 1
            connected_once = True
            backoff.reset()
            try:
                with pipeline:
                    while pipeline.isRunning() and not self._stop.is_set():
                        got = False
                        for side, queue in queues.items():
                            frame = queue.tryGet()
                            if frame is None:
                                continue
                            got = True
                            try:
                                pair = self.pairer.add(side, frame)
                            except InvalidDataError as exc:
                                self.errors[str(exc)[:80]] += 1
                                continue
                            if pair is not None:
                                self.frames += 1
                                yield pair
                        if not got:
                            time.sleep(0.001)
            except RuntimeError as exc:  # X_LINK_ERROR: the device went away
                self.errors["xlink"] += 1
                log.warning("OAK: %s; reconnecting", exc)
