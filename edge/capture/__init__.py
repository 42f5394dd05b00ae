"""Sources of stereo frames and LiDAR scans: hardware adapters, MCAP replay, the synthetic rig.

A source is an iterable of events (`StereoFrame`, `LidarScan`, and for replay and the rig
`Calibration` / `GroundTruth`), a context manager, and stops on `close()` from any thread."""

from __future__ import annotations

import queue
import threading


class Source:
    """What every source shares: `close()` (from any thread) sets `_stop`, which the source's
    iteration checks; as a context manager it closes itself on exit."""

    def __init__(self) -> None:
        self._stop = threading.Event()

    def close(self) -> None:
        self._stop.set()

    def counters(self) -> dict:
        """What the source counted (decode errors, reconnects, unpaired frames …): it goes
        to /diagnostics and the closing summary. A source with nothing to count: {}."""
        return {}

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Backoff:
    """Exponential back-off between reconnect attempts (the serial LiDARs and the OAK):
    `wait()` waits the current delay on `stop` (so a close ends it at once) and doubles it up
    to `max_s`; `reset()` after a success starts again at `first_s`."""

    def __init__(self, stop: threading.Event, first_s: float, max_s: float) -> None:
        self.stop, self.first_s, self.max_s = stop, first_s, max_s
        self.delay = first_s

    def wait(self) -> None:
        self.stop.wait(self.delay)
        self.delay = min(2 * self.delay, self.max_s)

    def reset(self) -> None:
        self.delay = self.first_s


class MergedSource(Source):
    """Several sources (a camera and a LiDAR) as one event stream: each runs in its own
    thread; events come out in arrival order. Ends when every source has ended."""

    def __init__(self, sources: list) -> None:
        super().__init__()
        self.sources = sources
        self._queue: queue.Queue = queue.Queue(maxsize=256)
        self.errors: list[BaseException] = []

    def close(self) -> None:
        super().close()
        for source in self.sources:
            source.close()

    def counters(self) -> dict:
        return {type(s).__name__: s.counters() for s in self.sources if s.counters()}

    def _pump(self, source) -> None:
        try:
            for event in source:
                while not self._stop.is_set():
                    try:
                        self._queue.put(event, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if self._stop.is_set():
                    break
        except Exception as exc:  # noqa: BLE001 - reported by the consumer's thread
            self.errors.append(exc)
        finally:
            self._queue.put(None)

    def __iter__(self):
        threads = [threading.Thread(target=self._pump, args=(s,), daemon=True)
                   for s in self.sources]
        for t in threads:
            t.start()
        running = len(threads)
        while running:
            event = self._queue.get()
            if event is None:
                running -= 1
                continue
            yield event
        if self.errors:
            raise self.errors[0]
