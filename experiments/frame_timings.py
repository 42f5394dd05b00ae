"""`edge-depth` with each processed frame's timings and EPE kept, for where a live run's
latency goes (docs/experiments.md, 2026-12-08 01:17).

    [bash experiments/avx2_kernels.sh] python experiments/frame_timings.py OUT.json \
        run --config experiments/sim_robot_camera_rate.toml --max-frames 300

Writes OUT.json: per frame its stamp, whether it was carried, its EPE against the sim's
ground truth (-1 without) and its capture-queue wait, LiDAR wait, engine, propagation, frame
and end-to-end ms (-1 where the frame has none).
"""

from __future__ import annotations

import atexit
import json
import sys

from edge_depth import daemon
from edge_depth.cli import main

KEYS = ("capture_queue", "sync_wait", "engine", "propagate", "frame", "end_to_end", "log")


def keep_timings(path: str) -> None:
    rows: list[dict] = []
    finish = daemon.Pipeline.finish

    def finish_kept(self, p, result):
        out = finish(self, p, result)
        t = self.stats.timings[-1] if self.stats.timings else {}
        rows.append(dict(stamp=p.frame.stamp_ns, carried=bool(p.carried),
                         epe=float(out.metrics["epe"]) if out.metrics else -1.0,
                         **{k: round(float(t.get(k, -1)), 1) for k in KEYS}))
        return out

    daemon.Pipeline.finish = finish_kept
    atexit.register(lambda: json.dump(rows, open(path, "w")))


if __name__ == "__main__":
    keep_timings(sys.argv[1])
    sys.argv = ["edge-depth"] + sys.argv[2:]
    sys.exit(main())
