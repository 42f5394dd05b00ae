"""What each `[log] results` topic costs the daemon: `McapLogger.log_result` on one engine
result (640x400 rig frame) with each set of result topics, median ms of 40 frames, and the
bytes written a frame (lz4 chunks); then every result topic under each `[log] compression`.

    python experiments/log_cost.py
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time

import numpy as np

from edge_depth.mcap_log import COMPRESSIONS, McapLogger
from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample
from edge_depth.topics import RESULT_TOPICS

SETS = [RESULT_TOPICS, ("disparity", "depth", "points", "diagnostics"),
        ("depth", "points", "diagnostics"), ("depth", "diagnostics"), ("disparity",),
        ("points",), ("diagnostics",)]


def main() -> None:
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    s = make_sample(1_000_000, RigConfig(), "beams16")
    sparse, valid = s.sparse_disparity("left")
    sparse = (sparse * valid).astype(np.float32)
    r = Engine(threads=2).infer(s.left, s.right, sparse, focal_px=s.rig.focal_px,
                                baseline_m=s.rig.baseline_m)
    runs = [(topics, "lz4") for topics in SETS] + \
        [(RESULT_TOPICS, compression) for compression in COMPRESSIONS]
    for topics, compression in runs:
        path = os.path.join(tempfile.mkdtemp(), "x.mcap")
        times = []
        with McapLogger(path, topics=topics, compression=compression) as logger:
            for i in range(43):
                t = time.perf_counter()
                logger.log_result(r, sparse, s.rig.focal_px, (s.rig.cx, s.rig.cy), s.left)
                if i >= 3:
                    times.append((time.perf_counter() - t) * 1000)
        mb = os.path.getsize(path) / 43 / 1e6
        print(f"{', '.join(topics):55s} {compression:4s} {statistics.median(times):5.2f} ms  "
              f"{mb:5.2f} MB")


if __name__ == "__main__":
    main()
