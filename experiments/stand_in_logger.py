"""A process that does a logger's work on the side: every PERIOD_S it lz4-compresses and
writes what one frame's logging writes (four float images, the sparse map, the rectified pair)
REPEAT times over, for SECONDS; then prints its median work per period. Beside the daemon
logging nothing, it bounds what moving the logging into a process of its own would gain
(`experiments/logger_process_probe.sh`).

    python experiments/stand_in_logger.py 0.09 9 3
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time

import lz4.frame
import numpy as np


def main() -> None:
    period, seconds, repeat = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    rng = np.random.default_rng(0)
    floats = [(rng.random((400, 640)) * 60).astype(np.float32) for _ in range(4)]
    sparse = np.zeros((400, 640), np.float32)
    sparse[::25, ::2] = 5.0
    pair = [(rng.random((400, 640)) * 255).astype(np.uint8) for _ in range(2)]
    work = []
    end = time.time() + seconds
    with tempfile.TemporaryFile() as out:
        while time.time() < end:
            t = time.perf_counter()
            out.seek(0)
            for image in (floats + [sparse] + pair) * repeat:
                out.write(lz4.frame.compress(image.tobytes(), compression_level=0))
            work.append(time.perf_counter() - t)
            time.sleep(max(0.0, period - (time.perf_counter() - t)))
    print(f"stand-in logger: {statistics.median(work) * 1000:.1f} ms of work every "
          f"{period * 1000:.0f} ms", file=sys.stderr)


if __name__ == "__main__":
    main()
